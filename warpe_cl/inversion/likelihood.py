"""The likelihood of recorded linear-mode shots given a model waveform (docs/inversion.md §4).

Shot s, sample k at time t_k (ns) records

    x_sk = baseline + a_s μ(t_k − δ_s) + ε_sk,   Var ε_sk = σ_n² + a_s ν(t_k − δ_s),

with μ, ν from :class:`warpe_cl.inversion.forward.Forward`, a_s the shot's amplitude and δ_s
its arrival (range offset plus the unknown sampling phase: the return is not locked to the ADC
clock, and real shots do not share one range). Shot noise with APD excess, electronic and
background noise and quantisation make up the variance (Gaussian: tens to thousands of
photoelectrons per sample). A clipped sample (at the saturation level or the top ADC code) is
censored: it says only x ≥ c and counts log P(x ≥ c) = log ½ erfc((c − m)/√(2 Var)).

Per-shot nuisances, integrated out:

- δ_s with a flat prior (the same for every model, so it drops out);
- a_s = A S_s with the speckle factor S_s ~ Gamma(M, 1/M) of docs/instrument.md §3.3, taken as
  N(A, A²/M); the overall amplitude A is profiled (:func:`overall_amplitude`) unless fixed.

A shot without clipped samples is integrated by Laplace's method around the mode of
ℓ_s(a, δ) + log N(a; A, A²/M) (Gauss–Newton):

    log L_s = ℓ_s(â_s, δ̂_s) + log N(â_s; A, A²/M) + log 2π − ½ log det H_s,

H_s the Gauss–Newton Hessian of the negative objective in (a, δ). A shot with clipped samples
is integrated numerically in δ, by Laplace in a at each δ (:meth:`Shots._arrival_integral`).
log L = Σ_s log L_s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import log_ndtr

LOG_2PI = math.log(2.0 * math.pi)
#: Gauss–Newton stops when no shot's log-likelihood rises by more than this in a step ...
TOLERANCE = 1e-4
#: ... or after this many steps.
MAX_ITERATIONS = 60
#: Arrival integral of clipped shots: coarse and fine steps (ns), the part of the coarse grid
#: kept (log units below its maximum), Newton steps in a at each arrival.
ARRIVAL_COARSE = 0.5
ARRIVAL_FINE = 0.1
ARRIVAL_RANGE = 12.0
ARRIVAL_NEWTON = 3
#: Speckle modes above this count as this many: without speckle (M = inf) every a_s is A.
MODES_CAP = 1e10
#: The first arrivals are scanned around every peak of the model at least this share of its
#: highest (:func:`peak_times`).
PEAK_SHARE = 0.5
#: ... and apart from the others: the model dips below this share of the lower one between
#: them (:func:`peak_times`), ...
PEAK_DIP = 0.8
#: ... and no more than this many.
MOST_PEAKS = 4
#: ... at once over as many offsets as keep its arrays (offsets × shots × samples) this small.
SCAN_ELEMENTS = 200_000


@dataclass
class ShotFit:
    """The per-shot nuisances at one model: amplitude a_s, arrival δ_s (ns), and the parts of
    the log-likelihood."""
    amplitude: np.ndarray
    arrival: np.ndarray
    loglike: float
    overall: float          # A
    chi2: float             # Σ r²/Var over uncensored samples
    samples: int            # uncensored samples
    censored: int
    emulator: float = 0.0   # Δ log L of the database's own error (emulator.shared_error)
    emulator_sd: float = 0.0    # the stated error of log L it causes
    emulator_offset: float = 0.0    # and the offset it causes on average
    table: np.ndarray | None = None     # the model fitted: model_table(μ, ν)


class Shots:
    """Recorded shots and what does not change between models.

    Parameters
    ----------
    time_ns : array (K,)
        Nominal sample times, ns.
    samples : array (S, K)
        Recorded samples, mV.
    forward : Forward
        Noise level, baseline, ceiling and speckle modes.
    """

    def __init__(self, time_ns, samples, forward):
        self.t = np.asarray(time_ns, float)
        self.x = np.asarray(samples, float)
        self.f = forward
        self.censored = self.x >= forward.ceiling - 1e-9
        self.censored_at = np.flatnonzero(self.censored)          # as flat indices
        self.uncensored = self.x.size - self.censored_at.size
        self.y = self.x - forward.baseline           # baseline-subtracted
        self.arrival = None
        self.amplitude = None

    def start(self, mu: np.ndarray) -> None:
        """First per-shot arrival and amplitude against model ``mu`` (on the fine grid): a scan
        of δ over ±1.5 sampling intervals around the alignment of the peak sample (the first
        clipped one) with the model's peak, the amplitude at each δ by least squares on the
        unclipped samples, raised if need be to the least that brings the model to the
        ceiling at every clipped one. A model with several peaks of like height (a slab's
        surface return and its first echo) is scanned around each (:func:`peak_times`): the
        recorded peak sample may be either, by sampling phase."""
        k = np.argmax(np.where(self.censored, np.inf, self.y), axis=1)
        c = self.f.ceiling - self.f.baseline
        offsets = np.linspace(-1.5, 1.5, 61) * self.f.interval
        n = len(self.y)
        best = np.full(n, np.inf)
        arrival = self.t[k] - float(self.f.t[np.argmax(mu)])
        amp = np.ones(n)
        free = np.where(self.censored, 0.0, self.y)
        table = padded([mu])
        block = max(1, SCAN_ELEMENTS // self.y.size)        # offsets scanned at once
        clipped = bool(self.censored.any())
        squares = (self.y * self.y).sum(-1)
        shots = np.arange(n)
        # δ = t[k_s] − t_peak + offset depends on the shot only through its peak sample k_s:
        # the model is read once per peak sample in use (a few) and offset
        peaks, which = np.unique(k, return_inverse=True)
        for t_peak in peak_times(self.f.t, mu, self.f.interval):
            centre = self.t[peaks] - t_peak
            for first in range(0, offsets.size, block):
                at = centre[None, :] + offsets[first: first + block, None]   # offsets × peaks
                m_at = self._gather(table, at.ravel())[0].reshape(at.shape + (-1,))
                delta, m = at[:, which], m_at[:, which]             # offsets × S (× K)
                a, chi = (self._scan_clipped(m, free, c) if clipped
                          else _scan_free(m, self.y, squares, (m_at * m_at).sum(-1)[:, which]))
                j = np.argmin(chi, axis=0)          # the first of equals, as a scan in turn
                better = chi[j, shots] < best
                best = np.where(better, chi[j, shots], best)
                arrival = np.where(better, delta[j, shots], arrival)
                amp = np.where(better, a[j, shots], amp)
        self.arrival, self.amplitude = arrival, np.where(np.isfinite(amp), amp, 1.0)

    def _scan_clipped(self, m, free, c) -> tuple:
        """:meth:`start`'s amplitudes and squared residuals at the model samples ``m``
        (offsets × shots × samples) when some samples are clipped: least squares on the
        unclipped ones, raised to reach the ceiling at the clipped ones, which count only
        below it."""
        mu_free = np.where(self.censored, 0.0, m)
        norm = (mu_free * mu_free).sum(-1)
        a = (free * mu_free).sum(-1) / np.where(norm > 0, norm, 1.0)
        reach = np.where(self.censored & (m > 0), c / np.where(m > 0, m, 1.0), 0.0).max(-1)
        reach = np.where((self.censored & (m <= 0)).any(-1), np.inf, reach)
        a = np.maximum(np.maximum(a, reach), 1e-6)
        r = self.y - np.where(np.isfinite(a), a, 0.0)[..., None] * m
        r = np.where(self.censored, np.maximum(r, 0.0), r)
        return a, np.where(np.isfinite(a), (r * r).sum(-1), np.inf)

    def _interp(self, values: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """``values`` (fine grid) at t_k − δ_s, shape (S, K); 0 outside the grid."""
        return self._gather(padded([values]), delta)[0]

    def _gather(self, table: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """The rows of ``table`` (:func:`padded` arrays of the uniform fine grid) linearly
        interpolated at t_k − δ_s: shape (rows, S, K). The index arithmetic of np.interp on a
        uniform grid, done once for all rows; beyond the grid the zero padding gives 0."""
        grid = self.f.t
        x = (self.t[None, :] - np.asarray(delta)[:, None] - grid[0]) / (grid[1] - grid[0]) + 1.0
        np.minimum(np.maximum(x, 0.0, out=x), grid.size + 1.0, out=x)    # np.clip's bits
        i = x.astype(np.intp)
        frac = x - i
        lo = np.take(table, i, axis=1)
        return lo + frac * (np.take(table[:, 1:], i, axis=1) - lo)

    def fit(self, mu: np.ndarray, nu: np.ndarray, overall: float | None = None,
            iterations: int = MAX_ITERATIONS) -> ShotFit:
        """The Laplace log-likelihood of the module docstring at model (``mu``, ``nu``).

        Gauss–Newton on each shot's (a_s, δ_s), from the last fit, for the largest
        ℓ_s(a_s, δ_s) + log N(a_s; A, A²/M), alternating with A's maximum-likelihood update
        (:func:`overall_amplitude`; ``overall`` holds A instead), until no shot's objective
        rises by more than ``TOLERANCE`` (at most ``iterations`` steps).

        The speckle prior is part of the mode and of its Hessian, not convolved afterwards:
        a shot with clipped samples may keep only one edge sample above the noise, and its
        likelihood alone is then a ridge in (a, δ) (a larger amplitude further from that
        sample) ending at the clipping constraint, where no Gaussian approximation of the
        likelihood holds; the prior bounds the ridge, and the Laplace approximation of the
        product holds. Converging matters for the same shots: a fixed small number of steps
        leaves a model-dependent part of the way undone, noise of a few units in log L from
        one pulse width to the next (docs/inversion.md §4)."""
        if self.arrival is None:
            self.start(mu)
        table = model_table(mu, nu, self.f.t)
        a, d = self.amplitude.copy(), self.arrival.copy()
        sig2 = self.f.sigma_n ** 2
        c = self.f.ceiling - self.f.baseline
        limit = 0.5 * self.f.interval
        modes = min(self.f.modes, MODES_CAP)
        big_a = float(overall) if overall is not None else overall_amplitude(a, modes)

        def with_prior(a_, lik):
            """The objective's Hessian, gradient and value per shot: the likelihood's
            (:meth:`_normal`) plus the speckle prior's at the current A."""
            h_aa, h_ad, h_dd, g_a, g_d, ell_, _ = lik
            prec = modes / big_a ** 2                       # speckle prior precision of a_s
            prior = -0.5 * (LOG_2PI - math.log(prec) + prec * (a_ - big_a) ** 2)
            return (h_aa + prec, h_ad, h_dd), (g_a - prec * (a_ - big_a), g_d), ell_ + prior

        lik = self._normal(a, d, table, sig2, c)
        h, g, obj = with_prior(a, lik)
        for _ in range(iterations):
            before = obj
            det = h[0] * h[2] - h[1] ** 2
            ok = det > 0
            da = np.where(ok, (h[2] * g[0] - h[1] * g[1]) / np.where(ok, det, 1.0), 0.0)
            dd = np.where(ok, (h[0] * g[1] - h[1] * g[0]) / np.where(ok, det, 1.0), 0.0)
            da = np.minimum(np.maximum(da, -0.5 * a), 0.5 * a + 1e-3)     # np.clip's bits
            dd = np.minimum(np.maximum(dd, -limit), limit)
            # a step is kept for a shot only where it raises its objective; else a quarter,
            # a sixteenth (the shorter steps for the shots still pending only)
            pending = np.arange(a.size)
            for shrink in (1.0, 0.25, 0.0625):
                trial_a = np.maximum(a[pending] + shrink * da[pending], 1e-9)
                trial_d = d[pending] + shrink * dd[pending]
                t_lik = self._normal(trial_a, trial_d, table, sig2, c,
                                     None if pending.size == a.size else pending)
                better = with_prior(trial_a, t_lik)[2] > obj[pending]
                kept = pending[better]
                a[kept], d[kept] = trial_a[better], trial_d[better]
                for whole, part in zip(lik, t_lik):
                    whole[kept] = part[better]
                h, g, obj = with_prior(a, lik)
                pending = pending[~better]
                if not pending.size:
                    break
            moved = float(np.max(obj - before))
            if overall is None:
                new_a = overall_amplitude(a, modes)
                # what A's change is worth in log L: ½ n M (ΔA/A)² (its curvature)
                moved = max(moved, 0.5 * a.size * modes * ((new_a - big_a) / big_a) ** 2)
                big_a = new_a
                h, g, obj = with_prior(a, lik)
            if moved < TOLERANCE:
                break
        self.amplitude, self.arrival = a, d
        det = np.maximum(h[0] * h[2] - h[1] ** 2, 1e-300)
        per_shot = obj + LOG_2PI - 0.5 * np.log(det)
        clipped = np.nonzero(self.censored.any(axis=1))[0]
        if clipped.size:
            per_shot[clipped] = self._arrival_integral(table, a, d, clipped, big_a,
                                                       modes / big_a ** 2, sig2, c)
        total = float(np.sum(per_shot))
        return ShotFit(a, d, total, big_a, float(np.sum(lik[6])), self.uncensored,
                       self.x.size - self.uncensored, table=table)

    def _arrival_integral(self, table, a, d, rows, big_a, prec, sig2, c) -> np.ndarray:
        """log ∫∫ exp(ℓ_s(a, δ)) N(a; A, A²/M) da dδ for the shots ``rows`` that have
        clipped samples: Laplace in a at each δ (the objective is concave in a), the
        trapezoid rule in δ.

        Clipping leaves such a shot's arrival on a plateau: any δ that keeps the clipped
        samples above the ceiling and the unclipped ones at their values fits about as well,
        and the plateau ends at a cliff where a clipped sample would fall below the ceiling.
        No Gaussian approximation in δ holds there. The integral is taken on a coarse grid
        (``ARRIVAL_COARSE`` ns over ± half a sampling interval around the fitted δ_s), then
        on a fine one (``ARRIVAL_FINE`` ns) over the part within ``ARRIVAL_RANGE`` of the
        coarse maximum, where the mass is."""
        half = 0.5 * self.f.interval
        coarse = np.arange(-half, half + 1e-9, ARRIVAL_COARSE)
        logv, _ = self._on_arrivals(table, a[rows], d[rows][:, None] + coarse[None, :], rows,
                                    big_a, prec, sig2, c)
        lo, hi = kept_span(coarse, logv, ARRIVAL_RANGE)
        lo, hi = d[rows] + lo, d[rows] + hi
        count = int(np.ceil(np.max(hi - lo) / ARRIVAL_FINE)) + 1
        frac = np.linspace(0.0, 1.0, count)
        grid = lo[:, None] + (hi - lo)[:, None] * frac[None, :]
        logv, _ = self._on_arrivals(table, a[rows], grid, rows, big_a, prec, sig2, c)
        return log_trapezoid(logv, (hi - lo) / (count - 1))

    def _on_arrivals(self, table, a0, deltas, rows, big_a, prec, sig2, c):
        """For shots ``rows`` at arrivals ``deltas`` (rows × D, ns): the log of the Laplace
        integral over a, max_a [ℓ + log prior] + ½ log(2π / H_aa), by Newton steps in a
        from ``a0``; and that a. Shape (rows, D)."""
        n_rows, n_d = deltas.shape
        m, _, n = self._gather(table, deltas.ravel())
        y = np.repeat(self.y[rows], n_d, axis=0)
        at = np.flatnonzero(np.repeat(self.censored[rows], n_d, axis=0))
        a = np.repeat(a0, n_d)
        for step in range(ARRIVAL_NEWTON + 1):
            grad_m, weight, ell_k, _ = _terms(y, at, a, m, n, sig2, c)
            h = (weight * m * m).sum(1) + prec
            if step == ARRIVAL_NEWTON:
                break
            g = (grad_m * m).sum(1) - prec * (a - big_a)
            a = np.maximum(a + g / h, 1e-9)
        obj = ell_k.sum(1) - 0.5 * (LOG_2PI - math.log(prec) + prec * (a - big_a) ** 2)
        logv = obj + 0.5 * (LOG_2PI - np.log(h))
        return logv.reshape(n_rows, n_d), a.reshape(n_rows, n_d)

    def _normal(self, a, d, table, sig2, c, rows=None) -> list:
        """Per shot: the Gauss–Newton Hessian of −ℓ_s in (a, δ) (H_aa, H_aδ, H_δδ), the
        gradient of ℓ_s (g_a, g_δ), ℓ_s itself and Σ r²/Var over its uncensored samples. A
        censored sample contributes log Φ(z), z = (m − c)/√Var, whose derivative in the model
        m is λ(z)/√Var and whose curvature is λ(z)(z + λ(z))/Var, λ = φ/Φ (the Tobit terms),
        so that the steps follow the same ℓ_s that is reported. ``rows``: the shots ``a`` and
        ``d`` belong to (default: all); each shot's terms are the same bits either way."""
        m, dm, n = self._gather(table, d)
        y, at = ((self.y, self.censored_at) if rows is None
                 else (self.y[rows], np.flatnonzero(self.censored[rows])))
        grad_m, weight, ell_k, chi2 = _terms(y, at, a, m, n, sig2, c)
        j_d = -a[:, None] * dm
        wm = weight * m
        wj = weight * j_d
        return [(wm * m).sum(1), (wm * j_d).sum(1), (wj * j_d).sum(1), (grad_m * m).sum(1),
                (grad_m * j_d).sum(1), ell_k.sum(1), chi2.sum(1)]


def overall_amplitude(a: np.ndarray, modes: float) -> float:
    """The A that maximises Σ_s log N(a_s; A, A²/M): the positive root of
    n A² + M S₁ A − M S₂ = 0 (S₁ = Σ a_s, S₂ = Σ a_s²), written without cancellation; S₂/S₁
    for M → inf."""
    s1, s2 = float(np.sum(a)), float(np.sum(a * a))
    return 2.0 * s2 / (s1 + math.sqrt(s1 * s1 + 4.0 * a.size * s2 / modes))


def _scan_free(m: np.ndarray, y: np.ndarray, squares: np.ndarray, mm: np.ndarray) -> tuple:
    """:meth:`Shots.start`'s amplitudes and squared residuals at the model samples ``m``
    (offsets × shots × samples) when no sample is clipped, from two sums per shot:
    a = Σ y m / Σ m², Σ (y − a m)² = Σ y² − 2 a Σ y m + a² Σ m² (``squares``: Σ y²; ``mm``:
    Σ m², offsets × shots)."""
    ym = (y * m).sum(-1)
    a = np.maximum(ym / np.where(mm > 0, mm, 1.0), 1e-6)
    return a, squares - 2.0 * a * ym + a * a * mm


def peak_times(t: np.ndarray, mu: np.ndarray, interval: float) -> list:
    """Times (ns) of the peaks of model ``mu`` (on times ``t``) that a recorded peak sample may
    be: the highest first, then, highest first, every local maximum of at least
    :data:`PEAK_SHARE` of it that lies more than ``interval`` (the sampling interval) from
    each one already taken, with the model falling below :data:`PEAK_DIP` of the lower of
    the two between them (Monte Carlo ripples on one peak or on a plateau are not peaks of
    their own); :data:`MOST_PEAKS` at most."""
    top = int(np.argmax(mu))
    inner = mu[1:-1]
    local = np.flatnonzero((inner >= PEAK_SHARE * mu[top]) & (inner >= mu[:-2])
                           & (inner > mu[2:])) + 1
    taken = [top]

    def apart(i, j):
        lo, hi = min(i, j), max(i, j)
        return abs(t[i] - t[j]) > interval and \
            mu[lo: hi + 1].min() < PEAK_DIP * min(mu[i], mu[j])
    for i in local[np.argsort(-mu[local], kind="stable")]:
        if len(taken) == MOST_PEAKS:
            break
        if all(apart(int(i), j) for j in taken):
            taken.append(int(i))
    return [float(t[i]) for i in taken]


def kept_span(points: np.ndarray, logv: np.ndarray, below: float) -> tuple:
    """Per row of ``logv`` (rows × D, on the grid ``points`` (D,)), the span of the points
    whose value is within ``below`` of the row's maximum, widened by one point each side:
    (low, high) arrays of the rows. Where a coarse scan tells a fine grid where the mass is."""
    keep = logv > logv.max(axis=1, keepdims=True) - below
    first = np.argmax(keep, axis=1)
    last = keep.shape[1] - 1 - np.argmax(keep[:, ::-1], axis=1)
    return points[np.maximum(first - 1, 0)], points[np.minimum(last + 1, points.size - 1)]


def log_trapezoid(logv: np.ndarray, step) -> np.ndarray:
    """log ∫ exp(logv) by the trapezoid rule along the last axis, points ``step`` apart (a
    number, or one per row), without overflow."""
    w = np.full(logv.shape[-1], 1.0)
    w[[0, -1]] = 0.5
    top = logv.max(axis=-1)
    return top + np.log(np.sum(w * np.exp(logv - top[..., None]), axis=-1) * step)


def model_table(mu: np.ndarray, nu: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The :func:`padded` table [μ, μ′, ν] of a model on the fine grid ``t`` (ns): what
    :meth:`Shots.fit` reads at the shots' arrivals, and the database error after it."""
    return padded([mu, np.gradient(mu, t), nu])


def padded(arrays: list) -> np.ndarray:
    """Arrays of the fine grid as the rows of one table with a zero column before and two
    after (what :meth:`Shots._gather` reads)."""
    table = np.zeros((len(arrays), arrays[0].size + 3))
    for row, values in zip(table, arrays):
        row[1:-2] = values
    return table


def _terms(y, at, a, m, n, sig2, c):
    """Per sample, for amplitudes ``a`` (per row) and model ``m``, ``n`` (rows × K): ∂ℓ/∂m,
    the Gauss–Newton weight, ℓ and r²/Var. ``at``: flat indices of the censored samples,
    where the Tobit terms replace the Gaussian ones (r²/Var is then 0); they are a few per
    clipped shot, so the costly log Φ is taken there only."""
    var = sig2 + a[:, None] * n
    r = y - a[:, None] * m
    grad_m = r / var
    weight = 1.0 / var
    chi2 = r * grad_m
    ell = -0.5 * (chi2 + np.log(var) + LOG_2PI)
    if at.size:
        var_c = var.ravel()[at]
        sd_c = np.sqrt(var_c)
        z = (a[at // m.shape[1]] * m.ravel()[at] - c) / sd_c
        log_phi_z = log_ndtr(z)
        mills = np.exp(-0.5 * z * z - 0.5 * LOG_2PI - log_phi_z)
        grad_m.ravel()[at] = mills / sd_c
        weight.ravel()[at] = mills * (z + mills) / var_c
        ell.ravel()[at] = log_phi_z
        chi2.ravel()[at] = 0.0
    return grad_m, weight, ell, chi2
