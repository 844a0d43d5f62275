"""What the benchmarks share, in the standard library only: ``mcxcl_anchor.py`` imports it
inside MCX-CL's own virtual environment, where warpe-cl is not installed.

The tools run as scripts (``python tools/bench/bench.py``), so their folder is first on
``sys.path`` and ``from _common import loadavg`` finds this file; a study that uses it
(``tools/studies/nadir_cones.py``) puts this folder on ``sys.path`` itself.
"""
from __future__ import annotations


def loadavg():
    """The 1, 5 and 15 min load averages (None where /proc/loadavg is missing)."""
    try:
        with open("/proc/loadavg") as fh:
            return [float(v) for v in fh.read().split()[:3]]
    except OSError:
        return None
