"""Compare the OpenCL drivers of this machine side by side, in one run (docs/performance.md).

    python tools/bench/bench_drivers.py [--devices all|SPEC,SPEC,...] [--scenes B1,B3]
                                        [--photons 1e6] [--rounds 5] [--json FILE]

For every device (default: all that qualify), first the qualification from an empty cache
(wall time of the child process: builds, known-answer walk, speed probe), then ``--rounds``
rounds in which each device walks each scene once in turn (interleaved, so that the load of a
shared machine falls on all of them alike). Prints the median and the range of scattering
events/s and photons/s per device and scene, and each device's ratio to the first one.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import loadavg  # noqa: E402
from bench import SCENES  # noqa: E402
from warpe_cl.config import load_preset  # noqa: E402
from warpe_cl.api import walk_params  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--devices", default="all")
    p.add_argument("--scenes", default="B1,B3")
    p.add_argument("--photons", type=float, default=1e6)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--precision", default="single", choices=("single", "double"))
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)

    from warpe_cl import device as devmod, qualify
    from warpe_cl.api import get_engine

    # qualification from an empty cache, timed
    os.environ["WARPE_CL_CACHE_DIR"] = tempfile.mkdtemp(prefix="warpe-bench-cache-")
    listed = devmod.list_devices()
    if args.devices == "all":
        chosen = [info for info, dev in listed if devmod.probe(dev) is None]
    else:
        chosen = []
        for spec in args.devices.split(","):
            chosen += [m[0] for m in devmod.candidates(spec, listed)[:1]]
    rows = {}
    for info in chosen:
        t0 = time.perf_counter()
        status = qualify.qualification(info, say=lambda m: None)
        wall = time.perf_counter() - t0
        label = f"{info.spec} {info.device} ({info.platform_version.split(',')[0].strip()})"
        print(f"# {label}: qualification from an empty cache {wall:.1f} s: "
              + (f"{status.lanes} lanes" if status.usable else f"NOT usable: {status.reason}"),
              flush=True)
        if status.usable:
            rows[label] = {"spec": info.spec, "lanes": status.lanes,
                           "qualification_s": round(wall, 2), "scenes": {}}

    engines = {label: get_engine(row["spec"]) for label, row in rows.items()}
    scenes = {s: walk_params(load_preset(SCENES[s]))[0] for s in args.scenes.split(",")}
    n = int(args.photons)
    for engine in engines.values():                    # builds, outside the timing
        for params in scenes.values():
            engine.run(params, 10_000, precision=args.precision)
    start = loadavg()
    for r in range(args.rounds):
        for label, engine in engines.items():
            for s, params in scenes.items():
                t0 = time.perf_counter()
                counts = engine.run(params, n, precision=args.precision)
                dt = time.perf_counter() - t0
                row = rows[label]["scenes"].setdefault(s, {"events_per_s": [], "photons_per_s": []})
                row["events_per_s"].append(counts.scattering_events / dt)
                row["photons_per_s"].append(n / dt)
        print(f"# round {r + 1}/{args.rounds} done, load average {loadavg()}", flush=True)

    first = next(iter(rows), None)
    for label, row in rows.items():
        for s, v in row["scenes"].items():
            med = statistics.median(v["events_per_s"])
            v["median_events_per_s"] = med
            v["median_photons_per_s"] = statistics.median(v["photons_per_s"])
            ratio = med / statistics.median(rows[first]["scenes"][s]["events_per_s"])
            v["ratio_to_first"] = ratio
            print(f"{s} {label}, {row['lanes']} lanes: {med:.3g} scattering events/s "
                  f"(range {min(v['events_per_s']):.3g}-{max(v['events_per_s']):.3g}), "
                  f"{v['median_photons_per_s']:.3g} photons/s; {ratio:.2f}x the first")
    result = {"date": time.strftime("%Y-%m-%dT%H:%M:%S"), "cores": os.cpu_count(),
              "photons": n, "rounds": args.rounds, "precision": args.precision,
              "loadavg_start": start, "loadavg_end": loadavg(), "devices": rows}
    print(f"# load average {start} -> {result['loadavg_end']}")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
