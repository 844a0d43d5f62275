"""Sweeps as a resumable scenario database: the plan, the manifest, and :func:`run_sweep`.

``warpe-cl sweep PRESET.yaml --out DIR`` (docs/interface.md §2) runs every point of the preset's
``sweep:`` block (the outer product, :func:`warpe_cl.config.load_grid`) and writes

``DIR/s00003_1a2b3c4d5e6f7081.nc``
    One NetCDF file per scenario: the grid index and the 64-bit Philox scenario key
    (:func:`warpe_cl.api.scenario_key`, 16 hex digits). Written atomically (a hidden temporary file
    renamed into place), so a file of that name is always a complete result.
``DIR/manifest.json`` (``DIR/manifest-shard-I-of-N.json`` for ``--shard I/N``)
    The preset, the swept keys, every point with its key, file, configuration hash and status
    (``done``, ``failed`` with its one-line error, ``pending``, or ``other shard``), photons,
    wall time, device, versions; rewritten atomically as results come in. One manifest per
    shard, so that shards sharing a folder never write the same file.

A scenario's random numbers are keyed by (seed, scenario key), and its key is a hash of its own
resolved configuration (seed and photons apart): the same point gives the same bits whichever
grid, process, shard, worker or order computes it, and the same bits as ``warpe-cl run`` gives
for that point alone. Scenario ``i`` belongs to shard ``i mod N`` (round robin, so costly
regions of a grid spread over the shards).

The sweep is in three modules:

- here, what one sweep does: its plan (:func:`plan`), its manifest, the scenario task
  (:func:`run_scenario`) and :func:`run_sweep`;
- :mod:`warpe_cl.workers`, where the scenarios run (this process, one spawned worker process
  per device, or Dask) and the OpenCL environment of the workers;
- :mod:`warpe_cl.database`, reading a database back (:func:`~warpe_cl.database.open_database`).
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from .database import database_folder, manifest_name, open_database, read_manifests
from .errors import ConfigError, one_line
from .io import json_default, utc_now, versions, write_text
from .progress import Progress
from .report import point_text, sweep_start_line
from .report import sweep_summary_lines as summary_lines     # docs/cluster.md imports it here
from .workers import CLUSTER_HINT, Workers, worker_environment

# open_database, summary_lines, worker_environment and CLUSTER_HINT live in database.py,
# report.py and workers.py; they stay importable from here, where earlier versions had them.
__all__ = ["run_sweep", "open_database", "SweepSummary", "parse_shard", "worker_environment",
           "CLUSTER_HINT", "summary_lines"]

FORMAT = "warpe-cl sweep database"
FORMAT_VERSION = 1
MANIFEST_INTERVAL_S = 2.0     # the manifest is rewritten at most this often (and at the end)


# --------------------------------------------------------------------------- small helpers

def _sha256(value) -> str:
    text = json.dumps(value, sort_keys=True, default=json_default, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def parse_shard(text: str | None):
    """``"I/N"`` -> ``(I, N)`` with 0 <= I < N; None -> None."""
    if text is None:
        return None
    match = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", str(text))
    if not match or int(match[2]) < 1 or int(match[1]) >= int(match[2]):
        raise ConfigError(f"{text} is not allowed; give I/N with 0 <= I < N, e.g. "
                          f"--shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT", key="--shard")
    return int(match[1]), int(match[2])


def _remove_partial(folder: Path, name: str) -> int:
    """Delete temporary files a killed writer of ``name`` left behind (``.NAME.X.tmp`` and
    ``.NAME.X.tmp.EXT``, warpe_cl.io)."""
    removed = 0
    for tmp in folder.glob(f".{name}.*.tmp*"):
        try:
            tmp.unlink()
            removed += 1
        except FileNotFoundError:
            pass
    return removed


# --------------------------------------------------------------------------- one scenario

def run_scenario(task: dict) -> dict:
    """Compute one scenario and write its file atomically; runs in any process.

    Parameters
    ----------
    task : dict
        ``index``, ``point`` (swept values as written), ``cfg`` (the point's Config), ``path``
        (the result file), ``device`` (spec or None), ``threads`` (PoCL threads or None),
        ``fingerprint`` (of the grid), ``progress`` (ray progress bar: None or False).

    Returns
    -------
    dict
        ``index``, ``status`` (``done`` or ``failed``), ``error``, ``photons``,
        ``wall_time_s``, ``device``, ``host``, ``pid``, ``finished_utc``. Errors are
        returned, never raised, so that one bad point does not stop the others.
    """
    worker_environment(task.get("threads"))
    import platform
    record = {"index": task["index"], "host": platform.node(), "pid": os.getpid(),
              "pocl_max_pthread_count": os.environ.get("POCL_MAX_PTHREAD_COUNT"),
              "pocl_cache_dir": os.environ.get("POCL_CACHE_DIR")}
    t0 = time.perf_counter()
    try:
        from . import api, io
        ds = api.simulate_point(task["cfg"], task["point"], task["device"], task.get("progress"))
        ds.attrs.update({
            "sweep_index": int(task["index"]),
            "sweep_point": json.dumps(task["point"], sort_keys=True, default=str),
            "sweep_fingerprint": task["fingerprint"],
        })
        io.write_netcdf(ds, task["path"])
        record.update(status="done", error=None, photons=int(ds["photons"]),
                      wall_time_s=float(ds["wall_time"]),
                      device=str(ds.attrs.get("opencl_device", "?")))
    except Exception as err:  # noqa: BLE001 - recorded in the manifest, the sweep goes on
        record.update(status="failed", error=one_line(err), photons=0,
                      wall_time_s=time.perf_counter() - t0)
    record["finished_utc"] = utc_now()
    return record


# --------------------------------------------------------------------------- the plan

@dataclass
class Scenario:
    """One point of the grid as the database sees it."""

    index: int
    point: dict
    cfg: object                     # Config, or the ConfigError that rejects the point
    key: str | None = None          # the 64-bit scenario key, 16 hex digits
    file: str | None = None
    config_sha256: str | None = None

    @property
    def valid(self) -> bool:
        return not isinstance(self.cfg, ConfigError)


def plan(grid) -> tuple:
    """Scenarios of a :class:`~warpe_cl.config.Grid` with keys, file names, and the grid's
    fingerprint (a hash of every point's resolved configuration)."""
    from .api import format_key, scenario_key
    width = max(5, len(str(len(grid.points) - 1)))
    scenarios = []
    for index, (point, cfg) in enumerate(grid.points):
        sc = Scenario(index, point, cfg)
        if sc.valid:
            sc.key = format_key(scenario_key(point, cfg))
            sc.file = f"s{index:0{width}d}_{sc.key}.nc"
            sc.config_sha256 = _sha256(cfg.data)
        scenarios.append(sc)
    fingerprint = _sha256([[s.index, s.point, s.config_sha256] for s in scenarios])
    return scenarios, fingerprint


@dataclass
class _Sweep:
    """One invocation of :func:`run_sweep` once its input is checked: the grid, this shard's
    part of it, what the folder already holds, and where the scenarios are to run."""

    grid: object                    # warpe_cl.config.Grid
    scenarios: list                 # every Scenario of the grid
    fingerprint: str
    folder: Path                    # the database folder
    combined: Path | None           # X.nc for --out X.nc
    shard: tuple | None             # (I, N)
    owned: list                     # the Scenarios of this shard
    present: set                    # indices whose result file is in the folder
    previous: dict                  # index -> the record an earlier manifest holds
    device: str | None = None
    scheduler: str | None = None

    @property
    def shard_text(self) -> str | None:
        return None if self.shard is None else f"{self.shard[0]}/{self.shard[1]}"

    @property
    def runnable(self) -> int:
        """Scenarios of this shard still to compute."""
        return sum(s.valid and s.index not in self.present for s in self.owned)


# --------------------------------------------------------------------------- the sweep

@dataclass
class SweepSummary:
    """What one ``warpe-cl sweep`` invocation did."""

    folder: Path
    total: int                      # scenarios in the grid
    owned: int                      # scenarios of this shard
    done: int = 0                   # computed now
    skipped: int = 0                # already in the folder (resume)
    failed: list = field(default_factory=list)      # (index, point, error)
    pending: int = 0                # of this shard, not finished (interrupted)
    photons: int = 0                # computed now
    wall_time_s: float = 0.0
    finished_in_folder: int = 0     # scenarios of the whole grid with a result file
    combined: Path | None = None

    @property
    def exit_code(self) -> int:
        """0: every scenario of this run is done; 1: some failed or did not finish."""
        return 0 if not self.failed and not self.pending else 1


def run_sweep(preset, out, *, overrides=None, shard=None, scheduler=None, resume=False,
              device=None, quiet=False, say=print) -> SweepSummary:
    """Run (or resume) a sweep into a database folder.

    Parameters
    ----------
    preset : str, path or dict
        The preset (its ``sweep:`` block is the grid).
    out : str or path
        The database folder, or ``X.nc``: scenarios in ``X.sweep/`` and, once every
        scenario of the grid is done, their combination in ``X.nc``.
    overrides : list of str or dict, optional
        ``--set`` values; a list on a scalar key becomes a sweep axis (:func:`load_grid`).
    shard : (int, int), optional
        ``(I, N)``: only the scenarios ``i`` with ``i % N == I``.
    scheduler : str, optional
        A Dask scheduler address, or ``local:N`` for a local cluster of N worker processes.
    resume : bool
        Keep the scenarios already in the folder and compute the others. Without it, a folder
        that already holds results for this run's scenarios is an error.
    device : str, optional
        Device spec; a comma-separated list or ``all`` (every GPU) runs one worker process
        per device.
    quiet : bool
        No progress bar and no line per scenario (failures are still printed on stderr).
    say : callable
        Prints the first line (``print``; the command line passes one that ``--quiet``
        silences).

    Returns
    -------
    SweepSummary

    Raises
    ------
    ConfigError
        Bad preset, ``--shard``, ``--scheduler``, or a folder that holds another grid.
    DeviceError
        No usable device (local engine), before anything is written.
    """
    sweep = _prepare(preset, out, overrides, shard, resume)
    sweep.device, sweep.scheduler = device, scheduler
    # Where the scenarios run; device problems surface before anything is written.
    workers = Workers.open(scheduler, device, sweep.runnable)
    try:
        return _run(sweep, workers, quiet, say)
    finally:
        workers.close()


def _prepare(preset, out, overrides, shard, resume) -> _Sweep:
    """The grid and the folder checked against each other, before anything is written.

    Raises
    ------
    ConfigError
        Every point invalid, ``--out`` not a folder or in a missing one, a folder holding
        another grid, or results of these scenarios already there without ``resume``.
    """
    from .config import load_grid
    grid = load_grid(preset, overrides)
    scenarios, fingerprint = plan(grid)
    valid = [s for s in scenarios if s.valid]
    if not valid:
        raise scenarios[0].cfg
    folder, combined = database_folder(out)
    if folder.exists() and not folder.is_dir():
        raise ConfigError("exists and is not a folder; give a database folder or a .nc name",
                          key=str(folder))
    if not folder.resolve().parent.exists():
        raise ConfigError(f"folder {folder.resolve().parent} does not exist", key="--out")
    owned = [s for s in scenarios if shard is None or s.index % shard[1] == shard[0]]

    # A folder holds one grid: every manifest already there must share our fingerprint.
    previous = {}
    for path, manifest in read_manifests(folder):
        if manifest.get("fingerprint") != fingerprint:
            raise ConfigError(
                f"holds a database of another grid ({path.name}: preset "
                f"{manifest.get('preset')}); the preset, --set, --photons or --seed differ. "
                f"Give another --out", key=str(folder))
        for rec in manifest.get("scenarios", []):
            if rec.get("status") in ("done", "failed"):
                previous.setdefault(rec["index"], rec)
    present = {s.index for s in valid if (folder / s.file).is_file()}
    if not resume and any(s.index in present for s in owned):
        count = sum(s.index in present for s in owned)
        raise ConfigError(f"already holds {count} result(s) of these scenarios; pass --resume "
                          f"to keep them and compute the rest, or give another --out",
                          key=str(folder))
    return _Sweep(grid, scenarios, fingerprint, folder, combined, shard, owned, present,
                  previous)


class _Manifest:
    """The manifest this process writes: the grid, and the status of its scenarios."""

    def __init__(self, path: Path, grid, scenarios: list, fingerprint: str, header: dict):
        self.path, self.scenarios, self.records = path, scenarios, {}
        valid = [s for s in scenarios if s.valid]
        photons = sorted({int(s.cfg.get("simulation.photons")) for s in valid})
        seeds = sorted({int(s.cfg.get("simulation.seed")) for s in valid})
        self.header = {
            "format": FORMAT, "format_version": FORMAT_VERSION, "name": valid[0].cfg.name,
            "preset": str(grid.source), "keys": grid.keys, "fingerprint": fingerprint,
            **header, "started_utc": utc_now(),
            "photons": photons[0] if len(photons) == 1 else photons,
            "seed": seeds[0] if len(seeds) == 1 else seeds,
            "preset_yaml": grid.to_yaml(),
        }
        self.written = 0.0
        _remove_partial(path.parent, path.name)

    def write(self, force: bool = False):
        """Rewrite the manifest atomically (at most every MANIFEST_INTERVAL_S unless forced)."""
        now = time.monotonic()
        if not force and now - self.written < MANIFEST_INTERVAL_S:
            return
        self.written = now
        rows = []
        for s in self.scenarios:
            row = {"index": s.index, "point": s.point, "key": s.key, "file": s.file,
                   "config_sha256": s.config_sha256}
            row.update(self.records.get(s.index, {"status": "other shard"}))
            rows.append(row)
        counts = {k: sum(r["status"] == k for r in rows) for k in ("done", "failed", "pending")}
        used = ("dask", "distributed") if "distributed" in sys.modules else ()
        manifest = {**self.header, "updated_utc": utc_now(),
                    "versions": versions(("xarray", "pyopencl") + used), "counts": counts,
                    "scenarios": rows}
        write_text(self.path, json.dumps(manifest, indent=1, default=json_default))


def _triage(sweep: _Sweep, records: dict, summary: SweepSummary) -> list:
    """Sort this shard's scenarios: invalid (failed now), already in the folder (skipped), or
    to compute (pending; returned). Fills ``records`` and ``summary``."""
    todo = []
    for s in sweep.owned:
        if not s.valid:
            records[s.index] = {"status": "failed", "error": str(s.cfg), "photons": 0}
            summary.failed.append((s.index, s.point, str(s.cfg)))
        elif s.index in sweep.present:
            old = sweep.previous.get(s.index, {})
            records[s.index] = {**(old if old.get("status") == "done" else {}),
                                "status": "done", "this_run": "skipped"}
            summary.skipped += 1
        else:
            _remove_partial(sweep.folder, s.file)          # what a killed writer left behind
            records[s.index] = {"status": "pending"}
            todo.append(s)
    return todo


def _count_from_records(summary: SweepSummary, todo: list, records: dict) -> None:
    """This run's done and failed scenarios, its rays and what is pending, from ``records``.

    Counted once, when the run ends or stops, from the records the manifest writes: a count
    kept beside them could miss the record that a signal (Ctrl-C, SIGTERM) interrupted.
    """
    computed = [(s, records[s.index]) for s in todo]
    summary.done = sum(r["status"] == "done" for _, r in computed)
    summary.photons = sum(r.get("photons") or 0 for _, r in computed if r["status"] == "done")
    summary.failed += [(s.index, s.point, r["error"]) for s, r in computed
                       if r["status"] == "failed"]
    summary.pending = sum(r["status"] == "pending" for r in records.values())


def _run(sweep: _Sweep, workers: Workers, quiet: bool, say) -> SweepSummary:
    """The body of :func:`run_sweep` once the workers are open: manifest, tasks, progress."""
    folder = sweep.folder
    folder.mkdir(parents=True, exist_ok=True)
    manifest = _Manifest(folder / manifest_name(sweep.shard), sweep.grid, sweep.scenarios,
                         sweep.fingerprint,
                         {"shard": sweep.shard_text, "engine": workers.text,
                          "device": sweep.device, "scheduler": sweep.scheduler})
    records = manifest.records
    summary = SweepSummary(folder=folder, total=len(sweep.scenarios), owned=len(sweep.owned))
    todo = _triage(sweep, records, summary)
    manifest.write(force=True)
    say(sweep_start_line(summary, manifest.header["name"], sweep.grid.source, sweep.shard,
                         len(todo), workers.text))
    for index, _, error in summary.failed:
        print(f"warpe-cl: scenario {index} failed: {error}", file=sys.stderr)

    tasks = [{"index": s.index, "point": s.point, "cfg": s.cfg, "path": str(folder / s.file),
              "device": sweep.device, "fingerprint": sweep.fingerprint, "progress": False}
             for s in todo]
    by_index = {s.index: s for s in todo}
    progress = Progress(len(todo), False if quiet else None, quiet=quiet, unit="scenario",
                        desc="sweep" if sweep.shard is None else f"shard {sweep.shard_text}",
                        dynamic_ncols=True)
    t0 = time.perf_counter()
    try:
        for rec in workers.results(run_scenario, tasks, sweep.fingerprint, quiet):
            s = by_index[rec["index"]]
            records[s.index] = {**rec, "this_run": "computed"}
            where = point_text(s.point) or "the preset"
            if rec["status"] == "done":
                progress.advance(f"{s.file} done in {rec['wall_time_s']:.2f} s ({where})")
            else:
                progress.advance(f"scenario {s.index} failed ({where}): {rec['error']}",
                                 error=True)
            manifest.write()
    except KeyboardInterrupt as err:   # Ctrl-C or SIGTERM: the manifest is flushed below
        # A scenario whose file was put in place just before the signal, but whose record had
        # not come back yet, is done: its file is complete (atomic rename), as --resume sees it.
        for s in todo:
            if records[s.index]["status"] == "pending" and (folder / s.file).is_file():
                records[s.index] = {"status": "done", "error": None, "this_run": "computed",
                                    "photons": int(s.cfg.get("simulation.photons")),
                                    "finished_utc": utc_now(),
                                    "note": "file in place when the run was stopped"}
        err.summary = summary          # the command line's one line counts the finished ones
        raise
    finally:
        progress.close()
        summary.wall_time_s = time.perf_counter() - t0
        _count_from_records(summary, todo, records)
        manifest.write(force=True)

    summary.finished_in_folder = sum((folder / s.file).is_file()
                                     for s in sweep.scenarios if s.valid)
    if sweep.combined is not None and summary.finished_in_folder == len(sweep.scenarios):
        from .io import write_netcdf
        write_netcdf(open_database(folder), sweep.combined)
        summary.combined = sweep.combined
    return summary
