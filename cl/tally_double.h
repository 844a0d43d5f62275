/* tally_double.h: the double-precision parts of the tallies (tally.h; the host puts it before
 * tally.h where the build has WARPE_DOUBLE, docs/walk.md §5.1; the single-precision
 * builds get tally_single.h). */

/* cos(k degrees), k = 0 .. N_EMERGENCE - 1: the emergence bins' edges in cosine, exactly the
 * doubles of warpe_cl/params.py COS_DEGREE (Python's math.cos(math.radians(k)), which the
 * reference uses), rounded to float for the single-precision walk (tests/test_layout.py). */
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

/* w = m 2^(s - FIXED_SHIFT) exactly for w > 0 (tally.h fixed_words): the significand m as an
 * integer (the implicit bit set for a normal w) and s from the biased exponent, both read from
 * w's bits with integer operations (IEEE 754 binary64; subnormals have the exponent of the
 * smallest normal). Returns s. */
inline int fixed_significand(REAL w, ulong *m)
{
    const ulong bits = as_ulong(w);
    const int biased = (int)(bits >> 52) & 0x7ff;
    *m = (bits & 0xffffffffffffful) | (biased ? 0x10000000000000ul : 0ul);
    return (biased ? biased : 1) - 1075 + FIXED_SHIFT;      /* w = m 2^(biased - 1075) */
}
