"""Quantities with a unit: ``"100 mm"``, ``"12.5 ns"``, ``"0.25 deg"``.

Presets write every dimensioned value as a string with a unit; this module turns such a
string into a float in the package's canonical unit and back. It is the package's one
quantity parser: scenario presets use the first three dimensions, instrument presets
(:mod:`warpe_cl.config.instrument_fields`) all of them.

=================  ==============  ===============================================
dimension          canonical unit  accepted units
=================  ==============  ===============================================
``length``         metre           m, cm, mm, um, µm, micron, nm, km
``time``           nanosecond      s, ms, us, µs, ns, ps
``angle``          degree          deg, degree, degrees, °, rad, mrad, urad, µrad
``energy``         joule           J, mJ, uJ, µJ, nJ
``voltage``        volt            V, mV, uV, µV
``current``        ampere          A, mA, uA, µA, nA, pA
``current_noise``  A/√Hz           A/rtHz, nA/rtHz, pA/rtHz, fA/rtHz
``frequency``      hertz           Hz, kHz, MHz, GHz
``resistance``     ohm             ohm, kohm, Mohm
``irradiance``     W m⁻² nm⁻¹      W/m2/nm
``distance``       astronomical    AU
                   unit
=================  ==============  ===============================================

Units are case-sensitive (``Mm`` is not ``mm``). The number and the unit may be separated
by spaces or not (``"500 km"``, ``"500km"``). A bare number is refused: the unit is what
makes a preset readable, and guessing it is how a 100 mm layer becomes 100 m.

>>> parse_quantity("200 um", "length")
0.0002
>>> parse_quantity("1e-6 ns", "time")
1e-06
>>> format_quantity(0.1, "length")
'100 mm'

This module imports nothing from the package.
"""
from __future__ import annotations

import math
import re

__all__ = ["UnitError", "DIMENSIONS", "UNITS", "parse_quantity", "format_quantity",
           "format_attribute", "canonical_unit", "unit_list"]

DIMENSIONS = ("length", "time", "angle", "energy", "voltage", "current", "current_noise",
              "frequency", "resistance", "irradiance", "distance")

# Each unit is (power of ten, extra factor). Powers of ten are applied by an exact
# multiplication or division by an integer power of ten, so that "100 um" gives exactly
# the float 1e-4 and format_quantity round-trips. The instrument dimensions (energy and
# after) are read as number x factor, the arithmetic their presets have always used.
_RAD = 180.0 / math.pi
UNITS: dict[str, dict[str, tuple[int, float]]] = {
    "length": {  # -> metres
        "m": (0, 1.0), "cm": (-2, 1.0), "mm": (-3, 1.0),
        "um": (-6, 1.0), "µm": (-6, 1.0), "μm": (-6, 1.0),
        "micron": (-6, 1.0), "microns": (-6, 1.0),
        "nm": (-9, 1.0), "km": (3, 1.0),
    },
    "time": {  # -> nanoseconds
        "s": (9, 1.0), "ms": (6, 1.0), "us": (3, 1.0), "µs": (3, 1.0), "μs": (3, 1.0),
        "ns": (0, 1.0), "ps": (-3, 1.0),
    },
    "angle": {  # -> degrees
        "deg": (0, 1.0), "degree": (0, 1.0), "degrees": (0, 1.0), "°": (0, 1.0),
        "rad": (0, _RAD), "mrad": (-3, _RAD), "urad": (-6, _RAD),
        "µrad": (-6, _RAD), "μrad": (-6, _RAD),
    },
    "energy": {"J": (0, 1.0), "mJ": (0, 1e-3), "uJ": (0, 1e-6), "µJ": (0, 1e-6),
               "nJ": (0, 1e-9)},
    "voltage": {"V": (0, 1.0), "mV": (0, 1e-3), "uV": (0, 1e-6), "µV": (0, 1e-6)},
    "current": {"A": (0, 1.0), "mA": (0, 1e-3), "uA": (0, 1e-6), "µA": (0, 1e-6),
                "nA": (0, 1e-9), "pA": (0, 1e-12)},
    "current_noise": {"A/rtHz": (0, 1.0), "nA/rtHz": (0, 1e-9), "pA/rtHz": (0, 1e-12),
                      "fA/rtHz": (0, 1e-15)},
    "frequency": {"Hz": (0, 1.0), "kHz": (0, 1e3), "MHz": (0, 1e6), "GHz": (0, 1e9)},
    "resistance": {"ohm": (0, 1.0), "kohm": (0, 1e3), "Mohm": (0, 1e6)},
    "irradiance": {"W/m2/nm": (0, 1.0)},
    "distance": {"AU": (0, 1.0)},
}

# Shown to users in error messages (aliases such as the Greek-letter mu are left out).
_SHOWN = {
    "length": ("m", "cm", "mm", "um", "µm", "micron", "nm", "km"),
    "time": ("s", "ms", "us", "µs", "ns", "ps"),
    "angle": ("deg", "degree(s)", "°", "rad", "mrad", "urad", "µrad"),
    **{d: tuple(u for u in UNITS[d] if "μ" not in u) for d in DIMENSIONS[3:]},
}
_ARTICLE = {"length": "a length", "time": "a time", "angle": "an angle",
            "energy": "an energy", "voltage": "a voltage", "current": "a current",
            "current_noise": "a current noise density", "frequency": "a frequency",
            "resistance": "a resistance", "irradiance": "a spectral irradiance",
            "distance": "a heliocentric distance"}

_NUMBER = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"
_QUANTITY = re.compile(rf"^\s*({_NUMBER})\s*(.*?)\s*$")


class UnitError(ValueError):
    """A quantity string that cannot be read as the expected dimension.

    ``str(e)`` is a complete one-line sentence naming the value, the expected dimension and
    the allowed units. The attribute ``problem`` holds only what is wrong (no unit list),
    for callers that add their own advice.
    """

    def __init__(self, problem: str, dimension: str):
        self.problem = problem
        self.dimension = dimension
        super().__init__(f"{problem}; give {_ARTICLE[dimension]} with a unit "
                         f"({unit_list(dimension)})")


def unit_list(dimension: str) -> str:
    """The accepted units of ``dimension`` as a comma-separated string, for messages."""
    _check_dimension(dimension)
    return ", ".join(_SHOWN[dimension])


def _check_dimension(dimension: str) -> None:
    if dimension not in UNITS:
        raise ValueError(f"unknown dimension {dimension!r}; expected one of "
                         f"{', '.join(DIMENSIONS)}")


def _scale(number: float, unit: str, dimension: str) -> float:
    """``number`` in ``unit`` expressed in the canonical unit of ``dimension``."""
    power, factor = UNITS[dimension][unit]
    value = number * 10 ** power if power >= 0 else number / 10 ** -power
    return value * factor if factor != 1.0 else value


def parse_quantity(text, dimension: str) -> float:
    """Read a string such as ``"100 mm"`` as a float in the canonical unit.

    Parameters
    ----------
    text : str
        A number followed by a unit, e.g. ``"100 mm"``, ``"1e-6 ns"``, ``"0.25°"``.
    dimension : str
        What the quantity must be: one of :data:`DIMENSIONS`.

    Returns
    -------
    float
        The value in the canonical unit of ``dimension``: metres (length), nanoseconds
        (time), degrees (angle), or for the instrument dimensions the first unit of their
        row in :data:`UNITS` (J, V, A, A/rtHz, Hz, ohm, W/m2/nm, AU). The sign is kept; range checks are the caller's
        business.

    Raises
    ------
    UnitError
        For a bare number (``100``, ``"100"``), a unit of another dimension (``"12 deg"``
        for a length), an unknown unit, a non-finite number or anything that is not a string.

    Examples
    --------
    >>> parse_quantity("500 km", "length")
    500000.0
    >>> parse_quantity("12.5 ns", "time")
    12.5
    >>> parse_quantity("5 mrad", "angle")  # doctest: +ELLIPSIS
    0.28647889756...
    """
    _check_dimension(dimension)
    if isinstance(text, bool) or not isinstance(text, (str, int, float)):
        shown = str(text).lower() if isinstance(text, bool) else repr(text)
        raise UnitError(f"{shown} is not a quantity", dimension)
    if not isinstance(text, str):
        raise UnitError(f"{text!r} is a bare number with no unit", dimension)
    match = _QUANTITY.match(text)
    if match is None:
        raise UnitError(f'"{text}" is not a number followed by a unit', dimension)
    number, unit = float(match.group(1)), match.group(2)
    if not math.isfinite(number):  # e.g. "1e999 m"
        raise UnitError(f'"{text}" is not a finite number', dimension)
    if unit == "":
        raise UnitError(f'"{text}" is a bare number with no unit', dimension)
    if unit in UNITS[dimension]:
        return _scale(number, unit, dimension)
    for other, units in UNITS.items():
        if unit in units:
            raise UnitError(f'"{text}" is {_ARTICLE[other]} ({unit}), not {_ARTICLE[dimension]}',
                            dimension)
    hint = ""
    for known in UNITS[dimension]:
        if known.lower() == unit.lower():
            hint = f" (did you mean {known}?)"
            break
    raise UnitError(f'"{text}" has an unknown unit "{unit}"{hint}', dimension)


def split_quantity(text: str):
    """A number and the unit written after it, read with the same grammar as
    :func:`parse_quantity` but for no dimension in particular.

    Returns
    -------
    (float, str) or None
        ``(10.0, "mm")`` for ``"10 mm"``, ``(0.3, "")`` for ``"0.3"``; None for text that is
        not a number followed by an optional unit.

    Examples
    --------
    >>> split_quantity("10 mm"), split_quantity("0.3"), split_quantity("granular")
    ((10.0, 'mm'), (0.3, ''), None)
    """
    match = _QUANTITY.match(text)
    return None if match is None else (float(match.group(1)), match.group(2))


def same_quantity(a: str, b: str, rtol: float = 1e-9) -> bool:
    """Whether two quantities written as text are equal to ``rtol``: ``"10mm"`` and
    ``"0.01 m"`` are; a bare number equals only a bare number, and a length never an angle."""
    qa, qb = split_quantity(a), split_quantity(b)
    if qa is None or qb is None:
        return False
    if qa[1] == qb[1]:
        return math.isclose(qa[0], qb[0], rel_tol=rtol)
    for dimension, units in UNITS.items():
        if qa[1] in units and qb[1] in units:
            return math.isclose(_scale(*qa, dimension), _scale(*qb, dimension), rel_tol=rtol)
    return False


def _number_text(x: float) -> str:
    """Shortest text that reads back as exactly ``x``: ``100``, ``12.5``, ``1e+05``."""
    if x == 0.0:
        return "0"
    if 1e-4 <= abs(x) < 1e5:
        text = repr(float(x))
        return text[:-2] if text.endswith(".0") else text
    for digits in range(1, 18):
        text = f"{x:.{digits}g}"
        if float(text) == x:
            return text
    return repr(float(x))


# Units format_quantity may choose from, largest first; the canonical unit (the first of
# its row of UNITS) for the instrument dimensions.
_CANONICAL = {"length": "m", "time": "ns", "angle": "deg",
              **{d: next(iter(UNITS[d])) for d in DIMENSIONS[3:]}}
_DISPLAY = {"length": ("km", "m", "mm", "um", "nm"), "time": ("ns",), "angle": ("deg",),
            **{d: (_CANONICAL[d],) for d in DIMENSIONS[3:]}}


def canonical_unit(dimension: str) -> str:
    """The unit values of ``dimension`` are stored in: ``m``, ``ns``, ``deg``, ``J`` ..."""
    _check_dimension(dimension)
    return _CANONICAL[dimension]


def format_quantity(value: float, dimension: str) -> str:
    """Write a canonical value as a readable string that :func:`parse_quantity` reads back.

    Lengths take the unit among km, m, mm, um, nm that gives the shortest text with a
    number between 1 and 10000 (``0.1`` -> ``"100 mm"``, ``1.064e-6`` -> ``"1064 nm"``);
    times are always written in ns, angles in deg and the instrument dimensions in their
    canonical unit.

    Parameters
    ----------
    value : float
        In the canonical unit of ``dimension`` (m, ns, deg, J, ...).
    dimension : str
        One of :data:`DIMENSIONS`.

    Returns
    -------
    str
        ``parse_quantity(format_quantity(v, d), d) == v`` exactly for every finite ``v``.

    Examples
    --------
    >>> format_quantity(1e-4, "length")
    '100 um'
    >>> format_quantity(3.0, "angle")
    '3 deg'
    >>> format_quantity(1e5, "time")
    '1e+05 ns'
    """
    _check_dimension(dimension)
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"cannot format the non-finite {dimension} {value!r}")
    candidates = []
    for unit in _DISPLAY[dimension]:
        power, _ = UNITS[dimension][unit]
        number = value / 10 ** power if power >= 0 else value * 10 ** -power
        if 1.0 <= abs(number) < 1e4:
            candidates.append(f"{_number_text(number)} {unit}")
    # Shortest first (a stable sort keeps the larger unit on ties); exact round trips only.
    for text in sorted(candidates, key=len):
        if parse_quantity(text, dimension) == value:
            return text
    return f"{_number_text(value)} {_CANONICAL[dimension]}"


def format_attribute(value: float, dimension: str) -> str:
    """A canonical value as a short readable text for output attributes (6 digits).

    Lengths, times and angles as :func:`format_quantity` (exact), except angles below
    0.01 deg, written in urad (``"1.74533 urad"``); the other dimensions as ``"0.05 J"``.
    Unlike :func:`format_quantity` the text is rounded: it describes, it is not read back.

    Parameters
    ----------
    value : float
        In the canonical unit of ``dimension``.
    dimension : str
        One of :data:`DIMENSIONS`.

    Returns
    -------
    str

    Examples
    --------
    >>> format_attribute(500e3, "length")
    '500 km'
    >>> format_attribute(2e-12, "current_noise")
    '2e-12 A/rtHz'
    """
    if dimension == "angle" and 0 < abs(value) < 0.01:
        return f"{math.radians(value) * 1e6:.6g} urad"
    if dimension in ("length", "time", "angle"):
        return format_quantity(value, dimension)
    return f"{value:.6g} {canonical_unit(dimension)}"
