#!/usr/bin/env python3
"""Run the layered presets and draw their figures (docs/physics.md §11, docs/figures).

    python tools/layer_figures.py [--photons N] [--out docs/figures] [--only NAME ...]

For each preset of ``presets/layers/``: the waveform figure ``NAME.png`` (the buried
interfaces' echoes marked), and, for a preset with an instrument block, what the instrument
records, ``NAME_instrument.png``. Prints, per scenario, the numbers docs/figures/README.md
quotes: the specular and BF-direct fractions, where the rays are absorbed (per layer and by
the floor) and the direct-echo delays, and the time each preset took; and records each
preset drawn in ``provenance.json`` (tools/figure_provenance.py).
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import warpe_cl
from warpe_cl.catalog import presets_dir
from warpe_cl.errors import WarpeWarning
from warpe_cl.plot import _scenarios, plot_waveform

from figure_provenance import write_provenance


def summary(ds) -> list:
    """One line per scenario: its label, the specular and BF-direct fractions, the fractions
    absorbed per layer and by the floor, and the echo delays (ns)."""
    lines = []
    for label, sc in _scenarios(ds):
        frac = sc["fraction"]
        layers = " ".join(f"{v:.3g}" for v in sc["layer_fate_fraction"].values)
        echoes = " ".join(f"{v:.4g}" for v in sc["echo_time"].values)
        lines.append(f"  {label or sc.attrs.get('name', '')}: specular "
                     f"{float(frac.sel(component='specular')):.4g}, bf_direct "
                     f"{float(frac.sel(component='bf_direct')):.3g}, scattering "
                     f"{float(frac.sel(component='scattering')):.3g}, bf_diffuse "
                     f"{float(frac.sel(component='bf_diffuse')):.3g}; absorbed per layer "
                     f"[{layers}], by the floor "
                     f"{float(sc['fate_fraction'].sel(fate='absorbed_floor')):.3g}; echoes "
                     f"[{echoes}] ns")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--photons", type=float, default=None,
                        help="rays per scenario (default: each preset's own)")
    parser.add_argument("--out", type=Path, default=Path("docs/figures"))
    parser.add_argument("--only", nargs="*", default=None, help="preset names")
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    drawn, devices = [], set()
    for path in sorted((presets_dir() / "layers").glob("*.yaml")):
        if args.only and path.stem not in args.only:
            continue
        overrides = {"simulation.photons": args.photons} if args.photons else {}
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", WarpeWarning)   # thin lags: said in the preset
            cfg = warpe_cl.load_preset(path, overrides=overrides)
            ds = warpe_cl.simulate(cfg, device=args.device, progress=False)
        plot_waveform(ds, args.out / f"{path.stem}.png")
        if "signal_mv" in ds:
            from warpe_cl.instrument.plot import plot_instrument
            plot_instrument(ds, args.out / f"{path.stem}_instrument.png")
        print(f"{path.stem}: {time.perf_counter() - t0:.1f} s")
        print("\n".join(summary(ds)))
        drawn.append(path.stem)
        devices.add(str(ds.attrs.get("opencl_device", "numpy reference")))
    if drawn:
        command = " ".join(["python tools/layer_figures.py"] + list(argv or sys.argv[1:]))
        print("provenance: " + str(write_provenance(
            args.out / "provenance.json", "layers", drawn, args.photons,
            ", ".join(sorted(devices)), command)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
