/* lanes_vector.h: WARPE_LANES = 2, 4, 8 or 16 lanes in the OpenCL vector types (lanes.h; the
 * host appends it after lanes_N.h, the masks' bytes and lane indices of the width N, where the
 * build's lane width is N, docs/walk.md §5.1). A mask's lane is 0 or -1. The names of the types
 * are REAL_NAME and IREAL_NAME's (real_single.h, real_double.h): float16 and int16, double8 and
 * long8, ... */

typedef WARPE_CAT(REAL_NAME, WARPE_LANES) VREAL;
typedef WARPE_CAT(IREAL_NAME, WARPE_LANES) VMASK;
typedef WARPE_CAT(uint, WARPE_LANES) VUINT;
typedef WARPE_CAT(ulong, WARPE_LANES) VULONG;
#define CONVERT_VULONG(x) WARPE_CAT(convert_ulong, WARPE_LANES)(x)
#define CONVERT_VREAL(x) WARPE_CAT(WARPE_CAT(convert_, REAL_NAME), WARPE_LANES)(x)
#define CONVERT_VMASK(x) WARPE_CAT(WARPE_CAT(convert_, IREAL_NAME), WARPE_LANES)(x)
#define MASK32(m) MASK32_VECTOR(m)   /* a mask for 32-bit values (real_double.h: intN) */
#define CONVERT_VUINT(x) WARPE_CAT(convert_uint, WARPE_LANES)(x)
/* the bits of a VREAL as a VMASK and back */
#define AS_VREAL(x) WARPE_CAT(WARPE_CAT(as_, REAL_NAME), WARPE_LANES)(x)
#define AS_VMASK(x) WARPE_CAT(WARPE_CAT(as_, IREAL_NAME), WARPE_LANES)(x)
/* ANY / ALL: any_lane and all_lanes below, not any() and all(), whose reduction of the sign
 * bits through four max or min steps Intel's compiler emits (docs/performance.md, issue 13) */
#define ANY(m) any_lane(m)
#define ALL(m) all_lanes(m)
#define ONE(m) (-(m))                      /* vector comparisons give -1 for true */
/* SEL(a, b, m), b where m, else a, and VSTORE(v, p) / VLOAD(p), a vector to and from a private
 * array of its lanes: lanes_vector_builtins.h or lanes_vector_inline.h. VSTORE_GLOBAL /
 * VLOAD_GLOBAL: global arrays (the self-test kernels), vstoreN / vloadN on every driver. */
#define VSTORE_GLOBAL(v, p) WARPE_CAT(vstore, WARPE_LANES)((v), 0, (p))
#define VLOAD_GLOBAL(p) WARPE_CAT(vload, WARPE_LANES)(0, (p))

/* The top bits of 8 bytes gathered into one byte, byte i to bit i: the multiplier is the sum
 * of 2^(7k), k = 0 .. 7, so byte i's top bit (bit 8i + 7) times 2^(7 (7 - i)) lands on bit
 * 56 + i, and every other product falls below bit 56 or beyond bit 63 without a carry (checked
 * for all 256 patterns, tests/test_kernel_blocks.py). */
inline uint byte_signs(ulong b)
{
    return (uint)(((b & 0x8080808080808080ul) * 0x0002040810204081ul) >> 56);
}

inline int all_lanes(VMASK m)
{
    return BYTES_ALL(MASK_BYTES(m));
}

/* ANY: clang's OR reduction of the lanes where the compiler has it (pip's PoCL 3.0 and Intel's
 * CPU runtime both do), which x86's LLVM turns into one vptest where the bytes took five
 * shuffles and moves: 4.4 % fewer instructions per event in B1's walk with the nadir estimate
 * on pip's PoCL, 1 % without it, and 1.03-1.06x its speed there (docs/performance.md). Both
 * give the same answer for every mask (tests/test_kernel_blocks.py). A property of the
 * compiler, not of the build: the one switch left here (__has_builtin as clang's manual
 * writes it for a compiler that has no __has_builtin: none of its built-ins). */
#ifndef __has_builtin
#define __has_builtin(x) 0
#endif

/* The lanes of a mask, one bit each (lane j: bit j): the OR of the lanes' own bits 2^j where
 * the compiler has the reduction, else from the mask's bytes (MASK_BYTES, BYTES_SIGNS of
 * lanes_N.h). */
#if __has_builtin(__builtin_reduce_or)
inline int any_lane(VMASK m)
{
    return __builtin_reduce_or(m) != 0;
}
inline uint lane_bits(VMASK m)
{
    return (uint)__builtin_reduce_or(m & ((VMASK)1 << LANE_INDEX));
}
#else
inline int any_lane(VMASK m)
{
    return BYTES_ANY(MASK_BYTES(m));
}
inline uint lane_bits(VMASK m)
{
    const BYTES_T b = MASK_BYTES(m);
    return BYTES_SIGNS(b);
}
#endif
