"""The noiseless instrument model of the inversion: a surface response -> the expected samples of
a linear-mode receiver and their variance, with the pulse width as a free nuisance
(docs/inversion.md §3).

The chain of docs/instrument.md §3 is linear in the surface response up to saturation, so the
expected analog voltage is

    v(t) = baseline + a · μ(t),    μ = G_T q M 10⁹ η [h_e ⊗ (p_v ⊗ g ⊗ n)] / δt   (mV)

with n the photons at the aperture per fine bin for the surface response (per_reflectance ×
R_d rebinned, plus the specular and back-and-forth returns times their aperture fractions κ),
p_v ⊗ g the pulse and footprint kernels with their variance changed by the nuisance ``v``
(ns²), and ``a`` the shot's amplitude (1 = the instrument's radiometry exactly; the fitted
overall amplitude times the shot's speckle factor). The photoelectron shot noise with APD excess
F gives the signal-dependent variance

    Var v(t) = σ_n² + a · ν(t),    ν = (G_T q M)² F η [h_e² ⊗ (p_v ⊗ g ⊗ n)] / δt² · 10⁶ (mV²)

(σ_n: electronic, background and dark noise and quantisation, as in §3.8). For a Gaussian pulse
p_v is the Gaussian of variance σ_p² + v (a different pulse width); for a tabulated pulse the
footprint's Gaussian gets the variance σ_g² + v (more or less footprint broadening). Both act
as a convolution with a Gaussian, so one nuisance covers the pulse width and the slope and
roughness broadening: a Gaussian-pulse waveform cannot tell them apart. At v = 0 the kernels are
the chain's own and v(t) is the chain's ``expected_analog_mv`` (tests/test_inversion.py).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import fft as sp_fft

from ..instrument import electronics, pulse, radiometry
from ..instrument.chain import (Geometry, aperture_photons, check_wavelength, receiver_levels,
                               steady_rate)
from ..instrument.grid import make_grid
from ..instrument.radiometry import ELEMENTARY_CHARGE

#: Default prior range of the pulse FWHM relative to the instrument's (Gaussian pulse).
PULSE_RANGE = (0.5, 1.5)
#: Default largest extra Gaussian broadening (footprint, slope, roughness), ns.
BROADENING_MAX_NS = 10.0


class Spectrum:
    """A 1-D signal and its real FFTs at the lengths asked, each taken once: a signal
    convolved with several kernels (one point's photons with the pulse at several widths, a
    waveform with the receiver's h and h²) reuses them. :meth:`convolve` gives the bits of
    ``scipy.signal.fftconvolve(a, b, mode="full")`` (the same real FFTs of ``scipy.fft`` at the
    same fast length; a length-1 operand a product, as there), without importing
    ``scipy.signal`` (0.7-1.0 s of every ``warpe-cl invert`` on 2 cores) or its checks of
    every call.

    Parameters
    ----------
    signal : array (N,)
    """

    def __init__(self, signal):
        self.signal = np.asarray(signal, float)
        self._spectra = {}

    def at(self, length: int) -> np.ndarray:
        """``scipy.fft.rfft(signal, length)``, kept."""
        if length not in self._spectra:
            self._spectra[length] = sp_fft.rfft(self.signal, length)
        return self._spectra[length]

    def convolve(self, other: "Spectrum") -> np.ndarray:
        """The full convolution with ``other``'s signal (``signal.size + other.size - 1``)."""
        a, b = self.signal, other.signal
        if a.size == 1 or b.size == 1:
            return a * b
        n = a.size + b.size - 1
        m = sp_fft.next_fast_len(n, True)
        return sp_fft.irfft(self.at(m) * other.at(m), m)[:n]


class Forward:
    """Expected samples and their variance for one linear-mode instrument.

    Parameters
    ----------
    params : InstrumentParams
        The instrument (:func:`warpe_cl.instrument.load_instrument`).
    pulse_range : (float, float)
        Prior range of the pulse FWHM relative to the instrument's (Gaussian pulse).
    broadening_max : float
        Largest extra Gaussian broadening σ, ns (footprint, slope, roughness).

    Attributes
    ----------
    v_bounds : (float, float)
        Range of the nuisance v, ns².
    sigma_n, baseline, ceiling : float
        Per-sample noise, baseline and clipped level (saturation or the top ADC code), mV
        (NaN for a photon-counting receiver).
    counting : bool
        A photon-counting receiver (time tags): :meth:`waveform` gives photoelectrons per ns.
    dc_rate : float
        Background and dark photoelectrons per ns.
    modes : float
        Speckle modes M (per-shot amplitude variance 1/M); inf without speckle.
    """

    def __init__(self, params, pulse_range=PULSE_RANGE, broadening_max=BROADENING_MAX_NS):
        p = self.params = params
        self.step = p["window.fine_step"]
        self.interval = p["adc.sampling_interval"]
        self.geo = Geometry(p)
        self.gaussian_pulse = p["transmitter.pulse_shape"] == "gaussian"
        self.sigma_p = pulse.sigma_from_fwhm(p["transmitter.pulse_fwhm"])
        self.fwhm = p["transmitter.pulse_fwhm"]
        if self.gaussian_pulse:
            lo = self.sigma_p ** 2 * (pulse_range[0] ** 2 - 1.0)
            hi = self.sigma_p ** 2 * (pulse_range[1] ** 2 - 1.0) + broadening_max ** 2
        else:
            lo, hi = -self.geo.sigma_g ** 2, broadening_max ** 2
        self.v_bounds = (lo, hi)
        self.counting = p["detector.type"] == "photon_counting"
        if self.counting:       # time tags: no receiver filter; the jitter comes after the
            self.h, self.h_origin = np.ones(1), 0        # dead time (:meth:`jitter`)
            jitter, self.jitter_origin = pulse.gaussian_kernel(p["detector.timing_jitter"],
                                                               self.step)
            self._jitter = Spectrum(jitter)
        else:
            self.h, self.h_origin = electronics.filter_kernel(
                p["electronics.filter"], p["electronics.bandwidth"], self.step)
        self._h, self._h2 = Spectrum(self.h), Spectrum(self.h ** 2)     # their FFTs, kept
        widest = math.sqrt(self.sigma_p ** 2 + self.geo.sigma_g ** 2 + max(hi, 0.0))
        spread = self._jitter.signal.size if self.counting else self.h.size
        margin = self.step * spread + 8.0 * widest + 2.0 * self.interval + 5.0
        self.grid = make_grid(p["window.start"], p["window.stop"], self.step, margin)
        self.t = self.grid.centres
        self.eta = radiometry.detection_efficiency(p)
        self.modes = radiometry.speckle_modes(p)
        self.dc_rate = steady_rate(p)                  # pe ns⁻¹: background and dark counts
        if self.counting:
            self.sigma_n = self.baseline = self.ceiling = math.nan
            return
        gain = p["detector.gain"]
        g_t = p["electronics.transimpedance"]
        levels = receiver_levels(p, self.h, self.step, self.dc_rate)
        dt_s = self.step * 1e-9
        self.mv_per_pe = g_t * ELEMENTARY_CHARGE * gain / dt_s * 1e3         # mV per pe per bin
        self.mv2_per_pe = (g_t * ELEMENTARY_CHARGE * gain / dt_s) ** 2 * levels.excess * 1e6
        self.sigma_n = levels.noise_mv
        self.baseline = levels.baseline_mv
        self.ceiling = levels.ceiling_mv

    def photons(self, surface) -> np.ndarray:
        """Photons at the aperture per fine bin (amplitude 1) for a surface response, before the
        pulse: the chain's ``amounts`` (docs/instrument.md §3.3, §3.4)."""
        check_wavelength(surface, self.params)
        return aperture_photons(surface, self.params, self.grid, self.geo)[0]

    def kernel(self, v: float) -> tuple[np.ndarray, int]:
        """The pulse and footprint kernel with its variance changed by ``v`` (ns²): amount per
        bin (Σ = 1) and origin index (the chain's own at v = 0)."""
        p = self.params
        if self.gaussian_pulse:
            p_k, p_o = pulse.gaussian_kernel(math.sqrt(max(self.sigma_p ** 2 + v, 0.0)), self.step)
            g_k, g_o = pulse.gaussian_kernel(self.geo.sigma_g, self.step)
        else:
            p_k, p_o = pulse.pulse_kernel(p, self.step)
            g_k, g_o = pulse.gaussian_kernel(math.sqrt(max(self.geo.sigma_g ** 2 + v, 0.0)),
                                             self.step)
        return np.convolve(p_k, g_k), p_o + g_o

    def waveform(self, photons, v: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """μ (mV) and ν (mV²) of the module docstring on the fine grid (``self.t``); for a
        photon-counting detector, the signal photoelectrons per ns at the detector (amplitude
        1, before the dead time and the timing jitter: :mod:`.recording`), and None.
        ``photons``: an array (:meth:`photons`), or its :class:`Spectrum` when the same
        photons are taken at several ``v``."""
        if not isinstance(photons, Spectrum):
            photons = Spectrum(photons)
        k, k_o = self.kernel(v)
        pe = np.clip(self._convolve(photons, Spectrum(k), k_o), 0.0, None) * self.eta
        pe = Spectrum(pe)
        if self.counting:
            return pe.signal / self.step, None
        mu = self.mv_per_pe * self._convolve(pe, self._h, self.h_origin)
        nu = self.mv2_per_pe * self._convolve(pe, self._h2, self.h_origin)
        return mu, np.clip(nu, 0.0, None)

    def jitter(self, rate: np.ndarray) -> np.ndarray:
        """A photon-counting receiver's rate on the fine grid (per ns) spread by its Gaussian
        timing jitter, which acts on the recorded tags: after the dead time."""
        if self._jitter.signal.size == 1:
            return rate * self._jitter.signal[0]
        return self._convolve(Spectrum(rate), self._jitter, self.jitter_origin)

    @staticmethod
    def _convolve(signal: Spectrum, kernel: Spectrum, origin: int) -> np.ndarray:
        return signal.convolve(kernel)[origin: origin + signal.signal.size]

    def fwhm_of(self, v: float) -> float:
        """The pulse FWHM (ns) that ``v`` means for a Gaussian pulse at the nominal footprint."""
        return pulse.FWHM_PER_SIGMA * math.sqrt(max(self.sigma_p ** 2 + v, 0.0))

    def footprint_of(self, v: float) -> float:
        """The footprint σ_g (ns) that ``v`` means at the nominal pulse width."""
        return math.sqrt(max(self.geo.sigma_g ** 2 + v, 0.0))
