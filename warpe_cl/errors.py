"""The package's exceptions.

Every error a user can cause by what they type or write derives from :class:`WarpeError`,
so the command line can turn it into one readable line and an exit code
(docs/interface.md §2): :class:`ConfigError` -> 2, :class:`DeviceError` -> 3, any other
:class:`WarpeError` (e.g. :class:`WeightError`) -> 1.
"""
from __future__ import annotations

import re

__all__ = ["WarpeError", "ConfigError", "DeviceError", "WeightError", "WarpeWarning", "one_line",
           "printable", "LINE_LIMIT"]

#: The longest line the command line prints for an error or a value read from a file.
LINE_LIMIT = 500
#: C0 and C1 control characters and DEL: an ESC sequence (colours, cursor moves, a terminal's
#: title) starts with one, so escaping them leaves every sequence inert.
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


class WarpeError(Exception):
    """Base class of the errors warpe-cl raises on purpose."""


class ConfigError(WarpeError):
    """Bad input: a preset, a ``--set`` override, a value or a unit.

    Parameters
    ----------
    message : str
        What is wrong and what is allowed, e.g.
        ``'-1 mm is not allowed; give a length > 0 with a unit, e.g. "100 mm"'``.
    key : str or None
        Dotted key of the offending entry (``"medium.thickness"``); None for errors about
        the whole file.
    source : str or None
        Where the input came from: a file path, ``"<dict>"``, or None.

    Notes
    -----
    ``str(e)`` is the complete one-line message ``"{source}: {key}: {message}"``, with the
    parts that are None left out; line breaks in ``message`` are replaced by spaces.
    """

    def __init__(self, message: str, key: str | None = None, source: str | None = None):
        self.message = " ".join(str(message).splitlines())
        self.key = key
        self.source = source
        super().__init__(self.message, key, source)

    def __str__(self) -> str:
        parts = [p for p in (self.source, self.key) if p is not None]
        return ": ".join([*map(str, parts), self.message])

    def with_source(self, source: str | None) -> "ConfigError":
        """A copy of this error that names ``source`` (kept when already set)."""
        return ConfigError(self.message, self.key, self.source if self.source else source)


class DeviceError(WarpeError):
    """No usable OpenCL device (or the requested one does not exist); exit code 3."""


class WeightError(WarpeError):
    """The weighted walk produced weights its exact tallies cannot hold (NaN, negative, or so
    large that w^2 >= 2^42: docs/walk.md §6); the result is refused instead of returned with
    those rays silently missing. Exit code 1.

    Parameters
    ----------
    rays : int
        How many exiting rays had such a weight.
    """

    def __init__(self, rays: int):
        self.rays = int(rays)
        super().__init__(
            f"{self.rays} exiting ray(s) had a weight the exact tallies cannot hold (NaN, "
            f"negative, or >= 2^21 so that w^2 >= 2^42); the result is refused. Check the "
            f"medium (omega in [0, 1]) and the roulette keys (roulette_survival not tiny)")


class WarpeWarning(UserWarning):
    """A physically doubtful input: the run goes on, and the command line prints one line."""


def one_line(err: BaseException) -> str:
    """An exception as one line, white space folded: the message of a :class:`WarpeError`,
    ``"Type: message"`` for any other (how the sweep manifest records a failed scenario)."""
    if isinstance(err, WarpeError):
        return " ".join(str(err).split())
    return " ".join(f"{type(err).__name__}: {err}".split())


def printable(text, limit: int = LINE_LIMIT) -> str:
    """``text`` as one inert, bounded line for a terminal.

    Control characters (``\\x00``-``\\x1f``, DEL, the C1 range; so every ANSI escape
    sequence, which starts with ESC) are written as Python escapes (``\\x1b``, ``\\n``,
    ``\\t``), and a line longer than ``limit`` characters keeps its beginning (the file and the
    key) and its end (what is allowed) with ``… (N more characters) …`` in place of the middle.

    Parameters
    ----------
    text : object
        The line (``str(text)`` is used).
    limit : int
        The longest line returned, in characters (at least 80).

    Returns
    -------
    str

    Examples
    --------
    >>> printable("name: \\x1b[31mred\\x1b[0m")
    'name: \\\\x1b[31mred\\\\x1b[0m'
    >>> line = printable("key: " + "x" * 10_000 + " allowed: 1 to 10")
    >>> len(line) <= 500 and line.startswith("key: xx") and line.endswith("allowed: 1 to 10")
    True
    """
    text = _CONTROL.sub(lambda m: repr(m.group())[1:-1], str(text))
    limit = max(int(limit), 80)
    if len(text) <= limit:
        return text
    tail = limit // 3
    head = limit - tail - len(f" … ({len(text)} more characters) … ")
    cut = len(text) - head - tail
    return text[:head] + f" … ({cut} more characters) … " + text[len(text) - tail:]
