"""Footprint and geometric (slope / roughness) kernel g(t), docs/instrument.md §3.2.

σ_g² = (2/c)² [σ_ξ²/cos²φ + σ_f² (tan²θ_x + tan²θ_y) + (R σ_θ²)²], with R = H/cos φ the slant
range, σ_f = R σ_θ the footprint rms radius, θ_x = φ − s the signed angle between the beam axis
and the mean-surface normal in the pointing plane (θ_y = 0 here), σ_ξ the rms height (Gardner
roughness) and σ_θ the beam's angular σ. Divergences are read as 1/e² full angles [A], so
σ_θ = θ_div/4 and the beam half-angle δ = θ_div/2 = 2σ_θ.
"""
from __future__ import annotations

import math

C_M_PER_NS = 0.299792458


def beam_sigma(divergence_full_deg: float) -> float:
    """Angular σ_θ of the beam, rad, from the full 1/e² divergence (deg)."""
    return math.radians(divergence_full_deg) / 4.0


def half_angle(divergence_full_deg: float) -> float:
    """Beam half-angle δ, rad (the paper's δ: 30 µrad for BELA, docs/instrument.md §1 item 1)."""
    return math.radians(divergence_full_deg) / 2.0


def slant_range(altitude_m: float, pointing_deg: float) -> float:
    """R = H / cos φ, m."""
    return altitude_m / math.cos(math.radians(pointing_deg))


def footprint_radius(altitude_m: float, half_angle_rad: float) -> float:
    """Radius a = 2 H tan δ of the flat-surface specular spot at the receiver, m (paper eq. 7):
    24.0 m at 400 km and 84.0 m at 1400 km for BELA's δ = 30 µrad."""
    return 2.0 * altitude_m * math.tan(half_angle_rad)


def geometric_sigma(altitude_m: float, divergence_full_deg: float, pointing_deg: float = 0.0,
                    slope_deg: float = 0.0, rms_height_m: float = 0.0) -> float:
    """σ_g of the geometric kernel, ns (formula above)."""
    phi = math.radians(pointing_deg)
    sigma_theta = beam_sigma(divergence_full_deg)
    r = slant_range(altitude_m, pointing_deg)
    sigma_f = r * sigma_theta
    theta_x = phi - math.radians(slope_deg)
    var = (rms_height_m ** 2 / math.cos(phi) ** 2 + sigma_f ** 2 * math.tan(theta_x) ** 2
           + (r * sigma_theta ** 2) ** 2)
    return 2.0 / C_M_PER_NS * math.sqrt(var)
