/* scatter.h: sampling of directions (physics.md §5.4, §5.5). */
#ifndef WARPE_SCATTER_H
#define WARPE_SCATTER_H

/* Henyey-Greenstein deflection cosine from one uniform U (physics.md §5.4):
 *   cos(Theta) = [1 + g^2 - ((1 - g^2)/(1 - g + 2gU))^2] / (2g),  g != 0;  2U - 1 for g = 0. */
inline REAL hg_cos_theta(REAL g, REAL U)
{
    if (g == (REAL)0)
        return (REAL)2 * U - (REAL)1;
    REAL f = ((REAL)1 - g * g) / ((REAL)1 - g + (REAL)2 * g * U);
    REAL c = ((REAL)1 + g * g - f * f) / ((REAL)2 * g);
    return clamp(c, (REAL)-1, (REAL)1);
}

/* Turn the unit direction u by the polar angle acos(cos_theta) and azimuth psi (MCML,
 * Wang, Jacques & Zheng 1995; physics.md §5.4). */
inline void rotate_direction(REAL *ux, REAL *uy, REAL *uz, REAL cos_theta, REAL psi)
{
    REAL sin_theta = sqrt(fmax((REAL)1 - cos_theta * cos_theta, (REAL)0));
    REAL cos_psi, sin_psi;
    sin_psi = sincos(psi, &cos_psi);
    if (fabs(*uz) > (REAL)0.99999) {
        *ux = sin_theta * cos_psi;
        *uy = sin_theta * sin_psi;
        *uz = (*uz >= (REAL)0 ? cos_theta : -cos_theta);
    } else {
        REAL d = sqrt((REAL)1 - *uz * *uz);
        REAL x = *ux, y = *uy, z = *uz;
        *ux = sin_theta * (x * z * cos_psi - y * sin_psi) / d + x * cos_theta;
        *uy = sin_theta * (y * z * cos_psi + x * sin_psi) / d + y * cos_theta;
        *uz = -sin_theta * cos_psi * d + z * cos_theta;
    }
#ifndef WARPE_DOUBLE
    /* float32 drifts off the unit sphere over long walks: renormalise (physics.md §5.4) */
    REAL inv = rsqrt(*ux * *ux + *uy * *uy + *uz * *uz);
    *ux *= inv; *uy *= inv; *uz *= inv;
#endif
}

/* Lambertian reflection by the floor, inside the medium (docs/walk.md §3.1):
 * mu = sqrt(U), psi = 2 pi U', direction upwards. */
inline void lambert_up(rng_t *r, REAL *ux, REAL *uy, REAL *uz)
{
    REAL mu = sqrt(uniform(r));
    REAL psi = (REAL)(2.0 * WARPE_PI) * uniform(r);
    REAL s = sqrt(fmax((REAL)1 - mu * mu, (REAL)0));
    REAL c, sn = sincos(psi, &c);
    *ux = s * c;
    *uy = s * sn;
    *uz = -mu;
}

#endif /* WARPE_SCATTER_H */
