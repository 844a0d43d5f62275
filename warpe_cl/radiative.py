"""Radiative parameters of a medium, and the Fresnel laws on the host (docs/physics.md §3–§4).

A preset gives its medium either directly in radiative terms (``medium.radiative: {tau0,
omega, n, k}``) or physically (grain size, compacity, materials); both end here as the same
set of numbers: the optical depth τ0, the single-scattering albedo ω, the effective index
(n_eff, k_eff), the extinction coefficient E = τ0/h and the first back-and-forth time.
"""
from __future__ import annotations

import functools
import warnings

import numpy as np

from .errors import ConfigError, WarpeWarning
from .materials import lookup, optical_constants
from .params import C_M_PER_NS


def fresnel_external(mu, n: float, k: float = 0.0):
    """Unpolarised reflectance from vacuum into a medium of index n + ik (Hapke 1993 eqs.
    4.48–4.53, docs/physics.md §3.4).

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
    critical angle (docs/physics.md §3.5).

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
    """R0 = ((n − 1)² + k²)/((n + 1)² + k²), a slab's specular fraction (docs/physics.md §3.4)."""
    return ((n - 1.0) ** 2 + k * k) / ((n + 1.0) ** 2 + k * k)


@functools.lru_cache(maxsize=4)
def _gauss_legendre(order: int) -> tuple:
    """Gauss–Legendre nodes and weights on [−1, 1], computed once per order (an eigenvalue
    problem of size ``order``: ~0.1 s at 400, which a sweep would otherwise pay per point)."""
    x, w = np.polynomial.legendre.leggauss(order)
    x.flags.writeable = False
    w.flags.writeable = False
    return x, w


def _hemispherical(reflectance, order: int = 400) -> float:
    """∫₀¹ R(μ) 2μ dμ by Gauss–Legendre quadrature (R smooth on [0, 1])."""
    x, w = _gauss_legendre(order)
    mu = 0.5 * (x + 1.0)
    return float(np.sum(0.5 * w * reflectance(mu) * 2.0 * mu))


def hemispherical_external(n: float, k: float = 0.0) -> float:
    """S_e, the cosine-weighted hemispherical reflectance from vacuum (docs/physics.md §3.6)."""
    return _hemispherical(lambda mu: fresnel_external(mu, n, k))


def hemispherical_internal(n: float) -> float:
    """S_i: the same for light inside the medium, total internal reflection included.

    Below the critical cosine μ_c = √(1 − 1/n²) the reflectance is 1 (∫₀^μc 2μ dμ = μ_c²);
    the rest is integrated by Gauss–Legendre quadrature on [μ_c, 1], where R is smooth.
    """
    if n <= 1.0:
        return _hemispherical(lambda mu: fresnel_internal(mu, n))
    mu_c = np.sqrt(1.0 - 1.0 / (n * n))
    x, w = _gauss_legendre(400)
    mu = mu_c + 0.5 * (x + 1.0) * (1.0 - mu_c)
    partial = np.sum(0.5 * (1.0 - mu_c) * w * fresnel_internal(mu, n) * 2.0 * mu)
    return float(mu_c ** 2 + partial)


def first_bf_time(thickness_m: float, n: float) -> float:
    """t1 = 2 h n_eff / c, ns: the first back-and-forth time (docs/physics.md §5.7)."""
    return 2.0 * thickness_m * n / C_M_PER_NS


def _derived(texture: str, thickness: float, tau0: float, extinction: float, omega: float,
             n: float, k: float) -> dict:
    """The derived parameters every medium reports, from its radiative values (SI)."""
    return {
        "tau0": float(tau0),
        "omega": float(omega),
        "extinction_per_m": float(extinction),
        "n_eff": float(n),
        "k_eff": float(k),
        "first_bf_time_ns": first_bf_time(thickness, n),
        "specular_r0": normal_reflectance(n, k) if texture == "slab" else 0.0,
        "thickness_m": float(thickness),
    }


def relative_index(n_i: float, k_i: float, n_m: float, k_m: float) -> tuple:
    """Complex relative index m_i / m_m of an inclusion in a matrix (docs/physics.md §3.3,
    Andrieu's ``fresnel_coef.pro``): returns ``(n_rel, k_rel)``."""
    m = complex(n_i, k_i) / complex(n_m, k_m)
    return m.real, m.imag


def hapke_internal_path(n_rel: float, diameter: float) -> float:
    """Mean internal path ⟨D⟩ of a sphere, m (Hapke 1993 ch. 11; docs/physics.md §4.4):
    (2/3)[n² − (1/n)(n² − 1)^{3/2}] d for n > 1, and the n → 1 limit (2/3) d otherwise."""
    if n_rel <= 1.0:
        return 2.0 / 3.0 * diameter
    return 2.0 / 3.0 * (n_rel ** 2 - (n_rel ** 2 - 1.0) ** 1.5 / n_rel) * diameter


def particle_albedo(n_rel: float, k_rel: float, absorption: float, diameter: float,
                    integrals: str = "exact") -> dict:
    """Single-scattering albedo of one particle by Hapke's equivalent slab (Hapke 1993 eqs.
    11.14, 11.15a; docs/physics.md §4.4), without internal scatterers (s = 0).

    Parameters
    ----------
    n_rel, k_rel : float
        Relative index of the particle in its surroundings (k_rel < 0, a particle less absorbing
        than its matrix, is taken as 0 in the Fresnel terms: a 1e-6 effect for ices).
    absorption : float
        Internal absorption coefficient α = 4π k / λ, m⁻¹.
    diameter : float
        Particle diameter d, m.
    integrals : {"exact", "hapke"}
        S_e, S_i by quadrature of the Fresnel law, or Hapke's approximations (n_rel > 1 only).

    Returns
    -------
    dict
        ``w``, ``s_e``, ``s_i``, ``theta`` (internal transmission Θ = exp(−α⟨D⟩)),
        ``mean_path_m`` (⟨D⟩).
    """
    k_f = max(k_rel, 0.0)
    if integrals == "hapke":
        s_e = normal_reflectance(n_rel, k_f) + 0.05
        s_i = 1.014 - 4.0 / (n_rel * (n_rel + 1.0) ** 2)
    else:
        s_e = hemispherical_external(n_rel, k_f)
        s_i = hemispherical_internal(n_rel)
    path = hapke_internal_path(n_rel, diameter)
    theta = float(np.exp(-absorption * path))
    w = s_e + (1.0 - s_e) * (1.0 - s_i) * theta / (1.0 - s_i * theta)
    return {"w": float(w), "s_e": s_e, "s_i": s_i, "theta": theta, "mean_path_m": path}


def porosity_factor(compacity: float, texture: str) -> float:
    """Close-packing factor C_γ (paper eqs. 1–2; docs/physics.md §4.2): −ln(1 − γ)/γ for a granular
    medium, ln(γ)/(γ − 1) for a slab (the granular form with the particle fraction 1 − γ).
    Its limit at a vanishing particle fraction is 1."""
    phi = compacity if texture == "granular" else 1.0 - compacity
    if phi <= 0.0:
        return 1.0
    return float(-np.log1p(-phi) / phi)


def _warn(message: str):
    warnings.warn(message, WarpeWarning, stacklevel=3)


def _spec(cfg) -> dict:
    """The single medium of ``cfg`` as a layer: texture, thickness and composition."""
    return {name: cfg.get(f"medium.{name}") for name in
            ("texture", "thickness", "radiative", "compacity", "matrix", "inclusions")}


def physical_parameters(cfg, layer: dict | None = None, where: str = "medium") -> dict:
    """Radiative parameters of a medium given physically (docs/physics.md §3–§4).

    Slab: a matrix (volume fraction γ_c) holding inclusions; granular: grains (volume fraction
    γ_c) and void pores. For each species i (relative proportion ρ_i, diameter d_i):
    N_i = φ ρ_i/(π d_i³/6) with φ the particle fraction, σ_i = Q_e π d_i²/4, w_i by Hapke's
    equivalent slab; E = C_γ Σ N_i σ_i + a_m, S = C_γ Σ N_i σ_i w_i, ω = S/E, τ0 = E h;
    n_eff, k_eff by volume mixing (paper eqs. 5–6).

    Parameters
    ----------
    cfg : warpe_cl.config.Config
        The configuration: materials, wavelength and the medium-level options
        (``extinction_efficiency``, ``matrix_absorption``, ``inclusion_absorption``,
        ``fresnel_integrals``).
    layer : dict, optional
        The medium or layer to compute (``texture``, ``thickness``, ``compacity``,
        ``matrix``, ``inclusions``, as in ``Config.data``); default: the single medium.
    where : str
        Its key in messages (``"medium"``, ``"medium.layers[1]"``).

    Returns
    -------
    dict
        The keys of :func:`radiative_parameters`, plus ``porosity_factor``,
        ``matrix_absorption_per_m`` and ``species`` (one dict per inclusion: material,
        n_rel, k_rel, number_density_per_m3, cross_section_m2, w, s_e, s_i).
    """
    layer = _spec(cfg) if layer is None else layer
    source = cfg.source
    texture = layer["texture"]
    h = layer["thickness"]
    gamma = layer["compacity"]
    lam = cfg.get("wavelength")
    q_e = cfg.get("medium.extinction_efficiency")
    integrals = cfg.get("medium.fresnel_integrals")
    constants = optical_constants(cfg)
    inclusions = layer["inclusions"]
    total_rho = sum(inc["proportion"] for inc in inclusions)
    what = "medium" if where == "medium" else "layer"

    if texture == "granular" and gamma >= 1.0:
        raise ConfigError(f"{gamma:g} is not allowed for a granular {what}; give a compacity in "
                          "(0, 1) (at 1 the pores vanish: describe a compact layer as a slab)",
                          key=f"{where}.compacity", source=source)
    if texture == "slab":
        n_m, k_m = lookup(constants, layer["matrix"], f"{where}.matrix", source,
                          cfg.get("wavelength"))
        phi = 1.0 - gamma
        a_m = 4.0 * np.pi * k_m / lam
        if cfg.get("medium.matrix_absorption") == "volume_weighted":
            a_m *= gamma
    else:
        n_m, k_m = 1.0, 0.0
        phi = gamma
        a_m = 0.0

    species, n_mix, k_mix = [], 0.0, 0.0
    extinction_particles = scattering = 0.0
    for i, inc in enumerate(inclusions):
        key = f"{where}.inclusions[{i}]"
        n_i, k_i = lookup(constants, inc["material"], key + ".material", source,
                          cfg.get("wavelength"))
        rho = inc["proportion"] / total_rho
        d = inc["grain_size"]
        n_mix += n_i * rho
        k_mix += k_i * rho
        n_rel, k_rel = relative_index(n_i, k_i, n_m, k_m)
        if integrals == "hapke" and n_rel <= 1.0:
            raise ConfigError(f"Hapke's S_e/S_i approximations are invalid for {inc['material']} "
                              f"in its surroundings (n_rel = {n_rel:.4g} <= 1"
                              + ("" if where == "medium" else f", {key}")
                              + "); use fresnel_integrals: exact",
                              key="medium.fresnel_integrals", source=source)
        k_abs = k_i if cfg.get("medium.inclusion_absorption") == "absolute" else max(k_rel, 0.0)
        particle = particle_albedo(n_rel, k_rel, 4.0 * np.pi * k_abs / lam, d, integrals)
        number = phi * rho / (np.pi * d ** 3 / 6.0)
        sigma = q_e * np.pi * d ** 2 / 4.0
        extinction_particles += number * sigma
        scattering += number * sigma * particle["w"]
        species.append({"material": inc["material"], "proportion": rho,
                        "proportion_given": float(inc["proportion"]), "grain_size_m": d,
                        "n_rel": n_rel, "k_rel": k_rel, "number_density_per_m3": number,
                        "cross_section_m2": sigma, **particle})
        if phi <= 0.0 or h <= 0.0:
            continue   # compacity 1: a pure slab, the inclusion is a placeholder; h = 0: no layer
        if d > 0.1 * h:
            _warn(f"{key}.grain_size: {d * 1e3:g} mm is more than a tenth of the thickness "
                  f"({h * 1e3:g} mm): a continuous medium of grains is doubtful")
        if np.pi * d / lam < 30.0:
            _warn(f"{key}.grain_size: {d * 1e6:g} um is close to the wavelength "
                  f"({lam * 1e9:g} nm; size parameter pi d / lambda = {np.pi * d / lam:.3g} < 30): "
                  "geometric optics and Hapke's equivalent slab are doubtful")

    c_gamma = porosity_factor(gamma, texture)
    if texture == "slab":
        n_eff = n_m * gamma + n_mix * (1.0 - gamma)
        k_eff = k_m * gamma + k_mix * (1.0 - gamma)
    else:
        n_eff = n_mix * gamma + 1.0 * (1.0 - gamma)
        k_eff = k_mix * gamma
    extinction = c_gamma * extinction_particles + a_m
    omega = c_gamma * scattering / extinction if extinction > 0 else 0.0
    return {
        **_derived(texture, h, extinction * h, extinction, omega, n_eff, k_eff),
        "porosity_factor": c_gamma,
        "matrix_absorption_per_m": float(a_m),
        "species": species,
    }


def medium_parameters(cfg, layer: dict | None = None, where: str = "medium") -> dict:
    """Radiative parameters of one medium or layer, from either form: the one computation of
    a single medium and of each layer of a stack.

    Parameters
    ----------
    cfg : warpe_cl.config.Config
        Materials, wavelength and the medium-level options of the physical form.
    layer : dict, optional
        ``texture``, ``thickness``, ``radiative`` or the physical keys (``compacity``,
        ``matrix``, ``inclusions``), as in ``Config.data``; default: the single medium.
    where : str
        Its key in messages (``"medium"``, ``"medium.layers[1]"``).

    Returns
    -------
    dict
        The keys listed by :func:`radiative_parameters` for a single medium. A layer of
        thickness 0 (no layer) given radiatively has ``extinction_per_m`` 0.
    """
    layer = _spec(cfg) if layer is None else layer
    if layer["radiative"] is None:
        return physical_parameters(cfg, layer, where)
    h = layer["thickness"]
    rad = layer["radiative"]
    tau0 = rad["tau0"]
    return _derived(layer["texture"], h, tau0, tau0 / h if h > 0 else 0.0, rad["omega"],
                    rad["n"], rad["k"])


def substrate_index(cfg) -> tuple | None:
    """``(n, k)`` of ``medium.substrate`` (its material's constants at the wavelength, or the
    n and k given), or None without a substrate."""
    spec = cfg.get("medium.substrate")
    if spec is None:
        return None
    if spec.get("material") is None:
        return float(spec["n"]), float(spec["k"])
    n, k = lookup(optical_constants(cfg), spec["material"], "medium.substrate.material",
                  cfg.source, cfg.get("wavelength"))
    return float(n), float(k)


def radiative_parameters(cfg) -> dict:
    """Derived radiative parameters of a configuration's medium, from either form.

    Parameters
    ----------
    cfg : warpe_cl.config.Config

    Returns
    -------
    dict
        ``tau0`` (1), ``omega`` (1), ``extinction_per_m`` (m⁻¹), ``n_eff``, ``k_eff`` (1),
        ``first_bf_time_ns`` (ns), ``specular_r0`` (1; the slab's normal-incidence Fresnel
        reflectance, 0 for granular media, which have no interface), ``thickness_m`` (m); the
        physical form adds ``porosity_factor``, ``matrix_absorption_per_m`` and ``species``.

        A stack (``medium.layers``) or a medium over a substrate adds ``layers``: one dict
        per layer of the preset, top first, with the keys above (of that layer alone) and
        ``texture`` and ``phase_g`` (a layer of thickness 0 is listed, with
        ``thickness_m`` 0: the walk leaves it out); ``echo_times_ns``: 2 Σ_{i<=j} h_i n_i / c
        of the bottom of each layer j, ns; and with a substrate ``substrate_n``,
        ``substrate_k``. The top-level keys are then those of the top layer of the walk
        (the first of thickness > 0), but for ``thickness_m``, the stack's, and
        ``first_bf_time_ns``, the floor's echo (the last of ``echo_times_ns``).
    """
    layers = cfg.get("medium.layers")
    substrate = substrate_index(cfg)
    if layers is None and substrate is None:
        return medium_parameters(cfg)
    if layers is None:      # one layer over a substrate
        out = medium_parameters(cfg)
        per_layer = [{**out, "texture": cfg.get("medium.texture"),
                      "phase_g": cfg.get("medium.phase_g")}]
    else:
        per_layer = [{**medium_parameters(cfg, layer, f"medium.layers[{i}]"),
                      "texture": layer["texture"], "phase_g": layer["phase_g"]}
                     for i, layer in enumerate(layers)]
        top = next(d for d in per_layer if d["thickness_m"] > 0)
        out = {k: v for k, v in top.items() if k not in ("texture", "phase_g")}
    out["layers"] = per_layer
    # each layer's leg 2 h_i n_i / c is its own first back-and-forth time
    out["echo_times_ns"] = [float(t) for t in np.cumsum([d["first_bf_time_ns"]
                                                         for d in per_layer])]
    # the first back-and-forth time of a stack is its floor's echo (docs/walk.md §7.2)
    out["first_bf_time_ns"] = out["echo_times_ns"][-1]
    out["thickness_m"] = float(sum(d["thickness_m"] for d in per_layer))
    if substrate is not None:
        out["substrate_n"], out["substrate_k"] = substrate
    return out
