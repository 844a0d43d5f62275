"""Sweeps as a resumable scenario database: grids, scenario files, shards, resume, Dask.

``warpe-cl sweep PRESET.yaml --out DIR`` (interface.md §2) runs every point of the preset's
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
for that point alone.

Engines (:func:`run_sweep`): the points run in this process when there is one device
(the usual case: no start-up cost, one device is kept busy by one scenario at a time); in one
spawned worker process per device when several are named (``--device 0:0,0:1`` or
``--device all``); on a Dask cluster with ``--scheduler``. Scenario ``i`` belongs to shard
``i mod N`` (round robin, so costly regions of a grid spread over the shards).

``dask.distributed`` and the OpenCL driver are imported only where they are used.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from .errors import ConfigError, DeviceError, WarpeError

__all__ = ["run_sweep", "open_database", "SweepSummary", "parse_shard", "worker_environment",
           "CLUSTER_HINT"]

CLUSTER_HINT = "pip install 'warpe-cl[cluster]'"
FORMAT = "warpe-cl sweep database"
FORMAT_VERSION = 1
MANIFEST_RE = re.compile(r"^manifest(-shard-\d+-of-\d+)?\.json$")
MANIFEST_INTERVAL_S = 2.0     # the manifest is rewritten at most this often (and at the end)
OPENCL_RESOURCE = "opencl"    # Dask worker resource: one per OpenCL device


# --------------------------------------------------------------------------- small helpers

def _utc() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _jsonable(value):
    """JSON fallback for numpy values in configurations."""
    tolist = getattr(value, "tolist", None)
    return tolist() if tolist is not None else str(value)


def _sha256(value) -> str:
    text = json.dumps(value, sort_keys=True, default=_jsonable, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def _atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a hidden temporary file and a rename."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _one_line(err: BaseException) -> str:
    """An exception as the one line the command line would print."""
    if isinstance(err, WarpeError):
        return " ".join(str(err).split())
    return " ".join(f"{type(err).__name__}: {err}".split())


def _versions(dask_used: bool = False) -> dict:
    from .io import package_version
    import numpy
    out = {"warpe_cl": package_version(), "python": sys.version.split()[0],
           "numpy": numpy.__version__}
    for name in ("xarray", "pyopencl") + (("dask", "distributed") if dask_used else ()):
        module = sys.modules.get(name)
        if module is not None:
            out[name] = getattr(module, "__version__", getattr(module, "VERSION_TEXT", "?"))
    return out


def parse_shard(text: str | None):
    """``"I/N"`` -> ``(I, N)`` with 0 <= I < N; None -> None."""
    if text is None:
        return None
    match = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", str(text))
    if not match or int(match[2]) < 1 or int(match[1]) >= int(match[2]):
        raise ConfigError(f"{text} is not allowed; give I/N with 0 <= I < N, e.g. "
                          f"--shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT", key="--shard")
    return int(match[1]), int(match[2])


# --------------------------------------------------------------------------- worker hygiene

def allocated_cpus() -> int:
    """CPUs this process may use: ``$SLURM_CPUS_PER_TASK``, else the CPU affinity mask."""
    slurm = os.environ.get("SLURM_CPUS_PER_TASK", "")
    if slurm.isdigit() and int(slurm) > 0:
        return int(slurm)
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def worker_environment(threads: int | None = None) -> dict:
    """Set the OpenCL environment of a worker before OpenCL is first loaded in it.

    PoCL runs ``threads`` threads (default: :func:`allocated_cpus`), so that workers sharing a
    node do not oversubscribe it, and the PoCL and pyopencl kernel caches live on node-local
    disk (``$TMPDIR`` or ``/tmp``), not on a shared home folder. Variables the user set are
    kept. Once pyopencl is imported the driver has read them, so nothing is changed then.

    Returns
    -------
    dict
        The variables this call set.
    """
    if "pyopencl" in sys.modules:
        return {}
    user = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    local = Path(os.environ.get("TMPDIR") or "/tmp") / f"warpe-cl-{user}"
    wanted = {
        "POCL_MAX_PTHREAD_COUNT": str(max(1, threads or allocated_cpus())),
        "POCL_CACHE_DIR": str(local / "pocl-cache"),
        "PYOPENCL_CACHE_DIR": str(local / "pyopencl-cache"),
    }
    done = {}
    for name, value in wanted.items():
        if not os.environ.get(name):
            if name.endswith("_DIR"):
                Path(value).mkdir(parents=True, exist_ok=True)
            os.environ[name] = value
            done[name] = value
    return done


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
        record.update(status="failed", error=_one_line(err), photons=0,
                      wall_time_s=time.perf_counter() - t0)
    record["finished_utc"] = _utc()
    return record


_POOL_DEVICE = None   # the device of a local pool worker (set by _pool_init)


def _pool_init(devices, threads):
    """Initializer of a local pool worker: take one device, set the OpenCL environment."""
    global _POOL_DEVICE
    _POOL_DEVICE = devices.get()
    worker_environment(threads)


def _pool_task(task: dict) -> dict:
    return run_scenario({**task, "device": _POOL_DEVICE})


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


def _manifests(folder: Path) -> list:
    """Every manifest in ``folder`` as (path, dict)."""
    out = []
    if folder.is_dir():
        for path in sorted(folder.iterdir()):
            if MANIFEST_RE.match(path.name):
                try:
                    out.append((path, json.loads(path.read_text(encoding="utf-8"))))
                except (OSError, ValueError) as err:
                    raise ConfigError(f"unreadable manifest ({_one_line(err)}); it is not a "
                                      f"warpe-cl sweep database", key=str(path)) from None
    return out


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


# --------------------------------------------------------------------------- progress

class _Progress:
    """One tqdm bar over scenarios on a terminal; one plain line per scenario otherwise."""

    def __init__(self, total: int, quiet: bool, label: str):
        self.quiet = quiet
        self.count = 0
        self.total = total
        self.bar = None
        if not quiet and total and sys.stderr.isatty():
            from tqdm.auto import tqdm
            self.bar = tqdm(total=total, unit="scenario", desc=label, file=sys.stderr,
                            dynamic_ncols=True)

    def write(self, text: str, error: bool = False):
        if self.bar is not None:
            self.bar.write(text, file=sys.stderr if error else sys.stdout)
        elif error or not self.quiet:
            print(text, file=sys.stderr if error else sys.stdout, flush=True)

    def advance(self, text: str, error: bool = False):
        self.count += 1
        if self.bar is not None:
            self.bar.update(1)
            if error:
                self.write(text, error=True)
        else:
            self.write(f"[{self.count}/{self.total}] {text}", error=error)

    def close(self):
        if self.bar is not None:
            self.bar.close()


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


def database_folder(out) -> tuple:
    """``--out`` -> (database folder, combined file or None): ``X.nc`` keeps its scenarios in
    ``X.sweep/`` and gets the combined Dataset once the grid is complete."""
    out = Path(out)
    if out.suffix == ".nc":
        return out.with_suffix(".sweep"), out
    return out, None


def _local_devices(device: str | None) -> list:
    """The device specs of the local engine: one, or one per worker of a spawned pool."""
    from .device import resolve_spec
    spec = resolve_spec(device)
    if spec == "all":
        from .device import list_devices
        gpus = [info.spec for info, _ in list_devices() if info.kind == "gpu"]
        return gpus or ["auto"]
    specs = [s.strip() for s in spec.split(",") if s.strip()]
    if not specs:
        raise ConfigError(f"{device!r} names no device", key="--device")
    return specs


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
    for path, manifest in _manifests(folder):
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

    # Where the scenarios run; device problems surface before anything is written.
    runnable = sum(s.valid and s.index not in present for s in owned)
    engine = _Engine.open(scheduler, device, runnable)
    try:
        return _run(grid, scenarios, fingerprint, owned, present, previous, folder, combined,
                    shard, scheduler, device, engine, quiet, say)
    finally:
        engine.close()


class _Engine:
    """Where scenarios run: nowhere (nothing to do), in this process, a spawned pool of one
    worker per device, or Dask. ``results(tasks)`` yields each task's record as it finishes."""

    def __init__(self, mode: str, text: str, devices=None, client=None, cluster=None,
                 threads=None):
        self.mode, self.text, self.devices = mode, text, devices
        self.client, self.cluster, self.threads = client, cluster, threads

    @classmethod
    def open(cls, scheduler, device, runnable: int) -> "_Engine":
        if scheduler is not None and device is not None and "," in device:
            raise ConfigError(f"{device} is not allowed with --scheduler; each Dask worker uses "
                              f"one device (give one spec, or none to let each worker's "
                              f"$WARPE_CL_DEVICE choose)", key="--device")
        if runnable == 0:
            return cls("none", "nothing to run")
        if scheduler is not None:
            client, cluster, threads, text = _dask_client(scheduler)
            return cls("dask", text, client=client, cluster=cluster, threads=threads)
        devices = _local_devices(device)
        if len(devices) == 1:
            worker_environment()
            from .api import get_engine
            engine = get_engine(devices[0])            # DeviceError -> exit 3
            info = getattr(engine, "info", None)
            return cls("in-process", f"in-process, {info.device if info else engine.name}",
                       devices)
        from .device import candidates, list_devices
        listed = list_devices()
        for spec in devices:
            if spec != "numpy" and not candidates(spec, listed):
                raise DeviceError(f"--device {spec}: no OpenCL device matches")
        return cls("pool", f"{len(devices)} worker processes ({', '.join(devices)})", devices)

    def results(self, tasks: list, fingerprint: str, quiet: bool):
        for task in tasks:
            if self.devices:
                task["device"] = self.devices[0]
            task["threads"] = self.threads
        if self.mode == "dask":
            return _run_dask(self.client, tasks, fingerprint)
        if self.mode == "pool":
            return _run_pool(tasks, self.devices)
        for task in tasks:    # in this process: the ray progress bar on a terminal
            task["progress"] = None if (not quiet and sys.stderr.isatty()) else False
        return map(run_scenario, tasks)

    def close(self):
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()


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
            **header, "started_utc": _utc(),
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
        manifest = {**self.header, "updated_utc": _utc(),
                    "versions": _versions("distributed" in sys.modules), "counts": counts,
                    "scenarios": rows}
        _atomic_write_text(self.path, json.dumps(manifest, indent=1, default=_jsonable))


def _run(grid, scenarios, fingerprint, owned, present, previous, folder, combined, shard,
         scheduler, device, engine, quiet, say) -> SweepSummary:
    """The body of :func:`run_sweep` once the engine is open: manifest, tasks, progress."""
    folder.mkdir(parents=True, exist_ok=True)
    manifest = _Manifest(
        folder / ("manifest.json" if shard is None else
                  f"manifest-shard-{shard[0]}-of-{shard[1]}.json"),
        grid, scenarios, fingerprint,
        {"shard": None if shard is None else f"{shard[0]}/{shard[1]}", "engine": engine.text,
         "device": device, "scheduler": scheduler})
    records = manifest.records
    summary = SweepSummary(folder=folder, total=len(scenarios), owned=len(owned))
    todo = []
    for s in owned:
        if not s.valid:
            records[s.index] = {"status": "failed", "error": str(s.cfg), "photons": 0}
            summary.failed.append((s.index, s.point, str(s.cfg)))
        elif s.index in present:
            old = previous.get(s.index, {})
            records[s.index] = {**(old if old.get("status") == "done" else {}),
                                "status": "done", "this_run": "skipped"}
            summary.skipped += 1
        else:
            _remove_partial(folder, s.file)          # what a killed writer left behind
            records[s.index] = {"status": "pending"}
            todo.append(s)
    manifest.write(force=True)
    say(f"warpe-cl sweep: {manifest.header['name']} ({grid.source}), {len(scenarios)} "
        f"scenario(s) in the grid"
        + ("" if shard is None else f", {len(owned)} in shard {shard[0]}/{shard[1]}")
        + f"; {summary.skipped} already done, {len(todo)} to run, "
          f"{len(summary.failed)} invalid; {engine.text}; database {folder}")
    for index, _, error in summary.failed:
        print(f"warpe-cl: scenario {index} failed: {error}", file=sys.stderr)

    tasks = [{"index": s.index, "point": s.point, "cfg": s.cfg, "path": str(folder / s.file),
              "device": device, "fingerprint": fingerprint, "progress": False} for s in todo]
    by_index = {s.index: s for s in todo}
    progress = _Progress(len(todo), quiet,
                         "sweep" if shard is None else f"shard {shard[0]}/{shard[1]}")
    t0 = time.perf_counter()
    try:
        for rec in engine.results(tasks, fingerprint, quiet):
            s = by_index[rec["index"]]
            records[s.index] = {**rec, "this_run": "computed"}
            where = ", ".join(f"{k}={v}" for k, v in s.point.items()) or "the preset"
            if rec["status"] == "done":
                summary.done += 1
                summary.photons += rec["photons"]
                progress.advance(f"{s.file} done in {rec['wall_time_s']:.2f} s ({where})")
            else:
                summary.failed.append((s.index, s.point, rec["error"]))
                progress.advance(f"scenario {s.index} failed ({where}): {rec['error']}",
                                 error=True)
            manifest.write()
    finally:
        progress.close()
        summary.wall_time_s = time.perf_counter() - t0
        summary.pending = sum(r["status"] == "pending" for r in records.values())
        manifest.write(force=True)

    summary.finished_in_folder = sum((folder / s.file).is_file() for s in scenarios if s.valid)
    if combined is not None and summary.finished_in_folder == len(scenarios):
        from .io import write_netcdf
        write_netcdf(open_database(folder), combined)
        summary.combined = combined
    return summary


def summary_lines(summary: SweepSummary) -> list:
    """The end-of-run report: counts, time, speed, the failures."""
    rate = summary.photons / summary.wall_time_s if summary.wall_time_s > 0 else 0.0
    lines = [f"warpe-cl sweep: {summary.done} done, {summary.skipped} skipped (already in the "
             f"folder), {len(summary.failed)} failed"
             + (f", {summary.pending} not finished" if summary.pending else "")
             + f"; {summary.wall_time_s:.2f} s, {rate:,.0f} photons/s; "
               f"{summary.finished_in_folder} of {summary.total} scenarios of the grid in "
               f"{summary.folder}"]
    if summary.combined is not None:
        lines.append(f"wrote {summary.combined} (all {summary.total} scenarios)")
    return lines


# --------------------------------------------------------------------------- engines

def _run_pool(tasks: list, devices: list):
    """One spawned worker process per device; results as they come."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    for spec in devices:
        queue.put(spec)
    threads = max(1, allocated_cpus() // len(devices))
    with ProcessPoolExecutor(max_workers=len(devices), mp_context=ctx,
                             initializer=_pool_init, initargs=(queue, threads)) as pool:
        futures = {pool.submit(_pool_task, task): task for task in tasks}
        for future in as_completed(futures):
            try:
                yield future.result()
            except BrokenProcessPool as err:
                yield {"index": futures[future]["index"], "status": "failed", "photons": 0,
                       "error": f"the worker process died ({_one_line(err)})",
                       "wall_time_s": 0.0, "finished_utc": _utc()}


def _dask_client(address: str):
    """(Client, LocalCluster or None, PoCL threads per worker, description) for --scheduler."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ConfigError(f"needs dask.distributed, which is not installed: "
                          f"{CLUSTER_HINT}", key="--scheduler") from None
    text = str(address).strip()
    if text.startswith("local"):
        match = re.fullmatch(r"local(?::(\d+))?", text)
        if not match or (match[1] is not None and int(match[1]) < 1):
            raise ConfigError(f"{text} is not allowed; give local:N (N worker processes) or a "
                              f"scheduler address such as tcp://HOST:8786", key="--scheduler")
        workers = int(match[1] or 1)
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               resources={OPENCL_RESOURCE: 1}, dashboard_address=None)
        client = Client(cluster)
        threads = max(1, allocated_cpus() // workers)
        return client, cluster, threads, f"Dask LocalCluster of {workers} worker processes"
    try:
        client = Client(text, timeout="20s")
    except (OSError, TimeoutError, ValueError) as err:
        raise ConfigError(f"cannot reach a Dask scheduler there ({_one_line(err)})",
                          key=f"--scheduler {text}") from None
    workers = client.scheduler_info().get("workers", {})
    if workers and not any(w.get("resources", {}).get(OPENCL_RESOURCE) for w in workers.values()):
        client.close()
        raise ConfigError(f"no worker of this scheduler offers the resource {OPENCL_RESOURCE}; "
                          f"start one worker per device with `dask worker {text} --nthreads 1 "
                          f"--resources {OPENCL_RESOURCE}=1` (docs/cluster.md)",
                          key=f"--scheduler {text}")
    return client, None, None, f"Dask scheduler {text} ({len(workers)} worker(s) now)"


def _run_dask(client, tasks: list, fingerprint: str):
    """Scenarios as Dask tasks needing one ``opencl`` resource each; results as they come.

    Each worker keeps its OpenCL engine (context, queue, built kernels) between tasks: the
    engine cache of :func:`warpe_cl.api.get_engine` lives in the worker process.
    """
    from distributed import as_completed
    futures = {}
    for task in tasks:
        future = client.submit(run_scenario, task, key=f"warpe-cl-{fingerprint[:12]}-{task['index']}",
                               resources={OPENCL_RESOURCE: 1}, pure=False, retries=0)
        futures[future] = task
    for future in as_completed(futures):
        try:
            yield future.result()
        except Exception as err:  # noqa: BLE001 - e.g. KilledWorker: recorded, retried on --resume
            yield {"index": futures[future]["index"], "status": "failed", "photons": 0,
                   "error": _one_line(err), "wall_time_s": 0.0, "finished_utc": _utc()}


# --------------------------------------------------------------------------- reading

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


def open_database(paths):
    """One Dataset of every finished scenario of a sweep database.

    Parameters
    ----------
    paths : str, path, or a list of them
        Database folders (``warpe-cl sweep --out``; for ``--out X.nc`` the folder is
        ``X.sweep``). Several folders of the same grid (shards written to separate folders)
        are merged; a scenario found in several is read once.

    Returns
    -------
    xarray.Dataset
        The layout ``warpe-cl run`` writes for a sweep (interface.md §5): a leading
        ``scenario`` dimension whose coordinate is the grid index, the swept values as
        coordinates along it, the derived parameters and ``scenario_key`` as variables.
        Unfinished scenarios are absent; the attributes ``sweep_scenarios_total``,
        ``sweep_failed`` (JSON: index -> error) and ``sweep_fingerprint`` say what the grid
        holds.

    Raises
    ------
    ConfigError
        A path that is not a database, folders of different grids, or no finished scenario.
    """
    import xarray as xr
    from .io import combine_scenarios

    folders = [Path(p) for p in ([paths] if isinstance(paths, (str, os.PathLike)) else paths)]
    grid = None
    fingerprint = None
    failed = {}
    found = {}
    for folder in folders:
        if folder.suffix == ".nc" and not folder.is_dir():
            folder = folder.with_suffix(".sweep")
        manifests = _manifests(folder)
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
    return out
