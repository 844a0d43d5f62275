"""A point's log L is a function of the point alone (warpe_cl/inversion/posterior.py,
docs/inversion.md §5): not of the points evaluated before it, nor of the worker processes a
grid is spread over (``invert --jobs``).

The shots are BELA's of a synthetic surface of delay τ = 2.8 ns (conftest.synthetic_surface,
R_d ∝ exp(−t/τ)/τ), against the one-key database of tests/test_inversion.py: nodes from
0.5 to 16 ns, of which the thick end fits the shots very poorly (log L 300 below the best).
"""
from __future__ import annotations

import multiprocessing
import os
import sys
from concurrent.futures.process import BrokenProcessPool

import numpy as np
import pytest

from test_inversion import database, observation
from warpe_cl.inversion import posterior
from warpe_cl.inversion.forked import forked_map, workers
from warpe_cl.inversion.invert import prepare
from warpe_cl.inversion.observed import Observed
from warpe_cl.inversion.posterior import refine


@pytest.fixture(scope="module")
def problem():
    obs = observation(2.8, shots=60, seed=4)
    shots = Observed("mv", obs["sample_time"].values, obs["signal_mv"].values, "obs", "bela")
    return prepare(shots, database(), "bela").problem


def test_a_point_after_a_poor_one_has_its_own_log_l(problem):
    """Started from the fit of the point before, a shot's arrival could stay on a poor local
    optimum: the thinnest node evaluated after the thickest came out 20 lower in log L, and
    so did the next ten points of the refined grid."""
    thin, thick = (np.array([x]) for x in problem.space.free_axes[0].nodes[[0, -1]])
    alone = problem.evaluate(thin)
    problem.evaluate(thick)
    again = problem.evaluate(thin)
    assert again.loglike == alone.loglike and again.v == alone.v


def test_the_grid_is_the_same_bits_with_any_number_of_jobs(problem, monkeypatch):
    monkeypatch.setattr(posterior, "CHUNK", 4)      # the 6 nodes in two chunks too
    start = problem.count
    one = refine(problem, budget=40, jobs=1)
    counted = problem.count - start
    two = refine(problem, budget=40, jobs=2)
    assert problem.count - start == 2 * counted     # the workers' evaluations are counted
    for a, b in zip(one, two):
        assert all(np.array_equal(x, y) for x, y in zip(a.coords, b.coords))
        assert np.array_equal(a.loglike, b.loglike)
        assert a.evaluations.keys() == b.evaluations.keys()
        for key, e in a.evaluations.items():
            f = b.evaluations[key]
            assert (e.v, e.fit.overall) == (f.v, f.fit.overall)
            assert np.array_equal(e.fit.arrival, f.fit.arrival)


def test_forked_workers_return_every_piece_in_order():
    done = forked_map(lambda x: (x * x, os.getpid()), range(7), jobs=3)
    assert [x for x, _ in done] == [x * x for x in range(7)]
    if sys.platform.startswith("linux"):            # elsewhere: this process, in turn
        assert os.getpid() not in {pid for _, pid in done}
    assert forked_map(lambda x: (x, os.getpid()), [1, 2], jobs=1) == [(1, os.getpid()),
                                                                      (2, os.getpid())]


def test_the_first_arrivals_find_a_slab_echo_as_high_as_its_surface_return():
    """Every point starts from the scan of Shots.start. A 1.5 m GALA slab returns its surface
    and its first echo 13 ns apart at about the same height; by sampling phase a shot's
    highest sample is either. Scanned around the model's highest peak only, a third of the
    noiseless shots were aligned on the wrong one and log L came out near -98000 instead
    of -3303 (its value from the true arrivals)."""
    from test_inversion_delays import _noiseless, slab_database, NODES
    from warpe_cl.inversion.forward import Spectrum
    from warpe_cl.inversion.likelihood import peak_times
    obs = _noiseless("gala", 1.5, 30)
    p = prepare(obs, slab_database(NODES), "gala").problem
    u = np.array([np.log(1.5)])
    mu, nu = p.forward.waveform(Spectrum(p.forward.photons(p.space.surface(p.point(u)))))
    assert len(peak_times(p.forward.t, mu, p.forward.interval)) == 2
    p.shots.start(mu)
    fresh = p.shots.fit(mu, nu).loglike
    phases = np.linspace(0.0, p.forward.interval, 30, endpoint=False)
    p.shots.arrival, p.shots.amplitude = -phases, np.ones(30)      # the truth
    true = p.shots.fit(mu, nu).loglike
    assert abs(fresh - true) < 0.01        # the fits' own tolerance: 1e-4 a shot and step


def test_ripples_on_one_peak_are_not_peaks_of_their_own():
    from warpe_cl.inversion.likelihood import peak_times
    t = np.arange(0.0, 100.0, 0.1)
    one = np.exp(-0.5 * ((t - 40.0) / 3.0) ** 2) * (1 + 0.05 * np.sin(t * 9.0))
    assert peak_times(t, one, 5.0) == [float(t[np.argmax(one)])]
    two = one + 0.6 * np.exp(-0.5 * ((t - 60.0) / 3.0) ** 2)
    low = one + 0.4 * np.exp(-0.5 * ((t - 60.0) / 3.0) ** 2)
    assert len(peak_times(t, two, 5.0)) == 2 and len(peak_times(t, low, 5.0)) == 1
    # a 90 ns plateau with 2 % noise, smoothed over 2 ns: without the dip, ripples were peaks
    noise = np.random.default_rng(1).normal(0.0, 0.02, t.size)
    plateau = np.where((t > 5.0) & (t < 95.0), 1.0, 0.0) + noise
    assert len(peak_times(t, np.convolve(plateau, np.ones(20) / 20, "same"), 2.0)) == 1


def test_a_worker_that_dies_ends_the_map_instead_of_hanging():
    parent = os.getpid()

    def dies_in_a_worker(x):
        if os.getpid() != parent:
            os._exit(3)             # as a worker killed for memory
        return x
    if workers(2, 3):
        with pytest.raises(BrokenProcessPool):
            forked_map(dies_in_a_worker, range(3), jobs=2)
    else:                           # no fork here: the pieces run in this process
        assert forked_map(dies_in_a_worker, range(3), jobs=2) == [0, 1, 2]


def _inside_a_pool_worker(_):
    return forked_map(lambda x: x + 1, range(3), jobs=2)


def test_a_pool_worker_runs_its_pieces_itself():
    """A multiprocessing.Pool worker is daemonic and may not start processes (the studies run
    their inversions in one): its map runs in the worker."""
    with multiprocessing.Pool(1) as pool:
        assert pool.map(_inside_a_pool_worker, [0]) == [[1, 2, 3]]
