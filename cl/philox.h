/* philox.h: counter-based random numbers (docs/walk.md §2).
 *
 * Philox4x32-10 (Salmon, Moraes, Dror & Shaw 2011, "Parallel random numbers: as easy as
 * 1, 2, 3", the Random123 library), pinned by Random123's known-answer vectors in
 * tests/test_rng.py.
 * Key = (seed, scenario); counter = (block, photon_lo, photon_hi, 0). The j-th draw of a
 * photon is word j mod 4 of block j div 4, so a ray's numbers depend only on (seed, scenario,
 * photon index, draw index): never on the device, the work-group size or the batch.
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

/* One photon's stream of draws. */
typedef struct {
    uint2 key;
    uint photon_lo, photon_hi;
    uint block;   /* next block to generate */
    uint used;    /* words of `words` already consumed (4: generate a new block) */
    uint words[4];
} rng_t;

inline void rng_init(rng_t *r, uint seed, uint scenario, ulong photon)
{
    r->key = (uint2)(seed, scenario);
    r->photon_lo = (uint)photon;
    r->photon_hi = (uint)(photon >> 32);
    r->block = 0;
    r->used = 4;
}

inline uint rng_next(rng_t *r)
{
    if (r->used == 4) {
        uint4 w = philox4x32_10((uint4)(r->block, r->photon_lo, r->photon_hi, 0u), r->key);
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
#ifdef WARPE_DOUBLE
    return (double)x * 0x1p-32 + 0x1p-33;
#else
    return (float)x * 0x1p-32f + 0x1p-33f;
#endif
}

#endif /* WARPE_PHILOX_H */
