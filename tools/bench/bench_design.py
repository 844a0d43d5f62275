#!/usr/bin/env python3
"""Speed of ``warpe-cl design`` (issue 42: a family of about 100 surfaces x 5 instruments in
under 10 minutes on 2 cores).

    python tools/bench/bench_design.py --work DIR [--grid 5,4,5] [--photons 1e4]
                                       [--database DB] [--rounds 3]

The family is ``--database`` when given, else a database built once in ``DIR/db`` (kept for the
next run) by ``warpe-cl sweep`` of the granular CO2 study preset with ``--grid`` values of
grain size, compacity and thickness (tools/bench/bench_invert.py's ``bench_preset``; 5,4,5 is
100 surfaces). The instruments are the five of presets/design/example.yaml (BELA, GALA, BELA
sampled at 5 ns, 1 ns and 0.1 ns full-waveform receivers). The study runs in this process
``--rounds`` times (:func:`warpe_cl.design.run.run_study`); the tool prints, per round, the time
of the expected widths per instrument, of the family's opening and points, and in all, with
the machine's load.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import loadavg  # noqa: E402
from bench_invert import bench_preset, grid_shape, run  # noqa: E402

EXAMPLE = Path(__file__).resolve().parents[2] / "presets" / "design" / "example.yaml"


def build(work: Path, grid, photons) -> Path:
    """The benchmark database in ``work/db`` (swept once, resumed if stopped)."""
    shape = grid_shape(grid)
    work.mkdir(parents=True, exist_ok=True)
    db, preset = work / "db", work / "preset.yaml"
    preset.write_text(yaml.safe_dump(bench_preset(shape), sort_keys=False))
    if not (db / "database.nc").exists():
        run(["sweep", preset, "--out", db, "--photons", photons, "--quiet"]
            + (["--resume"] if db.exists() else []))
    return db


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", required=True, help="folder for the database, study and outputs")
    ap.add_argument("--grid", default="5,4,5")
    ap.add_argument("--photons", default="1e4")
    ap.add_argument("--database", help="an existing sweep folder or file instead")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    from warpe_cl.design.run import run_study
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    db = Path(args.database).resolve() if args.database else build(work, args.grid,
                                                                    args.photons)
    study = yaml.safe_load(EXAMPLE.read_text())
    study["families"] = [{"name": "bench", "database": str(db)}]
    path = work / "study.yaml"
    path.write_text(yaml.safe_dump(study, sort_keys=False))
    totals, widths = [], []
    for r in range(args.rounds):
        lines = []
        t0 = time.perf_counter()
        done = run_study(path, work / "out", overwrite=True, say=lines.append, quiet=True)
        total = time.perf_counter() - t0
        totals.append(total)
        widths.append(done["elapsed_s"])
        ds = done["dataset"]
        per = ", ".join(f"{n} {s:.2f} s" for n, s in zip(ds["instrument"].values,
                                                          ds["elapsed"].values))
        print(f"round {r}: {ds.sizes['point']} surfaces x {ds.sizes['instrument']} "
              f"instruments: expected widths {done['elapsed_s']:.2f} s ({per}); "
              f"{total:.2f} s in all (opening, points, outputs, figures); load {loadavg()}",
              flush=True)
    print(f"median: expected widths {statistics.median(widths):.2f} s, in all "
          f"{statistics.median(totals):.2f} s over {args.rounds} rounds")
    return 0


if __name__ == "__main__":
    sys.exit(main())
