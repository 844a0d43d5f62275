/* lanes.h: the lane width of the walk (docs/walk.md §5).
 *
 * One kernel source, two shapes. WARPE_LANES = 1 walks one photon per work-item (GPUs, where
 * work-items are the lanes); WARPE_LANES = 2, 4, 8 or 16 walks that many photons at once in
 * the OpenCL vector types of one work-item (CPUs: PoCL does not vectorise a per-photon loop
 * across work-items, but it maps float16 onto AVX-512 / AVX2 registers). Every lane follows its
 * own photon; a lane whose photon ends takes the next photon, so all lanes stay busy and the
 * control flow of the vector never diverges: branches become selects, and a costly branch is
 * entered when any lane needs it.
 *
 * Types (REAL is float or double, real.h):
 *   VREAL  the lanes' real values            (float16, double8, ... or REAL when WARPE_LANES = 1)
 *   VMASK  the lanes' integers and masks     (int16 for float lanes, long8 for double lanes):
 *          a comparison of VREAL or VMASK values gives a VMASK; a lane is "true" when its
 *          value is non-zero (scalar: 1) or all ones (vectors: -1); only ANY / ALL / SEL / ONE
 *          below look at masks, so the two conventions never meet.
 *   VUINT  the lanes' 32-bit Philox words.
 */
#ifndef WARPE_LANES_H
#define WARPE_LANES_H

#ifndef WARPE_LANES
#define WARPE_LANES 1
#endif
#if WARPE_LANES != 1 && WARPE_LANES != 2 && WARPE_LANES != 4 && WARPE_LANES != 8 \
    && WARPE_LANES != 16
#error "WARPE_LANES must be 1, 2, 4, 8 or 16"
#endif

#ifdef WARPE_DOUBLE
typedef long IREAL;      /* integer of REAL's width: masks of double vectors are long */
#else
typedef int IREAL;
#endif

#define WARPE_CAT_(a, b) a##b
#define WARPE_CAT(a, b) WARPE_CAT_(a, b)

#if WARPE_LANES == 1
typedef REAL VREAL;
typedef IREAL VMASK;
typedef uint VUINT;
typedef ulong VULONG;
#define CONVERT_VULONG(x) ((ulong)(x))
#define CONVERT_VREAL(x) ((REAL)(x))
#define CONVERT_VMASK(x) ((IREAL)(x))
#define CONVERT_VUINT(x) ((uint)(x))
#ifdef WARPE_DOUBLE
#define AS_VREAL(x) as_double(x)
#define AS_VMASK(x) as_long(x)
#else
#define AS_VREAL(x) as_float(x)
#define AS_VMASK(x) as_int(x)
#endif
#define ANY(m) ((m) != 0)
#define ALL(m) ((m) != 0)
#define SEL(a, b, m) ((m) ? (b) : (a))     /* b where m, else a */
#define ONE(m) ((m) ? (IREAL)1 : (IREAL)0) /* 1 where m, else 0 */
#define VSTORE(v, p) (*(p) = (v))
#define VLOAD(p) (*(p))
#define VSTORE_GLOBAL(v, p) (*(p) = (v))
#define VLOAD_GLOBAL(p) (*(p))
#define MASK32(m) (m)
#else
#ifdef WARPE_DOUBLE
typedef WARPE_CAT(double, WARPE_LANES) VREAL;
typedef WARPE_CAT(long, WARPE_LANES) VMASK;
#else
typedef WARPE_CAT(float, WARPE_LANES) VREAL;
typedef WARPE_CAT(int, WARPE_LANES) VMASK;
#endif
typedef WARPE_CAT(uint, WARPE_LANES) VUINT;
typedef WARPE_CAT(ulong, WARPE_LANES) VULONG;
#define CONVERT_VULONG(x) WARPE_CAT(convert_ulong, WARPE_LANES)(x)
#ifdef WARPE_DOUBLE
#define CONVERT_VREAL(x) WARPE_CAT(convert_double, WARPE_LANES)(x)
#define CONVERT_VMASK(x) WARPE_CAT(convert_long, WARPE_LANES)(x)
#define MASK32(m) WARPE_CAT(convert_int, WARPE_LANES)(m)   /* a mask for 32-bit values */
#else
#define CONVERT_VREAL(x) WARPE_CAT(convert_float, WARPE_LANES)(x)
#define CONVERT_VMASK(x) WARPE_CAT(convert_int, WARPE_LANES)(x)
#define MASK32(m) (m)
#endif
#define CONVERT_VUINT(x) WARPE_CAT(convert_uint, WARPE_LANES)(x)
/* the bits of a VREAL as a VMASK and back */
#ifdef WARPE_DOUBLE
#define AS_VREAL(x) WARPE_CAT(as_double, WARPE_LANES)(x)
#define AS_VMASK(x) WARPE_CAT(as_long, WARPE_LANES)(x)
#else
#define AS_VREAL(x) WARPE_CAT(as_float, WARPE_LANES)(x)
#define AS_VMASK(x) WARPE_CAT(as_int, WARPE_LANES)(x)
#endif
/* ANY / ALL: any_lane and all_lanes below, not any() and all(), whose reduction of the sign
 * bits through four max or min steps Intel's compiler emits (docs/performance.md, issue 13) */
#define ANY(m) any_lane(m)
#define ALL(m) all_lanes(m)
/* SEL(a, b, m): b where m, else a. The ?: operator on vectors, which clang turns into one
 * select instruction: pip's PoCL 3.0 calls a library function for each select(), and walks
 * 1.14-1.44x faster with ?: (docs/performance.md). Intel's CPU runtime, whose built-ins are
 * inline, keeps select() (WARPE_BUILTINS, below). Both give the same bits. */
#ifdef WARPE_BUILTINS
#define SEL(a, b, m) select((a), (b), (m))
#else
#define SEL(a, b, m) ((m) ? (b) : (a))
#endif
#define ONE(m) (-(m))                      /* vector comparisons give -1 for true */
/* VSTORE(v, p) / VLOAD(p): a vector to and from a private array of its lanes (the walk's
 * per-lane arrays). Intel's CPU runtime (WARPE_BUILTINS) keeps vstoreN / vloadN, inline
 * there; every other driver copies the bytes with __builtin_memcpy, which clang turns into one
 * unaligned store or load, where pip's PoCL 3.0 calls a library function for each vstoreN and
 * vloadN, with the vector registers saved around the call (docs/performance.md). VLOAD's
 * vector type is that of the array's lanes (ext_vector_type: OpenCL's floatN, intN, uintN,
 * longN, doubleN are such types). Both give the same bits. VSTORE_GLOBAL / VLOAD_GLOBAL:
 * global arrays (the self-test kernels), vstoreN / vloadN on every driver. */
#ifdef WARPE_BUILTINS
#define VSTORE(v, p) WARPE_CAT(vstore, WARPE_LANES)((v), 0, (p))
#define VLOAD(p) WARPE_CAT(vload, WARPE_LANES)(0, (p))
#else
#define VSTORE(v, p) do {                                                                  \
        const __typeof__(v) vstore_v_ = (v);                                                \
        __builtin_memcpy((p), &vstore_v_, sizeof(vstore_v_));                               \
    } while (0)
#define VLOAD(p) ({                                                                         \
        typedef __typeof__((p)[0] + 0) vload_t_ __attribute__((ext_vector_type(WARPE_LANES))); \
        vload_t_ vload_v_;                                                                  \
        __builtin_memcpy(&vload_v_, (p), sizeof(vload_v_));                                 \
        vload_v_;                                                                           \
    })
#endif
#define VSTORE_GLOBAL(v, p) WARPE_CAT(vstore, WARPE_LANES)((v), 0, (p))
#define VLOAD_GLOBAL(p) WARPE_CAT(vload, WARPE_LANES)(0, (p))
#endif

#if WARPE_LANES > 1
/* A mask's lanes as bytes, 0 or -1 each (lanes.h's masks are 0 or -1: no lane is out of a
 * char's range), read as one or two integers. */
#if WARPE_LANES == 16
#define MASK_BYTES(m) as_ulong2(convert_char16(m))
#define BYTES_ANY(b) (((b).x | (b).y) != 0)
#define BYTES_ALL(b) (((b).x & (b).y) == ~0ul)
#elif WARPE_LANES == 8
#define MASK_BYTES(m) as_ulong(convert_char8(m))
#define BYTES_ANY(b) ((b) != 0)
#define BYTES_ALL(b) ((b) == ~0ul)
#elif WARPE_LANES == 4
#define MASK_BYTES(m) as_uint(convert_char4(m))
#define BYTES_ANY(b) ((b) != 0)
#define BYTES_ALL(b) ((b) == ~0u)
#else
#define MASK_BYTES(m) as_ushort(convert_char2(m))
#define BYTES_ANY(b) ((b) != 0)
#define BYTES_ALL(b) ((b) == (ushort)0xFFFF)
#endif

/* Each lane's index 0 .. WARPE_LANES - 1, to pick one lane of a vector:
 * SEL(v, x, LANE_INDEX == j) */
#if WARPE_LANES == 16
#define LANE_INDEX ((VMASK)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#elif WARPE_LANES == 8
#define LANE_INDEX ((VMASK)(0, 1, 2, 3, 4, 5, 6, 7))
#elif WARPE_LANES == 4
#define LANE_INDEX ((VMASK)(0, 1, 2, 3))
#else
#define LANE_INDEX ((VMASK)(0, 1))
#endif

/* ANY: clang's OR reduction of the lanes where the compiler has it (pip's PoCL 3.0 and Intel's
 * CPU runtime both do), which x86's LLVM turns into one vptest where the bytes took five
 * shuffles and moves: 4.4 % fewer instructions per event in B1's walk with the nadir estimate
 * on pip's PoCL, 1 % without it, and 1.03-1.06x its speed there (docs/performance.md). Both
 * give the same answer for every mask (tests/test_kernel_blocks.py). */
#if defined(__has_builtin)
#if __has_builtin(__builtin_reduce_or)
#define WARPE_REDUCE_OR
#endif
#endif
inline int any_lane(VMASK m)
{
#ifdef WARPE_REDUCE_OR
    return __builtin_reduce_or(m) != 0;
#else
    return BYTES_ANY(MASK_BYTES(m));
#endif
}
inline int all_lanes(VMASK m)
{
    return BYTES_ALL(MASK_BYTES(m));
}

/* The top bits of 8 bytes gathered into one byte, byte i to bit i: the multiplier is the sum
 * of 2^(7k), k = 0 .. 7, so byte i's top bit (bit 8i + 7) times 2^(7 (7 - i)) lands on bit
 * 56 + i, and every other product falls below bit 56 or beyond bit 63 without a carry (checked
 * for all 256 patterns, tests/test_kernel_blocks.py). */
inline uint byte_signs(ulong b)
{
    return (uint)(((b & 0x8080808080808080ul) * 0x0002040810204081ul) >> 56);
}

/* The lanes of a mask, one bit each (lane j: bit j): the OR of the lanes' own bits 2^j where
 * the compiler has the reduction (WARPE_REDUCE_OR), else from the mask's bytes (MASK_BYTES). */
inline uint lane_bits(VMASK m)
{
#ifdef WARPE_REDUCE_OR
    return (uint)__builtin_reduce_or(m & ((VMASK)1 << LANE_INDEX));
#elif WARPE_LANES == 16
    const ulong2 b = MASK_BYTES(m);
    return byte_signs(b.x) | byte_signs(b.y) << 8;
#else
    return byte_signs((ulong)MASK_BYTES(m));
#endif
}

#else
inline uint lane_bits(VMASK m)
{
    return m ? 1u : 0u;
}
#define LANE_INDEX ((VMASK)0)
#endif

/* The index of the lowest set bit of bits != 0 (0 .. 31): bits & -bits is a power of two up to
 * 2^31, which a float holds exactly, so its exponent is the index. Inline arithmetic where
 * pip's PoCL 3.0 calls a library function for clz (docs/performance.md). */
inline int lowest_lane(uint bits)
{
    return (int)(as_uint((float)(bits & (0u - bits))) >> 23) - 127;
}

/* fmax(x, 0), clamp, fabs and rint of the lanes. WARPE_BUILTINS (warpe_cl/engine.py
 * driver_options: Intel's CPU runtime, whose built-ins are inline instructions) uses the
 * built-ins; every other driver gets comparisons, selects and bits, where pip's PoCL 3.0 calls
 * a library function for each built-in, with the vector registers saved around the call
 * (docs/performance.md). The same values for every number the walk gives them (never a NaN,
 * tests/test_kernel_blocks.py): max0 gives +0 for -0, where fmax may give either zero, and no
 * difference or sum of the walk is -0 (a - a is +0). */
#ifdef WARPE_BUILTINS
#define max0(x) fmax((x), (REAL)0)
#define clamp_lanes(x, lo, hi) clamp((x), (lo), (hi))
#define abs_lanes(x) fabs(x)
#define rint_lanes(x) rint(x)
#else
#ifdef WARPE_DOUBLE
#define SIGN_BIT ((VMASK)(-0x7fffffffffffffffL - 1))
#define ROUND_BIG 0x1.0p52
#else
#define SIGN_BIT ((VMASK)(-0x7fffffff - 1))
#define ROUND_BIG 0x1.0p23f
#endif
inline VREAL max0(VREAL x)
{
    return SEL((VREAL)0, x, x > (REAL)0);
}
inline VREAL clamp_lanes(VREAL x, REAL lo, REAL hi)
{
    return SEL(SEL(x, (VREAL)lo, x < lo), (VREAL)hi, x > hi);
}
inline VREAL abs_lanes(VREAL x)
{
    return AS_VREAL(AS_VMASK(x) & ~SIGN_BIT);
}
/* rint (to nearest, ties to even): x + m - m with m = 2^23 (double: 2^52) of x's sign rounds x
 * to an integer where |x| < 2^23, ties to even, and the sign of zero is x's, as rint's; from
 * 2^23 on, x is an integer. */
inline VREAL rint_lanes(VREAL x)
{
    const VMASK sign = AS_VMASK(x) & SIGN_BIT;
    const VREAL m = AS_VREAL(AS_VMASK((VREAL)ROUND_BIG) | sign);
    const VREAL r = AS_VREAL(AS_VMASK((x + m) - m) | sign);
    return SEL(r, x, abs_lanes(x) >= (REAL)ROUND_BIG);
}
#endif

#endif /* WARPE_LANES_H */
