#!/usr/bin/env python3
"""Speed and figure of merit of the next-event (nadir) estimator on bench scene B1 (or --scene).

    python tools/bench/nadir_fom.py [--photons N] [--rounds R] [--roulettes 0,0.01,0.1,1]
                                    [--cones 1,3,12] [--scene B1] [--device SPEC] [--write [FILE]]

Scene B1 of tools/bench/bench.py (60 mm slab, tau0 = 60.3, omega = 0.99502, n = 1.3, g = 0.8,
Lambertian floor A = 0.15, 5 ns cap) is walked with ``simulation.nadir: false`` and with the
estimator at each ``simulation.nadir_roulette`` of --roulettes, in interleaved rounds: a round
runs every configuration once, in one order, and the next round in the reverse order,
after one untimed warm-up run of each configuration that builds its kernel, so that a drift
of a shared machine's load falls on all alike. T is the engine's walk time
(``get_engine().last_walk_s``: the launches, not the reduction). Each round prints its
events/s and its exact T / T(off) per configuration (the rounds of several sessions were
pooled by tools/pool_rounds.py, since retired: docs/performance.md, "Tools retired"). Round i
walks seed i (from 1) in every configuration, so the ratios are paired on the same rays and the
FOMs' ranges over rounds carry the noise of their standard errors (32 batches: about 13 %
each, 25 % on a FOM), not only the machine's. Per configuration, median
[min-max] over rounds:

- scattering events/s, ``scattering_events`` / T, and the time ratio T / T(no estimator) of
  the same round;
- the figure of merit FOM = 1 / ((sigma / value)^2 T) (1/s; relative sigma, as tools/bench/bench.py
  writes its FOMs, so that estimates of slightly different values compare) of the
  time-integrated nadir estimate ``nadir_brdf`` of ``scattering`` and of ``bf_diffuse``, each
  with its own ``nadir_brdf_stderr`` (the spread of the walk's 32 batches), and of their sum,
  whose error is the spread of the batches of the summed rows (both rows come from the same
  rays: their errors do not add in quadrature);
- for the run without the estimator, the FOM of the FOV estimate of the same quantities in
  cones of --cones degrees, time-integrated from ``angular_reflectance`` (rays in the cone,
  Poisson sigma = sqrt(rays), the same T);
- per time bin, each estimator configuration's FOM of the ``scattering`` row over the first
  one's in the same round (the median over the bins, and the lowest bin), which shows what a
  larger roulette costs the bins it touches most (the earliest and the latest).

B1's slab lies over a vacuum gap: the estimate includes the mirror paths of its lower face
(docs/walk.md §8.5; at τ0 = 60 none is above the mirror table's cut).

Prints the table with the machine and the OpenCL device; --write also writes it to
docs/bench/2026-11-23_nadir_fom.txt (or FILE).
"""
from __future__ import annotations

import argparse
import copy
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import warpe_cl
from bench import SCENES, fmt_spread, rounds_text, spread  # tools/bench/ is first on sys.path

# the estimator's checks and the FOV cones are the study's, tools/studies/nadir_cones.py
sys.path.append(str(Path(__file__).resolve().parent.parent / "studies"))
from nadir_cones import (DIFFUSE, check_estimator, fov_cone, machine_line,  # noqa: E402
                         nadir_sum, run_with_counts)
from warpe_cl.api import get_engine  # noqa: E402

DEFAULT_OUT = Path("docs/bench/2026-11-23_nadir_fom.txt")
QUANTITIES = ("scattering", "bf_diffuse", "diffuse")


def configurations(roulettes) -> list:
    """(label, overrides) of each configuration: the estimator off, then on at each roulette."""
    out = [("nadir off", {"simulation.nadir": False})]
    out += [(f"nadir, roulette {r:g}", {"simulation.nadir": True,
                                         "simulation.nadir_roulette": float(r)})
            for r in roulettes]
    return out


def fom(value: float, sigma: float, seconds: float) -> float:
    """1 / ((sigma / value)^2 T), 1/s (inf where sigma is 0, 0 where the value is 0)."""
    if value <= 0 or not math.isfinite(sigma):
        return 0.0
    return math.inf if sigma == 0 else value * value / (sigma * sigma * seconds)


def one_run(overrides: dict, photons: int, cones, device=None, scene_name: str = "B1") -> dict:
    """Walk bench scene ``scene_name`` once with ``overrides``: T, events/s, and the estimates
    with their FOMs."""
    scene = copy.deepcopy(SCENES[scene_name])
    cfg = warpe_cl.load_preset(scene, overrides={"simulation.photons": photons,
                                                 **overrides})
    ds, counts, walk = run_with_counts(cfg, device)
    events = float(ds["scattering_events"])
    row = {"walk_s": walk, "events": events, "events_per_s": events / walk, "nadir": {},
           "fov": {}}
    if counts.nadir:
        for comp in DIFFUSE:
            v = float(ds["nadir_brdf"].sel(component=comp))
            s = float(ds["nadir_brdf_stderr"].sel(component=comp))
            row["nadir"][comp] = (v, s, fom(v, s, walk))
        nad = nadir_sum(ds, counts)
        row["nadir"]["diffuse"] = (nad["brdf"], nad["brdf_err"],
                                   fom(nad["brdf"], nad["brdf_err"], walk))
        row["bins"] = (ds["nadir_reflectance"].sel(component="scattering").values,
                       ds["nadir_reflectance_stderr"].sel(component="scattering").values,
                       ds["nadir_reflectance"]["time"].values)
    kind = cfg.get("simulation.solid_angle")
    for theta in cones:
        for q, comps in (("scattering", ("scattering",)), ("bf_diffuse", ("bf_diffuse",)),
                         ("diffuse", DIFFUSE)):
            v, s, rays = fov_cone(ds, theta, kind, comps)
            row["fov"][(theta, q)] = (v, s, fom(v, s, walk), rays)
    return row


def measure(args) -> dict:
    """Warm-up, then --rounds interleaved rounds of every configuration, in turn in one order
    and the reverse (as tools/bench/bench_ab.py), so that a drift of the machine's speed within a
    round weighs on every configuration alike. Round i walks seed i (from 1): the same rays
    in every configuration of a round, other rays in the next."""
    configs = configurations(args.roulettes)
    for _, over in configs:                     # builds each kernel, untimed
        one_run(over, min(args.photons, 10_000), args.cones, args.device, args.scene_name)
    runs = {label: [] for label, _ in configs}
    for i in range(args.rounds):
        for label, over in (configs if i % 2 == 0 else configs[::-1]):
            runs[label].append(one_run({**over, "simulation.seed": 1 + i}, args.photons,
                                       args.cones, args.device, args.scene_name))
        off = runs[configs[0][0]][-1]["walk_s"]
        print(f"round {i + 1}/{args.rounds}: scattering events/s: "
              + ", ".join(f"{label} {runs[label][-1]['events_per_s']:.3g}"
                          for label, _ in configs)
              + "; T / T(off): "
              + ", ".join(f"{label} {runs[label][-1]['walk_s'] / off:.4f}"
                          for label, _ in configs[1:]), flush=True)
    return runs


def bin_foms(row: dict) -> np.ndarray:
    """The FOM of each time bin of the run's scattering row, (value / sigma)^2 / T (NaN where
    either is 0)."""
    v, s, _ = row["bins"]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((v > 0) & (s > 0), (v / s) ** 2 / row["walk_s"], np.nan)


def per_bin_lines(runs: dict) -> list:
    """Each nadir configuration's per-bin FOM over the first nadir configuration's, same round
    (time bins of ``scattering`` whose relative error is below 0.3 in the first round of the
    first configuration): the median over bins (median [min-max] over rounds), and the lowest
    bin of the ratio averaged over rounds, which shows a bin that a roulette hurts."""
    labels = [label for label in runs if runs[label][0]["nadir"]]
    if len(labels) < 2:
        return []
    ref = labels[0]
    v, s, t = runs[ref][0]["bins"]
    ok = (v > 0) & (s > 0) & (s < 0.3 * v)
    lines = ["", f"per-bin FOM of the scattering row over {ref}'s, same round ({ok.sum()} time "
                 "bins with relative error < 0.3): median over bins, lowest bin of the mean "
                 "over rounds"]
    for label in labels[1:]:
        ratios = np.array([bin_foms(r)[ok] / bin_foms(o)[ok]
                           for r, o in zip(runs[label], runs[ref])])
        med = spread(np.nanmedian(ratios, axis=1))
        mean = np.nanmean(ratios, axis=0)
        low = int(np.nanargmin(mean))
        lines.append(f"{label:<22} median {fmt_spread(med, '.3f')}, lowest {mean[low]:.3f} "
                     f"(t = {t[ok][low]:.3g} ns)")
    return lines


def table(runs: dict, args, header: str) -> list:
    """The report's lines."""
    off = runs["nadir off"]
    lines = [header,
             f"# {args.scene_name} (tools/bench/bench.py), {args.photons:.3g} photons per run, "
             f"{rounds_text(args.rounds)}, median [min-max]; T = walk time; "
             f"FOM = 1 / ((sigma / value)^2 T), 1/s",
             "",
             f"{'configuration':<22} {'T (s)':>22} {'scattering events/s':>28} "
             f"{'T / T(off)':>22}"]
    for label, rows in runs.items():
        t = spread(r["walk_s"] for r in rows)
        e = spread(r["events_per_s"] for r in rows)
        ratio = spread(r["walk_s"] / o["walk_s"] for r, o in zip(rows, off))
        lines.append(f"{label:<22} {fmt_spread(t, '.3g'):>22} {fmt_spread(e, '.3g'):>28} "
                     f"{fmt_spread(ratio, '.3f'):>22}")
    lines += ["", "time-integrated nadir estimate (nadir_brdf, sr^-1: value +- sigma of the "
                  "first round) and its FOM:",
              f"{'configuration':<22} " + " ".join(f"{q:>46}" for q in QUANTITIES)]
    for label, rows in runs.items():
        if not rows[0]["nadir"]:
            continue
        cells = []
        for q in QUANTITIES:
            v, s, _ = rows[0]["nadir"][q]
            f = spread(r["nadir"][q][2] for r in rows)
            cells.append(f"{v:.4g}+-{s:.2g} FOM {fmt_spread(f, '.3g')}")
        lines.append(f"{label:<22} " + " ".join(f"{c:>46}" for c in cells))
    lines += ["", "FOV estimate in a cone (angular_reflectance rings, Poisson sigma; run without "
                  "the estimator, same T), sr^-1, and its FOM:",
              f"{'cone':<22} " + " ".join(f"{q:>46}" for q in QUANTITIES)]
    for theta in args.cones:
        cells = []
        for q in QUANTITIES:
            v, s, _, rays = off[0]["fov"][(theta, q)]
            if rays == 0:
                cells.append("no ray in the cone")
                continue
            f = spread(r["fov"][(theta, q)][2] for r in off)
            cells.append(f"{v:.4g}+-{s:.2g} FOM {fmt_spread(f, '.3g')}")
        lines.append(f"{f'FOV {theta} deg':<22} " + " ".join(f"{c:>46}" for c in cells))
    best_label = max((lbl for lbl in runs if runs[lbl][0]["nadir"]),
                     key=lambda lbl: statistics.median(r["nadir"]["diffuse"][2]
                                                       for r in runs[lbl]))
    gains = []
    for theta in args.cones:
        g = spread(r["nadir"]["diffuse"][2] / o["fov"][(theta, "diffuse")][2]
                   for r, o in zip(runs[best_label], off) if o["fov"][(theta, "diffuse")][2] > 0)
        gains.append(f"{theta} deg {fmt_spread(g, '.3g')}")
    lines += ["", f"FOM gain of the diffuse sum, best nadir configuration ({best_label}) / FOV "
                  f"(same round): " + ", ".join(gains)]
    return lines + per_bin_lines(runs)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--photons", type=float, default=3e5, help="rays per run (default 3e5)")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--roulettes", default="0,0.01,0.1,1",
                   help="simulation.nadir_roulette values (default 0,0.01,0.1,1)")
    p.add_argument("--cones", default="1,3,12", help="FOV cones, whole degrees (default 1,3,12)")
    p.add_argument("--scene", dest="scene_name", default="B1", choices=sorted(SCENES),
                   help="the bench scene of tools/bench/bench.py (default B1)")
    p.add_argument("--device", default=None)
    p.add_argument("--write", nargs="?", const=str(DEFAULT_OUT), default=None, metavar="FILE",
                   help=f"also write the table (default file {DEFAULT_OUT})")
    args = p.parse_args(argv)
    args.photons = int(args.photons)
    args.roulettes = [float(r) for r in args.roulettes.split(",")]
    args.cones = [int(c) for c in args.cones.split(",")]
    t0 = time.perf_counter()
    get_engine(args.device)
    check_estimator(copy.deepcopy(SCENES[args.scene_name]), {})
    header = f"# {machine_line(args.device)}"
    print(header, flush=True)
    runs = measure(args)
    lines = table(runs, args, header)
    lines.append(f"# load average at the end {machine_line(args.device).split('load average ')[1]}"
                 f"; {time.perf_counter() - t0:.0f} s in all")
    print("\n".join(lines[1:]))
    if args.write:
        out = Path(args.write)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text("python tools/bench/nadir_fom.py " + " ".join(argv or sys.argv[1:]) + "\n"
                       + "\n".join(lines) + "\n")
        print(f"written: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
