/* exits.h: the exits and the tallies (walk.md §4): the component of an exit (docs/physics.md
 * §6.1), its time and emergence bins, the counts of each component, and in the weighted walk
 * the exact sums of weights (walk.md §6); the fates and the work-item's statistics; and, for the
 * parity tests, one record per photon (WARPE_RECORD).
 *
 * The host module that pairs with it is warpe_cl/tally.py (the tallies read back and added up;
 * their layouts are warpe_cl/params.py's, cl/tally.h's macros). The weighted sums and the
 * records have stand-ins where they are compiled out; the per-layer counts are layers.h's and
 * the pending nadir cells nadir.h's. After rays.h, layers.h and nadir.h; before walk.cl.
 */

/* The component of an exit (walk.md §4, docs/physics.md §6.1): specular; bf_direct without
 * scattering or floor reflection; otherwise, by the history rule, bf_diffuse after a floor
 * reflection and scattering without one, or by the time-window rule bf_diffuse iff t >= t1. */
WALK_STEP int exit_component(int fate, uint n_s, uint n_l, REAL t, const tallies_t *tally)
{
    if (fate == FATE_SPECULAR)
        return COMPONENT_SPECULAR;
    if (n_s == 0 && n_l == 0)
        return COMPONENT_BF_DIRECT;
    if (tally->rule_time_window)
        return t >= tally->t1 ? COMPONENT_BF_DIFFUSE : COMPONENT_SCATTERING;
    return n_l > 0 ? COMPONENT_BF_DIFFUSE : COMPONENT_SCATTERING;
}

#ifdef WARPE_WEIGHTED
/* The weighted sums' fields of tallies_t, from the kernel's arguments (walk.cl). */
#define TALLIES_WEIGHTED \
    .w_time_in_fov = w_time_in_fov, .w_time_any = w_time_any, .w_angular = w_angular, \
    .w_total = w_total, .w_early = w_early, .w2_time_in_fov = w2_time_in_fov, \
    .w2_total = w2_total,

/* An exit's weight w in the exact sums of its component's cells (walk.md §6), and w^2 in
 * those of total and time_in_fov: the same cells as the counts of tally_exits. */
WALK_STEP void add_weight(const tallies_t *tally, int component, int tb, int eb, int in_fov,
                       REAL w)
{
    const int cell = component * (tally->n_edges - 1) + tb;
    if (tb == TIME_BIN_EARLY)
        fixed_add(tally->w_early + FIXED_WORDS * component, w);
    fixed_add(tally->w_total + FIXED_WORDS * component, w);
    fixed_add(tally->w2_total + FIXED_WORDS * component, w * w);
    fixed_add(tally->w_angular + FIXED_WORDS * (component * N_EMERGENCE + eb), w);
    if (tb >= 0) {
        fixed_add(tally->w_time_any + FIXED_WORDS * cell, w);
        if (in_fov) {
            fixed_add(tally->w_time_in_fov + FIXED_WORDS * cell, w);
            fixed_add(tally->w2_time_in_fov + FIXED_WORDS * cell, w * w);
        }
    }
}

/* An exit's weight wj (specular: 1): a weight the exact sums cannot hold (NaN, < 0, or
 * w >= MAX_WEIGHT) is counted, and the host refuses the result (walk.md §6) */
WALK_STEP void weigh_exit(stats_t *st, const tallies_t *tally, int component, int tb, int eb,
                          int in_fov, REAL wj)
{
    st->lost += weight_lost(wj) ? 1 : 0;
    add_weight(tally, component, tb, eb, in_fov, wj);
}
#else
/* the analog walk: counts only */
#define TALLIES_WEIGHTED
WALK_STEP void weigh_exit(stats_t *st, const tallies_t *tally, int component, int tb, int eb,
                          int in_fov, REAL wj) {}
#endif

#ifdef WARPE_RECORD
/* The records' fields of tallies_t, from the kernel's arguments (walk.cl). */
#define TALLIES_RECORD .rec_int = rec_int, .rec_real = rec_real, .record_base = record_base,

/* The counters a record holds and the tallies do not, per lane. */
WALK_STEP void store_record_counters(const rays_t *r, IREAL *nb, IREAL *nt)
{
    VSTORE(r->n_bspec, nb);
    VSTORE(r->n_top, nt);
}


/* Photon i's record (columns RECORD_*, tally.h; warpe_cl/params.py RECORD_FIELDS), for the
 * parity tests: fate, component (-1: no exit), counters, time and emergence bins, exit time
 * (ns) and cosine, and the weight at its end. */
WALK_STEP void write_record(const tallies_t *tally, size_t i, int fate, int component, uint n_s,
                         uint n_l, int n_bspec, int n_top, int tb, int eb, REAL t,
                         REAL cos_exit, REAL w, int layer, REAL nadir)
{
    __global int *ri = tally->rec_int + N_RECORD_INT * i;
    __global REAL *rr = tally->rec_real + N_RECORD_REAL * i;
    ri[RECORD_FATE] = fate;
    ri[RECORD_COMPONENT] = component;
    ri[RECORD_N_SCAT] = (int)n_s;
    ri[RECORD_N_LAMB] = (int)n_l;
    ri[RECORD_N_BSPEC] = n_bspec;
    ri[RECORD_N_TOP] = n_top;
    ri[RECORD_TIME_BIN] = tb;
    ri[RECORD_EMERGENCE_BIN] = eb;
    ri[RECORD_LAYER] = layer;
    rr[RECORD_TIME_NS] = t;
    rr[RECORD_COS_EXIT] = cos_exit;
    rr[RECORD_WEIGHT] = w;
    rr[RECORD_NADIR] = nadir;
}
#else
/* no records */
#define TALLIES_RECORD
WALK_STEP void store_record_counters(const rays_t *r, IREAL *nb, IREAL *nt) {}
WALK_STEP void write_record(const tallies_t *tally, size_t i, int fate, int component, uint n_s,
                         uint n_l, int n_bspec, int n_top, int tb, int eb, REAL t,
                         REAL cos_exit, REAL w, int layer, REAL nadir) {}
#endif


/* Tally the lanes whose ray ended in this event (walk.md §4): its fate and scatterings in the
 * work-item's statistics; an exit (specular or escaped) in its component's total, angular,
 * time_any, and time_in_fov within the component's FOV, or in early before the first edge
 * (never in a bin); weighted, its weight (specular: 1) in the exact sums (walk.md §6).
 * WARPE_NADIR: the ray's pending nadir score into the sums (walk.md §8).
 * WARPE_RECORD: every ended ray's record. */
WALK_STEP void tally_exits(const rays_t *r, const ends_t *e, const tallies_t *tally, stats_t *st)
{
    IREAL ly[WARPE_LANES];       /* the layer each ray ends in (walk.md §7.2, §7.4) */
    store_layers(r, ly);         /* layers.h */
    const int n_time = tally->n_edges - 1;
    IREAL d[WARPE_LANES], f[WARPE_LANES], ns[WARPE_LANES], nl[WARPE_LANES];
    REAL t[WARPE_LANES], ce[WARPE_LANES];
    VSTORE(e->done, d);
    VSTORE(e->fate, f);
    VSTORE(r->n_scat, ns);
    VSTORE(r->n_lamb, nl);
    VSTORE(r->Ls * tally->ns_per_m, t);
    VSTORE(e->cos_exit, ce);
    REAL wt[WARPE_LANES];
    store_weights(r, wt);        /* rays.h */
    uint p[WARPE_LANES];
    VSTORE(r->p_lo, p);
    IREAL nb[WARPE_LANES], nt[WARPE_LANES];
    store_record_counters(r, nb, nt);
    REAL pv[WARPE_LANES], nadir[WARPE_LANES];
    IREAL pc[WARPE_LANES];
    store_pending(r, pv, pc, nadir);   /* nadir.h */
    for (int j = 0; j < WARPE_LANES; ++j) {
        if (!d[j])
            continue;
        const int fj = (int)f[j];
        const uint n_s = (uint)ns[j], n_l = (uint)nl[j];
        REAL tj = t[j];
        st->fates[fj] += 1;
        st->scattering_events += n_s;
        flush_pending(tally, p[j], pv, pc, j);
        const REAL nadir_j = lane_total(nadir, j);
        const int layer = lane_layer(ly, j);
        count_layer_end(st, fj, layer);
        int component = -1, tb = -1, eb = -1;
        if (fj == FATE_SPECULAR || fj == FATE_ESCAPED) {
            if (fj == FATE_SPECULAR) {   /* at t = 0, theta_e = 0 (walk.md §3 step 2) */
                tj = (REAL)0;
                ce[j] = (REAL)1;
            }
            component = exit_component(fj, n_s, n_l, tj, tally);
            if (n_s > 0 && n_l > 0)
                st->mixed += 1;
            eb = emergence_bin(ce[j]);
            tb = time_bin(tj, tally->time_edges, tally->n_edges);
            const int in_fov = ce[j] >= tally->cos_fov[component];
            atomic_inc(&tally->total[component]);
            atomic_inc(&tally->angular[component * N_EMERGENCE + eb]);
            if (tb >= 0) {
                atomic_inc(&tally->time_any[component * n_time + tb]);
                if (in_fov)
                    atomic_inc(&tally->time_in_fov[component * n_time + tb]);
            } else if (tb == TIME_BIN_EARLY) {
                atomic_inc(&tally->early[component]);   /* walk.md §4: never in a bin */
            }
            weigh_exit(st, tally, component, tb, eb, in_fov,
                       fj == FATE_SPECULAR ? (REAL)1 : lane_weight(wt, j));
        }
        const REAL w_end = fj == FATE_SPECULAR ? (REAL)1 : lane_weight(wt, j);
        write_record(tally, (size_t)(p[j] - tally->record_base), fj, component, n_s, n_l, (int)nb[j], (int)nt[j], tb,
                     eb, tj, ce[j], w_end, layer, nadir_j);
    }
}


/* The work-item's statistics into its row of item_stats (slots STAT_*, tally.h). */
WALK_STEP void write_stats(__global ulong *item, const stats_t *st)
{
    item[STAT_FATE_SPECULAR] = st->fates[FATE_SPECULAR];
    item[STAT_FATE_ESCAPED] = st->fates[FATE_ESCAPED];
    item[STAT_FATE_ABSORBED_MEDIUM] = st->fates[FATE_ABSORBED_MEDIUM];
    item[STAT_FATE_ABSORBED_FLOOR] = st->fates[FATE_ABSORBED_FLOOR];
    item[STAT_FATE_TERMINATED] = st->fates[FATE_TERMINATED];
    item[STAT_SCATTERING_EVENTS] = st->scattering_events;
    item[STAT_MIXED_HISTORY] = st->mixed;
    item[STAT_LOST_WEIGHTS] = st->lost;
}
