"""Material tables and the limits of optical constants: a leaf module (it imports no other
part of warpe-cl's configuration but :mod:`.validate`, and nothing of :mod:`warpe_cl.materials`),
so that the preset's check and the materials read the same table, once.

A table is read and every cell checked once per process and file version (:func:`load_table`,
keyed by the file's path, inode, size and modification time): the validation of the preset,
the interpolation of the walk and the recorded SHA-256 all use that one read.
"""
from __future__ import annotations

import csv
import hashlib
import io
import math
import os

import numpy as np

from ..errors import ConfigError
from .validate import read_input_bytes

#: Largest real refractive index n and extinction index k a run may use (a constant, a
#: substrate, a radiative medium, or the value interpolated from a table at the run's
#: wavelength). Not a physical limit (the highest real indices of solids at laser wavelengths
#: are 4-6, aluminium's k reaches ~150 in the thermal infrared) but what the walk computes
#: without overflow: the kernel evaluates the Fresnel reflectance of n + ik in single precision
#: (largest float 3.4e38), whose largest intermediate terms are (n^2 + k^2)^2 and
#: (n^2 mu + g1)^2 + (2 n k mu + g2)^2 <= 4 (n^2 + k^2)^2; with n, k <= 1e9 they stay below
#: 4 (2e18)^2 = 1.6e37, a factor 20 under the overflow. The host's double-precision relations
#: (Hapke's mean path (n^2 - 1)^1.5 / n, S_i = 1.014 - 4 / (n (n + 1)^2), the absorption
#: coefficient 4 pi k / lambda) are far from theirs (1e308). docs/materials.md §4.
MAX_N = 1e9
MAX_K = 1e9

def _cell_rule(column: str) -> str:
    """What a table cell of ``column`` may hold, in words."""
    if column == "wavelength_nm":
        return "a finite wavelength > 0 nm, strictly increasing from row to row"
    if column == "n":
        return "a finite real index > 0"
    return "a finite extinction index >= 0"


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
        finite or out of its range (wavelength_nm > 0 and strictly increasing; n > 0;
        k >= 0). The upper bounds :data:`MAX_N`, :data:`MAX_K` apply to the value a run
        interpolates (:func:`warpe_cl.materials.optical_constants`), not to every cell. One line naming the file, the row, the column, the value and
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
                ok = x > 0
            elif ok:
                ok = x >= 0
            if not ok:
                shown = cell if len(cell) <= 40 else cell[:37] + "..."
                raise ConfigError(f"{path}: line {line}, column {column}: {shown or '(empty)'} "
                                  f"is not allowed; give {_cell_rule(column)}",
                                  key=key, source=source)
            data[j, c] = x
    return data, hashlib.sha256(raw).hexdigest()




#: tables read in this process: (path, inode, size, mtime_ns) -> (data, sha256)
_TABLES: dict = {}


def load_table(path, name: str, source=None) -> tuple:
    """:func:`read_table`, read once per process and file version: the preset's check reads
    it, the walk and the recorded digest reuse that read while the file is unchanged (same
    path, inode, size and modification time).

    Returns
    -------
    (numpy.ndarray, str)
        The rows (wavelength nm, n, k) and the SHA-256 of the bytes they were parsed from.
    """
    try:
        st = os.stat(path)
        stamp = (os.path.abspath(os.fspath(path)), st.st_ino, st.st_size, st.st_mtime_ns)
    except OSError:
        return read_table(path, name, source)         # the read says what is wrong
    if stamp not in _TABLES:
        data, digest = read_table(path, name, source)
        data.setflags(write=False)
        _TABLES[stamp] = (data, digest)
    return _TABLES[stamp]
