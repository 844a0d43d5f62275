"""The grid posterior's refinement (warpe_cl/inversion/posterior.py, docs/inversion.md §5):
the grid must resolve the posterior along every axis, also when the others span the prior.

These tests use an analytic log-likelihood on the database's node grid: no Monte Carlo.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from warpe_cl.inversion.posterior import GridPosterior, intervals, marginal, refine

#: Node coordinates of a 3 × 3 × 3 database (interpolation coordinates).
NODES = [np.array([0.0, 1.0, 2.0])] * 3


class Analytic:
    """A stand-in for :class:`~warpe_cl.inversion.posterior.Problem` whose log L is a
    Gaussian with centre ``centre`` and widths ``sigma`` (coordinates) per axis."""

    def __init__(self, centre, sigma, nodes=NODES):
        self.centre, self.sigma = np.asarray(centre), np.asarray(sigma)
        self.space = SimpleNamespace(free_axes=[SimpleNamespace(nodes=n) for n in nodes])
        self.points = 0

    def grid(self, coords, jobs=1):
        mesh = np.meshgrid(*coords, indexing="ij")
        z = sum(((m - c) / s) ** 2 for m, c, s in zip(mesh, self.centre, self.sigma))
        self.points += z.size
        return GridPosterior(list(coords), -0.5 * z)


def test_a_narrow_axis_is_resolved_while_the_others_span_the_prior():
    """Two keys nearly free, the third read to 1 % of a node spacing (the thickness of
    granular CO2 at 1000 BELA shots). With the same subdivision on every axis the budget was
    spent on the broad axes and the narrow one kept a single point: its 68 % interval was the
    grid's cell (0.4 wide here), 20 times the posterior's. Now the 600 points left by the two
    broad axes' 64 sample the narrow one every 2 σ or finer, and its interval is the
    Gaussian's ±1 σ to within that spacing (a deterministic grid: the tolerance is the
    spacing, not a Monte Carlo error)."""
    sigma = 0.01
    problem = Analytic(centre=[1.0, 1.0, 1.137], sigma=[3.0, 3.0, sigma])
    _, final = refine(problem, budget=600)
    coords, mass = marginal(final, 2)
    low, high = intervals(coords, mass)[0.68]
    spacing = np.min(np.diff(coords))
    assert spacing < 2.0 * sigma
    assert high - low == pytest.approx(2 * 0.994 * sigma, abs=spacing)
    assert 0.5 * (low + high) == pytest.approx(1.137, abs=spacing)
    assert problem.points <= 600 * 5            # nodes + four rounds at most


@pytest.mark.parametrize("sigma, points", [(3.0, 3 + 24), (0.01, 3 + 24 + 24)])
def test_one_free_key_is_resolved_in_a_few_dozen_points(sigma, points):
    """One free key (the others fixed with --fix): each round gave the narrow axis all 600
    points of the budget, 600 model evaluations where a few dozen resolve it (a 1-D
    inversion of 8 BELA shots of a clipped slab took a minute). A round now makes the axis
    at most four times finer than its span's spacing, with at least 24 points, and the next
    round refines it again where that is not enough: a broad posterior is resolved by the
    first round, one 1 % of the node spacing wide by the second. Its 68 % interval is the
    Gaussian's ±1 σ within the grid's spacing (a deterministic grid: the tolerance is the
    spacing, not a Monte Carlo error)."""
    problem = Analytic(centre=[1.137], sigma=[sigma], nodes=NODES[:1])
    _, final = refine(problem, budget=600)
    coords, mass = marginal(final, 0)
    assert problem.points == points
    assert float(np.max(mass)) <= 0.5 and coords.size >= 6         # resolved
    if sigma < 1.0:
        low, high = intervals(coords, mass)[0.68]
        spacing = np.min(np.diff(coords))
        assert spacing < 1.25 * sigma
        assert high - low == pytest.approx(2 * 0.994 * sigma, abs=spacing)
        assert 0.5 * (low + high) == pytest.approx(1.137, abs=spacing)


class Ridge:
    """An analytic log L over a 7-node axis u and a 4-node axis w: a narrow key u (σ 0.002)
    whose error is taken up by w along a ridge, w = w0 + 8 (u − u0) (σ 0.05 across it), as a
    slab's floor albedo takes up a thickness read a little off its peak."""

    def __init__(self, u0, w0):
        self.u0, self.w0 = u0, w0
        self.space = SimpleNamespace(free_axes=[
            SimpleNamespace(nodes=np.linspace(0.0, 1.5, 7)),
            SimpleNamespace(nodes=np.array([0.05, 0.15, 0.3, 0.45]))])

    def grid(self, coords, jobs=1):
        u, w = np.meshgrid(*coords, indexing="ij")
        z = ((u - self.u0) / 0.002) ** 2 + ((w - self.w0 - 8.0 * (u - self.u0)) / 0.05) ** 2
        return GridPosterior(list(coords), -0.5 * z)


def test_a_mode_the_nodes_misplace_is_still_reached():
    """At the nodes the narrow key is read a quarter cell off its peak, so the best node puts
    the broad key near 0.05 while its truth is 0.41. The first refined grid spans the nodes
    around that best one, [0.05, 0.3]; each later grid covered only the box of the one before,
    so the mode above 0.3 was never evaluated again and the 95 % interval of w ended below
    0.3 (a rough CO2 slab's albedo, docs/inversion.md §7.7). The box now goes on to the next
    node wherever it reaches an end of its grid that is not the prior's: w's 95 % interval
    holds 0.41 (its posterior sd is 0.05; the grid's spacing is the tolerance)."""
    problem = Ridge(u0=0.5906, w0=0.41)
    _, final = refine(problem, budget=600)
    coords, mass = marginal(final, 1)
    iv = intervals(coords, mass)
    assert iv[0.95][0] <= 0.41 <= iv[0.95][1]
    assert iv[0.5] == pytest.approx(0.41, abs=0.05)
