"""The text reports of the command line: what ``warpe-cl`` prints about a run, an instrument,
the devices and a sweep.

Every function here returns text (a line or a list of lines) and prints nothing; the commands
of :mod:`warpe_cl.cli` decide where and when the lines go (``--quiet``, flushing between slow
steps). Times are in s, lengths in the units named in each line. Lines that show text read
from a file (names, labels, units) are made inert and bounded by
:func:`warpe_cl.errors.printable`: a file's attribute cannot send escape sequences to the
terminal.
"""
from __future__ import annotations

import json

import numpy as np

from .errors import printable
from .inversion.identifiability import verdict
from .plot import cases_of

__all__ = ["point_text", "derived_lines", "run_header", "scenario_lines", "instrument_lines",
           "device_status_lines", "verdict_line", "device_choice_line", "sweep_start_line",
           "sweep_summary_lines"]


def point_text(point: dict) -> str:
    """A sweep point as ``key=value, key=value`` (empty for a preset without sweep)."""
    return ", ".join(f"{k}={v}" for k, v in point.items())


# --------------------------------------------------------------------------- run, show-config

def derived_lines(d: dict) -> list:
    """The derived radiative parameters of one scenario, indented two spaces.

    Parameters
    ----------
    d : dict
        :func:`warpe_cl.radiative.radiative_parameters`: ``extinction_per_m`` in m-1,
        ``thickness_m`` (printed in mm), ``first_bf_time_ns`` in ns, ``grain_size_m`` of each
        species (printed in um), ``number_density_per_m3`` in m-3.

    Returns
    -------
    list of str
    """
    omega, ext = d["omega"], d["extinction_per_m"]
    return [
        f"  tau0              {d['tau0']:.6g}",
        f"  omega             {omega:.6g}",
    ] + ([f"  1 - omega         {1.0 - omega:.3g}"] if omega > 0.999 else []) + [
        f"  extinction        {ext:.6g} m-1",
        f"  mean free path    {_length(1.0 / ext) if ext > 0 else 'inf'}  (1/E)",
        f"  absorption length "
        f"{_length(1.0 / ((1.0 - omega) * ext)) if ext > 0 and omega < 1 else 'inf'}"
        "  (1/((1 - omega) E))",
        f"  n_eff, k_eff      {d['n_eff']:.6g}, {d['k_eff']:.4g}",
        f"  thickness         {d['thickness_m'] * 1e3:.6g} mm",
        f"  first BF time     {d['first_bf_time_ns']:.6g} ns  (2 h n_eff / c)",
        f"  specular R0       {d['specular_r0']:.6g}",
    ] + ([f"  porosity factor   {d['porosity_factor']:.6g}   matrix absorption "
          f"{d['matrix_absorption_per_m']:.6g} m-1"] if "porosity_factor" in d else []) + [
        f"  {sp['material']:<8s}          rho_v {sp['proportion']:.4g}  d {sp['grain_size_m'] * 1e6:.4g} um"
        f"  N {sp['number_density_per_m3']:.4g} m-3  n_rel {sp['n_rel']:.5g}  w {sp['w']:.6g}"
        for sp in d.get("species", [])] + _rescaled(d.get("species", []))


def _length(metres: float) -> str:
    """A length with a readable unit: km, m, mm or um."""
    for scale, unit in ((1e3, "km"), (1.0, "m"), (1e-3, "mm")):
        if metres >= scale:
            return f"{metres / scale:.4g} {unit}"
    return f"{metres * 1e6:.4g} um"


def _rescaled(species: list) -> list:
    """One line when the given proportions do not sum to 1 and were rescaled."""
    given = [sp.get("proportion_given", sp["proportion"]) for sp in species]
    if not species or abs(sum(given) - 1.0) <= 1e-9:
        return []
    pairs = ", ".join(f"{g:.4g} -> {sp['proportion']:.4g}" for g, sp in zip(given, species))
    return [f"  proportions given sum to {sum(given):.6g}: rescaled to sum to 1 ({pairs})"]


def run_header(cfg, scenarios: int) -> str:
    """The first line of ``warpe-cl run``: preset, source, scenarios, rays each, seed."""
    return (f"warpe-cl run: {cfg.get('name')} ({cfg.source}), {scenarios} scenario(s), "
            f"{int(cfg.get('simulation.photons')):,} rays each, seed {cfg.get('simulation.seed')}")


def scenario_lines(ds, build_s: float = 0.0, walk_s: float | None = None) -> list:
    """What one simulated scenario gave: device, fates, components, wall time (s) and speed.

    Parameters
    ----------
    ds : xarray.Dataset
        One scenario of :func:`warpe_cl.api.simulate_point`.
    build_s : float
        Seconds of the wall time spent qualifying and building the kernel on its first use
        (the engine's ``last_build_s``): said apart, and left out of the speeds.
    walk_s : float, optional
        Seconds of the walk itself (the engine's ``last_walk_s``): the speeds are rays and
        scattering events per second of it. None: the wall time less ``build_s``.

    Returns
    -------
    list of str
    """
    photons = int(ds["photons"])
    wall = float(ds["wall_time"])
    build_s = build_s if 0.0 <= build_s < wall else 0.0
    walk_given = walk_s is not None and 0.0 < walk_s <= wall
    if not walk_given:
        walk_s = wall - (build_s if build_s >= 0.05 else 0.0)
    walk = max(walk_s, 1e-9)            # the speeds: per second of the walk, not of the build
    events = int(ds["scattering_events"])
    return [
        f"  device            {ds.attrs.get('opencl_device', '?')} ({ds.attrs.get('engine')}, "
        f"{ds.attrs.get('precision')} precision)",
        "  fates             " + "  ".join(
            f"{f} {v:.5f}" for f, v in zip(ds["fate"].values, ds["fate_fraction"].values)),
        "  components        " + "  ".join(
            f"{c} {v:.5f}" for c, v in zip(ds["component"].values, ds["fraction"].values)),
        f"  time              {wall:.2f} s" + (
            f", kernel build {build_s:.1f} s (first use)" if build_s >= 0.05 else "")
        + (f", walk {walk:.2f} s" if walk_given else "")
        + f"   {photons / walk:,.0f} photons/s   {events / walk:,.0f} scattering events/s",
    ]


# --------------------------------------------------------------------------- instrument

def instrument_lines(ds) -> list:
    """What the instrument recorded, case by case: photons at the aperture per part, the
    expected peak (mV) and noise, or photons recorded per shot (with their expectation and
    the share the dead times take), detection, range and width (ns).

    Parameters
    ----------
    ds : xarray.Dataset
        A result of :func:`warpe_cl.instrument.apply_instrument`.

    Returns
    -------
    list of str
    """
    def attr(key):   # a value that differs between scenarios is dropped from a combined file
        return ds.attrs.get(f"instrument_{key}", "per scenario")
    lines = [f"instrument {attr('name')}: altitude {attr('geometry_altitude')}, roughness "
             f"{attr('geometry_roughness')}, {ds.sizes.get('shot', 0)} shots"]
    for label, sc in cases_of(ds):
        parts = "  ".join(f"{p} {v:.3g}" for p, v in zip(sc["part"].values,
                                                       sc["photons_at_aperture"].values))
        lines.append(f"  {label or 'scenario'}")
        lines.append(f"    photons at aperture   {parts}")
        if "signal_mv" in sc:
            lines.append(
                f"    expected peak         {float(sc['expected_analog_mv'].max()):.4g} mV "
                f"(unclipped), noise {float(sc['noise_mv']):.3g} mV, saturated shots "
                f"{float(sc['saturated'].mean()):.2f}")
        else:
            line = f"    photons recorded      {float(sc['photon_count'].mean()):.3g} per shot"
            if "dead_time_loss" in sc:    # files of older versions lack it
                after = float(sc["expected_recorded_counts"].sum())
                exact = bool(sc["dead_time_loss_exact"])
                lost = 100.0 * float(sc["dead_time_loss"])
                line += (f" (expected {'' if exact else 'at most '}{after:.3g}; the dead times "
                         f"take {'' if exact else 'at least '}{lost:.0f} %)")
            lines.append(line)
        detected = sc["detected"].any()
        lines.append(
            f"    detected              {float(sc['detected'].mean()):.2f} of shots; range "
            f"{float(np.nanmean(sc['range_time'])) if detected else float('nan'):.3g} ns, "
            f"width {float(np.nanmean(sc['pulse_width'])) if detected else float('nan'):.3g} ns")
    return [printable(line) for line in lines]     # names and labels come from the file


# --------------------------------------------------------------------------- devices

def device_status_lines(reason: str | None, status=None) -> list:
    """The lines under a device of ``warpe-cl devices``: why it is not usable, or its
    qualification (lanes, speed on scene B1, date, seconds taken) and the widths that failed.

    Parameters
    ----------
    reason : str or None
        Why the self-test program does not build (:func:`warpe_cl.device.probe`), or None.
    status : optional
        The device's qualification (:func:`warpe_cl.qualify.qualification`) where it builds.

    Returns
    -------
    list of str
    """
    if reason is not None:
        return [f"      NOT usable: {reason}"]
    if not status.usable:
        return [f"      NOT usable: {status.reason}"]
    speed = (f"{status.events_per_s:.3g} scattering events/s on scene B1"
             if status.events_per_s else "speed not measured")
    return ([f"      qualified: {status.lanes} lane{'s' if status.lanes > 1 else ''}, {speed} "
             f"(single precision; checked {status.date or '?'} in {status.seconds or 0:.1f} s)"]
            + [f"      failed at {lanes} lanes: {why}" for lanes, why in status.failures]
            + [f"      not checked yet at {lanes} lanes"
               + (f": {why.removeprefix('not checked yet: ')}" if why else "")
               + " (checked again after a day, or with `warpe-cl devices --requalify`)"
               for lanes, why in getattr(status, "unchecked", ())])


def verdict_line(combo, lanes: int | None, failures, unchecked=()) -> str:
    """One kernel combination of ``warpe-cl devices``: its widest qualified lane width, the
    widths that failed (with why) and those not checked yet.

    Parameters
    ----------
    combo : warpe_cl.qualify.Combo
    lanes : int or None
        The widest qualified width (``None`` or 0: none).
    failures : sequence of (int, str)
        Widths that failed, with why.
    unchecked : sequence of (int, str or None)
        Widths not checked yet: never checked (``None``), or a check that came to no verdict
        (timed out, killed from outside), with why.

    Returns
    -------
    str
        ``"        slab:double:weighted       4 lanes, qualified; failed at 8: ..."``; a
        combination of which nothing is known reads ``not checked yet``.
    """
    never = [w for w, r in unchecked if r is None]
    stopped = [(w, r) for w, r in unchecked if r is not None]
    if lanes:
        verdict = f"{lanes} lanes, qualified"
    elif failures and not unchecked:
        verdict = "NOT usable (failed at every lane width)"
    elif failures or stopped:
        verdict = "no lane width qualified yet"
    else:
        return f"        {combo.label:26s} not checked yet"
    verdict += "".join(f"; failed at {w}: {r}" for w, r in failures)
    verdict += "".join(f"; not checked yet at {w}: {r.removeprefix('not checked yet: ')}"
                       for w, r in stopped)
    if never:
        verdict += f"; not checked yet at {', '.join(str(w) for w in never)}"
    return f"        {combo.label:26s} {verdict}"


def device_choice_line(spec: str, info) -> str:
    """The last line of ``warpe-cl devices``: the device ``spec`` resolves to."""
    return (f"--device {spec} picks {info.spec} ({info.device}, {info.platform} "
            f"{info.platform_version})")


# --------------------------------------------------------------------------- sweep

def sweep_start_line(summary, name: str, source, shard, to_run: int, engine: str) -> str:
    """The first line of ``warpe-cl sweep``: the grid, this shard's part, what is already done,
    what runs where, and the database folder.

    Parameters
    ----------
    summary : SweepSummary
        Before any scenario ran (:class:`warpe_cl.sweep.SweepSummary`).
    name, source : str
        The preset's name and file.
    shard : (int, int) or None
    to_run : int
        Scenarios this run computes.
    engine : str
        Where they run (:attr:`warpe_cl.workers.Workers.text`).
    """
    return (f"warpe-cl sweep: {name} ({source}), {summary.total} scenario(s) in the grid"
            + ("" if shard is None else f", {summary.owned} in shard {shard[0]}/{shard[1]}")
            + f"; {summary.skipped} already done, {to_run} to run, "
              f"{len(summary.failed)} invalid; {engine}; database {summary.folder}")


def sweep_summary_lines(summary) -> list:
    """The end of ``warpe-cl sweep``: counts, wall time (s), photons/s, the grid's scenarios in
    the folder, and the combined file where one was written.

    Parameters
    ----------
    summary : SweepSummary
        What :func:`warpe_cl.sweep.run_sweep` returned.

    Returns
    -------
    list of str
    """
    rate = summary.photons / summary.wall_time_s if summary.wall_time_s > 0 else 0.0
    lines = [f"warpe-cl sweep: {summary.done} done, {summary.skipped} skipped (already in the "
             f"folder), {len(summary.failed)} failed"
             + (f", {summary.pending} not finished" if summary.pending else "")
             + f"; {summary.wall_time_s:.2f} s, {rate:,.0f} photons/s; "
               f"{summary.finished_in_folder} of {summary.total} scenarios of the grid in "
               f"{summary.folder}"]
    if summary.combined is not None:
        lines.append(f"wrote {summary.combined} (all {summary.total} scenarios)")
    return lines


def inversion_lines(ds) -> list:
    """The result of ``warpe-cl invert``, what the data measure first: each parameter's
    median and intervals (a one-sided bound where the posterior reaches a prior edge), how
    much of its prior the data rule out, the derived quantities, the degenerate pairs, then
    the best grid point, the truth when known, the nuisances and the goodness of fit
    (docs/inversion.md §6). Values in the unit of the database; lengths as :func:`_length`
    writes them.

    Parameters
    ----------
    ds : xarray.Dataset
        A result of :func:`warpe_cl.inversion.invert.invert`.

    Returns
    -------
    list of str
    """
    return [printable(line) for line in
            [_channel_head(ds, "inversion")] + posterior_lines(ds) + fit_lines(ds)]


def _channel_head(ds, what: str) -> str:
    """``WHAT: N of M shots, INSTRUMENT, database DB``."""
    return (f"{what}: {ds.attrs['shots_used']} of {ds.attrs['shots_total']} shots, "
            f"{ds.attrs['instrument_name']}, database {ds.attrs['database']}")


def joint_lines(fits, notes=None) -> list:
    """The result of ``warpe-cl invert --joint``: the joint posterior once, then each
    channel's nuisances and goodness of fit, and the joint log evidence.

    Parameters
    ----------
    fits : list of xarray.Dataset
        The channels' FIT Datasets (:func:`warpe_cl.inversion.joint.invert_joint`).
    notes : list of list of str, optional
        Further lines per channel (its checks and warnings), said after its fit.

    Returns
    -------
    list of str
    """
    first = fits[0]
    lines = [f"joint inversion of {len(fits)} channels (one surface; log L summed, each "
             "channel's nuisances its own)"] + posterior_lines(first)
    for i, ds in enumerate(fits):
        wavelength = json.loads(ds.attrs["joint"])[i]["wavelength_nm"]
        lines.append(_channel_head(ds, f"  channel at {wavelength:g} nm")
                     + f", ln L at the best point {float(ds['loglike']):.6g}")
        lines += ["  " + line for line in fit_lines(ds) + (list(notes[i]) if notes else [])]
    lines.append(f"  joint ln Z {float(first['log_evidence']):.6g}; "
                 f"{first.attrs['joint_evaluations']} model evaluations in "
                 f"{first.attrs['elapsed_s']:.2f} s")
    return [printable(line) for line in lines]


def posterior_lines(ds) -> list:
    """The posterior part of :func:`inversion_lines`: each parameter's median and intervals,
    the derived quantities, the degenerate pairs, the best grid point and the truth."""
    def show(value, units):
        if not np.isfinite(value):
            return "nan"
        if units == "m":
            return _length(value)
        return f"{value:.4g}" + ("" if units in ("1", "") else f" {units}")

    def bound(kind, limit, units):
        kind = int(kind)
        if kind == 1:
            return f"> {show(limit, units)} (95 %)"
        if kind == 2:
            return f"< {show(limit, units)} (95 %)"
        return ""

    def measured(ratio, kl):
        return f"width {ratio:.2f} of the prior's, KL {kl:.2f} nats: {verdict(ratio)}"

    lines = []
    for key in ds["parameter"].values:
        r = ds.sel(parameter=key)
        u = str(r["units"].values)
        head = bound(r["bound"], float(r["bound95"]), u) if "bound" in r else ""
        if "bound" in r and int(r["bound"]) == 3:
            head = "reaches both prior edges"
        text = (f"  {key:<34} {head + '   ' if head else ''}median "
                f"{show(float(r['median']), u)}   68 % [{show(float(r['low68']), u)}, "
                f"{show(float(r['high68']), u)}]   95 % [{show(float(r['low95']), u)}, "
                f"{show(float(r['high95']), u)}]")
        if "width_ratio" in r:
            text += "   " + measured(float(r["width_ratio"]), float(r["kl_divergence"]))
        lines.append(text)
    if "derived" in ds.coords:
        lines.append("  derived quantities (posterior over the same grid, docs/inversion.md "
                     "§6.1):")
        for name in ds["derived"].values:
            r = ds.sel(derived=name)
            u = str(r["derived_units"].values)
            head = bound(r["derived_bound"], float(r["derived_bound95"]), u)
            if int(r["derived_bound"]) == 3:
                head = "reaches both prior edges"
            ratio = float(r["derived_width_ratio"])
            lines.append(
                f"    {name:<32} {head + '   ' if head else ''}median "
                f"{show(float(r['derived_median']), u)}   68 % "
                f"[{show(float(r['derived_low68']), u)}, {show(float(r['derived_high68']), u)}]"
                f"   95 % [{show(float(r['derived_low95']), u)}, "
                f"{show(float(r['derived_high95']), u)}]   "
                + measured(ratio, float(r["derived_kl_divergence"])))
    for line in json.loads(ds.attrs.get("degeneracy", "[]")):
        lines.append(f"  {line}")

    def each(name):
        return [(k, float(ds[name].sel(parameter=k)), str(ds["units"].sel(parameter=k).values))
                for k in ds["parameter"].values]
    best = ", ".join(f"{k} {show(x, u)}" for k, x, u in each("best"))
    lines.append(f"  best grid point (largest log L; may sit on a flat ridge): {best}")
    if "truth" in ds and np.isfinite(ds["truth"].values).any():
        known = ", ".join(f"{k} {show(x, u)}" for k, x, u in each("truth") if np.isfinite(x))
        lines.append(f"  truth ({ds.attrs.get('truth_source', '')}): {known}")
    return lines


def fit_lines(ds) -> list:
    """The channel part of :func:`inversion_lines`: the nuisances, the goodness of fit and
    the database's adequacy for these shots."""
    lines = []
    lines.append(f"  nuisances: amplitude {float(ds['amplitude']):.3g}, pulse FWHM "
                 f"{float(ds['pulse_fwhm']):.3g} ns (or footprint sigma "
                 f"{float(ds['footprint_sigma']):.3g} ns), arrival {float(ds['arrival_time']):.3g} ns")
    lines.append(f"  fit: chi2/dof {float(ds['chi2_per_dof']):.3f} ({int(ds['dof'])} dof), "
                 f"p = {float(ds['p_value']):.3g}; {ds.attrs['evaluations']} model evaluations "
                 f"in {ds.attrs['elapsed_s']:.2f} s")
    if "database_adequacy" in ds.attrs:
        lines.append(f"  {ds.attrs['database_adequacy']}")
    return lines
