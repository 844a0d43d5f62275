"""The expected information of a receiver's shots about a surface: the Fisher information of
the calibrated likelihood of docs/inversion.md §4 at its noiseless expected samples, with the
nuisances marginalised (docs/design.md §2).

**Linear mode** (BELA, GALA). Shot s, sample k at model time τ_k = t_k + φ_s (φ_s the
sampling phase) records x_sk ~ N(a_s μ(τ_k − δ_s), σ_n² + a_s ν(τ_k − δ_s)) (μ, ν of
:class:`warpe_cl.inversion.forward.Forward`). For a Gaussian of parameter-dependent mean m and
variance V the information of one sample is

    I_ij = ∂_i m ∂_j m / V + ½ ∂_i V ∂_j V / V²,

at a_s = 1, δ_s = 0. Per shot, its own amplitude a_s (speckle prior N(A, A²/M)) and arrival δ_s
are marginalised by the Schur complement of their 2 × 2 block; the shots' information is the
average over ``phases`` sampling phases spread evenly over one sampling interval, times the
number of shots. The global nuisances (the overall amplitude A, the pulse broadening v) and the
database's own error are then marginalised by the Schur complement of theirs.

**The database's own error** (docs/inversion.md §4.3) is taken as the inversion takes it: a
common error e_b of variance S_b per block of model time one sampling interval long, the
blocks independent, every sample of every shot in block b moved by a_s e_b. Each e_b is a
global nuisance with the prior precision 1/S_b: it does not average down with the shots, and
it caps what many shots can learn.

**Photon counting** (ATLAS). The counts of histogram bin k summed over N shots are Poisson of
mean N m_k, m_k the recorded counts after the dead time and the jitter (docs/inversion.md §4.2,
:mod:`warpe_cl.inversion.recording`); the information is N Σ_k ∂_i m_k ∂_j m_k / m_k, with A,
δ (common to the shots) and v marginalised; the database's own error, common to the shots, is
eliminated per block of model time as long as the kernel (and at least the dead time), as the
inversion does (:func:`counting_information`). As in the inversion, the speckle's extra variance is left out.

Samples whose expected value reaches the receiver's clipped level carry no information here
(a censored sample carries little; this is conservative).
"""
from __future__ import annotations

import math

import numpy as np

from ..instrument import adc
from ..inversion.emulator import kernel_length
from ..inversion.recording import Recording

#: Speckle modes above this count as this many (a_s = A up to 1e-3): keeps the Schur
#: complement of the amplitude well conditioned without speckle (M = inf).
MODES_CAP = 1e6
#: The database's own error is not modelled in more blocks than this; adjacent blocks are
#: merged (each error then common to both: a stronger correlation than the inversion assumes).
MOST_BLOCKS = 4000
#: Eigenvalues of the information below this fraction of the largest are directions the data
#: do not constrain (infinite variance).
NULL_FRACTION = 1e-12
#: The nuisances marginalised by default: per-shot amplitude (and the overall amplitude),
#: per-shot (or common) arrival, pulse broadening v.
NUISANCES = ("amplitude", "arrival", "pulse")


def _at(grid: np.ndarray, rows: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Rows of values on the uniform fine ``grid`` (R × N) linearly interpolated at model
    times ``tau`` (K,): shape (R, K), 0 beyond the grid."""
    step = grid[1] - grid[0]
    x = (tau - grid[0]) / step
    inside = (x >= 0) & (x <= grid.size - 1)
    i = np.clip(x.astype(np.intp), 0, grid.size - 2)
    f = np.clip(x - i, 0.0, 1.0)
    out = rows[:, i] * (1.0 - f) + rows[:, i + 1] * f
    return np.where(inside, out, 0.0)


def linear_information(forward, mu, nu, d_mu, d_nu, shots: int, *, pulse=None,
                       variance=None, phases: int = 8, nuisances=NUISANCES) -> np.ndarray:
    """The information matrix of ``shots`` linear-mode shots about the directions ``d_mu``,
    with the nuisances marginalised (module docstring).

    Parameters
    ----------
    forward : Forward
        A linear-mode instrument (noise σ_n, baseline and clipped level in mV; sampling).
    mu, nu : array (N,)
        μ (mV) and ν (mV²) at the point, amplitude 1, on ``forward.t``.
    d_mu, d_nu : array (d, N)
        Their derivatives along the d parameters of interest (mV and mV² per unit of the
        parameter: per unit of an interpolation coordinate, or across a whole step for a
        distance between two models).
    shots : int
        Shots of the observation.
    pulse : (array, array), optional
        ∂μ/∂v (mV ns⁻²) and ∂ν/∂v (mV² ns⁻²), the pulse broadening nuisance; required when
        ``"pulse"`` is in ``nuisances``.
    variance : array (N,), optional
        S(t), the database's own error (mV², amplitude 1; :meth:`Emulator.variance
        <warpe_cl.inversion.emulator.Emulator.variance>`); None: the database is exact.
    phases : int
        Sampling phases averaged over one sampling interval.
    nuisances : iterable of str
        Which of ``amplitude``, ``arrival``, ``pulse`` are marginalised (the others are
        known: a_s = A = 1, δ_s = 0, v = 0).

    Returns
    -------
    array (d, d)
        Information about the parameters (inverse squared units of the parameters).
    """
    nuisances = set(nuisances)
    t = forward.t
    d = d_mu.shape[0]
    rows_mu = [mu, np.gradient(mu, t), *d_mu]
    rows_nu = [nu, np.gradient(nu, t), *d_nu]
    use_pulse = "pulse" in nuisances
    if use_pulse:
        rows_mu.append(pulse[0])
        rows_nu.append(pulse[1])
    table_mu, table_nu = np.array(rows_mu), np.array(rows_nu)
    interval = forward.interval
    ts = adc.sample_times(forward.params["window.start"], forward.params["window.stop"],
                          interval)
    sig2 = forward.sigma_n ** 2
    room = forward.ceiling - forward.baseline
    blocks, s_b = _blocks(forward, mu, nu, variance)
    n_blocks = s_b.size
    # the global parameters: the d directions, v, A, then the blocks' errors
    p = d + int(use_pulse) + int("amplitude" in nuisances)
    amp = d + int(use_pulse)              # index of A when the amplitude is free
    local = [j for j, name in ((0, "amplitude"), (1, "arrival")) if name in nuisances]
    modes = min(forward.modes, MODES_CAP)
    t_pp = np.zeros((p, p))                  # globals × globals
    t_pb = np.zeros((p, n_blocks))           # globals × blocks
    t_bb = np.zeros(n_blocks)                # blocks (diagonal)
    x_p, x_b, x_ll = [], [], []              # per phase: the shot's locals against them
    for j in range(phases):
        tau = ts + (j + 0.5) * interval / phases
        m = _at(t, table_mu, tau)
        v = _at(t, table_nu, tau)
        keep = m[0] < room                       # expected below the clipped level
        w = np.where(keep, 1.0 / (sig2 + np.clip(v[0], 0.0, None)), 0.0)
        # rows: p globals (directions, v, A = no effect on the samples), then a_s, δ_s
        jm = np.zeros((p + 2, tau.size))
        jv = np.zeros((p + 2, tau.size))
        jm[:d], jv[:d] = m[2:2 + d], v[2:2 + d]
        if use_pulse:
            jm[d], jv[d] = m[2 + d], v[2 + d]
        jm[p], jv[p] = m[0], v[0]                # ∂/∂a_s
        jm[p + 1], jv[p + 1] = -m[1], -v[1]      # ∂/∂δ_s
        info = (jm * w) @ jm.T + 0.5 * (jv * w * w) @ jv.T
        if "amplitude" in nuisances:            # speckle prior a_s ~ N(A, A²/M) at A = 1
            info[p, p] += modes
            info[p, amp] -= modes
            info[amp, p] -= modes
            info[amp, amp] += modes
        b = blocks(tau)
        inside = (b >= 0) & keep
        cross = np.zeros((p + 2, n_blocks))      # Σ_{k in b} w_k J_k: rows × blocks
        for r in range(p + 2):
            cross[r] = np.bincount(b[inside], (w * jm[r])[inside], n_blocks)
        weight = np.bincount(b[inside], w[inside], n_blocks)
        t_pp += info[:p, :p]
        t_pb += cross[:p]
        t_bb += weight
        loc = [p + i for i in local]
        x_p.append(info[:p][:, loc])
        x_b.append(cross[loc].T)
        x_ll.append(info[np.ix_(loc, loc)])
    # The Schur complement of each shot's locals, I_gg − x I_ll⁻¹ xᵀ summed over the shots,
    # is the Schur complement of an augmented matrix holding one copy of the locals per
    # phase (scaled by √(shots / phases)); Schur complements compose, so the blocks
    # (diagonal) are eliminated first, then the small dense rest: O(blocks), not O(blocks³).
    scale = shots / phases
    c = math.sqrt(scale)
    r = len(local) * phases
    small = np.zeros((p + r, p + r))
    small[:p, :p] = scale * t_pp
    if r:
        small[:p, p:] = c * np.concatenate(x_p, axis=1)
        small[p:, :p] = small[:p, p:].T
        small[p:, p:] = _block_diagonal(x_ll)
    if n_blocks:
        diag = scale * t_bb + 1.0 / s_b
        side = np.concatenate([scale * t_pb] + ([c * np.concatenate(x_b, axis=1).T]
                                                if r else []), axis=0)
        small -= (side / diag) @ side.T
    return schur(small, np.arange(d), np.arange(d, p + r))


def _block_diagonal(blocks: list) -> np.ndarray:
    """The block-diagonal matrix of square ``blocks``."""
    n = sum(b.shape[0] for b in blocks)
    out = np.zeros((n, n))
    i = 0
    for b in blocks:
        k = b.shape[0]
        out[i:i + k, i:i + k] = b
        i += k
    return out


def _blocks(forward, mu, nu, variance):
    """The blocks of model time (one sampling interval, docs/inversion.md §4.3) where the
    database's error is not negligible, as (function τ -> block index or -1, S_b (mV²)):
    S_b is S(t) averaged over the block weighted by 1/Var(t)."""
    t = forward.t
    if variance is None or not np.any(variance > 0):
        return (lambda tau: np.full(tau.size, -1, np.intp)), np.zeros(0)
    interval = forward.interval
    index = np.floor((t - t[0]) / interval).astype(np.intp)
    inv = 1.0 / (forward.sigma_n ** 2 + np.clip(nu, 0.0, None))
    n = int(index.max()) + 1
    s = np.bincount(index, variance * inv, n) / np.bincount(index, inv, n)
    used = np.flatnonzero(s > 1e-12 * s.max())
    merge = max(1, math.ceil(used.size / MOST_BLOCKS))
    if merge > 1:                       # merge neighbours: one error per `merge` blocks
        index = index // merge
        n = int(index.max()) + 1
        s = np.bincount(index, variance * inv, n) / np.bincount(index, inv, n)
        used = np.flatnonzero(s > 1e-12 * s.max())
    lookup = np.full(n, -1, np.intp)
    lookup[used] = np.arange(used.size)
    width = interval * merge

    def blocks(tau):
        k = np.floor((tau - t[0]) / width).astype(np.intp)
        ok = (k >= 0) & (k < n)
        return np.where(ok, lookup[np.clip(k, 0, n - 1)], -1)
    return blocks, s[used]


def counting_information(forward, rate, d_rate, shots: int, *, pulse=None, phases: int = 8,
                         nuisances=NUISANCES, variance=None) -> np.ndarray:
    """The information matrix of ``shots`` photon-counting shots (their summed histogram)
    about the directions ``d_rate``, with A, δ and v marginalised (module docstring).

    The database's own error, when ``variance`` is given, is taken as the inversion takes it
    (:meth:`warpe_cl.inversion.counting.CountShots.error_blocks`): a common error e_b of the
    rate in each block of model time as long as the kernel's effective length (and at least
    the dead time, :attr:`warpe_cl.inversion.recording.Recording.correlation_ns`), with the
    prior N(0, S_b) (S_b the mean of S over the block's bins, weighted as the bins weigh
    it); it moves bin k's expected counts per shot by Δ G_k e_b (G the recorded rate's gain,
    :meth:`warpe_cl.inversion.recording.Recording.gain`; S is taken as G² S, in units of the
    recorded rate) and is eliminated block by block
    (Schur): I −= c_b c_bᵀ / (Σ_k N Δ²/m_k + 1/S_b), c_b = Σ_k N Δ ∂m_k/m_k. It does not
    average down with the shots. (Blocks of one bin would give each bin the weight
    N/(m_k + N Δ² S_k) instead.)

    Parameters
    ----------
    forward : Forward
        A photon-counting instrument (histogram bins of ``forward.interval`` ns, background
        ``forward.dc_rate`` per ns).
    rate : array (N,)
        Signal photoelectrons per ns at amplitude 1 on ``forward.t``, before the dead time and
        the jitter (:meth:`warpe_cl.inversion.forward.Forward.waveform`).
    d_rate : array (d, N)
        Its derivatives along the d parameters of interest.
    shots : int
    pulse : array (N,), optional
        ∂rate/∂v (pe ns⁻¹ ns⁻²); required when ``"pulse"`` is in ``nuisances``.
    phases : int
        Offsets of the arrival against the bin edges averaged over one bin.
    nuisances : iterable of str
        Which of ``amplitude`` (A), ``arrival`` (δ), ``pulse`` (v) are marginalised.
    variance : array (N,), optional
        The database's error S(t) ((pe ns⁻¹)², :mod:`warpe_cl.inversion.emulator`); None:
        the database is exact.

    Returns
    -------
    array (d, d)
    """
    nuisances = set(nuisances)
    t = forward.t
    step = t[1] - t[0]
    d = d_rate.shape[0]
    rec = Recording(forward)
    along = rec.derivative(rate, 1.0)       # the dead time's window of the rate, once
    error = np.zeros_like(rate) if variance is None else \
        np.asarray(variance, float) * rec.gain(rate, 1.0, along) ** 2
    rows = [error, rec.level(rate, 1.0), *(along(w) for w in d_rate)]
    if "pulse" in nuisances:
        rows.append(along(pulse))
    if "amplitude" in nuisances:
        rows.append(along(rate))            # ∂m/∂A
    recorded = rows[1]
    table = np.cumsum(np.array(rows), axis=1) * step
    table = np.concatenate([np.zeros((table.shape[0], 1)), table], axis=1)
    edges = np.concatenate([t - 0.5 * step, [t[-1] + 0.5 * step]])
    width = forward.interval
    ts = adc.sample_times(forward.params["window.start"], forward.params["window.stop"], width)
    background = rec.background * width
    total = np.zeros((len(rows) - 2 + int("arrival" in nuisances),) * 2)
    length = max(kernel_length(forward), width, rec.correlation_ns)
    for j in range(phases):
        lo = ts + (j + 0.5) * width / phases
        hi = lo + width
        lam = np.array([np.interp(hi, edges, c) - np.interp(lo, edges, c) for c in table])
        s_k = lam[0] / width                    # mean S over the bin ((pe ns⁻¹)²)
        m = lam[1] + background
        jac = list(lam[2:])
        if "arrival" in nuisances:              # ∂λ_k/∂δ = −(r(hi) − r(lo))
            jac.append(-(np.interp(hi, t, recorded) - np.interp(lo, t, recorded)))
        jac = np.array(jac)
        ok = m > 1e-300
        m, jac, s_k, lo = m[ok], jac[:, ok], s_k[ok], lo[ok]
        total += (jac * (shots / m)) @ jac.T
        if variance is None or m.size == 0:
            continue
        block = np.floor((lo - lo[0]) / length).astype(np.intp)
        w_e = shots * width ** 2 / m            # information of each bin about e_b
        w_b = np.bincount(block, w_e)
        s_b = np.bincount(block, w_e * s_k) / np.maximum(w_b, 1e-300)
        c_b = np.array([np.bincount(block, shots * width * row / m) for row in jac])
        keep = s_b > 0
        c_b = c_b[:, keep]
        total -= (c_b / (w_b[keep] + 1.0 / s_b[keep])) @ c_b.T
    total /= phases
    return schur(total, np.arange(d), np.arange(d, total.shape[0]))


def schur(info: np.ndarray, keep, drop) -> np.ndarray:
    """The information about ``keep`` with ``drop`` marginalised:
    I_kk − I_kd I_dd⁺ I_dk (I_dd⁺ a pseudo-inverse: a nuisance the data do not see costs
    nothing)."""
    keep, drop = np.asarray(keep, np.intp), np.asarray(drop, np.intp)
    a = info[np.ix_(keep, keep)]
    if drop.size == 0:
        return a
    b = info[np.ix_(keep, drop)]
    c = info[np.ix_(drop, drop)]
    scale = np.sqrt(np.clip(np.diag(c), 1e-300, None))
    cn = c / np.outer(scale, scale)
    bn = b / scale
    try:                 # positive definite (the usual case): Cholesky
        low = np.linalg.cholesky(cn + 1e-12 * np.eye(cn.shape[0]))
        half = np.linalg.solve(low, bn.T)
        out = a - half.T @ half
    except np.linalg.LinAlgError:
        out = a - bn @ np.linalg.lstsq(cn, bn.T, rcond=1e-13)[0]
    return 0.5 * (out + out.T)


def covariance(info: np.ndarray) -> np.ndarray:
    """The inverse of an information matrix, with inf on the variances (and NaN on the
    covariances) of the parameters that a null direction (eigenvalue below
    ``NULL_FRACTION`` of the largest) involves: the Fisher approximation of the posterior
    covariance without the prior."""
    d = info.shape[0]
    if d == 0:
        return np.zeros((0, 0))
    lam, vec = np.linalg.eigh(0.5 * (info + info.T))
    top = float(lam.max()) if lam.size else 0.0
    if not top > 0:
        return np.full((d, d), np.inf)
    good = lam > NULL_FRACTION * top
    cov = (vec[:, good] / lam[good]) @ vec[:, good].T
    null = vec[:, ~good]
    involved = np.any(np.abs(null) > 1e-6, axis=1) if null.size else np.zeros(d, bool)
    cov[involved, :] = np.nan
    cov[:, involved] = np.nan
    cov[involved, involved] = np.inf
    return cov


def sd_along(cov: np.ndarray, gradient: np.ndarray) -> float:
    """The standard deviation of a function of the parameters with ``gradient`` under the
    covariance ``cov`` (inf where it depends on an unconstrained parameter)."""
    g = np.asarray(gradient, float)
    used = np.abs(g) > 0
    if not used.any():
        return 0.0
    sub = cov[np.ix_(used, used)]
    if not np.all(np.isfinite(sub)):
        return math.inf
    return math.sqrt(max(float(g[used] @ sub @ g[used]), 0.0))
