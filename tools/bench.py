#!/usr/bin/env python3
"""Benchmark the walk kernels on the scenes of the speed issue, and the NumPy reference beside them.

    python tools/bench.py [--photons N] [--device SPEC] [--precision single|double]
                          [--scenes B1,B2,B3] [--modes analog,weighted]
                          [--compare numpy] [--compare mcxcl] [--json FILE]

Scenes (time cap 5 ns, Lambertian floor A = 0.15, HG g = 0.8):
  B1  slab 60 mm, tau0 = 60.3, omega = 0.99502, n = 1.3 (89 scatterings per launched ray in our
      analog walk; about 220 where absorption does not end rays: docs/performance.md)
  B2  the same medium, granular (no interfaces)
  B3  granular CO2 ice, d = 200 um, compacity 0.9, h = 100 mm (physical form)

Prints and writes (JSON) photons/s and scattering events/s per scene, with the device, driver,
cores, precision and date. ``--modes analog,weighted`` measures each scene in both Monte Carlo
modes (docs/walk.md §6) and prints their figures of merit, 1/(relative variance x time), for the
scattering energy in its 12 deg FOV over all times and over t >= 2 ns. ``--compare numpy`` runs the reference walk on the same scenes in the
same run (fewer photons: it is ~100x slower) and prints the ratio.

``--compare mcxcl`` runs MCX-CL (pmcxcl 0.7.5, in its own venv at $WARPE_MCXCL_VENV or
/tmp/mcxcl-venv, created on first use) on B1 in the anchor's 60 mm voxel box, on the same OpenCL
device, right after our kernel: MCX photons/s and scattering events/s (kernel and wall time), our
events/s in the same run, their ratio, and our time-resolved reflectance against MCX's. A second,
matched check puts MCX in a 400 mm wide box against our B1 with A = 0 (MCX has no Lambertian
floor). See tools/mcxcl_compare.py and docs/performance.md, "MCX-CL anchor".
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import os
import platform
import sys
import time

import numpy as np

from _common import loadavg  # tools/ is first on sys.path when run as a script
from warpe_cl.api import get_engine, walk_params
from warpe_cl.config import load_preset

COMMON_SIM = {"time_bins": {"start": "1e-6 ns", "stop": "5 ns", "per_decade": 20},
              "max_time": "5 ns", "seed": 1}
SCENES = {
    "B1": {"medium": {"texture": "slab", "thickness": "60 mm", "bottom_albedo": 0.15,
                      "phase_g": 0.8, "radiative": {"tau0": 60.3, "omega": 0.99502, "n": 1.3}},
           "simulation": COMMON_SIM},
    "B2": {"medium": {"texture": "granular", "thickness": "60 mm", "bottom_albedo": 0.15,
                      "phase_g": 0.8, "radiative": {"tau0": 60.3, "omega": 0.99502, "n": 1.3}},
           "simulation": COMMON_SIM},
    "B3": {"medium": {"texture": "granular", "thickness": "100 mm", "compacity": 0.9,
                      "bottom_albedo": 0.15, "phase_g": 0.8,
                      "inclusions": [{"material": "CO2", "proportion": 1.0,
                                      "grain_size": "200 um"}]},
           "simulation": COMMON_SIM},
}


def measure(engine, params, photons, precision, repeats=3, keep=None):
    """Best of ``repeats`` timed runs (after one warm-up that builds the kernel); the best run's
    :class:`~warpe_cl.params.Counts` go to ``keep["counts"]`` when ``keep`` is a dict."""
    engine.run(params, min(photons, 10_000), precision=precision)
    best = None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        counts = engine.run(params, photons, precision=precision)
        elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
        if best is None or elapsed < best[0]:
            best = (elapsed, counts, cpu)
    elapsed, counts, cpu = best
    if keep is not None:
        keep["counts"] = counts
    return {"photons": photons, "seconds": elapsed, "cpu_seconds": cpu,
            "photons_per_s": photons / elapsed,
            "scattering_events_per_s": counts.scattering_events / elapsed,
            "scatterings_per_photon": counts.scattering_events / photons}


def figure_of_merit(counts, params, seconds: float, t_min: float = 0.0) -> dict:
    """FOM = 1 / (relative variance x run time), 1/s, of the scattering component's
    energy inside its FOV, exits at t >= t_min ns (every ray adds its weight; analog: 1).

    A ray lands in at most one time bin, so for the sum over bins Q = sum(w)/N the variance is
    (sum(w^2)/N - Q^2)/N with the sums over the selected bins (w = 1 in the analog walk)."""
    from warpe_cl.params import fixed_to_float
    edges = np.asarray(params.time_edges, dtype=float)
    sel = edges[:-1] >= t_min
    n = counts.photons
    if counts.weighted:
        s1 = fixed_to_float(counts.w_time_in_fov[3])[sel].sum()
        s2 = fixed_to_float(counts.w2_time_in_fov[3])[sel].sum()
    else:
        s1 = s2 = float(counts.time_in_fov[3][sel].sum())
    q = s1 / n
    var = max(s2 / n - q * q, 0.0) / n
    rel_var = var / (q * q) if q > 0 else float("inf")
    return {"t_min_ns": t_min, "value": q, "relative_stderr": rel_var ** 0.5,
            "fom_per_s": 1.0 / (rel_var * seconds) if rel_var > 0 else float("inf")}


def compare_mcxcl(engine, params, ours, counts, args, state) -> tuple:
    """MCX-CL on a slab scene right after our kernel: its row for the JSON and a report.

    ``state`` keeps MCX's python and platform between scenes. Raises ``McxclUnavailable``.
    """
    import mcxcl_compare as mc
    wd = state.setdefault("workdir", mc.workdir())
    if "python" not in state:
        state["python"] = mc.ensure_venv(mc.venv_path(args.mcxcl_venv))
        label, icd, gpuid = mc.choose_platform(args.mcxcl_icd, engine.info.device,
                                               state["python"], wd)
        state.update(icd_label=label, icd=icd, gpuid=gpuid)
    py, icd, gpuid = state["python"], state["icd"], state["gpuid"]
    row = {"icd": state["icd_label"], "ocl_icd_vendors": icd, "gpuid": gpuid}

    # 1. timing, and the reflectance of B1 itself, in the anchor's box. The load of a shared
    # machine drifts during a run: each MCX run is bracketed by one run of ours before and one
    # after, the round's ratio uses their mean, and the reported ratio is the median of rounds.
    scene = mc.mcx_scene(params, int(args.mcxcl_photons), box_mm=args.mcxcl_box,
                         tstep_ns=args.mcxcl_tstep, gpuid=gpuid)
    keys = ("nphoton", "kernel_ms", "wall_s", "cpu_s", "build_ms", "mcx_photons_per_ms",
            "mcx_device", "launch", "faces", "inside_at_tend", "top_mean_scatterings",
            "top_weighted_mean_scatterings", "loadavg_before", "loadavg_after", "pmcxcl", "log")
    rounds, first = [], None
    prev = measure(engine, params, ours["photons"], args.precision, repeats=1)
    for _ in range(max(1, args.mcxcl_rounds)):
        res = mc.run_mcx(py, icd, scene, wd)
        ev = mc.mcx_events(res, scene["mus_per_mm"], scene["path_cap_mm"])
        nxt = measure(engine, params, ours["photons"], args.precision, repeats=1)
        o_ev = 0.5 * (prev["scattering_events_per_s"] + nxt["scattering_events_per_s"])
        o_ph = 0.5 * (prev["photons_per_s"] + nxt["photons_per_s"])
        rounds.append({"mcx": {"box_mm": scene["vol_shape"],
                               "tstep_ns": scene["cfg"]["tstep"] * 1e9,
                               **{k: res.get(k) for k in keys}, **ev},
                       "ours_before": prev, "ours_after": nxt,
                       "ratio_events_per_s": o_ev / ev["scattering_events_per_s"],
                       "ratio_photons_per_s": o_ph / ev["photons_per_s"]})
        first = first or res
        prev = nxt
    row["rounds"] = rounds
    row["ratio_events_per_s"] = float(np.median([r["ratio_events_per_s"] for r in rounds]))
    row["ratio_photons_per_s"] = float(np.median([r["ratio_photons_per_s"] for r in rounds]))
    row["tpsf"] = mc.compare_tpsf(counts, params, first)
    report = []
    for i, r in enumerate(rounds):
        t = r["mcx"]
        report += [
            f"  round {i + 1}: MCX-CL {t['pmcxcl']} on {t['mcx_device']} ({row['icd']} ICD, gpuid "
            f"{gpuid}), {t['box_mm'][0]}x{t['box_mm'][1]}x{t['box_mm'][2]} mm box, "
            f"{t['nphoton']:.3g} photons: kernel {t['kernel_ms'] / 1e3:.2f} s, wall "
            f"{t['wall_s']:.2f} s (build {t['build_ms']} ms); {t['photons_per_s']:.3g} photons/s, "
            f"{t['scattering_events_per_s']:.3g} scattering events/s "
            f"({t['scatterings_per_photon']:.1f} per launched photon; "
            f"{t['top_mean_scatterings']:.1f} per photon detected at z = 0); wall "
            f"{t['photons_per_s_wall']:.3g} photons/s; {t['cpu_s'] / t['wall_s']:.2f} cores busy; "
            f"load average {t['loadavg_before']} -> {t['loadavg_after']}",
            f"    ours before/after {r['ours_before']['scattering_events_per_s']:.3g} / "
            f"{r['ours_after']['scattering_events_per_s']:.3g} events/s "
            f"({r['ours_after']['scatterings_per_photon']:.1f} per launched photon, "
            f"{r['ours_after']['cpu_seconds'] / r['ours_after']['seconds']:.2f} cores busy) -> "
            f"ratio {r['ratio_events_per_s']:.2f}x events/s, {r['ratio_photons_per_s']:.2f}x "
            f"photons/s"]
    report += [
        f"  RATIO ours / MCX-CL (median of {len(rounds)} rounds): "
        f"{row['ratio_events_per_s']:.2f}x in scattering events/s, "
        f"{row['ratio_photons_per_s']:.2f}x in photons/s",
        "  time-resolved reflectance, ours (A = 0.15, laterally infinite) vs MCX (box, no floor), "
        "per photon entering the medium:",
        mc.format_tpsf(row["tpsf"])]

    # 2. matched check: a box wide enough to be laterally infinite, our floor black (A = 0)
    if args.mcxcl_check_photons > 0:
        n_chk = int(args.mcxcl_check_photons)
        ours_a0 = dataclasses.replace(params, albedo=0.0)
        wide = mc.mcx_scene(ours_a0, n_chk, box_mm=args.mcxcl_check_box, tstep_ns=1e9,
                            gpuid=gpuid)          # one time gate: the box's fluence buffer stays small
        res_w = mc.run_mcx(py, icd, wide, wd)
        ev_w = mc.mcx_events(res_w, wide["mus_per_mm"], wide["path_cap_mm"])
        c_a0 = engine.run(ours_a0, n_chk, precision=args.precision)
        # MCX's paths do not depend on mua (absorption is a weight): compare its scattering
        # counts with our walk in the same medium without absorption (E = mus, omega = 1), per
        # ray that entered (MCX has no specular loss). The census of B1 itself and of B1 with
        # omega = 1 explains the scatterings per photon (docs/performance.md, MCX-CL anchor).
        walks = {"B1": params,
                 "B1, omega = 1 (absorption not ending rays)": dataclasses.replace(params,
                                                                                    omega=1.0),
                 "B1, A = 0, E = mus, omega = 1 (MCX's medium)": dataclasses.replace(
                     ours_a0, omega=1.0, extinction=params.extinction * params.omega)}
        census = {k: mc.scattering_census(engine.run(p, n_chk, precision=args.precision,
                                                     records=True))
                  for k, p in walks.items()}
        matched = census["B1, A = 0, E = mus, omega = 1 (MCX's medium)"]
        dz = ((ev_w["scatterings_per_photon"] - matched["per_entered"])
              / np.hypot(ev_w["scatterings_per_photon_err"], matched["per_entered_err"]))
        row["check"] = {
            "box_mm": wide["vol_shape"], "nphoton": n_chk, "faces": res_w["faces"],
            "inside_at_tend": res_w["inside_at_tend"], **{f"mcx_{k}": v for k, v in ev_w.items()},
            "mcx_top_mean_scatterings": res_w["top_mean_scatterings"],
            "mcx_top_weighted_mean_scatterings": res_w["top_weighted_mean_scatterings"],
            "ours_census": census, "scatterings_z": float(dz),
            "tpsf": mc.compare_tpsf(c_a0, ours_a0, res_w)}
        report += [
            f"  matched check, {n_chk:.3g} photons: MCX in a {wide['vol_shape'][0]} mm wide box vs "
            f"ours with A = 0 (reflectance per photon entering):",
            mc.format_tpsf(row["check"]["tpsf"]),
            f"    scatterings per photon entering, MCX (absorption as a weight) vs our walk in the "
            f"same medium without absorption: {ev_w['scatterings_per_photon']:.1f} ± "
            f"{ev_w['scatterings_per_photon_err']:.1f} ({res_w['inside_at_tend']} still inside "
            f"at the gate) vs {matched['per_entered']:.1f} ± {matched['per_entered_err']:.1f} "
            f"(z = {dz:+.1f})",
            "  scattering census of our walks:"]
        report += [mc.format_census(k, c) for k, c in census.items()]
    return row, "\n".join(report)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--photons", type=float, default=1e6)
    p.add_argument("--device", default=None)
    p.add_argument("--precision", choices=("single", "double"), default="single")
    p.add_argument("--scenes", default=",".join(SCENES),
                   help="comma-separated scenes to run (default: all)")
    p.add_argument("--compare", choices=("numpy", "mcxcl"), action="append", default=[])
    p.add_argument("--numpy-photons", type=float, default=2e3)
    p.add_argument("--mcxcl-photons", type=float, default=1e6,
                   help="MCX-CL photons for the timing run (default 1e6)")
    p.add_argument("--mcxcl-rounds", type=int, default=3,
                   help="MCX-CL timing runs, each between two runs of ours (default 3)")
    p.add_argument("--mcxcl-icd", default="auto",
                   help="OpenCL platform for MCX-CL: auto (the one whose device has our device's "
                        "name), system (/etc/OpenCL/vendors), pip (our pyopencl's PoCL) or a "
                        "folder of .icd files")
    p.add_argument("--mcxcl-venv", default=None,
                   help="MCX-CL's venv (default $WARPE_MCXCL_VENV or /tmp/mcxcl-venv)")
    p.add_argument("--mcxcl-box", type=float, default=None,
                   help="lateral size of MCX's voxel box, mm (default: the slab thickness)")
    p.add_argument("--mcxcl-tstep", type=float, default=0.05,
                   help="MCX time-gate width, ns (the anchor's 0.05)")
    p.add_argument("--mcxcl-check-photons", type=float, default=2e5,
                   help="photons of the matched check (wide box, A = 0); 0 skips it")
    p.add_argument("--mcxcl-check-box", type=float, default=400.0,
                   help="lateral size of the matched check's box, mm")
    p.add_argument("--modes", default="analog",
                   help="comma-separated: analog, weighted (each scene in each mode, with the "
                        "figure of merit of both; default analog)")
    p.add_argument("--json", default=None, help="write the results here")
    args = p.parse_args(argv)
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    if not modes or any(m not in ("analog", "weighted") for m in modes):
        p.error(f"--modes: {args.modes!r}; choose from analog, weighted")
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    unknown = [s for s in scenes if s not in SCENES]
    if unknown:
        p.error(f"--scenes: unknown {', '.join(unknown)}; choose from {', '.join(SCENES)}")

    engine = get_engine(args.device)
    result = {"date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
              "host": platform.node(), "cores": os.cpu_count(),
              "cpu": platform.processor() or platform.machine(),
              "device": engine.provenance, "precision": args.precision,
              "loadavg_start": loadavg(), "scenes": {}}
    print(f"# {engine.provenance['opencl_device']} | {engine.provenance['opencl_platform']} | "
          f"{os.cpu_count()} cores | {args.precision} precision | load average "
          f"{result['loadavg_start']}")
    mcx_state = {}
    for name in scenes:
        params, _ = walk_params(load_preset(SCENES[name]))
        row, lines = {}, []
        for mode in modes:
            mode_params = dataclasses.replace(params, mode=mode)
            kept = {}
            m = measure(engine, mode_params, int(args.photons), args.precision, keep=kept)
            m["figure_of_merit"] = [figure_of_merit(kept["counts"], mode_params, m["seconds"], t)
                                    for t in (0.0, 2.0)]
            row["opencl" if mode == "analog" else "opencl_weighted"] = m
            if mode == "analog":
                keep = kept
            fom = ", ".join(f"t >= {f['t_min_ns']:g} ns {f['fom_per_s']:.3g}/s"
                            for f in m["figure_of_merit"])
            lines.append(f"{name} {mode}: {m['photons_per_s']:.3g} photons/s, "
                         f"{m['scattering_events_per_s']:.3g} scattering events/s "
                         f"({m['scatterings_per_photon']:.0f} per photon); FOM of the "
                         f"scattering energy in its FOV: {fom}")
        if "analog" not in modes:
            row["opencl"] = row["opencl_weighted"]
            keep = kept
        line = "\n".join(lines)
        if "numpy" in args.compare:
            row["numpy"] = measure(get_engine("numpy"), params, int(args.numpy_photons),
                                   "double", repeats=1)
            ratio = row["opencl"]["scattering_events_per_s"] / row["numpy"]["scattering_events_per_s"]
            row["ratio_to_numpy"] = ratio
            line += f"; numpy {row['numpy']['scattering_events_per_s']:.3g} events/s, ratio {ratio:.0f}x"
        print(line, flush=True)
        if "mcxcl" in args.compare:
            if params.texture != "slab":
                print(f"  MCX-CL: not run on {name} (granular: MCX's voxel box has interfaces)")
            else:
                import mcxcl_compare
                try:
                    row["mcxcl"], report = compare_mcxcl(engine, params, row["opencl"],
                                                         keep["counts"], args, mcx_state)
                except mcxcl_compare.McxclUnavailable as err:
                    print(f"bench: --compare mcxcl: {err}", file=sys.stderr)
                    return 1
                row["ratio_to_mcxcl"] = row["mcxcl"]["ratio_events_per_s"]
                print(report, flush=True)
        result["scenes"][name] = row
    result["loadavg_end"] = loadavg()
    print(f"# load average at the end {result['loadavg_end']}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
