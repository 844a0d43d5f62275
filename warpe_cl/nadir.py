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
q T exp(-tau) / (m_l^2 mu_l): the ``factor`` column is T / (m_l^2 mu_l). The paths that the
Fresnel faces reflect on the way (a slab over a vacuum gap, the contacts of a stack) score
too (:func:`mirror_table`).
"""
from __future__ import annotations

import math

import numpy as np

from .params import (COMPONENTS, MIRROR_COLUMNS, MIRROR_KINDS, NADIR_ROWS, VIEW_COLUMNS,
                     WalkParams, fixed_to_float)
from .radiative import fresnel_external, fresnel_internal
from .stack import gap_face

__all__ = ["view_table", "mirror_table", "up_transmission", "reduce_nadir", "mirror_below",
           "nadir_min_score", "nadir_new_cell_score"]

#: The mirror table leaves out the virtual paths whose factor (the product of their
#: reflections, transmissions and e^-tau of their whole crossings) is below this fraction of the
#: straight path's from the same layer (docs/walk.md §8.5).
MIRROR_CUT = 1e-9
#: At most this many mirror rows (after merging the paths of equal delay): a stack whose faces
#: reflect so strongly that more paths stay above MIRROR_CUT gets no nadir estimate.
MAX_MIRROR_ROWS = 512
#: The enumeration of the mirror paths gives up after this many partial paths.
_MAX_PARTIAL_PATHS = 200_000


class _TooManyMirrorPaths(ValueError):
    """The mirror paths above MIRROR_CUT exceed MAX_MIRROR_ROWS (or _MAX_PARTIAL_PATHS)."""


def mirror_below(params: WalkParams) -> str | None:
    """Why the estimator would be incomplete for ``params``, or None where it is exact.

    The estimator follows each virtual path up along the view direction and every path that
    the Fresnel faces of the slab or stack reflect on the way (:func:`mirror_table`,
    docs/walk.md §8.5), down to a fraction :data:`MIRROR_CUT` of the straight path. Only a
    stack whose faces reflect so strongly that more than :data:`MAX_MIRROR_ROWS` paths stay
    above it is refused.
    """
    try:
        mirror_table(params)
    except _TooManyMirrorPaths as err:
        return str(err)
    return None


class _Geometry:
    """The view direction through a stack (docs/walk.md §8.5): per layer l its cosine mu_l,
    a_l = exp(-E_l h_l / mu_l) the transmission of one crossing and P_l = h_l (n_l / n_0) /
    mu_l its path at layer 0's speed; per interface j = 0..N the Fresnel reflectances at the
    view's angle, ``up[j]`` from below (layer j, the gap medium for j = N) and ``down[j]``
    from above (layer j - 1), 0 at a transparent interface; ``gap_mu`` the cosine in the gap
    medium (None where no real direction there leaves along the view)."""

    def __init__(self, params: WalkParams):
        faces, gap = _faces(params)
        sin_v = math.sin(math.radians(float(params.view_zenith)))
        n0 = float(params.stack[0].n)
        self.n_layers = len(faces)
        self.mu, self.a, self.P = [], [], []
        for layer, face in zip(params.stack, faces):
            mu = math.sqrt(max(0.0, 1.0 - (sin_v / face[0]) ** 2))
            self.mu.append(mu)
            self.a.append(math.exp(-float(layer.extinction) * float(layer.thickness) / mu))
            self.P.append(float(layer.thickness) * (float(layer.n) / n0) / mu)
        self.gap_mu = (math.sqrt(max(0.0, 1.0 - (sin_v / gap[0]) ** 2)) if gap[0] > sin_v
                       else None)
        sides = [(1.0, 0.0)] + list(faces) + [gap]       # the face above interface j: sides[j]
        self.transparent = [sides[j] == sides[j + 1] for j in range(self.n_layers + 1)]
        self.up, self.down = [], []
        for j in range(self.n_layers + 1):
            above, below = sides[j], sides[j + 1]
            mu_below = self.mu[j] if j < self.n_layers else (self.gap_mu or 0.0)
            self.up.append(1.0 - up_transmission(mu_below, below[0], above[0], above[1]))
            self.down.append(0.0 if j == 0 else
                             1.0 - up_transmission(self.mu[j - 1], above[0], below[0], below[1]))

    def paths(self, state: tuple, limit: float) -> dict:
        """Every specular path from ``state`` to the vacuum above the stack whose factor stays
        at or above ``limit``: {crossings per layer: summed factor}. ``state`` is ("up", j), at
        interface j from below, or ("down", j), at interface j from above. A path that meets
        the floor (through the gap, or in contact) ends there: it is not specular.

        Each step crosses one layer, so the partial paths are followed one crossing at a
        time, those at the same interface, going the same way, with the same crossings per
        layer (the same delay) merged: their number grows with the crossings, not with the
        orderings of the reflections."""
        n = self.n_layers
        out: dict = {}
        front = {(state, (0,) * n): 1.0}
        seen = 0
        while front:
            seen += len(front)
            if seen > _MAX_PARTIAL_PATHS:
                raise _TooManyMirrorPaths(
                    f"its faces reflect more than {_MAX_PARTIAL_PATHS} partial virtual paths "
                    f"above {MIRROR_CUT:g} of the straight one")
            after: dict = {}

            def step(to, f, crossings, layer):
                if f >= limit:
                    key = (to, _plus(crossings, layer))
                    after[key] = after.get(key, 0.0) + f * self.a[layer]

            for ((way, j), crossings), f in front.items():
                if way == "up":
                    t = 1.0 - self.up[j]
                    if j == 0:
                        out[crossings] = out.get(crossings, 0.0) + f * t
                    elif t > 0.0:
                        step(("up", j - 1), f * t, crossings, j - 1)
                    if self.up[j] > 0.0 and j < n:       # back down through layer j
                        step(("down", j + 1), f * self.up[j], crossings, j)
                else:
                    if self.down[j] > 0.0:               # back up through layer j - 1
                        step(("up", j - 1), f * self.down[j], crossings, j - 1)
                    if j < n and self.down[j] < 1.0:     # on down through layer j
                        step(("down", j + 1), f * (1.0 - self.down[j]), crossings, j)
            front = {key: f for key, f in after.items() if f >= limit}
        return {c: f for c, f in out.items() if f >= limit}

    def path(self, crossings) -> float:
        """The path (m, at layer 0's speed) of the given crossings per layer."""
        return sum(c * p for c, p in zip(crossings, self.P))


def _plus(crossings: tuple, i: int) -> tuple:
    return crossings[:i] + (crossings[i] + 1,) + crossings[i + 1:]


def mirror_table(params: WalkParams) -> np.ndarray:
    """The mirror paths of a slab over a vacuum gap or of a stack (docs/walk.md §8.5), shape
    (K, 4): one row per virtual path besides the straight ones, columns
    :data:`~warpe_cl.params.MIRROR_COLUMNS` (kind, layer, factor, extra path in m at layer 0's
    speed). The view direction's ray crosses each layer l at the fixed cosine mu_l, and every
    Fresnel interface on its way either transmits it (1 - R) or reflects it (R); the straight
    paths (every interface crossed once, upwards) are the view table's. For a scattering in
    layer l (``layer`` = l):

    - ``up``: the paths that start up from it, other than the straight one: factor relative to
      the straight path's (so the kernel multiplies the straight score), extra path beyond it;
    - ``down``: the paths that start down along the view's mirror image, reflected by a face
      below: factor relative to the transmissions of the straight path, T_l of the view table
      (the kernel multiplies it by the phase function toward the mirror image and by
      e^{-tau} of the crossing down to the bottom of layer l), whole path after that crossing;

    a reflection by a floor in contact with the last layer scores the ``up`` rows of that
    layer too; one by the floor below the gap (``layer`` = N), the ``gap`` rows: relative to
    the gap row's straight path. In a single slab over a vacuum gap, with a = exp(-E h / mu),
    R_t and R_b the faces' reflectances and rho = R_t R_b a^2, these are ``up`` rho^k (k >= 1),
    ``down`` R_b a rho^k (k >= 0) and ``gap`` rho^k (k >= 1), 2 k h / mu later.

    Paths of equal crossings (the same delay) are merged into one row; paths whose factor is
    below :data:`MIRROR_CUT` of the straight one are left out. Rows are sorted by kind, layer
    and path. Empty where no Fresnel face lies below a scattering layer (a single layer on a
    floor in contact, a granular layer).

    Raises
    ------
    _TooManyMirrorPaths
        More than :data:`MAX_MIRROR_ROWS` rows (:func:`mirror_below` turns it into a reason).
    """
    empty = np.zeros((0, len(MIRROR_COLUMNS)))
    if not params.layered and (params.texture != "slab" or params.bottom_interface != "fresnel"):
        return empty
    geo = _Geometry(params)
    n = geo.n_layers
    if all(geo.transparent[1:]):
        return empty                       # no face below the top: nothing reflects back up
    kind = {k: float(i) for i, k in enumerate(MIRROR_KINDS)}
    rows = []
    for l in range(n + 1):
        if l == n:                         # the floor below the gap: the gap rows
            if geo.transparent[n] or geo.gap_mu is None:
                continue
            starts = (("gap", ("up", n)),)
        else:
            starts = (("up", ("up", l)), ("down", ("down", l + 1)))
        straight = (1,) * l + (0,) * (n - l)
        transmission = math.prod(1.0 - geo.up[j] for j in range(l + 1))
        reference = transmission * math.prod(geo.a[:l])
        if not reference > 0.0:
            continue                       # nothing comes up from there
        for name, state in starts:
            found = geo.paths(state, MIRROR_CUT * reference)
            if name != "down":
                found.pop(straight, None)  # the view table's own path
            for crossings, factor in found.items():
                if name == "down":
                    rows.append([kind[name], l, factor / transmission, geo.path(crossings)])
                else:
                    rows.append([kind[name], l, factor / reference,
                                 geo.path(crossings) - geo.path(straight)])
    if len(rows) > MAX_MIRROR_ROWS:
        raise _TooManyMirrorPaths(
            f"its faces reflect {len(rows)} virtual paths above {MIRROR_CUT:g} of the straight "
            f"one, more than the {MAX_MIRROR_ROWS} the estimator follows")
    rows.sort(key=lambda r: (r[0], r[1], r[3]))
    return np.asarray(rows, dtype=np.float64).reshape(-1, len(MIRROR_COLUMNS))


def _faces(params: WalkParams) -> tuple:
    """The face index (n, k) of each layer (top first), and of the gap medium below."""
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


def nadir_min_score(params: WalkParams) -> float:
    """s_min of the analog walk's roulette of small nadir scores (docs/walk.md §8.3), sr^-1.

    ``params.nadir_roulette`` times the score of a scattering at the top of the first layer
    straight back up, p(pi) T_0 / (m_0^2 mu_0), p the HG phase function of its g.

    Parameters
    ----------
    params : WalkParams

    Returns
    -------
    float
        The threshold; 0 (no roulette) in the weighted mode or where ``nadir_roulette`` is 0.
    """
    if params.weighted or not params.nadir_roulette > 0:
        return 0.0
    g = float(params.stack[0].g)
    back = (1.0 - g * g) / (4.0 * np.pi * (1.0 + g) ** 3)      # p(pi)
    return float(params.nadir_roulette) * float(view_table(params)[0, -1]) * back


def nadir_new_cell_score(params: WalkParams) -> float:
    """s_new of the roulette for a nadir score that would open a new pending cell
    (docs/walk.md §8.3), sr^-1.

    s_min (:func:`nadir_min_score`) times the ratio of the HG phase function's mean
    1/(4 pi) to its backscatter p(pi), (1 + g)^2 / (1 - g), kept between s_min and
    s_min / nadir_roulette (the score of a scattering at the top straight back up).

    Parameters
    ----------
    params : WalkParams

    Returns
    -------
    float
        The threshold; 0 where s_min is 0.
    """
    s_min = nadir_min_score(params)
    if not s_min > 0:
        return 0.0
    g = float(params.stack[0].g)
    r = float(params.nadir_roulette)
    return s_min * min(max((1.0 + g) ** 2 / (1.0 - g), 1.0), 1.0 / r)


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

