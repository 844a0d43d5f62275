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

/* cos(k degrees), k = 0 .. N_EMERGENCE - 1: the emergence bins' edges in cosine, exactly the
 * doubles of warpe_cl/params.py COS_DEGREE (Python's math.cos(math.radians(k)), which the
 * reference uses), rounded to float for the single-precision walk (tests/test_layout.py). */
#ifdef WARPE_DOUBLE
__constant REAL COS_DEGREE[N_EMERGENCE] = {
    0x1.0000000000000p+0, 0x1.ffec097f5af8ap-1, 0x1.ffb0278bf0567p-1, 0x1.ff4c5ed12e61dp-1,
    0x1.fec0b7170fff6p-1, 0x1.fe0d3b41815a2p-1, 0x1.fd31f94f867c6p-1, 0x1.fc2f025a23e8bp-1,
    0x1.fb046a930947ap-1, 0x1.f9b24942fe45cp-1, 0x1.f838b8c811c17p-1, 0x1.f697d6938b6c2p-1,
    0x1.f4cfc327a0080p-1, 0x1.f2e0a214e870fp-1, 0x1.f0ca99f79ba25p-1, 0x1.ee8dd4748bf15p-1,
    0x1.ec2a7e35e7b80p-1, 0x1.e9a0c6e7bdb1fp-1, 0x1.e6f0e134454ffp-1, 0x1.e41b02bfeb4cbp-1,
    0x1.e11f642522d1cp-1, 0x1.ddfe40effb805p-1, 0x1.dab7d7997cb58p-1, 0x1.d74c6982c666fp-1,
    0x1.d3bc3aeff7f95p-1, 0x1.d0079302dd767p-1, 0x1.cc2ebbb5638cap-1, 0x1.c83201d3d2c6dp-1,
    0x1.c411b4f6d2708p-1, 0x1.bfce277d339c6p-1, 0x1.bb67ae8584cabp-1, 0x1.b6dea1e76eadep-1,
    0x1.b2335c2cda945p-1, 0x1.ad663a8ae2fdcp-1, 0x1.a8779cda8eea4p-1, 0x1.a367e59158747p-1,
    0x1.9e3779b97f4a8p-1, 0x1.98e6c0ea27a14p-1, 0x1.9376253f463d1p-1, 0x1.8de613515a328p-1,
    0x1.8836fa2cf5039p-1, 0x1.82694b4a11c37p-1, 0x1.7c7d7a833bec2p-1, 0x1.7673fe0c86982p-1,
    0x1.704d4e6a54d39p-1, 0x1.6a09e667f3bcdp-1, 0x1.63aa430e07310p-1, 0x1.5d2ee398c9c2bp-1,
    0x1.5698496e20bd8p-1, 0x1.4fe6f81384fd4p-1, 0x1.491b7523c161dp-1, 0x1.4236484487abep-1,
    0x1.3b37fb1bdc939p-1, 0x1.342119455beb7p-1, 0x1.2cf2304755a5ep-1, 0x1.25abcf87c4979p-1,
    0x1.1e4e88411fd12p-1, 0x1.16daed770771dp-1, 0x1.0f5193eacdd2ap-1, 0x1.07b3120fddf13p-1,
    0x1.0000000000001p-1, 0x1.f071eedefa0eep-2, 0x1.e0bd27424507ap-2, 0x1.d0e2e2b44de01p-2,
    0x1.c0e45dabe05c9p-2, 0x1.b0c2d77379853p-2, 0x1.a07f921061ad1p-2, 0x1.901bd2298ffaap-2,
    0x1.7f98deee59680p-2, 0x1.6ef801fced33ep-2, 0x1.5e3a8748a0bf7p-2, 0x1.4d61bd000cdddp-2,
    0x1.3c6ef372fe950p-2, 0x1.2b637cf83d5c8p-2, 0x1.1a40add328e29p-2, 0x1.0907dc1930690p-2,
    0x1.ef74bf2e4b91bp-3, 0x1.ccb3236cdc672p-3, 0x1.a9cd9ac4258fap-3, 0x1.86c6ddd766253p-3,
    0x1.63a1a7e0b738cp-3, 0x1.4060b67a85377p-3, 0x1.1d06c968d9e1ap-3, 0x1.f32d44c4f62d4p-4,
    0x1.ac2609b3c576bp-4, 0x1.64fd6b8c28100p-4, 0x1.1db8f6d6a5123p-4, 0x1.acbc748efc921p-5,
    0x1.1de58c9f7dc37p-5, 0x1.1df0b2b89dd37p-6
};
#else
__constant REAL COS_DEGREE[N_EMERGENCE] = {
    0x1.0p+0f, 0x1.ffec0ap-1f, 0x1.ffb028p-1f, 0x1.ff4c5ep-1f, 0x1.fec0b8p-1f,
    0x1.fe0d3cp-1f, 0x1.fd31fap-1f, 0x1.fc2f02p-1f, 0x1.fb046ap-1f, 0x1.f9b24ap-1f,
    0x1.f838b8p-1f, 0x1.f697d6p-1f, 0x1.f4cfc4p-1f, 0x1.f2e0a2p-1f, 0x1.f0ca9ap-1f,
    0x1.ee8dd4p-1f, 0x1.ec2a7ep-1f, 0x1.e9a0c6p-1f, 0x1.e6f0e2p-1f, 0x1.e41b02p-1f,
    0x1.e11f64p-1f, 0x1.ddfe4p-1f, 0x1.dab7d8p-1f, 0x1.d74c6ap-1f, 0x1.d3bc3ap-1f,
    0x1.d00794p-1f, 0x1.cc2ebcp-1f, 0x1.c83202p-1f, 0x1.c411b4p-1f, 0x1.bfce28p-1f,
    0x1.bb67aep-1f, 0x1.b6dea2p-1f, 0x1.b2335cp-1f, 0x1.ad663ap-1f, 0x1.a8779cp-1f,
    0x1.a367e6p-1f, 0x1.9e377ap-1f, 0x1.98e6cp-1f, 0x1.937626p-1f, 0x1.8de614p-1f,
    0x1.8836fap-1f, 0x1.82694cp-1f, 0x1.7c7d7ap-1f, 0x1.7673fep-1f, 0x1.704d4ep-1f,
    0x1.6a09e6p-1f, 0x1.63aa44p-1f, 0x1.5d2ee4p-1f, 0x1.56984ap-1f, 0x1.4fe6f8p-1f,
    0x1.491b76p-1f, 0x1.423648p-1f, 0x1.3b37fcp-1f, 0x1.34211ap-1f, 0x1.2cf23p-1f,
    0x1.25abdp-1f, 0x1.1e4e88p-1f, 0x1.16daeep-1f, 0x1.0f5194p-1f, 0x1.07b312p-1f,
    0x1.0p-1f, 0x1.f071eep-2f, 0x1.e0bd28p-2f, 0x1.d0e2e2p-2f, 0x1.c0e45ep-2f,
    0x1.b0c2d8p-2f, 0x1.a07f92p-2f, 0x1.901bd2p-2f, 0x1.7f98dep-2f, 0x1.6ef802p-2f,
    0x1.5e3a88p-2f, 0x1.4d61bep-2f, 0x1.3c6ef4p-2f, 0x1.2b637cp-2f, 0x1.1a40aep-2f,
    0x1.0907dcp-2f, 0x1.ef74cp-3f, 0x1.ccb324p-3f, 0x1.a9cd9ap-3f, 0x1.86c6dep-3f,
    0x1.63a1a8p-3f, 0x1.4060b6p-3f, 0x1.1d06cap-3f, 0x1.f32d44p-4f, 0x1.ac260ap-4f,
    0x1.64fd6cp-4f, 0x1.1db8f6p-4f, 0x1.acbc74p-5f, 0x1.1de58cp-5f, 0x1.1df0b2p-6f
};
#endif

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
#ifdef WARPE_DOUBLE
    const ulong bits = as_ulong(w);
    const int biased = (int)(bits >> 52) & 0x7ff;
    const ulong m = (bits & 0xffffffffffffful) | (biased ? 0x10000000000000ul : 0ul);
    const int s = (biased ? biased : 1) - 1075 + FIXED_SHIFT;      /* w = m 2^(biased - 1075) */
#else
    const uint bits = as_uint(w);
    const int biased = (int)(bits >> 23) & 0xff;
    const ulong m = (ulong)((bits & 0x7fffffu) | (biased ? 0x800000u : 0u));
    const int s = (biased ? biased : 1) - 150 + FIXED_SHIFT;       /* w = m 2^(biased - 150) */
#endif
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
