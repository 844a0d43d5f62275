#!/usr/bin/env python3
"""B1 with the nadir estimate on this tree, against B1 without it on this tree and on an older
checkout (docs/performance.md, issue 16's speed goal).

    python tools/nadir_vs_tree.py --tree /path/to/older/checkout [--device SPEC]
                                  [--photons 1e6] [--rounds 9] [--write FILE]

Each round walks B1 (tools/bench.py's scene) three times, each in a new process: the older
tree without the estimate (its ``warpe_cl`` found first on ``PYTHONPATH``; ``simulation.nadir:
false``, or no such key in a tree from before the estimate), this tree without it, and
this tree with it; the order turns from round to round so that a drift of the machine's load
falls on all three alike. A process builds its engine, walks 20 000 untimed rays (the build and
the qualification), then times one ``Engine.run`` of ``--photons`` rays. Printed: the median and
range of each configuration's scattering events/s, and the median, quartiles and range of the
rounds' own time ratios (this tree with the estimate over the older tree without it, this tree
without it over the older one, and with over without on this tree).

An older tree must still walk on the device: one whose kernels fail today's qualification on
it (Intel's runtime before 2026-11-23, whose ``native_log`` was 1e-4 off) cannot be timed there.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
CONFIGS = (("older tree, no estimate", "older", False),
           ("this tree, no estimate", "this", False),
           ("this tree, estimate", "this", True))
RATIOS = (("this tree with the estimate / older tree without", 2, 0),
          ("this tree without the estimate / older tree without", 1, 0),
          ("this tree with the estimate / without", 2, 1))


def b1_config(nadir: bool, older: bool):
    """B1's configuration with ``simulation.nadir`` set; for an older tree that does not know
    the key (a ``ConfigError``) and a walk without the estimate, B1 without the key."""
    import copy

    import warpe_cl
    from bench import SCENES
    from warpe_cl.errors import ConfigError

    scene = copy.deepcopy(SCENES["B1"])
    scene["simulation"]["nadir"] = nadir
    try:
        return warpe_cl.load_preset(scene)
    except ConfigError:
        if nadir or not older:
            raise
        del scene["simulation"]["nadir"]     # a tree from before the estimate: no such key
        return warpe_cl.load_preset(scene)


def child(device: str | None, photons: int, nadir: bool, older: bool) -> dict:
    """One timed walk of B1 in this process (run with the tree's ``PYTHONPATH``)."""
    import warpe_cl
    from warpe_cl.api import get_engine, walk_params

    params, _ = walk_params(b1_config(nadir, older))
    engine = get_engine(device)
    engine.run(params, 20_000)
    t0 = time.perf_counter()
    counts = engine.run(params, photons)
    seconds = time.perf_counter() - t0
    return {"seconds": seconds, "events_per_s": counts.scattering_events / seconds,
            "package": str(Path(warpe_cl.__file__).parent),
            "device": engine.provenance.get("opencl_device", "?"),
            "platform": engine.provenance.get("opencl_platform", "?")}


def run_child(tree: Path, device: str | None, photons: int, nadir: bool, older: bool) -> dict:
    """:func:`child` in a new process with ``tree`` first on ``PYTHONPATH``."""
    from _common import run_in_tree
    args = ["--child", "--photons", photons, *(["--device", device] if device else []),
            *(["--nadir"] if nadir else []), *(["--older"] if older else [])]
    return run_in_tree(Path(__file__).resolve(), tree, args, cwd=HERE)


def round_order(r: int) -> list:
    """The configurations' order in round r: turned by one each round, so that each comes
    first, second and third alike."""
    order = list(range(len(CONFIGS)))
    return order[r % len(order):] + order[:r % len(order)]


def quartiles(numerators: list, denominators: list) -> str:
    """``median [quartiles q1-q3, range min-max]`` of the rounds' ratios (bench_ab's
    paired_ratios)."""
    from bench_ab import paired_ratios
    r = paired_ratios(denominators, numerators)
    return (f"{r['median']:.3f} [quartiles {r['q1']:.3f}-{r['q3']:.3f}, "
            f"range {r['min']:.3f}-{r['max']:.3f}]")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", type=Path, help="the older checkout")
    ap.add_argument("--device", default=None)
    ap.add_argument("--photons", type=float, default=1e6)
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--write", type=Path, help="also write the report here")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--nadir", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--older", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    photons = int(args.photons)
    if args.child:
        print(json.dumps(child(args.device, photons, args.nadir, args.older)))
        return 0
    if args.tree is None:
        ap.error("--tree is required")
    from _common import loadavg, print_report

    trees = {"older": args.tree.resolve(), "this": HERE.parent}
    lines = [f"python tools/nadir_vs_tree.py --tree {args.tree} --device {args.device} "
             f"--photons {args.photons:g} --rounds {args.rounds}",
             f"# load average at the start {loadavg()}"]
    runs = [[] for _ in CONFIGS]
    for r in range(args.rounds):
        for i in round_order(r):
            _, tree, nadir = CONFIGS[i]
            runs[i].append(run_child(trees[tree], args.device, photons, nadir, tree == "older"))
        print(f"round {r + 1}/{args.rounds}: " + ", ".join(
            f"{CONFIGS[i][0]} {runs[i][-1]['events_per_s']:.3g}" for i in range(len(CONFIGS))),
            file=sys.stderr, flush=True)
    first = runs[0][0]
    lines.append(f"# {first['device']} | {first['platform']} | {os.cpu_count()} cores | "
                 f"B1 (tools/bench.py), {photons:.3g} rays per run, {args.rounds} rounds")
    for i, (label, tree, _) in enumerate(CONFIGS):
        ev = [x["events_per_s"] for x in runs[i]]
        lines.append(f"{label:28s} scattering events/s {statistics.median(ev):.3g} "
                     f"[{min(ev):.3g}-{max(ev):.3g}]  ({runs[i][0]['package']})")
    for label, a, b in RATIOS:
        seconds = [[x["seconds"] for x in runs[i]] for i in (a, b)]
        lines.append(f"time, {label}: {quartiles(*seconds)}")
    lines.append(f"# load average at the end {loadavg()}")
    print_report(lines, args.write)
    return 0


if __name__ == "__main__":
    sys.exit(main())
