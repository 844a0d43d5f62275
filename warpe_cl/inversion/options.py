"""What ``warpe-cl invert`` checks before it reads a database's scenario files
(docs/inversion.md §1): the database is complete, and every ``--free`` and ``--fix`` names a
swept key with a value in its unit and range.

A database folder's manifests say its swept keys, their values at every grid point and which
scenarios are finished (:func:`header`): reading them takes milliseconds, less than reading the
database (its store, or every scenario file of a folder without one: seconds for a large
sweep), so a typo in an option is refused at once.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config.instrument_fields import field_for
from ..database import finished_scenarios, database_folder
from ..dataset import sweep_coordinates
from ..errors import ConfigError
from ..units import DIMENSIONS, UnitError, canonical_unit, format_quantity, parse_quantity, \
    unit_list
from .space import swept_keys

#: Nuisances that ``--fix`` may hold: name -> (dimension of :mod:`warpe_cl.units` or None for
#: a plain number, unit of the stored value).
NUISANCES = {"amplitude": (None, "1"), "pulse_fwhm": ("time", "ns"),
             "broadening": (None, "ns2")}
#: Missing scenario indices named in the refusal of an incomplete database.
SHOWN_MISSING = 8


@dataclass
class Header:
    """What a database says about its grid, read without its scenario files.

    Attributes
    ----------
    source : str
        Its name, for messages.
    keys : list of str
        The swept dotted keys.
    values : dict
        Key -> the swept values at every grid point: floats in the canonical unit (m, ns,
        deg, 1) for numeric keys, text otherwise.
    units : dict
        Key -> unit of the values (``m``, ``1`` ...; None for text).
    total : int or None
        Scenarios of the grid (None: not recorded, a complete sweep file).
    finished : list of int
        Indices of the finished scenarios.
    failed : dict
        Index -> error of failed scenarios.
    folder : Path or None
        The database folder (for the ``--resume`` hint).
    """
    source: str
    keys: list
    values: dict
    units: dict
    total: int | None = None
    finished: list = field(default_factory=list)
    failed: dict = field(default_factory=dict)
    folder: Path | None = None

    def numeric(self, key: str) -> bool:
        """Whether ``key`` is swept over numbers (an axis of the inversion)."""
        return self.units.get(key) is not None


def header(database, source: str | None = None) -> Header | None:
    """The :class:`Header` of a database folder (from its manifests only), a sweep file or a
    Dataset.

    Parameters
    ----------
    database : path or xarray.Dataset
        A ``warpe-cl sweep`` folder (or ``X.nc`` whose folder is ``X.sweep``), a sweep file,
        or a Dataset (:func:`warpe_cl.open_database`).
    source : str, optional
        Name for messages (default: the path).

    Returns
    -------
    Header or None
        None for a path that is not a folder (a sweep file, read whole by the caller; or a
        missing path, which :func:`warpe_cl.database.load_result` refuses).

    Raises
    ------
    ConfigError
        A folder without a valid manifest (:func:`warpe_cl.database.open_database`'s rules).
    """
    if hasattr(database, "dims"):
        return dataset_header(database, source or "<database>")
    path = Path(database)
    folder = database_folder(path)[0] if path.suffix == ".nc" and not path.is_file() else path
    if not folder.is_dir():
        return None          # a sweep file: read whole (one file), then :func:`dataset_header`
    grid, _, failed, found = finished_scenarios([folder])      # the rule of open_database
    rows = grid["scenarios"]
    keys = [str(k) for k in grid["keys"]]
    values, units = {}, {}
    for key in keys:
        coords = sweep_coordinates(key, [row["point"].get(key) for row in rows])
        _, v, attrs = coords[key]
        numeric = np.issubdtype(np.asarray(v).dtype, np.number)
        values[key] = np.asarray(v, float) if numeric else np.asarray(v).astype(str)
        units[key] = attrs.get("units", "1") if numeric else None
    return Header(source or str(database), keys, values, units, len(rows), sorted(found),
                  {int(i): e for i, e in failed.items() if i not in found}, folder)


def dataset_header(db, source: str) -> Header:
    """The :class:`Header` of a loaded database or sweep file (its ``sweep_scenarios_total``
    and ``sweep_failed`` attributes, where :func:`warpe_cl.open_database` set them)."""
    if "scenario" not in db.dims:
        raise ConfigError("holds one scenario, not a sweep: give a `warpe-cl sweep` "
                          "database (a folder) or a sweep file", key=source)
    keys = swept_keys(db)
    values, units = {}, {}
    for key in keys:
        v = db[key].values
        numeric = np.issubdtype(v.dtype, np.number)
        values[key] = np.asarray(v, float) if numeric else v.astype(str)
        units[key] = db[key].attrs.get("units", "1") if numeric else None
    total = db.attrs.get("sweep_scenarios_total")
    finished = ([int(i) for i in np.asarray(db["scenario"].values)]
                if "scenario" in db.coords else list(range(db.sizes["scenario"])))
    try:
        failed = {int(k): e for k, e in json.loads(db.attrs.get("sweep_failed", "{}")).items()}
    except (TypeError, ValueError):
        failed = {}
    return Header(source, keys, values, units, None if total is None else int(total),
                  finished, failed, None)


def check_complete(h: Header) -> None:
    """Refuse a database whose grid is not complete (a sweep stopped after 3 of 45 scenarios
    once inverted with exit 0 over a grid of one grain size).

    Raises
    ------
    ConfigError
        One line: how many scenarios are missing, the first indices, how many failed, and the
        ``warpe-cl sweep PRESET --out DB --resume`` that finishes them.
    """
    if h.total is None or len(h.finished) >= h.total:
        return
    missing = sorted(set(range(h.total)) - set(h.finished))
    shown = ", ".join(map(str, missing[:SHOWN_MISSING])) + \
        (", ..." if len(missing) > SHOWN_MISSING else "")
    failed = sum(1 for i in missing if i in h.failed)
    out = h.folder if h.folder is not None else "DB"
    raise ConfigError(f"an incomplete database: {len(missing)} of its {h.total} scenarios are "
                      f"missing (indices {shown})"
                      + (f", {failed} of them failed" if failed else "")
                      + f"; the inversion needs the whole grid: run `warpe-cl sweep PRESET "
                        f"--out {out} --resume` to finish it", key=h.source)


def dimension_of(key: str, units: str | None) -> str | None:
    """The dimension (:data:`warpe_cl.units.DIMENSIONS`) a swept key's value is written in,
    from the configuration table, else from the database's unit; None for a plain number."""
    f = field_for(key)
    if f is not None and f.kind in DIMENSIONS:
        return f.kind
    for dim in ("length", "time", "angle"):
        if units == canonical_unit(dim):
            return dim
    return None


def parse_value(key: str, value, dimension: str | None, allowed: str) -> float:
    """A ``--fix`` value as a float in the canonical unit of ``dimension``, by the unit rule
    of ``run --set`` (:func:`warpe_cl.units.parse_quantity`): a quantity needs its unit, a
    bare number is refused; a plain number (``dimension`` None) is a number.

    Parameters
    ----------
    key : str
        The key, for messages.
    value : str, float
        As given (``"500 mm"``, ``0.3``).
    dimension : str or None
        ``length``, ``time``, ... or None.
    allowed : str
        What is allowed, for the message (``within the database's range [0.5, 2] m``).

    Raises
    ------
    ConfigError
        One line naming the key, the value, the unit wanted and what is allowed.
    """
    if dimension is not None:
        try:
            return parse_quantity(value, dimension)
        except UnitError as exc:
            raise ConfigError(f"{key}={value}: {exc.problem}; give a {dimension} with a "
                              f"unit ({unit_list(dimension)}) {allowed}", key="--fix") from None
    try:
        if isinstance(value, bool):
            raise ValueError
        x = float(value)
        if not np.isfinite(x):
            raise ValueError
        return x
    except (TypeError, ValueError):
        raise ConfigError(f"{key}={value}: not a number; give a plain number {allowed}",
                          key="--fix") from None


def show(value: float, dimension: str | None, units: str | None) -> str:
    """A value with its unit, for the report (``500 mm``, ``0.3``, ``6.5 ns``)."""
    if dimension is not None:
        return format_quantity(value, dimension)
    return f"{value:.6g}" + ("" if units in (None, "", "1") else f" {units}")


def check_options(h: Header, free, fix: dict, nuisance: dict) -> tuple[dict, dict]:
    """Check ``--free`` and ``--fix`` against the database's swept keys, units and ranges.

    Parameters
    ----------
    h : Header
    free : list of str or None
        Keys to report.
    fix : dict
        Swept key -> value as given.
    nuisance : dict
        Nuisance name (:data:`NUISANCES`) -> value as given.

    Returns
    -------
    (dict, dict)
        Swept key -> value (a float in the database's unit, text for a non-numeric key), and
        every fixed key or nuisance -> the value as echoed with its unit (``"500 mm"``).

    Raises
    ------
    ConfigError
        One line: an unknown key, a value without its unit or outside the range, a
        non-numeric key not fixed or fixed to a value it does not take, a ``--free`` key that
        is not free, every key fixed.
    """
    parsed, echoed = {}, {}
    for name, value in nuisance.items():
        dim, unit = NUISANCES[name]
        x = parse_value(name, value, dim, f"(the nuisance {name}, in {unit})")
        if name in ("amplitude", "pulse_fwhm") and not x > 0:
            raise ConfigError(f"{name}={value}: not allowed; give a value > 0", key="--fix")
        echoed[name] = show(x, dim, unit)
    unknown = [k for k in fix if k not in h.keys]
    if unknown:
        raise ConfigError(f"--fix {unknown[0]}: not a swept key of the database (swept: "
                          f"{', '.join(h.keys) or 'none'}; nuisances: {', '.join(NUISANCES)})",
                          key=h.source)
    for key in h.keys:
        values = h.values[key]
        if not h.numeric(key):
            choices = sorted(set(map(str, values)))
            if key not in fix:
                raise ConfigError(f"{key} is swept over non-numeric values ({', '.join(choices)})"
                                  f"; choose one with --fix {key}=VALUE", key=h.source)
            if str(fix[key]) not in choices:
                raise ConfigError(f"--fix {key}={fix[key]}: not one of its values "
                                  f"({', '.join(choices)})", key=h.source)
            parsed[key] = echoed[key] = str(fix[key])
            continue
        if key not in fix:
            continue
        dim, unit = dimension_of(key, h.units[key]), h.units[key]
        lo, hi = float(np.min(values)), float(np.max(values))
        span = f"[{show(lo, dim, unit)}, {show(hi, dim, unit)}]"
        x = parse_value(key, fix[key], dim, f"within the database's range {span}")
        tol = 1e-9 * max(abs(lo), abs(hi))
        if not lo - tol <= x <= hi + tol:
            raise ConfigError(f"--fix {key}={fix[key]}: {show(x, dim, unit)} is outside the "
                              f"database's range {span}", key=h.source)
        parsed[key] = x
        echoed[key] = show(x, dim, unit)
    keys = [k for k in h.keys if h.numeric(k) and k not in fix]
    bad = [k for k in (free or []) if k not in keys]
    if bad:
        raise ConfigError(f"--free {bad[0]}: not a free swept key of the database (free: "
                          f"{', '.join(keys) or 'none'})", key=h.source)
    if not keys:
        raise ConfigError("every swept key is fixed: nothing to invert", key="--fix")
    return parsed, echoed
