"""Independent pieces of work spread over forked worker processes, the results in order: the
chunks of an inversion's grid (docs/inversion.md §5).

Forked workers inherit the parent's objects (the database's surface, the shots, the forward
model) as they are: the function and its pieces reach a worker as arguments of its start,
never pickled, and only a piece's index goes out and its result comes back. Fork is used on
Linux only (macOS's system libraries are not fork-safe, Windows has no fork), and not from a
daemonic process (a worker of a ``multiprocessing.Pool`` may not have children); elsewhere, or
with one job, the pieces run in this process, one after the other. A worker that dies (killed
for memory) ends the map with ``BrokenProcessPool`` instead of leaving it waiting. A piece
must give the same bits wherever it runs: the caller starts every piece from the same state.
"""
from __future__ import annotations

import multiprocessing
import signal
import sys
from concurrent.futures import ProcessPoolExecutor

#: In a worker: the function and pieces of its map (set when the worker starts).
_WORK: list = []


def workers(jobs: int, pieces: int) -> int:
    """How many worker processes :func:`forked_map` starts for ``pieces`` pieces and ``jobs``
    jobs: 0 where the pieces run in this process."""
    n = min(int(jobs), int(pieces))
    if n <= 1 or not sys.platform.startswith("linux") \
            or multiprocessing.current_process().daemon:
        return 0
    return n


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
        Worker processes at most (1: this process; :func:`workers`).

    Returns
    -------
    list
        The results, in the order of ``pieces``.
    """
    pieces = list(pieces)
    n = workers(jobs, len(pieces))
    if not n:
        return [function(p) for p in pieces]
    with ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork"),
                             initializer=_start, initargs=(function, pieces)) as pool:
        return list(pool.map(_run, range(len(pieces))))


def _start(function, pieces) -> None:
    """A worker's start: its map's work, and Ctrl-C left to its parent, SIGTERM (the pool's
    own stop) ending it at once, whatever handlers it inherited (:mod:`warpe_cl.stops`)."""
    _WORK[:] = [function, pieces]
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _run(index: int):
    function, pieces = _WORK
    return function(pieces[index])
