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
    shard, so that shards sharing a folder never write the same file. Each done row records
    the SHA-256 of its file, taken once the file is flushed to disk (``fsync``).
``DIR/database.nc``
    The store: the whole grid in one NetCDF file, written when a run ends with every scenario
    of the grid done (:func:`_consolidate`), recorded in the manifest (``store``: its SHA-256
    and those of the scenario files it was built from), read by
    :func:`~warpe_cl.database.open_database` while it matches them.
``DIR/rejected/``
    Files ``--resume`` found wrong (another seed or grid, a different SHA-256, unreadable),
    moved aside with a ``.reason.txt`` beside each; never deleted.

A run holds two locks (:class:`_Lock`, ``flock``): the folder's (``DIR/.warpe-cl.lock``) for
the moment it checks the fingerprints of the manifests there and writes its own, so that two
runs cannot both find a folder free and claim it (a run waits for it as long as other sweeps
hold it, saying so every few seconds); and its manifest's (``DIR/.manifest.json.lock``) for
the whole run, so that two runs of the same shard never write the same files: the second
exits 2 naming the first (pid, host, start). Checking the files ``--resume`` keeps (hashing
them) needs only the manifest's lock. Lock files are never removed: removing one by name
could remove another holder's, and the next run reuses them.

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
import platform
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from . import api, stops
from .api import scenario_key
from .config import load_grid
from .database import (FORMAT, FORMAT_VERSION, MANIFEST_RE, STORE, database_folder,
                       file_sha256, finished_scenarios, h5_attribute, manifest_name,
                       open_database, read_folder, read_manifests, recorded_sha256,
                       scenario_file_name, store_problem, store_record)
from .errors import ConfigError, one_line, printable
from .io import json_default, utc_now, versions, write_netcdf, write_text
from .progress import Progress
from .report import point_text, sweep_start_line
from .scenario_keys import format_key
from .report import sweep_summary_lines as summary_lines     # docs/cluster.md imports it here
from .workers import CLUSTER_HINT, Workers, worker_environment

# open_database, summary_lines, worker_environment and CLUSTER_HINT live in database.py,
# report.py and workers.py; they stay importable from here, where earlier versions had them.
__all__ = ["run_sweep", "open_database", "SweepSummary", "parse_shard", "worker_environment",
           "CLUSTER_HINT", "summary_lines"]

MANIFEST_INTERVAL_S = 2.0     # the manifest is rewritten at most this often (and at the end)
FOLDER_LOCK = ".warpe-cl.lock"
FOLDER_LOCK_NOTE_S = 10.0     # waiting for the folder lock: a line on stderr this often
REJECTED = "rejected"
# What a run's record of an earlier run may carry forward (never a file name or a point: those
# come from the plan).
RECORD_KEYS = ("host", "pid", "pocl_max_pthread_count", "pocl_cache_dir", "error", "photons",
               "wall_time_s", "device", "finished_utc", "note")


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


def _durable(path: Path) -> str:
    """Flush a finished result file and its folder to disk (``fsync``), then its SHA-256.

    ``warpe_cl.io.write_netcdf`` renames a complete file into place; without the flush a node
    crash can still leave a file of that name truncated, or the rename undone. A result counts
    (its record says ``done``) only once this returns.
    """
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    try:
        fd = os.open(path.parent, os.O_RDONLY)
    except OSError:           # a platform without directory handles (Windows)
        return file_sha256(path)
    try:
        os.fsync(fd)
    except OSError:
        pass                  # some file systems refuse fsync on a directory
    finally:
        os.close(fd)
    return file_sha256(path)


class _Lock:
    """An exclusive lock on a file in a database folder (``fcntl.flock``).

    On Linux, ``flock`` on NFS is carried out as a POSIX lock on the whole file (the same as
    ``fcntl.lockf``), so it excludes runs on other nodes sharing the folder; on a local file
    system it also excludes another ``open`` in the same process. The holder writes who it is
    (pid, host, start) into the file, for the messages of the next comer. The file is never
    removed, only closed (unlocked): removing it by name could remove a file that another run
    has locked since (one deleted by hand and created again), and the next run reuses it.
    """

    def __init__(self, path: Path, fd: int):
        self.path, self.fd = path, fd

    @classmethod
    def take(cls, path: Path, wait_s: float | None = 0.0, note=None,
             note_s: float = 10.0) -> "_Lock | None":
        """Lock ``path`` (created if absent).

        Parameters
        ----------
        path : Path
            The lock file.
        wait_s : float or None
            How long to wait for another holder to let go, in seconds; None: as long as it
            takes.
        note : callable, optional
            Called with the seconds waited so far every ``note_s`` seconds of waiting.
        note_s : float
            See ``note``.

        Returns
        -------
        _Lock or None
            None if another process still holds it after ``wait_s``.
        """
        import fcntl
        t0 = time.monotonic()
        noted = t0
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return cls(path, fd)
            except OSError:                       # EWOULDBLOCK (EACCES on some NFS)
                now = time.monotonic()
                if wait_s is not None and now - t0 >= wait_s:
                    os.close(fd)
                    return None
                if note is not None and now - noted >= note_s:
                    noted = now
                    note(now - t0)
                time.sleep(0.05)

    def claim(self, started_utc: str) -> None:
        """Write who holds the lock: pid, host, start (read by :func:`_holder`)."""
        text = json.dumps({"pid": os.getpid(), "host": platform.node(),
                           "started_utc": started_utc})
        os.ftruncate(self.fd, 0)
        os.pwrite(self.fd, text.encode(), 0)

    def release(self) -> None:
        """Unlock: close the file, never remove it (idempotent)."""
        if self.fd is None:
            return
        os.close(self.fd)
        self.fd = None


def _holder(path: Path) -> str:
    """``pid P on HOST, started T``: who holds a lock, as written by :meth:`_Lock.claim`."""
    try:
        who = json.loads(path.read_text(encoding="utf-8"))
        return f"pid {who['pid']} on {who['host']}, started {who['started_utc']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "pid unknown, just starting"


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
        ``wall_time_s``, ``device``, ``host``, ``pid``, ``finished_utc``, and for a done
        one the ``sha256`` of its file, taken once file and folder are flushed to disk. Errors
        are returned, never raised, so that one bad point does not stop the others.
    """
    worker_environment(task.get("threads"))   # before OpenCL is first loaded in this process
    record = {"index": task["index"], "host": platform.node(), "pid": os.getpid(),
              "pocl_max_pthread_count": os.environ.get("POCL_MAX_PTHREAD_COUNT"),
              "pocl_cache_dir": os.environ.get("POCL_CACHE_DIR")}
    t0 = time.perf_counter()
    try:
        ds = api.simulate_point(task["cfg"], task["point"], task["device"], task.get("progress"))
        ds.attrs.update({
            "sweep_index": int(task["index"]),
            "sweep_point": json.dumps(task["point"], sort_keys=True, default=str),
            "sweep_fingerprint": task["fingerprint"],
        })
        write_netcdf(ds, task["path"])
        record["sha256"] = _durable(Path(task["path"]))
        record.update(status="done", error=None, photons=int(ds["photons"]),
                      wall_time_s=float(ds["wall_time"]),
                      device=str(ds.attrs.get("opencl_device", "?")))
    except Exception as err:  # noqa: BLE001 - recorded in the manifest, the sweep goes on
        record.pop("sha256", None)        # only a done file has one (database.check_manifest)
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
    scenarios = []
    for index, (point, cfg) in enumerate(grid.points):
        sc = Scenario(index, point, cfg)
        if sc.valid:
            sc.key = format_key(scenario_key(point, cfg))
            sc.file = scenario_file_name(index, sc.key, len(grid.points))
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
    resume: bool = False
    present: set = field(default_factory=set)      # indices whose result file is in the folder
    previous: dict = field(default_factory=dict)   # index -> the done records of the manifests
    stores: dict = field(default_factory=dict)     # manifest name -> its store entry
    recorded: dict = field(default_factory=dict)   # index -> the SHA-256s its file may have
    seen: dict = field(default_factory=dict)       # manifest name -> stat when fully checked
    checked: dict = field(default_factory=dict)    # index -> (stat, reason, (sha256, photons))
    verified: dict = field(default_factory=dict)   # index -> (sha256, photons) checked on resume
    device: str | None = None
    scheduler: str | None = None

    @property
    def shard_text(self) -> str | None:
        return None if self.shard is None else f"{self.shard[0]}/{self.shard[1]}"

    @property
    def runnable(self) -> int:
        """Scenarios of this shard still to compute: not in the folder, or in it and found
        wrong by :func:`_check_files`."""
        return sum(s.valid and (s.index not in self.present
                                or self.checked.get(s.index, (None, None))[1] is not None)
                   for s in self.owned)


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
    store: Path | None = None       # DIR/database.nc when this run wrote it

    @property
    def exit_code(self) -> int:
        """0: every scenario of this run is done; 1: some failed or did not finish."""
        return 0 if not self.failed and not self.pending else 1


def run_sweep(preset, out, *, overrides=None, shard=None, scheduler=None, resume=False,
              device=None, quiet=False, say=print, overwrite=False) -> SweepSummary:
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
        Keep the scenarios already in the folder and compute the others. Every file kept is
        checked first (its seed, photons, index and grid fingerprint, its SHA-256 against the
        manifest's); one that fails is moved into ``DIR/rejected/`` and computed again.
        Without it, a folder that already holds results for this run's scenarios is an error.
    device : str, optional
        Device spec; a comma-separated list or ``all`` (every GPU) runs one worker process
        per device.
    quiet : bool
        No progress bar and no line per scenario (failures are still printed on stderr).
    say : callable
        Prints the first line (``print``; the command line passes one that ``--quiet``
        silences).
    overwrite : bool
        ``--out X.nc`` where ``X.nc`` exists and is not the combined file of this grid: replace
        it once the grid is complete (without it, that is an error).

    Returns
    -------
    SweepSummary

    Raises
    ------
    ConfigError
        Bad preset, ``--shard``, ``--scheduler``, a folder that holds another grid or that
        is not a database, an ``X.nc`` of something else without ``overwrite``, or another
        sweep writing the same manifest (its pid, host and start named).
    DeviceError
        No usable device (local engine), before anything is written: on ``--resume`` the
        files kept are checked first (read only), so that the workers are opened for the
        scenarios to compute again too.
    """
    sweep = _prepare(preset, out, overrides, shard, resume, overwrite)
    sweep.device, sweep.scheduler = device, scheduler
    if resume:
        _check_files(sweep)        # read only; what changes before the lock is checked again
    # Where the scenarios run; device problems surface before anything is written.
    workers = Workers.open(scheduler, device, sweep.runnable)
    lock = None
    try:
        lock, manifest, summary, todo = _claim(sweep, workers.text)
        if todo and workers.mode == "none":      # a file changed since _check_files (a race)
            workers = Workers.open(scheduler, device, len(todo))
            manifest.header["engine"] = workers.text
        return _run(sweep, workers, manifest, summary, todo, quiet, say)
    finally:
        workers.close()
        if lock is not None:
            lock.release()


def _prepare(preset, out, overrides, shard, resume, overwrite=False) -> _Sweep:
    """The grid and the folder checked against each other, before anything is written.

    Raises
    ------
    ConfigError
        Every point invalid, ``--out`` not a folder or in a missing one, a folder holding
        another grid or that is not a database, results of these scenarios already there
        without ``resume``, ``X.nc`` of another grid without ``overwrite``.
    """
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
    if combined is not None and combined.exists() and not overwrite \
            and _combined_fingerprint(combined) != fingerprint:
        raise ConfigError(f"{combined} exists and is not the combined file of this grid; pass "
                          f"--overwrite to replace it once the grid is complete, or give "
                          f"another --out", key="--out")
    owned = [s for s in scenarios if shard is None or s.index % shard[1] == shard[0]]
    sweep = _Sweep(grid, scenarios, fingerprint, folder, combined, shard, owned, resume)
    _inspect(sweep)       # read-only now; again under the folder's lock before writing
    return sweep


def _combined_fingerprint(path: Path) -> str | None:
    """The ``sweep_fingerprint`` of a combined file ``X.nc`` (None if unreadable or none)."""
    try:
        import h5py
        with h5py.File(path, "r") as h5:
            value = h5.attrs.get("sweep_fingerprint")
        return None if value is None else str(h5_attribute(value))
    except Exception:  # noqa: BLE001 - not an HDF5 file, a folder, unreadable: not ours
        return None


_OURS_RE = re.compile(r"^(s\d{5,}_[0-9a-f]{16}\.nc|database\.nc|\.warpe-cl\.lock|"
                      r"\.(s\d{5,}_[0-9a-f]{16}\.nc|database\.nc|"
                      r"manifest(-shard-\d+-of-\d+)?\.json)"
                      r"\.(lock|[0-9a-f]+\.tmp(\.nc|\.json)?))$")


def _inspect(sweep: _Sweep) -> None:
    """What the folder holds, checked against this run: sets ``present`` and ``previous``.

    Raises
    ------
    ConfigError
        A non-empty folder with no manifest holding something a sweep never writes, a
        manifest of another grid (or one that fails its checks), or results of this run's
        scenarios without ``resume``.
    """
    folder = sweep.folder
    seen = {path.name: _stat(path) for path in _manifest_paths(folder)}
    manifests = read_manifests(folder)
    if folder.is_dir() and not manifests:
        _refuse_foreign(folder)
    # A folder holds one grid: every manifest already there must share our fingerprint.
    previous = {}
    for path, manifest in manifests:
        _same_grid(sweep, path, manifest)
        _match_plan(path, manifest, sweep.scenarios)
        for rec in manifest["scenarios"]:
            if rec["status"] == "done":
                previous.setdefault(rec["index"], []).append(rec)
    sweep.seen = seen
    sweep.previous = previous
    sweep.stores = {path.name: manifest["store"] for path, manifest in manifests
                    if "store" in manifest}
    sweep.recorded = recorded_sha256(manifests)       # the rule open_database follows
    _find_present(sweep)


def _manifest_paths(folder: Path) -> list:
    """The manifests' paths in ``folder`` (none if it does not exist).

    Raises
    ------
    ConfigError
        A folder that cannot be listed.
    """
    if not folder.is_dir():
        return []
    try:
        return sorted(p for p in folder.iterdir() if MANIFEST_RE.match(p.name))
    except OSError as err:
        raise ConfigError(f"cannot be listed ({one_line(err)})", key=str(folder)) from None


def _stat(path: Path):
    """What changes when a file is replaced or written: (inode, size, mtime, ctime); None if
    it is gone."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns


def _refuse_foreign(folder: Path) -> None:
    """A folder without a manifest may hold only what a sweep writes.

    Raises
    ------
    ConfigError
        Naming the first name a sweep never writes.
    """
    foreign = [p.name for p in sorted(folder.iterdir())
               if not (_OURS_RE.match(p.name) or MANIFEST_RE.match(p.name)
                       or (p.name == REJECTED and p.is_dir()))]
    if foreign:
        more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
        raise ConfigError(f"is not empty and is not a warpe-cl sweep database (no "
                          f"manifest; it holds {foreign[0]}{more}); give a new or empty "
                          f"folder", key=str(folder))


def _same_grid(sweep: _Sweep, path: Path, manifest: dict) -> None:
    """A manifest in the folder must be of this grid (its fingerprint).

    Raises
    ------
    ConfigError
        A manifest of another grid, named with its preset, seed and photons.
    """
    if manifest["fingerprint"] != sweep.fingerprint:
        raise ConfigError(
            f"holds a database of another grid ({path.name}: preset "
            f"{manifest.get('preset')}, seed {manifest.get('seed')}, photons "
            f"{manifest.get('photons')}); the preset, --set, --photons or --seed differ. "
            f"Give another --out", key=str(sweep.folder))


def _find_present(sweep: _Sweep) -> None:
    """Set ``present`` (the indices whose file is in the folder).

    Raises
    ------
    ConfigError
        Results of this shard's scenarios without ``resume``.
    """
    folder = sweep.folder
    sweep.present = {s.index for s in sweep.scenarios
                     if s.valid and (folder / s.file).is_file()}
    count = sum(s.index in sweep.present for s in sweep.owned)
    if not sweep.resume and count:
        raise ConfigError(f"already holds {count} result(s) of these scenarios; pass --resume "
                          f"to keep them and compute the rest, or give another --out",
                          key=str(folder))


def _inspect_under_lock(sweep: _Sweep) -> None:
    """Under the folder's lock, what must be atomic with writing this run's manifest: no
    manifest of another grid, nothing foreign in a folder without one, no results of this
    shard without ``resume``.

    A manifest unchanged since :func:`_inspect` checked it in full is not read again; one new
    or rewritten since is read for its fingerprint only (its rows are checked in full once
    the folder's lock is released, before anything else is written).

    Raises
    ------
    ConfigError
        As :func:`_inspect`.
    """
    folder = sweep.folder
    paths = _manifest_paths(folder)
    if not paths:
        _refuse_foreign(folder)
    for path in paths:
        stat = _stat(path)
        if stat is None or sweep.seen.get(path.name) == stat:
            continue
        try:
            manifest = json.loads(path.read_text(encoding="utf-8"))
            fingerprint = manifest["fingerprint"]
        except (OSError, ValueError, KeyError, TypeError):
            read_manifests(folder)                      # names the file and what is wrong
            raise
        if fingerprint != sweep.fingerprint:
            _same_grid(sweep, path, manifest)
    _find_present(sweep)


def _match_plan(path: Path, manifest: dict, scenarios: list) -> None:
    """A manifest of this grid must list the plan's points and files, row by row.

    Raises
    ------
    ConfigError
        Naming the manifest and the first row whose ``point`` or ``file`` differs (an edited
        or swapped row), or a manifest with another number of rows.
    """
    rows = manifest["scenarios"]
    if len(rows) != len(scenarios):
        raise ConfigError(f"lists {len(rows)} scenarios, the plan of this grid "
                          f"{len(scenarios)}; delete it and run again with --resume",
                          key=f"{path}: scenarios")
    for row, s in zip(rows, scenarios):
        for name, want in (("point", s.point), ("file", s.file)):
            if json.dumps(row[name], sort_keys=True, default=str) != \
                    json.dumps(want, sort_keys=True, default=str):
                raise ConfigError(f"{json.dumps(row[name], default=str)} is not the plan's "
                                  f"{json.dumps(want, default=str)}; delete the manifest and "
                                  f"run again with --resume",
                                  key=f"{path}: scenarios[{s.index}].{name}")


def _claim(sweep: _Sweep, engine: str) -> tuple:
    """Take the folder for this run: claim it atomically, then hold its manifest.

    Under the folder's lock, only what must be atomic: the manifests' fingerprints checked
    again (:func:`_inspect_under_lock`), this manifest's lock taken (held for the whole run)
    and, if this manifest is not in the folder yet, its first version written (every
    scenario of this shard pending). A second run started at the same time then finds this
    run's manifest (another grid: refused) or its lock (the same manifest: refused). A run
    waits for the folder's lock as long as other sweeps hold it, with a line on stderr every
    FOLDER_LOCK_NOTE_S seconds naming the holder.

    Then, under this manifest's lock alone (it protects this shard's files): every manifest
    checked in full (:func:`_inspect`), the files ``--resume`` keeps checked
    (:func:`_check_present`), the scenarios sorted (:func:`_triage`) and the manifest
    written.

    Returns
    -------
    tuple
        (the manifest's :class:`_Lock`, the :class:`_Manifest`, the :class:`SweepSummary`,
        the scenarios to compute).

    Raises
    ------
    ConfigError
        Another run holds this manifest, or the folder no longer passes :func:`_inspect`.
    """
    folder = sweep.folder
    folder.mkdir(parents=True, exist_ok=True)
    name = manifest_name(sweep.shard)

    def waiting(seconds):
        print(printable(f"warpe-cl: {folder}: waited {seconds:.0f} s so far for {FOLDER_LOCK}, "
                        f"held by another sweep ({_holder(folder / FOLDER_LOCK)}) while it "
                        f"checks the folder; sweeps sharing a folder take it in turn, "
                        f"waiting"), file=sys.stderr, flush=True)
    folder_lock = _Lock.take(folder / FOLDER_LOCK, None, waiting, FOLDER_LOCK_NOTE_S)
    lock = None
    try:
        try:
            folder_lock.claim(utc_now())
            _inspect_under_lock(sweep)      # another grid is named as such, running or not
            lock = _Lock.take(folder / f".{name}.lock")
            if lock is None:
                raise ConfigError(f"another sweep ({_holder(folder / f'.{name}.lock')}) is "
                                  f"writing this database ({name}); wait for it to end or "
                                  f"stop it, then run again with --resume", key=str(folder))
            lock.claim(utc_now())
            manifest = _Manifest(folder / name, sweep.grid, sweep.scenarios, sweep.fingerprint,
                                 {"shard": sweep.shard_text, "engine": engine,
                                  "device": sweep.device, "scheduler": sweep.scheduler})
            if not manifest.path.exists():  # an existing one of this grid claims it already
                manifest.records.update({s.index: {"status": "pending"} for s in sweep.owned})
                manifest.write(force=True)
        finally:
            folder_lock.release()
        _inspect(sweep)                     # every manifest in full, the files present now
        if name in sweep.stores:            # kept: it is checked against the rows when read
            manifest.header["store"] = sweep.stores[name]
        if sweep.resume:
            _check_present(sweep)
        summary = SweepSummary(folder=folder, total=len(sweep.scenarios),
                               owned=len(sweep.owned))
        todo = _triage(sweep, manifest.records, summary)
        manifest.write(force=True)
    except BaseException:
        if lock is not None:
            lock.release()
        raise
    return lock, manifest, summary, todo


def _file_problem(path: Path, scenario: Scenario, fingerprint: str, shas) -> tuple:
    """Why a result file in the folder is not scenario ``scenario`` of this grid, or None.

    Its attributes are read with h5py (a millisecond): seed, photons, ``sweep_index`` and
    ``sweep_fingerprint`` must be this run's; its SHA-256 must be one of ``shas``, those the
    folder's manifests recorded for it (:func:`warpe_cl.database.recorded_sha256`, the rule
    :func:`open_database` follows), if they recorded any.

    Returns
    -------
    tuple
        (reason or None, (sha256, photons) or None).
    """
    try:
        import h5py
        with h5py.File(path, "r") as h5:
            attrs = {k: h5_attribute(h5.attrs[k])
                     for k in ("seed", "sweep_index", "sweep_fingerprint") if k in h5.attrs}
            photons = int(h5["photons"][()]) if "photons" in h5 else None
    except Exception as err:  # noqa: BLE001 - truncated, not HDF5, I/O error: rejected
        return f"unreadable ({type(err).__name__}: {one_line(err)})", None
    seed, count = int(scenario.cfg.get("simulation.seed")), \
        int(scenario.cfg.get("simulation.photons"))
    if "seed" not in attrs or int(attrs["seed"]) != seed:
        return f"holds seed {attrs.get('seed')}, this run has seed {seed}", None
    if photons != count:
        return f"holds {photons} photons, this run has {count}", None
    if "sweep_index" not in attrs or int(attrs["sweep_index"]) != scenario.index:
        return f"its sweep_index is {attrs.get('sweep_index')}, not {scenario.index}", None
    if str(attrs.get("sweep_fingerprint")) != fingerprint:
        return (f"its sweep_fingerprint {str(attrs.get('sweep_fingerprint'))[:16]}... is not "
                f"this grid's {fingerprint[:16]}..."), None
    sha = file_sha256(path)
    if shas and sha not in shas:
        return (f"its sha256 {sha[:16]}... is not the {sorted(shas)[0][:16]}... the manifest "
                f"recorded: the file changed after it was written"), None
    return None, (sha, photons)


def _reject(folder: Path, name: str, reason: str) -> Path:
    """Move ``folder/name`` into ``folder/rejected/`` (never deleted), with ``.reason.txt``
    beside it; a name already there gets a numbered suffix."""
    target_dir = folder / REJECTED
    try:
        target_dir.mkdir(exist_ok=True)
    except OSError as err:     # FileExistsError: a file of that name
        raise ConfigError(_no_rejected_folder(target_dir, err), key=str(target_dir)) from None
    target, n = target_dir / name, 1
    while target.exists() or target.with_name(target.name + ".reason.txt").exists():
        target, n = target_dir / f"{name}.{n}", n + 1
    os.replace(folder / name, target)
    target.with_name(target.name + ".reason.txt").write_text(
        f"{utc_now()} {name}: {reason}\n", encoding="utf-8")
    return target


def _no_rejected_folder(target_dir: Path, err: OSError | None = None) -> str:
    why = "exists and is not a folder" if err is None or isinstance(err, FileExistsError) \
        else f"cannot be made ({one_line(err)})"
    return (f"{why}; --resume moves the files it finds wrong into {target_dir.name}/: move "
            f"it away and run again with --resume")


def _check_files(sweep: _Sweep) -> None:
    """``--resume``: check every result file of this shard in the folder (read only), into
    ``sweep.checked``; a file unchanged since it was checked (its :func:`_stat`) is not read
    again."""
    for s in sweep.owned:
        if not (s.valid and s.index in sweep.present):
            continue
        path = sweep.folder / s.file
        stat = _stat(path)
        if stat is not None and sweep.checked.get(s.index, (None,))[0] == stat:
            continue
        reason, checked = _file_problem(path, s, sweep.fingerprint,
                                        sweep.recorded.get(s.index))
        sweep.checked[s.index] = (stat, reason, checked)


def _check_present(sweep: _Sweep) -> None:
    """``--resume``, under this manifest's lock: check every result file of this shard in the
    folder (:func:`_check_files`); move aside (:func:`_reject`) and count as to compute those
    that fail, one line each on stderr.

    Raises
    ------
    ConfigError
        A file to move aside and ``DIR/rejected`` that is not a folder (before any is moved).
    """
    _check_files(sweep)
    bad = [s for s in sweep.owned if s.valid and s.index in sweep.present
           and sweep.checked[s.index][1] is not None]
    target_dir = sweep.folder / REJECTED
    if bad and target_dir.exists() and not target_dir.is_dir():
        raise ConfigError(_no_rejected_folder(target_dir), key=str(target_dir))
    for s in sweep.owned:
        if not (s.valid and s.index in sweep.present):
            continue
        _, reason, checked = sweep.checked[s.index]
        if reason is None:
            sweep.verified[s.index] = checked
            continue
        path = sweep.folder / s.file
        target = _reject(sweep.folder, s.file, reason)
        sweep.present.discard(s.index)
        print(printable(f"warpe-cl: {path}: {reason}; moved to "
                        f"{target.parent.name}/{target.name}, computing it again"),
              file=sys.stderr)


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
            # What an earlier run recorded, the run's facts only: the file, point and key come
            # from the plan, the SHA-256 and photons from the file checked now.
            sha, photons = sweep.verified[s.index]
            olds = sweep.previous.get(s.index, [])
            old = next((r for r in olds if r.get("sha256") == sha),
                       next((r for r in olds if not r.get("sha256")), {}))
            carried = {k: old[k] for k in RECORD_KEYS if k in old}
            records[s.index] = {**carried, "status": "done", "this_run": "skipped",
                                "sha256": sha, "photons": photons}
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


def _run(sweep: _Sweep, workers: Workers, manifest: _Manifest, summary: SweepSummary,
         todo: list, quiet: bool, say) -> SweepSummary:
    """The body of :func:`run_sweep` once the folder is claimed (:func:`_claim`): tasks,
    progress, the manifest kept up to date, and a stop (:func:`warpe_cl.stops.check`) looked
    for between scenarios."""
    folder = sweep.folder
    records = manifest.records
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
        stops.check()
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
            stops.check()          # a SIGTERM whose exception was dropped stops here
    except KeyboardInterrupt as err:   # Ctrl-C or SIGTERM: the manifest is flushed below
        # A scenario whose file was put in place just before the signal, but whose record had
        # not come back yet, is done once its file is flushed: complete (atomic rename), as
        # --resume sees it.
        for s in todo:
            path = folder / s.file
            if records[s.index]["status"] == "pending" and path.is_file():
                try:
                    sha = _durable(path)
                except OSError:
                    continue
                records[s.index] = {"status": "done", "error": None, "this_run": "computed",
                                    "photons": int(s.cfg.get("simulation.photons")),
                                    "sha256": sha, "finished_utc": utc_now(),
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
    if summary.finished_in_folder == len(sweep.scenarios):
        try:
            combined = _consolidate(sweep, manifest, summary)
        except KeyboardInterrupt as err:   # while the store is written: none is left half done
            err.summary = summary
            raise
        except ConfigError as err:
            # Another shard's problem (a damaged file, a manifest), or no room: this shard's
            # work is done; the store and X.nc wait for a --resume that mends the folder.
            names = " and ".join(str(p) for p in (folder / STORE, sweep.combined) if p)
            print(printable(f"warpe-cl: warning: {names} not written: {one_line(err)}"),
                  file=sys.stderr)
            return summary
        # Another shard's last files may be in place before its manifest lists them: the
        # shard that records them writes X.nc then.
        if combined is not None and sweep.combined is not None:
            write_netcdf(combined, sweep.combined)
            summary.combined = sweep.combined
    return summary


def _consolidate(sweep: _Sweep, manifest: _Manifest, summary: SweepSummary):
    """Once every scenario of the grid is done: the store, ``DIR/database.nc``, written if
    it is missing or no longer matches the manifests, and recorded in this run's manifest.

    The store is every scenario of the grid in one NetCDF file, as
    :func:`~warpe_cl.database.open_database` returns it, so that a database opens in a
    fraction of a second (docs/cluster.md). It is built from the scenario files read and
    checked one by one (:func:`~warpe_cl.database.read_folder`), written atomically
    (:func:`warpe_cl.io.write_netcdf`), flushed to disk and hashed (:func:`_durable`); the
    manifest's ``store`` entry (:func:`~warpe_cl.database.store_record`) then records its
    SHA-256 and that of every scenario file it was built from. A store that still matches the
    manifests (:func:`~warpe_cl.database.store_problem`) is kept as it is and its entry
    carried into this run's manifest.

    Returns
    -------
    xarray.Dataset or None
        The whole grid (for ``--out X.nc``), or None if the manifests do not list every
        scenario as done yet (another shard's last files, in place before its manifest lists
        them: that shard writes the store).

    Raises
    ------
    ConfigError
        A scenario file that fails its checks, or a store that cannot be written.
    """
    folder = sweep.folder
    # One writer at a time: shards finishing together each find the grid complete; the
    # second, once the first lets go, finds its store good and records it.
    lock = _Lock.take(folder / f".{STORE}.lock", None)
    try:
        lock.claim(utc_now())
        grid, _, _, found = finished_scenarios([folder])
        if len(found) != len(sweep.scenarios):
            return None
        record, _ = store_problem(folder, read_manifests(folder), grid, found)
        if record is not None:
            manifest.header["store"] = record
            manifest.write(force=True)
            return open_database(folder) if sweep.combined is not None else None
        combined, digests = read_folder(folder)
        _remove_partial(folder, STORE)             # what a killed writer of the store left
        path = write_netcdf(combined, folder / STORE)
        manifest.header["store"] = store_record(_durable(path), grid, digests)
        manifest.write(force=True)
    finally:
        lock.release()
    summary.store = path
    return combined
