"""Summary numbers of a return waveform, with their Monte Carlo standard errors.

:func:`metrics` reduces a result (one scenario, a sweep along ``scenario``, or the grid of
:func:`warpe_cl.as_grid`) to, per waveform:

- ``mean_delay`` (ns): the centroid of the time distribution, sum(s_i t_i) / S;
- ``rms_width`` (ns): its RMS width, sqrt(sum(s_i (t_i - mean)^2) / S);
- ``peak_time`` (ns): the time of the peak of the smoothed waveform;
- ``fraction_after`` (1): the share of S at or after each time of ``after`` (ns),

each with its standard error ``<name>_stderr``. It works at one of two stages. A surface
result (``warpe-cl run``) gives them per component, from the time bins (below). A result that
went through an instrument (``warpe-cl instrument``, or a preset's ``instrument:`` block) gives
them, by default, for the recorded signal, after the pulse, the footprint, the detector and the
electronics (further below); the components are summed by then, so these have no ``component``
dimension (``stage="surface"`` gives the surface's numbers of the same file).

Surface
-------
Here s_i = ``reflectance`` x bin width (what bin i holds, per launched ray and sr), t_i the
bin centre (``time``: the geometric mean of the edges) and S = sum(s_i). ``fraction_after``
counts the bins that start at or after the time. Rays leaving before the first time edge
(``early_fraction``, the specular with log bins) are in no bin and so in none of these numbers.

Standard errors (``<name>_stderr``) come from the counts: each bin is independent with the
variance var_i = (``reflectance_stderr`` x bin width)^2 (Poisson: s_i^2 / n_i for n_i rays;
the sums of w^2 in the weighted mode; ``hemispherical_reflectance``, which has no stderr
variable, takes s_i / N of an analog walk of N rays), propagated to first order (the delta
method):
var(mean) = sum(var_i (t_i - mean)^2) / S^2; var(rms^2) = sum(var_i ((t_i - mean)^2 -
rms^2)^2) / S^2 and var(rms) = var(rms^2) / (4 rms^2); var(fraction) = sum(var_i (a_i - f)^2) /
S^2 with a_i = 1 after the time, 0 before. For n rays drawn from one distribution these are
sigma^2/n, (mu_4 - sigma^4)/(4 sigma^2 n) and f(1 - f)/n.

The peak is robust to the 1-2 rays a fine bin holds: consecutive bins are merged, from the
first bin holding a ray to the last, until each merged bin holds at least ``min_rays`` rays (``ray_count``; the remainder
joins the last), and the peak is the centre (geometric mean of its edges, or the arithmetic
mean from 0) of the merged bin of largest s / width; with fewer than two merged bins (fewer
than 2 ``min_rays`` rays in all) there is no peak (NaN). Its standard error is the standard
deviation of that peak over ``resamples`` Poisson resamplings of the bins (s_i scaled by
n*_i / n_i, n*_i ~ Poisson(n_i); fixed seed), so it includes the jumps between merged bins.

After the instrument chain
--------------------------
*The window.* Noise fills the whole record, the return only part of it, and a sample's weight
in the centroid and the width grows with its distance from the return: over the whole record
the numbers would be mostly noise. Each scenario's numbers are therefore taken over one window,
[``window_start``, ``window_stop``] (ns): the first and last times at which the noiseless
expected signal on the fine grid (``expected_analog_mv`` - ``baseline_mv``; ``photon_rate``
for photon counting) reaches ``level`` (1e-3) of its peak. It is fixed before any noise is
drawn (a window placed around each shot's own detection would move with that shot's noise and
bias the numbers), it spans the whole return, tail and BF-direct echoes included, whatever the
pulse and the surface, and for a Gaussian return it is +-3.7 sigma (0.02 % of the return is
outside). The numbers are those of the return within the window.

*Linear mode* (``signal_mv``). A shot's samples are y_k = ``signal_mv`` - ``baseline_mv`` at
their actual times t_k = ``sample_time`` + ``sampling_phase`` of the shot. The samples in the
window of all the detected shots (``detected``; ``shots_used`` of them) are taken together as
s_i = y_k, t_i = t_k in the formulas above (``fraction_after``: the samples at or after the
time), so that each shot counts in proportion to its windowed sum S_s. With the phase uniform
over the sampling interval dt, E sum_k g(t_k) = (1/dt) integral g(t) dt for any g: the sums
estimate the integrals of the continuous signal without bias, and their ratios to first order.
A mean of each shot's own numbers would not: a shot's second moment sums a few noisy samples
weighted by (t - mean)^2, large away from the return, and is mostly noise (BELA, 1.2 mV, on the
granular case of presets/paper/bela_cases.yaml: 25 +- 44 ns^2 per shot for a true 27 ns^2,
28 % of them negative); a negative moment has no root, and a shot's width about its own
centroid is low by that centroid's scatter.

The standard errors come from the scatter of the shots, which holds every random draw of the
chain (noise, speckle, sampling phase, pulse jitter). A number Q = sum_s N_s / sum_s S_s (N_s:
the shot's sum of s_i t_i, of s_i (t_i - mean)^2, or of its late s_i) has, to first order,
var(Q) = sum_s (N_s - Q S_s)^2 / (n (n - 1) Sbar^2) over the n shots: the shot-to-shot
variance of the shots' residuals (N_s - Q S_s) / Sbar, over n; and var(rms) = var(rms^2) /
(4 rms^2).

``peak_time`` is the one number a single shot gives without a ratio of noisy sums: the vertex
of the Gaussian through the shot's largest sample in the window and that sample's two
neighbours (the parabola through their logarithms; through the values where one is <= 0),
clipped to +-1 sample (the electronics' filter has smoothed the signal); the mean over the
shots, with their standard deviation (ddof 1) / sqrt(n) as its error. Three samples of a return
about as wide as the sampling interval place an asymmetric peak only to a fraction of that
interval (BELA, 12.5 ns: a return with a 5 ns exponential tail comes out 0.9 ns late);
``expected_peak_time`` shows by how much. Saturated shots (``saturated``) are kept: clipping
flattens the top of the return, which biases its width and its peak.

*Photon counting* (``signal_counts``). A shot holds a few photons (ATLAS: about 10): its own
width would be biased by 1/n and its own peak would be that of a handful of time tags. The
histogram of all shots is what is analysed, and the numbers are the surface's, applied to it:
s_i = the counts of bin i summed over every shot minus the expected background
(``background_rate`` x bin width x shots), t_i the bin centres, var_i = the counts (Poisson;
dead time makes the counts slightly sub-Poisson, so these errors are slightly conservative),
the peak over the window's bins merged, from the window's start, until each holds
``min_rays`` photons, with its Poisson resampling error (with few photons the merged bins are
wide and so is that error; below 2 ``min_rays`` photons in the window, no peak). ``shots_used``
is every shot.

*The noiseless values*, ``expected_mean_delay``, ``expected_rms_width``,
``expected_peak_time`` and ``expected_fraction_after``: the same numbers of the expected signal
on the fine grid, in the same window, with no error (the peak: the vertex through its largest
value; the fraction: the fine bins starting at or after the time). The difference between a
number and its expected value is the bias of the recorded estimate: sampling, noise,
quantisation and saturation; for photon counting, dead time and timing jitter, which
``photon_rate`` does not include.

Example (docs/interface.md §5.3)::

    m = warpe_cl.metrics(warpe_cl.open_database("db/", grid=True)).sel(component="scattering")
    m["mean_delay"], m["mean_delay_stderr"]          # ns, along grain_size, ...
    b = warpe_cl.metrics(xarray.load_dataset("bela.nc"))   # after the instrument chain
    b["mean_delay"] - b["expected_mean_delay"]       # the bias of the recorded estimate, ns
"""
from __future__ import annotations

import warnings

import numpy as np

from .errors import ConfigError

__all__ = ["metrics"]

#: What every metric is, for the ``long_name`` attributes.
_LONG = {"mean_delay": "centroid of the time distribution",
         "rms_width": "RMS width of the time distribution",
         "fraction_after": "share of the waveform at or after the time"}


def _centres(lo, hi):
    """Bin centres: geometric mean of the edges, arithmetic where the lower edge is 0."""
    with np.errstate(invalid="ignore"):
        return np.where(lo > 0, np.sqrt(np.abs(lo * hi)), 0.5 * (lo + hi))


def _moments(s, var, t):
    """Mean, RMS width and their standard errors along the last axis (NaN where S = 0)."""
    total = s.sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (s * t).sum(-1) / total
        d2 = (t - mean[..., None]) ** 2
        msq = (s * d2).sum(-1) / total
        mean_se = np.sqrt((var * d2).sum(-1)) / total
        rms = np.sqrt(msq)
        rms_se = np.sqrt((var * (d2 - msq[..., None]) ** 2).sum(-1)) / total / (2 * rms)
    return mean, mean_se, rms, rms_se


def _fraction_after(s, var, lo, after):
    """Share of S in the bins with lower edge >= each time of ``after``, and its error."""
    total = s.sum(-1)
    out, err = [], []
    for a in after:
        inside = (lo >= a).astype(float)
        with np.errstate(invalid="ignore", divide="ignore"):
            f = (s * inside).sum(-1) / total
            e = np.sqrt((var * (inside - f[..., None]) ** 2).sum(-1)) / total
        out.append(f)
        err.append(e)
    return np.stack(out, -1), np.stack(err, -1)


def _peak(s, n, lo, hi, min_rays):
    """Centre of the merged bin of largest density, one waveform (1-D arrays). The merging
    runs from the first bin holding a ray to the last: empty bins before and after the
    waveform would widen its first and last merged bins (a late return on log bins from 1e-6 ns
    would peak at the middle of the axis)."""
    held_any = np.flatnonzero(n > 0)
    if held_any.size == 0:
        return np.nan
    first, end = int(held_any[0]), int(held_any[-1]) + 1
    groups = []
    start, held = first, 0.0
    for i in range(first, end):
        held += n[i]
        if held >= min_rays:
            groups.append((start, i + 1))
            start, held = i + 1, 0.0
    if start < end:
        if groups and held < min_rays:
            groups[-1] = (groups[-1][0], end)
        else:
            groups.append((start, end))
    if len(groups) < 2 or not np.any(s > 0):     # one merged bin spans the record: no peak
        return np.nan
    density = [s[a:b].sum() / (hi[b - 1] - lo[a]) for a, b in groups]
    a, b = groups[int(np.argmax(density))]
    return float(_centres(np.asarray(lo[a]), np.asarray(hi[b - 1])))


def _peaks(s, n, lo, hi, min_rays, resamples, rng):
    """Peak time and its resampled standard error for every waveform (leading axes)."""
    peak = np.full(s.shape[:-1], np.nan)
    err = np.full(s.shape[:-1], np.nan)
    for idx in np.ndindex(*s.shape[:-1]):
        si, ni = s[idx], n[idx]
        peak[idx] = _peak(si, ni, lo, hi, min_rays)
        if resamples and np.isfinite(peak[idx]):
            with np.errstate(invalid="ignore", divide="ignore"):
                per_ray = np.where(ni > 0, si / ni, 0.0)
            draws = [_peak(per_ray * m, m, lo, hi, min_rays)
                     for m in rng.poisson(ni, size=(resamples, ni.size)).astype(float)]
            err[idx] = np.nanstd(draws, ddof=1)
    return peak, err


def _vertex(t, y, k):
    """Time of the maximum of samples ``y`` near index ``k``, along the last axis.

    Parameters
    ----------
    t, y : array (..., n)
        Sample times (ns, uniform spacing) and values (any unit).
    k : int array (...)
        The index of the largest sample.

    Returns
    -------
    array (...)
        The vertex (ns) of the Gaussian through samples k - 1, k, k + 1 (the parabola through
        their logarithms), or of the parabola through their values where one is <= 0, clipped
        to one sample either side of t[k]; t[k] at an end of the record.
    """
    n = y.shape[-1]
    at = np.take_along_axis(t, k[..., None], -1)[..., 0]
    if n < 3:
        return at
    three = np.clip(k, 1, n - 2)[..., None] + np.arange(-1, 2)
    a, b, c = np.moveaxis(np.take_along_axis(y, three, -1), -1, 0)
    positive = (a > 0) & (b > 0) & (c > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b, c = (np.where(positive, np.log(np.where(positive, v, 1.0)), v) for v in (a, b, c))
        curve = a - 2.0 * b + c
        shift = np.where(curve < 0, np.clip(0.5 * (a - c) / curve, -1.0, 1.0), 0.0)
    inner = (k >= 1) & (k <= n - 2)
    return at + np.where(inner, shift, 0.0) * (t[..., 1] - t[..., 0])


def _window(t, f, level):
    """First and last time of ``t`` (ns) where ``f`` reaches ``level`` of its peak; NaN, NaN
    where ``f`` holds nothing."""
    f = np.nan_to_num(np.asarray(f, float))
    if not np.any(f > 0):
        return np.nan, np.nan
    on = t[f >= level * f.max()]
    return float(on[0]), float(on[-1])


def _shot_mean(values):
    """Mean over the shots (first axis) of the finite values, and its standard error: their
    standard deviation (ddof 1) / sqrt(their number); NaN below two values."""
    n = np.isfinite(values).sum(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # no shot: NaN, said by the NaN
        mean = np.nanmean(values, 0)
        sd = np.nanstd(values, 0, ddof=1)
    return mean, np.where(n > 1, sd / np.sqrt(np.maximum(n, 1)), np.nan)


def _ratio(num, den):
    """sum(num) / sum(den) over the shots (first axis) and its standard error from the shots'
    scatter (delta method): the standard deviation (ddof 1) of r / mean(den) over sqrt(n), with
    r = num - ratio x den (mean 0); NaN below two shots or where sum(den) <= 0."""
    n = num.shape[0]
    total = den.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(total > 0, num.sum(0) / total, np.nan)
        r = num - ratio * den
        err = np.sqrt((r ** 2).sum(0) / (n * (n - 1))) / (total / n) if n > 1 \
            else np.full(np.shape(ratio), np.nan)
    return ratio, err


def _expected(t, f, window, after):
    """The noiseless numbers of the expected signal ``f`` on the fine grid ``t`` (ns), within
    ``window``: {name: value} with the ``expected_`` names."""
    lo, hi = window
    none = np.zeros(0) if not after.size else np.full(after.size, np.nan)
    if not np.isfinite(lo):
        return {"expected_mean_delay": np.nan, "expected_rms_width": np.nan,
                "expected_peak_time": np.nan, "expected_fraction_after": none}
    s = np.where((t >= lo) & (t <= hi), np.nan_to_num(f), 0.0)
    zero = np.zeros_like(s)
    mean, _, rms, _ = _moments(s, zero, t)
    step = t[1] - t[0]
    frac = _fraction_after(s, zero, t - 0.5 * step, after)[0] if after.size else none
    peak = _vertex(t, s, np.asarray(np.argmax(s)))
    return {"expected_mean_delay": mean, "expected_rms_width": rms,
            "expected_peak_time": float(peak), "expected_fraction_after": frac}


def _linear(sc, after, level):
    """The numbers of one scenario of a linear-mode instrument (``signal_mv``): moments of the
    detected shots' samples taken together, errors from their scatter, the mean of each shot's
    peak (module notes)."""
    base = float(sc["baseline_mv"])
    t_fine = sc["fine_time"].values
    expected = sc["expected_analog_mv"].values - base
    window = _window(t_fine, expected, level)
    out = _expected(t_fine, expected, window, after)
    use = np.nan_to_num(sc["detected"].values.astype(float)) > 0.5
    t = sc["sample_time"].values[None, :] + sc["sampling_phase"].values[use, None]
    y = sc["signal_mv"].values[use].astype(float) - base
    inside = (t >= window[0]) & (t <= window[1])
    s = np.where(inside, y, 0.0)
    weight = s.sum(-1)
    out["mean_delay"], out["mean_delay_stderr"] = _ratio((s * t).sum(-1), weight)
    msq, msq_se = _ratio((s * (t - out["mean_delay"]) ** 2).sum(-1), weight)
    with np.errstate(invalid="ignore", divide="ignore"):
        out["rms_width"] = np.sqrt(msq)
        out["rms_width_stderr"] = msq_se / (2.0 * out["rms_width"])
    if after.size:
        late = np.stack([(s * (t >= a)).sum(-1) for a in after], -1)
        out["fraction_after"], out["fraction_after_stderr"] = _ratio(late, weight[:, None])
    peaks = _vertex(t, y, np.argmax(np.where(inside, y, -np.inf), -1))
    out["peak_time"], out["peak_time_stderr"] = _shot_mean(np.where(inside.any(-1), peaks,
                                                                    np.nan))
    out.update(shots_used=int(use.sum()), window_start=window[0], window_stop=window[1])
    return out


def _counting(sc, after, level, min_rays, resamples, rng):
    """The numbers of one scenario of a photon-counting instrument (``signal_counts``): the
    surface's, on the histogram of all shots less the background (module notes)."""
    t_fine = sc["fine_time"].values
    window = _window(t_fine, sc["photon_rate"].values, level)
    out = _expected(t_fine, sc["photon_rate"].values, window, after)
    lo = sc["sample_time"].values
    step = lo[1] - lo[0]
    hi, t = lo + step, lo + 0.5 * step
    counts = np.nan_to_num(sc["signal_counts"].values.astype(float)).sum(0)
    shots = sc.sizes["shot"]
    inside = (t >= window[0]) & (t <= window[1])
    s = np.where(inside, counts - float(sc["background_rate"]) * step * shots, 0.0)
    n = np.where(inside, counts, 0.0)
    out["mean_delay"], out["mean_delay_stderr"], out["rms_width"], out["rms_width_stderr"] = \
        _moments(s, n, t)
    peak, peak_se = _peaks(s[None, inside], n[None, inside], lo[inside], hi[inside], min_rays,
                           resamples, rng)                 # merged from the window's start
    out["peak_time"], out["peak_time_stderr"] = peak[0], peak_se[0]
    if after.size:
        out["fraction_after"], out["fraction_after_stderr"] = _fraction_after(s, n, lo, after)
    out.update(shots_used=shots, window_start=window[0], window_stop=window[1])
    return out


def _lead_coords(ds, lead):
    """The coordinates of ``ds`` that lie along the dimensions ``lead`` only."""
    coords = {d: ds[d] for d in lead if d in ds.coords}
    coords.update({name: c for name, c in ds.coords.items()
                   if name not in coords and set(c.dims) <= set(lead) and c.dims})
    return coords


def _dataset(lead, values, coords, after, attrs):
    """The metrics Dataset: ``values`` maps a name to (array, units, long name); the names
    holding ``fraction_after`` take the ``after`` dimension (ns) after ``lead``."""
    import xarray as xr
    out = xr.Dataset(coords=coords, attrs=attrs)
    if after.size:
        out = out.assign_coords(after=("after", after, {
            "units": "ns", "long_name": "time from which fraction_after counts (rounded up to "
                                       "the next bin edge or sample)"}))
    for name, (data, units, long_name) in values.items():
        dims = lead + (("after",) if "fraction_after" in name else ())
        out[name] = (dims, np.asarray(data, float), {"units": units, "long_name": long_name})
    return out


def _bin_variances(ds, variable, signal, width):
    """var_i of what each bin holds: from ``<variable>_stderr``, or, where a result has none
    (``hemispherical_reflectance``), from the counts of an analog walk: bin i then holds
    n_i = s_i N rays of weight 1 for N launched rays, so var_i = s_i^2 / n_i = s_i / N."""
    if f"{variable}_stderr" in ds:
        err = ds[f"{variable}_stderr"].transpose(..., "time").values.astype(float)
        return (np.nan_to_num(err) * width) ** 2
    if ds.attrs.get("mode") != "analog" or "photons" not in ds:
        raise ConfigError(f"has no {variable}_stderr, and the standard errors of {variable} "
                          f"follow from the counts only in the analog mode (mode: "
                          f"{ds.attrs.get('mode', 'not given')})")
    per_ray = (signal / ds["photons"]).transpose(*signal.dims).values.astype(float)
    return np.nan_to_num(per_ray) * width


def _surface(ds, after, variable, min_rays, resamples, seed):
    """The numbers of each component's waveform of a surface result (module notes)."""
    missing = [n for n in ("time_edges", variable, "ray_count") if n not in ds.variables]
    if missing:
        raise ConfigError(f"has no {', '.join(missing)}; metrics need the time bins of a result "
                          "of `warpe-cl run` or the recorded signal of `warpe-cl instrument`")
    edges = np.asarray(ds["time_edges"].values, dtype=float)
    lo, hi = edges[:-1], edges[1:]
    width = hi - lo
    t = _centres(lo, hi)
    signal = ds[variable].transpose(..., "time")
    lead = signal.dims[:-1]
    s = np.nan_to_num(signal.values.astype(float)) * width
    var = _bin_variances(ds, variable, signal, width)
    n = np.nan_to_num(ds["ray_count"].transpose(*lead, "time").values.astype(float))
    mean, mean_se, rms, rms_se = _moments(s, var, t)
    peak, peak_se = _peaks(s, n, lo, hi, min_rays, resamples, np.random.default_rng(seed))
    values = {
        "mean_delay": (mean, "ns", _LONG["mean_delay"]),
        "mean_delay_stderr": (mean_se, "ns", "its standard error"),
        "rms_width": (rms, "ns", _LONG["rms_width"]),
        "rms_width_stderr": (rms_se, "ns", "its standard error"),
        "peak_time": (peak, "ns", f"peak of the waveform rebinned to >= {min_rays} rays per bin"),
        "peak_time_stderr": (peak_se, "ns", f"its standard deviation over {resamples} Poisson "
                                            "resamplings"),
    }
    if after.size:
        frac, frac_se = _fraction_after(s, var, lo, after)
        values["fraction_after"] = (frac, "1", "share of the waveform in the bins starting at "
                                               "or after")
        values["fraction_after_stderr"] = (frac_se, "1", "its standard error")
    return _dataset(lead, values, _lead_coords(ds, lead), after,
                    {"metrics_stage": "surface", "metrics_variable": variable,
                     "metrics_min_rays": min_rays})


def _instrument(ds, after, level, min_rays, resamples, seed):
    """The numbers of the recorded signal of each scenario of an instrument result."""
    counting = "signal_counts" in ds
    lead = tuple(d for d in ds["signal_counts" if counting else "signal_mv"].dims
                 if d not in ("shot", "sample_time"))
    shape = tuple(ds.sizes[d] for d in lead)
    rng = np.random.default_rng(seed)
    found = {}
    for idx in np.ndindex(*shape):
        sc = ds.isel(dict(zip(lead, idx)))
        one = _counting(sc, after, level, min_rays, resamples, rng) if counting \
            else _linear(sc, after, level)
        for name, value in one.items():
            found.setdefault(name, np.full(shape + np.shape(value), np.nan))[idx] = value
    how = (f"the histogram of all shots less the background, bins merged to >= {min_rays} "
           "photons for the peak" if counting else "mean over the detected shots")
    se = ("its standard error (Poisson counts)" if counting else
          "its standard error: shot-to-shot standard deviation / sqrt(shots_used)")
    values = {}
    for name in ("mean_delay", "rms_width", "peak_time", "fraction_after"):
        if name not in found:
            continue
        units = "1" if name == "fraction_after" else "ns"
        long_name = _LONG.get(name, "peak of the recorded return")
        values[name] = (found[name], units, f"{long_name}, recorded, in the window ({how})")
        values[f"{name}_stderr"] = (found[f"{name}_stderr"], units, se)
        values[f"expected_{name}"] = (found[f"expected_{name}"], units,
                                      f"{long_name}, noiseless expected signal, in the window")
    values["window_start"] = (found["window_start"], "ns", f"start of the window: the expected "
                              f"signal reaches {level:g} of its peak")
    values["window_stop"] = (found["window_stop"], "ns", "end of the window")
    values["shots_used"] = (found["shots_used"], "1", "shots behind the numbers")
    return _dataset(lead, values, _lead_coords(ds, lead), after,
                    {"metrics_stage": "instrument", "metrics_level": level,
                     "metrics_min_rays": min_rays,
                     "metrics_method": "photon counting: " + how if counting
                     else "linear mode: " + how})


def _recorded(ds) -> bool:
    """Whether ``ds`` holds an instrument's recorded signal."""
    return "signal_mv" in ds.variables or "signal_counts" in ds.variables


def metrics(ds, after=(), *, stage: str | None = None, variable: str = "reflectance",
            min_rays: int = 100, resamples: int = 100, seed: int = 0, level: float = 1e-3):
    """Mean delay, RMS width, peak time and late fraction of each waveform of ``ds``.

    Parameters
    ----------
    ds : xarray.Dataset
        A result of ``warpe-cl run``, :func:`warpe_cl.simulate`,
        :func:`warpe_cl.open_database` or :func:`warpe_cl.as_grid`: ``time_edges`` (ns),
        ``variable`` and ``<variable>_stderr`` along ``time`` (ns-1 ...), ``ray_count``; or
        one that went through an instrument (``warpe-cl instrument``): ``signal_mv`` or
        ``signal_counts`` (shot, sample_time) and the chain's other arrays.
    after : float or sequence of float
        Times (ns) for ``fraction_after``; none by default.
    stage : {None, "surface", "instrument"}
        ``"surface"``: the surface response, per component; ``"instrument"``: the recorded
        signal, after the instrument chain (components summed). None: ``"instrument"`` when
        ``ds`` holds a recorded signal, else ``"surface"``.
    variable : str
        Surface: ``reflectance`` (inside the field of view, per sr: what an instrument sees) or
        ``hemispherical_reflectance`` (at any angle). ``ray_count`` counts the rays of
        ``reflectance``: the peak's merging by ``min_rays`` uses it for either. A result with
        no ``<variable>_stderr`` (``hemispherical_reflectance``) takes the Poisson errors of
        its analog counts, var_i = s_i / ``photons``; a weighted one raises ConfigError.
    min_rays : int
        Rays (photon counting: recorded photons) each merged bin of the peak search holds at
        least.
    resamples : int
        Poisson resamplings behind ``peak_time_stderr`` (0: none, NaN); not for a linear-mode
        instrument, whose errors come from the shots.
    seed : int
        Seed of those resamplings (the result is deterministic).
    level : float
        Instrument: the window spans the times where the noiseless expected signal reaches
        this fraction of its peak (module notes).

    Returns
    -------
    xarray.Dataset
        The leading dimensions of ``ds`` (surface: ``component``, ``scenario`` or the grid's;
        instrument: ``scenario`` or the grid's), with ``mean_delay``, ``rms_width``,
        ``peak_time`` (ns) and, when ``after`` is given, ``fraction_after`` (1; dimension
        ``after`` in ns), each with ``<name>_stderr`` (the module's notes say how). NaN where
        a waveform holds nothing (or a grid lacks the scenario). An instrument adds, per
        scenario, ``expected_<name>`` (the noiseless values), ``window_start`` and
        ``window_stop`` (ns) and ``shots_used``.

    Raises
    ------
    ConfigError
        ``ds`` lacks what the stage needs (one line, exit 2 on the command line).
    """
    after = np.atleast_1d(np.asarray(after, dtype=float))
    stage = stage or ("instrument" if _recorded(ds) else "surface")
    if stage == "surface":
        return _surface(ds, after, variable, min_rays, resamples, seed)
    if stage != "instrument":
        raise ConfigError(f"{stage!r} is not a stage; give surface or instrument", key="stage")
    if not _recorded(ds):
        raise ConfigError("has no recorded signal (signal_mv or signal_counts); give a result "
                          "of `warpe-cl instrument`")
    return _instrument(ds, after, level, min_rays, resamples, seed)
