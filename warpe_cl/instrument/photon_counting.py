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

import numpy as np


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
