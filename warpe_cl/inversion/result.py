"""The Dataset ``warpe-cl invert`` writes (docs/inversion.md §6)."""
from __future__ import annotations

import json
import math

import numpy as np
from scipy.special import chdtrc     # chi2's survival function, without scipy.stats

from ..errors import ConfigError
from ..instrument.footprint import C_M_PER_NS
from ..io import provenance
from .derived import variables as measure_variables
from .identifiability import CONSTRAINED

#: Posterior points drawn for the 68 % band of the fitted waveform.
BAND_POINTS = 64


def _band(problem, final, rng_seed: int = 0):
    """The 68 % band of the expected waveform (baseline + A μ) over the posterior: models at
    BAND_POINTS points drawn from the final grid's posterior mass (a fixed seed: the same
    band for the same input), each with its own profiled nuisances."""
    f = problem.forward
    w = final.weights().ravel()
    rng = np.random.default_rng(rng_seed)
    picks = rng.choice(w.size, size=BAND_POINTS, p=w)
    curves = []
    for flat in picks:
        index = np.unravel_index(flat, final.loglike.shape)
        e = final.evaluations[index]
        u = np.array([c[i] for c, i in zip(final.coords, index)])
        photons = f.photons(problem.space.surface(problem.point(u)))
        mu, _ = f.waveform(photons, e.v)
        curves.append(_curve(problem, mu, e.fit.overall))
    curves = np.array(curves)
    return np.percentile(curves, 16, axis=0), np.percentile(curves, 84, axis=0)


def _curve(problem, mu, amplitude):
    """The expected waveform at amplitude A on the fine grid: mV (baseline + A μ), or for a
    photon-counting receiver recorded counts per histogram bin per shot ((d_r + ρ) Δ, dead
    time and jitter applied: :mod:`.counting`)."""
    f = problem.forward
    if f.counting:
        recording = problem.shots.recording
        return (recording.background + recording.level(mu, amplitude)) * f.interval
    return f.baseline + amplitude * mu


def _check_fit(chi2: float, loglike: float, dof: int, shots: int, free: int, source) -> None:
    """Refuse a best fit that cannot be trusted, instead of printing intervals from it.

    Raises
    ------
    ConfigError
        The log-likelihood or chi2 of the best fit is not finite (samples far outside what the
        receiver can record), or the fit has fewer samples than parameters (negative degrees
        of freedom): one line saying which.
    """
    if not (math.isfinite(chi2) and math.isfinite(loglike)):
        raise ConfigError(f"the best fit has chi2 {chi2:g} and log-likelihood {loglike:g}; "
                          "both must be finite: the observed samples are not what the "
                          "receiver records (check the file and --instrument)", key=source)
    if dof < 0:
        raise ConfigError(f"the fit has {dof} degrees of freedom: {shots} shot(s) hold fewer "
                          f"samples than the fit's parameters (2 per shot -- amplitude and "
                          f"delay --, 2 nuisances, {free} free key(s)); give more samples or "
                          "shots, or fix keys with --fix", key=source)


def dof_bound(counting: bool, shots: int, samples: int, free: int) -> int:
    """The most degrees of freedom the fit can have, from counts known before the search.

    Parameters
    ----------
    counting : bool
        A photon-counting receiver (one histogram of ``samples`` bins, Pearson groups).
    shots : int
        Shots used.
    samples : int
        Samples (or histogram bins) per shot.
    free : int
        Free swept keys.

    Returns
    -------
    int
        Linear mode: ``shots samples - 2 shots - 2 - free`` (a per-shot amplitude and delay,
        two nuisances); photon counting: ``samples - 3 - free`` (A, δ, v). The fit's own
        count (:func:`build_result`) is at most this: censored samples and merged groups
        only lower it.
    """
    if counting:
        return samples - 3 - free
    return shots * samples - 2 * shots - 2 - free


def check_dof(dof: int, shots: int, samples: int, free: int, counting: bool, source) -> None:
    """Refuse, before any work, a fit that would have negative degrees of freedom
    (:func:`dof_bound`).

    Raises
    ------
    ConfigError
        One line: the counts, the parameters and what to do.
    """
    if dof >= 0:
        return
    if counting:
        held = (f"{samples} histogram bin(s) are fewer than the fit's parameters (3 "
                f"nuisances -- amplitude, delay, broadening --, {free} free key(s))")
    else:
        held = (f"{shots} shot(s) of {samples} sample(s) hold fewer samples than the fit's "
                f"parameters (2 for each shot -- amplitude and delay --, 2 nuisances, {free} "
                "free key(s))")
    raise ConfigError(f"the fit would have {dof} degrees of freedom: {held}; give more samples "
                      "or shots, or fix keys with --fix", key=source)


def build_result(obs, params, space, problem, nodes, final, summary, used, *, db_source,
                 db_attrs, fixed=None):
    """The output Dataset (see the module docstring of :mod:`warpe_cl.inversion.invert`).

    ``fixed``: every ``--fix`` key or nuisance -> its value with its unit (``"500 mm"``), as
    recorded in the attribute ``fixed`` (default: the space's fixed values, in its units).
    """
    import xarray as xr

    f = problem.forward
    best = summary["best"]
    photons = f.photons(space.surface(problem.point(summary["best_u"])))
    mu, _ = f.waveform(photons, best.v)
    fit = best.fit          # the nuisances of the evaluation that ranked the best point
    low, high = _band(problem, final)
    n_shots = int(used.sum())
    if f.counting:          # Pearson groups less A, δ, v and the free axes
        dof = fit.samples - 3 - len(space.free_axes)
        unit, suffix = "counts", "counts"
        expected = np.broadcast_to(problem.shots.expected(mu, fit.overall, fit.arrival[0]),
                                   (n_shots, obs.time_ns.size))
    else:
        dof = fit.samples - 2 * n_shots - 2 - len(space.free_axes)
        unit, suffix = "mV", "mv"
        expected = f.baseline + fit.amplitude[:, None] * problem.shots._interp(mu, fit.arrival)
        expected = np.minimum(expected, f.ceiling)
    _check_fit(fit.chi2, best.loglike, dof, n_shots, len(space.free_axes), obs.source)
    rows = [r for r in summary["rows"] if r["reported"]]
    names = [r["key"] for r in rows]
    data = {}
    # median and intervals first, the best grid point after them (issue 41)
    for col in ("median", "low68", "high68", "low95", "high95"):
        data[col] = ("parameter", np.array([r[col] for r in rows], float))
    extra, extra_coords, extra_attrs = measure_variables(summary["measure"], summary["rows"])
    for col in ("bound", "bound95", "width_ratio", "kl_divergence"):
        data[col] = extra.pop(col)
    data["constrained"] = ("parameter", data["width_ratio"][1] < CONSTRAINED)
    data["truth"] = extra.pop("truth")
    for col in ("best", "prior_low", "prior_high", "interval_fraction"):
        data[col] = ("parameter", np.array([r[col] for r in rows], float))
    data["units"] = ("parameter", np.array([r["units"] for r in rows]))
    data["log_scale"] = ("parameter", np.array([r["scale"] == "log" for r in rows]))
    data["scale"] = ("parameter", np.array([r["scale"] for r in rows]), {
        "long_name": "interpolation coordinate, in which the prior is uniform: linear (the "
                     "value), log (ln value) or log1m (-ln(1 - value))"})
    coords = {"parameter": ("parameter", np.array(names), {
        "long_name": "swept dotted key of the database, in its unit (m, 1, ...)"})}
    for j, (axis, row) in enumerate(zip(space.free_axes, summary["rows"])):
        dim = f"grid_{axis.short}"
        coords[dim] = (dim, axis.values, {"units": axis.units, "sweep_key": axis.key})
        data[f"marginal_{axis.short}"] = (dim, row["node_mass"], {
            "long_name": f"marginal posterior of {axis.key} on the grid values "
                         "(mass of the refined grid gathered on the nearest node)"})
        fine = f"posterior_{axis.short}"
        coords[fine] = (fine, axis.value(final.coords[j]), {"units": axis.units,
                                                             "sweep_key": axis.key})
    data.update(extra)
    coords.update(extra_coords)
    data["posterior"] = (tuple(f"posterior_{a.short}" for a in space.free_axes),
                         final.weights(), {"long_name": "posterior mass on the refined grid"})
    data["loglike_nodes"] = (tuple(f"grid_{a.short}" for a in space.free_axes), nodes.loglike,
                             {"long_name": "log-likelihood at the database's nodes"})
    arrival = fit.arrival
    shot_index = np.nonzero(used)[0]
    coords.update({
        "shot": ("shot", shot_index, {"long_name": "index of the shot in the observed file"}),
        "sample_time": ("sample_time", obs.time_ns, {"units": "ns"}),
        "fit_time": ("fit_time", f.t, {"units": "ns",
                                       "long_name": "model time from the fitted arrival"}),
    })
    data.update({
        "amplitude": ((), fit.overall, {"long_name": "overall amplitude A relative to the "
                                                     "instrument's radiometry"}),
        "shot_amplitude": ("shot", fit.amplitude, {"long_name": "a_s = A x speckle factor"}),
        "shot_arrival": ("shot", arrival, {"units": "ns", "long_name":
                                           "arrival of each shot (range offset + phase)"}),
        "arrival_time": ((), float(np.median(arrival)), {"units": "ns"}),
        "arrival_plus_sampling_phase": ((), float(np.median(arrival)) * C_M_PER_NS / 2.0,
                                        {"units": "m"}),
        "broadening_variance": ((), best.v, {"units": "ns2", "long_name":
                                             "v: change of the pulse and footprint variance"}),
        "pulse_fwhm": ((), f.fwhm_of(best.v) if f.gaussian_pulse else np.nan, {
            "units": "ns", "long_name": "pulse FWHM equivalent to v at the nominal footprint"}),
        "footprint_sigma": ((), f.footprint_of(best.v), {
            "units": "ns", "long_name": "footprint sigma_g equivalent to v at the nominal pulse"}),
        f"observed_{suffix}": (("shot", "sample_time"), obs.shots[used], {"units": unit}),
        f"expected_{suffix}": (("shot", "sample_time"), np.array(expected), {
            "units": unit, "long_name": "best-fit expected samples of each shot"
                                        + (" (per histogram bin)" if f.counting else "")}),
        f"fit_{suffix}": ("fit_time", _curve(problem, mu, fit.overall), {
            "units": unit, "long_name": "best-fit expected waveform, amplitude A"
                                        + (", per bin width and shot" if f.counting else "")}),
        f"fit_low68_{suffix}": ("fit_time", low, {"units": unit}),
        f"fit_high68_{suffix}": ("fit_time", high, {"units": unit}),
        "chi2": ((), fit.chi2),
        "dof": ((), dof),
        "chi2_per_dof": ((), fit.chi2 / dof if dof > 0 else np.nan),
        "p_value": ((), float(chdtrc(dof, fit.chi2)) if dof > 0 else np.nan, {
            "long_name": "P(chi2 >= observed) for the best fit"}),
        "censored_samples": ((), fit.censored),
        "loglike": ((), best.loglike),
        "loglike_database_error": ((), fit.emulator),
        "loglike_database_sd": ((), fit.emulator_sd),
    })
    if "adequacy" in summary:
        ad = summary["adequacy"]
        data["loglike_database_sd_monte_carlo"] = ((), ad["sigma_monte_carlo"])
        data["loglike_database_sd_time_bins"] = ((), ad["sigma_time_bins"])
        data["loglike_database_sd_interpolation"] = ((), ad["sigma_interpolation"])
    attrs = provenance({
        "title": "warpe-cl inversion",
        "observed": obs.source,
        "observed_attrs": json.dumps({k: str(v) for k, v in obs.attrs.items()}),
        "instrument_name": params["name"],
        "database": db_source,
        "database_fingerprint": str(db_attrs.get("sweep_fingerprint", "")),
        "fixed": json.dumps(fixed if fixed is not None else
                            {**space.fixed, **{k: f"{v:g} {space.axis(k).units}"
                                               for k, v in space.point.items()}}),
        "marginalised": json.dumps([r["key"] for r in summary["rows"] if not r["reported"]]),
        "database_error": _database_error(problem.emulator),
        "database_adequacy": summary["adequacy"]["advice"] if "adequacy" in summary else
        "not assessed (the database taken as exact)",
        "shots_total": int(used.size),
        "shots_used": n_shots,
        "evaluations": summary["evaluations"],
        "elapsed_s": round(summary["elapsed_s"], 3),
        **extra_attrs,
        "method": "grid posterior (docs/inversion.md): uniform prior in each axis' "
                  "interpolation coordinate; "
                  + ("aggregated photon-count histogram, Poisson; common arrival integrated, "
                     "amplitude profiled; " if f.counting else
                     "per-shot amplitude and arrival by Laplace (arrival integrated for "
                     "clipped shots); ")
                  + "pulse/footprint broadening profiled",
    })
    return describe(xr.Dataset(data, coords=coords, attrs=attrs))


def _database_error(emulator) -> str:
    """How the database's own error entered the likelihood, in words (FIT.nc attribute)."""
    if emulator is None:
        return "not included: the database is taken as exact"
    text = ("integrated out: the nodes' Monte Carlo errors and the leave-one-out interpolation "
            "error (docs/inversion.md §4.3)")
    if emulator.unmeasured:
        text += ("; no interpolation estimate along " + ", ".join(emulator.unmeasured)
                 + " (two grid values)")
    return text


#: CF-style ``long_name`` and ``units`` of every variable and coordinate of FIT.nc that
#: :func:`build_result` does not describe where it makes it (``units`` "1": a number or flag
#: without dimension, or text). ``None`` as units: the parameter's own unit, per row of
#: ``units`` (one name for all rows when they share it).
DESCRIPTIONS = {
    "best": ("parameter value at the best grid point (largest log-likelihood); a corner of a "
             "flat ridge can lie outside its own intervals: read median and intervals", None),
    "median": ("posterior median of the parameter", None),
    "low68": ("lower bound of the equal-tailed 68 % posterior interval", None),
    "high68": ("upper bound of the equal-tailed 68 % posterior interval", None),
    "low95": ("lower bound of the equal-tailed 95 % posterior interval", None),
    "high95": ("upper bound of the equal-tailed 95 % posterior interval", None),
    "prior_low": ("lower end of the uniform prior: the database's smallest grid value", None),
    "prior_high": ("upper end of the uniform prior: the database's largest grid value", None),
    "interval_fraction": ("share of the prior range (in the interpolation coordinate) spanned "
                          "by the 95 % interval", "1"),
    "constrained": ("whether width_ratio < 0.5: the 95 % interval is narrower than half the "
                    "prior's 95 % interval", "1"),
    "units": ("unit of the parameter's values (text)", "1"),
    "log_scale": ("whether the interpolation coordinate is ln(value)", "1"),
    "scale": (None, "1"),
    "parameter": (None, "1"),
    "posterior": (None, "1"),
    "loglike_nodes": (None, "1"),
    "amplitude": (None, "1"),
    "shot_amplitude": ("amplitude of each shot a_s: the overall amplitude A times its speckle "
                       "factor", "1"),
    "shot_arrival": ("arrival of each shot: the delay of its model waveform, the range offset "
                     "plus the unknown ADC sampling phase of the shot", "ns"),
    "arrival_time": ("median shot arrival: the range offset plus the unknown ADC sampling "
                     "phase (up to one sampling interval), not a surface delay", "ns"),
    "arrival_plus_sampling_phase": (
        "median shot arrival as a one-way distance c t / 2: the range offset plus the unknown "
        "ADC sampling phase (up to c/2 times one sampling interval; the return is not locked "
        "to the ADC clock), not a range to the surface", "m"),
    "broadening_variance": (None, "ns2"),
    "chi2": ("chi-square of the best fit over the unclipped samples (Pearson groups for "
             "photon counts)", "1"),
    "dof": ("degrees of freedom of the best fit", "1"),
    "chi2_per_dof": ("chi-square per degree of freedom of the best fit", "1"),
    "p_value": (None, "1"),
    "loglike": ("log-likelihood of the best fit, the per-shot nuisances integrated out and the "
                "database's own error with them", "1"),
    "loglike_database_error": ("what integrating the database's own error (Monte Carlo, "
                               "time bins and interpolation) out changed the best fit's log-likelihood by",
                               "1"),
    "loglike_database_sd": ("stated error of the best fit's log-likelihood due to the "
                            "database's own error (0: the database taken as exact)", "1"),
    "loglike_database_sd_monte_carlo": ("part of loglike_database_sd due to the nodes' Monte "
                                        "Carlo errors", "1"),
    "loglike_database_sd_time_bins": ("part of loglike_database_sd due to the nodes' time "
                                      "bins (where in its bin each return arrives)", "1"),
    "loglike_database_sd_interpolation": ("part of loglike_database_sd due to the "
                                          "interpolation between nodes", "1"),
    "censored_samples": ("samples at or above the receiver's clipped level, counted as "
                         "censored", "1"),
    "shot": (None, "1"),
    "sample_time": ("nominal time of each sample of a shot", "ns"),
    "fit_time": (None, "ns"),
}


def describe(ds):
    """Give every variable and coordinate of a FIT Dataset a ``long_name`` and ``units``
    (:data:`DESCRIPTIONS`; the marginal, grid and fine-grid coordinates by their key; the
    waveform variables by their suffix ``_mv`` or ``_counts``), keeping any already set.

    Parameters
    ----------
    ds : xarray.Dataset
        The Dataset :func:`build_result` assembles.

    Returns
    -------
    xarray.Dataset
        The same Dataset, described in place.
    """
    row_units = [str(u) for u in np.asarray(ds["units"].values)] if "units" in ds else []
    shared = row_units[0] if row_units and len(set(row_units)) == 1 else \
        "per parameter: see the variable units"
    for name in list(ds.variables):
        var = ds[name] if name not in ds.coords else ds.coords[name]
        attrs = var.attrs
        long_name, units = DESCRIPTIONS.get(name, (None, "1"))
        if name.startswith(("grid_", "posterior_")) and "sweep_key" in attrs:
            long_name = (("grid values of " if name.startswith("grid_") else
                          "refined-grid values of ") + attrs["sweep_key"])
        elif name.endswith(("_mv", "_counts")):
            if name.startswith("fit_low68_") or name.startswith("fit_high68_"):
                long_name = (("lower" if "low68" in name else "upper") + " edge of the 68 % band "
                             "of the expected waveform over 64 posterior draws")
            elif name.startswith("observed_"):
                long_name = "observed samples of each shot used"
            units = "mV" if name.endswith("_mv") else "counts"
        if "long_name" not in attrs and long_name is not None:
            attrs["long_name"] = long_name
        if "units" not in attrs:
            attrs["units"] = shared if units is None else units
    return ds
