"""The posterior over the database's parameters: a grid posterior, refined where the mass is
(docs/inversion.md §5).

Prior: uniform in each axis' interpolation coordinate (ln of grain size and thickness, the value
of compacity) over the database's range; the database defines what is possible. The nuisance v
(pulse width and footprint broadening) is profiled at each point, the per-shot nuisances are
marginalised (:mod:`.likelihood`).

Why a grid and not a sampler (emcee, dynesty): the parameter spaces are the database's own grids
of 1 to 4 keys; a grid evaluates every model once, needs no burn-in nor convergence check, is
deterministic, and gives the marginal on the grid values directly. It is first evaluated at the
nodes, then re-evaluated on a finer grid over the box holding the nodes within 20 in log
likelihood of the best (``log`` L > max − 20: the rest holds < 1e-8 of the mass), up to four
times, until every axis has at least 6 points in the box and no point holding more than half
of its marginal mass, or the budget is spent. Only the axes not yet resolved are subdivided,
at most fourfold a round (:func:`_finer`); a box that reaches an end of its grid that is not
the prior's goes on to the database node beyond it (two more rounds are allowed after that).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace

import numpy as np

from .emulator import shared_error
from .forked import forked_map, workers
from .forward import Spectrum

#: Points with log L below the best minus this hold a negligible share of the posterior.
SIGNIFICANT = 20.0
#: An axis is resolved when no point of it holds more than this share of the marginal mass: a
#: Gaussian posterior of width σ sampled every h puts about h / (σ √(2π)) on its central
#: point, so 0.5 means points at most 1.25 σ apart, where the intervals of the trapezoid rule
#: (:func:`intervals`) hold a Gaussian's truth 0.71 and 0.96 of the time for 0.68 and 0.95
#: (wider grids hold it more often: coarse is conservative, not overconfident).
RESOLVED_SHARE = 0.5
#: Rounds of refinement allowed beyond ``refine``'s ``rounds`` after a round that carried a
#: box past its grid (:func:`_finer`).
EXTRA_ROUNDS = 2
#: The profile over v stops when a further step would raise log L by less than this.
V_GAIN = 0.01
#: A narrow axis gets, per round, at most this many times its span's intervals (:func:`_finer`)
SUBDIVISION = 4
#: ... and at least this many points: the 600-point budget's share of each of two narrow axes,
#: so that one free key is not sampled at 600 points where a few dozen resolve it.
MIN_POINTS = 24
#: A grid's points go to the worker processes in chunks of this many (:meth:`Problem.grid`).
CHUNK = 32


@dataclass
class Evaluation:
    """The likelihood at one point: log L with v profiled, the nuisances at the best v
    (a joint inversion's: the sum over its channels, and each channel's own in ``parts``)."""
    loglike: float
    v: float
    fit: object            # likelihood.ShotFit
    parts: tuple = ()


@dataclass
class GridPosterior:
    """Log-likelihoods on a rectangular grid of the free axes' coordinates.

    Attributes
    ----------
    coords : list of arrays
        The grid's coordinates per free axis (interpolation coordinates).
    loglike : array
        log L at every point (shape: the coordinates' lengths).
    evaluations : dict
        index tuple -> Evaluation.
    """
    coords: list
    loglike: np.ndarray
    evaluations: dict = field(default_factory=dict)

    def weights(self) -> np.ndarray:
        """Normalised posterior mass at each point (trapezoid cell volumes in the coordinates)."""
        vol = np.ones(self.loglike.shape)
        for i, c in enumerate(self.coords):
            w = cell_widths(c)
            vol = vol * w.reshape([-1 if j == i else 1 for j in range(len(self.coords))])
        logp = self.loglike - np.nanmax(self.loglike)
        p = np.where(np.isfinite(logp), np.exp(logp), 0.0) * vol
        return p / p.sum()

    def best(self) -> tuple:
        """Index of the largest log L."""
        return np.unravel_index(int(np.nanargmax(self.loglike)), self.loglike.shape)


def cell_widths(c: np.ndarray) -> np.ndarray:
    """Trapezoid weights of points ``c`` (one point: weight 1)."""
    if c.size == 1:
        return np.ones(1)
    d = np.diff(c)
    return 0.5 * (np.concatenate([[0.0], d]) + np.concatenate([d, [0.0]]))


class Problem:
    """log L(θ) with the nuisances handled: the surface at θ (space), the instrument model
    (forward) and the recorded shots (likelihood.Shots).

    Parameters
    ----------
    space, forward, shots
        :class:`.space.Space`, :class:`.forward.Forward`, :class:`.likelihood.Shots`.
    overall : float, optional
        The overall amplitude A, fixed (None: profiled).
    v : float, optional
        The broadening nuisance v, fixed, ns² (None: profiled in ``forward.v_bounds``).
    emulator : Emulator, optional
        The database's own error S(t) (:mod:`.emulator`), integrated out of log L at every
        point (None: the database is taken as exact).
    """

    def __init__(self, space, forward, shots, overall=None, v=None, emulator=None):
        self.space, self.forward, self.shots = space, forward, shots
        self.overall, self.v_fixed = overall, v
        self.emulator = emulator
        self.count = 0

    def point(self, u: np.ndarray) -> dict:
        """The free keys' values at coordinates ``u``."""
        return {a.key: float(a.value(x)) for a, x in zip(self.space.free_axes, u)}

    def evaluate(self, u: np.ndarray) -> Evaluation:
        """log L at free coordinates ``u``, v profiled (:meth:`_profile_v`), with the
        database's own error integrated out when there is an emulator."""
        point = self.point(u)
        photons = Spectrum(self.forward.photons(self.space.surface(point)))
        shared = None if self.emulator is None else self.emulator.variance(point)
        fits = {}
        # each point afresh: the arrivals and amplitudes from the scan of Shots.start, the
        # pulse width from the nominal one, so that a point's log L does not depend on the
        # points evaluated before it. Started from the last point's fit, a shot could stay on
        # a poor local optimum of its arrival for the next dozen points (ln L 20 too low
        # after a grid's thick end), and a clipped shot's nearly free amplitude carried
        # rounding from point to point; the pulse widths at one point start from its own fit

        def neg(v):
            mu, nu = self.forward.waveform(photons, v)
            if not fits:                    # the point's first pulse width
                self.shots.start(mu)
            fit = self.shots.fit(mu, nu, self.overall)
            if shared is not None:
                fit.emulator, fit.emulator_sd, fit.emulator_offset = shared_error(
                    self.shots, fit, mu, nu, shared, self.overall is None)
                fit.loglike += fit.emulator
            fits[v] = replace(fit, table=None)      # the model's table is not kept (72 kB)
            self.count += 1
            return -fit.loglike

        if self.v_fixed is not None:
            v = float(self.v_fixed)
            neg(v)
        else:
            v = self._profile_v(neg)
        return Evaluation(fits[v].loglike, v, fits[v])

    def _profile_v(self, neg) -> float:
        """The v (ns²) minimising ``neg`` in ``forward.v_bounds``: successive parabolas
        through the three best points, started at v = 0 (the nominal pulse and footprint),
        steps capped at 4 h and kept inside the bounds; stops when the parabola promises less
        than ``V_GAIN`` in log L, or a step is below 1e-3 σ_p² (a 0.05 % change of the pulse
        width)."""
        lo, hi = self.forward.v_bounds
        scale = self.forward.sigma_p ** 2
        h = 0.1 * scale
        tol = 1e-3 * scale
        v0 = min(max(0.0, lo + h), hi - h)
        seen = {v: neg(v) for v in (v0 - h, v0, v0 + h)}
        for _ in range(12):
            (x0, f0), (x1, f1), (x2, f2) = sorted(sorted(seen.items(), key=lambda p: p[1])[:3])
            best = min(seen, key=seen.get)
            denom = (x1 - x0) * (f1 - f2) - (x1 - x2) * (f1 - f0)
            numer = (x1 - x0) ** 2 * (f1 - f2) - (x1 - x2) ** 2 * (f1 - f0)
            curvature = ((f2 - f1) / (x2 - x1) - (f1 - f0) / (x1 - x0)) / (x2 - x0)
            if curvature > 0 and denom != 0:            # convex: the parabola's vertex
                step = x1 - 0.5 * numer / denom - best
                vertex = best + step
                promised = seen[best] - (f1 + (vertex - x1) * ((f2 - f1) / (x2 - x1)
                                                                + curvature * (vertex - x2)))
                if promised < V_GAIN and lo <= vertex <= hi:
                    break
            else:                                       # downhill, towards the better end
                step = (x0 - x2) if f0 < f2 else (x2 - x0)
            step = max(-4 * h, min(4 * h, step))
            v = min(max(best + step, lo), hi)
            if abs(v - best) < tol or v in seen:
                break
            seen[v] = neg(v)
            h = max(abs(v - best), tol)
        return min(seen, key=seen.get)

    def counts(self) -> list:
        """Model evaluations so far (one number; a joint problem's per channel)."""
        return [self.count]

    def add_counts(self, extra) -> None:
        """Add ``extra`` (as :meth:`counts`) to the model evaluations."""
        self.count += int(extra[0])

    def grid(self, coords: list, jobs: int = 1) -> GridPosterior:
        """Evaluate every point of the rectangular grid ``coords`` (per free axis), in chunks
        of :data:`CHUNK` points in grid order, spread over ``jobs`` worker processes
        (:func:`.forked.forked_map`). Every point is evaluated afresh (:meth:`evaluate`): its
        log L is the same bits with any ``jobs``."""
        shape = tuple(c.size for c in coords)
        indices = list(itertools.product(*(range(n) for n in shape)))

        chunks = [indices[i: i + CHUNK] for i in range(0, len(indices), CHUNK)]
        elsewhere = workers(jobs, len(chunks)) > 0

        def chunk(part):
            before = self.counts()
            done = [self.evaluate(np.array([c[i] for c, i in zip(coords, index)]))
                    for index in part]
            return done, [n - b for n, b in zip(self.counts(), before)]

        results = forked_map(chunk, chunks, jobs)
        loglike = np.full(shape, -np.inf)
        evaluations = {}
        for part, (done, counted) in zip(chunks, results):
            if elsewhere:                   # counted in the workers: add them here
                self.add_counts(counted)
            for index, e in zip(part, done):
                loglike[index] = e.loglike if math.isfinite(e.loglike) else -np.inf
                evaluations[index] = e
        return GridPosterior(list(coords), loglike, evaluations)


def refine(problem: Problem, budget: int = 600, rounds: int = 4, resolved: int = 6,
           jobs: int = 1) -> tuple[GridPosterior, GridPosterior]:
    """Nodes first, then finer grids where the mass is (module docstring), each grid's points
    spread over ``jobs`` worker processes (:meth:`Problem.grid`).

    Returns
    -------
    (nodes, final)
        The posterior at the database's nodes and on the last grid.
    """
    limits = [a.nodes for a in problem.space.free_axes]
    nodes = problem.grid(limits, jobs)
    current = nodes
    done, grew = 0, False
    # a round that carried a box past its grid regrids that axis over the wider span, maybe
    # more coarsely: up to two rounds more then, so that the last grid is not the coarser one
    while done < rounds or (grew and done < rounds + EXTRA_ROUNDS):
        box = _significant_box(current)
        coords, grew = _finer(current.coords, box, budget,
                              unresolved(current, box, resolved), limits)
        if coords is None:
            break
        current = problem.grid(coords, jobs)
        done += 1
    return nodes, current


def unresolved(post: GridPosterior, box: list, resolved: int = 6) -> list:
    """Per axis, whether the grid is too coarse for the posterior along it: fewer than
    ``resolved`` of its points in ``box`` (:func:`_significant_box`), or one point holding more
    than :data:`RESOLVED_SHARE` of the marginal mass."""
    return [c.size > 1 and (hi - lo + 1 < resolved
                            or float(np.max(marginal(post, i)[1])) > RESOLVED_SHARE)
            for i, (c, (lo, hi)) in enumerate(zip(post.coords, box))]


def _beyond(c: np.ndarray, lo: int, hi: int, nodes: np.ndarray) -> tuple:
    """Where the significant points of a grid axis reach one of its ends that is not the
    prior's, the database node beyond that end (else None), below and above: the posterior
    may go on past the grid there. A refined grid covers only the box of the grid before it,
    so without this a mode that the coarse grid misplaced (a narrow key evaluated off its peak
    biases a broad one) could never be reached again."""
    below = nodes[nodes < c[0]] if lo == 0 else nodes[:0]
    above = nodes[nodes > c[-1]] if hi == c.size - 1 else nodes[:0]
    return (float(below[-1]) if below.size else None,
            float(above[0]) if above.size else None)


def _significant_box(post: GridPosterior) -> list:
    """Per axis, the index range of points within SIGNIFICANT of the best log L."""
    keep = post.loglike > np.nanmax(post.loglike) - SIGNIFICANT
    box = []
    for axis in range(keep.ndim):
        other = tuple(j for j in range(keep.ndim) if j != axis)
        idx = np.nonzero(keep.any(axis=other) if other else keep)[0]
        box.append((int(idx.min()), int(idx.max())))
    return box


def _finer(coords: list, box: list, budget: int, narrow: list, limits=None):
    """A finer grid over ``box`` and whether a box reached past its grid, or ``(None,
    False)`` when no ``narrow`` axis (:func:`unresolved`) can be made finer within ``budget``
    points and no box reaches past its grid.

    Every axis spans ``box`` widened by one point each side (mass may lie between the last
    point within SIGNIFICANT of the best and the next), and, where the box reaches an end of
    the grid that is not the prior's, on to the database node beyond it (``limits``: the
    nodes per axis; :func:`_beyond`), and such an axis is gridded afresh. A resolved axis
    keeps its points; a narrow one gets as many evenly spaced points as ``budget`` allows,
    the same number on every narrow axis, but no more than :data:`SUBDIVISION` times its
    span's intervals (at least :data:`MIN_POINTS`), if its spacing shrinks by a third or more:
    the next round refines it again if that is not enough. So an
    axis along which the posterior is much narrower than the grid is refined even while
    others span the prior: with the same subdivision on every axis, two broad axes filled the
    budget and a narrow third one kept a single point, its intervals the grid's cell and not
    the posterior (docs/inversion.md §5).
    """
    spans = [c[max(lo - 1, 0): min(hi + 1, c.size - 1) + 1] for c, (lo, hi) in zip(coords, box)]
    grown = []
    for j, (c, (lo, hi)) in enumerate(zip(coords, box)):
        if limits is None or c.size < 2:
            continue
        below, above = _beyond(c, lo, hi, np.asarray(limits[j], float))
        if below is not None or above is not None:
            spans[j] = np.concatenate([[below] if below is not None else [], spans[j],
                                       [above] if above is not None else []])
            grown.append(j)
    fine = [j for j, n in enumerate(narrow) if n or j in grown]
    if not fine:
        return None, False
    kept = int(np.prod([s.size for j, s in enumerate(spans) if j not in fine]))
    share = int((budget / kept) ** (1.0 / len(fine)))
    out, refined = list(spans), False
    for j in fine:
        s = spans[j]
        points = min(share, max(MIN_POINTS, SUBDIVISION * (s.size - 1) + 1))
        finer = (s[-1] - s[0]) / max(points - 1, 1)
        if points >= 3 and (finer <= float(np.min(np.diff(s))) * (2.0 / 3.0) or j in grown):
            out[j] = np.linspace(s[0], s[-1], points)
            refined = True
    return (out, bool(grown)) if refined else (None, False)


def marginal(post: GridPosterior, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """(coordinates, mass) of the marginal posterior of one axis on the grid's points."""
    w = post.weights()
    other = tuple(j for j in range(w.ndim) if j != axis)
    return post.coords[axis], (w.sum(axis=other) if other else w)


def intervals(coords: np.ndarray, mass: np.ndarray, levels=(0.68, 0.95)) -> dict:
    """Equal-tailed credible intervals of a marginal given as point masses on ``coords``.

    The mass of each point is spread over its trapezoid cell (a piecewise-linear CDF through
    the cell boundaries), so an interval is not snapped to the grid points. Returns
    ``{level: (low, high)}`` in the coordinates, and the median under ``0.5``.
    """
    if coords.size == 1:
        return {**{lv: (coords[0], coords[0]) for lv in levels}, 0.5: coords[0]}
    mids = 0.5 * (coords[1:] + coords[:-1])
    bounds = np.concatenate([[coords[0]], mids, [coords[-1]]])
    cdf = np.concatenate([[0.0], np.cumsum(mass)])
    cdf = cdf / cdf[-1]

    def at(q):
        return float(np.interp(q, cdf, bounds))
    out = {lv: (at(0.5 - lv / 2.0), at(0.5 + lv / 2.0)) for lv in levels}
    out[0.5] = at(0.5)
    return out


def nearest_node_mass(fine: np.ndarray, mass: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """The marginal mass of a fine grid gathered on the nearest database node (the marginal
    posterior on the grid values)."""
    out = np.zeros(nodes.size)
    idx = np.argmin(np.abs(fine[:, None] - nodes[None, :]), axis=1)
    np.add.at(out, idx, mass)
    return out
