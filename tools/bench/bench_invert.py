#!/usr/bin/env python3
"""Speed of ``warpe-cl invert`` (issue 14's goal: 100 BELA shots at 12.5 ns against a
1,000-scenario database in under 10 s on 2 cores).

    python tools/bench/bench_invert.py --work DIR [--grid 10] [--photons 1e4] [--rounds 5]
                                       [--shots 100] [--instrument bela]

In ``DIR`` it builds, once (kept for the next run):

- ``db/``: a ``warpe-cl sweep`` database of granular CO2 (presets/study/gran_co2.yaml) with
  ``--grid`` values per key, log-spaced over the study's ranges: grain size 25-400 um,
  thickness 1-1000 mm, and compacity 0.1-0.9 (linear): ``grid``³ scenarios;
- ``obs.nc``: ``--shots`` shots of ``--instrument`` from a surface off every grid node (grain
  size 141 um, compacity 0.55, thickness 43 mm), simulated with the database's photon count.

It then times ``warpe_cl.invert(obs.nc, db)`` ``--rounds`` times in this process (the database
loaded once, as a user inverting many waveforms would; the first round also pays for
loading it and is reported apart), and prints the median and range of the wall time, the
model evaluations and evaluations per second, with the machine's load.
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import loadavg  # noqa: E402

#: The inversion study's granular CO2 family (the repository is three folders up).
PRESET = Path(__file__).resolve().parents[2] / "presets" / "study" / "gran_co2.yaml"
#: The injected surface: off every node of any grid of the ranges below.
TRUTH = {"medium.inclusions[0].grain_size": "141 um", "medium.compacity": 0.55,
         "medium.thickness": "43 mm"}


def bench_preset(grid: int) -> dict:
    """presets/study/gran_co2.yaml with ``grid`` values per swept key."""
    raw = yaml.safe_load(PRESET.read_text())
    raw["name"] = f"bench_invert_{grid}"
    raw["sweep"] = {
        "medium.inclusions[0].grain_size": [f"{v:.4g} um" for v in np.geomspace(25, 400, grid)],
        "medium.compacity": [round(float(v), 6) for v in np.linspace(0.1, 0.9, grid)],
        "medium.thickness": [f"{v:.4g} mm" for v in np.geomspace(1, 1000, grid)],
    }
    return raw


def run(cmd: list) -> None:
    print("$ " + " ".join(map(str, cmd)), flush=True)
    subprocess.run([sys.executable, "-m", "warpe_cl", *map(str, cmd)], check=True)


def build(work: Path, grid: int, photons: int, shots: int, instrument: str) -> tuple:
    """The database and the observation (made once)."""
    work.mkdir(parents=True, exist_ok=True)
    db, obs = work / "db", work / "obs.nc"
    preset = work / "preset.yaml"
    preset.write_text(yaml.safe_dump(bench_preset(grid), sort_keys=False))
    if not (db / "manifest.json").exists() or len(list(db.glob("s*.nc"))) < grid ** 3:
        run(["sweep", preset, "--out", db, "--photons", photons, "--quiet"]
            + (["--resume"] if db.exists() else []))
    if not obs.exists():
        one = {k: v for k, v in bench_preset(grid).items() if k != "sweep"}
        from warpe_cl.config.keys import apply_overrides
        apply_overrides(one, dict(TRUTH))
        (work / "truth.yaml").write_text(yaml.safe_dump(one, sort_keys=False))
        run(["run", work / "truth.yaml", "--photons", photons, "--seed", 11,
             "--out", work / "truth.nc", "--overwrite", "--quiet"])   # a stopped build's
        run(["instrument", work / "truth.nc", "--instrument", instrument, "--shots", shots,
             "--seed", 12, "--out", obs, "--quiet"])
    return db, obs


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--work", required=True, help="folder of the database and observation")
    p.add_argument("--grid", type=int, default=10, help="values per swept key (10: 1,000)")
    p.add_argument("--photons", type=float, default=1e4, help="rays per scenario (1e4)")
    p.add_argument("--shots", type=int, default=100, help="recorded shots (100)")
    p.add_argument("--instrument", default="bela")
    p.add_argument("--rounds", type=int, default=5, help="timed inversions (5)")
    args = p.parse_args(argv)
    db_path, obs = build(Path(args.work), args.grid, int(args.photons), args.shots,
                         args.instrument)

    from warpe_cl import invert
    from warpe_cl.database import load_result
    start = time.perf_counter()
    db = load_result(db_path)
    load_s = time.perf_counter() - start
    times, evaluations = [], []
    for _ in range(args.rounds):
        start = time.perf_counter()
        fit = invert(obs, db, database_source=str(db_path))
        times.append(time.perf_counter() - start)
        evaluations.append(int(fit.attrs["evaluations"]))
    med = statistics.median(times)
    print(f"machine: {platform.node()}, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, load {loadavg()}")
    print(f"database: {db.sizes['scenario']} scenarios ({args.grid}^3), loaded in "
          f"{load_s:.2f} s; observation: {args.shots} {args.instrument} shots")
    print(f"invert: median {med:.2f} s over {args.rounds} rounds [{min(times):.2f}, "
          f"{max(times):.2f}], {statistics.median(evaluations)} model evaluations, "
          f"{statistics.median(evaluations) / med:.0f} evaluations/s")
    r = fit.sel(parameter=list(TRUTH))
    for key in TRUTH:
        q = r.sel(parameter=key)
        print(f"  {key}: truth {TRUTH[key]}, best {float(q['best']):.4g}, 95 % "
              f"[{float(q['low95']):.4g}, {float(q['high95']):.4g}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
