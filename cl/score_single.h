/* score_single.h: the single-precision forms of the nadir scores' arithmetic (score.h; the
 * host appends it to score.h where the build has no WARPE_DOUBLE, docs/walk.md §5.1;
 * real_double.h's builds get score_double.h): correctly rounded operations only, the same bits
 * on every device and at every lane width. */

/* e^-tau (tau >= 0) for the nadir scores, cheaper than exp_neg (scatter.h) and less accurate:
 * at every event of every ray, where the scores' own statistical error is far larger. Double
 * precision: exp. Single precision: 2^n 2^f with y = -tau log2(e) = n + f, n = rint(y),
 * |f| <= 1/2, and 2^f by a degree-5 polynomial, each product and sum rounded (a weighted
 * least-squares fit of 2^f on [-1/2, 1/2]: 3.5e-7 relative at most, 6 ulp), times 2^n
 * (as times_pow2, scatter.h, for n <= 0: 0 below n = -125). exp_neg in its place cost B1 with
 * the estimate 4 % (docs/performance.md). */
SCORE_STEP VREAL exp_neg_score(VREAL tau)
{
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
}

/* x^(-3/2) (x > 0), of the HG phase function. Double precision: rsqrt(x) / x, as the
 * reference computes it. Single precision: y^3, y the inverse square root from the bits of x
 * (0x5f3759df - bits / 2: within 3.5 %, Lomont 2003) and three Newton steps
 * y (3/2 - x y^2 / 2), within a few ulp; cheaper than the accurate rsqrt and a division,
 * which were three of the slowest instructions of an event (docs/performance.md). */
SCORE_STEP VREAL pow_m3_2(VREAL x)
{
    const VREAL hx = (REAL)0.5 * x;
    VREAL y = AS_VREAL((VMASK)0x5f3759df - (AS_VMASK(x) >> 1));
    y = y * ((REAL)1.5 - hx * y * y);
    y = y * ((REAL)1.5 - hx * y * y);
    y = y * ((REAL)1.5 - hx * y * y);
    return y * y * y;
}

/* 2^-j with j = trunc(tau log2(e) (1 - 1e-6)) clamped to [0, 126] (double: [0, 1022]), from
 * the bits: a product, a conversion and a shift. For tau >= 0 it is at least e^-tau (the
 * factor below log2(e) keeps the rounded product below tau log2(e)) and less than 2 e^-tau
 * until the clamp; below 0 it is 1. */
SCORE_STEP VREAL exp_neg_bound(VREAL tau)
{
    const VMASK j = CONVERT_VMASK(clamp_lanes(tau * (REAL)1.4426936f, (REAL)0, (REAL)126));
    return AS_VREAL(((VMASK)127 - j) << 23);
}
