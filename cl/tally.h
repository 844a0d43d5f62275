/* tally.h: integer histograms of exits (docs/walk.md §4).
 *
 * Histograms are uint32 per launch, updated with atomic_inc (exact integer accumulation: no
 * float atomics); the host bounds each launch below 2^32 rays and adds them into int64.
 */
#ifndef WARPE_TALLY_H
#define WARPE_TALLY_H

/* The layouts the host reads back are defined once, in warpe_cl/params.py (kernel_layout), and
 * given to every build as -D macros (warpe_cl/engine.py build_options):
 *   N_COMPONENTS, COMPONENT_SPECULAR .. COMPONENT_SCATTERING   component indices (walk.md §4)
 *   N_FATES, FATE_SPECULAR .. FATE_TERMINATED                  fate indices (walk.md §4)
 *   N_EMERGENCE                                                1-degree emergence bins
 *   TIME_BIN_LATE, TIME_BIN_EARLY                              time_bin of a late, an early exit
 *   N_ITEM_STATS, STAT_*                                       slots of item_stats (walk.cl)
 *   N_RECORD_INT, N_RECORD_REAL, RECORD_*                      columns of the per-photon records
 *   N_STATE_REAL, N_STATE_INT, STATE_*                         columns of a parked ray (walk.cl)
 *   FIXED_SHIFT, FIXED_WORDS, MAX_WEIGHT                       the weighted sums (below) */
#if !defined(N_COMPONENTS) || !defined(N_FATES) || !defined(N_ITEM_STATS) \
    || !defined(N_RECORD_INT) || !defined(N_STATE_REAL) || !defined(FIXED_SHIFT)
#error "build the walk with the layout macros of warpe_cl/params.py (warpe_cl/engine.py)"
#endif

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

/* cos(k degrees), k = 0 .. N_EMERGENCE - 1, the emergence bins' edges in cosine: COS_DEGREE of
 * the build's precision, tally_single.h or tally_double.h, which the host puts before this file
 * (warpe_cl/device.py program_files, docs/walk.md §5.1). */

/* Emergence bin: min(floor(theta_e in degrees), 89), theta_e = acos(cos_exit), as the number of
 * whole degrees k in 1 .. 89 with cos_exit <= cos(k deg): acos gives the first guess and the
 * table decides (as the edges do in time_bin), so that every driver's acos, whose last bits
 * OpenCL leaves to it, gives the same bin. */
inline int emergence_bin(REAL cos_exit)
{
    const REAL c = clamp(cos_exit, (REAL)0, (REAL)1);
    int b = min((int)floor(acos(c) * (REAL)(180.0 / WARPE_PI)), N_EMERGENCE - 1);
    while (b > 0 && c > COS_DEGREE[b])
        --b;
    while (b < N_EMERGENCE - 1 && c <= COS_DEGREE[b + 1])
        ++b;
    return b;
}

#if defined(WARPE_WEIGHTED) || defined(WARPE_NADIR)
#pragma OPENCL EXTENSION cl_khr_int64_base_atomics : enable
#if FIXED_WORDS != 3
#error "fixed_add keeps FIXED_WORDS = 3 words per sum"
#endif
/* Weighted tallies (docs/walk.md §6) and the nadir sums (§8) are sums of weights (scores) in
 * 192-bit fixed point, in units of 2^-FIXED_SHIFT (2^-150): acc[0], acc[1], acc[2] are the low, middle and high 64-bit words.
 * Integer addition is exact and commutative, so the sums are the same bits whatever the order
 * in which lanes, work-items and launches add them (no float atomics); a weight of 1e-20 keeps
 * 83 bits. fixed_add adds floor(w 2^FIXED_SHIFT) for 0 <= w < 2^(192 - FIXED_SHIFT); a carry
 * out of a word is seen by the one atomic add that made it wrap, which passes it on to the
 * next word. */
/* True for a weight that the exact sums would drop: NaN, negative, or w >= MAX_WEIGHT (2^21),
 * whose square (the w^2 sums) reaches 2^42 (walk.md §6). */
#ifdef WARPE_WEIGHTED
inline int weight_lost(REAL w)
{
    return !(w >= (REAL)0 && w < (REAL)MAX_WEIGHT);
}
#endif

/* floor(w 2^FIXED_SHIFT) for w > 0 as its low, middle and high 64-bit words. w = m 2^(s -
 * FIXED_SHIFT) exactly, with m the significand as an integer (the implicit bit set for a
 * normal w) and s from the biased exponent, both read from w's bits with integer operations
 * (IEEE 754 binary32/binary64; subnormals have the exponent of the smallest normal). */
inline void fixed_words(REAL w, ulong *lo, ulong *mid, ulong *hi)
{
    ulong m;
    const int s = fixed_significand(w, &m);     /* tally_single.h, tally_double.h */
    *lo = 0;
    *mid = 0;
    *hi = 0;
    if (s < 0) {
        if (s > -64)
            *lo = m >> (-s);
    } else if (s < 64) {
        *lo = m << s;
        *mid = s ? m >> (64 - s) : 0;
    } else if (s < 128) {
        *mid = m << (s - 64);
        *hi = s > 64 ? m >> (128 - s) : 0;
    } else if (s < 192) {
        *hi = m << (s - 128);
    }
}

inline void fixed_add(__global ulong *acc, REAL w)
{
    if (!(w > (REAL)0))
        return;
    ulong lo, mid, hi;
    fixed_words(w, &lo, &mid, &hi);
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

#ifdef WARPE_NADIR
/* (*lo, *mid, *hi) += (b0, b1, b2): a 192-bit addition of words (low first), with the carries
 * from word to word, in private memory. */
inline void words_add(ulong *lo, ulong *mid, ulong *hi, ulong b0, ulong b1, ulong b2)
{
    const ulong a0 = *lo + b0;
    const ulong c0 = a0 < b0 ? 1ul : 0ul;
    const ulong a1 = *mid + b1;
    const ulong c1 = a1 < b1 ? 1ul : 0ul;
    const ulong a2 = a1 + c0;
    const ulong c2 = a2 < c0 ? 1ul : 0ul;
    *lo = a0;
    *mid = a2;
    *hi += b2 + c1 + c2;
}

/* fixed_add into sums that only this work-item writes (the nadir sums of a CPU work-item's own
 * slice, walk.md §8): the same 192-bit addition with plain loads and stores, no atomics. */
inline void fixed_add_own(__global ulong *acc, REAL w)
{
    if (!(w > (REAL)0))
        return;
    ulong lo, mid, hi;
    fixed_words(w, &lo, &mid, &hi);
    ulong a0 = acc[0], a1 = acc[1], a2 = acc[2];
    words_add(&a0, &a1, &a2, lo, mid, hi);
    acc[0] = a0;
    acc[1] = a1;
    acc[2] = a2;
}
#endif

#endif /* WARPE_TALLY_H */
