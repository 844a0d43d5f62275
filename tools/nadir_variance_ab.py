#!/usr/bin/env python3
"""The nadir estimate's variance, time bin by time bin, of two checkouts on the same rays.

    python tools/nadir_variance_ab.py --before <checkout> --after <checkout>
                                      [--scenes B1,B2,B3,T1] [--photons 2e5]
                                      [--set medium.phase_g=0.5] [--device SPEC] [--out FILE]

The estimator draws no random number (docs/walk.md §8), so two kernels that differ only in
how they score (a roulette's threshold, say) walk the same rays from the same seed, and the
ratio of their standard errors, bin by bin, is the change the scoring made, with no noise of
the rays in it. Each checkout walks each scene of tools/bench.py once with
``simulation.nadir: true``, in a process of its own (its own ``warpe_cl`` and ``cl/``); this
prints, per scene and per row (``scattering``, ``bf_diffuse``): the cells the rays opened
(``nadir_ray_count`` summed: the flushes of docs/performance.md), the variance ratio
(after / before) of the time-integrated estimate, and over the bins that both hold, the
median, 90th percentile and extremes of the per-bin variance ratio, with the bins above 1.05.
Walk times are printed as seen, one run each: speed is for tools/bench_ab.py.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from _common import print_report, run_in_tree  # tools/ is first on sys.path when run as a script

ROWS = ("scattering", "bf_diffuse")


def child(scene: str, photons: int, device: str | None, sets: list) -> dict:
    """Walk ``scene`` with the estimate in this process's warpe_cl; its errors per bin."""
    import copy
    import warnings

    import warpe_cl
    from bench import SCENES                              # tools/ is on sys.path
    from warpe_cl.api import get_engine
    overrides = {"simulation.photons": photons, "simulation.nadir": True}
    for item in sets:
        key, value = item.split("=", 1)
        overrides[key] = float(value)
    cfg = warpe_cl.load_preset(copy.deepcopy(SCENES[scene]), overrides=overrides)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = warpe_cl.simulate(cfg, device=device, progress=False)
    out = {"walk_s": float(get_engine(device).last_walk_s), "package": warpe_cl.__file__}
    for row in ROWS:
        sel = {"component": row}
        out[row] = {"brdf_stderr": float(ds["nadir_brdf_stderr"].sel(sel)),
                    "stderr": ds["nadir_reflectance_stderr"].sel(sel).values.tolist(),
                    "cells": int(ds["nadir_ray_count"].sel(sel).values.sum())}
    return out


def run_child(tree: Path, scene: str, photons: int, device: str | None, sets: list) -> dict:
    """``child`` in a new process whose warpe_cl and cl/ are ``tree``'s."""
    args = ["--child", scene, "--photons", photons, *(["--device", device] if device else []),
            *(x for s in sets for x in ("--set", s))]
    return run_in_tree(Path(__file__).resolve(), tree, args)


def variance_ratios(before: dict, after: dict) -> dict:
    """Per-row comparison of two ``child`` results: the cells opened, the variance ratio of
    the time-integrated estimate, and the per-bin variance ratios (after / before) over the
    bins where both errors are positive."""
    out = {}
    for row in ROWS:
        a, b = before[row], after[row]
        sa, sb = np.asarray(a["stderr"], float), np.asarray(b["stderr"], float)
        both = (sa > 0) & (sb > 0)
        ratio = (sb[both] / sa[both]) ** 2
        whole = (b["brdf_stderr"] / a["brdf_stderr"]) ** 2 if a["brdf_stderr"] > 0 else np.nan
        out[row] = {"cells": (a["cells"], b["cells"]), "whole": float(whole),
                    "bins": int(both.sum()), "ratio": ratio,
                    "above": [(int(i), float(r)) for i, r in zip(np.nonzero(both)[0], ratio)
                              if r > 1.05]}
    return out


def report(scene: str, before: dict, after: dict) -> list:
    """The lines of one scene."""
    lines = [f"{scene}: walk {before['walk_s']:.3f} s before, {after['walk_s']:.3f} s after "
             "(one run each)"]
    for row, c in variance_ratios(before, after).items():
        if not c["bins"]:
            lines.append(f"  {row}: no bin with an error in both")
            continue
        r = c["ratio"]
        lines.append(
            f"  {row}: cells opened {c['cells'][0]} -> {c['cells'][1]} "
            f"({c['cells'][1] / max(c['cells'][0], 1):.3f}); variance after / before: "
            f"integrated {c['whole']:.4f}; per bin ({c['bins']} bins) median "
            f"{np.median(r):.4f}, 90th percentile {np.quantile(r, 0.9):.3f}, "
            f"range {r.min():.3f}-{r.max():.3f}")
        if c["above"]:
            lines.append("    bins above 1.05: "
                         + ", ".join(f"{i}: {v:.2f}" for i, v in c["above"]))
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", type=Path)
    ap.add_argument("--after", type=Path)
    ap.add_argument("--scenes", default="B1,B2,B3")
    ap.add_argument("--photons", type=float, default=2e5)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=NUMBER",
                    help="override a scene key (numbers only), e.g. medium.phase_g=0.5")
    ap.add_argument("--device")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    photons = int(args.photons)
    if args.child:
        print(json.dumps(child(args.child, photons, args.device, args.set)))
        return 0
    if args.before is None or args.after is None:
        ap.error("--before and --after are required")
    lines = ["# " + " ".join(["python tools/nadir_variance_ab.py", *sys.argv[1:]])]
    for scene in args.scenes.split(","):
        before = run_child(args.before.resolve(), scene, photons, args.device, args.set)
        after = run_child(args.after.resolve(), scene, photons, args.device, args.set)
        lines += report(scene + "".join(f" ({s})" for s in args.set), before, after)
    print_report(lines, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
