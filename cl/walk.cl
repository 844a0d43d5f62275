/* walk.cl: the random walk of rays through a slab or a granular layer, several rays at a
 * time (lanes.h), and the kernel that tallies their exits.
 *
 * The rules, event by event, are docs/walk.md; the physics is shared/docs/physics.md §5-§6.
 * Structure switches (-D): WARPE_TEXTURE_SLAB or WARPE_TEXTURE_GRANULAR (exactly one),
 * WARPE_DOUBLE (precision), WARPE_LANES (photons per work-item), WARPE_WEIGHTED (survival
 * weighting, docs/walk.md §6), WARPE_RECORD (one record per photon, for the parity tests).
 * Every physical value is a kernel argument, so a new scenario never recompiles.
 *
 * A ray is a small state machine: in each event it takes the next Philox block of its own
 * stream (four uniforms u0..u3, walk.md §2) and does one of
 *   ENTRY   (slab) u0: specular reflection at the top, or entry                 (walk.md §3.2)
 *   FLIGHT  u0: free flight; then a collision (u1 absorption, u2 HG, u3 azimuth), or a boundary
 *           (u1 Fresnel, or at a contact floor u1 absorption, u2 mu, u3 azimuth) (walk.md §3.3)
 *   GAP     (slab over a vacuum gap) one floor reflection: u0 absorption, u1 mu, u2 azimuth,
 *           u3 Fresnel of the slab's lower face                                  (walk.md §3.4)
 * All lanes do their event at once; a lane whose ray ends is tallied and takes a new photon.
 */
#if defined(WARPE_TEXTURE_SLAB) == defined(WARPE_TEXTURE_GRANULAR)
#error "define exactly one of WARPE_TEXTURE_SLAB and WARPE_TEXTURE_GRANULAR"
#endif

#define PHASE_ENTRY 0
#define PHASE_FLIGHT 1
#define PHASE_GAP 2

/* Lanes in `m` end with fate f (tally.h): they are tallied after this event. */
#define FINISH(m, f) do { VMASK m_ = (m); done |= m_; fate = SEL(fate, (VMASK)(f), m_); } while (0)

/* The floor's toll on the lanes in mask variable m, on the event's word x and its uniform u
 * (walk.md §3.1, §6): analog, absorbed iff x >= albedo_words (U > A decided exactly on the
 * word, philox.h word_at_least); weighted, the weight times A (A = 0 ends the ray) and the
 * roulette on u. Afterwards m holds the lanes the floor reflects. */
#ifndef WARPE_WEIGHTED
#define FLOOR_TOLL(m, u, x) do {                                                             \
        FINISH((m) & word_at_least((x), albedo_words), FATE_ABSORBED_FLOOR);                \
        (m) &= !done;                                                                        \
    } while (0)
#else
#define FLOOR_TOLL(m, u, x) do {                                                             \
        if (A == (REAL)0) { FINISH((m), FATE_ABSORBED_FLOOR); (m) = 0; }                   \
        w = SEL(w, w * A, (m));                                                              \
        ROULETTE(m, u, FATE_ABSORBED_FLOOR);                                                 \
    } while (0)
/* Russian roulette (walk.md §6) of the lanes in mask variable m whose weight fell below
 * roulette_weight: they live on iff u <= roulette_survival, their weight divided by it; the
 * others end with fate f. Afterwards m holds the lanes that live on. */
#define ROULETTE(m, u, f) do {                                                               \
        VMASK low_ = (m) & (w < roulette_weight), dies_ = low_ & ((u) > roulette_survival);  \
        FINISH(dies_, (f));                                                                  \
        w = SEL(w, w / roulette_survival, low_ & !dies_);                                    \
        (m) &= !dies_;                                                                       \
    } while (0)
#endif

__kernel void walk(const uint seed, const ulong scenario,
                   const ulong first_photon, const uint n_photons,
                   const REAL h, const REAL E, const ulong omega_words, const REAL g,
                   const REAL n, const REAL k, const REAL A, const ulong albedo_words,
                   const REAL L_max, const uint max_flights, const int bottom_fresnel,
                   const REAL mu_a, const REAL roulette_weight, const REAL roulette_survival,
                   const int rule_time_window, const REAL t1,
                   __global const REAL *time_edges, const int n_edges,
                   const REAL cos_fov_specular, const REAL cos_fov_bf_direct,
                   const REAL cos_fov_bf_diffuse, const REAL cos_fov_scattering,
                   __global uint *next_photon,   /* [1] photons handed out so far (starts at 0) */
                   __global uint *time_in_fov,   /* [N_COMPONENTS][n_edges - 1] */
                   __global uint *time_any,      /* [N_COMPONENTS][n_edges - 1] */
                   __global uint *angular,       /* [N_COMPONENTS][N_EMERGENCE] */
                   __global uint *total,         /* [N_COMPONENTS] */
                   __global uint *early,         /* [N_COMPONENTS] exits before time_edges[0] */
                   __global ulong *item_stats    /* [global size][N_ITEM_STATS] */
#ifdef WARPE_WEIGHTED   /* sums of weights (w_) and of their squares (w2_), FIXED_WORDS each */
                   , __global ulong *w_time_in_fov  /* [N_COMPONENTS][n_edges - 1][FIXED_WORDS] */
                   , __global ulong *w_time_any     /* [N_COMPONENTS][n_edges - 1][FIXED_WORDS] */
                   , __global ulong *w_angular      /* [N_COMPONENTS][N_EMERGENCE][FIXED_WORDS] */
                   , __global ulong *w_total        /* [N_COMPONENTS][FIXED_WORDS] */
                   , __global ulong *w_early        /* [N_COMPONENTS][FIXED_WORDS] */
                   , __global ulong *w2_time_in_fov /* [N_COMPONENTS][n_edges - 1][FIXED_WORDS] */
                   , __global ulong *w2_total       /* [N_COMPONENTS][FIXED_WORDS] */
#endif
#ifdef WARPE_RECORD
                   , __global int *rec_int       /* [n_photons][N_RECORD_INT] */
                   , __global REAL *rec_real     /* [n_photons][N_RECORD_REAL] */
#endif
                   )
{
    const REAL cos_fov[N_COMPONENTS] = {cos_fov_specular, cos_fov_bf_direct, cos_fov_bf_diffuse,
                             cos_fov_scattering};
    const int n_time = n_edges - 1;
    const uint base_lo = (uint)first_photon, base_hi = (uint)(first_photon >> 32);
    /* the 64-bit scenario key: its low word keys Philox, its high word is counter word 3 */
    const uint key_lo = (uint)scenario, key_hi = (uint)(scenario >> 32);
    const REAL ns_per_m = n / (REAL)WARPE_C_M_PER_NS;   /* seed eq. 4: t = L n_eff / c */
    const REAL two_pi = (REAL)(2.0 * WARPE_PI);
#ifdef WARPE_TEXTURE_SLAB
    const VREAL R0 = fresnel_external((VREAL)1, n, k);  /* §5.2, normal incidence */
    const IREAL phase_start = PHASE_ENTRY;
#else
    const IREAL phase_start = PHASE_FLIGHT;
#endif
    ulong fates[N_FATES] = {0};
    ulong scattering_events = 0, mixed = 0, lost = 0;

    /* the lanes' rays (walk.md §3): position, direction, path, counters, stream */
    VREAL z = 0, ux = 0, uy = 0, uz = 1, Ls = 0, Lc = 0, cos_exit = 1;
    VMASK flights = 0, n_scat = 0, n_lamb = 0, n_bspec = 0, n_top = 0;
    VMASK phase = phase_start, event = 0, photon = 0, alive = 0;
    VUINT p_lo = 0, p_hi = 0;
#ifdef WARPE_WEIGHTED
    VREAL w = 1;
#endif
    int exhausted = 0;

    for (;;) {
        /* ---- refill: every lane without a ray takes the next photon ---- */
        if (!exhausted && !ALL(alive)) {
            IREAL a[WARPE_LANES], p[WARPE_LANES];
            VSTORE(alive, a);
            VSTORE(photon, p);
            uint wanted = 0;
            for (int j = 0; j < WARPE_LANES; ++j)
                wanted += a[j] ? 0u : 1u;
            uint next = atomic_add(next_photon, wanted);
            for (int j = 0; j < WARPE_LANES; ++j) {
                if (a[j])
                    continue;
                if (next < n_photons) {
                    p[j] = (IREAL)next;
                    a[j] = (IREAL)-1;    /* "true" in both mask conventions (lanes.h) */
                    next += 1;
                } else {
                    exhausted = 1;
                }
            }
            VMASK fresh = VLOAD(a) & !alive;
            photon = VLOAD(p);
            alive |= fresh;
            VUINT lo = (VUINT)base_lo + CONVERT_VUINT(photon);
            p_lo = SEL(p_lo, lo, MASK32(fresh));
            p_hi = SEL(p_hi, SEL((VUINT)base_hi, (VUINT)(base_hi + 1u), lo < base_lo),
                       MASK32(fresh));
            /* §5.1 launch: top of the layer, straight down, nothing done yet */
            z = SEL(z, (VREAL)0, fresh);
            ux = SEL(ux, (VREAL)0, fresh);
            uy = SEL(uy, (VREAL)0, fresh);
            uz = SEL(uz, (VREAL)1, fresh);
            Ls = SEL(Ls, (VREAL)0, fresh);
            Lc = SEL(Lc, (VREAL)0, fresh);
            cos_exit = SEL(cos_exit, (VREAL)1, fresh);
            flights = SEL(flights, (VMASK)0, fresh);
            n_scat = SEL(n_scat, (VMASK)0, fresh);
            n_lamb = SEL(n_lamb, (VMASK)0, fresh);
            n_bspec = SEL(n_bspec, (VMASK)0, fresh);
            n_top = SEL(n_top, (VMASK)0, fresh);
            phase = SEL(phase, (VMASK)phase_start, fresh);
            event = SEL(event, (VMASK)0, fresh);
#ifdef WARPE_WEIGHTED
            w = SEL(w, (VREAL)1, fresh);
#endif
        }
        if (!ANY(alive))
            break;

        /* ---- one event of every live lane, from block `event` of its stream (walk.md §2) ---- */
        VUINT x0, x1, x2, x3;
        philox_lanes(CONVERT_VUINT(event), p_lo, p_hi, key_hi, seed, key_lo, &x0, &x1, &x2, &x3);
        const VREAL u0 = uniform_lanes(x0), u1 = uniform_lanes(x1);
        const VREAL u2 = uniform_lanes(x2), u3 = uniform_lanes(x3);
        event += (VMASK)1;
        VMASK done = 0, fate = 0;
        const VMASK in_flight = alive & (phase == (VMASK)PHASE_FLIGHT);

#ifdef WARPE_TEXTURE_SLAB
        /* ENTRY, §5.2: specular iff u0 <= R0, recorded at t = 0, theta_e = 0; else enter */
        {
            VMASK entry = alive & (phase == (VMASK)PHASE_ENTRY);
            FINISH(entry & (u0 <= R0), FATE_SPECULAR);
            phase = SEL(phase, (VMASK)PHASE_FLIGHT, entry);
        }
        const VMASK in_gap = alive & (phase == (VMASK)PHASE_GAP);
#endif

        /* FLIGHT, §5.3-§5.8 */
        VMASK fl = in_flight;
        FINISH(fl & (flights == (VMASK)max_flights), FATE_TERMINATED);   /* §5.8 flight cap */
        fl &= !done;
        flights += ONE(fl);
        /* free flight: optical step -ln u0, physical step s = l/E (seed eq. 3) */
        VREAL s = E > (REAL)0 ? -LOG(u0) / E : (VREAL)INFINITY;
        VREAL s_b = SEL(SEL((VREAL)INFINITY, -z / uz, uz < (REAL)0), (h - z) / uz, uz > (REAL)0);
        VMASK coll = fl & (s < s_b);
        VMASK bnd = fl & !(s < s_b);
        VREAL len = SEL(s_b, s, coll);
        z = SEL(z, SEL(SEL((VREAL)0, (VREAL)h, uz > (REAL)0), z + s * uz, coll), fl);
#ifdef WARPE_DOUBLE
        Ls = SEL(Ls, Ls + len, fl);
#else
        {   /* compensated (Kahan) sum of the path: physics.md A15 */
            VREAL y = len - Lc, sum = Ls + y;
            Lc = SEL(Lc, (sum - Ls) - y, fl);
            Ls = SEL(Ls, sum, fl);
        }
#endif
        VMASK over = fl & (Ls > L_max);                                   /* §5.8 time cap */
        FINISH(over, FATE_TERMINATED);
        coll &= !over;
        bnd &= !over;
#ifdef WARPE_WEIGHTED
        /* walk.md §6: absorption as exp(-mu_a s) along every flight */
        w = SEL(w, w * exp(-mu_a * len), coll | bnd);
#endif
        /* the azimuth of a scattering or of a floor reflection: psi = 2 pi u3 */
        VREAL cos_psi, sin_psi;
        SINCOS(two_pi * u3, sin_psi, cos_psi);

        /* collision, §5.4: absorbed iff U1 > omega, decided exactly on the word: x1 >=
         * omega_words (walk.md §2); else HG deflection (u2) and azimuth (u3) */
#ifndef WARPE_WEIGHTED
        FINISH(coll & word_at_least(x1, omega_words), FATE_ABSORBED_MEDIUM);
        coll &= !done;
#else
        ROULETTE(coll, u1, FATE_ABSORBED_MEDIUM);    /* weighted: every collision scatters */
#endif
        n_scat += ONE(coll);
        if (ANY(coll)) {
            VREAL vx = ux, vy = uy, vz = uz;
            rotate_direction(&vx, &vy, &vz, hg_cos_theta(g, u2), cos_psi, sin_psi);
            ux = SEL(ux, vx, coll);
            uy = SEL(uy, vy, coll);
            uz = SEL(uz, vz, coll);
        }

        if (ANY(bnd)) {
            const VMASK down = uz > (REAL)0;
            VMASK bottom = bnd & down;
            const VMASK top = bnd & !down;
#ifdef WARPE_TEXTURE_SLAB
            /* §5.5/§5.6 interfaces of the slab: total internal reflection, else reflect iff
             * u1 <= R_int(mu) (walk.md §3.3) */
            const VREAL mu = fabs(uz);
            const VMASK reflect = (n * sqrt(fmax((REAL)1 - mu * mu, (REAL)0)) >= (REAL)1)
                                | (u1 <= fresnel_internal(mu, n));
            if (bottom_fresnel) {
                VMASK back = bottom & reflect;
                uz = SEL(uz, -uz, back);
                n_bspec += ONE(back);
                phase = SEL(phase, (VMASK)PHASE_GAP, bottom & !reflect);   /* into the gap */
                bottom = 0;
            }
            VMASK up = top & reflect;
            uz = SEL(uz, -uz, up);
            n_top += ONE(up);
            VMASK out = top & !reflect;
            /* Snell: cos theta_e = sqrt(1 - n^2 (1 - mu^2)) */
            cos_exit = SEL(cos_exit, sqrt(fmax(((REAL)1 - n * n) + n * n * mu * mu, (REAL)0)), out);
            FINISH(out, FATE_ESCAPED);
#else
            /* granular: no interface, the ray leaves at cos theta_e = -uz */
            cos_exit = SEL(cos_exit, -uz, top);
            FINISH(top, FATE_ESCAPED);
#endif
            if (ANY(bottom)) {
                /* §5.5 Lambertian floor in optical contact: absorbed iff U1 > A, else
                 * mu = sqrt(u2) and the azimuth u3 */
                FLOOR_TOLL(bottom, u1, x1);
                n_lamb += ONE(bottom);
                VREAL vx, vy, vz;
                lambert_direction(sqrt(u2), cos_psi, sin_psi, &vx, &vy, &vz);
                ux = SEL(ux, vx, bottom);
                uy = SEL(uy, vy, bottom);
                uz = SEL(uz, vz, bottom);
            }
        }

#ifdef WARPE_TEXTURE_SLAB
        /* GAP, §5.5: one reflection by the floor below the slab's lower face */
        if (ANY(in_gap)) {
            VMASK gap = in_gap;
            FLOOR_TOLL(gap, u0, x0);                            /* absorbed iff U0 > A */
            n_lamb += ONE(gap);
            VREAL mu_v = sqrt(u1);                                  /* Lambertian, in vacuum */
            VREAL c2, s2;
            SINCOS(two_pi * u2, s2, c2);
            /* u3 <= R_ext(mu_v; n, k): the slab's lower face sends it back to the floor */
            VMASK enter = gap & (u3 > fresnel_external(mu_v, n, k));
            /* refraction in (Snell, real part): sin theta_s = sin theta_v / n */
            VREAL sin_s = sqrt(fmax((REAL)1 - mu_v * mu_v, (REAL)0)) / n;
            ux = SEL(ux, sin_s * c2, enter);
            uy = SEL(uy, sin_s * s2, enter);
            uz = SEL(uz, -sqrt((REAL)1 - sin_s * sin_s), enter);
            phase = SEL(phase, (VMASK)PHASE_FLIGHT, enter);
        }
#endif

        /* ---- tally the lanes whose ray ended (walk.md §4) ---- */
        if (ANY(done)) {
            IREAL d[WARPE_LANES], f[WARPE_LANES], ns[WARPE_LANES], nl[WARPE_LANES];
            IREAL p[WARPE_LANES];
            REAL t[WARPE_LANES], ce[WARPE_LANES];
            VSTORE(done, d);
            VSTORE(fate, f);
            VSTORE(n_scat, ns);
            VSTORE(n_lamb, nl);
            VSTORE(photon, p);
            VSTORE(Ls * ns_per_m, t);
            VSTORE(cos_exit, ce);
#ifdef WARPE_WEIGHTED
            REAL wt[WARPE_LANES];
            VSTORE(w, wt);
#endif
#ifdef WARPE_RECORD
            IREAL nb[WARPE_LANES], nt[WARPE_LANES];
            VSTORE(n_bspec, nb);
            VSTORE(n_top, nt);
#endif
            for (int j = 0; j < WARPE_LANES; ++j) {
                if (!d[j])
                    continue;
                const int fj = (int)f[j];
                const uint n_s = (uint)ns[j], n_l = (uint)nl[j];
                REAL tj = t[j];
                fates[fj] += 1;
                scattering_events += n_s;
                int component = -1, tb = -1, eb = -1;
                if (fj == FATE_SPECULAR || fj == FATE_ESCAPED) {
                    /* §6.1 components */
                    if (fj == FATE_SPECULAR) {
                        component = COMPONENT_SPECULAR;
                        tj = (REAL)0;
                        ce[j] = (REAL)1;
                    } else if (n_s == 0 && n_l == 0) {
                        component = COMPONENT_BF_DIRECT;
                    } else if (rule_time_window) {
                        component = tj >= t1 ? COMPONENT_BF_DIFFUSE : COMPONENT_SCATTERING;
                    } else {
                        component = n_l > 0 ? COMPONENT_BF_DIFFUSE : COMPONENT_SCATTERING;
                    }
                    if (n_s > 0 && n_l > 0)
                        mixed += 1;
                    eb = emergence_bin(ce[j]);
                    tb = time_bin(tj, time_edges, n_edges);
                    const int in_fov = ce[j] >= cos_fov[component];
                    atomic_inc(&total[component]);
                    atomic_inc(&angular[component * N_EMERGENCE + eb]);
                    if (tb >= 0) {
                        atomic_inc(&time_any[component * n_time + tb]);
                        if (in_fov)
                            atomic_inc(&time_in_fov[component * n_time + tb]);
                    } else if (tb == TIME_BIN_EARLY) {
                        atomic_inc(&early[component]);   /* walk.md §4: never in a bin */
                    }
#ifdef WARPE_WEIGHTED
                    const REAL wj = fj == FATE_SPECULAR ? (REAL)1 : wt[j];
                    /* a weight the exact sums cannot hold (NaN, < 0, or w^2 >= 2^42) is
                     * counted, and the host refuses the result (walk.md §6) */
                    lost += weight_lost(wj) ? 1 : 0;
                    if (tb == TIME_BIN_EARLY)
                        fixed_add(w_early + FIXED_WORDS * component, wj);
                    fixed_add(w_total + FIXED_WORDS * component, wj);
                    fixed_add(w2_total + FIXED_WORDS * component, wj * wj);
                    fixed_add(w_angular + FIXED_WORDS * (component * N_EMERGENCE + eb), wj);
                    if (tb >= 0) {
                        fixed_add(w_time_any + FIXED_WORDS * (component * n_time + tb), wj);
                        if (in_fov) {
                            fixed_add(w_time_in_fov + FIXED_WORDS * (component * n_time + tb), wj);
                            fixed_add(w2_time_in_fov + FIXED_WORDS * (component * n_time + tb), wj * wj);
                        }
                    }
#endif
                }
#ifdef WARPE_RECORD
                const size_t i = (size_t)p[j];
                __global int *ri = rec_int + N_RECORD_INT * i;
                __global REAL *rr = rec_real + N_RECORD_REAL * i;
                ri[RECORD_FATE] = fj;
                ri[RECORD_COMPONENT] = component;
                ri[RECORD_N_SCAT] = (int)n_s;
                ri[RECORD_N_LAMB] = (int)n_l;
                ri[RECORD_N_BSPEC] = (int)nb[j];
                ri[RECORD_N_TOP] = (int)nt[j];
                ri[RECORD_TIME_BIN] = tb;
                ri[RECORD_EMERGENCE_BIN] = eb;
                rr[RECORD_TIME_NS] = tj;
                rr[RECORD_COS_EXIT] = ce[j];
#ifdef WARPE_WEIGHTED
                rr[RECORD_WEIGHT] = fj == FATE_SPECULAR ? (REAL)1 : wt[j];
#else
                rr[RECORD_WEIGHT] = (REAL)1;
#endif
#endif
            }
            alive &= !done;
        }
    }

    __global ulong *st = item_stats + N_ITEM_STATS * get_global_id(0);
    st[STAT_FATE_SPECULAR] = fates[FATE_SPECULAR];
    st[STAT_FATE_ESCAPED] = fates[FATE_ESCAPED];
    st[STAT_FATE_ABSORBED_MEDIUM] = fates[FATE_ABSORBED_MEDIUM];
    st[STAT_FATE_ABSORBED_FLOOR] = fates[FATE_ABSORBED_FLOOR];
    st[STAT_FATE_TERMINATED] = fates[FATE_TERMINATED];
    st[STAT_SCATTERING_EVENTS] = scattering_events;
    st[STAT_MIXED_HISTORY] = mixed;
    st[STAT_LOST_WEIGHTS] = lost;   /* weights dropped by the exact sums (weighted mode) */
}
