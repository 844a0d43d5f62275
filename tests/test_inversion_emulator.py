"""The database's own error in the likelihood (docs/inversion.md §4.3,
warpe_cl/inversion/emulator.py): its Monte Carlo part against the exact propagation of the
nodes' standard errors, what the common amplitude absorbs, and log L through a database
against log L of the surface itself at a point between the nodes.

Deterministic: the synthetic surfaces (tests/conftest.py) carry no Monte Carlo noise, and the
shots are drawn with fixed seeds.
"""
from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from conftest import sweep_of, synthetic_database, synthetic_surface
from warpe_cl.instrument import apply_instrument, load_instrument
from warpe_cl.inversion.agreement import agreement
from warpe_cl.inversion.counting import CountShots
from warpe_cl.inversion.emulator import Emulator, integrate_blocks, response_variance, shared_error
from warpe_cl.inversion.forward import Forward
from warpe_cl.surface import SurfaceResponse, response
from warpe_cl.inversion.space import Space

KEY = "medium.thickness"


@pytest.fixture(scope="module")
def bela():
    return Forward(load_instrument("bela"))


@pytest.mark.parametrize("tau", [0.5, 5.0, 50.0])
def test_monte_carlo_variance_matches_the_exact_propagation(bela, tau):
    """Var μ(t) of a response with 5 % standard errors per log bin against the exact sum over
    log bins of (the waveform of one bin's standard error)²: the correlation count c_b of
    the module docstring is exact for bins much narrower or much wider than the kernel, and
    within a factor 2.1 between (the 50 ns tail, where bins are as wide as the kernel; 7 %
    in total)."""
    ds = synthetic_surface(diffuse_integral=0.05, tau=tau)
    ds["reflectance_stderr"] = 0.05 * ds["reflectance"]
    s = response(ds)
    approx = response_variance(s, bela)
    exact = np.zeros_like(approx)
    for b in np.nonzero(s.diffuse_stderr > 0)[0]:
        one = np.where(np.arange(s.diffuse.size) == b, s.diffuse_stderr[b], 0.0)
        exact += bela.waveform(bela.photons(SurfaceResponse(s.edges, one, [],
                                                            s.wavelength)), 0.0)[0] ** 2
    seen = exact > 1e-3 * exact.max()
    ratio = approx[seen] / exact[seen]
    assert ratio.min() > 0.999 and ratio.max() < 2.1
    assert abs(approx.sum() / exact.sum() - 1.0) < 0.08


def test_return_variance_is_binomial(bela):
    """A specular return of fraction f from N rays: Var μ = (∂μ/∂f)² f (1 − f) / N."""
    f, n = 2e-5, 1e5
    ds = synthetic_surface(f_spec=f, photons=int(n))
    s = response(ds)
    dmu = bela.waveform(bela.photons(SurfaceResponse(s.edges, 0 * s.diffuse,
                                                     [("specular", 0.0, 1.0)], s.wavelength)),
                        0.0)[0]
    got = response_variance(s, bela)
    np.testing.assert_allclose(got.max(), (dmu ** 2).max() * f * (1 - f) / n, rtol=2e-3)


def _shots(forward, surface_ds, shots=200, seed=11):
    rec = apply_instrument(surface_ds, forward.params, shots=shots, seed=seed)
    return rec["sample_time"].values, rec["signal_mv"].values


def mixture(x: float):
    """A surface whose slow share p(x) (decay 8 ns, the rest 0.5 ns) is a parabola in ln x
    through p(1) = 0.1, p(2) = 0.5, p(4) = 0.2: displacement interpolation between nodes
    of it errs, and the error's curvature is what leaving one out measures."""
    u = np.log(x) / np.log(2.0)
    p = 0.1 + 0.55 * u - 0.15 * u * u
    fast = synthetic_surface(diffuse_integral=0.05 * (1 - p), tau=0.5)
    fast["reflectance"] = fast["reflectance"] + synthetic_surface(
        diffuse_integral=0.05 * p, tau=8.0)["reflectance"]
    return fast


def mixture_database(nodes=(1.0, 2.0, 4.0)):
    return sweep_of([mixture(x) for x in nodes], np.asarray(nodes) * 1e-3, KEY)


@pytest.mark.parametrize("x", [1.4, 2.8])
def test_log_likelihood_through_the_database_agrees_within_its_stated_error(bela, x):
    """Nodes at 1, 2, 4 of :func:`mixture` and the surface itself between them (no Monte
    Carlo noise: only the interpolation errs): log L through the database, less its expected
    offset, lies within 3 stated errors of log L of the surface itself (z is N(0, 1) where
    the stated error holds: |z| > 3 once in 370), at 100 and 1000 shots; and the stated error
    is not vacuous (it is below 30 log-likelihood units)."""
    space = Space(mixture_database())
    surface_ds = mixture(x)
    for shots in (100, 1000):
        t, x_mv = _shots(bela, surface_ds, shots=shots, seed=5)
        out = agreement(space, bela, t, x_mv, {KEY: x * 1e-3}, response(surface_ds))
        assert abs(out["z"]) < 3.0, out
        assert 0.0 < out["sigma"] < 30.0, out


def test_the_emulator_has_no_interpolation_error_at_a_node(bela, tmp_path):
    """At a node the interpolation error is 0 and only the node's own Monte Carlo variance
    remains (none for a synthetic node)."""
    db = xr.open_dataset(synthetic_database(tmp_path / "db.nc", taus=(1.0, 2.0, 4.0)))
    emulator = Emulator(Space(db), bela)
    assert not np.any(emulator.variance({KEY: 2e-3}))
    assert np.any(emulator.variance({KEY: 2.8e-3}))


def test_adequacy_with_a_key_fixed_between_nodes(bela):
    """A second axis (compacity, three copies of the same surfaces) free and the thickness
    fixed between its nodes: the adequacy advice reads the fixed value (it once looked it up
    among the free keys only and raised KeyError), and the interpolation part of the fixed
    axis' cell is counted."""
    from warpe_cl.inversion.invert import invert
    from warpe_cl.inversion.observed import Observed
    one = mixture_database()
    parts = []
    for c in (0.2, 0.4, 0.6):
        part = one.copy()
        part["scenario_key"] = one["scenario_key"] + int(c * 1000)
        parts.append(part.assign_coords({"medium.compacity": (
            "scenario", [c] * one.sizes["scenario"], {"sweep_key": "medium.compacity",
                                                      "units": "1"})}))
    db = xr.concat(parts, dim="scenario", data_vars="different", compat="equals")
    db["time_edges"] = one["time_edges"]
    t, x = _shots(bela, mixture(2.8), shots=300, seed=5)
    fit = invert(Observed("mv", t, x, "test", "bela"), db, "bela",
                 fix={KEY: "2.8 mm"}, budget=30)
    assert "halved spacing of medium.thickness around 0.0028" in fit.attrs["database_adequacy"]
    assert float(fit["loglike_database_sd_interpolation"]) > 1.0


def _dense_integral(w_b, g_b, s_b, base):
    """The block integral of :func:`~warpe_cl.inversion.emulator.integrate_blocks` the
    direct way: the projected W, the eigenvalues of S^½ W_eff S^½ and the sums over them."""
    wb = w_b[:, None] * base
    w_eff = np.diag(w_b) - wb @ np.linalg.lstsq(base.T @ wb, wb.T, rcond=None)[0]
    g_eff = g_b - wb @ np.linalg.lstsq(base.T @ wb, base.T @ g_b, rcond=None)[0]
    root = np.sqrt(s_b)
    lam, vec = np.linalg.eigh(root[:, None] * w_eff * root[None, :])
    lam = np.clip(lam, 0.0, None)
    proj = vec.T @ (root * g_eff)
    return (0.5 * np.sum(proj ** 2 / (1.0 + lam)) - 0.5 * np.sum(np.log1p(lam)),
            np.sqrt(np.sum(lam) + 0.5 * np.sum(lam ** 2)), -0.5 * np.sum(lam))


@pytest.mark.parametrize("blocks", [3, 12, 60])
def test_block_integral_in_linear_time_equals_the_eigen_sums(blocks):
    """integrate_blocks (Woodbury and the determinant lemma, O(blocks)) against the dense
    eigen-decomposition it replaces, on random blocks (some with S = 0) and on directions
    the blocks cannot tell apart (a singular projection)."""
    rng = np.random.default_rng(blocks)
    w, g, s = rng.uniform(0.1, 10.0, blocks), rng.normal(0.0, 3.0, blocks), \
        rng.uniform(0.0, 2.0, blocks)
    s[::4] = 0.0
    for base in (rng.normal(size=(blocks, 2)), np.ones((blocks, 2))):
        np.testing.assert_allclose(integrate_blocks(w, g, s, base),
                                   _dense_integral(w, g, s, base), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("x", [1.4, 2.8])
def test_photon_counts_through_the_database_agree_within_the_stated_error(x):
    """As for linear-mode samples: ATLAS's receiver (moved to the database's 1064 nm), the
    nodes at 1, 2, 4 of :func:`mixture` and the surface itself between them; log L through
    the database, less its expected offset, within 3 stated errors of log L of the surface
    itself at 100 and 1000 shots, and the stated error not vacuous."""
    atlas = Forward(load_instrument("atlas", {"wavelength": "1064 nm"}))
    space = Space(mixture_database())
    surface_ds = mixture(x)
    for shots in (100, 1000):
        rec = apply_instrument(surface_ds, atlas.params, shots=shots, seed=5)
        out = agreement(space, atlas, rec["sample_time"].values, rec["signal_counts"].values,
                        {KEY: x * 1e-3}, response(surface_ds))
        assert abs(out["z"]) < 3.0, out
        assert 0.0 < out["sigma"] < 30.0, out


def test_photon_counts_with_the_amplitude_fixed_keep_the_error_along_the_model():
    """Photon counts have no per-shot amplitude: with ``--fix amplitude`` nothing absorbs a
    database error along the model λ, so the stated error is larger than with A fitted
    (where the error along λ is projected out), never smaller."""
    atlas = Forward(load_instrument("atlas", {"wavelength": "1064 nm"}))
    space = Space(mixture_database())
    surface_ds = mixture(1.4)
    rec = apply_instrument(surface_ds, atlas.params, shots=1000, seed=5)
    shots = CountShots(rec["sample_time"].values, rec["signal_counts"].values, atlas)
    point = {KEY: 1.4e-3}
    mu, _ = atlas.waveform(atlas.photons(space.surface(point)), 0.0)
    fit = shots.fit(mu)
    variance = Emulator(space, atlas).variance(point)
    free = shared_error(shots, fit, mu, None, variance, amplitude_free=True)
    held = shared_error(shots, fit, mu, None, variance, amplitude_free=False)
    assert held[1] > free[1] > 0.0
