/* tally.h: integer histograms of exits (docs/walk.md §4).
 *
 * Histograms are uint32 per launch, updated with atomic_inc (exact integer accumulation: no
 * float atomics); the host bounds each launch below 2^32 rays and adds them into int64.
 */
#ifndef WARPE_TALLY_H
#define WARPE_TALLY_H

#define N_COMPONENTS 4
#define N_EMERGENCE 90
#define COMPONENT_SPECULAR 0
#define COMPONENT_BF_DIRECT 1
#define COMPONENT_BF_DIFFUSE 2
#define COMPONENT_SCATTERING 3

#define FATE_SPECULAR 0
#define FATE_ESCAPED 1
#define FATE_ABSORBED_MEDIUM 2
#define FATE_ABSORBED_FLOOR 3
#define FATE_TERMINATED 4
#define N_FATES 5

#define TIME_BIN_LATE (-1)
#define TIME_BIN_EARLY (-2)

/* Index i with edges[i] <= t < edges[i+1]; TIME_BIN_EARLY (-2) if t < edges[0] (an early exit,
 * counted apart, never in a bin: walk.md §4); TIME_BIN_LATE (-1) if t >= edges[n_edges-1]. */
inline int time_bin(REAL t, __global const REAL *edges, int n_edges)
{
    int lo = 0, hi = n_edges - 1;
    if (t >= edges[hi])
        return TIME_BIN_LATE;
    if (t < edges[0])
        return TIME_BIN_EARLY;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (edges[mid] <= t)
            lo = mid;
        else
            hi = mid;
    }
    return lo;
}

/* Emergence bin: min(floor(theta_e in degrees), 89). */
inline int emergence_bin(REAL cos_exit)
{
    REAL deg = acos(clamp(cos_exit, (REAL)0, (REAL)1)) * (REAL)(180.0 / WARPE_PI);
    return min((int)floor(deg), N_EMERGENCE - 1);
}

#ifdef WARPE_WEIGHTED
#pragma OPENCL EXTENSION cl_khr_int64_base_atomics : enable
/* Weighted tallies (docs/walk.md §6) are sums of weights in 192-bit fixed point, in units of
 * 2^-150: acc[0], acc[1], acc[2] are the low, middle and high 64-bit words. Integer addition is
 * exact and commutative, so the sums are the same bits whatever the order in which lanes,
 * work-items and launches add them (no float atomics); a weight of 1e-20 keeps 83 bits.
 * fixed_add adds floor(w 2^150) for 0 <= w < 2^42; a carry out of a word is seen by the one
 * atomic add that made it wrap, which passes it on to the next word. */
/* True for a weight that the exact sums would drop: NaN, negative, or w >= 2^21, whose square
 * (the w^2 sums) reaches 2^42 (walk.md §6). */
inline int weight_lost(REAL w)
{
    return !(w >= (REAL)0 && w < (REAL)0x1p21);
}

inline void fixed_add(__global ulong *acc, REAL w)
{
    if (!(w > (REAL)0))
        return;
    int e;
    REAL f = frexp(w, &e);                 /* w = f 2^e, f in [1/2, 1) */
#ifdef WARPE_DOUBLE
    ulong m = (ulong)(f * 0x1p53);         /* exact: 53-bit integer, w 2^150 = m 2^s */
    int s = e - 53 + 150;
#else
    ulong m = (ulong)(f * 0x1p24f);
    int s = e - 24 + 150;
#endif
    ulong lo = 0, mid = 0, hi = 0;
    if (s < 0) {
        if (s > -64)
            lo = m >> (-s);
    } else if (s < 64) {
        lo = m << s;
        mid = s ? m >> (64 - s) : 0;
    } else if (s < 128) {
        mid = m << (s - 64);
        hi = s > 64 ? m >> (128 - s) : 0;
    } else if (s < 192) {
        hi = m << (s - 128);
    }
    ulong old = atom_add(acc, lo);
    ulong carry = (old + lo < old) ? 1ul : 0ul;
    if (mid | carry) {
        ulong add = mid + carry;            /* mid < 2^64 - 1 whenever carry = 1 (m < 2^53) */
        old = atom_add(acc + 1, add);
        carry = (old + add < old) ? 1ul : 0ul;
    } else {
        carry = 0;
    }
    if (hi | carry)
        atom_add(acc + 2, hi + carry);
}
#endif

#endif /* WARPE_TALLY_H */
