"""Radiometry: lidar equation for the diffuse part, photon budgets, background and the number
of speckle modes, docs/instrument.md §3.3 and §3.5.

Photons at the aperture from a surface response of integrated reflectance ∫R dt (sr⁻¹):
N = E_t η_t T_atm² Ω_r ∫R dt / (hν), Ω_r = π D_r²/(4R²). For a Lambertian surface of albedo A,
∫R dt = A/π.
"""
from __future__ import annotations

import math

from .footprint import slant_range
from .specular import receiver_solid_angle

PLANCK = 6.62607015e-34        # J s
LIGHT_SPEED = 299792458.0      # m s⁻¹
ELEMENTARY_CHARGE = 1.602176634e-19   # C


def photon_energy(wavelength_m: float) -> float:
    """hν = h c / λ, J."""
    return PLANCK * LIGHT_SPEED / wavelength_m


def transmitted_photons(params) -> float:
    """Photons leaving the instrument per shot, E_t η_t / (hν)."""
    return (params["transmitter.pulse_energy"] * params["transmitter.efficiency"]
            / photon_energy(params["wavelength"]))


def photons_per_reflectance(params) -> float:
    """Photons at the aperture per unit integrated reflectance (per sr⁻¹):
    E_t η_t T² Ω_r / (hν). BELA with η_t = 1: 5.26e4 at 400 km (docs/instrument.md §3.3)."""
    r = slant_range(params["geometry.altitude"], params["geometry.pointing"])
    t2 = params["geometry.atmosphere_transmission"] ** 2
    return transmitted_photons(params) * t2 * receiver_solid_angle(params["receiver.aperture"], r)


def detection_efficiency(params) -> float:
    """η_r η_q: photoelectrons per photon at the aperture."""
    return params["receiver.efficiency"] * params["detector.quantum_efficiency"]


def background_rate(params) -> float:
    """Background photoelectron rate, pe ns⁻¹ (§3.5).

    n_b = η_r η_q / (hν) · L_b Δλ A_r Ω_FOV, with L_b = scale · E_☉(1 AU)/d² · (A/π) cos i
    (W m⁻² sr⁻¹ nm⁻¹), A_r = π D_r²/4, Ω_FOV = π (θ_FOV/2)². ``background.count_rate``, when
    given, is the photoelectron rate itself.
    """
    if params["background.count_rate"] is not None:
        return params["background.count_rate"] * 1e-9
    cos_i = math.cos(math.radians(params["background.solar_incidence"]))
    cos_i = 0.0 if abs(cos_i) < 1e-12 else cos_i
    radiance = (params["background.scale"] * params["background.solar_irradiance"]
                / params["background.sun_distance"] ** 2 * params["background.albedo"] / math.pi
                * cos_i)
    area = math.pi * params["receiver.aperture"] ** 2 / 4.0
    omega_fov = math.pi * (math.radians(params["receiver.fov"]) / 2.0) ** 2
    watts = radiance * params["receiver.filter_width"] * 1e9 * area * omega_fov
    return detection_efficiency(params) * watts / photon_energy(params["wavelength"]) * 1e-9


def speckle_modes(params) -> float:
    """M = A_r π θ_div² / (4 λ²) (§3.3; BELA 78, GALA 340, ATLAS 1600), or the preset's value;
    inf when speckle is off (``modes: 0``)."""
    modes = params["speckle.modes"]
    if modes == "auto":
        area = math.pi * params["receiver.aperture"] ** 2 / 4.0
        theta = math.radians(params["transmitter.divergence"])
        return area * math.pi * theta ** 2 / (4.0 * params["wavelength"] ** 2)
    return math.inf if modes == 0 else float(modes)
