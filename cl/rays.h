/* rays.h: the state of the walk -- the scenario (scene_t), the rays of a work-item's lanes
 * (rays_t), the ends of an event (ends_t), where exits go (tallies_t), a work-item's statistics
 * (stats_t) and its photon pool (pool_t) -- and the tolls that end rays: the medium's
 * absorption, the floor's, the weighted walk's roulette.
 *
 * The first of the walk's own files (warpe_cl/engine.py WALK_FILES): rays.h, layers.h,
 * nadir.h, carry.h, exits.h, walk.cl, each appended to the one before; docs/walk.md §5.1 says
 * which file holds what. The host module that pairs with it is warpe_cl/engine.py (the kernel's
 * arguments, WALK_ARGS, which fill scene_t and tallies_t). The rules are docs/walk.md (cited
 * "walk.md §N"); the physics behind them is docs/physics.md §5-§6.
 *
 * Structure switches (-D): WARPE_TEXTURE_SLAB, WARPE_TEXTURE_GRANULAR or WARPE_TEXTURE_LAYERS
 * (a stack, walk.md §7: exactly one), WARPE_DOUBLE (precision), WARPE_LANES (photons per
 * work-item), WARPE_POOL (photons a work-item takes ahead, pool_t), WARPE_WEIGHTED (survival
 * weighting, walk.md §6), WARPE_NADIR (the next-event estimate toward the receiver, walk.md §8),
 * WARPE_RECORD (one record per photon, for the parity tests), WARPE_NO_SCORE_SKIP (every nadir
 * score computed, for the test that the skip of nadir_scatter changes no bit); the layouts the
 * host reads back come as -D macros too (tally.h). Every physical value is a kernel argument, so
 * a new scenario never recompiles.
 *
 * A feature's switch is tested in its own file, which defines empty stand-ins of its steps
 * when the feature is compiled out: the walk calls every step, and the compiler removes the
 * empty ones. The structures below hold the fields of every feature; a build reads and writes
 * only those of its own features (the others are never touched, and take no register).
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
 * kernel, so that the rays stay in registers (all but nadir_add in double precision, whose
 * inlined copies made Intel's compiler take 15 to 25 s: nadir.h). With a plain `inline`, PoCL
 * 3.1 (LLVM 15) kept the larger ones out of line, and the rays in memory (about -1 % events/s
 * on B1 and B3: docs/bench/2026-11-22_refactor_ab.txt). */
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
    /* a stack (WARPE_TEXTURE_LAYERS; layers.h SCENE_LAYERS) */
    int n_layers;                /* N (walk.md §7.1) */
    __global const REAL *layer_real;   /* [N][N_LAYER_REAL]: LAYER_* columns (walk.md §7.3) */
    __global const ulong *layer_words; /* [N]: the word threshold T_omega of each layer */
    __global const REAL *iface_real;   /* [N + 1][N_IFACE_REAL]: IFACE_* columns */
    __global const int *iface_kind;    /* [N + 1]: 0 transparent, 1 Fresnel */
    REAL gap_near, gap_far_n, gap_far_k;   /* from the gap up into the last layer */
    /* the next-event estimate (WARPE_NADIR; nadir.h SCENE_NADIR) */
    /* a stack: [N + 1][N_VIEW]: VIEW_* columns per layer (walk.md §8) */
    __global const REAL *view;
    /* one layer: the layer's row of the view table (walk.md §8), phase_k = (1 - g^2) / (4 pi)
     * and s_cap: a scattering's score <= s_cap exp_neg_bound(tau) (score.h) */
    REAL v_sin, v_mu, v_tau_per_m, v_path_per_m, v_factor, phase_k, s_cap;
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
    VREAL w;                     /* WARPE_WEIGHTED: the weight (walk.md §6) */
    /* a stack (WARPE_TEXTURE_LAYERS) */
    VMASK layer;                 /* the layer l the ray is in (N: the gap; walk.md §7.2) */
    /* layer l's values, loaded when the ray enters it (load_layer) */
    VREAL z_top, z_bottom, E, g, time_scale;
    VUINT omega_lo;              /* absorbed iff x1 >= omega_lo, unless scatter_all */
    VMASK scatter_all;           /* T_omega = 2^32: no word absorbs */
    /* WARPE_NADIR: the ray's pending nadir score (walk.md §8): its consecutive scores in one
     * cell, of time range [pend_lo, pend_hi), added up before they go to the batch sums;
     * cell -1: none */
    VREAL pend, pend_lo, pend_hi;
    VMASK pend_cell;
    VREAL nadir_total;           /* WARPE_NADIR and WARPE_RECORD: every score of the ray */
    /* WARPE_NADIR in a stack: layer l's row of the view table, loaded with its other values
     * (load_layer) */
    VREAL v_sin, v_mu, v_tau_per_m, v_path_per_m, v_tau_above, v_path_above, v_factor;
} rays_t;

/* The lanes' state as per-lane arrays (the rows of carry.h's carry_t are per ray; layers.h and
 * nadir.h move their own fields). */
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

/* The lanes whose ray ends in this event, their fate (FATE_*, tally.h) and, for an exit,
 * cos theta_e. */
typedef struct {
    VMASK done, fate;
    VREAL cos_exit;
} ends_t;

/* Where exits are tallied, and the rules that place them (walk.md §4). */
typedef struct {
    __global uint *time_in_fov, *time_any, *angular, *total, *early;
    /* WARPE_WEIGHTED (exits.h TALLIES_WEIGHTED) */
    __global ulong *w_time_in_fov, *w_time_any, *w_angular, *w_total, *w_early;
    __global ulong *w2_time_in_fov, *w2_total;
    /* WARPE_RECORD (exits.h TALLIES_RECORD) */
    __global int *rec_int;       /* [photons of the walk][N_RECORD_INT] */
    __global REAL *rec_real;     /* [photons of the walk][N_RECORD_REAL] */
    uint record_base;            /* the low word of the walk's first photon: row 0 */
    __global const REAL *time_edges;
    int n_edges;
    REAL cos_fov[N_COMPONENTS];  /* cos of each component's FOV; -1: any angle */
    int rule_time_window;        /* component rule time_window (else history) */
    REAL t1;                     /* first back-and-forth time 2 h n / c, ns
                                  * (docs/physics.md §5.7) */
    REAL ns_per_m;               /* t = L n / c (docs/physics.md §5.7, paper eq. 4) */
    /* WARPE_NADIR (nadir.h TALLIES_NADIR): the work-item's slice of the sums:
     * [NADIR_BATCHES][N_NADIR_ROWS][nadir_cols][FIXED_WORDS] and of the visits:
     * [N_NADIR_ROWS][nadir_cols]; own: no other work-item writes them */
    __global ulong *nadir_sum;
    __global ulong *nadir_visits;
    int nadir_cols;              /* n_edges + 1: before the first edge, the bins, after */
    int nadir_own;
    /* a first guess of a time's bin: floor(b (ln t - a)) for log-spaced edges (bin_log; a is
     * ln of the argument bin_a, the first edge), else floor(b (t - a)); the edges then correct
     * it (walk.md §8) */
    int bin_log;
    REAL bin_a, bin_b;
} tallies_t;

/* A work-item's statistics, written to item_stats at the end (exits.h write_stats). */
typedef struct {
    ulong fates[N_FATES];        /* rays per fate */
    ulong scattering_events;     /* volume scatterings of every ray */
    ulong mixed;                 /* exits with both a scattering and a floor reflection */
    ulong lost;                  /* weighted exits the exact sums cannot hold (walk.md §6) */
#ifdef WARPE_TEXTURE_LAYERS
    ulong layer[N_LAYER_STATS];  /* per layer and interface (LSTAT_*, walk.md §7.4) */
#endif
} stats_t;

/* A work-item's photons of the launch taken from the counter next_photon but not yet
 * walked: [next, end). A work-item takes photons WARPE_POOL at a time beyond those it wants
 * (walk.md §5), so that its lanes rarely wait on the launch-wide atomic counter, whose cache
 * line the cores pass to and fro; parked with the rays when the launch's budget is spent. */
typedef struct {
    uint next, end;
} pool_t;

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

/* A new ray's weight, 1, in the lanes in fresh (walk.md §6). */
WALK_STEP void fresh_weight(rays_t *r, VMASK fresh)
{
    r->w = SEL(r->w, (VREAL)1, fresh);
}

/* exp(-mu_a s) on the weight of every flight of the lanes in m, s = len (walk.md §6) */
WALK_STEP void weigh_flight(rays_t *r, const scene_t *sc, VREAL len, VMASK m)
{
    r->w = SEL(r->w, r->w * exp_neg(sc->mu_a * len), m);
}

/* The weights to and from per-lane rows (carry.h), as per-lane values (exits.h), and lane
 * j's of them. */
WALK_STEP void weight_to_rows(const rays_t *r, lane_rows_t *l)
{
    VSTORE(r->w, l->w);
}

WALK_STEP void rows_to_weight(const lane_rows_t *l, rays_t *r)
{
    r->w = VLOAD(l->w);
}

WALK_STEP void store_weights(const rays_t *r, REAL *w)
{
    VSTORE(r->w, w);
}

WALK_STEP REAL lane_weight(const REAL *w, int j)
{
    return w[j];
}
#else
/* the analog walk: every weight is 1 */
WALK_STEP void fresh_weight(rays_t *r, VMASK fresh) {}
WALK_STEP void weigh_flight(rays_t *r, const scene_t *sc, VREAL len, VMASK m) {}
WALK_STEP void weight_to_rows(const rays_t *r, lane_rows_t *l) {}
WALK_STEP void rows_to_weight(const lane_rows_t *l, rays_t *r) {}
WALK_STEP void store_weights(const rays_t *r, REAL *w) {}

WALK_STEP REAL lane_weight(const REAL *w, int j)
{
    return (REAL)1;
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
