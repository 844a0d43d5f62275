"""Reading a sweep database: its manifests, and every finished scenario as one Dataset.

A database is the folder ``warpe-cl sweep --out DIR`` writes (:mod:`warpe_cl.sweep`,
docs/cluster.md): one NetCDF file per finished scenario and one manifest per shard
(``manifest.json``, or ``manifest-shard-I-of-N.json`` for ``--shard I/N``). :func:`open_database`
stacks the scenario files of one or several such folders along ``scenario``, reading most of
them with h5py (:func:`_read_scenario`), which gives the same bits as xarray in a fraction of
the time.

xarray and h5py are imported only where they are used.
"""
from __future__ import annotations

import json
import os
import re
from pathlib import Path

from .errors import ConfigError, one_line

__all__ = ["open_database", "database_folder", "manifest_name", "read_manifests"]

MANIFEST_RE = re.compile(r"^manifest(-shard-\d+-of-\d+)?\.json$")


def manifest_name(shard: tuple | None) -> str:
    """The manifest of a run: ``manifest.json``, or ``manifest-shard-I-of-N.json`` for the
    shard ``(I, N)``, so that shards sharing a folder never write the same file."""
    return "manifest.json" if shard is None else f"manifest-shard-{shard[0]}-of-{shard[1]}.json"


def database_folder(out) -> tuple:
    """``--out`` -> (database folder, combined file or None): ``X.nc`` keeps its scenarios in
    ``X.sweep/`` and gets the combined Dataset once the grid is complete."""
    out = Path(out)
    if out.suffix == ".nc":
        return out.with_suffix(".sweep"), out
    return out, None


def read_manifests(folder: Path) -> list:
    """Every manifest in ``folder`` (none if it does not exist).

    Returns
    -------
    list of (Path, dict)
        In the order of their names.

    Raises
    ------
    ConfigError
        A manifest that cannot be read or is not JSON.
    """
    out = []
    if folder.is_dir():
        for path in sorted(folder.iterdir()):
            if MANIFEST_RE.match(path.name):
                try:
                    out.append((path, json.loads(path.read_text(encoding="utf-8"))))
                except (OSError, ValueError) as err:
                    raise ConfigError(f"unreadable manifest ({one_line(err)}); it is not a "
                                      f"warpe-cl sweep database", key=str(path)) from None
    return out


def _attribute(value):
    """A NetCDF attribute as read by h5py -> as xarray's h5netcdf backend gives it."""
    import numpy as np
    if isinstance(value, (bytes, np.bytes_)):
        return value.decode()
    if isinstance(value, np.ndarray) and value.ndim == 1 and value.size == 1:
        return value[0]
    return value


def _read_scenario(path: Path, template):
    """One scenario file, read with h5py into the layout of ``template`` (a scenario of the
    same grid opened by xarray).

    Opening a small file through xarray and h5netcdf costs tens of milliseconds, most of it
    resolving dimension scales; a database holds thousands. Every scenario of a grid shares
    its dimensions, coordinates and variable attributes, so only the values and the global
    attributes are read here, the same bits as ``xarray.load_dataset`` gives (tested). A file
    whose variables or coordinates do not match the template is read by xarray instead.
    """
    import h5py
    import numpy as np
    import xarray as xr
    with h5py.File(path, "r") as h5:
        same_layout = all(name in h5 and h5[name].shape == template[name].shape
                          for name in list(template.data_vars) + list(template.coords))
        same_layout = same_layout and all(
            np.array_equal(h5[name][()], template[name].values)
            for name in template.coords if template[name].dtype.kind in "fiu")
        if same_layout:
            ds = template.copy(deep=False)     # new Variable objects; the template keeps its data
            for name, var in template.data_vars.items():
                ds.variables[name].values = np.asarray(h5[name][()]).astype(var.dtype)
            ds.attrs = {k: _attribute(v) for k, v in h5.attrs.items() if not k.startswith("_")}
            return ds
    return xr.load_dataset(path, engine="h5netcdf")


def _finished(folders: list) -> tuple:
    """What the manifests of ``folders`` say: (a manifest of the grid, its fingerprint, the
    failed scenarios as index -> error, the finished ones as index -> file)."""
    grid = None
    fingerprint = None
    failed = {}
    found = {}
    for folder in folders:
        if folder.suffix == ".nc" and not folder.is_dir():
            folder = folder.with_suffix(".sweep")
        manifests = read_manifests(folder)
        if not manifests:
            raise ConfigError("is not a warpe-cl sweep database (no manifest.json)",
                              key=str(folder))
        for path, manifest in manifests:
            if fingerprint is None:
                fingerprint, grid = manifest["fingerprint"], manifest
            elif manifest["fingerprint"] != fingerprint:
                raise ConfigError(f"{path.name} belongs to another grid than "
                                  f"{folders[0]}; open them separately", key=str(folder))
            for rec in manifest["scenarios"]:
                if rec.get("status") == "failed":
                    failed.setdefault(rec["index"], rec.get("error"))
        for rec in grid["scenarios"]:
            if rec["file"] and rec["index"] not in found and (folder / rec["file"]).is_file():
                found[rec["index"]] = folder / rec["file"]
    if not found:
        raise ConfigError("holds no finished scenario yet", key=", ".join(map(str, folders)))
    return grid, fingerprint, failed, found


def open_database(paths, grid: bool = False):
    """One Dataset of every finished scenario of a sweep database.

    Parameters
    ----------
    paths : str, path, or a list of them
        Database folders (``warpe-cl sweep --out``; for ``--out X.nc`` the folder is
        ``X.sweep``). Several folders of the same grid (shards written to separate folders)
        are merged; a scenario found in several is read once.
    grid : bool
        Unstack ``scenario`` into one dimension per swept key, each sorted in increasing
        value (:func:`warpe_cl.as_grid`; ``grain_size`` for
        ``medium.inclusions[0].grain_size``): ``open_database(DIR, grid=True)`` is
        ``as_grid(open_database(DIR))``.

    Returns
    -------
    xarray.Dataset
        The layout ``warpe-cl run`` writes for a sweep (docs/interface.md §5): a leading
        ``scenario`` dimension whose coordinate is the grid index, the swept values as
        coordinates along it (numbers in the canonical unit, with ``units``, and the
        written text as ``<key>_text``: :func:`warpe_cl.io.sweep_coordinates`), the derived
        parameters and ``scenario_key`` as variables.
        Unfinished scenarios are absent; the attributes ``sweep_scenarios_total``,
        ``sweep_failed`` (JSON: index -> error) and ``sweep_fingerprint`` say what the grid
        holds.

    Raises
    ------
    ConfigError
        A path that is not a database, folders of different grids, or no finished scenario.
    """
    import xarray as xr
    from .io import as_grid, combine_scenarios

    folders = [Path(p) for p in ([paths] if isinstance(paths, (str, os.PathLike)) else paths)]
    unstack = grid
    grid, fingerprint, failed, found = _finished(folders)
    rows = {rec["index"]: rec for rec in grid["scenarios"]}
    indices = sorted(found)
    template = xr.load_dataset(found[indices[0]], engine="h5netcdf")
    datasets = [template] + [_read_scenario(found[i], template) for i in indices[1:]]
    points = [rows[i]["point"] for i in indices]
    out = combine_scenarios(datasets, points, {"config": grid.get("preset_yaml", "")})
    out = out.assign_coords(scenario=("scenario", indices, {
        "long_name": "index of the scenario in the sweep grid (outer product order)"}))
    for name in ("sweep_index", "sweep_point"):
        out.attrs.pop(name, None)
    out.attrs.update({
        "sweep_fingerprint": fingerprint,
        "sweep_scenarios_total": len(rows),
        "sweep_failed": json.dumps({str(i): e for i, e in sorted(failed.items())
                                    if i not in found}),
    })
    return as_grid(out) if unstack else out
