"""A sweep database that defends itself (issue 39): locks against concurrent writers, files
checked on --resume and on reading, manifests validated, folders and --out files that are not
this grid's refused, grids with duplicate values or too many points refused."""
from __future__ import annotations

import json
import os
import re
import signal
import threading
from pathlib import Path

import h5py
import pytest
import yaml

import warpe_cl
import warpe_cl.sweep as sweep_module
from warpe_cl.cli import main
from warpe_cl.errors import ConfigError
from conftest import quiet_sweep, read_manifest, tiny_grid

GRID = tiny_grid(photons=300, seed=1)





@pytest.fixture
def preset(tmp_path):
    path = tmp_path / "grid.yaml"
    path.write_text(GRID)
    return path


@pytest.fixture(scope="module")
def done_db(tmp_path_factory):
    """A complete 4-point database; tests copy it before changing it."""
    tmp = tmp_path_factory.mktemp("done")
    path = tmp / "grid.yaml"
    path.write_text(GRID)
    summary = quiet_sweep(path, tmp / "db")
    assert summary.exit_code == 0 and summary.done == 4
    return tmp / "db", path


@pytest.fixture
def db(done_db, tmp_path):
    import shutil
    folder, preset = done_db
    shutil.copytree(folder, tmp_path / "db")
    return tmp_path / "db", preset


def _hidden(folder: Path) -> list:
    """Hidden names in ``folder`` but the lock files, which stay (docs/cluster.md): the
    folder's ``.warpe-cl.lock``, the store's ``.database.nc.lock`` and a manifest's
    ``.<manifest>.lock``."""
    locks = re.compile(r"^\.(warpe-cl|database\.nc|manifest(-shard-\d+-of-\d+)?\.json)"
                       r"\.lock$")
    return sorted(p.name for p in folder.glob(".*") if not locks.match(p.name))


def _one_line_error(capsys) -> str:
    err = [x for x in capsys.readouterr().err.strip().splitlines()   # device notes aside
           if not x.startswith(("warpe-cl: qualifying", "warpe-cl: warning:"))]
    assert len(err) == 1, err
    return err[0]


# --------------------------------------------------------------------------- locks (1, 5)

def test_a_held_manifest_lock_refuses_a_second_sweep(preset, tmp_path, capsys):
    """Another sweep writing this manifest: exit 2, one line naming the folder and that
    sweep's pid, host and start; nothing of the folder touched."""
    folder = tmp_path / "db"
    folder.mkdir()
    lock = sweep_module._Lock.take(folder / ".manifest.json.lock")
    lock.claim("2026-01-01T00:00:00+00:00")
    try:
        rc = main(["sweep", str(preset), "--out", str(folder), "--quiet"])
        err = _one_line_error(capsys)
        assert rc == 2 and str(folder) in err and "another sweep" in err, err
        assert f"pid {os.getpid()}" in err and "started 2026-01-01" in err, err
        assert sorted(p.name for p in folder.iterdir()) == [".manifest.json.lock",
                                                             ".warpe-cl.lock"]
        with pytest.raises(ConfigError, match="is writing this database"):
            quiet_sweep(preset, folder)
    finally:
        lock.release()
    assert quiet_sweep(preset, folder).done == 4          # free again
    assert not _hidden(folder), "temporary files left behind"


def test_two_resumes_at_once_the_second_is_refused(db, capsys):
    """A --resume while another --resume of the same manifest runs: refused (exit 2) before
    it deletes the running one's temporary files (it once did, FileNotFoundError)."""
    folder, preset = db
    victim = next(folder.glob("s00001_*.nc"))
    victim.unlink()                                   # something left to compute
    running = folder / f".{victim.name}.0a1b2c3d.tmp.nc"
    running.write_bytes(b"\x89HDF being written by the first --resume")
    lock = sweep_module._Lock.take(folder / ".manifest.json.lock")
    lock.claim("2026-01-01T00:00:00+00:00")
    try:
        rc = main(["sweep", str(preset), "--out", str(folder), "--resume", "--quiet"])
        err = _one_line_error(capsys)
        assert rc == 2 and "another sweep" in err and "--resume" in err, err
        assert running.exists(), "the running sweep's temporary file was deleted"
    finally:
        lock.release()
        running.unlink()
    assert main(["sweep", str(preset), "--out", str(folder), "--resume"]) == 0
    assert "1 done, 3 skipped" in capsys.readouterr().out


def test_two_sweeps_of_different_seeds_into_one_folder(preset, tmp_path, monkeypatch):
    """Two sweeps of different seeds started together into one folder: exactly one runs, the
    other is refused (another grid), whichever order their checks come in. Sweep B starts
    while sweep A is between reading the folder's manifests and writing its own."""
    folder = tmp_path / "db"
    folder.mkdir()
    real = sweep_module.read_manifests
    outcome = {}

    def run(name, seed):
        try:
            outcome[name] = quiet_sweep(preset, folder, overrides={"simulation.seed": seed}).done
        except ConfigError as err:
            outcome[name] = err

    started = []

    def read_manifests(path):
        found = real(path)
        if not started:                 # sweep A has read the folder: B starts now
            started.append(threading.Thread(target=run, args=("B", 7)))
            started[0].start()
            started[0].join(timeout=0.5)
        return found
    monkeypatch.setattr(sweep_module, "read_manifests", read_manifests)
    run("A", 1)
    started[0].join(timeout=120)
    refused = [n for n, v in outcome.items() if isinstance(v, ConfigError)]
    assert len(outcome) == 2 and len(refused) == 1, outcome
    # refused by what the folder holds when its check came: the other's manifest, or already
    # its result files (the check before the lock is a read-only preview)
    assert "another grid" in str(outcome[refused[0]]) or \
        "already holds" in str(outcome[refused[0]]), outcome
    seeds = {int(h5py.File(p, "r").attrs["seed"][0]) for p in folder.glob("s*.nc")}
    assert len(seeds) == 1 and len(list(folder.glob("s*.nc"))) == 4, "files mixed"


# --------------------------------------------------------------------------- resume (2)

def test_resume_rejects_files_of_another_seed_and_photons(db, capsys):
    """A folder whose manifest was lost, refilled with --resume --seed 7 --photons 200: every
    file (seed 1, 300 photons) is named, moved to rejected/ with its reason, and recomputed;
    none is counted as skipped."""
    folder, preset = db
    (folder / "manifest.json").unlink()
    names = sorted(p.name for p in folder.glob("s*.nc"))
    rc = main(["sweep", str(preset), "--out", str(folder), "--resume", "--seed", "7",
               "--photons", "200"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert "4 done, 0 skipped" in captured.out
    lines = [x for x in captured.err.splitlines() if "rejected/" in x]
    assert len(lines) == 4 and all("holds seed 1, this run has seed 7" in x for x in lines)
    assert sorted(p.name for p in (folder / "rejected").glob("s*.nc")) == names
    reason = (folder / "rejected" / f"{names[0]}.reason.txt").read_text()
    assert "seed 1" in reason
    db = warpe_cl.open_database(folder)
    assert (db["photons"] == 200).all() and list(db["scenario"].values) == [0, 1, 2, 3]


def test_resume_rejects_truncated_and_changed_files(db, capsys):
    folder, preset = db
    files = sorted(folder.glob("s*.nc"))
    data = files[1].read_bytes()
    files[1].write_bytes(data[: len(data) // 2])                    # a node crash
    data = bytearray(files[2].read_bytes())
    data[len(data) // 2] ^= 0x01                                     # one flipped bit
    files[2].write_bytes(bytes(data))
    rc = main(["sweep", str(preset), "--out", str(folder), "--resume"])
    captured = capsys.readouterr()
    assert rc == 0 and "2 done, 2 skipped" in captured.out, captured
    err = [x for x in captured.err.splitlines() if "rejected/" in x]
    assert len(err) == 2
    assert files[1].name in err[0] and "unreadable" in err[0]
    assert files[2].name in err[1] and "sha256" in err[1]
    rows = read_manifest(folder)["scenarios"]
    assert [r["this_run"] for r in rows] == ["skipped", "computed", "computed", "skipped"]
    assert len(warpe_cl.open_database(folder)["scenario"]) == 4


# --------------------------------------------------------------------------- reading (3)

def test_every_done_row_records_its_files_sha256(done_db):
    folder, _ = done_db
    from warpe_cl.database import file_sha256
    rows = read_manifest(folder)["scenarios"]
    assert all(r["sha256"] == file_sha256(folder / r["file"]) for r in rows)


@pytest.mark.parametrize("damage, message", [
    ("truncate", "sha256"), ("flip", "sha256"), ("delete", "is missing")])
def test_open_database_names_a_damaged_file(db, damage, message, capsys):
    """A truncated, changed or missing file: ConfigError naming it and --resume, never a
    Dataset of the others, nor an HDF5 error naming no file; `plot DIR` exits 2."""
    folder, _ = db
    path = sorted(folder.glob("s*.nc"))[2]
    data = bytearray(path.read_bytes())
    if damage == "truncate":
        path.write_bytes(bytes(data[: len(data) - 4096]))
    elif damage == "flip":
        data[len(data) // 2] ^= 0x10
        path.write_bytes(bytes(data))
    else:
        path.unlink()
    with pytest.raises(ConfigError) as caught:
        warpe_cl.open_database(folder)
    text = str(caught.value)
    assert str(path) in text and message in text and "--resume" in text, text
    assert len(text.splitlines()) == 1
    assert main(["plot", str(folder), "--out", str(folder.parent / "x.png")]) == 2
    assert "--resume" in _one_line_error(capsys)


# --------------------------------------------------------------------------- manifests (4)

def _swap_points(m):
    rows = m["scenarios"]
    rows[0]["point"], rows[1]["point"] = rows[1]["point"], rows[0]["point"]


def _swap_files(m):
    rows = m["scenarios"]
    rows[0]["file"], rows[1]["file"] = rows[1]["file"], rows[0]["file"]


def _other_folder(m):
    m["scenarios"][0]["file"] = "../other/" + m["scenarios"][0]["file"]


@pytest.mark.parametrize("tamper, key", [
    (_swap_points, "sweep_point"),
    (_swap_files, "scenarios[0].file"),
    (_other_folder, "scenarios[0].file"),
    (lambda m: m.pop("fingerprint"), "fingerprint"),
    (lambda m: m["scenarios"][3].update(index="3"), "scenarios[3].index"),
    (lambda m: m.update(scenarios={}), "scenarios"),
])
def test_a_tampered_manifest_is_refused(db, tamper, key, capsys):
    """Swapped points or files, a file elsewhere, a missing fingerprint, a mistyped index:
    open_database and sweep --resume refuse with one line naming the file and the key
    (never relabelled data, another grid's result or a Python error)."""
    folder, preset = db
    manifest = read_manifest(folder)
    tamper(manifest)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ConfigError, match=key.replace("[", r"\[").replace("]", r"\]")):
        warpe_cl.open_database(folder)
    assert main(["sweep", str(preset), "--out", str(folder), "--resume", "--quiet"]) == 2
    assert "manifest.json" in _one_line_error(capsys)


@pytest.mark.parametrize("content", ["[]", '"text"', "{}"])
def test_a_manifest_that_is_no_mapping_or_empty_is_refused(db, content, capsys):
    folder, preset = db
    (folder / "manifest.json").write_text(content)
    with pytest.raises(ConfigError, match="manifest.json"):
        warpe_cl.open_database(folder)
    assert main(["sweep", str(preset), "--out", str(folder), "--resume", "--quiet"]) == 2
    assert "manifest.json" in _one_line_error(capsys)


# --------------------------------------------------------------------------- folders (6)

def test_a_folder_that_is_not_a_database_is_refused(preset, tmp_path, capsys):
    folder = tmp_path / "thesis"
    folder.mkdir()
    (folder / "notes.txt").write_text("mine")
    for extra in ([], ["--resume"]):
        rc = main(["sweep", str(preset), "--out", str(folder), *extra])
        err = _one_line_error(capsys)
        assert rc == 2 and "not a warpe-cl sweep database" in err and "notes.txt" in err, err
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt"]


def test_out_file_of_something_else_needs_overwrite(preset, tmp_path):
    out = tmp_path / "all.nc"
    out.write_text("not a combined file of this grid")
    with pytest.raises(ConfigError, match="--overwrite"):
        quiet_sweep(preset, out)
    assert out.read_text() == "not a combined file of this grid"
    assert not (tmp_path / "all.sweep").exists()
    assert quiet_sweep(preset, out, overwrite=True).combined == out
    combined = warpe_cl.open_database(tmp_path / "all.sweep")
    assert h5py.File(out, "r").attrs["sweep_fingerprint"] == combined.attrs["sweep_fingerprint"]
    # the combined file of this same grid is no obstacle
    assert quiet_sweep(preset, out, resume=True).skipped == 4


# --------------------------------------------------------------------------- grids (7)

def test_duplicate_values_of_a_swept_key_are_refused():
    from warpe_cl.config import load_grid
    raw = yaml.safe_load(GRID)
    raw["sweep"] = {"medium.thickness": ["10 mm", "5 mm", "1 cm"]}
    with pytest.raises(ConfigError) as caught:
        load_grid(raw)
    text = str(caught.value)
    assert "sweep.medium.thickness" in text and "10 mm" in text and "1 cm" in text, text
    raw["sweep"] = {"medium.radiative.tau0": [0.5, 0.50]}
    with pytest.raises(ConfigError, match="tau0"):
        load_grid(raw)


def test_a_grid_of_too_many_points_is_refused_before_expanding():
    """10^4 x 10^4 points (once: a MemoryError after minutes) is refused at once, from the
    product of the axis lengths."""
    import time
    from warpe_cl.config import load_grid
    from warpe_cl.config.grid import MAX_GRID_POINTS
    raw = yaml.safe_load(GRID)
    raw["sweep"] = {"medium.thickness": [f"{i} um" for i in range(1, 10001)],
                    "medium.radiative.tau0": [0.001 * i for i in range(1, 10001)]}
    t0 = time.perf_counter()
    with pytest.raises(ConfigError, match=f"at most {MAX_GRID_POINTS}") as caught:
        load_grid(raw)
    assert time.perf_counter() - t0 < 5 and "100000000" in str(caught.value)


# --------------------------------------------------------------------------- stops (8)

def test_a_dropped_sigterm_stops_the_sweep_between_scenarios(preset, tmp_path, monkeypatch):
    """A SIGTERM whose exception was lost (stops.py) is raised again between two scenarios:
    the sweep stops after the first, its one line and its manifest count it."""
    from warpe_cl import stops

    def dropped(point):
        stops._pending = signal.SIGTERM      # as the handler records it
        return "somewhere"
    monkeypatch.setattr(sweep_module, "point_text", dropped)
    folder = tmp_path / "db"
    try:
        with pytest.raises(stops.Terminated) as caught:
            quiet_sweep(preset, folder)
    finally:
        stops.clear()
    summary = caught.value.summary
    assert (summary.done, summary.pending) == (1, 3)
    rows = [r for r in read_manifest(folder)["scenarios"] if r["status"] == "done"]
    assert [r["file"] for r in rows] == [p.name for p in folder.glob("s*.nc")]
    assert not _hidden(folder), "temporary files left behind"


# --------------------------------------------------------------------------- review of issue 39

def test_a_busy_folder_lock_is_waited_for_and_never_called_deletable(preset, tmp_path, capsys,
                                                                     monkeypatch):
    """Other sweeps holding the folder lock longer than a minute (32 shards of a large grid
    queue for it): the sweep waits, says so every few seconds, and never tells the user to
    delete a live lock file."""
    monkeypatch.setattr(sweep_module, "FOLDER_LOCK_WAIT_S", 0.3, raising=False)
    monkeypatch.setattr(sweep_module, "FOLDER_LOCK_NOTE_S", 0.3, raising=False)
    folder = tmp_path / "db"
    folder.mkdir()
    busy = sweep_module._Lock.take(folder / sweep_module.FOLDER_LOCK)
    busy.claim("2026-01-01T00:00:00+00:00")
    timer = threading.Timer(1.5, busy.release)
    timer.start()
    try:
        rc = main(["sweep", str(preset), "--out", str(folder), "--quiet"])
    finally:
        timer.cancel()
        busy.release()
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "delete" not in err and "waiting" in err and f"pid {os.getpid()}" in err, err


def test_resume_checks_files_outside_the_folder_lock(db, monkeypatch):
    """Hashing a shard's files on --resume happens without the folder lock (other shards
    need it), under the shard's own manifest lock."""
    folder, preset = db
    real = sweep_module._file_problem
    seen = []

    def problem(path, *args):
        other = sweep_module._Lock.take(folder / sweep_module.FOLDER_LOCK)
        seen.append(other is not None)
        if other is not None:
            other.release()
        return real(path, *args)
    monkeypatch.setattr(sweep_module, "_file_problem", problem)
    assert quiet_sweep(preset, folder, resume=True).skipped == 4
    assert seen and all(seen), "files hashed under the folder lock"


def test_resume_after_another_shard_layout_keeps_a_correct_file(preset, tmp_path, capsys):
    """Manifests of shards 0/2 and 1/2 remain; s00000 is deleted and recomputed by an
    unsharded --resume (new bytes: wall_time differs). A further --resume keeps it: the file
    is checked as open_database checks it, not against the stale shard row."""
    folder = tmp_path / "db"
    for shard in ((0, 2), (1, 2)):
        assert quiet_sweep(preset, folder, shard=shard).done == 2
    next(folder.glob("s00000_*.nc")).unlink()
    assert quiet_sweep(preset, folder, resume=True).done == 1
    warpe_cl.open_database(folder)
    capsys.readouterr()
    summary = quiet_sweep(preset, folder, resume=True)
    assert (summary.done, summary.skipped) == (0, 4), capsys.readouterr().err
    assert not (folder / "rejected").exists()


def test_releasing_a_lock_never_removes_another_holders_file(tmp_path):
    """A lock file deleted by hand and taken again by another run: releasing the first lock
    leaves the new holder's file in place (and so its lock)."""
    path = tmp_path / ".warpe-cl.lock"
    first = sweep_module._Lock.take(path)
    path.unlink()
    second = sweep_module._Lock.take(path)
    assert second is not None
    first.release()
    assert path.exists(), "the new holder's lock file was removed"
    assert sweep_module._Lock.take(path) is None, "the new holder lost its lock"
    second.release()
    assert path.exists()            # lock files stay, reused by the next run
    assert sweep_module._Lock.take(path) is not None


def test_a_bad_other_shard_does_not_fail_this_shards_combined_file(preset, tmp_path, capsys,
                                                                   monkeypatch):
    """Reading the folder for the combination refusing it (another shard's damaged file)
    after this shard finished its own work: one warning line, no X.nc and no store, exit 0."""
    out = tmp_path / "all.nc"

    def refuse(folder):
        raise ConfigError("its sha256 is not the one recorded\x1b[31m", key="s00001_x.nc")
    monkeypatch.setattr(sweep_module, "read_folder", refuse)
    rc = main(["sweep", str(preset), "--out", str(out), "--quiet"])
    err = [x for x in capsys.readouterr().err.splitlines()
           if not x.startswith("warpe-cl: qualifying")]
    assert rc == 0, err
    assert len(err) == 1 and "s00001_x.nc" in err[0] and "\x1b" not in err[0], err
    assert "database.nc" in err[0] and "all.nc" in err[0]
    assert not out.exists() and not (tmp_path / "all.sweep" / "database.nc").exists()


def test_a_device_error_on_resume_comes_before_files_are_moved(db, monkeypatch):
    """--resume with a damaged file and no usable device: DeviceError before any file is
    moved to rejected/ or the manifest rewritten."""
    from warpe_cl.errors import DeviceError
    folder, preset = db
    path = sorted(folder.glob("s*.nc"))[1]
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))
    before = (folder / "manifest.json").read_bytes()
    real = sweep_module.Workers.open

    def open_(scheduler, device, runnable):
        if runnable:
            raise DeviceError("no usable OpenCL device")
        return real(scheduler, device, runnable)
    monkeypatch.setattr(sweep_module.Workers, "open", staticmethod(open_))
    with pytest.raises(DeviceError):
        quiet_sweep(preset, folder, resume=True)
    assert path.exists() and not (folder / "rejected").exists()
    assert (folder / "manifest.json").read_bytes() == before


def test_a_rejected_file_line_is_printable(preset, tmp_path, capsys):
    """The --resume line naming a rejected file goes through errors.printable."""
    folder = tmp_path / "db\x1b[31m"
    assert quiet_sweep(preset, folder).done == 4
    path = sorted(folder.glob("s*.nc"))[0]
    path.write_bytes(path.read_bytes()[:1000])
    capsys.readouterr()
    assert quiet_sweep(preset, folder, resume=True).done == 1
    err = [x for x in capsys.readouterr().err.splitlines() if "rejected/" in x]
    assert len(err) == 1 and "\x1b" not in err[0] and "\\x1b" in err[0], err


def test_a_rejected_that_is_a_file_is_one_line(db, capsys):
    folder, preset = db
    path = sorted(folder.glob("s*.nc"))[0]
    path.write_bytes(path.read_bytes()[:1000])
    (folder / "rejected").write_text("mine")
    rc = main(["sweep", str(preset), "--out", str(folder), "--resume", "--quiet"])
    err = _one_line_error(capsys)
    assert rc == 2 and "rejected" in err, err
    assert (folder / "rejected").read_text() == "mine"


def test_an_unreadable_folder_is_one_line(preset, tmp_path, capsys, monkeypatch):
    """A folder whose listing is refused (PermissionError): exit 2 in one line (root reads
    any folder, so the refusal is simulated)."""
    folder = tmp_path / "db"
    folder.mkdir()
    real = Path.iterdir

    def iterdir(self):
        if self == folder:
            raise PermissionError(13, "Permission denied", str(self))
        return real(self)
    monkeypatch.setattr(Path, "iterdir", iterdir)
    rc = main(["sweep", str(preset), "--out", str(folder), "--quiet"])
    err = _one_line_error(capsys)
    assert rc == 2 and str(folder) in err and "Permission denied" in err, err


def test_a_failed_record_carries_no_sha256(preset, tmp_path, monkeypatch):
    """A scenario that fails after its file was written and hashed (here: its Dataset lacks
    ``photons``): the record says failed and names no SHA-256, which only a done file has."""
    from warpe_cl import api
    real = api.simulate_point

    def no_photons(*args, **kw):
        return real(*args, **kw).drop_vars("photons")
    monkeypatch.setattr(api, "simulate_point", no_photons)
    folder = tmp_path / "db"
    summary = quiet_sweep(preset, folder)
    assert summary.exit_code == 1 and len(summary.failed) == 4
    rows = read_manifest(folder)["scenarios"]
    assert all(r["status"] == "failed" and "sha256" not in r for r in rows), rows
