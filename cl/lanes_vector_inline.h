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
 * vloadN, with the vector registers saved around the call (docs/performance.md).
 *
 * LANES_OF(p): the vector type of the array's lanes, WARPE_LANES of its element type
 * (ext_vector_type: OpenCL's floatN, intN, uintN, longN, doubleN are such types). The element
 * type is that of (p)[0] + 0, an rvalue, which has no qualifier and no address space (C11
 * 6.3.2.1 §2, lvalue conversion drops them): __typeof__ of an lvalue (r->alive, (p)[0]) keeps
 * its address space where pointers are generic (OpenCL C 2.0 §6.5.5, NVIDIA's OpenCL 3.0),
 * and NVIDIA's compiler rejects a copy declared with it ("automatic variable qualified with an
 * invalid address space", issue 43). VSTORE's copy has the array's vector type, so a value of
 * another vector type is refused by the compiler (OpenCL C §6.2.1: no implicit conversion
 * between vector types) instead of copied with the wrong size; the bits stored are v's
 * (tools/preset_bits.py, tests/test_kernel_blocks.py). */
#define LANES_OF(p) __typeof__((p)[0] + 0) __attribute__((ext_vector_type(WARPE_LANES)))
#define VSTORE(v, p) do {                                                                  \
        typedef LANES_OF(p) vstore_t_;                                                      \
        const vstore_t_ vstore_v_ = (v);                                                    \
        __builtin_memcpy((p), &vstore_v_, sizeof(vstore_v_));                               \
    } while (0)
#define VLOAD(p) ({                                                                         \
        typedef LANES_OF(p) vload_t_;                                                       \
        vload_t_ vload_v_;                                                                  \
        __builtin_memcpy(&vload_v_, (p), sizeof(vload_v_));                                 \
        vload_v_;                                                                           \
    })
