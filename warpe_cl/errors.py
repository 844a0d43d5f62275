"""The package's exceptions.

Every error a user can cause by what they type or write derives from :class:`WarpeError`,
so the command line can turn it into one readable line and an exit code
(docs/interface.md §2): :class:`ConfigError` -> 2, :class:`DeviceError` -> 3, any other
:class:`WarpeError` (e.g. :class:`WeightError`) -> 1.
"""
from __future__ import annotations

__all__ = ["WarpeError", "ConfigError", "DeviceError", "WeightError", "WarpeWarning", "one_line"]


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
