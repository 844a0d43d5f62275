#!/usr/bin/env python3
"""Run every paper preset and draw every figure of the seed (Barron et al. 2026).

    python tools/reproduce_paper.py [--photons N] [--out docs/figures] [--only NAME ...]

Writes ``NAME.nc`` (in --data, default a temporary folder) and ``NAME.png`` for each preset of
``presets/paper/`` (plus ``fov_numerical_angular.png``, the FOV figure), and prints the time
each took. ``--photons`` overrides every preset's ray count per scenario (the presets' own
counts are used otherwise).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

import warpe_cl
from warpe_cl import io
from warpe_cl.catalog import presets_dir
from warpe_cl.plot import plot_angular, plot_waveform


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--photons", type=float, default=None, help="rays per scenario")
    p.add_argument("--out", default="docs/figures", help="folder for the PNG figures")
    p.add_argument("--data", default=None, help="folder for the NetCDF results")
    p.add_argument("--only", nargs="*", default=None, help="preset names to run")
    p.add_argument("--device", default=None)
    args = p.parse_args(argv)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data = Path(args.data or tempfile.mkdtemp(prefix="warpe-paper-"))
    data.mkdir(parents=True, exist_ok=True)
    overrides = {"simulation.photons": args.photons} if args.photons else None
    total = time.perf_counter()
    for preset in sorted((presets_dir() / "paper").glob("*.yaml")):
        if args.only and preset.stem not in args.only:
            continue
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ds = warpe_cl.simulate(warpe_cl.load_preset(preset, overrides=overrides),
                                   device=args.device, progress=False)
        io.write_netcdf(ds, data / f"{preset.stem}.nc")
        plot_waveform(ds, out / f"{preset.stem}.png")
        if preset.stem == "fov_numerical":
            plot_angular(ds, out / "fov_numerical_angular.png")
        photons = int(ds["photons"].sum()) if "scenario" in ds.dims else int(ds["photons"])
        print(f"{preset.stem:26s} {photons:>11,d} rays  {time.perf_counter() - t0:7.1f} s"
              + "".join(f"\n    warning: {w.message}" for w in caught), flush=True)
    print(f"all presets: {time.perf_counter() - total:.1f} s; results in {data}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
