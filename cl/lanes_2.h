/* lanes_2.h: the masks' bytes and the lanes' indices of 2 lanes (lanes.h; the host appends
 * it, then lanes_vector.h, where the build's lane width is 2, docs/walk.md §5.1). */

/* A mask's lanes as bytes, 0 or -1 each (lanes.h's masks are 0 or -1: no lane is out of a
 * char's range), read as one integer (BYTES_T); BYTES_ANY, BYTES_ALL and
 * BYTES_SIGNS (one bit a lane, lanes_vector.h byte_signs) of those bytes. */
#define MASK_BYTES(m) as_ushort(convert_char2(m))
#define BYTES_T ushort
#define BYTES_ANY(b) ((b) != 0)
#define BYTES_ALL(b) ((b) == (ushort)0xFFFF)
#define BYTES_SIGNS(b) byte_signs((ulong)(b))

/* Each lane's index 0 .. WARPE_LANES - 1, to pick one lane of a vector:
 * SEL(v, x, LANE_INDEX == j) */
#define LANE_INDEX ((VMASK)(0, 1))
