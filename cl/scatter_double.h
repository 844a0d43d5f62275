/* scatter_double.h: the double-precision forms of the walk's elementary functions (scatter.h;
 * the host puts it before scatter.h where the build has WARPE_DOUBLE, docs/walk.md §5.1; the
 * single-precision builds get scatter_single.h, whose comments describe both): -log, exp and
 * sincos, as the reference computes them. */

inline VREAL optical_step(VREAL U)
{
    return -log(U);
}

inline VREAL exp_neg(VREAL tau)
{
    return exp(-tau);
}

inline void azimuth(VREAL U, VREAL *sin_psi, VREAL *cos_psi)
{
    *sin_psi = sincos((REAL)(2.0 * WARPE_PI) * U, cos_psi);
}

/* scatter.h rotate_direction's renormalisation: none in double precision */
inline void renormalise(VREAL *x, VREAL *y, VREAL *z)
{
}
