/* tally_single.h: the single-precision parts of the tallies (tally.h; the host puts it before
 * tally.h where the build has no WARPE_DOUBLE, docs/walk.md §5.1; the double-precision
 * builds get tally_double.h). */

/* cos(k degrees), k = 0 .. N_EMERGENCE - 1: the emergence bins' edges in cosine, exactly the
 * doubles of warpe_cl/params.py COS_DEGREE (Python's math.cos(math.radians(k)), which the
 * reference uses), rounded to float for the single-precision walk (tests/test_layout.py). */
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

/* w = m 2^(s - FIXED_SHIFT) exactly for w > 0 (tally.h fixed_words): the significand m as an
 * integer (the implicit bit set for a normal w) and s from the biased exponent, both read from
 * w's bits with integer operations (IEEE 754 binary32; subnormals have the exponent of the
 * smallest normal). Returns s. */
inline int fixed_significand(REAL w, ulong *m)
{
    const uint bits = as_uint(w);
    const int biased = (int)(bits >> 23) & 0xff;
    *m = (ulong)((bits & 0x7fffffu) | (biased ? 0x800000u : 0u));
    return (biased ? biased : 1) - 150 + FIXED_SHIFT;       /* w = m 2^(biased - 150) */
}
