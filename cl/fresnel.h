/* fresnel.h: Fresnel reflectances of the slab's interfaces (docs/walk.md §3.3, §7.1), lane by
 * lane (lanes.h): the incidence cosine varies per lane; the indices are the scenario's (a
 * scalar broadcast to the lanes) or, in a stack, each lane's interface's. */
#ifndef WARPE_FRESNEL_H
#define WARPE_FRESNEL_H

/* From vacuum into a medium of complex index m = n + ik, at incidence cos(theta) = mu.
 * Hapke (1993) eqs. 4.48-4.53 (docs/physics.md §3.4):
 *   a = n^2 - k^2 - sin^2(theta), b = sqrt(a^2 + 4 n^2 k^2),
 *   G1 = sqrt((a + b)/2), G2 = sqrt((b - a)/2),
 *   R_perp = [(mu - G1)^2 + G2^2] / [(mu + G1)^2 + G2^2],
 *   R_par  = [((n^2-k^2) mu - G1)^2 + (2nk mu - G2)^2] / [((n^2-k^2) mu + G1)^2 + (2nk mu + G2)^2],
 *   R = (R_perp + R_par)/2. */
inline VREAL fresnel_external(VREAL mu, VREAL n, VREAL k)
{
    /* a = n^2 - k^2 - sin^2 = (n^2 - k^2 - 1) + mu^2: no cancellation at grazing incidence */
    VREAL nk2 = n * n - k * k;
    VREAL a = (nk2 - (REAL)1) + mu * mu;
    VREAL b = sqrt(a * a + (REAL)4 * n * n * k * k);
    VREAL G1 = sqrt((REAL)0.5 * (a + b));
    VREAL G2 = sqrt(max0((REAL)0.5 * (b - a)));
    VREAL r_perp = ((mu - G1) * (mu - G1) + G2 * G2) / ((mu + G1) * (mu + G1) + G2 * G2);
    VREAL tnk = (REAL)2 * n * k * mu;
    VREAL r_par = ((nk2 * mu - G1) * (nk2 * mu - G1) + (tnk - G2) * (tnk - G2))
               / ((nk2 * mu + G1) * (nk2 * mu + G1) + (tnk + G2) * (tnk + G2));
    return (REAL)0.5 * (r_perp + r_par);
}

/* From inside a medium of real index n into vacuum at incidence cos(theta) = mu, below the
 * critical angle (the caller handles total internal reflection). Real n inside (docs/physics.md
 * §3.5, A12): cos(theta_t) = sqrt(1 - n^2 (1 - mu^2)),
 *   r_s = (n mu - cos_t)/(n mu + cos_t), r_p = (mu - n cos_t)/(mu + n cos_t), R = (r_s^2 + r_p^2)/2. */
inline VREAL fresnel_internal(VREAL mu, VREAL n)
{
    /* 1 - n^2 (1 - mu^2) written as (1 - n^2) + n^2 mu^2: well conditioned near grazing */
    VREAL cos_t = sqrt(max0(((REAL)1 - n * n) + n * n * mu * mu));
    VREAL rs = (n * mu - cos_t) / (n * mu + cos_t);
    VREAL rp = (mu - n * cos_t) / (mu + n * cos_t);
    return (REAL)0.5 * (rs * rs + rp * rp);
}

#endif /* WARPE_FRESNEL_H */
