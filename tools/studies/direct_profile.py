#!/usr/bin/env python3
"""Is the likelihood itself unbiased at an injection? log L along one key from direct
simulations, no database, for the injection's own shots and for fresh noise realisations of
them (docs/inversion.md §7.7).

    python tools/studies/direct_profile.py FAMILY --work DIR --injection N --instrument LABEL
        --key KEY [--values V1,V2,...] [--points 13] [--profile-points 9] [--photons 3e6]
        [--realisations 30] [--seed 90000] [--out rows.json]

It reads the injection ``DIR/FAMILY/inj/iNNN`` of ``tools/studies/inversion_study.py`` (its
``preset.yaml``, ``surface.nc`` and ``LABEL.nc``; the instrument from ``DIR/FAMILY/instruments``
or the study's or bundled ones, as ``inversion_recovery.py`` finds it) and the family's
database, for its keys' ranges and interpolation coordinates only. It simulates a grid of
surfaces directly, each with ``--photons`` rays and its own seed: ``--key`` at ``--points``
values evenly spaced in its coordinate over the database's range (or at ``--values``, in the
database's unit: m, ns, deg or 1) and at the truth's value, every other free key at
``--profile-points`` values over its range. For the injection's shots (row 0) and
``--realisations`` fresh ones (the instrument on the truth's surface with seeds SEED + 1,
SEED + 2, ...) it computes log L at every grid point (the nuisances fitted, each surface's own
Monte Carlo error integrated out, docs/inversion.md §4.3), profiles it along ``--key`` (the
maximum over the other keys) and prints where the profile peaks and Δ = its maximum − its value
at the truth.

Where the likelihood is right, the fresh realisations' best values scatter around the truth
and 2Δ is of order one (at most a χ² on the free keys' count of degrees of freedom; less on a
grid); the injection's own shots are one more draw from that spread. Exit codes: 0 done, 2 bad
input.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from emulator_check import point_overrides  # noqa: E402
from inversion_recovery import StudyError, instrument_source, read_injections  # noqa: E402


def key_grid(axis, points: int, values: str | None, truth: float) -> np.ndarray:
    """The values (axis units) of ``axis`` to simulate: ``values`` (comma-separated numbers)
    or ``points`` values evenly spaced in its coordinate over its nodes' range; with
    ``truth`` added; sorted, each once."""
    if values:
        grid = np.array([float(v) for v in values.split(",")], float)
    else:
        nodes = axis.nodes
        grid = np.asarray(axis.value(np.linspace(nodes[0], nodes[-1], points)), float)
    return np.unique(np.append(grid, truth))


def profile(loglike: np.ndarray) -> np.ndarray:
    """The profile along the first axis: the maximum over every other one."""
    flat = loglike.reshape(loglike.shape[0], -1)
    return flat.max(axis=1)


def summary(grid: np.ndarray, truth: float, profiles: list) -> dict:
    """Where each profile (rows over ``grid``) peaks and Δ = its maximum − its value at
    ``truth``; row 0 is the injection's own shots, the others the fresh realisations."""
    at = int(np.flatnonzero(grid == truth)[0])
    best = [float(grid[int(np.argmax(p))]) for p in profiles]
    delta = [float(np.max(p) - p[at]) for p in profiles]
    fresh_best, fresh_delta = np.array(best[1:]), np.array(delta[1:])
    out = {"truth": truth, "own_best": best[0], "own_delta": delta[0],
           "best": best, "delta": delta}
    if fresh_best.size:
        out.update(fresh_median_best=float(np.median(fresh_best)),
                   fresh_above=float(np.mean(fresh_best > truth)),
                   fresh_mean_2delta=float(2.0 * fresh_delta.mean()),
                   fresh_max_delta=float(fresh_delta.max()),
                   own_rank=float(np.mean(fresh_delta < delta[0])))
    return out


def run(args) -> dict:
    """Simulate the grid, compute the profiles, return :func:`summary` with the grid."""
    import xarray as xr

    from warpe_cl import load_preset, simulate
    from warpe_cl.database import load_result
    from warpe_cl.instrument import apply_instrument, load_instrument
    from warpe_cl.inversion.emulator import DirectSurface
    from warpe_cl.inversion.forward import Forward
    from warpe_cl.inversion.likelihood import Shots
    from warpe_cl.inversion.counting import CountShots
    from warpe_cl.inversion.posterior import Problem
    from warpe_cl.inversion.space import Space
    from warpe_cl.surface import response

    family = Path(args.work) / args.family
    folder = family / "inj" / f"i{args.injection:03d}"
    rows, keys, _ = read_injections(family)
    row = next((r for r in rows if int(r["index"]) == args.injection), None)
    if row is None:
        raise StudyError(f"--injection {args.injection}: not a row of {family / 'injections.csv'}")
    space = Space(load_result(family / "db"), source=str(family / "db"))
    if args.key not in [a.key for a in space.free_axes]:
        raise StudyError(f"--key {args.key}: not a swept key of the database "
                         f"({', '.join(a.key for a in space.free_axes)})")
    lacking = [a.key for a in space.free_axes if a.key not in keys]
    if lacking:
        raise StudyError(f"{family / 'injections.csv'}: no column {lacking[0]}, a swept key of "
                         "the database: the injections are of another family")
    truth = {a.key: float(row[a.key]) for a in space.free_axes}
    axes = [next(a for a in space.free_axes if a.key == args.key)] + \
        [a for a in space.free_axes if a.key != args.key]
    grids = [key_grid(axes[0], args.points, args.values, truth[args.key])] + \
        [key_grid(a, args.profile_points, None, truth[a.key]) for a in axes[1:]]
    params = load_instrument(instrument_source(args.instrument, family))
    forward = Forward(params)
    signal = "signal_counts" if forward.counting else "signal_mv"
    base = yaml.safe_load((folder / "preset.yaml").read_text())
    base.pop("sweep", None)
    u = np.array([a.nodes[0] for a in space.free_axes])     # not read by a direct surface
    shape = tuple(g.size for g in grids)
    surfaces = {}
    for n, index in enumerate(np.ndindex(*shape)):
        point = {a.key: float(g[i]) for a, g, i in zip(axes, grids, index)}
        overrides = {**point_overrides(space, point), "simulation.photons": args.photons,
                     "simulation.seed": args.seed + 100000 + n}
        ds = simulate(load_preset(dict(base), overrides=overrides), progress=False)
        surfaces[index] = DirectSurface(response(ds), forward, space.free_axes)
        print(f"surface {n + 1}/{int(np.prod(shape))}", file=sys.stderr, flush=True)
    truth_ds = xr.open_dataset(folder / "surface.nc")
    at = int(np.flatnonzero(grids[0] == truth[args.key])[0])
    profiles = []
    for r in range(args.realisations + 1):
        rec = (xr.open_dataset(folder / f"{args.instrument}.nc") if r == 0 else
               apply_instrument(truth_ds, params, shots=int(params["shots"]), seed=args.seed + r))
        # one set of shots for every surface, as invert reads them: each point starts afresh
        shots = (CountShots if forward.counting else Shots)(
            rec["sample_time"].values, rec[signal].values, forward)
        loglike = np.full(shape, -np.inf)
        for index, surface in surfaces.items():
            loglike[index] = Problem(surface, forward, shots, emulator=surface).evaluate(u).loglike
        profiles.append(profile(loglike))
        print(f"{'own shots' if r == 0 else f'realisation {r}'}: best "
              f"{grids[0][int(np.argmax(profiles[-1]))]:.6g} {axes[0].units}, delta at the truth "
              f"{np.max(profiles[-1]) - profiles[-1][at]:.2f}", flush=True)
    return {"key": args.key, "units": axes[0].units, "grid": grids[0].tolist(),
            "profiles": [p.tolist() for p in profiles],
            **summary(grids[0], truth[args.key], profiles)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("family")
    ap.add_argument("--work", required=True)
    ap.add_argument("--injection", type=int, required=True)
    ap.add_argument("--instrument", required=True, help="an instrument label of the injections")
    ap.add_argument("--key", required=True)
    ap.add_argument("--values", help="comma-separated values of --key, the database's unit")
    ap.add_argument("--points", type=int, default=13)
    ap.add_argument("--profile-points", type=int, default=9)
    ap.add_argument("--photons", type=float, default=3e6)
    ap.add_argument("--realisations", type=int, default=30)
    ap.add_argument("--seed", type=int, default=90000)
    ap.add_argument("--out", help="JSON of the grid, the profiles and the summary")
    args = ap.parse_args(argv)
    folder = Path(args.work) / args.family / "inj" / f"i{args.injection:03d}"
    bad = ("--points must be 2 or more" if args.points < 2 and not args.values else
           "--profile-points must be 2 or more" if args.profile_points < 2 else
           "--realisations must be 0 or more" if args.realisations < 0 else
           f"--injection {args.injection}: no folder {folder}" if not folder.is_dir() else
           f"--instrument {args.instrument}: no shots {folder / (args.instrument + '.nc')}"
           if not (folder / f"{args.instrument}.nc").is_file() else
           f"--injection {args.injection}: no surface.nc or preset.yaml in {folder}"
           if not all((folder / n).is_file() for n in ("surface.nc", "preset.yaml")) else
           f"--photons {args.photons:g}: give a count of rays of 1 or more"
           if not args.photons >= 1 else
           f"--out {args.out}: no folder {Path(args.out).parent}"
           if args.out and not Path(args.out).resolve().parent.is_dir() else None)
    if args.values and not bad:
        try:
            [float(v) for v in args.values.split(",")]
        except ValueError:
            bad = f"--values {args.values!r}: give numbers in the database's unit, e.g. 0.1,0.2"
    if bad:
        print(f"direct_profile: {bad}", file=sys.stderr)
        return 2
    from warpe_cl.errors import ConfigError
    try:
        out = run(args)
    except (ConfigError, StudyError) as exc:
        print(f"direct_profile: {exc}", file=sys.stderr)
        return 2
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1))
    print(f"truth {out['truth']:.6g} {out['units']}; own shots: best {out['own_best']:.6g}, "
          f"delta {out['own_delta']:.2f}")
    if "fresh_median_best" in out:
        print(f"{args.realisations} fresh realisations: median best "
              f"{out['fresh_median_best']:.6g}, share above the truth {out['fresh_above']:.2f}, "
              f"mean 2 delta {out['fresh_mean_2delta']:.2f}, largest delta "
              f"{out['fresh_max_delta']:.2f}; "
              f"the own shots' delta exceeds {out['own_rank']:.0%} of theirs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
