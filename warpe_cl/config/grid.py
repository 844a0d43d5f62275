"""Sweep grids: the outer product of a preset's ``sweep:`` block, point by point.

:func:`~warpe_cl.config.keys.expand_points` is the one expander: :meth:`Config.sweep_points
<warpe_cl.config.Config.sweep_points>` (``warpe-cl run``, :func:`warpe_cl.simulate`) stops at
the first invalid point, :func:`load_grid` (``warpe-cl sweep``) keeps each point's error
beside the valid ones; both build every point the same way, so a point gives the same
scenario (and the same bits) whichever way it is computed.
"""
from __future__ import annotations

import copy
import json
from dataclasses import dataclass

import yaml

from ..errors import ConfigError
from .check import sweep_field
from .keys import apply_overrides, expand_points, parse_overrides, schema_key, split_key
from .preset import Config, read_source
from .schema import FIELDS, SCALAR_KINDS, SWEEPABLE
from .validate import allowed, check_scalar, show

__all__ = ["Grid", "load_grid", "expand_points", "MAX_GRID_POINTS"]

#: The most points a sweep grid may have (the product of its axes' lengths, checked before the
#: outer product is built: 1e8 points ran out of memory after minutes).
MAX_GRID_POINTS = 1_000_000


def _check_axes(sweep: dict) -> None:
    """Refuse a value given twice on one axis (after unit resolution: ``"10 mm"`` and
    ``"1 cm"``), and a grid of more than :data:`MAX_GRID_POINTS` points.

    A value that is invalid for its key is left to its point's own error.

    Raises
    ------
    ConfigError
        Naming the key and the two values, or the axes and their product.
    """
    total = 1
    for key, values in sweep.items():
        target = sweep_field(key, f"sweep.{key}")
        seen = {}
        for value in values:
            try:
                if target.kind in SCALAR_KINDS:
                    resolved = check_scalar(target, value, f"sweep.{key}")
                else:
                    resolved = json.dumps(value, sort_keys=True, default=str)
            except ConfigError:
                continue
            marker = (type(resolved).__name__ if isinstance(resolved, str) else "",
                      resolved)
            if marker in seen:
                raise ConfigError(f"{show(seen[marker])} and {show(value)} are the same value; "
                                  f"give each value of a swept key once", f"sweep.{key}")
            seen[marker] = value
        total *= len(values)
    if total > MAX_GRID_POINTS:
        sizes = " x ".join(str(len(v)) for v in sweep.values())
        raise ConfigError(f"{sizes} = {total} points is not allowed; a sweep grid has at most "
                          f"{MAX_GRID_POINTS} points (split it into several sweeps)", "sweep")


@dataclass
class Grid:
    """A preset's sweep grid with every point validated on its own (``warpe-cl sweep``).

    Attributes
    ----------
    source : str
        The preset's path as given, or ``"<dict>"``.
    raw : dict
        The preset as written, overrides applied and list overrides turned into sweep axes.
    keys : list of str
        The swept keys, in the order of the outer product (empty without a sweep).
    points : list of (dict, Config or ConfigError)
        For each point of the outer product (the order of :meth:`Config.sweep_points`), the
        swept values as written and that point's validated configuration, or the one-line
        error that rejects it.
    """

    source: str
    raw: dict
    keys: list
    points: list

    def to_yaml(self) -> str:
        """The resolved preset (with its sweep block) when every point is valid, else the
        preset as written (overrides applied)."""
        try:
            return Config(copy.deepcopy(self.raw), self.source).to_yaml()
        except ConfigError:
            text = yaml.safe_dump(self.raw, sort_keys=False, allow_unicode=True, width=100)
            return f"# warpe-cl preset {self.source} as written (a sweep point is invalid)\n{text}"


def load_grid(source, overrides=None) -> Grid:
    """Load a preset as a grid of independent points, for a resumable sweep.

    Unlike :func:`load_preset`, a value that rejects one point (a compacity of 1.2) does not
    reject the preset: that point carries its :class:`ConfigError`, the others stand. Each
    valid point's Config is built exactly as :meth:`Config.sweep_points` builds it, so it
    gives the same scenario (and the same bits) as ``warpe-cl run``.

    Parameters
    ----------
    source : str, os.PathLike or dict
        A YAML preset or a dict of the same shape.
    overrides : dict or list of str, optional
        As for :func:`load_preset`. An override whose value is a list, on a key that a sweep
        may name and that is not itself a list (``medium.thickness=["1 mm", "10 mm"]``),
        becomes a sweep axis: it replaces a swept key of the same name, or is added after
        the preset's own.

    Raises
    ------
    ConfigError
        For what no point can survive: an unreadable file, a malformed sweep block, an
        unknown sweep key, a value given twice on one axis (after unit resolution), more
        than :data:`MAX_GRID_POINTS` points; or, without a sweep, the single point's error.
    """
    name, raw, base_dir, name_default = read_source(source)
    if not isinstance(raw, dict):
        Config(raw, name, name_default=name_default, base_dir=base_dir)  # raises its message
    try:
        axes = {}
        plain = {}
        for key, value in parse_overrides(overrides).items():
            skey = schema_key(split_key(key))
            if (isinstance(value, list) and skey in SWEEPABLE
                    and (skey == "medium" or FIELDS[skey].kind in SCALAR_KINDS)):
                axes[key] = value
            else:
                plain[key] = value
        apply_overrides(raw, plain)
        if axes:
            sweep = raw.get("sweep") if isinstance(raw.get("sweep"), dict) else {}
            raw["sweep"] = {**{k: v for k, v in sweep.items() if k not in axes}, **axes}
        sweep = raw.get("sweep") or {}
        if not isinstance(sweep, dict):
            raise ConfigError(f"{show(sweep)} is not a mapping; give KEY: [VALUE, ...], "
                              f'e.g. medium.thickness: ["1 mm", "10 mm"]', "sweep")
        for key, values in sweep.items():
            target = sweep_field(key, f"sweep.{key}")
            if not isinstance(values, list) or not values:
                raise ConfigError(f"{show(values)} is not allowed; give a non-empty list of "
                                  f"values, each {allowed(target)}", f"sweep.{key}")
        _check_axes(sweep)
    except ConfigError as exc:
        raise exc.with_source(name) from None
    points = expand_points(raw, name, lambda point_raw: Config(
        point_raw, name, name_default=name_default, base_dir=base_dir), keep_errors=True)
    return Grid(name, raw, list(sweep), points)
