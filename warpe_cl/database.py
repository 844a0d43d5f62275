"""Reading results back: a sweep database (its manifests, and every finished scenario as one
Dataset), and any result file or database folder (:func:`load_result`).

A database is the folder ``warpe-cl sweep --out DIR`` writes (:mod:`warpe_cl.sweep`,
docs/cluster.md): one NetCDF file per finished scenario and one manifest per shard
(``manifest.json``, or ``manifest-shard-I-of-N.json`` for ``--shard I/N``), and, once the grid
is complete, its store ``database.nc`` (:data:`STORE`): every scenario in one NetCDF file,
recorded in a manifest (:func:`store_record`). :func:`open_database` reads a folder's store
when it matches the manifests and the scenario files' SHA-256s (:func:`store_problem`), and
otherwise stacks the scenario files of one or several folders along ``scenario``, reading
most of them with h5py (:func:`_read_scenario`), which gives the same bits as xarray in a
fraction of the time.

A database defends itself (docs/cluster.md, "What defends a database"): every manifest is
checked for its format, keys and types before it is used (:func:`check_manifest`); a row's file
name must be the plan's name for its index (``sNNNNN_KEY.nc``, never a path elsewhere); each
file's own ``sweep_index``, ``sweep_point`` and ``sweep_fingerprint`` must be those of its
row; and a file whose manifest recorded its SHA-256 must still have it
(:func:`file_sha256`). A file that fails any of these is named in one line (ConfigError, exit
2) with the way out, ``warpe-cl sweep ... --resume``: :func:`open_database` never returns a
mixture. A store that does not match is not used (one :class:`~warpe_cl.errors.WarpeWarning`
line) and the files are read instead.

xarray and h5py are imported only where they are used.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import warnings
from pathlib import Path

import numpy as np

from .dataset import as_grid, combine_scenarios
from .errors import ConfigError, WarpeWarning, one_line
from .io import utc_now

__all__ = ["load_result", "open_database", "database_folder", "manifest_name", "read_manifests",
           "finished_scenarios", "h5_attribute", "check_manifest", "scenario_file_name",
           "file_sha256", "recorded_sha256", "read_folder", "store_record", "store_problem",
           "rows_sha256", "STORE", "FORMAT", "FORMAT_VERSION"]

MANIFEST_RE = re.compile(r"^manifest(-shard-\d+-of-\d+)?\.json$")
SCENARIO_FILE_RE = re.compile(r"^s\d{5,}_[0-9a-f]{16}\.nc$")
FORMAT = "warpe-cl sweep database"
FORMAT_VERSION = 2            # 2: each done row carries the sha256 of its file
_STATUSES = ("done", "failed", "pending", "other shard")
#: The consolidated store of a complete database: every scenario in one NetCDF file, written
#: by ``warpe-cl sweep`` when the grid is complete and recorded in a manifest (``store``).
STORE = "database.nc"


def scenario_file_name(index: int, key: str, total: int) -> str:
    """The plan's file name of scenario ``index`` (scenario key ``key``) in a grid of
    ``total`` points: ``s00003_1a2b3c4d5e6f7081.nc``, the index on at least five digits."""
    width = max(5, len(str(total - 1)))
    return f"s{index:0{width}d}_{key}.nc"


def file_sha256(path) -> str:
    """The SHA-256 of a file's bytes, hex (read in 1 MiB blocks)."""
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _resume_hint(folder) -> str:
    return (f"run `warpe-cl sweep PRESET --out {folder} --resume` (with the sweep's own "
            f"options) to check every file and compute this one again")


def check_manifest(path: Path, manifest) -> dict:
    """Check a manifest's format, keys and types before anything follows it.

    Parameters
    ----------
    path : Path
        The manifest, for messages.
    manifest : object
        Its JSON content.

    Returns
    -------
    dict
        ``manifest``, unchanged.

    Raises
    ------
    ConfigError
        One line naming the file and the key: not a mapping, another format, a missing or
        mistyped key, a row whose ``index`` is not its position, whose ``status`` is unknown,
        or whose ``file`` is not the plan's name for its index and key (a path elsewhere,
        another scenario's file).
    """
    def bad(key, what):
        return ConfigError(f"{what}; it is not a valid warpe-cl sweep manifest (delete it "
                           f"and run the sweep again with --resume)", key=f"{path}: {key}")

    if not isinstance(manifest, dict):
        raise bad("(top level)", f"a JSON {type(manifest).__name__}, not a mapping")
    if manifest.get("format") != FORMAT:
        raise bad("format", f"{manifest.get('format')!r}, not {FORMAT!r}")
    version = manifest.get("format_version")
    if type(version) is not int or not 1 <= version <= FORMAT_VERSION:
        raise bad("format_version", f"{version!r}; this warpe-cl reads 1 to {FORMAT_VERSION}")
    fingerprint = manifest.get("fingerprint")
    if not isinstance(fingerprint, str) or not re.fullmatch(r"[0-9a-f]{64}", fingerprint):
        raise bad("fingerprint", f"{fingerprint!r}, not 64 hex digits")
    for key, kind in (("preset_yaml", str), ("keys", list), ("scenarios", list)):
        if not isinstance(manifest.get(key), kind):
            raise bad(key, f"{manifest.get(key)!r:.60}, not a {kind.__name__}")
    rows = manifest["scenarios"]
    if not rows:
        raise bad("scenarios", "an empty list")
    for position, row in enumerate(rows):
        where = f"scenarios[{position}]"
        if not isinstance(row, dict):
            raise bad(where, f"{row!r:.60}, not a mapping")
        if type(row.get("index")) is not int or row["index"] != position:
            raise bad(f"{where}.index", f"{row.get('index')!r}, not {position}")
        if not isinstance(row.get("point"), dict):
            raise bad(f"{where}.point", f"{row.get('point')!r:.60}, not a mapping")
        if row.get("status") not in _STATUSES:
            raise bad(f"{where}.status", f"{row.get('status')!r}, not one of "
                                         f"{', '.join(_STATUSES)}")
        key, name = row.get("key"), row.get("file")
        if key is None and name is None:
            continue                     # an invalid point: no key, no file
        if not isinstance(key, str) or not re.fullmatch(r"[0-9a-f]{16}", key):
            raise bad(f"{where}.key", f"{key!r}, not 16 hex digits")
        if name != scenario_file_name(position, key, len(rows)):
            raise bad(f"{where}.file", f"{name!r}, not the plan's name "
                                       f"{scenario_file_name(position, key, len(rows))}")
        sha = row.get("sha256")
        if sha is not None and not (isinstance(sha, str) and re.fullmatch(r"[0-9a-f]{64}", sha)):
            raise bad(f"{where}.sha256", f"{sha!r}, not 64 hex digits")
        if version >= 2 and row["status"] == "done" and sha is None:
            raise bad(f"{where}.sha256", "missing from a done row")
    return manifest


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
        A folder that cannot be listed, a manifest that cannot be read, is not JSON, or fails
        :func:`check_manifest`.
    """
    out = []
    if folder.is_dir():
        try:
            names = sorted(folder.iterdir())
        except OSError as err:          # PermissionError, an NFS error: one line, exit 2
            raise ConfigError(f"cannot be listed ({one_line(err)})", key=str(folder)) from None
        for path in names:
            if MANIFEST_RE.match(path.name):
                try:
                    manifest = json.loads(path.read_text(encoding="utf-8"))
                except (OSError, ValueError) as err:
                    raise ConfigError(f"unreadable manifest ({one_line(err)}); it is not a "
                                      f"warpe-cl sweep database", key=str(path)) from None
                out.append((path, check_manifest(path, manifest)))
    return out


def recorded_sha256(manifests) -> dict:
    """The SHA-256s a scenario's file may have: every one a done row of any manifest of the
    folder recorded for its index.

    The one rule for both sides: ``warpe-cl sweep --resume`` keeps a file whose SHA-256 is in
    this set (:mod:`warpe_cl.sweep`), and :func:`open_database` reads it. A folder may hold
    manifests of several shard layouts (``--shard 0/2`` and ``1/2``, then an unsharded run);
    each recorded the file it wrote, and a file recomputed since has new bytes (its
    ``wall_time``), so no single row is the file's own. A set needs no clock: rows come from
    several hosts, whose ``finished_utc`` need not agree.

    Parameters
    ----------
    manifests : iterable of (Path, dict)
        As :func:`read_manifests` returns them.

    Returns
    -------
    dict
        index -> set of hex SHA-256s; an index no done row recorded a SHA-256 for (version
        1) is absent.
    """
    recorded = {}
    for _, manifest in manifests:
        for rec in manifest["scenarios"]:
            if rec["status"] == "done" and rec.get("sha256"):
                recorded.setdefault(rec["index"], set()).add(rec["sha256"])
    return recorded


def h5_attribute(value):
    """A NetCDF attribute as read by h5py -> as xarray's h5netcdf backend gives it."""
    if isinstance(value, (bytes, np.bytes_)):
        return value.decode()
    if isinstance(value, np.ndarray) and value.ndim == 1 and value.size == 1:
        return value[0]
    return value


def _h5_values(dataset):
    """A dataset's values as h5py reads them; text (variable-length or fixed) decoded to
    ``str``, as xarray's h5netcdf backend gives it."""
    import h5py
    info = h5py.check_string_dtype(dataset.dtype)
    if info is not None:
        return np.asarray(dataset.asstr()[()], dtype=str)
    return np.asarray(dataset[()])


def _read_scenario(path: Path, template):
    """One scenario file, read with h5py into the layout of ``template`` (a scenario of the
    same grid opened by xarray).

    Opening a small file through xarray and h5netcdf costs tens of milliseconds, most of it
    resolving dimension scales; a database holds thousands. Every scenario of a grid shares
    its dimensions, index coordinates and variable attributes, so only the values (the
    variables' and those of coordinates along a dimension, such as ``layer_thickness``) and
    the global attributes are read here, the same bits as ``xarray.load_dataset`` gives
    (tested). A file whose variables, index coordinates or text coordinates do not match the
    template's is read by xarray instead.
    """
    import h5py
    import xarray as xr
    variables = template.variables       # Variables, not DataArrays: 10x cheaper to reach
    with h5py.File(path, "r") as h5:
        datasets = {}
        for name in variables:
            item = h5.get(name)
            if not isinstance(item, h5py.Dataset) or item.shape != variables[name].shape:
                datasets = None
                break
            datasets[name] = item
        values = {}
        for name in template.coords if datasets is not None else ():
            have, want = _h5_values(datasets[name]), variables[name].values
            if name in template.indexes or want.dtype.kind not in "fiub":
                if not np.array_equal(have, want):    # a dimension's labels, or text
                    datasets = None
                    break
            else:
                values[name] = have           # numbers along a dimension (layer_thickness)
        if datasets is not None:
            ds = template.copy(deep=False)     # new Variable objects; the template keeps its data
            out = ds.variables
            for name in template.data_vars:
                out[name].values = np.asarray(datasets[name][()]).astype(variables[name].dtype)
            for name, value in values.items():
                out[name].values = value.astype(variables[name].dtype)
            ds.attrs = {k: h5_attribute(v) for k, v in h5.attrs.items() if not k.startswith("_")}
            return ds
    return xr.load_dataset(path, engine="h5netcdf")


def finished_scenarios(folders: list) -> tuple:
    """What the manifests of ``folders`` say: (a manifest of the grid, its fingerprint, the
    failed scenarios as index -> error, the finished ones as index -> (file, the SHA-256s its
    folder's manifests recorded for it, or None for a version-1 database, which recorded
    none)).

    A scenario is finished when a manifest of its folder lists it as done (with its file's
    SHA-256); a file no manifest lists yet (a sweep still writing, or killed before its
    manifest caught up) is left out until ``--resume`` checks and records it. Version-1
    manifests recorded no SHA-256: there, a file in place counts, as it always did.

    Raises
    ------
    ConfigError
        A folder without a manifest, folders of different grids, a file listed as done but
        missing, or no finished scenario.
    """
    return _finished(folders)[:4]


def _finished(folders: list) -> tuple:
    """:func:`finished_scenarios`, and the manifests read, as (Path, dict) of every folder."""
    grid = None
    fingerprint = None
    failed = {}
    found = {}
    read = []
    for folder in folders:
        if folder.suffix == ".nc" and not folder.is_dir():
            folder = folder.with_suffix(".sweep")
        manifests = read_manifests(folder)
        read += manifests
        if not manifests:
            raise ConfigError("is not a warpe-cl sweep database (no manifest.json)",
                              key=str(folder))
        recorded = recorded_sha256(manifests)   # the same rule as sweep --resume
        legacy = False
        for path, manifest in manifests:
            if fingerprint is None:
                fingerprint, grid = manifest["fingerprint"], manifest
            elif manifest["fingerprint"] != fingerprint:
                raise ConfigError(f"{path.name} belongs to another grid than "
                                  f"{folders[0]}; open them separately", key=str(folder))
            legacy = legacy or manifest["format_version"] < 2
            for rec in manifest["scenarios"]:
                if rec["status"] == "failed":
                    failed.setdefault(rec["index"], rec.get("error"))
        for rec in grid["scenarios"]:
            index, name = rec["index"], rec["file"]
            if not name or index in found:
                continue
            path = folder / name
            if index in recorded:
                if not path.is_file():
                    raise ConfigError(f"is missing, though a manifest lists it as done; "
                                      f"{_resume_hint(folder)}", key=str(path))
                found[index] = (path, recorded[index])
            elif legacy and path.is_file():
                found[index] = (path, None)
    if not found:
        raise ConfigError("holds no finished scenario yet", key=", ".join(map(str, folders)))
    return grid, fingerprint, failed, found, read


def _checked(path: Path, shas, read) -> tuple:
    """(``read()``, the file's SHA-256): a scenario file's Dataset once its SHA-256 is one its
    manifests recorded (``shas``; None: not recorded, version 1); any failure named in one
    line."""
    try:
        digest = file_sha256(path)
        if shas is not None and digest not in shas:
            raise ConfigError(
                f"its sha256 ({digest[:16]}...) is not the one its manifest recorded "
                f"({sorted(shas)[0][:16]}...): the file changed after it was written; "
                f"{_resume_hint(path.parent)}", key=str(path))
        return read(), digest
    except ConfigError:
        raise
    except Exception as err:  # noqa: BLE001 - truncated, HDF5 errors, I/O: one line
        raise ConfigError(f"unreadable ({type(err).__name__}: {one_line(err)}); "
                          f"{_resume_hint(path.parent)}", key=str(path)) from None


def _check_attributes(ds, path: Path, index: int, fingerprint: str, point: dict) -> None:
    """A scenario file's own ``sweep_index``, ``sweep_fingerprint`` and ``sweep_point`` must
    be those of the manifest row that names it (a swapped or edited row relabels no data)."""
    want = {"sweep_index": index, "sweep_fingerprint": fingerprint,
            "sweep_point": json.dumps(point, sort_keys=True, default=str)}
    for name, value in want.items():
        have = ds.attrs.get(name)
        same = have is not None and (int(have) == value if name == "sweep_index"
                                     else str(have) == value)
        if not same:
            raise ConfigError(f"its attribute {name} is {have!r:.80}, its manifest row says "
                              f"{value!r:.80}; {_resume_hint(path.parent)}", key=str(path))


def _read_files(grid: dict, fingerprint: str, found: dict) -> tuple:
    """The finished scenarios' files, each checked (:func:`_checked`,
    :func:`_check_attributes`), stacked along ``scenario``: (Dataset, index -> the SHA-256 of
    the file read)."""
    import xarray as xr
    rows = {rec["index"]: rec for rec in grid["scenarios"]}
    indices = sorted(found)
    datasets, digests = [], {}
    for i in indices:
        path, shas = found[i]
        if datasets:
            ds, digests[i] = _checked(path, shas, lambda: _read_scenario(path, datasets[0]))
        else:
            ds, digests[i] = _checked(path, shas,
                                      lambda: xr.load_dataset(path, engine="h5netcdf"))
        _check_attributes(ds, path, i, fingerprint, rows[i]["point"])
        datasets.append(ds)
    points = [rows[i]["point"] for i in indices]
    out = combine_scenarios(datasets, points, {"config": grid.get("preset_yaml", "")})
    out = out.assign_coords(scenario=("scenario", indices, {
        "long_name": "index of the scenario in the sweep grid (outer product order)"}))
    for name in ("sweep_index", "sweep_point"):
        out.attrs.pop(name, None)
    return out, digests


def _grid_attributes(out, fingerprint: str, total: int, failed: dict, found: dict):
    """``out`` with the attributes that say what the grid holds, from its manifests:
    ``sweep_fingerprint``, ``sweep_scenarios_total`` and ``sweep_failed``."""
    out.attrs.update({
        "sweep_fingerprint": fingerprint,
        "sweep_scenarios_total": total,
        "sweep_failed": json.dumps({str(i): e for i, e in sorted(failed.items())
                                    if i not in found}),
    })
    return out


def read_folder(folder) -> tuple:
    """Every finished scenario of one database folder, read from its scenario files (never
    from its store), and what the store of these files records.

    Parameters
    ----------
    folder : str or path
        A database folder.

    Returns
    -------
    (xarray.Dataset, dict)
        The Dataset :func:`open_database` returns, and index -> the SHA-256 of the scenario
        file read for it (:func:`store_record`).

    Raises
    ------
    ConfigError
        As :func:`open_database`.
    """
    grid, fingerprint, failed, found = finished_scenarios([Path(folder)])
    out, digests = _read_files(grid, fingerprint, found)
    return _grid_attributes(out, fingerprint, len(grid["scenarios"]), failed, found), digests


def rows_sha256(rows) -> str:
    """The SHA-256 of a grid's rows as a manifest lists them: each row's index, point and
    file (the store's entry records it: an edited or swapped row makes the store unused)."""
    text = json.dumps([[r["index"], r["point"], r["file"]] for r in rows], sort_keys=True,
                      default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def store_record(sha256: str, grid: dict, digests: dict) -> dict:
    """What a manifest records of the store (its ``store`` entry): the file's name and
    SHA-256, the grid's fingerprint and the SHA-256 of its rows (:func:`rows_sha256`), and
    the SHA-256 of every scenario file it was built from (index as text -> hex), so that
    :func:`store_problem` can tell, from hashes alone (no scenario file opened as NetCDF),
    that the store holds what the manifests vouch for.

    Parameters
    ----------
    sha256 : str
        The store file's SHA-256 (hex), taken once it is flushed to disk.
    grid : dict
        A manifest of the grid (its ``fingerprint`` and ``scenarios``).
    digests : dict
        Index -> SHA-256 of the scenario file read (:func:`read_folder`).

    Returns
    -------
    dict
        ``file``, ``sha256``, ``fingerprint``, ``rows_sha256``, ``scenarios``,
        ``written_utc``.
    """
    return {"file": STORE, "sha256": sha256, "fingerprint": grid["fingerprint"],
            "rows_sha256": rows_sha256(grid["scenarios"]),
            "scenarios": {str(i): digests[i] for i in sorted(digests)},
            "written_utc": utc_now()}


def _hex(value, digits: int = 64) -> bool:
    return isinstance(value, str) and re.fullmatch(f"[0-9a-f]{{{digits}}}", value) is not None


def _record_problem(record, grid: dict, found: dict) -> str | None:
    """Why a manifest's ``store`` entry does not describe the finished scenarios of now, or
    None: its form, its fingerprint and rows (``grid``, a manifest of the grid), and every
    scenario's SHA-256 one its manifests recorded for it (the rule a scenario file is read
    by, :func:`recorded_sha256`)."""
    if not isinstance(record, dict) or record.get("file") != STORE \
            or not isinstance(record.get("scenarios"), dict) \
            or not all(_hex(v) for v in record["scenarios"].values()):
        return "its manifest entry is malformed"
    if record.get("fingerprint") != grid["fingerprint"]:
        return "it was built for another grid"
    if record.get("rows_sha256") != rows_sha256(grid["scenarios"]):
        return "the manifest's rows (points, files) are not those it was built for"
    built = record["scenarios"]
    if set(built) != {str(i) for i in found}:
        missing = sorted(set(found) - {int(i) for i in built if i.isdigit()})
        return (f"it holds {len(built)} scenarios, the manifests list {len(found)} as done"
                + (f" (scenario {missing[0]} is not in it)" if missing else ""))
    for i, (path, shas) in sorted(found.items()):
        if shas is None or built[str(i)] not in shas:
            return (f"it was built from another {path.name} (sha256 "
                    f"{built[str(i)][:16]}...) than the manifests list")
    return None


def store_problem(folder, manifests, grid: dict, found: dict, files: bool = True) -> tuple:
    """Whether a database folder's store can stand for its scenario files.

    The store's SHA-256 (one file) must be the one a manifest's ``store`` entry recorded,
    and that entry must list, for every finished scenario and no other, a SHA-256 that the
    manifests record for its file (:func:`_record_problem`). With ``files``, every scenario
    file is hashed too, as reading the files does (200 files of 120 kB: 40 ms), and must be
    the very file the store was built from: so a damaged file is named as it always was, and
    a store built from another recorded version of a file is not used.

    Parameters
    ----------
    folder : path
        The database folder.
    manifests : list of (Path, dict)
        Its manifests (:func:`read_manifests`).
    grid : dict
        A manifest of the grid (:func:`finished_scenarios`).
    found : dict
        The finished scenarios (:func:`finished_scenarios`).
    files : bool
        Hash every scenario file as well.

    Returns
    -------
    (dict or None, str or None)
        (the matching ``store`` entry, None) when the store is good; (None, None) when there
        is no store; (None, why) when it is not to be used.

    Raises
    ------
    ConfigError
        With ``files``: a scenario file that is unreadable or whose SHA-256 no manifest
        recorded for it (one line naming it and ``--resume``, as :func:`open_database`).
    """
    path = Path(folder) / STORE
    if not path.is_file():
        return None, None
    records = [m["store"] for _, m in manifests if "store" in m]
    if not records:
        return None, "no manifest records it (a sweep is running, or was stopped)"
    try:
        digest = file_sha256(path)
    except OSError as err:
        return None, f"unreadable ({one_line(err)})"
    matching = [r for r in records if isinstance(r, dict) and r.get("sha256") == digest]
    if not matching:
        return None, (f"its sha256 ({digest[:16]}...) is not the one its manifest recorded: "
                      f"it changed after it was written")
    record = matching[0]
    why = _record_problem(record, grid, found)
    if why is None and files:
        for i, (scenario, shas) in sorted(found.items()):
            _, digest = _checked(scenario, shas, lambda: None)
            if digest != record["scenarios"][str(i)]:
                why = (f"it was built from another {scenario.name} (sha256 "
                       f"{record['scenarios'][str(i)][:16]}...) than the folder holds")
                break
    return (None, why) if why else (record, None)


def _open_store(folder: Path, manifests, grid: dict, found: dict):
    """A folder's store as the Dataset of its scenario files, or None (no store, or one not
    to be used: one :class:`~warpe_cl.errors.WarpeWarning` line says why)."""
    import xarray as xr
    path = folder / STORE
    fingerprint = grid["fingerprint"]
    record, why = store_problem(folder, manifests, grid, found)
    if record is not None:
        try:
            ds = xr.load_dataset(path, engine="h5netcdf")
            if str(ds.attrs.get("sweep_fingerprint")) != fingerprint or \
                    [int(i) for i in ds["scenario"].values] != sorted(found):
                why = "its scenarios are not those its manifest entry lists"
            else:
                return ds
        except Exception as err:  # noqa: BLE001 - truncated, HDF5 errors: the files instead
            why = f"unreadable ({type(err).__name__}: {one_line(err)})"
    if why is not None:
        warnings.warn(f"{path}: not used, {why}; reading the {len(found)} scenario files "
                      f"instead (`warpe-cl sweep PRESET --out {folder} --resume` writes it "
                      f"again)", WarpeWarning, stacklevel=3)
    return None


def open_database(paths, grid: bool = False, store: bool = True):
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
    store : bool
        Read one folder's store, ``DIR/database.nc`` (:data:`STORE`, written by ``warpe-cl
        sweep`` once the grid is complete), instead of its scenario files, when a manifest
        records it and it matches the manifests and the scenario files (:func:`store_problem`:
        their SHA-256s, as when the files are read): one file, read in a fraction of a
        second. A store that does not match (changed, stale, unreadable) is
        not used, with one warning line (:class:`~warpe_cl.errors.WarpeWarning`), and the
        files are read. False: always read the files. Several folders: always the files.

    Returns
    -------
    xarray.Dataset
        The layout ``warpe-cl run`` writes for a sweep (docs/interface.md §5): a leading
        ``scenario`` dimension whose coordinate is the grid index, the swept values as
        coordinates along it (numbers in the canonical unit, with ``units``, and the
        written text as ``<key>_text``: :func:`warpe_cl.dataset.sweep_coordinates`), the derived
        parameters and ``scenario_key`` as variables.
        Unfinished scenarios are absent; the attributes ``sweep_scenarios_total``,
        ``sweep_failed`` (JSON: index -> error) and ``sweep_fingerprint`` say what the grid
        holds. Loaded into memory either way; ``sweep_store`` is the store's name when it
        was read, absent otherwise.

    Raises
    ------
    ConfigError
        A path that is not a database, a manifest that fails :func:`check_manifest`, folders
        of different grids, no finished scenario; or a finished scenario's file that is
        missing, unreadable (truncated), whose SHA-256 is not the one its manifest recorded,
        or whose own index, point or fingerprint is not its row's. The message names the file
        and says to run ``warpe-cl sweep ... --resume``; no Dataset of the others is returned.
    """
    folders = [Path(p) for p in ([paths] if isinstance(paths, (str, os.PathLike)) else paths)]
    unstack = grid
    grid, fingerprint, failed, found, manifests = _finished(folders)
    out = None
    if store and len(folders) == 1:
        folder = next(iter(found.values()))[0].parent
        out = _open_store(folder, manifests, grid, found)
        if out is not None:
            out.attrs["sweep_store"] = STORE
    if out is None:
        out, _ = _read_files(grid, fingerprint, found)
        out.attrs.pop("sweep_store", None)
    out = _grid_attributes(out, fingerprint, len(grid["scenarios"]), failed, found)
    return as_grid(out) if unstack else out


def load_result(path):
    """A result file of ``run``, ``sweep`` or ``instrument``, or a sweep database folder
    (docs/interface.md §5.5), as a Dataset.

    Parameters
    ----------
    path : str or path
        A NetCDF result file, or a database folder (read by :func:`open_database`).

    Returns
    -------
    xarray.Dataset
        The file's contents, loaded into memory.

    Raises
    ------
    ConfigError
        One line (exit 2) for a path that is neither: missing, or not a readable NetCDF file.
    """
    import xarray as xr
    path = Path(path)
    if path.is_dir():
        return open_database(path)
    if not path.is_file():
        raise ConfigError("no such file", key=str(path))
    try:
        return xr.load_dataset(path, engine="h5netcdf")
    except Exception as err:  # noqa: BLE001 - any unreadable file: one line
        raise ConfigError(f"not a warpe-cl NetCDF file ({type(err).__name__})",
                          key=str(path)) from None
