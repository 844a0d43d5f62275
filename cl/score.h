/* score.h: the arithmetic of the next-event (nadir) scores (docs/walk.md §8): e^-tau and
 * x^(-3/2) of the HG phase function, and the bound that lets walk.cl's nadir_scatter leave out
 * the events whose score the roulette would drop for certain (walk.md §8.3). In single
 * precision only correctly rounded operations: the same bits on every device and at every lane
 * width. */
#ifndef WARPE_SCORE_H
#define WARPE_SCORE_H

#define SCORE_STEP inline __attribute__((always_inline))

/* e^-tau (exp_neg_score), x^(-3/2) (pow_m3_2) and the bound 2^-j of e^-tau (exp_neg_bound) are
 * those of the build's precision: score_single.h or score_double.h, which the host appends to
 * this file (warpe_cl/device.py program_files, docs/walk.md §5.1). */

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
