"""Optical constants of the end-members: built-ins at 532 nm and 1064 nm, and user materials.

The built-ins (``BUILTIN``) exist at two laser wavelengths only: 1064 nm (BELA, GALA, the
paper's Table 2) and 532 nm (ATLAS on ICESat-2); docs/materials.md gives every value with its
published source. A preset may add or override materials under ``materials:``, either as
constants at the run's wavelength (``{n, k}``) or as a CSV table over wavelength
(``{table: FILE}``, columns ``wavelength_nm, n, k``), interpolated linearly; such materials work
at any wavelength. Names are case-insensitive. Every cell of a table is checked (finite,
wavelengths > 0 and increasing, 0 < n <= MAX_N, 0 <= k <= MAX_K) and the output records each
table's SHA-256 and the n, k interpolated from it (:func:`table_attrs`).
"""
from __future__ import annotations

import csv
import hashlib
import io
import math
from pathlib import Path

import numpy as np

from .config.schema import MAX_K, MAX_N
from .config.validate import read_input_bytes
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


def _cell_rule(column: str) -> str:
    """What a table cell of ``column`` may hold, in words."""
    if column == "wavelength_nm":
        return "a finite wavelength > 0 nm, strictly increasing from row to row"
    if column == "n":
        return f"a finite real index in (0, {MAX_N:g}]"
    return f"a finite extinction index in [0, {MAX_K:g}]"


def read_table(path, name: str, source=None) -> tuple:
    """The rows of a material table and the SHA-256 of its bytes, every cell checked.

    Parameters
    ----------
    path : str or os.PathLike
        A CSV file with the header ``wavelength_nm, n, k`` (comment lines starting with
        ``#`` and blank lines are skipped): a regular UTF-8 file of at most 1 MiB.
    name : str
        The material, for the key ``materials.NAME.table`` of messages.
    source : str, optional
        The preset, for messages.

    Returns
    -------
    data : numpy.ndarray
        Shape (rows, 3): wavelength (nm), n, k.
    sha256 : str
        Hex digest of the file's bytes, recorded in the output with the interpolated n, k.

    Raises
    ------
    ConfigError
        A file that is missing, not regular, too large, not UTF-8 text, without the header
        or without rows; a row with fewer than 3 cells; a cell that is not a number, not
        finite or out of its range (wavelength_nm > 0 and strictly increasing; 0 < n <=
        MAX_N; 0 <= k <= MAX_K). One line naming the file, the row, the column, the value and
        what is allowed.
    """
    key = f"materials.{name}.table"
    try:
        raw = read_input_bytes(path, "a material table")
    except ConfigError as err:
        raise ConfigError(f"{err.source}: {err.message}", key=key, source=source) from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: not UTF-8 text (byte {err.start}); a material table is a "
                          "CSV text file with the header wavelength_nm, n, k", key=key,
                          source=source) from None
    try:
        rows = [(i, r) for i, r in enumerate(csv.reader(io.StringIO(text, newline="")),
                                             start=1)
                if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    except csv.Error as err:
        raise ConfigError(f"{path}: not a CSV table ({err})", key=key, source=source) from None
    header = [c.strip().lower() for c in rows[0][1]] if rows else []
    if header[:3] != ["wavelength_nm", "n", "k"]:
        raise ConfigError(f"{path}: the first row must be the header wavelength_nm, n, k",
                          key=key, source=source)
    if len(rows) < 2:
        raise ConfigError(f"{path}: no rows under the header; give at least one row "
                          "wavelength_nm, n, k", key=key, source=source)
    columns = ("wavelength_nm", "n", "k")
    data = np.empty((len(rows) - 1, 3))
    for j, (line, row) in enumerate(rows[1:]):
        if len(row) < 3:
            raise ConfigError(f"{path}: line {line} has {len(row)} cell(s); every row gives "
                              "wavelength_nm, n, k", key=key, source=source)
        for c, column in enumerate(columns):
            cell = row[c].strip()
            try:
                x = float(cell)
            except ValueError:
                x = None
            ok = x is not None and math.isfinite(x)
            if ok and column == "wavelength_nm":
                ok = x > 0 and (j == 0 or x > data[j - 1, 0])
            elif ok and column == "n":
                ok = 0 < x <= MAX_N
            elif ok:
                ok = 0 <= x <= MAX_K
            if not ok:
                shown = cell if len(cell) <= 40 else cell[:37] + "..."
                raise ConfigError(f"{path}: line {line}, column {column}: {shown or '(empty)'} "
                                  f"is not allowed; give {_cell_rule(column)}",
                                  key=key, source=source)
            data[j, c] = x
    return data, hashlib.sha256(raw).hexdigest()


def _table_constants(spec: dict, name: str, wavelength: float, source) -> dict:
    """The table material ``name`` at ``wavelength`` (m): ``{table, sha256, rows,
    wavelength_nm, n, k}``, n and k interpolated linearly."""
    data, digest = read_table(Path(spec["table"]), name, source)
    lam_nm = wavelength * 1e9
    lo, hi = data[0, 0], data[-1, 0]
    if not lo <= lam_nm <= hi:
        raise ConfigError(f"wavelength {lam_nm:g} nm is outside the table's range "
                          f"{lo:g}-{hi:g} nm", key=f"materials.{name}.table", source=source)
    n = float(np.interp(lam_nm, data[:, 0], data[:, 1]))
    k = float(np.interp(lam_nm, data[:, 0], data[:, 2]))
    return {"table": str(spec["table"]), "sha256": digest, "rows": int(data.shape[0]),
            "wavelength_nm": lam_nm, "n": n, "k": k}


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
    for name, spec in (cfg.get("materials") or {}).items():
        if spec.get("table"):
            row = _table_constants(spec, name, wavelength, cfg.source)
            table[name.upper()] = (row["n"], row["k"])
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
    wavelength = cfg.get("wavelength")
    lines = []
    for name, spec in (cfg.get("materials") or {}).items():
        if spec.get("table"):
            row = _table_constants(spec, name, wavelength, cfg.source)
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
        import difflib
        known = sorted(constants)
        hint = difflib.get_close_matches(name.upper(), known, n=1)
        allowed = f"known: {', '.join(known)}; add it under materials: NAME: {{n, k}}"
        raise ConfigError(f"unknown material {name!r}" + (f" (did you mean {hint[0]}?)" if hint
                                                          else "") + f"; {allowed}",
                          key=key, source=source) from None
