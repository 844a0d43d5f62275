/* score.h: the arithmetic of the next-event (nadir) scores (docs/walk.md §8): e^-tau and
 * x^(-3/2) of the HG phase function, and the bound that lets walk.cl's nadir_scatter leave out
 * the events whose score the roulette would drop for certain (walk.md §8.3). In single
 * precision only correctly rounded operations: the same bits on every device and at every lane
 * width. */
#ifndef WARPE_SCORE_H
#define WARPE_SCORE_H

#define SCORE_STEP inline __attribute__((always_inline))

/* e^-tau (tau >= 0) for the nadir scores, cheaper than exp_neg (scatter.h) and less accurate:
 * at every event of every ray, where the scores' own statistical error is far larger. Double
 * precision: exp. Single precision: 2^n 2^f with y = -tau log2(e) = n + f, n = rint(y),
 * |f| <= 1/2, and 2^f by a degree-5 polynomial, each product and sum rounded (a weighted
 * least-squares fit of 2^f on [-1/2, 1/2]: 3.5e-7 relative at most, 6 ulp), times 2^n
 * (as times_pow2, scatter.h, for n <= 0: 0 below n = -125). exp_neg in its place cost B1 with
 * the estimate 4 % (docs/performance.md). */
SCORE_STEP VREAL exp_neg_score(VREAL tau)
{
#ifdef WARPE_DOUBLE
    return exp(-tau);
#else
#ifdef WARPE_BUILTINS
    const VREAL y = -tau * (REAL)1.4426950408889634;
    const VREAL n = rint(y);
#else
    /* rint(y) as (y + 1.5 2^23) - 1.5 2^23, exact and ties to even for |y| < 2^22: y is at
     * most 1/2 (tau >= 0 but for a rounding), and held at -150, below which e^-tau is 0 all
     * the same */
    VREAL y = -tau * (REAL)1.4426950408889634;
    y = SEL(y, (VREAL)-150, y < (REAL)-150);
    const VREAL n = (y + (REAL)0x1.8p23f) - (REAL)0x1.8p23f;
#endif
    const VREAL f = y - n;
    VREAL p = f * (REAL)0.0012915669940412045f + (REAL)0.009668530896306038f;
    p = f * p + (REAL)0.055516887456178665f;
    p = f * p + (REAL)0.24022264778614044f;
    p = f * p + (REAL)0.6931464672088623f;
    p = f * p + (REAL)1.0f;
    /* times 2^n, n <= 0: times_pow2 without its test for n > 127 (0 below n = -125) */
    const VREAL e = SEL(n, (VREAL)-126, n < (REAL)-126);
    const VREAL scale = AS_VREAL((CONVERT_VMASK(e) + (VMASK)127) << 23);
    return SEL(p * scale, (VREAL)0, n < (REAL)-125);
#endif
}

/* x^(-3/2) (x > 0), of the HG phase function. Double precision: rsqrt(x) / x, as the
 * reference computes it. Single precision: y^3, y the inverse square root from the bits of x
 * (0x5f3759df - bits / 2: within 3.5 %, Lomont 2003) and three Newton steps
 * y (3/2 - x y^2 / 2), within a few ulp; cheaper than the accurate rsqrt and a division,
 * which were three of the slowest instructions of an event (docs/performance.md). */
SCORE_STEP VREAL pow_m3_2(VREAL x)
{
#ifdef WARPE_DOUBLE
    return rsqrt(x) / x;
#else
    const VREAL hx = (REAL)0.5 * x;
    VREAL y = AS_VREAL((VMASK)0x5f3759df - (AS_VMASK(x) >> 1));
    y = y * ((REAL)1.5 - hx * y * y);
    y = y * ((REAL)1.5 - hx * y * y);
    y = y * ((REAL)1.5 - hx * y * y);
    return y * y * y;
#endif
}

/* 2^-j with j = trunc(tau log2(e) (1 - 1e-6)) clamped to [0, 126] (double: [0, 1022]), from
 * the bits: a product, a conversion and a shift. For tau >= 0 it is at least e^-tau (the
 * factor below log2(e) keeps the rounded product below tau log2(e)) and less than 2 e^-tau
 * until the clamp; below 0 it is 1. */
SCORE_STEP VREAL exp_neg_bound(VREAL tau)
{
#ifdef WARPE_DOUBLE
    const VMASK j = CONVERT_VMASK(clamp_lanes(tau * (REAL)1.4426936, (REAL)0, (REAL)1022));
    return AS_VREAL(((VMASK)1023 - j) << 52);
#else
    const VMASK j = CONVERT_VMASK(clamp_lanes(tau * (REAL)1.4426936f, (REAL)0, (REAL)126));
    return AS_VREAL(((VMASK)127 - j) << 23);
#endif
}

/* s_cap such that every score k pow_m3_2(x) exp_neg_score(tau) of nadir_scatter is at most
 * s_cap exp_neg_bound(tau) (walk.md §8.3), for the phase factor k of a layer of asymmetry g:
 * x = (1 + g^2) - 2 g cos Theta is at least (1 - |g|)^2, less 1.2e-5 for the roundings of x
 * and of a direction's |u| = 1 (a few 1e-7 each); a factor 2 covers those of the products,
 * of pow_m3_2 and exp_neg_score (1e-6 together) and a tau a rounding below 0 at the top.
 * +inf (no event is ever left out) with mirror rows (scores of other paths: walk.md §8.5),
 * without the roulette (s_min = 0) or with an absurdly small s_min (v s_min could then be
 * subnormal), and where (1 - |g|)^2 is within the margin of 0 (|g| > 0.99654). */
inline REAL score_cap(REAL k, REAL g, REAL s_min, int n_mirror)
{
    const REAL a = (REAL)1 - fabs(g);
    const REAL x_low = a * a - (REAL)1.2e-5;
    if (n_mirror > 0 || !(s_min > (REAL)0x1p-60) || !(x_low > (REAL)0))
        return INFINITY;
    return (REAL)2 * k / (x_low * sqrt(x_low));
}

#endif /* WARPE_SCORE_H */
