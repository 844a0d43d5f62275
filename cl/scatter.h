/* scatter.h: sampling of directions (docs/physics.md §5.4, §5.5), lane by lane (lanes.h). The
 * walk's own elementary functions, -ln U (optical_step), the azimuth's sine and cosine
 * (azimuth), e^-tau (exp_neg) and the renormalisation of a turned direction, are those of the
 * build's precision: scatter_single.h or scatter_double.h, which the host puts before this file
 * (warpe_cl/device.py program_files, docs/walk.md §5.1). */
#ifndef WARPE_SCATTER_H
#define WARPE_SCATTER_H

/* Henyey-Greenstein deflection cosine from one uniform U (docs/physics.md §5.4, docs/walk.md §3),
 * in the form that has no cancellation for small |g|: with s = 2U - 1, 1 - s^2 = 4U(1 - U)
 * and d = 1 + g s = (1 - g) + 2gU,
 *   cos(Theta) = s + g (1 - s^2) (3 + 2 g s - g^2) / (2 d^2),
 * an exact rewrite of [1 + g^2 - ((1 - g^2)/(1 - g + 2gU))^2] / (2g) that gives s at g = 0 and
 * +-1 at U = 1, 0. In float its error is ~1 ulp of 1 for every g (the classic form loses
 * 6e-8/g: <cos> = -0.34 at g = 1e-7), and no larger than the classic form's at g = 0.8-0.999. */
inline VREAL hg_cos_theta(VREAL g, VREAL U)
{
    VREAL s = (REAL)2 * U - (REAL)1;
    VREAL q = (REAL)4 * U * ((REAL)1 - U);
    VREAL d = ((REAL)1 - g) + (REAL)2 * g * U;
    VREAL c = s + g * q * (((REAL)3 - g * g) + (REAL)2 * g * s) / ((REAL)2 * d * d);
    return clamp_lanes(c, (REAL)-1, (REAL)1);
}

/* Turn the unit direction u by the polar angle acos(cos_theta) and azimuth psi, given as
 * (cos psi, sin psi) (MCML, Wang, Jacques & Zheng 1995; docs/physics.md §5.4). Both branches are
 * evaluated and each lane keeps its own (|uz| > 0.99999: the vertical formula). */
inline void rotate_direction(VREAL *ux, VREAL *uy, VREAL *uz, VREAL cos_theta,
                             VREAL cos_psi, VREAL sin_psi)
{
    VREAL sin_theta = sqrt(max0((REAL)1 - cos_theta * cos_theta));
    VREAL x = *ux, y = *uy, z = *uz;
    VMASK vertical = abs_lanes(z) > (REAL)0.99999;
    /* general case; d is replaced by 1 on vertical lanes so that no lane divides by 0 */
    VREAL d = SEL(sqrt(max0((REAL)1 - z * z)), (VREAL)1, vertical);
    VREAL gx = sin_theta * (x * z * cos_psi - y * sin_psi) / d + x * cos_theta;
    VREAL gy = sin_theta * (y * z * cos_psi + x * sin_psi) / d + y * cos_theta;
    VREAL gz = -sin_theta * cos_psi * d + z * cos_theta;
    /* vertical: u' = (sin cos psi, sin sin psi, sign(uz) cos Theta) */
    VREAL vx = sin_theta * cos_psi, vy = sin_theta * sin_psi;
    VREAL vz = SEL(-cos_theta, cos_theta, z >= (REAL)0);
    x = SEL(gx, vx, vertical);
    y = SEL(gy, vy, vertical);
    z = SEL(gz, vz, vertical);
    renormalise(&x, &y, &z);        /* scatter_single.h, scatter_double.h */
    *ux = x; *uy = y; *uz = z;
}

/* A Lambertian direction from (mu, cos psi, sin psi): mu = sqrt(U) is the cosine to the
 * normal (docs/walk.md §3.1); sign -1 points it upwards (into the medium from the floor). */
inline void lambert_direction(VREAL mu, VREAL cos_psi, VREAL sin_psi,
                              VREAL *ux, VREAL *uy, VREAL *uz)
{
    VREAL s = sqrt(max0((REAL)1 - mu * mu));
    *ux = s * cos_psi;
    *uy = s * sin_psi;
    *uz = -mu;
}

#endif /* WARPE_SCATTER_H */
