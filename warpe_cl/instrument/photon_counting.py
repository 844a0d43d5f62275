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
    s = np.asarray(signal_rate, float)
    width = np.diff(edges)
    centre = 0.5 * (edges[:-1] + edges[1:])
    cumulative = np.concatenate([[0.0], np.cumsum(s * width)])
    window = (np.interp(centre, edges, cumulative)
              - np.interp(centre - analog_dead, edges, cumulative, left=0.0))
    x = window / channels
    if math.isfinite(modes):
        base = 1.0 + x / modes
        with_signal, without = base ** -(modes + 1.0), base ** -modes
    else:
        with_signal = without = np.exp(-x)
    # no arrival before the grid starts: a dead window reaching before it sees less dark
    dark_seen = dark_rate * np.minimum(analog_dead, centre - edges[0])
    rate = np.exp(-dark_seen / channels) * (s * with_signal + dark_rate * without)
    bins = np.asarray(bins_ns, float)
    exact = bool(digital_dead <= 2.0 * analog_dead)
    if jitter <= 0.0:
        return rebin_density(edges, rate, bins), exact
    amount = rate * width
    total = np.concatenate([[0.0], np.cumsum(amount)])
    # the recorded amount below each edge b: the fine bins wholly below b − 8σ_j, then
    # those within reach, each by P(u + J < b) for u uniform over [a, a + h]:
    # (σ/h)[ψ(z) − ψ(z − h/σ)], z = (b − a)/σ, ψ(z) = z Φ(z) + φ(z)
    reach = 8.0 * jitter
    first = np.clip(np.searchsorted(edges, bins - reach, side="right") - 1, 0, s.size)
    last = np.clip(np.searchsorted(edges, bins + reach, side="left"), 0, s.size)
    k = first[:, None] + np.arange(max(int(np.max(last - first, initial=0)), 1))[None, :]
    inside = k < last[:, None]
    k = np.minimum(k, s.size - 1)
    h = width[k]
    z = (bins[:, None] - edges[k]) / jitter
    part = jitter / h * (_psi(z) - _psi(z - h / jitter))
    below = total[first] + np.sum(np.where(inside, part * amount[k], 0.0), axis=1)
    return np.diff(below), exact


def _psi(z: np.ndarray) -> np.ndarray:
    """z Φ(z) + φ(z): the integral of the normal CDF Φ up to z."""
    phi_cdf = 0.5 * _ERFC(-z / math.sqrt(2.0)).astype(float)
    return z * phi_cdf + np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
