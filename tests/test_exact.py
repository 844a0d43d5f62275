"""Exact sampling in single precision (issue 10 §4): the absorption rule on the raw Philox word,
the stable Henyey-Greenstein form, early exits counted apart, 64-bit scenario keys, and weights
the exact tallies cannot hold.

Monte Carlo tolerances are 5 standard errors (false alarm ~6e-7 per assertion), written next
to each assertion.
"""
from __future__ import annotations

import math

import numpy as np
import pyopencl as cl
import pytest

from conftest import medium
from warpe_cl import rng
from warpe_cl.api import scenario_key
from warpe_cl.config import load_preset
from warpe_cl.errors import WeightError
from warpe_cl.params import WalkParams, word_threshold
from warpe_cl.reference import simulate_reference

# ----------------------------------------------------------------- 1. absorption near omega = 1


@pytest.mark.parametrize("q", [3e-7, 3e-6, 1e-4, 3.38e-6, 0.5])
def test_absorption_threshold_is_exact(q):
    """P(absorb) = (2^32 - T) 2^-32 with T = word_threshold(omega), within 2^-33 of 1 - omega
    (so within 0.1 % of it down to 1 - omega = 1.2e-7), the same in every precision; exhaustive,
    since the rule is monotone in the word: x >= T absorbs, and T is the first word whose exact
    uniform (x + 1/2) 2^-32 exceeds omega."""
    omega = 1.0 - q
    T = word_threshold(omega)
    p_absorb = (2 ** 32 - T) / 2 ** 32
    assert abs(p_absorb - (1 - omega)) <= 2.0 ** -33
    assert abs(p_absorb / (1 - omega) - 1) < 1e-3
    # T is the boundary: U(T - 1) <= omega < U(T), with U exact in double
    u = rng.uniform_from_uint32(np.array([T - 1, T], dtype=np.uint32), "double")
    assert u[0] <= omega < u[1]


def test_absorption_threshold_extremes():
    assert word_threshold(0.0) == 0            # omega = 0 always absorbs (every x >= 0)
    assert word_threshold(1.0) == 2 ** 32      # omega = 1 never does (no x >= 2^32)
    assert word_threshold(float("nan")) == 0
    assert word_threshold(0.5) == 2 ** 31


@pytest.mark.parametrize("precision", ["single", "double"])
def test_kernel_word_rule_at_the_threshold(engine, selftest, precision):
    """The kernel's rule (philox.h word_at_least) at the words that decide it: the threshold,
    its neighbours, and the ends of the range, for omega = 0, 1 and near 1."""
    prog = selftest[precision]
    words = np.array([0, 1, 2 ** 31, 2 ** 32 - 2, 2 ** 32 - 1], dtype=np.uint32)
    for omega in (0.0, 1.0, 1 - 3e-7, 1 - 3e-6, 1 - 1e-4, 0.15):
        T = word_threshold(omega)
        x = np.unique(np.concatenate([words, np.clip([T - 1, T, T + 1], 0, 2 ** 32 - 1)
                                      .astype(np.uint32)]))
        out = np.zeros(len(x), dtype=np.int32)
        mf = cl.mem_flags
        d_x = cl.Buffer(engine.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
        d_out = cl.Buffer(engine.context, mf.WRITE_ONLY, out.nbytes)
        prog.word_events(engine.queue, (len(x),), None, np.uint64(T), d_x, d_out)
        cl.enqueue_copy(engine.queue, out, d_out)
        np.testing.assert_array_equal(out, (x.astype(np.int64) >= T).astype(np.int32),
                                      err_msg=str(omega))


@pytest.mark.slow
def test_single_and_double_absorb_the_same_rays(engine):
    """Paired: the same photons (same seed) in single and double precision, in a conservative
    granular medium (1 - omega = 3.01e-6, where the old float test u1 > omega absorbed 2.0 %
    too rarely) so deep that rays only leave through the top, up to 2e4 flights.

    Both precisions decide an absorption on the same word with the same integer threshold, so a
    ray's fate can differ only where rounding made its history diverge (a flight ending within
    rounding of the top); such a diverged ray is as likely absorbed in either precision. Bound:
    with M the photons whose fates (absorbed or not) differ, |A_single - A_double| <= 5 sqrt(M)
    (5 sigma of a sum of M independent +-1). The old rule gave A_single - A_double ~ -M with
    M ~ 40 here (6.7e8 collisions x 6e-8); measured with the exact rule: M = 0."""
    params = WalkParams(texture="granular", bottom_interface="none", thickness=1.0,
                        extinction=1e4, omega=1 - 3.01e-6, g=0.0, n=1.3, k=0.0, albedo=1.0,
                        time_edges=np.array([1e-3, 1e7]), max_time=1e7, max_flights=20_000,
                        seed=3)
    n = 1_500_000
    single = engine.run(params, n, precision="single", records=True)
    double = engine.run(params, n, precision="double", records=True)
    a_s, a_d = int(single.fates[2]), int(double.fates[2])
    assert a_d > 1000            # the test has power: ~2000 absorptions
    m = int(np.sum((single.records["fate"] == 2) != (double.records["fate"] == 2)))
    assert abs(a_s - a_d) <= 5 * math.sqrt(m), (a_s, a_d, m)


# ----------------------------------------------------------------- 2. Henyey-Greenstein


def _hg_cosines(engine, selftest, precision, g, n):
    real = np.float64 if precision == "double" else np.float32
    hg = np.zeros(n, dtype=real)
    lam = np.zeros(n, dtype=real)
    mf = cl.mem_flags
    d_hg = cl.Buffer(engine.context, mf.WRITE_ONLY, hg.nbytes)
    d_lam = cl.Buffer(engine.context, mf.WRITE_ONLY, lam.nbytes)
    selftest[precision].sample_directions(engine.queue, (n,), None, np.uint32(5), real(g),
                                          d_hg, d_lam)
    cl.enqueue_copy(engine.queue, hg, d_hg)
    return hg.astype(np.float64)


@pytest.mark.slow
@pytest.mark.parametrize("precision", ["single", "double"])
@pytest.mark.parametrize("g", [1e-3, -1e-3, 1e-5, -1e-5, 1e-7, -1e-7, 0.8, -0.8, 0.0])
def test_hg_moments(engine, selftest, precision, g):
    """<cos> = g and <cos^2> = (1 + 2 g^2)/3 (HG: <P_l> = g^l), within 5 standard errors of
    2e6 samples: sigma(<cos>) = sqrt(<cos^2> - g^2)/sqrt(N) = 4e-4, and
    sigma(<cos^2>) = sqrt(<cos^4> - <cos^2>^2)/sqrt(N) with <cos^4> = (8 g^4 + 20 g^2 + 7)/35.
    The old form gave <cos> = -0.003 at g = 1e-5 and -0.34 at g = 1e-7 in float."""
    n = 2_000_000
    c = _hg_cosines(engine, selftest, precision, g, n)
    assert np.all(np.abs(c) <= 1)
    m2 = (1 + 2 * g * g) / 3
    m4 = (8 * g ** 4 + 20 * g * g + 7) / 35
    assert abs(c.mean() - g) < 5 * math.sqrt((m2 - g * g) / n)
    assert abs((c * c).mean() - m2) < 5 * math.sqrt((m4 - m2 * m2) / n)


def test_hg_form_equals_the_classic_one_in_double():
    """The stable form is an exact rewrite: in double it agrees with the classic formula to
    rounding where the classic one is well conditioned (|g| >= 0.01)."""
    from warpe_cl.reference import henyey_greenstein_cosine
    u = np.linspace(1e-6, 1, 2001)
    for g in (-0.99, -0.5, -0.01, 0.01, 0.3, 0.8, 0.99):
        f = (1 - g * g) / (1 - g + 2 * g * u)
        classic = (1 + g * g - f * f) / (2 * g)
        new = np.array([henyey_greenstein_cosine(g, x) for x in u])
        np.testing.assert_allclose(new, classic, atol=1e-12, rtol=0)
    assert henyey_greenstein_cosine(0.0, 0.25) == -0.5
    assert henyey_greenstein_cosine(0.7, 1.0) == 1.0


# ----------------------------------------------------------------- 3. early exits


@pytest.mark.parametrize("precision", ["single", "double"])
@pytest.mark.parametrize("mode", ["analog", "weighted"])
def test_early_exits_are_counted_apart(engine, precision, mode):
    """A first edge set late (0.05 ns, inside the bulk of a 10 mm granular layer's exits):
    early_fraction is exactly the fraction of exits with t < edges[0] in the per-photon records,
    per component, and bin 0 holds only exits with edges[0] <= t < edges[1]."""
    edges = np.array([0.05, 0.07, 0.1, 0.2, 0.5, 1.0, 10.0])
    params = medium(texture="granular", extinction=200.0, omega=0.95, g=0.5, n=1.36, k=0.0,
                    albedo=0.5, time_edges=edges, mode=mode)
    n = 20_000
    for counts in (engine.run(params, n, precision=precision, records=True),
                   simulate_reference(params, 3000, records=True)):
        rec = counts.records
        t, comp = rec["time_ns"], rec["component"]
        exited = comp >= 0
        early = exited & (t < edges[0])
        assert early.sum() > 0.05 * counts.photons
        for c in range(4):
            assert counts.early[c] == np.sum(early & (comp == c))
            in_bin0 = exited & (comp == c) & (t >= edges[0]) & (t < edges[1])
            assert counts.time_any[c, 0] == in_bin0.sum()
        assert np.all(rec["time_bin"][early] == -2)
        assert counts.total.sum() == exited.sum()
        if mode == "weighted":
            from warpe_cl.params import fixed_to_float
            w_early = [rec["weight"][early & (comp == c)].sum() for c in range(4)]
            np.testing.assert_allclose(fixed_to_float(counts.w_early), w_early, rtol=1e-5)


def test_early_fraction_in_the_output(engine):
    from warpe_cl import dataset, tally
    edges = np.array([0.05, 0.1, 1.0])
    params = medium(texture="granular", extinction=200.0, omega=0.95, g=0.5, n=1.36, k=0.0,
                    albedo=0.5, time_edges=edges)
    counts = engine.run(params, 5000)
    arrays = tally.reduce_counts(counts, params)
    np.testing.assert_array_equal(arrays["early_fraction"], counts.early / 5000)
    ds = dataset.build_dataset(arrays, counts, params, {}, {})
    assert ds["early_fraction"].attrs["units"] == "1" and "long_name" in ds["early_fraction"].attrs
    # split launches add up to the whole run, early exits included
    part = engine.run(params, 2000)
    part += engine.run(params, 3000, first_photon=2000)
    assert part.same_as(counts) and part.early.sum() > 0


# ----------------------------------------------------------------- 4. scenario keys

BASE = {"medium": {"texture": "slab", "thickness": "10 mm", "bottom_albedo": 0.3,
                   "radiative": {"tau0": 1.0, "omega": 0.5, "n": 1.3}},
        "simulation": {"photons": 1000, "time_bins": {"start": "1e-3 ns", "stop": "10 ns",
                                                      "per_decade": 5}}}


def _leaves(tree, prefix=""):
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from _leaves(v, f"{prefix}.{k}" if prefix else k)
    else:
        yield prefix


def _perturbed(value):
    if isinstance(value, bool):
        return not value
    if isinstance(value, (int, float)):
        return value * 1.0000001 + 1e-300 if value else 1e-9
    if value is None:
        return "x"
    return str(value) + "x"


def test_every_value_changes_the_scenario_key():
    """Any single value of the resolved medium or simulation blocks (seed, photons and the
    nadir estimator's keys apart) gives another 64-bit key, hence other streams; seed and
    photons do not change it, nor do the estimator's keys (it draws no number: the same rays
    at any view, docs/walk.md §8)."""
    import copy
    from warpe_cl.api import UNKEYED
    cfg = load_preset(BASE)
    base = scenario_key(None, cfg)
    assert 0 < base < 2 ** 64
    assert scenario_key(None, cfg.with_overrides({"simulation.seed": 9})) == base
    assert scenario_key(None, cfg.with_overrides({"simulation.photons": 99})) == base
    assert scenario_key(None, cfg.with_overrides({"simulation.nadir": False,
                                                  "simulation.view_zenith": "30 deg",
                                                  "simulation.nadir_roulette": 0.0})) == base
    checked = 0
    for block in ("medium", "simulation"):
        for leaf in _leaves(cfg.data[block], block):
            if leaf in UNKEYED:
                continue
            data = copy.deepcopy(cfg.data)
            node = data
            parts = leaf.split(".")
            for p in parts[:-1]:
                node = node[p]
            node[parts[-1]] = _perturbed(node[parts[-1]])
            assert scenario_key(None, data) != base, leaf
            checked += 1
    assert checked > 20
    # real presets: equal values elsewhere no longer share a key (it was 0 for every run)
    other = load_preset({**BASE, "medium": {**BASE["medium"], "texture": "granular"}})
    k2 = scenario_key(None, other)
    assert k2 != base
    a = rng.photon_draws(1, base, 0, 8)
    b = rng.photon_draws(1, k2, 0, 8)
    assert not np.any(a == b)


@pytest.mark.parametrize("precision", ["single", "double"])
def test_key_high_word_is_in_the_kernel_streams(engine, selftest, precision):
    """The 64-bit key: low word in the Philox key, high word in counter word 3, in the kernel
    as in NumPy (a high word of 0 is the layout of the known-answer tests)."""
    real = np.float64 if precision == "double" else np.float32
    key = 0x89ABCDEF_01234567
    out = np.zeros((4, 8), dtype=real)
    d_out = cl.Buffer(engine.context, cl.mem_flags.WRITE_ONLY, out.nbytes)
    selftest[precision].photon_uniforms(engine.queue, (4,), None, np.uint32(7), np.uint64(key),
                                        np.uint64(3), np.int32(8), d_out)
    cl.enqueue_copy(engine.queue, out, d_out)
    for i in range(4):
        expected = rng.photon_draws(7, key, 3 + i, 8, precision=precision)
        np.testing.assert_array_equal(out[i], expected.astype(real))
    words = rng.philox4x32(np.array([0, 3, 0, key >> 32], dtype=np.uint32),
                           np.array([7, key & 0xFFFFFFFF], dtype=np.uint32))
    np.testing.assert_array_equal(rng.uniform_from_uint32(words), rng.photon_draws(7, key, 3, 4))


def test_walk_with_a_64_bit_key_follows_the_reference(engine):
    params = medium(scenario=0xFEDCBA98_76543210)
    ref = simulate_reference(params, 500, records=True)
    ker = engine.run(params, 500, precision="double", records=True)
    np.testing.assert_array_equal(ker.records["n_scat"], ref.records["n_scat"])
    assert ker.same_as(ref)
    assert not ker.same_as(engine.run(medium(scenario=0x76543210), 500, precision="double"))


def test_point_alone_equals_point_in_a_grid():
    """The same point run alone and inside a sweep grid: same key, same counts."""
    from warpe_cl import api
    grid = load_preset({**BASE, "sweep": {"medium.thickness": ["5 mm", "10 mm", "20 mm"]}})
    alone = load_preset(BASE)
    (_, in_grid), = [(p, c) for p, c in grid.sweep_points() if p["medium.thickness"] == "10 mm"]
    assert scenario_key(None, in_grid) == scenario_key(None, alone)
    a = api.simulate_point(alone, device="numpy", progress=False)
    b = api.simulate_point(in_grid, {"medium.thickness": "10 mm"}, device="numpy", progress=False)
    assert a.attrs["scenario_key"] == b.attrs["scenario_key"]
    assert len(a.attrs["scenario_key"]) == 16
    for name in ("ray_count", "fraction", "fate_fraction", "early_fraction"):
        np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)


# ----------------------------------------------------------------- 5. lost weights


@pytest.mark.parametrize("omega", [float("nan"), 1.6])
def test_weights_the_tallies_cannot_hold_raise(engine, omega):
    """NaN (omega = NaN) or huge weights (omega = 1.6: the weight grows as exp(0.6 E L) along
    the path and passes 2^21) are refused by the kernel (both precisions) and the reference."""
    params = medium(mode="weighted", omega=omega, extinction=3000.0, thickness=0.01)
    for precision in ("single", "double"):
        with pytest.raises(WeightError, match="ray"):
            engine.run(params, 2000, precision=precision)
    with pytest.raises(WeightError, match="ray"):
        simulate_reference(params, 300)


def test_lost_weights_exit_1_from_the_cli(tmp_path, capsys, monkeypatch):
    from warpe_cl import api
    from warpe_cl.cli import main

    def boom(*args, **kw):
        raise WeightError(3)
    monkeypatch.setattr(api, "simulate_point", boom)
    preset = tmp_path / "p.yaml"
    import yaml
    preset.write_text(yaml.safe_dump(BASE))
    assert main(["run", str(preset), "--out", str(tmp_path / "o.nc"), "--quiet",
                 "--device", "numpy"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "3 exiting ray(s)" in err[0]
    assert not (tmp_path / "o.nc").exists()


# ----------------------------------------------------------------- 6. fixed-point words

FIXED_WORDS_KERNEL = """
__kernel void fixed_words_of(__global const REAL *w, __global ulong *out)
{
    const size_t i = get_global_id(0);
    ulong lo, mid, hi;
    fixed_words(w[i], &lo, &mid, &hi);
    out[3 * i] = lo;
    out[3 * i + 1] = mid;
    out[3 * i + 2] = hi;
}
"""


@pytest.mark.parametrize("precision", ["single", "double"])
def test_fixed_words_are_the_exact_floor(engine, precision):
    """tally.h fixed_words (the exact sums of the weighted mode and of the nadir estimate,
    docs/walk.md §6, §8.2) gives floor(w 2^FIXED_SHIFT) as three 64-bit words, exactly, for
    weights that use every branch of its shifts: subnormal, the smallest and largest normal
    numbers, weights that land below 2^-FIXED_SHIFT (0), straddle a word boundary or lie next
    to MAX_WEIGHT; compared with Python integers."""
    from warpe_cl.device import assemble_source, build_source, program_files
    from warpe_cl.engine import layout_options
    from warpe_cl.params import FIXED_SHIFT, MAX_WEIGHT
    if precision == "double" and not engine.info.fp64:
        pytest.skip("device has no fp64")  # pragma: no cover - PoCL and NVIDIA have fp64
    real = np.float64 if precision == "double" else np.float32
    info = np.finfo(real)
    w = [info.smallest_subnormal, 3 * info.smallest_subnormal, info.smallest_normal,
         np.nextafter(info.smallest_normal, real(0)), 2.0 ** -151, 2.0 ** -150, 2.0 ** -149.5,
         2.0 ** -86, 2.0 ** -87.3, 2.0 ** -22, 2.0 ** -23.7, 1e-20, 1e-3, 0.1, 1.0 / 3, 1.0,
         2.0 ** 14 * 1.7, np.nextafter(real(MAX_WEIGHT), real(0))]
    w += list(np.random.default_rng(6).lognormal(-20.0, 12.0, 300))
    w = np.array([x for x in w if 0 < x < MAX_WEIGHT], dtype=real)
    options = list(layout_options()) + ["-DWARPE_NADIR", "-DWARPE_LANES=1"]
    if precision == "double":
        options.append("-DWARPE_DOUBLE")
    source = (assemble_source(program_files(("real.h", "lanes.h", "tally.h"), options))
              + FIXED_WORDS_KERNEL)
    prog = build_source(engine.context, source, options)
    out = np.zeros((len(w), 3), dtype=np.uint64)
    mf = cl.mem_flags
    d_w = cl.Buffer(engine.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=w)
    d_out = cl.Buffer(engine.context, mf.WRITE_ONLY, out.nbytes)
    prog.fixed_words_of(engine.queue, (len(w),), None, d_w, d_out)
    cl.enqueue_copy(engine.queue, out, d_out)
    from fractions import Fraction
    for x, words in zip(w, out):
        expected = math.floor(Fraction(float(x)) * 2 ** FIXED_SHIFT)
        got = int(words[0]) + (int(words[1]) << 64) + (int(words[2]) << 128)
        assert got == expected, (float(x), got, expected)
