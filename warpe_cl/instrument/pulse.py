"""Transmitted pulse p(t), docs/instrument.md §3.1.

p(t) = exp(−t²/2σ_l²)/(√(2π) σ_l) with σ_l = FWHM/(2√(2 ln 2)) and ∫p dt = 1 (ns⁻¹), or a
tabulated profile (CSV with columns ``time_ns``, ``power``) whose time origin is put at its
centroid, so that a symmetric or asymmetric pulse ranges on the same reference [A].
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from .grid import rebin_density

FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))   # 2.3548


def sigma_from_fwhm(fwhm: float) -> float:
    """σ of a Gaussian of full width at half maximum ``fwhm`` (same unit)."""
    return fwhm / FWHM_PER_SIGMA


def gaussian_kernel(sigma: float, step: float, half_width: float = 7.0) -> tuple[np.ndarray, int]:
    """A unit-area Gaussian of rms width ``sigma`` (ns) on a grid of ``step`` (ns).

    Each value is the integral of the Gaussian over its bin (differences of erf), so the kernel
    sums to 1 to within 1e-11 and a zero width gives the unit impulse.

    Returns
    -------
    (kernel, origin)
        Amount per bin (dimensionless, Σ = 1) and the index of t = 0.
    """
    if sigma <= 0.0:
        return np.array([1.0]), 0
    n = int(math.ceil(half_width * sigma / step))
    edges = (np.arange(-n, n + 2) - 0.5) * step
    from scipy.special import erf      # scipy on use: a run's start does not pay for it
    cdf = 0.5 * (1.0 + erf(edges / (math.sqrt(2.0) * sigma)))
    kernel = np.diff(cdf)
    return kernel / kernel.sum(), n


def tabulated_kernel(path: str, step: float) -> tuple[np.ndarray, int]:
    """A measured pulse profile rebinned to ``step`` (ns), unit area, origin at its centroid."""
    try:
        table = np.genfromtxt(path, delimiter=",", names=True)
        t = np.asarray(table["time_ns"], float)
        power = np.asarray(table["power"], float)
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ConfigError(f"cannot read the pulse table ({type(err).__name__}); give a CSV file "
                          "with columns time_ns, power", key="instrument.transmitter.pulse_shape",
                          source=str(path)) from None
    if t.size < 2 or np.any(np.diff(t) <= 0) or np.any(power < 0) or power.sum() <= 0:
        raise ConfigError("the pulse table needs increasing times and powers >= 0, not all zero",
                          key="instrument.transmitter.pulse_shape", source=str(path))
    # each sample stands for the cell between the midpoints to its neighbours
    mids = np.concatenate([[t[0]], 0.5 * (t[1:] + t[:-1]), [t[-1]]])
    area = power * np.diff(mids)
    centroid = float(np.sum(area * t) / area.sum())
    n_lo = int(math.ceil((centroid - t[0]) / step)) + 1
    n_hi = int(math.ceil((t[-1] - centroid) / step)) + 1
    edges = centroid + (np.arange(-n_lo, n_hi + 1) - 0.5) * step
    kernel = rebin_density(mids, power, edges)
    return kernel / kernel.sum(), n_lo


def pulse_kernel(params, step: float, fwhm: float | None = None) -> tuple[np.ndarray, int]:
    """The transmitted pulse of ``params`` on the fine grid: (amount per bin, origin index)."""
    shape = params["transmitter.pulse_shape"]
    if shape == "gaussian":
        width = params["transmitter.pulse_fwhm"] if fwhm is None else fwhm
        return gaussian_kernel(sigma_from_fwhm(width), step)
    path = Path(shape)
    if not path.is_absolute() and not path.is_file():   # relative to the instrument preset
        path = Path(getattr(params, "source", ".")).parent / shape
    return tabulated_kernel(str(path), step)
