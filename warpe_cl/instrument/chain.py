"""The instrument chain of docs/instrument.md §3, stage by stage, for one scenario, and the output
Dataset (docs/interface.md §5: ``sample_time``, ``signal_mv``, ``expected_mv``).

Time zero is WARPE's: the arrival of light reflected at the mean surface at the footprint
centre. Each shot draws its noise from its own generator, ``Generator(Philox(key))`` with the
128-bit key (seed, 64-bit scenario key) and the shot in the top word of its 256-bit counter, so the same seed gives the same shots whatever the
number of shots or the order they are computed in.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import stops
from ..config.instrument_fields import at_wavelength
from ..errors import ConfigError
from ..surface import SurfaceResponse
from . import adc, detection, detector, electronics, footprint, photon_counting, pulse, \
    radiometry, specular, speckle
from .grid import FineGrid, convolve, deposit, make_grid, rebin_density

C_M_PER_NS = footprint.C_M_PER_NS
PARTS = ("diffuse", "specular", "bf_direct")


def shot_rng(seed: int, scenario_key: int, shot: int) -> np.random.Generator:
    """The generator of one shot: Philox4x64 with the 128-bit key (seed << 64) | scenario key
    (both uint64) and the shot in the top word of the 256-bit counter, which the generator
    advances from its bottom word: shots never share numbers (each would need 2**192 draws)."""
    key = (int(seed) % 2**64) << 64 | (int(scenario_key) % 2**64)
    counter = np.array([0, 0, 0, int(shot) % 2**64], dtype=np.uint64)
    return np.random.Generator(np.random.Philox(key=key, counter=counter))


def check_wavelength(surface: SurfaceResponse, params) -> None:
    """ConfigError unless the surface response was computed at the instrument's wavelength."""
    lam = params["wavelength"]
    if surface.wavelength is None:
        raise ConfigError("the surface result does not say its wavelength (no configuration "
                          "attribute); recompute it with `warpe-cl run`", key="wavelength")
    if not at_wavelength(surface.wavelength, lam):
        raise ConfigError(f"the surface response was computed at {surface.wavelength * 1e9:g} nm "
                          f"but {params['name']} works at {lam * 1e9:g} nm; recompute the surface "
                          f"with wavelength: \"{lam * 1e9:g} nm\" (and optical constants at it)",
                          key="wavelength")


class Geometry:
    """Slant range, footprint kernel width, lobe and aperture fractions of one instrument."""

    def __init__(self, params):
        p = params
        self.range_m = footprint.slant_range(p["geometry.altitude"], p["geometry.pointing"])
        self.sigma_g = footprint.geometric_sigma(p["geometry.altitude"], p["transmitter.divergence"],
                                                 p["geometry.pointing"], p["geometry.slope"],
                                                 p["geometry.rms_height"])
        self.lobe_deg = specular.lobe_half_angle(p["geometry.roughness"], p["geometry.lobe_factor"])
        tilt = p["geometry.pointing"] - p["geometry.slope"]
        common = dict(aperture_m=p["receiver.aperture"], range_m=self.range_m,
                      divergence_full_deg=p["transmitter.divergence"], tilt_deg=tilt,
                      model=p["geometry.lobe_model"])
        self.kappa = {
            "specular": specular.aperture_fraction(lobe_deg=self.lobe_deg, **common),
            "bf_direct": specular.aperture_fraction(
                lobe_deg=self.lobe_deg * p["geometry.bf_lobe_factor"], **common),
        }


def _shape_kernel(params, step, sigma_g, fwhm=None):
    p_k, p_o = pulse.pulse_kernel(params, step, fwhm)
    g_k, g_o = pulse.gaussian_kernel(sigma_g, step)
    return np.convolve(p_k, g_k), p_o + g_o


def _photon_rate(amounts, kernel, origin, step):
    """Photons per ns at the aperture: the per-bin photon amounts convolved with p ⊗ g
    (FFT round-off below zero removed: both factors are non-negative)."""
    return np.clip(convolve(amounts, kernel, origin), 0.0, None) / step


def aperture_photons(surface: SurfaceResponse, params, grid: FineGrid,
                     geo: Geometry) -> tuple[np.ndarray, list]:
    """Photons at the aperture per fine bin before the pulse, §3.3 and §3.4.

    Returns
    -------
    (amounts, returns)
        Photons per bin of ``grid``: the diffuse response times E_t η_t T² Ω_r / (hν), plus the
        specular and BF-direct returns deposited at their delays; and those returns as
        (component, delay ns, photons), their fractions times the transmitted photons and
        the aperture fractions κ of ``geo``.
    """
    per_reflectance = radiometry.photons_per_reflectance(params)
    n_tx = radiometry.transmitted_photons(params) * params["geometry.atmosphere_transmission"] ** 2
    diffuse = rebin_density(surface.edges, surface.diffuse, grid.edges)          # sr⁻¹ per bin
    returns = [(c, t, n_tx * f * geo.kappa[c]) for c, t, f in surface.returns]
    amounts = per_reflectance * diffuse
    if returns:
        amounts = amounts + deposit(grid, [t for _, t, _ in returns], [n for _, _, n in returns])
    return amounts, returns


def steady_rate(params) -> float:
    """Steady primary rate (pe ns⁻¹) besides the signal: background, plus the dark counts of a
    photon-counting detector or the APD's bulk dark current I_db/q."""
    rate = radiometry.background_rate(params)
    if params["detector.type"] == "photon_counting":
        return rate + params["detector.dark_count_rate"] * 1e-9
    return rate + detector.dark_rate(params["detector.bulk_dark_current"])


@dataclass(frozen=True)
class Levels:
    """The linear-mode receiver's fixed levels, §3.6–3.8: APD excess F, electronic noise
    σ_v (V), per-sample noise σ_n, baseline and clipped level (mV)."""
    excess: float
    sigma_electronic: float
    noise_mv: float
    baseline_mv: float
    ceiling_mv: float


def receiver_levels(params, h: np.ndarray, step: float, dc_rate: float) -> Levels:
    """:class:`Levels` of ``params`` with the filter ``h`` on a grid of ``step`` (ns) and the
    steady rate ``dc_rate`` (pe ns⁻¹). The ceiling is the saturation voltage or the top ADC
    code, whichever is lower, as recorded."""
    p = params
    gain = p["detector.gain"]
    excess = p["detector.excess_noise"] or detector.excess_noise_factor(gain, p["detector.k_eff"])
    g_t = p["electronics.transimpedance"]
    full_scale = p["adc.full_scale"]
    bits = p["adc.bits"]
    bandwidth = electronics.noise_bandwidth(h, step)
    sigma_el = g_t * p["electronics.current_noise"] * math.sqrt(bandwidth)
    sigma_n = detection.sample_noise_sigma(sigma_el, dc_rate, gain, excess, g_t, bandwidth,
                                           adc.lsb(full_scale, bits)) * 1e3          # mV
    baseline = (g_t * detector.expected_current(dc_rate, gain, p["detector.surface_dark_current"])
                + p["electronics.offset"]) * 1e3
    top = adc.quantise(np.array([min(p["electronics.saturation"], full_scale)]) * 1e3,
                       full_scale * 1e3, bits)[0]
    return Levels(excess, sigma_el, sigma_n, baseline, float(top))


def run_scenario(surface: SurfaceResponse, params, shots: int, seed: int,
                 scenario_key: int = 0) -> dict:
    """Every output array of one scenario (names as in the Dataset)."""
    check_wavelength(surface, params)
    p = params
    step = p["window.fine_step"]
    geo = Geometry(p)
    kernel, k_origin = _shape_kernel(p, step, geo.sigma_g)
    counting = p["detector.type"] == "photon_counting"
    if counting:
        h, h_origin = np.array([1.0]), 0
    else:
        h, h_origin = electronics.filter_kernel(p["electronics.filter"], p["electronics.bandwidth"],
                                                step)
    jitter_pad = 6.0 * p["transmitter.pulse_fwhm_jitter"]
    margin = step * (kernel.size + h.size) + jitter_pad + 5.0
    grid = make_grid(p["window.start"], p["window.stop"], step, margin)
    t_fine = grid.centres

    # §3.3, §3.4: photons at the aperture per fine bin, before the pulse
    per_reflectance = radiometry.photons_per_reflectance(p)
    total_diffuse = surface.diffuse_integral
    amounts, returns = aperture_photons(surface, p, grid, geo)
    photon_rate = _photon_rate(amounts, kernel, k_origin, step)
    photons_part = np.array([per_reflectance * total_diffuse]
                            + [sum(n for c, _, n in returns if c == part)
                               for part in PARTS[1:]])
    eta = radiometry.detection_efficiency(p)
    modes = radiometry.speckle_modes(p)
    dc_rate = steady_rate(p)
    signal_rate = eta * photon_rate                                                # pe ns⁻¹

    lo = grid.edges[grid.crop.start]
    hi = grid.edges[grid.crop.stop]
    inside = rebin_density(surface.edges, surface.diffuse, np.array([lo, hi]))[0]
    out = {
        "fine_time": t_fine[grid.crop],
        "photon_rate": photon_rate[grid.crop],
        "received_reflectance": photon_rate[grid.crop] / per_reflectance,
        "photons_at_aperture": photons_part,
        "signal_photoelectrons": eta * photons_part.sum(),
        "diffuse_in_window": inside / total_diffuse if total_diffuse > 0 else math.nan,
        "background_rate": dc_rate,
        "geometric_sigma": geo.sigma_g,
        "lobe_half_angle": geo.lobe_deg,
        "receiver_solid_angle": specular.receiver_solid_angle(p["receiver.aperture"],
                                                              geo.range_m),
        "aperture_fraction_specular": geo.kappa["specular"],
        "aperture_fraction_bf_direct": geo.kappa["bf_direct"],
        "speckle_modes": modes,
    }
    if counting:
        out.update(_photon_counting(p, grid, signal_rate, dc_rate, modes, shots, seed,
                                    scenario_key))
    else:
        out.update(_linear_mode(p, grid, amounts, kernel, k_origin, h, h_origin, signal_rate,
                                dc_rate, modes, shots, seed, scenario_key, geo, eta,
                                per_reflectance))
    return out


def _template(kernel, k_origin, h, h_origin, step, interval):
    """The expected pulse shape p ⊗ g ⊗ h_e sampled every ``interval`` around its peak:
    (samples, time of the peak relative to the arrival, rms width), ns."""
    shape = np.convolve(kernel, h)
    origin = k_origin + h_origin
    t = (np.arange(shape.size) - origin) * step
    peak = float(t[np.argmax(shape)])
    mean = float(np.sum(shape * t) / shape.sum())
    width = math.sqrt(float(np.sum(shape * (t - mean) ** 2) / shape.sum()))
    c = int(math.ceil(3.0 * width / interval)) + 1
    at = peak + interval * (np.arange(2 * c + 1) - c)
    return np.interp(at, t, shape, left=0.0, right=0.0), peak, width


def _continuous_template(kernel, k_origin, h, h_origin, step):
    """p ⊗ g ⊗ h_e on the fine grid as a :class:`detection.Template` (time from the arrival)."""
    shape = np.convolve(kernel, h)
    t = (np.arange(shape.size) - (k_origin + h_origin)) * step
    return detection.Template(shape, t)


def _linear_mode(p, grid, amounts, kernel, k_origin, h, h_origin, signal_rate, dc_rate, modes,
                 shots, seed, scenario_key, geo, eta, per_reflectance):
    """§3.6–3.8: APD, electronics, ADC, detection."""
    step = grid.step
    t_fine = grid.centres
    gain = p["detector.gain"]
    g_t = p["electronics.transimpedance"]
    i_ds = p["detector.surface_dark_current"]
    v_sat = p["electronics.saturation"]
    offset = p["electronics.offset"]
    full_scale = p["adc.full_scale"]
    bits = p["adc.bits"]
    interval = p["adc.sampling_interval"]

    i_exp = detector.expected_current(signal_rate + dc_rate, gain, i_ds)
    v_exp = electronics.amplify(i_exp, h, h_origin, g_t) + offset                  # V
    ts = adc.sample_times(p["window.start"], p["window.stop"], interval)
    expected_mv = np.minimum(adc.sample(t_fine, v_exp, ts), v_sat) * 1e3

    levels = receiver_levels(p, h, step, dc_rate)
    excess, sigma_el, sigma_n = levels.excess, levels.sigma_electronic, levels.noise_mv
    baseline_mv, top = levels.baseline_mv, levels.ceiling_mv
    template, t_peak, t_width = _template(kernel, k_origin, h, h_origin, step, interval)
    model = _continuous_template(kernel, k_origin, h, h_origin, step)
    m = p["detection.threshold_sigma"]
    threshold = m * sigma_n
    y_exp = detection.matched_filter(expected_mv - baseline_mv, template)

    signal = np.empty((shots, ts.size))
    phase = np.empty(shots)
    factor = np.empty(shots)
    fwhm = np.empty(shots)
    det = np.zeros(shots, bool)
    arrival = np.full(shots, np.nan)
    width = np.full(shots, np.nan)
    peak = np.empty(shots)
    saturated = np.zeros(shots, bool)
    jitter = p["transmitter.pulse_fwhm_jitter"]
    for s in range(shots):
        stops.check()          # a Ctrl-C or SIGTERM whose exception was dropped: stop here
        rng = shot_rng(seed, scenario_key, s)
        phase[s] = adc.sampling_phase(rng, interval, p["adc.random_phase"])
        rate = signal_rate
        fwhm[s] = p["transmitter.pulse_fwhm"]
        if jitter > 0.0:
            fwhm[s] = max(p["transmitter.pulse_fwhm"] + rng.normal(0.0, jitter), 0.05)
            k_s, o_s = _shape_kernel(p, step, geo.sigma_g, fwhm[s])
            rate = eta * _photon_rate(amounts, k_s, o_s, step)
        factor[s] = speckle.speckle_factor(rng, modes)
        lam = factor[s] * rate + dc_rate
        electrons = detector.avalanche(rng, detector.photoelectrons(rng, lam, step), gain, excess)
        current = detector.current(electrons, step, i_ds) + electronics.white_current_noise(
            rng, grid.size, p["electronics.current_noise"], step)
        volts = electronics.saturate(electronics.amplify(current, h, h_origin, g_t) + offset, v_sat)
        at = ts + phase[s]
        signal[s] = adc.quantise(adc.sample(t_fine, volts, at) * 1e3, full_scale * 1e3, bits)
        saturated[s] = bool(np.any(signal[s] >= top - 1e-9))
        det[s], arrival[s], width[s], peak[s] = detection.estimate(
            at, signal[s] - baseline_mv, template, t_peak, threshold, model, top - baseline_mv)
    return {
        "sample_time": ts,
        "signal_mv": signal,
        "expected_mv": expected_mv,
        "expected_analog_mv": v_exp[grid.crop] * 1e3,
        "sampling_phase": phase,
        "speckle_factor": factor,
        "pulse_fwhm": fwhm,
        "detected": det,
        "range_time": arrival,
        "range_offset": arrival * C_M_PER_NS / 2.0,
        "pulse_width": width,
        "peak_mv": peak + baseline_mv,
        "saturated": saturated,
        "noise_mv": sigma_n,
        "electronic_noise_mv": sigma_el * 1e3,
        "baseline_mv": baseline_mv,
        "threshold_mv": threshold,
        "saturation_mv": v_sat * 1e3,
        "template_width": t_width,
        "excess_noise_factor": excess,
        "mv_per_photoelectron": g_t * radiometry.ELEMENTARY_CHARGE * gain
        / (math.sqrt(2.0 * math.pi) * t_width * 1e-9) * 1e3,
        "detection_probability": detection.detection_probability(threshold, float(y_exp.max()),
                                                                 sigma_n),
        "false_alarm_probability": detection.false_alarm_probability(ts.size, m),
    }


def _photon_counting(p, grid, signal_rate, dc_rate, modes, shots, seed, scenario_key):
    """§3.9: Poisson arrivals, channels, dead times, jitter; per-shot histograms and tags."""
    crop = grid.crop
    edges = grid.edges[crop.start: crop.stop + 1]
    expected_pe = float(np.sum((signal_rate[crop] + dc_rate) * grid.step))
    if expected_pe > p["detector.max_photoelectrons"]:
        raise ConfigError(f"{expected_pe:.3g} photoelectrons expected per shot (more than "
                          f"detector.max_photoelectrons = {p['detector.max_photoelectrons']:g}): "
                          "the photon-counting branch has no model for such floods "
                          "(e.g. a specular return)", key="instrument.detector.max_photoelectrons")
    interval = p["adc.sampling_interval"]
    ts = adc.sample_times(p["window.start"], p["window.stop"], interval)
    bins = np.concatenate([ts, [ts[-1] + interval]])
    expected = rebin_density(edges, signal_rate[crop] + dc_rate, bins)
    recorded, exact = photon_counting.expected_recorded(
        edges, signal_rate[crop], dc_rate, bins, p["detector.channels"],
        p["detector.analog_dead_time"], p["detector.digital_dead_time"],
        p["detector.timing_jitter"], modes)
    # the same with no dead time: what they take, the jitter's spill past the window aside
    spread_only, _ = photon_counting.expected_recorded(
        edges, signal_rate[crop], dc_rate, bins, p["detector.channels"], 0.0, 0.0,
        p["detector.timing_jitter"], modes)
    lost = 1.0 - recorded.sum() / spread_only.sum() if spread_only.sum() > 0 else 0.0
    sig = signal_rate[crop] * grid.step
    t_c = grid.centres[crop]
    mean = float(np.sum(sig * t_c) / sig.sum()) if sig.sum() > 0 else 0.0
    spread = math.sqrt(float(np.sum(sig * (t_c - mean) ** 2) / sig.sum())) if sig.sum() > 0 else 1.0
    gate = 3.0 * spread + 3.0 * p["detector.timing_jitter"] + 1.0
    counts = np.zeros((shots, ts.size), np.int32)
    tags, factor = [], np.empty(shots)
    det = np.zeros(shots, bool)
    arrival = np.full(shots, np.nan)
    width = np.full(shots, np.nan)
    for s in range(shots):
        stops.check()          # a Ctrl-C or SIGTERM whose exception was dropped: stop here
        rng = shot_rng(seed, scenario_key, s)
        factor[s] = speckle.speckle_factor(rng, modes)
        times = photon_counting.arrivals(rng, edges, factor[s] * signal_rate[crop] + dc_rate)
        t = photon_counting.record(rng, times, p["detector.channels"],
                                   p["detector.analog_dead_time"], p["detector.digital_dead_time"],
                                   p["detector.timing_jitter"])
        tags.append(t)
        counts[s] = np.histogram(t, bins)[0]
        near = t[np.abs(t - mean) <= gate]
        if near.size:
            det[s] = True
            arrival[s] = near.mean()
            width[s] = near.std()
    longest = max((t.size for t in tags), default=0)
    photon_time = np.full((shots, max(longest, 1)), np.nan, np.float32)
    for s, t in enumerate(tags):
        photon_time[s, :t.size] = t
    return {
        "sample_time": ts,
        "signal_counts": counts,
        "expected_counts": expected,
        "expected_recorded_counts": recorded,
        "dead_time_loss": lost,
        "dead_time_loss_exact": int(exact),
        "photon_time": photon_time,
        "photon_count": np.array([t.size for t in tags]),
        "speckle_factor": factor,
        "detected": det,
        "range_time": arrival,
        "range_offset": arrival * C_M_PER_NS / 2.0,
        "pulse_width": width,
        "expected_photoelectrons": expected_pe,
    }
