/* lanes_scalar.h: one lane, WARPE_LANES = 1 (lanes.h; the host appends it where the build's
 * lane width is 1, docs/walk.md §5.1): the lane types are the scalars, a mask is 0 or 1. */

/* The self-test program is built without the option: one lane */
#ifndef WARPE_LANES
#define WARPE_LANES 1
#endif

typedef REAL VREAL;
typedef IREAL VMASK;
typedef uint VUINT;
typedef ulong VULONG;
#define CONVERT_VULONG(x) ((ulong)(x))
#define CONVERT_VREAL(x) ((REAL)(x))
#define CONVERT_VMASK(x) ((IREAL)(x))
#define CONVERT_VUINT(x) ((uint)(x))
/* the bits of a VREAL as a VMASK and back: as_float and as_int, as_double and as_long */
#define AS_VREAL(x) WARPE_CAT(as_, REAL_NAME)(x)
#define AS_VMASK(x) WARPE_CAT(as_, IREAL_NAME)(x)
#define ANY(m) ((m) != 0)
#define ALL(m) ((m) != 0)
#define SEL(a, b, m) ((m) ? (b) : (a))     /* b where m, else a */
#define ONE(m) ((m) ? (IREAL)1 : (IREAL)0) /* 1 where m, else 0 */
#define VSTORE(v, p) (*(p) = (v))
#define VLOAD(p) (*(p))
#define VSTORE_GLOBAL(v, p) (*(p) = (v))
#define VLOAD_GLOBAL(p) (*(p))
#define MASK32(m) (m)

inline uint lane_bits(VMASK m)
{
    return m ? 1u : 0u;
}
#define LANE_INDEX ((VMASK)0)
