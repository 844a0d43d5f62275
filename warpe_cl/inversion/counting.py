"""The likelihood of photon-counting shots (ATLAS ``signal_counts``; docs/inversion.md §4.2).

A photon-counting receiver records a few time tags per shot; shot s puts c_sk of them in
histogram bin k = [t_k, t_k + Δ). With r(t) the signal photoelectrons per ns at amplitude 1
(pulse, footprint and timing jitter: :meth:`.forward.Forward.waveform`) and b the background
and dark counts per ns, the expected counts per shot are

    m_k(A, δ) = A λ_k(δ) + b Δ,    λ_k(δ) = ∫ r(t − δ) dt over bin k,

with A the overall amplitude (profiled, like the linear mode's) and δ the arrival (range
offset), common to the shots: the tags are continuous times, not samples of a free-running
clock, so there is no per-shot sampling phase, and a shot's few photons could not fix its own
arrival anyway. The counts of bin k summed over the N shots, c_k, are then Poisson of mean
N m_k, and

    log L = log ∫ dδ max_A Σ_k [c_k log(N m_k) − N m_k − log c_k!]

(the arrival integrated with a flat prior on a coarse, then a fine grid; A profiled by
Newton's method, the objective being concave in A).

Left out, and why it is small for ATLAS-like receivers (say so when it is not):

- speckle: each shot's amplitude A S_s varies, which adds N A² λ_k²/M to the variance of c_k,
  a fraction A λ_k / M of the Poisson term: below 1e-3 when a bin holds less than a tenth of a
  photon per shot;
- dead time: a channel that fired is blind for a few ns; with 16 channels and a few photons per
  shot the lost fraction is the chance that two photons of a shot meet in one channel within
  the dead time, under 2 % for 5 photons within 3 ns.
"""
from __future__ import annotations

import numpy as np
from scipy.special import gammaln

from ..instrument.pulse import sigma_from_fwhm
from .likelihood import ShotFit, kept_span, log_trapezoid

#: Arrival grid: coarse step (fraction of the pulse's σ at the nominal width), half-width
#: of the coarse scan (ns, around the histogram's peak), points of the fine grid, and the part
#: of the coarse grid kept (log units below its maximum).
COARSE_FRACTION = 0.25
SCAN_NS = 10.0
FINE_POINTS = 81
KEEP = 12.0
#: Newton steps of the amplitude at each arrival.
NEWTON = 8
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
        self.width = forward.interval
        self.b = forward.dc_rate * self.width             # background counts per bin per shot
        self.censored = np.zeros(self.x.shape, bool)      # nothing clips
        self.arrival = None
        self.amplitude = None
        self.log_factorial = float(np.sum(gammaln(self.c + 1.0)))

    def start(self, mu: np.ndarray) -> None:
        """Nothing to start: every fit scans its arrivals afresh."""

    def _lambda(self, mu: np.ndarray, deltas: np.ndarray) -> np.ndarray:
        """λ_k(δ) (counts per bin per shot at amplitude 1) for each arrival: shape (D, K)."""
        step = self.f.step
        edges = np.concatenate([self.f.t - 0.5 * step, [self.f.t[-1] + 0.5 * step]])
        cum = np.concatenate([[0.0], np.cumsum(mu) * step])
        lo = np.interp(self.t[None, :] - deltas[:, None], edges, cum)
        hi = np.interp(self.t[None, :] + self.width - deltas[:, None], edges, cum)
        return hi - lo

    def _profile(self, lam: np.ndarray, overall) -> tuple[np.ndarray, np.ndarray]:
        """(log L, A) at each arrival (rows of ``lam``), A profiled unless ``overall``."""
        n, c, b = self.n, self.c, self.b
        total = lam.sum(axis=1)
        if overall is not None:
            a = np.full(lam.shape[0], float(overall))
        else:
            a = np.maximum((c.sum() - n * b * c.size) / np.maximum(n * total, 1e-300), 1e-6)
            for _ in range(NEWTON):
                ratio = lam / np.maximum(a[:, None] * lam + b, 1e-300)
                g = (c * ratio).sum(1) - n * total
                h = (c * ratio * ratio).sum(1)
                a = np.maximum(a + g / np.maximum(h, 1e-300), 0.5 * a)
        m = n * (a[:, None] * lam + b)
        ll = (c * np.log(np.maximum(m, 1e-300))).sum(1) - m.sum(1) - self.log_factorial
        return ll, a

    def fit(self, mu: np.ndarray, nu=None, overall: float | None = None) -> ShotFit:
        """The log-likelihood of the module docstring at model rate ``mu`` (pe per ns on the
        fine grid), with the best arrival and amplitude."""
        sigma = np.hypot(sigma_from_fwhm(self.f.fwhm), self.f.geo.sigma_g)  # nominal σ, ns
        step = COARSE_FRACTION * max(sigma, self.width)
        centre = (self.t[np.argmax(self.c)] + 0.5 * self.width) - self.f.t[np.argmax(mu)]
        coarse = centre + np.arange(-SCAN_NS, SCAN_NS + 1e-9, step)
        ll, _ = self._profile(self._lambda(mu, coarse), overall)
        (lo,), (hi,) = kept_span(coarse, ll[None, :], KEEP)
        fine = np.linspace(lo, hi, FINE_POINTS)
        ll, a = self._profile(self._lambda(mu, fine), overall)
        top = int(np.argmax(ll))
        loglike = float(log_trapezoid(ll, fine[1] - fine[0]))
        chi2, groups = pearson(self.c, self.n * self.expected(mu, a[top], fine[top]))
        self.arrival, self.amplitude = float(fine[top]), float(a[top])
        return ShotFit(np.full(self.n, a[top]), np.full(self.n, fine[top]), loglike,
                       float(a[top]), chi2, groups, 0)

    def error_blocks(self, fit, mu: np.ndarray, variance: np.ndarray, block_ns: float) -> tuple:
        """The database's common error per block of model time, for
        :func:`~.emulator.integrate_blocks`. With e_b the error of the rate in block b (pe
        ns⁻¹ at amplitude 1, common to its bins: the error is correlated over the kernel's
        length, many 0.1 ns bins), bin k's summed counts move by N A Δ e_b; the Poisson log L,
        quadratic around the fit, has per bin G_k = N A Δ (c_k − M_k)/M_k and W_k =
        (N A Δ)²/M_k (M_k = N m_k), summed over the block's bins, and S_b the W-weighted mean
        of S over them, as for linear-mode samples (docs/inversion.md §4.3).

        Parameters
        ----------
        fit : ShotFit
            The common amplitude A and arrival δ of the fit.
        mu, variance : array
            The rate (pe ns⁻¹) and S(t) ((pe ns⁻¹)²) on the forward grid, amplitude 1.
        block_ns : float
            The blocks' length, ns (at least one bin).

        Returns
        -------
        (w, g, s, base)
            Per block: W, G, S and the directions A and δ absorb (the rate and its time
            derivative, per ns).
        """
        a, d = float(fit.overall), float(fit.arrival[0])
        lam, s, slope = (self._lambda(x, np.array([d]))[0] / self.width
                         for x in (mu, variance, np.gradient(mu, self.f.t)))
        expect = self.n * (a * lam * self.width + self.b)
        scale = self.n * a * self.width
        # the quadratic form holds where the error of a bin's expected counts (sd scale √S)
        # is below the counts themselves; where it is not (a bin expecting almost nothing that
        # the database is unsure of) the mean cannot go below 0 and the Gaussian integral
        # would charge log(1 + scale² S / M) for it: such bins are left out
        kept = (expect > ERROR_MIN_COUNTS) & (scale ** 2 * s <= expect ** 2)
        w = np.where(kept, scale ** 2 / np.maximum(expect, 1e-300), 0.0)
        g = np.where(kept, scale * (self.c - expect) / np.maximum(expect, 1e-300), 0.0)
        block = np.floor((self.t - d - self.f.t[0]) / max(block_ns, self.width)).astype(np.intp)
        block -= block.min()
        w_b = np.bincount(block, w)
        used = w_b > 0
        w_b = w_b[used]

        def mean(x):
            return np.bincount(block, w * x)[used] / w_b
        return (w_b, np.bincount(block, g)[used], mean(s),
                np.stack([mean(lam), mean(slope)], axis=1))

    def expected(self, mu: np.ndarray, amplitude: float, arrival: float) -> np.ndarray:
        """Expected counts per bin per shot at ``amplitude`` and ``arrival``."""
        return amplitude * self._lambda(mu, np.array([arrival]))[0] + self.b


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
