"""From integer counts to physical quantities: the normalisations of docs/physics.md §7.

Nothing here knows how the counts were made (OpenCL engine or NumPy reference).
"""
from __future__ import annotations

import numpy as np

from .params import COMPONENTS, Counts, N_COMPONENTS, N_EMERGENCE, WalkParams, fixed_to_float

#: specular, bf_direct: delta functions in angle, scaled by the lobe
SPECULAR_LIKE = tuple(COMPONENTS.index(c) for c in ("specular", "bf_direct"))
#: bf_diffuse, scattering: counted inside their numerical FOV
DIFFUSE = tuple(COMPONENTS.index(c) for c in ("bf_diffuse", "scattering"))


def fov_solid_angle(fov_deg: float, convention: str = "cone") -> float:
    """Solid angle of a numerical field of view, sr (docs/physics.md §7.1, A10).

    ``cone``: 2π(1 − cos θ) (0.0086106 sr at 3°, 0.137303 sr at 12°);
    ``projected``: π sin²θ, with which a Lambertian surface reads exactly A/π.
    """
    theta = np.radians(fov_deg)
    if convention == "projected":
        return float(np.pi * np.sin(theta) ** 2)
    return float(2.0 * np.pi * (1.0 - np.cos(theta)))


def lobe_solid_angle(lobe_deg: float) -> float:
    """Ω_lobe = π tan²(θ_L), sr: the specular scaling of docs/physics.md §7.3.

    The paper's peak height R = N_spec·r_ap/(N·Ω·Δt), with r_ap = (A_r/2)²/(H tan θ_L)² and Ω the
    receiver's solid angle π(A_r/2)²/H² seen from the ground, is F/(Ω_lobe·Δt): the altitude H
    and the aperture A_r cancel (docs/physics.md A9). 5.98e-5 sr for θ_L = 0.25°.
    """
    return float(np.pi * np.tan(np.radians(lobe_deg)) ** 2)


def reduce_counts(counts: Counts, params: WalkParams, *, solid_angle: str = "cone",
                  specular_lobe: float = 0.25, min_rays: int = 3) -> dict:
    """The output variables of docs/interface.md §5 as NumPy arrays.

    Parameters
    ----------
    counts : Counts
    params : WalkParams
        For the time edges (ns) and the FOV of each component (deg).
    solid_angle : {"cone", "projected"}
        FOV normalisation of the diffuse components.
    specular_lobe : float
        Half-angle of the roughness lobe that scales specular and BF-direct, deg.
    min_rays : int
        Bins with fewer rays are flagged ``undersampled`` (specular exempt).

    Returns
    -------
    dict
        ``reflectance`` and ``reflectance_stderr`` (4, n_time) ns⁻¹ sr⁻¹; ``ray_count`` (4, n_time);
        ``undersampled`` (4, n_time) bool; ``hemispherical_reflectance`` (4, n_time) ns⁻¹;
        ``fraction`` (4,); ``early_fraction`` (4,), the rays (weighted: the weight) of each
        component leaving before the first time edge, per launched ray (in ``fraction`` and
        ``angular_reflectance``, never in a time bin); ``fate_fraction`` (5,);
        ``angular_reflectance`` (4, 90) sr⁻¹; ``omega_sr`` (4,), the solid angle each
        component is divided by.
    """
    n = counts.photons
    if n <= 0:
        raise ValueError("no photons were launched")
    edges = np.asarray(params.time_edges, dtype=float)
    width = np.diff(edges)
    omega_sr = np.empty(N_COMPONENTS)
    ray_count = np.empty_like(counts.time_any)
    for c in SPECULAR_LIKE:
        omega_sr[c] = lobe_solid_angle(specular_lobe)
        ray_count[c] = counts.time_any[c]
    for c in DIFFUSE:
        omega_sr[c] = fov_solid_angle(params.fov[c], solid_angle)
        ray_count[c] = counts.time_in_fov[c]
    scale = 1.0 / (n * omega_sr[:, None] * width[None, :])
    undersampled = ray_count < min_rays
    undersampled[COMPONENTS.index("specular")] = False
    e = np.radians(np.arange(N_EMERGENCE + 1, dtype=float))
    band = np.pi * np.diff(np.sin(e) ** 2)      # ∫ cos e dΩ over each 1° ring

    if counts.weighted:
        # docs/walk.md §6: every ray adds its weight w; the mean of w per launched ray is
        # unbiased, with standard error sqrt((<w^2> - <w>^2) / N).
        w_in, w_any = fixed_to_float(counts.w_time_in_fov), fixed_to_float(counts.w_time_any)
        w2_in = fixed_to_float(counts.w2_time_in_fov)
        w_bins = np.where(np.isin(np.arange(N_COMPONENTS), SPECULAR_LIKE)[:, None], w_any, w_in)
        # specular and bf_direct use any angle: their w^2 sums are those of the any-angle
        # cells, which the kernel also counts in time_in_fov (their FOV is 90 deg)
        variance = np.maximum(w2_in / n - (w_bins / n) ** 2, 0.0) / n
        sums = {"bins": w_bins, "any": w_any, "total": fixed_to_float(counts.w_total),
                "angular": fixed_to_float(counts.w_angular),
                "early": fixed_to_float(counts.w_early)}
        stderr = np.sqrt(variance) * n * scale
    else:
        sums = {"bins": ray_count, "any": counts.time_any, "total": counts.total,
                "angular": counts.angular, "early": counts.early}
        stderr = np.sqrt(ray_count) * scale   # Poisson error of each bin's count
    return {
        "reflectance": sums["bins"] * scale,
        "reflectance_stderr": stderr,
        "ray_count": ray_count,
        "undersampled": undersampled,
        "hemispherical_reflectance": sums["any"] / (n * width[None, :]),
        "fraction": sums["total"] / n,
        "early_fraction": sums["early"] / n,
        "fate_fraction": counts.fates / n,
        "angular_reflectance": sums["angular"] / (n * band[None, :]),
        "omega_sr": omega_sr,
    }
