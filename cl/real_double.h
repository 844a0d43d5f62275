/* real_double.h: the double-precision walk (real.h; the host appends it to real.h where the
 * build has WARPE_DOUBLE, docs/walk.md §5.1). */

#pragma OPENCL EXTENSION cl_khr_fp64 : enable

typedef double REAL;
typedef long IREAL;      /* integer of REAL's width: masks of double vectors are long */

/* The names of REAL and IREAL, for the lane types' names (lanes.h: double8, long8, ...) */
#define REAL_NAME double
#define IREAL_NAME long
/* A constant of REAL's type: REAL_C(0x1p-32) is 0x1p-32 */
#define REAL_C(x) x
/* A vector mask of 32-bit values from one of REAL's width (lanes_vector.h MASK32) */
#define MASK32_VECTOR(m) WARPE_CAT(convert_int, WARPE_LANES)(m)
/* The sign bit of a REAL in a VMASK, and 2^52, from which on a double is an integer
 * (lanes_inline.h abs_lanes and rint_lanes) */
#define SIGN_BIT ((VMASK)(-0x7fffffffffffffffL - 1))
#define ROUND_BIG 0x1.0p52
