"""How many CPUs this process may use (a sweep's worker threads, an inversion's processes)."""
from __future__ import annotations

import os


def allocated_cpus() -> int:
    """CPUs this process may use: ``$SLURM_CPUS_PER_TASK``, else the CPU affinity mask."""
    slurm = os.environ.get("SLURM_CPUS_PER_TASK", "")
    if slurm.isdigit() and int(slurm) > 0:
        return int(slurm)
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1
