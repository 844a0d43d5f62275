"""Summary numbers of a return waveform, with their Monte Carlo standard errors.

:func:`metrics` reduces the ``time`` axis of a result (one scenario, a sweep along
``scenario``, or the grid of :func:`warpe_cl.as_grid`) to, per component:

- ``mean_delay`` (ns): the centroid of the time distribution, sum(s_i t_i) / S;
- ``rms_width`` (ns): its RMS width, sqrt(sum(s_i (t_i - mean)^2) / S);
- ``peak_time`` (ns): the time of the peak of the waveform smoothed by rebinning (below);
- ``fraction_after`` (1): the share of S in the bins that start at or after each time of
  ``after`` (ns).

Here s_i = ``reflectance`` x bin width (what bin i holds, per launched ray and sr), t_i the
bin centre (``time``: the geometric mean of the edges) and S = sum(s_i). Rays leaving before
the first time edge (``early_fraction``, the specular with log bins) are in no bin and so in
none of these numbers.

Standard errors (``<name>_stderr``) come from the counts: each bin is independent with the
variance var_i = (``reflectance_stderr`` x bin width)^2 (Poisson: s_i^2 / n_i for n_i rays;
the sums of w^2 in the weighted mode; ``hemispherical_reflectance``, which has no stderr
variable, takes s_i / N of an analog walk of N rays), propagated to first order (the delta method):
var(mean) = sum(var_i (t_i - mean)^2) / S^2; var(rms^2) = sum(var_i ((t_i - mean)^2 -
rms^2)^2) / S^2 and var(rms) = var(rms^2) / (4 rms^2); var(fraction) = sum(var_i (a_i - f)^2) /
S^2 with a_i = 1 after the time, 0 before. For n rays drawn from one distribution these are
sigma^2/n, (mu_4 - sigma^4)/(4 sigma^2 n) and f(1 - f)/n.

The peak is robust to the 1-2 rays a fine bin holds: consecutive bins are merged, from the
first, until each merged bin holds at least ``min_rays`` rays (``ray_count``; the remainder
joins the last), and the peak is the centre (geometric mean of its edges, or the arithmetic
mean from 0) of the merged bin of largest s / width. Its standard error is the standard
deviation of that peak over ``resamples`` Poisson resamplings of the bins (s_i scaled by
n*_i / n_i, n*_i ~ Poisson(n_i); fixed seed), so it includes the jumps between merged bins.

Example (docs/interface.md §5.3)::

    m = warpe_cl.metrics(warpe_cl.open_database("db/", grid=True)).sel(component="scattering")
    m["mean_delay"], m["mean_delay_stderr"]          # ns, along grain_size, ...
"""
from __future__ import annotations

import numpy as np

__all__ = ["metrics"]


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
    """Centre of the merged bin of largest density, one waveform (1-D arrays)."""
    groups = []
    start, held = 0, 0.0
    for i, count in enumerate(n):
        held += count
        if held >= min_rays:
            groups.append((start, i + 1))
            start, held = i + 1, 0.0
    if start < len(n):
        if groups and held < min_rays:
            groups[-1] = (groups[-1][0], len(n))
        else:
            groups.append((start, len(n)))
    if not groups or not np.any(s > 0):
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


def _bin_variances(ds, variable, signal, width):
    """var_i of what each bin holds: from ``<variable>_stderr``, or, where a result has none
    (``hemispherical_reflectance``), from the counts of an analog walk: bin i then holds
    n_i = s_i N rays of weight 1 for N launched rays, so var_i = s_i^2 / n_i = s_i / N."""
    if f"{variable}_stderr" in ds:
        err = ds[f"{variable}_stderr"].transpose(..., "time").values.astype(float)
        return (np.nan_to_num(err) * width) ** 2
    if ds.attrs.get("mode") != "analog" or "photons" not in ds:
        raise ValueError(f"{variable} has no {variable}_stderr in this result, and its "
                         f"standard errors follow from the counts only in the analog mode "
                         f"(mode: {ds.attrs.get('mode', 'not given')})")
    per_ray = (signal / ds["photons"]).transpose(*signal.dims).values.astype(float)
    return np.nan_to_num(per_ray) * width


def metrics(ds, after=(), *, variable: str = "reflectance", min_rays: int = 100,
            resamples: int = 100, seed: int = 0):
    """Mean delay, RMS width, peak time and late fraction of each waveform of ``ds``.

    Parameters
    ----------
    ds : xarray.Dataset
        A result of ``warpe-cl run``, :func:`warpe_cl.simulate`,
        :func:`warpe_cl.open_database` or :func:`warpe_cl.as_grid`: ``time_edges`` (ns),
        ``variable`` and ``<variable>_stderr`` along ``time`` (ns-1 ...), ``ray_count``.
    after : float or sequence of float
        Times (ns) for ``fraction_after``; none by default.
    variable : str
        ``reflectance`` (inside the field of view, per sr: what an instrument sees) or
        ``hemispherical_reflectance`` (at any angle). ``ray_count`` counts the rays of
        ``reflectance``: the peak's merging by ``min_rays`` uses it for either. A result with
        no ``<variable>_stderr`` (``hemispherical_reflectance``) takes the Poisson errors of
        its analog counts, var_i = s_i / ``photons``; a weighted one raises ValueError.
    min_rays : int
        Rays each merged bin of the peak search holds at least.
    resamples : int
        Poisson resamplings behind ``peak_time_stderr`` (0: none, NaN).
    seed : int
        Seed of those resamplings (the result is deterministic).

    Returns
    -------
    xarray.Dataset
        The leading dimensions of ``ds`` (``component``, ``scenario`` or the grid's), with
        ``mean_delay``, ``rms_width``, ``peak_time`` (ns) and, when ``after`` is given,
        ``fraction_after`` (1; dimension ``after`` in ns), each with ``<name>_stderr`` (the
        module's notes say how). NaN where a waveform holds nothing (or a grid lacks the
        scenario).
    """
    import xarray as xr

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
    coords = {d: ds[d] for d in lead if d in ds.coords}
    coords.update({name: c for name, c in ds.coords.items()
                   if name not in coords and set(c.dims) <= set(lead) and c.dims})
    ns = {"units": "ns"}
    out = xr.Dataset({
        "mean_delay": (lead, mean, {**ns, "long_name": "centroid of the time distribution"}),
        "mean_delay_stderr": (lead, mean_se, {**ns, "long_name": "its standard error"}),
        "rms_width": (lead, rms, {**ns, "long_name": "RMS width of the time distribution"}),
        "rms_width_stderr": (lead, rms_se, {**ns, "long_name": "its standard error"}),
        "peak_time": (lead, peak, {**ns, "long_name": f"peak of the waveform rebinned to >= "
                                                      f"{min_rays} rays per bin"}),
        "peak_time_stderr": (lead, peak_se, {**ns, "long_name": f"its standard deviation "
                                                                f"over {resamples} Poisson "
                                                                f"resamplings"}),
    }, coords=coords, attrs={"metrics_variable": variable, "metrics_min_rays": min_rays})
    after = np.atleast_1d(np.asarray(after, dtype=float))
    if after.size:
        frac, frac_se = _fraction_after(s, var, lo, after)
        dims = lead + ("after",)
        out = out.assign_coords(after=("after", after, {
            "units": "ns", "long_name": "time from which fraction_after counts (rounded up to "
                                       "the next bin edge)"}))
        out["fraction_after"] = (dims, frac, {"units": "1", "long_name": "share of the "
                                              "waveform in the bins starting at or after"})
        out["fraction_after_stderr"] = (dims, frac_se, {"units": "1",
                                                        "long_name": "its standard error"})
    return out
