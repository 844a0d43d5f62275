/* selftest.cl (built with WARPE_LANES = 1; lane_bits_of at every width): small kernels that
 * expose the walk's building blocks to the test suite (Philox known answers, uniforms, the HG
 * and Lambert samplers, the Fresnel laws, the nadir score and its bound, the lanes' masks) and
 * to `warpe-cl devices`, which builds them to check that a device can compile our code. */

#if WARPE_LANES == 1        /* the building blocks of one lane */
__kernel void philox_kat(__global const uint4 *ctr, __global const uint2 *key, __global uint4 *out)
{
    size_t i = get_global_id(0);
    out[i] = philox4x32_10(ctr[i], key[i]);
}

/* The first n_draws uniforms of each photon first_photon + i. */
__kernel void photon_uniforms(const uint seed, const ulong scenario, const ulong first_photon,
                              const int n_draws, __global REAL *out)
{
    size_t i = get_global_id(0);
    rng_t r;
    rng_init(&r, seed, scenario, first_photon + i);
    for (int j = 0; j < n_draws; ++j)
        out[i * n_draws + j] = uniform(&r);
}

/* HG deflection cosines and Lambertian cosines from photon i's stream. */
__kernel void sample_directions(const uint seed, const REAL g, __global REAL *hg_cos,
                                __global REAL *lambert_mu)
{
    size_t i = get_global_id(0);
    rng_t r;
    rng_init(&r, seed, 0u, (ulong)i);
    hg_cos[i] = hg_cos_theta(g, uniform(&r));
    REAL mu = sqrt(uniform(&r));
    REAL c, s;
    azimuth(uniform(&r), &s, &c);
    REAL ux, uy, uz;
    lambert_direction(mu, c, s, &ux, &uy, &uz);
    lambert_mu[i] = -uz;
}

/* Fresnel reflectances on a grid of incidence cosines. */
__kernel void fresnel_grid(__global const REAL *mu, const REAL n, const REAL k,
                           __global REAL *r_external, __global REAL *r_internal)
{
    size_t i = get_global_id(0);
    r_external[i] = fresnel_external(mu[i], n, k);
    REAL m = mu[i];
    r_internal[i] = n * sqrt(fmax((REAL)1 - m * m, (REAL)0)) >= (REAL)1
                  ? (REAL)1 : fresnel_internal(m, n);
}

/* The walk's optical step and azimuth (scatter.h optical_step, azimuth) on a grid of uniforms,
 * for the accuracy test: out = (-ln u, sin 2 pi u, cos 2 pi u). */
__kernel void walk_math(__global const REAL *u, __global REAL *out)
{
    size_t i = get_global_id(0);
    REAL s, c;
    azimuth(u[i], &s, &c);
    out[3 * i] = optical_step(u[i]);
    out[3 * i + 1] = s;
    out[3 * i + 2] = c;
}

/* The operations every result of the walk is made of, each rounded once as IEEE 754 says:
 * out = (a / b, sqrt(a), a * b + c), the last with no fused multiply-add (real.h FP_CONTRACT
 * OFF). OpenCL lets a driver divide and take square roots 2.5 and 3 ulp off in single
 * precision unless the program is built with -cl-fp32-correctly-rounded-divide-sqrt
 * (warpe_cl/device.py build_source), and NVIDIA's does: a walk built without it leaves the
 * CPUs' bits. */
__kernel void exact_ops(__global const REAL *a, __global const REAL *b, __global const REAL *c,
                        __global REAL *out)
{
    const size_t i = get_global_id(0), n = get_global_size(0);
    out[i] = a[i] / b[i];
    out[n + i] = sqrt(a[i]);
    out[2 * n + i] = a[i] * b[i] + c[i];
}

/* The walk's e^-tau (scatter.h exp_neg) on given tau, for the accuracy test. */
__kernel void exp_neg_of(__global const REAL *tau, __global REAL *out)
{
    size_t i = get_global_id(0);
    out[i] = exp_neg(tau[i]);
}

/* score.h on given x and tau: the nadir score of walk.cl's nadir_scatter before its weight
 * and roulette, k pow_m3_2(x) exp_neg_score(tau), and the bound its skip compares with,
 * score_cap(k, g, s_min, 0) exp_neg_bound(tau) (walk.md §8.3). */
__kernel void score_and_bound(const REAL k, const REAL g, const REAL s_min,
                              __global const REAL *x, __global const REAL *tau,
                              __global REAL *score, __global REAL *bound)
{
    size_t i = get_global_id(0);
    score[i] = k * pow_m3_2(x[i]) * exp_neg_score(tau[i]);
    bound[i] = score_cap(k, g, s_min, 0) * exp_neg_bound(tau[i]);
}

/* The walk's exact event rule (philox.h word_at_least) on given words: out = 1 where the event
 * "U > P" happens for the threshold T = floor(P 2^32 + 1/2). */
__kernel void word_events(const ulong T, __global const uint *x, __global int *out)
{
    size_t i = get_global_id(0);
    out[i] = word_at_least(x[i], T) ? 1 : 0;
}
#endif

/* lanes.h lane_bits, ANY and ALL of the mask whose lane j is set where bit j of pattern[i] is
 * (the lanes of the width this program is built with; the test builds it at each width), in
 * out[3i], out[3i + 1] and out[3i + 2] */
__kernel void lane_bits_of(__global const uint *pattern, __global uint *out)
{
    size_t i = get_global_id(0);
    const VMASK m = (((VMASK)(IREAL)pattern[i] >> LANE_INDEX) & (VMASK)1) != (VMASK)0;
    out[3 * i] = lane_bits(m);
    out[3 * i + 1] = ANY(m) ? 1u : 0u;
    out[3 * i + 2] = ALL(m) ? 1u : 0u;
}

/* lanes.h lowest_lane of pattern[i] (never 0) */
__kernel void lowest_lane_of(__global const uint *pattern, __global int *out)
{
    size_t i = get_global_id(0);
    out[i] = lowest_lane(pattern[i]);
}

/* lanes.h max0, clamp_lanes(x, -1, 1), abs_lanes and rint_lanes of x[i], WARPE_LANES values a
 * work-item (the width this program is built with; the test builds it at several): the four
 * results of x[i] at out[i], out[n + i], out[2 n + i], out[3 n + i], n values in all. */
__kernel void lane_math_of(__global const REAL *x, __global REAL *out)
{
    const size_t i = get_global_id(0) * WARPE_LANES, n = get_global_size(0) * WARPE_LANES;
    const VREAL v = VLOAD_GLOBAL(x + i);
    VSTORE_GLOBAL(max0(v), out + i);
    VSTORE_GLOBAL(clamp_lanes(v, (REAL)-1, (REAL)1), out + n + i);
    VSTORE_GLOBAL(abs_lanes(v), out + 2 * n + i);
    VSTORE_GLOBAL(rint_lanes(v), out + 3 * n + i);
}
