"""The fine time grid of the chain and energy-conserving operations on it.

Every stage works on one uniform grid of step δt (ns) covering the recorded window plus a margin
on both sides, so that convolutions near the window edges see the signal (and the stationary
noise and DC levels) outside it. Arrays on the grid hold either a rate (per ns, sampled at bin
centres) or an amount per bin; the docstrings say which.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FineGrid:
    """A uniform grid: bin ``i`` covers ``[start + i δt, start + (i + 1) δt)`` (ns).

    ``crop`` selects the bins of the recorded window.
    """
    start: float
    step: float
    size: int
    crop: slice

    @property
    def edges(self) -> np.ndarray:
        return self.start + self.step * np.arange(self.size + 1)

    @property
    def centres(self) -> np.ndarray:
        return self.start + self.step * (np.arange(self.size) + 0.5)


def make_grid(window_start: float, window_stop: float, step: float, margin: float) -> FineGrid:
    """A grid covering ``[window_start - margin, window_stop + margin]`` (ns), with the window
    bins aligned on the grid."""
    n_before = int(np.ceil(margin / step))
    n_window = int(np.ceil((window_stop - window_start) / step))
    start = window_start - n_before * step
    return FineGrid(start, step, n_before + n_window + n_before, slice(n_before, n_before + n_window))


def rebin_density(edges_in: np.ndarray, density: np.ndarray, edges_out: np.ndarray) -> np.ndarray:
    """Integral of a piecewise-constant density over each output bin.

    Parameters
    ----------
    edges_in : array (n + 1,)
        Edges of the input bins (any spacing, e.g. the log bins of a surface result), ns.
    density : array (n,)
        Value per ns in each input bin (e.g. sr⁻¹ ns⁻¹).
    edges_out : array (m + 1,)
        Output edges, ns.

    Returns
    -------
    array (m,)
        ∫ density dt over each output bin (e.g. sr⁻¹). The total over output bins covering the
        input range equals Σ density·Δt exactly (up to rounding): energy is conserved.
    """
    cumulative = np.concatenate([[0.0], np.cumsum(density * np.diff(edges_in))])
    at_out = np.interp(edges_out, edges_in, cumulative, left=0.0, right=cumulative[-1])
    return np.diff(at_out)


def deposit(grid: FineGrid, times: np.ndarray, amounts: np.ndarray) -> np.ndarray:
    """Amounts placed at exact times, split linearly between the two nearest bin centres
    (conserves the total and the first moment). Times outside the grid are dropped."""
    out = np.zeros(grid.size)
    x = (np.asarray(times, float) - grid.start) / grid.step - 0.5
    lo = np.floor(x).astype(int)
    w_hi = x - lo
    for i, w, a in zip(lo, w_hi, np.asarray(amounts, float)):
        if 0 <= i < grid.size:
            out[i] += a * (1.0 - w)
        if 0 <= i + 1 < grid.size:
            out[i + 1] += a * w
    return out


def convolve(signal: np.ndarray, kernel: np.ndarray, origin: int) -> np.ndarray:
    """Discrete convolution ``Σ_j signal[i - j + origin] kernel[j]``, same length as ``signal``.

    ``kernel[origin]`` is the kernel at lag 0 (its time origin). With ``Σ kernel = 1`` the
    total of ``signal`` is kept, apart from what is pushed past the ends of the grid.
    """
    from scipy.signal import fftconvolve
    full = fftconvolve(signal, kernel, mode="full")
    return full[origin: origin + signal.size]
