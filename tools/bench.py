#!/usr/bin/env python3
"""Benchmark the walk kernels on the scenes of the speed issue, and the NumPy reference beside them.

    python tools/bench.py [--photons N] [--device SPEC] [--precision single|double]
                          [--compare numpy] [--json FILE]

Scenes (time cap 5 ns, Lambertian floor A = 0.15, HG g = 0.8):
  B1  slab 60 mm, tau0 = 60.3, omega = 0.99502, n = 1.3 (about 212 scatterings per photon)
  B2  the same medium, granular (no interfaces)
  B3  granular CO2 ice, d = 200 um, compacity 0.9, h = 100 mm (physical form)

Prints and writes (JSON) photons/s and scattering events/s per scene, with the device, driver,
cores, precision and date. ``--compare numpy`` runs the reference walk on the same scenes in the
same run (fewer photons: it is ~100x slower) and prints the ratio.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import sys
import time

from warpe_cl.api import get_engine, walk_params
from warpe_cl.config import load_preset

COMMON_SIM = {"time_bins": {"start": "1e-6 ns", "stop": "5 ns", "per_decade": 20},
              "max_time": "5 ns", "seed": 1}
SCENES = {
    "B1": {"medium": {"texture": "slab", "thickness": "60 mm", "bottom_albedo": 0.15,
                      "phase_g": 0.8, "radiative": {"tau0": 60.3, "omega": 0.99502, "n": 1.3}},
           "simulation": COMMON_SIM},
    "B2": {"medium": {"texture": "granular", "thickness": "60 mm", "bottom_albedo": 0.15,
                      "phase_g": 0.8, "radiative": {"tau0": 60.3, "omega": 0.99502, "n": 1.3}},
           "simulation": COMMON_SIM},
    "B3": {"medium": {"texture": "granular", "thickness": "100 mm", "compacity": 0.9,
                      "bottom_albedo": 0.15, "phase_g": 0.8,
                      "inclusions": [{"material": "CO2", "proportion": 1.0,
                                      "grain_size": "200 um"}]},
           "simulation": COMMON_SIM},
}


def measure(engine, params, photons, precision, repeats=3):
    """Best of ``repeats`` timed runs (after one warm-up that builds the kernel)."""
    engine.run(params, min(photons, 10_000), precision=precision)
    best = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        counts = engine.run(params, photons, precision=precision)
        elapsed = time.perf_counter() - t0
        if best is None or elapsed < best[0]:
            best = (elapsed, counts)
    elapsed, counts = best
    return {"photons": photons, "seconds": elapsed, "photons_per_s": photons / elapsed,
            "scattering_events_per_s": counts.scattering_events / elapsed,
            "scatterings_per_photon": counts.scattering_events / photons}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--photons", type=float, default=1e6)
    p.add_argument("--device", default=None)
    p.add_argument("--precision", choices=("single", "double"), default="single")
    p.add_argument("--compare", choices=("numpy",), action="append", default=[])
    p.add_argument("--numpy-photons", type=float, default=2e3)
    p.add_argument("--json", default=None, help="write the results here")
    args = p.parse_args(argv)

    engine = get_engine(args.device)
    result = {"date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
              "host": platform.node(), "cores": os.cpu_count(),
              "cpu": platform.processor() or platform.machine(),
              "device": engine.provenance, "precision": args.precision, "scenes": {}}
    print(f"# {engine.provenance['opencl_device']} | {engine.provenance['opencl_platform']} | "
          f"{os.cpu_count()} cores | {args.precision} precision")
    for name, scene in SCENES.items():
        params, _ = walk_params(load_preset(scene))
        row = {"opencl": measure(engine, params, int(args.photons), args.precision)}
        line = (f"{name}: {row['opencl']['photons_per_s']:.3g} photons/s, "
                f"{row['opencl']['scattering_events_per_s']:.3g} scattering events/s "
                f"({row['opencl']['scatterings_per_photon']:.0f} per photon)")
        if "numpy" in args.compare:
            row["numpy"] = measure(get_engine("numpy"), params, int(args.numpy_photons),
                                   "double", repeats=1)
            ratio = row["opencl"]["scattering_events_per_s"] / row["numpy"]["scattering_events_per_s"]
            row["ratio_to_numpy"] = ratio
            line += f"; numpy {row['numpy']['scattering_events_per_s']:.3g} events/s, ratio {ratio:.0f}x"
        print(line, flush=True)
        result["scenes"][name] = row
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
