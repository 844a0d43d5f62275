"""Ctrl-C and SIGTERM that are never lost.

Python runs a signal handler between two bytecodes of the main thread, wherever that thread is:
inside a weakref callback or a ``__del__`` too, where an exception raised by the handler is
printed as "Exception ignored in: ..." and dropped. A handler that only raised could so lose
a SIGTERM (Slurm's time limit) and let a sweep run its whole grid to exit 0.

Here the handler first records the signal, then raises as before. The long loops (the
engine's launches, a sweep's scenarios, the instrument's shots) call :func:`check` between
their steps: a stop whose exception was dropped is raised again there, so that every signal
ends the run within one step. The command line clears the record (:func:`clear`) once it has
reported the stop. While the handler is installed, the "Exception ignored in: ..." report of
such a dropped stop is not printed: the stop is not ignored, and the command line says it in
its one line.
"""
from __future__ import annotations

import signal
import sys
import threading

__all__ = ["Terminated", "install", "restore", "check", "clear", "pending"]


class Terminated(KeyboardInterrupt):
    """SIGTERM (Slurm's time limit, ``kill``), handled as Ctrl-C is: outputs all or nothing,
    a sweep's manifest flushed; exit 143 with one line."""


_pending: int | None = None        # the signal received and not yet reported, or None


def _exception(signum: int) -> KeyboardInterrupt:
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _handler(signum, frame):
    global _pending
    _pending = signum
    raise _exception(signum)


def _unraisable(hook):
    """A ``sys.unraisablehook`` that says nothing of a stop raised by :func:`_handler` where
    Python cannot raise it (a ``__del__``, a weakref callback): :func:`check` raises it again;
    anything else goes to ``hook``."""
    def quiet(unraisable):
        if isinstance(unraisable.exc_value, KeyboardInterrupt) and _pending is not None:
            return
        hook(unraisable)
    return quiet


def install() -> dict:
    """Route SIGINT and SIGTERM through the recording handler (main thread only), and keep
    the stops it raises where Python drops exceptions from being printed.

    Returns
    -------
    dict
        What :func:`restore` puts back: signal number -> the handler replaced, and
        ``"unraisablehook"``; empty where handlers cannot be set (not the main thread).
    """
    clear()
    previous = {}
    if threading.current_thread() is not threading.main_thread():
        return previous
    for signum in (signal.SIGINT, signal.SIGTERM):
        try:
            previous[signum] = signal.signal(signum, _handler)
        except (ValueError, OSError):
            pass
    previous["unraisablehook"] = sys.unraisablehook
    sys.unraisablehook = _unraisable(sys.unraisablehook)
    return previous


def restore(previous: dict) -> None:
    """Put back the handlers (and the unraisable hook) :func:`install` replaced."""
    for signum, handler in previous.items():
        if signum == "unraisablehook":
            sys.unraisablehook = handler
            continue
        try:
            signal.signal(signum, handler)
        except (ValueError, OSError, TypeError):
            pass


def pending() -> int | None:
    """The signal received and not yet reported (``signal.SIGINT``/``SIGTERM``), or None."""
    return _pending


def check() -> None:
    """Raise the stop a signal asked for, if its own exception was dropped on the way.

    Raises
    ------
    KeyboardInterrupt
        :class:`Terminated` for SIGTERM, a plain KeyboardInterrupt for SIGINT.
    """
    if _pending is not None:
        raise _exception(_pending)


def clear() -> None:
    """Forget the recorded signal (the stop has been reported)."""
    global _pending
    _pending = None
