"""The database's own error in the likelihood (docs/inversion.md §4.3).

The expected waveform at a point of the parameter space is not known exactly: it is built
from Monte Carlo nodes (each with its standard errors) and interpolated between them. Both
errors are common to every shot of an observation: they do not average down with the number
of shots, and at 1000 shots a database error a few per cent of the signal outweighs the noise
of the mean waveform many times. This module gives that error as a variance S(t) of the
amplitude-1 model μ(t) (mV², or (pe ns⁻¹)² for a photon-counting receiver) on the forward
model's fine grid, and integrates it out of the likelihood.

**Monte Carlo part.** A node's diffuse response has a standard error se_b per log time bin b
(width w_b), its specular and back-and-forth fractions f a binomial variance f (1 − f) / N
(N rays). Carried through the chain of :class:`~warpe_cl.inversion.forward.Forward`
(photons at the aperture, detection efficiency η, the pulse, footprint and receiver kernel K):

    Var μ(t) = s² [K² ⊗ V](t),   V_j = (P² Σ_b se_b² min(w_b, δt) c_b o_jb)   (photons² per fine bin)

with P the photons per unit reflectance, o_jb the overlap of fine bin j (width δt) with log
bin b, and s the mV (or pe ns⁻¹) per photoelectron per bin times η. The pieces of one log
bin on the fine grid are one Monte Carlo estimate, fully correlated: c_b = min(max(w_b/δt, 1),
L) counts the pieces the kernel (effective length L = (Σ K)² / Σ K² fine bins) sees at once.
At a point between nodes, Var = Σ w_i² Var_i over the nodes that make it, with their weights
w_i in the response (:meth:`~.space.Space.node_weights`: the corners' and the curvature
terms'); the nodes' errors are independent.

**Time-bin part.** A node's diffuse response is known per log time bin, and the chain spreads
each bin's amount evenly over the bin. Where a return is sharper than a bin (a slab floor's,
arriving all at the round trip 2 n h / c) its true time is anywhere in the bin: the bins of
20 per decade are 3 ns wide at 27 ns, as wide as GALA's pulse and filter. Each bin's mean
arrival lies δ_b from its centre (:func:`bin_offsets`: Δ/√12 where a neighbour is empty, the
offset s Δ²/12 of an exponential density of log slope s where the density is resolved),
which moves μ by m_b δ_b / Δ_b (w(t − t_b) − w(t − t_b − Δ_b)) (:func:`binning_variance`).
The bins are independent and, like the Monte Carlo part, the nodes too: Σ w_i² Var_i.

**Interpolation part.** Leave one out along each axis: node m predicted from its neighbours
m − 1 and m + 1 (:meth:`~.space.Space.left_out`, the cell of width D = x_{m+1} − x_{m−1}, m at
fraction f₀ of it) gives the error E_m(t) of that wider cell. Linear interpolation errs by
½ c Δ² f (1 − f) (c the curvature) in a cell of width Δ at fraction f, so inside a cell of the
grid it errs by g E_m, g = Δ² f (1 − f) / (D² f₀ (1 − f₀)), zero at the nodes. The space adds
that term back (its curvature correction, :mod:`.space`); what is left is the part of the
curvature that changes from cell to cell, of unknown sign, and its size is taken as that of
the correction itself: E_m² less the own variance of the three nodes (Monte Carlo and time
bins: what the prediction misses by their noise), floored at 0, and the variance used is
Σ_corners w_c g_c² E_c² summed over the axes. An axis
of two values has no node to leave out, no correction and no estimate (the report says so).

**In the likelihood.** A common error e(t) ~ N(0, S(t)) of the model shifts every shot's
sample k by a_s e(t_k − δ_s). Model time is cut in blocks one sampling interval long; the
errors of different blocks are taken as independent. Each block has G_b = Σ a_s r_sk / Var_sk
and W_b = Σ a_s² / Var_sk over the (uncensored) samples that fall in it and S_b their S
weighted by a_s²/Var_sk. What the common amplitude and arrival absorb (errors along the
blocks' μ and μ′) is projected out of W and G (W_eff, G_eff). With λ_i the eigenvalues of
S^½ W_eff S^½ and v_i their vectors, integrating e out of the Gaussian likelihood at the
fitted nuisances adds

    Δ log L = ½ Σ_i (v_iᵀ S^½ G_eff)² / (1 + λ_i) − ½ Σ_i log(1 + λ_i),

and the error it leaves on log L (its stated error) is σ² = Σ λ_i + ½ Σ λ_i² around an
expected offset −½ Σ λ_i (the spread and mean of G_effᵀ e − ½ eᵀ W_eff e over the noise and e).
"""
from __future__ import annotations

import math

import numpy as np

from ..instrument import radiometry
from ..instrument.grid import deposit, rebin_density
from .likelihood import model_table, padded


def kernel_of(forward) -> tuple[np.ndarray, int]:
    """The whole kernel of the forward model at v = 0 (pulse, footprint and receiver filter;
    a photon-counting receiver has none, its jitter coming after the dead time), amounts per
    fine bin, and its origin index."""
    k, k_o = forward.kernel(0.0)
    return np.convolve(k, forward.h), k_o + forward.h_origin


def kernel_length(forward) -> float:
    """The effective length (ns) of the whole kernel, (Σ K)² / Σ K² fine bins: over how long
    the database's error of the model is correlated."""
    kernel, _ = kernel_of(forward)
    return float(kernel.sum() ** 2 / np.sum(kernel ** 2)) * forward.step


def output_scale(forward) -> float:
    """What one photon at the aperture in a fine bin gives at the output: mV (linear mode) or
    pe ns⁻¹ (photon counting), detection efficiency included."""
    step = forward.grid.step
    return forward.eta / step if forward.counting else forward.eta * forward.mv_per_pe


def response_variance(surface, forward) -> np.ndarray:
    """Var μ(t) of the module docstring for one simulated surface response.

    Parameters
    ----------
    surface : SurfaceResponse
        With ``diffuse_stderr`` (sr⁻¹ ns⁻¹) and ``photons`` (rays); without them the diffuse
        part, or the returns' part, is 0.
    forward : Forward

    Returns
    -------
    array
        On ``forward.t``: mV² (linear mode) or (pe ns⁻¹)² (photon counting), amplitude 1.
    """
    p = forward.params
    grid = forward.grid
    kernel, origin = kernel_of(forward)
    var = np.zeros(grid.size)
    if surface.diffuse_stderr is not None:
        width = np.diff(surface.edges)
        length = kernel_length(forward) / forward.step
        pieces = np.minimum(np.maximum(width / grid.step, 1.0), length)
        density = surface.diffuse_stderr ** 2 * np.minimum(width, grid.step) * pieces
        var += radiometry.photons_per_reflectance(p) ** 2 * rebin_density(
            surface.edges, density, grid.edges)
    n = surface.photons
    if surface.returns and math.isfinite(n) and n > 0:
        n_tx = radiometry.transmitted_photons(p) * p["geometry.atmosphere_transmission"] ** 2
        times = [t for _, t, _ in surface.returns]
        amounts = [(n_tx * forward.geo.kappa[c]) ** 2 * f * (1.0 - f) / n
                   for c, _, f in surface.returns]
        var += deposit(grid, times, amounts)
    full = np.convolve(var, kernel ** 2)[origin: origin + var.size]
    return np.clip(full, 0.0, None) * output_scale(forward) ** 2


def bin_offsets(edges: np.ndarray, diffuse: np.ndarray) -> np.ndarray:
    """How far (ns, rms) each log time bin's mean arrival may lie from the bin's centre, which
    is where the chain puts it (uniform over the bin).

    Where the bin and both neighbours hold a return, the density is resolved: an exponential
    density of log slope s = d ln R_d / dt (from the neighbours) puts its mean s Δ² / 12 from
    the centre of a bin of width Δ. Where a neighbour is empty (a return sharper than a bin,
    such as a slab floor's), the arrival is anywhere in the bin: Δ / √12, the rms of a uniform
    offset, which also bounds the resolved estimate.

    Parameters
    ----------
    edges : array (n + 1,)
        Time bin edges, ns.
    diffuse : array (n,)
        R_d per bin (any unit per ns).

    Returns
    -------
    array (n,)
        ns.
    """
    width = np.diff(edges)
    centre = 0.5 * (edges[1:] + edges[:-1])
    density = np.asarray(diffuse, float)
    lo, hi = np.roll(density, 1), np.roll(density, -1)
    lo[0] = hi[-1] = 0.0
    resolved = (lo > 0) & (hi > 0) & (density > 0)
    span = np.roll(centre, -1) - np.roll(centre, 1)
    slope = np.zeros_like(density)
    slope[resolved] = (np.log(hi[resolved]) - np.log(lo[resolved])) / span[resolved]
    cap = width / math.sqrt(12.0)
    return np.where(resolved, np.minimum(np.abs(slope) * width ** 2 / 12.0, cap), cap)


def binning_variance(surface, forward) -> np.ndarray:
    """Var μ(t) from where each log time bin's return lies inside its bin
    (:func:`bin_offsets`), carried through the chain as :func:`response_variance` carries
    the Monte Carlo error.

    Moving the amount m_b of a bin of width Δ_b by δ_b changes the waveform by
    m_b δ_b / Δ_b (w(t − t_b) − w(t − t_b − Δ_b)), w the chain's waveform of a unit spike:
    the derivative of the bin's box. The bins' offsets are independent. A bin narrower than
    two fine steps takes the derivative's limit, m_b δ_b w′(t − c_b).

    Parameters
    ----------
    surface : SurfaceResponse
    forward : Forward

    Returns
    -------
    array
        On ``forward.t``: mV² (linear mode) or (pe ns⁻¹)² (photon counting), amplitude 1.
    """
    grid = forward.grid
    kernel, origin = kernel_of(forward)
    unit = radiometry.photons_per_reflectance(forward.params) * output_scale(forward)
    edges = surface.edges
    width = np.diff(edges)
    shift = surface.diffuse * width * bin_offsets(edges, surface.diffuse)   # sr⁻¹ ns
    inside = (shift > 0) & (edges[1:] > grid.start) & (edges[:-1] < grid.edges[-1])
    narrow = inside & (width < 2.0 * grid.step)
    slope = np.gradient(kernel) / grid.step                    # w′ per unit amount, ns⁻¹
    centre = 0.5 * (edges[1:] + edges[:-1])
    var = np.convolve(deposit(grid, centre[narrow], shift[narrow] ** 2),
                      slope ** 2)[origin: origin + grid.size]
    for b in np.nonzero(inside & ~narrow)[0]:
        step = deposit(grid, [edges[b], edges[b + 1]], [1.0, -1.0])
        used = np.nonzero(step)[0]
        if used.size == 0:                  # a bin over the whole grid: flat across it
            continue
        first, last = used[0], used[-1] + 1
        piece = np.convolve(step[first:last], kernel) * (shift[b] / width[b])
        start = first - origin
        lo, hi = max(start, 0), min(start + piece.size, grid.size)
        if hi > lo:
            var[lo:hi] += piece[lo - start: hi - start] ** 2
    return np.clip(var, 0.0, None) * unit ** 2


class Emulator:
    """S(t) at any point of a database's space (module docstring).

    Parameters
    ----------
    space : Space
    forward : Forward

    Node waveforms, their variances and the leave-one-out errors are computed when first
    needed and kept: an inversion visits a few cells.
    """

    def __init__(self, space, forward):
        self.space, self.forward = space, forward
        self._mu, self._var, self._bins, self._loo = {}, {}, {}, {}
        self.unmeasured = [a.key for a in space.axes if 1 < a.values.size < 3
                           and not (a.key in space.point
                                    and np.isclose(a.values, space.point[a.key]).any())]

    def _node(self, index: tuple) -> tuple[np.ndarray, np.ndarray]:
        """μ (v = 0, amplitude 1) and its Monte Carlo variance at node ``index``."""
        if index not in self._mu:
            surface = self.space.nodes[index].surface
            self._mu[index] = self.forward.waveform(self.forward.photons(surface), 0.0)[0]
            self._var[index] = response_variance(surface, self.forward)
        return self._mu[index], self._var[index]

    def _binning(self, index: tuple) -> np.ndarray:
        """The variance of node ``index``'s μ from its time bins (:func:`binning_variance`)."""
        if index not in self._bins:
            self._bins[index] = binning_variance(self.space.nodes[index].surface, self.forward)
        return self._bins[index]

    def _own(self, index: tuple) -> np.ndarray:
        """Node ``index``'s own variance: Monte Carlo and time bins."""
        return self._node(index)[1] + self._binning(index)

    def _left_out(self, middle: tuple, d: int) -> np.ndarray:
        """E_m² of node ``middle`` (interior along axis ``d``) predicted from its two
        neighbours (:meth:`~.space.Space.left_out`), less the three nodes' own variance
        (Monte Carlo and time bins), floored at 0."""
        key = (middle, d)
        if key not in self._loo:
            guess, _, f0 = self.space.left_out(middle, d)
            predicted = self.forward.waveform(self.forward.photons(guess.surface), 0.0)[0]
            mu = self._node(middle)[0]
            _, lo, hi = self.space.stencil(d, middle)
            noise = self._own(middle) + (1 - f0) ** 2 * self._own(lo) + f0 ** 2 * self._own(hi)
            self._loo[key] = np.maximum((predicted - mu) ** 2 - noise, 0.0)
        return self._loo[key]

    def variance(self, point: dict) -> np.ndarray:
        """S(t) at ``point`` (free keys -> values, axis units): the Monte Carlo, time-bin and
        interpolation parts of the module docstring, on ``forward.t``: mV² (linear mode) or
        (pe ns⁻¹)² (photon counting), at amplitude 1."""
        return sum(self.parts(point).values())

    def parts(self, point: dict) -> dict:
        """The parts of S(t) at ``point`` (units of :meth:`variance`): ``"monte carlo"``,
        ``"time bins"`` and, per axis of three values or more whose cell the point (or a
        fixed value) is inside, the axis' dotted key (its interpolation part)."""
        space = self.space
        bends = space.bends(point)
        weights = space.node_weights(point, bends)
        used = [(i, w) for i, w in weights.items() if w != 0.0]
        out = {"monte carlo": sum(w ** 2 * self._node(i)[1] for i, w in used),
               "time bins": sum(w ** 2 * self._binning(i) for i, w in used)}
        for d, middle, w, g in bends:
            key = space.axes[d].key
            out[key] = out.get(key, 0.0) + w * g ** 2 * self._left_out(middle, d)
        return out


#: A database is adequate for an observation where its own error moves log L by at most this
#: much (σ, log-likelihood units): a 68 % interval is where log L is within 0.5 of its
#: maximum, a 95 % one within 2.
ADEQUATE_SD = 1.0
#: The most rays per node or time bins per decade (factors of today's) or halvings of a cell
#: the advice considers.
MOST_RAYS, MOST_BINS, MOST_HALVINGS = 1024, 64, 4


def adequacy(emulator, shots, fit, point: dict, mu, nu, amplitude_free: bool = True) -> dict:
    """Is the database good enough for this observation? The stated error of log L at the
    best point split by source, and what would bring each under ``ADEQUATE_SD / 2``.

    Parameters
    ----------
    emulator : Emulator
    shots : Shots
    fit : ShotFit
        The nuisances at the best point.
    point : dict
        The best point (free keys -> values, axis units; the fixed keys are the space's).
    mu, nu : array
        The model there (mV, mV²).
    amplitude_free : bool
        Whether the overall amplitude is fitted (:func:`shared_error`).

    Returns
    -------
    dict
        ``sigma`` (all sources), ``sigma_monte_carlo``, ``sigma_time_bins``,
        ``sigma_interpolation`` (every axis' part together), ``sigma_per_axis`` (axis key ->
        its part alone), ``adequate`` (σ ≤ ``ADEQUATE_SD``), ``rays_factor`` (rays per node,
        as a factor of the database's, that bring the Monte Carlo part under half of it; the
        variance falls as 1/rays), ``bins_factor`` (time bins per decade, as a factor of the
        database's, that bring the time-bin part under half of it; the variance falls as the
        bin width squared) and ``halvings`` (per axis, halvings of the cell spacing that bring
        its part under half of it; an interpolation error falls 4 times per halving, its
        variance 16 times), and ``advice``, one line.
    """
    parts = emulator.parts(point)
    values = {**emulator.space.point, **point}      # fixed keys too: their cells count

    def sd(var):
        return shared_error(shots, fit, mu, nu, var, amplitude_free)[1]
    total = sd(sum(parts.values()))
    mc, bins = sd(parts["monte carlo"]), sd(parts["time bins"])
    axes = {k: v for k, v in parts.items() if k not in ("monte carlo", "time bins")}
    interp = sd(sum(axes.values())) if axes else 0.0
    target = 0.5 * ADEQUATE_SD
    advice = []

    def doublings(var, fall: float, most: int, say) -> int:
        """The fewest doublings (at most ``most``) that bring the part ``var`` under the
        target, its variance falling ``fall`` times per doubling; ``say(n)`` is added to the
        advice when n > 0, after "more than" if even ``most`` fall short."""
        n = 0
        while sd(var / fall ** n) > target and n < most:
            n += 1
        if n:
            advice.append(("more than " if sd(var / fall ** n) > target else "") + say(n))
        return n

    rays = 2 ** doublings(parts["monte carlo"], 2.0, int(math.log2(MOST_RAYS)),
                          lambda n: f"{2 ** n}x the rays per node")
    finer = 2 ** doublings(parts["time bins"], 4.0, int(math.log2(MOST_BINS)),
                           lambda n: f"{2 ** n}x the time bins per decade "
                                     "(simulation.time_bins.per_decade)")
    per_axis, halvings = {}, {}
    for key, var in axes.items():
        per_axis[key] = sd(var)
        halvings[key] = doublings(var, 16.0, MOST_HALVINGS,
                                  lambda n: f"{n}x halved spacing of {key} "
                                            f"around {values[key]:.4g}")
    adequate = total <= ADEQUATE_SD
    line = (f"database adequate for these shots: its own error moves log L by {total:.2f} "
            f"(<= {ADEQUATE_SD:g})" if adequate else
            f"database not adequate for these shots: its own error moves log L by {total:.2f} "
            f"(> {ADEQUATE_SD:g}; Monte Carlo {mc:.2f}, time bins {bins:.2f}, interpolation "
            + ", ".join(f"{k.rsplit('.', 1)[-1]} {v:.2f}" for k, v in per_axis.items())
            + "); for these shots: " + ("; ".join(advice) or "no single change suffices"))
    return {"sigma": total, "sigma_monte_carlo": mc, "sigma_time_bins": bins,
            "sigma_interpolation": interp, "sigma_per_axis": per_axis, "adequate": adequate,
            "rays_factor": rays, "bins_factor": finer,
            "halvings": halvings, "advice": line}


class DirectSurface:
    """One directly simulated surface in place of a database: the surface wherever it is
    asked, and its own Monte Carlo and time-bin variance as S(t) (no interpolation). What log L of a
    direct simulation is computed with (tools/studies/emulator_check.py).

    Parameters
    ----------
    surface : SurfaceResponse
    forward : Forward
    free_axes : list of Axis
        The axes of the database the point is given in (for :class:`~.posterior.Problem`).
    """

    def __init__(self, surface, forward, free_axes=()):
        self._surface = surface
        self._variance = response_variance(surface, forward) + binning_variance(surface, forward)
        self.free_axes = list(free_axes)
        self.unmeasured = []

    def surface(self, point: dict):
        return self._surface

    def variance(self, point: dict) -> np.ndarray:
        return self._variance


def shared_error(shots, fit, mu: np.ndarray, nu, variance: np.ndarray,
                 amplitude_free: bool = True):
    """Δ log L, the stated error σ and the expected offset of log L of the module docstring.

    Parameters
    ----------
    shots : Shots or CountShots
        The recorded shots: linear-mode samples, or photon-counting histograms.
    fit : ShotFit
        The fitted nuisances at this model: per-shot amplitudes a_s and arrivals δ_s (ns), or
        the common A and δ of photon counts; its ``table`` (μ, μ′, ν), when set and made
        from these ``mu`` and ``nu``, is read instead of being made again.
    mu, nu : array
        The model's μ (mV) and ν (mV²) on the forward grid, or the count rate (pe ns⁻¹ per
        shot at amplitude 1) and None.
    variance : array
        S(t) on the forward grid (mV², or (pe ns⁻¹)², amplitude 1).
    amplitude_free : bool
        Whether the overall amplitude is fitted (not ``--fix amplitude``): photon counts have
        no per-shot amplitude, so with A fixed nothing absorbs an error along the model.

    Returns
    -------
    (float, float, float)
        Δ log L, σ and the offset −½ Σ λ_i (log-likelihood units).
    """
    if shots.f.counting:            # blocks as long as the kernel (its error's correlation)
        block = max(kernel_length(shots.f), shots.recording.correlation_ns)    # and the dead time
        w, g, s, base = shots.error_blocks(fit, mu, variance, block)
        return integrate_blocks(w, g, s, base if amplitude_free else base[:, 1:])
    f = shots.f
    a, d = fit.amplitude, fit.arrival
    table = fit.table
    if table is None or not (np.array_equal(table[0, 1:-2], mu)
                             and np.array_equal(table[2, 1:-2], nu)):
        table = model_table(mu, nu, f.t)
    m, dm, n = shots._gather(table, d)
    s = shots._gather(padded([variance]), d)[0]
    var = f.sigma_n ** 2 + a[:, None] * n
    keep = ~shots.censored
    r = shots.y - a[:, None] * m
    weight = np.where(keep, a[:, None] ** 2 / var, 0.0)
    block = np.floor((shots.t[None, :] - d[:, None] - f.t[0]) / f.interval).astype(np.intp)
    block = block.ravel() - block.min()
    size = int(block.max()) + 1

    def per_block(x):
        return np.bincount(block, x.ravel(), size)
    w_b = per_block(weight)
    used = w_b > 0
    w_b = w_b[used]
    g_b = per_block(np.where(keep, a[:, None] * r / var, 0.0))[used]
    s_b, m_b, dm_b = (per_block(weight * x)[used] / w_b for x in (s, m, dm))
    return integrate_blocks(w_b, g_b, s_b, np.stack([m_b, dm_b], axis=1))


def integrate_blocks(w_b, g_b, s_b, base) -> tuple:
    """The common error e_b ~ N(0, S_b) of independent blocks integrated out of a log
    likelihood that is quadratic in it, ``G·e − ½ eᵀ W e`` with W = diag(w_b), after
    projecting out what the fitted nuisances absorb (errors along the columns of ``base``:
    the model and its time derivative per block). With M = S^½ W_eff S^½ (eigenvalues λ_i),
    W_eff = W − W B (Bᵀ W B)⁻¹ Bᵀ W, h = S^½ G_eff:

        Δ log L = ½ hᵀ (I + M)⁻¹ h − ½ log det(I + M),   σ² = tr M + ½ tr M²,

    and the offset −½ tr M (module docstring). M is a diagonal less a rank-2 term, so the
    Woodbury identity and the determinant lemma give all of it in O(blocks): a 0.1 ns
    photon-counting histogram has thousands of blocks.

    Parameters
    ----------
    w_b, g_b, s_b : arrays (K,)
        W's diagonal, G and S per block.
    base : array (K, 2)
        The directions the nuisances absorb.

    Returns
    -------
    (float, float, float)
        Δ log L, σ and the offset.
    """
    w_b, g_b, s_b = (np.asarray(x, float) for x in (w_b, g_b, s_b))
    # the absorbed directions made W-orthonormal (qᵀ W q = I), dropping any the blocks
    # cannot tell apart: the projection is then W q qᵀ W
    e, v = np.linalg.eigh(base.T @ (w_b[:, None] * base))
    kept = e > 1e-12 * max(float(e.max()), 1e-300)
    q = base @ (v[:, kept] / np.sqrt(e[kept]))
    wq = w_b[:, None] * q
    g_eff = g_b - wq @ (q.T @ g_b)
    root = np.sqrt(np.clip(s_b, 0.0, None))
    a = root * root * w_b                       # S W: M = diag(a) − p pᵀ
    p = root[:, None] * wq
    h = root * g_eff
    x = 1.0 + a
    p_x = p / x[:, None]
    inner = np.eye(p.shape[1]) - p.T @ p_x     # I − pᵀ X⁻¹ p (Woodbury, determinant lemma)
    ph = p_x.T @ h
    quad = float(np.sum(h * h / x) + ph @ np.linalg.solve(inner, ph))
    logdet = float(np.sum(np.log1p(a)) + math.log(max(np.linalg.det(inner), 1e-300)))
    ptp = p.T @ p
    trace = float(np.sum(a) - np.trace(ptp))
    trace2 = float(np.sum(a * a) - 2.0 * np.trace(p.T @ (a[:, None] * p)) + np.sum(ptp * ptp))
    trace, trace2 = max(trace, 0.0), max(trace2, 0.0)
    return 0.5 * quad - 0.5 * logdet, math.sqrt(trace + 0.5 * trace2), -0.5 * trace
