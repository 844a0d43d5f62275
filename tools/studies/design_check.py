#!/usr/bin/env python3
"""Do the design study's expected widths hold against full noisy injections? (docs/design.md §3)

    python tools/studies/design_check.py --database DB [--instrument bela|gala|FILE.yaml]
        [--set KEY=VALUE ...] [--nodes 4 | --node I ...] [--seeds 2] [--seed 1] [--out rows.csv]

For ``--nodes`` nodes of the database (drawn at random, interior ones first) or the nodes
``--node I`` (indices in the database's grid order, the last axis fastest), the tool records
``--seeds`` noise realisations of the node's own surface with the instrument
(:func:`warpe_cl.instrument.apply_instrument`, the full chain), inverts each against the
database (:func:`warpe_cl.invert`, nuisances free, the database's error integrated) and
compares the recovered width ratio (posterior 95 % width over the prior's, in the prior's
coordinate) of every swept key and derived quantity with the expected one of
:func:`warpe_cl.design.expected.expected`.

A row **disagrees** when the expected width ratio lies outside the range of the recovered ones
widened by 0.15 (the recovered width of one realisation scatters by about that much on grids
of a few nodes per axis). Both are capped at 1; a grid posterior's width is bounded by the
prior, a Fisher width is not (it is capped), so where the Fisher width nears 1 the two differ
by construction. Exit codes: 0 done, 2 bad input.
"""
from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

#: The recovered width ratios of the seeds, widened by this, must hold the expected one.
TOLERANCE = 0.15


def pick_nodes(family, count: int, rng) -> list:
    """``count`` node indices (in ``family.nodes``), interior nodes (no axis at its edge)
    first, drawn at random."""
    shape = family.space.nodes.shape
    interior = [i for i, n in enumerate(family.nodes)
                if all(0 < k < s - 1 for k, s in zip(n.index, shape) if s > 2)]
    rest = [i for i in range(len(family.nodes)) if i not in interior]
    order = list(rng.permutation(interior)) + list(rng.permutation(rest))
    return [int(i) for i in order[:count]]


def run(args) -> list:
    """Every row: one per node, seed and parameter."""
    from warpe_cl import invert
    from warpe_cl.config.keys import parse_overrides
    from warpe_cl.database import load_result
    from warpe_cl.design.expected import expected
    from warpe_cl.design.family import Family
    from warpe_cl.instrument import apply_instrument, load_instrument
    from warpe_cl.inversion.observed import Observed

    db = load_result(Path(args.database))
    family = Family("check", db, source=args.database)
    params = load_instrument(args.instrument, parse_overrides(args.set or []))
    exp = expected(family, params)
    names = family.parameters
    rng = np.random.default_rng(args.seed)
    rows = []
    for i in args.node or pick_nodes(family, args.nodes, rng):
        node = family.nodes[i]
        scenario = _scenario_of(db, family, node)
        surface = db.isel(scenario=scenario)
        got = {n: [] for n in names}
        for s in range(args.seeds):
            rec = apply_instrument(surface, params, shots=int(params["shots"]),
                                   seed=100 * args.seed + s)
            counting = "signal_counts" in rec
            obs = Observed("counts" if counting else "mv", rec["sample_time"].values,
                           rec["signal_counts" if counting else "signal_mv"].values,
                           f"node {i} seed {s}", params["name"])
            fit = invert(obs, db, params, database_source=args.database)
            keys = list(fit["parameter"].values)
            for n in names:
                if n in keys:
                    got[n].append(float(fit["width_ratio"].values[keys.index(n)]))
                elif "derived" in fit.coords and n in list(fit["derived"].values):
                    k = list(fit["derived"].values).index(n)
                    got[n].append(float(fit["derived_width_ratio"].values[k]))
        for j, n in enumerate(names):
            values = np.minimum(np.array(got[n], float), 1.0)
            want = float(exp.width_ratio[i, j])
            lo, hi = (float(values.min()), float(values.max())) if values.size else (np.nan,) * 2
            agree = lo - TOLERANCE <= want <= hi + TOLERANCE
            rows.append({"node": i, **{k: f"{v:.4g}" for k, v in node.point.items()},
                         "parameter": n, "expected": f"{want:.3f}",
                         "recovered": " ".join(f"{v:.3f}" for v in values),
                         "agree": "yes" if agree else "NO"})
            print(f"node {i} {n}: expected {want:.3f}, recovered "
                  f"{' '.join(f'{v:.3f}' for v in values)} -> "
                  f"{'agree' if agree else 'DISAGREE'}", flush=True)
    return rows


def _scenario_of(db, family, node) -> int:
    """The scenario index of a node of the family in the database."""
    match = np.ones(db.sizes["scenario"], bool)
    for axis in family.axes:
        match &= np.isclose(np.asarray(db[axis.key].values, float), node.point[axis.key],
                            rtol=1e-9, atol=0.0)
    return int(np.flatnonzero(match)[0])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--database", required=True, help="a sweep folder or sweep file")
    ap.add_argument("--instrument", default="bela", help="bela, gala or an instrument file")
    ap.add_argument("--set", action="append", metavar="KEY=VALUE",
                    help='an instrument key, e.g. --set shots=1000 (repeatable)')
    ap.add_argument("--nodes", type=int, default=4)
    ap.add_argument("--node", type=int, action="append",
                    help="a node's index (repeatable; instead of --nodes)")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", help="CSV of every row")
    args = ap.parse_args(argv)
    from warpe_cl.errors import ConfigError
    try:
        rows = run(args)
    except ConfigError as err:
        print(f"design_check: error: {err}", file=sys.stderr)
        return 2
    bad = [r for r in rows if r["agree"] == "NO"]
    print(f"{len(rows) - len(bad)} of {len(rows)} rows agree (expected within the recovered "
          f"range +- {TOLERANCE:g})")
    if args.out:
        with open(args.out, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
