"""Speckle, docs/instrument.md §3.3: a per-shot multiplicative factor S ~ Gamma(shape M, mean 1) on
the surface signal [A, first-order model after Gardner 1982], so that the photoelectron count
is negative-binomial with variance N + N²/M."""
from __future__ import annotations

import math

import numpy as np


def speckle_factor(rng: np.random.Generator, modes: float) -> float:
    """One shot's factor: Gamma(M, 1/M) (mean 1, variance 1/M); exactly 1 when M is infinite."""
    if not math.isfinite(modes):
        return 1.0
    return float(rng.gamma(modes, 1.0 / modes))
