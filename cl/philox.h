/* philox.h: counter-based random numbers (docs/walk.md §2).
 *
 * Philox4x32-10 (Salmon, Moraes, Dror & Shaw 2011, "Parallel random numbers: as easy as
 * 1, 2, 3", the Random123 library), pinned by Random123's known-answer vectors in
 * tests/test_rng.py.
 * Key = (seed, key_lo); counter = (block, photon_lo, photon_hi, key_hi), where (key_lo, key_hi)
 * are the low and high words of the 64-bit scenario key (docs/walk.md §2). The walk uses block
 * k of a photon for its k-th event (one block per event, at most four draws), so a ray's
 * numbers depend only on (seed, scenario key, photon index, event index): never on the device,
 * the lane width, the work-group size or the batch.
 */
#ifndef WARPE_PHILOX_H
#define WARPE_PHILOX_H

#define PHILOX_M0 0xD2511F53u
#define PHILOX_M1 0xCD9E8D57u
#define PHILOX_W0 0x9E3779B9u
#define PHILOX_W1 0xBB67AE85u

inline uint4 philox4x32_10(uint4 ctr, uint2 key)
{
    for (int round = 0; round < 10; ++round) {
        if (round > 0) {
            key.x += PHILOX_W0;
            key.y += PHILOX_W1;
        }
        uint hi0 = mul_hi(PHILOX_M0, ctr.x), lo0 = PHILOX_M0 * ctr.x;
        uint hi1 = mul_hi(PHILOX_M1, ctr.z), lo1 = PHILOX_M1 * ctr.z;
        ctr = (uint4)(hi1 ^ ctr.y ^ key.x, lo1, hi0 ^ ctr.w ^ key.y, lo0);
    }
    return ctr;
}

/* The same rounds on every lane at once (lanes.h): counter (c0, c1, c2, c3w), key (k0, k1);
 * returns the four output words in x0..x3. */
inline void philox_lanes(VUINT c0, VUINT c1, VUINT c2, uint c3w, uint k0, uint k1,
                         VUINT *x0, VUINT *x1, VUINT *x2, VUINT *x3)
{
#if WARPE_LANES > 1
    /* CPUs: each 32-bit word rides in the low half of a 64-bit lane for all ten rounds, so one
     * 32x32 -> 64-bit vector product (vpmuludq, which reads only the low halves) gives both
     * halves of a product with no conversion between rounds: a word's high half may hold
     * garbage (the lo words are whole products), and only the low halves are kept at the end.
     * The same words as mul_hi and a 32-bit multiply; 1.17x (Intel's runtime) and 1.25x (PoCL)
     * the events/s of the whole walk on B1 against converting to and from 64 bits in every
     * round (docs/performance.md, issue 13), which was itself 14 % faster than mul_hi on PoCL. */
    const VULONG low = (VULONG)0xFFFFFFFFul;
    VULONG d0 = CONVERT_VULONG(c0), d1 = CONVERT_VULONG(c1), d2 = CONVERT_VULONG(c2);
    VULONG d3 = (VULONG)(ulong)c3w;
    for (int round = 0; round < 10; ++round) {
        if (round > 0) {
            k0 += PHILOX_W0;
            k1 += PHILOX_W1;
        }
        VULONG p0 = (d0 & low) * (ulong)PHILOX_M0, p1 = (d2 & low) * (ulong)PHILOX_M1;
        VULONG n0 = (p1 >> 32) ^ d1 ^ (ulong)k0, n2 = (p0 >> 32) ^ d3 ^ (ulong)k1;
        d0 = n0; d1 = p1; d2 = n2; d3 = p0;
    }
    *x0 = CONVERT_VUINT(d0); *x1 = CONVERT_VUINT(d1); *x2 = CONVERT_VUINT(d2);
    *x3 = CONVERT_VUINT(d3);
#else
    /* GPUs: mul_hi is one native instruction */
    uint c3 = c3w;
    for (int round = 0; round < 10; ++round) {
        if (round > 0) {
            k0 += PHILOX_W0;
            k1 += PHILOX_W1;
        }
        uint hi0 = mul_hi(PHILOX_M0, c0), lo0 = PHILOX_M0 * c0;
        uint hi1 = mul_hi(PHILOX_M1, c2), lo1 = PHILOX_M1 * c2;
        uint n0 = hi1 ^ c1 ^ k0, n2 = hi0 ^ c3 ^ k1;
        c0 = n0; c1 = lo1; c2 = n2; c3 = lo0;
    }
    *x0 = c0; *x1 = c1; *x2 = c2; *x3 = c3;
#endif
}

/* Philox words to uniforms U = (x + 1/2) 2^-32 in (0, 1], lane by lane (see uniform below). */
inline VREAL uniform_lanes(VUINT x)
{
    return CONVERT_VREAL(x) * REAL_C(0x1p-32) + REAL_C(0x1p-33);   /* REAL_C: real_single.h */
}

/* An event "U > P" (probability 1 - P) decided exactly on the word x: true iff x >= T with
 * T = floor(P 2^32 + 1/2) in [0, 2^32], computed exactly by the host (params.py
 * word_threshold). In exact arithmetic this is U > P for U = (x + 1/2) 2^-32, so it happens
 * with probability (2^32 - T) 2^-32, within 2^-33 of 1 - P in any precision; T = 2^32 (P = 1)
 * never happens, T = 0 (P = 0) always does (docs/walk.md §2). */
inline VMASK word_at_least(VUINT x, ulong T)
{
    if (T > 0xFFFFFFFFul)
        return (VMASK)0;
    return CONVERT_VMASK(x >= (VUINT)(uint)T);
}

/* One photon's stream of draws, in order (the self-test kernels). */
typedef struct {
    uint2 key;
    uint key_hi;
    uint photon_lo, photon_hi;
    uint block;   /* next block to generate */
    uint used;    /* words of `words` already consumed (4: generate a new block) */
    uint words[4];
} rng_t;

inline void rng_init(rng_t *r, uint seed, ulong scenario, ulong photon)
{
    r->key = (uint2)(seed, (uint)scenario);
    r->key_hi = (uint)(scenario >> 32);
    r->photon_lo = (uint)photon;
    r->photon_hi = (uint)(photon >> 32);
    r->block = 0;
    r->used = 4;
}

inline uint rng_next(rng_t *r)
{
    if (r->used == 4) {
        uint4 w = philox4x32_10((uint4)(r->block, r->photon_lo, r->photon_hi, r->key_hi), r->key);
        r->words[0] = w.x; r->words[1] = w.y; r->words[2] = w.z; r->words[3] = w.w;
        r->block += 1;
        r->used = 0;
    }
    return r->words[r->used++];
}

/* U = (x + 1/2) 2^-32 in (0, 1): exact in double; in single precision rounded to nearest
 * (it may round to 1.0f). An event of probability P happens iff U <= P (docs/walk.md §2). */
inline REAL uniform(rng_t *r)
{
    uint x = rng_next(r);
    return (REAL)x * REAL_C(0x1p-32) + REAL_C(0x1p-33);
}

#endif /* WARPE_PHILOX_H */
