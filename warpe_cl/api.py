"""The Python entry points: :func:`simulate` and :func:`walk_params`.

A bundled preset by name, a thousand rays, on the NumPy reference walk (any device spec of
docs/interface.md §2.2 works the same way, e.g. ``device="auto"``, the default):

    >>> import warpe_cl
    >>> cfg = warpe_cl.load_preset("radiative/slab_co2_1m", overrides={"simulation.photons": 1e3})
    >>> ds = warpe_cl.simulate(cfg, device="numpy", progress=False)
    >>> int(ds["photons"]), ds["reflectance"].dims
    (1000, ('component', 'time'))
    >>> ds["fraction"].sel(component="specular").item() > 0.02     # R0 = 0.028 for CO2 ice
    True
"""
from __future__ import annotations

import contextlib
import copy
import dataclasses
import hashlib
import json
import pickle
import time

from . import io, tally
from .dataset import build_dataset, combine_scenarios
from .config import Config, load_preset, time_edges
from .device import resolve_spec
from .engine import Engine
from .materials import table_attrs
from .instrument.scenario import apply_scenario_instrument
from .nadir import mirror_below, reduce_nadir
from .params import Layer, WalkParams, stack_params
from .progress import Progress
from .qualify import LaneChooser, qualifier_for, select_device
from .radiative import radiative_parameters
from .reference import ReferenceEngine
from .scenario_keys import format_key

_engines: dict = {}
#: The walks kept by :func:`reusing_walks` (None: none kept), by :func:`_walk_key`.
_walks: dict | None = None


@contextlib.contextmanager
def reusing_walks():
    """Within this block, a walk that repeats one already made (the same device, walk
    parameters, seed and scenario key, photons and precision: the same bits, docs/walk.md §1)
    is not walked again; its counts are reused. For a run of several presets that share a
    scenario, as ``tools/reproduce_paper.py``, where the BELA figure's granular case is a curve
    of ``gran_co2_thickness``. The kept counts are dropped when the block ends.

        >>> with reusing_walks():
        ...     ds = simulate(cfg)           # doctest: +SKIP
    """
    global _walks
    outer = _walks
    _walks = {} if outer is None else outer
    try:
        yield
    finally:
        _walks = outer


def _walk_key(engine, params: WalkParams, photons: int, precision: str) -> tuple:
    """What a walk's counts depend on: the engine, every walk parameter (the seed and the
    scenario key among them), the photon count and the precision."""
    digest = hashlib.sha256(pickle.dumps(params, protocol=4)).hexdigest()
    return (getattr(engine, "name", type(engine).__name__), digest, int(photons), precision)


def _walk(engine, params: WalkParams, photons: int, precision: str, progress):
    """``engine.run(params, photons, ...)``, or the counts of the same walk kept by
    :func:`reusing_walks` (a copy: the caller may add to them)."""
    key = _walk_key(engine, params, photons, precision) if _walks is not None else None
    if key is not None and key in _walks:
        if progress is not None:
            progress(photons)
        return copy.deepcopy(_walks[key])
    counts = engine.run(params, photons, precision=precision, progress=progress)
    if key is not None:
        _walks[key] = copy.deepcopy(counts)
    return counts


def walk_params(cfg: Config, scenario: int = 0) -> tuple:
    """The :class:`WalkParams` of a (single-point) configuration and its derived parameters.

    A single layer gives the ``slab`` or ``granular`` walk's parameters; a stack
    (``medium.layers``) or a layer over a substrate gives those of the layered walk
    (:func:`~warpe_cl.params.stack_params`, docs/walk.md §7), its layers of thickness 0 left
    out.

    Returns
    -------
    (WalkParams, dict)
    """
    derived = radiative_parameters(cfg)
    common = dict(
        bottom_interface=cfg.get("medium.bottom_interface"),
        albedo=cfg.get("medium.bottom_albedo"),
        time_edges=time_edges(cfg),
        max_time=cfg.get("simulation.max_time"),
        max_flights=int(cfg.get("simulation.max_flights")),
        fov=(90.0, 90.0, cfg.get("simulation.fov.bf_diffuse"), cfg.get("simulation.fov.scattering")),
        rule=cfg.get("simulation.component_rule"),
        seed=int(cfg.get("simulation.seed")),
        scenario=scenario,
        mode=cfg.get("simulation.mode"),
        roulette_weight=float(cfg.get("simulation.roulette_weight")),
        roulette_survival=float(cfg.get("simulation.roulette_survival")),
        nadir=bool(cfg.get("simulation.nadir")),
        view_zenith=float(cfg.get("simulation.view_zenith")),
        nadir_roulette=float(cfg.get("simulation.nadir_roulette")),
    )
    if "layers" in derived:
        layers = tuple(Layer(d["texture"], d["thickness_m"], d["extinction_per_m"], d["omega"],
                             d["phase_g"], d["n_eff"], d["k_eff"])
                       for d in derived["layers"] if d["thickness_m"] > 0)
        substrate = ((derived["substrate_n"], derived["substrate_k"])
                     if "substrate_n" in derived else None)
        params = stack_params(layers, substrate=substrate, **common)
    else:
        params = WalkParams(
            texture=cfg.get("medium.texture"),
            thickness=derived["thickness_m"],
            extinction=derived["extinction_per_m"],
            omega=derived["omega"],
            g=cfg.get("medium.phase_g"),
            n=derived["n_eff"],
            k=derived["k_eff"],
            **common,
        )
    # no estimate where the faces reflect more mirror paths than the estimator follows
    # (docs/walk.md §8.5): the result says so in its nadir_estimator attribute, the FOV
    # reflectance is as always
    if params.nadir and mirror_below(params) is not None:
        params = dataclasses.replace(params, nadir=False)
    return params, derived


#: The blocks of a point's configuration that key its random streams (scenario_key).
KEYED_BLOCKS = ("medium", "materials", "wavelength", "simulation")
#: Simulation keys left out of the key: the seed is the other key word, and the photon count is
#: left out so that a longer run extends a shorter one ray for ray (photon p draws the same
#: numbers whatever the number of photons). The nadir estimator's keys are left out because it
#: draws no number: the same rays are walked with or without it, at any view angle.
UNKEYED = ("simulation.seed", "simulation.photons", "simulation.nadir",
           "simulation.view_zenith", "simulation.nadir_roulette")


def keyed_configuration(data: dict) -> dict:
    """The part of a resolved configuration (``Config.data``) that :func:`scenario_key` hashes:
    the blocks of :data:`KEYED_BLOCKS`, without the keys of :data:`UNKEYED`."""
    out = {name: data.get(name) for name in KEYED_BLOCKS}
    sim = dict(out.get("simulation") or {})
    for key in UNKEYED:
        sim.pop(key.split(".", 1)[1], None)
    out["simulation"] = sim
    return out


def scenario_key(point: dict | None, cfg) -> int:
    """The 64-bit scenario key of a point's configuration (docs/walk.md §2).

    The first 8 bytes (big-endian) of the SHA-256 of the canonical JSON (sorted keys, floats
    as ``repr``, no whitespace) of :func:`keyed_configuration`: the full resolved medium,
    materials, wavelength and simulation blocks (canonical units), seed and photon count left
    out. So two scenarios that differ in any value of those blocks draw from different streams
    (a collision among 1e5 points has probability ~3e-10), and a point's key (hence its rays)
    does not depend on the grid it belongs to, on its index or on the order points are computed
    in: ``warpe-cl run`` of the point alone gives the same bits.

    Parameters
    ----------
    point : dict or None
        The swept values (unused: the resolved configuration already holds them; kept for the
        callers' signature).
    cfg : Config or dict
        The point's validated configuration, or its ``data`` mapping.

    Returns
    -------
    int
        In [0, 2**64): low word = second Philox key word, high word = fourth counter word.
    """
    data = cfg.data if hasattr(cfg, "data") else cfg
    canonical = json.dumps(keyed_configuration(data), sort_keys=True, separators=(",", ":"),
                           default=io.json_default, allow_nan=True)
    return int.from_bytes(hashlib.sha256(canonical.encode()).digest()[:8], "big")


def get_engine(device: str | None = None):
    """The engine for ``device``, kept for the process.

    Parameters
    ----------
    device : str, optional
        A device spec (:func:`warpe_cl.device.resolve_spec`: ``None`` reads
        ``$WARPE_CL_DEVICE``, then ``$PYOPENCL_CTX``, else ``auto``); ``"numpy"`` for the
        reference walk.

    Returns
    -------
    Engine or ReferenceEngine
        An :class:`~warpe_cl.engine.Engine` on the device that
        :func:`warpe_cl.qualify.select_device` chose, with the lane chooser of its
        qualification (:class:`warpe_cl.qualify.LaneChooser`); or the
        :class:`~warpe_cl.reference.ReferenceEngine`.

    Raises
    ------
    DeviceError
        No usable device matches (exit 3).
    """
    spec = resolve_spec(device)
    if spec not in _engines:
        if spec == "numpy":
            _engines[spec] = ReferenceEngine()
        else:
            info, dev = select_device(spec)
            _engines[spec] = Engine(info, dev, choose_lanes=LaneChooser(qualifier_for(info)))
    return _engines[spec]


def _nadir_attrs(cfg: Config, params: WalkParams) -> dict:
    """The ``nadir_estimator`` attribute: what the nadir variables are, or why there are
    none (docs/walk.md §8)."""
    if params.nadir:
        return {"view_zenith_deg": float(params.view_zenith),
                "nadir_estimator": "next-event estimate toward the view direction "
                                   "(docs/walk.md §8)"}
    if not cfg.get("simulation.nadir"):
        return {"nadir_estimator": "none: simulation.nadir is false"}
    return {"nadir_estimator": f"none: {mirror_below(params)} (docs/walk.md §8.5)"}


def simulate_point(cfg: Config, point: dict | None = None, device=None, progress=None):
    """Run one scenario (a configuration without sweep) and return its Dataset.

    The one function every path computes a scenario with (:func:`simulate`, hence
    ``warpe-cl run``, and each scenario of ``warpe-cl sweep``): the walk, the tallies and,
    when the preset has an ``instrument:`` block, the instrument chain on this scenario's
    result (:func:`warpe_cl.instrument.scenario.apply_scenario_instrument`), so a point gives
    the same bits, instrument variables included, whichever way it is computed.
    """
    point = point or {}
    t0 = time.perf_counter()
    params, derived = walk_params(cfg, scenario_key(point, cfg))
    engine = get_engine(device)
    photons = int(cfg.get("simulation.photons"))
    precision = cfg.get("simulation.precision")
    # on a terminal, once the run has taken 2 s; removed when it ends
    bar = Progress(photons, progress, unit="ray", unit_scale=True, delay=2.0, leave=False)
    try:
        counts = _walk(engine, params, photons, precision,
                       None if progress is False else bar.update_to)
    finally:
        bar.close()
    arrays = tally.reduce_counts(counts, params, solid_angle=cfg.get("simulation.solid_angle"),
                                 specular_lobe=cfg.get("simulation.specular_lobe"),
                                 min_rays=int(cfg.get("simulation.min_rays")))
    attrs = io.provenance({
        "name": cfg.get("name"),
        "description": cfg.get("description"),
        "config": cfg.to_yaml(),
        "source": str(cfg.source),
        "seed": int(params.seed),
        "scenario_key": format_key(params.scenario),
        "precision": getattr(engine, "fixed_precision", None) or precision,
        "mode": cfg.get("simulation.mode"),
        "texture": params.texture,
        "bottom_interface": params.bottom_interface if params.texture == "slab" else "none",
        "engine": engine.name,
        "kernel_sha256": engine.kernel_hash or "",
        **_nadir_attrs(cfg, params),
        **table_attrs(cfg),
        **engine.provenance,
    })
    if counts.nadir:
        arrays.update(reduce_nadir(counts, params, arrays))
    ds = build_dataset(arrays, counts, params, derived, attrs)
    ds["wall_time"] = ((), time.perf_counter() - t0, {"units": "s",
                                                      "long_name": "time spent in simulate"})
    return apply_scenario_instrument(ds, cfg)


def simulate(cfg, *, device: str | None = None, progress=None, overrides=None,
             before_point=None, after_point=None):
    """Simulate a preset: one scenario, or every point of its ``sweep:`` block.

    Parameters
    ----------
    cfg : Config, dict, str or path
        A loaded configuration, a dict of the YAML's shape, or a preset file.
    device : str, optional
        Device spec (docs/interface.md §2), or ``"numpy"`` for the reference walk.
    progress : bool or None
        Progress bar: None shows one on a terminal for runs over 2 s; False never.
    overrides : dict, optional
        Dotted-key overrides, when ``cfg`` is not yet a Config.
    before_point, after_point : callable, optional
        Called as ``before_point(index, point, point_cfg)`` before each scenario and
        ``after_point(dataset)`` after it (the command line prints its summary with them).

    Returns
    -------
    xarray.Dataset
        The variables of docs/interface.md §5; with a sweep, a leading ``scenario`` dimension whose
        swept values are coordinates. With an ``instrument:`` block, also the instrument's
        variables (docs/instrument.md), computed scenario by scenario.

    Raises
    ------
    ConfigError
        Bad input, before any walk: the preset, its sweep points and its instrument block
        are validated when loaded.
    """
    if not isinstance(cfg, Config):
        cfg = load_preset(cfg, overrides=overrides)
    points = cfg.sweep_points()
    datasets = []
    for i, (point, point_cfg) in enumerate(points):
        if before_point:
            before_point(i, point, point_cfg)
        datasets.append(simulate_point(point_cfg, point, device, progress))
        if after_point:
            after_point(datasets[-1])
    if len(points) == 1 and not points[0][0]:
        return datasets[0]
    return combine_scenarios(datasets, [p for p, _ in points], {"config": cfg.to_yaml()})
