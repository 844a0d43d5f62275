"""Optical constants of the end-members: built-ins at 532 nm and 1064 nm, and user materials.

The built-ins (``BUILTIN``) exist at two laser wavelengths only: 1064 nm (BELA, GALA, the
paper's Table 2) and 532 nm (ATLAS on ICESat-2); docs/materials.md gives every value with its
published source. A preset may add or override materials under ``materials:``, either as
constants at the run's wavelength (``{n, k}``) or as a CSV table over wavelength
(``{table: FILE}``, columns ``wavelength_nm, n, k``), interpolated linearly; such materials work
at any wavelength. Names are case-insensitive. Every cell of a table is checked (finite,
wavelengths > 0 and increasing, n > 0, k >= 0; :mod:`warpe_cl.config.tables`, which reads
each file once), the values interpolated at the run's wavelength are held to n <= MAX_N,
k <= MAX_K (what the walk computes without overflow), and the output records each table's
SHA-256 and the n, k the walk used, from that same read (:func:`table_attrs`).
"""
from __future__ import annotations

import difflib
from pathlib import Path

import numpy as np

from .config.tables import MAX_K, MAX_N, load_table
from .errors import ConfigError

#: Built-in end-members at 1064 nm (paper Table 2; docs/physics.md §3.1): name -> (n, k)
BUILTIN_1064NM = {
    "void": (1.0, 0.0),
    "H2O": (1.30042, 1.27200e-6),   # water ice, Schmitt et al. 1998
    "CO2": (1.4026, 8.47e-10),      # CO2 ice, Schmitt et al. 1998
    "S": (1.92, 9.5e-6),            # sulfur, Sasson et al. 1985
}
BUILTIN_WAVELENGTH = 1064e-9       # m: the wavelength of BUILTIN_1064NM (the paper's)
_WAVELENGTH_TOLERANCE = 1e-3       # relative: "1064 nm" and "1.064 um" are the same

#: The lag materials at 1064 nm, next to the paper's end-members (docs/materials.md): the two
#: bracketing rows of each source, n interpolated linearly and k linearly in log k.
LAGS_1064NM = {
    "tholin": (1.65, 8.3e-4),       # Titan tholin, Khare et al. 1984 (1016 and 1148 nm rows)
    "regolith": (1.5856, 1.52e-3),  # Mg0.8Fe0.2SiO3 glass, Dorschner et al. 1995 (1.0, 1.1 um)
}

#: Built-in end-members at 532 nm (docs/materials.md), interpolated as LAGS_1064NM.
BUILTIN_532NM = {
    "void": (1.0, 0.0),
    "H2O": (1.31164, 1.48e-9),      # water ice, Warren & Brandt 2008 (530 and 540 nm rows)
    "CO2": (1.4141, 4.23e-10),      # CO2 ice: n Warren 1986 Table I, k from Hansen 2005
    "S": (2.010, 8.25e-7),          # alpha-sulfur, Fuller, Downing & Querry 1998 (530, 540 nm)
    "tholin": (1.705, 2.95e-2),     # Titan tholin, Khare et al. 1984 (442.8 and 563.5 nm rows)
    "regolith": (1.6114, 1.70e-3),  # Mg0.8Fe0.2SiO3 glass, Dorschner et al. 1995 (0.50, 0.55 um)
}

#: Every built-in, by wavelength (m): wavelength -> {name: (n, k)}.
BUILTIN = {
    532e-9: BUILTIN_532NM,
    BUILTIN_WAVELENGTH: {**BUILTIN_1064NM, **LAGS_1064NM},
}


def builtin_wavelengths(name: str | None = None) -> tuple:
    """The wavelengths (m, ascending) that have built-in optical constants; with ``name``
    (case-insensitive), only those where that material is built in."""
    return tuple(sorted(lam for lam, table in BUILTIN.items()
                        if name is None or name.upper() in {b.upper() for b in table}))


def builtin_constants(wavelength: float):
    """The built-in ``{name: (n, k)}`` at ``wavelength`` (m, within 0.1 %), or None where no
    built-in exists there."""
    for lam, table in BUILTIN.items():
        if abs(wavelength / lam - 1) < _WAVELENGTH_TOLERANCE:
            return table
    return None


def _nm_list(wavelengths) -> str:
    """The wavelengths (m) in words: ``532 nm and 1064 nm``."""
    names = [f"{lam * 1e9:g} nm" for lam in wavelengths]
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _table_constants(spec: dict, name: str, wavelength: float, source) -> dict:
    """The table material ``name`` at ``wavelength`` (m): ``{table, sha256, rows,
    wavelength_nm, n, k}``, n and k interpolated linearly from the one read of the file
    (:func:`~warpe_cl.config.tables.load_table`) whose SHA-256 is recorded."""
    data, digest = load_table(Path(spec["table"]), name, source)
    key = f"materials.{name}.table"
    lam_nm = wavelength * 1e9
    lo, hi = data[0, 0], data[-1, 0]
    if not lo <= lam_nm <= hi:
        raise ConfigError(f"wavelength {lam_nm:g} nm is outside the table's range "
                          f"{lo:g}-{hi:g} nm", key=key, source=source)
    n = float(np.interp(lam_nm, data[:, 0], data[:, 1]))
    k = float(np.interp(lam_nm, data[:, 0], data[:, 2]))
    for symbol, value, limit in (("n", n, MAX_N), ("k", k, MAX_K)):
        if not value <= limit:
            raise ConfigError(f"{symbol} = {value:g} interpolated at {lam_nm:g} nm is not "
                              f"allowed; give a table whose {symbol} at the run's wavelength "
                              f"is at most {limit:g} (what the walk computes without overflow,"
                              " docs/materials.md §4)", key=key, source=source)
    return {"table": str(spec["table"]), "sha256": digest, "rows": int(data.shape[0]),
            "wavelength_nm": lam_nm, "n": n, "k": k}


def _table_rows(cfg) -> dict:
    """``{NAME: row}`` of :func:`_table_constants` for every table material of ``cfg`` at its
    wavelength, made once per configuration (kept on it), so that the n, k a walk uses and
    the digest the output records come from the same read."""
    wavelength = cfg.get("wavelength")
    memo = cfg.__dict__.setdefault("_material_table_rows", {})
    if wavelength not in memo:
        memo[wavelength] = {
            name: _table_constants(spec, name, wavelength, cfg.source)
            for name, spec in (cfg.get("materials") or {}).items() if spec.get("table")}
    return memo[wavelength]


def optical_constants(cfg) -> dict:
    """Every material the configuration can name, at its wavelength: ``{NAME: (n, k)}`` with
    upper-case keys.

    Built-ins apply at the wavelengths of ``BUILTIN`` only (532 nm and 1064 nm); at another
    wavelength a material other than ``void`` must come from the preset's ``materials:`` block
    (a constant or a table covering the wavelength).
    """
    wavelength = cfg.get("wavelength")
    table = {}
    builtins = builtin_constants(wavelength)
    if builtins is not None:
        table.update({k.upper(): v for k, v in builtins.items()})
    else:
        table["VOID"] = (1.0, 0.0)
    rows = _table_rows(cfg)
    for name, spec in (cfg.get("materials") or {}).items():
        if spec.get("table"):
            table[name.upper()] = (rows[name]["n"], rows[name]["k"])
        else:
            table[name.upper()] = (float(spec["n"]), float(spec.get("k") or 0.0))
    return table


def table_attrs(cfg) -> dict:
    """The output attribute that records the configuration's material tables:
    ``{"material_tables": TEXT}``, TEXT one entry per table material, ``NAME: FILE sha256
    HEX, R rows; at W nm n = N, k = K`` (the interpolated constants the walk used), joined by
    ``"; "``; ``{}`` when no material comes from a table.

    The resolved configuration names a table by its path only; this attribute keeps what the
    file held when the scenario ran.
    """
    lines = []
    for name, row in _table_rows(cfg).items():
        lines.append(f"{name}: {row['table']} sha256 {row['sha256']}, {row['rows']} rows; "
                     f"at {row['wavelength_nm']:g} nm n = {row['n']!r}, k = {row['k']!r}")
    return {"material_tables": "; ".join(lines)} if lines else {}


def lookup(constants: dict, name: str, key: str, source, wavelength=None) -> tuple:
    """``(n, k)`` of ``name`` (case-insensitive), or a ConfigError naming the known materials."""
    try:
        return constants[name.upper()]
    except KeyError:
        where = builtin_wavelengths(name)
        if where:                                           # a built-in, wrong wavelength
            raise ConfigError(
                f"material {name!r}: built-in optical constants exist at {_nm_list(where)} "
                "only, not at "
                + ("this wavelength" if wavelength is None else f"{wavelength * 1e9:g} nm")
                + f"; give its constants at that wavelength under materials: "
                f"{name}: {{n: N, k: K}} (or "
                + "{table: FILE}, columns wavelength_nm, n, k; docs/materials.md)",
                key=key, source=source) from None
        known = sorted(constants)
        hint = difflib.get_close_matches(name.upper(), known, n=1)
        allowed = f"known: {', '.join(known)}; add it under materials: NAME: {{n, k}}"
        raise ConfigError(f"unknown material {name!r}" + (f" (did you mean {hint[0]}?)" if hint
                                                          else "") + f"; {allowed}",
                          key=key, source=source) from None
