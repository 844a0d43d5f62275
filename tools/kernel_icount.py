#!/usr/bin/env python3
"""Instructions per scattering event of the walk kernel, counted by valgrind on pip's PoCL.

    python tools/kernel_icount.py [--trees <checkout>,<checkout>] [--scenes B1]
                                  [--nadir off,on] [--photons 2e4] [--out FILE] [--json FILE]

This machine's speed drifts by 20-40 % within minutes (docs/performance.md), so a change of a
few per cent to the walk kernel cannot be timed in one run. The count of instructions it
executes does not drift: for each checkout (default: this one), scene of tools/bench.py and
nadir setting, a child process walks the scene once on pip's PoCL (``pthread``: the kernel
runs in the process, as machine code that PoCL compiled and cached on disk) under valgrind's
cachegrind, and this prints the instructions of the walk kernel's function
(``_pocl_kernel_walk_*``), per scattering event and per photon. A first child without
valgrind builds and caches the kernel, so the count is the walk's alone. The ratios printed:
each tree's nadir on over off (what the estimate costs in instructions), and each tree over
the first (a change's saving). Instructions are not time: a loop's branches, a store that a
load waits for and a slow instruction (a division) weigh more; tools/bench_ab.py times a
change, this tells what it did to the code. Needs valgrind (``apt install valgrind``).
"""
from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import tempfile
from pathlib import Path

from _common import print_report, run_in_tree  # tools/ is first on sys.path when run as a script

HERE = Path(__file__).resolve()
#: The walk kernel's functions in PoCL's machine code (the work-group loop and its variants).
KERNEL_FN = re.compile(r"_pocl_kernel_walk(_workgroup(_fast)?)?$")
DEVICE = "pthread"


def kernel_instructions(cachegrind_out: str) -> int:
    """The instructions (``Ir``) that a cachegrind output file counts in the walk kernel's
    functions (``KERNEL_FN``), summed over their lines. The file's format: ``fn=<name>`` opens
    a function, and each line after it until the next ``fl=`` / ``fn=`` is ``<line> <Ir>``."""
    total, inside = 0, False
    for line in cachegrind_out.splitlines():
        if line.startswith("fn="):
            inside = bool(KERNEL_FN.match(line[3:].strip()))
        elif line.startswith("fl="):
            inside = False
        elif inside and line[:1].isdigit():
            parts = line.split()
            if len(parts) >= 2:
                total += int(parts[1])
    return total


def child(scene: str, nadir: bool, photons: int) -> dict:
    """Walk ``scene`` once on PoCL in this process's warpe_cl; its events."""
    import copy
    import warnings

    import warpe_cl
    from bench import SCENES                              # tools/ is on sys.path
    from warpe_cl.api import get_engine, walk_params
    from warpe_cl.config import load_preset
    cfg = load_preset(copy.deepcopy(SCENES[scene]), overrides={"simulation.nadir": nadir})
    params, _ = walk_params(cfg)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        engine = get_engine(DEVICE)
        counts = engine.run(params, photons)
    return {"package": warpe_cl.__file__, "device": engine.provenance["opencl_device"],
            "lanes": engine.lanes_for(params.texture, "single", False),
            "photons": photons, "scattering_events": int(counts.scattering_events)}


def count(tree: Path, scene: str, nadir: bool, photons: int) -> dict:
    """The kernel's instructions for one walk of ``scene`` in ``tree``'s warpe_cl."""
    args = ["--child", scene, "--photons", photons, "--nadir", "on" if nadir else "off"]
    run_in_tree(HERE, tree, args)                 # builds and caches the kernel
    with tempfile.TemporaryDirectory() as tmp:
        out_file = Path(tmp) / "cachegrind.out"
        prefix = ["valgrind", "--tool=cachegrind", "--cache-sim=no",
                  f"--cachegrind-out-file={out_file}"]
        result = run_in_tree(HERE, tree, args, prefix=prefix)
        result["kernel_instructions"] = kernel_instructions(out_file.read_text())
    if result["kernel_instructions"] == 0:
        raise SystemExit(f"{tree}: no instructions counted in the walk kernel "
                         f"({KERNEL_FN.pattern}): is {DEVICE} pip's PoCL?")
    result["per_event"] = result["kernel_instructions"] / result["scattering_events"]
    result["per_photon"] = result["kernel_instructions"] / result["photons"]
    return result


def report(results: dict, trees: list, scenes: list, nadirs: list) -> list:
    """The lines printed: one per walk, then the ratios of instructions per event."""
    lines = []
    for tree in trees:
        for scene in scenes:
            for nadir in nadirs:
                r = results[(tree, scene, nadir)]
                lines.append(f"{tree} {scene} nadir {'on' if nadir else 'off'}: "
                             f"{r['per_event']:.2f} instructions per scattering event, "
                             f"{r['per_photon']:.0f} per photon ({r['kernel_instructions']:,} "
                             f"for {r['scattering_events']:,} events, {r['lanes']} lanes)")
    for tree in trees:
        for scene in scenes:
            if len(nadirs) == 2:
                on, off = results[(tree, scene, True)], results[(tree, scene, False)]
                lines.append(f"{tree} {scene} nadir on / off: "
                             f"{on['per_event'] / off['per_event']:.4f}")
    for tree in trees[1:]:
        for scene in scenes:
            for nadir in nadirs:
                a, b = results[(trees[0], scene, nadir)], results[(tree, scene, nadir)]
                lines.append(f"{scene} nadir {'on' if nadir else 'off'}: {tree} / {trees[0]}: "
                             f"{b['per_event'] / a['per_event']:.4f}")
    return lines


def parse_args(argv):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--trees", default=str(HERE.parent.parent),
                   help="checkouts, comma-separated (default: this one)")
    p.add_argument("--scenes", default="B1", help="scenes of tools/bench.py (default B1)")
    p.add_argument("--nadir", default="off,on", help="off, on or both (default off,on)")
    p.add_argument("--photons", type=float, default=2e4, help="photons per walk (default 2e4)")
    p.add_argument("--out", help="also write the report here")
    p.add_argument("--json", help="write every count here")
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    args.photons = int(args.photons)
    if args.photons < 1:
        p.error(f"--photons {args.photons}: at least 1 photon")
    from bench import scene_list                          # tools/ is on sys.path
    try:
        args.scene_list = scene_list(args.scenes)
    except ValueError as err:
        p.error(str(err))
    choices = {"off": False, "on": True}
    try:
        args.nadir_list = [choices[v] for v in args.nadir.split(",")]
    except KeyError:
        p.error(f"--nadir {args.nadir}: off, on or off,on")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child, args.nadir_list[0], args.photons)))
        return 0
    if shutil.which("valgrind") is None:
        raise SystemExit("kernel_icount: valgrind is not installed (apt install valgrind)")
    trees = [str(Path(t).resolve()) for t in args.trees.split(",")]
    scenes = args.scene_list
    results = {}
    for tree in trees:
        for scene in scenes:
            for nadir in args.nadir_list:
                results[(tree, scene, nadir)] = count(Path(tree), scene, nadir, args.photons)
    lines = report(results, trees, scenes, args.nadir_list)
    print_report(lines, args.out)
    if args.json:
        Path(args.json).write_text(json.dumps(
            [{"tree": t, "scene": s, "nadir": n, **r} for (t, s, n), r in results.items()],
            indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
