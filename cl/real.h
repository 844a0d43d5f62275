/* real.h: working precision and constants.
 *
 * Structure switches (set by the host as -D options, never physical values):
 *   WARPE_DOUBLE  compute the walk in double precision (default: single).
 * The single-precision walk keeps its path length L in a compensated (Kahan) float sum
 * (walk.cl, docs/physics.md A15); nothing in it computes in double.
 */
#ifndef WARPE_REAL_H
#define WARPE_REAL_H

/* fp64 is enabled wherever the device has it, in single precision too: constant expressions
 * such as (REAL)(180.0 / WARPE_PI) are then evaluated in double and rounded once. */
#if defined(WARPE_DOUBLE) || defined(cl_khr_fp64)
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif

/* No contraction of a * b + c into one fma: each product and sum is rounded as written, so
 * that every device and every lane width gives the same bits (a compiler free to contract
 * fuses where it likes: in a vector path and not in the scalar one, on one driver and not on
 * another), and no driver without fused hardware (PoCL built for a generic x86-64 CPU) emulates
 * fma in software: 6x slower than a product and a sum there (docs/performance.md). */
#pragma OPENCL FP_CONTRACT OFF

#ifdef WARPE_DOUBLE
typedef double REAL;
#else
typedef float REAL;
#endif

#define WARPE_PI 3.14159265358979323846

/* The walk's elementary functions whose accuracy the result depends on, -ln U and the
 * azimuth's sine and cosine, are scatter.h's optical_step and azimuth: correctly rounded
 * operations only, the same bits on every device (no native_ function, whose accuracy OpenCL
 * leaves to the driver). */
/* speed of light in vacuum, m/ns */
#define WARPE_C_M_PER_NS 0.299792458

#endif /* WARPE_REAL_H */
