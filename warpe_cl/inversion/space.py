"""The parameter space of a sweep database and the surface response anywhere inside it
(docs/inversion.md §2).

Each swept numeric key of the database is an axis. Its interpolation coordinate is the one its
values are most evenly spaced in (:func:`axis_scale`): ln(value) for grain sizes and
thicknesses spaced by factors, -ln(1 - value) for compacities crowding towards 1, the value
itself otherwise. A point inside the grid is a multilinear combination of the 2^d corners of
its cell in those coordinates.

What is combined is not the waveform but the surface response, in the form in which it moves
smoothly with the parameters:

- the diffuse response R_d(t) as its total ∫R_d dt and its shape as the quantile function of
  the normalised cumulative return, ln t(q) (displacement interpolation: a response whose
  delays grow with thickness moves along the time axis between grid points instead of fading
  from one shape into the other, which a weighted sum of waveforms does). The total is
  combined one axis after the other, each in its own coordinate of the total
  (:func:`total_scale`): ln ∫R_d where the axis' interior nodes are predicted better so (the
  total falls by factors along a thickness or grain size), ∫R_d itself where they are
  predicted better so (a floor's albedo A enters it almost in proportion, R_d ∝ A/(1 − rA));
- the specular fraction and, for each k-th back-and-forth passage, its fraction (linear in
  the corner weights) and its delay, in the coordinate in which it is exact: the delay
  t_k = 2 k Σ h_i n_eff,i / c is linear in each layer thickness h_i, not in ln h_i, so the
  delays are combined with multilinear weights in the axis *values* (:func:`value_weights`),
  whatever an axis' interpolation coordinate. Along a thickness axis this is 2 k h n_eff / c
  at the interpolated h exactly; along the others (compacity, ...) it is n_eff interpolated
  linearly between the nodes' values. (Combining the delays with the weights of the ln h
  coordinate put the echo of a 700 mm slab between 500 and 1000 mm nodes 6 % late, and the
  fitted thickness came back 674 mm; docs/inversion.md §2.)

**Curvature.** Multilinear interpolation errs with one sign across a cell wherever the
response is convex or concave in the coordinate (the late diffuse tail of a thick granular
layer lies low everywhere between nodes). Along each axis of three values or more, node m is
predicted from its neighbours m ± 1 on their cell (width D, m at fraction f₀ of it); that
prediction's error, scaled to the point's own cell (width Δ, fraction f) by the quadratic
law g = Δ² f (1 − f) / (D² f₀ (1 − f₀)), is added back, a = w g for each corner (weight w)
and axis (m the corner's index kept off the ends, :meth:`Space.bends`), in the coordinates
the interpolation combines: on ln t(q), on the specular and passages' fractions (floored at
0) and on the axis' coordinate of the total (:meth:`Space.total`). Every node then enters
with one weight (:meth:`Space.node_weights`: +a on m, −a (1 − f₀) and −a f₀ on its
neighbours): quadratic Lagrange interpolation through three nodes in each of those
coordinates, and a blend of the two stencils with four or more
(tests/test_inversion_curvature.py). Where negative weights make ln t(q) decrease it is
rearranged to increase, each stretch of q keeping its share of the amount (the monotone
rearrangement, :func:`rearranged_cdf`: a distribution again), and it is held inside the time
edges (the total kept); a term whose three nodes do not all have a diffuse response bends the
fractions and the total, not the shape. The delays stay exact. Moving
quantiles, the correction lands where the point's response is: a slab floor's spike moves
with its round trip, and a tail that ends between nodes ends where the point's does, where
a correction of the density, added at node m's times, put node m's edges into the point's
response (docs/inversion.md §2).

At a grid point the corner weights are (1, 0, …), there is no curvature term, and every step
is exact: the response is the node's own, to rounding (tests/test_inversion.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..surface import SurfaceResponse, check_variables, responses


#: Interpolation coordinates of an axis: name -> (coordinate of a value, value of a
#: coordinate). ``log1m`` is -ln(1 - x), for values crowding towards 1 (compacities of
#: compact slabs, 0.9 ... 0.999).
SCALES = {
    "linear": (lambda x: x, lambda u: u),
    "log": (np.log, np.exp),
    "log1m": (lambda x: -np.log1p(-x), lambda u: -np.expm1(-u)),
}


@dataclass
class Axis:
    """One swept key of the database.

    Attributes
    ----------
    key : str
        The dotted key (``medium.inclusions[0].grain_size``).
    values : array
        Its grid values, increasing, in the database's unit (``units``: m, ns, deg or 1).
    units : str
    scale : str
        The interpolation coordinate, a key of ``SCALES``: the value, ln(value) or
        -ln(1 - value) (:func:`axis_scale`). The prior is uniform in it.
    """
    key: str
    values: np.ndarray
    units: str
    scale: str = "linear"

    @property
    def log(self) -> bool:
        """Whether the interpolation coordinate is ln(value)."""
        return self.scale == "log"

    def coord(self, x):
        """The interpolation coordinate of value(s) ``x``."""
        return SCALES[self.scale][0](np.asarray(x, float))

    def value(self, u):
        """The value at interpolation coordinate(s) ``u``."""
        return SCALES[self.scale][1](np.asarray(u, float))

    @property
    def nodes(self) -> np.ndarray:
        """The grid values in the interpolation coordinate."""
        return self.coord(self.values)

    @property
    def short(self) -> str:
        """The last part of the key (``grain_size``)."""
        return self.key.rsplit(".", 1)[-1]

    def same_nodes(self, other) -> bool:
        """Whether ``other`` sweeps the same key, in the same coordinate, over the same values
        (to 1e-9): the same axis of one sweep run at another wavelength."""
        return (self.key == other.key and self.scale == other.scale
                and self.values.size == other.values.size
                and bool(np.allclose(self.values, other.values, rtol=1e-9, atol=0.0)))


def axis_scale(values: np.ndarray) -> str:
    """The coordinate of ``SCALES`` in which the grid ``values`` are closest to evenly spaced:
    ``log`` for positive values closer to even in ln (two values: a ratio above 3),
    ``log1m`` for values in (0, 1) closer to even in -ln(1 - x) than in both others (three
    values at least), else ``linear``."""
    v = np.asarray(values, float)
    if v.size < 2:
        return "linear"
    if v.size == 2:
        if np.all(v > 0) and v[1] / v[0] > 3.0:
            return "log"
        return "linear"

    def unevenness(x):
        d = np.diff(x)
        return float(np.std(d) / np.mean(d))
    score = {"linear": unevenness(v)}
    if np.all(v > 0):
        score["log"] = unevenness(np.log(v))
    if np.all((v > 0) & (v < 1)):
        score["log1m"] = unevenness(-np.log1p(-v))
    best = min(score, key=score.get)
    return best if score[best] < score["linear"] else "linear"


def swept_keys(ds) -> list:
    """The dotted keys swept along ``scenario`` (coordinates with a ``sweep_key`` attribute)."""
    return [name for name, c in ds.coords.items()
            if "sweep_key" in c.attrs and c.dims == ("scenario",)]


def cell_of(x: float, nodes: np.ndarray) -> tuple[int, float]:
    """The grid cell [nodes[j], nodes[j + 1]] that holds coordinate ``x`` (the first or last
    outside the grid) and x's fraction f of it, clipped to [0, 1]."""
    j = int(np.clip(np.searchsorted(nodes, x, side="right") - 1, 0, nodes.size - 2))
    f = float((x - nodes[j]) / (nodes[j + 1] - nodes[j]))
    return j, min(max(f, 0.0), 1.0)


def corner_weights(u: np.ndarray, nodes: list) -> tuple[list, list]:
    """Multilinear weights of point ``u`` (one coordinate per axis) in its grid cell.

    Returns
    -------
    (indices, weights)
        Index tuples of the cell's corners with a non-zero weight and their weights (sum 1).
    """
    per_axis = []
    for x, n in zip(u, nodes):
        if n.size == 1:
            per_axis.append([(0, 1.0)])
            continue
        j, f = cell_of(x, n)
        per_axis.append([(j, 1.0 - f), (j + 1, f)])
    indices, weights = [()], [1.0]
    for options in per_axis:
        indices = [i + (j,) for i in indices for j, _ in options]
        weights = [w * f for w in weights for _, f in options]
    keep = [k for k, w in enumerate(weights) if w > 0.0]
    return [indices[k] for k in keep], [weights[k] for k in keep]


def value_weights(x: np.ndarray, values: list, indices: list) -> list:
    """Multilinear weights of the point of values ``x`` (one per axis, axis units) on the
    corners ``indices`` of its cell, linear in the values themselves rather than in the
    interpolation coordinates: the weights of the echo delays (module docstring).

    Parameters
    ----------
    x : array
        The point's value on every axis (m, 1, ... as the axis).
    values : list of arrays
        Every axis' grid values, increasing.
    indices : list of tuples
        The corners (index tuples) that :func:`corner_weights` gave in the interpolation
        coordinates: the same cell, as every coordinate is increasing in the value.

    Returns
    -------
    list of float
        One weight per corner of ``indices``, summing to 1.
    """
    idx, w = corner_weights(np.asarray(x, float), [np.asarray(v, float) for v in values])
    by_index = dict(zip(idx, w))
    out = np.array([by_index.get(i, 0.0) for i in indices], float)
    total = out.sum()
    if not total > 0:       # a corner set the value weights do not reach (rounding at a node)
        return [1.0 / len(indices)] * len(indices) if indices else []
    return list(out / total)


def blend_total(a, b, f: float, scale: str):
    """The total(s) (sr⁻¹, floats or arrays) a fraction ``f`` of the way from ``a`` to ``b``,
    in ln (``log``) or in the total itself (``linear``); ``a`` at f = 0 and ``b`` at f = 1
    exactly."""
    if f <= 0.0:
        return a
    if f >= 1.0:
        return b
    if scale == "log":
        with np.errstate(divide="ignore"):
            return np.exp((1.0 - f) * np.log(a) + f * np.log(b))
    return (1.0 - f) * np.asarray(a) + f * np.asarray(b)


def total_scale(totals: np.ndarray, nodes: np.ndarray, axis: int) -> str:
    """The coordinate, ``log`` (ln total) or ``linear`` (the total), in which the diffuse
    totals ``totals`` (the grid's array, sr⁻¹) are best interpolated along ``axis`` (grid
    ``nodes`` in the interpolation coordinate): each interior node predicted from its two
    neighbours both ways (:func:`blend_total`), the one with the smaller sum of squared
    ln(prediction / node) kept (``log`` on a tie, on an axis of fewer than three values,
    which has no interior node, and where a total is 0)."""
    n = nodes.size
    if n < 3 or not np.all(totals > 0):
        return "log"
    t = np.moveaxis(totals, axis, 0)
    misfit = {}
    for scale in ("log", "linear"):
        misfit[scale] = 0.0
        for m in range(1, n - 1):
            f0 = float((nodes[m] - nodes[m - 1]) / (nodes[m + 1] - nodes[m - 1]))
            guess = blend_total(t[m - 1], t[m + 1], f0, scale)
            misfit[scale] += float(np.sum(np.log(guess / t[m]) ** 2))
    return "linear" if misfit["linear"] < misfit["log"] else "log"


def _quantile(cdf: np.ndarray, edges: np.ndarray, q: np.ndarray) -> np.ndarray:
    """t(q) = inf{t : F(t) ≥ q} of a CDF linear in t inside each bin (a piecewise-constant
    density), F given at ``edges`` (non-decreasing, from 0 to 1), for q in [0, 1]."""
    i = np.clip(np.searchsorted(cdf, q, side="left"), 1, cdf.size - 1)
    lo, hi = cdf[i - 1], cdf[i]
    frac = np.where(hi > lo, (q - lo) / np.where(hi > lo, hi - lo, 1.0), 1.0)
    start = np.searchsorted(cdf, 0.0, side="right") - 1      # the edge where the mass begins
    t = edges[i - 1] + np.clip(frac, 0.0, 1.0) * (edges[i] - edges[i - 1])
    return np.where(q <= 0.0, edges[max(start, 0)], t)


def rearranged_cdf(t: np.ndarray, q: np.ndarray, x: np.ndarray) -> np.ndarray:
    """How much of [q₀, q_n] has t(q) ≤ x, at each of the increasing ``x``, for t given at the
    knots ``q`` and linear in t between them (as np.interp reads a CDF from knots), whether
    or not t is monotone: F(x) = Σ_j Δq_j clip((x − a_j)/(b_j − a_j), 0, 1), a_j and b_j the
    lower and higher end of knot interval j. For q from 0 to 1 it is the CDF of t(Q), Q
    uniform: where t decreases, the monotone rearrangement of t(q) (its quantile function is
    t sorted as a function on [0, 1]), each knot interval keeping its share Δq_j of the
    amount however few or many knots the others hold. Held within [0, q_n − q₀] and
    non-decreasing against rounding."""
    a, b = np.minimum(t[:-1], t[1:]), np.maximum(t[:-1], t[1:])
    dq = np.diff(q)
    order = np.argsort(b, kind="stable")            # intervals wholly at or below x
    below = np.concatenate([[0.0], np.cumsum(dq[order])])
    cdf = below[np.searchsorted(b[order], x, side="right")]
    first = np.searchsorted(x, a, side="right")     # and the parts of those x lies inside
    count = np.maximum(np.searchsorted(x, b, side="left") - first, 0)
    inside = np.repeat(np.arange(a.size), count)
    at = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count) \
        + np.repeat(first, count)
    part = dq[inside] * (x[at] - a[inside]) / (b[inside] - a[inside])
    cdf = cdf + np.bincount(at, weights=part, minlength=x.size)
    return np.maximum.accumulate(np.minimum(cdf, q[-1] - q[0]))


class NodeResponse:
    """One scenario's surface response in the form that is interpolated (module docstring)."""

    def __init__(self, r: SurfaceResponse, first_bf_time: float):
        self.surface = r
        amount = r.diffuse * np.diff(r.edges)
        self.total = float(amount.sum())
        cdf = np.concatenate([[0.0], np.cumsum(amount)])
        self.cdf = cdf / cdf[-1] if cdf[-1] > 0 else cdf
        self.specular = sum(f for c, _, f in r.returns if c == "specular")
        self.first_bf = first_bf_time
        self.passages = {}
        for c, t, f in r.returns:
            if c == "bf_direct":
                k = max(1, round(t / first_bf_time)) if first_bf_time > 0 else 1
                delay, frac = self.passages.get(k, (t, 0.0))
                self.passages[k] = (delay, frac + f)


class Space:
    """The database's grid: axes, fixed keys, and the surface response at any point.

    Parameters
    ----------
    db : xarray.Dataset
        A sweep database (:func:`warpe_cl.open_database`) or a ``warpe-cl run`` sweep file.
    fix : dict, optional
        Dotted key -> value (float in the axis unit, or text for a non-numeric key): the key is
        held there (a grid value, or any value inside its range for a numeric key).
    source : str
        Name of the database, for messages.
    """

    def __init__(self, db, fix: dict | None = None, source: str = "database"):
        check_variables(db, source)
        if "scenario" not in db.dims:
            raise ConfigError("holds one scenario, not a sweep: give a `warpe-cl sweep` "
                              "database (a folder) or a sweep file", key=source)
        fix = dict(fix or {})
        keys = swept_keys(db)
        unknown = [k for k in fix if k not in keys]
        if unknown:
            raise ConfigError(f"--fix {unknown[0]}: not a swept key of the database (swept: "
                              f"{', '.join(keys)})", key=source)
        self.source = source
        self.edges = np.asarray(db["time_edges"].values, float)
        keep = np.ones(db.sizes["scenario"], bool)
        numeric = []
        self.fixed = {}
        for key in keys:
            values = db[key].values
            if not np.issubdtype(values.dtype, np.number):
                if key not in fix:
                    raise ConfigError(f"{key} is swept over non-numeric values "
                                      f"({', '.join(sorted(set(map(str, values))))}); choose one "
                                      f"with --fix {key}=VALUE", key=source)
                keep &= values.astype(str) == str(fix[key])
                if not keep.any():
                    raise ConfigError(f"--fix {key}={fix[key]}: not one of its values "
                                      f"({', '.join(sorted(set(map(str, values))))})", key=source)
                self.fixed[key] = str(fix[key])
            else:
                numeric.append(key)
        sub = db.isel(scenario=np.nonzero(keep)[0])
        self.axes = []
        for key in numeric:
            v = np.unique(np.asarray(sub[key].values, float))
            self.axes.append(Axis(key, v, sub[key].attrs.get("units", "1"), axis_scale(v)))
        shape = tuple(a.values.size for a in self.axes)
        if int(np.prod(shape)) != sub.sizes["scenario"]:
            raise ConfigError(f"its {sub.sizes['scenario']} finished scenarios do not fill the "
                              f"grid of {' x '.join(map(str, shape))} points (an unfinished sweep? "
                              "run `warpe-cl sweep --resume` first)", key=source)
        self.nodes = np.empty(shape, object)
        t1 = (sub["first_bf_time_ns"].values if "first_bf_time_ns" in sub.variables
              else np.full(sub.sizes["scenario"], math.nan))
        values = [np.asarray(sub[a.key].values, float) for a in self.axes]
        for i, r in enumerate(responses(sub, uniform=True)):
            index = tuple(int(np.searchsorted(a.values, v[i])) for a, v in zip(self.axes, values))
            self.nodes[index] = NodeResponse(r, float(t1[i]))
        self.wavelength = self.nodes.flat[0].surface.wavelength
        self.totals = np.vectorize(lambda n: n.total, otypes=[float])(self.nodes)
        self.total_scales = [total_scale(self.totals, a.nodes, d)
                             for d, a in enumerate(self.axes)]
        self._left_out = {}
        self.point = {}
        for key, value in fix.items():
            if key in self.fixed:
                continue
            axis = self.axis(key)
            lo, hi = axis.values[0], axis.values[-1]
            if not lo * (1 - 1e-9) <= value <= hi * (1 + 1e-9):
                raise ConfigError(f"--fix {key}={value:g} {axis.units}: outside the database's "
                                  f"range [{lo:g}, {hi:g}] {axis.units}", key=source)
            self.point[key] = float(value)

    def axis(self, key: str) -> Axis:
        """The axis of dotted ``key``."""
        for a in self.axes:
            if a.key == key:
                return a
        raise KeyError(key)

    @property
    def free_axes(self) -> list:
        """The axes not held by ``fix``."""
        return [a for a in self.axes if a.key not in self.point]

    def coords_of(self, point: dict) -> np.ndarray:
        """Interpolation coordinates of every axis for ``point`` (free keys) plus the fixed
        values."""
        values = {**self.point, **point}
        return np.array([a.coord(values[a.key]) for a in self.axes], float)

    def values_of(self, point: dict) -> np.ndarray:
        """Values (axis units) of every axis for ``point`` (free keys) plus the fixed
        values."""
        values = {**self.point, **point}
        return np.array([float(values[a.key]) for a in self.axes], float)

    def surface(self, point: dict) -> SurfaceResponse:
        """The surface response at ``point`` (dotted key -> value of every free axis, in the
        axis unit), by the interpolation of the module docstring with each axis' curvature
        term (:meth:`bends`) in the same coordinates: every node's weight is its
        :meth:`node_weights` one, on ln t(q), the fractions and (axis by axis) the total."""
        idx, w = corner_weights(self.coords_of(point), [a.nodes for a in self.axes])
        if len(idx) == 1:
            return self.nodes[idx[0]].surface
        bends = self.bends(point)
        weights = self.node_weights(point, bends)
        # a term moves quantiles only where its three nodes have a diffuse response (a
        # shape); elsewhere it still bends the fractions and the total
        shaped = [b for b in bends if all(self.totals[i] > 0 for i in self.stencil(*b[:2]))]
        shape = weights if len(shaped) == len(bends) else self.node_weights(point, shaped)
        delay_w = dict(zip(idx, value_weights(self.values_of(point),
                                              [a.values for a in self.axes], idx)))
        used = [i for i in {**weights, **shape}
                if weights.get(i, 0.0) != 0.0 or shape.get(i, 0.0) != 0.0 or i in delay_w]
        return combine([self.nodes[i] for i in used], [weights.get(i, 0.0) for i in used],
                       self.edges, delay_weights=[delay_w.get(i, 0.0) for i in used],
                       total=self.total(point, bends),
                       shape_weights=[shape.get(i, 0.0) for i in used])

    def stencil(self, d: int, middle: tuple) -> tuple:
        """Node ``middle`` and its two neighbours along axis ``d``: (m, m − 1, m + 1)."""
        m = middle[d]
        return (middle,) + tuple(middle[:d] + (k,) + middle[d + 1:] for k in (m - 1, m + 1))

    def total(self, point: dict, bends: list | None = None) -> float:
        """The diffuse total ∫R_d dt (sr⁻¹) at ``point``: the cell's corners combined one
        axis after the other, in the axis' order, each in its coordinate of
        ``total_scales`` (module docstring), then each curvature term of :meth:`bends`
        (given, or computed) in its axis' coordinate: a (ln T_m − ln T̂_m) added to ln ∫R_d,
        or a (T_m − T̂_m) to ∫R_d (T̂_m node m's total predicted from its neighbours,
        a = w g; the latter where one of the three totals, or the total so far, is 0);
        floored at 0."""
        block, steps = self.totals, []
        for x, a in zip(self.coords_of(point), self.axes):
            n = a.nodes
            if n.size == 1:
                steps.append(0.0)
                continue
            j, f = cell_of(x, n)
            steps.append(f)
            block = np.take(block, [j, j + 1], axis=len(steps) - 1)
        for f, scale in zip(steps, self.total_scales):
            block = blend_total(block[0], block[-1], f, scale)
        total = float(block)
        for d, middle, w, g in (self.bends(point) if bends is None else bends):
            _, _, f0 = self.left_out(middle, d)
            own, lo, hi = (float(self.totals[i]) for i in self.stencil(d, middle))
            if self.total_scales[d] == "log" and min(own, lo, hi, total) > 0:
                total *= math.exp(w * g * math.log(own / blend_total(lo, hi, f0, "log")))
            else:
                total += w * g * (own - blend_total(lo, hi, f0, "linear"))
        return max(total, 0.0)

    def bends(self, point: dict) -> list:
        """The curvature terms at ``point``: for every corner of its cell (weight w) and every
        axis of three values or more whose cell holds the point inside (fraction f of a cell
        of width Δ), the node m that axis' terms leave out (the corner's own index along the
        axis, kept off the ends) and the cell factor g = Δ² f (1 − f) / (D² f₀ (1 − f₀))
        (module docstring).

        Returns
        -------
        list of (int, tuple, float, float)
            (axis, index of m, w, g); empty at the nodes and on axes of two values.
        """
        u = self.coords_of(point)
        idx, w = corner_weights(u, [a.nodes for a in self.axes])
        out = []
        for d, axis in enumerate(self.axes):
            n = axis.values.size
            if n < 3:
                continue
            x = axis.nodes
            j, f = cell_of(u[d], x)
            if f <= 0.0 or f >= 1.0:
                continue
            cell = x[j + 1] - x[j]
            for i, wi in zip(idx, w):
                m = min(max(i[d], 1), n - 2)
                middle = i[:d] + (m,) + i[d + 1:]
                _, wide, f0 = self.left_out(middle, d)
                out.append((d, middle, wi, cell ** 2 * f * (1 - f) / (wide ** 2 * f0 * (1 - f0))))
        return out

    def left_out(self, middle: tuple, d: int) -> tuple:
        """Node ``middle`` (interior along axis ``d``) predicted from its two neighbours along
        that axis, by the interpolation of the module docstring on the cell they span.

        Returns
        -------
        (NodeResponse, float, float)
            The prediction, the width D of the neighbours' cell and the node's fraction f₀ of
            it (interpolation coordinate). Kept: an inversion visits a few cells.
        """
        key = (middle, d)
        if key not in self._left_out:
            m = middle[d]
            _, lo, hi = self.stencil(d, middle)
            x, v = self.axes[d].nodes, self.axes[d].values
            f0 = (x[m] - x[m - 1]) / (x[m + 1] - x[m - 1])
            fv = (v[m] - v[m - 1]) / (v[m + 1] - v[m - 1])
            a, b = self.nodes[lo], self.nodes[hi]
            predicted = combine([a, b], [1 - f0, f0], self.edges, delay_weights=[1 - fv, fv],
                                total=blend_total(a.total, b.total, f0, self.total_scales[d]))
            self._left_out[key] = (NodeResponse(predicted, self.nodes[middle].first_bf),
                                   float(x[m + 1] - x[m - 1]), float(f0))
        return self._left_out[key]

    def node_weights(self, point: dict, bends: list | None = None) -> dict:
        """Each node's weight in the response at ``point`` (index -> weight): the corners'
        multilinear weights and the curvature terms' (+a on m, −a (1 − f₀) and −a f₀ on its
        neighbours, a = w g). The response combines the nodes' ln t(q) and fractions with
        them (:meth:`surface`), and their Monte Carlo errors are carried by them
        (:mod:`.emulator`). ``bends``: the point's :meth:`bends`, if the caller has them
        already."""
        idx, w = corner_weights(self.coords_of(point), [a.nodes for a in self.axes])
        out = dict(zip(idx, w))
        for d, middle, wi, g in (self.bends(point) if bends is None else bends):
            _, _, f0 = self.left_out(middle, d)
            for index, share in zip(self.stencil(d, middle), (1.0, -(1 - f0), -f0)):
                out[index] = out.get(index, 0.0) + wi * g * share
        return out


def floored(density: np.ndarray, width: np.ndarray) -> np.ndarray:
    """A diffuse response combined with negative weights (sr⁻¹ ns⁻¹ on bins ``width`` ns
    wide; :func:`combine` where a node has none) with its negative bins set to 0 and the
    rest scaled down so that its integral stays what the weights made it: the clipped part
    would otherwise be added to the total."""
    kept = np.maximum(density, 0.0)
    intended, total = float(np.sum(density * width)), float(np.sum(kept * width))
    if total > intended > 0.0:
        kept *= intended / total
    return kept


def combine(nodes: list, weights: list, edges: np.ndarray,
            delay_weights: list | None = None, total: float | None = None,
            shape_weights: list | None = None) -> SurfaceResponse:
    """The displacement interpolation of the module docstring.

    Parameters
    ----------
    nodes : list of NodeResponse
        The nodes combined: a cell's corners, and the nodes of its curvature terms.
    weights : list of float
        Their weights in the interpolation coordinates (sum 1; negative ones where a
        curvature term takes a neighbour's share off, :meth:`Space.node_weights`): on the
        diffuse response's ln t(q), the specular and back-and-forth fractions (each floored
        at 0).
    edges : array
        The common time edges, ns.
    delay_weights : list of float, optional
        The nodes' multilinear weights in the axis values (sum 1, 0 off the cell's corners,
        :func:`value_weights`), for the back-and-forth delays, which are linear in the
        thicknesses; default ``weights``.
    total : float, optional
        The diffuse total ∫R_d dt, sr⁻¹, where every node's is positive
        (:meth:`Space.total`); default the totals combined in ln with the shape weights.
    shape_weights : list of float, optional
        The weights on ln t(q) (sum 1), where they differ from ``weights``: a curvature term
        whose nodes do not all have a diffuse response bends no shape (:meth:`Space.surface`).

    Returns
    -------
    SurfaceResponse
        Where every node with a shape weight has a positive diffuse total, its diffuse
        response is ``total`` spread by the quantile function ln t(q) = Σ w_i ln t_i(q),
        rearranged to be non-decreasing in q where negative weights make it cross (the
        monotone rearrangement, :func:`rearranged_cdf`: a distribution again, closer to the
        true one) and held inside the time edges, so that the whole total stays on them; where
        one is 0, the weighted sum of the densities floored at 0 keeping its integral
        (:func:`floored`).
    """
    w = np.asarray(weights, float)
    wd = w if delay_weights is None else np.asarray(delay_weights, float)
    ws = w if shape_weights is None else np.asarray(shape_weights, float)
    shaped = [(wi, n) for wi, n in zip(ws, nodes) if wi != 0.0]
    if all(n.total > 0 for _, n in shaped):
        if total is None:
            total = float(np.exp(sum(wi * np.log(n.total) for wi, n in shaped)))
        q = np.unique(np.concatenate([n.cdf for _, n in shaped]))
        first = edges[edges > 0][0]
        log_t = sum(wi * np.log(np.maximum(_quantile(n.cdf, edges, q), first))
                    for wi, n in shaped)
        t = np.clip(np.exp(log_t), first, edges[-1])
        cdf = (np.interp(edges, t, q, left=0.0, right=1.0) if np.all(np.diff(log_t) >= 0)
               else rearranged_cdf(t, q, edges))
        cdf[0], cdf[-1] = 0.0, 1.0          # quantiles held on an edge keep their mass
        diffuse = total * np.diff(cdf) / np.diff(edges)
    else:
        diffuse = floored(sum(wi * n.surface.diffuse for wi, n in zip(w, nodes)),
                          np.diff(edges))
    returns = []
    specular = max(float(np.sum(w * [n.specular for n in nodes])), 0.0)
    if specular > 0:
        returns.append(("specular", 0.0, specular))
    ks = sorted(set(k for n in nodes for k in n.passages))
    for k in ks:
        delay, frac = 0.0, 0.0
        for wi, wdi, n in zip(w, wd, nodes):
            t_k = n.passages[k][0] if k in n.passages else k * n.first_bf
            if not math.isfinite(t_k):      # a node without this passage nor a known period
                known = [m.passages[k][0] for m, x in zip(nodes, wd) if k in m.passages and x]
                t_k = np.mean(known or [m.passages[k][0] for m in nodes if k in m.passages])
            delay += wdi * t_k              # t_k = 2 k h n_eff / c: linear in h
            frac += wi * (n.passages[k][1] if k in n.passages else 0.0)
        if frac > 0:
            returns.append(("bf_direct", float(delay), float(frac)))
    return SurfaceResponse(edges, diffuse, returns, nodes[0].surface.wavelength)
