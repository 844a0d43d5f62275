"""Device qualification: a known-answer walk before a device is trusted (docs/devices.md).

An OpenCL driver can build our kernels and still compute garbage: pip's PoCL 3.0 (LLVM 14) on
an AVX-512 CPU it does not know compiles the 8-lane walk into one whose every ray is
"specular", and aborts the process while building the 16-lane one. So before warpe-cl uses a
*combination* -- device, driver version, kernel source, and the build switches that change the
machine code (lane width, precision, texture, weighted mode) -- it walks a few thousand rays of
small scenes that cover every path of that kernel and compares them ray by ray with the NumPy
reference (warpe_cl/reference.py), with the tolerances of tests/test_parity.py:

* double precision: every ray has the same fate, component, counters, time and emergence bins
  as the reference, times and exit cosines to 1e-9 relative, weights to 1e-9 relative;
* single precision: >= 99.5 % of the rays have identical histories, and their times agree to
  1e-4 t + 1e-7 ns (weights to 1e-4 relative);
* and the production kernel (built without per-ray records) gives the reference's histograms:
  identical in double, within 2 x 0.5 % of the rays (L1 over fates, components, early exits,
  time bins) in
  single.

The check runs in a child process (a driver that aborts or crashes kills the child, not
warpe-cl) and its verdict is cached per user in ``qualification.json`` of
:func:`warpe_cl.drivers.cache_dir`, under a lock, keyed by everything above plus the hash of
the reference walk and of this check; a changed key means a new check. A passing check of the
slab, analog kernel also measures the device's speed on scene B1 (events/s), which ``auto``
uses to pick the fastest qualified device.

The cache is trusted no further than it can be checked: an entry is used only if its fields
have the types and ranges a check writes (:func:`entry_problem`), its stored key is the key
looked up, and the SHA-256 stored with it matches its contents and key (:func:`entry_hash`);
anything else is ignored and checked again. A check that did not come to a verdict -- it ran
past its time limit, or its process was killed from outside (SIGKILL, SIGTERM, SIGINT,
SIGHUP: the OOM killer, a Ctrl-C) -- is *not checked yet*: cached as such with its date and a
count (no failure), so that other processes do not wait for it again; a run walks the next
narrower width that is already qualified, or checks the narrower ones. Such an entry is
checked again once it is older than :data:`UNCHECKED_TTL_S` (or after ``warpe-cl devices
--requalify``); a second check with no verdict at the same key, or a timeout on a machine
that was not busy (1-min load average per core below :data:`QUIET_LOAD`), is a failure
(:func:`after_no_verdict`).

Run by hand: ``python -m warpe_cl.qualify --device P:D --lanes 16 --combos slab:single:analog``.
"""
from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import signal
import subprocess
import sys
import time
import warnings
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from . import device as devmod
from .config.schema import FIELDS
from .device import INSTALL_HINT
from .drivers import usable_cache_dir
from .engine import WALK_FILES, Engine, kernel_key, walk_options, widest_lanes
from .errors import DeviceError, WarpeWarning
from .io import write_text
from .params import KERNEL_TEXTURES, RECORD_INT_COLUMNS, Layer, WalkParams, stack_params
from .reference import simulate_reference

try:
    import fcntl
except ImportError:          # no POSIX locks (Windows): the cache is written unlocked
    fcntl = None

#: bump when the check itself changes meaning, or the build of every program does (the hash of
#: this file is in the key as well); 2: division and square root correctly rounded
#: (device.EXACT_DIVIDE_SQRT)
QUALIFY_VERSION = 2
#: the lane widths a CPU falls back through (docs/walk.md §5); GPUs walk one ray per work-item
FALLBACK_LANES = (16, 8, 4, 1)
#: rays per scene of the known-answer walk
N_RAYS = 2000
#: a check that takes longer than this is stopped, s (``$WARPE_CL_QUALIFY_TIMEOUT``): a
#: build takes seconds, the walk and the speed probe about one; a driver stuck in its compiler
#: (pip's PoCL 3.0 at 16 lanes on Zen 4 spins for 2-3 minutes before it aborts) must not hold
#: a user's first run for long. A stopped check is *not checked yet*, not a failure: a loaded
#: machine is no verdict on the driver; it is cached as such for :data:`UNCHECKED_TTL_S`, then
#: checked again; a second one (or one on an idle machine) is a failure (:func:`after_no_verdict`)
CHILD_TIMEOUT_S = 60
#: a cached *not checked yet* entry is believed this long, s; then the width is checked again
#: (one day: a busy machine is rarely busy all day; a hang costs at most one timeout a day)
UNCHECKED_TTL_S = 86400
#: 1-min load average per CPU core below which the machine was not busy: a check that timed
#: out then is the driver's hang, a failure at once (every core had a free turn)
QUIET_LOAD = 1.0
MARK = "WARPE-QUALIFY "
#: signals that end a check's process from outside (the OOM killer, a Ctrl-C, a logout): they
#: say nothing about the driver, so the check is not checked yet rather than failed. A driver
#: that breaks ends its process with SIGABRT, SIGSEGV, SIGILL, SIGFPE or SIGBUS, a failure.
EXTERNAL_SIGNALS = tuple(int(getattr(signal, name)) for name in
                         ("SIGKILL", "SIGTERM", "SIGINT", "SIGHUP") if hasattr(signal, name))
#: no device walks scene B1 faster than this, events/s (a 2-core CPU: ~1e8; the largest GPUs
#: of 2026 below 1e11): a cached speed above it is not believed
MAX_EVENTS_PER_S = 1e13


@dataclass(frozen=True)
class Combo:
    """One kernel build: texture (slab, granular or layers: a stack, docs/walk.md §7),
    precision (single/double), weighted mode (never with layers)."""

    texture: str
    precision: str
    weighted: bool

    @property
    def label(self) -> str:
        return f"{self.texture}:{self.precision}:{'weighted' if self.weighted else 'analog'}"

    @classmethod
    def parse(cls, text: str) -> "Combo":
        texture, precision, mode = text.split(":")
        if texture not in KERNEL_TEXTURES or precision not in FIELDS["simulation.precision"].choices \
                or mode not in FIELDS["simulation.mode"].choices:
            raise ValueError(f"bad combination {text!r}")
        return cls(texture, precision, mode == "weighted")


#: the combination whose speed ranks devices (scene B1 is a slab walked analog)
RANK_COMBO = Combo("slab", "single", False)


def all_combos(fp64: bool) -> list:
    """Every combination a device can be asked for."""
    return [Combo(t, p, w) for p in (("single", "double") if fp64 else ("single",))
            for t in KERNEL_TEXTURES for w in (False, True) if not (w and t == "layers")]


# --------------------------------------------------------------------------------------------
# the known-answer walk (runs in the child)

def _scenes(combo: Combo) -> dict:
    """The small media of the check: every path of the kernel that ``combo`` builds, with the
    nadir estimate (docs/walk.md §8), which every run makes by default (its build holds the
    whole walk and the estimator, with the mirror paths of a slab over a gap and of a stack's
    Fresnel contacts)."""
    edges = 1e-6 * 10 ** (np.arange(0, 221) / 20)          # 1e-6 .. 1e5 ns
    base = dict(thickness=0.01, time_edges=edges, seed=7, bottom_interface="fresnel",
                nadir=True)
    if combo.texture == "layers":
        # every contact of docs/walk.md §7: slab over slab (Fresnel both ways, TIR), slab
        # over granular (the pores' face), granular over granular (transparent), a substrate
        # under a granular layer (gap events with n_g > 1), and a granular top (no entry)
        common = dict(time_edges=edges, seed=7, albedo=0.6, nadir=True)
        return {
            "slab_slab_granular": stack_params(
                [Layer("slab", 0.004, 150.0, 0.97, 0.7, 1.31, 1e-5),
                 Layer("slab", 0.003, 120.0, 0.9, 0.3, 1.6, 1e-3),
                 Layer("granular", 0.005, 300.0, 0.99, 0.5, 1.36)],
                bottom_interface="fresnel", **common),
            "granular_granular_substrate": stack_params(
                [Layer("granular", 0.003, 400.0, 0.98, 0.6, 1.2),
                 Layer("granular", 0.004, 250.0, 0.95, 0.2, 1.4)],
                substrate=(1.7, 1e-3), **common),
            "granular_slab_contact": stack_params(
                [Layer("granular", 0.004, 300.0, 0.99, 0.5, 1.3),
                 Layer("slab", 0.006, 80.0, 0.96, 0.8, 1.92, 9.5e-6)],
                bottom_interface="none", rule="time_window", **common),
        }
    if combo.texture == "slab":
        media = {
            # Fresnel top and bottom, a vacuum gap over the floor, HG scattering, absorption
            "slab_fresnel": dict(texture="slab", extinction=100.0, omega=0.9, g=0.8, n=1.3,
                                 k=1e-4, albedo=0.5),
            # the floor in optical contact (no bottom interface)
            "slab_contact": dict(texture="slab", bottom_interface="none", extinction=50.0,
                                 omega=0.97, g=0.6, n=1.45, k=0.0, albedo=0.8),
            # a thin, high-index slab: total internal reflection, isotropic scattering
            "slab_thin_tir": dict(texture="slab", extinction=20.0, omega=0.99, g=0.0, n=1.92,
                                  k=9.5e-6, albedo=0.9, thickness=0.02),
        }
    else:
        media = {
            "granular": dict(texture="granular", extinction=200.0, omega=0.95, g=0.5, n=1.36,
                             k=0.0, albedo=0.5),
            "granular_time_window": dict(texture="granular", extinction=150.0, omega=0.99,
                                         g=0.8, n=1.27, k=0.0, albedo=0.3, rule="time_window"),
        }
    out = {}
    for name, kw in media.items():
        kw = {**base, **kw}
        if combo.weighted:
            kw.update(mode="weighted", roulette_weight=0.05)
        out[name] = WalkParams(**kw)
    return out


EXACT_FIELDS = RECORD_INT_COLUMNS
HIST_FIELDS = ("fates", "total", "early", "time_any", "time_in_fov", "angular")


def compare_records(ker, ref, precision: str, weighted: bool) -> str | None:
    """Ray-by-ray comparison of kernel and reference records; ``None`` or what differs."""
    kr, rr = ker.records, ref.records
    n = len(rr["fate"])
    same = np.ones(n, dtype=bool)
    for field in EXACT_FIELDS:
        same &= kr[field] == rr[field]
    exited = np.isfinite(rr["time_ns"])
    if precision == "double":
        if not same.all():
            i = int(np.argmin(same))
            bad = [f for f in EXACT_FIELDS if kr[f][i] != rr[f][i]]
            return f"ray {i}: {', '.join(bad)} differ from the reference ({int((~same).sum())} of {n} rays)"
        for field, rtol in (("time_ns", 1e-9), ("cos_exit", 1e-9)):
            a, b = kr[field][exited], rr[field][exited]
            if not np.all(np.abs(a - b) <= rtol * np.abs(b) + 1e-12):
                return f"{field} differs from the reference by more than {rtol:g}"
        if weighted and not np.allclose(kr["weight"], rr["weight"], rtol=1e-9, atol=0):
            return "ray weights differ from the reference by more than 1e-9"
        if not np.allclose(kr["nadir"], rr["nadir"], rtol=1e-9, atol=0):
            return "nadir scores differ from the reference by more than 1e-9"
        return None
    if same.mean() < 0.995:
        return (f"only {same.mean():.1%} of the rays follow the reference's history "
                f"(>= 99.5 % required)")
    ok = same & exited
    t_ker, t_ref = kr["time_ns"][ok], rr["time_ns"][ok]
    if not np.all(np.abs(t_ker - t_ref) <= 1e-4 * t_ref + 1e-7):
        return "exit times differ from the reference by more than 1e-4 t + 1e-7 ns"
    if weighted:
        w_ker, w_ref = kr["weight"][same], rr["weight"][same]
        if not np.all(np.abs(w_ker - w_ref) <= 1e-4 * np.abs(w_ref)):
            return "ray weights differ from the reference by more than 1e-4"
    # a ray's nadir score: its sum over its events, in single precision to about 1e-5; a
    # roulette decided within rounding of its threshold may differ (rarely)
    n_ker, n_ref = kr["nadir"][same], rr["nadir"][same]
    close = np.abs(n_ker - n_ref) <= 1e-3 * np.abs(n_ref) + 1e-30
    if close.mean() < 0.995:
        return (f"only {close.mean():.1%} of the rays' nadir scores are within 1e-3 of the "
                f"reference's (>= 99.5 % required)")
    return None


def compare_counts(ker, ref, precision: str) -> str | None:
    """The production kernel's histograms against the reference's (same rays)."""
    if ker.photons != ref.photons:
        return "the kernel walked a different number of rays"
    allowed = 0 if precision == "double" else 2 * int(np.ceil(0.005 * ref.photons))
    for name in HIST_FIELDS:
        a = np.asarray(getattr(ker, name), dtype=np.int64)
        b = np.asarray(getattr(ref, name), dtype=np.int64)
        diff = int(np.abs(a - b).sum())
        if diff > allowed:
            return (f"its {name} histogram differs from the reference's by {diff} rays "
                    f"of {ref.photons} (at most {allowed} allowed)")
    return None


def _b1_params():
    """Scene B1 of tools/bench/bench.py (60 mm slab, tau0 = 60.3, omega = 0.995): the speed probe."""
    edges = 1e-6 * 10 ** (np.arange(0, 221) / 20)
    return WalkParams(texture="slab", thickness=0.06, extinction=1005.0, omega=0.99502, g=0.8,
                      n=1.3, k=0.0, albedo=0.15, time_edges=edges, seed=1, max_time=5.0,
                      bottom_interface="fresnel")


def measure_speed(engine, lanes: int, precision: str, seconds: float = 0.5) -> float:
    """Scattering events per second of scene B1 on ``engine`` at ``lanes``."""
    params = _b1_params()
    engine.run(params, 2000, precision=precision, lanes=lanes, batch=2000)     # warm-up
    n = 20_000
    while True:
        t0 = time.perf_counter()
        counts = engine.run(params, n, precision=precision, lanes=lanes)
        dt = time.perf_counter() - t0
        if dt >= seconds or n >= 1 << 26:
            return counts.scattering_events / dt
        n = int(min(n * max(2.0, 1.2 * seconds / max(dt, 1e-3)), 1 << 26))


def check(engine, lanes: int, combo: Combo, measure: bool = True, corrupt: bool = False) -> dict:
    """Qualify one combination on ``engine`` (in this process). Returns the verdict entry.

    ``corrupt`` stands in for a miscompiling driver (every ray reported specular, as pip's
    PoCL 3.0 did at 8 lanes on AVX-512 CPUs): the test of the check itself."""
    t0 = time.perf_counter()
    entry = {"passed": False, "reason": None, "events_per_s": None}
    try:
        for name, params in _scenes(combo).items():
            ref = simulate_reference(params, N_RAYS, first_photon=11, records=True)
            ker = engine.run(params, N_RAYS, precision=combo.precision, first_photon=11,
                             records=True, lanes=lanes, qualified=True)
            if corrupt:
                ker.records["fate"][:] = 0
                ker.records["component"][:] = 0
            reason = compare_records(ker, ref, combo.precision, combo.weighted)
            if reason is None:
                prod = engine.run(params, N_RAYS, precision=combo.precision, first_photon=11,
                                  lanes=lanes, qualified=True)
                reason = compare_counts(prod, ref, combo.precision)
            if reason is not None:
                entry["reason"] = f"{name}: {reason}"
                break
        else:
            entry["passed"] = True
            if measure and combo.texture == "slab" and not combo.weighted:
                entry["events_per_s"] = measure_speed(engine, lanes, combo.precision)
    except Exception as err:  # noqa: BLE001 - any failure of the driver is a verdict
        text = " ".join(str(err).split())
        entry["reason"] = f"{type(err).__name__}: {text[:300]}"
    entry["seconds"] = round(time.perf_counter() - t0, 3)
    return entry


# --------------------------------------------------------------------------------------------
# the cache of verdicts

@lru_cache(maxsize=None)
def _source_digest() -> str:
    """Hash of everything that decides a verdict besides the device and the build options:
    kernel sources (their contents, wherever they are installed), the reference walk, its
    random numbers, and this check (read once per process)."""
    h = hashlib.sha256(devmod.source_hash(WALK_FILES).encode())
    here = Path(__file__).resolve().parent
    for name in ("reference.py", "rng.py", "params.py", "qualify.py"):
        h.update((here / name).read_bytes())
    return h.hexdigest()


def combo_key(info, lanes: int, combo: Combo) -> dict:
    """Everything a verdict depends on."""
    fault = _fault(lanes)
    key = {"fault": fault} if fault else {}
    structure = kernel_key(combo.texture, combo.precision, False, lanes, combo.weighted)
    return {**key, "platform": f"{info.platform} {info.platform_version}", "device": info.device,
            "driver": info.driver, "sources": _source_digest(), "version": QUALIFY_VERSION,
            "options": list(walk_options(info, structure)), "lanes": lanes, "combo": combo.label}


def _key_id(key: dict) -> str:
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:32]


def _canonical(value) -> str:
    """JSON text of ``value`` with sorted keys and no white space (NaN refused)."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def entry_hash(entry: dict, key: dict) -> str:
    """SHA-256 of a verdict and its key: the canonical JSON of the entry without its own
    ``sha256`` field, with ``key`` in its ``key`` field.

    Parameters
    ----------
    entry : dict
        The verdict (its ``sha256`` and ``key`` fields, if any, are replaced).
    key : dict
        The key it is stored under (:func:`combo_key`).

    Returns
    -------
    str
        64 hexadecimal digits.
    """
    body = {k: v for k, v in entry.items() if k != "sha256"}
    body["key"] = key
    return hashlib.sha256(_canonical(body).encode()).hexdigest()


def is_unchecked(entry: dict) -> bool:
    """True for the entry of a check that came to no verdict (it timed out, or its process was
    killed from outside): *not checked yet*, cached with its date for :data:`UNCHECKED_TTL_S`
    (:func:`after_no_verdict`)."""
    return entry.get("checked") is False


DATE_FORMAT = "%Y-%m-%dT%H:%M:%S"


def _date_seconds(date) -> float | None:
    """Seconds since the epoch of a stored ``date`` (local time, :data:`DATE_FORMAT`), or
    ``None`` where it is no such date."""
    try:
        return time.mktime(time.strptime(date, DATE_FORMAT))
    except (TypeError, ValueError, OverflowError):
        return None


def is_stale(entry: dict, now: float | None = None) -> bool:
    """True for a *not checked yet* entry older than :data:`UNCHECKED_TTL_S` (or undated, or
    dated in the future): its width is checked again."""
    if not is_unchecked(entry):
        return False
    when = _date_seconds(entry.get("date"))
    now = time.time() if now is None else now
    return when is None or not (-3600 <= now - when < UNCHECKED_TTL_S)


def load_per_core() -> float | None:
    """The 1-min load average per CPU core, or ``None`` where the system does not say."""
    try:
        return os.getloadavg()[0] / max(1, os.cpu_count() or 1)
    except (AttributeError, OSError):
        return None


def after_no_verdict(previous: dict | None, entry: dict, lanes: int) -> dict:
    """The entry to cache for a check at ``lanes`` that came to no verdict (``entry``, from
    :func:`run_child`), given the entry cached before at the same key (``previous``).

    The rule (docs/devices.md): the first such check is *not checked yet* (``checked: false``,
    ``unfinished: 1``, its date), no failure. It becomes a **failure**, with the reason, when

    * an earlier check at the same key came to no verdict too (``previous`` not checked yet,
      whatever its age): a second timeout or kill is the driver's, not the machine's; or
    * the check timed out while the machine was not busy: the 1-min load average per core
      (``load_per_core``, measured at the timeout) was below :data:`QUIET_LOAD`.

    Parameters
    ----------
    previous : dict or None
        The entry cached at the key before this check.
    entry : dict
        The check's entry: ``checked`` false, ``reason``, ``seconds`` (s), ``date``,
        ``child_wall_s`` (s), ``load_per_core`` (None for a kill).
    lanes : int
        The lane width checked.

    Returns
    -------
    dict
        The entry to cache and use: not checked yet, or a failure.
    """
    load = entry.get("load_per_core")
    timed_out = "did not finish" in (entry.get("reason") or "")
    what = (entry.get("reason") or "").removeprefix("not checked yet: ")
    again = previous is not None and is_unchecked(previous)
    if again:
        reason = (f"the check came to no verdict twice at {lanes} lanes (first on "
                  f"{previous.get('date')}; now {what}): a failure "
                  "(`warpe-cl devices --requalify` checks again)")
    elif timed_out and load is not None and load < QUIET_LOAD:
        reason = (f"{what} on a machine that was not busy (load {load:.2f} per core): the "
                  "driver hangs, a failure (`warpe-cl devices --requalify` checks again)")
    else:
        return {**entry, "checked": False, "unfinished": 1}
    out = {k: v for k, v in entry.items() if k not in ("checked", "unfinished")}
    out.update(passed=False, reason=reason, events_per_s=None)
    return out


def _finite_number(value) -> bool:
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and bool(np.isfinite(value)))


#: the fields of a stored verdict: name -> is it required
ENTRY_FIELDS = {"passed": True, "reason": True, "events_per_s": True, "seconds": True,
                "date": False, "child_wall_s": False, "key": True, "sha256": True,
                "checked": False, "unfinished": False, "load_per_core": False}


def entry_problem(entry, key: dict) -> str | None:
    """What is wrong with a stored verdict of ``key``, or ``None`` where it can be believed.

    A verdict is believed when it is a JSON object with exactly the fields a check stores
    (:data:`ENTRY_FIELDS`), ``passed`` a boolean, ``reason`` a string or null, ``events_per_s``
    null or (on a pass) a finite number in (0, :data:`MAX_EVENTS_PER_S`), ``seconds`` and
    ``child_wall_s`` finite and >= 0, ``date`` a string, its ``key`` the key looked up, and its
    ``sha256`` the :func:`entry_hash` of the rest.

    Parameters
    ----------
    entry : object
        What the cache file holds under the key's id.
    key : dict
        The key looked up (:func:`combo_key`).

    Returns
    -------
    str or None
        One phrase naming the first problem found.
    """
    if not isinstance(entry, dict):
        return "not a JSON object"
    missing = [f for f, required in ENTRY_FIELDS.items() if required and f not in entry]
    if missing:
        return f"no {', '.join(missing)}"
    unknown = sorted(set(entry) - set(ENTRY_FIELDS))
    if unknown:
        return f"unknown field(s) {', '.join(unknown)}"
    if not isinstance(entry["passed"], bool):
        return f"passed is {entry['passed']!r}, not true or false"
    if entry["reason"] is not None and not isinstance(entry["reason"], str):
        return "reason is not a string"
    speed = entry["events_per_s"]
    if speed is not None:
        if not entry["passed"]:
            return "a failed check has a speed"
        if not (_finite_number(speed) and 0 < speed < MAX_EVENTS_PER_S):
            return f"events_per_s {speed!r} is not a speed in (0, {MAX_EVENTS_PER_S:g})"
    for name in ("seconds", "child_wall_s"):
        if name in entry and not (_finite_number(entry[name]) and entry[name] >= 0):
            return f"{name} {entry[name]!r} is not a finite duration"
    if "date" in entry and not isinstance(entry["date"], str):
        return "date is not a string"
    if "checked" in entry:
        # a check that came to no verdict: not checked yet, with its date and count
        if entry["checked"] is not False or entry["passed"] is not False:
            return "checked is not false on a failed entry"
        count = entry.get("unfinished")
        if not (isinstance(count, int) and not isinstance(count, bool) and count == 1):
            return f"unfinished {count!r} is not 1 (a second one is a failure)"
        if _date_seconds(entry.get("date")) is None:
            return "a check with no verdict has no date"
    elif "unfinished" in entry:
        return "unfinished without checked"
    if "load_per_core" in entry and entry["load_per_core"] is not None \
            and not (_finite_number(entry["load_per_core"]) and entry["load_per_core"] >= 0):
        return f"load_per_core {entry['load_per_core']!r} is not a load"
    try:
        if _canonical(entry["key"]) != _canonical(key):
            return "its stored key is not the key looked up"
        if entry["sha256"] != entry_hash(entry, key):
            return "its sha256 does not match its contents"
    except (TypeError, ValueError):
        return "it cannot be written as JSON again"
    return None


#: cache files whose invalid entries were reported (one line per file and process)
_warned_invalid: set = set()


class VerdictCache:
    """Verdicts on disk (JSON), shared by every process of the user under a file lock.

    Parameters
    ----------
    folder : Path, optional
        Where ``qualification.json`` is (default :func:`warpe_cl.drivers.usable_cache_dir`:
        the cache folder, or this run's private folder where that cannot be written).
    """

    def __init__(self, folder: Path | None = None):
        self.folder = Path(folder) if folder else usable_cache_dir()
        self.path = self.folder / "qualification.json"

    @contextlib.contextmanager
    def _locked(self):
        self.folder.mkdir(parents=True, exist_ok=True)
        with open(self.folder / "qualification.lock", "a+") as fh:
            try:
                if fcntl is not None:
                    fcntl.flock(fh, fcntl.LOCK_EX)
            except OSError:
                pass
            yield

    def _read(self) -> dict:
        try:
            data = json.loads(self.path.read_text())
            return data if isinstance(data, dict) else {}
        except (OSError, ValueError):
            return {}

    def get(self, key: dict) -> dict | None:
        """The stored verdict of ``key`` if it can be believed (:func:`entry_problem`), else
        ``None``: an invalid entry is checked again, and said once per file in one line."""
        entry = self._read().get(_key_id(key))
        if entry is None:
            return None
        problem = entry_problem(entry, key)
        if problem is None:
            return {k: v for k, v in entry.items() if k not in ("key", "sha256")}
        if not (isinstance(entry, dict) and "sha256" not in entry and "key" in entry) \
                and str(self.path) not in _warned_invalid:
            # an entry of warpe-cl <= 0.x had no hash: replaced quietly; others are said
            _warned_invalid.add(str(self.path))
            warnings.warn(f"{self.path}: a cached verdict ({key.get('combo')} at "
                          f"{key.get('lanes')} lanes) is not valid ({problem}): ignored, "
                          "checked again", WarpeWarning, stacklevel=2)
        return None

    def clear(self) -> None:
        """Forget every verdict (``warpe-cl devices --requalify``)."""
        with contextlib.suppress(OSError), self._locked():
            self.path.unlink(missing_ok=True)

    def put(self, items) -> None:
        """Store ``[(key, entry), ...]`` (read-modify-write under the lock, atomic replace)."""
        try:
            with self._locked():
                data = self._read()
                for key, entry in items:
                    stored = {**entry, "key": key}
                    stored["sha256"] = entry_hash(stored, key)
                    data[_key_id(key)] = stored
                write_text(self.path, json.dumps(data, indent=1, sort_keys=True))
        except OSError:
            pass   # a cache that cannot be written costs time, never correctness


# --------------------------------------------------------------------------------------------
# the parent's side

def _signal_name(code: int) -> str:
    try:
        return signal.Signals(-code).name
    except ValueError:
        return f"signal {-code}"


def _crash_reason(proc: subprocess.CompletedProcess, lanes: int) -> str:
    how = (f"was killed by {_signal_name(proc.returncode)}" if proc.returncode < 0
           else f"exited with code {proc.returncode}")
    lines = [ln.strip() for ln in (proc.stderr or "").splitlines() if ln.strip()]
    hint = next((ln for ln in lines if "ERROR" in ln or "Error" in ln), lines[-1] if lines else "")
    return (f"the driver's process {how} while building or walking {lanes} lanes"
            + (f" ({hint[:200]})" if hint else ""))


def run_child(info, lanes: int, combos, measure: bool = True) -> dict:
    """Qualify ``combos`` at ``lanes`` on the device ``info`` in a child process.

    Returns ``{combo: entry}``; a child that crashes or prints nothing fails every
    combination it was given, with the reason. A child that runs past the time limit
    (``$WARPE_CL_QUALIFY_TIMEOUT``, default :data:`CHILD_TIMEOUT_S`) or is killed from outside
    (:data:`EXTERNAL_SIGNALS`) came to no verdict: its entries are *not checked yet*
    (``"checked": False``, :func:`is_unchecked`; a timeout's with the machine's
    ``load_per_core`` then), which the caller caches by the rule of :func:`after_no_verdict`.
    """
    cmd = [sys.executable, "-m", "warpe_cl.qualify", "--device", info.spec, "--lanes",
           str(lanes), "--combos", ",".join(c.label for c in combos), "--expect", info.device]
    if not measure:
        cmd.append("--no-measure")
    env = dict(os.environ)
    env.pop("WARPE_CL_LANES", None)
    timeout = float(os.environ.get("WARPE_CL_QUALIFY_TIMEOUT", "") or CHILD_TIMEOUT_S)
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        reason = (f"not checked yet: the check did not finish in {timeout:g} s at {lanes} "
                  "lanes (a busy machine?; $WARPE_CL_QUALIFY_TIMEOUT)")
        load = load_per_core()
        return {c: {"passed": False, "checked": False, "reason": reason, "events_per_s": None,
                    "seconds": timeout, "load_per_core": load} for c in combos}
    if proc.returncode < 0 and -proc.returncode in EXTERNAL_SIGNALS:
        reason = (f"not checked yet: the check's process was killed by "
                  f"{_signal_name(proc.returncode)} from outside at {lanes} lanes")
        took = round(time.perf_counter() - t0, 3)
        return {c: {"passed": False, "checked": False, "reason": reason, "events_per_s": None,
                    "seconds": took, "load_per_core": None} for c in combos}
    results = None
    for line in proc.stdout.splitlines():
        if line.startswith(MARK):
            results = json.loads(line[len(MARK):])
    if proc.returncode != 0 or results is None:
        reason = _crash_reason(proc, lanes)
        took = round(time.perf_counter() - t0, 3)
        return {c: {"passed": False, "reason": reason, "events_per_s": None, "seconds": took}
                for c in combos}
    return {Combo.parse(label): entry for label, entry in results.items()}


class Qualifier:
    """Verdicts for one device: cached, else checked in a child process."""

    def __init__(self, info, cache: VerdictCache | None = None, say=None):
        self.info = info
        self.cache = cache or VerdictCache()
        self.say = say
        self._memo = {}

    def lane_chain(self, precision: str) -> tuple:
        """The lane widths tried, widest first (engine.widest_lanes: a vector of 512 bits on
        CPUs, or the driver's preferred vector width where narrower; one on GPUs)."""
        widest = widest_lanes(self.info.kind, precision, self.info.preferred_width(precision))
        return (widest,) + tuple(w for w in FALLBACK_LANES if w < widest)

    def verdicts(self, lanes: int, combos, measure: bool = True) -> dict:
        """``{combo: entry}`` at ``lanes``; the missing ones are checked in one child."""
        out, missing, keys = {}, [], {c: combo_key(self.info, lanes, c) for c in combos}
        before = {}
        for c in combos:
            kid = _key_id(keys[c])
            entry = self._memo.get(kid) or self.cache.get(keys[c])
            # a passing verdict of the ranking kernel without its speed is checked again
            # when the speed is wanted (it was made by a run that did not measure); a cached
            # "not checked yet" older than UNCHECKED_TTL_S is checked again
            unmeasured = (measure and c == RANK_COMBO and entry is not None and entry["passed"]
                          and entry.get("events_per_s") is None)
            if entry is not None and not unmeasured and not (
                    kid not in self._memo and is_stale(entry)):
                out[c] = self._memo[kid] = entry
            else:
                before[c] = entry
                missing.append(c)
        if missing:
            if self.say:
                self.say(f"qualifying {describe_short(self.info)} at {lanes} lanes: "
                         f"{', '.join(c.label for c in missing)} (first use; cached after)")
            t0 = time.perf_counter()
            fresh = run_child(self.info, lanes, missing, measure)
            wall = round(time.perf_counter() - t0, 2)
            stamp = time.strftime("%Y-%m-%dT%H:%M:%S")
            items = []
            for c in missing:
                entry = {**fresh.get(c, {"passed": False, "reason": "no verdict returned",
                                         "events_per_s": None, "seconds": 0.0}),
                         "date": stamp, "child_wall_s": wall}
                previous = before.get(c)
                if is_unchecked(entry) and previous is not None and previous["passed"]:
                    # the speed of a passing kernel could not be measured: it still passed
                    # (kept as it was, without a speed); measured again by the next process
                    out[c] = self._memo[_key_id(keys[c])] = previous
                    continue
                if is_unchecked(entry):
                    entry = after_no_verdict(previous, entry, lanes)
                out[c] = self._memo[_key_id(keys[c])] = entry
                items.append((keys[c], entry))
            if items:
                self.cache.put(items)
        return out

    def known(self, lanes: int, combo: Combo) -> dict | None:
        """The verdict of ``combo`` at ``lanes`` if this process or the cache has one (a check
        with no verdict included), else ``None``; never checks."""
        key = combo_key(self.info, lanes, combo)
        kid = _key_id(key)
        if kid not in self._memo:
            entry = self.cache.get(key)
            if entry is None:
                return None
            self._memo[kid] = entry
        return self._memo[kid]

    def choose(self, combo: Combo, measure: bool = False, check: bool = True) -> "LaneChoice":
        """The widest usable lane width for ``combo``, the widths that failed above it, and
        those not checked yet.

        The widths of :meth:`lane_chain` are taken widest first. A width that fails is a
        failure. A width whose check came to no verdict (timed out, killed from outside) is
        *not checked yet*: the next narrower width that is already qualified (cached) is used,
        the failures cached on the way listed; where none is, the narrower widths are checked
        in turn.

        Parameters
        ----------
        combo : Combo
        measure : bool
            Measure the speed of the ranking kernel when checking it.
        check : bool
            ``False``: look only at the verdicts this process and the cache have (a width
            never checked is *not checked yet*, with reason ``None``); nothing is checked.

        Returns
        -------
        LaneChoice
        """
        chain = self.lane_chain(combo.precision)
        failures, unchecked = [], []
        i = 0
        while i < len(chain):
            lanes = chain[i]
            entry = (self.verdicts(lanes, [combo], measure=measure)[combo] if check
                     else self.known(lanes, combo))
            i += 1
            if entry is None:
                unchecked.append((lanes, None))
                continue
            if entry["passed"]:
                return LaneChoice(lanes, tuple(failures), tuple(unchecked), entry)
            if not is_unchecked(entry):
                failures.append((lanes, entry["reason"]))
                continue
            unchecked.append((lanes, entry["reason"]))
            # a busy machine: walk a narrower width already qualified rather than check more
            for j in range(i, len(chain)):
                known = self.known(chain[j], combo)
                if known is not None and known["passed"] and check and measure:
                    # the entry used must be the one the caller gets (with its speed, where
                    # measured): a usable choice is only ever made of a passed entry
                    known = self.verdicts(chain[j], [combo], measure=True)[combo]
                if known is not None and known["passed"]:
                    for w in chain[i:j]:            # the widths skipped, as far as known
                        e = self.known(w, combo)
                        if e is None or is_unchecked(e):
                            unchecked.append((w, None if e is None else e["reason"]))
                        else:
                            failures.append((w, e["reason"]))
                    return LaneChoice(chain[j], tuple(failures), tuple(unchecked), known)
        return LaneChoice(None, tuple(failures), tuple(unchecked))

    def best_lanes(self, combo: Combo, measure: bool = False):
        """The widest qualified lane width for ``combo`` and the failures above it
        (:meth:`choose`, checking what is not known yet).

        Widths whose check came to no verdict are not failures: where a narrower width is
        walked instead, one :class:`~warpe_cl.errors.WarpeWarning` line says so; where no
        width is usable, they are listed with the failures (their reasons say "not checked
        yet").

        Returns
        -------
        (int or None, list of (lanes, reason))
        """
        choice = self.choose(combo, measure=measure)
        if choice.lanes is None:
            return None, sorted(choice.failures + choice.unchecked, reverse=True)
        message = fallback_message(self.info, combo, choice)
        if message:
            warnings.warn(message, WarpeWarning, stacklevel=3)
        return choice.lanes, list(choice.failures)


def fallback_message(info, combo: Combo, choice: "LaneChoice") -> str | None:
    """The one warning line of a run that walks ``choice.lanes`` narrower than the widest
    width: the widths that failed (the first one's reason) and those not checked yet (the
    first one's reason), merged; ``None`` where nothing above was skipped.

    Parameters
    ----------
    info : DeviceInfo
    combo : Combo
    choice : LaneChoice
        With ``lanes`` set (a usable width).

    Returns
    -------
    str or None
    """
    parts = []
    if choice.failures:
        parts.append(f"failed qualification at {', '.join(str(w) for w, _ in choice.failures)}"
                     f" lanes ({choice.failures[0][1]})")
    if choice.unchecked:
        first, why = choice.unchecked[0]
        why = (why or "not checked yet").removeprefix("not checked yet: ")
        parts.append(f"not checked yet at {', '.join(str(w) for w, _ in choice.unchecked)} "
                     f"lanes ({why}; checked again after {UNCHECKED_TTL_S // 3600} h, or "
                     "with `warpe-cl devices --requalify`)")
    if not parts:
        return None
    return (f"{describe_short(info)}: {combo.label} {'; '.join(parts)}; walking {choice.lanes} "
            "lanes" + (", already qualified" if choice.unchecked else ""))


@dataclass(frozen=True)
class LaneChoice:
    """What :meth:`Qualifier.choose` found for one kernel combination.

    Attributes
    ----------
    lanes : int or None
        The widest usable (qualified) lane width, ``None`` when there is none.
    failures : tuple of (int, str)
        Widths above it (or all, when none) that failed, with why.
    unchecked : tuple of (int, str or None)
        Widths above it (or all) not checked yet: the check timed out or was killed (its
        reason), or was never run (``None``, when only the cache is read).
    """

    lanes: int | None
    failures: tuple = ()
    unchecked: tuple = ()
    #: the passed verdict of ``lanes`` (``None`` when there is none)
    entry: dict | None = None


_qualifiers: dict = {}


def describe_short(info) -> str:
    """``P:D device (driver)`` in a few words, for one-line messages."""
    return f"{info.spec} {info.device} ({info.platform_version.split(',')[0].strip()})"


def qualifier_for(info, say=None) -> Qualifier:
    """The process's :class:`Qualifier` of the device ``info`` (one per device)."""
    key = (info.platform, info.platform_version, info.device, info.driver, info.spec)
    if key not in _qualifiers:
        _qualifiers[key] = Qualifier(info, say=say or _stderr)
    return _qualifiers[key]


def _stderr(message: str) -> None:
    print(f"warpe-cl: {message}", file=sys.stderr, flush=True)


class LaneChooser:
    """The lane width an :class:`~warpe_cl.engine.Engine` walks each kernel with, qualified on
    its device (docs/devices.md): what :func:`warpe_cl.api.get_engine` hands the engine.

    Parameters
    ----------
    qualifier : Qualifier
        The device's verdicts (:func:`qualifier_for`).
    """

    def __init__(self, qualifier: Qualifier):
        self.qualifier = qualifier
        self.info = qualifier.info
        self._lanes = {}

    def __call__(self, texture: str, precision: str, weighted: bool,
                 lanes: int | None = None) -> int:
        """The lane width for this kernel.

        Parameters
        ----------
        texture, precision, weighted
            The kernel's combination (:class:`Combo`).
        lanes : int, optional
            One width asked for (``lanes=`` or ``$WARPE_CL_LANES``): used if it qualifies,
            otherwise :class:`~warpe_cl.errors.DeviceError` says why. Without it, the widest
            width that qualifies (:meth:`Qualifier.choose`); a fallback is said in one warning
            line.

        Returns
        -------
        int

        Raises
        ------
        DeviceError
            The width asked for failed or is not checked yet, or no width is usable.
        """
        combo = Combo(texture, precision, bool(weighted))
        key = (combo, lanes)
        if key in self._lanes:
            return self._lanes[key]
        if lanes is not None:
            entry = self.qualifier.verdicts(int(lanes), [combo], measure=False)[combo]
            if is_unchecked(entry):
                raise DeviceError(
                    f"{describe_short(self.info)}: {combo.label} at {lanes} lanes (asked for) "
                    f"is not checked yet: the check timed out or was stopped "
                    f"({entry['reason'].removeprefix('not checked yet: ')}); run again after "
                    f"{UNCHECKED_TTL_S // 3600} h or `warpe-cl devices --requalify` (on a "
                    "machine less busy), or unset WARPE_CL_LANES to walk a qualified width")
            if not entry["passed"]:
                raise DeviceError(
                    f"{describe_short(self.info)} failed qualification at {lanes} lanes for "
                    f"{combo.label}: "
                    f"{entry['reason']}")
            chosen = int(lanes)
        else:
            choice = self.qualifier.choose(combo)
            chosen = choice.lanes
            if chosen is None:
                raise DeviceError(
                    f"{describe_short(self.info)} is not usable for {combo.label}: "
                    + "; ".join(f"{w} lanes: {r}" for w, r in
                                sorted(choice.failures + choice.unchecked, reverse=True)))
            message = fallback_message(self.info, combo, choice)   # one line, both kinds
            if message:
                # stacklevel 3: the line that called Engine.lanes_for
                warnings.warn(message, WarpeWarning, stacklevel=3)
        self._lanes[key] = chosen
        return chosen


# --------------------------------------------------------------------------------------------
# choosing a device

def select_device(spec: str | None = None, qualify: bool = True):
    """Choose a usable OpenCL device.

    Parameters
    ----------
    spec : str, optional
        ``auto``, ``cpu``, ``gpu``, ``P:D`` (platform and device index), or a substring of the
        device or platform name. ``None`` reads ``$WARPE_CL_DEVICE``, then ``$PYOPENCL_CTX``.
    qualify : bool
        Require the device to pass the known-answer walk (:mod:`warpe_cl.qualify`) at some
        lane width; ``auto``, ``cpu`` and ``gpu`` then pick the fastest qualified device
        (scattering events/s on scene B1, measured once and cached). ``False`` only builds
        the self-test program (the qualification's own child process uses this).

    Returns
    -------
    (DeviceInfo, pyopencl.Device)

    Raises
    ------
    DeviceError
        When nothing matches, or nothing that matches is usable; the message says why and
        what to install.
    """
    spec = devmod.resolve_spec(spec)
    devices = devmod.list_devices()
    if not devices:
        raise DeviceError(f"no OpenCL platform found; {INSTALL_HINT}")
    matches = devmod.candidates(spec, devices)
    if not matches:
        listing = "; ".join(d[0].describe() for d in devices)
        raise DeviceError(f"--device {spec}: no OpenCL device matches; available: {listing}")
    reasons, ranked = [], []
    for info, dev in matches:
        reason = devmod.probe(dev)
        if reason is None and qualify:
            status = qualification(info)
            reason = None if status.usable else status.reason
            if reason is None:
                ranked.append((status.events_per_s or 0.0, info, dev))
                if spec not in ("auto", "cpu", "gpu"):
                    break
                continue
        elif reason is None:
            return info, dev
        reasons.append(f"{info.spec} {info.device} ({info.platform} {info.platform_version}): {reason}")
    if ranked:
        best = max(ranked, key=lambda r: r[0])       # the first of equals: list order
        return best[1], best[2]
    raise DeviceError(f"--device {spec}: no usable OpenCL device: " + "; ".join(reasons)
                      + f"; {INSTALL_HINT}")


@dataclass(frozen=True)
class Qualification:
    """A device's verdict for the ranking kernel (slab, single precision, analog)."""

    usable: bool
    lanes: int | None
    events_per_s: float | None
    reason: str | None
    failures: tuple = ()
    seconds: float | None = None     # wall time of the passing check (child process, builds,
                                     # known-answer walk, speed)
    date: str | None = None          # when it ran
    #: widths above ``lanes`` (all, when none is usable) whose check came to no verdict --
    #: timed out, or killed from outside -- as ``(lanes, reason)``: checked again after a day
    unchecked: tuple = ()


def qualification(info, say=None) -> Qualification:
    """Qualify ``info`` for the ranking kernel at its widest passing lane width (cached).

    A width whose check came to no verdict (timed out on a busy machine) is no failure: the
    next narrower qualified width is used and the width is listed in ``unchecked``; where no
    width is usable because of it, the reason says "not checked yet".
    """
    q = qualifier_for(info, say=say)
    choice = q.choose(RANK_COMBO, measure=True)
    if choice.lanes is None:
        unchecked_only = not choice.failures
        return Qualification(False, None, None,
                             ("not checked yet at any lane width (checked again after a day, "
                              "or with `warpe-cl devices --requalify`): "
                              if unchecked_only else
                              "failed the known-answer walk at every lane width: ")
                             + "; ".join(f"{w} lanes: {r}" for w, r in
                                         sorted(choice.failures + choice.unchecked,
                                                reverse=True)),
                             choice.failures, unchecked=choice.unchecked)
    entry = choice.entry                   # the passed verdict the choice was made of
    if entry is None or not entry["passed"]:
        raise AssertionError(f"lane choice {choice.lanes} without a passed verdict")
    return Qualification(True, choice.lanes, entry.get("events_per_s"), None, choice.failures,
                         entry.get("child_wall_s", entry.get("seconds")), entry.get("date"),
                         choice.unchecked)


# --------------------------------------------------------------------------------------------
# the child

FAULT_ENV = "WARPE_CL_QUALIFY_FAULT"


def _fault(lanes: int) -> str | None:
    """The fault injected at ``lanes`` by ``$WARPE_CL_QUALIFY_FAULT`` (tests of the check
    itself: ``"16:abort,8:wrong"`` makes the child abort at 16 lanes and report wrong rays at
    8). A faulted verdict has its own cache key, so it never stands for a real one."""
    for item in os.environ.get(FAULT_ENV, "").split(","):
        if ":" in item:
            w, kind = item.split(":", 1)
            if w.strip() == str(lanes) and kind.strip() in ("abort", "wrong"):
                return kind.strip()
    return None


def _child(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m warpe_cl.qualify",
                                     description="Qualify one OpenCL device (docs/devices.md).")
    parser.add_argument("--device", required=True, help="P:D, as `warpe-cl devices` lists it")
    parser.add_argument("--lanes", type=int, required=True)
    parser.add_argument("--combos", default=",".join(c.label for c in all_combos(True)))
    parser.add_argument("--expect", default=None, help="the device name P:D must have")
    parser.add_argument("--no-measure", action="store_true")
    args = parser.parse_args(argv)
    info, dev = select_device(args.device, qualify=False)
    engine = Engine(info, dev)         # no lane chooser: the widths asked for, unchecked
    if args.expect is not None and engine.info.device != args.expect:
        print(f"device {args.device} is {engine.info.device!r}, not {args.expect!r}",
              file=sys.stderr)
        return 4
    fault = _fault(args.lanes)
    if fault == "abort":
        os.abort()
    results = {}
    for label in args.combos.split(","):
        combo = Combo.parse(label)
        if combo.precision == "double" and not engine.info.fp64:
            results[label] = {"passed": False, "reason": "no double precision",
                              "events_per_s": None, "seconds": 0.0}
            continue
        results[label] = check(engine, args.lanes, combo, measure=not args.no_measure,
                               corrupt=fault == "wrong")
        print(f"{label}: {'pass' if results[label]['passed'] else results[label]['reason']}",
              file=sys.stderr, flush=True)
    print(MARK + json.dumps(results), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(_child())
