"""ADC: sampling with a random phase per shot, and quantisation, docs/instrument.md §3.7.5.

Samples are taken at t_k = t₀ + k Δt_s with t₀ = window start + φ, φ ~ U(0, Δt_s) per shot
(the return is not locked to the ADC clock), and quantised to N bits over 0 … full scale:
LSB = FS/(2^N − 1), code = clip(round(v/LSB), 0, 2^N − 1).
"""
from __future__ import annotations

import numpy as np


def sampling_phase(rng: np.random.Generator, interval_ns: float, random: bool = True) -> float:
    """φ ~ U(0, Δt_s), ns (0 when the phase is not random)."""
    return float(rng.uniform(0.0, interval_ns)) if random else 0.0


def sample_times(start_ns: float, stop_ns: float, interval_ns: float) -> np.ndarray:
    """Nominal sample times start + kΔt_s below stop, ns."""
    n = int(np.floor((stop_ns - start_ns) / interval_ns + 1e-9))
    return start_ns + interval_ns * np.arange(n)


def sample(times_fine: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Values at times ``at`` by linear interpolation on the fine grid (δt ≪ σ of the signal)."""
    return np.interp(at, times_fine, values)


def lsb(full_scale: float, bits: int) -> float:
    """Quantisation step FS/(2^N − 1) (so the top code is the full scale)."""
    return full_scale / (2 ** bits - 1)


def quantise(values: np.ndarray, full_scale: float, bits: int) -> np.ndarray:
    """Nearest ADC level in 0 … full scale (same unit as the input)."""
    step = lsb(full_scale, bits)
    codes = np.clip(np.rint(np.asarray(values, float) / step), 0, 2 ** bits - 1)
    return codes * step
