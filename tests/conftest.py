"""Shared fixtures and helpers: one OpenCL engine for the whole session, media with readable
defaults, the repository's folders and the binomial standard error the Monte Carlo tolerances
are written in.

A test that walks a lane width of its own choosing and checks that walk against the reference
ray by ray, or against another lane width that is checked so, passes ``qualified=True``: its
own check is the qualification's (docs/devices.md), and a qualification costs two builds of
the nadir kernel in a child process (8-20 s each with Intel's compiler on 2 cores: about a
third of the suite's time on a fresh machine, measured 2026-11-23). Every other test walks the
widths a user gets, qualified as a user's run is.

The session has a cache folder of its own (``$WARPE_CL_CACHE_DIR``, set here before warpe-cl
reads it, so that every child process -- a qualification, a CLI run, a sweep's workers --
inherits it): the verdicts of faults injected by tests, of devices monkeypatched or of checks
on a loaded machine never reach the user's ``~/.cache/warpe-cl``. Intel's runtime is
registered in that folder as in a user's (warpe_cl/drivers.py), so the devices keep their
numbers. A fresh folder means the session qualifies the kernels it walks anew, as CI does with
its empty cache; ``$WARPE_CL_TEST_CACHE_DIR`` names a folder to keep between sessions instead
(never the user's own cache)."""
from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path

#: set for the session's children (and pytest-xdist's workers, which then share the folder)
SESSION_CACHE_ENV = "WARPE_CL_TEST_SESSION_CACHE"


def _users_cache_dir() -> Path:
    """The user's own cache folder, by the rule of :func:`warpe_cl.drivers.cache_dir`
    (``$WARPE_CL_CACHE_DIR``, else ``$XDG_CACHE_HOME/warpe-cl``, else ``~/.cache/warpe-cl``),
    read before this file changes ``$WARPE_CL_CACHE_DIR`` and without importing warpe-cl."""
    env = os.environ.get("WARPE_CL_CACHE_DIR", "").strip()
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME", "").strip() or os.path.join(Path.home(), ".cache")
    return Path(base) / "warpe-cl"


def _session_cache_dir() -> str:
    """The test session's cache folder: ``$WARPE_CL_TEST_CACHE_DIR`` if set, the one a parent
    session made, else a new temporary folder removed when the session ends.

    ``$WARPE_CL_TEST_CACHE_DIR`` resolving to the user's own cache folder is refused (the
    session stops with one line): the faults and fake devices of the tests would land in it.
    """
    folder = os.environ.get("WARPE_CL_TEST_CACHE_DIR", "").strip()
    if folder and not os.environ.get(SESSION_CACHE_ENV, "").strip():
        # (a child of a session has the session's folder as $WARPE_CL_CACHE_DIR: checked
        # by its parent)
        users = _users_cache_dir()
        if Path(folder).expanduser().resolve() == users.expanduser().resolve():
            import pytest
            pytest.exit(f"$WARPE_CL_TEST_CACHE_DIR={folder} is the user's own warpe-cl cache "
                        f"folder ({users}); give another folder (or none: a temporary one)",
                        returncode=4)
    for name in ("WARPE_CL_TEST_CACHE_DIR", SESSION_CACHE_ENV):
        folder = os.environ.get(name, "").strip()
        if folder:
            return folder
    folder = tempfile.mkdtemp(prefix="warpe-cl-test-cache-")
    atexit.register(shutil.rmtree, folder, True)
    return folder


os.environ[SESSION_CACHE_ENV] = os.environ["WARPE_CL_CACHE_DIR"] = _session_cache_dir()

import numpy as np  # noqa: E402 - after the cache folder is set
import pytest  # noqa: E402
import xarray as xr  # noqa: E402

from warpe_cl.params import COMPONENTS, WalkParams  # noqa: E402

#: The repository (for its presets/ and tools/ as a user's checkout has them).
REPO = Path(__file__).resolve().parent.parent
TOOLS = REPO / "tools"
#: BELA's wavelength, m.
LAMBDA = 1064e-9
LOG_EDGES = 1e-6 * 10 ** (np.arange(0, 221) / 20)   # 1e-6 .. 1e5 ns, 20 bins per decade
#: A scattering slab (tau0 = 3 for 10 mm, omega = 0.98) that exercises every kernel path.
SCATTERING = dict(texture="slab", extinction=300.0, omega=0.98, g=0.8, n=1.31, k=1e-5, albedo=0.4)


def binomial_sigma(p: float, n: int) -> float:
    """Standard error of a fraction p measured on n independent rays, sqrt(p (1 - p) / n).

    p (1 - p) is floored at 1/n, so that an expected fraction of 0 or 1 still allows about
    one ray; for every p with p (1 - p) >= 1/n this is the plain binomial value. The tests
    write their tolerances as 5 of these (a false alarm ~6e-7 per assertion)."""
    return float(np.sqrt(max(p * (1.0 - p), 1.0 / n) / n))


@pytest.fixture(scope="session")
def engine():
    """The OpenCL engine on the device `auto` picks (a usable device is required: the
    kernels are what this project is)."""
    from warpe_cl.api import get_engine
    return get_engine()


@pytest.fixture(scope="session")
def selftest(engine):
    """The self-test program (single and double precision), for the kernel building blocks."""
    from warpe_cl.device import SELFTEST_FILES, build_program
    progs = {"single": build_program(engine.device, SELFTEST_FILES, ())}
    if engine.info.fp64:
        progs["double"] = build_program(engine.device, SELFTEST_FILES, ("-DWARPE_DOUBLE",))
    return progs


def lane_chain(engine, precision: str = "single") -> tuple:
    """The lane widths the device under test walks a kernel with, widest first: its lane
    chooser's chain (:meth:`warpe_cl.qualify.Qualifier.lane_chain`: 16 lanes, 8 in double, or
    the driver's narrower preferred vector width, then 8, 4 and 1 on CPUs; 1 on GPUs, whose
    work-items are the lanes; docs/devices.md "Fallback"). Tests that compare lane widths
    walk these, never a width the device's own runs would not (issue 43: 16 lanes on NVIDIA's
    GPUs). An engine without a chooser (never the session's) gets the same chain from
    :func:`warpe_cl.engine.widest_lanes`.

    Parameters
    ----------
    engine : warpe_cl.engine.Engine
    precision : {"single", "double"}

    Returns
    -------
    tuple of int
        Photons per work-item, widest first, ending with 1.
    """
    qualifier = getattr(engine.choose_lanes, "qualifier", None)
    if qualifier is not None:
        return tuple(qualifier.lane_chain(precision))
    from warpe_cl.engine import widest_lanes
    from warpe_cl.qualify import FALLBACK_LANES
    widest = widest_lanes(engine.info.kind, precision, engine.info.preferred_width(precision))
    return (widest,) + tuple(w for w in FALLBACK_LANES if w < widest)


def vector_widths(engine, precision: str = "single") -> tuple:
    """The vector widths (more than one photon per work-item) of the device's lane chain
    (:func:`lane_chain`), widest first; a device that walks none (a GPU) skips the test that
    asks, saying so: its runs never walk one.

    Parameters
    ----------
    engine : warpe_cl.engine.Engine
    precision : {"single", "double"}

    Returns
    -------
    tuple of int
        Photons per work-item, at least one width.
    """
    chain = lane_chain(engine, precision)
    vectors = tuple(w for w in chain if w > 1)
    if not vectors:
        pytest.skip(f"{engine.info.device} walks no vector lanes in {precision} precision "
                    f"(its lane chain: {chain})")
    return vectors


def scalar_and_vector(engine, precision: str = "single") -> tuple:
    """One lane and, where the device's chain has one, its widest vector width
    (:func:`lane_chain`): the two forms of the walk a test that loops over them walks, without
    skipping on a device that has only the first.

    Parameters
    ----------
    engine : warpe_cl.engine.Engine
    precision : {"single", "double"}

    Returns
    -------
    tuple of int
        ``(1,)`` or ``(1, widest vector width)``, photons per work-item.
    """
    return (1,) + tuple(w for w in lane_chain(engine, precision)[:1] if w > 1)


def lanes_of(engine, form: str, precision: str = "single") -> int:
    """The lane width of one form of the walk on the device under test: ``"scalar"``, one
    photon per work-item (what GPUs walk); ``"vector"``, the widest vector width of the
    device's chain (:func:`lane_chain`: what a CPU walks where it qualifies). A device whose
    chain has no vector width (a GPU) skips the vector form: its runs never walk it.

    Parameters
    ----------
    engine : warpe_cl.engine.Engine
    form : {"scalar", "vector"}
    precision : {"single", "double"}

    Returns
    -------
    int
        Photons per work-item.
    """
    if form == "scalar":
        return 1
    if form != "vector":
        raise ValueError(f"form {form!r}: 'scalar' or 'vector'")
    return vector_widths(engine, precision)[0]


def walk_with_options(engine, structure: tuple, options: tuple, params: WalkParams,
                      photons: int, **run_kw):
    """Walk ``params`` with a walk program built from ``options`` in place of the engine's own
    for ``structure`` (a :func:`~warpe_cl.engine.kernel_key`'s fields), check that the engine
    walked with it, and give the engine back its own build (``Engine.forget``): the other form
    of a kernel that a test compares with the engine's, bit for bit. Returns the Counts."""
    from warpe_cl.device import build_program
    from warpe_cl.engine import WALK_FILES, kernel_key
    key = kernel_key(*structure)
    program = build_program(engine.device, WALK_FILES, options)
    try:
        kernel = engine.use_program(program, key)
        counts = engine.run(params, photons, **run_kw)
        assert engine.kernel(*structure) is kernel         # it walked with `program`
    finally:
        engine.forget(key)                                  # the engine builds its own again
    return counts


def medium(**kw) -> WalkParams:
    """A WalkParams with readable defaults (slab, 10 mm, tau0 = 1, omega = 0.9, ...)."""
    base = dict(texture="slab", thickness=0.01, extinction=100.0, omega=0.9, g=0.8, n=1.3,
                k=1e-4, albedo=0.5, time_edges=LOG_EDGES, bottom_interface="fresnel", seed=7)
    base.update(kw)
    return WalkParams(**base)


def synthetic_surface(diffuse_integral=0.0, tau=5.0, f_spec=0.0, f_bf=0.0, t_bf=14.0357,
                      wavelength="1064 nm", photons=10**6, seed=3, scenarios=None,
                      edges=LOG_EDGES):
    """A surface result: R_d(t) = diffuse_integral · exp(−t/τ)/τ in the scattering component
    (sr⁻¹ ns⁻¹), specular and BF-direct fractions as ray counts, on time ``edges`` (ns)."""
    cdf = 1.0 - np.exp(-edges / tau)
    refl = np.zeros((4, edges.size - 1))
    refl[3] = diffuse_integral * np.diff(cdf) / (cdf[-1] - cdf[0]) / np.diff(edges)
    counts = np.zeros((4, edges.size - 1), np.int64)
    counts[0, 0] = round(f_spec * photons)
    counts[1, np.searchsorted(edges, t_bf) - 1] = round(f_bf * photons)
    ds = xr.Dataset(
        {"time_edges": ("time_edge", edges), "reflectance": (("component", "time"), refl),
         "ray_count": (("component", "time"), counts), "photons": ((), np.int64(photons))},
        coords={"component": list(COMPONENTS), "time": np.sqrt(edges[:-1] * edges[1:])},
        attrs={"config": f"wavelength: {wavelength}\n", "seed": seed, "first_bf_time_ns": t_bf,
               "name": "synthetic"})
    if scenarios:
        ds = xr.concat([ds] * scenarios, dim="scenario")
        ds["time_edges"] = ("time_edge", edges)
        ds["scenario_key"] = ("scenario", np.arange(scenarios) + 11)
    return ds


def quiet_sweep(preset, folder, **kw):
    """:func:`warpe_cl.sweep.run_sweep` of ``preset`` into ``folder``, printing nothing."""
    from warpe_cl.sweep import run_sweep
    return run_sweep(preset, folder, quiet=True, say=lambda line: None, **kw)


def read_manifest(folder, name: str = "manifest.json") -> dict:
    """The manifest ``name`` of the database folder ``folder``, as a dict."""
    import json
    return json.loads((Path(folder) / name).read_text())


def tiny_grid(photons: int, seed: int) -> str:
    """A preset of four slab scenarios (thickness 5 and 10 mm x tau0 0.5 and 2.0) as YAML
    text: the sweep grid of the database tests."""
    return f"""\
name: tiny_grid
medium:
  texture: slab
  thickness: "10 mm"
  radiative: {{tau0: 1.0, omega: 0.9, n: 1.3, k: 0.0}}
  bottom_albedo: 0.15
simulation:
  photons: {photons}
  seed: {seed}
  time_bins: {{start: "1e-3 ns", stop: "1e3 ns", per_decade: 5}}
sweep:
  medium.thickness: ["5 mm", "10 mm"]
  medium.radiative.tau0: [0.5, 2.0]
"""


def sweep_of(parts: list, values, key: str = "medium.thickness", units: str = "m"):
    """Synthetic surfaces (:func:`synthetic_surface` results) stacked along ``scenario`` as a
    sweep over ``key`` (``values`` in ``units``): what a `warpe-cl sweep` database reads back
    as, with scenario keys 100, 101, ..."""
    db = xr.concat(parts, dim="scenario", data_vars="different", compat="equals")
    db["time_edges"] = parts[0]["time_edges"]
    db = db.assign_coords({key: ("scenario", np.asarray(values, float),
                                 {"sweep_key": key, "units": units})})
    db["scenario_key"] = ("scenario", np.arange(len(parts)) + 100)
    return db


def synthetic_database(path, key: str = "medium.thickness", taus=(1.0, 2.0, 4.0)):
    """Write a sweep-like NetCDF of synthetic surfaces (:func:`synthetic_surface`, decay
    times ``taus`` in ns) along ``key`` (the decay time in mm, stored in m) to ``path``;
    returns ``path``."""
    parts = [synthetic_surface(diffuse_integral=0.05, tau=t) for t in taus]
    sweep_of(parts, np.asarray(taus) * 1e-3, key).to_netcdf(path, engine="h5netcdf")
    return path
