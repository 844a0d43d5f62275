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
 *
 * The host follows this file with the parts of the build's lane width and driver
 * (warpe_cl/device.py program_files, docs/walk.md §5.1), never chosen here:
 *   lanes_scalar.h                 WARPE_LANES = 1: the types are the scalars
 *   lanes_N.h, lanes_vector.h      WARPE_LANES = N = 2, 4, 8, 16: the vector types, and the
 *                                  masks' bytes and lane indices of that width
 *   lanes_vector_builtins.h        vectors on a driver with WARPE_BUILTINS (SEL, VSTORE, VLOAD
 *   or lanes_vector_inline.h       as built-ins, or inline)
 *   lanes_builtins.h               max0, clamp_lanes, abs_lanes, rint_lanes as built-ins
 *   or lanes_inline.h              (WARPE_BUILTINS) or as comparisons, selects and bits
 * A lane width other than 1, 2, 4, 8 or 16 has no file: the host refuses it.
 */
#ifndef WARPE_LANES_H
#define WARPE_LANES_H

#define WARPE_CAT_(a, b) a##b
#define WARPE_CAT(a, b) WARPE_CAT_(a, b)

/* The index of the lowest set bit of bits != 0 (0 .. 31): bits & -bits is a power of two up to
 * 2^31, which a float holds exactly, so its exponent is the index. Inline arithmetic where
 * pip's PoCL 3.0 calls a library function for clz (docs/performance.md). */
inline int lowest_lane(uint bits)
{
    return (int)(as_uint((float)(bits & (0u - bits))) >> 23) - 127;
}

#endif /* WARPE_LANES_H */
