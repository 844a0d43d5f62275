/* scatter_single.h: the single-precision forms of the walk's elementary functions (scatter.h;
 * the host puts it before scatter.h where the build has no WARPE_DOUBLE, docs/walk.md §5.1;
 * real_double.h's builds get scatter_double.h): -ln U, e^-tau, the azimuth's sine and cosine
 * and the renormalisation of a turned direction, from correctly rounded operations only. */

/* The optical depth to the next collision, l = -ln U (U in (0, 1]; docs/physics.md §5.3,
 * paper eq. 3). Double precision: -log(U). Single precision: Cephes' logf (S. L. Moshier,
 * Cephes Mathematical Library, 1984-1992) as Cephes writes it, each product and sum rounded
 * (real.h turns contraction off: no fma, which some drivers emulate in software): U = 2^e m
 * with m in [sqrt(1/2), sqrt(2)) from the bits, f = m - 1 (exact), ln m = f - f^2/2 + f^3 P(f)
 * with P of degree 8, and e ln 2 in two parts (0.693359375, exact in float, and
 * -2.12194440e-4); within 1 ulp of the correctly rounded -ln U (tests/test_kernel_blocks.py).
 * Only correctly rounded operations (products, sums, bit operations): the same bits on every
 * device and at every lane width. native_log, which this replaced, is each device's own:
 * Intel's CPU runtime on AVX2 (Zen 3) was 1e-4 relative off, which moved exit times by up to
 * 3e-4 (docs/performance.md). U >= 2^-33 in single precision (philox.h uniform): never
 * subnormal. */
inline VREAL optical_step(VREAL U)
{
    const VMASK bits = AS_VMASK(U);
    const VREAL m = AS_VREAL((bits & (VMASK)0x007fffff) | (VMASK)0x3f000000);   /* [1/2, 1) */
    const VMASK low = m < (REAL)0.707106781186547524;
    const VREAL e = CONVERT_VREAL((bits >> 23) - (VMASK)126 - ONE(low));
    const VREAL f = SEL(m - (REAL)1, (m + m) - (REAL)1, low);        /* exact (Sterbenz) */
    const VREAL z = f * f;
    VREAL p = (REAL)7.0376836292e-2f * f - (REAL)1.1514610310e-1f;
    p = p * f + (REAL)1.1676998740e-1f;
    p = p * f - (REAL)1.2420140846e-1f;
    p = p * f + (REAL)1.4249322787e-1f;
    p = p * f - (REAL)1.6668057665e-1f;
    p = p * f + (REAL)2.0000714765e-1f;
    p = p * f - (REAL)2.4999993993e-1f;
    p = p * f + (REAL)3.3333331174e-1f;
    VREAL y = p * f * z;
    y = y + e * (REAL)-2.12194440e-4f;
    y = y - (REAL)0.5f * z;                  /* 0.5 z is exact */
    return -(e * (REAL)0.693359375f + (f + y));  /* e 0.693359375 is exact (|e| <= 33) */
}

/* p 2^n for an integral n (a float), 2^n from its bits: 0 where n < -125, so that no device's
 * flushing of denormals matters (p is in [0.7, 1.42] for exp_neg and exp_neg_score); +inf where
 * n > 127 (tau < 0: the growing weights of omega > 1, which the exits then refuse); NaN where
 * p is (a NaN n gives some scale, and p is NaN with it): no bad input becomes a plausible
 * value. */
inline VREAL times_pow2(VREAL p, VREAL n)
{
    const VMASK e = CONVERT_VMASK(clamp_lanes(n, (REAL)-126, (REAL)127));
    const VREAL scale = AS_VREAL((e + (VMASK)127) << 23);
    const VREAL v = SEL(p * scale, (VREAL)0, n < (REAL)-125);
    return SEL(v, (VREAL)INFINITY, n > (REAL)127);
}

/* e^-tau: the weighted walk's absorbed fraction (and a gap's nadir score). Double
 * precision: exp. Single precision: Cephes' expf (S. L. Moshier, Cephes Mathematical Library),
 * each product and sum rounded: n = rint(-tau log2(e)), x = -tau - n ln 2 with ln 2 in two
 * parts (0.693359375, whose product with n is exact, and -2.12194440e-4), e^x = 1 + x + x^2
 * P(x) with P of degree 5, times 2^n (times_pow2). Within 1 ulp of e^-tau
 * (tests/test_kernel_blocks.py). Only correctly rounded operations: the same bits at every
 * lane width and on every device, where exp and native_exp are each driver's own (and differ
 * between their vector and scalar forms on Intel's runtime), and no library call (native_exp
 * is one on Intel's CPU runtime, which spills every vector register: docs/performance.md). */
inline VREAL exp_neg(VREAL tau)
{
    const VREAL n = rint_lanes(-tau * (REAL)1.4426950408889634);
    VREAL x = -tau - n * (REAL)0.693359375f;
    x = x - n * (REAL)-2.12194440e-4f;
    const VREAL z = x * x;
    VREAL p = (REAL)1.9875691500e-4f * x + (REAL)1.3981999507e-3f;
    p = p * x + (REAL)8.3334519073e-3f;
    p = p * x + (REAL)4.1665795894e-2f;
    p = p * x + (REAL)1.6666665459e-1f;
    p = p * x + (REAL)5.0000001201e-1f;
    p = (p * z + x) + (REAL)1;
    return times_pow2(p, n);
}

/* The azimuth psi = 2 pi U (U in (0, 1]; docs/physics.md §5.4) as (sin psi, cos psi).
 * Double precision: sincos(2 pi U), as the reference computes it. Single precision: the
 * quadrant from U itself, q = rint(4U) and r = U - q/4 in [-1/8, 1/8] (exact: Sterbenz), so
 * that no angle is reduced; x = 2 pi r in [-pi/4, pi/4]; Cephes' sinf and cosf polynomials
 * (S. L. Moshier, Cephes Mathematical Library), each product and sum rounded; then the
 * quadrant's turn by q pi/2. Within 2e-7 of sin and cos of 2 pi U (1.0e-7 measured;
 * tests/test_kernel_blocks.py). Only correctly rounded operations, like optical_step: the same
 * bits on every device, where native_sin and native_cos are each device's own. */
inline void azimuth(VREAL U, VREAL *sin_psi, VREAL *cos_psi)
{
    const VREAL q = rint_lanes((REAL)4 * U);
    const VREAL x = (U - (REAL)0.25 * q) * (REAL)(2.0 * WARPE_PI);
    const VREAL z = x * x;
    VREAL s = z * (REAL)-1.9515295891e-4f + (REAL)8.3321608736e-3f;
    s = z * s - (REAL)1.6666654611e-1f;
    s = (z * x) * s + x;
    VREAL c = z * (REAL)2.443315711809948e-5f - (REAL)1.388731625493765e-3f;
    c = z * c + (REAL)4.166664568298827e-2f;
    c = (z * z) * c + ((REAL)1 - (REAL)0.5f * z);
    /* psi = q pi/2 + x: quadrant 1 (sin, cos) = (cos x, -sin x), 2: (-sin x, -cos x),
     * 3: (-cos x, sin x); q = 4 is quadrant 0 */
    const VMASK k = CONVERT_VMASK(q) & (VMASK)3;
    const VMASK odd = (k & (VMASK)1) != (VMASK)0;
    const VREAL sn = SEL(s, c, odd), cs = SEL(c, s, odd);
    *sin_psi = SEL(sn, -sn, (k & (VMASK)2) != (VMASK)0);
    *cos_psi = SEL(cs, -cs, ((k + (VMASK)1) & (VMASK)2) != (VMASK)0);
}

/* float32 drifts off the unit sphere over long walks: renormalise (docs/physics.md §5.4) by
 * one Newton step for 1/sqrt(r2) from 1, 3/2 - r2/2, off by (3/8)(r2 - 1)^2: 1e-14 for the
 * |r2 - 1| ~ 1e-7 of one turn's rounding (scatter.h rotate_direction). Correctly rounded
 * operations only, where rsqrt is each driver's own (Intel's vector rsqrt differs from its
 * scalar one in the last bits) */
inline void renormalise(VREAL *x, VREAL *y, VREAL *z)
{
    VREAL inv = (REAL)1.5 - (REAL)0.5 * (*x * *x + *y * *y + *z * *z);
    *x *= inv; *y *= inv; *z *= inv;
}
