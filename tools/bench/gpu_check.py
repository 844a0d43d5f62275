#!/usr/bin/env python3
"""The GPU benchmark and check of issue 43 in one command, for a maintainer with a lent GPU
(about 5 minutes on an H200; with ``--suite`` 2-3 more):

    python tools/bench/gpu_check.py [--device SPEC] [--out DIR] [--quick] [--dry-run]
                                    [--limit S] [--suite]

Each step runs as its own process, its output in DIR/<step>.log, one after the other:

1. ``devices``  ``warpe-cl devices --requalify --device SPEC``: every verdict checked anew on
   this machine, the GPU's lane width and B1 figure, and the hint when a GPU is visible to
   the system but not to OpenCL (docs/devices.md).
2. ``tests``    the GPU-relevant test files (:data:`TEST_FILES`: parity with the NumPy
   reference, reproducibility across launches and lane widths, weighted, nadir, layers,
   kernel blocks) with ``$WARPE_CL_DEVICE=SPEC``, the device the session's ``engine`` fixture
   takes (tests/conftest.py), slow tests left out.
3. ``bench``    ``tools/bench/bench.py`` on every scene (B1-B3, T1) in both modes, 3 rounds,
   JSON in DIR/bench.json: events/s per scene and mode, and T1 / B1 (goal >= 0.8).
4. ``fill``     B1 and T1 again in both modes with :data:`FILL`'s photons, JSON in
   DIR/fill.json: the same figures with every work-item kept busy (``filled`` in the
   summary), which tells a launch bound by its longest ray from a slow walk.
5. ``mcx``      MCX side by side on B1 (``bench.py --compare mcxcl``) where ``pmcx`` (MCX for
   CUDA) or ``pmcxcl`` can be imported by this Python: ``pmcx`` stands in for ``pmcxcl``
   through a one-line module in a venv of DIR that sees this Python's packages (as in issue
   43); skipped, and said so, where neither is there. Goal: ours >= 2x MCX in events/s.
6. ``paper``    ``tools/reproduce_paper.py`` at 1e6 rays per scenario, timed end to end
   (goal: under 5 s on one GPU, files and figures included), its files in DIR/paper/.
7. ``suite``    with ``--suite``: the whole default test run with ``$WARPE_CL_DEVICE=SPEC``, a
   worker per core, each test named in the log as it ends (``-v``), so that a run stopped by
   ``--limit`` still names its failures; the summary lists them. It needs the ``[test]``
   extras (iadpython, dask.distributed, pytest-xdist: carry them to a machine without a
   network); the summary names those this Python cannot import.

DIR/summary.txt and DIR/summary.json hold each step's command, exit code and wall time and
the figures against the issue's goals. ``--quick`` runs every step small (a few thousand rays,
one round, a few tests), so that the script itself can be tried on a CPU in about two
minutes: ``python tools/bench/gpu_check.py --device 0:0 --quick``. ``--dry-run`` prints the
steps and runs nothing. Without ``--device``, the first GPU OpenCL lists; with none, the
script stops (exit 2) and says to give ``--device`` (a CPU stands in with ``--quick``).
``--limit S`` stops any step after S seconds (a lent machine's short lease).
Bad input: one line, exit 2. A failed step is reported and the next one runs; the exit code
is 1 where a step failed.
"""
from __future__ import annotations

import argparse
import datetime as dt
import importlib.util
import json
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
BENCH = REPO / "tools" / "bench"
#: the test files a GPU fails or passes on its own (issue 43: 33 of 134 failed on an H200)
TEST_FILES = ("tests/test_parity.py", "tests/test_reproducibility.py", "tests/test_weighted.py",
              "tests/test_nadir.py", "tests/test_layers.py", "tests/test_kernel_blocks.py")
#: --quick: the tests of the lane widths and launches only
QUICK_TESTS = "lane_width or lane_widths or typeof or event_budget"
#: the issue's goals: T1 / B1 events/s, ours / MCX events/s on B1, the paper's wall time (s)
GOALS = {"t1_over_b1": 0.8, "ours_over_mcx": 2.0, "paper_s": 5.0}
#: the test extras the ``suite`` step needs (import names), from setup.cfg's ``[test]``
TEST_EXTRAS = ("iadpython", "dask", "distributed", "xdist")
#: the ``fill`` step: B1 and T1 with photons enough to fill a GPU's 2^20 work-items ten and
#: two times over (bench.py's defaults, 1e6 and 1e5, give each work-item one photon or none,
#: so that a launch lasts as long as its longest ray)
FILL = {"photons": 1e7, "tail_photons": 2e6}


@dataclass
class Step:
    """One step of the check: a command run in the repository, its log and time limit."""
    name: str
    command: list
    env: dict = field(default_factory=dict)
    timeout_s: float = 600.0
    skip: str | None = None         # why the step is not run (then command is not run)


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None,
                   help="device spec P:D (default: the first GPU OpenCL lists)")
    p.add_argument("--out", default=None,
                   help="folder for every log and the summary (default gpu_check_<date>)")
    p.add_argument("--quick", action="store_true",
                   help="every step small: a try of the script itself, on a CPU too")
    p.add_argument("--dry-run", action="store_true", help="print the steps, run nothing")
    p.add_argument("--photons", type=float, default=None,
                   help="rays per scenario of the paper step (default 1e6; --quick 2e3)")
    p.add_argument("--suite", action="store_true",
                   help="also run the whole test suite on the device (step 7)")
    p.add_argument("--limit", type=float, default=None,
                   help="stop any step after this many seconds (default: each step's own, "
                        "5-15 minutes); for a lent machine's short lease")
    args = p.parse_args(argv)
    if args.limit is not None and not args.limit > 0:
        refuse(f"--limit {args.limit:g}: seconds, a positive number")
    if args.device is not None and not re.fullmatch(r"\d+:\d+", args.device.strip()):
        refuse(f"--device {args.device!r}: give P:D as `warpe-cl devices` lists it")
    if args.photons is not None and not (args.photons >= 1 and args.photons < 1e10):
        refuse(f"--photons {args.photons:g}: a number of rays from 1 to 1e10")
    return args


def refuse(message: str):
    """Bad input: one line on stderr, exit 2."""
    print(f"gpu_check: {message}", file=sys.stderr)
    raise SystemExit(2)


def mcx_available(find_spec=importlib.util.find_spec) -> str | None:
    """The MCX package this Python can import for the side-by-side run: ``"pmcxcl"``,
    ``"pmcx"`` (MCX for CUDA, which stands in), or ``None``."""
    for name in ("pmcxcl", "pmcx"):
        if find_spec(name) is not None:
            return name
    return None


def plan(device: str, out: Path, quick: bool, mcx: str | None, photons: float | None = None,
         python: str = sys.executable, pythonpath: str | None = None,
         suite: bool = False) -> list:
    """The steps of the check, in order.

    Parameters
    ----------
    device : str
        The device spec, P:D.
    out : Path
        The folder of logs and results.
    quick : bool
        Every step small (a try of the script; numbers not meaningful).
    mcx : str or None
        ``"pmcxcl"``, ``"pmcx"`` (:func:`mcx_available`) or None: the MCX step is skipped.
    photons : float, optional
        Rays per scenario of the paper step (default 1e6, quick 2e3).
    python : str
        The interpreter of every step.
    pythonpath : str, optional
        The caller's ``PYTHONPATH`` (default: this process's), kept after the repository.
    suite : bool
        Run the whole test suite too (else the step is skipped, and said so).

    Returns
    -------
    list of Step
    """
    # the repository first, then whatever the caller's PYTHONPATH holds (on a lent GPU, the
    # wheels installed with --target: pyopencl, h5netcdf, pmcx)
    if pythonpath is None:
        pythonpath = os.environ.get("PYTHONPATH", "")
    env = {"WARPE_CL_DEVICE": device,
           "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), pythonpath]))}
    bench = [python, str(BENCH / "bench.py"), "--device", device, "--modes", "analog,weighted"]
    if quick:
        bench += ["--photons", "2e4", "--tail-photons", "500", "--rounds", "1"]
    else:
        bench += ["--rounds", "3"]
    tests = [python, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-m", "not slow",
             *TEST_FILES] + (["-k", QUICK_TESTS] if quick else [])
    paper_photons = photons or (2e3 if quick else 1e6)
    paper = [python, str(REPO / "tools" / "reproduce_paper.py"), "--device", device,
             "--photons", f"{paper_photons:g}", "--out", str(out / "paper" / "figures"),
             "--data", str(out / "paper" / "data")]
    if quick:
        paper += ["--only", "slab_h2o_thickness"]
    mcx_cmd = [python, str(BENCH / "bench.py"), "--device", device, "--scenes", "B1",
               "--compare", "mcxcl", "--mcxcl-venv", str(out / "mcx-venv"),
               "--json", str(out / "mcx.json")]
    mcx_cmd += (["--photons", "2e4", "--mcxcl-photons", "2e4", "--mcxcl-rounds", "1",
                 "--mcxcl-check-photons", "0"] if quick else ["--mcxcl-rounds", "3"])
    fill = [python, str(BENCH / "bench.py"), "--device", device, "--modes", "analog,weighted",
            "--scenes", "B1,T1", "--json", str(out / "fill.json")]
    fill += (["--photons", "4e4", "--tail-photons", "1e3", "--rounds", "1"] if quick else
             ["--photons", f"{FILL['photons']:g}", "--tail-photons",
              f"{FILL['tail_photons']:g}", "--rounds", "3"])
    suite_cmd = [python, "-m", "pytest", "-v", "-rfE", "-p", "no:cacheprovider", "-n", "auto",
                 "--maxprocesses", str(os.cpu_count() or 1)]
    suite_cmd += ["-k", QUICK_TESTS] if quick else []
    return [
        Step("devices", [python, "-m", "warpe_cl", "devices", "--requalify", "--device", device],
             env, 300),
        Step("tests", tests, env, 900),
        Step("bench", bench + ["--json", str(out / "bench.json")], env, 900),
        Step("fill", fill, env, 600),
        Step("mcx", mcx_cmd, env, 600,
             skip=None if mcx else "neither pmcx nor pmcxcl can be imported by this Python"),
        Step("paper", paper, env, 900),
        Step("suite", suite_cmd, env, 900,
             skip=None if suite else "not asked for (--suite runs it)"),
    ]


def _checkout_on_path() -> None:
    """Let this process import the checkout's warpe_cl and tools/studies, as every step's
    ``PYTHONPATH`` does: on a lent GPU the project is not installed, only its wheels."""
    for folder in (str(REPO / "tools" / "studies"), str(REPO)):
        if folder not in sys.path:
            sys.path.insert(0, folder)


def caller_paths(pythonpath: str | None = None, site_dirs=None) -> list:
    """The folders where this Python finds its packages beyond the standard library: the
    entries of ``PYTHONPATH`` (default: this process's) and its site-packages (default:
    :func:`site.getsitepackages`), in that order, each once."""
    import site
    if pythonpath is None:
        pythonpath = os.environ.get("PYTHONPATH", "")
    if site_dirs is None:
        site_dirs = site.getsitepackages()
    out = []
    for folder in [*pythonpath.split(os.pathsep), *site_dirs]:
        if folder and folder not in out:
            out.append(folder)
    return out


def mcx_venv(folder: Path, mcx: str, python: str = sys.executable) -> None:
    """A venv at ``folder`` that sees this Python's packages, where ``import pmcxcl`` gives
    pmcxcl, or ``pmcx`` under pmcxcl's name (the same ``run`` API; issue 43 ran MCX for CUDA
    so), with the version string bench.py's check asks for. bench.py runs MCX in that venv
    without ``PYTHONPATH`` (tools/studies/mcxcl_compare.py ``mcx_env``), and a venv made from
    a venv sees the base Python's packages, not the first venv's: a ``.pth`` file names
    :func:`caller_paths`, where the wheels carried to a lent GPU and numpy are."""
    if not (folder / "bin" / "python").exists():
        subprocess.run([python, "-m", "venv", "--system-site-packages", str(folder)], check=True)
    site = subprocess.run([str(folder / "bin" / "python"), "-c",
                           "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    Path(site, "gpu_check_caller.pth").write_text("\n".join(caller_paths()) + "\n")
    if mcx == "pmcx":
        _checkout_on_path()
        from mcxcl_compare import PMCXCL_VERSION
        Path(site, "pmcxcl.py").write_text(
            "# pmcx (MCX for CUDA) standing in for pmcxcl: tools/bench/gpu_check.py\n"
            "from pmcx import *  # noqa: F401,F403\n"
            f"__version__ = {PMCXCL_VERSION!r}\n")


def pytest_counts(text: str) -> dict:
    """The counts of pytest's last summary line (``3 failed, 131 passed, 2 skipped in 9.1s``):
    ``{"passed": 131, "failed": 3, "skipped": 2, ...}``; empty where there is none."""
    lines = [ln for ln in text.splitlines() if re.search(r"\d+ (passed|failed|error)", ln)]
    if not lines:
        return {}
    return {k: int(n) for n, k in re.findall(r"(\d+) (\w+)", lines[-1])
            if k in ("passed", "failed", "skipped", "errors", "error", "deselected", "xfailed")}


def pytest_outcomes(text: str) -> tuple:
    """The tests a ``pytest -v`` log names as ended, with or without xdist (``[gw3] [ 12%]
    PASSED tests/t.py::test_a`` or ``tests/t.py::test_a PASSED [ 12%]``): the counts per
    outcome and the names of those that failed or erred, in order. A run stopped before its
    summary line is read so."""
    words = "PASSED|FAILED|ERROR|SKIPPED|XFAIL|XPASS"
    # xdist: the outcome, then the id to the end of the line (an id may hold spaces);
    # without: the id, then the last outcome word before the progress "[ 12%]"
    xdist = re.compile(rf"^\[gw\d+\] \[\s*\d+%\] ({words}) (tests/.+?)\s*$")
    plain = re.compile(rf"^(tests/.+::.+) ({words})\b.*\[\s*\d+%\]\s*$")
    counts, failed = {}, []
    for line in text.splitlines():
        m = xdist.match(line)
        if m:
            outcome, name = m.group(1), m.group(2)
        else:
            m = plain.match(line)
            if not m:           # the summary, -rfE's recap, anything else
                continue
            name, outcome = m.group(1), m.group(2)
        outcome = outcome.lower()
        counts[outcome] = counts.get(outcome, 0) + 1
        if outcome in ("failed", "error"):
            failed.append(name)
    return counts, failed


def bench_figures(result: dict) -> dict:
    """The figures of a bench.py JSON: ``{"B1 analog": events/s, ...}`` (medians), and
    ``"T1/B1"`` and ``"ours/MCX"`` where the JSON has them."""
    out = {}
    for name, row in result.get("scenes", {}).items():
        for key, mode in (("opencl", "analog"), ("opencl_weighted", "weighted")):
            if isinstance(row.get(key), dict) and "scattering_events_per_s" in row[key]:
                out[f"{name} {mode}"] = row[key]["scattering_events_per_s"]
        if "ratio_to_mcxcl" in row:
            out["ours/MCX"] = row["ratio_to_mcxcl"]
    tail = result.get("tail_over_b1")
    if tail:
        out["T1/B1"] = tail["ratio_events_per_s"]["median"]
    return out


def verdicts(figures: dict, paper_s: float | None) -> list:
    """The issue's goals against the figures: ``(goal, value, met)`` rows; a figure not
    measured is left out."""
    rows = []
    if "T1/B1" in figures:
        rows.append((f"T1/B1 >= {GOALS['t1_over_b1']}", figures["T1/B1"],
                     figures["T1/B1"] >= GOALS["t1_over_b1"]))
    if "ours/MCX" in figures:
        rows.append((f"ours/MCX >= {GOALS['ours_over_mcx']}", figures["ours/MCX"],
                     figures["ours/MCX"] >= GOALS["ours_over_mcx"]))
    if paper_s is not None:
        rows.append((f"paper < {GOALS['paper_s']} s", paper_s, paper_s < GOALS["paper_s"]))
    return rows


def summary_lines(device: str, records: list, figures: dict, quick: bool) -> list:
    """summary.txt's lines: each step's exit code, time and log; the figures; the goals
    (not with ``quick``, whose figures say nothing of speed)."""
    lines = [f"# GPU check on {device} ({dt.datetime.now().isoformat(timespec='seconds')})", ""]
    if quick:
        lines += ["--quick: every step small; the figures say nothing of speed.", ""]
    lines += ["| step | exit | wall s | note |", "| --- | --- | --- | --- |"]
    for r in records:
        note = r.get("skip") or r.get("note") or ""
        rc = "skipped" if r.get("skip") else r["rc"]
        lines.append(f"| {r['name']} | {rc} | {r.get('wall_s', 0):.1f} | {note} |")
    failed = next((r.get("failed_tests") for r in records if r["name"] == "suite"), None)
    if failed:
        lines += ["", f"Failed or erred in the suite ({len(failed)}):"]
        lines += [f"- {name}" for name in failed[:40]]
        if len(failed) > 40:
            lines.append(f"- ... and {len(failed) - 40} more (suite.log)")
    if figures:
        lines += ["", "| figure | value |", "| --- | --- |"]
        lines += [f"| {k} | {v:.4g} |" for k, v in figures.items()]
    paper = next((r for r in records if r["name"] == "paper" and not r.get("skip")), None)
    rows = [] if quick else verdicts(figures, paper["wall_s"] if paper and paper["rc"] == 0
                                     else None)
    if rows:
        lines += ["", "| goal (issue 43) | measured | met |", "| --- | --- | --- |"]
        lines += [f"| {g} | {v:.4g} | {'yes' if ok else 'NO'} |" for g, v, ok in rows]
    return lines


def first_gpu() -> str | None:
    """The spec of the first GPU OpenCL lists, or None."""
    _checkout_on_path()
    from warpe_cl.device import list_devices
    return next((info.spec for info, _ in list_devices() if info.kind == "gpu"), None)


def run_step(step: Step, out: Path) -> dict:
    """Run one step, its output into out/<name>.log; its record for the summary."""
    record = {"name": step.name, "command": " ".join(step.command)}
    if step.skip:
        record["skip"] = step.skip
        print(f"gpu_check: {step.name}: skipped ({step.skip})", flush=True)
        return record
    log = out / f"{step.name}.log"
    print(f"gpu_check: {step.name}: {record['command']}", flush=True)
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        try:
            proc = subprocess.run(step.command, cwd=REPO, env={**os.environ, **step.env},
                                  stdout=fh, stderr=subprocess.STDOUT, timeout=step.timeout_s)
            record["rc"] = proc.returncode
        except subprocess.TimeoutExpired:
            record["rc"], record["note"] = 124, f"stopped after {step.timeout_s:.0f} s"
    record["wall_s"] = time.perf_counter() - t0
    record["log"] = str(log)
    print(f"gpu_check: {step.name}: exit {record['rc']} in {record['wall_s']:.1f} s ({log})",
          flush=True)
    return record


def main(argv=None) -> int:
    args = parse_args(argv)
    device = args.device.strip() if args.device else None
    if device is None:
        device = first_gpu()
        if device is None:
            print("gpu_check: OpenCL lists no GPU (`warpe-cl devices` says why, and how to "
                  "register a driver); give --device P:D (a CPU stands in with --quick)",
                  file=sys.stderr)
            return 2
    out = Path(args.out or f"gpu_check_{dt.datetime.now():%Y%m%d_%H%M%S}").resolve()
    mcx = mcx_available()
    steps = plan(device, out, args.quick, mcx, args.photons, suite=args.suite)
    if args.dry_run:
        for s in steps:
            env = " ".join(f"{k}={v}" for k, v in s.env.items())
            print(f"{s.name}: " + (f"skipped ({s.skip})" if s.skip else
                                   f"{env} {' '.join(s.command)}"))
        return 0
    out.mkdir(parents=True, exist_ok=True)
    if mcx:
        try:
            mcx_venv(out / "mcx-venv", mcx)
        except (OSError, subprocess.CalledProcessError) as err:
            next(s for s in steps if s.name == "mcx").skip = \
                f"could not make the venv for {mcx}: {err}"
    if args.limit:
        for s in steps:
            s.timeout_s = min(s.timeout_s, args.limit)
    records = [run_step(s, out) for s in steps]
    figures = {}
    for name, prefix in (("bench.json", ""), ("fill.json", "filled "), ("mcx.json", "")):
        if (out / name).is_file():
            figures.update({prefix + k: v for k, v in
                            bench_figures(json.loads((out / name).read_text())).items()})
    tests = next(r for r in records if r["name"] == "tests")
    if "log" in tests:
        counts = pytest_counts(Path(tests["log"]).read_text())
        tests["note"] = ", ".join(f"{n} {k}" for k, n in counts.items())
    suite = next(r for r in records if r["name"] == "suite")
    if "log" in suite:
        text = Path(suite["log"]).read_text()
        counts = pytest_counts(text)
        ended, suite["failed_tests"] = pytest_outcomes(text)
        note = ", ".join(f"{n} {k}" for k, n in (counts or ended).items())
        if not counts:
            note += " (stopped before pytest's summary: the tests that ended)"
        missing = [m for m in TEST_EXTRAS if importlib.util.find_spec(m) is None]
        if missing:
            note += "; test extras missing: " + ", ".join(missing)
        suite["note"] = note
    lines = summary_lines(device, records, figures, args.quick)
    (out / "summary.txt").write_text("\n".join(lines) + "\n")
    (out / "summary.json").write_text(json.dumps(
        {"device": device, "quick": args.quick, "steps": records, "figures": figures}, indent=1))
    print("\n".join(lines))
    return 1 if any(r.get("rc") not in (0, None) for r in records) else 0


if __name__ == "__main__":
    sys.exit(main())
