/* walk.cl: the random walk of rays through a slab or a granular layer, several rays at a
 * time (lanes.h), and the kernel that tallies their exits.
 *
 * The rules, event by event, are docs/walk.md (cited "walk.md §N" below); the physics behind
 * them is docs/physics.md §5-§6, which walk.md cites rule by rule ("docs/physics.md §N" below).
 * Structure switches (-D): WARPE_TEXTURE_SLAB, WARPE_TEXTURE_GRANULAR or WARPE_TEXTURE_LAYERS
 * (a stack, walk.md §7: exactly one),
 * WARPE_DOUBLE (precision), WARPE_LANES (photons per work-item), WARPE_POOL (photons a
 * work-item takes ahead, pool_t), WARPE_WEIGHTED (survival weighting, walk.md §6),
 * WARPE_NADIR (the next-event estimate toward the receiver, walk.md §8),
 * WARPE_RECORD (one record per photon, for the parity tests), WARPE_NO_SCORE_SKIP (every
 * nadir score computed, for the test that the skip of nadir_scatter changes no bit); the
 * layouts the host reads back come as -D macros too (tally.h). Every physical value is a
 * kernel argument, so a new scenario never recompiles.
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
#if defined(WARPE_TEXTURE_SLAB) + defined(WARPE_TEXTURE_GRANULAR) + defined(WARPE_TEXTURE_LAYERS) != 1
#error "define exactly one of WARPE_TEXTURE_SLAB, WARPE_TEXTURE_GRANULAR and WARPE_TEXTURE_LAYERS"
#endif
/* The builds with an entry event and a gap: a slab, and a stack (whose top and bottom are
 * per-scenario values, walk.md §7) */
#if defined(WARPE_TEXTURE_SLAB) || defined(WARPE_TEXTURE_LAYERS)
#define WARPE_INTERFACES
#endif

#define PHASE_ENTRY 0
#define PHASE_FLIGHT 1
#define PHASE_GAP 2

/* The steps of the walk below are functions to be read, not called: each is inlined into the
 * kernel, so that the rays stay in registers. With a plain `inline`, PoCL 3.1 (LLVM 15) kept
 * the larger ones out of line, and the rays in memory (about -1 % events/s on B1 and B3:
 * docs/bench/2026-11-22_refactor_ab.txt). */
#define WALK_STEP inline __attribute__((always_inline))

/* The scenario's inputs (walk.md §1), the same for every ray of a launch. */
typedef struct {
    REAL h, E, g, n, k;          /* thickness (m), extinction (1/m), HG g, index n + ik */
    REAL L_max;                  /* path-length cap, m (docs/physics.md §5.8) */
    uint max_flights;            /* flight cap (docs/physics.md §5.8) */
    int bottom_fresnel;          /* slab: a vacuum gap above the floor (else optical contact) */
    ulong omega_words;           /* analog: absorbed in the medium iff x1 >= it (walk.md §2) */
    ulong albedo_words;          /* analog: absorbed by the floor iff its word >= it */
    REAL A;                      /* the floor's albedo (weighted: a factor of the weight) */
    REAL mu_a;                   /* weighted: absorption along the path, 1/m (walk.md §6) */
    REAL roulette_weight, roulette_survival;   /* weighted: the roulette (walk.md §6) */
#ifdef WARPE_TEXTURE_LAYERS
    int n_layers;                /* N (walk.md §7.1) */
    __global const REAL *layer_real;   /* [N][N_LAYER_REAL]: LAYER_* columns (walk.md §7.3) */
    __global const ulong *layer_words; /* [N]: the word threshold T_omega of each layer */
    __global const REAL *iface_real;   /* [N + 1][N_IFACE_REAL]: IFACE_* columns */
    __global const int *iface_kind;    /* [N + 1]: 0 transparent, 1 Fresnel */
    REAL gap_near, gap_far_n, gap_far_k;   /* from the gap up into the last layer */
#endif
#ifdef WARPE_NADIR
#ifdef WARPE_TEXTURE_LAYERS
    __global const REAL *view;   /* [N + 1][N_VIEW]: VIEW_* columns per layer (walk.md §8) */
#else
    /* the layer's row of the view table (walk.md §8), and phase_k = (1 - g^2) / (4 pi) */
    REAL v_sin, v_mu, v_tau_per_m, v_path_per_m, v_factor, phase_k;
#endif
    /* the mirror paths of a slab over a vacuum gap or of a stack, [n_mirror][N_MIRROR]
     * (walk.md §8.5) */
    __global const REAL *mirror;
    int n_mirror;
    /* the gap's row: a floor reflection below a Fresnel bottom (walk.md §8) */
    REAL vg_mu, vg_tau, vg_path, vg_factor;
    /* analog: scores below s_min, or s_new where they would open a new pending cell, play a
     * roulette (walk.md §8.3); inv_omega_words and inv_albedo_words turn a surviving word
     * x < T into a uniform (x + 1/2) / T, the roulette's v (nothing else uses it) */
    REAL s_min, s_new, inv_omega_words, inv_albedo_words;
#ifndef WARPE_TEXTURE_LAYERS
    REAL s_cap;                  /* a scattering's score <= s_cap exp_neg_bound(tau) (score.h) */
#endif
#endif
} scene_t;

/* The rays of a work-item's lanes (walk.md §3), one per lane. */
typedef struct {
    VREAL z, ux, uy, uz;         /* depth (m, 0 at the top, downwards) and direction */
    VREAL Ls, Lc;                /* path length L (m) and, in single precision, its Kahan carry */
    VMASK flights, n_scat, n_lamb, n_bspec, n_top;   /* the counters of walk.md §3 */
    VMASK phase;                 /* PHASE_ENTRY, PHASE_FLIGHT or PHASE_GAP: the next event */
    VMASK event;                 /* the next event's Philox block (walk.md §2) */
    VMASK alive;                 /* lanes with a ray */
    VUINT p_lo, p_hi;            /* the photon's 64-bit index (first_photon + photon) */
#ifdef WARPE_WEIGHTED
    VREAL w;                     /* the weight (walk.md §6) */
#endif
#ifdef WARPE_TEXTURE_LAYERS
    VMASK layer;                 /* the layer l the ray is in (N: the gap; walk.md §7.2) */
    /* layer l's values, loaded when the ray enters it (load_layer) */
    VREAL z_top, z_bottom, E, g, time_scale;
    VUINT omega_lo;              /* absorbed iff x1 >= omega_lo, unless scatter_all */
    VMASK scatter_all;           /* T_omega = 2^32: no word absorbs */
#endif
#ifdef WARPE_NADIR
    /* the ray's pending nadir score (walk.md §8): its consecutive scores in one cell, of time
     * range [pend_lo, pend_hi), added up before they go to the batch sums; cell -1: none */
    VREAL pend, pend_lo, pend_hi;
    VMASK pend_cell;
#ifdef WARPE_RECORD
    VREAL nadir_total;           /* every score of the ray (its record) */
#endif
#ifdef WARPE_TEXTURE_LAYERS
    /* layer l's row of the view table, loaded with its other values (load_layer) */
    VREAL v_sin, v_mu, v_tau_per_m, v_path_per_m, v_tau_above, v_path_above, v_factor;
#endif
#endif
} rays_t;

/* A work-item's lanes before the first refill: no ray (every lane takes one then). */
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
#ifdef WARPE_WEIGHTED
    r.w = (VREAL)1;
#endif
#ifdef WARPE_TEXTURE_LAYERS
    r.layer = (VMASK)0;
    r.z_top = (VREAL)0;
    r.z_bottom = (VREAL)0;
    r.E = (VREAL)0;
    r.g = (VREAL)0;
    r.time_scale = (VREAL)1;
    r.omega_lo = (VUINT)0;
    r.scatter_all = (VMASK)0;
#endif
#ifdef WARPE_NADIR
    r.pend = (VREAL)0;
    r.pend_lo = (VREAL)0;
    r.pend_hi = (VREAL)0;
    r.pend_cell = (VMASK)-1;
#ifdef WARPE_RECORD
    r.nadir_total = (VREAL)0;
#endif
#ifdef WARPE_TEXTURE_LAYERS
    r.v_sin = (VREAL)0;
    r.v_mu = (VREAL)1;
    r.v_tau_per_m = (VREAL)0;
    r.v_path_per_m = (VREAL)0;
    r.v_tau_above = (VREAL)0;
    r.v_path_above = (VREAL)0;
    r.v_factor = (VREAL)0;
#endif
#endif
    return r;
}

#ifdef WARPE_TEXTURE_LAYERS
/* The lanes in m take the values of the layer they are in (walk.md §7.3): a select per layer,
 * done only when a ray changes layer or a lane takes a ray. */
WALK_STEP void load_layer(rays_t *r, VMASK m, const scene_t *sc)
{
    for (int i = 0; i < sc->n_layers; ++i) {
        const VMASK hit = m & (r->layer == (VMASK)i);
        if (!ANY(hit))
            continue;
        __global const REAL *row = sc->layer_real + N_LAYER_REAL * i;
        const ulong T = sc->layer_words[i];
        r->z_top = SEL(r->z_top, (VREAL)row[LAYER_Z_TOP], hit);
        r->z_bottom = SEL(r->z_bottom, (VREAL)row[LAYER_Z_BOTTOM], hit);
        r->E = SEL(r->E, (VREAL)row[LAYER_EXTINCTION], hit);
        r->g = SEL(r->g, (VREAL)row[LAYER_G], hit);
        r->time_scale = SEL(r->time_scale, (VREAL)row[LAYER_TIME_SCALE], hit);
        r->omega_lo = SEL(r->omega_lo, (VUINT)(uint)min(T, (ulong)0xFFFFFFFFu), MASK32(hit));
        r->scatter_all = SEL(r->scatter_all, (VMASK)(T > 0xFFFFFFFFul ? -1 : 0), hit);
#ifdef WARPE_NADIR
        __global const REAL *v = sc->view + N_VIEW * i;
        r->v_sin = SEL(r->v_sin, (VREAL)v[VIEW_SIN], hit);
        r->v_mu = SEL(r->v_mu, (VREAL)v[VIEW_MU], hit);
        r->v_tau_per_m = SEL(r->v_tau_per_m, (VREAL)v[VIEW_TAU_PER_M], hit);
        r->v_path_per_m = SEL(r->v_path_per_m, (VREAL)v[VIEW_PATH_PER_M], hit);
        r->v_tau_above = SEL(r->v_tau_above, (VREAL)v[VIEW_TAU_ABOVE], hit);
        r->v_path_above = SEL(r->v_path_above, (VREAL)v[VIEW_PATH_ABOVE], hit);
        r->v_factor = SEL(r->v_factor, (VREAL)v[VIEW_FACTOR], hit);
#endif
    }
}
#endif

/* The lanes whose ray ends in this event, their fate (FATE_*, tally.h) and, for an exit,
 * cos theta_e. */
typedef struct {
    VMASK done, fate;
    VREAL cos_exit;
} ends_t;

/* Where exits are tallied, and the rules that place them (walk.md §4). */
typedef struct {
    __global uint *time_in_fov, *time_any, *angular, *total, *early;
#ifdef WARPE_WEIGHTED
    __global ulong *w_time_in_fov, *w_time_any, *w_angular, *w_total, *w_early;
    __global ulong *w2_time_in_fov, *w2_total;
#endif
#ifdef WARPE_RECORD
    __global int *rec_int;       /* [photons of the walk][N_RECORD_INT] */
    __global REAL *rec_real;     /* [photons of the walk][N_RECORD_REAL] */
    uint record_base;            /* the low word of the walk's first photon: row 0 */
#endif
    __global const REAL *time_edges;
    int n_edges;
    REAL cos_fov[N_COMPONENTS];  /* cos of each component's FOV; -1: any angle */
    int rule_time_window;        /* component rule time_window (else history) */
    REAL t1;                     /* first back-and-forth time 2 h n / c, ns
                                  * (docs/physics.md §5.7) */
    REAL ns_per_m;               /* t = L n / c (docs/physics.md §5.7, paper eq. 4) */
#ifdef WARPE_NADIR
    /* the work-item's slice of the sums: [NADIR_BATCHES][N_NADIR_ROWS][nadir_cols][FIXED_WORDS]
     * and of the visits: [N_NADIR_ROWS][nadir_cols]; own: no other work-item writes them */
    __global ulong *nadir_sum;
    __global ulong *nadir_visits;
    int nadir_cols;              /* n_edges + 1: before the first edge, the bins, after */
    int nadir_own;
    /* a first guess of a time's bin: floor(b (ln t - a)) for log-spaced edges (bin_log; a is
     * ln of the argument bin_a, the first edge), else floor(b (t - a)); the edges then correct
     * it (walk.md §8) */
    int bin_log;
    REAL bin_a, bin_b;
#endif
} tallies_t;

/* A work-item's statistics, written to item_stats at the end. */
typedef struct {
    ulong fates[N_FATES];        /* rays per fate */
    ulong scattering_events;     /* volume scatterings of every ray */
    ulong mixed;                 /* exits with both a scattering and a floor reflection */
    ulong lost;                  /* weighted exits the exact sums cannot hold (walk.md §6) */
#ifdef WARPE_TEXTURE_LAYERS
    ulong layer[N_LAYER_STATS];  /* per layer and interface (LSTAT_*, walk.md §7.4) */
#endif
} stats_t;

#ifdef WARPE_TEXTURE_LAYERS
#ifdef WARPE_WEIGHTED
#error "the layered walk is analog only (walk.md §7)"
#endif
/* st->layer[base + idx] += 1 for every lane in m (walk.md §7.4) */
WALK_STEP void count_lanes(stats_t *st, int base, VMASK m, VMASK idx)
{
    IREAL a[WARPE_LANES], b[WARPE_LANES];
    VSTORE(m, a);
    VSTORE(idx, b);
    for (int j = 0; j < WARPE_LANES; ++j)
        if (a[j])
            st->layer[base + (int)b[j]] += 1;
}
#endif

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

#ifdef WARPE_TEXTURE_LAYERS
/* The work-item's per-layer statistics into its row of layer_stats (walk.md §7.4). */
WALK_STEP void write_layer_stats(__global ulong *row, const stats_t *st)
{
    for (int i = 0; i < N_LAYER_STATS; ++i)
        row[i] = st->layer[i];
}
#endif

/* The lanes in m end with fate f: they are tallied after this event. */
WALK_STEP void finish(ends_t *e, VMASK m, int f)
{
    e->done |= m;
    e->fate = SEL(e->fate, (VMASK)(f), m);
}

#ifdef WARPE_WEIGHTED
/* Russian roulette (walk.md §6) of the lanes in m whose weight fell below roulette_weight:
 * they live on iff u <= roulette_survival, their weight divided by it; the others end with
 * fate f. Returns the lanes that live on. */
WALK_STEP VMASK roulette(VMASK m, VREAL u, int f, const scene_t *sc, rays_t *r, ends_t *e)
{
    const VMASK low = m & (r->w < sc->roulette_weight);
    const VMASK dies = low & (u > sc->roulette_survival);
    finish(e, dies, f);
    r->w = SEL(r->w, r->w / sc->roulette_survival, low & !dies);
    return m & !dies;
}
#endif

/* The medium's toll on the colliding lanes in m (walk.md §3 step 3.4, §6): analog, absorbed
 * iff U1 > omega, decided exactly on the word, x1 >= omega_words (walk.md §2, philox.h
 * word_at_least); weighted, every collision scatters and the roulette plays on u1. Returns the
 * lanes that scatter. */
WALK_STEP VMASK medium_toll(VMASK m, VREAL u1, VUINT x1, const scene_t *sc, rays_t *r, ends_t *e)
{
#if defined(WARPE_TEXTURE_LAYERS)
    /* the lane's layer's threshold (walk.md §7.2) */
    finish(e, m & !r->scatter_all & CONVERT_VMASK(x1 >= r->omega_lo), FATE_ABSORBED_MEDIUM);
    return m & !e->done;
#elif !defined(WARPE_WEIGHTED)
    finish(e, m & word_at_least(x1, sc->omega_words), FATE_ABSORBED_MEDIUM);
    return m & !e->done;
#else
    return roulette(m, u1, FATE_ABSORBED_MEDIUM, sc, r, e);
#endif
}

/* The floor's toll on the lanes in m, with the event's word x and its uniform u (walk.md
 * §3.1, §6): analog, absorbed iff x >= albedo_words (U > A, decided exactly on the word);
 * weighted, the weight times A (A = 0 ends the ray) and the roulette on u. Returns the lanes
 * the floor reflects. */
WALK_STEP VMASK floor_toll(VMASK m, VREAL u, VUINT x, const scene_t *sc, rays_t *r, ends_t *e)
{
#ifndef WARPE_WEIGHTED
    finish(e, m & word_at_least(x, sc->albedo_words), FATE_ABSORBED_FLOOR);
    return m & !e->done;
#else
    if (sc->A == (REAL)0) {
        finish(e, m, FATE_ABSORBED_FLOOR);
        m = 0;
    }
    r->w = SEL(r->w, r->w * sc->A, m);
    return roulette(m, u, FATE_ABSORBED_FLOOR, sc, r, e);
#endif
}

/* A work-item's photons of the launch taken from the counter next_photon but not yet
 * walked: [next, end). A work-item takes photons WARPE_POOL at a time beyond those it wants
 * (walk.md §5), so that its lanes rarely wait on the launch-wide atomic counter, whose cache
 * line the cores pass to and fro; parked with the rays when the launch's budget is spent. */
typedef struct {
    uint next, end;
} pool_t;

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
#ifdef WARPE_WEIGHTED
    r->w = SEL(r->w, (VREAL)1, fresh);
#endif
#ifdef WARPE_TEXTURE_LAYERS
    r->layer = SEL(r->layer, (VMASK)0, fresh);
#endif
#ifdef WARPE_NADIR
    r->pend = SEL(r->pend, (VREAL)0, fresh);
    r->pend_cell = SEL(r->pend_cell, (VMASK)-1, fresh);
#ifdef WARPE_RECORD
    r->nadir_total = SEL(r->nadir_total, (VREAL)0, fresh);
#endif
#endif
}

/* The rays carried from one launch to the next (walk.md §5): a launch stops each work-item
 * after event_budget events and parks its unfinished rays, one row each (N_STATE_REAL REALs,
 * N_STATE_INT uints: columns STATE_* of warpe_cl/params.py); the next launch resumes them
 * before it takes new photons. A row holds the whole state of rays_t: the ray goes on from the
 * same event block, so its history does not depend on where launches cut it. */
typedef struct {
    uint resume_count;                   /* rows in resume_real / resume_int */
    __global uint *next_resume;          /* rows taken so far (starts at 0) */
    __global const REAL *resume_real;
    __global const uint *resume_int;
    __global uint *parked;               /* rows written so far (starts at 0) */
    __global REAL *park_real;
    __global uint *park_int;
} carry_t;

/* The lanes' state as per-lane arrays (the rows of carry_t are per ray). */
typedef struct {
    REAL z[WARPE_LANES], ux[WARPE_LANES], uy[WARPE_LANES], uz[WARPE_LANES];
    REAL Ls[WARPE_LANES], Lc[WARPE_LANES], w[WARPE_LANES];
    IREAL flights[WARPE_LANES], n_scat[WARPE_LANES], n_lamb[WARPE_LANES];
    IREAL n_bspec[WARPE_LANES], n_top[WARPE_LANES], phase[WARPE_LANES], event[WARPE_LANES];
    IREAL alive[WARPE_LANES], layer[WARPE_LANES];
    uint p_lo[WARPE_LANES], p_hi[WARPE_LANES];
    REAL pend[WARPE_LANES], pend_lo[WARPE_LANES], pend_hi[WARPE_LANES];
    REAL nadir_total[WARPE_LANES];
    IREAL pend_cell[WARPE_LANES];
} lane_rows_t;

WALK_STEP void rays_to_rows(const rays_t *r, lane_rows_t *l)
{
    VSTORE(r->z, l->z);
    VSTORE(r->ux, l->ux);
    VSTORE(r->uy, l->uy);
    VSTORE(r->uz, l->uz);
    VSTORE(r->Ls, l->Ls);
    VSTORE(r->Lc, l->Lc);
#ifdef WARPE_WEIGHTED
    VSTORE(r->w, l->w);
#endif
    VSTORE(r->flights, l->flights);
    VSTORE(r->n_scat, l->n_scat);
    VSTORE(r->n_lamb, l->n_lamb);
    VSTORE(r->n_bspec, l->n_bspec);
    VSTORE(r->n_top, l->n_top);
    VSTORE(r->phase, l->phase);
    VSTORE(r->event, l->event);
    VSTORE(r->alive, l->alive);
    VSTORE(r->p_lo, l->p_lo);
    VSTORE(r->p_hi, l->p_hi);
#ifdef WARPE_TEXTURE_LAYERS
    VSTORE(r->layer, l->layer);
#else
    for (int j = 0; j < WARPE_LANES; ++j)
        l->layer[j] = 0;
#endif
#ifdef WARPE_NADIR
    VSTORE(r->pend, l->pend);
    VSTORE(r->pend_lo, l->pend_lo);
    VSTORE(r->pend_hi, l->pend_hi);
    VSTORE(r->pend_cell, l->pend_cell);
#ifdef WARPE_RECORD
    VSTORE(r->nadir_total, l->nadir_total);
#else
    for (int j = 0; j < WARPE_LANES; ++j)
        l->nadir_total[j] = (REAL)0;
#endif
#else
    for (int j = 0; j < WARPE_LANES; ++j) {
        l->pend[j] = l->pend_lo[j] = l->pend_hi[j] = l->nadir_total[j] = (REAL)0;
        l->pend_cell[j] = -1;
    }
#endif
}

WALK_STEP void rows_to_rays(const lane_rows_t *l, rays_t *r)
{
    r->z = VLOAD(l->z);
    r->ux = VLOAD(l->ux);
    r->uy = VLOAD(l->uy);
    r->uz = VLOAD(l->uz);
    r->Ls = VLOAD(l->Ls);
    r->Lc = VLOAD(l->Lc);
#ifdef WARPE_WEIGHTED
    r->w = VLOAD(l->w);
#endif
    r->flights = VLOAD(l->flights);
    r->n_scat = VLOAD(l->n_scat);
    r->n_lamb = VLOAD(l->n_lamb);
    r->n_bspec = VLOAD(l->n_bspec);
    r->n_top = VLOAD(l->n_top);
    r->phase = VLOAD(l->phase);
    r->event = VLOAD(l->event);
    r->alive = VLOAD(l->alive);
    r->p_lo = VLOAD(l->p_lo);
    r->p_hi = VLOAD(l->p_hi);
#ifdef WARPE_TEXTURE_LAYERS
    r->layer = VLOAD(l->layer);
#endif
#ifdef WARPE_NADIR
    r->pend = VLOAD(l->pend);
    r->pend_lo = VLOAD(l->pend_lo);
    r->pend_hi = VLOAD(l->pend_hi);
    r->pend_cell = VLOAD(l->pend_cell);
#ifdef WARPE_RECORD
    r->nadir_total = VLOAD(l->nadir_total);
#endif
#endif
}

/* Lanes without a ray take the parked rays of the last launch first (walk.md §5); clears
 * *resuming once they are all taken. */
WALK_STEP void resume_lanes(rays_t *r, const carry_t *cy, int *resuming)
{
    lane_rows_t l;
    rays_to_rows(r, &l);
    uint wanted = 0;
    for (int j = 0; j < WARPE_LANES; ++j)
        wanted += l.alive[j] ? 0u : 1u;
    const uint first = atomic_add(cy->next_resume, wanted);
    if (first + wanted >= cy->resume_count)
        *resuming = 0;
    if (first >= cy->resume_count)
        return;
    const uint end = min(first + wanted, cy->resume_count);
    uint row = first;
    for (int j = 0; j < WARPE_LANES && row < end; ++j) {
        if (l.alive[j])
            continue;
        __global const REAL *rr = cy->resume_real + N_STATE_REAL * (size_t)row;
        __global const uint *ri = cy->resume_int + N_STATE_INT * (size_t)row;
        l.z[j] = rr[STATE_Z];
        l.ux[j] = rr[STATE_UX];
        l.uy[j] = rr[STATE_UY];
        l.uz[j] = rr[STATE_UZ];
        l.Ls[j] = rr[STATE_LS];
        l.Lc[j] = rr[STATE_LC];
        l.w[j] = rr[STATE_W];
        l.flights[j] = (IREAL)ri[STATE_FLIGHTS];
        l.n_scat[j] = (IREAL)ri[STATE_N_SCAT];
        l.n_lamb[j] = (IREAL)ri[STATE_N_LAMB];
        l.n_bspec[j] = (IREAL)ri[STATE_N_BSPEC];
        l.n_top[j] = (IREAL)ri[STATE_N_TOP];
        l.phase[j] = (IREAL)ri[STATE_PHASE];
        l.event[j] = (IREAL)ri[STATE_EVENT];
        l.p_lo[j] = ri[STATE_P_LO];
        l.p_hi[j] = ri[STATE_P_HI];
        l.layer[j] = (IREAL)ri[STATE_LAYER];
        l.pend[j] = rr[STATE_NADIR_PENDING];
        l.pend_lo[j] = rr[STATE_NADIR_LO];
        l.pend_hi[j] = rr[STATE_NADIR_HI];
        l.nadir_total[j] = rr[STATE_NADIR_SUM];
        l.pend_cell[j] = (IREAL)(int)ri[STATE_NADIR_CELL];
        l.alive[j] = (IREAL)-1;     /* "true" in both mask conventions (lanes.h) */
        row += 1;
    }
    rows_to_rays(&l, r);
}

/* The live lanes' rays, then the photons left in the work-item's pool as new rays, into rows
 * of the park buffer, for the next launch (walk.md §5). */
WALK_STEP void park_lanes(const rays_t *r, const pool_t *pool, const carry_t *cy, uint base_lo,
                       uint base_hi, IREAL phase_start)
{
    lane_rows_t l;
    rays_to_rows(r, &l);
    uint count = pool->end - pool->next;
    for (int j = 0; j < WARPE_LANES; ++j)
        count += l.alive[j] ? 1u : 0u;
    if (count == 0)
        return;
    uint row = atomic_add(cy->parked, count);
    for (int j = 0; j < WARPE_LANES; ++j) {
        if (!l.alive[j])
            continue;
        __global REAL *rr = cy->park_real + N_STATE_REAL * (size_t)row;
        __global uint *ri = cy->park_int + N_STATE_INT * (size_t)row;
        rr[STATE_Z] = l.z[j];
        rr[STATE_UX] = l.ux[j];
        rr[STATE_UY] = l.uy[j];
        rr[STATE_UZ] = l.uz[j];
        rr[STATE_LS] = l.Ls[j];
        rr[STATE_LC] = l.Lc[j];
#ifdef WARPE_WEIGHTED
        rr[STATE_W] = l.w[j];
#else
        rr[STATE_W] = (REAL)1;
#endif
        ri[STATE_FLIGHTS] = (uint)l.flights[j];
        ri[STATE_N_SCAT] = (uint)l.n_scat[j];
        ri[STATE_N_LAMB] = (uint)l.n_lamb[j];
        ri[STATE_N_BSPEC] = (uint)l.n_bspec[j];
        ri[STATE_N_TOP] = (uint)l.n_top[j];
        ri[STATE_PHASE] = (uint)l.phase[j];
        ri[STATE_EVENT] = (uint)l.event[j];
        ri[STATE_P_LO] = l.p_lo[j];
        ri[STATE_P_HI] = l.p_hi[j];
        ri[STATE_LAYER] = (uint)l.layer[j];
        rr[STATE_NADIR_PENDING] = l.pend[j];
        rr[STATE_NADIR_LO] = l.pend_lo[j];
        rr[STATE_NADIR_HI] = l.pend_hi[j];
        rr[STATE_NADIR_SUM] = l.nadir_total[j];
        ri[STATE_NADIR_CELL] = (uint)(int)l.pend_cell[j];
        row += 1;
    }
    for (uint q = pool->next; q < pool->end; ++q, ++row) {
        __global REAL *rr = cy->park_real + N_STATE_REAL * (size_t)row;
        __global uint *ri = cy->park_int + N_STATE_INT * (size_t)row;
        rr[STATE_Z] = (REAL)0;
        rr[STATE_UX] = (REAL)0;
        rr[STATE_UY] = (REAL)0;
        rr[STATE_UZ] = (REAL)1;
        rr[STATE_LS] = (REAL)0;
        rr[STATE_LC] = (REAL)0;
        rr[STATE_W] = (REAL)1;
        ri[STATE_FLIGHTS] = 0;
        ri[STATE_N_SCAT] = 0;
        ri[STATE_N_LAMB] = 0;
        ri[STATE_N_BSPEC] = 0;
        ri[STATE_N_TOP] = 0;
        ri[STATE_PHASE] = (uint)phase_start;
        ri[STATE_EVENT] = 0;
        ri[STATE_P_LO] = base_lo + q;          /* as refill_lanes numbers a photon */
        ri[STATE_P_HI] = base_lo + q < base_lo ? base_hi + 1u : base_hi;
        ri[STATE_LAYER] = 0;
        rr[STATE_NADIR_PENDING] = (REAL)0;
        rr[STATE_NADIR_LO] = (REAL)0;
        rr[STATE_NADIR_HI] = (REAL)0;
        rr[STATE_NADIR_SUM] = (REAL)0;
        ri[STATE_NADIR_CELL] = 0xFFFFFFFFu;     /* -1: no pending cell */
    }
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
#ifdef WARPE_TEXTURE_LAYERS
    const VREAL s = SEL((VREAL)INFINITY, optical_step(u0) / r->E, r->E > (REAL)0);
    /* the way to the layer's face ahead (walk.md §7.2) */
    const VREAL s_b = SEL((VREAL)INFINITY,
                          SEL(r->z_top - r->z, r->z_bottom - r->z, r->uz > (REAL)0) / r->uz,
                          (r->uz < (REAL)0) | (r->uz > (REAL)0));
    VMASK c = fl & (s < s_b);
    VMASK b = fl & !(s < s_b);
    /* the path at layer 0's speed: n_l / n_0 = 1 exactly in layer 0 */
    const VREAL len = SEL(s_b, s, c) * r->time_scale;
    r->z = SEL(r->z, SEL(SEL(r->z_top, r->z_bottom, r->uz > (REAL)0), r->z + s * r->uz, c), fl);
#else
    const VREAL s = SEL((VREAL)INFINITY, optical_step(u0) / sc->E,
                        (VMASK)(sc->E > (REAL)0 ? -1 : 0));
    /* the way to the boundary ahead: (h - z)/uz down, -z/uz up, none level (one division) */
    const VREAL s_b = SEL((VREAL)INFINITY, SEL(-r->z, sc->h - r->z, r->uz > (REAL)0) / r->uz,
                          (r->uz < (REAL)0) | (r->uz > (REAL)0));
    VMASK c = fl & (s < s_b);
    VMASK b = fl & !(s < s_b);
    const VREAL len = SEL(s_b, s, c);
    r->z = SEL(r->z, SEL(SEL((VREAL)0, (VREAL)sc->h, r->uz > (REAL)0), r->z + s * r->uz, c), fl);
#endif
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
#ifdef WARPE_WEIGHTED
    r->w = SEL(r->w, r->w * exp_neg(sc->mu_a * len), c | b);
#endif
    *coll = c;
    *bnd = b;
}

/* A floor in optical contact (walk.md §3.1, second rule) under the lanes in m: the floor's
 * toll on u1 (x1), then a Lambertian direction, mu = sqrt(u2), azimuth (cos psi, sin psi). */
WALK_STEP void contact_floor(VMASK m, VREAL u1, VUINT x1, VREAL u2, VREAL cos_psi,
                             VREAL sin_psi, const scene_t *sc, rays_t *r, ends_t *e)
{
    m = floor_toll(m, u1, x1, sc, r, e);
    r->n_lamb += ONE(m);
    VREAL vx, vy, vz;
    lambert_direction(sqrt(u2), cos_psi, sin_psi, &vx, &vy, &vz);
    r->ux = SEL(r->ux, vx, m);
    r->uy = SEL(r->uy, vy, m);
    r->uz = SEL(r->uz, vz, m);
}

#ifndef WARPE_TEXTURE_LAYERS
/* The lanes in bnd at a boundary, with the words u1 (x1), u2 and the azimuth (cos psi,
 * sin psi) = u3 of their block (walk.md §3.1-§3.2, docs/physics.md §5.5-§5.6). Slab: at the top
 * and, over a vacuum gap, at the bottom, total internal reflection or reflect iff
 * u1 <= R_int(mu) (walk.md §3.3); out at the top with cos theta_e by Snell, down into the gap
 * at the bottom. Granular: no interface, exit at cos theta_e = -uz. A floor in optical contact
 * (slab without the gap, granular): the floor's toll on u1 (x1), then a Lambertian direction,
 * mu = sqrt(u2). */
WALK_STEP void reach_boundary(VMASK bnd, VREAL u1, VUINT x1, VREAL u2, VREAL cos_psi,
                           VREAL sin_psi, const scene_t *sc, rays_t *r, ends_t *e)
{
    const VMASK down = r->uz > (REAL)0;
    VMASK bottom = bnd & down;
    const VMASK top = bnd & !down;
#ifdef WARPE_TEXTURE_SLAB
    const REAL n = sc->n;
    const VREAL mu = abs_lanes(r->uz);
    const VMASK reflect = (n * sqrt(max0((REAL)1 - mu * mu)) >= (REAL)1)
                        | (u1 <= fresnel_internal(mu, (VREAL)n));
    if (sc->bottom_fresnel) {
        const VMASK back = bottom & reflect;
        r->uz = SEL(r->uz, -r->uz, back);
        r->n_bspec += ONE(back);
        r->phase = SEL(r->phase, (VMASK)PHASE_GAP, bottom & !reflect);   /* into the gap */
        bottom = 0;
    }
    const VMASK up = top & reflect;
    r->uz = SEL(r->uz, -r->uz, up);
    r->n_top += ONE(up);
    const VMASK out = top & !reflect;
    /* Snell: cos theta_e = sqrt(1 - n^2 (1 - mu^2)) (docs/physics.md §3.5) */
    e->cos_exit = SEL(e->cos_exit, sqrt(max0(((REAL)1 - n * n) + n * n * mu * mu)),
                      out);
    finish(e, out, FATE_ESCAPED);
#else
    e->cos_exit = SEL(e->cos_exit, -r->uz, top);
    finish(e, top, FATE_ESCAPED);
#endif
    if (ANY(bottom))
        contact_floor(bottom, u1, x1, u2, cos_psi, sin_psi, sc, r, e);
}
#else
/* The lanes in bnd at interface j of the stack, j = l + 1 going down and l going up, with the
 * words u1 (x1), u2 and the azimuth (cos psi, sin psi) = u3 of their block (walk.md §7.1-§7.2,
 * docs/physics-layers.md). A Fresnel interface: total internal reflection, or reflect iff
 * u1 <= R(mu) (R_int towards vacuum, else R_ext with the relative index); a transmitted ray
 * refracts. A transparent one lets it through unchanged. At j = 0 the ray exits; at j = N it
 * enters the gap (Fresnel) or meets a floor in contact (transparent). Counts the
 * transmissions (walk.md §7.4). */
WALK_STEP void cross_interface(VMASK bnd, VREAL u1, VUINT x1, VREAL u2, VREAL cos_psi,
                               VREAL sin_psi, const scene_t *sc, rays_t *r, ends_t *e,
                               stats_t *st)
{
    const int N = sc->n_layers;
    const VMASK down = r->uz > (REAL)0;
    const VMASK j = SEL(r->layer, r->layer + (VMASK)1, down);
    /* the faces of each lane's interface, seen from its side (walk.md §7.1) */
    VREAL near = (VREAL)1, far_n = (VREAL)1, far_k = (VREAL)0;
    VMASK fres = (VMASK)0;
    for (int i = 0; i <= N; ++i) {
        const VMASK at = bnd & (j == (VMASK)i);
        if (!ANY(at))
            continue;
        __global const REAL *row = sc->iface_real + N_IFACE_REAL * i;
        const VMASK d = at & down, u = at & !down;
        near = SEL(SEL(near, (VREAL)row[IFACE_DOWN_NEAR], d), (VREAL)row[IFACE_UP_NEAR], u);
        far_n = SEL(SEL(far_n, (VREAL)row[IFACE_DOWN_FAR_N], d), (VREAL)row[IFACE_UP_FAR_N], u);
        far_k = SEL(SEL(far_k, (VREAL)row[IFACE_DOWN_FAR_K], d), (VREAL)row[IFACE_UP_FAR_K], u);
        fres = SEL(fres, (VMASK)(sc->iface_kind[i] ? -1 : 0), at);
    }
    const VMASK top = bnd & (j == (VMASK)0);
    const VMASK bottom = bnd & (j == (VMASK)N);
    const VMASK inner = bnd & !top & !bottom;
    const VREAL mu = abs_lanes(r->uz);
    VMASK reflect = (VMASK)0;
    VREAL cos_t = mu;
    if (ANY(fres)) {
        /* R_int(mu; near) towards vacuum, else R_ext(mu; far/near) (walk.md §7.1) */
        const VMASK to_vacuum = (far_n == (REAL)1) & (far_k == (REAL)0);
        VREAL R = fresnel_internal(mu, near);
        if (!ALL(to_vacuum | !fres))
            R = SEL(fresnel_external(mu, far_n / near, far_k / near), R, to_vacuum);
        reflect = fres & ((near * sqrt(max0((REAL)1 - mu * mu)) >= far_n)
                          | (u1 <= R));
        /* the refracted |uz| = sqrt((1 - r^2) + r^2 mu^2), r = near/far: Snell */
        const VREAL ratio = near / far_n;
        cos_t = SEL(mu, sqrt(max0(((REAL)1 - ratio * ratio) + ratio * ratio * mu * mu)), fres);
        const VMASK bend = inner & fres & !reflect;
        r->ux = SEL(r->ux, r->ux * ratio, bend);
        r->uy = SEL(r->uy, r->uy * ratio, bend);
        r->uz = SEL(r->uz, SEL(-cos_t, cos_t, down), bend);
    }
    r->uz = SEL(r->uz, -r->uz, reflect);
    r->n_top += ONE(reflect & top);
    r->n_bspec += ONE(reflect & !top);
    const VMASK through = bnd & !reflect;
    const VMASK floor = bottom & through & !fres;           /* a floor in contact */
    const VMASK moved = through & !floor;
    count_lanes(st, LSTAT_DOWN, moved & down, j);
    count_lanes(st, LSTAT_UP, moved & !down, j);
    /* out at the top: cos theta_e = -uz through a transparent top, Snell through a slab's */
    const VMASK out = top & through;
    e->cos_exit = SEL(e->cos_exit, cos_t, out);
    finish(e, out, FATE_ESCAPED);
    /* into the next layer */
    const VMASK step = inner & through;
    r->layer = SEL(r->layer, SEL(r->layer - (VMASK)1, r->layer + (VMASK)1, down), step);
    load_layer(r, step, sc);
    /* into the gap, whose events follow (walk.md §7.2) */
    const VMASK gap = bottom & through & fres;
    r->phase = SEL(r->phase, (VMASK)PHASE_GAP, gap);
    r->layer = SEL(r->layer, (VMASK)N, gap);
    if (ANY(floor))
        contact_floor(floor, u1, x1, u2, cos_psi, sin_psi, sc, r, e);
}
#endif

#ifdef WARPE_INTERFACES
/* GAP, one reflection of the lanes in gap by the floor below the slab's lower face (walk.md
 * §3.1, docs/physics.md §5.5): the floor's toll on u0 (x0); a Lambertian direction in vacuum,
 * mu_v = sqrt(u1), azimuth 2 pi u2; back to the floor iff u3 <= R_ext(mu_v; n, k), else
 * refracted into the slab (Snell, real part: sin theta_s = sin theta_v / n) and flights
 * resume. The gap adds no path length. In a stack (walk.md §7.2) the gap medium has the real
 * index n_g (a substrate's; 1 for vacuum) and the last layer's face (n2, k2) is above it:
 * total internal reflection if n_g sin theta_g >= n2, R_int(mu_g; n_g) towards a granular
 * layer's pores, R_ext(mu_g; n2/n_g, k2/n_g) otherwise, and sin theta = sin theta_g n_g / n2. */
WALK_STEP void gap_event(VMASK gap, VREAL u0, VUINT x0, VREAL u1, VREAL u2, VREAL u3,
                      const scene_t *sc, rays_t *r, ends_t *e, stats_t *st)
{
    gap = floor_toll(gap, u0, x0, sc, r, e);
    r->n_lamb += ONE(gap);
    const VREAL mu_v = sqrt(u1);
    VREAL c2, s2;
    azimuth(u2, &s2, &c2);
#ifdef WARPE_TEXTURE_LAYERS
    const REAL n_g = sc->gap_near, n2 = sc->gap_far_n, k2 = sc->gap_far_k;
    const VREAL sin_g = sqrt(max0((REAL)1 - mu_v * mu_v));
    const VREAL R = (n2 == (REAL)1 && k2 == (REAL)0)
                  ? fresnel_internal(mu_v, (VREAL)n_g)
                  : fresnel_external(mu_v, (VREAL)(n2 / n_g), (VREAL)(k2 / n_g));
    const VMASK enter = gap & !(n_g * sin_g >= n2) & (u3 > R);
    const VREAL sin_s = (sin_g * n_g) / n2;
    r->layer = SEL(r->layer, (VMASK)(sc->n_layers - 1), enter);
    load_layer(r, enter, sc);
    count_lanes(st, LSTAT_UP, enter, (VMASK)sc->n_layers);
#else
    const VMASK enter = gap & (u3 > fresnel_external(mu_v, (VREAL)sc->n, (VREAL)sc->k));
    const VREAL sin_s = sqrt(max0((REAL)1 - mu_v * mu_v)) / sc->n;
#endif
    r->ux = SEL(r->ux, sin_s * c2, enter);
    r->uy = SEL(r->uy, sin_s * s2, enter);
    r->uz = SEL(r->uz, -sqrt((REAL)1 - sin_s * sin_s), enter);
    r->phase = SEL(r->phase, (VMASK)PHASE_FLIGHT, enter);
}
#endif

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
WALK_STEP void nadir_add(VMASK m, VREAL s, VREAL v, const scene_t *sc, VREAL tv, VMASK row,
                         VMASK first, rays_t *r, const tallies_t *tally)
{
    const int cols = tally->nadir_cols;
    const VMASK cell0 = row * (VMASK)cols;
    VMASK same = (r->pend_cell >= cell0) & (r->pend_cell < cell0 + (VMASK)cols)
               & (tv >= r->pend_lo) & (tv < r->pend_hi);
#ifndef WARPE_WEIGHTED
    const VREAL thr = SEL((VREAL)sc->s_min, (VREAL)sc->s_new, !same & !first);
    s = SEL(s, SEL((VREAL)0, thr, v * thr < s), s < thr);
#endif
    m &= s > (REAL)0;            /* nothing to add where exp(-tau) underflowed, or lost the
                                  * roulette */
    same &= m;
    r->pend = SEL(r->pend, r->pend + s, same);
#ifdef WARPE_RECORD
    r->nadir_total = SEL(r->nadir_total, r->nadir_total + s, m);
#endif
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
#ifdef WARPE_TEXTURE_LAYERS
        const VMASK in = m & (r->layer == (VMASK)(int)row[MIRROR_LAYER]);
#else
        const VMASK in = m;                  /* one layer: every up and down row is its own */
#endif
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
#ifdef WARPE_TEXTURE_LAYERS
    const VREAL g = r->g, sin_v = r->v_sin, mu_v = r->v_mu, depth = r->z - r->z_top;
    const VREAL tau = r->v_tau_above + r->v_tau_per_m * depth;
    const VREAL path = r->v_path_above + r->v_path_per_m * depth;
    const VREAL k = r->v_factor * ((REAL)1 - g * g) * (REAL)(0.25 / WARPE_PI);
#else
    const REAL g = sc->g, sin_v = sc->v_sin, mu_v = sc->v_mu;
    const VREAL tau = sc->v_tau_per_m * r->z;
    const VREAL path = sc->v_path_per_m * r->z;
    const REAL k = sc->v_factor * sc->phase_k;
#endif
#ifdef WARPE_WEIGHTED
    const VREAL v = (VREAL)0;    /* no roulette */
#elif defined(WARPE_TEXTURE_LAYERS)
    const VREAL words = SEL(CONVERT_VREAL(r->omega_lo), (VREAL)0x1p32, r->scatter_all);
    const VREAL v = (CONVERT_VREAL(x1) + (REAL)0.5) / words;
#else
    const VREAL v = (CONVERT_VREAL(x1) + (REAL)0.5) * sc->inv_omega_words;
#ifndef WARPE_NO_SCORE_SKIP
    /* every lane's score lost to the roulette for certain (walk.md §8.3): v s_min above the
     * bound s_cap exp_neg_bound(tau) of the score s, so v s_min > s: nothing to add, and
     * nothing to compute (the events deep in a thick medium: most of them) */
    if (!ANY(m & !(v * sc->s_min > sc->s_cap * exp_neg_bound(tau))))
        return;
#endif
#endif
    const VREAL c = ux * sin_v - uz * mu_v;
    const VREAL x = ((REAL)1 + g * g) - (REAL)2 * g * c;
    VREAL s = k * pow_m3_2(x) * exp_neg_score(tau);
#ifdef WARPE_WEIGHTED
    s *= r->w;
#endif
    const VMASK first = (r->n_scat == (VMASK)1) & (r->n_lamb == (VMASK)0);
    const VREAL tv = (r->Ls + path) * tally->ns_per_m;
    nadir_add(m, s, v, sc, tv, nadir_row(r->n_lamb > (VMASK)0, tv, tally),
              first, r, tally);
    if (sc->n_mirror > 0) {
        /* the mirror paths of a slab over a gap or of the lanes' layers of a stack
         * (mirror_table, walk.md §8.5); down: along the mirror image (sin_l, 0, +mu_l) to the
         * bottom of the layer, then the row */
#ifdef WARPE_TEXTURE_LAYERS
        const VREAL below = r->z_bottom - r->z;
        const VREAL tau_down = r->v_tau_per_m * below, path_down = r->v_path_per_m * below;
#else
        const VREAL below = (REAL)sc->h - r->z;
        const VREAL tau_down = sc->v_tau_per_m * below, path_down = sc->v_path_per_m * below;
#endif
        const VREAL xd = ((REAL)1 + g * g) - (REAL)2 * g * (ux * sin_v + uz * mu_v);
        VREAL sd = k * pow_m3_2(xd) * exp_neg_score(tau_down);
#ifdef WARPE_WEIGHTED
        sd *= r->w;
#endif
        mirror_scores(m, s, path, sd, path_down, v, first, sc, r, tally);
    }
}

/* A reflection of the lanes in m by a floor in contact with the last layer, at its bottom
 * (walk.md §8): q = mu_l / pi, Lambert's law into the view direction inside the layer. Called
 * after the reflection is counted (n_lamb >= 1). */
WALK_STEP void nadir_contact(VMASK m, VUINT x1, const scene_t *sc, rays_t *r,
                             const tallies_t *tally)
{
#ifdef WARPE_TEXTURE_LAYERS
    const VREAL depth = r->z - r->z_top;
    const VREAL tau = r->v_tau_above + r->v_tau_per_m * depth;
    const VREAL path = r->v_path_above + r->v_path_per_m * depth;
    const VREAL k = r->v_factor * r->v_mu * (REAL)(1.0 / WARPE_PI);
#else
    const VREAL tau = sc->v_tau_per_m * r->z;
    const VREAL path = sc->v_path_per_m * r->z;
    const REAL k = sc->v_factor * sc->v_mu * (REAL)(1.0 / WARPE_PI);
#endif
    VREAL s = k * exp_neg_score(tau);
#ifdef WARPE_WEIGHTED
    s *= r->w;
    const VREAL v = (VREAL)0;    /* no roulette */
#else
    const VREAL v = (CONVERT_VREAL(x1) + (REAL)0.5) * sc->inv_albedo_words;
#endif
    const VREAL tv = (r->Ls + path) * tally->ns_per_m;
    const VMASK first = (r->n_scat == (VMASK)0) & (r->n_lamb == (VMASK)1);
    nadir_add(m, s, v, sc, tv, nadir_row(r->n_lamb > (VMASK)0, tv, tally),
              first, r, tally);
    /* a stack: the up rows of the last layer, whose bottom the floor is (walk.md §8.5); no
     * down rows (nothing but the floor lies below; a single layer on a floor has no rows) */
    if (sc->n_mirror > 0)
        mirror_scores(m, s, path, (VREAL)0, (VREAL)0, v, first, sc, r, tally);
}

#ifdef WARPE_INTERFACES
/* A reflection of the lanes in m by the floor below a gap (walk.md §8): q = mu_g / pi in the
 * gap medium, and the gap row's path through every layer (its own interface included). */
WALK_STEP void nadir_gap(VMASK m, VUINT x0, const scene_t *sc, rays_t *r,
                         const tallies_t *tally)
{
    /* exp_neg, not the driver's exp: the same bits on every driver */
    VREAL s = (sc->vg_factor * sc->vg_mu * (REAL)(1.0 / WARPE_PI)) * exp_neg((VREAL)sc->vg_tau);
#ifdef WARPE_WEIGHTED
    s *= r->w;
    const VREAL v = (VREAL)0;    /* no roulette */
#else
    const VREAL v = (CONVERT_VREAL(x0) + (REAL)0.5) * sc->inv_albedo_words;
#endif
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
#endif
#endif

#ifdef WARPE_WEIGHTED
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
#endif

#ifdef WARPE_RECORD
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
#endif

/* Tally the lanes whose ray ended in this event (walk.md §4): its fate and scatterings in the
 * work-item's statistics; an exit (specular or escaped) in its component's total, angular,
 * time_any, and time_in_fov within the component's FOV, or in early before the first edge
 * (never in a bin); weighted, its weight (specular: 1) in the exact sums (walk.md §6).
 * WARPE_NADIR: the ray's pending nadir score into the sums (walk.md §8).
 * WARPE_RECORD: every ended ray's record. */
WALK_STEP void tally_exits(const rays_t *r, const ends_t *e, const tallies_t *tally, stats_t *st)
{
#ifdef WARPE_TEXTURE_LAYERS
    IREAL ly[WARPE_LANES];       /* the layer each ray ends in (walk.md §7.2, §7.4) */
    VSTORE(r->layer, ly);
#endif
    const int n_time = tally->n_edges - 1;
    IREAL d[WARPE_LANES], f[WARPE_LANES], ns[WARPE_LANES], nl[WARPE_LANES];
    REAL t[WARPE_LANES], ce[WARPE_LANES];
    VSTORE(e->done, d);
    VSTORE(e->fate, f);
    VSTORE(r->n_scat, ns);
    VSTORE(r->n_lamb, nl);
    VSTORE(r->Ls * tally->ns_per_m, t);
    VSTORE(e->cos_exit, ce);
#ifdef WARPE_WEIGHTED
    REAL wt[WARPE_LANES];
    VSTORE(r->w, wt);
#endif
#if defined(WARPE_RECORD) || defined(WARPE_NADIR)
    uint p[WARPE_LANES];
    VSTORE(r->p_lo, p);
#endif
#ifdef WARPE_RECORD
    IREAL nb[WARPE_LANES], nt[WARPE_LANES];
    VSTORE(r->n_bspec, nb);
    VSTORE(r->n_top, nt);
#endif
#ifdef WARPE_NADIR
    REAL pv[WARPE_LANES];
#ifdef WARPE_RECORD
    REAL nadir[WARPE_LANES];
#endif
    IREAL pc[WARPE_LANES];
    VSTORE(r->pend, pv);
    VSTORE(r->pend_cell, pc);
#ifdef WARPE_RECORD
    VSTORE(r->nadir_total, nadir);
#endif
#endif
    for (int j = 0; j < WARPE_LANES; ++j) {
        if (!d[j])
            continue;
        const int fj = (int)f[j];
        const uint n_s = (uint)ns[j], n_l = (uint)nl[j];
        REAL tj = t[j];
        st->fates[fj] += 1;
        st->scattering_events += n_s;
#ifdef WARPE_NADIR
        if (pc[j] >= 0)
            nadir_flush(tally, p[j], (int)pc[j], pv[j]);
#endif
#if defined(WARPE_NADIR) && defined(WARPE_RECORD)
        const REAL nadir_j = nadir[j];
#else
        const REAL nadir_j = (REAL)0;
#endif
#ifdef WARPE_TEXTURE_LAYERS
        const int layer = (int)ly[j];
        if (fj == FATE_ABSORBED_MEDIUM)
            st->layer[LSTAT_ABSORBED + layer] += 1;
        else if (fj == FATE_TERMINATED)
            st->layer[LSTAT_TERMINATED + layer] += 1;
#else
        const int layer = 0;
#endif
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
#ifdef WARPE_WEIGHTED
            const REAL wj = fj == FATE_SPECULAR ? (REAL)1 : wt[j];
            /* a weight the exact sums cannot hold (NaN, < 0, or w >= MAX_WEIGHT) is counted,
             * and the host refuses the result (walk.md §6) */
            st->lost += weight_lost(wj) ? 1 : 0;
            add_weight(tally, component, tb, eb, in_fov, wj);
#endif
        }
#ifdef WARPE_RECORD
#ifdef WARPE_WEIGHTED
        const REAL w_end = fj == FATE_SPECULAR ? (REAL)1 : wt[j];
#else
        const REAL w_end = (REAL)1;
#endif
        write_record(tally, (size_t)(p[j] - tally->record_base), fj, component, n_s, n_l, (int)nb[j], (int)nt[j], tb,
                     eb, tj, ce[j], w_end, layer, nadir_j);
#endif
    }
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
#if defined(WARPE_NADIR) && !defined(WARPE_TEXTURE_LAYERS)
    const REAL phase_k = ((REAL)1 - g * g) * (REAL)(0.25 / WARPE_PI);   /* HG's (1 - g^2)/4pi */
#endif
    const scene_t sc = {.h = h, .E = E, .g = g, .n = n, .k = k, .L_max = L_max,
                        .max_flights = max_flights, .bottom_fresnel = bottom_fresnel,
                        .omega_words = omega_words, .albedo_words = albedo_words, .A = A,
                        .mu_a = mu_a, .roulette_weight = roulette_weight,
                        .roulette_survival = roulette_survival,
#ifdef WARPE_TEXTURE_LAYERS
                        .n_layers = n_layers, .layer_real = layer_real,
                        .layer_words = layer_words, .iface_real = iface_real,
                        .iface_kind = iface_kind,
                        /* from the gap up into the last layer (walk.md §7.2 gap events) */
                        .gap_near = iface_real[N_IFACE_REAL * n_layers + IFACE_UP_NEAR],
                        .gap_far_n = iface_real[N_IFACE_REAL * n_layers + IFACE_UP_FAR_N],
                        .gap_far_k = iface_real[N_IFACE_REAL * n_layers + IFACE_UP_FAR_K],
#endif
#ifdef WARPE_NADIR
#ifdef WARPE_TEXTURE_LAYERS
                        .view = view,
#define GAP_ROW (N_VIEW * n_layers)
#else
                        .v_sin = view[VIEW_SIN], .v_mu = view[VIEW_MU],
                        .v_tau_per_m = view[VIEW_TAU_PER_M],
                        .v_path_per_m = view[VIEW_PATH_PER_M], .v_factor = view[VIEW_FACTOR],
                        .phase_k = phase_k,
#define GAP_ROW N_VIEW
#endif
                        .mirror = mirror, .n_mirror = n_mirror,
                        .vg_mu = view[GAP_ROW + VIEW_MU], .vg_tau = view[GAP_ROW + VIEW_TAU_ABOVE],
                        .vg_path = view[GAP_ROW + VIEW_PATH_ABOVE],
                        .vg_factor = view[GAP_ROW + VIEW_FACTOR],
                        .s_min = nadir_min, .s_new = nadir_min_new,
                        .inv_omega_words = (REAL)(1.0 / (double)omega_words),
                        .inv_albedo_words = (REAL)(1.0 / (double)albedo_words),
#ifndef WARPE_TEXTURE_LAYERS
                        .s_cap = score_cap(view[VIEW_FACTOR] * phase_k, g, nadir_min,
                                           n_mirror),
#endif
#undef GAP_ROW
#endif
                        };
    const tallies_t tally = {
        .time_in_fov = time_in_fov, .time_any = time_any, .angular = angular, .total = total,
        .early = early,
#ifdef WARPE_WEIGHTED
        .w_time_in_fov = w_time_in_fov, .w_time_any = w_time_any, .w_angular = w_angular,
        .w_total = w_total, .w_early = w_early, .w2_time_in_fov = w2_time_in_fov,
        .w2_total = w2_total,
#endif
#ifdef WARPE_RECORD
        .rec_int = rec_int, .rec_real = rec_real, .record_base = record_base,
#endif
        .time_edges = time_edges, .n_edges = n_edges,
        .cos_fov = {cos_fov_specular, cos_fov_bf_direct, cos_fov_bf_diffuse, cos_fov_scattering},
        .rule_time_window = rule_time_window, .t1 = t1,
        .ns_per_m = n / (REAL)WARPE_C_M_PER_NS,     /* paper eq. 4: t = L n_eff / c */
#ifdef WARPE_NADIR
        .nadir_sum = nadir_sum + (size_t)(get_global_id(0) % nadir_slices)
                     * (NADIR_BATCHES * N_NADIR_ROWS * FIXED_WORDS) * (size_t)(n_edges + 1),
        .nadir_visits = nadir_visits + (size_t)(get_global_id(0) % nadir_slices)
                        * N_NADIR_ROWS * (size_t)(n_edges + 1),
        .nadir_cols = n_edges + 1, .nadir_own = nadir_slices >= get_global_size(0),
        .bin_log = bin_log, .bin_a = bin_log ? rough_log(bin_a) : bin_a, .bin_b = bin_b,
#endif
        };
    const uint base_lo = (uint)first_photon, base_hi = (uint)(first_photon >> 32);
    /* the 64-bit scenario key: its low word keys Philox, its high word is counter word 3 */
    const uint key_lo = (uint)scenario, key_hi = (uint)(scenario >> 32);
#if defined(WARPE_TEXTURE_SLAB)
    /* the specular reflectance at normal incidence (docs/physics.md §5.2) */
    const VREAL R0 = fresnel_external((VREAL)1, (VREAL)n, (VREAL)k);
    const IREAL phase_start = PHASE_ENTRY;
#elif defined(WARPE_TEXTURE_LAYERS)
    /* an entry event iff the top of the stack is a Fresnel interface (walk.md §7.2) */
    const VREAL R0 = fresnel_external((VREAL)1, (VREAL)n, (VREAL)k);
    const IREAL phase_start = iface_kind[0] ? PHASE_ENTRY : PHASE_FLIGHT;
#else
    const IREAL phase_start = PHASE_FLIGHT;           /* granular: no entry event */
#endif
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
#ifdef WARPE_TEXTURE_LAYERS
            const VMASK had = r.alive;
#endif
            if (!exhausted) {
                if (resuming)
                    resume_lanes(&r, &carry, &resuming);
                if (!ALL(r.alive))
                    refill_lanes(&r, &pool, &exhausted, next_photon, n_photons, base_lo, base_hi,
                                 phase_start);
            }
#ifdef WARPE_TEXTURE_LAYERS
            load_layer(&r, r.alive & !had, &sc);    /* new and resumed rays (walk.md §7.3) */
#endif
            all_alive = ALL(r.alive);
            if (!all_alive && !ANY(r.alive))
                break;
        }
        events += 1;

        /* one event of every live lane, from block `event` of its stream (walk.md §2) */
        VUINT x0, x1, x2, x3;
        philox_lanes(CONVERT_VUINT(r.event), r.p_lo, r.p_hi, key_hi, seed, key_lo,
                     &x0, &x1, &x2, &x3);
        const VREAL u0 = uniform_lanes(x0), u1 = uniform_lanes(x1);
        const VREAL u2 = uniform_lanes(x2), u3 = uniform_lanes(x3);
#ifdef WARPE_TEXTURE_LAYERS
        const VMASK first = r.alive & (r.event == (VMASK)0);   /* entering the stack */
#endif
        r.event += (VMASK)1;
        ends_t e;
        e.done = (VMASK)0;
        e.fate = (VMASK)0;
        e.cos_exit = (VREAL)1;
        const VMASK in_flight = r.alive & (r.phase == (VMASK)PHASE_FLIGHT);

#ifdef WARPE_INTERFACES
        /* ENTRY (walk.md §3 step 2, docs/physics.md §5.2): specular iff u0 <= R0, recorded at
         * t = 0, theta_e = 0; else the ray enters, and flies from its next event */
        {
            const VMASK entry = r.alive & (r.phase == (VMASK)PHASE_ENTRY);
            finish(&e, entry & (u0 <= R0), FATE_SPECULAR);
            r.phase = SEL(r.phase, (VMASK)PHASE_FLIGHT, entry);
        }
        const VMASK in_gap = r.alive & (r.phase == (VMASK)PHASE_GAP);
#endif
#ifdef WARPE_TEXTURE_LAYERS
        if (ANY(first))     /* down[0]: the rays that enter the stack (walk.md §7.4) */
            count_lanes(&st, LSTAT_DOWN, first & !e.done, (VMASK)0);
        const VREAL g_lanes = r.g;
#else
        const VREAL g_lanes = (VREAL)sc.g;
#endif

        VMASK coll, bnd;
        free_flight(in_flight, u0, &sc, &r, &e, &coll, &bnd);
#ifdef WARPE_NADIR
        const VMASK lamb_before = r.n_lamb;   /* a floor reflection in this event adds one */
#endif
        /* the azimuth of a scattering or of a floor reflection: psi = 2 pi u3 */
        VREAL cos_psi, sin_psi;
        azimuth(u3, &sin_psi, &cos_psi);

        /* collision (walk.md §3 step 3.4, docs/physics.md §5.4): the medium's toll, then the HG
         * deflection (u2) and the azimuth (u3) */
        coll = medium_toll(coll, u1, x1, &sc, &r, &e);
        r.n_scat += ONE(coll);
#ifdef WARPE_NADIR
        const VREAL ux_before = r.ux, uz_before = r.uz;   /* nadir_scatter's, below */
#endif
        {   /* some lane collides in almost every event: no test */
            VREAL vx = r.ux, vy = r.uy, vz = r.uz;
            rotate_direction(&vx, &vy, &vz, hg_cos_theta(g_lanes, u2), cos_psi, sin_psi);
            r.ux = SEL(r.ux, vx, coll);
            r.uy = SEL(r.uy, vy, coll);
            r.uz = SEL(r.uz, vz, coll);
        }

#ifdef WARPE_TEXTURE_LAYERS
        if (ANY(bnd))
            cross_interface(bnd, u1, x1, u2, cos_psi, sin_psi, &sc, &r, &e, &st);
#else
        if (ANY(bnd))
            reach_boundary(bnd, u1, x1, u2, cos_psi, sin_psi, &sc, &r, &e);
#endif
#ifdef WARPE_INTERFACES
        if (ANY(in_gap))
            gap_event(in_gap, u0, x0, u1, u2, u3, &sc, &r, &e, &st);
#endif
#ifdef WARPE_NADIR
        {   /* the lanes a floor reflected in this event: in the gap, or a floor in contact */
            const VMASK lamb = r.n_lamb != lamb_before;
            if (ANY(lamb)) {
#ifdef WARPE_INTERFACES
                if (ANY(lamb & in_gap))
                    nadir_gap(lamb & in_gap, x0, &sc, &r, &tally);
                if (ANY(lamb & !in_gap))
                    nadir_contact(lamb & !in_gap, x1, &sc, &r, &tally);
#else
                nadir_contact(lamb, x1, &sc, &r, &tally);
#endif
            }
        }
        /* the scatterings of this event, with the direction before them (walk.md §8): no
         * lane both scatters and reflects or ends in one event, so the order of the two
         * leaves each ray's scores as they were */
        nadir_scatter(coll, x1, ux_before, uz_before, &sc, &r, &tally);
#endif

        if (ANY(e.done)) {
            tally_exits(&r, &e, &tally, &st);
            r.alive &= !e.done;
#ifdef WARPE_NADIR
            r.pend_cell = SEL(r.pend_cell, (VMASK)-1, e.done);   /* flushed by tally_exits */
#endif
            all_alive = 0;
        }
    }

    write_stats(item_stats + N_ITEM_STATS * get_global_id(0), &st);
#ifdef WARPE_TEXTURE_LAYERS
    write_layer_stats(layer_stats + N_LAYER_STATS * get_global_id(0), &st);
#endif
}

#ifdef WARPE_NADIR
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
#endif
