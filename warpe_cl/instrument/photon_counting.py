"""Photon-counting branch (ATLAS), docs/instrument.md §3.9.

Arrivals are a Poisson process of rate n_pe(t) (signal, background, dark) over the window; each
photoelectron goes to one of N_ch detector channels at random. Per channel, a paralyzable
analog dead time τ_a removes any arrival within τ_a of the previous arrival (recorded or not);
the survivors are handed in turn to two alternating timing channels, each with a
non-paralyzable digital dead time τ_d: an event is lost when the timing channel next in line
is still busy, and the alternation then does not advance [A: our reading of the structure of
A. S. Gardner's ``deadtime2_fast.m``]. Recorded times get Gaussian jitter σ_j.
"""
from __future__ import annotations

import math

import numpy as np

from .grid import rebin_density

#: math.erfc over arrays (exact to double precision; the chain of a run or a sweep worker
#: does not import scipy, tests/test_cli.py)
_ERFC = np.frompyfunc(math.erfc, 1, 1)


def arrivals(rng: np.random.Generator, edges_ns: np.ndarray, rate_per_ns: np.ndarray) -> np.ndarray:
    """Sorted arrival times (ns) of a Poisson process with a piecewise-constant rate."""
    counts = rng.poisson(np.asarray(rate_per_ns, float) * np.diff(edges_ns))
    lo = np.repeat(edges_ns[:-1], counts)
    width = np.repeat(np.diff(edges_ns), counts)
    return np.sort(lo + width * rng.random(lo.size))


def paralyzable(times: np.ndarray, dead: float) -> np.ndarray:
    """Mask of the arrivals a paralyzable detector records: the gap to the previous arrival,
    recorded or not, is at least ``dead`` (recorded rate r e^{−rτ} for a Poisson input)."""
    if times.size == 0 or dead <= 0.0:
        return np.ones(times.size, bool)
    keep = np.empty(times.size, bool)
    keep[0] = True
    keep[1:] = np.diff(times) >= dead
    return keep


def alternating_nonparalyzable(times: np.ndarray, dead: float) -> np.ndarray:
    """Mask of the events two alternating non-paralyzable timing channels record."""
    keep = np.zeros(times.size, bool)
    if dead <= 0.0:
        keep[:] = True
        return keep
    free_at = [-np.inf, -np.inf]
    turn = 0
    for i, t in enumerate(times):
        if t >= free_at[turn]:
            keep[i] = True
            free_at[turn] = t + dead
            turn = 1 - turn
    return keep


def record(rng: np.random.Generator, times: np.ndarray, channels: int, analog_dead: float,
           digital_dead: float, jitter: float) -> np.ndarray:
    """Recorded time tags (sorted, ns) of one shot's arrivals."""
    channel = rng.integers(0, channels, times.size)
    kept = []
    for c in range(channels):
        t = times[channel == c]
        t = t[paralyzable(t, analog_dead)]
        kept.append(t[alternating_nonparalyzable(t, digital_dead)])
    out = np.sort(np.concatenate(kept)) if kept else np.zeros(0)
    if jitter > 0.0 and out.size:
        out = out + rng.normal(0.0, jitter, out.size)
    return out


def expected_recorded(edges_ns: np.ndarray, signal_rate: np.ndarray, dark_rate: float,
                      bins_ns: np.ndarray, channels: int, analog_dead: float,
                      digital_dead: float, jitter: float, modes: float) -> tuple:
    """Expected recorded photons per histogram bin per shot, after the dead times and the
    timing jitter, averaged over the shots' speckle (docs/instrument.md §3.9).

    Per channel the arrivals are Poisson of rate μ(t) = (S s(t) + d) / N_ch for a shot of
    speckle factor S; an arrival at t passes the paralyzable analog dead time τ_a when none
    came in (t − τ_a, t), with probability exp(−∫ μ over it). Passed events are at least τ_a
    apart, so the two alternating timing channels, each busy τ_d after an event, lose one only
    when the last but one event passed lies within τ_d: never when τ_d ≤ 2 τ_a. The recorded
    rate of all channels is then (S s + d) exp(−(S Σ(t) + d τ_a) / N_ch), Σ(t) = ∫ s over
    (t − τ_a, t), and over S ~ Gamma(M, 1/M) (E[e^{−S x}] = (1 + x/M)^{−M}, E[S e^{−S x}] =
    (1 + x/M)^{−(M+1)}; e^{−x} for M infinite):

        R(t) = e^{−d τ_a / N_ch} [s(t) (1 + x/M)^{−(M+1)} + d (1 + x/M)^{−M}],  x = Σ(t)/N_ch.

    (within τ_a of the grid's start, where no arrival precedes it, d τ_a becomes d (t − t₀)).
    R is taken on the fine grid (its value at each bin's centre), each fine bin spread
    uniformly over its width and by the Gaussian jitter σ_j, and integrated over ``bins_ns``.

    Parameters
    ----------
    edges_ns : array (n + 1,)
        Edges of the fine grid, ns (uniform or not).
    signal_rate : array (n,)
        Signal photoelectrons per ns in each fine bin, speckle factor 1.
    dark_rate : float
        Background and dark photoelectrons per ns.
    bins_ns : array (m + 1,)
        Edges of the histogram bins, ns.
    channels : int
        Detector channels N_ch.
    analog_dead, digital_dead : float
        Dead times τ_a (paralyzable, per channel) and τ_d (each of two alternating timing
        channels), ns.
    jitter : float
        Timing jitter σ_j, ns.
    modes : float
        Speckle modes M (``inf``: no speckle).

    Returns
    -------
    (array (m,), bool)
        The expected photons per bin per shot, and whether it is exact: False where
        τ_d > 2 τ_a, whose timing-channel losses it leaves out (it is then an upper bound).
    """
    edges = np.asarray(edges_ns, float)
    rate = DeadTime(edges, dark_rate, channels, analog_dead, modes,
                    steady=False).rate(np.asarray(signal_rate, float))
    return jittered_bins(edges, rate, bins_ns, jitter), bool(digital_dead <= 2.0 * analog_dead)


class DeadTime:
    """The rate a photon-counting receiver's channels pass, before the jitter
    (:func:`expected_recorded`), as a function of the signal rate u(t) (pe ns⁻¹) on a fine
    grid, with its first two derivatives along a direction w (pe ns⁻¹):

        R(u) = E_d [u F₁(X) + d F₀(X)],   X = W(u) / N_ch,   W(u)(t) = ∫ u over (t − τ_a, t),
        DR[u]·w = E_d [w F₁(X) + (u F₁′(X) + d F₀′(X)) W(w) / N_ch],
        D²R[u](w, w) = E_d [2 w F₁′(X) W(w) / N_ch + (u F₁″(X) + d F₀″(X)) (W(w) / N_ch)²],

    with F_k(x) = (1 + x/M)^{−(M+k)} (e^{−x} for M infinite) and E_d = e^{−d τ_a / N_ch}. The
    amplitude A of a rate A s enters as u = A s: ∂R/∂A = DR[A s]·s, ∂²R/∂A² = D²R[A s](s, s).

    Parameters
    ----------
    edges : array (n + 1,)
        Edges of the fine grid, ns.
    dark_rate : float
        Background and dark photoelectrons per ns.
    channels : int
        Detector channels N_ch.
    analog_dead : float
        Paralyzable dead time τ_a per channel, ns (0: none, R(u) = u + d).
    modes : float
        Speckle modes M (``inf``: no speckle).
    steady : bool
        Dark counts from long before the grid (E_d everywhere), as for an arrival the
        likelihood shifts; False: none before the grid's start, E_d = e^{−d min(τ_a, t − t₀)
        / N_ch}, as the chain draws them.
    """

    def __init__(self, edges, dark_rate: float, channels: int, analog_dead: float,
                 modes: float, steady: bool = True):
        self.edges = np.asarray(edges, float)
        self.width = np.diff(self.edges)
        self.centre = 0.5 * (self.edges[:-1] + self.edges[1:])
        self.dark, self.channels, self.tau, self.modes = (float(dark_rate), int(channels),
                                                          float(analog_dead), float(modes))
        seen = self.dark * (self.tau if steady
                            else np.minimum(self.tau, self.centre - self.edges[0]))
        self.e_d = np.exp(-seen / self.channels)
        #: The passed rate far from any signal (pe ns⁻¹), where steady.
        self.dark_level = float(np.exp(-self.dark * self.tau / self.channels) * self.dark)

    @property
    def active(self) -> bool:
        """Whether any arrival is lost (τ_a > 0)."""
        return self.tau > 0.0

    def window(self, w: np.ndarray) -> np.ndarray:
        """W(w) / N_ch at the fine bins' centres (w piecewise constant)."""
        cumulative = np.concatenate([[0.0], np.cumsum(w * self.width)])
        window = (np.interp(self.centre, self.edges, cumulative)
                  - np.interp(self.centre - self.tau, self.edges, cumulative, left=0.0))
        return window / self.channels

    def _factors(self, x: np.ndarray, order: int) -> tuple:
        """(F₁, F₀) at x, or their ``order``-th derivatives."""
        m = self.modes
        if not math.isfinite(m):
            f = np.exp(-x) * (-1.0) ** order
            return f, f
        base = 1.0 + x / m
        coefficient = {0: (1.0, 1.0), 1: (-(m + 1.0) / m, -1.0),
                       2: ((m + 1.0) * (m + 2.0) / m ** 2, (m + 1.0) / m)}[order]
        return (coefficient[0] * base ** -(m + 1.0 + order),
                coefficient[1] * base ** -(m + order))

    def rate(self, u: np.ndarray) -> np.ndarray:
        """R(u), pe ns⁻¹ on the fine grid."""
        return self.expansion(u, order=0)[0]

    def along(self, u: np.ndarray, w: np.ndarray) -> np.ndarray:
        """DR[u]·w, pe ns⁻¹."""
        return self.derivative(u)(w)

    def derivative(self, u: np.ndarray):
        """DR[u] as a function of the direction w (pe ns⁻¹ -> pe ns⁻¹): the window of u and
        its factors taken once for any number of directions (the terms and order of
        :meth:`expansion`'s first derivative, the same bits)."""
        x = self.window(u)
        f1, _ = self._factors(x, 0)
        d1, d0 = self._factors(x, 1)
        slope = u * d1 + self.dark * d0

        def along(w: np.ndarray) -> np.ndarray:
            return self.e_d * (w * f1 + slope * self.window(w))
        return along

    def bend(self, u: np.ndarray, w: np.ndarray) -> np.ndarray:
        """D²R[u](w, w), pe ns⁻¹."""
        return self.expansion(u, w)[2]

    def expansion(self, u: np.ndarray, w: np.ndarray | None = None, order: int = 2) -> tuple:
        """(R(u), DR[u]·w, D²R[u](w, w)) up to ``order`` (0, 1 or 2), pe ns⁻¹, the windows
        and factors taken once (the class docstring's formulas)."""
        x = self.window(u)
        f1, f0 = self._factors(x, 0)
        out = [self.e_d * (u * f1 + self.dark * f0)]
        if order >= 1:
            ww = self.window(w)
            d1, d0 = self._factors(x, 1)
            out.append(self.e_d * (w * f1 + (u * d1 + self.dark * d0) * ww))
        if order >= 2:
            b1, b0 = self._factors(x, 2)
            out.append(self.e_d * (2.0 * w * d1 * ww + (u * b1 + self.dark * b0) * ww * ww))
        return tuple(out)


def jittered_bins(edges_ns: np.ndarray, rate: np.ndarray, bins_ns: np.ndarray,
                  jitter: float) -> np.ndarray:
    """A rate (per ns, piecewise constant on the fine grid ``edges_ns``) spread by a Gaussian
    timing jitter σ_j (ns) and integrated over the histogram bins ``bins_ns``: each fine bin
    uniform over its width, convolved exactly with the Gaussian."""
    edges = np.asarray(edges_ns, float)
    rate = np.asarray(rate, float)
    width = np.diff(edges)
    bins = np.asarray(bins_ns, float)
    if jitter <= 0.0:
        return rebin_density(edges, rate, bins)
    amount = rate * width
    total = np.concatenate([[0.0], np.cumsum(amount)])
    # the recorded amount below each edge b: the fine bins wholly below b − 8σ_j, then
    # those within reach, each by P(u + J < b) for u uniform over [a, a + h]:
    # (σ/h)[ψ(z) − ψ(z − h/σ)], z = (b − a)/σ, ψ(z) = z Φ(z) + φ(z)
    reach = 8.0 * jitter
    first = np.clip(np.searchsorted(edges, bins - reach, side="right") - 1, 0, rate.size)
    last = np.clip(np.searchsorted(edges, bins + reach, side="left"), 0, rate.size)
    k = first[:, None] + np.arange(max(int(np.max(last - first, initial=0)), 1))[None, :]
    inside = k < last[:, None]
    k = np.minimum(k, rate.size - 1)
    h = width[k]
    z = (bins[:, None] - edges[k]) / jitter
    part = jitter / h * (_psi(z) - _psi(z - h / jitter))
    below = total[first] + np.sum(np.where(inside, part * amount[k], 0.0), axis=1)
    return np.diff(below)


def _psi(z: np.ndarray) -> np.ndarray:
    """z Φ(z) + φ(z): the integral of the normal CDF Φ up to z."""
    phi_cdf = 0.5 * _ERFC(-z / math.sqrt(2.0)).astype(float)
    return z * phi_cdf + np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
