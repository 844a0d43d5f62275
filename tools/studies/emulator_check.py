#!/usr/bin/env python3
"""Does log L through a database agree with log L of directly simulated surfaces within the
database's stated error? (docs/inversion.md §4.3)

    python tools/studies/emulator_check.py --database DB --preset PRESET.yaml
        [--instrument bela|gala|atlas|FILE.yaml] [--points 8] [--photons 3e5] [--shots 100,1000]
        [--seeds 2] [--seed 1] [--out rows.csv]

PRESET is the preset the database was swept from (its ``sweep:`` block is dropped). The tool
draws ``--points`` points uniformly in the database's interpolation coordinates, off the nodes;
simulates each directly with ``--photons`` rays (its own seed); records ``--seeds`` noise
realisations of each shot count with the instrument; and computes at each point log L three
ways (:func:`warpe_cl.inversion.agreement.agreement`): through the database taken as exact
(``plain``), through the database with its error integrated out, and with the direct
surface. It prints, per shot count, the mean and standard deviation of

    z = (log L_plain − log L_direct − offset) / σ,

σ and the offset being the database's stated error and expected offset of log L at that point:
z is about N(0, 1) where the stated error holds (sd(z) ≫ 1: the error is understated; ≪ 1:
overstated). Exit codes: 0 done, 2 bad input.
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

import numpy as np
import yaml


def point_overrides(space, point: dict) -> dict:
    """Dotted key -> override text (value with the axis unit) of a point of ``space``."""
    out = {}
    for axis in space.axes:
        v = point[axis.key]
        out[axis.key] = f"{v!r} {axis.units}" if axis.units not in ("1", "") else v
    return out


def draw_points(space, count: int, rng) -> list:
    """``count`` points uniform in the interpolation coordinates, each more than a tenth of a
    cell from the nodes along every axis of two values or more (an axis of one value keeps
    it)."""
    points = []
    while len(points) < count:
        point = {}
        for axis in space.axes:
            x = axis.nodes
            if x.size < 2:
                point[axis.key] = float(axis.values[0])
                continue
            u = rng.uniform(x[0], x[-1])
            j = min(int(np.searchsorted(x, u, side="right")) - 1, x.size - 2)
            f = (u - x[j]) / (x[j + 1] - x[j])
            if not 0.1 < f < 0.9:
                break
            point[axis.key] = float(axis.value(u))
        else:
            points.append(point)
    return points


def run(args) -> list:
    """Every row of the study (one per point, shot count and noise seed)."""
    from warpe_cl import load_preset, simulate
    from warpe_cl.database import load_result
    from warpe_cl.instrument import apply_instrument, load_instrument
    from warpe_cl.inversion.agreement import agreement
    from warpe_cl.inversion.emulator import Emulator
    from warpe_cl.inversion.forward import Forward
    from warpe_cl.inversion.space import Space
    from warpe_cl.surface import response

    space = Space(load_result(Path(args.database)), source=args.database)
    params = load_instrument(args.instrument)
    forward = Forward(params)
    signal = "signal_counts" if forward.counting else "signal_mv"
    emulator = Emulator(space, forward)         # node waveforms and leave-one-out errors once
    base = yaml.safe_load(Path(args.preset).read_text())
    base.pop("sweep", None)
    rng = np.random.default_rng(args.seed)
    rows = []
    for p, point in enumerate(draw_points(space, args.points, rng)):
        overrides = {**point_overrides(space, point), "simulation.photons": args.photons,
                     "simulation.seed": 1000 + args.seed * 100 + p}
        surface_ds = simulate(load_preset(dict(base), overrides=overrides), progress=False)
        surface = response(surface_ds)
        for shots in args.shots:
            for s in range(args.seeds):
                rec = apply_instrument(surface_ds, params, shots=shots, seed=7 + s)
                out = agreement(space, forward, rec["sample_time"].values,
                                rec[signal].values, point, surface, emulator=emulator)
                rows.append({"point": p, **{k: f"{v:.6g}" for k, v in point.items()},
                             "shots": shots, "seed": 7 + s,
                             **{k: f"{out[k]:.6g}" for k in ("plain", "database", "direct",
                                                            "sigma", "offset", "sigma_direct",
                                                            "z")}})
                print(f"point {p} shots {shots} seed {7 + s}: log L db - direct "
                      f"{out['plain'] - out['direct']:+.2f}, offset {out['offset']:+.2f}, "
                      f"sigma {out['sigma']:.2f}, z {out['z']:+.2f}", flush=True)
    return rows


def summary(rows: list) -> list:
    """Lines: per shot count, the points, mean and sd of z, |z| < 2 share, median σ."""
    lines = ["| shots | n | mean z | sd z | |z| < 2 | median sigma | median |db - direct| |",
             "|---|---|---|---|---|---|---|"]
    for shots in sorted({int(r["shots"]) for r in rows}):
        sel = [r for r in rows if int(r["shots"]) == shots]
        z = np.array([float(r["z"]) for r in sel])
        diff = np.array([abs(float(r["plain"]) - float(r["direct"])) for r in sel])
        sigma = np.array([float(r["sigma"]) for r in sel])
        lines.append(f"| {shots} | {z.size} | {z.mean():+.2f} ± {z.std(ddof=1) / math.sqrt(z.size):.2f} "
                     f"| {z.std(ddof=1):.2f} | {np.mean(np.abs(z) < 2):.2f} "
                     f"| {np.median(sigma):.2f} | {np.median(diff):.2f} |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--database", required=True)
    ap.add_argument("--preset", required=True)
    ap.add_argument("--instrument", default="bela", help="bela, gala, atlas or an instrument file")
    ap.add_argument("--points", type=int, default=8)
    ap.add_argument("--photons", type=float, default=3e5)
    ap.add_argument("--shots", default="100,1000")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", help="CSV of every row")
    args = ap.parse_args(argv)
    try:
        args.shots = [int(s) for s in args.shots.split(",")]
    except ValueError:
        print(f"emulator_check: --shots {args.shots!r}: give whole numbers, e.g. 100,1000",
              file=sys.stderr)
        return 2
    bad = ("--points must be 1 or more" if args.points < 1 else
           "--seeds must be 1 or more" if args.seeds < 1 else
           f"--preset {args.preset}: no such file" if not Path(args.preset).is_file() else
           None)
    if bad:
        print(f"emulator_check: {bad}", file=sys.stderr)
        return 2
    from warpe_cl.errors import ConfigError
    try:
        rows = run(args)
    except ConfigError as exc:
        print(f"emulator_check: {exc}", file=sys.stderr)
        return 2
    if args.out:
        with open(args.out, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    print("\n".join(summary(rows)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
