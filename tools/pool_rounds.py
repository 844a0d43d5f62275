#!/usr/bin/env python3
"""Pool the rounds of several runs of tools/nadir_fom.py (sessions) into one time ratio with
its confidence interval: is a speed goal met beyond the noise of a shared machine?

    python tools/pool_rounds.py FILE [FILE ...] [--config "nadir, roulette 0.1"] [--goal 1.5]
                                [--resamples 20000] [--seed 1]

Each FILE is the printed output of tools/nadir_fom.py (the raw output kept in docs/bench/);
only its round lines are read. A round's ratio is T / T(off) of the configuration --config
(default: the second of the round line, the first estimator configuration): the exact ratio
where the round line prints it (tools/nadir_fom.py since 2026-11-24), else events/s without
the estimator over events/s of --config, which is the same ratio to the three digits printed
(the estimate draws no random number: both runs walk the same rays, the same events).

Prints, per file: its rounds, their median ratio, range, and the share of rounds above
--goal. Then, over every file: the median of all rounds with two 95 % percentile bootstrap
intervals (--resamples resamples, seeded): one that resamples the rounds, and one that
resamples the files, then the rounds within each, which also carries the spread between
sessions (a session's rounds share its machine's state: they are not independent of each
other). The medians of the files are printed too, with their range.
"""
from __future__ import annotations

import argparse
import re
import statistics
import sys
from pathlib import Path

import numpy as np

ROUND = re.compile(r"^round \d+/\d+: scattering events/s: (?P<speeds>.*?)"
                   r"(?:; T / T\(off\): (?P<ratios>.*))?$")
ITEM = re.compile(r"(.+?) (\d[\d.]*(?:e[+-]?\d+)?)(?:, |$)")


def parse_items(text: str) -> dict:
    """``{label: value}`` of a round line's list ``label value, label value`` (labels may hold
    commas and numbers: ``nadir, roulette 0.1 1.18e+08``)."""
    return {label: float(value) for label, value in ITEM.findall(text)}


def round_ratios(text: str, config: str | None = None) -> list:
    """T / T(off) of ``config`` (default: the second configuration) in every round line of
    ``text``, in order; exact where printed, else from the events/s."""
    out = []
    for line in text.splitlines():
        m = ROUND.match(line.strip())
        if not m:
            continue
        speeds = parse_items(m["speeds"])
        labels = list(speeds)
        label = config or labels[1]
        if label not in speeds:
            raise ValueError(f"--config {label!r}: not in the round line; "
                             f"choose from {', '.join(labels[1:])}")
        exact = parse_items(m["ratios"]) if m["ratios"] else {}
        out.append(exact[label] if label in exact else speeds[labels[0]] / speeds[label])
    return out


def pooled(sessions: list, resamples: int = 20000, seed: int = 1) -> dict:
    """The median of all rounds of ``sessions`` (a list of lists of ratios) and its 95 %
    percentile bootstrap intervals: ``rounds`` (the rounds resampled) and ``sessions`` (the
    sessions resampled, then the rounds within each); ``session_medians``."""
    rng = np.random.default_rng(seed)
    arrays = [np.asarray(s, dtype=float) for s in sessions if len(s)]
    every = np.concatenate(arrays)
    by_rounds = np.median(rng.choice(every, (resamples, every.size)), axis=1)
    by_sessions = np.empty(resamples)
    for i in range(resamples):
        picked = rng.integers(len(arrays), size=len(arrays))
        by_sessions[i] = np.median(np.concatenate(
            [rng.choice(arrays[k], arrays[k].size) for k in picked]))
    return {"rounds": int(every.size), "median": float(np.median(every)),
            "ci_rounds": tuple(np.percentile(by_rounds, [2.5, 97.5])),
            "ci_sessions": tuple(np.percentile(by_sessions, [2.5, 97.5])),
            "session_medians": [float(np.median(a)) for a in arrays]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+", type=Path)
    ap.add_argument("--config", default=None,
                    help="the configuration's label (default: the second of the round lines)")
    ap.add_argument("--goal", type=float, default=1.5, help="the ratio not to exceed")
    ap.add_argument("--resamples", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    if args.resamples < 1:
        ap.error(f"--resamples {args.resamples}: at least 1")
    sessions = []
    for path in args.files:
        try:
            ratios = round_ratios(path.read_text(), args.config)
        except (OSError, ValueError) as err:
            ap.error(f"{path}: {err}")
        if not ratios:
            ap.error(f"{path}: no round line of tools/nadir_fom.py")
        sessions.append(ratios)
        above = sum(r > args.goal for r in ratios)
        print(f"{path.name}: {len(ratios)} rounds, median {statistics.median(ratios):.3f} "
              f"[{min(ratios):.3f}–{max(ratios):.3f}], {above} above {args.goal:g}")
    p = pooled(sessions, args.resamples, args.seed)
    every = [r for s in sessions for r in s]
    lo, hi = p["ci_rounds"]
    slo, shi = p["ci_sessions"]
    med = p["session_medians"]
    print(f"all {p['rounds']} rounds of {len(sessions)} files: median {p['median']:.3f}, "
          f"95 % interval {lo:.3f}–{hi:.3f} (rounds resampled), {slo:.3f}–{shi:.3f} (files, "
          f"then rounds, resampled); {sum(r > args.goal for r in every)} rounds above "
          f"{args.goal:g}; the files' medians {statistics.median(med):.3f} "
          f"[{min(med):.3f}–{max(med):.3f}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
