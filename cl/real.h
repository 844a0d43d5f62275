/* real.h: working precision and constants.
 *
 * Structure switches (set by the host as -D options, never physical values):
 *   WARPE_DOUBLE  compute the walk in double precision (default: single).
 * The host follows this file with real_single.h or real_double.h, the build's precision
 * (warpe_cl/device.py program_files, docs/walk.md §5.1): REAL, the integer of its width IREAL,
 * their names for the lane types (lanes.h) and REAL_C, a constant of REAL's type.
 */
#ifndef WARPE_REAL_H
#define WARPE_REAL_H

/* No contraction of a * b + c into one fma: each product and sum is rounded as written, so
 * that every device and every lane width gives the same bits (a compiler free to contract
 * fuses where it likes: in a vector path and not in the scalar one, on one driver and not on
 * another), and no driver without fused hardware (PoCL built for a generic x86-64 CPU) emulates
 * fma in software: 6x slower than a product and a sum there (docs/performance.md). */
#pragma OPENCL FP_CONTRACT OFF

#define WARPE_PI 3.14159265358979323846

/* The walk's elementary functions whose accuracy the result depends on, -ln U and the
 * azimuth's sine and cosine, are scatter.h's optical_step and azimuth: correctly rounded
 * operations only, the same bits on every device (no native_ function, whose accuracy OpenCL
 * leaves to the driver). */
/* speed of light in vacuum, m/ns */
#define WARPE_C_M_PER_NS 0.299792458

#endif /* WARPE_REAL_H */
