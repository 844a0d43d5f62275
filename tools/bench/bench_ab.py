#!/usr/bin/env python3
"""A/B speed of two checkouts of warpe-cl, interleaved in one run (docs/performance.md).

    python tools/bench/bench_ab.py --before /path/to/A --after /path/to/B [--rounds 5]
                                   [--scenes B1,B3] [--photons 1e6] [--device SPEC]
                                   [--precision single|double] [--modes analog] [--out FILE]

Each round runs tools/bench/bench.py (this folder's, so both trees are measured the same way) once
per tree, in a new process with ``PYTHONPATH`` set to that tree; the order alternates from
round to round (A B, B A, A B, ...) so that a drift of the machine's load falls on both alike.
bench.py times one run per scene after a warm-up. Prints every round and the load
average, then per scene the median and the range of scattering events/s and photons/s of each
tree, the ratio of the medians (B / A), and the median, quartiles and range of the rounds' own
ratios (a round's two runs are close in time, so on a machine whose speed drifts from second to
second these are the sharper measure: short runs, many rounds). ``--out`` also writes everything
printed to a file.

``--kernel-only`` compares the two trees' walk kernels (their ``cl/`` folders) in this one
process instead, with the host of the tree this script belongs to: both are built with its
build options, and each round walks every scene once with each kernel, alternating run by run
(about a second apart, so that a shared machine's changing load falls on both alike), and
checks that both give the same counts, bit for bit (``--different-bits``: a change of
arithmetic, which moves the last bits; the difference of their scattering events is printed);
it also reports scattering events per CPU second of the process (the driver's threads
included), less sensitive to other processes on a shared machine than the wall time. It needs
kernels with the same arguments (a file of the host's walk files that a tree lacks, a header
split out after it, is built as if empty, and said so). Each run installs its kernel in the
engine (``Engine.use_program``) and checks that the engine walked with it. ``--nadir`` walks the
scenes with the nadir estimate (``simulation.nadir: true``), which bench.py's scenes leave out;
``--modes analog,weighted`` walks each scene in each mode.

    python tools/bench/bench_ab.py --kernel-only [--nadir] [--different-bits] --before A --after B
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from _common import loadavg  # tools/bench/ is first on sys.path when run as a script

HERE = Path(__file__).resolve().parent
#: The checkout this script belongs to (tools/bench/ is two folders down).
REPO = HERE.parent.parent


def tree_env(tree: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tree)
    return env


def describe_tree(tree: Path) -> str:
    """Where the tree's package and kernels are read from, and its commit."""
    probe = ("import warpe_cl, warpe_cl.device as d; "
             "print(warpe_cl.__file__, d.kernel_dir())")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         env=tree_env(tree), cwd=tree)
    commit = subprocess.run(["git", "-C", str(tree), "log", "-1", "--format=%h %s"],
                            capture_output=True, text=True).stdout.strip()
    return f"{out.stdout.strip() or out.stderr.strip()[-300:]} | {commit[:90]}"


def run_bench(tree: Path, args) -> dict:
    """One tools/bench/bench.py process on ``tree``; its JSON result."""
    with tempfile.TemporaryDirectory(prefix="warpe-bench-ab-") as tmp:
        out = Path(tmp) / "bench.json"
        cmd = [sys.executable, str(HERE / "bench.py"), "--scenes", args.scenes,
               "--photons", str(args.photons), "--precision", args.precision,
               "--modes", args.modes, "--json", str(out)]
        if args.device:
            cmd += ["--device", args.device]
        proc = subprocess.run(cmd, capture_output=True, text=True, env=tree_env(tree), cwd=tree)
        if proc.returncode != 0:
            raise RuntimeError(f"bench.py failed on {tree}:\n{proc.stdout}\n{proc.stderr}")
        return json.loads(out.read_text())


def paired_ratios(a: list, b: list) -> dict:
    """B / A of each round (the two runs of a round are seconds apart, so a drift of a shared
    machine's speed cancels in their ratio, where it widens the two ranges): median, quartiles
    (the middle half of the rounds) and range."""
    r = sorted(y / x for x, y in zip(a, b))
    n = len(r)
    return {"median": statistics.median(r), "q1": r[n // 4], "q3": r[(3 * n) // 4],
            "min": r[0], "max": r[-1], "values": r}


def kernel_only(trees: dict, args, say) -> dict:
    """``--kernel-only``: both trees' kernels in this process; ``{label: {scene: samples}}``."""
    import time

    sys.path.insert(0, str(REPO))
    sys.path.insert(1, str(HERE))
    from bench import SCENES
    from warpe_cl import device as devmod
    from warpe_cl.api import walk_params
    from warpe_cl.config import load_preset
    from warpe_cl.api import get_engine
    from warpe_cl.engine import WALK_FILES, kernel_key

    engine = get_engine(args.device)
    say(f"# host {REPO}; device {engine.info.device} | {engine.info.platform} "
        f"{engine.info.platform_version}")
    for label, tree in trees.items():        # a header split out after the tree was written
        for missing in (f for f in devmod.every_program_file(WALK_FILES)
                        if not (tree / "cl" / f).exists()):
            say(f"# {label}: {tree / 'cl'} has no {missing}: built as if it were empty")

    def source(tree, options):
        """The walk's files of this build (devmod.program_files) that ``tree`` has."""
        return devmod.assemble_source([f for f in devmod.program_files(WALK_FILES, options)
                                       if (tree / "cl" / f).exists()], tree / "cl")
    samples = {label: {} for label in trees}
    n = int(args.photons)
    for scene, mode in ((s, m) for s in args.scenes.split(",") for m in args.modes.split(",")):
        name = scene if mode == "analog" else f"{scene} {mode}"
        cfg = load_preset(SCENES[scene], overrides={"simulation.nadir": bool(args.nadir),
                                                    "simulation.mode": mode})
        params, _ = walk_params(cfg)
        lanes = engine.lanes_for(params.texture, args.precision, params.weighted)
        structure = (params.texture, args.precision, False, lanes, params.weighted,
                     params.nadir)
        key = kernel_key(*structure)
        options = engine.program_options(key)
        programs = {label: devmod.build_source(engine.context, source(tree, options), options)
                    for label, tree in trees.items()}

        def walk(label):
            """One run of ``label``'s kernel; checks that the engine walked with it."""
            kern = engine.use_program(programs[label], key)
            t0, c0 = time.perf_counter(), time.process_time()
            c = engine.run(params, n, precision=args.precision, lanes=lanes)
            dt, cpu = time.perf_counter() - t0, time.process_time() - c0
            if engine.kernel(*structure) is not kern:
                raise RuntimeError(f"{name}: the engine did not walk with {label}'s kernel")
            return c, dt, cpu

        counts = {label: walk(label)[0] for label in trees}     # warm-up, and the same bits
        if counts["A"].same_as(counts["B"]):
            say(f"# {name}: {lanes} lanes, both kernels give the same counts ({n} photons)")
        elif args.different_bits:
            ea, eb = counts["A"].scattering_events, counts["B"].scattering_events
            say(f"# {name}: {lanes} lanes, the kernels' counts differ (--different-bits): "
                f"{ea} and {eb} scattering events ({eb / ea - 1:+.2e}), {n} photons")
        else:
            raise RuntimeError(f"{name}: the two kernels give different counts "
                               "(--different-bits for a change of arithmetic)")
        for r in range(args.rounds):
            order = list(trees) if r % 2 == 0 else list(trees)[::-1]
            cells = []
            for label in order:
                c, dt, cpu = walk(label)
                v = samples[label].setdefault(name, {"events_per_s": [], "photons_per_s": [],
                                                     "events_per_cpu_s": []})
                v["events_per_s"].append(c.scattering_events / dt)
                v["photons_per_s"].append(n / dt)
                v["events_per_cpu_s"].append(c.scattering_events / cpu)
                cells.append(f"{label} {c.scattering_events / dt:.4g} "
                             f"({c.scattering_events / cpu:.4g} per CPU s)")
            say(f"{name} round {r + 1}: " + ", ".join(cells) + f" events/s | load {loadavg()}")
        engine.forget(key)
    return samples


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", required=True, type=Path, help="tree A (a checkout)")
    p.add_argument("--after", required=True, type=Path, help="tree B (a checkout)")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--scenes", default="B1,B3")
    p.add_argument("--photons", type=float, default=1e6)
    p.add_argument("--device", default=None)
    p.add_argument("--precision", default="single", choices=("single", "double"))
    p.add_argument("--modes", default="analog")
    p.add_argument("--out", default=None, help="also write the report here")
    p.add_argument("--json", default=None, help="write every measurement here")
    p.add_argument("--kernel-only", action="store_true",
                   help="compare the two cl/ folders' kernels in this process (same host)")
    p.add_argument("--different-bits", action="store_true",
                   help="--kernel-only: the kernels may differ in their last bits (a change of "
                        "arithmetic); say by how much their scattering events differ instead "
                        "of stopping")
    p.add_argument("--nadir", action="store_true",
                   help="--kernel-only: walk the scenes with the nadir estimate "
                        "(simulation.nadir: true; bench.py's scenes walk without it)")
    args = p.parse_args(argv)
    if args.nadir and not args.kernel_only:
        p.error("--nadir goes with --kernel-only")
    trees = {"A": args.before.resolve(), "B": args.after.resolve()}
    lines = []

    def say(text: str) -> None:
        print(text, flush=True)
        lines.append(text)

    what = ("the two cl/ folders' walk kernels in one process" if args.kernel_only
            else "tools/bench/bench.py")
    say(f"# bench_ab: {args.rounds} interleaved rounds of {what}, --scenes {args.scenes} "
        f"--photons {args.photons:g} --precision {args.precision} --modes {args.modes}"
        + (f" --device {args.device}" if args.device else "")
        + (" --nadir" if args.nadir else ""))
    say(f"# {os.cpu_count()} cores, load average at the start {loadavg()}")
    for label, tree in trees.items():
        say(f"# {label} = {tree}: {describe_tree(tree)}")
    samples = {label: {} for label in trees}
    device = None
    if args.kernel_only:
        samples = kernel_only(trees, args, say)
    for r in range(0 if args.kernel_only else args.rounds):
        order = list(trees) if r % 2 == 0 else list(trees)[::-1]
        for label in order:
            res = run_bench(trees[label], args)
            device = device or res["device"]
            cells = []
            for scene, row in res["scenes"].items():
                m = row["opencl"]
                s = samples[label].setdefault(scene, {"events_per_s": [], "photons_per_s": []})
                s["events_per_s"].append(m["scattering_events_per_s"])
                s["photons_per_s"].append(m["photons_per_s"])
                cells.append(f"{scene} {m['scattering_events_per_s']:.4g} events/s")
            say(f"round {r + 1} {label}: " + ", ".join(cells)
                + f" | load average {res['loadavg_start']} -> {res['loadavg_end']}")
    if device:
        say(f"# device: {device.get('opencl_device')} | {device.get('opencl_platform')}")
    say(f"# load average at the end {loadavg()}")
    med = statistics.median
    for scene in samples["A"]:
        for label in trees:
            v = samples[label][scene]
            ev, ph = v["events_per_s"], v["photons_per_s"]
            cpu = v.get("events_per_cpu_s")
            say(f"{scene} {label}: median {med(ev):.4g} scattering events/s (range "
                f"{min(ev):.4g}-{max(ev):.4g}, spread {(max(ev) - min(ev)) / med(ev):.1%}); "
                f"{med(ph):.4g} photons/s"
                + (f"; {med(cpu):.4g} events per CPU s (range {min(cpu):.4g}-{max(cpu):.4g})"
                   if cpu else ""))
        a, b = samples["A"][scene], samples["B"][scene]
        line = f"{scene} B / A: {med(b['events_per_s']) / med(a['events_per_s']):.3f}"
        if a.get("events_per_cpu_s"):
            line += (f" (per CPU s: "
                     f"{med(b['events_per_cpu_s']) / med(a['events_per_cpu_s']):.3f})")
        pairs = paired_ratios(a["events_per_s"], b["events_per_s"])
        line += (f"; paired, B / A of each round: median {pairs['median']:.3f}, quartiles "
                 f"{pairs['q1']:.3f}-{pairs['q3']:.3f}, range {pairs['min']:.3f}-"
                 f"{pairs['max']:.3f} ({len(pairs['values'])} rounds)")
        say(line)
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")
    if args.json:
        Path(args.json).write_text(json.dumps({"trees": {k: str(v) for k, v in trees.items()},
                                               "device": device, "samples": samples}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
