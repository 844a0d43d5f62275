/* lanes_inline.h: fmax(x, 0), clamp, fabs and rint of the lanes without OpenCL's built-ins, on
 * every driver but Intel's CPU runtime (no WARPE_BUILTINS, warpe_cl/engine.py driver_options;
 * the host appends it to the lane types, docs/walk.md §5.1; Intel's runtime gets
 * lanes_builtins.h): comparisons, selects and bits, where pip's PoCL 3.0 calls a library
 * function for each built-in, with the vector registers saved around the call
 * (docs/performance.md). The same values for every number the walk gives them (never a NaN,
 * tests/test_kernel_blocks.py): max0 gives +0 for -0, where fmax may give either zero, and no
 * difference or sum of the walk is -0 (a - a is +0). SIGN_BIT and ROUND_BIG: real_single.h,
 * real_double.h. */
inline VREAL max0(VREAL x)
{
    return SEL((VREAL)0, x, x > (REAL)0);
}
inline VREAL clamp_lanes(VREAL x, REAL lo, REAL hi)
{
    return SEL(SEL(x, (VREAL)lo, x < lo), (VREAL)hi, x > hi);
}
inline VREAL abs_lanes(VREAL x)
{
    return AS_VREAL(AS_VMASK(x) & ~SIGN_BIT);
}
/* rint (to nearest, ties to even): x + m - m with m = 2^23 (double: 2^52) of x's sign rounds x
 * to an integer where |x| < 2^23, ties to even, and the sign of zero is x's, as rint's; from
 * 2^23 on, x is an integer. */
inline VREAL rint_lanes(VREAL x)
{
    const VMASK sign = AS_VMASK(x) & SIGN_BIT;
    const VREAL m = AS_VREAL(AS_VMASK((VREAL)ROUND_BIG) | sign);
    const VREAL r = AS_VREAL(AS_VMASK((x + m) - m) | sign);
    return SEL(r, x, abs_lanes(x) >= (REAL)ROUND_BIG);
}
