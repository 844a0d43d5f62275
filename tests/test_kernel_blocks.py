"""The kernel's building blocks against NumPy: Philox, uniforms, HG and Lambert samplers,
Fresnel laws. Monte Carlo tolerances are 5 standard errors (false alarm ~6e-7 per check)."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from scipy import stats

from warpe_cl import radiative, rng

KAT = [  # Random123 kat_vectors, philox4x32_10
    ((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
    ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
    ((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0),
     (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1)),
]


def _run(engine, kernel, n, *args):
    kernel(engine.queue, (n,), None, *args)  # one retrieval per call: these kernels run once
    engine.queue.finish()


def test_philox_known_answers_in_kernel(engine, selftest):
    ctx = engine.context
    ctr = np.array([k[0] for k in KAT], dtype=np.uint32)
    key = np.array([k[1] for k in KAT], dtype=np.uint32)
    mf = cl.mem_flags
    d_ctr = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=ctr)
    d_key = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=key)
    out = np.zeros((len(KAT), 4), dtype=np.uint32)
    d_out = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    _run(engine, selftest["single"].philox_kat, len(KAT), d_ctr, d_key, d_out)
    cl.enqueue_copy(engine.queue, out, d_out)
    assert out.tolist() == [list(k[2]) for k in KAT]


@pytest.mark.parametrize("precision", ["single", "double"])
def test_kernel_streams_equal_numpy(engine, selftest, precision):
    """The kernel's uniforms are bit-identical to the NumPy generator's, for photons beyond
    2^32 too (the photon index fills two counter words)."""
    if precision not in selftest:
        pytest.skip("device has no fp64")  # pragma: no cover - PoCL and NVIDIA have fp64
    real = np.float64 if precision == "double" else np.float32
    n_photons, n_draws, first = 64, 11, 2 ** 32 - 20
    out = np.zeros((n_photons, n_draws), dtype=real)
    d_out = cl.Buffer(engine.context, cl.mem_flags.WRITE_ONLY, out.nbytes)
    _run(engine, selftest[precision].photon_uniforms, n_photons, np.uint32(12345),
         np.uint64(678), np.uint64(first), np.int32(n_draws), d_out)
    cl.enqueue_copy(engine.queue, out, d_out)
    for i in range(n_photons):
        words = np.concatenate([
            rng.philox4x32(np.array([b, (first + i) & 0xFFFFFFFF, (first + i) >> 32, 0],
                                    dtype=np.uint32), np.array([12345, 678], dtype=np.uint32))
            for b in range(3)])[:n_draws]
        expected = rng.uniform_from_uint32(words, precision=precision)
        np.testing.assert_array_equal(out[i], expected.astype(real))


def _directions(engine, selftest, g, n):
    hg = np.zeros(n, dtype=np.float32)
    lam = np.zeros(n, dtype=np.float32)
    mf = cl.mem_flags
    d_hg = cl.Buffer(engine.context, mf.WRITE_ONLY, hg.nbytes)
    d_lam = cl.Buffer(engine.context, mf.WRITE_ONLY, lam.nbytes)
    _run(engine, selftest["single"].sample_directions, n, np.uint32(99), np.float32(g), d_hg, d_lam)
    cl.enqueue_copy(engine.queue, hg, d_hg)
    cl.enqueue_copy(engine.queue, lam, d_lam)
    return hg.astype(float), lam.astype(float)


@pytest.mark.parametrize("g", [0.8, 0.0, -0.5])
def test_hg_sampler_mean_and_distribution(engine, selftest, g):
    n = 4_000_000
    cos_t, _ = _directions(engine, selftest, g, n)
    # mean cos(Theta) = g; Var = <cos^2> - g^2 with <cos^2> = (1 + 2 g^2)/3 for HG
    sigma = np.sqrt((1 + 2 * g * g) / 3 - g * g) / np.sqrt(n)
    assert abs(cos_t.mean() - g) < 5 * sigma
    # binned against the HG cumulative distribution: chi2 with 39 dof, p > 1e-6
    edges = np.linspace(-1, 1, 41)
    if g == 0:
        cdf = (edges + 1) / 2
    else:
        cdf = (1 - g * g) / (2 * g) * (1 / np.sqrt(1 + g * g - 2 * g * edges) - 1 / (1 + g))
    expected = n * np.diff(cdf)
    observed, _ = np.histogram(cos_t, edges)
    chi2 = np.sum((observed - expected) ** 2 / expected)
    assert stats.chi2.sf(chi2, len(expected) - 1) > 1e-6


def test_lambert_sampler(engine, selftest):
    n = 4_000_000
    _, mu = _directions(engine, selftest, 0.8, n)
    # <mu> = 2/3, Var(mu) = 1/2 - 4/9 = 1/18
    assert abs(mu.mean() - 2 / 3) < 5 * np.sqrt(1 / 18 / n)
    # cos-weighted: P(mu < x) = x^2
    edges = np.linspace(0, 1, 41)
    expected = n * np.diff(edges ** 2)
    observed, _ = np.histogram(mu, edges)
    chi2 = np.sum((observed - expected) ** 2 / expected)
    assert stats.chi2.sf(chi2, len(expected) - 1) > 1e-6


@pytest.mark.parametrize("n_k", [(1.30042, 1.272e-6), (1.4026, 8.47e-10), (1.92, 9.5e-6),
                                 (1.5, 0.3), (1.0, 0.0)])
def test_kernel_fresnel_matches_host(engine, selftest, n_k):
    n, k = n_k
    mu = np.linspace(0, 1, 1001)
    for precision, tol in (("single", 2e-6), ("double", 1e-13)):
        if precision not in selftest:
            continue  # pragma: no cover
        real = np.float64 if precision == "double" else np.float32
        mu_r = mu.astype(real)
        ext = np.zeros_like(mu_r)
        inn = np.zeros_like(mu_r)
        mf = cl.mem_flags
        d_mu = cl.Buffer(engine.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=mu_r)
        d_ext = cl.Buffer(engine.context, mf.WRITE_ONLY, ext.nbytes)
        d_in = cl.Buffer(engine.context, mf.WRITE_ONLY, inn.nbytes)
        _run(engine, selftest[precision].fresnel_grid, len(mu), d_mu, real(n), real(k), d_ext, d_in)
        cl.enqueue_copy(engine.queue, ext, d_ext)
        cl.enqueue_copy(engine.queue, inn, d_in)
        np.testing.assert_allclose(
            ext, radiative.fresnel_external(mu_r.astype(float), float(real(n)), float(real(k))),
            atol=tol, rtol=0)
        # R_int has an infinite slope at the critical angle: a float32 rounding (eps = 6e-8) of
        # cos_t^2 = (1 - n^2) + n^2 mu^2 moves cos_t by eps n^2 / (2 cos_t), and R by at most
        # |dR/dcos_t| <= 4 times that. The double kernel pins the formula to 1e-13 everywhere;
        # the single one gets this conditioning bound added to its tolerance.
        tol_in = tol
        if precision == "single":
            cos_t2 = (1 - n * n) + n * n * mu ** 2
            cos_t = np.sqrt(np.where(cos_t2 > 0, cos_t2, np.inf))
            tol_in = tol + 4 * 6e-8 * n * n / (2 * cos_t)
        # the kernel sees n rounded to its precision; near the critical angle that matters
        host_in = radiative.fresnel_internal(mu_r.astype(float), float(real(n)))
        assert np.all(np.abs(inn - host_in) <= tol_in)


def _complex_fresnel(mu, m):
    """Plain complex-arithmetic Fresnel, vacuum -> m (an independent route to Hapke's form)."""
    sin2 = 1 - mu ** 2
    cos_t = np.sqrt(1 - sin2 / m ** 2 + 0j)
    rs = (mu - m * cos_t) / (mu + m * cos_t)
    rp = (m * mu - cos_t) / (m * mu + cos_t)
    return 0.5 * (abs(rs) ** 2 + abs(rp) ** 2)


@pytest.mark.parametrize("n,k", [(1.3, 0.0), (1.92, 9.5e-6), (2.5, 1.0), (1.4026, 8.47e-10)])
def test_hapke_fresnel_equals_complex_fresnel(n, k):
    mu = np.linspace(0.0, 1.0, 501)
    np.testing.assert_allclose(radiative.fresnel_external(mu, n, k), _complex_fresnel(mu, n + 1j * k),
                               rtol=1e-10, atol=1e-12)
    assert radiative.fresnel_external(1.0, n, k) == pytest.approx(radiative.normal_reflectance(n, k),
                                                                  rel=1e-12)


@pytest.mark.parametrize("n", [1.30042, 1.4026, 1.0786, 1.4764, 1.92])
def test_hemispherical_reciprocity(n):
    """docs/physics.md §8 check 6: S_i = 1 - (1 - S_e)/n^2 (and the §3.6 table)."""
    s_e = radiative.hemispherical_external(n, 0.0)
    s_i = radiative.hemispherical_internal(n)
    assert s_i == pytest.approx(1 - (1 - s_e) / n ** 2, abs=1e-7)


def test_hemispherical_table():
    table = {1.30042: (0.0612, 0.4449), 1.4026: (0.0772, 0.5309), 1.0786: (0.0205, 0.1581),
             1.4764: (0.0883, 0.5817)}
    for n, (s_e, s_i) in table.items():
        assert radiative.hemispherical_external(n) == pytest.approx(s_e, abs=6e-5)
        assert radiative.hemispherical_internal(n) == pytest.approx(s_i, abs=6e-5)


def test_division_sqrt_and_products_round_once(engine, selftest):
    """a / b, sqrt(a) and a * b + c in single precision, bit for bit as NumPy rounds them
    (IEEE 754: each operation rounded once, no fused multiply-add), over 2^18 operands spread
    over 2^-30 .. 2^30 in magnitude, b and c of either sign. Every result of the walk is made of
    these: NVIDIA's driver divides 2.5 ulp off unless the program is built with
    -cl-fp32-correctly-rounded-divide-sqrt (warpe_cl/device.py EXACT_DIVIDE_SQRT), and its
    walks of the paper's presets left the CPUs' bits by a ray (issue 43)."""
    gen = np.random.default_rng(43)
    n = 2 ** 18

    def operands(signed):
        x = np.ldexp(gen.uniform(0.5, 1.0, n), gen.integers(-30, 31, n)).astype(np.float32)
        return x * np.where(gen.random(n) < 0.5, -1, 1).astype(np.float32) if signed else x
    a, b, c = operands(False), operands(True), operands(True)
    out = np.zeros(3 * n, dtype=np.float32)
    mf = cl.mem_flags
    bufs = [cl.Buffer(engine.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
            for x in (a, b, c)]
    d_out = cl.Buffer(engine.context, mf.WRITE_ONLY, out.nbytes)
    _run(engine, selftest["single"].exact_ops, n, *bufs, d_out)
    cl.enqueue_copy(engine.queue, out, d_out)
    quotient, root, product_sum = out.reshape(3, n)
    np.testing.assert_array_equal(quotient.view(np.uint32), (a / b).view(np.uint32))
    np.testing.assert_array_equal(root.view(np.uint32), np.sqrt(a).view(np.uint32))
    np.testing.assert_array_equal(product_sum.view(np.uint32), (a * b + c).view(np.uint32))


def test_walk_math_accuracy(engine, selftest):
    """The walk's elementary functions in single precision (scatter.h: correctly rounded
    operations only, the same bits on every device): the optical step -ln U (Cephes' logf)
    within 1 ulp of the correctly rounded float of -ln U, and the azimuth's sine and cosine
    of 2 pi U (Cephes' sinf and cosf after an exact reduction of U) within 2e-7 absolute: the
    float of 2 pi is 2.8e-8 relative off, and the polynomials within an ulp of values below 1.
    Checked on 2^20 uniforms spread over (0, 1], the extreme words and the words around the
    log's switch at U = sqrt(1/2) included. Measured (2026-11-23, Intel's CPU runtime and PoCL
    3.0 on Zen 3, the same values): at most 1.0 ulp, 0.07 on average; 1.01e-7 on sin and cos.
    The device's native_log and native_sin/cos, which the walk used before, were 1e-4
    relative off (the log, Intel's runtime on this CPU) and 4.2e-7 (both devices)."""
    switch = int(np.sqrt(0.5) * 2 ** 32)
    words = np.concatenate([np.arange(0, 2 ** 32, 4096, dtype=np.uint64),
                            np.arange(switch - 4096, switch + 4096, dtype=np.uint64),
                            [2 ** 32 - 1, 2 ** 32 - 2, 0, 1]]).astype(np.uint32)
    u = rng.uniform_from_uint32(words, precision="single").astype(np.float32)
    out = np.zeros((len(u), 3), dtype=np.float32)
    mf = cl.mem_flags
    d_u = cl.Buffer(engine.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=u)
    d_out = cl.Buffer(engine.context, mf.WRITE_ONLY, out.nbytes)
    _run(engine, selftest["single"].walk_math, len(u), d_u, d_out)
    cl.enqueue_copy(engine.queue, out, d_out)
    u64 = u.astype(np.float64)
    nearest = (-np.log(u64)).astype(np.float32)      # the correctly rounded float of -ln U
    ulp = np.spacing(np.maximum(nearest, np.finfo(np.float32).tiny)).astype(np.float64)
    assert np.all(np.abs(out[:, 0].astype(np.float64) - nearest) <= ulp)
    assert np.all(np.abs(out[:, 1] - np.sin(2 * np.pi * u64)) <= 2e-7)
    assert np.all(np.abs(out[:, 2] - np.cos(2 * np.pi * u64)) <= 2e-7)


@pytest.mark.parametrize("lanes", [1, 2, 4, 8, 16])
def test_lane_bits_at_every_width(engine, lanes):
    """lanes.h lane_bits (one bit per true lane: an OR reduction of the lanes' bits, or from
    the mask's bytes by one multiply per 8 lanes), which the nadir estimate's flushes use to
    find their lanes, and ANY and ALL, which every step of the walk tests: every mask of every
    lane width gives its own bits, lane j on bit j, ANY iff some lane is set, ALL iff every
    lane is."""
    from warpe_cl.device import SELFTEST_FILES, build_program
    prog = build_program(engine.device, SELFTEST_FILES, (f"-DWARPE_LANES={lanes}",))
    pattern = np.arange(2 ** lanes, dtype=np.uint32)
    out = np.zeros((len(pattern), 3), dtype=np.uint32)
    mf = cl.mem_flags
    d_p = cl.Buffer(engine.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=pattern)
    d_out = cl.Buffer(engine.context, mf.WRITE_ONLY, out.nbytes)
    _run(engine, prog.lane_bits_of, len(pattern), d_p, d_out)
    cl.enqueue_copy(engine.queue, out, d_out)
    np.testing.assert_array_equal(out[:, 0], pattern)
    np.testing.assert_array_equal(out[:, 1], pattern != 0)
    np.testing.assert_array_equal(out[:, 2], pattern == 2 ** lanes - 1)


def test_lowest_lane_of_every_bit(engine):
    """lanes.h lowest_lane, the lane the nadir flushes visit next (from a float's exponent): the
    index of the lowest set bit at each of the 32 positions, alone, under every higher bit, and
    under random higher bits."""
    from warpe_cl.device import SELFTEST_FILES, build_program
    prog = build_program(engine.device, SELFTEST_FILES, ("-DWARPE_LANES=1",))
    rng = np.random.default_rng(5)
    k = np.repeat(np.arange(32, dtype=np.uint64), 3)
    high = np.stack([np.zeros(32, np.uint64), np.full(32, 0xFFFFFFFF, np.uint64),
                     rng.integers(0, 2 ** 32, 32, dtype=np.uint64)], axis=1).ravel()
    pattern = (((high >> k) << k) | (np.uint64(1) << k)).astype(np.uint32)
    out = np.zeros(len(pattern), dtype=np.int32)
    mf = cl.mem_flags
    d_p = cl.Buffer(engine.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=pattern)
    d_out = cl.Buffer(engine.context, mf.WRITE_ONLY, out.nbytes)
    _run(engine, prog.lowest_lane_of, len(pattern), d_p, d_out)
    cl.enqueue_copy(engine.queue, out, d_out)
    np.testing.assert_array_equal(out, k.astype(np.int32))


@pytest.mark.parametrize("builtins", [False, True])
@pytest.mark.parametrize("lanes", [1, 8, 16])
@pytest.mark.parametrize("precision", ["single", "double"])
def test_lane_math_is_the_builtins(engine, lanes, precision, builtins):
    """lanes.h max0, clamp_lanes, abs_lanes and rint_lanes, in their inline form (comparisons,
    selects and bits in place of fmax(x, 0), clamp, fabs and rint, which are calls on pip's
    PoCL) and as the built-ins (-DWARPE_BUILTINS): bit for bit NumPy's maximum (with +0 for
    -0, which the walk never gives them: fmax(-0, 0) may be either zero), clip, abs and rint
    (to nearest, ties to even, the sign of zero kept), on ties, zeros of both signs, the edges
    of the rounding trick (2^23 in single, 2^52 in double) and random values, at 1, 8 and 16
    lanes."""
    from warpe_cl.device import SELFTEST_FILES, build_program
    if precision == "double" and not engine.info.fp64:
        pytest.skip("device has no fp64")  # pragma: no cover - PoCL and NVIDIA have fp64
    dtype = np.float64 if precision == "double" else np.float32
    big = 2.0 ** (52 if precision == "double" else 23)
    edges = [0.0, -0.0, 0.5, -0.5, 1.5, -1.5, 2.5, -2.5, 3.5, -3.5, 0.49999997, -0.49999997,
             1e-30, -1e-30, 1.0, -1.0, 1.0000001, -1.0000001, big / 2 + 0.5, -(big / 2 + 0.5),
             big - 1.0, big - 0.5, -(big - 0.5), big, -big, big + 2.0, 3e18, -3e18,
             np.inf, -np.inf]
    rng_ = np.random.default_rng(11)
    x = np.concatenate([edges, rng_.normal(0, 3, 4000), rng_.normal(0, 1e6, 2000),
                        np.round(rng_.normal(0, 100, 2000)) + 0.5]).astype(dtype)
    x = np.concatenate([x, np.zeros(-len(x) % 16, dtype)])
    options = ((f"-DWARPE_LANES={lanes}",) + (("-DWARPE_DOUBLE",) if precision == "double" else ())
               + (("-DWARPE_BUILTINS",) if builtins else ()))
    prog = build_program(engine.device, SELFTEST_FILES, options)
    out = np.zeros(4 * len(x), dtype)
    mf = cl.mem_flags
    d_x = cl.Buffer(engine.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
    d_out = cl.Buffer(engine.context, mf.WRITE_ONLY, out.nbytes)
    _run(engine, prog.lane_math_of, len(x) // lanes, d_x, d_out)
    cl.enqueue_copy(engine.queue, out, d_out)
    got = out.reshape(4, len(x))
    expected = [np.where(x > 0, x, dtype(0.0)), np.clip(x, -1, 1), np.abs(x), np.rint(x)]
    if builtins:                                   # fmax(-0, 0): either zero
        got[0][x == 0] = expected[0][x == 0] = 0.0
    bits = np.uint64 if precision == "double" else np.uint32
    for name, g, e in zip(("max0", "clamp", "abs", "rint"), got, expected):
        assert np.array_equal(g.view(bits), e.astype(dtype).view(bits)), name


def test_exp_neg_accuracy(engine, selftest):
    """scatter.h exp_neg, the weighted walk's absorbed fraction (Cephes' expf in products and
    sums): within 1 ulp of the correctly rounded e^-tau over tau in [-88, 86] (measured 0.98
    ulp on [0, 86]), 1 at tau = 0, 0 where e^-tau < 2^-125; and no bad input turns into a
    plausible weight: NaN stays NaN, e^-tau beyond 2^128 is +inf (omega > 1 makes tau < 0, and
    the exits refuse such weights: test_exact.py)."""
    rng_ = np.random.default_rng(5)
    tau = np.concatenate([rng_.uniform(0, 1e-3, 100_000), rng_.uniform(0, 1, 200_000),
                          rng_.uniform(0, 86, 200_000), rng_.uniform(-88, 0, 100_000),
                          [0.0, 1e-30, 86.6, 87.0, 200.0, -89.0, -1e4, np.nan]]
                         ).astype(np.float32)
    out = np.zeros_like(tau)
    mf = cl.mem_flags
    d_t = cl.Buffer(engine.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=tau)
    d_out = cl.Buffer(engine.context, mf.WRITE_ONLY, out.nbytes)
    _run(engine, selftest["single"].exp_neg_of, len(tau), d_t, d_out)
    cl.enqueue_copy(engine.queue, out, d_out)
    with np.errstate(over="ignore"):              # e^-tau beyond float's range: +inf
        exact = np.exp(-tau.astype(np.float64))
        ulp = np.spacing(exact.astype(np.float32)).astype(np.float64)
    normal = (exact >= 2.0 ** -125 * np.sqrt(2)) & (exact < 2.0 ** 127)   # p in [0.7, 1.42]
    assert np.all(np.abs(out[normal] - exact[normal]) <= ulp[normal])
    assert out[tau == 0.0][0] == 1.0
    assert np.all(out[exact < 2.0 ** -126] == 0.0)
    assert np.all(out[exact > 2.0 ** 129] == np.inf) and np.isnan(out[np.isnan(tau)]).all()


@pytest.mark.parametrize("precision", ["single", "double"])
def test_nadir_score_bound_holds(engine, selftest, precision):
    """score.h: the bound that lets nadir_scatter skip the events whose score the roulette
    drops for certain (walk.md §8.3) is above every score the kernel computes,
    k pow_m3_2(x) exp_neg_score(tau) <= score_cap exp_neg_bound(tau), for x as the kernel
    rounds it from cos Theta in [-1, 1] and a little beyond (|u| = 1 to a few ulp), at the
    forward peak x = (1 - |g|)^2 above all, and tau across the steps of exp_neg_bound; and it
    stays useful: exp_neg_bound(tau) in [e^-tau, 2 e^-tau) until its clamp. The cap is +inf
    where (1 - |g|)^2 is within its rounding margin of 0, and without the roulette."""
    if precision not in selftest:
        pytest.skip("the device has no double precision")
    real = np.float32 if precision == "single" else np.float64
    rng_ = np.random.default_rng(11)
    steps = np.arange(0, 130) / (np.log2(np.e) * (1 - 1e-6))    # where 2^-j steps down
    tau = np.concatenate([rng_.uniform(0, 100, 4000), rng_.uniform(0, 1e-3, 500), [0.0],
                          steps, np.nextafter(steps, 0), np.nextafter(steps, 1e3)])
    c = np.concatenate([np.linspace(-1, 1, 41), [1 + 1e-6, 1 + 3e-7, -1 - 1e-6]])
    k_factor = 0.37                                   # a view factor times (1 - g^2) / 4 pi
    mf = cl.mem_flags
    for g in (0.0, 0.3, -0.5, 0.8, -0.9, 0.95, 0.99, 0.996, 0.997):
        gr = real(g)
        cc, tt = np.meshgrid(c, tau)
        # x as nadir_scatter rounds it: (1 + g^2) - 2 g c, each operation in `real`
        x = ((real(1) + gr * gr) - (real(2) * gr) * cc.astype(real)).ravel().astype(real)
        tt = tt.ravel().astype(real)
        score, bound = np.zeros_like(x), np.zeros_like(x)
        d_x = cl.Buffer(engine.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x)
        d_t = cl.Buffer(engine.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=tt)
        d_s = cl.Buffer(engine.context, mf.WRITE_ONLY, score.nbytes)
        d_b = cl.Buffer(engine.context, mf.WRITE_ONLY, bound.nbytes)
        _run(engine, selftest[precision].score_and_bound, len(x), real(k_factor), gr,
             real(1e-3), d_x, d_t, d_s, d_b)
        cl.enqueue_copy(engine.queue, score, d_s)
        cl.enqueue_copy(engine.queue, bound, d_b)
        if g == 0.997:                           # (1 - |g|)^2 = 9e-6: within the margin
            assert np.all(bound == np.inf)
            continue
        assert np.all(np.isfinite(bound)) and np.all(score <= bound), g
        # and as tight as the skip needs: the cap's margin 2 (x / x_low)^(3/2) times
        # exp_neg_bound / e^-tau in [1, 2), until exp_neg_score nears its underflow
        x_low = (1 - abs(g)) ** 2 - 1.2e-5
        live = tt < 80
        ratio = bound[live].astype(float) / score[live]
        assert np.all(ratio < 4.001 * (x[live] / x_low) ** 1.5), g
    # without the roulette (s_min = 0) nothing is ever skipped
    one = np.ones(1, dtype=np.float32)
    d_one = cl.Buffer(engine.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=one)
    d_s, d_b = (cl.Buffer(engine.context, mf.WRITE_ONLY, 4) for _ in range(2))
    _run(engine, selftest["single"].score_and_bound, 1, np.float32(0.37), np.float32(0.5),
         np.float32(0.0), d_one, d_one, d_s, d_b)
    out = np.zeros(1, dtype=np.float32)
    cl.enqueue_copy(engine.queue, out, d_b)
    assert out[0] == np.inf



def _typeof_operands(text: str) -> list:
    """The operand of every ``__typeof__(...)`` in ``text`` (parentheses balanced)."""
    out, start = [], 0
    while (at := text.find("__typeof__(", start)) >= 0:
        depth, i = 1, at + len("__typeof__(")
        while depth:
            depth += {"(": 1, ")": -1}.get(text[i], 0)
            i += 1
        out.append(text[at + len("__typeof__("):i - 1])
        start = i
    return out


def _is_sum_with_zero(operand: str) -> bool:
    """Whether ``operand`` is ``EXPR + 0`` at its top level (outside every parenthesis): an
    rvalue, whose type has no qualifier and no address space (C11 6.3.2.1 §2)."""
    flat = "".join(operand.split())
    if not flat.endswith("+0"):
        return False
    depth = 0
    for ch in flat[:-2]:
        depth += {"(": 1, ")": -1}.get(ch, 0)
    return depth == 0


def test_typeof_takes_no_address_space():
    """Every ``__typeof__`` of the kernels names the type of an rvalue (``x + 0``): the
    ``__typeof__`` of an lvalue (``r->alive``, ``(p)[0]``) keeps its address space where
    pointers are generic, and NVIDIA's compiler rejects a private copy declared with it
    ("automatic variable qualified with an invalid address space", issue 43; Intel's and
    PoCL's compilers accept it, so only this source check sees it on a CPU)."""
    from warpe_cl.device import kernel_dir
    found = 0
    for path in sorted(kernel_dir().iterdir()):
        if path.suffix not in (".h", ".cl"):
            continue
        for operand in _typeof_operands(path.read_text()):
            found += 1
            assert _is_sum_with_zero(operand), f"{path.name}: __typeof__({operand}) is an lvalue"
    assert found >= 1      # VSTORE / VLOAD's LANES_OF (cl/lanes_vector_inline.h)


def test_typeof_check_refuses_lvalues():
    """The check above: the form NVIDIA rejected, an lvalue, a sum inside parentheses and a
    product are refused; the sums with zero are taken."""
    assert _typeof_operands("const __typeof__(v) x; __typeof__((p)[0] + 0) y") == [
        "v", "(p)[0] + 0"]
    assert _typeof_operands("__typeof__(f(a, (b)))") == ["f(a, (b))"]
    for lvalue in ("v", "r->alive", "(p)[0]", "(x + 0)", "(a + 0) * b", "a + 0)[0"):
        assert not _is_sum_with_zero(lvalue), lvalue
    for rvalue in ("(p)[0] + 0", "x+0", "(r->alive) + 0"):
        assert _is_sum_with_zero(rvalue), rvalue
