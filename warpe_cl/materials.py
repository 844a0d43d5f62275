"""Optical constants of the end-members: built-ins at 1064 nm, and user materials.

A preset may add or override materials under ``materials:``, either as constants at the run's
wavelength (``{n, k}``) or as a CSV table over wavelength (``{table: FILE}``, columns
``wavelength_nm, n, k``), interpolated linearly. Names are case-insensitive.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from .errors import ConfigError

#: Built-in end-members at 1064 nm (paper Table 2; docs/physics.md §3.1): name -> (n, k)
BUILTIN_1064NM = {
    "void": (1.0, 0.0),
    "H2O": (1.30042, 1.27200e-6),   # water ice, Schmitt et al. 1998
    "CO2": (1.4026, 8.47e-10),      # CO2 ice, Schmitt et al. 1998
    "S": (1.92, 9.5e-6),            # sulfur, Sasson et al. 1985
}
BUILTIN_WAVELENGTH = 1064e-9       # m
_WAVELENGTH_TOLERANCE = 1e-3       # relative: "1064 nm" and "1.064 um" are the same


def _read_table(path: Path, name: str, source):
    try:
        with open(path, newline="") as fh:
            rows = [r for r in csv.reader(fh) if r and not r[0].lstrip().startswith("#")]
    except OSError as err:
        raise ConfigError(f"cannot read {path} ({err.strerror})", key=f"materials.{name}.table",
                          source=source)
    header = [c.strip().lower() for c in rows[0]] if rows else []
    if header[:3] != ["wavelength_nm", "n", "k"]:
        raise ConfigError(f"{path}: the first row must be the header wavelength_nm, n, k",
                          key=f"materials.{name}.table", source=source)
    try:
        data = np.array([[float(c) for c in r[:3]] for r in rows[1:]], dtype=float)
    except ValueError as err:
        raise ConfigError(f"{path}: a value is not a number ({err})",
                          key=f"materials.{name}.table", source=source)
    if data.shape[0] < 1 or np.any(np.diff(data[:, 0]) <= 0) or np.any(data[:, 1] <= 0) \
            or np.any(data[:, 2] < 0):
        raise ConfigError(f"{path}: needs rows with increasing wavelength_nm, n > 0 and k >= 0",
                          key=f"materials.{name}.table", source=source)
    return data


def optical_constants(cfg) -> dict:
    """Every material the configuration can name, at its wavelength: ``{NAME: (n, k)}`` with
    upper-case keys.

    Built-ins apply at 1064 nm only; at another wavelength a material must come from the
    preset's ``materials:`` block (a constant or a table covering the wavelength).
    """
    wavelength = cfg.get("wavelength")
    table = {}
    if abs(wavelength / BUILTIN_WAVELENGTH - 1) < _WAVELENGTH_TOLERANCE:
        table.update({k.upper(): v for k, v in BUILTIN_1064NM.items()})
    else:
        table["VOID"] = (1.0, 0.0)
    for name, spec in (cfg.get("materials") or {}).items():
        if spec.get("table"):
            data = _read_table(Path(spec["table"]), name, cfg.source)
            lam_nm = wavelength * 1e9
            lo, hi = data[0, 0], data[-1, 0]
            if not lo <= lam_nm <= hi:
                raise ConfigError(f"wavelength {lam_nm:g} nm is outside the table's range "
                                  f"{lo:g}-{hi:g} nm", key=f"materials.{name}.table",
                                  source=cfg.source)
            n = float(np.interp(lam_nm, data[:, 0], data[:, 1]))
            k = float(np.interp(lam_nm, data[:, 0], data[:, 2]))
            table[name.upper()] = (n, k)
        else:
            table[name.upper()] = (float(spec["n"]), float(spec.get("k") or 0.0))
    return table


def lookup(constants: dict, name: str, key: str, source, wavelength=None) -> tuple:
    """``(n, k)`` of ``name`` (case-insensitive), or a ConfigError naming the known materials."""
    try:
        return constants[name.upper()]
    except KeyError:
        if name.upper() in {b.upper() for b in BUILTIN_1064NM}:   # a built-in, wrong wavelength
            raise ConfigError(
                f"material {name!r} has built-in optical constants only at "
                f"{BUILTIN_WAVELENGTH * 1e9:g} nm, not at "
                + ("this wavelength" if wavelength is None else f"{wavelength * 1e9:g} nm")
                + f"; give its constants at that wavelength under materials: "
                f"{name}: {{n: N, k: K}} (or "
                + "{table: FILE}, columns wavelength_nm, n, k; docs/config.md)",
                key=key, source=source) from None
        import difflib
        known = sorted(constants)
        hint = difflib.get_close_matches(name.upper(), known, n=1)
        allowed = f"known: {', '.join(known)}; add it under materials: NAME: {{n, k}}"
        raise ConfigError(f"unknown material {name!r}" + (f" (did you mean {hint[0]}?)" if hint
                                                          else "") + f"; {allowed}",
                          key=key, source=source) from None
