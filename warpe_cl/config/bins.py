"""Time-bin edges of ``simulation.time_bins``: log-spaced or linear."""
from __future__ import annotations

import math

import numpy as np

__all__ = ["edges", "bin_count", "time_edges"]


def bin_count(bins: dict) -> int:
    """How many bins the canonical ``simulation.time_bins`` mapping ``bins`` makes."""
    if "width" in bins:
        return math.ceil((bins["stop"] - bins["start"]) / bins["width"] - 1e-9)
    return math.ceil(bins["per_decade"] * math.log10(bins["stop"] / bins["start"]) - 1e-9)


def edges(bins: dict) -> np.ndarray:
    """The edges (ns) of the canonical ``simulation.time_bins`` mapping ``bins``."""
    count = bin_count(bins)
    if "width" in bins:
        return bins["start"] + bins["width"] * np.arange(0, count + 1, dtype=float)
    return bins["start"] * 10.0 ** (np.arange(0, count + 1, dtype=float) / bins["per_decade"])


def time_edges(cfg) -> np.ndarray:
    """Time-bin edges of a configuration, ns.

    Parameters
    ----------
    cfg : Config or dict
        A configuration, or its canonical ``simulation.time_bins`` mapping.

    Returns
    -------
    numpy.ndarray of float64
        Increasing edges, ns. Log-spaced bins: ``start * 10**(i / per_decade)`` for
        ``i = 0 .. n`` with ``n = ceil(per_decade * log10(stop / start))``; linear bins:
        ``start + width * i`` for ``i = 0 .. ceil((stop - start) / width)``. The last edge
        is at or just after ``stop``.

    Examples
    --------
    >>> edges = time_edges({"start": 1.0, "stop": 100.0, "per_decade": 2})
    >>> edges.round(3).tolist()
    [1.0, 3.162, 10.0, 31.623, 100.0]
    """
    bins = cfg.data["simulation"]["time_bins"] if hasattr(cfg, "data") else cfg
    return edges(bins)
