#!/usr/bin/env python3
"""Run every paper preset and draw every figure of the paper (Barron et al. 2026).

    python tools/reproduce_paper.py [--photons N] [--out docs/figures] [--only NAME ...]

Writes ``NAME.nc`` (in --data, default a temporary folder) and ``NAME.png`` for each preset of
``presets/paper/`` (plus ``fov_numerical_angular.png``, the FOV figure, and
``bela_cases_instrument.png``, the paper's three-panel BELA figure, whose claims it checks and
prints), and prints the time each took: its simulation, and its files and figures. ``--photons``
overrides every preset's ray count per scenario (the presets' own counts are used otherwise).

The files and figures (single-threaded Python: h5netcdf, matplotlib, the BELA instrument chain)
are made in worker processes while the next presets walk, so that they use the cores the walk
leaves: where the walks run on a GPU, one fewer than the machine's cores (at most one per
preset after the first), so that the files of every preset are written side by side; where
they run on a CPU device, which takes every core, one worker takes them in turn.
``--workers N`` sets their number; ``--serial`` makes each in this process before the next
walk starts (the same files).

It also writes ``metrics.csv`` next to the figures: the waveform metrics of every result
(``warpe_cl.metrics``: mean delay and RMS width in ns, each with its standard error), one row
per preset, scenario, variable (``reflectance``, in the component's field of view, as the
figures draw it; ``hemispherical_reflectance``, at any angle) and diffuse component
(scattering, bf_diffuse) holding rays. The specular and BF-direct returns are left out: they
are delta-like, at exact times (t = 0, 2 k h n_eff / c), which their binned centroid would
only blur by a bin width. The rows of presets not run (``--only``) are kept from an existing
file.

And an entry per preset in ``provenance.json`` (tools/figure_provenance.py): the tree, rays
and device that made its figure, and the check bits that tests/test_metrics.py compares with
what the code gives now.
"""
from __future__ import annotations

import argparse
import csv
import multiprocessing
import os
import sys
import tempfile
import time
import warnings
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path

import warpe_cl
from warpe_cl import io
from warpe_cl.api import get_engine, reusing_walks
from warpe_cl.catalog import presets_dir
from warpe_cl.plot import plot_angular, plot_waveform

from figure_provenance import write_provenance


#: The columns of metrics.csv: ``rays`` launched; ``fraction`` of them in the component (any
#: angle); ``waveform_rays`` in the waveform measured (a few: the errors mean little); times
#: in ns.
METRICS_COLUMNS = ("preset", "scenario", "label", "variable", "component", "rays", "fraction",
                   "waveform_rays", "mean_delay_ns", "mean_delay_stderr_ns", "rms_width_ns", "rms_width_stderr_ns")
METRICS_VARIABLES = ("reflectance", "hemispherical_reflectance")
#: The diffuse components: the specular and BF-direct returns are delta-like (their times are
#: exact), and a centroid of their bins would only measure the bin.
METRICS_COMPONENTS = ("scattering", "bf_diffuse")


def metrics_rows(name: str, ds) -> list:
    """The rows of metrics.csv for the result ``ds`` of preset ``name``: ``warpe_cl.metrics``
    of each scenario, for each variable of METRICS_VARIABLES and each component of
    METRICS_COMPONENTS whose waveform holds rays (a finite mean delay); values with 4
    significant digits, errors with 2."""
    import numpy as np
    from warpe_cl.plot import _scenarios
    rows = []
    for i, (label, sc) in enumerate(_scenarios(ds)):
        for variable in METRICS_VARIABLES:
            m = warpe_cl.metrics(sc, stage="surface", variable=variable,
                                 resamples=0)                 # no peak_time error
            for comp in METRICS_COMPONENTS:
                one = m.sel(component=comp)
                if not np.isfinite(float(one["mean_delay"])):
                    continue
                row = {"preset": name, "scenario": i, "label": label, "variable": variable,
                       "component": comp, "rays": int(sc["photons"]),
                       "fraction": f"{float(sc['fraction'].sel(component=comp)):.4g}",
                       "waveform_rays": _waveform_rays(sc, variable, comp)}
                for key in ("mean_delay", "rms_width"):
                    row[f"{key}_ns"] = f"{float(one[key]):.4g}"
                    row[f"{key}_stderr_ns"] = f"{float(one[f'{key}_stderr']):.2g}"
                rows.append(row)
    return rows


def _waveform_rays(sc, variable: str, comp: str):
    """Rays in the binned waveform of one component: ``ray_count`` for ``reflectance``; for
    ``hemispherical_reflectance`` of an analog walk, its sum x bin width x rays launched
    (weights of 1); else an empty field."""
    import numpy as np
    if variable == "reflectance":
        return int(sc["ray_count"].sel(component=comp).sum())
    if sc.attrs.get("mode") != "analog":
        return ""
    width = np.diff(sc["time_edges"].values)
    held = float(np.nansum(sc[variable].sel(component=comp).values * width))
    return int(round(held * float(sc["photons"])))


def write_metrics(rows: list, path: Path) -> Path:
    """Write ``rows`` to the CSV ``path``, keeping the rows an existing file holds for the
    presets that ``rows`` lacks; rows sorted by preset, in their own order within one."""
    presets = {r["preset"] for r in rows}
    kept = []
    if path.is_file():
        with open(path, newline="", encoding="utf-8") as f:
            kept = [r for r in csv.DictReader(f) if r["preset"] not in presets]
    merged = sorted(kept + rows, key=lambda r: r["preset"])   # stable: order within a preset
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=METRICS_COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(merged)
    return path


def bela_instrument(ds, out: Path, data: Path, shots: int = 200) -> dict:
    """The paper's BELA figure (fig. WARPE_BELA) and the numbers behind its claims.

    Three cases through the BELA chain at the preset's altitude: the granular CO2 layer, the
    perfect 1500 mm CO2 slab (roughness 0: beam-limited specular) and the same slab with 0.01°
    of roughness (only the lobe changes). Prints and returns the numbers quoted in
    docs/figures/README.md.
    """
    import numpy as np
    from warpe_cl.instrument import apply_instrument, load_instrument
    from warpe_cl.instrument.plot import plot_instrument
    from warpe_cl.units import format_quantity

    # the preset's instrument block, resolved as run, sweep and simulate resolve it
    block = warpe_cl.load_preset(presets_dir() / "paper" / "bela_cases.yaml").instrument
    altitude = format_quantity(block["geometry.altitude"], "length")
    base = {"geometry.altitude": altitude}
    runs = {r: apply_instrument(ds, "bela", dict(base, **{"geometry.roughness": r}), shots=shots)
            for r in ("0 deg", "0.01 deg", "0.1 deg")}
    for r, res in runs.items():
        io.write_netcdf(res, data / f"bela_cases_instrument_{r.split()[0]}deg.nc")
    cases = [("granular CO2 1000 mm", runs["0.01 deg"].isel(scenario=0)),
             ("perfect slab CO2 1500 mm", runs["0 deg"].isel(scenario=1)),
             ("slab, roughness 0.01°", runs["0.01 deg"].isel(scenario=1))]
    plot_instrument(cases, out / "bela_cases_instrument.png",
                    title=f"BELA at {altitude}: {shots} shots, noise seed "
                          f"{runs['0 deg'].attrs['instrument_seed']}")
    facts = {}
    for label, sc in cases + [("slab, roughness 0.1°", runs["0.1 deg"].isel(scenario=1))]:
        analog = sc["expected_analog_mv"].values
        t = sc["fine_time"].values
        facts[label] = {
            "photons": dict(zip(sc["part"].values.tolist(), sc["photons_at_aperture"].values)),
            "unclipped_peak_mv": float(analog.max()),
            "peak_time_ns": float(t[np.argmax(analog)]),
            "saturated_shots": float(sc["saturated"].mean()),
            "detected": float(sc["detected"].mean()),
            "range_ns": float(np.nanmean(sc["range_time"])),
            "width_ns": float(np.nanmean(sc["pulse_width"])),
        }
    # the sampled maximum, as if nothing saturated: over random sampling phases, how often is
    # the largest sample of specular + BF direct (at t_BF, amplitude ratio b) one sample later
    # than that of the specular alone? Gaussian pulses of the template width.
    slab = runs["0 deg"].isel(scenario=1)
    sigma = float(slab["template_width"])
    t_bf = float(slab["first_bf_time_ns"])
    ph = slab["photons_at_aperture"].values
    # the t = 0 specular is in no log bin (ray_count): its rays are early_fraction x photons
    one = ds.isel(scenario=1)
    n_spec = (ds["ray_count"].isel(scenario=1).sel(component="specular").sum().item()
              + round(float(one["early_fraction"].sel(component="specular")) * float(one["photons"])))
    n_bf = ds["ray_count"].isel(scenario=1).sel(component="bf_direct").sum().item()
    ratio = ph[2] / ph[1]
    ratio_se = ratio * np.sqrt(1 / n_spec + 1 / n_bf)

    def later_fraction(b):
        shifts = []
        for phase in np.linspace(0, 12.5, 1000, endpoint=False):
            at = np.arange(-50, 250, 12.5) + phase
            both = np.exp(-0.5 * (at / sigma) ** 2) + b * np.exp(-0.5 * ((at - t_bf) / sigma) ** 2)
            alone = np.exp(-0.5 * (at / sigma) ** 2)
            shifts.append(at[np.argmax(both)] - at[np.argmax(alone)])
        return float(np.mean(np.asarray(shifts) > 12.5 / 2))
    facts["bf_to_specular_ratio"] = (float(ratio), float(ratio_se))
    facts["later_max_sample_fraction"] = {f"{b:.3f}": later_fraction(b) for b in
                                          (ratio - 2 * ratio_se, ratio, ratio + 2 * ratio_se, 1.0)}
    w = slab["photon_rate"].values
    facts["slab_centroid_ns"] = float(np.sum(w * t) / w.sum())
    gran = runs["0 deg"].isel(scenario=0)
    w = gran["photon_rate"].values
    facts["granular_centroid_ns"] = float(np.sum(w * t) / w.sum())
    # roughness: the specular peak against the noise, with the preset's gain (lobe = 2.5 x)
    bela = load_instrument("bela")
    noise = float(runs["0 deg"]["noise_mv"].values[1])
    spec01 = facts["slab, roughness 0.1°"]["unclipped_peak_mv"]
    facts["noise_mv"] = noise
    facts["threshold_mv"] = float(runs["0 deg"]["threshold_mv"].values[1])
    facts["mv_per_pe"] = float(runs["0 deg"]["mv_per_photoelectron"].values[1])
    lobe = bela["geometry.lobe_factor"]
    # the unclipped specular peak scales as 1/tan^2(theta_L) (docs/physics.md §7.3), from the
    # 0.1 deg run; with the preset's lobe factor (2.5: the paper's 0.1 deg -> 0.25 deg) and with
    # 5 (its 0.5 deg -> 2.5 deg point), which the paper's two statements disagree on
    for name, factor in (("roughness_scan", lobe), ("roughness_scan_lobe_factor_5", 5.0)):
        facts[name] = {
            r: spec01 * (np.tan(np.radians(0.1 * lobe)) / np.tan(np.radians(r * factor))) ** 2
            for r in (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)}
    perfect = facts["perfect slab CO2 1500 mm"]["unclipped_peak_mv"]
    rough001 = facts["slab, roughness 0.01°"]["unclipped_peak_mv"]
    facts["gain_window_paper_figure"] = (1000.0 / perfect, 1000.0 / rough001)
    print("bela_cases instrument:")
    for k, val in facts.items():
        print(f"    {k}: {val}")
    return facts


def finish(name: str, ds, out: Path, data: Path) -> tuple:
    """Everything of preset ``name`` after its walk: its NetCDF file, its figures (and, for
    ``bela_cases``, the BELA instrument figure and its facts) and its metrics rows. Returns
    (rows, what it printed, seconds it took)."""
    import contextlib
    import io as text_io
    t0 = time.perf_counter()
    printed = text_io.StringIO()
    with contextlib.redirect_stdout(printed):
        io.write_netcdf(ds, data / f"{name}.nc")
        plot_waveform(ds, out / f"{name}.png")
        if name == "fov_numerical":
            plot_angular(ds, out / "fov_numerical_angular.png")
        if name == "bela_cases":
            bela_instrument(ds, out, data)
        rows = metrics_rows(name, ds)
    return rows, printed.getvalue(), time.perf_counter() - t0


def file_workers(presets: int, asked: int | None = None, cores: int | None = None,
                 gpu: bool = False) -> int:
    """Processes that write the presets' files and figures: ``asked``; or, where the walks run
    on a GPU, the machine's cores less the one that drives them (at least 1); or one, where
    the walks take every core of a CPU device. Never more than the presets after the first
    (the first preset's files cannot start before its walk ends)."""
    if asked is None:
        asked = max(1, (cores or os.cpu_count() or 2) - 1) if gpu else 1
    return max(1, min(asked, presets - 1))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--photons", type=float, default=None, help="rays per scenario")
    p.add_argument("--out", default="docs/figures", help="folder for the PNG figures")
    p.add_argument("--data", default=None, help="folder for the NetCDF results")
    p.add_argument("--only", nargs="*", default=None, help="preset names to run")
    p.add_argument("--device", default=None)
    p.add_argument("--no-nadir", action="store_true",
                   help="walk without the nadir estimate (simulation.nadir: false), as the paper "
                        "did: the same waveform figures; the BELA chain then uses the FOV "
                        "reflectance")
    p.add_argument("--serial", action="store_true",
                   help="write each preset's files and figures before the next walk starts, "
                        "in this process (default: in a second process, while the next walks)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes that write the files and figures (default: the machine's "
                        "cores less one where the walks run on a GPU, else 1)")
    args = p.parse_args(argv)
    if args.workers is not None and args.workers < 1:
        print(f"reproduce_paper: --workers {args.workers}: a number of processes, 1 or more",
              file=sys.stderr)
        return 2

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data = Path(args.data or tempfile.mkdtemp(prefix="warpe-paper-"))
    data.mkdir(parents=True, exist_ok=True)
    overrides = {"simulation.photons": args.photons} if args.photons else {}
    if args.no_nadir:
        overrides["simulation.nadir"] = False
    presets = [path for path in sorted((presets_dir() / "paper").glob("*.yaml"))
               if not args.only or path.stem in args.only]
    total = time.perf_counter()
    devices = set()
    rows = []
    done = []          # (name, photons, simulation s, warnings, Future) in preset order

    def report(block: bool) -> None:
        """Print the presets whose files and figures are written, in order."""
        while done and (block or done[0][4].done()):
            name, photons, walk_s, caught, job = done.pop(0)
            got, printed, post_s = job.result()
            rows.extend(got)
            print(f"{printed}{name:26s} {photons:>11,d} rays  simulation {walk_s:6.1f} s, files "
                  f"and figures {post_s:5.1f} s" + "".join(f"\n    warning: {w}" for w in caught),
                  flush=True)

    # the files and figures of each preset (single-threaded Python: matplotlib, h5netcdf, the
    # BELA chain) are made in worker processes while the next presets walk on the device
    pool = None
    if not args.serial and len(presets) > 1:
        engine = get_engine(args.device)           # the walks' device (kept for them)
        gpu = getattr(getattr(engine, "info", None), "kind", "") == "gpu"
        pool = ProcessPoolExecutor(file_workers(len(presets), args.workers, gpu=gpu),
                                   mp_context=multiprocessing.get_context("spawn"))
    try:
        # a scenario two presets share is walked once: bela_cases' granular case is
        # gran_co2_thickness' 1000 mm curve (the same scenario key and photons, the same bits)
        with reusing_walks():
            for preset in presets:
                t0 = time.perf_counter()
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    config = warpe_cl.load_preset(preset, overrides=overrides or None)
                    ds = warpe_cl.simulate(config, device=args.device, progress=False)
                walk_s = time.perf_counter() - t0
                devices.add(str(ds.attrs.get("opencl_device", "numpy reference")))
                photons = int(ds["photons"].sum() if "scenario" in ds.dims else ds["photons"])
                if pool is not None:
                    job = pool.submit(finish, preset.stem, ds, out, data)
                else:
                    job = Future()
                    job.set_result(finish(preset.stem, ds, out, data))
                done.append((preset.stem, photons, walk_s, [str(w.message) for w in caught], job))
                report(block=False)
        report(block=True)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    if rows:
        print(f"waveform metrics: {write_metrics(rows, out / 'metrics.csv')}")
    if presets:
        command = " ".join(["python tools/reproduce_paper.py"] + list(argv or sys.argv[1:]))
        print("provenance: " + str(write_provenance(
            out / "provenance.json", "paper", [p.stem for p in presets], args.photons,
            ", ".join(sorted(devices)), command)))
    print(f"all presets: {time.perf_counter() - total:.1f} s; results in {data}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
