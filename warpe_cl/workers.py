"""Where the scenarios of a sweep run: this process, a spawned pool of one worker process per
device, or a Dask cluster; and the OpenCL environment of each worker.

:class:`Workers` opens one of these engines for :func:`warpe_cl.sweep.run_sweep` and yields
each scenario's record as it finishes. The scenario itself is computed by the function it is
given (:func:`warpe_cl.sweep.run_scenario`), in whichever process the engine chose.

- **In this process** when there is one device: no start-up cost, and one device is kept busy
  by one scenario at a time.
- **A spawned pool** (``--device 0:0,0:1`` or ``--device all``): one worker process per
  device, each holding its device for its life (:func:`_pool_init`).
- **Dask** (``--scheduler ADDRESS`` or ``local:N``): each scenario is a task needing one
  ``opencl`` resource, so a worker runs one scenario at a time (docs/cluster.md).

:func:`worker_environment` sets, before OpenCL is first loaded in a worker, the PoCL thread
count and node-local kernel caches. ``dask.distributed`` and the OpenCL driver are imported
only where they are used.
"""
from __future__ import annotations

import multiprocessing
import os
import re
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from .api import get_engine
from .cpus import allocated_cpus
from .device import candidates, list_devices, resolve_spec
from .errors import ConfigError, DeviceError, one_line
from .io import utc_now

__all__ = ["Workers", "allocated_cpus", "worker_environment", "CLUSTER_HINT",
           "OPENCL_RESOURCE"]

CLUSTER_HINT = "pip install 'warpe-cl[cluster]'"
OPENCL_RESOURCE = "opencl"    # Dask worker resource: one per OpenCL device


# --------------------------------------------------------------------------- worker hygiene

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


def _failed(task: dict, error: str) -> dict:
    """The record of a scenario whose worker failed it (the scenario's own errors are
    recorded by the scenario function)."""
    return {"index": task["index"], "status": "failed", "photons": 0, "error": error,
            "wall_time_s": 0.0, "finished_utc": utc_now()}


# --------------------------------------------------------------------------- local pool

_POOL_DEVICE = None   # the device of a local pool worker (set by _pool_init)


def _pool_init(devices, threads):
    """Initializer of a local pool worker: take one device, set the OpenCL environment."""
    global _POOL_DEVICE
    _POOL_DEVICE = devices.get()
    worker_environment(threads)


def _pool_task(function, task: dict) -> dict:
    """``function(task)`` on this pool worker's device."""
    return function({**task, "device": _POOL_DEVICE})


def _run_pool(function, tasks: list, devices: list):
    """One spawned worker process per device; results as they come."""
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    for spec in devices:
        queue.put(spec)
    threads = max(1, allocated_cpus() // len(devices))
    with ProcessPoolExecutor(max_workers=len(devices), mp_context=ctx,
                             initializer=_pool_init, initargs=(queue, threads)) as pool:
        futures = {pool.submit(_pool_task, function, task): task for task in tasks}
        for future in as_completed(futures):
            try:
                yield future.result()
            except BrokenProcessPool as err:
                yield _failed(futures[future], f"the worker process died ({one_line(err)})")


def _local_devices(device: str | None) -> list:
    """The device specs of the local engine: one, or one per worker of a spawned pool."""
    spec = resolve_spec(device)
    if spec == "all":
        gpus = [info.spec for info, _ in list_devices() if info.kind == "gpu"]
        return gpus or ["auto"]
    specs = [s.strip() for s in spec.split(",") if s.strip()]
    if not specs:
        raise ConfigError(f"{device!r} names no device", key="--device")
    return specs


# --------------------------------------------------------------------------- Dask

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
        raise ConfigError(f"cannot reach a Dask scheduler there ({one_line(err)})",
                          key=f"--scheduler {text}") from None
    workers = client.scheduler_info().get("workers", {})
    if workers and not any(w.get("resources", {}).get(OPENCL_RESOURCE) for w in workers.values()):
        client.close()
        raise ConfigError(f"no worker of this scheduler offers the resource {OPENCL_RESOURCE}; "
                          f"start one worker per device with `dask worker {text} --nthreads 1 "
                          f"--resources {OPENCL_RESOURCE}=1` (docs/cluster.md)",
                          key=f"--scheduler {text}")
    return client, None, None, f"Dask scheduler {text} ({len(workers)} worker(s) now)"


def _run_dask(client, function, tasks: list, fingerprint: str):
    """Scenarios as Dask tasks needing one ``opencl`` resource each; results as they come.

    Each worker keeps its OpenCL engine (context, queue, built kernels) between tasks: the
    engine cache of :func:`warpe_cl.api.get_engine` lives in the worker process.
    """
    from distributed import as_completed as dask_completed
    futures = {}
    for task in tasks:
        future = client.submit(function, task, key=f"warpe-cl-{fingerprint[:12]}-{task['index']}",
                               resources={OPENCL_RESOURCE: 1}, pure=False, retries=0)
        futures[future] = task
    for future in dask_completed(futures):
        try:
            yield future.result()
        except Exception as err:  # noqa: BLE001 - e.g. KilledWorker: recorded, retried on --resume
            yield _failed(futures[future], one_line(err))


# --------------------------------------------------------------------------- the engine

class Workers:
    """Where scenarios run: nowhere (nothing to do), in this process, a spawned pool of one
    worker per device, or Dask.

    Attributes
    ----------
    mode : str
        ``none``, ``in-process``, ``pool`` or ``dask``.
    text : str
        The engine as the sweep's first line names it.
    """

    def __init__(self, mode: str, text: str, devices=None, client=None, cluster=None,
                 threads=None):
        self.mode, self.text, self.devices = mode, text, devices
        self.client, self.cluster, self.threads = client, cluster, threads

    @classmethod
    def open(cls, scheduler: str | None, device: str | None, runnable: int) -> "Workers":
        """The engine for ``--scheduler`` and ``--device``, ready to run ``runnable``
        scenarios; device and scheduler problems surface here, before anything is written.

        Raises
        ------
        ConfigError
            A device list with ``--scheduler``, a bad ``--scheduler``, Dask missing.
        DeviceError
            No usable device (one device), or a listed one that matches none.
        """
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
            engine = get_engine(devices[0])            # DeviceError -> exit 3
            info = getattr(engine, "info", None)
            return cls("in-process", f"in-process, {info.device if info else engine.name}",
                       devices)
        listed = list_devices()
        for spec in devices:
            if spec != "numpy" and not candidates(spec, listed):
                raise DeviceError(f"--device {spec}: no OpenCL device matches")
        return cls("pool", f"{len(devices)} worker processes ({', '.join(devices)})", devices)

    def results(self, function, tasks: list, fingerprint: str, quiet: bool):
        """``function(task)`` for every task, on this engine; the records as they finish.

        Parameters
        ----------
        function : callable
            The scenario function (a module-level function: pool and Dask workers import it).
        tasks : list of dict
            Its arguments; ``device``, ``threads`` and ``progress`` are set here.
        fingerprint : str
            The grid's, for the Dask task keys.
        quiet : bool
            No ray progress bar (in this process only; workers never show one).
        """
        for task in tasks:
            if self.devices:
                task["device"] = self.devices[0]
            task["threads"] = self.threads
        if self.mode == "dask":
            return _run_dask(self.client, function, tasks, fingerprint)
        if self.mode == "pool":
            return _run_pool(function, tasks, self.devices)
        for task in tasks:    # in this process: the ray progress bar on a terminal
            task["progress"] = None if (not quiet and sys.stderr.isatty()) else False
        return map(function, tasks)

    def close(self) -> None:
        """Close the Dask client and the local cluster this engine started."""
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
