/* lanes_16.h: the masks' bytes and the lanes' indices of 16 lanes (lanes.h; the host appends
 * it, then lanes_vector.h, where the build's lane width is 16, docs/walk.md §5.1). */

/* A mask's lanes as bytes, 0 or -1 each (lanes.h's masks are 0 or -1: no lane is out of a
 * char's range), read as two integers (BYTES_T); BYTES_ANY, BYTES_ALL and
 * BYTES_SIGNS (one bit a lane, lanes_vector.h byte_signs) of those bytes. */
#define MASK_BYTES(m) as_ulong2(convert_char16(m))
#define BYTES_T ulong2
#define BYTES_ANY(b) (((b).x | (b).y) != 0)
#define BYTES_ALL(b) (((b).x & (b).y) == ~0ul)
#define BYTES_SIGNS(b) (byte_signs((b).x) | byte_signs((b).y) << 8)

/* Each lane's index 0 .. WARPE_LANES - 1, to pick one lane of a vector:
 * SEL(v, x, LANE_INDEX == j) */
#define LANE_INDEX ((VMASK)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
