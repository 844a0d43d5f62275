#!/usr/bin/env python3
"""Benchmark the walk kernels on the scenes of the speed issues, and the references beside them.

    python tools/bench/bench.py [--photons N] [--tail-photons N] [--rounds R] [--device SPEC]
                                [--precision single|double] [--scenes B1,B2,B3,T1]
                                [--modes analog,weighted] [--compare numpy] [--compare toy]
                                [--compare mcxcl] [--json FILE]

Scenes B1-B3 (issue 5; time cap 5 ns, Lambertian floor A = 0.15, HG g = 0.8):
  B1  slab 60 mm, tau0 = 60.3, omega = 0.99502, n = 1.3 (89 scatterings per launched ray in our
      analog walk; about 220 where absorption does not end rays: docs/performance.md)
  B2  the same medium, granular (no interfaces)
  B3  granular CO2 ice, d = 200 um, compacity 0.9, h = 100 mm (physical form)
Scene T1 (issue 13), the heavy tail: granular, tau0 = 1e5 over 60 mm, omega = 1 - 3e-7, g = 0,
  n = 1, black floor (A = 0), default max_flights (1e7), time bins 1e-6 to 1e5 ns (20 per
  decade) and no time cap but their last edge. A ray's number of scatterings has a power-law
  tail cut only by absorption, after about 1/(1 - omega) = 3.3e6 flights: thousands per
  launched ray on average (about 5000 in the issue; a small run's mean scatters widely), most
  of them in a few long rays. B1-B3's 5 ns cap would stop rays after 5 ns x c / (0.6 um mean
  free path) = 2.5e6 flights, before absorption does: the cap, not the medium, would end the
  tail, so T1 keeps the default cap (1e5 ns, far beyond any ray's life).
  T1 is timed with --tail-photons rays (default 1e5), not --photons. Its events/s are printed
  next to B1's with their ratio T1 / B1 (issue 13's goal: >= 0.8).

Every figure is the median over --rounds rounds, with the range seen [min-max]. A round times
each scene once in each mode (one run, after a warm-up run per scene and mode before the first
round that builds the kernels), then runs each --compare reference once, so that a drift of a
shared machine's load falls on all alike; a ratio is taken within each round, and its median
and range are reported. Prints and writes (JSON) photons/s and scattering events/s per scene,
with the device, driver, cores, precision, load average and date. ``--modes analog,weighted``
measures each scene in both Monte Carlo modes (docs/walk.md §6) and prints their figures of
merit, 1/(relative variance x time), for the scattering energy in its 12 deg FOV over all times
and over t >= 2 ns.

``--compare numpy`` runs the reference walk on the same scenes (fewer photons: it is ~1000x
slower; --numpy-photons on B1-B3, the same fraction of --tail-photons on T1) and prints the
ratio of events/s.

``--compare toy`` runs the hand-vectorised toy layer walk ``toy_walk.py`` (a performance anchor
that is not part of warpe-cl: --toy-script PATH, default $WARPE_TOY_WALK) with this Python, as
``toy_walk.py --photons 4e6 --variants vec16 --platform P --wait block --json FILE``
(--toy-photons; ``--wait block`` so that the toy, like ours, runs on every core), with
B1's medium (mus, mua, g, n, h, A and the 5 ns cap passed explicitly) on our device's OpenCL
platform P, once per round after our scenes. It prints the toy's scattering events/s (its
``scat/s``: scatterings / kernel wall time, build and warm-up excluded), our B1 events/s and
the ratio ours / toy. The toy is not the same walk; it does less per event: each work-item
carries 16 photons in 16-lane float vectors (OpenCL float16) with native, relaxed math;
absorption is a weight exp(-mua L) applied at exit, so absorption never ends a ray (about 220
scatterings per photon against our 89: compare events/s, not photons/s); the photon starts
inside the medium (no specular reflection); and it fills one exit-time histogram (count and
weight), where we sort every exit into components, FOVs and angles.

``--compare mcxcl`` runs MCX-CL (pmcxcl 0.7.5, in its own venv at $WARPE_MCXCL_VENV or
/tmp/mcxcl-venv, created on first use) on B1 in the anchor's 60 mm voxel box, on the same OpenCL
device, after the rounds: MCX photons/s and scattering events/s (kernel and wall time), our
events/s in the same run, their ratio, and our time-resolved reflectance against MCX's. It keeps
its own interleaving: --mcxcl-rounds MCX runs, each between two runs of ours, the ratio's median
and range over them. A second, matched check puts MCX in a 400 mm wide box against our B1 with
A = 0 (MCX has no Lambertian floor). See tools/studies/mcxcl_compare.py and docs/performance.md,
"MCX-CL anchor".
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import math
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import loadavg  # tools/bench/ is first on sys.path when run as a script
from warpe_cl.api import get_engine, walk_params
from warpe_cl.config import load_preset

#: tools/studies/, where mcxcl_compare.py lives: the host side of --compare mcxcl is also the
#: layered study's (docs/validation.md §5); imported from there, after this folder.
STUDIES = Path(__file__).resolve().parent.parent / "studies"
if str(STUDIES) not in sys.path:
    sys.path.append(str(STUDIES))

#: The scenes time the walk as MCX-CL and the toy walk do: without the nadir estimate, whose
#: cost tools/bench/nadir_fom.py measures (it turns it on per configuration).
COMMON_SIM = {"time_bins": {"start": "1e-6 ns", "stop": "5 ns", "per_decade": 20},
              "max_time": "5 ns", "seed": 1, "nadir": False}
#: T1's simulation: the paper's time bins and no cap but their last edge (module docstring).
TAIL_SIM = {"time_bins": {"start": "1e-6 ns", "stop": "1e5 ns", "per_decade": 20}, "seed": 1,
            "nadir": False}
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
    "T1": {"medium": {"texture": "granular", "thickness": "60 mm", "bottom_albedo": 0.0,
                      "phase_g": 0.0, "radiative": {"tau0": 1e5, "omega": 1 - 3e-7, "n": 1.0}},
           "simulation": TAIL_SIM},
}
#: Scenes timed with ``--tail-photons`` rays (a few thousand scatterings each).
TAIL_SCENES = ("T1",)
#: Issue 13's goal for T1's scattering events/s, as a fraction of B1's.
TAIL_GOAL = 0.8

TOY_VARIANT = "vec16"
#: What one timed run of ours reports, each summarised over rounds.
RUN_KEYS = ("seconds", "cpu_seconds", "photons_per_s", "scattering_events_per_s",
            "scatterings_per_photon", "walk_seconds", "launches")


# ---------------------------------------------------------------- statistics over rounds

def spread(values) -> dict:
    """Median and range of one figure over rounds: ``{"median", "min", "max", "values"}``."""
    values = [float(v) for v in values]
    return {"median": statistics.median(values), "min": min(values), "max": max(values),
            "values": values}


def fmt_spread(s: dict, spec: str = ".3g") -> str:
    """``median [min–max]`` (the median alone for one round)."""
    if len(s["values"]) == 1:
        return format(s["median"], spec)
    return f"{s['median']:{spec}} [{s['min']:{spec}}–{s['max']:{spec}}]"


def rounds_text(n: int) -> str:
    """``1 round``, ``5 rounds``."""
    return f"{n} round" + ("" if n == 1 else "s")


def ratios(numerators: list, denominators: list, key: str) -> dict:
    """The spread of the round-by-round ratios of ``key`` (runs of the same rounds)."""
    return spread([a[key] / b[key] for a, b in zip(numerators, denominators)])


# ---------------------------------------------------------------- our kernel

def warm_up(engine, params, photons: int, precision: str) -> None:
    """One untimed run that builds the kernel (at most 10 000 photons)."""
    engine.run(params, min(photons, 10_000), precision=precision)


def timed_run(engine, params, photons: int, precision: str) -> tuple:
    """One timed run: its figures (``RUN_KEYS``) and its :class:`~warpe_cl.params.Counts`.
    ``walk_seconds`` is the part of ``seconds`` spent in the launches (the rest: setting up
    the walk's buffers, its warm-up and the final readback); ``launches`` their number, and
    ``launch_seconds`` each one's time. A walk of the same rays whose time varies from round
    to round (B3 on the H200) shows there whether its launches or the rest vary."""
    t0, c0 = time.perf_counter(), time.process_time()
    counts = engine.run(params, photons, precision=precision)
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    launches = getattr(engine, "last_launches", [])
    return {"photons": photons, "seconds": elapsed, "cpu_seconds": cpu,
            "photons_per_s": photons / elapsed,
            "scattering_events_per_s": counts.scattering_events / elapsed,
            "scatterings_per_photon": counts.scattering_events / photons,
            "walk_seconds": sum(x["seconds"] for x in launches), "launches": len(launches),
            "launch_seconds": [x["seconds"] for x in launches]}, counts


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


def summarize_runs(runs: list) -> dict:
    """One scene and mode over rounds: the medians of ``RUN_KEYS`` (under their own names, as
    tools/bench/bench_ab.py reads them), their ranges, the figures of merit and every run."""
    out = {"photons": runs[0]["photons"], "rounds": len(runs), "range": {}}
    for key in RUN_KEYS:
        s = spread(r[key] for r in runs)
        out[key], out["range"][key] = s["median"], [s["min"], s["max"]]
    if "figure_of_merit" in runs[0]:
        out["figure_of_merit"] = []
        for i, first in enumerate(runs[0]["figure_of_merit"]):
            s = spread(r["figure_of_merit"][i]["fom_per_s"] for r in runs)
            out["figure_of_merit"].append({**first, "fom_per_s": s["median"],
                                           "fom_per_s_range": [s["min"], s["max"]]})
    out["runs"] = runs
    return out


def scene_line(name: str, mode: str, runs: list) -> str:
    """The summary line of one scene in one mode."""
    fom = ", ".join(
        f"t >= {f['t_min_ns']:g} ns "
        + fmt_spread(spread(r["figure_of_merit"][i]["fom_per_s"] for r in runs)) + "/s"
        for i, f in enumerate(runs[0]["figure_of_merit"]))
    per_photon = spread(r["scatterings_per_photon"] for r in runs)["median"]
    # an engine that keeps no launch record (an older tree's, tools/bench/bench_ab.py) has none
    launches = (f"launches {fmt_spread(spread(r['launches'] for r in runs))}, their time "
                f"{fmt_spread(spread(r['walk_seconds'] for r in runs))} s of "
                f"{fmt_spread(spread(r['seconds'] for r in runs))} s; "
                if any(r.get("launches") for r in runs) else "")
    return (f"{name} {mode}: "
            f"{fmt_spread(spread(r['photons_per_s'] for r in runs))} photons/s, "
            f"{fmt_spread(spread(r['scattering_events_per_s'] for r in runs))} scattering "
            f"events/s ({per_photon:.0f} per photon, {runs[0]['photons']:.3g} photons); "
            f"{launches}FOM of the scattering energy in its FOV: {fom}")


# ---------------------------------------------------------------- the toy walk

class ToyUnavailable(RuntimeError):
    """The toy walk could not be found or run (a one-line reason)."""


def toy_script_path(given: str | None) -> Path:
    """The toy walk script: ``given``, else $WARPE_TOY_WALK.

    Raises :class:`ToyUnavailable` when neither names an existing file."""
    named = given or os.environ.get("WARPE_TOY_WALK")
    if not named:
        raise ToyUnavailable("--compare toy needs the toy walk script: give --toy-script PATH "
                             "or set $WARPE_TOY_WALK")
    path = Path(named).expanduser()
    if not path.is_file():
        raise ToyUnavailable(f"no toy walk script at {path} (give --toy-script PATH or set "
                             "$WARPE_TOY_WALK)")
    return path.resolve()


def toy_command(script: Path, params, photons: int, platform_name: str, json_path) -> list:
    """The toy's command line: B1's medium (``params``) passed explicitly, lengths in mm, and
    ``--wait block``: with its default ``--wait poll`` Intel's CPU runtime ran the toy on one
    thread, ours on two (docs/performance.md, issue 13)."""
    mus = params.extinction * params.omega * 1e-3
    mua = params.extinction * (1.0 - params.omega) * 1e-3
    dt_ns = 0.05
    return [sys.executable, str(script), "--photons", f"{photons:g}",
            "--variants", TOY_VARIANT, "--platform", platform_name, "--wait", "block",
            "--json", str(json_path),
            "--mus", f"{mus:.9g}", "--mua", f"{mua:.9g}", "--g", f"{params.g:g}",
            "--n", f"{params.n:g}", "--h", f"{params.thickness * 1e3:g}",
            "--albedo", f"{params.albedo:g}", "--tend", f"{params.max_time:g}",
            "--dt", f"{dt_ns:g}", "--nbins", str(math.ceil(params.max_time / dt_ns - 1e-9))]


def parse_toy_output(stdout: str, json_text: str | None = None,
                     variant: str = TOY_VARIANT) -> dict:
    """The toy's speed from its ``--json`` result (preferred) or, failing that, its report
    line: scatterings/s (its ``scat/s``: scatterings / kernel wall time), photons/s and
    scatterings per photon. Raises :class:`ToyUnavailable` when neither holds them."""
    if json_text:
        doc = json.loads(json_text)
        for r in doc.get("results", []):
            if r.get("variant") == variant and r.get("stats_valid", True) and r["wall"] > 0:
                n = r["nphot"]
                return {"scat_per_s": r["nscat"] / r["wall"], "photons_per_s": n / r["wall"],
                        "scatterings_per_photon": r["nscat"] / n, "photons": n,
                        "seconds": r["wall"], "cpu_seconds": r.get("cpu"),
                        "device": doc.get("args", {}).get("device_desc"), "source": "json"}
    for line in stdout.splitlines():
        fields = line.split()
        if not fields or fields[0] != variant:
            continue
        num = r"([0-9.]+(?:[eE][-+]?\d+)?)"
        got = {k: re.search(rf"\b{re.escape(k)}={num}", line)
               for k in ("scat/s", "photons/s", "scat/ph", "N", "wall")}
        if got["scat/s"] and got["photons/s"]:
            return {"scat_per_s": float(got["scat/s"].group(1)),
                    "photons_per_s": float(got["photons/s"].group(1)),
                    "scatterings_per_photon": (float(got["scat/ph"].group(1))
                                               if got["scat/ph"] else None),
                    "photons": int(float(got["N"].group(1))) if got["N"] else None,
                    "seconds": float(got["wall"].group(1)) if got["wall"] else None,
                    "cpu_seconds": None, "device": None, "source": "stdout"}
    raise ToyUnavailable(f"the toy printed no {variant} speed (scat/s)")


def run_toy(script: Path, params, photons: int, platform_name: str,
            timeout: float = 3600) -> dict:
    """One run of the toy walk in a subprocess (this Python, our environment: the same OpenCL
    drivers); its parsed speed. Raises :class:`ToyUnavailable`."""
    with tempfile.TemporaryDirectory(prefix="warpe-bench-toy-") as tmp:
        out = Path(tmp) / "toy.json"
        cmd = toy_command(script, params, photons, platform_name, out)
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise ToyUnavailable(f"{script.name} ran past {timeout:.0f} s") from None
        if proc.returncode != 0:
            last = (proc.stderr.strip() or proc.stdout.strip() or "(no message)").splitlines()[-1]
            raise ToyUnavailable(f"{script.name} failed (exit {proc.returncode}): {last}")
        result = parse_toy_output(proc.stdout, out.read_text() if out.exists() else None)
    result["photons"] = result["photons"] or photons
    at = cmd.index("--json") + 1
    result["command"] = [*cmd[:at], "FILE", *cmd[at + 1:]]      # the temporary file is gone
    return result


def toy_summary(toy_runs: list, b1_runs: list, script: Path) -> tuple:
    """The toy's row for the JSON and its report lines, against B1's runs of the same rounds."""
    scat = spread(t["scat_per_s"] for t in toy_runs)
    ours = spread(r["scattering_events_per_s"] for r in b1_runs)
    ratio = spread(r["scattering_events_per_s"] / t["scat_per_s"]
                   for r, t in zip(b1_runs, toy_runs))
    first = toy_runs[0]
    row = {"script": str(script), "variant": TOY_VARIANT, "command": first["command"],
           "device": first["device"], "scat_per_s": scat,
           "photons_per_s": spread(t["photons_per_s"] for t in toy_runs),
           "ours_b1_events_per_s": ours, "ratio_events_per_s": ratio, "runs": toy_runs}
    per_photon = first["scatterings_per_photon"]
    lines = [
        f"toy walk ({script.name} {TOY_VARIANT}, {first['photons']:.3g} photons, B1's medium, "
        f"{first['device'] or 'device not reported'}): "
        f"{fmt_spread(scat)} scattering events/s (scat/s; "
        + (f"{per_photon:.0f} per photon, " if per_photon else "")
        + f"absorption as a weight), {fmt_spread(row['photons_per_s'])} photons/s",
        f"B1 ours {fmt_spread(ours)} scattering events/s -> RATIO ours / toy "
        f"{fmt_spread(ratio, '.2f')} in events/s (median over {rounds_text(len(toy_runs))})"]
    return row, lines


# ---------------------------------------------------------------- MCX-CL

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
    prev = timed_run(engine, params, ours["photons"], args.precision)[0]
    for _ in range(max(1, args.mcxcl_rounds)):
        res = mc.run_mcx(py, icd, scene, wd)
        ev = mc.mcx_events(res, scene["mus_per_mm"], scene["path_cap_mm"])
        nxt = timed_run(engine, params, ours["photons"], args.precision)[0]
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
    ev_ratio = spread(r["ratio_events_per_s"] for r in rounds)
    ph_ratio = spread(r["ratio_photons_per_s"] for r in rounds)
    row["ratio_events_per_s"], row["ratio_photons_per_s"] = ev_ratio["median"], ph_ratio["median"]
    row["ratio_events_per_s_range"] = [ev_ratio["min"], ev_ratio["max"]]
    row["ratio_photons_per_s_range"] = [ph_ratio["min"], ph_ratio["max"]]
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
        f"  RATIO ours / MCX-CL (median [range] of {len(rounds)} rounds): "
        f"{fmt_spread(ev_ratio, '.2f')}x in scattering events/s, "
        f"{fmt_spread(ph_ratio, '.2f')}x in photons/s",
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




# ---------------------------------------------------------------- the run

def scene_list(text: str) -> list:
    """The scenes of a comma-separated ``--scenes``; ValueError naming the unknown ones and the
    choices."""
    names = [s.strip() for s in text.split(",") if s.strip()]
    unknown = [s for s in names if s not in SCENES]
    if unknown:
        raise ValueError(f"--scenes: unknown {', '.join(unknown)}; "
                         f"choose from {', '.join(SCENES)}")
    return names


def parse_args(argv) -> argparse.Namespace:
    """The command line, checked; ``args.scene_list`` and ``args.mode_list`` are its lists."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--photons", type=float, default=1e6,
                   help="photons per timed run on B1-B3 (default 1e6)")
    p.add_argument("--tail-photons", type=float, default=1e5,
                   help="photons per timed run on T1, a few thousand scatterings each "
                        "(default 1e5)")
    p.add_argument("--rounds", type=int, default=1,
                   help="interleaved rounds; every figure is their median and range "
                        "(default 1; 5 for the figures of docs/performance.md)")
    p.add_argument("--device", default=None)
    p.add_argument("--precision", choices=("single", "double"), default="single")
    p.add_argument("--scenes", default=",".join(SCENES),
                   help="comma-separated scenes to run (default: all)")
    p.add_argument("--compare", choices=("numpy", "toy", "mcxcl"), action="append", default=[])
    p.add_argument("--numpy-photons", type=float, default=2e3,
                   help="NumPy reference photons on B1-B3; T1 gets the same fraction of "
                        "--tail-photons (default 2e3)")
    p.add_argument("--toy-script", default=None,
                   help="the toy walk, toy_walk.py (default $WARPE_TOY_WALK)")
    p.add_argument("--toy-photons", type=float, default=4e6,
                   help="photons of each toy run (default 4e6)")
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
    args.mode_list = [m.strip() for m in args.modes.split(",") if m.strip()]
    if not args.mode_list or any(m not in ("analog", "weighted") for m in args.mode_list):
        p.error(f"--modes: {args.modes!r}; choose from analog, weighted")
    try:
        args.scene_list = scene_list(args.scenes)
    except ValueError as err:
        p.error(str(err))
    if args.rounds < 1:
        p.error("--rounds: at least 1")
    if "toy" in args.compare and "B1" not in args.scene_list:
        p.error("--compare toy: compares with B1; add B1 to --scenes")
    return args


def scene_photons(name: str, args) -> tuple:
    """Photons of one timed run of ours and of the NumPy reference on scene ``name``."""
    if name in TAIL_SCENES:
        share = args.tail_photons / args.photons
        return int(args.tail_photons), max(1, round(args.numpy_photons * share))
    return int(args.photons), int(args.numpy_photons)


def mode_key(mode: str) -> str:
    """A mode's key in a scene's JSON row."""
    return "opencl" if mode == "analog" else "opencl_weighted"


def run_round(plan: dict, engine, args, runs: dict, counts: dict, toy: dict | None) -> str:
    """One round: every scene in every mode, then the NumPy reference and the toy once each.
    Appends to ``runs[scene][key]`` (key: ``mode_key`` or ``numpy``) and ``toy["runs"]``,
    keeps the last counts of each scene's first mode in ``counts``; returns the round's line."""
    cells = []
    for name, scene in plan.items():
        for mode in args.mode_list:
            params = dataclasses.replace(scene["params"], mode=mode)
            run, c = timed_run(engine, params, scene["photons"], args.precision)
            run["figure_of_merit"] = [figure_of_merit(c, params, run["seconds"], t)
                                      for t in (0.0, 2.0)]
            runs[name][mode_key(mode)].append(run)
            if mode == args.mode_list[0]:
                counts[name] = c
            cells.append(f"{name} {mode} {run['scattering_events_per_s']:.3g}")
        if "numpy" in args.compare:
            run, _ = timed_run(get_engine("numpy"), scene["params"], scene["numpy_photons"],
                               "double")
            runs[name]["numpy"].append(run)
            cells.append(f"{name} numpy {run['scattering_events_per_s']:.3g}")
    if toy is not None:
        t = run_toy(toy["script"], plan["B1"]["params"], int(args.toy_photons), toy["platform"])
        toy["runs"].append(t)
        cells.append(f"toy {t['scat_per_s']:.3g}")
    return "scattering events/s: " + ", ".join(cells)


def scene_report(name: str, runs: dict, args) -> tuple:
    """A scene's JSON row and report lines, over the rounds."""
    row, lines = {}, []
    for mode in args.mode_list:
        row[mode_key(mode)] = summarize_runs(runs[mode_key(mode)])
        lines.append(scene_line(name, mode, runs[mode_key(mode)]))
    primary = mode_key(args.mode_list[0])
    row.setdefault("opencl", row[primary])
    if runs["numpy"]:
        row["numpy"] = summarize_runs(runs["numpy"])
        ratio = ratios(runs[primary], runs["numpy"], "scattering_events_per_s")
        row["ratio_to_numpy"], row["ratio_to_numpy_range"] = ratio["median"], [ratio["min"],
                                                                               ratio["max"]]
        numpy_ev = spread(r["scattering_events_per_s"] for r in runs["numpy"])
        lines.append(f"{name} NumPy reference: {fmt_spread(numpy_ev)} scattering events/s "
                     f"({runs['numpy'][0]['photons']} photons); ratio ours "
                     f"({args.mode_list[0]}) / NumPy {fmt_spread(ratio, '.0f')}x")
    return row, lines


def tail_report(runs: dict, args) -> tuple:
    """T1's events/s beside B1's, round by round: the JSON entry and the report line."""
    key = mode_key(args.mode_list[0])
    t1, b1 = runs["T1"][key], runs["B1"][key]
    ratio = ratios(t1, b1, "scattering_events_per_s")
    entry = {"mode": args.mode_list[0], "goal": TAIL_GOAL, "ratio_events_per_s": ratio,
             "t1_events_per_s": spread(r["scattering_events_per_s"] for r in t1),
             "b1_events_per_s": spread(r["scattering_events_per_s"] for r in b1)}
    verdict = "met" if ratio["median"] >= TAIL_GOAL else "NOT met"
    line = (f"T1 / B1 ({args.mode_list[0]}): T1 {fmt_spread(entry['t1_events_per_s'])}, B1 "
            f"{fmt_spread(entry['b1_events_per_s'])} scattering events/s -> RATIO T1 / B1 "
            f"{fmt_spread(ratio, '.2f')} (median over {rounds_text(len(t1))}; goal >= {TAIL_GOAL}: "
            f"{verdict})")
    return entry, line


def prepare_toy(args) -> tuple:
    """The toy's script (checked first, before any device is opened) and the engine, whose
    OpenCL platform the toy runs on: ``(toy or None without --compare toy, engine)``.
    Raises :class:`ToyUnavailable`."""
    script = toy_script_path(args.toy_script) if "toy" in args.compare else None
    engine = get_engine(args.device)
    if script is None:
        return None, engine
    platform_name = engine.provenance.get("opencl_platform")
    if not platform_name:
        raise ToyUnavailable("needs an OpenCL device (--device)")
    return {"script": script, "platform": platform_name, "runs": []}, engine


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        toy, engine = prepare_toy(args)
    except ToyUnavailable as err:
        print(f"bench: --compare toy: {err}", file=sys.stderr)
        return 1
    result = {"date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
              "host": platform.node(), "cores": os.cpu_count(),
              "cpu": platform.processor() or platform.machine(),
              "device": engine.provenance, "precision": args.precision, "rounds": args.rounds,
              "loadavg_start": loadavg(), "scenes": {}}
    print(f"# {engine.provenance['opencl_device']} | {engine.provenance['opencl_platform']} | "
          f"{os.cpu_count()} cores | {args.precision} precision | {rounds_text(args.rounds)} | "
          f"load average {result['loadavg_start']}")
    plan = {}
    for name in args.scene_list:
        params, _ = walk_params(load_preset(SCENES[name]))
        photons, numpy_photons = scene_photons(name, args)
        plan[name] = {"params": params, "photons": photons, "numpy_photons": numpy_photons}
        for mode in args.mode_list:
            warm_up(engine, dataclasses.replace(params, mode=mode), photons, args.precision)
            result.setdefault("lanes", {})[f"{params.texture} {mode}"] = engine.lanes_for(
                params.texture, args.precision, mode == "weighted")
    print("# lanes: " + ", ".join(f"{k} {v}" for k, v in result.get("lanes", {}).items()))

    runs = {name: {"numpy": [], **{mode_key(m): [] for m in args.mode_list}} for name in plan}
    counts = {}
    result["loadavg_rounds"] = []
    for r in range(args.rounds):
        try:
            line = run_round(plan, engine, args, runs, counts, toy)
        except ToyUnavailable as err:
            print(f"bench: --compare toy: {err}", file=sys.stderr)
            return 1
        result["loadavg_rounds"].append(loadavg())
        print(f"round {r + 1}/{args.rounds}: {line} | load average {result['loadavg_rounds'][-1]}",
              flush=True)

    print(f"# median [min–max] over {rounds_text(args.rounds)}")
    for name in plan:
        row, lines = scene_report(name, runs[name], args)
        result["scenes"][name] = row
        print("\n".join(lines), flush=True)
    if "T1" in plan and "B1" in plan:
        result["tail_over_b1"], line = tail_report(runs, args)
        print(line)
    if toy is not None:
        result["toy"], lines = toy_summary(toy["runs"], runs["B1"][mode_key(args.mode_list[0])],
                                           toy["script"])
        result["scenes"]["B1"]["ratio_to_toy"] = result["toy"]["ratio_events_per_s"]["median"]
        toy_device = (result["toy"]["device"] or "").split(" | ")[0]
        if toy_device and toy_device != engine.provenance["opencl_device"]:
            lines.append(f"  NOTE: the toy ran on {toy_device!r}, ours on "
                         f"{engine.provenance['opencl_device']!r}")
        print("\n".join(lines), flush=True)
    if "mcxcl" in args.compare and run_mcxcl(plan, engine, counts, result, args) != 0:
        return 1
    result["loadavg_end"] = loadavg()
    print(f"# load average at the end {result['loadavg_end']}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=1)
    return 0


def run_mcxcl(plan: dict, engine, counts: dict, result: dict, args) -> int:
    """``--compare mcxcl`` on each slab scene, after the rounds; 1 if MCX-CL is unavailable."""
    import mcxcl_compare
    state = {}
    for name, scene in plan.items():
        if scene["params"].texture != "slab":
            print(f"  MCX-CL: not run on {name} (granular: MCX's voxel box has interfaces)")
            continue
        row = result["scenes"][name]
        try:
            row["mcxcl"], report = compare_mcxcl(engine, scene["params"], row["opencl"],
                                                 counts[name], args, state)
        except mcxcl_compare.McxclUnavailable as err:
            print(f"bench: --compare mcxcl: {err}", file=sys.stderr)
            return 1
        row["ratio_to_mcxcl"] = row["mcxcl"]["ratio_events_per_s"]
        print(report, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
