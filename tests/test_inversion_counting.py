"""Photon-counting inversion (docs/inversion.md §4.2): ATLAS-like time-tag histograms against
a synthetic database at 532 nm (the delay τ of R_d ∝ exp(−t/τ) stands for the swept
``medium.thickness``, as in tests/test_inversion.py)."""
from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from scipy.optimize import minimize_scalar

from conftest import synthetic_surface
from warpe_cl.cli import main
from warpe_cl.instrument import apply_instrument, load_instrument
from warpe_cl.inversion.counting import CountShots, _nonnegative, pearson
from warpe_cl.inversion.emulator import Emulator, shared_error
from warpe_cl.inversion.space import Space
from warpe_cl.inversion.forward import Forward
from warpe_cl.inversion.invert import invert
from warpe_cl.inversion.observed import Observed
from warpe_cl.surface import response

KEY = "medium.thickness"
TAUS = np.array([0.5, 1.0, 2.0, 4.0, 8.0, 16.0])      # ns


def database(integral=0.05):
    parts = [synthetic_surface(diffuse_integral=integral, tau=t, wavelength="532 nm")
             for t in TAUS]
    ds = xr.concat(parts, dim="scenario", data_vars="different", compat="equals")
    ds["time_edges"] = parts[0]["time_edges"]
    ds = ds.assign_coords({KEY: ("scenario", TAUS * 1e-3, {"sweep_key": KEY, "units": "m"})})
    ds["scenario_key"] = ("scenario", np.arange(TAUS.size) + 100)
    return ds


def observation(tau, shots=100, seed=1, overrides=None):
    surface = synthetic_surface(diffuse_integral=0.05, tau=tau, wavelength="532 nm")
    return apply_instrument(surface, "atlas", overrides, shots=shots, seed=seed)


@pytest.mark.parametrize("overrides", [
    {"detector.timing_jitter": "0 ns"},
    {"detector.timing_jitter": "0 ns", "speckle.modes": 2},
    {"detector.timing_jitter": "0 ns", "detector.analog_dead_time": "0 ns"},
    {},
    {"speckle.modes": 2, "background.count_rate": "20 MHz"}])
def test_count_model_is_the_chains_expected_recorded_counts(overrides):
    """The model's counts per bin at amplitude 1 and arrival 0 are the chain's
    ``expected_recorded_counts``: dead time (here 31 % of a bright surface's photons, 39 %
    with two speckle modes), speckle and jitter. Without jitter they agree to rounding; with
    it the model convolves the fine grid with a Gaussian kernel of the fine step h, the chain
    integrates each fine bin's Gaussian spread exactly: a difference of order h²/12 against
    the pulse's variance σ_p² (1.6 ns FWHM) on the peak, 4.5e-4 of it."""
    params = load_instrument("atlas", overrides)
    surface = synthetic_surface(diffuse_integral=0.5, tau=2.0, wavelength="532 nm")
    obs = apply_instrument(surface, "atlas", overrides, shots=2, seed=1)
    f = Forward(params)
    mu, nu = f.waveform(f.photons(response(surface)), 0.0)
    assert nu is None
    shots = CountShots(obs["sample_time"].values, obs["signal_counts"].values, f)
    model = shots.expected(mu, 1.0, 0.0)
    chain = obs["expected_recorded_counts"].values
    if params["detector.analog_dead_time"] > 0:
        assert float(obs["dead_time_loss"]) > 0.3        # a test of the dead time indeed
    jittered = params["detector.timing_jitter"] > 0
    bound = f.step ** 2 / 12.0 / f.sigma_p ** 2 if jittered else 1e-9
    # the chain draws no arrival outside its window: within τ_a + 8 σ_j of either end its
    # dark counts see less dead time and lose their jitter's spill; the model's arrivals,
    # like an instrument's, go on (docs/inversion.md §4.2)
    t = obs["sample_time"].values
    edge = params["detector.analog_dead_time"] + 8.0 * params["detector.timing_jitter"]
    inner = (t >= t[0] + edge) & (t + f.interval <= t[-1] + f.interval - edge)
    assert inner.sum() > 0.9 * t.size
    np.testing.assert_allclose(model[inner], chain[inner], rtol=0, atol=bound * chain.max())


def test_photon_counts_hold_the_truth_off_the_grid():
    """τ = 2.8 ns from 100 ATLAS shots (1.7 photons each): the 95 % interval holds it
    (2.46-3.66 ns for this seed; 5 of 5 seeds held it at 95 %, 4 of 5 at 68 %) and excludes
    the far nodes."""
    obs = observation(2.8)
    fit = invert(Observed("counts", obs["sample_time"].values, obs["signal_counts"].values,
                          "atlas", "atlas"), database(), "atlas")
    r = fit.sel(parameter=KEY)
    assert float(r["low95"]) <= 2.8e-3 <= float(r["high95"])
    assert float(r["low95"]) > 1.0e-3 and float(r["high95"]) < 8.0e-3
    assert "fit_counts" in fit and "observed_counts" in fit and "fit_mv" not in fit
    assert int(fit["dof"]) > 0 and 0.0 <= float(fit["p_value"]) <= 1.0


def bright_observation(tau, shots, seed):
    """ATLAS over a bright surface: 17 photons per shot, 28 % of them lost to dead time."""
    surface = synthetic_surface(diffuse_integral=0.5, tau=tau, wavelength="532 nm")
    return apply_instrument(surface, "atlas", None, shots=shots, seed=seed)


def test_a_bright_surface_is_recovered_through_the_dead_time():
    """1000 ATLAS shots over a bright surface (τ = 2.8 ns, off the nodes; the dead time takes
    28 % of the photons): the 95 % interval holds the truth, the fit is good and the amplitude
    is 1 within 5 σ_A. σ_A ≈ 0.7⁻¹ / √12400: the recorded photons' relative error, 0.9 %,
    over d ln(recorded)/d ln A ≈ 0.7 at this loss: 0.013, 5 σ = 0.065. The likelihood that
    left the dead time out read A = 0.73 and 95 % [3.05, 3.19] ns with p = 0 for this seed;
    with the database's error integrated at 1/M per bin alone, the grid's first node
    (0.5 ns, its ln L 27000 below) ranked first."""
    obs = bright_observation(2.8, 1000, 2)
    assert float(obs["dead_time_loss"]) > 0.25
    fit = invert(Observed("counts", obs["sample_time"].values, obs["signal_counts"].values,
                          "atlas", "atlas"), database(0.5), "atlas")
    r = fit.sel(parameter=KEY)
    assert float(r["low95"]) <= 2.8e-3 <= float(r["high95"])
    assert float(r["high95"]) - float(r["low95"]) < 0.5e-3
    assert float(fit["p_value"]) > 1e-3
    assert abs(float(fit["amplitude"]) - 1.0) < 5 * 0.013


def test_the_database_error_gains_no_more_than_the_counts_allow():
    """Integrating the database's error out can raise log L at most as far as moving every
    bin's mean to its counts would, Σ c log(c/M) − (c − M): each bin's quadratic gain
    ½ (c − M)² / max(c, M) is below it. A model far off (τ = 0.5 ns for a 2.8 ns surface,
    at the narrower pulse the fit of v had reached) gained 47400 there with 1/M per bin, 3000
    beyond the ceiling, and ranked above the truth."""
    obs = bright_observation(2.8, 1000, 2)
    f = Forward(load_instrument("atlas"))
    shots = CountShots(obs["sample_time"].values, obs["signal_counts"].values, f)
    space = Space(database(0.5))
    point = {KEY: 0.5e-3}
    mu, _ = f.waveform(f.photons(space.surface(point)), -0.346)
    fit = shots.fit(mu)
    gain, _, _ = shared_error(shots, fit, mu, None, Emulator(space, f).variance(point))
    m = shots.n * shots.expected(mu, fit.overall, fit.arrival[0])
    c = shots.c
    m = np.maximum(m, 1e-300)
    ceiling = float(np.sum(np.where(c > 0, c * np.log(np.where(c > 0, c, 1.0) / m), 0.0)
                           - (c - m)))
    assert 0.0 < gain <= ceiling


def test_a_weak_return_in_daylight_keeps_its_amplitude():
    """1000 ATLAS shots of a dim surface (34 recorded signal counts in all) under a 10 MHz
    background: the window's net counts are negative (−26) and its highest bin is
    background. The fit's amplitude at its arrival is the exact profile's (1-D maximum of the
    expected recorded counts' Poisson log L, to 1e-3), near 0.88, and the return is seen:
    log L 5 above background alone. Started from the window's net counts the amplitude
    stayed at 1e-9 (background only); centred on the highest bin the arrival scan missed
    the return (A 0.24, 21 ns away)."""
    overrides = {"background.count_rate": "10 MHz"}
    surface = synthetic_surface(diffuse_integral=0.001, tau=2.8, wavelength="532 nm")
    obs = apply_instrument(surface, "atlas", overrides, shots=1000, seed=1)
    f = Forward(load_instrument("atlas", overrides))
    mu, _ = f.waveform(f.photons(response(surface)), 0.0)
    shots = CountShots(obs["sample_time"].values, obs["signal_counts"].values, f)
    assert shots.c.sum() - shots.n * shots.b * shots.c.size < 0
    fit = shots.fit(mu)
    d = float(fit.arrival[0])

    def loglike(a):
        m = shots.n * shots.expected(mu, a, d)
        return float(np.sum(shots.c * np.log(np.maximum(m, 1e-300)) - m))
    best = minimize_scalar(lambda x: -loglike(np.exp(x)), bounds=(-20.0, 3.0),
                           method="bounded", options={"xatol": 1e-8})
    assert fit.overall == pytest.approx(float(np.exp(best.x)), rel=1e-3)
    assert 0.5 < fit.overall < 1.5
    assert loglike(fit.overall) - loglike(1e-9) > 3.0


def test_the_start_amplitude_stays_on_the_rising_count():
    """Recording.amplitude_for: the A whose recorded photons are the target, approached from
    below. A paralyzable dead time makes the recorded count rise, stall and fall again with A
    (12.4 recorded photons per shot at A = 1 here, 24.4 at A = 10, a stall near A = 13.5):
    for a target past a stall, the A
    where the count stops rising, never one past it where it falls (Newton's step overshot
    there)."""
    f = Forward(load_instrument("atlas"))
    surface = synthetic_surface(diffuse_integral=0.5, tau=2.8, wavelength="532 nm")
    mu, _ = f.waveform(f.photons(response(surface)), 0.0)
    rec = CountShots(np.arange(3) * f.interval, np.ones((1, 3)), f).recording

    def recorded(a):
        return float(np.sum(rec.level(mu, a))) * f.step
    assert recorded(rec.amplitude_for(mu, 8.0)) == pytest.approx(8.0, rel=1e-6)
    for target in (20.0, 24.5, 25.0, 40.0, 1e3):
        a = rec.amplitude_for(mu, target)
        assert recorded(a) <= target * (1 + 1e-6)
        assert recorded(a) >= recorded(0.99 * a) - 1e-9 * target, target


def test_an_inexact_dead_time_is_said():
    """Timing channels' dead time above twice the analog one: the expected counts leave out
    their losses, and the inversion says so."""
    overrides = {"detector.digital_dead_time": "7 ns"}
    surface = synthetic_surface(diffuse_integral=0.05, tau=2.8, wavelength="532 nm")
    obs = apply_instrument(surface, "atlas", overrides, shots=50, seed=1)
    with pytest.warns(UserWarning, match="inexact dead time"):
        invert(Observed("counts", obs["sample_time"].values, obs["signal_counts"].values,
                        "atlas", "atlas"), database(), load_instrument("atlas", overrides))


def test_a_cropped_and_shifted_histogram_finds_its_return():
    """The arrival scan's centre comes from the model's counts over the whole forward grid,
    not only over the histogram's bins: a histogram whose times are moved by 30 ns and cut
    to [10, 60) ns (the return's leading edge outside it at arrival 0) gives the arrival
    30.01 ns and A 1.004, as uncut (the template over the histogram's own bins missed it:
    log L 290 below)."""
    f = Forward(load_instrument("atlas"))
    surface = synthetic_surface(diffuse_integral=0.5, tau=2.8, wavelength="532 nm")
    mu, _ = f.waveform(f.photons(response(surface)), 0.0)
    obs = bright_observation(2.8, 1000, 2)
    t, counts = obs["sample_time"].values, obs["signal_counts"].values
    whole = CountShots(t, counts, f).fit(mu)
    moved = t + 30.0
    keep = (moved >= 10.0) & (moved < 60.0)
    cut = CountShots(moved[keep], counts[:, keep], f).fit(mu)
    assert cut.arrival[0] - 30.0 == pytest.approx(whole.arrival[0], abs=0.02)
    assert cut.overall == pytest.approx(whole.overall, rel=1e-3)


def test_a_stray_count_costs_the_same_at_every_arrival():
    """Without background, one count far from the return (−15 ns) where the model expects
    only its convolution's rounding (±1e-17) costs log of NEGLIGIBLE of the largest expected
    count at every arrival, not −33 at some and −691 at the next."""
    f = Forward(load_instrument("atlas"))
    surface = synthetic_surface(diffuse_integral=0.5, tau=2.8, wavelength="532 nm")
    mu, _ = f.waveform(f.photons(response(surface)), 0.0)
    obs = bright_observation(2.8, 1000, 2)
    t, counts = obs["sample_time"].values, obs["signal_counts"].values.copy()
    plain = CountShots(t, counts, f)
    counts[0, np.argmin(np.abs(t + 15.0))] += 1
    stray = CountShots(t, counts, f)
    deltas = np.linspace(-0.3, 0.3, 81)
    a = plain.fit(mu).overall
    cost = (stray._profile(stray._rows(mu, a, deltas), a, a)[0]
            - plain._profile(plain._rows(mu, a, deltas), a, a)[0])
    assert np.ptp(cost) < 1.0


def test_an_unsettled_centre_falls_back_on_the_exact_profile():
    """Where the expansion's centre has not stayed after its moves (here 2 moves from a
    centre 20 times too low), every arrival's log L is exact at the held A (never above the
    profile) and the best arrival's is the exact profile's: the maximum over A of the
    recorded counts' Poisson log L, made anew at each A (a grid of 0.1 % steps here)."""
    f = Forward(load_instrument("atlas"))
    surface = synthetic_surface(diffuse_integral=0.5, tau=2.8, wavelength="532 nm")
    mu, _ = f.waveform(f.photons(response(surface)), 0.0)
    obs = bright_observation(2.8, 1000, 2)
    shots = CountShots(obs["sample_time"].values, obs["signal_counts"].values, f)
    deltas = np.linspace(-0.2, 0.2, 21)
    ll, a, centre = shots._scan(mu, deltas, 0.05, None, moves=2)
    top = int(np.argmax(ll))

    def exact(amplitude, delta):
        m = shots.n * shots.expected(mu, amplitude, delta)
        return float(np.sum(shots.c * np.log(np.maximum(m, 1e-300)) - m)) - shots.log_factorial
    grid = np.exp(np.linspace(np.log(0.5), np.log(2.0), 1387))
    best = max(exact(x, deltas[top]) for x in grid)
    assert ll[top] == pytest.approx(best, abs=1e-3)
    assert abs(a[top] - 1.0) < 0.05
    for i in (0, 10, 20):
        if i != top:
            assert ll[i] == pytest.approx(exact(centre, deltas[i]), abs=1e-6)


def test_the_amplitude_expansion_stays_nonnegative():
    """_nonnegative: the range of e keeping r0 + e r1 + ½ e² r2 ≥ 0 at every point."""
    r0 = np.array([1.0, 2.0, 1e-20])
    r1 = np.array([1.0, -1.0, -5.0])                # the last point is too small to count
    r2 = np.array([-1.0, 0.0, 0.0])
    lo, hi = _nonnegative(r0, r1, r2)
    assert hi == pytest.approx(2.0)                 # the second point: 2 − e = 0
    assert lo == pytest.approx(1.0 - 3.0 ** 0.5)    # the first: 1 + e − ½ e² = 0
    e = np.linspace(lo, hi, 101)
    assert (r0[:2, None] + e * r1[:2, None] + 0.5 * e * e * r2[:2, None] >= -1e-12).all()


def test_pearson_groups_bins_to_five_expected_counts():
    chi2, groups = pearson(np.array([0, 1, 6, 0, 0, 0]), np.array([0.5, 0.5, 4.0, 2.0, 2.0, 1.0]))
    # groups: [0.5+0.5+4] = 5 (observed 7), [2+2+1] = 5 (observed 0)
    assert groups == 2 and chi2 == pytest.approx((7 - 5) ** 2 / 5 + (0 - 5) ** 2 / 5)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("counts")
    observation(2.8, shots=50).to_netcdf(d / "atlas.nc", engine="h5netcdf")
    database().to_netcdf(d / "db.nc", engine="h5netcdf")
    return d


def test_cli_inverts_photon_counts_with_a_figure(files):
    out = files / "fit.nc"
    assert main(["invert", str(files / "atlas.nc"), "--database", str(files / "db.nc"),
                 "--out", str(out), "--plot", str(files / "fit.png"), "--quiet"]) == 0
    assert "fit_counts" in xr.load_dataset(out, engine="h5netcdf")
    assert (files / "fit.png").stat().st_size > 10_000


def test_counts_with_a_linear_mode_instrument_are_refused(files, capsys):
    assert main(["invert", str(files / "atlas.nc"), "--database", str(files / "db.nc"),
                 "--instrument", "bela", "--out", str(files / "x.nc")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "photon counts" in err, err
