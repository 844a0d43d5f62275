"""Dotted keys: ``medium.inclusions[0].grain_size`` read, written and looked up in a nested
preset, ``--set KEY=VALUE`` overrides parsed and applied, and the points of a sweep block
expanded (:func:`expand_points`, which needs no Config: the caller builds each point's)."""
from __future__ import annotations

import copy
import itertools
import re

import yaml

from ..errors import ConfigError
from .validate import MAX_DEPTH, _check_shape, show

__all__ = ["split_key", "display_key", "schema_key", "set_path", "get_path",
           "parse_overrides", "apply_overrides", "expand_points"]

_INDEX = re.compile(r"\[(\d+)\]")


def split_key(key: str) -> list:
    """``"medium.inclusions[0].grain_size"`` -> ``["medium", "inclusions", 0, "grain_size"]``.

    ``medium.inclusions.0.grain_size`` is read the same way. After ``sweep`` the rest of the
    key is one name (the swept key).
    """
    key = key.strip()
    if key.startswith("sweep.") and len(key) > len("sweep."):
        return ["sweep", key[len("sweep."):]]
    parts = []
    for part in _INDEX.sub(r".\1", key).split("."):
        parts.append(int(part) if part.isdigit() else part)
    return parts


def display_key(parts) -> str:
    """The inverse of :func:`split_key`, list indices written ``[i]``."""
    text = ""
    for p in parts:
        if isinstance(p, int):
            text += f"[{p}]"
        else:
            text += f".{p}" if text else str(p)
    return text


def schema_key(parts) -> str:
    """Table key of a concrete path: indices become ``[]``, material names ``*``."""
    text = ""
    for i, p in enumerate(parts):
        if isinstance(p, int):
            text += "[]"
        else:
            name = "*" if (i == 1 and parts[0] == "materials") else str(p)
            text += f".{name}" if text else name
    return text


def set_path(tree: dict, key: str, value) -> None:
    """Set dotted ``key`` in the nested ``tree``, creating mappings on the way."""
    parts = split_key(key)
    if not parts or any(p == "" for p in parts):
        raise ConfigError("not a valid dotted key; write e.g. medium.thickness", key)
    node = tree
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        where = display_key(parts[:depth + 1])
        if isinstance(part, int):
            if not isinstance(node, list):
                raise ConfigError(f"{display_key(parts[:depth])} is not a list", where)
            if part >= len(node):
                raise ConfigError(f"no such item: the list has {len(node)} item(s)", where)
        elif not isinstance(node, dict):
            raise ConfigError(f"{display_key(parts[:depth])} is not a mapping", where)
        if last:
            node[part] = value
        else:
            child = node[part] if (isinstance(node, list) or part in node) else None
            if child is None:
                child = {}
                node[part] = child
            node = child


def get_path(tree, parts):
    """The value at ``parts`` in ``tree``, or raise KeyError."""
    node = tree
    for part in parts:
        if isinstance(part, int):
            if not isinstance(node, list) or part >= len(node):
                raise KeyError(part)
        elif not isinstance(node, dict) or part not in node:
            raise KeyError(part)
        node = node[part]
    return node


def parse_overrides(overrides) -> dict:
    """``{key: value}`` from a dict or from ``["KEY=VALUE", ...]`` strings."""
    if overrides is None:
        return {}
    if isinstance(overrides, dict):
        for key in overrides:
            if not isinstance(key, str):
                raise ConfigError("override keys must be dotted strings such as "
                                  "medium.thickness", show(key))
        return dict(overrides)
    if isinstance(overrides, str):
        overrides = [overrides]
    out = {}
    for item in overrides:
        if not isinstance(item, str) or "=" not in item:
            raise ConfigError('an override is written KEY=VALUE, e.g. '
                              'medium.thickness="100 mm"', show(item))
        key, text = item.split("=", 1)
        key = key.strip()
        try:
            value = yaml.safe_load(text) if text.strip() else None
        except yaml.YAMLError:
            value = text.strip()  # e.g. "a: b: c": take the text as it is
        except RecursionError:
            raise ConfigError(f"the value is nested too deeply; at most {MAX_DEPTH} levels of "
                              "mappings and lists are allowed", key) from None
        _check_shape(value, None, key)
        out[key] = value
    return out



def apply_overrides(raw: dict, overrides: dict) -> None:
    """Set every dotted key of ``overrides`` in ``raw`` (in place)."""
    for key, value in overrides.items():
        set_path(raw, key, value)


def expand_points(raw: dict, source: str, build, keep_errors: bool) -> list:
    """Every point of the ``sweep`` block of ``raw``, outer product in the order keys appear.

    Parameters
    ----------
    raw : dict
        A preset as written (overrides applied); its ``sweep`` block (absent or empty: one
        point) maps dotted keys to lists of values.
    source : str
        The preset's name, for messages.
    build : callable
        ``build(point_raw) -> Config``: the point's preset (``raw`` without its sweep block,
        the point's values set) validated.
    keep_errors : bool
        False: the first invalid point raises. True: an invalid point carries its error in
        place of its Config (a preset without a sweep still raises).

    Returns
    -------
    list of (dict, Config or ConfigError)
        The swept values as written and the point's configuration (or its one-line error,
        ending in ``(in the sweep point KEY=VALUE, ...)``).
    """
    sweep = raw.get("sweep") or {}
    base = {k: v for k, v in raw.items() if k != "sweep"}
    keys = list(sweep)
    points = []
    for combo in itertools.product(*(sweep[k] for k in keys)):
        point = dict(zip(keys, combo))
        point_raw = copy.deepcopy(base)
        try:
            apply_overrides(point_raw, copy.deepcopy(point))
            cfg = build(point_raw)
        except ConfigError as exc:
            if not keys:
                raise
            where = ", ".join(f"{k}={show(v)}" for k, v in point.items())
            cfg = ConfigError(f"{exc.message} (in the sweep point {where})", exc.key, source)
            if not keep_errors:
                raise cfg from None
        points.append((point, cfg))
    return points
