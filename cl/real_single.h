/* real_single.h: the single-precision walk (real.h; the host appends it to real.h where the
 * build has no WARPE_DOUBLE, docs/walk.md §5.1). The single-precision walk keeps its path
 * length L in a compensated (Kahan) float sum (walk.cl, docs/physics.md A15); nothing in it
 * computes in double.
 */

/* fp64 is enabled wherever the device has it, in single precision too: constant expressions
 * such as (REAL)(180.0 / WARPE_PI) are then evaluated in double and rounded once. */
#ifdef cl_khr_fp64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif

typedef float REAL;
typedef int IREAL;       /* integer of REAL's width: masks of float vectors are int */

/* The names of REAL and IREAL, for the lane types' names (lanes.h: float16, int16, ...) */
#define REAL_NAME float
#define IREAL_NAME int
/* A constant of REAL's type: REAL_C(0x1p-32) is 0x1p-32f */
#define REAL_C(x) x##f
/* A vector mask of 32-bit values from one of REAL's width (lanes_vector.h MASK32): the same */
#define MASK32_VECTOR(m) (m)
/* The sign bit of a REAL in a VMASK, and 2^23, from which on a float is an integer
 * (lanes_inline.h abs_lanes and rint_lanes) */
#define SIGN_BIT ((VMASK)(-0x7fffffff - 1))
#define ROUND_BIG 0x1.0p23f
