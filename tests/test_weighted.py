"""The weighted mode (docs/walk.md §6): survival weighting, exp(-a L) absorption, Russian
roulette and exact fixed-point tallies.

Monte Carlo tolerances are 5 standard errors (false alarm ~6e-7 per assertion); the standard
error of a weighted mean is sqrt((<w^2> - <w>^2)/N), from the w^2 sums the kernel keeps.
"""
from __future__ import annotations

import numpy as np
import pytest

from conftest import LAMBDA, SCATTERING, lanes_of, medium, vector_widths
from warpe_cl import radiative
from warpe_cl.params import C_M_PER_NS, RECORD_INT_COLUMNS, fixed_point, fixed_to_float
from warpe_cl.reference import simulate_reference
from warpe_cl.tally import reduce_counts

CO2 = dict(n=1.4026, k=8.47e-10)
H2O = dict(n=1.30042, k=1.272e-6)
EXACT_FIELDS = RECORD_INT_COLUMNS    # every integer column of a ray's record


def test_fixed_point_is_exact_and_ordered():
    assert fixed_point(1.0) == 2 ** 150
    assert fixed_point(0.0) == 0 and fixed_point(-1.0) == 0
    w = 1.2345678901234567e-20
    assert fixed_to_float([fixed_point(w)])[0] == pytest.approx(w, rel=1e-15)
    # a 1e-20 weight next to weights of order 1 survives the sum
    total = fixed_point(0.75) + fixed_point(w) + fixed_point(0.25)
    assert total - fixed_point(1.0) == fixed_point(w) or abs(total - 2 ** 150 - fixed_point(w)) <= 2


def test_fixed_to_float_is_correctly_rounded():
    """Every sum, as an (n,) or (b, r, c) array of Python ints, becomes the float64 nearest to
    sum 2^-150 (ties to even): against Fraction, on ints of 1 to 200 bits, halfway cases, and
    one beyond float64's range (the shifted fallback)."""
    from fractions import Fraction
    from warpe_cl.params import FIXED_SHIFT
    rng = np.random.default_rng(5)
    values = [0, 1, 2 ** 53 + 1, 2 ** 54 + 2, 2 ** 54 + 6, (2 ** 53 + 1) << 120,
              (2 ** 52 + 1) << 139 | (1 << 139) - 1]
    values += [int(rng.integers(1, 2 ** 62)) << int(rng.integers(0, 140))
               | int(rng.integers(0, 2 ** 40)) for _ in range(500)]
    got = fixed_to_float(np.array(values, dtype=object).reshape(-1))
    want = [float(Fraction(v, 2 ** FIXED_SHIFT)) for v in values]
    assert np.array_equal(got, np.array(want))
    assert fixed_to_float(np.array(values[:6], dtype=object).reshape(2, 3, 1)).shape == (2, 3, 1)
    huge = fixed_to_float([2 ** 1100, 3])
    assert huge[0] == float(2 ** (1100 - FIXED_SHIFT)) and huge[1] == 3 * 2.0 ** -FIXED_SHIFT


@pytest.mark.parametrize("form", ["scalar", "vector"])
@pytest.mark.parametrize("kw", [dict(texture="slab"), dict(texture="slab", bottom_interface="none"),
                                dict(texture="granular")])
def test_double_kernel_follows_reference_per_photon(engine, kw, form):
    """Same events as the reference walk; weights to 1e-12 (exp() of two libms), one photon
    per work-item and the device's widest vector lanes (conftest.lanes_of)."""
    lanes = lanes_of(engine, form, "double")
    params = medium(mode="weighted", roulette_weight=0.05, albedo=0.3, **kw)
    n = 3000
    ref = simulate_reference(params, n, first_photon=5, records=True)
    ker = engine.run(params, n, precision="double", first_photon=5, records=True, lanes=lanes,
                     qualified=True)
    for field in EXACT_FIELDS:
        np.testing.assert_array_equal(ker.records[field], ref.records[field], err_msg=field)
    np.testing.assert_allclose(ker.records["weight"], ref.records["weight"], rtol=1e-12)
    assert ker.fates.tolist() == ref.fates.tolist()
    for name in ("w_total", "w_time_any", "w_angular", "w2_total"):
        np.testing.assert_allclose(fixed_to_float(getattr(ker, name)),
                                   fixed_to_float(getattr(ref, name)), rtol=1e-12, err_msg=name)
    # roulette did happen, and a killed ray counts as absorbed
    assert np.any(ref.records["weight"] > 0.05) and ref.fates[2] > 0


@pytest.mark.parametrize("precision", ["single", "double"])
def test_weighted_sums_do_not_depend_on_launch_geometry(engine, precision):
    """Integer (fixed-point) sums: the same bits whatever the batch, global size, work-group
    size or split of the photons, and whatever the order the work-items add them in."""
    p = medium(**SCATTERING, mode="weighted")
    n = 30_000
    whole = engine.run(p, n, precision=precision)
    for kw in (dict(batch=7_777), dict(global_size=33), dict(global_size=64, local_size=4)):
        assert engine.run(p, n, precision=precision, **kw).same_as(whole), kw
    part = engine.run(p, 12_345, precision=precision)
    part += engine.run(p, n - 12_345, precision=precision, first_photon=12_345)
    assert part.same_as(whole)


@pytest.mark.parametrize("precision, rtol", [("single", 0.0), ("double", 1e-12)])
def test_weighted_sums_across_lane_widths(engine, precision, rtol):
    """The same histories and weights at every lane width. In single precision a ray's weight
    is the same bits (the absorbed fraction is the walk's own exp_neg, cl/scatter.h; with the
    driver's exp, whose vector and scalar forms differ in the last bit, the sums differed by
    2e-5): sums identical. In double precision the driver's exp: sums equal to rounding
    (measured 2e-14). The widths: the device's own chain (conftest.vector_widths)."""
    p = medium(**SCATTERING, mode="weighted")
    n = 20_000
    widths = vector_widths(engine, precision)
    base = engine.run(p, n, precision=precision, lanes=1, qualified=True)
    for lanes in widths:
        other = engine.run(p, n, precision=precision, lanes=lanes, qualified=True)
        assert other.fates.tolist() == base.fates.tolist()
        assert np.array_equal(other.time_any, base.time_any)
        for name in ("w_total", "w_time_any", "w2_total"):
            if rtol == 0.0:
                assert np.array_equal(getattr(other, name), getattr(base, name)), name
            else:
                np.testing.assert_allclose(fixed_to_float(getattr(other, name)),
                                           fixed_to_float(getattr(base, name)), rtol=rtol)


def _first_bf_peak(engine, material, photons, mode):
    """The pure slab of 1 m over a floor A = 0.15 (docs/physics.md §8): the BF-direct energy of the
    first pass (arrival in [0.99 t1, 1.5 t1)) and its standard error."""
    h = 1.0
    tau0 = 4 * np.pi * material["k"] * h / LAMBDA
    t1 = 2 * h * material["n"] / C_M_PER_NS
    edges = np.array([0.0, 0.99 * t1, 1.5 * t1, 1e6])
    p = medium(texture="slab", thickness=h, extinction=tau0 / h, omega=0.0, albedo=0.15,
               time_edges=edges, mode=mode, **material)
    c = engine.run(p, photons)
    arrays = reduce_counts(c, p)
    width = edges[2] - edges[1]
    energy = arrays["hemispherical_reflectance"][1, 1] * width
    scale = arrays["reflectance"][1, 1] / energy if energy > 0 else 0.0
    stderr = arrays["reflectance_stderr"][1, 1] / scale if scale else 0.0
    return energy, stderr, c


@pytest.mark.slow
@pytest.mark.parametrize("material, paper_value", [(H2O, 1.4728e-15), (CO2, 0.025999)])
def test_paper_pure_slab_values_to_one_percent(engine, material, paper_value):
    """docs/physics.md §8: the paper's "analytical solution", (1 - R0)^2 R0 exp(-2 tau0): 1.47e-15
    for 1000 mm of water ice and 0.026 for CO2, reproduced to 1 % by the weighted walk. Its
    only randomness is the Fresnel draws, so 1.5e7 rays give a relative standard error of
    0.2 %: 5 sigma is inside 1 %."""
    r0 = radiative.normal_reflectance(**material)
    tau0 = 4 * np.pi * material["k"] / LAMBDA
    analytic = (1 - r0) ** 2 * r0 * np.exp(-2 * tau0)
    assert analytic == pytest.approx(paper_value, rel=2e-4)
    energy, stderr, _ = _first_bf_peak(engine, material, 15_000_000, "weighted")
    assert 5 * stderr < 0.01 * analytic
    assert abs(energy - analytic) < 5 * stderr


@pytest.mark.slow
def test_analog_mode_sees_nothing_of_the_water_ice_peak(engine):
    """Where the weighted walk measures 1.47e-15, the analog one has not a single ray."""
    energy, _, c = _first_bf_peak(engine, H2O, 1_000_000, "analog")
    assert energy == 0.0 and c.time_any[1].sum() == 0


def test_weighted_and_analog_agree_in_a_scattering_slab(engine):
    """Same medium, both modes: every component's fraction and the diffuse time histograms
    agree within 5 combined standard errors (roulette and weighting are unbiased)."""
    edges = np.concatenate([[0.0], np.geomspace(0.01, 2.0, 16)])   # ns, coarse bins
    wide = (90.0, 90.0, 60.0, 60.0)                                 # deg, many rays per bin
    p_a = medium(**SCATTERING, seed=11, time_edges=edges, fov=wide)
    p_w = medium(**SCATTERING, seed=12, mode="weighted", roulette_weight=0.01, time_edges=edges,
                 fov=wide)
    n = 200_000
    a, w = engine.run(p_a, n), engine.run(p_w, n)
    frac_a = a.total / n
    sig_a = np.sqrt(frac_a * (1 - frac_a) / n)
    mean_w = fixed_to_float(w.w_total) / n
    sig_w = np.sqrt(np.maximum(fixed_to_float(w.w2_total) / n - mean_w ** 2, 0) / n)
    assert np.all(np.abs(frac_a - mean_w) < 5 * np.sqrt(sig_a ** 2 + sig_w ** 2) + 1e-12)
    ra, rw = reduce_counts(a, p_a), reduce_counts(w, p_w)
    for c in (2, 3):
        sel = (ra["ray_count"][c] >= 20) & (rw["ray_count"][c] >= 20)
        diff = ra["reflectance"][c, sel] - rw["reflectance"][c, sel]
        sigma = np.hypot(ra["reflectance_stderr"][c, sel], rw["reflectance_stderr"][c, sel])
        assert sel.sum() >= 8
        assert np.all(np.abs(diff) < 5 * sigma), c
