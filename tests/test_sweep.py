"""Sweeps as a database: the same bits locally, by shards, on Dask and from `run`; resume after
SIGKILL; a bad point recorded while the others complete; open_database's layout."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import warpe_cl
from warpe_cl.cli import main
from warpe_cl.config import load_grid, load_preset
from warpe_cl.errors import ConfigError
from conftest import read_manifest, tiny_grid

GRID = tiny_grid(photons=3000, seed=3)
THICKNESS = ["5 mm", "5 mm", "10 mm", "10 mm"]          # outer product, first key slowest
TAU0 = ["0.5", "2.0", "0.5", "2.0"]

BAD_POINT = """\
name: bad_point
medium:
  texture: granular
  thickness: "1 mm"
  compacity: 0.5
  inclusions:
    - {material: H2O, proportion: 1.0, grain_size: "100 um"}
simulation:
  photons: 300
  time_bins: {start: "1e-3 ns", stop: "1e3 ns", per_decade: 5}
sweep:
  medium.compacity: [0.5, 1.2, 1.0, 0.3]
"""


def _preset(tmp_path, text=GRID, name="grid.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _hidden(folder: Path) -> list:
    """Hidden names in ``folder`` but the lock files, which stay (docs/cluster.md): the
    folder's ``.warpe-cl.lock``, the store's ``.database.nc.lock`` and a manifest's
    ``.<manifest>.lock``."""
    locks = re.compile(r"^\.(warpe-cl|database\.nc|manifest(-shard-\d+-of-\d+)?\.json)"
                       r"\.lock$")
    return sorted(p.name for p in folder.glob(".*") if not locks.match(p.name))



def _assert_same_bits(a: xr.Dataset, b: xr.Dataset):
    """Every variable but the wall time identical, bit for bit."""
    assert sorted(a.data_vars) == sorted(b.data_vars)
    for name in a.data_vars:
        if name != "wall_time":
            assert np.array_equal(a[name].values, b[name].values), name


# --------------------------------------------------------------------------- grids

def test_grid_points_are_those_of_run():
    raw = yaml_load(GRID)
    grid = load_grid(raw)
    run_points = load_preset(raw).sweep_points()
    assert grid.keys == ["medium.thickness", "medium.radiative.tau0"]
    assert [p for p, _ in grid.points] == [p for p, _ in run_points]
    assert all(c.data == r.data for (_, c), (_, r) in zip(grid.points, run_points))


def test_list_override_becomes_a_sweep_axis():
    raw = yaml_load(GRID)
    del raw["sweep"]
    grid = load_grid(raw, ['medium.thickness=["1 mm", "2 mm", "3 mm"]', "simulation.photons=10"])
    assert grid.keys == ["medium.thickness"] and len(grid.points) == 3
    assert [c.get("medium.thickness") for _, c in grid.points] == [0.001, 0.002, 0.003]
    assert all(c.get("simulation.photons") == 10 for _, c in grid.points)
    # a list on a swept key replaces that axis; other axes stay, in their order
    grid = load_grid(yaml_load(GRID), ["medium.radiative.tau0=[3.0]"])
    assert grid.keys == ["medium.thickness", "medium.radiative.tau0"] and len(grid.points) == 2


def test_a_bad_value_rejects_only_its_point():
    grid = load_grid(yaml_load(BAD_POINT))
    errors = [c for _, c in grid.points if isinstance(c, ConfigError)]
    assert len(errors) == 1 and "medium.compacity" in str(errors[0]) and "1.2" in str(errors[0])
    with pytest.raises(ConfigError, match="unknown key"):
        load_grid(yaml_load(GRID.replace("medium.thickness:", "medium.thicknes:")))


def yaml_load(text):
    import yaml
    return yaml.safe_load(text)


# --------------------------------------------------------------------------- same bits

@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The grid computed by `warpe-cl run` (all points in one file) and by a local sweep."""
    tmp = tmp_path_factory.mktemp("sweep")
    preset = _preset(tmp)
    assert main(["run", str(preset), "--out", str(tmp / "run.nc"), "--quiet"]) == 0
    assert main(["sweep", str(preset), "--out", str(tmp / "local"), "--quiet"]) == 0
    return tmp, preset, xr.load_dataset(tmp / "run.nc"), warpe_cl.open_database(tmp / "local")


def test_local_sweep_equals_run(reference):
    tmp, _, run, local = reference
    _assert_same_bits(local, run)
    assert list(local["scenario"].values) == [0, 1, 2, 3]
    assert list(local["medium.thickness_text"].values) == THICKNESS
    assert list(local["medium.thickness"].values) == [0.005, 0.005, 0.01, 0.01]
    assert local["medium.thickness"].attrs["units"] == "m"
    assert list(local["medium.radiative.tau0"].values) == [float(t) for t in TAU0]
    assert run["medium.thickness"].dtype.kind == "f" and run["medium.thickness"].attrs == \
        local["medium.thickness"].attrs
    assert np.allclose(local["thickness_m"], [0.005, 0.005, 0.01, 0.01], rtol=1e-12)
    assert set(local.coords) == set(run.coords) and set(local.dims) == set(run.dims)
    manifest = read_manifest(tmp / "local")
    assert [r["status"] for r in manifest["scenarios"]] == ["done"] * 4
    assert [r["key"] for r in manifest["scenarios"]] == list(run["scenario_key"].values)
    for rec in manifest["scenarios"]:
        assert rec["file"] == f"s{rec['index']:05d}_{rec['key']}.nc" and len(rec["key"]) == 16
        assert rec["photons"] == 3000 and rec["wall_time_s"] > 0
    assert manifest["versions"]["warpe_cl"] and manifest["keys"] == ["medium.thickness",
                                                                      "medium.radiative.tau0"]


def test_grid_unstacks_numerically(reference):
    """open_database(grid=True) and as_grid: one dimension per swept key, sorted by value
    (10 mm after 5 mm, not before it as text), the same from a run's file and a database."""
    tmp, _, run, local = reference
    for ds in (warpe_cl.open_database(tmp / "local", grid=True), warpe_cl.as_grid(run)):
        assert ds["reflectance"].dims[:2] == ("thickness", "radiative_tau0")
        assert list(ds["thickness"].values) == [0.005, 0.01]
        assert list(ds["thickness_text"].values) == ["5 mm", "10 mm"]
        assert ds["thickness"].attrs["sweep_key"] == "medium.thickness"
        assert ds["thickness"].attrs["units"] == "m"
        assert list(ds["radiative_tau0"].values) == [0.5, 2.0]   # tau0: the derived one
        assert ds["scenario"].values.tolist() == [[0, 1], [2, 3]]
        flat = run["reflectance"].values.reshape(2, 2, *run["reflectance"].shape[1:])
        assert np.array_equal(ds["reflectance"].values, flat)


def test_grid_names_and_order():
    """Swept text sorts as numbers; a dotted key's last part names its dimension when unique."""
    from warpe_cl import dataset
    ds = [xr.Dataset({"a": ("t", np.arange(3.0) + i), "time_edges": ("e", [1.0, 2.0])})
          for i in range(4)]
    points = [{"medium.inclusions[0].grain_size": g, "medium.compacity": c}
              for g in ("50 um", "1 cm") for c in (0.3, 0.25)]
    out = dataset.as_grid(dataset.combine_scenarios(ds, points))
    assert list(out["grain_size"].values) == [5e-5, 0.01]
    assert list(out["grain_size_text"].values) == ["50 um", "1 cm"]
    assert list(out["compacity"].values) == [0.25, 0.3]
    assert out["scenario"].values.tolist() == [[1, 0], [3, 2]]
    assert dataset.grid_name("medium.inclusions[1].grain_size",
                             ["medium.inclusions[0].grain_size", "medium.inclusions[1].grain_size"]
                             ) == "inclusions_1_grain_size"
    part = dataset.as_grid(dataset.combine_scenarios(ds, points).isel(scenario=[0, 1, 3]))
    assert np.isnan(part["a"].values[1, 1, 0]) and part["scenario"].values[0, 1] == 0


def test_fast_scenario_reader_matches_xarray(reference):
    """open_database reads scenario files with h5py into a template's layout: the same
    values, types and attributes as xarray.load_dataset gives."""
    from warpe_cl.database import _read_scenario
    tmp = reference[0]
    files = sorted((tmp / "local").glob("s*.nc"))
    template = xr.load_dataset(files[0], engine="h5netcdf")
    for path in files:
        slow, fast = xr.load_dataset(path, engine="h5netcdf"), _read_scenario(path, template)
        assert fast.identical(slow), path.name
        for name, value in slow.attrs.items():
            assert type(fast.attrs[name]) is type(value), name
        for name in slow.variables:
            assert fast[name].dtype == slow[name].dtype, name
    assert template.identical(xr.load_dataset(files[0], engine="h5netcdf"))  # left untouched


def test_the_fast_reader_reads_every_file_of_a_thickness_sweep(reference, monkeypatch):
    """Scenarios of different thicknesses differ in the coordinate ``layer_thickness``: the
    fast reader takes it from each file, where it once sent every such file to xarray (ten
    times slower: 57 s for 200 files)."""
    tmp = reference[0]
    calls = []
    real = xr.load_dataset

    def counted(*args, **kw):
        calls.append(args[0])
        return real(*args, **kw)
    monkeypatch.setattr(xr, "load_dataset", counted)
    ds = warpe_cl.open_database(tmp / "local", store=False)
    assert len(calls) == 1                                  # the template alone
    assert sorted(set(ds["layer_thickness"].values.ravel())) == [0.005, 0.01]


def test_the_fast_reader_never_copies_the_templates_text(reference, tmp_path):
    """A text coordinate that differs from the template's (``layer_texture``) is read from
    the file; the template's was kept, silently."""
    from warpe_cl.database import _read_scenario
    files = sorted((reference[0] / "local").glob("s*.nc"))
    template = xr.load_dataset(files[0], engine="h5netcdf")
    other = template.copy(deep=True).assign_coords(layer_texture=("layer", ["granular"]))
    other.to_netcdf(tmp_path / "other.nc", engine="h5netcdf")
    got = _read_scenario(tmp_path / "other.nc", template)
    assert list(got["layer_texture"].values) == ["granular"]
    assert list(template["layer_texture"].values) == ["slab"]


@pytest.mark.slow
def test_shards_in_one_folder_and_in_separate_folders(reference, tmp_path, capsys):
    _, preset, run, _ = reference
    folder = tmp_path / "shards"
    for i in range(3):
        assert main(["sweep", str(preset), "--out", str(folder), "--shard", f"{i}/3",
                     "--quiet"]) == 0
        owned = [r["index"] for r in read_manifest(folder, f"manifest-shard-{i}-of-3.json")
                 ["scenarios"] if r["status"] == "done"]
        assert owned == [j for j in range(4) if j % 3 == i]     # round robin: i mod N
    _assert_same_bits(warpe_cl.open_database(folder), run)
    # shards in separate folders, merged by open_database
    parts = [tmp_path / f"part{i}" for i in range(2)]
    for i, part in enumerate(parts):
        assert main(["sweep", str(preset), "--out", str(part), "--shard", f"{i}/2",
                     "--quiet"]) == 0
    half = warpe_cl.open_database(parts[0])
    assert list(half["scenario"].values) == [0, 2]
    assert list(half["medium.thickness_text"].values) == ["5 mm", "10 mm"]
    _assert_same_bits(warpe_cl.open_database(parts), run)


@pytest.mark.slow
def test_dask_local_cluster_gives_the_same_bits(reference, tmp_path):
    import distributed  # noqa: F401 - in the test extra: this test must run, never skip
    _, preset, run, _ = reference
    folder = tmp_path / "dask"
    assert main(["sweep", str(preset), "--out", str(folder), "--scheduler", "local:2",
                 "--quiet"]) == 0
    _assert_same_bits(warpe_cl.open_database(folder), run)
    records = read_manifest(folder)["scenarios"]
    assert len({r["pid"] for r in records}) <= 2 and os.getpid() not in {r["pid"] for r in records}
    # cluster hygiene: PoCL threads from the CPUs shared by 2 workers, node-local kernel cache
    cpus = len(os.sched_getaffinity(0))
    tmp_root = os.environ.get("TMPDIR") or "/tmp"
    for r in records:
        if "POCL_MAX_PTHREAD_COUNT" not in os.environ:
            assert r["pocl_max_pthread_count"] == str(max(1, cpus // 2))
        if "POCL_CACHE_DIR" not in os.environ:
            assert r["pocl_cache_dir"].startswith(tmp_root)


@pytest.mark.slow
def test_dask_scheduler_address_needs_workers_with_the_opencl_resource(reference, tmp_path,
                                                                      capsys):
    from distributed import LocalCluster
    _, preset, run, _ = reference
    folder = tmp_path / "dask"
    # threaded workers in this process: quick to start; the address path is what is tested
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=None) as bare:
        rc = main(["sweep", str(preset), "--out", str(folder), "--scheduler",
                   bare.scheduler_address])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and len(err.splitlines()) == 1 and "--resources opencl=1" in err, err
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      resources={"opencl": 1}, dashboard_address=None) as cluster:
        assert main(["sweep", str(preset), "--out", str(folder), "--scheduler",
                     cluster.scheduler_address, "--quiet"]) == 0
    _assert_same_bits(warpe_cl.open_database(folder), run)


@pytest.mark.slow
def test_one_worker_process_per_device(reference, engine, tmp_path):
    _, preset, run, _ = reference
    folder = tmp_path / "pool"
    spec = engine.info.spec
    assert main(["sweep", str(preset), "--out", str(folder), "--device", f"{spec},{spec}",
                 "--quiet"]) == 0
    _assert_same_bits(warpe_cl.open_database(folder), run)
    assert os.getpid() not in {r["pid"] for r in read_manifest(folder)["scenarios"]}


@pytest.mark.slow
def test_one_worker_process_per_driver(reference, tmp_path):
    """The sweep over several devices (docs/cluster.md "Several GPUs"), with this machine's two
    CPU drivers standing in for two GPUs: `--device A,B` spawns one worker process per device;
    every scenario is walked on one of them, and the grid is the same bits as `warpe-cl run`
    on the session's device (the walk gives the same bits on every qualified driver)."""
    from warpe_cl.device import list_devices
    cpus = {info.spec: info.device for info, _ in list_devices() if info.kind == "cpu"}
    if len(cpus) < 2:
        pytest.skip(f"one CPU driver only ({sorted(cpus)}): no two devices to spread over")
    specs = sorted(cpus)[:2]
    _, preset, run, _ = reference
    folder = tmp_path / "drivers"
    assert main(["sweep", str(preset), "--out", str(folder), "--device", ",".join(specs),
                 "--quiet"]) == 0
    _assert_same_bits(warpe_cl.open_database(folder), run)
    records = read_manifest(folder)["scenarios"]
    assert {r["device"] for r in records} <= {cpus[s] for s in specs}, records
    assert os.getpid() not in {r["pid"] for r in records}


def test_out_file_gets_the_combined_grid(reference, tmp_path):
    _, preset, run, _ = reference
    out = tmp_path / "all.nc"
    assert main(["sweep", str(preset), "--out", str(out), "--shard", "0/2", "--quiet"]) == 0
    assert not out.exists() and (tmp_path / "all.sweep").is_dir()    # half the grid so far
    assert main(["sweep", str(preset), "--out", str(out), "--shard", "1/2", "--quiet"]) == 0
    _assert_same_bits(xr.load_dataset(out), run)


# --------------------------------------------------------------------------- resume

@pytest.mark.slow
def test_sigkill_then_resume_recomputes_nothing(tmp_path, capsys):
    # 2e6 rays per scenario: about half a second each on 2 CPU cores, so the kill lands
    # while later scenarios are still to come.
    preset = _preset(tmp_path)
    folder = tmp_path / "db"
    cmd = [sys.executable, "-m", "warpe_cl", "sweep", str(preset), "--out", str(folder),
           "--photons", "2e6"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while not list(folder.glob("s*.nc")):
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() < deadline
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    proc.stderr.close()
    before = {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in folder.glob("s*.nc")}
    assert 0 < len(before) < 4, f"the kill came too late to test resuming: {sorted(before)}"
    # a partial file a killed writer could leave: never a result, removed on resume
    pending = next(r for r in read_manifest(folder)["scenarios"] if r["file"] not in before)
    partial = folder / f".{pending['file']}.x1y2z3.tmp"
    partial.write_bytes(b"\x89HDF\r\n half a file")
    assert main(["sweep", str(preset), "--out", str(folder), "--photons", "2e6"]) == 2, \
        "without --resume, a folder holding results is refused"
    capsys.readouterr()
    assert main(["sweep", str(preset), "--out", str(folder), "--photons", "2e6",
                 "--resume"]) == 0
    out = capsys.readouterr().out
    assert f"{4 - len(before)} done, {len(before)} skipped" in out
    after = {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in folder.glob("s*.nc")}
    assert len(after) == 4 and all(after[n] == v for n, v in before.items())  # none recomputed
    assert not _hidden(folder), "temporary files left behind"
    records = read_manifest(folder)["scenarios"]
    assert [r["status"] for r in records] == ["done"] * 4
    assert sorted(r["file"] for r in records if r["this_run"] == "skipped") == sorted(before)
    db = warpe_cl.open_database(folder)
    assert list(db["scenario"].values) == [0, 1, 2, 3]
    assert (db["photons"] == 2_000_000).all()


@pytest.mark.slow
def test_sigterm_flushes_the_manifest_and_names_resume(tmp_path):
    """Slurm's time limit (SIGTERM) as Ctrl-C: exit 143, one line naming --resume, and the
    manifest lists every scenario whose file is in the folder."""
    preset = _preset(tmp_path)
    folder = tmp_path / "db"
    cmd = [sys.executable, "-m", "warpe_cl", "sweep", str(preset), "--out", str(folder),
           "--photons", "2e6", "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not list(folder.glob("s*.nc")):
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < deadline
        time.sleep(0.005)
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=60)
    err = proc.stderr.read()
    proc.stderr.close()
    assert proc.returncode == 143, err
    said = [x for x in err.splitlines() if not x.startswith("warpe-cl: warning:")]
    files = sorted(p.name for p in folder.glob("s*.nc"))
    assert len(said) == 1 and "stopped by SIGTERM after" in said[0] \
        and "--resume" in said[0], err
    assert f"after {len(files)} of 4 scenarios" in said[0], (said, files)
    done = sorted(r["file"] for r in read_manifest(folder)["scenarios"] if r["status"] == "done")
    assert done == files
    assert not _hidden(folder), "temporary files left behind"
    assert all(r["photons"] == 2_000_000 for r in read_manifest(folder)["scenarios"]
               if r["status"] == "done")


def test_a_stop_between_a_record_and_its_count_counts_it(tmp_path, monkeypatch):
    """The one line after Ctrl-C or SIGTERM counts what the manifest lists: a stop raised
    after a scenario's record is stored but before it is counted (here, in the progress text
    made between the two) still counts it. The race that once printed "after 0 of 4" with one
    file in the folder, made deterministic."""
    import warpe_cl.sweep as sweep_module

    def stop(point):
        raise KeyboardInterrupt
    monkeypatch.setattr(sweep_module, "point_text", stop)
    folder = tmp_path / "db"
    with pytest.raises(KeyboardInterrupt) as caught:
        sweep_module.run_sweep(_preset(tmp_path), folder, overrides={"simulation.photons": 300},
                               quiet=True, say=lambda line: None)
    summary = caught.value.summary
    files = sorted(p.name for p in folder.glob("s*.nc"))
    done = sorted(r["file"] for r in read_manifest(folder)["scenarios"] if r["status"] == "done")
    assert len(files) == 1 and done == files
    assert (summary.done, summary.pending, summary.photons) == (1, 3, 300)


def test_a_stop_after_a_file_is_in_place_counts_it_with_its_rays(tmp_path, monkeypatch):
    """A stop raised after a scenario's file is renamed into place but before its record
    comes back (here, at the record's time stamp) counts that scenario as done, with its
    rays, in the one line and in the manifest: --resume will skip its file."""
    import warpe_cl.sweep as sweep_module
    folder = tmp_path / "db"
    real_now = sweep_module.utc_now
    stopped = []

    def now():
        if not stopped and list(folder.glob("s*.nc")):
            stopped.append(True)
            raise KeyboardInterrupt
        return real_now()
    monkeypatch.setattr(sweep_module, "utc_now", now)
    with pytest.raises(KeyboardInterrupt) as caught:
        sweep_module.run_sweep(_preset(tmp_path), folder, overrides={"simulation.photons": 300},
                               quiet=True, say=lambda line: None)
    summary = caught.value.summary
    files = sorted(p.name for p in folder.glob("s*.nc"))
    rows = [r for r in read_manifest(folder)["scenarios"] if r["status"] == "done"]
    assert len(files) == 1 and [r["file"] for r in rows] == files
    assert rows[0]["note"] == "file in place when the run was stopped"
    assert rows[0]["photons"] == 300
    assert (summary.done, summary.pending, summary.photons) == (1, 3, 300)


# --------------------------------------------------------------------------- failures

def test_a_bad_point_is_recorded_and_the_rest_completes(tmp_path, capsys):
    preset = _preset(tmp_path, BAD_POINT)
    folder = tmp_path / "db"
    assert main(["sweep", str(preset), "--out", str(folder)]) == 1
    captured = capsys.readouterr()
    assert "2 done, 0 skipped (already in the folder), 2 failed" in captured.out
    assert "medium.compacity: 1.2 is not allowed" in captured.err
    assert "Traceback" not in captured.err
    records = read_manifest(folder)["scenarios"]
    assert [r["status"] for r in records] == ["done", "failed", "failed", "done"]
    assert "1.2 is not allowed" in records[1]["error"] and records[1]["file"] is None
    assert "not allowed for a granular medium" in records[2]["error"]   # found at run time
    db = warpe_cl.open_database(folder)
    assert list(db["scenario"].values) == [0, 3]
    assert list(db["medium.compacity"].values) == [0.5, 0.3]
    assert sorted(json.loads(db.attrs["sweep_failed"])) == ["1", "2"]
    assert db.attrs["sweep_scenarios_total"] == 4
    # resume retries the failed points (they fail again) and recomputes none of the others
    assert main(["sweep", str(preset), "--out", str(folder), "--resume"]) == 1
    assert "0 done, 2 skipped (already in the folder), 2 failed" in capsys.readouterr().out


@pytest.mark.parametrize("extra, message", [
    (["--shard", "3/3"], "--shard: 3/3 is not allowed"),
    (["--shard", "x"], "--shard: x is not allowed"),
    (["--scheduler", "local:0"], "--scheduler: local:0 is not allowed"),
    (["--set", "sweep.medium.thickness=[]"], "sweep.medium.thickness"),
    (["--set", "medium.radiative.omega=[1.5, 2.0]"], "omega"),   # every point invalid
])
def test_bad_sweep_command_lines_exit_2(tmp_path, capsys, extra, message):
    preset = _preset(tmp_path)
    rc = main(["sweep", str(preset), "--out", str(tmp_path / "db"), *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "db").exists()


def test_without_dask_the_scheduler_says_what_to_install(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)      # import distributed fails
    rc = main(["sweep", str(_preset(tmp_path)), "--out", str(tmp_path / "db"),
               "--scheduler", "local:2"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "pip install 'warpe-cl[cluster]'" in err


def test_a_folder_holds_one_grid(reference, tmp_path, capsys):
    _, preset, _, _ = reference
    folder = tmp_path / "db"
    assert main(["sweep", str(preset), "--out", str(folder), "--shard", "0/4", "--quiet"]) == 0
    rc = main(["sweep", str(preset), "--out", str(folder), "--seed", "4", "--resume"])
    err = capsys.readouterr().err
    assert rc == 2 and "another grid" in err


def test_worker_environment_from_slurm_and_tmpdir(tmp_path):
    code = ("import os, warpe_cl.sweep as s; s.worker_environment(); "
            "print(os.environ['POCL_MAX_PTHREAD_COUNT'], os.environ['POCL_CACHE_DIR'], "
            "os.environ['PYOPENCL_CACHE_DIR'])")
    env = {k: v for k, v in os.environ.items()
           if k not in ("POCL_MAX_PTHREAD_COUNT", "POCL_CACHE_DIR", "PYOPENCL_CACHE_DIR")}
    env.update(SLURM_CPUS_PER_TASK="7", TMPDIR=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    assert out[0] == "7"
    assert all(Path(p).is_dir() and Path(p).is_relative_to(tmp_path) for p in out[1:])
    env["POCL_MAX_PTHREAD_COUNT"] = "3"                          # what the user set is kept
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    assert out[0] == "3"


# --------------------------------------------------------------------------- derived variables

GRAINS = """\
name: tiny_grains
medium:
  texture: granular
  thickness: "2 cm"
  compacity: 0.5
  inclusions:
    - {material: H2O, proportion: 1.0, grain_size: "100 um"}
simulation:
  photons: 300
  seed: 5
  time_bins: {start: "1e-3 ns", stop: "1e3 ns", per_decade: 5}
sweep:
  medium.inclusions[0].grain_size: ["1 mm", "50 um", "200 um"]
"""


@pytest.fixture(scope="module")
def grains(tmp_path_factory):
    """A physical medium swept over three grain sizes: `run`'s file and a database."""
    tmp = tmp_path_factory.mktemp("grains")
    preset = _preset(tmp, GRAINS, "grains.yaml")
    assert main(["run", str(preset), "--out", str(tmp / "run.nc"), "--quiet"]) == 0
    assert main(["sweep", str(preset), "--out", str(tmp / "db"), "--quiet"]) == 0
    return tmp, xr.load_dataset(tmp / "run.nc"), warpe_cl.open_database(tmp / "db")


@pytest.mark.slow
def test_derived_parameters_are_variables_with_units(grains):
    """tau0 ... and the per-species w and N: variables with units, the same in one scenario's
    file, a run of the grid and a database; one scenario keeps them as attributes too."""
    tmp, run, db = grains
    _assert_same_bits(db, run)
    units = {"tau0": "1", "omega": "1", "n_eff": "1", "k_eff": "1", "extinction_per_m": "m-1",
             "first_bf_time_ns": "ns", "thickness_m": "m", "species_w": "1",
             "species_number_density_per_m3": "m-3"}
    for ds in (run, db):
        for name, unit in units.items():
            assert ds[name].attrs["units"] == unit, name
        assert ds["tau0"].dims == ("scenario",)
        assert ds["species_w"].dims == ("scenario", "species")
    one = xr.load_dataset(sorted((tmp / "db").glob("s00001_*.nc"))[0])
    for name in ("tau0", "n_eff", "k_eff", "first_bf_time_ns"):
        assert one[name].values == one.attrs[name] == run[name].values[1], name
    assert np.array_equal(one["species_w"].values, np.atleast_1d(one.attrs["species_w"]))
    cfg = load_preset(tmp / "grains.yaml", overrides={"sweep": None})
    rp = warpe_cl.radiative_parameters(cfg)
    single = warpe_cl.simulate(cfg, progress=False, device="numpy")
    assert single["tau0"].values == rp["tau0"] == single.attrs["tau0"]
    assert single["species_number_density_per_m3"].values[0] == \
        rp["species"][0]["number_density_per_m3"]


@pytest.mark.slow
def test_readme_delay_vs_grain_size(grains, tmp_path, monkeypatch):
    """The README's figure from a sweep, its five lines as written (the database path aside),
    on the tiny grain-size sweep: the plotted points are the three grain sizes in order."""
    import re
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    tmp, run, _ = grains
    readme = (Path(__file__).parents[1] / "README.md").read_text(encoding="utf-8")
    code = re.search(r"<!-- delay-vs-grain-size[^>]*-->\n```python\n(.*?)```", readme,
                     re.S).group(1)
    assert len(code.strip().splitlines()) <= 5
    monkeypatch.chdir(tmp_path)
    plt.close("all")
    namespace = {}
    exec(code.replace('"db/"', repr(str(tmp / "db"))), namespace)
    assert (tmp_path / "delay_vs_grain_size.png").stat().st_size > 0
    m = namespace["m"]
    assert list(m["grain_size"].values) == [5e-5, 2e-4, 1e-3]
    assert list(m["grain_size_text"].values) == ["50 um", "200 um", "1 mm"]
    expected = warpe_cl.metrics(run).sel(component="scattering")["mean_delay"].values
    assert np.array_equal(m["mean_delay"].values, expected[[1, 2, 0]])
    x = plt.gca().lines[0].get_xdata()
    assert np.allclose(x, [50, 200, 1000])
    plt.close("all")


def test_in_memory_netcdf_touches_no_dask_config(reference, tmp_path, monkeypatch):
    """Outputs.netcdf builds its image under its own lock, never through dask's global
    configuration (not thread-safe: a worker's other thread could restore it mid-write),
    and writes the same data as ``to_netcdf(path, engine="h5netcdf")``."""
    import dask
    from warpe_cl.io import write_netcdf
    _, _, run, _ = reference
    ds = run.isel(scenario=0) if "scenario" in run.dims else run

    def refuse(*args, **kwargs):
        raise AssertionError("dask.config.set called")
    monkeypatch.setattr(dask.config, "set", refuse)
    ours, theirs = tmp_path / "ours.nc", tmp_path / "theirs.nc"
    write_netcdf(ds, ours)
    monkeypatch.undo()
    ds.to_netcdf(theirs, engine="h5netcdf")
    a, b = xr.load_dataset(ours, engine="h5netcdf"), xr.load_dataset(theirs, engine="h5netcdf")
    assert a.identical(b)
    for name in a.variables:
        assert a[name].values.tobytes() == b[name].values.tobytes(), name
