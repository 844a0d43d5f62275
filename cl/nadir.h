/* nadir.h: the next-event estimate toward the receiver (WARPE_NADIR, walk.md §8): the scores
 * of the scatterings and floor reflections (§8.1), their roulette (§8.3), the mirror paths of
 * the Fresnel faces (§8.5), each ray's pending cell and the exact sums of every cell (§8.2),
 * and the kernel nadir_fold that adds the work-items' slices.
 *
 * The host module that pairs with it is warpe_cl/nadir.py (the view and mirror tables, the
 * roulette's thresholds, the sums read back); the estimator and its variance are docs/walk.md
 * §8.1-§8.5, the components it scores docs/physics.md §6.1. Without
 * WARPE_NADIR every step here is an empty stand-in, which the compiler removes. After rays.h
 * and layers.h (where a score's view starts in the lane's layer); before carry.h and exits.h.
 */
#ifdef WARPE_NADIR

/* The next-event estimate toward the receiver (walk.md §8). At each volume scattering and each
 * floor reflection a ray scores s = w q T exp(-tau) / (m^2 mu): the density q per steradian
 * of leaving along the view direction inside its layer (HG phase function, or Lambert's
 * mu / pi), times what the view table holds for the virtual path up to vacuum: exp(-tau)
 * along it, the Fresnel transmissions T of its interfaces and the etendue 1 / (m^2 mu). The
 * score arrives at t = (L + path) n_0 / c and goes to the row of its component (by the
 * component rule, with the virtual path's history) and, for the first scattering or floor
 * reflection of the ray, to the order-1 row too. In a slab over a vacuum gap and in a stack the
 * virtual paths that the Fresnel faces reflect score too, each at its own time (the mirror
 * table, walk.md §8.5). */

/* The estimate's fields of scene_t and tallies_t, from the kernel's arguments (walk.cl): the
 * view (layers.h SCENE_VIEW), the mirror and gap rows, the roulette's thresholds; the
 * work-item's slice of the sums and the first guess of a time's bin. */
#define SCENE_NADIR \
    SCENE_VIEW \
    .mirror = mirror, .n_mirror = n_mirror, \
    .vg_mu = view[GAP_VIEW_ROW + VIEW_MU], .vg_tau = view[GAP_VIEW_ROW + VIEW_TAU_ABOVE], \
    .vg_path = view[GAP_VIEW_ROW + VIEW_PATH_ABOVE], \
    .vg_factor = view[GAP_VIEW_ROW + VIEW_FACTOR], \
    .s_min = nadir_min, .s_new = nadir_min_new, \
    .inv_omega_words = (REAL)(1.0 / (double)omega_words), \
    .inv_albedo_words = (REAL)(1.0 / (double)albedo_words),
#define TALLIES_NADIR \
    .nadir_sum = nadir_sum + (size_t)(get_global_id(0) % nadir_slices) \
                 * (NADIR_BATCHES * N_NADIR_ROWS * FIXED_WORDS) * (size_t)(n_edges + 1), \
    .nadir_visits = nadir_visits + (size_t)(get_global_id(0) % nadir_slices) \
                    * N_NADIR_ROWS * (size_t)(n_edges + 1), \
    .nadir_cols = n_edges + 1, .nadir_own = nadir_slices >= get_global_size(0), \
    .bin_log = bin_log, .bin_a = bin_log ? rough_log(bin_a) : bin_a, .bin_b = bin_b,


/* ln x for a normal x > 0 within 1e-3: the exponent of x plus a cubic in its significand's
 * fraction f (least squares for log2(1 + f) on [0, 1), at most 1.34e-3 off), read from x's
 * bits; inline arithmetic, where native_log is a library call on some drivers. Only the first
 * guess of nadir_column uses it, which the edges then decide: any guess gives the same bins. */
WALK_STEP REAL rough_log(REAL x)
{
#ifdef WARPE_DOUBLE
    const ulong bits = as_ulong(x);
    const int e = (int)((bits >> 52) & 0x7ff) - 1023;
    const REAL f = as_double((bits & 0xffffffffffffful) | 0x3ff0000000000000ul) - (REAL)1;
#else
    const uint bits = as_uint(x);
    const int e = (int)((bits >> 23) & 0xff) - 127;
    const REAL f = as_float((bits & 0x7fffffu) | 0x3f800000u) - (REAL)1;
#endif
    const REAL log2_f = (((REAL)0.153912 * f - (REAL)0.567749) * f + (REAL)1.41348) * f
                      + (REAL)0.00133493;
    return ((REAL)e + log2_f) * (REAL)0.69314718055994531;
}

/* A time's column of the nadir rows: 0 before the first edge, 1 + its bin, n_edges at or after
 * the last edge; and that column's time range [lo, hi) (time_bin's comparisons). */
WALK_STEP int nadir_column(REAL t, const tallies_t *tally, REAL *lo, REAL *hi)
{
    __global const REAL *edges = tally->time_edges;
    const int last = tally->n_edges - 1;
    if (t < edges[0]) {
        *lo = -INFINITY;
        *hi = edges[0];
        return 0;
    }
    if (t >= edges[last]) {
        *lo = edges[last];
        *hi = INFINITY;
        return tally->n_edges;
    }
    /* the guess, then the edges decide: edges[tb] <= t < edges[tb + 1], as time_bin */
    const REAL x = tally->bin_b * ((tally->bin_log ? rough_log(t) : t) - tally->bin_a);
    int tb = (int)x;             /* t >= the first edge: x > -1, and (int)x is floor(x) or 0 */
    tb = tb < 0 ? 0 : (tb > last - 1 ? last - 1 : tb);
    while (t < edges[tb])
        --tb;
    while (t >= edges[tb + 1])
        ++tb;
    *lo = edges[tb];
    *hi = edges[tb + 1];
    return tb + 1;
}

/* v into cell `cell` of photon p's batch (p mod NADIR_BATCHES; 2^32 is a multiple of it, so
 * the low word decides), exactly, and one visit of the cell: with plain adds in a slice the
 * work-item owns (CPUs: no cache line passed between cores), else with atomics. */
WALK_STEP void nadir_flush(const tallies_t *tally, uint p_lo, int cell, REAL v)
{
    const size_t batch = p_lo % NADIR_BATCHES;
    __global ulong *acc = tally->nadir_sum
        + FIXED_WORDS * ((batch * N_NADIR_ROWS) * tally->nadir_cols + (size_t)cell);
    if (tally->nadir_own) {
        fixed_add_own(acc, v);
        tally->nadir_visits[cell] += 1;
    } else {
        fixed_add(acc, v);
        atom_inc(tally->nadir_visits + cell);
    }
}

/* The row of a virtual path: bf_diffuse or scattering by the component rule (walk.md §4) with
 * its history (lamb: it has a floor reflection) and its arrival time tv. A path with a floor
 * reflection arrives at t >= t1 exactly, and so does one that went straight down to the
 * slab's lower face and back up; rounding put those at t1 itself just below it, so the time
 * window takes lamb as t >= t1, and t >= t1 (1 - 2^-16) as t >= t1 (walk.md §8.1). */
WALK_STEP VMASK nadir_row(VMASK lamb, VREAL tv, const tallies_t *tally)
{
    const VMASK late = (VMASK)(tv >= tally->t1 * (REAL)(1.0 - 0x1p-16));
    const VMASK bf = tally->rule_time_window ? (lamb | late) : lamb;
    return SEL((VMASK)NADIR_ROW_SCATTERING, (VMASK)NADIR_ROW_BF_DIFFUSE, bf);
}

#ifdef WARPE_WEIGHTED
/* Weighted: a score is w times the analog one, and plays no roulette (v = 0, walk.md §8.3). */
WALK_STEP void weigh_score(VREAL *s, const rays_t *r)
{
    *s *= r->w;
}

WALK_STEP void score_roulette(VREAL *s, VREAL v, VMASK same, VMASK first, const scene_t *sc) {}

WALK_STEP VREAL scatter_uniform(VUINT x1, const scene_t *sc, const rays_t *r)
{
    return (VREAL)0;
}

WALK_STEP int scatter_lost(VMASK m, VREAL v, VREAL tau, const scene_t *sc)
{
    return 0;
}

WALK_STEP VREAL floor_uniform(VUINT x, const scene_t *sc)
{
    return (VREAL)0;
}
#else
/* Analog: the roulette of small scores (walk.md §8.3) with the uniform v of the word that
 * decided the event's toll (scattering: below the medium's threshold, layers.h
 * medium_uniform; floor: below the albedo's); a score the roulette surely loses is skipped
 * (layers.h scores_lost). */
WALK_STEP void weigh_score(VREAL *s, const rays_t *r) {}

WALK_STEP void score_roulette(VREAL *s, VREAL v, VMASK same, VMASK first, const scene_t *sc)
{
    const VREAL thr = SEL((VREAL)sc->s_min, (VREAL)sc->s_new, !same & !first);
    *s = SEL(*s, SEL((VREAL)0, thr, v * thr < *s), *s < thr);
}

WALK_STEP VREAL scatter_uniform(VUINT x1, const scene_t *sc, const rays_t *r)
{
    return medium_uniform(x1, sc, r);
}

WALK_STEP int scatter_lost(VMASK m, VREAL v, VREAL tau, const scene_t *sc)
{
    return scores_lost(m, v, tau, sc);
}

WALK_STEP VREAL floor_uniform(VUINT x, const scene_t *sc)
{
    return (CONVERT_VREAL(x) + (REAL)0.5) * sc->inv_albedo_words;
}
#endif

#ifdef WARPE_RECORD
/* Every score of the ray, its record's RECORD_NADIR (exits.h write_record). */
WALK_STEP void record_score(rays_t *r, VREAL s, VMASK m)
{
    r->nadir_total = SEL(r->nadir_total, r->nadir_total + s, m);
}

WALK_STEP void fresh_total(rays_t *r, VMASK fresh)
{
    r->nadir_total = SEL(r->nadir_total, (VREAL)0, fresh);
}

WALK_STEP void store_totals(const rays_t *r, REAL *nadir)
{
    VSTORE(r->nadir_total, nadir);
}

WALK_STEP REAL lane_total(const REAL *nadir, int j)
{
    return nadir[j];
}

WALK_STEP void totals_to_rows(const rays_t *r, lane_rows_t *l)
{
    VSTORE(r->nadir_total, l->nadir_total);
}

WALK_STEP void rows_to_totals(const lane_rows_t *l, rays_t *r)
{
    r->nadir_total = VLOAD(l->nadir_total);
}
#else
/* no records: no total */
WALK_STEP void record_score(rays_t *r, VREAL s, VMASK m) {}
WALK_STEP void fresh_total(rays_t *r, VMASK fresh) {}
WALK_STEP void store_totals(const rays_t *r, REAL *nadir) {}
WALK_STEP void rows_to_totals(const lane_rows_t *l, rays_t *r) {}

WALK_STEP REAL lane_total(const REAL *nadir, int j)
{
    return (REAL)0;
}

WALK_STEP void totals_to_rows(const rays_t *r, lane_rows_t *l)
{
    for (int j = 0; j < WARPE_LANES; ++j)
        l->nadir_total[j] = (REAL)0;
}
#endif


/* The scores s (at times tv, in rows row) of the lanes in m, after the analog walk's roulette
 * of small scores (walk.md §8.3): a score s below the threshold S becomes S with probability
 * s / S, else 0 (unbiased for any S fixed before the uniform v is drawn). S is s_new for a
 * score that would open a new pending cell (an exact add and a time column: the estimate's
 * dearest work), s_min for one that adds to the ray's pending cell and for the ray's first
 * score (order 1, which opens its cells anyway). A surviving score is added to its lane's
 * pending cell while the lane stays in it, else the pending cell goes to the sums and the
 * score starts a new one; the lanes in `first` add theirs to the order-1 row at once. A ray's
 * pending sums depend on its own scores only, so the tallies do not depend on lanes or
 * launches. */
#ifdef WARPE_DOUBLE
/* Out of line in double precision: inlined at its five calls, Intel's CPU compiler took 15 to
 * 25 s to build a double-precision vector walk with the estimate (1.1 s out of line); the
 * single-precision builds keep it inline (rays.h WALK_STEP). Where it is inlined changes no
 * bit (real.h: no contraction). */
#define NADIR_ADD_STEP __attribute__((noinline))
#else
#define NADIR_ADD_STEP WALK_STEP
#endif
NADIR_ADD_STEP void nadir_add(VMASK m, VREAL s, VREAL v, const scene_t *sc, VREAL tv,
                              VMASK row, VMASK first, rays_t *r, const tallies_t *tally)
{
    const int cols = tally->nadir_cols;
    const VMASK cell0 = row * (VMASK)cols;
    VMASK same = (r->pend_cell >= cell0) & (r->pend_cell < cell0 + (VMASK)cols)
               & (tv >= r->pend_lo) & (tv < r->pend_hi);
    score_roulette(&s, v, same, first, sc);
    m &= s > (REAL)0;            /* nothing to add where exp(-tau) underflowed, or lost the
                                  * roulette */
    same &= m;
    r->pend = SEL(r->pend, r->pend + s, same);
    record_score(r, s, m);
    const VMASK moved = m & !same;
    const VMASK one = m & first;
    if (!ANY(moved | one))
        return;

    /* The lanes to visit, one bit each; the lanes' values read one by one from stores of
     * whole vectors, and the new pending cells written back into the vectors by selects, one
     * lane at a time: no vector is read back from stores of single lanes (a load that waits
     * for its stores to retire on x86, docs/performance.md). */
    const uint bits_moved = lane_bits(moved), bits_one = lane_bits(one);
    IREAL cell[WARPE_LANES], rw[WARPE_LANES];
    REAL pv[WARPE_LANES], sv[WARPE_LANES], tt[WARPE_LANES];
    uint pl[WARPE_LANES];
    VSTORE(r->pend_cell, cell);
    VSTORE(row, rw);
    VSTORE(r->pend, pv);
    VSTORE(s, sv);
    VSTORE(tv, tt);
    VSTORE(r->p_lo, pl);
    VMASK new_cell = r->pend_cell;
    VREAL new_lo = r->pend_lo, new_hi = r->pend_hi;
    uint bits = bits_moved | bits_one;
    while (bits) {
        const int j = lowest_lane(bits);
        bits &= bits - 1u;
        REAL a, b;
        const int col = nadir_column(tt[j], tally, &a, &b);
        if (bits_one >> j & 1u)
            nadir_flush(tally, pl[j], NADIR_ROW_ORDER_1 * cols + col, sv[j]);
        if (bits_moved >> j & 1u) {
            if (cell[j] >= 0)
                nadir_flush(tally, pl[j], (int)cell[j], pv[j]);
            const VMASK lane = LANE_INDEX == (VMASK)j;
            new_cell = SEL(new_cell, (VMASK)(IREAL)((int)rw[j] * cols + col), lane);
            new_lo = SEL(new_lo, (VREAL)a, lane);
            new_hi = SEL(new_hi, (VREAL)b, lane);
        }
    }
    r->pend_cell = new_cell;
    r->pend = SEL(r->pend, s, moved);
    r->pend_lo = new_lo;
    r->pend_hi = new_hi;
}

/* The mirror rows (mirror_table, walk.md §8.5) of a slab over a vacuum gap or of a stack for
 * the lanes in m, each from its own layer: an up row multiplies s, the straight score, and
 * arrives its row path after the straight path `up`; a down row multiplies sd, the score of
 * the path down along the view's mirror image to the bottom of the layer (path `down`), and
 * arrives its row path after it. Each plays the roulette with the event's uniform v. */
WALK_STEP void mirror_scores(VMASK m, VREAL s, VREAL up, VREAL sd, VREAL down, VREAL v,
                             VMASK first, const scene_t *sc, rays_t *r, const tallies_t *tally)
{
    for (int i = 0; i < sc->n_mirror; ++i) {
        __global const REAL *row = sc->mirror + N_MIRROR * i;
        const int kind = (int)row[MIRROR_KIND];
        const VMASK in = mirror_lanes(m, r, row);   /* layers.h */
        if ((kind != MIRROR_UP && kind != MIRROR_DOWN) || !ANY(in))
            continue;                        /* the gap's rows: nadir_gap */
        const VREAL si = (kind == MIRROR_UP ? s : sd) * row[MIRROR_FACTOR];
        const VREAL tvi = (r->Ls + ((kind == MIRROR_UP ? up : down) + row[MIRROR_PATH]))
                        * tally->ns_per_m;
        nadir_add(in, si, v, sc, tvi,
                  nadir_row(r->n_lamb > (VMASK)0, tvi, tally), first, r, tally);
    }
}

/* A scattering of the lanes in m, with ux, uz of their direction before it (walk.md §8):
 * q = p(Theta), the HG phase function normalised to 1 over the sphere,
 *   p = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos Theta)^(3/2)),
 * cos Theta = u . (sin_l, 0, -mu_l); tau and the path from its depth in layer l up. Called at
 * the end of the event, where the walk's own temporaries are dead and the next event's Philox
 * block, which needs none of it, overlaps it (B1 1.02-1.08x faster than in the middle of the
 * event, docs/performance.md): the lanes' position, time and weight are still those of the
 * scattering, which has been counted (n_scat >= 1). */
WALK_STEP void nadir_scatter(VMASK m, VUINT x1, VREAL ux, VREAL uz, const scene_t *sc,
                             rays_t *r, const tallies_t *tally)
{
    /* where the view starts in the lanes' layers (layers.h) */
    LAYERED_REAL g, sin_v, mu_v;
    view_angles(sc, r, &g, &sin_v, &mu_v);
    VREAL tau, path;
    view_at_depth(sc, r, &tau, &path);
    const LAYERED_REAL k = scatter_factor(sc, r, g);
    const VREAL v = scatter_uniform(x1, sc, r);
    if (scatter_lost(m, v, tau, sc))
        return;
    const VREAL c = ux * sin_v - uz * mu_v;
    const VREAL x = ((REAL)1 + g * g) - (REAL)2 * g * c;
    VREAL s = k * pow_m3_2(x) * exp_neg_score(tau);
    weigh_score(&s, r);
    const VMASK first = (r->n_scat == (VMASK)1) & (r->n_lamb == (VMASK)0);
    const VREAL tv = (r->Ls + path) * tally->ns_per_m;
    nadir_add(m, s, v, sc, tv, nadir_row(r->n_lamb > (VMASK)0, tv, tally),
              first, r, tally);
    if (sc->n_mirror > 0) {
        /* the mirror paths of a slab over a gap or of the lanes' layers of a stack
         * (mirror_table, walk.md §8.5); down: along the mirror image (sin_l, 0, +mu_l) to the
         * bottom of the layer, then the row */
        VREAL tau_down, path_down;
        view_to_bottom(sc, r, &tau_down, &path_down);
        const VREAL xd = ((REAL)1 + g * g) - (REAL)2 * g * (ux * sin_v + uz * mu_v);
        VREAL sd = k * pow_m3_2(xd) * exp_neg_score(tau_down);
        weigh_score(&sd, r);
        mirror_scores(m, s, path, sd, path_down, v, first, sc, r, tally);
    }
}

/* A reflection of the lanes in m by a floor in contact with the last layer, at its bottom
 * (walk.md §8): q = mu_l / pi, Lambert's law into the view direction inside the layer. Called
 * after the reflection is counted (n_lamb >= 1). */
WALK_STEP void nadir_contact(VMASK m, VUINT x1, const scene_t *sc, rays_t *r,
                             const tallies_t *tally)
{
    VREAL tau, path;
    view_at_depth(sc, r, &tau, &path);
    const LAYERED_REAL k = contact_factor(sc, r);
    VREAL s = k * exp_neg_score(tau);
    weigh_score(&s, r);
    const VREAL v = floor_uniform(x1, sc);
    const VREAL tv = (r->Ls + path) * tally->ns_per_m;
    const VMASK first = (r->n_scat == (VMASK)0) & (r->n_lamb == (VMASK)1);
    nadir_add(m, s, v, sc, tv, nadir_row(r->n_lamb > (VMASK)0, tv, tally),
              first, r, tally);
    /* a stack: the up rows of the last layer, whose bottom the floor is (walk.md §8.5); no
     * down rows (nothing but the floor lies below; a single layer on a floor has no rows) */
    if (sc->n_mirror > 0)
        mirror_scores(m, s, path, (VREAL)0, (VREAL)0, v, first, sc, r, tally);
}

/* A reflection of the lanes in m by the floor below a gap (walk.md §8): q = mu_g / pi in the
 * gap medium, and the gap row's path through every layer (its own interface included). */
WALK_STEP void nadir_gap(VMASK m, VUINT x0, const scene_t *sc, rays_t *r,
                         const tallies_t *tally)
{
    /* exp_neg, not the driver's exp: the same bits on every driver */
    VREAL s = (sc->vg_factor * sc->vg_mu * (REAL)(1.0 / WARPE_PI)) * exp_neg((VREAL)sc->vg_tau);
    weigh_score(&s, r);
    const VREAL v = floor_uniform(x0, sc);
    const VMASK first = (r->n_scat == (VMASK)0) & (r->n_lamb == (VMASK)1);
    const VREAL tv = (r->Ls + sc->vg_path) * tally->ns_per_m;
    nadir_add(m, s, v, sc, tv, nadir_row(r->n_lamb > (VMASK)0, tv, tally),
              first, r, tally);
    /* the paths that the faces above reflect back down and up again (walk.md §8.5): in a slab
     * over the gap, k round trips between its faces after the crossing */
    for (int i = 0; i < sc->n_mirror; ++i) {
        __global const REAL *row = sc->mirror + N_MIRROR * i;
        if ((int)row[MIRROR_KIND] != MIRROR_GAP)
            continue;
        const VREAL tvi = (r->Ls + (sc->vg_path + row[MIRROR_PATH])) * tally->ns_per_m;
        nadir_add(m, s * row[MIRROR_FACTOR], v, sc, tvi,
                  nadir_row(r->n_lamb > (VMASK)0, tvi, tally), first, r, tally);
    }
}

/* The scores of one event (walk.md §8): of the lanes a floor reflected in it, in the gap (lanes
 * in_gap) or a floor in contact, whose count n_lamb grew from lamb_before; then of the
 * scatterings (lanes coll), with the direction (ux, uz) before them: no lane both scatters and
 * reflects or ends in one event, so the order of the two leaves each ray's scores as they
 * were. */
WALK_STEP void nadir_event(VMASK coll, VMASK lamb_before, VMASK in_gap, VUINT x0, VUINT x1,
                           VREAL ux_before, VREAL uz_before, const scene_t *sc, rays_t *r,
                           const tallies_t *tally)
{
    {   /* the lanes a floor reflected in this event: in the gap, or a floor in contact */
        const VMASK lamb = r->n_lamb != lamb_before;
        if (ANY(lamb)) {
            if (ANY(lamb & in_gap))
                nadir_gap(lamb & in_gap, x0, sc, r, tally);
            if (ANY(lamb & !in_gap))
                nadir_contact(lamb & !in_gap, x1, sc, r, tally);
        }
    }
    nadir_scatter(coll, x1, ux_before, uz_before, sc, r, tally);
}

/* A new ray in the lanes in fresh: no pending score. */
WALK_STEP void fresh_nadir(rays_t *r, VMASK fresh)
{
    r->pend = SEL(r->pend, (VREAL)0, fresh);
    r->pend_cell = SEL(r->pend_cell, (VMASK)-1, fresh);
    fresh_total(r, fresh);
}

/* The pending cells of the rays that end, per lane (exits.h tally_exits), and each lane's into
 * the sums; then the lanes in done have none (they were flushed). */
WALK_STEP void store_pending(const rays_t *r, REAL *pv, IREAL *pc, REAL *nadir)
{
    VSTORE(r->pend, pv);
    VSTORE(r->pend_cell, pc);
    store_totals(r, nadir);
}

WALK_STEP void flush_pending(const tallies_t *tally, uint p, const REAL *pv, const IREAL *pc,
                             int j)
{
    if (pc[j] >= 0)
        nadir_flush(tally, p, (int)pc[j], pv[j]);
}

WALK_STEP void forget_pending(rays_t *r, VMASK done)
{
    r->pend_cell = SEL(r->pend_cell, (VMASK)-1, done);   /* flushed by tally_exits */
}

/* The pending scores to and from per-lane rows (carry.h). */
WALK_STEP void nadir_to_rows(const rays_t *r, lane_rows_t *l)
{
    VSTORE(r->pend, l->pend);
    VSTORE(r->pend_lo, l->pend_lo);
    VSTORE(r->pend_hi, l->pend_hi);
    VSTORE(r->pend_cell, l->pend_cell);
    totals_to_rows(r, l);
}

WALK_STEP void rows_to_nadir(const lane_rows_t *l, rays_t *r)
{
    r->pend = VLOAD(l->pend);
    r->pend_lo = VLOAD(l->pend_lo);
    r->pend_hi = VLOAD(l->pend_hi);
    r->pend_cell = VLOAD(l->pend_cell);
    rows_to_totals(l, r);
}

/* The nadir sums of slices 1 .. slices-1 added into slice 0, exactly (walk.md §8.2), on the
 * device: one work-item per cell of a slice (cells of FIXED_WORDS words, low word first, with
 * the carries between words; visits: one word each). The host then reads one slice, not one
 * per work-item of the walk. */
__kernel void nadir_fold(__global ulong *nadir_sum, __global ulong *nadir_visits,
                         const uint slices, const uint cells, const uint visit_cells)
{
    const size_t c = get_global_id(0);
    if (c < cells) {
        __global ulong *acc = nadir_sum + FIXED_WORDS * c;
        ulong lo = acc[0], mid = acc[1], hi = acc[2];
        for (uint s = 1; s < slices; ++s) {
            __global const ulong *b = nadir_sum + FIXED_WORDS * ((size_t)s * cells + c);
            words_add(&lo, &mid, &hi, b[0], b[1], b[2]);     /* cl/tally.h */
        }
        acc[0] = lo;
        acc[1] = mid;
        acc[2] = hi;
    }
    if (c < visit_cells) {
        ulong v = nadir_visits[c];
        for (uint s = 1; s < slices; ++s)
            v += nadir_visits[(size_t)s * visit_cells + c];
        nadir_visits[c] = v;
    }
}

#else
/* no estimate: no fields to fill, nothing to score, carry or flush */
#define SCENE_NADIR
#define TALLIES_NADIR
WALK_STEP void nadir_event(VMASK coll, VMASK lamb_before, VMASK in_gap, VUINT x0, VUINT x1,
                           VREAL ux_before, VREAL uz_before, const scene_t *sc, rays_t *r,
                           const tallies_t *tally) {}
WALK_STEP void fresh_nadir(rays_t *r, VMASK fresh) {}
WALK_STEP void store_pending(const rays_t *r, REAL *pv, IREAL *pc, REAL *nadir) {}
WALK_STEP void flush_pending(const tallies_t *tally, uint p, const REAL *pv, const IREAL *pc,
                             int j) {}
WALK_STEP void forget_pending(rays_t *r, VMASK done) {}
WALK_STEP void rows_to_nadir(const lane_rows_t *l, rays_t *r) {}

WALK_STEP REAL lane_total(const REAL *nadir, int j)
{
    return (REAL)0;
}

WALK_STEP void nadir_to_rows(const rays_t *r, lane_rows_t *l)
{
    for (int j = 0; j < WARPE_LANES; ++j) {
        l->pend[j] = l->pend_lo[j] = l->pend_hi[j] = l->nadir_total[j] = (REAL)0;
        l->pend_cell[j] = -1;
    }
}
#endif
