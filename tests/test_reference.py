"""Tests of the NumPy reference walk (warpe_cl/reference.py) on its own.

Every statistical assertion states its tolerance as a number of Monte Carlo standard errors,
derived next to it (counts of independent rays are binomial: sigma = sqrt(N p (1 - p))).
The seeds are fixed, so the tests are deterministic; the 5-sigma bounds say how far a correct
walk could plausibly land, not a tuned margin.
"""
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import quad

from conftest import binomial_sigma

from warpe_cl.params import C_M_PER_NS, FATES, WalkParams
from warpe_cl.reference import (external_reflectance, henyey_greenstein_cosine,
                                internal_reflectance, normal_incidence_reflectance,
                                rotate_direction, simulate_reference)
from warpe_cl.rng import photon_draws

SPECULAR, BF_DIRECT, BF_DIFFUSE, SCATTERING = range(4)
ESCAPED = FATES.index("escaped")
N_CO2 = 1.4026  # effective index of CO2 ice at 1064 nm (docs/physics.md §3.1)


def count_sigma(photons, probability):
    """Standard deviation of a binomial count, sqrt(N p (1 - p)) (p (1 - p) >= 1/N here)."""
    return photons * binomial_sigma(probability, photons)


def slab(**changes):
    """A slab scenario with sensible defaults (thickness 1 m, CO2-like index)."""
    values = dict(texture="slab", thickness=1.0, extinction=1.0, omega=0.9, g=0.8, n=N_CO2,
                  k=0.0, albedo=0.15, time_edges=np.linspace(0.0, 50.0, 101),
                  bottom_interface="fresnel", seed=17, scenario=2)
    values.update(changes)
    return WalkParams(**values)


def granular(**changes):
    values = dict(texture="granular", thickness=1.0, extinction=1.0, omega=0.9, g=0.8,
                  n=1.3, k=0.0, albedo=0.5, time_edges=np.linspace(0.0, 50.0, 101),
                  seed=23, scenario=5)
    values.update(changes)
    return WalkParams(**values)


# --------------------------------------------------------------------------------------------
# Physics helpers
# --------------------------------------------------------------------------------------------

def hapke_reflectance(mu, n, k):
    """Hapke's G1/G2 form of the complex Fresnel reflectance (docs/physics.md §3.4), to compare."""
    a = n * n - k * k - (1.0 - mu * mu)
    b = math.sqrt(a * a + 4.0 * n * n * k * k)
    g1 = math.sqrt(0.5 * (a + b))
    g2 = math.sqrt(0.5 * (-a + b))
    perpendicular = ((mu - g1) ** 2 + g2 ** 2) / ((mu + g1) ** 2 + g2 ** 2)
    n2k2 = n * n - k * k
    parallel = (((n2k2 * mu - g1) ** 2 + (2 * n * k * mu - g2) ** 2)
                / ((n2k2 * mu + g1) ** 2 + (2 * n * k * mu + g2) ** 2))
    return 0.5 * (perpendicular + parallel)


@pytest.mark.parametrize("n, k", [(1.30042, 0.0), (N_CO2, 1e-6), (2.5, 0.3), (1.3, 1.0)])
def test_external_reflectance_agrees_with_hapke_form(n, k):
    for mu in np.linspace(0.001, 1.0, 101):
        assert external_reflectance(mu, n, k) == pytest.approx(hapke_reflectance(mu, n, k),
                                                               abs=1e-12)
    assert external_reflectance(1.0, n, k) == pytest.approx(normal_incidence_reflectance(n, k),
                                                            rel=1e-12)


@pytest.mark.parametrize("n, s_e_table, s_i_table",
                         [(1.30042, 0.0612, 0.4449), (N_CO2, 0.0772, 0.5309),
                          (1.0786, 0.0205, 0.1581), (1.4764, 0.0883, 0.5817)])
def test_hemispherical_reflectances_obey_reciprocity(n, s_e_table, s_i_table):
    # docs/physics.md §3.6: S_e = ∫ R_ext 2 sinθ cosθ dθ, S_i the same with R_int (R = 1 under TIR),
    # and S_i = 1 - (1 - S_e)/n².
    def weight(theta):
        return 2.0 * math.sin(theta) * math.cos(theta)

    s_e = quad(lambda t: external_reflectance(math.cos(t), n, 0.0) * weight(t),
               0.0, math.pi / 2, limit=200)[0]
    critical = math.asin(1.0 / n)
    s_i = (quad(lambda t: internal_reflectance(math.cos(t), n) * weight(t),
                0.0, critical, limit=200)[0] + math.cos(critical) ** 2)
    assert s_i == pytest.approx(1.0 - (1.0 - s_e) / n ** 2, abs=1e-9)
    assert s_e == pytest.approx(s_e_table, abs=1e-4)  # table values quoted to 4 decimals
    assert s_i == pytest.approx(s_i_table, abs=1e-4)


def test_internal_reflectance_at_normal_incidence_is_r0():
    assert internal_reflectance(1.0, N_CO2) == pytest.approx(
        normal_incidence_reflectance(N_CO2, 0.0), rel=1e-14)


@pytest.mark.parametrize("g", [0.0, 0.3, 0.8, -0.5])
def test_henyey_greenstein_inverse_cdf_has_mean_g(g):
    # Deterministic: the midpoint rule over U of the inverse CDF integrates cos Θ exactly enough
    # (smooth integrand, 2e5 nodes: error ~ 1e-9), so the mean must be g to 1e-6.
    nodes = (np.arange(200_000) + 0.5) / 200_000
    cosines = np.array([henyey_greenstein_cosine(g, u) for u in nodes.tolist()])
    assert cosines.mean() == pytest.approx(g, abs=1e-6)
    assert cosines.min() >= -1.0 - 1e-12 and cosines.max() <= 1.0 + 1e-12


@pytest.mark.parametrize("direction", [(0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (0.6, 0.0, 0.8),
                                       (0.1, -0.7, -math.sqrt(0.5))])
def test_rotation_keeps_unit_length_and_deflects_by_theta(direction):
    for cos_theta in (-0.9, 0.0, 0.5, 0.99):
        for psi in (0.0, 1.0, 4.0):
            new = rotate_direction(*direction, cos_theta, psi)
            assert math.fsum(c * c for c in new) == pytest.approx(1.0, abs=1e-12)
            if abs(direction[2]) <= 0.99999:  # the vertical branch is exact only for |uz| = 1
                assert math.fsum(a * b for a, b in zip(direction, new)) == pytest.approx(
                    cos_theta, abs=1e-12)
            else:
                assert new[2] == pytest.approx(cos_theta * math.copysign(1.0, direction[2]))


# --------------------------------------------------------------------------------------------
# Whole walks
# --------------------------------------------------------------------------------------------

SCENARIOS = {
    "slab_fresnel": slab(),
    "slab_none": slab(bottom_interface="none", n=1.3, k=1e-3),
    "slab_time_window": slab(rule="time_window", extinction=2.0),
    "granular": granular(),
    # edges that start after t = 0 (specular goes to bin 0) and stop early (late exits get no bin)
    "slab_short_edges": slab(time_edges=np.linspace(0.5, 12.0, 24), max_time=200.0),
}


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_fates_sum_and_tallies_match_records(name):
    params = SCENARIOS[name]
    photons = 1500
    counts = simulate_reference(params, photons, records=True)
    records = counts.records
    # Energy closure (docs/physics.md §8, check 1): every ray has exactly one fate.
    assert counts.photons == photons
    assert counts.fates.sum() == photons
    assert all(len(v) == photons for v in records.values())
    np.testing.assert_array_equal(np.bincount(records["fate"], minlength=len(FATES)),
                                  counts.fates)
    assert counts.scattering_events == records["n_scat"].sum()

    exited = records["component"] >= 0
    assert np.array_equal(exited, np.isin(records["fate"], [0, ESCAPED]))
    assert np.all(np.isnan(records["time_ns"][~exited]))
    assert np.all(records["time_bin"][~exited] == -1)
    assert np.all(records["emergence_bin"][~exited] == -1)

    # The tallies rebuilt from the records (walk.md §4).
    edges = np.asarray(params.time_edges)
    n_time = len(edges) - 1
    component = records["component"][exited].astype(int)
    time_ns = records["time_ns"][exited]
    cos_exit = records["cos_exit"][exited]
    emergence = np.minimum(np.floor(np.degrees(np.arccos(np.minimum(cos_exit, 1.0)))), 89)
    np.testing.assert_array_equal(records["emergence_bin"][exited], emergence)
    time_bin = np.searchsorted(edges, time_ns, side="right") - 1
    time_bin[time_ns < edges[0]] = -2      # early: counted apart, in no bin
    time_bin[time_ns >= edges[-1]] = -1
    np.testing.assert_array_equal(records["time_bin"][exited], time_bin)
    np.testing.assert_array_equal(counts.early, np.bincount(component[time_bin == -2],
                                                            minlength=4))

    total = np.bincount(component, minlength=4)
    angular = np.zeros((4, 90), dtype=np.int64)
    np.add.at(angular, (component, emergence.astype(int)), 1)
    time_any = np.zeros((4, n_time), dtype=np.int64)
    time_in_fov = np.zeros((4, n_time), dtype=np.int64)
    binned = time_bin >= 0
    np.add.at(time_any, (component[binned], time_bin[binned]), 1)
    in_fov = binned & (cos_exit >= params.cos_fov[component])
    np.add.at(time_in_fov, (component[in_fov], time_bin[in_fov]), 1)
    np.testing.assert_array_equal(counts.total, total)
    np.testing.assert_array_equal(counts.angular, angular)
    np.testing.assert_array_equal(counts.time_any, time_any)
    np.testing.assert_array_equal(counts.time_in_fov, time_in_fov)

    # Component rule (docs/physics.md §6.1) and the mixed-history count.
    n_scat = records["n_scat"][exited]
    n_lamb = records["n_lamb"][exited]
    escaped = records["fate"][exited] == ESCAPED
    assert np.all(component[~escaped] == SPECULAR)
    direct = escaped & (n_scat == 0) & (n_lamb == 0)
    assert np.all(component[direct] == BF_DIRECT)
    diffuse = escaped & ~direct
    if params.rule == "history":
        expected = np.where(n_lamb >= 1, BF_DIFFUSE, SCATTERING)
    else:
        expected = np.where(time_ns >= params.first_bf_time, BF_DIFFUSE, SCATTERING)
    np.testing.assert_array_equal(component[diffuse], expected[diffuse])
    assert counts.mixed_history == np.sum(escaped & (n_scat >= 1) & (n_lamb >= 1))
    if params.texture == "granular":
        assert counts.fates[FATES.index("specular")] == 0
        assert records["n_bspec"].sum() == 0 and records["n_top"].sum() == 0
    if name == "slab_short_edges":
        assert np.any(time_bin == -1) and counts.total[SPECULAR] > 0


@pytest.mark.slow
def test_specular_fraction_is_r0():
    # Only the entry draw matters; a thick absorbing slab ends every entered ray quickly.
    photons = 100_000
    params = slab(extinction=50.0, omega=0.0)
    counts = simulate_reference(params, photons)
    r0 = ((N_CO2 - 1) ** 2) / ((N_CO2 + 1) ** 2)  # k = 0
    # Specular count ~ Binomial(N, R0): 5 sigma = 5 sqrt(N R0 (1 - R0)) ≈ 260 of ≈ 2808.
    assert abs(counts.fates[FATES.index("specular")] - photons * r0) <= (
        5 * count_sigma(photons, r0))
    assert counts.total[SPECULAR] == counts.fates[FATES.index("specular")]
    assert counts.angular[SPECULAR, 0] == counts.total[SPECULAR]  # θ_e = 0 exactly
    assert counts.time_any[SPECULAR, 0] == counts.total[SPECULAR]  # t = 0


@pytest.mark.slow
def test_pure_absorbing_slab_bf_direct_series_and_times():
    # docs/physics.md §8 check 2 and §6.1: omega = 0, A = 0; the only exits are BF direct, after k
    # bottom reflections, with fraction (1 - R0)² Σ_k R0^(2k-1) e^(-2kτ0) and times 2k h n / c.
    photons = 100_000
    tau0, h = 0.05, 1.0
    params = slab(extinction=tau0 / h, thickness=h, omega=0.0, albedo=0.0,
                  time_edges=np.linspace(0.0, 100.0, 201))
    counts = simulate_reference(params, photons, records=True)
    records = counts.records
    r0 = normal_incidence_reflectance(N_CO2, 0.0)
    peaks = [(1 - r0) ** 2 * r0 ** (2 * k - 1) * math.exp(-2 * k * tau0) for k in range(1, 60)]
    series = math.fsum(peaks)

    assert counts.total[BF_DIFFUSE] == 0 and counts.total[SCATTERING] == 0
    assert counts.scattering_events == 0 and counts.fates[ESCAPED] == counts.total[BF_DIRECT]
    # BF direct count ~ Binomial(N, series), series ≈ 0.0247: 5 sigma ≈ 245 of ≈ 2470.
    assert abs(counts.total[BF_DIRECT] - photons * series) <= 5 * count_sigma(photons, series)
    # First peak alone (exits after one bottom reflection), same binomial bound.
    direct = records["component"] == BF_DIRECT
    first = np.sum(direct & (records["n_bspec"] == 1))
    assert abs(first - photons * peaks[0]) <= 5 * count_sigma(photons, peaks[0])

    # Times: path = 2k h exactly in exact arithmetic (k = number of bottom reflections).
    k_reflections = records["n_bspec"][direct]
    assert np.all(k_reflections >= 1)
    assert np.all(records["n_top"][direct] == k_reflections - 1)
    expected_time = 2 * k_reflections * h * N_CO2 / C_M_PER_NS
    np.testing.assert_allclose(records["time_ns"][direct], expected_time, rtol=1e-12, atol=0)
    assert np.all(records["cos_exit"][direct] == 1.0)


def test_draw_order_of_the_first_events():
    # walk.md §2-§3 for the pure absorbing slab, one Philox block per event: block 0 word 0
    # decides the entry; block 1 is the first flight (word 0 the step, word 1 the bottom
    # Fresnel reflection); the floor (A = 0) always absorbs. Draw j is word j % 4 of block j // 4.
    tau0 = 0.5
    params = slab(extinction=tau0, omega=0.0, albedo=0.0, seed=99, scenario=1)
    photons = 400
    records = simulate_reference(params, photons, records=True).records
    r0 = normal_incidence_reflectance(N_CO2, 0.0)
    fate_index = {name: i for i, name in enumerate(FATES)}
    for p in range(photons):
        u = photon_draws(params.seed, params.scenario, p, 8)
        if u[0] <= r0:
            expected = "specular"
        elif -math.log(u[4]) / tau0 < 1.0:  # step s < s_b = h = 1 m
            expected = "absorbed_medium"
        elif u[5] <= r0:  # reflected at the bottom: the ray lives on
            assert records["n_bspec"][p] >= 1
            continue
        else:
            expected = "absorbed_floor"
        assert records["fate"][p] == fate_index[expected], p


def test_conservative_granular_medium_lets_every_ray_escape():
    # docs/physics.md §8 check 3: omega = 1, A = 1, nothing can be absorbed; with a huge time cap
    # every ray escapes (exactly, not statistically).
    photons = 3000
    params = granular(omega=1.0, albedo=1.0, extinction=2.0, thickness=1.0, g=0.8,
                      max_time=1e9)
    counts = simulate_reference(params, photons)
    assert counts.fates[ESCAPED] == photons
    assert counts.fates.sum() == photons
    assert counts.total.sum() == photons
    assert counts.scattering_events > 0


@pytest.mark.slow
def test_bare_lambertian_floor_is_lambertian():
    # Granular, no extinction, n = 1: the ray falls on the floor, which reflects it with
    # probability A into cos θ = sqrt(U); it then leaves with cos θ_e = cos θ. The fraction in
    # the 1-degree bin [e1, e2] is A (sin²e2 - sin²e1), i.e. the reflectance
    # angular / (N π (sin²e2 - sin²e1)) = A/π sr⁻¹ in every bin.
    photons = 200_000
    albedo = 0.5
    h = 1.0
    params = granular(extinction=0.0, n=1.0, albedo=albedo, thickness=h, max_time=1e13,
                      time_edges=np.array([0.0, 10.0, 1e13]))
    counts = simulate_reference(params, photons, records=True)
    records = counts.records
    edges = np.radians(np.arange(91))
    probability = albedo * (np.sin(edges[1:]) ** 2 - np.sin(edges[:-1]) ** 2)
    observed = counts.angular[BF_DIFFUSE]
    # Each bin count ~ Binomial(N, p_b): 5 sigma per bin (smallest bin: p ≈ 1.5e-4, N p ≈ 30).
    sigma = np.sqrt(photons * probability * (1 - probability))
    assert np.all(np.abs(observed - photons * probability) <= 5 * sigma)
    reflectance = observed / (photons * math.pi * (np.sin(edges[1:]) ** 2
                                                   - np.sin(edges[:-1]) ** 2))
    assert np.all(np.abs(reflectance - albedo / math.pi)
                  <= 5 * sigma / (photons * math.pi * probability / albedo))
    # Escaped count ~ Binomial(N, A): 5 sigma.
    assert abs(counts.fates[ESCAPED] - photons * albedo) <= 5 * count_sigma(photons, albedo)
    assert counts.total[BF_DIFFUSE] == counts.fates[ESCAPED]
    # Geometry, exactly: path h down, h / cos θ back up; t = L n / c with n = 1.
    escaped = records["fate"] == ESCAPED
    assert np.all(records["n_lamb"][escaped] == 1) and np.all(records["n_scat"] == 0)
    expected_time = (h + h / records["cos_exit"][escaped]) / C_M_PER_NS
    np.testing.assert_allclose(records["time_ns"][escaped], expected_time, rtol=1e-12, atol=0)


@pytest.mark.parametrize("params", [slab(), slab(bottom_interface="none"), granular()],
                         ids=["slab_fresnel", "slab_none", "granular"])
def test_split_runs_give_the_same_photons(params):
    # Counter-based streams: photon p draws from counter (block, p, 0, 0) whatever the call.
    photons, split = 600, 257
    whole = simulate_reference(params, photons, records=True)
    first = simulate_reference(params, split, records=True)
    second = simulate_reference(params, photons - split, first_photon=split, records=True)
    for name, values in whole.records.items():
        joined = np.concatenate([first.records[name], second.records[name]])
        np.testing.assert_array_equal(values, joined, err_msg=name)  # NaN == NaN here
    first += second
    assert whole.same_as(first)
    # a different scenario key gives different rays
    other = simulate_reference(replace(params, scenario=77), photons)
    assert not whole.same_as(other)


def test_flight_cap_stops_exactly_at_max_flights():
    # Granular medium: every flight ends in a collision, the floor or the exit, so a ray that
    # ends after n_scat + n_lamb + 1 flights is untouched by a cap of 3 flights if that number
    # is at most 3, and is terminated otherwise.
    params = granular(omega=0.9, albedo=0.5, extinction=1.0)
    photons = 1500
    free = simulate_reference(params, photons, records=True).records
    capped = simulate_reference(replace(params, max_flights=3), photons,
                                records=True).records
    flights = free["n_scat"] + free["n_lamb"] + 1
    within = flights <= 3
    for name in free:
        np.testing.assert_array_equal(capped[name][within], free[name][within], err_msg=name)
    assert np.all(capped["fate"][~within] == FATES.index("terminated"))
    assert np.any(within) and np.any(~within)


def test_path_cap_terminates_late_exits_only():
    # Exits later than max_time are terminated (L > L_max after moving, before the exit rule);
    # exits within it are unchanged.
    base = slab(extinction=3.0)
    max_time = 15.0
    photons = 1500
    free = simulate_reference(replace(base, max_time=1e6), photons,
                              records=True).records
    capped = simulate_reference(replace(base, max_time=max_time), photons,
                                records=True).records
    exits = free["fate"] == ESCAPED
    early = exits & (free["time_ns"] < max_time * (1 - 1e-9))
    late = exits & (free["time_ns"] > max_time * (1 + 1e-9))
    for name in free:
        np.testing.assert_array_equal(capped[name][early], free[name][early], err_msg=name)
    assert np.all(capped["fate"][late] == FATES.index("terminated"))
    assert np.any(late) and np.any(early)
    assert np.all(capped["time_ns"][capped["fate"] == ESCAPED] <= max_time)


def test_progress_is_reported():
    seen = []
    simulate_reference(slab(), 2500, progress=seen.append)
    assert seen == [1000, 2000, 2500]


def test_invalid_parameters_are_rejected():
    with pytest.raises(ValueError):
        simulate_reference(slab(texture="foam"), 10)
    with pytest.raises(ValueError):
        simulate_reference(slab(time_edges=np.array([1.0, 0.5])), 10)


def test_rotation_from_vertical_keeps_the_sign_of_cos_theta():
    """A deflection of more than 90 degrees from straight down must send the ray upwards
    (a bug once found by the kernel parity test: copysign dropped the sign of cos Theta)."""
    from warpe_cl.reference import rotate_direction
    for uz, cos_theta in ((1.0, -0.5), (1.0, 0.5), (-1.0, -0.5), (-1.0, 0.5)):
        out = rotate_direction(0.0, 0.0, uz, cos_theta, 1.0)
        assert out[2] == pytest.approx(uz * cos_theta)
