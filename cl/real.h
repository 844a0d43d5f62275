/* real.h: working precision and constants.
 *
 * Structure switches (set by the host as -D options, never physical values):
 *   WARPE_DOUBLE  compute the walk in double precision (default: single).
 * Path lengths are accumulated in double wherever the device has fp64 (physics.md A15:
 * 1e4-1e6 steps of 1e-5 m in a float32 sum would lose the time scale), otherwise with
 * compensated (Kahan) float summation.
 */
#ifndef WARPE_REAL_H
#define WARPE_REAL_H

#if defined(WARPE_DOUBLE) || defined(cl_khr_fp64)
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif

#ifdef WARPE_DOUBLE
typedef double REAL;
#else
typedef float REAL;
#endif

#if defined(WARPE_DOUBLE) || defined(cl_khr_fp64)
#define WARPE_PATH_DOUBLE 1
typedef double PATH;
#else
typedef float PATH;
#endif

#define WARPE_PI 3.14159265358979323846

/* The walk's transcendental functions. In single precision the device's native_ versions
 * (measured 10 % faster on the whole walk on PoCL/AVX-512, and within the accuracy the parity
 * and physics tests demand: docs/performance.md); in double precision the correctly specified
 * ones, so that the double kernel follows the reference ray for ray. */
#if defined(WARPE_DOUBLE) || defined(WARPE_EXACT_MATH)
#define LOG(x) log(x)
#define SINCOS(x, s, c) ((s) = sincos((x), &(c)))
#else
#define LOG(x) native_log(x)
#define SINCOS(x, s, c) ((s) = native_sin(x), (c) = native_cos(x))
#endif
/* speed of light in vacuum, m/ns */
#define WARPE_C_M_PER_NS 0.299792458

/* A path length accumulator: double where available, else Kahan-compensated float. */
typedef struct {
    PATH sum;
    PATH carry;
} path_t;

inline void path_add(path_t *p, REAL s)
{
#ifdef WARPE_PATH_DOUBLE
    p->sum += (PATH)s;
#else
    PATH y = (PATH)s - p->carry;
    PATH t = p->sum + y;
    p->carry = (t - p->sum) - y;
    p->sum = t;
#endif
}

#endif /* WARPE_REAL_H */
