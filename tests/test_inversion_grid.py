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

    def __init__(self, centre, sigma):
        self.centre, self.sigma = np.asarray(centre), np.asarray(sigma)
        self.space = SimpleNamespace(free_axes=[SimpleNamespace(nodes=n) for n in NODES])
        self.points = 0

    def grid(self, coords):
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

