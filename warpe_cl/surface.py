"""What the surface simulation hands to the instrument, docs/instrument.md §3.0.

The surface response is read from a result by the instrument chain
(:mod:`warpe_cl.instrument`), the figures (:mod:`warpe_cl.plot`) and the inversion
(:mod:`warpe_cl.inversion`) alike; it sits below all three and imports none of them.

From a result file (docs/interface.md §5): the diffuse response R_d(t) = reflectance of
``scattering`` + ``bf_diffuse`` (sr⁻¹ ns⁻¹, log-spaced bins) — the next-event estimate in the
exact view direction, ``nadir_reflectance``, where the scenario has it (docs/walk.md §8), else
the numerical-FOV ``reflectance`` (:func:`diffuse_estimates` says which, scenario by
scenario) — and the specular and BF-direct returns as fractions per launched ray
(``ray_count / photons``) with their delays: t = 0 for the specular, t_k = k · 2 h n_eff / c
for the k-th BF-direct passage (``first_bf_time_ns``), so that the instrument applies the
aperture and lobe geometry once (the file's specular reflectance, already divided by a lobe
solid angle, is not used). The wavelength is read from the resolved
configuration stored with the result.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from .errors import ConfigError
from .units import parse_quantity

NEEDED = ("time_edges", "reflectance", "ray_count", "photons")
DIFFUSE = ("bf_diffuse", "scattering")


@dataclass
class SurfaceResponse:
    """One scenario's surface response.

    Attributes
    ----------
    edges : array (n + 1,)
        Time bin edges, ns.
    diffuse : array (n,)
        R_d per bin, sr⁻¹ ns⁻¹.
    returns : list of (str, float, float)
        (component, delay ns, fraction per launched ray) of the specular and BF-direct returns.
    wavelength : float or None
        m.
    estimate : str
        Which reflectance ``diffuse`` is: ``"nadir"`` (``nadir_reflectance``) or ``"fov"``
        (``reflectance``).
    diffuse_stderr : array (n,) or None
        The Monte Carlo standard error of ``diffuse`` per bin, sr⁻¹ ns⁻¹ (the components'
        ``*_stderr`` in quadrature); None where the result has none.
    photons : float
        Rays launched (the denominator of the returns' fractions); NaN if unknown.
    """
    edges: np.ndarray
    diffuse: np.ndarray
    returns: list = field(default_factory=list)
    wavelength: float | None = None
    estimate: str = "fov"
    diffuse_stderr: np.ndarray | None = None
    photons: float = math.nan

    @property
    def diffuse_integral(self) -> float:
        """∫R_d dt, sr⁻¹ (A/π for a Lambertian surface of albedo A)."""
        return float(np.sum(self.diffuse * np.diff(self.edges)))


def check_variables(ds, source: str = "<dataset>"):
    """ConfigError (exit 2) unless ``ds`` holds what the instrument needs."""
    missing = [v for v in NEEDED if v not in ds.variables]
    if "component" not in ds.coords:
        missing.append("component")
    if missing:
        raise ConfigError(f"has no {', '.join(missing)}: give a surface result written by "
                          "`warpe-cl run`", key=source)
    names = set(str(c) for c in ds["component"].values)
    lacking = [c for c in ("specular", "bf_direct") + DIFFUSE if c not in names]
    if lacking:
        raise ConfigError(f"component coordinate lacks {', '.join(lacking)}", key=source)
    check_values(ds, source)


def _refuse(ds, name: str, bad: np.ndarray, values: np.ndarray, allowed: str, source):
    """ConfigError naming the first value of ``name`` where ``bad`` holds, and its place."""
    where = np.argwhere(bad)[0]
    dims = ds[name].dims if name in ds.variables else ()
    place = ", ".join(f"{d} {i}" for d, i in zip(dims, where)) or "its value"
    value = np.asarray(values)[tuple(where)].item()
    raise ConfigError(f"{value!r} at {place} is not allowed; give {allowed} (a surface "
                      "result written by `warpe-cl run`)", key=name, source=source)


def check_values(ds, source: str = "<dataset>") -> None:
    """ConfigError (exit 2) unless every value the instrument chain and the inversion read
    from ``ds`` is in its range: a file edited or written by another tool must not give a
    different waveform silently.

    Checked: ``time_edges`` finite, >= 0 and strictly increasing; ``reflectance`` finite and
    >= 0; ``nadir_reflectance`` >= 0 where given (NaN: not made for that scenario);
    ``ray_count`` >= 0; ``photons`` > 0; ``fraction`` in [0, 1]; ``first_bf_time_ns`` (a
    variable or an attribute) finite and >= 0.

    Parameters
    ----------
    ds : xarray.Dataset
        A result of ``warpe-cl run`` or a sweep database, with the variables of
        :func:`check_variables`.
    source : str
        The file, for messages.
    """
    edges = np.asarray(ds["time_edges"].values, float)
    if edges.ndim != 1 or edges.size < 2:
        raise ConfigError(f"holds {edges.size} value(s) of shape {edges.shape}; give at least "
                          "two edges in one dimension", key="time_edges", source=source)
    _within(ds, "time_edges", edges, ~np.isfinite(edges) | (edges < 0),
            "finite edges >= 0 ns", source)
    steps = np.diff(edges)
    if np.any(steps <= 0):
        j = int(np.argmax(steps <= 0))
        raise ConfigError(f"{float(edges[j + 1])!r} at time_edge {j + 1} follows "
                          f"{float(edges[j])!r}; give "
                          "strictly increasing edges (a surface result written by "
                          "`warpe-cl run`)", key="time_edges", source=source)
    refl = np.asarray(ds["reflectance"].values, float)
    _within(ds, "reflectance", refl, ~np.isfinite(refl) | (refl < 0), "finite values >= 0",
            source)
    if "nadir_reflectance" in ds.variables:
        nadir = np.asarray(ds["nadir_reflectance"].values, float)
        _within(ds, "nadir_reflectance", nadir, np.isinf(nadir) | (nadir < 0),
                "values >= 0 (NaN where the estimate was not made)", source)
    counts = np.asarray(ds["ray_count"].values)
    if counts.dtype.kind not in "iu":
        counts = counts.astype(float)
        _within(ds, "ray_count", counts, ~np.isfinite(counts) | (counts != np.round(counts)),
                "whole numbers of rays >= 0", source)
    _within(ds, "ray_count", counts, counts < 0, "whole numbers of rays >= 0", source)
    photons = np.asarray(ds["photons"].values, float)
    _within(ds, "photons", photons, ~np.isfinite(photons) | (photons <= 0),
            "a number of rays > 0", source)
    if "fraction" in ds.variables:
        frac = np.asarray(ds["fraction"].values, float)
        _within(ds, "fraction", frac, ~np.isfinite(frac) | (frac < 0) | (frac > 1),
                "fractions in [0, 1]", source)
    if "first_bf_time_ns" in ds.variables:
        t1 = np.asarray(ds["first_bf_time_ns"].values, float)
    elif "first_bf_time_ns" in ds.attrs:
        try:
            t1 = np.asarray(float(ds.attrs["first_bf_time_ns"]))
        except (TypeError, ValueError):
            t1 = np.asarray(math.nan)
    else:
        return
    _within(ds, "first_bf_time_ns", np.atleast_1d(t1), ~np.isfinite(np.atleast_1d(t1))
            | (np.atleast_1d(t1) < 0), "a finite time >= 0 ns", source)


def _within(ds, name, values, bad, allowed, source) -> None:
    if np.any(bad):
        _refuse(ds, name, bad, values, allowed, source)


def diffuse_estimates(ds) -> list:
    """Which diffuse reflectance the instrument uses, per scenario (one item without a sweep):
    ``"nadir"`` (``nadir_reflectance``, the next-event estimate in the view direction) where the
    scenario has it, else ``"fov"`` (``reflectance``, counted in the numerical fields of view).
    In a sweep a scenario lacks it (NaN) where it was not made: ``simulation.nadir: false``
    for that scenario, or a stack whose faces reflect more paths than the estimator follows
    (docs/walk.md §8.5)."""
    n = ds.sizes["scenario"] if "scenario" in ds.dims else None
    if "nadir_reflectance" not in ds.variables:
        return ["fov"] * (n or 1)
    values = np.asarray(ds["nadir_reflectance"].values, float)
    if n is None or "scenario" not in ds["nadir_reflectance"].dims:
        return ["nadir" if np.all(np.isfinite(values)) else "fov"] * (n or 1)
    axis = ds["nadir_reflectance"].dims.index("scenario")
    finite = np.all(np.isfinite(np.moveaxis(values, axis, 0).reshape(n, -1)), axis=1)
    return ["nadir" if f else "fov" for f in finite]


def diffuse_estimate(ds, estimates: list | None = None) -> str:
    """One word for :func:`diffuse_estimates` (or the ``estimates`` already taken from ``ds``):
    ``"nadir"`` or ``"fov"`` when every scenario uses the same, else ``"mixed"``."""
    kinds = set(diffuse_estimates(ds) if estimates is None else estimates)
    return kinds.pop() if len(kinds) == 1 else "mixed"


def wavelength_of(ds, scenario: int | None = None) -> float | None:
    """The wavelength (m) the surface response was computed at: a swept ``wavelength``
    coordinate, else the ``wavelength`` of the stored configuration; None if neither."""
    if "wavelength" in ds.coords and scenario is not None and "scenario" in ds["wavelength"].dims:
        value = ds["wavelength"].values[scenario]
        if np.issubdtype(np.asarray(value).dtype, np.number):   # numeric, in its units (m)
            return float(value)
        return parse_quantity(str(value), "length")             # as written (older files)
    text = ds.attrs.get("config")
    return _config_wavelength(text) if text else None


@functools.lru_cache(maxsize=8)
def _config_wavelength(text: str) -> float | None:
    """The ``wavelength`` (m) of a stored configuration's YAML text; None if it has none or
    cannot be read. Cached: every scenario of a database carries the same text."""
    import yaml

    try:
        value = (yaml.safe_load(text) or {}).get("wavelength")
        return parse_quantity(str(value), "length") if value is not None else None
    except Exception:  # noqa: BLE001 - an unreadable config: the wavelength is unknown
        return None


def response(ds, scenario: int | None = None) -> SurfaceResponse:
    """The :class:`SurfaceResponse` of one scenario of ``ds`` (``scenario`` None: no sweep)."""
    return _Arrays(ds).response(scenario)


def responses(ds, uniform: bool = False) -> list:
    """The :class:`SurfaceResponse` of every scenario of the sweep ``ds``, each equal to
    ``response(ds, i)``; the arrays are read once (a database of 1,000 scenarios in a
    fraction of a second). ``uniform``: one estimate for all, the FOV reflectance unless every
    scenario has the nadir one (an interpolation between scenarios, as the inversion's, must
    not mix the two)."""
    arrays = _Arrays(ds, uniform)
    return [arrays.response(i) for i in range(ds.sizes["scenario"])]


class _Arrays:
    """The variables :func:`response` reads, as numpy arrays (a leading scenario axis for a
    sweep)."""

    def __init__(self, ds, uniform: bool = False):
        self.ds = ds
        self.edges = np.asarray(ds["time_edges"].values, float)
        comps = [str(c) for c in ds["component"].values]
        self.estimates = diffuse_estimates(ds)
        if uniform and len(set(self.estimates)) > 1:
            self.estimates = ["fov"] * len(self.estimates)
        self.diffuse, self.stderr = {}, {}
        for name, kind in (("reflectance", "fov"), ("nadir_reflectance", "nadir")):
            if kind in self.estimates:
                refl = ds[name].transpose(..., "component", "time").values
                self.diffuse[kind] = sum(np.asarray(refl[..., comps.index(c), :], float)
                                         for c in DIFFUSE)
                if f"{name}_stderr" in ds.variables:      # the components in quadrature
                    se = ds[f"{name}_stderr"].transpose(..., "component", "time").values
                    self.stderr[kind] = np.sqrt(sum(np.asarray(se[..., comps.index(c), :],
                                                               float) ** 2 for c in DIFFUSE))
        counts = ds["ray_count"].transpose(..., "component", "time").values
        self.bf = np.asarray(counts[..., comps.index("bf_direct"), :], float)
        self.photons = np.asarray(ds["photons"].values, float)
        if "fraction" in ds.variables:
            self.specular = np.asarray(ds["fraction"].sel(component="specular").values, float)
        else:
            self.specular = np.asarray(counts[..., comps.index("specular"), :], float).sum(-1) \
                / self.photons
        if "first_bf_time_ns" in ds.variables:
            self.t1 = np.asarray(ds["first_bf_time_ns"].values, float)
        else:
            self.t1 = np.asarray(float(ds.attrs.get("first_bf_time_ns", math.nan)))

    def response(self, scenario: int | None) -> SurfaceResponse:
        pick = (lambda a: a) if scenario is None else \
            (lambda a: a[scenario] if np.ndim(a) and a.shape[0] == self.ds.sizes["scenario"]
             else a)
        edges = self.edges
        photons = float(pick(self.photons))
        t1 = float(pick(self.t1))
        returns = []
        # the specular return leaves at t = 0, before the first edge of log bins (an early
        # exit, in no time bin): its fraction is the component's whole fraction
        spec_fraction = float(pick(self.specular))
        if spec_fraction > 0:
            returns.append(("specular", 0.0, spec_fraction))
        bf = pick(self.bf)
        merged: dict[float, float] = {}
        for j in np.nonzero(bf)[0]:
            lo, hi = edges[j], edges[j + 1]
            t = math.sqrt(lo * hi) if lo > 0 else 0.5 * (lo + hi)
            if math.isfinite(t1) and t1 > 0:
                k = max(1, round(t / t1))
                # the exact passage time 2 k h n_eff / c, when it lies in (or next to) the bin
                if lo / 1.2 <= k * t1 <= hi * 1.2:
                    t = k * t1
            merged[t] = merged.get(t, 0.0) + bf[j] / photons
        returns += [("bf_direct", t, f) for t, f in sorted(merged.items())]
        kind = self.estimates[0 if scenario is None else scenario]
        stderr = self.stderr.get(kind)
        return SurfaceResponse(edges, np.array(pick(self.diffuse[kind]), float), returns,
                               wavelength_of(self.ds, scenario), kind,
                               None if stderr is None else np.array(pick(stderr), float),
                               photons)
