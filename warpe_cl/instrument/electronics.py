"""Analog electronics: filter, electronic noise, gain and saturation, docs/instrument.md §3.7.

v(t) = G_T [h_e ⊗ i](t) + v_n(t) with ∫h_e dt = 1. Gaussian filter: σ_h = 0.1325/f_3dB and
one-sided noise bandwidth B_eq = ½∫h_e² dt = 1/(4√π σ_h); option: a 4th-order Bessel low-pass
at f_3dB [A]. White input current noise of density i_n (A/√Hz) is added on the fine grid with
per-bin variance i_n²/(2δt) before the filter, so that σ_v = G_T i_n √B_eq after it.
"""
from __future__ import annotations

import math

import numpy as np

from .grid import convolve
from .pulse import gaussian_kernel

GAUSS_SIGMA_TIMES_F3DB = math.sqrt(math.log(2.0)) / (2.0 * math.pi)   # 0.1325


def gaussian_filter_sigma(f3db_hz: float) -> float:
    """σ_h (ns) of a Gaussian filter whose power response is halved at f_3dB:
    |H(f)|² = exp(−(2πfσ)²) = ½ ⇒ σ = √(ln 2)/(2π f) = 0.1325/f. 33 MHz → 4.0 ns."""
    return GAUSS_SIGMA_TIMES_F3DB / f3db_hz * 1e9


def filter_kernel(kind: str, f3db_hz: float, step_ns: float) -> tuple[np.ndarray, int]:
    """Impulse response h_e on the fine grid as amount per bin (Σ = 1) and origin index."""
    if kind == "gaussian":
        return gaussian_kernel(gaussian_filter_sigma(f3db_hz), step_ns)
    if kind == "bessel4":
        from scipy.signal import bessel, impulse
        b, a = bessel(4, 2.0 * math.pi * f3db_hz, btype="low", analog=True, norm="mag")
        length = 40.0 / f3db_hz * 1e9                     # ns: far past the ringing
        t = np.arange(0.0, length, step_ns) + 0.5 * step_ns
        _, h = impulse((b, a), T=t * 1e-9)
        h = np.clip(h, 0.0, None) if h.min() > -1e-6 * h.max() else h
        return h / h.sum(), 0
    raise ValueError(f"unknown filter {kind!r}")


def noise_bandwidth(kernel: np.ndarray, step_ns: float) -> float:
    """One-sided noise-equivalent bandwidth ½∫h_e² dt, Hz, of a kernel given per bin."""
    h = kernel / (step_ns * 1e-9)          # s⁻¹
    return 0.5 * float(np.sum(h ** 2)) * step_ns * 1e-9


def white_current_noise(rng: np.random.Generator, size: int, density: float,
                        step_ns: float) -> np.ndarray:
    """White current noise samples (A) of one-sided density ``density`` (A/√Hz) on bins of
    ``step_ns``: variance density²/(2δt)."""
    if density == 0.0:
        return np.zeros(size)
    return rng.normal(0.0, density / math.sqrt(2.0 * step_ns * 1e-9), size)


def amplify(current_a: np.ndarray, kernel: np.ndarray, origin: int, transimpedance: float) -> np.ndarray:
    """G_T [h_e ⊗ i], V."""
    return transimpedance * convolve(current_a, kernel, origin)


def saturate(volts: np.ndarray, v_sat: float) -> np.ndarray:
    """v ← min(v, V_sat) (hard clip, §3.7.4)."""
    return np.minimum(volts, v_sat)
