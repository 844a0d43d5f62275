"""Checks of single values against a :class:`~warpe_cl.config.schema.Field`, the messages
they raise, and the YAML reader: shared by scenario presets and instrument presets.

Every check raises :class:`~warpe_cl.errors.ConfigError` with one line naming the value as
the user wrote it, what it counts, and what is allowed, with a did-you-mean hint where a
near miss is likely (a choice, a key, a unit)::

    simulation.photons: 1e+30 rays is not allowed; give a whole number of rays in [1, 2^53 = ...]
    instrument.detector.type: apdd is not allowed; give one of apd, photon_counting (did you mean apd?)

The caller adds the key (``where``) and the file (``ConfigError.with_source``).
"""
from __future__ import annotations

import difflib
import math
import os

import numpy as np
import yaml

from ..errors import ConfigError
from ..units import UNITS, UnitError, canonical_unit, format_attribute, parse_quantity, \
    unit_list

__all__ = ["check_scalar", "allowed", "show", "did_you_mean", "unknown_key", "read_yaml",
           "load_yaml", "is_quantity", "read_input_bytes", "MAX_FILE_BYTES", "MAX_DEPTH",
           "MAX_NODES", "MAX_TEXT"]

#: Largest input file read (a preset, an instrument preset, a material table), bytes: the
#: largest bundled preset is under 10 kB; a bigger file (or /dev/zero) is refused unread.
MAX_FILE_BYTES = 1 << 20
#: Deepest nesting of mappings and lists in a YAML document: a preset needs about 6 levels
#: (sweep values that are lists of layers); 1000 levels raised RecursionError.
MAX_DEPTH = 32
#: Most mappings, lists and values in a YAML document, aliases expanded (``&a`` / ``*a``
#: repeated so that a small file stands for billions of values is refused).
MAX_NODES = 100_000
#: Longest text value (``description``, ``name``, a path), characters: every output file
#: keeps it, twice (as an attribute and in the resolved configuration).
MAX_TEXT = 10_000

#: Valid values shown in messages when a quantity has no default to show.
EXAMPLES = {"length": "100 mm", "time": "12.5 ns", "angle": "12 deg", "energy": "50 mJ",
            "voltage": "1 V", "current": "10 nA", "current_noise": "2 pA/rtHz",
            "frequency": "33 MHz", "resistance": "50 kohm", "irradiance": "0.64 W/m2/nm",
            "distance": "0.387 AU"}


def is_quantity(kind: str) -> bool:
    """True for the kinds written as a number and a unit (a dimension of :mod:`warpe_cl.units`)."""
    return kind in UNITS


# --------------------------------------------------------------------------- messages

def _number_text(x) -> str:
    if isinstance(x, float) and x.is_integer() and abs(x) < 1e16:
        return str(int(x))
    return repr(x) if isinstance(x, float) else str(x)


#: The most characters of a text value an error message echoes.
SHOWN = 80


def show(value) -> str:
    """A value as a user would recognise it from their YAML, on one line."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "an empty value"
    if isinstance(value, str):
        if not value.strip():
            return '""'
        text = " ".join(value.split())   # one line; a file's text is not echoed whole
        return text if len(text) <= SHOWN else (f"{text[:SHOWN - 20]}... "
                                                f"({len(value):,} characters)")
    if isinstance(value, (int, float)):
        return _number_text(value)
    text = yaml.safe_dump(value, default_flow_style=True, allow_unicode=True, width=1e9)
    text = " ".join(text.split())
    return text if len(text) <= 60 else text[:57] + "..."


def _limit_text(x) -> str:
    """A limit of the table as written in messages; large powers of two also as 2^k."""
    if isinstance(x, int) and x >= 2 ** 20 and x & (x - 1) == 0:
        return f"2^{x.bit_length() - 1} = {x}"
    return _number_text(x)


def range_text(field) -> str:
    """The limits of ``field`` as ``in [0, 1]``, ``> 0 m``, ``<= 30 deg``; "" for none."""
    low, high = field.low, field.high
    unit = ""
    if is_quantity(field.kind) and any(b not in (None, 0) for b in (low, high)):
        unit = " " + canonical_unit(field.kind)
    if low is not None and high is not None:
        return (f"in {'(' if field.low_open else '['}{_limit_text(low)}, "
                f"{_limit_text(high)}{')' if field.high_open else ']'}{unit}")
    if low is not None:
        return f"{'>' if field.low_open else '>='} {_limit_text(low)}{unit}"
    if high is not None:
        return f"{'<' if field.high_open else '<='} {_limit_text(high)}{unit}"
    return ""


def with_unit(field, value) -> str:
    """``value`` as the user wrote it, followed by what it counts (``1e+30 rays``)."""
    return show(value) + (f" {field.unit}" if field.unit else "")


def _example(field) -> str:
    if field.example:
        return field.example
    if isinstance(field.default, str):
        return field.default
    if isinstance(field.default, (int, float)) and not isinstance(field.default, bool):
        return format_attribute(field.default, field.kind)   # a canonical default
    return EXAMPLES[field.kind]


def allowed(field) -> str:
    """What a valid value of ``field`` looks like, e.g. 'a number in [0, 1]'."""
    rng = range_text(field)
    rng = " " + rng if rng else ""
    words = ""
    if field.choices and field.kind in ("float", "int"):
        words = " or ".join(field.choices) + " or "
    if is_quantity(field.kind):
        article = "an" if field.kind in ("angle", "energy", "irradiance") else "a"
        noun = field.kind.replace("_", " ")
        return f'{article} {noun}{rng} with a unit, e.g. "{_example(field)}"'
    if field.kind == "float":
        return f"{words}a number{rng}"
    if field.kind == "int":
        if field.unit:
            return f"{words}a whole number of {field.unit}{rng}"
        return f"{words}an integer{rng}"
    if field.kind == "choice":
        return "one of " + ", ".join(field.choices)
    if field.kind == "bool":
        return "true or false"
    if field.kind == "str":
        return "a text string"
    if field.kind == "list":
        return "a list of mappings"
    return "a mapping"


def did_you_mean(word: str, candidates, cutoff: float = 0.6) -> str | None:
    """The candidate closest to ``word``, or None when none is close."""
    match = difflib.get_close_matches(word, list(candidates), n=1, cutoff=cutoff)
    return match[0] if match else None


def unknown_key(where: str, name: str, siblings: list, prefix: str, all_keys=(),
                listing: str | None = None) -> ConfigError:
    """'unknown key; did you mean ...?' for key ``name`` of the section at ``prefix``.

    Parameters
    ----------
    where : str
        The key as the message names it (``simulation.photon``).
    name : str
        The unknown name within its section (``photon``).
    siblings : list of str
        The names allowed in that section.
    prefix : str
        The section's dotted key (``""`` for the top level), put before a guess.
    all_keys : iterable of str
        Every dotted key of the table: the right name in the wrong section (``photons`` at
        the top level) is pointed to its place.
    listing : str, optional
        What to list when nothing is close (default: the siblings).
    """
    guess = did_you_mean(name, siblings)
    if guess is not None:
        full = f"{prefix}.{guess}" if prefix else guess
        return ConfigError(f"unknown key; did you mean {full}?", where)
    elsewhere = [k for k in all_keys if k.rsplit(".", 1)[-1] == name]
    if elsewhere:
        return ConfigError(f"unknown key here; did you mean {elsewhere[0].replace('[]', '[0]')}?",
                           where)
    listing = listing or "the keys allowed here are " + ", ".join(siblings)
    return ConfigError(f"unknown key; {listing}", where)


# --------------------------------------------------------------------------- scalars

def _number(field, value, where: str) -> float:
    """A finite float from a YAML number or a numeric string ("1e6")."""
    if isinstance(value, bool):
        raise ConfigError(f"{show(value)} is a boolean (YAML reads yes/no/on/off as "
                          f"booleans), not a number; give {allowed(field)}", where)
    if isinstance(value, (int, float, np.integer, np.floating)):
        x = value
    elif isinstance(value, str):
        try:
            x = float(value.strip().replace("_", ""))
        except ValueError:
            raise ConfigError(f"{show(value)} is not a number; give {allowed(field)}",
                              where) from None
    else:
        raise ConfigError(f"{show(value)} is not a number; give {allowed(field)}", where)
    if not math.isfinite(x):
        raise ConfigError(f"{show(value)} is not a finite number; give {allowed(field)}",
                          where)
    return x


def _integer(field, value, where: str) -> int:
    """An int from 3, 1e6, 1.0e6 or "1e6"; refuses 2.5."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return int(value)
    if isinstance(value, str) and value.strip().lstrip("+-").isdigit():
        return int(value)
    x = _number(field, value, where)
    if not float(x).is_integer():
        raise ConfigError(f"{with_unit(field, value)} is not a whole number; give "
                          f"{allowed(field)}", where)
    return int(x)


def in_range(field, x) -> bool:
    """True when ``x`` (canonical unit) lies within the limits of ``field``."""
    if field.low is not None and (x < field.low or (field.low_open and x == field.low)):
        return False
    if field.high is not None and (x > field.high or (field.high_open and x == field.high)):
        return False
    return True


def _choice(field, value, where: str) -> str:
    if isinstance(value, str) and value.strip().lower() in field.choices:
        return value.strip().lower()
    guess = did_you_mean(value.lower(), field.choices) if isinstance(value, str) else None
    hint = f" (did you mean {guess}?)" if guess else ""
    raise ConfigError(f"{show(value)} is not allowed; give {allowed(field)}{hint}", where)


def check_scalar(field, value, where: str):
    """Validate one scalar value of ``field`` and return it in the canonical unit.

    Parameters
    ----------
    field : Field
        Its kind is a dimension of :mod:`warpe_cl.units` (a string with a unit), or
        ``"float"``, ``"int"``, ``"bool"``, ``"str"``, ``"choice"``.
    value : object
        As written in the YAML or on the command line (``"100 mm"``, ``1e6``, ``"1e6"``).
    where : str
        The key named by the error.

    Returns
    -------
    object
        A float in the canonical unit (quantities, ``"float"``), an int, a bool, a string,
        a lower-case choice, or one of the words ``field.choices`` of a number (``auto``).

    Raises
    ------
    ConfigError
        One line: the value, what it counts and what is allowed, with a hint where one
        helps (the units of a quantity, the closest choice).
    """
    kind = field.kind
    if is_quantity(kind):
        try:
            x = parse_quantity(value, kind)
        except UnitError as exc:
            raise ConfigError(f"{exc.problem}; give {allowed(field)} "
                              f"(units: {unit_list(kind)})", where) from None
    elif kind in ("float", "int") and field.choices and isinstance(value, str) \
            and value.strip().lower() in field.choices:
        return value.strip().lower()
    elif kind == "float":
        x = float(_number(field, value, where))  # plain float, also from numpy
    elif kind == "int":
        x = _integer(field, value, where)
    elif kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{show(value)} is not allowed; give true or false", where)
        return value
    elif kind == "str":
        if not isinstance(value, str) or (not value.strip() and field.default != ""):
            raise ConfigError(f"{show(value)} is not allowed; give {allowed(field)}"
                              + (' (quote it: "...")' if isinstance(value, (int, float))
                                 else ""), where)
        if len(value) > MAX_TEXT:
            raise ConfigError(f"a text of {len(value)} characters is not allowed; give at "
                              f"most {MAX_TEXT} characters", where)
        return value
    elif kind == "choice":
        return _choice(field, value, where)
    else:  # pragma: no cover - table error
        raise TypeError(f"{field.key}: {kind} is not a scalar kind")
    if not in_range(field, x):
        raise ConfigError(f"{with_unit(field, value)} is not allowed; give {allowed(field)}",
                          where)
    return x


# --------------------------------------------------------------------------- YAML reading

class _Loader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys instead of silently keeping the last."""


def _construct_mapping(loader, node, deep=False):
    loader.flatten_mapping(node)
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            duplicate = key in seen
            seen.add(key)
        except TypeError:  # unhashable key: let SafeLoader report it
            break
        if duplicate:
            raise yaml.constructor.ConstructorError(
                None, None, f'the key "{key}" is given twice', key_node.start_mark)
    return loader.construct_mapping(node, deep=deep)


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def load_yaml(text: str, source: str | None = None):
    """The YAML document in ``text``, read safely; a duplicate key is an error.

    Raises
    ------
    ConfigError
        ``not valid YAML (line L, column C: the key "shots" is given twice)`` and the like,
        naming ``source``.
    """
    try:
        document = yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        raise ConfigError(f"not valid YAML ({where}{problem})", source=source) from None
    except RecursionError:
        raise ConfigError(f"mappings and lists nested too deeply; at most {MAX_DEPTH} levels "
                          "are allowed", source=source) from None
    _check_shape(document, source)
    return document


def _check_shape(document, source, key=None) -> None:
    """Refuse a document nested more than :data:`MAX_DEPTH` levels, or holding more than
    :data:`MAX_NODES` values once its aliases are expanded.

    Iterative and memoised on the identity of each container (an alias is the same object
    each time it appears), so that neither a deep nor an alias-bombed document costs more
    than one visit per object.
    """
    depth, size = {}, {}            # id -> levels below it, values in it (expanded)
    stack = [(document, False)]
    on_path = set()
    while stack:
        node, done = stack.pop()
        if not isinstance(node, (dict, list)):
            continue
        ident = id(node)
        if done:
            on_path.discard(ident)
            items = list(node.keys()) + list(node.values()) if isinstance(node, dict) else node
            below = [c for c in items if isinstance(c, (dict, list))]
            depth[ident] = 1 + max((depth[id(c)] for c in below), default=0)
            size[ident] = 1 + len(items) - len(below) + sum(size[id(c)] for c in below)
            if depth[ident] > MAX_DEPTH:
                raise ConfigError(f"mappings and lists nested {depth[ident]} levels deep or "
                                  f"more; at most {MAX_DEPTH} levels are allowed",
                                  key=key, source=source)
            if size[ident] > MAX_NODES:
                raise ConfigError(f"more than {MAX_NODES} values once its aliases (*name) "
                                  f"are expanded; at most {MAX_NODES} are allowed",
                                  key=key, source=source)
            continue
        if ident in depth:
            continue
        if ident in on_path:          # a recursive alias: a list that holds itself
            raise ConfigError("a mapping or list that contains itself (a recursive alias) is "
                              "not allowed", key=key, source=source)
        on_path.add(ident)
        stack.append((node, True))
        items = list(node.keys()) + list(node.values()) if isinstance(node, dict) else node
        stack.extend((c, False) for c in items if isinstance(c, (dict, list)))


def read_input_bytes(path, what: str = "a preset") -> bytes:
    """The bytes of the input file ``path``: a regular file of at most
    :data:`MAX_FILE_BYTES` bytes (a device such as /dev/zero, a pipe or a folder is refused
    before any byte is read).

    Parameters
    ----------
    path : str or os.PathLike
    what : str
        What the file should be, for messages (``"a preset"``, ``"a material table"``).

    Raises
    ------
    ConfigError
        No such file, not a regular file, larger than the cap, or unreadable; one line
        naming the file.
    """
    import stat
    path = os.fspath(path)
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise ConfigError("no such file", source=path) from None
    except OSError as exc:
        raise ConfigError(f"cannot be read ({exc.strerror})", source=path) from None
    if stat.S_ISDIR(info.st_mode):
        raise ConfigError(f"is a folder, not {what} file", source=path)
    if not stat.S_ISREG(info.st_mode):
        raise ConfigError(f"is not a regular file (a device, a pipe or a socket); {what} is "
                          "a regular file", source=path)
    limit = f"{MAX_FILE_BYTES} bytes (1 MiB)"
    if info.st_size > MAX_FILE_BYTES:
        raise ConfigError(f"{info.st_size} bytes is too large for {what}; at most {limit} "
                          "are read", source=path)
    try:
        with open(path, "rb") as stream:
            data = stream.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"cannot be read ({exc.strerror})", source=path) from None
    if len(data) > MAX_FILE_BYTES:                # grew since the stat
        raise ConfigError(f"more than {limit} is too large for {what}", source=path)
    return data


def read_yaml(path, what: str = "a preset", empty: str | None = None):
    """The YAML document in the file ``path``; file-level problems become ConfigErrors.

    Parameters
    ----------
    path : str or os.PathLike
    what : str
        What the file should be, for messages (``"a preset"``, ``"an instrument preset"``).
    empty : str, optional
        The end of the message for an empty file (default: none, the document is None).

    Raises
    ------
    ConfigError
        No such file, a folder, not a regular file, larger than :data:`MAX_FILE_BYTES`,
        not UTF-8, unreadable, not valid YAML (a duplicate key included), nested deeper than
        :data:`MAX_DEPTH` or larger than :data:`MAX_NODES` values, or empty when ``empty``
        is given; one line naming the file.
    """
    path = os.fspath(path)
    data = read_input_bytes(path, what)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(f"not UTF-8 text; {what} is a YAML text file", source=path) from None
    text = text.replace("\r\n", "\n").replace("\r", "\n")   # as open() in text mode
    document = load_yaml(text, path)
    if document is None and empty is not None:
        raise ConfigError(f"the file is empty; {empty}", source=path)
    return document
