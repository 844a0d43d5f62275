"""The checks of docs/physics.md §8 on the OpenCL kernel (single precision, the default).

Every Monte Carlo assertion carries its tolerance: 5 standard errors of the estimate (binomial
for fractions), i.e. a false-alarm rate of about 6e-7 per assertion.
"""
from __future__ import annotations

import numpy as np
import pytest

from conftest import LAMBDA, LOG_EDGES, binomial_sigma, medium
from warpe_cl import radiative
from warpe_cl.params import C_M_PER_NS
from warpe_cl.tally import reduce_counts

CO2 = dict(n=1.4026, k=8.47e-10)
H2O = dict(n=1.30042, k=1.272e-6)


@pytest.mark.parametrize("kw", [
    dict(texture="slab", bottom_interface="fresnel"),
    dict(texture="slab", bottom_interface="none"),
    dict(texture="granular"),
    dict(texture="slab", extinction=2000.0, omega=0.999, max_time=0.05),
    dict(texture="granular", extinction=5000.0, omega=1.0, albedo=1.0, max_flights=50),
])
def test_energy_closure(engine, kw):
    """§8.1: fates sum to the launched rays exactly; exits are tallied once each."""
    c = engine.run(medium(**kw), 100_000)
    assert c.fates.sum() == c.photons == 100_000
    assert c.total.sum() == c.fates[0] + c.fates[1]
    assert c.angular.sum() == c.total.sum()
    assert np.all(c.time_any.sum(axis=1) <= c.total)
    assert np.all(c.time_in_fov <= c.time_any)


@pytest.mark.slow
@pytest.mark.parametrize("n,k", [(1.4026, 8.47e-10), (1.30042, 1.272e-6), (1.92, 0.2)])
def test_specular_fraction_is_r0(engine, n, k):
    """§8.8: the specular fraction is R0(n_eff, k_eff)."""
    N = 1_000_000
    c = engine.run(medium(n=n, k=k), N)
    r0 = radiative.normal_reflectance(n, k)
    assert abs(c.fates[0] / N - r0) < 5 * binomial_sigma(r0, N)
    # t = 0, before the first edge (1e-6 ns): early exits, in no time bin (walk.md §4)
    assert c.total[0] == c.fates[0] and c.early[0] == c.fates[0] and c.time_any[0].sum() == 0


@pytest.mark.slow
def test_pure_slab_bf_direct_series_and_peak_times(engine):
    """§8.2 and §8.8: with omega = 0 and A = 0 there is no diffuse return, and the BF-direct
    peaks k = 1, 2, 3 sit exactly at t_k = 2 k h n / c with amplitudes
    (1 - R0)^2 R0^(2k-1) exp(-2 k tau0)."""
    n, k, h, tau0 = 1.92, 9.5e-6, 0.5, 0.05
    N = 2_000_000
    t1 = 2 * h * n / C_M_PER_NS
    # one narrow bin around each t_k (+-1e-5 relative: float32 paths of a few metres)
    edges = np.sort(np.concatenate([[0.0, 1e6], [t1 * kk * (1 + s) for kk in (1, 2, 3)
                                                 for s in (-1e-5, 1e-5)]]))
    p = medium(texture="slab", thickness=h, extinction=tau0 / h, omega=0.0, n=n, k=k, albedo=0.0,
               time_edges=edges)
    c = engine.run(p, N)
    assert c.total[2] == 0 and c.total[3] == 0
    r0 = radiative.normal_reflectance(n, k)
    r0_inside = float(radiative.fresnel_internal(1.0, n))
    t_in = 1 - r0
    series = 0.0
    for kk in (1, 2, 3):
        amp = t_in * (1 - r0_inside) * r0_inside ** (2 * kk - 1) * np.exp(-2 * kk * tau0)
        series += amp
        count = c.time_any[1, 2 * kk - 1]          # the bin [t_k(1-1e-5), t_k(1+1e-5))
        assert abs(count / N - amp) < 5 * binomial_sigma(amp, N), kk
    # nothing outside the narrow bins
    assert c.time_any[1].sum() == c.time_any[1, [1, 3, 5]].sum()
    full = t_in * (1 - r0_inside) * r0_inside * np.exp(-2 * tau0) / (
        1 - r0_inside ** 2 * np.exp(-2 * tau0))
    assert abs(c.total[1] / N - full) < 5 * binomial_sigma(full, N)
    assert series == pytest.approx(full, rel=1e-6)


def test_pure_slab_bf_direct_times_exact_in_double(engine):
    """§8.8 per ray: every BF-direct exit time equals 2 k h n / c (double precision, 1e-12)."""
    n, h = 1.92, 0.5
    p = medium(texture="slab", thickness=h, extinction=0.1, omega=0.0, n=n, k=0.0, albedo=0.0)
    c = engine.run(p, 200_000, precision="double", records=True)
    t = c.records["time_ns"][c.records["component"] == 1]
    t1 = 2 * h * n / C_M_PER_NS
    kk = np.rint(t / t1)
    assert kk.min() >= 1 and (kk >= 2).sum() > 100
    np.testing.assert_allclose(t, kk * t1, rtol=1e-12)


@pytest.mark.slow
def test_co2_slab_paper_values(engine):
    """§8 table: the pure CO2 slab of 1 m, A = 0.15: BF direct 0.02600 (first peak) and the
    BF diffuse of the first pass in the 3-degree FOV.

    The first pass (floor reached once through the slab; arrival in [t1, 1.5 t1)) reads
    (A/pi)(1 - R0)^4 exp(-2 tau0) / (1 - A S_e) sr^-1: the 0.0418 of docs/physics.md §6.1 times the
    zero-delay floor/slab inter-reflections of the gap, 1/(1 - A S_e) = 1.0117 (S_e = 0.0772),
    which the walk of §5.5 contains. Projected solid angle (pi sin^2 theta), so that a
    Lambertian radiance factor is read exactly.
    """
    h = 1.0
    tau0 = 4 * np.pi * CO2["k"] * h / LAMBDA
    t1 = 2 * h * CO2["n"] / C_M_PER_NS
    N = 20_000_000
    edges = np.array([0.0, 0.99 * t1, 1.5 * t1, 1e6])
    p = medium(texture="slab", thickness=h, extinction=tau0 / h, omega=0.0, albedo=0.15,
               time_edges=edges, **CO2)
    c = engine.run(p, N)
    r0 = radiative.normal_reflectance(**CO2)
    bf1 = (1 - r0) ** 2 * r0 * np.exp(-2 * tau0)
    assert bf1 == pytest.approx(0.025999, abs=2e-6)
    count_bf1 = c.time_any[1, 1]
    assert abs(count_bf1 / N - bf1) < 5 * binomial_sigma(bf1, N)

    s_e = radiative.hemispherical_external(**CO2)
    rho = 0.15 / np.pi * (1 - r0) ** 4 * np.exp(-2 * tau0)
    assert rho == pytest.approx(0.0418, abs=1e-4)
    cone = np.pi * np.sin(np.radians(3.0)) ** 2
    p_cone = rho / (1 - 0.15 * s_e) * cone
    measured = c.time_in_fov[2, 1] / N
    assert abs(measured - p_cone) < 5 * binomial_sigma(p_cone, N)
    arrays = reduce_counts(c, p, solid_angle="projected")
    r_first = arrays["reflectance"][2, 1] * (edges[2] - edges[1])
    assert r_first == pytest.approx(measured / cone)


@pytest.mark.slow
def test_bright_floor_first_pass_includes_gap_interreflections(engine):
    """As above with A = 0.9, where the gap term 1/(1 - A S_e) = 1.075 is well above the
    statistical error: the walk's floor loop (docs/physics.md §5.5) is what the formula sums."""
    h, n = 1.0, 1.4026
    t1 = 2 * h * n / C_M_PER_NS
    N = 10_000_000
    p = medium(texture="slab", thickness=h, extinction=0.0, omega=0.0, n=n, k=0.0, albedo=0.9,
               time_edges=np.array([0.0, 0.99 * t1, 1.5 * t1, 1e6]))
    c = engine.run(p, N)
    r0 = radiative.normal_reflectance(n)
    s_e = radiative.hemispherical_external(n)
    cone = np.pi * np.sin(np.radians(3.0)) ** 2
    p_cone = 0.9 / np.pi * (1 - r0) ** 4 / (1 - 0.9 * s_e) * cone
    assert abs(c.time_in_fov[2, 1] / N - p_cone) < 5 * binomial_sigma(p_cone, N)
    without_gap = 0.9 / np.pi * (1 - r0) ** 4 * cone
    assert abs(c.time_in_fov[2, 1] / N - without_gap) > 5 * binomial_sigma(without_gap, N)


def test_conservative_granular_layer_returns_everything(engine):
    """§8.3: omega = 1 and A = 1 in a granular layer: every ray escapes."""
    p = medium(texture="granular", extinction=500.0, omega=1.0, albedo=1.0, g=0.8)
    c = engine.run(p, 100_000)
    assert c.fates[1] == c.photons


@pytest.mark.slow
@pytest.mark.parametrize("kw", [dict(texture="granular"),
                                dict(texture="slab", bottom_interface="fresnel"),
                                dict(texture="slab", bottom_interface="none")])
def test_bare_lambertian_floor_reads_a_over_pi(engine, kw):
    """tau0 = 0 and n = 1: only the floor is seen; its angular reflectance is A/pi in every 1-degree
    bin (each within 5 of its binomial standard errors), and with the projected solid angle the
    3-degree FOV reflectance integrates to A/pi too."""
    N, A = 2_000_000, 0.5
    p = medium(extinction=0.0, omega=0.0, n=1.0, k=0.0, albedo=A, **kw)
    c = engine.run(p, N)
    arrays = reduce_counts(c, p, solid_angle="projected")
    e = np.radians(np.arange(91))
    band = np.diff(np.sin(e) ** 2)
    p_bin = A * band
    sigma = np.sqrt(p_bin * (1 - p_bin) / N) / (np.pi * band)
    assert np.all(np.abs(arrays["angular_reflectance"][2] - A / np.pi) < 5 * sigma)
    p_fov = A * np.sin(np.radians(3.0)) ** 2
    integrated = (arrays["reflectance"][2] * np.diff(LOG_EDGES)).sum()
    assert abs(integrated - A / np.pi) < 5 * binomial_sigma(p_fov, N) / (
        np.pi * np.sin(np.radians(3.0)) ** 2)


def test_time_cap_and_flight_cap_terminate_and_are_counted(engine):
    """A ray still inside at max_time, or after max_flights, is `terminated`; no exit is later
    than max_time."""
    p = medium(texture="granular", extinction=5000.0, omega=1.0, albedo=1.0, max_time=0.02)
    c = engine.run(p, 20_000, records=True)
    assert c.fates[4] > 0 and c.fates.sum() == c.photons
    t = c.records["time_ns"][c.records["fate"] == 1]
    assert t.max() <= 0.02
    q = medium(texture="granular", extinction=5000.0, omega=1.0, albedo=1.0, max_flights=5)
    d = engine.run(q, 20_000, records=True)
    assert d.fates[4] > 0
    assert d.records["n_scat"][d.records["fate"] == 1].max() <= 4


def test_paper_numbers():
    """§8 table: tau0 = 4 pi k h / lambda, the 'analytical solutions', t1 and the 1335 mm."""
    tau_h2o = 4 * np.pi * H2O["k"] * 1.0 / LAMBDA
    tau_co2 = 4 * np.pi * CO2["k"] * 1.0 / LAMBDA
    assert tau_h2o == pytest.approx(15.023, abs=1e-3)
    assert tau_co2 == pytest.approx(0.010003, abs=1e-6)
    for (nk, tau, value) in ((H2O, tau_h2o, 1.4728e-15), (CO2, tau_co2, 0.025999)):
        r0 = radiative.normal_reflectance(**nk)
        assert (1 - r0) ** 2 * r0 * np.exp(-2 * tau) == pytest.approx(value, rel=2e-4)
    assert radiative.first_bf_time(1.0, CO2["n"]) == pytest.approx(9.357, abs=1e-3)
    assert 12.5 * C_M_PER_NS / (2 * CO2["n"]) == pytest.approx(1.3359, abs=1e-4)
