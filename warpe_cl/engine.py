"""The OpenCL engine: launches photon batches of the walk kernel and reduces their tallies.

Each launch hands out the next photon indices of the walk; every ray draws its random numbers
from Philox keyed by (seed, scenario key) with the photon index and the event in the counter, so
the counts do not depend on the device, the work-group size, the global size or how the walk is
split into launches. A launch is bounded by events, not by its longest ray: each work-item walks
at most ``event_budget`` events, then parks its unfinished rays, which the next launch resumes
before it takes new photons (docs/walk.md §5). The budget is scaled so that a launch takes about
``target_launch_s`` seconds whatever the medium, and a launch offers at most 2^31 photons minus
the parked rays (the per-launch uint32 histograms cannot overflow); the host adds each launch's
histograms into int64 :class:`~warpe_cl.params.Counts`.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np

from . import device as devmod
from . import stops
from .buffers import check_walk_buffers, walk_buffer_bytes
from .errors import ConfigError, DeviceError, WeightError
from .nadir import mirror_table, nadir_min_score, nadir_new_cell_score, view_table
from .params import (COMPONENTS, FATES, FIXED_WORDS, HISTOGRAMS, ITEM_STATS, LAYER_STATS,
                     NADIR_BATCHES, NADIR_ROWS, RECORD_FIELDS, RECORD_INT_COLUMNS, RECORD_REAL_COLUMNS, STATE_INT_COLUMNS,
                     STATE_REAL_COLUMNS, Counts, WalkParams, batch_photons, kernel_layout,
                     tally_shapes)
from .stack import layer_tables

WALK_FILES = ("real.h", "lanes.h", "philox.h", "fresnel.h", "scatter.h", "score.h", "tally.h",
              "rays.h", "layers.h", "nadir.h", "carry.h", "exits.h", "walk.cl")
MAX_LAUNCH = 2 ** 31 - 1
#: Events per work-item of a walk's first launch; later launches scale it to take about
#: ``target_launch_s`` (docs/walk.md §5)
FIRST_EVENT_BUDGET = 4096
MAX_EVENT_BUDGET = 2 ** 32 - 1
LANE_WIDTHS = (1, 2, 4, 8, 16)
#: Rows a per-work-item statistics table is folded into on the device before it is read back
#: (:func:`sum_rows`): a GPU launch has 2^20 work-items, whose 64 MiB of rows took most of a
#: short walk's time when read whole; a CPU launch (16 work-items a core) is read as it is.
STATS_PARTS = 4096


def photon_pool(lanes: int) -> int:
    """Photons a work-item takes from the launch's counter beyond those its empty lanes want
    (``WARPE_POOL``, cl/walk.cl ``pool_t``; docs/walk.md §5): as many as its lanes on CPUs, so
    that most refills need no atomic on the counter, whose cache line the cores pass to and
    fro (B1 1.06x; 16, 32 and 64 photons measured the same); none with one lane (GPUs: a
    million work-items would hoard photons and park them). Results never depend on it."""
    return lanes if lanes > 1 else 0


def layout_options() -> tuple:
    """The ``-D`` macros of the layouts the host and the kernel share
    (:func:`warpe_cl.params.kernel_layout`), the same in every build."""
    return tuple(f"-D{name}={value}" for name, value in kernel_layout().items())


def build_options(texture: str, precision: str, records: bool, lanes: int = 1,
                  weighted: bool = False, nadir: bool = False) -> tuple:
    """The ``-D`` switches of the walk kernel: its structure (texture, lane width and the
    photon pool that goes with it, precision, per-photon records, weighted mode, the nadir
    estimator), then the shared layouts of :func:`layout_options`.
    No physical value is compiled in."""
    if lanes not in LANE_WIDTHS:
        raise ValueError(f"lanes must be one of {LANE_WIDTHS}, got {lanes}")
    opts = [f"-DWARPE_TEXTURE_{texture.upper()}",
            f"-DWARPE_LANES={lanes}", f"-DWARPE_POOL={photon_pool(lanes)}"]
    if precision == "double":
        opts.append("-DWARPE_DOUBLE")
    if records:
        opts.append("-DWARPE_RECORD")
    if weighted:
        opts.append("-DWARPE_WEIGHTED")
    if nadir:
        opts.append("-DWARPE_NADIR")
    return tuple(opts) + layout_options()


def driver_options(info) -> tuple:
    """The ``-D`` switches that depend on the driver, not on the walk: they change its speed,
    never a bit (tests/test_builtins.py). ``WARPE_BUILTINS`` (cl/lanes_builtins.h,
    cl/lanes_vector_builtins.h) keeps OpenCL's built-ins ``select``, ``fmax``, ``clamp``,
    ``fabs`` and ``rint`` on Intel's CPU runtime,
    whose built-ins are inline instructions: the code it was tuned with (without them its
    program is 4.7 times the size and B1 walks 0.9-0.98x as fast). Every other driver gets
    the ``?:`` operator and comparisons, selects and bits instead, where pip's PoCL 3.0 calls
    a library function for each built-in (its walk 1.2-1.5x faster without them;
    docs/performance.md)."""
    if info.kind == "cpu" and info.platform.startswith("Intel"):
        return ("-DWARPE_BUILTINS",)
    return ()


def walk_options(info, key: tuple) -> tuple:
    """The build options of the walk kernel of structure ``key`` (:func:`kernel_key`) on the
    device ``info`` (a :class:`~warpe_cl.device.DeviceInfo`): :func:`build_options` of the
    structure, then :func:`driver_options` of the driver. Every build of a walk, and the
    qualification's key of its verdict (warpe_cl/qualify.py ``combo_key``), takes them from
    here."""
    return build_options(*key) + driver_options(info)


def kernel_key(texture: str, precision: str, records: bool, lanes: int,
               weighted: bool = False, nadir: bool = False) -> tuple:
    """The key of one walk kernel in an :class:`Engine`: the structure :func:`build_options`
    compiles (the same arguments, normalised), so that every caller names a kernel alike."""
    return (texture, precision, bool(records), int(lanes), bool(weighted), bool(nadir))


@lru_cache(maxsize=1)
def walk_source_hash() -> str:
    """``kernel_sha256`` of the output files: SHA-256 of the walk kernel's files (their names
    and contents, :func:`warpe_cl.device.source_hash`) and of the options every build of it
    shares (:func:`shared_options`). The same for every texture, precision, mode and lane
    width (the files record the first three; the lane width never changes a result) and
    wherever the sources are installed; it changes when the kernel does."""
    return devmod.source_hash(WALK_FILES, shared_options())


def shared_options() -> tuple:
    """The options of every build of the walk that bear on its results: the layouts the host
    compiles in (:func:`layout_options`) and the exact division and square root of every
    device that offers them (:data:`warpe_cl.device.EXACT_DIVIDE_SQRT`)."""
    return layout_options() + (devmod.EXACT_DIVIDE_SQRT,)


@dataclass(frozen=True)
class KernelArg:
    """One parameter of the walk kernel (``__kernel void walk(...)`` in cl/walk.cl).

    Attributes
    ----------
    name : str
        The parameter's name in cl/walk.cl.
    ctype : str
        Its OpenCL C type: ``uint``, ``ulong``, ``int``, ``REAL`` (float or double, as the
        build's precision), or a ``__global`` buffer (``__global uint *``, ...).
    value : callable or None
        Scalars fixed by the scenario: ``value(params)`` of a :class:`WalkParams`. ``None``:
        the launch provides it, by name (photon range, buffers).
    only : {None, "weighted", "records", "layers", "nadir"}
        Present only in the builds with ``WARPE_WEIGHTED``, ``WARPE_RECORD``,
        ``WARPE_TEXTURE_LAYERS`` or ``WARPE_NADIR``.
    """

    name: str
    ctype: str
    value: Callable | None = None
    only: str | None = None

    @property
    def is_buffer(self) -> bool:
        return self.ctype.startswith("__global")


def _cos_fov(c: int) -> Callable:
    return lambda p: p.cos_fov[c]


def bin_guess(edges) -> tuple:
    """(log, a, b) of the nadir kernel's first guess of a time's bin (cl/walk.cl
    ``nadir_column``, which the edges then correct, so any guess gives the same bins):
    floor(b ln(t / a)) for log-spaced edges, floor(b (t - a)) otherwise (linear, or a
    guess as good as the first bin's width)."""
    e = np.asarray(edges, dtype=float)
    ratio = e[1:] / e[:-1] if e[0] > 0 else None
    if ratio is not None and np.allclose(ratio, ratio[0], rtol=1e-9, atol=0.0):
        return 1, float(e[0]), float(1.0 / np.log(ratio[0]))
    return 0, float(e[0]), float(1.0 / (e[1] - e[0]))


#: The walk kernel's parameters, in order: the one table that :meth:`Engine.run` fills and
#: tests/test_layout.py checks against the kernel's source.
WALK_ARGS = (
    KernelArg("seed", "uint", lambda p: p.seed),
    KernelArg("scenario", "ulong", lambda p: p.scenario),
    KernelArg("first_photon", "ulong"),
    KernelArg("n_photons", "uint"),
    KernelArg("h", "REAL", lambda p: p.thickness),
    KernelArg("E", "REAL", lambda p: p.flight_extinction),
    KernelArg("omega_words", "ulong", lambda p: p.omega_words),
    KernelArg("g", "REAL", lambda p: p.g),
    KernelArg("n", "REAL", lambda p: p.n),
    KernelArg("k", "REAL", lambda p: p.k),
    KernelArg("A", "REAL", lambda p: p.albedo),
    KernelArg("albedo_words", "ulong", lambda p: p.albedo_words),
    KernelArg("L_max", "REAL", lambda p: p.path_cap),
    KernelArg("max_flights", "uint", lambda p: min(p.max_flights, 2 ** 31 - 1)),
    KernelArg("bottom_fresnel", "int", lambda p: p.bottom_interface == "fresnel"),
    KernelArg("mu_a", "REAL", lambda p: p.absorption),
    KernelArg("roulette_weight", "REAL", lambda p: p.roulette_weight),
    KernelArg("roulette_survival", "REAL", lambda p: p.roulette_survival),
    KernelArg("rule_time_window", "int", lambda p: p.rule == "time_window"),
    KernelArg("t1", "REAL", lambda p: p.first_bf_time),
    KernelArg("time_edges", "__global const REAL *"),
    KernelArg("n_edges", "int", lambda p: len(p.time_edges)),
    *(KernelArg(f"cos_fov_{name}", "REAL", _cos_fov(c)) for c, name in enumerate(COMPONENTS)),
    KernelArg("next_photon", "__global uint *"),
    KernelArg("event_budget", "uint"),
    KernelArg("resume_count", "uint"),
    KernelArg("next_resume", "__global uint *"),
    KernelArg("resume_real", "__global const REAL *"),
    KernelArg("resume_int", "__global const uint *"),
    KernelArg("parked", "__global uint *"),
    KernelArg("park_real", "__global REAL *"),
    KernelArg("park_int", "__global uint *"),
    *(KernelArg(name, "__global uint *") for name in HISTOGRAMS),
    KernelArg("item_stats", "__global ulong *"),
    KernelArg("n_layers", "int", lambda p: len(p.stack), only="layers"),
    KernelArg("layer_real", "__global const REAL *", only="layers"),
    KernelArg("layer_words", "__global const ulong *", only="layers"),
    KernelArg("iface_real", "__global const REAL *", only="layers"),
    KernelArg("iface_kind", "__global const int *", only="layers"),
    KernelArg("layer_stats", "__global ulong *", only="layers"),
    *(KernelArg(name, "__global ulong *", only="weighted")
      for name in ("w_time_in_fov", "w_time_any", "w_angular", "w_total", "w_early",
                   "w2_time_in_fov", "w2_total")),
    KernelArg("view", "__global const REAL *", only="nadir"),
    KernelArg("mirror", "__global const REAL *", only="nadir"),
    KernelArg("n_mirror", "int", only="nadir"),
    KernelArg("nadir_min", "REAL", nadir_min_score, only="nadir"),
    KernelArg("nadir_min_new", "REAL", nadir_new_cell_score, only="nadir"),
    KernelArg("bin_log", "int", only="nadir"),
    KernelArg("bin_a", "REAL", only="nadir"),
    KernelArg("bin_b", "REAL", only="nadir"),
    KernelArg("nadir_slices", "uint", only="nadir"),
    KernelArg("nadir_sum", "__global ulong *", only="nadir"),
    KernelArg("nadir_visits", "__global ulong *", only="nadir"),
    KernelArg("rec_int", "__global int *", only="records"),
    KernelArg("rec_real", "__global REAL *", only="records"),
    KernelArg("record_base", "uint", only="records"),
)

_SCALAR_TYPES = {"uint": np.uint32, "ulong": np.uint64, "int": np.int32}


def walk_args(weighted: bool, records: bool, layered: bool = False,
              nadir: bool = False) -> tuple:
    """The :data:`WALK_ARGS` of one build of the walk kernel, in order."""
    present = {None: True, "weighted": weighted, "records": records, "layers": layered,
               "nadir": nadir}
    return tuple(a for a in WALK_ARGS if present[a.only])


def argument_values(args, params: WalkParams, launch: dict, real) -> list:
    """The values of ``args`` for one launch, in order: the scenario's from ``params``, the
    others from ``launch`` (by name); scalars as NumPy scalars of their OpenCL type (``real``:
    the dtype of REAL)."""
    out = []
    for a in args:
        value = a.value(params) if a.value is not None else launch[a.name]
        out.append(value if a.is_buffer else _SCALAR_TYPES.get(a.ctype, real)(value))
    return out


def requested_lanes() -> int | None:
    """The lane width asked for by ``$WARPE_CL_LANES`` (results never depend on it: e.g.
    ``WARPE_CL_LANES=1 pytest`` runs the whole suite on the GPU shape of the kernel, on any
    device), or None."""
    env = os.environ.get("WARPE_CL_LANES", "").strip()
    if not env:
        return None
    if not env.isdigit() or int(env) not in LANE_WIDTHS:
        raise ConfigError(f"{env!r} is not allowed; give one of "
                          f"{', '.join(map(str, LANE_WIDTHS))} (photons per work-item)",
                          key="WARPE_CL_LANES", source="environment")
    return int(env)


def widest_lanes(kind: str, precision: str, preferred: int = 1) -> int:
    """The widest lane width a device walks, before qualification: one on GPUs (their
    work-items are the lanes); on CPUs a vector of 512 bits (16 floats or 8 doubles), which
    AVX-512 holds in one register and AVX2 in two, or the driver's preferred vector width
    ``preferred`` (CL_DEVICE_PREFERRED_VECTOR_WIDTH_FLOAT or _DOUBLE) where it is narrower and
    above 1. Measured on an AVX2 CPU (Zen 3, docs/performance.md): pip's PoCL prefers 8 floats
    and 4 doubles and walks B1 and B3 1.4x faster at 8 lanes than at 16 (double: 1.35-1.5x at
    4 than at 8); Intel's runtime prefers 1 (it vectorises itself) and walks B3 1.1x faster
    at 16 lanes than at 8."""
    if kind == "gpu":
        return 1
    widest = 8 if precision == "double" else 16
    if 1 < preferred < widest:
        return max(w for w in LANE_WIDTHS if w <= preferred)
    return widest


def default_lanes(kind: str, precision: str, preferred: int = 1) -> int:
    """Photons per work-item before qualification: :func:`widest_lanes`;
    ``$WARPE_CL_LANES`` overrides it."""
    env = requested_lanes()
    if env is not None:
        return env
    return widest_lanes(kind, precision, preferred)


class Engine:
    """Runs walks on one OpenCL device.

    The engine neither chooses its device nor judges it: :func:`warpe_cl.api.get_engine` hands
    it a device that :func:`warpe_cl.qualify.select_device` chose and a lane chooser
    (:class:`warpe_cl.qualify.LaneChooser`) that knows which lane widths qualified there.

    Parameters
    ----------
    info : DeviceInfo
        The device, described (:class:`warpe_cl.device.DeviceInfo`).
    device : pyopencl.Device
        The device itself.
    choose_lanes : callable, optional
        ``choose_lanes(texture, precision, weighted, lanes)`` -> the lane width to walk a
        kernel with, qualified on the device (:class:`warpe_cl.qualify.LaneChooser`); ``None``
        walks the width asked for, else :func:`default_lanes`, unchecked (the known-answer
        walk of :mod:`warpe_cl.qualify` itself).
    target_launch_s : float
        Wanted duration of one launch, s (0.1-1 s keeps the progress bar and Ctrl-C responsive
        and stays far below GPU watchdog limits).
    """

    name = "opencl"

    def __init__(self, info, device, choose_lanes: Callable | None = None,
                 target_launch_s: float = 0.3):
        self.info, self.device = info, device
        self.context, self.queue = devmod.context_and_queue(self.device)
        self.target_launch_s = target_launch_s
        self.kernel_hash = None
        #: seconds the last :meth:`run` spent before its walk: qualifying the kernel and
        #: building it on first use, next to nothing once built (the speed report leaves it out)
        self.last_build_s = 0.0
        #: seconds the last :meth:`run` spent walking (its launches), what the speeds count
        self.last_walk_s = None
        #: the last :meth:`run`'s launches, in order: new photons taken, parked rays resumed,
        #: rays parked, the event budget and the seconds each took (launch to readback), for
        #: telling a walk bound by its launches from one bound by its set-up (tools/bench)
        self.last_launches: list = []
        self._kernels = {}
        self._folds = {}      # the nadir_fold kernel of each nadir build (same keys)
        self._stats_folds = {}   # the stats_fold kernel of each build (same keys)
        self._nadir_sums = None   # (shape, sums, visits) of the last nadir walk, kept
        self._warmed = set()
        self.choose_lanes = choose_lanes

    def lanes_for(self, texture: str, precision: str, weighted: bool,
                  lanes: int | None = None, check: bool = True) -> int:
        """The lane width to walk this kernel with, qualified on this device (docs/devices.md).

        ``lanes`` (or ``$WARPE_CL_LANES``) asks for one width: it is used if it qualifies,
        otherwise :class:`~warpe_cl.errors.DeviceError` says why. Without a request, the widest
        width that qualifies, from :func:`widest_lanes` (16, 8 in double, or the driver's narrower
        preferred vector width; 1 on GPUs) down through 8, 4 and 1; a fallback is said in one
        warning line (both: :attr:`choose_lanes`). ``check=False`` (the known-answer walk
        itself), or an engine without a lane chooser: the width asked for, else
        :func:`default_lanes`, unchecked.
        """
        if lanes is None:
            lanes = requested_lanes()
        if not check or self.choose_lanes is None:
            return int(lanes or default_lanes(self.info.kind, precision,
                                              self.info.preferred_width(precision)))
        return self.choose_lanes(texture, precision, weighted, lanes)

    @property
    def provenance(self) -> dict:
        """Platform, device and driver of this engine, for output attributes."""
        i = self.info
        return {"opencl_platform": f"{i.platform} {i.platform_version}", "opencl_device": i.device,
                "opencl_driver": i.driver, "opencl_device_type": i.kind}

    def default_global_size(self) -> int:
        """Work-items per launch: 2^20 on GPUs; 16 per compute unit on CPUs (each walks a
        vector of photons and takes new ones as its rays end, so a few per core keep every
        core busy to the end of a launch)."""
        if self.info.kind == "gpu":
            return 1 << 20
        return 16 * max(1, self.info.compute_units)

    def kernel(self, texture: str, precision: str, records: bool, lanes: int,
               weighted: bool = False, nadir: bool = False):
        """The walk kernel for this structure; programs are built once per process."""
        if precision == "double" and not self.info.fp64:
            raise DeviceError(f"{self.info.device} has no double precision; "
                                     "use simulation.precision: single")
        if weighted and "cl_khr_int64_base_atomics" not in self.device.extensions:
            raise DeviceError(f"{self.info.device} has no 64-bit atomics "
                                     "(cl_khr_int64_base_atomics), which the weighted mode's "
                                     "exact tallies need; use simulation.mode: analog")
        if nadir and "cl_khr_int64_base_atomics" not in self.device.extensions:
            raise DeviceError(f"{self.info.device} has no 64-bit atomics "
                                     "(cl_khr_int64_base_atomics), which the nadir "
                                     "estimator's exact sums need; use simulation.nadir: false")
        self.kernel_hash = walk_source_hash()
        key = kernel_key(texture, precision, records, lanes, weighted, nadir)
        if key not in self._kernels:
            self.use_program(devmod.build_program(self.device, WALK_FILES,
                                                  self.program_options(key)), key)
        return self._kernels[key]

    def program_options(self, key: tuple) -> tuple:
        """The build options of the walk kernel of structure ``key`` (:func:`kernel_key`) on
        this engine's device (:func:`walk_options`). Every build of a walk to be timed or
        compared with the engine's own takes them from here."""
        return walk_options(self.info, key)

    def use_program(self, program, key: tuple):
        """Walk the structure ``key`` (:func:`kernel_key`) with ``program``'s kernels from now
        on; returns its ``walk`` kernel. :meth:`kernel` calls it with the program it built;
        tools/bench/bench_ab.py --kernel-only with programs built from other trees' sources (in
        this engine's context, with :meth:`program_options` of the key), to time them in one
        process."""
        import pyopencl as cl
        self._kernels[key] = cl.Kernel(program, "walk")
        # a program of an older tree (bench_ab.py --kernel-only) may have no stats_fold: its
        # statistics are then read whole (sum_rows without a fold)
        names = program.get_info(cl.program_info.KERNEL_NAMES).split(";")
        self._stats_folds[key] = cl.Kernel(program, "stats_fold") if "stats_fold" in names else None
        if key[-1]:                                     # nadir: its fold kernel too
            self._folds[key] = cl.Kernel(program, "nadir_fold")
        return self._kernels[key]

    def forget(self, key: tuple) -> None:
        """Undo :meth:`use_program` for ``key``: the next :meth:`kernel` of that structure
        builds this engine's own program again."""
        self._kernels.pop(key, None)
        self._stats_folds.pop(key, None)
        self._folds.pop(key, None)

    def _nadir_buffers(self, shape: tuple) -> tuple:
        """The ``nadir_sum`` and ``nadir_visits`` buffers of ``shape`` (slices, NADIR_BATCHES,
        rows, columns), kept from the last nadir walk of the same shape: a CPU walk has a
        slice per work-item (10 MB on 2 cores), and the pages of a new buffer fault in at its
        first fill, which cost 5-8 times the fill of a kept one (docs/performance.md). Every
        run zeroes them before its first launch."""
        import pyopencl as cl
        if self._nadir_sums is None or self._nadir_sums[0] != shape:
            mf = cl.mem_flags
            cells, visit_cells = int(np.prod(shape)), shape[0] * int(np.prod(shape[2:]))
            self._nadir_sums = (
                shape,
                cl.Buffer(self.context, mf.READ_WRITE, size=8 * FIXED_WORDS * cells),
                cl.Buffer(self.context, mf.READ_WRITE, size=8 * visit_cells))
        return self._nadir_sums[1:]

    def run(self, params: WalkParams, photons: int, precision: str = "single",
            first_photon: int = 0, records: bool = False, batch: int | None = None,
            global_size: int | None = None, local_size: int | None = None,
            lanes: int | None = None, progress=None, qualified: bool = False,
            event_budget: int | None = None, shared_nadir: bool | None = None) -> Counts:
        """Walk ``photons`` rays, numbered from ``first_photon``.

        Parameters
        ----------
        params : WalkParams
        photons : int
            Number of rays.
        precision : {"single", "double"}
        first_photon : int
            Index of the first ray (the Philox counter): splitting a run into ranges and adding
            their counts gives exactly the counts of the whole run.
        records : bool
            Also return one record per photon (``Counts.records``), for the parity tests.
        batch : int, optional
            At most this many new photons per launch (default: no limit but the histograms').
        global_size, local_size : int, optional
            Work-items per launch and per work-group (results never depend on them).
        lanes : int, optional
            Photons walked at once by one work-item (1, 2, 4, 8, 16; results never depend on
            it); by default the widest that qualifies on the device (:meth:`lanes_for`).
        progress : callable, optional
            Called with the number of photons finished after each launch.
        qualified : bool
            Skip the qualification of this combination (for the known-answer walk itself,
            :mod:`warpe_cl.qualify`, which compares the result with the reference).
        event_budget : int, optional
            Events each work-item walks per launch before it parks its unfinished rays for the
            next launch (docs/walk.md §5; results never depend on it). By default
            :data:`FIRST_EVENT_BUDGET`, then scaled so that a launch takes about
            ``target_launch_s``.
        shared_nadir : bool, optional
            The nadir sums in one slice that every work-item adds to with 64-bit atomics (True),
            or one slice per work-item with plain adds (False); by default the first on GPUs,
            the second on CPUs (docs/walk.md §8.2; results never depend on it).

        Returns
        -------
        Counts

        Raises
        ------
        WeightError
            Weighted mode: some exiting ray's weight was NaN, negative or >= 2**21, so the
            exact sums would have dropped it (docs/walk.md §6).
        """
        t_build = time.perf_counter()    # first use: qualification and kernel build
        self.last_launches = []
        walk = self._set_up(params, precision, records, global_size, local_size, lanes,
                            qualified, shared_nadir, first_photon)
        self._warm_up(walk)
        t_walk = time.perf_counter()
        self.last_build_s = t_walk - t_build

        total = Counts(n_time=walk.n_time, weighted=walk.weighted, nadir=walk.nadir)
        walk.zero_nadir_sums(self.queue)   # exact sums over the launches, read at the end
        lost_weights = 0   # weighted exits whose weight the exact sums cannot hold
        records_of_walk = walk.record_buffers(photons) if records and photons else {}
        handed = 0         # photons handed to launches so far
        carried = 0        # rays parked by the last launch, resumed by the next
        budget = int(event_budget or FIRST_EVENT_BUDGET)
        # new photons per launch: the uint32 histograms hold them and the carried rays
        offer = min(int(batch) if batch else MAX_LAUNCH, MAX_LAUNCH - walk.capacity)
        while handed < photons or carried:
            stops.check()      # a Ctrl-C or SIGTERM whose exception was dropped: stop here
            n = min(offer, photons - handed)
            launch = {"first_photon": first_photon + handed, "n_photons": n,
                      "event_budget": budget, **records_of_walk}
            part, lost, resumed, parked, elapsed = self._launch(walk, launch, carried)
            lost_weights += lost
            took = part.photons
            self.last_launches.append({"photons": took, "resumed": resumed, "parked": parked,
                                       "event_budget": budget, "seconds": elapsed})
            total.add_walk(part)
            handed += took
            carried = _carry_unresumed(self.queue, walk.carry, carried, resumed, parked,
                                       walk.itemsize)
            budget_spent = carried > 0 or took < n
            walk.carry.reverse()
            if progress is not None:
                progress(handed - carried)
            if budget_spent and not event_budget:
                # the launch ran on its budget: scale it to the wanted launch time
                scale = min(max(self.target_launch_s / max(elapsed, 1e-6), 0.25), 4.0)
                budget = int(min(max(budget * scale, 64), MAX_EVENT_BUDGET))
        if lost_weights:
            raise WeightError(lost_weights)
        self._finish(walk, total, first_photon, photons, records_of_walk)
        self.last_walk_s = time.perf_counter() - t_walk
        return total

    def _set_up(self, params: WalkParams, precision: str, records: bool,
                global_size: int | None, local_size: int | None, lanes: int | None,
                qualified: bool, shared_nadir: bool | None, first_photon: int) -> "_Walk":
        """The kernel and device buffers of one walk (the arguments as for :meth:`run`):
        its lane width, qualified unless ``qualified``; its kernel, built on first use; its
        launch sizes; its buffers, checked against the device's memory first, with the
        layered and nadir tables uploaded.

        Returns
        -------
        _Walk

        Raises
        ------
        ConfigError
            The buffers do not fit the device (``simulation.time_bins``).
        ValueError
            A layered walk in the weighted mode.
        """
        import pyopencl as cl

        walk = _Walk()
        walk.params, walk.precision, walk.records = params, precision, records
        walk.first_photon = first_photon
        walk.real = real = np.float64 if precision == "double" else np.float32
        walk.weighted = weighted = params.weighted
        walk.lanes = lanes = self.lanes_for(params.texture, precision, weighted, lanes,
                                            check=not qualified)
        walk.nadir = nadir = bool(params.nadir)
        walk.key = kernel_key(params.texture, precision, records, lanes, weighted, nadir)
        walk.kern = self.kernel(params.texture, precision, records, lanes, weighted, nadir)
        edges = np.asarray(params.time_edges, dtype=real)
        walk.n_time = n_time = len(edges) - 1
        gsize = int(global_size or self.default_global_size())
        if local_size is None and self.info.kind != "gpu":
            # PoCL runs the work-items of a group one after the other in one thread: groups
            # of one work-item spread the vectors over every core (2x on 2 cores, measured).
            local_size = 1
        if local_size:
            gsize = -(-gsize // local_size) * local_size
        walk.gsize, walk.local_size = gsize, local_size

        mf = cl.mem_flags
        ctx = self.context
        walk.layered = layered = params.layered
        if layered and weighted:
            raise ValueError("the layered walk is analog only (docs/walk.md §7)")
        walk.args = args = walk_args(weighted, records, layered, nadir)
        walk.shapes = shapes = tally_shapes(n_time)
        walk.hist = hist = [a.name for a in args if a.name in HISTOGRAMS]
        walk.weights = weights = [a.name for a in args if a.only == "weighted"]
        walk.itemsize = itemsize = np.dtype(real).itemsize
        # every lane of every work-item may park a ray at the end of a launch, and so may every
        # photon left in its pool
        walk.capacity = capacity = gsize * (lanes + photon_pool(lanes))
        # the nadir sums: one slice per work-item on CPUs (plain adds, walk.md §8), one slice
        # that every work-item adds to atomically on GPUs
        if shared_nadir is None:
            shared_nadir = self.info.kind == "gpu"
        slices = 1 if shared_nadir else gsize
        # what the buffers below take, refused (exit 2) where the device cannot hold them
        check_walk_buffers(lambda n: walk_buffer_bytes(n, hist, weights, gsize, capacity,
                                                       itemsize, slices if nadir else 0),
                           n_time, self.device.max_mem_alloc_size, self.device.global_mem_size,
                           self.info.device)
        # the buffers, by kernel argument: uint32 histograms; weighted sums in FIXED_WORDS
        # uint64 words per cell (cl/tally.h); the statistics of every work-item; the counters
        walk.counters = counters = ("next_photon", "next_resume", "parked")
        walk.buffers = buffers = {
            "time_edges": cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=edges),
            **{k: cl.Buffer(ctx, mf.READ_WRITE, size=4) for k in counters},
            "item_stats": cl.Buffer(ctx, mf.READ_WRITE, size=8 * len(ITEM_STATS) * gsize),
            **{k: cl.Buffer(ctx, mf.READ_WRITE, size=4 * int(np.prod(shapes[k])))
               for k in hist},
            **{k: cl.Buffer(ctx, mf.READ_WRITE, size=8 * FIXED_WORDS * int(np.prod(shapes[k])))
               for k in weights}}
        if layered:
            for name, table in layer_tables(params, real).items():
                buffers[name] = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=table)
            buffers["layer_stats"] = cl.Buffer(ctx, mf.READ_WRITE,
                                               size=8 * len(LAYER_STATS) * gsize)
        walk.nadir_shape = nadir_shape = (slices, NADIR_BATCHES, len(NADIR_ROWS), n_time + 2)
        if nadir:
            buffers["view"] = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                        hostbuf=view_table(params).astype(real))
            mirror = mirror_table(params)
            padded = np.vstack([mirror, np.zeros((1, mirror.shape[1]))])   # no empty buffer
            buffers["mirror"] = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                          hostbuf=padded.astype(real))
            buffers["n_mirror"] = len(mirror)
            buffers.update(zip(("bin_log", "bin_a", "bin_b"), bin_guess(params.time_edges)))
            buffers["nadir_sum"], buffers["nadir_visits"] = self._nadir_buffers(nadir_shape)
            buffers["nadir_slices"] = slices
        walk.zeroed = [buffers[k] for k in (*hist, *weights, *counters)]
        # parked rays, in two buffers that swap roles each launch (written, then resumed)
        walk.carry = [
            (cl.Buffer(ctx, mf.READ_WRITE, size=itemsize * len(STATE_REAL_COLUMNS) * capacity),
             cl.Buffer(ctx, mf.READ_WRITE, size=4 * len(STATE_INT_COLUMNS) * capacity))
            for _ in range(2)]
        walk.context = ctx
        return walk

    def _warm_up(self, walk: "_Walk") -> None:
        """PoCL compiles a kernel for its work-group size at its first launch: a launch
        walking no ray (n_photons 0) does that here, once per structure and work-group size,
        inside the build time; every buffer it touches is zeroed or rewritten by the launches
        of the walk."""
        import pyopencl as cl

        params = walk.params
        warm_key = (params.texture, walk.precision, walk.records, walk.lanes, walk.weighted,
                    walk.nadir, walk.local_size)
        if warm_key in self._warmed:
            return
        launch = {**walk.buffers, "first_photon": walk.first_photon, "n_photons": 0,
                  "event_budget": 1, **walk.carry_args(0),
                  **(walk.record_buffers(1) if walk.records else {})}
        for k in walk.counters:
            cl.enqueue_fill_buffer(self.queue, walk.buffers[k], np.uint32(0), 0, 4)
        local = walk.local_size
        walk.kern(self.queue, (local or 1,), (local,) if local else None,
                  *argument_values(walk.args, params, launch, walk.real))
        self.queue.finish()
        self._warmed.add(warm_key)

    def _launch(self, walk: "_Walk", launch: dict, carried: int) -> tuple:
        """One launch of the walk and its readback.

        Parameters
        ----------
        walk : _Walk
        launch : dict
            ``first_photon``, ``n_photons`` (new photons offered), ``event_budget`` and the
            record buffers of the walk, if any.
        carried : int
            Rays parked by the last launch, resumed by this one (from ``walk.carry[0]``).

        Returns
        -------
        (Counts, int, int, int, float)
            The launch's counts (``photons``: the new photons it took), the weighted exits
            whose weight the exact sums could not hold, the parked rays it resumed, the rays
            it parked (into ``walk.carry[1]``), and its wall time, s.
        """
        import pyopencl as cl

        queue, buffers, n = self.queue, walk.buffers, launch["n_photons"]
        for buf in walk.zeroed:
            cl.enqueue_fill_buffer(queue, buf, np.uint32(0), 0, buf.size)
        launch = {**buffers, **launch, **walk.carry_args(carried)}
        launch_items = min(walk.gsize, -(-(n + carried) // walk.lanes))
        if walk.local_size:
            launch_items = -(-launch_items // walk.local_size) * walk.local_size
        t0 = time.perf_counter()
        walk.kern(queue, (launch_items,), (walk.local_size,) if walk.local_size else None,
                  *argument_values(walk.args, walk.params, launch, walk.real))
        taken, parked = np.empty(1, np.uint32), np.empty(1, np.uint32)
        resumed = np.empty(1, np.uint32)
        cl.enqueue_copy(queue, taken, buffers["next_photon"])
        cl.enqueue_copy(queue, parked, buffers["parked"])
        cl.enqueue_copy(queue, resumed, buffers["next_resume"])
        part = Counts(n_time=walk.n_time, weighted=walk.weighted)
        for name in walk.hist:
            host = np.empty(walk.shapes[name], dtype=np.uint32)
            cl.enqueue_copy(queue, host, buffers[name])
            getattr(part, name)[...] = host
        for name in walk.weights:
            words = np.empty((*walk.shapes[name], FIXED_WORDS), dtype=np.uint64)
            cl.enqueue_copy(queue, words, buffers[name])
            setattr(part, name, _exact_sums(words))
        fold = self._stats_folds[walk.key]
        stats = dict(zip(ITEM_STATS, sum_rows(queue, fold, buffers["item_stats"], launch_items,
                                              len(ITEM_STATS))))
        if walk.layered:
            part.layer_stats[...] = sum_rows(queue, fold, buffers["layer_stats"], launch_items,
                                             len(LAYER_STATS))
        queue.finish()
        elapsed = time.perf_counter() - t0
        part.fates[...] = [stats[f"fate_{f}"] for f in FATES]
        part.scattering_events = int(stats["scattering_events"])
        part.mixed_history = int(stats["mixed_history"])
        part.photons = min(int(taken[0]), n)
        return part, int(stats["lost_weights"]), int(resumed[0]), int(parked[0]), elapsed

    def _finish(self, walk: "_Walk", total: Counts, first_photon: int, photons: int,
                records_of_walk: dict) -> None:
        """Add to ``total`` what the walk kept on the device over its launches: the nadir
        sums of every slice, folded on the device and read once, with the photons of each
        batch; the per-photon records."""
        if walk.nadir:
            words, visits = fold_nadir_slices(self.queue, self._folds[walk.key],
                                              walk.buffers["nadir_sum"],
                                              walk.buffers["nadir_visits"], walk.nadir_shape)
            total.nadir_sum = _exact_sums(words)
            total.nadir_visits[...] = visits.astype(np.int64)
            total.nadir_batch_photons[...] = batch_photons(first_photon, photons)
        if walk.records:
            total.records = _read_records(self.queue, records_of_walk, photons, walk.real)


class _Walk:
    """What :meth:`Engine.run` keeps for one walk between its launches (set by
    :meth:`Engine._set_up`): the scenario and its build (``params``, ``precision``,
    ``records``, ``weighted``, ``layered``, ``nadir``, ``lanes``, ``key``, ``kern``, ``args``,
    ``real``, ``itemsize``), the launch sizes (``gsize``, ``local_size``, ``capacity``), the
    time grid and tallies (``n_time``, ``shapes``, ``hist``, ``weights``, ``nadir_shape``)
    and the device buffers (``buffers`` by kernel argument, ``counters``, ``zeroed``: those
    zeroed before each launch, ``carry``: the two parked-ray buffers, which swap roles each
    launch)."""

    def record_buffers(self, n: int) -> dict:
        """The per-photon record buffers of a walk of ``n`` photons (int and REAL columns,
        cl/tally.h), row 0 for ``first_photon``."""
        import pyopencl as cl

        mf = cl.mem_flags
        return {"rec_int": cl.Buffer(self.context, mf.WRITE_ONLY,
                                     size=4 * len(RECORD_INT_COLUMNS) * n),
                "rec_real": cl.Buffer(self.context, mf.WRITE_ONLY,
                                      size=self.itemsize * len(RECORD_REAL_COLUMNS) * n),
                "record_base": self.first_photon & 0xFFFFFFFF}

    def carry_args(self, resume_count: int) -> dict:
        """The carried rays' arguments: resume from carry[0], park into carry[1]."""
        carry = self.carry
        return {"resume_count": resume_count, "resume_real": carry[0][0],
                "resume_int": carry[0][1], "park_real": carry[1][0], "park_int": carry[1][1]}

    def zero_nadir_sums(self, queue) -> None:
        """Zero the nadir sums, which add up over the launches (no-op without them)."""
        import pyopencl as cl

        if self.nadir:
            for k in ("nadir_sum", "nadir_visits"):
                cl.enqueue_fill_buffer(queue, self.buffers[k], np.uint32(0), 0,
                                       self.buffers[k].size)


def _carry_unresumed(queue, carry: list, count: int, taken: int, parked: int,
                     itemsize: int) -> int:
    """The rays to resume in the next launch: the ``parked`` rows of this launch (in
    ``carry[1]``) and, after them, the rows of ``carry[0]`` that this launch did not resume
    (``count`` rows, the first ``taken`` of them taken). A launch parks the photons left in its
    work-items' pools as well as its rays (cl/walk.cl ``pool_t``), so the next launch may get
    more rows than it has lanes; rows are left over only where no lane had room before the
    budget was spent, so no work-item took a new photon and the two together are no more rows
    than the buffers hold (docs/walk.md §5)."""
    left = count - min(taken, count)
    if left:
        import pyopencl as cl
        for buf, width in ((0, itemsize * len(STATE_REAL_COLUMNS)),
                           (1, 4 * len(STATE_INT_COLUMNS))):
            cl.enqueue_copy(queue, carry[1][buf], carry[0][buf], byte_count=width * left,
                            src_offset=width * (count - left), dst_offset=width * parked)
    return parked + left


def _exact_sums(words: np.ndarray) -> np.ndarray:
    """Fixed-point words (low first, :data:`~warpe_cl.params.FIXED_WORDS` of them) as exact
    Python ints (object array)."""
    return sum(words[..., i].astype(object) << (64 * i) for i in range(FIXED_WORDS))


def sum_rows(queue, fold, table, items: int, columns: int, parts: int = STATS_PARTS):
    """The column sums of the first ``items`` rows of a per-work-item statistics table
    (``item_stats``, ``layer_stats``: uint64 counts, ``columns`` a row), exact: folded into
    ``parts`` rows on the device first (cl/walk.cl ``stats_fold``) where there are more, so
    that a GPU launch reads back a few thousand rows instead of 2^20.

    Parameters
    ----------
    queue : pyopencl.CommandQueue
    fold : pyopencl.Kernel or None
        ``stats_fold`` of the walk's program; None reads every row.
    table : pyopencl.Buffer
        The table; its first rows are overwritten where it is folded.
    items, columns : int
        Rows that count (the launch's work-items) and counts per row.
    parts : int
        Rows the device folds into.

    Returns
    -------
    numpy.ndarray
        ``columns`` int64 sums.
    """
    import pyopencl as cl
    rows = min(items, parts) if fold is not None else items
    if items > rows:
        fold(queue, (rows * columns,), None, table, np.uint32(items), np.uint32(columns),
             np.uint32(rows))
    host = np.empty((rows, columns), dtype=np.uint64)
    if rows:
        cl.enqueue_copy(queue, host, table)           # the first rows: host.nbytes
    return host.astype(np.int64).sum(axis=0)


def fold_nadir_slices(queue, fold, sums, visits, shape: tuple) -> tuple:
    """The nadir sums and visits of every slice added into the first on the device
    (cl/walk.cl ``nadir_fold``, exact), and that slice read back.

    Parameters
    ----------
    queue : pyopencl.CommandQueue
    fold : pyopencl.Kernel
        ``nadir_fold`` of the walk's program.
    sums, visits : pyopencl.Buffer
        ``nadir_sum`` (shape + (FIXED_WORDS,) uint64 words) and ``nadir_visits``
        (shape without its batch axis, uint64).
    shape : tuple
        (slices, NADIR_BATCHES, rows, columns).

    Returns
    -------
    (words, visits) : numpy.ndarray
        shape[1:] + (FIXED_WORDS,) and shape[2:], uint64: the sums of all slices.
    """
    import pyopencl as cl
    slices = int(shape[0])
    cells = int(np.prod(shape[1:]))
    visit_cells = int(np.prod(shape[2:]))
    if slices > 1:
        fold(queue, (max(cells, visit_cells),), None, sums, visits, np.uint32(slices),
             np.uint32(cells), np.uint32(visit_cells))
    words = np.empty((*shape[1:], FIXED_WORDS), dtype=np.uint64)
    counts = np.empty(shape[2:], dtype=np.uint64)
    cl.enqueue_copy(queue, words, sums)         # the first slice: words.nbytes from the start
    cl.enqueue_copy(queue, counts, visits)
    queue.finish()
    return words, counts


def _read_records(queue, buffers: dict, photons: int, real) -> dict:
    """The kernel's per-photon records of a walk (``rec_int``, ``rec_real``) as
    ``Counts.records``: one array per field of :data:`~warpe_cl.params.RECORD_FIELDS`, NaN
    times and exit cosines for the rays that did not exit."""
    import pyopencl as cl
    n_int, n_real = len(RECORD_INT_COLUMNS), len(RECORD_REAL_COLUMNS)
    ri = np.empty((photons, n_int), dtype=np.int32)
    rr = np.empty((photons, n_real), dtype=real)
    if photons:
        cl.enqueue_copy(queue, ri, buffers["rec_int"])
        cl.enqueue_copy(queue, rr, buffers["rec_real"])
        queue.finish()
    rr = rr.astype(np.float64)
    exited = ri[:, RECORD_INT_COLUMNS.index("component")] >= 0
    out = {name: ri[:, j].astype(RECORD_FIELDS[name]) for j, name in enumerate(RECORD_INT_COLUMNS)}
    for j, name in enumerate(RECORD_REAL_COLUMNS):
        out[name] = (rr[:, j] if name in ("weight", "nadir")
                     else np.where(exited, rr[:, j], np.nan))
    return out
