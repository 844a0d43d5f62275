"""Independent pieces of work spread over forked worker processes, the results in order: the
chunks of an inversion's grid (docs/inversion.md §5).

Forked workers inherit the parent's objects (the database's surface, the shots, the forward
model) as they are: only a piece's index goes out and its result comes back. Fork is used on
Linux only (macOS's system libraries are not fork-safe, Windows has no fork); elsewhere, or
with one job, the pieces run in this process, one after the other. A piece must give the same
bits wherever it runs: the caller starts every piece from the same state.
"""
from __future__ import annotations

import multiprocessing
import signal
import sys

#: The function and pieces of the map under way, inherited by the forked workers.
_WORK: list = []


def forked_map(function, pieces, jobs: int = 1) -> list:
    """``[function(p) for p in pieces]``, computed by up to ``jobs`` forked worker processes
    (module docstring), each taking the next piece as it finishes one.

    Parameters
    ----------
    function : callable
        Any callable, closures included (it is inherited, not pickled); its result must
        pickle.
    pieces : iterable
    jobs : int
        Worker processes at most (1: this process).

    Returns
    -------
    list
        The results, in the order of ``pieces``.
    """
    pieces = list(pieces)
    jobs = min(int(jobs), len(pieces))
    if jobs <= 1 or not sys.platform.startswith("linux"):
        return [function(p) for p in pieces]
    _WORK[:] = [function, pieces]
    try:
        with multiprocessing.get_context("fork").Pool(jobs, initializer=_worker_signals) as pool:
            return pool.map(_run, range(len(pieces)), chunksize=1)
    finally:
        _WORK.clear()


def _worker_signals() -> None:
    """A worker leaves Ctrl-C to its parent and ends at once on SIGTERM (the pool's own stop),
    whatever handlers it inherited (:mod:`warpe_cl.stops`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _run(index: int):
    function, pieces = _WORK
    return function(pieces[index])
