/* walk.cl: the random walk of rays through a slab, a granular layer or a stack, several rays
 * at a time (lanes.h), and the kernel that tallies their exits. The last of the walk's files
 * (warpe_cl/engine.py WALK_FILES), after rays.h (the state), layers.h (the geometry, layer by
 * layer), nadir.h (the next-event estimate), carry.h (the launch carry) and exits.h (the
 * tallies); docs/walk.md §5.1 says which file holds what. The host module that pairs with it is
 * warpe_cl/engine.py (WALK_ARGS: this kernel's arguments, in order).
 *
 * The rules, event by event, are docs/walk.md (cited "walk.md §N" below); the physics behind
 * them is docs/physics.md §5-§6, which walk.md cites rule by rule ("docs/physics.md §N" below).
 * The structure switches (-D) are listed in rays.h; each is tested in its feature's file, whose
 * stand-ins let the steps below call every feature's steps unconditionally.
 *
 * A ray is a small state machine: in each event it takes the next Philox block of its own
 * stream (four uniforms u0..u3, walk.md §2) and does one of
 *   ENTRY   (slab) u0: specular reflection at the top, or entry            (walk.md §3 step 2)
 *   FLIGHT  u0: free flight; then a collision (u1 absorption, u2 HG, u3 azimuth), or a boundary
 *           (u1 Fresnel, or at a contact floor u1 absorption, u2 mu, u3 azimuth)
 *                                                          (walk.md §3 step 3, §3.1, §3.2)
 *   GAP     (slab over a vacuum gap) one floor reflection: u0 absorption, u1 mu, u2 azimuth,
 *           u3 Fresnel of the slab's lower face                                (walk.md §3.1)
 * All lanes do their event at once; a lane whose ray ends is tallied and takes a new photon.
 */

/* A work-item's lanes before the first refill: no ray (every lane takes one then); every
 * feature's fields defined. */
WALK_STEP rays_t no_rays(IREAL phase_start)
{
    rays_t r;
    r.z = (VREAL)0;
    r.ux = (VREAL)0;
    r.uy = (VREAL)0;
    r.uz = (VREAL)1;
    r.Ls = (VREAL)0;
    r.Lc = (VREAL)0;
    r.flights = (VMASK)0;
    r.n_scat = (VMASK)0;
    r.n_lamb = (VMASK)0;
    r.n_bspec = (VMASK)0;
    r.n_top = (VMASK)0;
    r.phase = (VMASK)phase_start;
    r.event = (VMASK)0;
    r.alive = (VMASK)0;
    r.p_lo = (VUINT)0;
    r.p_hi = (VUINT)0;
    r.w = (VREAL)1;
    r.layer = (VMASK)0;
    r.z_top = (VREAL)0;
    r.z_bottom = (VREAL)0;
    r.E = (VREAL)0;
    r.g = (VREAL)0;
    r.time_scale = (VREAL)1;
    r.omega_lo = (VUINT)0;
    r.scatter_all = (VMASK)0;
    r.pend = (VREAL)0;
    r.pend_lo = (VREAL)0;
    r.pend_hi = (VREAL)0;
    r.pend_cell = (VMASK)-1;
    r.nadir_total = (VREAL)0;
    r.v_sin = (VREAL)0;
    r.v_mu = (VREAL)1;
    r.v_tau_per_m = (VREAL)0;
    r.v_path_per_m = (VREAL)0;
    r.v_tau_above = (VREAL)0;
    r.v_path_above = (VREAL)0;
    r.v_factor = (VREAL)0;
    return r;
}

/* Every lane without a ray takes the next photon of the work-item's pool (refilled from the
 * launch's counter next_photon: walk.md §5), launched at the top of the layer, straight down,
 * with nothing done yet (walk.md §3 step 1, docs/physics.md §5.1). Sets *exhausted once the
 * launch has no photon left. */
WALK_STEP void refill_lanes(rays_t *r, pool_t *pool, int *exhausted, __global uint *next_photon,
                         uint n_photons, uint base_lo, uint base_hi, IREAL phase_start)
{
    IREAL a[WARPE_LANES], p[WARPE_LANES];
    VSTORE(r->alive, a);
    uint wanted = 0;
    for (int j = 0; j < WARPE_LANES; ++j) {
        wanted += a[j] ? 0u : 1u;
        p[j] = 0;
    }
    for (int j = 0; j < WARPE_LANES; ++j) {
        if (a[j])
            continue;
        if (pool->next == pool->end) {
            /* the pool is empty: the photons still wanted and WARPE_POOL more */
            const uint take = wanted + WARPE_POOL;
            const uint first = atomic_add(next_photon, take);
            pool->next = min(first, n_photons);
            pool->end = first < n_photons ? min(first + take, n_photons) : n_photons;
            if (pool->next == pool->end) {
                *exhausted = 1;
                break;
            }
        }
        p[j] = (IREAL)pool->next;
        a[j] = (IREAL)-1;        /* "true" in both mask conventions (lanes.h) */
        pool->next += 1;
        wanted -= 1;
    }
    const VMASK fresh = VLOAD(a) & !r->alive;
    r->alive |= fresh;
    /* the photon's index first_photon + photon, carried into the high word (walk.md §2) */
    const VUINT lo = (VUINT)base_lo + CONVERT_VUINT(VLOAD(p));
    r->p_lo = SEL(r->p_lo, lo, MASK32(fresh));
    r->p_hi = SEL(r->p_hi, SEL((VUINT)base_hi, (VUINT)(base_hi + 1u), lo < base_lo),
                  MASK32(fresh));
    r->z = SEL(r->z, (VREAL)0, fresh);
    r->ux = SEL(r->ux, (VREAL)0, fresh);
    r->uy = SEL(r->uy, (VREAL)0, fresh);
    r->uz = SEL(r->uz, (VREAL)1, fresh);
    r->Ls = SEL(r->Ls, (VREAL)0, fresh);
    r->Lc = SEL(r->Lc, (VREAL)0, fresh);
    r->flights = SEL(r->flights, (VMASK)0, fresh);
    r->n_scat = SEL(r->n_scat, (VMASK)0, fresh);
    r->n_lamb = SEL(r->n_lamb, (VMASK)0, fresh);
    r->n_bspec = SEL(r->n_bspec, (VMASK)0, fresh);
    r->n_top = SEL(r->n_top, (VMASK)0, fresh);
    r->phase = SEL(r->phase, (VMASK)phase_start, fresh);
    r->event = SEL(r->event, (VMASK)0, fresh);
    fresh_weight(r, fresh);      /* rays.h */
    fresh_layers(r, fresh);      /* layers.h */
    fresh_nadir(r, fresh);       /* nadir.h */
}

/* FLIGHT, the free flight of the lanes in fl (walk.md §3 steps 3.1-3.5, docs/physics.md §5.3,
 * §5.7-§5.8): the flight cap; the optical step -ln u0 and the physical step s = l/E (paper
 * eq. 3); a collision if s is shorter than the way to the boundary, else the boundary; the path
 * L += s and its cap L_max; weighted, exp(-mu_a s) on the weight of every flight (walk.md §6).
 * In a stack, the lane's layer's E and faces, and L += s n_l / n_0 (walk.md §7.2).
 * Sets *coll and *bnd to the lanes that collide and that reach a boundary. */
WALK_STEP void free_flight(VMASK fl, VREAL u0, const scene_t *sc, rays_t *r, ends_t *e,
                        VMASK *coll, VMASK *bnd)
{
    finish(e, fl & (r->flights == (VMASK)sc->max_flights), FATE_TERMINATED);
    fl &= !e->done;
    r->flights += ONE(fl);
    VMASK c, b;
    const VREAL len = flight_to_face(fl, u0, sc, r, &c, &b);     /* layers.h */
#ifdef WARPE_DOUBLE
    r->Ls = SEL(r->Ls, r->Ls + len, fl);
#else
    {   /* compensated (Kahan) sum of the path: docs/physics.md A15 */
        const VREAL y = len - r->Lc, sum = r->Ls + y;
        r->Lc = SEL(r->Lc, (sum - r->Ls) - y, fl);
        r->Ls = SEL(r->Ls, sum, fl);
    }
#endif
    const VMASK over = fl & (r->Ls > sc->L_max);                   /* docs/physics.md §5.8 */
    finish(e, over, FATE_TERMINATED);
    c &= !over;
    b &= !over;
    weigh_flight(r, sc, len, c | b);                            /* rays.h */
    *coll = c;
    *bnd = b;
}

/* Lanes without a ray take one (walk.md §5): the parked rays of the last launch first
 * (carry.h), then new photons, until the launch has none left; in a stack they take their
 * layer's values (walk.md §7.3). Returns whether every lane has a ray. */
WALK_STEP int fill_lanes(rays_t *r, pool_t *pool, const carry_t *cy, int *exhausted,
                         int *resuming, __global uint *next_photon, uint n_photons,
                         uint base_lo, uint base_hi, IREAL phase_start, const scene_t *sc)
{
    const VMASK had = r->alive;
    if (!*exhausted) {
        if (*resuming)
            resume_lanes(r, cy, resuming);
        if (!ALL(r->alive))
            refill_lanes(r, pool, exhausted, next_photon, n_photons, base_lo, base_hi,
                         phase_start);
    }
    load_new_layers(r, had, sc);         /* new and resumed rays (layers.h) */
    return ALL(r->alive);
}

/* One event of every live lane, from block `event` of its stream (walk.md §2, §3): the entry,
 * the free flight, then a collision (the medium's toll and the HG deflection) or a face of the
 * layer (layers.h), the gap, and the nadir scores of the event (nadir.h). R0: the specular
 * reflectance at normal incidence (docs/physics.md §5.2). Sets *e to the lanes whose ray
 * ends. */
WALK_STEP void walk_event(rays_t *r, ends_t *e, stats_t *st, const scene_t *sc,
                          const tallies_t *tally, uint seed, uint key_lo, uint key_hi,
                          VREAL R0)
{
    VUINT x0, x1, x2, x3;
    philox_lanes(CONVERT_VUINT(r->event), r->p_lo, r->p_hi, key_hi, seed, key_lo,
                 &x0, &x1, &x2, &x3);
    const VREAL u0 = uniform_lanes(x0), u1 = uniform_lanes(x1);
    const VREAL u2 = uniform_lanes(x2), u3 = uniform_lanes(x3);
    const VMASK first = r->alive & (r->event == (VMASK)0);   /* entering the medium */
    r->event += (VMASK)1;
    e->done = (VMASK)0;
    e->fate = (VMASK)0;
    e->cos_exit = (VREAL)1;
    const VMASK in_flight = r->alive & (r->phase == (VMASK)PHASE_FLIGHT);

    entry_event(u0, R0, r, e);           /* ENTRY (layers.h) */
    const VMASK in_gap = gap_lanes(r);
    count_entries(st, first, e->done);   /* down[0] of a stack (walk.md §7.4) */
    const VREAL g_lanes = lanes_g(r, sc);

    VMASK coll, bnd;
    free_flight(in_flight, u0, sc, r, e, &coll, &bnd);
    const VMASK lamb_before = r->n_lamb;   /* nadir.h: a floor reflection in this event adds one */
    /* the azimuth of a scattering or of a floor reflection: psi = 2 pi u3 */
    VREAL cos_psi, sin_psi;
    azimuth(u3, &sin_psi, &cos_psi);

    /* collision (walk.md §3 step 3.4, docs/physics.md §5.4): the medium's toll, then the HG
     * deflection (u2) and the azimuth (u3) */
    coll = medium_toll(coll, u1, x1, sc, r, e);
    r->n_scat += ONE(coll);
    const VREAL ux_before = r->ux, uz_before = r->uz;   /* nadir_scatter's, below */
    {   /* some lane collides in almost every event: no test */
        VREAL vx = r->ux, vy = r->uy, vz = r->uz;
        rotate_direction(&vx, &vy, &vz, hg_cos_theta(g_lanes, u2), cos_psi, sin_psi);
        r->ux = SEL(r->ux, vx, coll);
        r->uy = SEL(r->uy, vy, coll);
        r->uz = SEL(r->uz, vz, coll);
    }

    if (ANY(bnd))
        boundary_event(bnd, u1, x1, u2, cos_psi, sin_psi, sc, r, e, st);
    if (ANY(in_gap))
        gap_event(in_gap, u0, x0, u1, u2, u3, sc, r, e, st);
    nadir_event(coll, lamb_before, in_gap, x0, x1, ux_before, uz_before, sc, r, tally);
}

/* The end of the rays in e->done (walk.md §4): tallied (exits.h), their lanes free, their
 * pending nadir cells flushed (nadir.h). */
WALK_STEP void end_rays(rays_t *r, const ends_t *e, const tallies_t *tally, stats_t *st)
{
    tally_exits(r, e, tally, st);
    r->alive &= !e->done;
    forget_pending(r, e->done);
}


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
                   const uint event_budget,      /* events per work-item in this launch */
                   const uint resume_count,      /* rays parked by the last launch */
                   __global uint *next_resume,   /* [1] parked rays taken so far (starts at 0) */
                   __global const REAL *resume_real, /* [resume_count][N_STATE_REAL] */
                   __global const uint *resume_int,  /* [resume_count][N_STATE_INT] */
                   __global uint *parked,        /* [1] rays parked by this launch (starts at 0) */
                   __global REAL *park_real,     /* [items x (lanes + WARPE_POOL)][N_STATE_REAL] */
                   __global uint *park_int,      /* [items x (lanes + WARPE_POOL)][N_STATE_INT] */
                   __global uint *time_in_fov,   /* [N_COMPONENTS][n_edges - 1] */
                   __global uint *time_any,      /* [N_COMPONENTS][n_edges - 1] */
                   __global uint *angular,       /* [N_COMPONENTS][N_EMERGENCE] */
                   __global uint *total,         /* [N_COMPONENTS] */
                   __global uint *early,         /* [N_COMPONENTS] exits before time_edges[0] */
                   __global ulong *item_stats    /* [global size][N_ITEM_STATS] */
#ifdef WARPE_TEXTURE_LAYERS     /* the stack (walk.md §7.3) */
                   , const int n_layers
                   , __global const REAL *layer_real  /* [n_layers][N_LAYER_REAL] */
                   , __global const ulong *layer_words /* [n_layers] */
                   , __global const REAL *iface_real  /* [n_layers + 1][N_IFACE_REAL] */
                   , __global const int *iface_kind   /* [n_layers + 1] */
                   , __global ulong *layer_stats      /* [global size][N_LAYER_STATS] */
#endif
#ifdef WARPE_WEIGHTED   /* sums of weights (w_) and of their squares (w2_), FIXED_WORDS each */
                   , __global ulong *w_time_in_fov  /* [N_COMPONENTS][n_edges - 1][FIXED_WORDS] */
                   , __global ulong *w_time_any     /* [N_COMPONENTS][n_edges - 1][FIXED_WORDS] */
                   , __global ulong *w_angular      /* [N_COMPONENTS][N_EMERGENCE][FIXED_WORDS] */
                   , __global ulong *w_total        /* [N_COMPONENTS][FIXED_WORDS] */
                   , __global ulong *w_early        /* [N_COMPONENTS][FIXED_WORDS] */
                   , __global ulong *w2_time_in_fov /* [N_COMPONENTS][n_edges - 1][FIXED_WORDS] */
                   , __global ulong *w2_total       /* [N_COMPONENTS][FIXED_WORDS] */
#endif
#ifdef WARPE_NADIR             /* the next-event estimate (walk.md §8) */
                   , __global const REAL *view   /* [n_layers + 1][N_VIEW] */
                   , __global const REAL *mirror /* [max(n_mirror, 1)][N_MIRROR] */
                   , const int n_mirror          /* its rows: 0 without a Fresnel face below */
                   , const REAL nadir_min        /* s_min of the score roulette (walk.md §8.3) */
                   , const REAL nadir_min_new    /* its s_new, for scores that open a cell */
                   , const int bin_log, const REAL bin_a, const REAL bin_b  /* bin guess */
                   , const uint nadir_slices     /* work-item i writes slice i mod nadir_slices */
                   , __global ulong *nadir_sum   /* [slices][NADIR_BATCHES][N_NADIR_ROWS][n_edges + 1][FIXED_WORDS] */
                   , __global ulong *nadir_visits   /* [slices][N_NADIR_ROWS][n_edges + 1] */
#endif
#ifdef WARPE_RECORD
                   , __global int *rec_int       /* [photons of the walk][N_RECORD_INT] */
                   , __global REAL *rec_real     /* [photons of the walk][N_RECORD_REAL] */
                   , const uint record_base      /* low word of the walk's first photon */
#endif
                   )
{
    /* HG's (1 - g^2)/4pi, of the nadir scores in one layer (layers.h SCENE_VIEW) */
    const REAL phase_k = ((REAL)1 - g * g) * (REAL)(0.25 / WARPE_PI);
    const scene_t sc = {.h = h, .E = E, .g = g, .n = n, .k = k, .L_max = L_max,
                        .max_flights = max_flights, .bottom_fresnel = bottom_fresnel,
                        .omega_words = omega_words, .albedo_words = albedo_words, .A = A,
                        .mu_a = mu_a, .roulette_weight = roulette_weight,
                        .roulette_survival = roulette_survival,
                        SCENE_LAYERS SCENE_NADIR};         /* layers.h, nadir.h */
    const tallies_t tally = {
        .time_in_fov = time_in_fov, .time_any = time_any, .angular = angular, .total = total,
        .early = early, TALLIES_WEIGHTED TALLIES_RECORD    /* exits.h */
        .time_edges = time_edges, .n_edges = n_edges,
        .cos_fov = {cos_fov_specular, cos_fov_bf_direct, cos_fov_bf_diffuse, cos_fov_scattering},
        .rule_time_window = rule_time_window, .t1 = t1,
        .ns_per_m = n / (REAL)WARPE_C_M_PER_NS,     /* paper eq. 4: t = L n_eff / c */
        TALLIES_NADIR};                              /* nadir.h */
    const uint base_lo = (uint)first_photon, base_hi = (uint)(first_photon >> 32);
    /* the 64-bit scenario key: its low word keys Philox, its high word is counter word 3 */
    const uint key_lo = (uint)scenario, key_hi = (uint)(scenario >> 32);
    /* the specular reflectance at normal incidence (docs/physics.md §5.2; a granular layer has
     * no entry event) */
    const VREAL R0 = fresnel_external((VREAL)1, (VREAL)n, (VREAL)k);
    const IREAL phase_start = start_phase(&sc);      /* ENTRY or FLIGHT (layers.h) */
    const carry_t carry = {.resume_count = resume_count, .next_resume = next_resume,
                           .resume_real = resume_real, .resume_int = resume_int,
                           .parked = parked, .park_real = park_real, .park_int = park_int};
    stats_t st = {{0}};
    rays_t r = no_rays(phase_start);
    int exhausted = 0, resuming = resume_count > 0;
    int all_alive = 0;           /* every lane has a ray (known without testing the mask) */
    pool_t pool = {0, 0};
    uint events = 0;

    for (;;) {
        /* the launch's event budget spent: park the rays still walking (walk.md §5) */
        if (events == event_budget) {
            park_lanes(&r, &pool, &carry, base_lo, base_hi, phase_start);
            break;
        }
        if (!all_alive) {
            all_alive = fill_lanes(&r, &pool, &carry, &exhausted, &resuming, next_photon,
                                   n_photons, base_lo, base_hi, phase_start, &sc);
            if (!all_alive && !ANY(r.alive))
                break;
        }
        events += 1;
        ends_t e;
        walk_event(&r, &e, &st, &sc, &tally, seed, key_lo, key_hi, R0);
        if (ANY(e.done)) {
            end_rays(&r, &e, &tally, &st);
            all_alive = 0;
        }
    }

    write_stats(item_stats + N_ITEM_STATS * get_global_id(0), &st);
#ifdef WARPE_TEXTURE_LAYERS     /* an argument of the stack's builds only */
    write_layer_stats(layer_stats + N_LAYER_STATS * get_global_id(0), &st);   /* layers.h */
#endif
}

/* The rows of a per-work-item statistics table (item_stats, layer_stats: `items` rows of
 * `columns` counts) added on the device into its first `parts` rows, exactly (64-bit integer
 * sums): row p gets rows p, p + parts, p + 2 parts, ... < items, column by column. Each
 * work-item reads only rows of its own residue, so row p is rewritten after its one reader.
 * The host then reads `parts` rows, not one per work-item of the walk: a GPU launch has 2^20,
 * and reading them all took most of a short walk's time (warpe_cl/engine.py sum_rows). */
__kernel void stats_fold(__global ulong *stats, const uint items, const uint columns,
                         const uint parts)
{
    const size_t g = get_global_id(0);
    if (g >= (size_t)parts * columns)
        return;
    const size_t p = g / columns, c = g % columns;
    ulong s = 0;
    for (size_t r = p; r < items; r += parts)
        s += stats[r * columns + c];
    stats[p * columns + c] = s;
}
