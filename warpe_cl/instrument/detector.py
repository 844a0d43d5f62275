"""Linear-mode APD, docs/instrument.md §3.6.

Photoelectrons per fine bin k ~ Poisson(λ δt), λ = S (n_s + n_spec) + n_b + I_db/q (pe ns⁻¹).
The summed avalanche gain of k electrons is drawn from a Gamma distribution of mean k M and
variance k M² (F − 1) [A: moment-matched stand-in for McIntyre's distribution], with
F = k_eff M + (1 − k_eff)(2 − 1/M). The current is i = q Σgain / δt + I_ds.
"""
from __future__ import annotations

import numpy as np

from .radiometry import ELEMENTARY_CHARGE


def excess_noise_factor(gain: float, k_eff: float) -> float:
    """McIntyre's F = k M + (1 − k)(2 − 1/M): 3.95 for M = 100, k = 0.02."""
    return k_eff * gain + (1.0 - k_eff) * (2.0 - 1.0 / gain)


def dark_rate(bulk_dark_current: float) -> float:
    """Primary dark electrons per ns, I_db / q."""
    return bulk_dark_current / ELEMENTARY_CHARGE * 1e-9


def photoelectrons(rng: np.random.Generator, rate_per_ns: np.ndarray, step_ns: float) -> np.ndarray:
    """Poisson photoelectron counts per bin of width ``step_ns`` for rates in pe ns⁻¹."""
    return rng.poisson(np.asarray(rate_per_ns, float) * step_ns)


def avalanche(rng: np.random.Generator, counts: np.ndarray, gain: float, excess: float) -> np.ndarray:
    """Summed gain of ``counts`` primary electrons per bin: Gamma(k/(F−1), M(F−1)), i.e.
    mean k M and variance k M²(F − 1); k M exactly when F = 1."""
    counts = np.asarray(counts)
    if excess <= 1.0:
        return counts * float(gain)
    out = np.zeros(counts.shape)
    hit = counts > 0
    out[hit] = rng.gamma(counts[hit] / (excess - 1.0), gain * (excess - 1.0))
    return out


def current(electrons: np.ndarray, step_ns: float, surface_dark_current: float) -> np.ndarray:
    """i = q Σgain / δt + I_ds, A."""
    return ELEMENTARY_CHARGE * np.asarray(electrons, float) / (step_ns * 1e-9) + surface_dark_current


def expected_current(rate_per_ns: np.ndarray, gain: float, surface_dark_current: float) -> np.ndarray:
    """E[i] = q M λ + I_ds, A, for primary rates λ in pe ns⁻¹."""
    return ELEMENTARY_CHARGE * gain * np.asarray(rate_per_ns, float) * 1e9 + surface_dark_current
