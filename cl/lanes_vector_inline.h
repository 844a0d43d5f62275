/* lanes_vector_inline.h: SEL, VSTORE and VLOAD of vector lanes without OpenCL's built-ins, on
 * every driver but Intel's CPU runtime (no WARPE_BUILTINS, warpe_cl/engine.py driver_options;
 * the host appends it after lanes_vector.h, docs/walk.md §5.1; Intel's runtime gets
 * lanes_vector_builtins.h). Both give the same bits. */

/* SEL(a, b, m): b where m, else a. The ?: operator on vectors, which clang turns into one
 * select instruction: pip's PoCL 3.0 calls a library function for each select(), and walks
 * 1.14-1.44x faster with ?: (docs/performance.md). */
#define SEL(a, b, m) ((m) ? (b) : (a))
/* VSTORE(v, p) / VLOAD(p): a vector to and from a private array of its lanes (the walk's
 * per-lane arrays). The bytes copied with __builtin_memcpy, which clang turns into one
 * unaligned store or load, where pip's PoCL 3.0 calls a library function for each vstoreN and
 * vloadN, with the vector registers saved around the call (docs/performance.md). VLOAD's
 * vector type is that of the array's lanes (ext_vector_type: OpenCL's floatN, intN, uintN,
 * longN, doubleN are such types). */
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
