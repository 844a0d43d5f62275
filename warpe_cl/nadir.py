"""The next-event (nadir) estimator's geometry and its reduction (docs/walk.md §8).

At every volume scattering and floor reflection the walk adds the probability, per steradian
of vacuum, that the ray leaves from there straight toward the receiver; this module computes,
once per scenario, what that probability needs besides the event itself (the view table the
kernel reads), and turns the kernel's exact sums into reflectances with their standard errors.

Geometry. The receiver looks down at zenith angle theta_v (azimuth 0; the incident beam is
vertical). Inside layer l, whose faces have the index m_l (a slab's n, a granular layer's
pores' 1), the ray that leaves along the view direction travels up at sin(theta_l) =
sin(theta_v) / m_l (Snell), mu_l = cos(theta_l). A virtual path from depth z in layer l to
vacuum crosses the rest of layer l and every layer above, and every Fresnel interface on the
way, whose transmissions T_j = 1 - R_j(mu_j) multiply. Radiance across a refracting interface
keeps L / m^2 (the etendue m^2 mu dOmega is conserved), so a density q per steradian inside
layer l becomes q T mu_v / (m_l^2 mu_l) per steradian of vacuum, and the bidirectional
reflectance (per unit incident irradiance, i.e. divided by mu_v) is
q T exp(-tau) / (m_l^2 mu_l): the ``factor`` column is T / (m_l^2 mu_l). In a slab over a
vacuum gap the paths that its faces reflect score too (:func:`mirror_table`).
"""
from __future__ import annotations

import math

import numpy as np

from .params import MIRROR_COLUMNS, MIRROR_KINDS, NADIR_ROWS, VIEW_COLUMNS, WalkParams, \
    fixed_to_float
from .radiative import fresnel_external, fresnel_internal

__all__ = ["view_table", "mirror_table", "up_transmission", "reduce_nadir", "mirror_below"]

#: The mirror table leaves out the virtual paths whose factor (the product of their
#: reflections and of e^-tau of their whole crossings) is below this (docs/walk.md §8.5).
MIRROR_CUT = 1e-9


def mirror_below(params: WalkParams) -> str | None:
    """Why the estimator would be incomplete for ``params``, or None where it is exact.

    The estimator follows each virtual path up along the view direction and, in a single slab
    over a vacuum gap, its mirror paths too (:func:`mirror_table`, docs/walk.md §8.5): a ray
    scattered down along the view's mirror image reflects on the slab's lower face and leaves
    toward the receiver, and every path bounces between the two faces. A stack with a Fresnel
    contact below its top has mirrors between layers whose paths are not followed: no nadir
    estimate there.
    """
    from .engine import layer_tables
    if not params.layered:
        return None
    kinds = layer_tables(params, np.float64)["iface_kind"]
    below = [j for j in range(1, len(kinds)) if kinds[j]]
    if below:
        return f"the stack's Fresnel contact {below[0]} (counted from the top, 0) is a mirror"
    return None


def mirror_table(params: WalkParams) -> np.ndarray:
    """The mirror paths of a slab over a vacuum gap (docs/walk.md §8.5), shape (K, 3): one row
    per virtual path besides the straight ones, columns :data:`~warpe_cl.params.MIRROR_COLUMNS`
    (kind, factor, extra path in m at the slab's speed). With μ the view direction's cosine in
    the slab, a = exp(−E h / μ) the transmission of one crossing, R_t and R_b the reflectances
    of the upper and lower faces at μ, ρ = R_t R_b a² one round trip and P = h / μ its half:

    - ``up`` (k ≥ 1): from a scattering, up along the view, k round trips: factor ρ^k, path
      2 k P (the straight path, k = 0, is the view table's);
    - ``down`` (k ≥ 0): from a scattering, down along the view's mirror image (its depth part
      E (h − z) / μ and (h − z) / μ taken in the kernel), reflected by the lower face, one
      crossing up and k round trips: factor R_b a ρ^k, path P + 2 k P;
    - ``gap`` (k ≥ 1): from the floor below the gap, k round trips after the crossing the
      view table's gap row holds: factor ρ^k, path 2 k P.

    Paths whose factor is below :data:`MIRROR_CUT` are left out (a bias below 1e-9 of the
    straight score). Empty for every other configuration (no mirror below a scattering
    layer, or a stack, whose mirrors :func:`mirror_below` refuses).
    """
    if params.layered or params.texture != "slab" or params.bottom_interface != "fresnel":
        return np.zeros((0, len(MIRROR_COLUMNS)))
    faces, gap = _faces(params)
    m = faces[0][0]
    sin_v = math.sin(math.radians(float(params.view_zenith)))
    mu = math.sqrt(max(0.0, 1.0 - (sin_v / m) ** 2))
    h = float(params.stack[0].thickness)
    a = math.exp(-float(params.stack[0].extinction) * h / mu)
    r_top = 1.0 - up_transmission(mu, m, 1.0, 0.0)
    r_bottom = 1.0 - up_transmission(mu, m, gap[0], gap[1])
    rho = r_top * r_bottom * a * a
    half = h / mu
    kind = {k: float(i) for i, k in enumerate(MIRROR_KINDS)}
    rows = []
    for name, first, factor, path in (("up", 1, rho, 2.0 * half),
                                      ("down", 0, r_bottom * a, half),
                                      ("gap", 1, rho, 2.0 * half)):
        k = first
        while factor >= MIRROR_CUT and k < 64:
            rows.append([kind[name], factor, path])
            factor *= rho
            path += 2.0 * half
            k += 1
    return np.asarray(rows, dtype=np.float64).reshape(-1, len(MIRROR_COLUMNS))


def _faces(params: WalkParams) -> tuple:
    """The face index (n, k) of each layer (top first), and of the gap medium below."""
    from .engine import gap_face
    return [layer.face for layer in params.stack], gap_face(params)


def up_transmission(mu: float, near: float, far_n: float, far_k: float) -> float:
    """Fresnel transmission 1 - R of an interface crossed upwards at incidence cosine ``mu``
    from the side of real index ``near`` into the face (far_n, far_k) (docs/walk.md §7.1):
    R_int(mu; near) toward vacuum, R_ext(mu; far/near) otherwise; 1 for equal faces; 0 beyond
    the critical angle."""
    if near == far_n and far_k == 0.0:
        return 1.0
    if near * math.sqrt(max(0.0, 1.0 - mu * mu)) >= far_n:
        return 0.0
    if far_n == 1.0 and far_k == 0.0:
        return 1.0 - float(fresnel_internal(mu, near))
    return 1.0 - float(fresnel_external(mu, far_n / near, far_k / near))


def view_table(params: WalkParams) -> np.ndarray:
    """The view table the kernel reads (docs/walk.md §8), shape (N + 1, len(VIEW_COLUMNS)).

    Row l < N is layer l of the stack (one row for a single layer), row N the gap medium below
    it (vacuum under a slab with a Fresnel bottom, the substrate of a stack; unused for a
    floor in contact). Columns (:data:`~warpe_cl.params.VIEW_COLUMNS`): sin and mu of the view
    direction inside; optical depth per metre of depth along it, E_l / mu_l (1/m); path per
    metre of depth at layer 0's speed, (n_l / n_0) / mu_l; the optical depth and the path (m)
    of the layers above; and T / (m_l^2 mu_l), the product of the upward Fresnel
    transmissions to vacuum over the etendue factor (0 where no real direction in the gap
    leaves along the view: m_g < sin theta_v).

    Parameters
    ----------
    params : WalkParams
        ``view_zenith`` in degrees; E_l is the true extinction (both modes).
    """
    sin_v = math.sin(math.radians(float(params.view_zenith)))
    layers = params.stack
    faces, gap = _faces(params)
    n0 = float(layers[0].n)
    rows = []
    tau_above = path_above = 0.0
    transmission = 1.0
    above = (1.0, 0.0)                       # vacuum above the stack
    for layer, face in zip(layers, faces):
        m = face[0]
        s = sin_v / m
        mu = math.sqrt(max(0.0, 1.0 - s * s))
        transmission *= up_transmission(mu, m, above[0], above[1])
        scale = float(layer.n) / n0
        rows.append([s, mu, float(layer.extinction) / mu, scale / mu, tau_above, path_above,
                     transmission / (m * m * mu)])
        tau_above += float(layer.extinction) * float(layer.thickness) / mu
        path_above += float(layer.thickness) * scale / mu
        above = face
    m = gap[0]
    if m > sin_v:
        s = sin_v / m
        mu = math.sqrt(max(0.0, 1.0 - s * s))
        factor = transmission * up_transmission(mu, m, above[0], above[1]) / (m * m * mu)
    else:
        s, mu, factor = 1.0, 0.0, 0.0
    rows.append([s, mu, 0.0, 0.0, tau_above, path_above, factor])
    table = np.asarray(rows, dtype=np.float64)
    assert table.shape[1] == len(VIEW_COLUMNS)
    return table


def _batch_error(sums: np.ndarray, batch_photons: np.ndarray) -> np.ndarray:
    """Standard error of sum_b S_b / N from the spread of the batch means (docs/walk.md §8):
    with m_b = S_b / n_b and m = sum S_b / N over the B batches that hold photons,
    var = B / (B - 1) sum_b (n_b / N)^2 (m_b - m)^2 (for equal batches, the variance of the
    batch means over B). ``sums`` has the batch axis first; NaN with fewer than 2 batches."""
    n_b = np.asarray(batch_photons, dtype=float)
    used = n_b > 0
    count = int(used.sum())
    shape = sums.shape[1:]
    if count < 2:
        return np.full(shape, np.nan)
    n = n_b.sum()
    s = sums[used]
    nb = n_b[used].reshape((-1,) + (1,) * len(shape))
    mean = s.sum(axis=0) / n
    var = count / (count - 1) * np.sum((nb / n) ** 2 * (s / nb - mean) ** 2, axis=0)
    return np.sqrt(var)


def reduce_nadir(counts, params: WalkParams, fov: dict) -> dict:
    """The nadir output variables (docs/interface.md §5.1) from a walk's counts.

    Parameters
    ----------
    counts : Counts
        With the estimator's sums (``counts.nadir``).
    params : WalkParams
    fov : dict
        :func:`warpe_cl.tally.reduce_counts` of the same counts: the specular and BF-direct
        returns are delta functions in angle, which no next-event estimate sees; their
        lobe-scaled values are copied from it, so that ``nadir_reflectance`` is a whole
        response.

    Returns
    -------
    dict
        ``nadir_reflectance``, ``nadir_reflectance_stderr`` (4, n_time) ns^-1 sr^-1 (the
        bidirectional reflectance per ns); ``nadir_ray_count`` (4, n_time);
        ``nadir_brdf``, ``nadir_brdf_stderr`` (4,) sr^-1, the time-integrated reflectance
        (every time, before the first edge and after the last included);
        ``nadir_order_reflectance``, ``nadir_order_reflectance_stderr`` (1, n_time) and
        ``nadir_order_brdf``, ``nadir_order_brdf_stderr`` (1,): the virtual paths of order 1.
    """
    from .params import COMPONENTS
    n = counts.photons
    width = np.diff(np.asarray(params.time_edges, dtype=float))
    sums = fixed_to_float(counts.nadir_sum)                  # (B, rows, n_time + 2)
    err = _batch_error(sums, counts.nadir_batch_photons)      # (rows, n_time + 2)
    mean = sums.sum(axis=0) / n
    total_mean = mean.sum(axis=-1)
    total_err = _batch_error(sums.sum(axis=-1), counts.nadir_batch_photons)
    n_time = len(width)
    refl = np.array(fov["reflectance"], dtype=float, copy=True)
    refl_err = np.array(fov["reflectance_stderr"], dtype=float, copy=True)
    ray_count = np.array(fov["ray_count"], copy=True)
    brdf = np.empty(len(COMPONENTS))
    brdf_err = np.empty(len(COMPONENTS))
    for c, name in enumerate(COMPONENTS):
        if name in NADIR_ROWS:
            r = NADIR_ROWS.index(name)
            refl[c] = mean[r, 1:n_time + 1] / width
            refl_err[c] = err[r, 1:n_time + 1] / width
            ray_count[c] = counts.nadir_visits[r, 1:n_time + 1]
            brdf[c], brdf_err[c] = total_mean[r], total_err[r]
        else:   # delta functions at nadir: the lobe-scaled fraction, as the FOV output
            omega = fov["omega_sr"][c]
            brdf[c] = fov["fraction"][c] / omega
            f = float(fov["fraction"][c])
            brdf_err[c] = math.sqrt(max(f * (1.0 - f), 0.0) / n) / omega   # binomial
    o = NADIR_ROWS.index("order_1")
    return {
        "nadir_reflectance": refl,
        "nadir_reflectance_stderr": refl_err,
        "nadir_ray_count": ray_count,
        "nadir_brdf": brdf,
        "nadir_brdf_stderr": brdf_err,
        "nadir_order_reflectance": (mean[o, 1:n_time + 1] / width)[None, :],
        "nadir_order_reflectance_stderr": (err[o, 1:n_time + 1] / width)[None, :],
        "nadir_order_brdf": np.array([total_mean[o]]),
        "nadir_order_brdf_stderr": np.array([total_err[o]]),
    }

