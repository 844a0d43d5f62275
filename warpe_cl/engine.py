"""The OpenCL engine: launches photon batches of the walk kernel and reduces their tallies.

Each launch walks a contiguous range of photon indices; every ray draws its random numbers
from Philox keyed by (seed, scenario key) with the photon index in the counter, so the counts do
not depend on the device, the work-group size, the global size or how photons are split into
launches. Launches are sized to take about ``target_launch_s`` seconds and at most 2^31
photons (the per-launch uint32 histograms cannot overflow); the host adds each launch's
histograms into int64 :class:`~warpe_cl.params.Counts`.
"""
from __future__ import annotations

import os
import time
from functools import lru_cache

import numpy as np

from . import device as devmod
from .errors import WeightError
from .params import Counts, N_EMERGENCE, WalkParams

WALK_FILES = ("real.h", "lanes.h", "philox.h", "fresnel.h", "scatter.h", "tally.h", "walk.cl")
MAX_LAUNCH = 2 ** 31 - 1
LANE_WIDTHS = (1, 2, 4, 8, 16)


def build_options(texture: str, precision: str, records: bool, lanes: int = 1,
                  weighted: bool = False) -> tuple:
    """The structural ``-D`` switches of the walk kernel (no physical value is compiled in)."""
    if lanes not in LANE_WIDTHS:
        raise ValueError(f"lanes must be one of {LANE_WIDTHS}, got {lanes}")
    opts = ["-DWARPE_TEXTURE_SLAB" if texture == "slab" else "-DWARPE_TEXTURE_GRANULAR",
            f"-DWARPE_LANES={lanes}"]
    if precision == "double":
        opts.append("-DWARPE_DOUBLE")
    if records:
        opts.append("-DWARPE_RECORD")
    if weighted:
        opts.append("-DWARPE_WEIGHTED")
    return tuple(opts)


@lru_cache(maxsize=1)
def walk_source_hash() -> str:
    """``kernel_sha256`` of the output files: SHA-256 of the walk kernel's files, their names
    and contents (:func:`warpe_cl.device.source_hash`). The same for every texture, precision,
    mode and lane width (the files record the first three; the lane width never changes a
    result) and wherever the sources are installed; it changes when the kernel does."""
    return devmod.source_hash(WALK_FILES)


def requested_lanes() -> int | None:
    """The lane width asked for by ``$WARPE_CL_LANES`` (results never depend on it: e.g.
    ``WARPE_CL_LANES=1 pytest`` runs the whole suite on the GPU shape of the kernel, on any
    device), or None."""
    env = os.environ.get("WARPE_CL_LANES", "").strip()
    if not env:
        return None
    if not env.isdigit() or int(env) not in LANE_WIDTHS:
        from .errors import ConfigError
        raise ConfigError(f"{env!r} is not allowed; give one of "
                          f"{', '.join(map(str, LANE_WIDTHS))} (photons per work-item)",
                          key="WARPE_CL_LANES", source="environment")
    return int(env)


def default_lanes(kind: str, precision: str) -> int:
    """Photons per work-item before qualification: one on GPUs (their work-items are the
    lanes); on CPUs a vector of 512 bits (16 floats or 8 doubles), which AVX-512 holds in one
    register and AVX2 in two. ``$WARPE_CL_LANES`` overrides it."""
    env = requested_lanes()
    if env is not None:
        return env
    if kind == "gpu":
        return 1
    return 8 if precision == "double" else 16


class Engine:
    """Runs walks on one OpenCL device.

    Parameters
    ----------
    device : str or None
        A device spec for :func:`warpe_cl.device.select_device` (``None``: environment, then auto).
    target_launch_s : float
        Wanted duration of one launch, s (0.1-1 s keeps the progress bar and Ctrl-C responsive
        and stays far below GPU watchdog limits).
    """

    name = "opencl"

    def __init__(self, device: str | None = None, target_launch_s: float = 0.3,
                 qualify: bool = True):
        self.info, self.device = devmod.select_device(device, qualify=qualify)
        self.context, self.queue = devmod.context_and_queue(self.device)
        self.target_launch_s = target_launch_s
        self.kernel_hash = None
        self._kernels = {}
        self.qualifier = None
        if qualify:
            from .qualify import qualifier_for
            self.qualifier = qualifier_for(self.info)
        self._lanes = {}

    def lanes_for(self, texture: str, precision: str, weighted: bool,
                  lanes: int | None = None, check: bool = True) -> int:
        """The lane width to walk this kernel with, qualified on this device (docs/devices.md).

        ``lanes`` (or ``$WARPE_CL_LANES``) asks for one width: it is used if it qualifies,
        otherwise :class:`~warpe_cl.errors.DeviceError` says why. Without a request, the widest
        width that qualifies, from 16 (8 in double; 1 on GPUs) down through 8, 4 and 1; a
        fallback is said in one warning line. ``check=False`` (the known-answer walk itself),
        or an engine made with ``qualify=False``: the width asked for, else
        :func:`default_lanes`, unchecked.
        """
        if lanes is None:
            lanes = requested_lanes()
        if not check or self.qualifier is None:
            return int(lanes or default_lanes(self.info.kind, precision))
        from .qualify import Combo, describe_short
        combo = Combo(texture, precision, bool(weighted))
        key = (combo, lanes)
        if key in self._lanes:
            return self._lanes[key]
        if lanes is not None:
            entry = self.qualifier.verdicts(int(lanes), [combo], measure=False)[combo]
            if not entry["passed"]:
                raise devmod.DeviceError(
                    f"{describe_short(self.info)} failed qualification at {lanes} lanes for "
                    f"{combo.label}: "
                    f"{entry['reason']}")
            chosen = int(lanes)
        else:
            chosen, failures = self.qualifier.best_lanes(combo)
            if chosen is None:
                raise devmod.DeviceError(
                    f"{describe_short(self.info)} is not usable for {combo.label}: "
                    + "; ".join(f"{w} lanes: {r}" for w, r in failures))
            if failures:
                import warnings
                from .errors import WarpeWarning
                warnings.warn(
                    f"{describe_short(self.info)}: {combo.label} failed qualification at "
                    f"{', '.join(str(w) for w, _ in failures)} lanes "
                    f"({failures[0][1]}); walking {chosen} lanes", WarpeWarning, stacklevel=2)
        self._lanes[key] = chosen
        return chosen

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
               weighted: bool = False):
        """The walk kernel for this structure; programs are built once per process."""
        if precision == "double" and not self.info.fp64:
            raise devmod.DeviceError(f"{self.info.device} has no double precision; "
                                     "use simulation.precision: single")
        if weighted and "cl_khr_int64_base_atomics" not in self.device.extensions:
            raise devmod.DeviceError(f"{self.info.device} has no 64-bit atomics "
                                     "(cl_khr_int64_base_atomics), which the weighted mode's "
                                     "exact tallies need; use simulation.mode: analog")
        options = build_options(texture, precision, records, lanes, weighted)
        program, _ = devmod.build_program(self.device, WALK_FILES, options)
        self.kernel_hash = walk_source_hash()
        key = (texture, precision, records, lanes, weighted)
        if key not in self._kernels:
            import pyopencl as cl
            self._kernels[key] = cl.Kernel(program, "walk")
        return self._kernels[key]

    def run(self, params: WalkParams, photons: int, precision: str = "single",
            first_photon: int = 0, records: bool = False, batch: int | None = None,
            global_size: int | None = None, local_size: int | None = None,
            lanes: int | None = None, progress=None, qualified: bool = False) -> Counts:
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
            Photons per launch; by default sized from the measured speed.
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

        Returns
        -------
        Counts

        Raises
        ------
        WeightError
            Weighted mode: some exiting ray's weight was NaN, negative or >= 2**21, so the
            exact sums would have dropped it (docs/walk.md §6).
        """
        import pyopencl as cl

        real = np.float64 if precision == "double" else np.float32
        weighted = params.weighted
        lanes = self.lanes_for(params.texture, precision, weighted, lanes, check=not qualified)
        kern = self.kernel(params.texture, precision, records, lanes, weighted)
        edges = np.asarray(params.time_edges, dtype=real)
        n_time = len(edges) - 1
        gsize = int(global_size or self.default_global_size())
        if local_size is None and self.info.kind != "gpu":
            # PoCL runs the work-items of a group one after the other in one thread: groups
            # of one work-item spread the vectors over every core (2x on 2 cores, measured).
            local_size = 1
        if local_size:
            gsize = -(-gsize // local_size) * local_size

        mf = cl.mem_flags
        ctx, queue = self.context, self.queue
        d_edges = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=edges)
        hist_shapes = {"time_in_fov": (4, n_time), "time_any": (4, n_time),
                       "angular": (4, N_EMERGENCE), "total": (4,), "early": (4,)}
        d_hist = {k: cl.Buffer(ctx, mf.READ_WRITE, size=4 * int(np.prod(s)))
                  for k, s in hist_shapes.items()}
        d_stats = cl.Buffer(ctx, mf.READ_WRITE, size=8 * 8 * gsize)
        d_next = cl.Buffer(ctx, mf.READ_WRITE, size=4)
        # weighted sums: 192-bit fixed point, three uint64 words per cell (cl/tally.h)
        weight_shapes = {"w_time_in_fov": (4, n_time), "w_time_any": (4, n_time),
                         "w_angular": (4, N_EMERGENCE), "w_total": (4,),
                         "w2_time_in_fov": (4, n_time), "w2_total": (4,),
                         "w_early": (4,)} if weighted else {}
        d_weight = {k: cl.Buffer(ctx, mf.READ_WRITE, size=8 * 3 * int(np.prod(s)))
                    for k, s in weight_shapes.items()}

        cos_fov = params.cos_fov
        scalar_args = [
            real(params.thickness), real(params.flight_extinction),
            np.uint64(params.omega_words), real(params.g), real(params.n), real(params.k),
            real(params.albedo), np.uint64(params.albedo_words),
            real(params.path_cap), np.uint32(min(params.max_flights, 2 ** 31 - 1)),
            np.int32(params.bottom_interface == "fresnel"),
            real(params.absorption), real(params.roulette_weight),
            real(params.roulette_survival),
            np.int32(params.rule == "time_window"), real(params.first_bf_time),
        ]
        total = Counts(n_time=n_time, weighted=weighted)
        lost_weights = 0   # weighted exits whose weight the exact sums cannot hold
        rec_chunks = []
        done = 0
        size = int(batch) if batch else min(gsize * lanes * 4, photons) or 1
        while done < photons:
            n = min(size, photons - done, MAX_LAUNCH)
            for buf in (*d_hist.values(), *d_weight.values(), d_next):
                cl.enqueue_fill_buffer(queue, buf, np.uint32(0), 0, buf.size)
            args = [np.uint32(params.seed), np.uint64(params.scenario),
                    np.uint64(first_photon + done), np.uint32(n), *scalar_args,
                    d_edges, np.int32(len(edges)), *(real(c) for c in cos_fov),
                    d_next, d_hist["time_in_fov"], d_hist["time_any"], d_hist["angular"],
                    d_hist["total"], d_hist["early"], d_stats,
                    *(d_weight[k] for k in ("w_time_in_fov", "w_time_any", "w_angular",
                                            "w_total", "w_early", "w2_time_in_fov",
                                            "w2_total") if k in d_weight)]
            launch_items = min(gsize, -(-n // lanes))
            if local_size:
                launch_items = -(-launch_items // local_size) * local_size
            if records:
                d_ri = cl.Buffer(ctx, mf.WRITE_ONLY, size=4 * 8 * n)
                d_rr = cl.Buffer(ctx, mf.WRITE_ONLY, size=np.dtype(real).itemsize * 3 * n)
                args += [d_ri, d_rr]
            t0 = time.perf_counter()
            kern(queue, (launch_items,), (local_size,) if local_size else None, *args)
            part = Counts(n_time=n_time, photons=n, weighted=weighted)
            for name, shape in hist_shapes.items():
                host = np.empty(shape, dtype=np.uint32)
                cl.enqueue_copy(queue, host, d_hist[name])
                getattr(part, name)[...] = host
            for name, shape in weight_shapes.items():
                words = np.empty((*shape, 3), dtype=np.uint64)
                cl.enqueue_copy(queue, words, d_weight[name])
                setattr(part, name, _exact_sums(words))
            stats = np.empty((gsize, 8), dtype=np.uint64)
            cl.enqueue_copy(queue, stats, d_stats)
            stats = stats[:launch_items].astype(np.int64).sum(axis=0)
            part.fates[...] = stats[:5]
            part.scattering_events = int(stats[5])
            part.mixed_history = int(stats[6])
            lost_weights += int(stats[7])
            if records:
                ri = np.empty((n, 8), dtype=np.int32)
                rr = np.empty((n, 3), dtype=real)
                cl.enqueue_copy(queue, ri, d_ri)
                cl.enqueue_copy(queue, rr, d_rr)
                rec_chunks.append((ri, rr))
            queue.finish()
            elapsed = time.perf_counter() - t0
            total += part
            done += n
            if progress is not None:
                progress(done)
            if not batch:
                rate = n / max(elapsed, 1e-6)
                size = int(min(max(rate * self.target_launch_s, gsize * lanes), 4 * n, MAX_LAUNCH))
        if lost_weights:
            raise WeightError(lost_weights)
        if records:
            total.records = _records_from_chunks(rec_chunks)
        return total


def _exact_sums(words: np.ndarray) -> np.ndarray:
    """192-bit fixed-point words (low, middle, high) as exact Python ints (object array)."""
    lo, mid, hi = (words[..., i].astype(object) for i in range(3))
    return (hi << 128) + (mid << 64) + lo


def _records_from_chunks(chunks) -> dict:
    ri = np.concatenate([c[0] for c in chunks]) if chunks else np.empty((0, 8), np.int32)
    rr = np.concatenate([c[1] for c in chunks]).astype(np.float64) if chunks else np.empty((0, 3))
    exited = ri[:, 1] >= 0
    return {
        "fate": ri[:, 0].astype(np.int8), "component": ri[:, 1].astype(np.int8),
        "n_scat": ri[:, 2].astype(np.int64), "n_lamb": ri[:, 3].astype(np.int64),
        "n_bspec": ri[:, 4].astype(np.int64), "n_top": ri[:, 5].astype(np.int64),
        "time_bin": ri[:, 6].astype(np.int64), "emergence_bin": ri[:, 7].astype(np.int64),
        "time_ns": np.where(exited, rr[:, 0], np.nan),
        "cos_exit": np.where(exited, rr[:, 1], np.nan),
        "weight": rr[:, 2],
    }
