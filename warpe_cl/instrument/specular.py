"""Specular and BF-direct returns: the fraction κ of the reflected beam that hits the aperture,
docs/instrument.md §3.4 and docs/physics.md §7.3 (paper eqs. 7–11).

WARPE hands over the fractions f_spec, f_BF (per launched ray) and their delays; the instrument
turns each into photons at the aperture, E_t η_t T² f κ / (hν), here, in one place.

uniform_cone (the paper's rule): the reflected light fills a cone. A flat surface returns the beam
itself, a spot of radius a = 2R tan δ (δ the half-angle, 30 µrad for BELA); a facet-rough surface
spreads it into a lobe of half-angle θ_L, a spot of radius a_spec = R tan θ_L. The spot is the
larger of the two; its centre moves by 2R tan θ_tilt, and

    κ = (D_r/2)² / a²  if 2R|tan θ_tilt| ≤ a,  else 0.

(D_r/2)²/(R tan X)² = Ω_r / (π tan² X) with Ω_r = π D_r²/(4R²): the lobe solid angle of
:func:`warpe_cl.tally.lobe_solid_angle` that also scales the surface file's specular reflectance.

gaussian (smoother, [D]/[A]): the spot is a Gaussian of rms radius s, with
s² = (2Rσ_θ)² + (R σ_L)², σ_θ = δ/2 and σ_L = tan(θ_L)/2 (the same 1/e²-radius reading as the
beam), and κ = A_r / (2π s²) · exp(−(2R tan θ_tilt)² / (2 s²)).
"""
from __future__ import annotations

import math

from ..tally import lobe_solid_angle
from .footprint import half_angle


def receiver_solid_angle(aperture_m: float, range_m: float) -> float:
    """Ω_r = π D_r² / (4 R²), sr: the aperture seen from the ground."""
    return math.pi * aperture_m ** 2 / (4.0 * range_m ** 2)


def lobe_half_angle(roughness_deg: float, lobe_factor: float) -> float:
    """θ_L = lobe_factor × roughness, deg (seed: 0.1° roughness → 0.25° lobe, factor 2.5)."""
    return lobe_factor * roughness_deg


def aperture_fraction(aperture_m: float, range_m: float, divergence_full_deg: float,
                      lobe_deg: float, tilt_deg: float = 0.0,
                      model: str = "uniform_cone") -> float:
    """κ: fraction of a specularly reflected return that enters the aperture.

    Parameters
    ----------
    aperture_m : float
        Receiver diameter D_r, m.
    range_m : float
        Slant range R, m.
    divergence_full_deg : float
        Full 1/e² beam divergence, deg (δ is half of it).
    lobe_deg : float
        Roughness-lobe half-angle θ_L, deg (0: a flat surface, beam-limited).
    tilt_deg : float
        Angle between the beam axis and the mean-surface normal, deg.
    model : {"uniform_cone", "gaussian"}
    """
    delta = half_angle(divergence_full_deg)
    omega_r = receiver_solid_angle(aperture_m, range_m)
    tilt = math.radians(tilt_deg)
    if model == "uniform_cone":
        beam_cone = math.degrees(math.atan(2.0 * math.tan(delta)))   # a = 2R tan δ = R tan X
        spot_deg = max(beam_cone, lobe_deg)
        radius = range_m * math.tan(math.radians(spot_deg))
        if 2.0 * range_m * abs(math.tan(tilt)) > radius:
            return 0.0
        return omega_r / lobe_solid_angle(spot_deg)
    if model == "gaussian":
        s2 = (2.0 * range_m * delta / 2.0) ** 2 + (range_m * math.tan(math.radians(lobe_deg)) / 2.0) ** 2
        area = math.pi * aperture_m ** 2 / 4.0
        return area / (2.0 * math.pi * s2) * math.exp(-(2.0 * range_m * math.tan(tilt)) ** 2 / (2.0 * s2))
    raise ValueError(f"unknown lobe model {model!r}")
