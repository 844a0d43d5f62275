"""Per-shot detection, range and width: a matched-filter stand-in for BELA's unknown onboard
algorithm [A], docs/instrument.md §3.8.

The sampled waveform minus its known baseline is correlated with the expected pulse template
(p ⊗ g ⊗ h_e, sampled at the shot's phase, unit norm); a shot is detected when the correlation
peak exceeds m σ_n, σ_n being the per-sample noise (electronic, background and dark shot noise,
quantisation). The range is the correlation peak refined by a parabola through its neighbours,
minus the template's own peak time; the width is the rms width of the baseline-subtracted
samples within ±3 template widths of it.

Closed forms reported alongside: false-alarm probability per range gate N_gate ½erfc(m/√2) and
P_D = ½erfc((V_th − V_peak)/(√2 σ_n)).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import erfc

from .radiometry import ELEMENTARY_CHARGE


def sample_noise_sigma(sigma_electronic_v: float, dc_rate_per_ns: float, gain: float,
                       excess: float, transimpedance: float, bandwidth_hz: float,
                       lsb_v: float) -> float:
    """Per-sample noise σ_n, V: electronic σ_v, shot noise of a steady primary rate λ
    (σ² = G_T² · 2 q² λ M² F · B_eq) and quantisation LSB²/12."""
    shot = transimpedance ** 2 * 2.0 * ELEMENTARY_CHARGE ** 2 * dc_rate_per_ns * 1e9 \
        * gain ** 2 * excess * bandwidth_hz
    return math.sqrt(sigma_electronic_v ** 2 + shot + lsb_v ** 2 / 12.0)


def false_alarm_probability(n_gate: int, m: float) -> float:
    """N_gate ½erfc(m/√2) (capped at 1)."""
    return min(1.0, n_gate * 0.5 * erfc(m / math.sqrt(2.0)))


def detection_probability(threshold: float, peak: float, sigma: float) -> float:
    """½erfc((V_th − V_peak)/(√2 σ))."""
    return 0.5 * erfc((threshold - peak) / (math.sqrt(2.0) * sigma))


def matched_filter(samples: np.ndarray, template: np.ndarray) -> np.ndarray:
    """y_k = Σ_j s_{k+j−c} w_j with w of unit norm, c its centre index (same length as s)."""
    w = template / np.linalg.norm(template)
    c = len(w) // 2
    padded = np.concatenate([np.zeros(c), samples, np.zeros(len(w) - 1 - c)])
    return np.correlate(padded, w, mode="valid")


def estimate(times: np.ndarray, samples: np.ndarray, template: np.ndarray, template_peak: float,
             threshold: float, width_hint: float) -> tuple[bool, float, float, float]:
    """Detection, arrival time (ns), rms width (ns) and peak value of one baseline-subtracted
    sampled waveform.

    Parameters
    ----------
    times : array
        Sample times of this shot, ns (uniform spacing).
    samples : array
        Samples minus the baseline, V (or mV: ``threshold`` in the same unit).
    template : array
        Expected pulse sampled on the same spacing, centred on its middle element.
    template_peak : float
        Time of the template's middle element relative to the arrival it represents, ns.
    threshold : float
        m σ_n in the unit of the samples × unit-norm template.
    width_hint : float
        rms width of the template, ns (sets the width window).
    """
    y = matched_filter(samples, template)
    k = int(np.argmax(y))
    detected = bool(y[k] > threshold)
    step = times[1] - times[0] if len(times) > 1 else 1.0
    shift = 0.0
    if 0 < k < len(y) - 1:
        denom = y[k - 1] - 2.0 * y[k] + y[k + 1]
        if denom < 0:
            shift = 0.5 * (y[k - 1] - y[k + 1]) / denom
    arrival = times[k] + shift * step - template_peak
    near = np.abs(times - (times[k] + shift * step)) <= 3.0 * width_hint + step
    w = np.clip(samples[near], 0.0, None)
    if w.sum() > 0:
        mean = np.sum(w * times[near]) / w.sum()
        width = math.sqrt(max(np.sum(w * (times[near] - mean) ** 2) / w.sum(), 0.0))
    else:
        width = math.nan
    if not detected:
        return False, math.nan, math.nan, float(samples.max())
    return True, float(arrival), float(width), float(samples.max())
