"""The next-event (nadir) estimator (docs/walk.md §8): exact single scattering, the time
dependence of the first order, per-ray parity with the reference, reproducibility, outputs.

Every Monte Carlo comparison uses the estimator's own standard error (the spread of its 32
photon batches, warpe_cl.nadir._batch_error) and a 5 sigma tolerance, written next to it.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from warpe_cl.params import (C_M_PER_NS, NADIR_BATCHES, NADIR_ROWS, Layer, WalkParams,
                             batch_photons, fixed_to_float, stack_params)
from warpe_cl.nadir import _batch_error, nadir_min_score, nadir_new_cell_score, view_table
from warpe_cl.radiative import fresnel_internal
from warpe_cl.reference import henyey_greenstein_phase, simulate_reference

EDGES = np.concatenate([[0.0], np.logspace(-4, 3, 71)])
ORDER_1 = NADIR_ROWS.index("order_1")


def _order1_bins(engine, n, omega, g, h, E, edges, bottom, roulette, photons=200_000):
    """Walk a slab (black floor) and return the order-1 nadir reflectance per time bin, its
    batch error and the counts."""
    p = WalkParams(texture="slab", thickness=h, extinction=E, omega=omega, g=g, n=n, k=0.0,
                   albedo=0.0, time_edges=edges, bottom_interface=bottom, nadir=True,
                   nadir_roulette=roulette)
    counts = engine.run(p, photons)
    sums = fixed_to_float(counts.nadir_sum)[:, ORDER_1, 1:-1]           # (batches, bins)
    return sums.sum(axis=0) / counts.photons, _batch_error(sums, counts.nadir_batch_photons), \
        counts


def _order1(counts):
    """(value, stderr) of the time-integrated order-1 nadir reflectance, sr^-1."""
    sums = fixed_to_float(counts.nadir_sum)[:, ORDER_1, :].sum(axis=-1)
    return sums.sum() / counts.photons, float(_batch_error(sums, counts.nadir_batch_photons))


@pytest.mark.parametrize("g", [0.0, 0.5, -0.3, 0.8])
@pytest.mark.parametrize("view", [0.0, 40.0])
@pytest.mark.parametrize("roulette", [0.0, 0.1])
def test_first_order_is_chandrasekhar_single_scattering(engine, g, view, roulette):
    """Semi-infinite, n = 1: the order-1 bidirectional reflectance is omega p(Theta) / (mu0 + mu)
    with p normalised to 1 over the sphere, mu0 = 1, mu = cos(view) and cos Theta = -mu (the
    incident beam goes down, the view direction up): omega p(pi) / 2 at nadir. The roulette of
    small scores is unbiased, so it holds with it too."""
    omega = 0.9
    p = WalkParams(texture="granular", thickness=1.0, extinction=2000.0, omega=omega, g=g,
                   n=1.0, k=0.0, albedo=0.0, time_edges=EDGES, bottom_interface="none",
                   nadir=True, view_zenith=view, nadir_roulette=roulette)
    counts = engine.run(p, 60_000)
    value, err = _order1(counts)
    mu = math.cos(math.radians(view))
    expected = omega * henyey_greenstein_phase(g, -mu) / (1.0 + mu)
    # tau0 = 2000: the semi-infinite limit to exp(-4000); 5 sigma of the batch error
    assert abs(value - expected) < 5.0 * err, (value, expected, err)
    assert err < 0.02 * expected            # a sharp test: 5 sigma is within 10 %


def test_first_order_time_dependence_in_a_finite_slab(engine):
    """A slab of index n over a black floor in contact (bottom_interface none, A = 0): the
    order-1 paths enter (1 - R0), scatter once at depth z before reaching the floor and leave
    along the view direction (nadir: mu_i = 1), arriving at t = 2 z n / c. Per time bin
    [ta, tb]: (1 - R0) omega p(pi) T(1) / n^2 [exp(-2 E za) - exp(-2 E zb)] / 2, z clipped
    to [0, h]."""
    n, omega, g, h, tau0 = 1.31, 0.95, 0.5, 0.05, 3.0
    E = tau0 / h
    edges = np.linspace(0.0, 2.0 * h * n / C_M_PER_NS * 1.25, 26)
    value, err, _ = _order1_bins(engine, n, omega, g, h, E, edges, "none", 0.1)
    r0 = ((n - 1) / (n + 1)) ** 2
    amplitude = (1 - r0) * omega * henyey_greenstein_phase(g, -1.0) \
        * (1 - float(fresnel_internal(1.0, n))) / n ** 2
    z = np.clip(edges * C_M_PER_NS / (2 * n), 0.0, h)
    expected = amplitude * (np.exp(-2 * E * z[:-1]) - np.exp(-2 * E * z[1:])) / 2
    live = expected > 0
    assert live.sum() >= 18 and not np.any(value[~live])   # nothing after 2 h n / c
    z_scores = (value[live] - expected[live]) / err[live]
    # 5 sigma per bin over ~20 bins (a false alarm ~1e-5)
    assert np.max(np.abs(z_scores)) < 5.0, z_scores
    # sharp where the signal is: the first 10 bins (most of it) to better than 5 % per bin
    assert np.all(err[live][:10] < 0.05 * expected[live][:10])


MEDIA = {
    "granular": dict(texture="granular", thickness=0.01, extinction=300.0, omega=0.9, g=0.5,
                     n=1.2, k=0.0, albedo=0.5, bottom_interface="none", view_zenith=20.0),
    "slab_gap": dict(texture="slab", thickness=0.01, extinction=300.0, omega=0.9, g=0.5,
                     n=1.3, k=1e-3, albedo=0.5, bottom_interface="fresnel", view_zenith=20.0),
    "slab_contact_time_window": dict(texture="slab", thickness=0.01, extinction=300.0,
                                     omega=0.9, g=0.5, n=1.3, k=0.0, albedo=0.5,
                                     bottom_interface="none", rule="time_window"),
    "slab_gap_thin": dict(texture="slab", thickness=0.01, extinction=50.0, omega=0.9, g=0.7,
                          n=1.4, k=0.0, albedo=0.6, bottom_interface="fresnel", view_zenith=10.0),
    "slab_weighted": dict(texture="slab", thickness=0.01, extinction=300.0, omega=0.9, g=0.5,
                          n=1.3, k=1e-3, albedo=0.5, bottom_interface="fresnel",
                          mode="weighted", view_zenith=30.0),
}
STACK = (Layer("granular", 0.003, 500.0, 0.95, 0.3, 1.1, 0.0),
         Layer("slab", 0.005, 200.0, 0.9, 0.6, 1.31, 1e-4))


def _cases():
    out = {name: WalkParams(time_edges=EDGES, nadir=True, nadir_roulette=0.05, **kw)
           for name, kw in MEDIA.items()}
    out["stack_gap"] = stack_params(STACK, albedo=0.6, time_edges=EDGES, nadir=True,
                                    view_zenith=30.0, nadir_roulette=0.05)
    out["stack_substrate"] = stack_params(STACK, substrate=(1.6, 0.01), albedo=0.6,
                                          time_edges=EDGES, nadir=True, view_zenith=10.0)
    # a clear slab on a scattering one, on a floor in contact: the floor's scores follow the
    # paths the two upper faces reflect (mirror_table's up rows of the last layer)
    out["stack_contact"] = stack_params(
        (Layer("slab", 0.002, 20.0, 0.0, 0.0, 1.5), STACK[1]), albedo=0.6,
        bottom_interface="none", time_edges=EDGES, nadir=True, view_zenith=15.0,
        nadir_roulette=0.05)
    return out


@pytest.mark.parametrize("name", list(_cases()))
def test_double_kernel_scores_as_the_reference_per_ray(engine, name):
    """The double-precision kernel and the reference (which follows each virtual path layer
    by layer on its own, not through the view table) give every ray the same total score (to
    1e-9 relative: exp and the Fresnel formulas differ by rounding only), the same cell visits
    (so the same roulette outcomes and cells) and the same batch sums."""
    params = _cases()[name]
    n = 1500
    ker = engine.run(params, n, precision="double", records=True, first_photon=7)
    ref = simulate_reference(params, n, first_photon=7, records=True)
    assert np.array_equal(ker.records["fate"], ref.records["fate"])
    a, b = ker.records["nadir"], ref.records["nadir"]
    assert np.count_nonzero(b) > n // 2
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=0.0)
    assert np.array_equal(ker.nadir_visits, ref.nadir_visits)
    np.testing.assert_allclose(fixed_to_float(ker.nadir_sum), fixed_to_float(ref.nadir_sum),
                               rtol=1e-9, atol=1e-300)
    assert np.array_equal(ker.nadir_batch_photons, batch_photons(7, n))


def test_estimator_leaves_the_rays_alone(engine):
    """The estimator draws no random number: every FOV tally is the same bits with it."""
    params = _cases()["slab_gap"]
    on = engine.run(params, 20_000)
    off = engine.run(dataclasses.replace(params, nadir=False), 20_000)
    for name in ("time_in_fov", "time_any", "angular", "total", "early", "fates"):
        assert np.array_equal(getattr(on, name), getattr(off, name)), name
    assert on.scattering_events == off.scattering_events


def test_sums_do_not_depend_on_launches_or_work_items(engine):
    """A ray's pending score is parked with it (walk.md §5), and the sums are exact integers:
    the same bits for an event budget of 1 per launch, another global size, two halves, and
    the GPUs' form of the sums (one slice for every work-item, 64-bit atomics), here on the
    CPU device, in a slab over a gap (its mirror paths) and in a stack. The runs follow one
    another on one engine, which keeps the sums' buffers of a shape from run to run
    (Engine._nadir_buffers): each run must zero them first, or a run would add its
    predecessor's sums to its own."""
    for name in ("stack_gap", "slab_gap_thin"):
        params = _cases()[name]
        whole = engine.run(params, 3000)
        cut = engine.run(params, 3000, event_budget=1)
        other = engine.run(params, 3000, global_size=5)
        shared = engine.run(params, 3000, shared_nadir=True)
        halves = engine.run(params, 1400)
        halves += engine.run(params, 1600, first_photon=1400)
        for c in (cut, other, shared, halves):
            assert np.array_equal(c.nadir_sum, whole.nadir_sum), name
            assert np.array_equal(c.nadir_visits, whole.nadir_visits), name
            assert np.array_equal(c.nadir_batch_photons, whole.nadir_batch_photons), name


def test_fold_adds_the_slices_exactly(engine):
    """The device's fold of the per-work-item slices (cl/walk.cl nadir_fold) is the exact sum
    of the 192-bit words, with the carries from word to word, and of the visits: against
    Python's integers, on words near 2^64 that carry in every add."""
    import pyopencl as cl
    from warpe_cl.engine import _exact_sums, fold_nadir_slices, kernel_key
    from warpe_cl.params import FIXED_WORDS
    engine.kernel("slab", "single", False, 1, False, True)
    fold = engine._folds[kernel_key("slab", "single", False, 1, False, True)]
    rng = np.random.default_rng(3)
    shape = (7, 2, 3, 5)
    words = rng.integers(0, 2**64, size=(*shape, FIXED_WORDS), dtype=np.uint64)
    words[..., 0] |= np.uint64(0xFFFF_FFFF_0000_0000)          # carries into the middle word
    words[0, 0, 0, 0] = [2**64 - 1, 2**64 - 1, 5]              # a carry through both words
    words[1, 0, 0, 0] = [1, 0, 0]
    words[..., 2] >>= np.uint64(8)                             # no overflow of the sum
    visits = rng.integers(0, 2**40, size=(shape[0], *shape[2:]), dtype=np.uint64)
    mf = cl.mem_flags
    sums_buf = cl.Buffer(engine.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=words)
    visits_buf = cl.Buffer(engine.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=visits)
    got, got_visits = fold_nadir_slices(engine.queue, fold, sums_buf, visits_buf, shape)
    assert np.array_equal(_exact_sums(got), _exact_sums(words).sum(axis=0))
    assert np.array_equal(got_visits, visits.sum(axis=0))


@pytest.mark.parametrize("name", ["granular", "slab_gap", "stack_gap"])
def test_lane_widths_give_the_same_bits(engine, name):
    """The vector (the device's widest vector width, conftest.lanes_of) and scalar (1 lane)
    forms of the walk give the same bits, nadir sums included: every score's last bit follows
    the ray's depth and path, so this fails wherever the two forms round one operation
    differently (it did on Intel's CPU runtime until the walk stopped calling rsqrt, whose
    vector and scalar forms differ there, and until contraction into fma was turned off:
    cl/real.h, cl/scatter.h)."""
    from conftest import lanes_of
    params = _cases()[name]
    wide = engine.run(params, 4000, lanes=lanes_of(engine, "vector"), qualified=True)
    one = engine.run(params, 4000, lanes=1, qualified=True)
    assert wide.same_as(one)
    assert np.array_equal(wide.nadir_sum, one.nadir_sum)


@pytest.mark.parametrize("form", ["scalar", "vector"])
@pytest.mark.parametrize("texture", ["granular", "slab"])
def test_skipped_scores_change_no_bit(engine, texture, form):
    """nadir_scatter leaves out the events at which every lane's score would lose the
    roulette for certain (cl/score.h's bound, walk.md §8.3). Every tally, the nadir sums and
    each ray's total score included, is the same bits as with every score computed
    (-DWARPE_NO_SCORE_SKIP), in a medium deep enough (tau0 = 200) that most events are left
    out, in the vector form (the device's widest, conftest.lanes_of) and in the GPUs' one-lane
    form."""
    from conftest import lanes_of, walk_with_options
    lanes = lanes_of(engine, form)
    from warpe_cl.engine import kernel_key
    params = WalkParams(texture=texture, thickness=0.05, extinction=4000.0, omega=0.999, g=0.8,
                        n=1.3, k=0.0, albedo=0.15, bottom_interface="none", time_edges=EDGES,
                        nadir=True, nadir_roulette=0.1, view_zenith=20.0)
    structure = (texture, "single", True, lanes, False, True)
    skipping = engine.run(params, 2000, records=True, lanes=lanes, qualified=True)
    every = engine.program_options(kernel_key(*structure)) + ("-DWARPE_NO_SCORE_SKIP",)
    computed = walk_with_options(engine, structure, every, params, 2000, records=True,
                                 lanes=lanes, qualified=True)
    assert np.count_nonzero(computed.records["nadir"]) > 1000
    assert skipping.same_as(computed)
    assert np.array_equal(skipping.records["nadir"], computed.records["nadir"])


@pytest.mark.parametrize("g", [0.0, 0.8, -0.3])
@pytest.mark.parametrize("view", [0.0, 40.0])
@pytest.mark.parametrize("texture", ["slab", "granular"])
def test_roulette_threshold(g, view, texture):
    """s_min of the roulette (walk.md §8.3): r F p(pi), r = nadir_roulette times the score of a
    scattering at the top straight back up (F the top layer's view factor); the host's value,
    which the kernel gets, and the reference's agree; none in the weighted mode or at r = 0."""
    from warpe_cl.reference import _nadir_scorer
    p = WalkParams(texture=texture, thickness=1e-3, extinction=1e3, omega=0.9, g=g, n=1.3,
                   k=0.0, albedo=0.0, time_edges=EDGES, nadir=True, nadir_roulette=0.1,
                   view_zenith=view)
    expected = 0.1 * view_table(p)[0, -1] * henyey_greenstein_phase(g, -1.0)
    assert nadir_min_score(p) == pytest.approx(expected, rel=1e-12)
    assert _nadir_scorer(p, None, list(EDGES)).s_min == pytest.approx(expected, rel=1e-12)
    assert nadir_min_score(dataclasses.replace(p, nadir_roulette=0.0)) == 0.0
    assert nadir_min_score(dataclasses.replace(p, mode="weighted")) == 0.0


@pytest.mark.parametrize("g", [0.0, 0.3, 0.8, -0.3])
@pytest.mark.parametrize("roulette", [0.05, 0.1, 0.5, 1.0])
def test_new_cell_roulette_threshold(g, roulette):
    """s_new of the roulette for a score that would open a new pending cell (walk.md §8.3): r
    times the score of a scattering at the top into the phase function's mean, F / (4 pi),
    kept between s_min (r F p(pi)) and F p(pi) (the score straight back up); the host's value,
    which the kernel gets, and the reference's agree; 0 without the roulette."""
    from warpe_cl.reference import _nadir_scorer
    p = WalkParams(texture="slab", thickness=1e-3, extinction=1e3, omega=0.9, g=g, n=1.3,
                   k=0.0, albedo=0.0, time_edges=EDGES, nadir=True, nadir_roulette=roulette,
                   view_zenith=20.0)
    top = view_table(p)[0, -1] * henyey_greenstein_phase(g, -1.0)
    mean = view_table(p)[0, -1] / (4.0 * math.pi)
    expected = min(max(roulette * mean, roulette * top), top)
    assert nadir_new_cell_score(p) == pytest.approx(expected, rel=1e-12)
    assert _nadir_scorer(p, None, list(EDGES)).s_new == pytest.approx(expected, rel=1e-12)
    assert nadir_new_cell_score(p) >= nadir_min_score(p)
    if g <= 0.0 or roulette == 1.0:
        assert nadir_new_cell_score(p) == pytest.approx(nadir_min_score(p), rel=1e-12)
    if g == 0.8 and roulette == 0.1:        # r (1 + g)^2 / (1 - g) = 1.62: the cap
        assert nadir_new_cell_score(p) == pytest.approx(top, rel=1e-12)
    assert nadir_new_cell_score(dataclasses.replace(p, nadir_roulette=0.0)) == 0.0
    assert nadir_new_cell_score(dataclasses.replace(p, mode="weighted")) == 0.0


def test_roulettes_are_unbiased_on_the_same_rays(engine):
    """The roulette of small scores, at s_min and at the higher s_new of the scores that open a
    new cell (walk.md §8.3), adds zero on average: the estimator draws no random number, so
    with and without the roulette the rays are the same and the difference of their nadir
    sums is the roulettes' noise alone. Its mean over the photons, per row and in the early and
    late halves of the bins, lies within 5 sigma of 0, sigma the spread of the difference's
    batch means. g = 0.8, where s_new is 10 s_min; r = 0.1 lowers the cells opened by a
    third or more."""
    p = WalkParams(texture="slab", thickness=0.01, extinction=1000.0, omega=0.99, g=0.8,
                   n=1.3, k=0.0, albedo=0.15, time_edges=EDGES, bottom_interface="none",
                   nadir=True, nadir_roulette=0.1)
    n = 20_000
    played = engine.run(p, n)
    every = engine.run(dataclasses.replace(p, nadir_roulette=0.0), n)
    assert played.scattering_events == every.scattering_events
    assert nadir_new_cell_score(p) == pytest.approx(10.0 * nadir_min_score(p), rel=1e-12)
    assert played.nadir_visits.sum() < 0.67 * every.nadir_visits.sum()
    diff = fixed_to_float(played.nadir_sum) - fixed_to_float(every.nadir_sum)   # (B, rows, cols)
    half = diff.shape[-1] // 2
    s, b, o = (NADIR_ROWS.index(r) for r in ("scattering", "bf_diffuse", "order_1"))
    for part in (diff[:, s, :half], diff[:, s, half:], diff[:, b, :half], diff[:, b, half:],
                 diff[:, o, :]):
        sums = part.sum(axis=-1)
        value = sums.sum() / n
        err = float(_batch_error(sums, played.nadir_batch_photons))
        assert err > 0.0                    # the roulettes played in this part
        # 5 sigma of the roulettes' own noise (the same rays: no ray-to-ray spread)
        assert abs(value) < 5.0 * err, (value, err)
    total = fixed_to_float(every.nadir_sum)[:, s].sum() / n
    noise = float(_batch_error(diff[:, s].sum(axis=-1), played.nadir_batch_photons))
    assert noise < 1e-3 * total             # a sharp test: 5 sigma is within 0.5 % of the value


def test_view_table_granular_and_slab():
    """The factor T / (m^2 mu): 1 / mu_v for a granular layer (no interface, m = 1); for a
    slab at nadir (1 - R_int(1)) / n^2, the gap row (1 - R_ext) T_top / 1."""
    g = WalkParams(texture="granular", thickness=0.01, extinction=100.0, omega=0.9, g=0.0,
                   n=1.2, k=0.0, albedo=0.5, time_edges=EDGES, view_zenith=60.0)
    t = view_table(g)
    assert t[0, 1] == pytest.approx(0.5) and t[0, -1] == pytest.approx(2.0)
    assert t[0, 2] == pytest.approx(200.0) and t[0, 3] == pytest.approx(2.0)
    s = WalkParams(texture="slab", thickness=0.01, extinction=100.0, omega=0.9, g=0.0, n=1.3,
                   k=0.0, albedo=0.5, time_edges=EDGES)
    t = view_table(s)
    top = 1 - float(fresnel_internal(1.0, 1.3))
    assert t[0, -1] == pytest.approx(top / 1.3 ** 2)
    assert t[1, -1] == pytest.approx(top * (1 - ((1.3 - 1) / 2.3) ** 2))
    assert t[1, 4] == pytest.approx(1.0)          # the gap sees the whole slab: tau = E h


def test_batch_error_is_the_spread_of_batch_means():
    """Equal batches: var = sum (m_b - m)^2 / (B (B - 1)); empty batches are left out."""
    rng = np.random.default_rng(3)
    sums = rng.random(NADIR_BATCHES) * 10
    nb = np.full(NADIR_BATCHES, 5)
    means = sums / 5
    expected = math.sqrt(np.sum((means - means.mean()) ** 2) / (NADIR_BATCHES * (NADIR_BATCHES - 1)))
    assert float(_batch_error(sums, nb)) == pytest.approx(expected, rel=1e-12)
    nb[3:] = 0
    assert math.isfinite(float(_batch_error(sums, nb)))
    nb[1:] = 0
    assert math.isnan(float(_batch_error(sums, nb)))


def test_outputs_and_instrument_choice():
    """simulate writes the nadir variables with units, keeps the FOV ones, and the
    instrument chain says it used the nadir estimate."""
    import warpe_cl
    cfg = warpe_cl.load_preset("radiative/slab_co2_1m",
                               overrides={"simulation.photons": 2000,
                                          "medium.bottom_interface": "none",
                                          "instrument": {"name": "bela"}})
    ds = warpe_cl.simulate(cfg, device="numpy", progress=False)
    for name in ("nadir_reflectance", "nadir_reflectance_stderr", "nadir_ray_count",
                 "nadir_brdf", "nadir_brdf_stderr", "nadir_order_reflectance",
                 "nadir_order_brdf"):
        assert name in ds.variables, name
    assert ds["nadir_reflectance"].attrs["units"] == "ns-1 sr-1"
    spec = ds["nadir_reflectance"].sel(component="specular")
    np.testing.assert_array_equal(spec, ds["reflectance"].sel(component="specular"))
    assert ds.attrs["instrument_diffuse_estimate"] == "nadir"
    assert ds.attrs["view_zenith_deg"] == 0.0
    off = warpe_cl.simulate(warpe_cl.load_preset("radiative/slab_co2_1m", overrides={
        "simulation.photons": 500, "simulation.nadir": False,
        "medium.bottom_interface": "none", "instrument": {"name": "bela"}}),
        device="numpy", progress=False)
    assert "nadir_reflectance" not in off and off.attrs["instrument_diffuse_estimate"] == "fov"
    # the estimator is not part of the scenario key: the same rays with or without it
    assert off.attrs["scenario_key"] == ds.attrs["scenario_key"]


def test_instrument_on_a_sweep_where_only_some_scenarios_have_the_nadir_estimate():
    """A sweep of a slab without the nadir estimate (simulation.nadir false: its
    nadir_reflectance is NaN in the stacked file) and with it: the instrument chain uses each
    scenario's own estimate, says which per scenario, and no NaN reaches the waveform (the
    whole-paper run's bela_cases once failed here with 'lam value too large', when its slab
    over a vacuum gap got no estimate)."""
    import warpe_cl
    from warpe_cl.instrument import apply_instrument
    from warpe_cl.surface import responses
    cfg = warpe_cl.load_preset("radiative/slab_co2_1m", overrides={
        "simulation.photons": 500, "sweep": {"simulation.nadir": [False, True]}})
    ds = warpe_cl.simulate(cfg, device="numpy", progress=False)
    assert ds["nadir_estimator"].values[0] == "none: simulation.nadir is false"   # why
    assert ds["nadir_estimator"].values[1].startswith("next-event")
    assert np.isnan(ds["nadir_reflectance"].isel(scenario=0)).all()
    assert np.isfinite(ds["nadir_reflectance"].isel(scenario=1)).all()
    # with an instrument block, simulate applies it scenario by scenario, and the stacked
    # result keeps which estimate each used
    inst = warpe_cl.simulate(cfg.with_overrides({"instrument": {"name": "bela"}}),
                             device="numpy", progress=False)
    assert inst.attrs["instrument_diffuse_estimate"] == "mixed"
    assert list(inst["diffuse_estimate"].values) == ["fov", "nadir"]
    out = apply_instrument(ds, "bela", shots=3)
    assert out.attrs["instrument_diffuse_estimate"] == "mixed"
    assert list(out["diffuse_estimate"].values) == ["fov", "nadir"]
    assert np.isfinite(out["expected_mv"]).all() and np.isfinite(out["signal_mv"]).all()
    each = responses(ds)
    np.testing.assert_array_equal(
        each[0].diffuse, sum(ds["reflectance"].isel(scenario=0).sel(component=c)
                             for c in ("bf_diffuse", "scattering")))
    np.testing.assert_array_equal(
        each[1].diffuse, sum(ds["nadir_reflectance"].isel(scenario=1).sel(component=c)
                             for c in ("bf_diffuse", "scattering")))
    # an interpolation between scenarios (the inversion's) takes one estimate for all: FOV
    assert {r.estimate for r in responses(ds, uniform=True)} == {"fov"}


def _order1_over_a_gap(n, omega, g, h, E, edges, samples=40_000):
    """The order-1 nadir reflectance of a slab over a vacuum gap with a black floor, per time
    bin, written out from the geometry alone (not from nadir.mirror_table): the unscattered
    beam enters (1 - R) and passes down and up the slab, reflected by its faces (R each, at
    normal incidence R = ((n - 1)/(n + 1))^2 for both faces from inside, as from outside);
    it scatters first at each point with density omega E exp(-E s) ds; from there the virtual
    paths to the receiver start up or down along the vertical, bounce between the faces and
    leave through the top (1 - R), each with p(Theta) of its start direction, e^-tau of its
    length and the etendue 1 / n^2, at t = (path of the beam + path of the virtual path) n / c.
    Midpoint sums over ``samples`` points per pass, histogrammed on ``edges``."""
    r = ((n - 1) / (n + 1)) ** 2
    ds = h / samples
    s = (np.arange(samples) + 0.5) * ds
    cut = 1e-13
    times, weights = [], []
    j, beam = 0, 1.0 - r                           # pass j of the beam, its weight at entry
    while beam > cut:
        down = j % 2 == 0                          # passes alternate: down, up, down, ...
        z = s if down else h - s
        density = beam * omega * E * np.exp(-E * s) * ds
        base = j * h + s                            # the beam's path to the scattering
        for start_up in (True, False):
            # u . v: v up along the view is (0, 0, -1) (z downwards); the beam's u is (0, 0, +-1)
            cos_theta = (-1.0 if down else 1.0) * (1.0 if start_up else -1.0)
            p = henyey_greenstein_phase(g, cos_theta)
            first = z if start_up else (h - z) + h  # to the top, or down and back up
            factor = 1.0 if start_up else r             # the lower face's reflection
            k = 0
            while np.max(factor * np.exp(-E * first)) * (r * r * np.exp(-2 * E * h)) ** k > cut:
                length = first + 2 * k * h
                amplitude = (density * p * factor * (r * r * np.exp(-2 * E * h)) ** k
                             * np.exp(-E * first) * (1.0 - r) / n ** 2)
                times.append((base + length) * n / C_M_PER_NS)
                weights.append(amplitude)
                k += 1
        beam *= r * np.exp(-E * h)                  # reflected by the face it reaches
        j += 1
    # the straight-down-and-back paths arrive at bin centres only (edges chosen so), and
    # rounding cannot move them across an edge
    return np.histogram(np.concatenate(times), bins=edges, weights=np.concatenate(weights))[0]


def test_first_order_time_dependence_over_a_vacuum_gap(engine):
    """A slab over a vacuum gap, black floor: the order-1 row, bin by bin, against the same
    paths written out from the geometry (_order1_over_a_gap): the straight path up, the
    mirror paths down to the lower face and back (a delta at t1 = 2 h n / c from the beam's
    first pass, whose forward peak p(0) makes it large), the round trips between the faces,
    and the first scatterings of the beam after the faces reflected it. A high index (R = 0.11)
    and a thin slab (tau0 = 0.3) make every one of these frequent; bins before 1.5 t1 take
    the beam's first three passes only (a pass j scatters at path >= j h), all well sampled
    (the fourth holds ~1e-3 of the scatterings)."""
    n, omega, g, h, tau0 = 2.0, 0.95, 0.5, 0.05, 0.3
    E = tau0 / h
    t1 = 2.0 * h * n / C_M_PER_NS
    # 24 bins per t1, t1 and its multiples at bin centres (the deltas), up to 4 t1
    edges = np.concatenate([[0.0], (np.arange(0, 97) + 0.5) * t1 / 24])
    value, err, counts = _order1_bins(engine, n, omega, g, h, E, edges, "fresnel", 0.0)
    sums = fixed_to_float(counts.nadir_sum)[:, ORDER_1, 1:-1]           # (batches, bins)
    expected = _order1_over_a_gap(n, omega, g, h, E, edges)
    centres = 0.5 * (edges[1:] + edges[:-1])
    delta = int(np.argmin(np.abs(centres - t1)))
    assert expected[delta] > 5 * expected[delta - 1]     # the down-path delta stands out
    window = (centres < 1.5 * t1) & (expected > 0)
    late = window & (centres > t1 * 1.01)      # mirror paths and the twice-reflected beam's
    assert late.sum() >= 10
    z_scores = (value[window] - expected[window]) / err[window]
    # 5 sigma per bin (~36 bins: a false alarm ~2e-5)
    assert np.max(np.abs(z_scores)) < 5.0, (np.argmax(np.abs(z_scores)), z_scores)
    assert err[delta] < 0.02 * expected[delta]          # sharp where the mirror path lands
    # what arrives in (t1, 1.5 t1), summed: its error from the batches of the
    # summed bins, 5 sigma; sharp (2 % here: doubling the round trips' factor fails it)
    late_sums = sums[:, late].sum(axis=1)
    late_value, late_err = late_sums.sum() / counts.photons, float(
        _batch_error(late_sums, counts.nadir_batch_photons))
    assert abs(late_value - expected[late].sum()) < 5.0 * late_err
    assert late_err < 0.05 * expected[late].sum()
