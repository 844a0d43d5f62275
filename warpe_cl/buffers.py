"""The device memory a walk needs, checked against the device before the walk.

A run whose time grid passes the preset's cap (``MAX_TIME_BINS``) can still need buffers the
device cannot allocate: the nadir sums hold ``slices x NADIR_BATCHES x rows x (bins + 2)``
cells of ``FIXED_WORDS`` 64-bit words, one slice per work-item on a CPU (docs/walk.md §8.2),
so 220,000 bins on a 2-core CPU asked for one 16 GB buffer and the walk failed with
INVALID_BUFFER_SIZE. :func:`walk_buffer_bytes` says what each buffer takes,
:func:`time_bins_allowed` how many bins fit, and :func:`check_walk_buffers` refuses the run
first with one line naming ``simulation.time_bins``.
"""
from __future__ import annotations

from typing import Callable

from .errors import ConfigError
from .params import (FIXED_WORDS, ITEM_STATS, NADIR_BATCHES, NADIR_ROWS, STATE_INT_COLUMNS,
                     STATE_REAL_COLUMNS, tally_shapes)

__all__ = ["walk_buffer_bytes", "time_bins_allowed", "check_walk_buffers"]


def _cells(shape) -> int:
    out = 1
    for s in shape:
        out *= int(s)
    return out


def walk_buffer_bytes(n_time: int, histograms, weighted_sums, global_size: int,
                      capacity: int, itemsize: int, nadir_slices: int) -> dict:
    """The bytes of each device buffer of a walk over ``n_time`` time bins that grows with the
    time grid or the launch (as :meth:`warpe_cl.engine.Engine.run` allocates them).

    Parameters
    ----------
    n_time : int
        Time bins.
    histograms, weighted_sums : iterable of str
        The uint32 histograms and the weighted sums (``FIXED_WORDS`` uint64 words per cell)
        the kernel writes, by name (:func:`~warpe_cl.params.tally_shapes`).
    global_size : int
        Work-items per launch.
    capacity : int
        Rays that may be parked between launches (each of the two carry buffers).
    itemsize : int
        Bytes of a REAL (4 in single precision, 8 in double).
    nadir_slices : int
        Slices of the nadir sums (1 shared, or one per work-item); 0 without the estimator.

    Returns
    -------
    dict
        Buffer name -> bytes.
    """
    shapes = tally_shapes(n_time)
    out = {name: 4 * _cells(shapes[name]) for name in histograms}
    out.update({name: 8 * FIXED_WORDS * _cells(shapes[name]) for name in weighted_sums})
    out["item_stats"] = 8 * len(ITEM_STATS) * global_size
    out["carry_real"] = itemsize * len(STATE_REAL_COLUMNS) * capacity
    out["carry_int"] = 4 * len(STATE_INT_COLUMNS) * capacity
    if nadir_slices:
        cells = nadir_slices * NADIR_BATCHES * len(NADIR_ROWS) * (n_time + 2)
        out["nadir_sum"] = 8 * FIXED_WORDS * cells
        out["nadir_visits"] = 8 * nadir_slices * len(NADIR_ROWS) * (n_time + 2)
    return out


def time_bins_allowed(sizes_for: Callable[[int], dict], max_alloc: int,
                      global_mem: int) -> int:
    """The most time bins whose buffers fit the device: every buffer at most ``max_alloc``
    bytes, all of them (the two carry buffers twice) at most ``global_mem``.

    Parameters
    ----------
    sizes_for : callable
        Time bins -> ``{buffer: bytes}`` (:func:`walk_buffer_bytes` with the rest fixed);
        every size is affine in the bins.
    max_alloc, global_mem : int
        The device's ``CL_DEVICE_MAX_MEM_ALLOC_SIZE`` and ``CL_DEVICE_GLOBAL_MEM_SIZE``.

    Returns
    -------
    int
        The largest count, 0 when not even one bin fits.
    """
    base, step = sizes_for(0), sizes_for(1)
    best = None
    for name, b0 in base.items():
        slope = step[name] - b0
        if slope > 0:
            fit = (max_alloc - b0) // slope
            best = fit if best is None else min(best, fit)
    total0 = sum(base.values()) + base["carry_real"] + base["carry_int"]
    total_slope = sum(step.values()) - sum(base.values())
    if total_slope > 0:
        fit = (global_mem - total0) // total_slope
        best = fit if best is None else min(best, fit)
    return max(0, int(best)) if best is not None else 1 << 62


def check_walk_buffers(sizes_for: Callable[[int], dict], n_time: int, max_alloc: int,
                       global_mem: int, device: str) -> None:
    """Refuse a walk whose buffers the device cannot allocate, before any is allocated.

    Parameters
    ----------
    sizes_for : callable
        As for :func:`time_bins_allowed`.
    n_time : int
        The run's time bins.
    max_alloc, global_mem : int
        The device's limits, bytes.
    device : str
        The device's name, for the message.

    Raises
    ------
    ConfigError
        ``simulation.time_bins``: the count, the buffer that does not fit, the device's limit
        and the largest count allowed on this device (one line; exit 2).
    """
    sizes = sizes_for(n_time)
    total = sum(sizes.values()) + sizes["carry_real"] + sizes["carry_int"]
    largest = max(sizes, key=sizes.get)
    if sizes[largest] <= max_alloc and total <= global_mem:
        return
    mib = 1 << 20
    allowed = time_bins_allowed(sizes_for, max_alloc, global_mem)
    if sizes[largest] > max_alloc:
        why = (f"its buffer {largest} needs {sizes[largest] / mib:.0f} MiB, more than the "
               f"{max_alloc / mib:.0f} MiB this device allocates at most")
    else:
        why = (f"its buffers need {total / mib:.0f} MiB, more than the device's "
               f"{global_mem / mib:.0f} MiB")
    hint = "; the nadir estimator's sums grow with the bins (simulation.nadir: false " \
           "leaves them out)" if "nadir_sum" in sizes else ""
    raise ConfigError(f"{n_time} time bins is not allowed on {device}: {why}; give at most "
                      f"{allowed} time bins here{hint}", key="simulation.time_bins")
