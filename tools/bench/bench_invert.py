#!/usr/bin/env python3
"""Speed of a sweep database's opening and of ``warpe-cl invert`` against it (issue 14: 100
BELA shots at 12.5 ns against a 1,000-scenario database in under 10 s on 2 cores; issue 41: a
200-scenario database opens in under 1 s, and 100 BELA shots invert against it in under 5 s).

    python tools/bench/bench_invert.py --work DIR [--grid 10 | --grid 8,5,5] [--photons 1e4]
                                       [--rounds 5] [--shots 100] [--instrument bela]
                                       [--open-rounds 5] [--cli-rounds 5] [--profile FILE]
                                       [--jobs N]

In ``DIR`` it builds, once (kept for the next run):

- ``db/``: a ``warpe-cl sweep`` database of granular CO2 (presets/study/gran_co2.yaml) with
  ``--grid`` values per key (one number for all three, or grain size, compacity, thickness),
  log-spaced over the study's ranges: grain size 25-400 um, thickness 1-1000 mm, and
  compacity 0.1-0.9 (linear); the sweep writes its store ``db/database.nc`` at the end;
- ``obs.nc``: ``--shots`` shots of ``--instrument`` from a surface off every grid node (grain
  size 141 um, compacity 0.55, thickness 43 mm), simulated with the database's photon count.

It then measures, printing the median and range of each:

1. opening the database (``warpe_cl.open_database``) from its store and from its scenario
   files (``store=False``, as a folder without a store is read), ``--open-rounds`` rounds
   interleaved (store, files, store, files ...), each in a fresh Python process: the imports
   (``warpe_cl.database``, xarray, h5py), the first open in the process and a second one;
2. ``warpe-cl invert obs.nc --database db --jobs N`` end to end (a fresh process: Python's
   start, imports, the open, the inversion, the output file), ``--cli-rounds`` times;
3. ``warpe_cl.invert(obs.nc, db)`` ``--rounds`` times in this process on the database loaded
   once (as a user inverting many waveforms would), with ``jobs=1`` and ``jobs=--jobs``
   interleaved: wall time, model evaluations and evaluations per second; ``--profile FILE``
   writes a cProfile of one more such inversion and prints its 25 costliest functions.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import loadavg  # noqa: E402
from warpe_cl.cpus import allocated_cpus  # noqa: E402

#: The inversion study's granular CO2 family (the repository is three folders up).
PRESET = Path(__file__).resolve().parents[2] / "presets" / "study" / "gran_co2.yaml"
#: The injected surface: off every node of any grid of the ranges below.
TRUTH = {"medium.inclusions[0].grain_size": "141 um", "medium.compacity": 0.55,
         "medium.thickness": "43 mm"}


def grid_shape(text) -> tuple:
    """``--grid``: ``"10"`` -> (10, 10, 10); ``"8,5,5"`` -> (8, 5, 5): values of grain size,
    compacity and thickness."""
    parts = [int(v) for v in str(text).split(",")]
    if len(parts) == 1:
        parts *= 3
    if len(parts) != 3 or min(parts) < 2:
        raise SystemExit(f"--grid {text}: give N or N1,N2,N3 with every N >= 2")
    return tuple(parts)


def bench_preset(grid) -> dict:
    """presets/study/gran_co2.yaml with ``grid`` values per swept key (an int for all three,
    or (grain size, compacity, thickness))."""
    shape = grid_shape(grid) if not isinstance(grid, tuple) else grid
    raw = yaml.safe_load(PRESET.read_text())
    raw["name"] = "bench_invert_" + "x".join(map(str, shape))
    raw["sweep"] = {
        "medium.inclusions[0].grain_size": [f"{v:.4g} um"
                                            for v in np.geomspace(25, 400, shape[0])],
        "medium.compacity": [round(float(v), 6) for v in np.linspace(0.1, 0.9, shape[1])],
        "medium.thickness": [f"{v:.4g} mm" for v in np.geomspace(1, 1000, shape[2])],
    }
    return raw


def spread(values) -> dict:
    """Median, least and largest of ``values``."""
    return {"median": statistics.median(values), "min": min(values), "max": max(values),
            "n": len(values)}


def spread_text(values, unit: str = "s") -> str:
    """``1.23 s [1.20, 1.31] (5 rounds)``."""
    s = spread(values)
    return (f"{s['median']:.3g} {unit} [{s['min']:.3g}, {s['max']:.3g}] "
            f"({s['n']} round{'s' if s['n'] != 1 else ''})")


def interleaved(labels: list, rounds: int) -> list:
    """The order of the measurements: every label once per round, the order reversed every
    other round (a drift of the machine weighs on all labels alike)."""
    order = []
    for r in range(rounds):
        order += labels if r % 2 == 0 else labels[::-1]
    return order


def run(cmd: list) -> None:
    print("$ " + " ".join(map(str, cmd)), flush=True)
    subprocess.run([sys.executable, "-m", "warpe_cl", *map(str, cmd)], check=True)


def build(work: Path, grid, photons: int, shots: int, instrument: str) -> tuple:
    """The database (with its store), a copy without the store (a folder written before
    stores, read file by file) and the observation (made once)."""
    shape = grid_shape(grid)
    work.mkdir(parents=True, exist_ok=True)
    db, obs = work / "db", work / "obs.nc"
    preset = work / "preset.yaml"
    preset.write_text(yaml.safe_dump(bench_preset(shape), sort_keys=False))
    if not (db / "manifest.json").exists() or not (db / "database.nc").exists():
        run(["sweep", preset, "--out", db, "--photons", photons, "--quiet"]
            + (["--resume"] if db.exists() else []))
    files = work / "db-files"
    if not files.exists():
        shutil.copytree(db, files, ignore=shutil.ignore_patterns("database.nc", ".*"))
    if not obs.exists():
        one = {k: v for k, v in bench_preset(shape).items() if k != "sweep"}
        from warpe_cl.config.keys import apply_overrides
        apply_overrides(one, dict(TRUTH))
        (work / "truth.yaml").write_text(yaml.safe_dump(one, sort_keys=False))
        run(["run", work / "truth.yaml", "--photons", photons, "--seed", 11,
             "--out", work / "truth.nc", "--overwrite", "--quiet"])   # a stopped build's
        run(["instrument", work / "truth.nc", "--instrument", instrument, "--shots", shots,
             "--seed", 12, "--out", obs, "--quiet"])
    return db, files, obs


#: A fresh process times its imports, a first and a second open_database, and prints JSON.
OPEN_CHILD = """
import json, sys, time
t0 = time.perf_counter()
import warpe_cl.database, xarray, h5py
t1 = time.perf_counter()
ds = warpe_cl.database.open_database(sys.argv[1])
t2 = time.perf_counter()
warpe_cl.database.open_database(sys.argv[1])
t3 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "first_s": t2 - t1, "second_s": t3 - t2,
                  "scenarios": ds.sizes["scenario"], "store": ds.attrs.get("sweep_store")}))
"""


def measure_open(folders: dict, rounds: int) -> dict:
    """label -> list of the child's JSON (:data:`OPEN_CHILD`), ``rounds`` interleaved rounds."""
    out = {label: [] for label in folders}
    for label in interleaved(list(folders), rounds):
        done = subprocess.run([sys.executable, "-c", OPEN_CHILD, str(folders[label])],
                              check=True, capture_output=True, text=True)
        out[label].append(json.loads(done.stdout.strip().splitlines()[-1]))
    return out


def measure_cli(obs: Path, folders: dict, rounds: int, work: Path, jobs: int) -> dict:
    """label -> wall times (s) of ``warpe-cl invert --jobs JOBS`` end to end, rounds
    interleaved."""
    out = {label: [] for label in folders}
    for label in interleaved(list(folders), rounds):
        cmd = [sys.executable, "-m", "warpe_cl", "invert", str(obs), "--database",
               str(folders[label]), "--out", str(work / "fit.nc"), "--overwrite", "--quiet",
               "--jobs", str(jobs)]
        start = time.perf_counter()
        subprocess.run(cmd, check=True)
        out[label].append(time.perf_counter() - start)
    return out


def in_process(args, db_path: Path, obs: Path) -> None:
    """``warpe_cl.invert`` ``args.rounds`` times on the database loaded once; the profile of
    one more with ``args.profile``."""
    from warpe_cl import invert
    from warpe_cl.database import load_result
    start = time.perf_counter()
    db = load_result(db_path)
    load_s = time.perf_counter() - start
    print(f"database: {db.sizes['scenario']} scenarios ({args.grid}), loaded in {load_s:.2f} s "
          f"(store: {db.attrs.get('sweep_store') or 'none'}); observation: {args.shots} "
          f"{args.instrument} shots")
    counts = sorted({1, args.jobs})
    times = {n: [] for n in counts}
    evaluations = {n: set() for n in counts}
    for _ in range(args.rounds):            # jobs=1 and jobs=N interleaved
        for n in counts:
            start = time.perf_counter()
            fit = invert(obs, db, database_source=str(db_path), jobs=n)
            times[n].append(time.perf_counter() - start)
            evaluations[n].add(int(fit.attrs["evaluations"]))
    for n in counts if args.rounds else []:
        med = statistics.median(times[n])
        count = max(evaluations[n])
        print(f"invert in process, jobs={n}: {spread_text(times[n])}, "
              f"{'/'.join(map(str, sorted(evaluations[n])))} model evaluations, "
              f"{count / med:.0f} evaluations/s")
    if args.rounds:
        r = fit.sel(parameter=list(TRUTH))
        for key in TRUTH:
            q = r.sel(parameter=key)
            print(f"  {key}: truth {TRUTH[key]}, best {float(q['best']):.4g}, 95 % "
                  f"[{float(q['low95']):.4g}, {float(q['high95']):.4g}]")
    if args.profile:
        import cProfile
        import pstats
        profiler = cProfile.Profile()
        profiler.runcall(invert, obs, db, database_source=str(db_path))
        profiler.dump_stats(args.profile)
        pstats.Stats(args.profile).sort_stats("cumulative").print_stats(30)
        pstats.Stats(args.profile).sort_stats("tottime").print_stats(15)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--work", required=True, help="folder of the database and observation")
    p.add_argument("--grid", default="10",
                   help="values per swept key: N (N^3 scenarios; 10: 1,000) or N1,N2,N3 "
                        "(grain size, compacity, thickness; 8,5,5: 200)")
    p.add_argument("--photons", type=float, default=1e4, help="rays per scenario (1e4)")
    p.add_argument("--shots", type=int, default=100, help="recorded shots (100)")
    p.add_argument("--instrument", default="bela")
    p.add_argument("--rounds", type=int, default=5, help="timed inversions in process (5)")
    p.add_argument("--open-rounds", type=int, default=5, help="interleaved opens (5)")
    p.add_argument("--cli-rounds", type=int, default=5, help="timed `warpe-cl invert` (5)")
    p.add_argument("--profile", help="write a cProfile of one inversion to this file")
    p.add_argument("--jobs", type=int, default=allocated_cpus(),
                   help="worker processes of `warpe-cl invert --jobs` and of the in-process "
                        "inversions timed beside jobs=1 (default: the CPUs this process may "
                        "use)")
    args = p.parse_args(argv)
    work = Path(args.work)
    db_path, files_path, obs = build(work, args.grid, int(args.photons), args.shots,
                                     args.instrument)
    print(f"machine: {platform.node()}, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, load {loadavg()}")
    folders = {"store": db_path, "files": files_path}

    if args.open_rounds:
        opens = measure_open(folders, args.open_rounds)
        n = opens["store"][0]["scenarios"]
        assert opens["store"][0]["store"] and not opens["files"][0]["store"]
        for label, rows in opens.items():
            print(f"open {n} scenarios from {label:5s}: first in a process "
                  f"{spread_text([r['first_s'] for r in rows])}, second "
                  f"{spread_text([r['second_s'] for r in rows])}; imports "
                  f"{spread_text([r['import_s'] for r in rows])}")
    if args.cli_rounds:
        cli = measure_cli(obs, folders, args.cli_rounds, work, args.jobs)
        for label, times in cli.items():
            print(f"warpe-cl invert --jobs {args.jobs} ({args.shots} {args.instrument} shots, "
                  f"database read from {label}), end to end: {spread_text(times)}")

    if args.rounds or args.profile:
        in_process(args, db_path, obs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
