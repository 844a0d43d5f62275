"""What the data measure (docs/inversion.md §6.1-§6.5): the posteriors of derived transport
quantities, how much each swept key and derived quantity is identified, one-sided bounds at the
prior's edges, degenerate pairs of keys, and the truth when it is known.

Grain size and compacity act on a waveform almost only through the extinction coefficient E: a
posterior of grain size and compacity is then a ridge along which E is constant, and each key's
interval spans most of its prior while E is read to a factor of a few. The grid posterior
(:mod:`.posterior`) gives the posterior mass at every point it evaluated; a derived quantity's
value at those points, weighted by that mass, is its posterior (no new model evaluation).

Derived quantities:

- **stored** per scenario by the database (``extinction_per_m`` E, m⁻¹; ``tau0`` τ0 = E h; ...,
  :data:`STORED`): interpolated from the nodes with the corner weights the surface response
  uses (:func:`warpe_cl.inversion.space.corner_weights`, the axes' interpolation
  coordinates), in ln of the quantity when every node's value is positive. Along a ln h axis
  ln τ0 = ln E + ln h is then exact in h.
- **of the response** at the point (:data:`RESPONSE`), from the interpolated surface response
  (:meth:`warpe_cl.inversion.space.Space.surface`): the mean delay of the diffuse return
  ⟨t⟩ = ∫ t R_d dt / ∫ R_d dt (ns) and its tail fraction, the share of ∫ R_d dt later than
  the instrument's nominal pulse FWHM (what a waveform shows as a tail rather than a wider
  pulse).

A derived quantity whose nodes all hold the same value is not reported (nothing to measure).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import yaml

from ..config import load_preset
from ..errors import ConfigError
from ..units import UnitError, parse_quantity, unit_list
from .options import dimension_of
from .posterior import cell_widths, intervals, marginal
from .space import corner_weights

#: Stored per-scenario derived variables reported when they vary over the grid: name ->
#: (units, long name, symbol for the summary).
STORED = {
    "extinction_per_m": ("m-1", "extinction coefficient E of the layer", "E"),
    "tau0": ("1", "optical thickness tau0 = E h of the layer", "tau0"),
    "omega": ("1", "single-scattering albedo of the layer", "omega"),
}
#: Derived quantities computed from the interpolated surface response: name -> (units, long
#: name, symbol).
RESPONSE = {
    "mean_delay_ns": ("ns", "mean delay <t> of the diffuse return R_d", "<t>"),
    "tail_fraction": ("1", "fraction of the diffuse return later than the instrument's "
                           "nominal pulse FWHM", "tail"),
}
#: Ratio of the posterior density at a prior edge to its peak above which the posterior is
#: not falling off there (a Gaussian 2 sigma from its peak: exp(-2)); the interval is then
#: reported as a one-sided bound.
EDGE_OPEN = math.exp(-2.0)
#: The outer share of the prior (each end, in the prior's coordinate for a key, in prior mass
#: for a derived quantity) where the posterior density is compared with its peak: an edge is
#: open when the 95 % interval could reach it.
EDGE_BAND = 0.025
#: Posterior correlation (in the prior's coordinates) from which two keys are a ridge.
RIDGE_CORRELATION = 0.6
#: Largest number of points of the uniform grid over the prior box on which the derived
#: quantities' prior is evaluated.
PRIOR_POINTS = 300
#: Points of the posterior grid lighter than this fraction of the heaviest are skipped (their
#: mass is dropped) when the response is interpolated for a derived quantity.
NEGLIGIBLE = 1e-9
#: Bound kinds (flag values of FIT.nc's ``bound``).
BOUND_KINDS = ("two_sided", "lower_bound", "upper_bound", "both_edges")


@dataclass
class Quantity:
    """One derived quantity.

    Attributes
    ----------
    name, units, long_name, symbol : str
    scale : str
        ``log`` (its posterior and prior are compared in ln of the value) or ``linear``.
    nodes : array
        Its value at every node of the space's grid (the axes' shape).
    stored : bool
        Interpolated from ``nodes`` (True), or computed from the interpolated response.
    """
    name: str
    units: str
    long_name: str
    symbol: str
    scale: str
    nodes: np.ndarray
    stored: bool

    def coord(self, x):
        """The comparison coordinate of value(s) ``x`` (ln x or x)."""
        x = np.asarray(x, float)
        return np.log(x) if self.scale == "log" else x

    def value(self, c):
        """The value of coordinate(s) ``c``."""
        c = np.asarray(c, float)
        return np.exp(c) if self.scale == "log" else c


def _response_values(r, tail_after_ns: float) -> dict:
    """Mean delay (ns) and tail fraction of a surface response's diffuse part (NaN without
    one)."""
    amount = np.asarray(r.diffuse, float) * np.diff(r.edges)
    total = float(amount.sum())
    if not total > 0:
        return {"mean_delay_ns": math.nan, "tail_fraction": math.nan}
    mid = 0.5 * (r.edges[1:] + r.edges[:-1])
    # the share after the cut summed from the end: none is 0 and all is 1, not a rounded 1
    later = np.concatenate([np.cumsum(amount[::-1])[::-1], [0.0]])
    later /= later[0]
    return {"mean_delay_ns": float(np.sum(mid * amount) / total),
            "tail_fraction": float(np.interp(tail_after_ns, r.edges, later))}


def quantities(space, db, tail_after_ns: float) -> list:
    """The derived quantities of a database that vary over its grid.

    Parameters
    ----------
    space : Space
        The inversion's space (its nodes, axes, and the values of non-numeric fixed keys).
    db : xarray.Dataset
        The database it was built from (the stored derived variables along ``scenario``).
    tail_after_ns : float
        The delay (ns) after which the diffuse return counts as tail: the instrument's nominal
        pulse FWHM.

    Returns
    -------
    list of Quantity
    """
    shape = space.nodes.shape
    keep = np.ones(db.sizes["scenario"], bool)
    for key, text in space.fixed.items():
        keep &= np.asarray(db[key].values).astype(str) == str(text)
    rows = np.nonzero(keep)[0]
    index = [tuple(int(np.searchsorted(a.values, float(db[a.key].values[i])))
                   for a in space.axes) for i in rows]
    tables = {}
    for name in STORED:
        if name in db.variables and db[name].dims == ("scenario",):
            table = np.full(shape, np.nan)
            values = np.asarray(db[name].values, float)
            for i, idx in zip(rows, index):
                table[idx] = values[i]
            tables[name] = table
    found = {name: np.full(shape, np.nan) for name in RESPONSE}
    for idx in np.ndindex(shape):
        for name, x in _response_values(space.nodes[idx].surface, tail_after_ns).items():
            found[name][idx] = x
    out = []
    for name, table in [*tables.items(), *found.items()]:
        if not np.all(np.isfinite(table)):
            continue
        lo, hi = float(table.min()), float(table.max())
        if not hi - lo > 1e-9 * max(abs(lo), abs(hi), 1e-300):
            continue            # the same at every node: nothing to measure
        units, long_name, symbol = {**STORED, **RESPONSE}[name]
        # a fraction is compared in its value: in ln, fractions of 1e-6 and 1e-3 that no
        # waveform tells apart would count as far apart
        scale = "log" if lo > 0 and (units != "1" or name == "tau0") else "linear"
        out.append(Quantity(name, units, long_name, symbol, scale, table, name in STORED))
    return out


def values_at(space, found: list, point: dict, tail_after_ns: float) -> list:
    """Each quantity's value at ``point`` (free key -> value in its unit)."""
    idx, w = corner_weights(space.coords_of(point), [a.nodes for a in space.axes])
    out, response = [], None
    for q in found:
        if q.stored:
            corners = np.array([q.nodes[i] for i in idx])
            out.append(float(q.value(np.dot(w, q.coord(corners)))))
        else:
            if response is None:
                response = _response_values(space.surface(point), tail_after_ns)
            out.append(response[q.name])
    return out


def grid_values(space, found, coords: list, weights: np.ndarray, tail_after_ns: float):
    """Each quantity's value at every point of a grid of the free axes' coordinates (NaN and
    no mass at the points lighter than NEGLIGIBLE of the heaviest): (values, weights), each
    quantity's values with the grid's shape."""
    axes = space.free_axes
    values = np.full((len(found),) + weights.shape, np.nan)
    w = np.where(weights >= NEGLIGIBLE * weights.max(), weights, 0.0)
    for index in zip(*np.nonzero(w)):
        point = {a.key: float(a.value(c[i])) for a, c, i in zip(axes, coords, index)}
        values[(slice(None),) + index] = values_at(space, found, point, tail_after_ns)
    return values, w / w.sum()


def prior_grid(space) -> tuple:
    """A uniform grid over the prior box (every free axis' range, each node cell divided the
    same number of times, at most PRIOR_POINTS points) and its prior mass."""
    nodes = [a.nodes for a in space.free_axes]
    r = 1
    while int(np.prod([(n.size - 1) * (r + 1) + 1 for n in nodes])) <= PRIOR_POINTS:
        r += 1
    coords = [np.concatenate([np.linspace(a, b, r, endpoint=False) for a, b in
                              zip(n[:-1], n[1:])] + [n[-1:]]) if n.size > 1 else n
              for n in nodes]
    vol = np.ones(tuple(c.size for c in coords))
    for i, c in enumerate(coords):
        vol = vol * cell_widths(c).reshape([-1 if j == i else 1 for j in range(len(coords))])
    return coords, vol / vol.sum()


def quantiles(x: np.ndarray, w: np.ndarray, qs) -> list:
    """Weighted quantiles of values ``x`` of masses ``w``. The masses of equal values are
    gathered (on a rectangular grid a derived quantity takes a few values many times: E is
    constant along the diagonals of a ln d x ln c grid) and each is spread over the cell
    between its neighbours' midpoints, as :func:`.posterior.intervals` spreads a marginal's,
    so that a quantile does not stick to one of those values."""
    ok = (w > 0) & np.isfinite(x)
    x, w = x[ok], w[ok]
    scale = max(float(np.max(np.abs(x))), 1e-300)
    values, where = np.unique(np.round(x / scale, 12), return_inverse=True)
    mass = np.bincount(where.ravel(), weights=w)
    if values.size == 1:
        return [float(values[0] * scale)] * len(qs)
    mids = 0.5 * (values[1:] + values[:-1]) * scale
    bounds = np.concatenate([[values[0] * scale], mids, [values[-1] * scale]])
    cdf = np.concatenate([[0.0], np.cumsum(mass)]) / mass.sum()
    return [float(np.interp(q, cdf, bounds)) for q in qs]


def _kl_histogram(post_c, post_w, prior_c, prior_w) -> float:
    """KL divergence (nats) of a posterior from a prior, both given as masses at values of the
    same coordinate, from histograms on common bins over the prior's range."""
    ok = (post_w > 0) & np.isfinite(post_c)
    post_c, post_w = post_c[ok], post_w[ok]
    lo, hi = float(np.min(prior_c)), float(np.max(prior_c))
    if not hi > lo:
        return math.nan
    bins = int(min(40, max(10, prior_c.size // 6)))
    edges = np.linspace(lo, hi, bins + 1)
    p, _ = np.histogram(np.clip(post_c, lo, hi), edges, weights=post_w)
    q, _ = np.histogram(prior_c, edges, weights=prior_w)
    p, q = p / p.sum(), q / q.sum()
    q = np.maximum(q, 1e-3 / bins)
    q = q / q.sum()
    m = p > 0
    return float(np.sum(p[m] * np.log(p[m] / q[m])))


def _bound(low_open: bool, high_open: bool) -> str:
    """The kind of interval (:data:`BOUND_KINDS`) of a posterior open at its prior edges."""
    if low_open and high_open:
        return "both_edges"
    if high_open:
        return "lower_bound"        # x > bound: the upper edge is not excluded
    if low_open:
        return "upper_bound"
    return "two_sided"


def key_measures(final, axes) -> list:
    """Identifiability and bounds of every free axis from the final grid posterior.

    Parameters
    ----------
    final : GridPosterior
    axes : list of Axis
        The free axes, in the grid's order.

    Returns
    -------
    list of dict
        Per axis: ``width_ratio`` (posterior 95 % width / the prior's 95 % width, 0.95 of the
        range, in the interpolation coordinate), ``kl_divergence`` (nats: Σ m ln(m / m_prior)
        over the grid's cells, the prior uniform over the range), ``bound`` (a kind of
        :data:`BOUND_KINDS`: an edge is open when the marginal density somewhere in the outer
        EDGE_BAND of the range reaches EDGE_OPEN of its peak), ``bound95`` (the one-sided
        95 % limit, the value in the axis unit; NaN for two-sided or both edges).
    """
    out = []
    for j, axis in enumerate(axes):
        u, mass = marginal(final, j)
        lo, hi = float(axis.nodes[0]), float(axis.nodes[-1])
        span = hi - lo
        if not span > 0 or u.size < 2:
            out.append({"width_ratio": math.nan, "kl_divergence": math.nan,
                        "bound": "two_sided", "bound95": math.nan})
            continue
        iv = intervals(u, mass, levels=(0.9, 0.95))
        ratio = (iv[0.95][1] - iv[0.95][0]) / (0.95 * span)
        cells = cell_widths(u)
        density = mass / cells
        m = mass > 0
        kl = float(np.sum(mass[m] * np.log(density[m] * span)))
        peak = float(density.max())
        edge = EDGE_BAND * span
        low_open = bool(np.any(density[u <= lo + edge] >= EDGE_OPEN * peak))
        high_open = bool(np.any(density[u >= hi - edge] >= EDGE_OPEN * peak))
        kind = _bound(low_open, high_open)
        limit = {"lower_bound": iv[0.9][0], "upper_bound": iv[0.9][1]}.get(kind)
        out.append({"width_ratio": float(ratio), "kl_divergence": max(kl, 0.0), "bound": kind,
                    "bound95": math.nan if limit is None else float(axis.value(limit))})
    return out


def correlations(final) -> np.ndarray:
    """Posterior correlation matrix of the free axes' coordinates (NaN for an axis of one
    point)."""
    w = final.weights()
    grids = np.meshgrid(*final.coords, indexing="ij")
    mean = [float(np.sum(w * g)) for g in grids]
    d = len(grids)
    cov = np.empty((d, d))
    for i in range(d):
        for j in range(d):
            cov[i, j] = float(np.sum(w * (grids[i] - mean[i]) * (grids[j] - mean[j])))
    sd = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        return cov / np.outer(sd, sd)


def derived_measures(space, db, final, tail_after_ns: float, truth: dict | None = None) -> list:
    """The posterior of every derived quantity (:func:`quantities`).

    Parameters
    ----------
    space : Space
    db : xarray.Dataset
    final : GridPosterior
        The last grid of the posterior.
    tail_after_ns : float
        Delay after which the diffuse return counts as tail (ns): the nominal pulse FWHM.
    truth : dict, optional
        Every free key -> its true value (axis unit): the quantities are also evaluated there.

    Returns
    -------
    list of dict
        Per quantity: ``name``, ``units``, ``long_name``, ``symbol``, ``scale``, ``median``,
        ``low68``, ``high68``, ``low95``, ``high95`` (its unit), ``prior_low95``,
        ``prior_high95`` (the prior's 95 % interval), ``width_ratio`` (posterior / prior 95 %
        width in ln of the value, or the value), ``kl_divergence`` (nats, histograms over the
        prior's range), ``bound``, ``bound95`` (as :func:`key_measures`: an edge is open when
        the most likely point beyond the prior's 2.5 % tail holds at least EDGE_OPEN of the
        peak's posterior density), ``truth`` (NaN unknown), ``depends`` (free axes it varies
        along, indices).
    """
    found = quantities(space, db, tail_after_ns)
    if not found:
        return []
    post_w = final.weights()
    values, w = grid_values(space, found, final.coords, post_w, tail_after_ns)
    vol = np.ones(post_w.shape)
    for i, c in enumerate(final.coords):
        vol = vol * cell_widths(c).reshape([-1 if j == i else 1 for j in range(len(final.coords))])
    density = np.where(w > 0, w / vol, 0.0)
    prior_coords, prior_w = prior_grid(space)
    prior_values, _ = grid_values(space, found, prior_coords, prior_w, tail_after_ns)
    free_index = [space.axes.index(a) for a in space.free_axes]
    inside = truth and all(
        a.key in truth and a.values[0] * (1 - 1e-9) <= truth[a.key] <= a.values[-1] * (1 + 1e-9)
        for a in space.free_axes)      # beyond the grid the interpolation would clip
    true_values = (values_at(space, found, {a.key: truth[a.key] for a in space.free_axes},
                              tail_after_ns) if inside else None)
    out = []
    for k, q in enumerate(found):
        c = q.coord(values[k])
        pc = q.coord(prior_values[k]).ravel()
        med, l68, h68, l95, h95, l90, h90 = quantiles(c.ravel(), w.ravel(),
                                                       (0.5, 0.16, 0.84, 0.025, 0.975, 0.05,
                                                        0.95))
        pl, ph = quantiles(pc, prior_w.ravel(), (EDGE_BAND, 1.0 - EDGE_BAND))
        ratio = (h95 - l95) / (ph - pl) if ph > pl else math.nan
        peak = float(density.max())
        low_open = bool(np.any(density[c <= pl] >= EDGE_OPEN * peak))
        high_open = bool(np.any(density[c >= ph] >= EDGE_OPEN * peak))
        kind = _bound(low_open, high_open)
        limit = {"lower_bound": l90, "upper_bound": h90}.get(kind)
        table = q.coord(q.nodes)
        spread = float(np.ptp(table))
        depends = [j for j, a in enumerate(free_index)
                   if float(np.max(np.ptp(table, axis=a))) > 1e-3 * spread]
        out.append({
            "name": q.name, "units": q.units, "long_name": q.long_name, "symbol": q.symbol,
            "scale": q.scale, "median": float(q.value(med)),
            "low68": float(q.value(l68)), "high68": float(q.value(h68)),
            "low95": float(q.value(l95)), "high95": float(q.value(h95)),
            "prior_low95": float(q.value(pl)), "prior_high95": float(q.value(ph)),
            "width_ratio": float(ratio),
            "kl_divergence": _kl_histogram(c.ravel(), w.ravel(), pc, prior_w.ravel()),
            "bound": kind, "bound95": math.nan if limit is None else float(q.value(limit)),
            "truth": math.nan if true_values is None else float(true_values[k]),
            "depends": depends,
        })
    return out


#: A derived quantity "fixes" a degenerate pair only if its 68 % interval spans at most this
#: factor (BELA pins E to about a factor 3 on granular CO2 where grain size and compacity each
#: span most of their range).
PINNED = 3.0


def degeneracies(axes, rows: list, derived: list, corr: np.ndarray) -> list:
    """One line per degenerate pair of free keys.

    A pair is degenerate when its posterior correlation in the prior's coordinates reaches
    RIDGE_CORRELATION in size, or when a derived quantity that varies along both is
    identified at least twice as well as either (its width ratio below half of each key's)
    while neither key is itself constrained (both width ratios at least 0.5), and its 68 %
    interval spans at most a factor ``PINNED``.
    The line names the best-identified such quantity with its 68 % interval.

    Parameters
    ----------
    axes : list of Axis
        The free axes.
    rows : list of dict
        Their :func:`key_measures`.
    derived : list of dict
        :func:`derived_measures`.
    corr : array
        :func:`correlations`.

    Returns
    -------
    list of str
    """
    lines = []
    for i in range(len(axes)):
        for j in range(i + 1, len(axes)):
            ri, rj = rows[i]["width_ratio"], rows[j]["width_ratio"]
            if not (math.isfinite(ri) and math.isfinite(rj)):
                continue
            both = [d for d in derived if i in d["depends"] and j in d["depends"]
                    and math.isfinite(d["width_ratio"])]
            # a combination better measured than keys that are themselves poorly measured
            # (and pinned within a factor PINNED at 68 %, not merely narrower than a prior of
            # many decades)
            better = [d for d in both if d["width_ratio"] < 0.5 * min(ri, rj)
                      and min(ri, rj) >= 0.5 and d["high68"] <= PINNED * d["low68"]]
            rho = corr[i, j]
            if not (abs(rho) >= RIDGE_CORRELATION or better):
                continue
            text = (f"{axes[i].short} and {axes[j].short} are degenerate (correlation "
                    f"{rho:+.2f} in the prior's coordinates)")
            pool = better or both
            # the first in the order of STORED, RESPONSE among those within 20 % of the best
            # identified: E rather than a mean delay that it sets just as well
            pick = (next(d for d in pool if d["width_ratio"]
                         <= 1.2 * min(e["width_ratio"] for e in pool)) if pool else None)
            if pick is not None and pick["width_ratio"] < min(ri, rj):
                unit = "" if pick["units"] in ("1", "") else f" {pick['units']}"
                text += (f": the data fix {pick['symbol']} = {pick['median']:.3g}{unit} "
                         f"[{pick['low68']:.3g}, {pick['high68']:.3g}] (68 %), not each")
            else:
                text += ": only a combination of them is measured"
            lines.append(text)
    return lines


def measure(problem, final, db, truth: dict | None = None) -> dict:
    """Everything this module adds to an inversion's summary.

    Parameters
    ----------
    problem : Problem
        Its ``space`` and ``forward`` (the nominal pulse FWHM, ns, sets the tail).
    final : GridPosterior
    db : xarray.Dataset
    truth : dict, optional
        Swept key -> true value in the axis unit (:func:`truth_values`).

    Returns
    -------
    dict
        ``keys`` (:func:`key_measures`, one per free axis), ``derived``
        (:func:`derived_measures`), ``correlation`` (:func:`correlations`),
        ``degeneracy`` (:func:`degeneracies`), ``truth`` (as given, or {}),
        ``tail_after_ns``.
    """
    space = problem.space
    axes = space.free_axes
    tail = float(problem.forward.fwhm)
    keys = key_measures(final, axes)
    derived = derived_measures(space, db, final, tail, truth)
    corr = correlations(final)
    return {"keys": keys, "derived": derived, "correlation": corr,
            "degeneracy": degeneracies(axes, keys, derived, corr), "truth": dict(truth or {}),
            "tail_after_ns": tail}


def truth_values(obs_attrs: dict, space, given: dict | None = None) -> tuple:
    """The true values of the swept keys, when known.

    Parameters
    ----------
    obs_attrs : dict
        The observed file's attributes (:class:`.observed.Observed` ``attrs``): a scenario of
        a sweep carries ``sweep_point`` (key -> value as written, ``"50 um"``), a
        ``warpe-cl run`` result its resolved ``config`` (YAML).
    space : Space
    given : dict, optional
        ``--truth KEY=VALUE``: a swept key -> its value by the unit rule of ``run --set``
        (a quantity with its unit; a plain number for a key without dimension); overrides
        the file.

    Returns
    -------
    (dict, str)
        Swept numeric key -> value in the axis unit, and where it came from (``--truth``,
        ``observed sweep_point``, ``observed config``, or "" when unknown).

    Raises
    ------
    ConfigError
        A ``--truth`` key that is not a numeric swept key of the database, or a value without
        its unit or not a finite number (one line, key ``--truth``).
    """
    numeric = {a.key: a for a in space.axes}
    found, source = {}, ""
    point = obs_attrs.get("sweep_point")
    config = obs_attrs.get("config")
    if isinstance(point, dict) and point:
        for key, value in point.items():
            if key in numeric:
                x = _read(key, value, numeric[key].units, stored=True)
                if x is not None:
                    found[key] = x
        source = "observed sweep_point" if found else ""
    elif isinstance(config, str) and config.strip():
        try:
            cfg = load_preset(yaml.safe_load(config))
            for key in numeric:
                x = cfg.get(key)
                if isinstance(x, (int, float)) and math.isfinite(float(x)):
                    found[key] = float(x)
        except (ConfigError, KeyError, ValueError, TypeError, yaml.YAMLError):
            found = {}
        source = "observed config" if found else ""
    for key, value in (given or {}).items():
        if key not in numeric:
            raise ConfigError(f"--truth {key}: not a numeric swept key of the database "
                              f"(swept: {', '.join(numeric) or 'none'})", key="--truth")
        x = _read(key, value, numeric[key].units)
        if x is None:
            dim = dimension_of(key, numeric[key].units)
            wanted = (f"a {dim} with a unit ({unit_list(dim)})" if dim else "a plain number")
            raise ConfigError(f"--truth {key}={value}: not allowed; give {wanted}",
                              key="--truth")
        found[key] = x
        source = "--truth"
    return found, source


def _read(key: str, value, units: str, stored: bool = False):
    """A value of a swept key in its canonical unit (None when it cannot be read). A bare
    number of a quantity is read as already in the canonical unit only when ``stored`` (a
    file's value), never from the command line."""
    dim = dimension_of(key, units)
    try:
        if stored and isinstance(value, (int, float)) and not isinstance(value, bool):
            x = float(value)
            return x if math.isfinite(x) else None
        if dim is not None:
            return float(parse_quantity(value, dim))
        if isinstance(value, bool):
            return None
        x = float(value)
        return x if math.isfinite(x) else None
    except (UnitError, TypeError, ValueError):
        return None



def variables(result: dict, rows: list) -> tuple:
    """FIT.nc's variables of :func:`measure` (docs/inversion.md §6).

    Parameters
    ----------
    result : dict
        :func:`measure`.
    rows : list of dict
        The summary's rows of the free axes (``key``, ``reported``), in the grid's order.

    Returns
    -------
    (dict, dict, dict)
        Data variables, coordinates and attributes to add: on ``parameter`` (the reported
        keys) ``width_ratio``, ``kl_divergence``, ``bound``, ``bound95``, ``truth``; on
        ``derived`` the derived quantities' ``derived_median`` ... ``derived_truth``; on
        (``free_key``, ``free_key_other``) the posterior ``correlation``; attributes
        ``degeneracy`` (JSON list of lines), ``truth_source`` and ``tail_after_ns``.
    """
    reported = [i for i, r in enumerate(rows) if r["reported"]]
    keys = [result["keys"][i] for i in reported]
    truth = result["truth"]
    flag = {"flag_values": np.arange(len(BOUND_KINDS), dtype=np.int8),
            "flag_meanings": " ".join(BOUND_KINDS)}
    data = {
        "width_ratio": ("parameter", np.array([k["width_ratio"] for k in keys], float), {
            "long_name": "posterior 95 % interval width / the prior's 95 % width, in the "
                         "interpolation coordinate (1: nothing learnt)", "units": "1"}),
        "kl_divergence": ("parameter", np.array([k["kl_divergence"] for k in keys], float), {
            "long_name": "KL divergence of the marginal posterior from the uniform prior",
            "units": "nats"}),
        "bound": ("parameter", np.array([BOUND_KINDS.index(k["bound"]) for k in keys],
                                        np.int8), {
            "long_name": "kind of interval: two-sided, a lower bound (the posterior reaches "
                         "the upper prior edge), an upper bound, or both edges", "units": "1",
            **flag}),
        "bound95": ("parameter", np.array([k["bound95"] for k in keys], float), {
            "long_name": "one-sided 95 % limit where bound is lower_bound (value > limit) or "
                         "upper_bound (value < limit); NaN otherwise"}),
        "truth": ("parameter", np.array([truth.get(rows[i]["key"], np.nan) for i in reported],
                                        float), {
            "long_name": "true value when known (--truth or the observed file), NaN if not"}),
    }
    coords = {}
    derived = result["derived"]
    if derived:
        coords["derived"] = ("derived", np.array([d["name"] for d in derived]), {
            "long_name": "derived transport quantity (docs/inversion.md §6.1)", "units": "1"})
        data["derived_units"] = ("derived", np.array([d["units"] for d in derived]), {
            "long_name": "unit of the derived quantity's values (text)", "units": "1"})
        data["derived_long_name"] = ("derived", np.array([d["long_name"] for d in derived]), {
            "long_name": "what the derived quantity is (text)", "units": "1"})
        units = sorted({d["units"] for d in derived})
        shared = units[0] if len(units) == 1 else "per derived quantity: see derived_units"
        for col, text in (("median", "posterior median"),
                          ("low68", "lower bound of the equal-tailed 68 % interval"),
                          ("high68", "upper bound of the equal-tailed 68 % interval"),
                          ("low95", "lower bound of the equal-tailed 95 % interval"),
                          ("high95", "upper bound of the equal-tailed 95 % interval"),
                          ("prior_low95", "lower bound of the prior's 95 % interval"),
                          ("prior_high95", "upper bound of the prior's 95 % interval"),
                          ("bound95", "one-sided 95 % limit (see derived_bound); NaN if none"),
                          ("truth", "value at the true point, interpolated in the database; "
                                    "NaN if not known")):
            data[f"derived_{col}"] = ("derived", np.array([d[col] for d in derived], float),
                                      {"long_name": f"{text} of the derived quantity",
                                       "units": shared})
        data["derived_width_ratio"] = ("derived", np.array([d["width_ratio"] for d in derived],
                                                           float), {
            "long_name": "posterior / prior 95 % width of the derived quantity, in ln of the "
                         "value (of the value if not positive)", "units": "1"})
        data["derived_kl_divergence"] = ("derived", np.array(
            [d["kl_divergence"] for d in derived], float), {
            "long_name": "KL divergence of the derived quantity's posterior from its prior "
                         "(histograms over the prior's range)", "units": "nats"})
        data["derived_bound"] = ("derived", np.array([BOUND_KINDS.index(d["bound"])
                                                      for d in derived], np.int8), {
            "long_name": "kind of interval of the derived quantity", "units": "1", **flag})
    corr = np.asarray(result["correlation"], float)
    names = np.array([r["key"] for r in rows])
    coords["free_key"] = ("free_key", names, {"long_name": "free swept key (reported or "
                                                           "marginalised)", "units": "1"})
    coords["free_key_other"] = ("free_key_other", names.copy(), {
        "long_name": "free swept key (second index of correlation)", "units": "1"})
    data["correlation"] = (("free_key", "free_key_other"), corr, {
        "long_name": "posterior correlation of the free keys in their interpolation "
                     "coordinates", "units": "1"})
    attrs = {"degeneracy": json.dumps(result["degeneracy"]),
             "truth_source": result.get("truth_source", ""),
             "tail_after_ns": result["tail_after_ns"]}
    return data, coords, attrs
