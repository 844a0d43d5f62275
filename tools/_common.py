"""What the tools share, in the standard library only: ``mcxcl_anchor.py`` imports it inside
MCX-CL's own virtual environment, where warpe-cl is not installed.

The tools run as scripts (``python tools/bench.py``), so their folder is first on
``sys.path`` and ``from _common import loadavg`` finds this file.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path


def loadavg():
    """The 1, 5 and 15 min load averages (None where /proc/loadavg is missing)."""
    try:
        with open("/proc/loadavg") as fh:
            return [float(v) for v in fh.read().split()[:3]]
    except OSError:
        return None


def run_in_tree(script, tree, args, cwd=None, prefix=()) -> dict:
    """Run ``python script *args`` in a new process whose ``warpe_cl`` (and so ``cl/``) is
    ``tree``'s (``PYTHONPATH``), and return the JSON of the last line it prints. A failure
    ends the tool with one line: the tree and the child's last line of stderr. ``prefix``:
    a command that runs the interpreter (``valgrind ...``, tools/kernel_icount.py)."""
    if not (Path(tree) / "warpe_cl").is_dir():
        raise SystemExit(f"{tree}: not a warpe-cl checkout (no warpe_cl/ folder in it)")
    env = dict(os.environ, PYTHONPATH=str(tree))
    out = subprocess.run([*map(str, prefix), sys.executable, str(script), *map(str, args)],
                         capture_output=True, text=True, env=env, cwd=str(cwd or tree))
    if out.returncode:
        last = (out.stderr.strip().splitlines() or ["no message"])[-1]
        raise SystemExit(f"{tree}: {last}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def print_report(lines, path=None) -> None:
    """Print a tool's report, one line each, and write the same lines to ``path`` if given."""
    text = "\n".join(lines)
    print(text)
    if path:
        Path(path).write_text(text + "\n")
