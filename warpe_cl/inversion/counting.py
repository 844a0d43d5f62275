"""The likelihood of photon-counting shots (ATLAS ``signal_counts``; docs/inversion.md §4.2).

A photon-counting receiver records a few time tags per shot; shot s puts c_sk of them in
histogram bin k = [t_k, t_k + Δ). With s(t) the signal photoelectrons per ns at amplitude 1
(pulse and footprint: :meth:`.forward.Forward.waveform`), the recorded rate at amplitude A is
d_r + ρ(t; A), ρ = J ⊗ R(A s) − d_r: the channels' dead time R averaged over the speckle, then
the timing jitter J, less the recorded dark and background level d_r (:mod:`.recording`). The
expected recorded counts per shot are

    m_k(A, δ) = d_r Δ + ∫ ρ(t − δ; A) dt over bin k,

with A the overall amplitude (profiled) and δ the arrival (range offset), common to the
shots: the tags are continuous times, not samples of a free-running clock, so there is no
per-shot sampling phase, and a shot's few photons could not fix its own arrival anyway. The
counts of bin k summed over the N shots, c_k, are taken as Poisson of mean N m_k, and

    log L = log ∫ dδ max_A Σ_k [c_k log(N m_k) − N m_k − log c_k!]

(the arrival integrated with a flat prior on a coarse, then a fine grid). Without dead time
m_k = A λ_k(δ) + d Δ, concave in A: A is profiled by Newton's method. With it, ρ is expanded to
second order in A around a centre A_c (:meth:`.recording.Recording.expansion`), A profiled by Newton
in that expansion at each δ (within A_c/2 and 2 A_c, where it stays ≥ 0), A_c starting where
the recorded photons equal the signal that the model without dead time fits at its best arrival,
and moved to the best arrival's A until it stays (to 1e-6): exact there, third order in A − A_c
at the other arrivals. Where it has not stayed after ``CENTRE_MOVES`` moves (a model far off,
whose best arrival moves with the centre), A is held at the last centre, exact and never above
the profile, and at the best of those arrivals log L is the exact profile's (a bounded scalar
search over ln A).

The sum of N shots' counts in a bin is not exactly Poisson: speckle spreads it more (a
fraction A λ_k / M of the Poisson variance: below 1e-3 when a bin holds less than a tenth of a
photon per shot) and the dead time less (a shot that recorded one photon is less likely to
record a second within τ_a); the likelihood leaves both out of the variance. When the timing
channels' dead time exceeds twice the analog one, their own losses are left out of the mean too
(``Recording.exact``; ``invert`` warns).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import gammaln

from ..instrument.pulse import sigma_from_fwhm
from .likelihood import ShotFit, kept_span, log_trapezoid
from .recording import Recording

#: Arrival grid: coarse step (fraction of the pulse's σ at the nominal width), half-width of
#: the coarse scan (ns, around :meth:`CountShots._centre`), points of the fine grid, and the
#: part of the coarse grid kept (log units below its maximum).
COARSE_FRACTION = 0.25
SCAN_NS = 10.0
FINE_POINTS = 81
KEEP = 12.0
#: Newton steps of the amplitude at each arrival, at most, and the relative step below which
#: they stop (every arrival's).
NEWTON, NEWTON_TOLERANCE = 8, 1e-10
#: With dead time: moves of the expansion's centre A_c, and when it has stayed (relative).
CENTRE_MOVES, CENTRE_TOLERANCE = 8, 1e-6
#: Bins holding counts whose expected counts are below this fraction of the arrival's largest
#: are left out of the amplitude's Newton steps and expect that fraction in log L: the model
#: reaches them only by the rounding of its convolutions.
NEGLIGIBLE = 1e-12
#: With dead time: the amplitudes the expansion is trusted over, relative to its centre.
TRUST = (0.5, 2.0)
#: Consecutive bins are grouped until the expected count reaches this for the Pearson χ².
CHI2_GROUP = 5.0
#: Bins expecting fewer counts (all shots) than this are left out of the database's error
#: (:meth:`CountShots.error_blocks`): their weight (N A Δ)² / M_k would divide by nothing.
ERROR_MIN_COUNTS = 1e-9


class CountShots:
    """Photon-counting histograms and what does not change between models.

    Parameters
    ----------
    time_ns : array (K,)
        Start of each histogram bin, ns (bins of ``forward.interval``).
    counts : array (S, K)
        Time tags per bin of each shot.
    forward : Forward
        A photon-counting instrument's forward model.
    """

    def __init__(self, time_ns, counts, forward):
        self.t = np.asarray(time_ns, float)
        self.x = np.asarray(counts, float)
        self.f = forward
        self.n = self.x.shape[0]
        self.c = self.x.sum(axis=0)                        # aggregated histogram
        self.hit = self.c > 0
        self.contiguous = bool(np.allclose(np.diff(self.t), forward.interval))
        self.width = forward.interval
        self.recording = Recording(forward)
        self.b = self.recording.background * self.width   # dark counts per bin per shot
        self.censored = np.zeros(self.x.shape, bool)      # nothing clips
        self.arrival = None
        self.amplitude = None
        self.log_factorial = float(np.sum(gammaln(self.c + 1.0)))

    def start(self, mu: np.ndarray) -> None:
        """Nothing to start: every fit scans its arrivals afresh."""

    def _cumulative(self, rate: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The fine grid's edges and the rate's integral up to each, for :func:`np.interp`."""
        step = self.f.step
        edges = np.concatenate([self.f.t - 0.5 * step, [self.f.t[-1] + 0.5 * step]])
        return edges, np.concatenate([[0.0], np.cumsum(rate) * step])

    def _integrals(self, edges: np.ndarray, cum: np.ndarray, starts: np.ndarray,
                   deltas: np.ndarray) -> np.ndarray:
        """The integral of a rate (its :meth:`_cumulative` ``edges`` and ``cum``) over the
        bins starting at ``starts`` (ns), shifted by each arrival: shape (D, len(starts))."""
        lo = np.interp(starts[None, :] - deltas[:, None], edges, cum)
        hi = np.interp(starts[None, :] + self.width - deltas[:, None], edges, cum)
        return hi - lo

    def _lambda(self, mu: np.ndarray, deltas: np.ndarray) -> np.ndarray:
        """The integral of a rate (per ns on the fine grid) over each bin, shifted by each
        arrival: shape (D, K)."""
        return self._integrals(*self._cumulative(mu), self.t, deltas)

    def _hits(self, rate: np.ndarray, deltas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The integrals of a rate over the bins holding counts, (D, hits), and over all
        bins, (D,), at each arrival: the likelihood needs no more. For contiguous bins the
        sum is one difference of the cumulative rate; otherwise every bin is integrated."""
        if not self.contiguous:
            full = self._lambda(rate, deltas)
            return full[:, self.hit], full.sum(1)
        edges, cum = self._cumulative(rate)
        total = (np.interp(self.t[-1] + self.width - deltas, edges, cum)
                 - np.interp(self.t[0] - deltas, edges, cum))
        return self._integrals(edges, cum, self.t[self.hit], deltas), total

    def _rows(self, mu: np.ndarray, centre: float, deltas: np.ndarray,
              jittered: np.ndarray | None = None) -> tuple:
        """The recorded signal counts per shot at amplitude ``centre`` and their first two
        derivatives in A (None without dead time), at each arrival: per row, the bins holding
        counts (D, hits) and the sum over all bins (D,); and the range of A − centre over
        which the expansion stays ≥ 0 (:func:`_nonnegative`) within ``TRUST``.
        ``jittered``: J ⊗ ``mu``, when already taken (read without dead time only)."""
        rec = self.recording
        if rec.linear:
            return self._linear_rows(self.f.jitter(mu) if jittered is None else jittered,
                                     centre, deltas)
        rows = rec.expansion(mu, centre)
        lo, hi = _nonnegative(rec.background + rows[0], rows[1], rows[2])
        span = (max(lo, (TRUST[0] - 1.0) * centre), min(hi, (TRUST[1] - 1.0) * centre))
        return (*(self._hits(row, deltas) for row in rows), span)

    def _linear_rows(self, jittered: np.ndarray, centre: float, deltas: np.ndarray) -> tuple:
        """:meth:`_rows` of the model without dead time, A J ⊗ s (``jittered``: J ⊗ s)."""
        one = self._hits(jittered, deltas)
        return (centre * one[0], centre * one[1]), one, None, (1e-6 - centre, np.inf)

    def _profile(self, rows: tuple, centre: float, overall) -> tuple[np.ndarray, np.ndarray]:
        """(log L, A) at each arrival, A profiled unless ``overall``: Newton's method on the
        counts' expansion in A around ``centre`` (:meth:`_rows`)."""
        n, b = self.n, self.b
        c = self.c[self.hit]
        (h0, s0), (h1, s1), bent, (lo, hi) = rows
        h2, s2 = (None, 0.0) if bent is None else bent
        if overall is not None:
            e = np.full(s0.shape[0], float(overall) - centre)
        else:
            # the linear estimate from the total, then Newton
            e = np.clip((self.c.sum() / n - b * self.c.size - s0) / np.maximum(s1, 1e-300),
                        lo, hi)
            for _ in range(NEWTON):
                x = e[:, None]
                slope = h1 if h2 is None else h1 + x * h2
                mean = b + h0 + x * (h1 if h2 is None else h1 + 0.5 * x * h2)
                # bins the model reaches only by rounding (the jitter's FFT) steer nothing
                live = mean > NEGLIGIBLE * np.max(mean, axis=1, initial=0.0)[:, None]
                inverse = np.where(live, 1.0 / np.where(live, mean, 1.0), 0.0)
                ratio = slope * inverse
                g = (c * ratio).sum(1) - n * (s1 + e * s2)
                h = (c * ratio * ratio).sum(1)          # −∂²/∂A², less the curvature below
                if h2 is not None:
                    h -= (c * h2 * inverse).sum(1) - n * s2
                step = g / np.where(h > 0, h, np.abs(g) / np.maximum(centre + e, 1e-300) + 1e-300)
                a = centre + e
                moved = np.clip(np.maximum(a + step, 0.5 * a) - centre, lo, hi)
                settled = np.all(np.abs(moved - e) <= NEWTON_TOLERANCE * a)
                e = moved
                if settled:
                    break
        x = e[:, None]
        hits = n * (b + h0 + x * (h1 if h2 is None else h1 + 0.5 * x * h2))
        total = n * (b * self.c.size + s0 + e * (s1 + 0.5 * e * s2))
        # expected counts below the convolution's rounding (NEGLIGIBLE of the arrival's
        # largest) are that much: a stray count there costs the same at every arrival
        floor = np.maximum(NEGLIGIBLE * np.max(hits, axis=1, initial=0.0), 1e-300)[:, None]
        ll = (c * np.log(np.maximum(hits, floor))).sum(1) - total - self.log_factorial
        return ll, centre + e

    def _scan(self, mu: np.ndarray, deltas: np.ndarray, centre: float, overall,
              moves: int = CENTRE_MOVES, jittered: np.ndarray | None = None) -> tuple:
        """(log L, A, centre) at ``deltas``, the expansion's centre moved to the best arrival's
        A until it stays, at most ``moves`` times (once without dead time or with
        ``overall``). ``jittered``: as for :meth:`_rows`."""
        for _ in range(moves):
            rows = self._rows(mu, centre, deltas, jittered)
            ll, a = self._profile(rows, centre, overall)
            best = float(a[int(np.argmax(ll))])
            if rows[2] is None or overall is not None \
                    or abs(best - centre) <= CENTRE_TOLERANCE * centre:
                return ll, a, best
            centre = best
        if moves > 1:
            # not settled (the best arrival moves with the centre, as for a model far off):
            # log L with A held at the last centre, exact and never above the profile, and at
            # the best of those arrivals the exact profile itself
            ll, a = self._profile(self._rows(mu, centre, deltas), centre, centre)
            top = int(np.argmax(ll))
            a_top, ll_top = self._exact_profile(mu, float(deltas[top]), centre)
            if ll_top > ll[top]:
                ll[top], a[top] = ll_top, a_top
        return ll, a, centre

    def _exact_profile(self, mu: np.ndarray, delta: float, around: float) -> tuple:
        """(A, log L) maximising the exact log L over A at one arrival (no expansion: the
        recorded counts made anew at each A), A within e^±12 of ``around``."""
        from scipy.optimize import minimize_scalar     # on use: rare, and 0.3 s to import
        at = np.array([delta])

        def loglike(x):         # log L with A held at e^x: the expansion's centre, exact
            a = math.exp(x)
            return float(self._profile(self._rows(mu, a, at), a, a)[0][0])
        x0 = math.log(max(around, 1e-300))
        found = minimize_scalar(lambda x: -loglike(x), bounds=(x0 - 12.0, x0 + 12.0),
                                method="bounded", options={"xatol": 1e-9})
        return math.exp(found.x), -float(found.fun)

    def _centre(self, rate: np.ndarray) -> float:
        """The arrival scan's centre (ns): the shift of the model's counts that matches the
        histogram best, their cross-correlation over bins of the histogram's width laid over
        the whole forward grid (the histogram's highest bin alone is a background count
        when the return is weak); for bins with gaps, the shift of the highest bin to the
        model's peak. ``rate``: the model's J ⊗ s."""
        peak = (self.t[np.argmax(self.c)] + 0.5 * self.width) - self.f.t[np.argmax(rate)]
        if not self.contiguous:
            return float(peak)
        grid = self.f.t
        m = int(np.floor((grid[0] - self.t[0]) / self.width))      # bins from t_0 to the grid
        starts = self.t[0] + self.width * np.arange(m, m + int(np.ceil(
            (grid[-1] - grid[0]) / self.width)) + 2)
        edges, cum = self._cumulative(rate)
        template = np.diff(np.interp(np.append(starts, starts[-1] + self.width), edges, cum))
        support = np.flatnonzero(template > 1e-6 * template.max(initial=0.0))
        if not support.size or not self.c.any():
            return float(peak)
        first = int(support[0])
        match = np.correlate(self.c, template[first: int(support[-1]) + 1], mode="full")
        # histogram bin i holding template bin k means δ = (i − k − m) Δ
        return (int(np.argmax(match)) - (support[-1] - first) - first - m) * self.width

    def fit(self, mu: np.ndarray, nu=None, overall: float | None = None) -> ShotFit:
        """The log-likelihood of the module docstring at the signal rate ``mu`` (pe per ns on
        the fine grid, amplitude 1), with the best arrival and amplitude."""
        sigma = np.hypot(sigma_from_fwhm(self.f.fwhm), self.f.geo.sigma_g)  # nominal σ, ns
        step = COARSE_FRACTION * max(sigma, self.width)
        jittered = self.f.jitter(mu)
        centre = self._centre(jittered)
        coarse = centre + np.arange(-SCAN_NS, SCAN_NS + 1e-9, step)
        if overall is not None or self.recording.linear:
            start = 1.0 if overall is None else float(overall)
        else:
            # the counts the model without dead time fits at its best arrival, then the
            # amplitude whose recorded photons are those
            ll, a = self._profile(self._linear_rows(jittered, 1.0, coarse), 1.0, None)
            signal = float(a[int(np.argmax(ll))]) * float(np.sum(mu)) * self.f.step
            start = self.recording.amplitude_for(mu, signal)
        ll, _, middle = self._scan(mu, coarse, start, overall, 1, jittered)  # where the mass is
        (lo,), (hi,) = kept_span(coarse, ll[None, :], KEEP)
        fine = np.linspace(lo, hi, FINE_POINTS)
        ll, a, _ = self._scan(mu, fine, middle, overall, jittered=jittered)
        top = int(np.argmax(ll))
        loglike = float(log_trapezoid(ll, fine[1] - fine[0]))
        chi2, groups = pearson(self.c, self.n * self.expected(mu, a[top], fine[top]))
        self.arrival, self.amplitude = float(fine[top]), float(a[top])
        return ShotFit(np.full(self.n, a[top]), np.full(self.n, fine[top]), loglike,
                       float(a[top]), chi2, groups, 0)

    def error_blocks(self, fit, mu: np.ndarray, variance: np.ndarray, block_ns: float) -> tuple:
        """The database's common error per block of model time, for
        :func:`~.emulator.integrate_blocks`. With e_b the error of the signal rate in block b
        (pe ns⁻¹ at amplitude 1, common to its bins: the error is correlated over the kernel's
        length, many 0.1 ns bins), bin k's summed counts move by N A Δ G_k e_b, G_k the
        recorded rate's gain for an error constant over the dead time (1 without dead time:
        :meth:`.recording.Recording.gain`); the Poisson log L, quadratic around the fit, has
        per bin G_k' = N A Δ G_k (c_k − M_k)/M_k and W_k = (N A Δ G_k)² max(c_k, M_k)/M_k²
        (M_k = N m_k; the comment in the code says why not 1/M_k), summed over the block's
        bins, and S_b the W-weighted mean of S over them, as for linear-mode samples
        (docs/inversion.md §4.3).

        Parameters
        ----------
        fit : ShotFit
            The common amplitude A and arrival δ of the fit.
        mu, variance : array
            The signal rate (pe ns⁻¹) and S(t) ((pe ns⁻¹)²) on the forward grid, amplitude 1.
        block_ns : float
            The blocks' length, ns (at least one bin).

        Returns
        -------
        (w, g, s, base)
            Per block: W, G, S and the directions A and δ absorb (in units of e: the
            recorded rate's derivatives in A and δ over A G_k).
        """
        a, d = float(fit.overall), float(fit.arrival[0])
        rec = self.recording
        at = np.array([d])
        level = rec.level(mu, a)
        along = rec.derivative(mu, a)
        gain, s, by_a, by_d = (self._lambda(x, at)[0] / self.width for x in (
            rec.gain(mu, a, along), variance, along(mu), np.gradient(level, self.f.t)))
        expect = self.n * (self.b + self._lambda(level, at)[0])
        scale = self.n * a * self.width * gain
        # the quadratic form holds where the error of a bin's expected counts (sd scale √S)
        # is below the counts themselves; where it is not (a bin expecting almost nothing that
        # the database is unsure of) the mean cannot go below 0 and the Gaussian integral
        # would charge log(1 + scale² S / M) for it: such bins are left out
        kept = (expect > ERROR_MIN_COUNTS) & (scale ** 2 * s <= expect ** 2) & (gain > 0)
        # the curvature of the Poisson log L in the mean is c/M² per count²: (N A Δ G)²/M at
        # the fit's own counts (c = M), more where the counts exceed it. The larger of the
        # two is taken: with 1/M alone the quadratic form's gain from moving the mean to the
        # counts, ½ (c − M)²/M, grows without bound where c ≫ M, the Poisson log L's own,
        # c log(c/M) − (c − M), only as a logarithm (a model far off, whose tail bins held
        # many counts expecting almost none, gained thousands of units from the database's
        # error and ranked above the truth); with c/M² it is ½ (c − M)²/c there, below it
        floor = np.maximum(expect, ERROR_MIN_COUNTS)       # bins below are not kept
        curvature = np.maximum(self.c / floor, 1.0) / floor
        w = np.where(kept, scale ** 2 * curvature, 0.0)
        g = np.where(kept, scale * (self.c - expect) / np.maximum(expect, 1e-300), 0.0)
        block = np.floor((self.t - d - self.f.t[0]) / max(block_ns, self.width)).astype(np.intp)
        block -= block.min()
        w_b = np.bincount(block, w)
        used = w_b > 0
        w_b = w_b[used]
        unit = np.where(kept, 1.0 / np.maximum(a * gain, 1e-300), 0.0)

        def mean(x):
            return np.bincount(block, w * x)[used] / w_b
        return (w_b, np.bincount(block, g)[used], mean(s),
                np.stack([mean(by_a * unit), mean(by_d * unit)], axis=1))

    def expected(self, mu: np.ndarray, amplitude: float, arrival: float) -> np.ndarray:
        """Expected recorded counts per bin per shot at ``amplitude`` and ``arrival``."""
        level = self.recording.level(mu, amplitude)
        return self.b + self._lambda(level, np.array([arrival]))[0]


def _nonnegative(r0: np.ndarray, r1: np.ndarray, r2: np.ndarray) -> tuple[float, float]:
    """The range of e around 0 over which r0 + e r1 + ½ e² r2 ≥ 0 at every point where r0
    is above 1e-9 of its largest (a rate's expansion in A: where it holds on the fine grid,
    every bin's integral holds it too, at any arrival)."""
    keep = r0 > 1e-9 * max(float(r0.max()), 1e-300)
    a, b, c = r0[keep], r1[keep], 0.5 * r2[keep]
    lo, hi = -np.inf, np.inf
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = b * b - 4.0 * a * c
        root = np.sqrt(np.clip(disc, 0.0, None))
        quadratic = (np.abs(c) > 1e-300) & (disc >= 0)
        roots = np.concatenate([np.where(quadratic, (-b - root) / (2 * c), np.nan),
                                np.where(quadratic, (-b + root) / (2 * c), np.nan),
                                np.where(~quadratic & (np.abs(c) <= 1e-300) & (b != 0),
                                         -a / b, np.nan)])
    roots = roots[np.isfinite(roots)]
    if (roots > 0).any():
        hi = float(roots[roots > 0].min())
    if (roots < 0).any():
        lo = float(roots[roots < 0].max())
    return lo, hi


def pearson(observed: np.ndarray, expected: np.ndarray) -> tuple[float, int]:
    """Pearson's χ² over consecutive bins grouped until each group expects ``CHI2_GROUP``
    counts (the last group joins the one before if it falls short), and the number of
    groups."""
    chi2, groups = 0.0, 0
    o_acc = e_acc = 0.0
    bounds = []
    for o, e in zip(observed, expected):
        o_acc += o
        e_acc += e
        if e_acc >= CHI2_GROUP:
            bounds.append((o_acc, e_acc))
            o_acc = e_acc = 0.0
    if e_acc > 0 and bounds:
        o_last, e_last = bounds.pop()
        bounds.append((o_last + o_acc, e_last + e_acc))
    for o, e in bounds:
        chi2 += (o - e) ** 2 / e
        groups += 1
    return float(chi2), groups
