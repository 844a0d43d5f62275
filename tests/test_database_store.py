"""A database's store (issue 41): ``DIR/database.nc``, every scenario in one file, written by
``warpe-cl sweep`` once the grid is complete and recorded in its manifest; read by
``open_database`` in its files' stead only while it matches the manifests; and the fast
reader of scenario files that builds it."""
from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import warpe_cl
import warpe_cl.database as database
import warpe_cl.sweep as sweep_module
from warpe_cl.database import STORE, file_sha256
from warpe_cl.errors import WarpeWarning
from warpe_cl.io import write_netcdf
from conftest import quiet_sweep, read_manifest, tiny_grid

GRID = tiny_grid(photons=300, seed=1)





def _write_manifest(folder: Path, manifest: dict, name="manifest.json") -> None:
    (folder / name).write_text(json.dumps(manifest, indent=1))


@pytest.fixture(scope="module")
def done_db(tmp_path_factory):
    """A complete 4-point database with its store; tests copy it before changing it."""
    tmp = tmp_path_factory.mktemp("store")
    preset = tmp / "grid.yaml"
    preset.write_text(GRID)
    summary = quiet_sweep(preset, tmp / "db")
    assert summary.exit_code == 0 and summary.done == 4
    assert summary.store == tmp / "db" / STORE
    return tmp / "db", preset


@pytest.fixture
def db(done_db, tmp_path):
    folder, preset = done_db
    shutil.copytree(folder, tmp_path / "db")
    return tmp_path / "db", preset


def _without_store_attr(ds):
    ds = ds.copy()
    ds.attrs.pop("sweep_store", None)
    return ds


def _open_warns(folder) -> tuple:
    """open_database(folder) and the one WarpeWarning it gives (asserted one line)."""
    with pytest.warns(WarpeWarning) as caught:
        ds = warpe_cl.open_database(folder)
    ours = [w for w in caught if issubclass(w.category, WarpeWarning)]
    assert len(ours) == 1
    message = str(ours[0].message)
    assert "\n" not in message and "--resume" in message and STORE in message
    return ds, message


# --------------------------------------------------------------------------- written

def test_a_finished_sweep_writes_its_store_and_records_it(done_db):
    folder, _ = done_db
    store = folder / STORE
    manifest = read_manifest(folder)
    record = manifest["store"]
    assert record["file"] == STORE and record["sha256"] == file_sha256(store)
    assert record["fingerprint"] == manifest["fingerprint"]
    rows = {str(r["index"]): r["sha256"] for r in manifest["scenarios"]}
    assert record["scenarios"] == rows
    assert rows == {str(r["index"]): file_sha256(folder / r["file"])
                    for r in manifest["scenarios"]}
    assert not [p.name for p in folder.glob(f".{STORE}.*tmp*")]      # nothing half-written
    # the store is the folder read file by file: same values, coordinates and attributes
    fast, slow = warpe_cl.open_database(folder), warpe_cl.open_database(folder, store=False)
    assert fast.attrs["sweep_store"] == STORE and "sweep_store" not in slow.attrs
    assert _without_store_attr(fast).identical(slow)
    for name in slow.variables:
        assert fast[name].dtype == slow[name].dtype, name
    # lazily readable with xarray alone
    with xr.open_dataset(store, engine="h5netcdf") as lazy:
        assert lazy.sizes["scenario"] == 4
        assert np.array_equal(lazy["reflectance"].values, slow["reflectance"].values)


def test_open_reads_the_store_not_the_files(db, monkeypatch):
    folder, _ = db

    def no_files(*args, **kw):
        raise AssertionError("a scenario file was read")
    monkeypatch.setattr(database, "_read_files", no_files)
    monkeypatch.setattr(database, "_read_scenario", no_files)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds = warpe_cl.open_database(folder)
        assert ds.sizes["scenario"] == 4 and ds.attrs["sweep_store"] == STORE
        assert warpe_cl.open_database(folder, grid=True)["reflectance"].dims[:2] == \
            ("thickness", "radiative_tau0")
        assert database.load_result(folder).attrs["sweep_store"] == STORE
    assert ds.attrs["sweep_scenarios_total"] == 4 and ds.attrs["sweep_failed"] == "{}"


def test_a_folder_without_a_store_is_read_file_by_file_silently(db):
    folder, _ = db
    (folder / STORE).unlink()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds = warpe_cl.open_database(folder)
    assert ds.sizes["scenario"] == 4 and "sweep_store" not in ds.attrs


# --------------------------------------------------------------------------- not used

def test_a_store_older_than_a_recomputed_scenario_is_not_used(db):
    """A scenario file replaced by new bytes whose manifest row records them (what a resume
    that recomputes it does): the store holds the old values, so it is not used."""
    folder, _ = db
    manifest = read_manifest(folder)
    row = manifest["scenarios"][2]
    path = folder / row["file"]
    ds = xr.load_dataset(path, engine="h5netcdf")
    ds["reflectance"] = ds["reflectance"] * 2.0
    write_netcdf(ds, path)
    row["sha256"] = file_sha256(path)
    _write_manifest(folder, manifest)
    out, message = _open_warns(folder)
    assert "built from another" in message and row["file"] in message
    assert "sweep_store" not in out.attrs
    assert np.array_equal(out["reflectance"].sel(scenario=2).values,
                          ds["reflectance"].values)           # the new values, not the store's


def test_a_store_holding_a_scenario_no_longer_done_is_not_used(db):
    folder, _ = db
    manifest = read_manifest(folder)
    row = manifest["scenarios"][1]
    row["status"] = "pending"
    del row["sha256"]
    _write_manifest(folder, manifest)
    out, message = _open_warns(folder)
    assert "holds 4 scenarios, the manifests list 3" in message
    assert list(out["scenario"].values) == [0, 2, 3]


def test_a_store_of_another_grid_or_a_malformed_entry_is_not_used(db):
    folder, _ = db
    manifest = read_manifest(folder)
    good = dict(manifest["store"])
    manifest["store"] = {**good, "fingerprint": "0" * 64}
    _write_manifest(folder, manifest)
    assert "another grid" in _open_warns(folder)[1]
    manifest["store"] = {**good, "scenarios": ["not", "a", "mapping"]}
    _write_manifest(folder, manifest)
    assert "malformed" in _open_warns(folder)[1]
    del manifest["store"]
    _write_manifest(folder, manifest)
    assert "no manifest records it" in _open_warns(folder)[1]


def test_edited_rows_make_the_store_unused_and_the_files_refuse_them(db):
    """Points swapped between two rows of the manifest: the store is not used (it was built
    for other rows), and the files, read instead, refuse the relabelling as they always did."""
    from warpe_cl.errors import ConfigError
    folder, _ = db
    manifest = read_manifest(folder)
    rows = manifest["scenarios"]
    rows[0]["point"], rows[1]["point"] = rows[1]["point"], rows[0]["point"]
    _write_manifest(folder, manifest)
    with pytest.warns(WarpeWarning, match="rows"):
        with pytest.raises(ConfigError, match="sweep_point"):
            warpe_cl.open_database(folder)


def test_a_damaged_scenario_file_is_named_though_the_store_is_good(db):
    """The store stands for files that are still there, intact: a changed byte in one is a
    ConfigError naming it, as without a store."""
    from warpe_cl.errors import ConfigError
    folder, _ = db
    path = sorted(folder.glob("s*.nc"))[1]
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x10
    path.write_bytes(bytes(data))
    with pytest.raises(ConfigError, match="sha256") as caught:
        warpe_cl.open_database(folder)
    assert str(path) in str(caught.value) and "--resume" in str(caught.value)


@pytest.mark.parametrize("damage", ["truncate", "flip"])
def test_a_corrupt_store_is_not_used(db, damage):
    folder, _ = db
    store = folder / STORE
    data = bytearray(store.read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 2]
    else:
        data[len(data) // 2] ^= 0xFF
    store.write_bytes(bytes(data))
    out, message = _open_warns(folder)
    assert "changed after it was written" in message
    assert _without_store_attr(out).identical(warpe_cl.open_database(folder, store=False))


def test_an_unreadable_store_its_manifest_vouches_for_is_not_used(db):
    """Bytes a manifest recorded but that are no NetCDF file (a store written by something
    else, its entry edited to match): refused when read, the files read instead."""
    folder, _ = db
    (folder / STORE).write_bytes(b"not an HDF5 file")
    manifest = read_manifest(folder)
    manifest["store"]["sha256"] = file_sha256(folder / STORE)
    _write_manifest(folder, manifest)
    out, message = _open_warns(folder)
    assert "unreadable" in message and out.sizes["scenario"] == 4


def test_the_command_line_says_it_in_one_line(db, tmp_path, capsys):
    """`warpe-cl plot DIR` on a folder whose store changed: one warning line, then the
    figure from the files."""
    from warpe_cl.cli import main
    folder, _ = db
    with open(folder / STORE, "r+b") as fh:
        fh.seek(100)
        fh.write(b"\0\1\2")
    assert main(["plot", str(folder), "--out", str(tmp_path / "w.png")]) == 0
    err = [x for x in capsys.readouterr().err.splitlines() if STORE in x]
    assert len(err) == 1 and err[0].startswith("warpe-cl: warning:")


# --------------------------------------------------------------------------- when written

def test_an_incomplete_sweep_writes_no_store_the_shard_that_completes_does(tmp_path):
    preset = tmp_path / "grid.yaml"
    preset.write_text(GRID)
    folder = tmp_path / "db"
    assert quiet_sweep(preset, folder, shard=(0, 2)).store is None
    assert not (folder / STORE).exists()
    assert "store" not in read_manifest(folder, "manifest-shard-0-of-2.json")
    summary = quiet_sweep(preset, folder, shard=(1, 2))
    assert summary.store == folder / STORE
    record = read_manifest(folder, "manifest-shard-1-of-2.json")["store"]
    assert record["sha256"] == file_sha256(folder / STORE) and len(record["scenarios"]) == 4
    assert warpe_cl.open_database(folder).attrs["sweep_store"] == STORE


def test_a_stopped_sweep_writes_no_store(tmp_path, monkeypatch):
    preset = tmp_path / "grid.yaml"
    preset.write_text(GRID)
    real = sweep_module.run_scenario
    calls = []

    def stop_after_two(task):
        if len(calls) == 2:
            raise KeyboardInterrupt
        calls.append(task["index"])
        return real(task)
    monkeypatch.setattr(sweep_module, "run_scenario", stop_after_two)
    with pytest.raises(KeyboardInterrupt):
        quiet_sweep(preset, tmp_path / "db")
    assert not (tmp_path / "db" / STORE).exists()
    assert "store" not in read_manifest(tmp_path / "db")


def test_resume_on_a_complete_folder_writes_a_missing_store(db):
    folder, preset = db
    (folder / STORE).unlink()
    manifest = read_manifest(folder)
    del manifest["store"]
    _write_manifest(folder, manifest)
    summary = quiet_sweep(preset, folder, resume=True)
    assert summary.skipped == 4 and summary.done == 0 and summary.store == folder / STORE
    assert read_manifest(folder)["store"]["sha256"] == file_sha256(folder / STORE)
    assert warpe_cl.open_database(folder).attrs["sweep_store"] == STORE


def test_resume_keeps_a_good_store_and_rewrites_a_stale_one(db):
    folder, preset = db
    store = folder / STORE
    before = store.stat()
    summary = quiet_sweep(preset, folder, resume=True)
    after = store.stat()
    assert summary.store is None                         # kept, not written again
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)
    assert read_manifest(folder)["store"]["sha256"] == file_sha256(store)
    with open(store, "r+b") as fh:                       # now a changed byte
        fh.seek(200)
        fh.write(b"\xff\xff")
    summary = quiet_sweep(preset, folder, resume=True)
    assert summary.store == store
    assert read_manifest(folder)["store"]["sha256"] == file_sha256(store)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert warpe_cl.open_database(folder).attrs["sweep_store"] == STORE


def test_resume_that_recomputes_a_changed_file_rebuilds_the_store(db, capsys):
    folder, preset = db
    manifest = read_manifest(folder)
    path = folder / manifest["scenarios"][3]["file"]
    data = bytearray(path.read_bytes())
    data[-100] ^= 0xFF
    path.write_bytes(bytes(data))
    summary = quiet_sweep(preset, folder, resume=True)
    assert summary.done == 1 and summary.store == folder / STORE
    assert (folder / "rejected" / path.name).is_file()
    record = read_manifest(folder)["store"]
    assert record["scenarios"]["3"] == file_sha256(path) == \
        read_manifest(folder)["scenarios"][3]["sha256"]
    fast = warpe_cl.open_database(folder)
    assert fast.attrs["sweep_store"] == STORE
    assert _without_store_attr(fast).identical(warpe_cl.open_database(folder, store=False))


def test_out_nc_gets_its_combined_file_and_the_folder_its_store(tmp_path):
    preset = tmp_path / "grid.yaml"
    preset.write_text(GRID)
    summary = quiet_sweep(preset, tmp_path / "x.nc")
    assert summary.combined == tmp_path / "x.nc"
    assert summary.store == tmp_path / "x.sweep" / STORE
    combined = xr.load_dataset(tmp_path / "x.nc", engine="h5netcdf")
    store = warpe_cl.open_database(tmp_path / "x.sweep")
    assert np.array_equal(combined["reflectance"].values, store["reflectance"].values)


def test_a_store_is_no_foreign_file_of_a_folder_without_manifest(db):
    """A folder whose manifests were lost, scenario files and store left, is resumed."""
    folder, preset = db
    for path in folder.glob("manifest*.json"):
        path.unlink()
    summary = quiet_sweep(preset, folder, resume=True)
    assert summary.exit_code == 0 and summary.store == folder / STORE
