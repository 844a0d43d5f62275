"""Radiative parameters of a medium, and the Fresnel laws on the host (physics.md §3–§4).

A preset gives its medium either directly in radiative terms (``medium.radiative: {tau0,
omega, n, k}``) or physically (grain size, compacity, materials); both end here as the same
set of numbers: the optical depth τ0, the single-scattering albedo ω, the effective index
(n_eff, k_eff), the extinction coefficient E = τ0/h and the first back-and-forth time.
"""
from __future__ import annotations

import numpy as np

from .errors import ConfigError
from .params import C_M_PER_NS


def fresnel_external(mu, n: float, k: float = 0.0):
    """Unpolarised reflectance from vacuum into a medium of index n + ik (Hapke 1993 eqs.
    4.48–4.53, physics.md §3.4).

    Parameters
    ----------
    mu : float or array
        Cosine of the incidence angle (in vacuum).
    n, k : float
        Real and imaginary index of the medium.
    """
    mu = np.asarray(mu, dtype=float)
    a = (n * n - k * k - 1.0) + mu * mu     # n² − k² − sin²θ, without cancellation
    b = np.sqrt(a * a + 4.0 * n * n * k * k)
    g1 = np.sqrt(0.5 * (a + b))
    g2 = np.sqrt(np.maximum(0.5 * (b - a), 0.0))
    nk2 = n * n - k * k
    with np.errstate(invalid="ignore", divide="ignore"):  # 0/0 only for n = 1, k = 0 at mu = 0
        r_perp = ((mu - g1) ** 2 + g2 ** 2) / ((mu + g1) ** 2 + g2 ** 2)
        r_par = ((nk2 * mu - g1) ** 2 + (2 * n * k * mu - g2) ** 2) / (
            (nk2 * mu + g1) ** 2 + (2 * n * k * mu + g2) ** 2)
    return 0.5 * (r_perp + r_par)


def fresnel_internal(mu, n: float):
    """Unpolarised reflectance from inside a medium of real index n into vacuum; 1 beyond the
    critical angle (physics.md §3.5).

    Parameters
    ----------
    mu : float or array
        Cosine of the incidence angle inside the medium.
    """
    mu = np.asarray(mu, dtype=float)
    arg = (1.0 - n * n) + n * n * mu * mu   # cos²θ_t = 1 − n² sin²θ
    tir = arg <= 0.0
    cos_t = np.sqrt(np.where(tir, 0.0, arg))
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = (n * mu - cos_t) / (n * mu + cos_t)
        rp = (mu - n * cos_t) / (mu + n * cos_t)
    return np.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))


def normal_reflectance(n: float, k: float = 0.0) -> float:
    """R0 = ((n − 1)² + k²)/((n + 1)² + k²): the specular fraction of a slab (physics.md §3.4)."""
    return ((n - 1.0) ** 2 + k * k) / ((n + 1.0) ** 2 + k * k)


def _hemispherical(reflectance, order: int = 400) -> float:
    """∫₀¹ R(μ) 2μ dμ by Gauss–Legendre quadrature (R smooth on [0, 1])."""
    x, w = np.polynomial.legendre.leggauss(order)
    mu = 0.5 * (x + 1.0)
    return float(np.sum(0.5 * w * reflectance(mu) * 2.0 * mu))


def hemispherical_external(n: float, k: float = 0.0) -> float:
    """S_e: cosine-weighted hemispherical reflectance for light from vacuum (physics.md §3.6)."""
    return _hemispherical(lambda mu: fresnel_external(mu, n, k))


def hemispherical_internal(n: float) -> float:
    """S_i: the same for light inside the medium, total internal reflection included.

    Below the critical cosine μ_c = √(1 − 1/n²) the reflectance is 1 (∫₀^μc 2μ dμ = μ_c²);
    the rest is integrated by Gauss–Legendre quadrature on [μ_c, 1], where R is smooth.
    """
    if n <= 1.0:
        return _hemispherical(lambda mu: fresnel_internal(mu, n))
    mu_c = np.sqrt(1.0 - 1.0 / (n * n))
    x, w = np.polynomial.legendre.leggauss(400)
    mu = mu_c + 0.5 * (x + 1.0) * (1.0 - mu_c)
    partial = np.sum(0.5 * (1.0 - mu_c) * w * fresnel_internal(mu, n) * 2.0 * mu)
    return float(mu_c ** 2 + partial)


def first_bf_time(thickness_m: float, n: float) -> float:
    """t1 = 2 h n_eff / c, ns: the first back-and-forth time (physics.md §5.7)."""
    return 2.0 * thickness_m * n / C_M_PER_NS


def radiative_parameters(cfg) -> dict:
    """Derived radiative parameters of a configuration's medium.

    Parameters
    ----------
    cfg : warpe_cl.config.Config

    Returns
    -------
    dict
        ``tau0`` (1), ``omega`` (1), ``extinction_per_m`` (m⁻¹), ``n_eff``, ``k_eff`` (1),
        ``first_bf_time_ns`` (ns), ``specular_r0`` (1; the slab's normal-incidence Fresnel
        reflectance, 0 for granular media, which have no interface), ``thickness_m`` (m).
    """
    h = cfg.get("medium.thickness")
    texture = cfg.get("medium.texture")
    if not cfg.is_radiative:
        raise ConfigError("the physical form (matrix, inclusions, compacity) is not supported "
                          "by this version; give medium.radiative: {tau0, omega, n, k}",
                          key="medium", source=cfg.source)
    tau0 = cfg.get("medium.radiative.tau0")
    omega = cfg.get("medium.radiative.omega")
    n = cfg.get("medium.radiative.n")
    k = cfg.get("medium.radiative.k")
    return {
        "tau0": float(tau0),
        "omega": float(omega),
        "extinction_per_m": float(tau0 / h),
        "n_eff": float(n),
        "k_eff": float(k),
        "first_bf_time_ns": first_bf_time(h, n),
        "specular_r0": normal_reflectance(n, k) if texture == "slab" else 0.0,
        "thickness_m": float(h),
    }
