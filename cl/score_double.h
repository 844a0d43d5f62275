/* score_double.h: the double-precision forms of the nadir scores' arithmetic (score.h; the
 * host appends it to score.h where the build has WARPE_DOUBLE, docs/walk.md §5.1; the
 * single-precision builds get score_single.h, whose comments describe both). */

SCORE_STEP VREAL exp_neg_score(VREAL tau)
{
    return exp(-tau);
}

SCORE_STEP VREAL pow_m3_2(VREAL x)
{
    return rsqrt(x) / x;
}

SCORE_STEP VREAL exp_neg_bound(VREAL tau)
{
    const VMASK j = CONVERT_VMASK(clamp_lanes(tau * (REAL)1.4426936, (REAL)0, (REAL)1022));
    return AS_VREAL(((VMASK)1023 - j) << 52);
}
