"""Fingerprint every bundled paper and radiative preset, bit for bit, to show that a change of
structure changed no result.

Each preset runs at a small photon count with a fixed seed (default 1e5 rays, seed 1, on the
device ``auto`` picks); every numeric output variable (``ray_count`` first among them) is hashed
with SHA-256. ``--write`` saves the fingerprints as JSON; ``--compare`` runs again and lists every
preset and variable whose bits differ (exit 1), or prints ``identical`` (exit 0).

    python tools/preset_bits.py --write before.json          # on the old tree
    python tools/preset_bits.py --compare before.json        # on the new one

The counter-based streams make the bits independent of the device, lane width and batch size
(docs/walk.md §2), so the two runs may use different devices. ``wall_time`` is left out.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import warnings

import numpy as np

import warpe_cl
from warpe_cl.catalog import presets_dir
from warpe_cl.errors import WarpeWarning

FOLDERS = ("paper", "radiative")
SKIP = ("wall_time",)


def fingerprints(photons: float, seed: int, device: str | None, folders=FOLDERS,
                 names=None, quiet: bool = False) -> dict:
    """``{preset: {variable: sha256 hex}}`` for every preset of ``folders``.

    Parameters
    ----------
    photons : float
        Rays per scenario.
    seed : int
        ``simulation.seed`` of every preset.
    device : str or None
        Device spec (None: auto).
    folders : tuple of str
        Folders of ``presets/`` (default: paper and radiative).
    names : collection of str, optional
        Only these presets (``folder/name``).
    quiet : bool
        No line per preset on stderr.
    """
    out = {}
    root = presets_dir()
    for folder in folders:
        for path in sorted((root / folder).glob("*.yaml")):
            name = f"{folder}/{path.stem}"
            if names is not None and name not in names:
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", WarpeWarning)
                cfg = warpe_cl.load_preset(path, overrides={"simulation.photons": photons,
                                                            "simulation.seed": seed})
                ds = warpe_cl.simulate(cfg, device=device, progress=False)
            out[name] = {}
            for var in sorted(ds.data_vars):
                values = np.ascontiguousarray(ds[var].values)
                if var in SKIP or values.dtype.kind not in "fiub":
                    continue
                out[name][var] = hashlib.sha256(values.tobytes()).hexdigest()
            if not quiet:
                print(f"{name}: {len(out[name])} variables, ray_count sum "
                      f"{int(ds['ray_count'].values.sum())}", file=sys.stderr)
    return out


def combined(variables: dict) -> str:
    """One SHA-256 (hex) of a preset's ``{variable: digest}``."""
    text = json.dumps(variables, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def differences(before: dict, after: dict) -> list:
    """Lines naming each preset or variable of ``before`` whose bits ``after`` does not have."""
    lines = []
    for name, variables in before.items():
        if name not in after:
            lines.append(f"{name}: missing")
            continue
        for var, digest in variables.items():
            if after[name].get(var) != digest:
                lines.append(f"{name}: {var} differs")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    action = parser.add_mutually_exclusive_group(required=True)
    action.add_argument("--write", metavar="JSON", help="save the fingerprints")
    action.add_argument("--compare", metavar="JSON", help="compare with saved fingerprints")
    parser.add_argument("--photons", type=float, default=1e5)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--device", default=None, help="device spec (default: auto)")
    args = parser.parse_args(argv)
    now = fingerprints(args.photons, args.seed, args.device)
    if args.write:
        with open(args.write, "w") as f:
            json.dump({"photons": args.photons, "seed": args.seed, "presets": now}, f, indent=1)
        print(f"wrote {args.write}: {len(now)} presets")
        return 0
    with open(args.compare) as f:
        saved = json.load(f)
    if (saved["photons"], saved["seed"]) != (args.photons, args.seed):
        print(f"{args.compare} was made with --photons {saved['photons']:g} --seed "
              f"{saved['seed']}; give the same", file=sys.stderr)
        return 2
    lines = differences(saved["presets"], now)
    print("\n".join(lines) if lines else f"identical ({len(now)} presets)")
    return 1 if lines else 0


if __name__ == "__main__":
    sys.exit(main())
