/* layers.h: the medium's geometry, layer by layer -- a stack of layers (WARPE_TEXTURE_LAYERS,
 * walk.md §7) or the one layer of a slab or a granular medium: the free flight to the faces
 * (walk.md §3 step 3, §7.2), the crossing of an interface (walk.md §3.1-§3.3, §7.1-§7.2), the
 * entry and the gap below a Fresnel bottom (walk.md §3 step 2, §3.1), each layer's values per
 * lane (walk.md §7.3) and the per-layer statistics (walk.md §7.4), and where a nadir score's view
 * starts in the layer (walk.md §8.1).
 *
 * The host module that pairs with it is warpe_cl/stack.py (the layer, interface and view
 * tables, docs/physics.md §11); the physics is docs/physics.md §5.5-§5.6. The stack's steps
 * have stand-ins in the one-layer builds (empty, or the one layer's value), so that the walk
 * calls them unconditionally. After rays.h; before nadir.h, carry.h and exits.h, which call its
 * steps.
 */
#if defined(WARPE_TEXTURE_LAYERS) && defined(WARPE_WEIGHTED)
#error "the layered walk is analog only (walk.md §7)"
#endif

#ifdef WARPE_TEXTURE_LAYERS
/* a value of the lane's layer: one per lane in a stack */
#define LAYERED_REAL VREAL

/* The stack's fields of scene_t, from the kernel's arguments (walk.cl). */
#define SCENE_LAYERS \
    .n_layers = n_layers, .layer_real = layer_real, .layer_words = layer_words, \
    .iface_real = iface_real, .iface_kind = iface_kind, \
    /* from the gap up into the last layer (walk.md §7.2 gap events) */ \
    .gap_near = iface_real[N_IFACE_REAL * n_layers + IFACE_UP_NEAR], \
    .gap_far_n = iface_real[N_IFACE_REAL * n_layers + IFACE_UP_FAR_N], \
    .gap_far_k = iface_real[N_IFACE_REAL * n_layers + IFACE_UP_FAR_K],
/* The view table's fields of scene_t (nadir.h SCENE_NADIR): a row per layer, loaded per lane
 * (load_layer), and the gap's row after them */
#define SCENE_VIEW .view = view,
#define GAP_VIEW_ROW (N_VIEW * n_layers)


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

/* The lanes of the new and resumed rays take their layer's values (walk.md §7.3). */
WALK_STEP void load_new_layers(rays_t *r, VMASK had, const scene_t *sc)
{
    load_layer(r, r->alive & !had, sc);
}

/* A new ray starts in layer 0 (walk.md §7.2). */
WALK_STEP void fresh_layers(rays_t *r, VMASK fresh)
{
    r->layer = SEL(r->layer, (VMASK)0, fresh);
}

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

/* down[0]: the rays that enter the stack in this event, the lanes in first that the entry did
 * not end (walk.md §7.4) */
WALK_STEP void count_entries(stats_t *st, VMASK first, VMASK done)
{
    if (ANY(first))
        count_lanes(st, LSTAT_DOWN, first & !done, (VMASK)0);
}

/* A ray ended by the medium or the flight cap, in its layer's statistics (walk.md §7.4). */
WALK_STEP void count_layer_end(stats_t *st, int fj, int layer)
{
    if (fj == FATE_ABSORBED_MEDIUM)
        st->layer[LSTAT_ABSORBED + layer] += 1;
    else if (fj == FATE_TERMINATED)
        st->layer[LSTAT_TERMINATED + layer] += 1;
}

/* The layer each ray ends in (walk.md §7.2, §7.4), as per-lane values (exits.h tally_exits). */
WALK_STEP void store_layers(const rays_t *r, IREAL *ly)
{
    VSTORE(r->layer, ly);
}

WALK_STEP int lane_layer(const IREAL *ly, int j)
{
    return (int)ly[j];
}

/* The work-item's per-layer statistics into its row of layer_stats (walk.md §7.4). */
WALK_STEP void write_layer_stats(__global ulong *row, const stats_t *st)
{
    for (int i = 0; i < N_LAYER_STATS; ++i)
        row[i] = st->layer[i];
}

/* The rays' layers to and from per-lane rows (carry.h). */
WALK_STEP void layers_to_rows(const rays_t *r, lane_rows_t *l)
{
    VSTORE(r->layer, l->layer);
}

WALK_STEP void rows_to_layers(const lane_rows_t *l, rays_t *r)
{
    r->layer = VLOAD(l->layer);
}

/* HG's g of the lanes' layers (walk.md §7.2) */
WALK_STEP VREAL lanes_g(const rays_t *r, const scene_t *sc)
{
    return r->g;
}

/* An entry event iff the top of the stack is a Fresnel interface (walk.md §7.2). */
WALK_STEP int top_is_fresnel(const scene_t *sc)
{
    return sc->iface_kind[0];
}

/* The flight of the lanes in fl to their next collision, s = l / E (l = -ln u0), or to the
 * face ahead of their layer (walk.md §3 step 3.2, §7.2): sets *coll and *bnd to the lanes that
 * collide and that reach the face, moves them, and returns the path at layer 0's speed,
 * L += s n_l / n_0. */
WALK_STEP VREAL flight_to_face(VMASK fl, VREAL u0, const scene_t *sc, rays_t *r, VMASK *coll,
                               VMASK *bnd)
{
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
    *coll = c;
    *bnd = b;
    return len;
}

/* The lanes in bnd at interface j of the stack, j = l + 1 going down and l going up, with the
 * words u1 (x1), u2 and the azimuth (cos psi, sin psi) = u3 of their block (walk.md §7.1-§7.2,
 * docs/physics.md §11). A Fresnel interface: total internal reflection, or reflect iff
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

/* The lanes in bnd at a face of their layer (walk.md §7.1-§7.2). */
WALK_STEP void boundary_event(VMASK bnd, VREAL u1, VUINT x1, VREAL u2, VREAL cos_psi,
                              VREAL sin_psi, const scene_t *sc, rays_t *r, ends_t *e,
                              stats_t *st)
{
    cross_interface(bnd, u1, x1, u2, cos_psi, sin_psi, sc, r, e, st);
}

/* From the gap up through the last layer's face (walk.md §7.2): the lanes in gap that a
 * Lambertian direction mu_v (sin theta_g = sin_g) takes into layer N - 1, and sin theta of
 * their direction there; they take its values, counted as up[N] (walk.md §7.4). */
WALK_STEP VMASK gap_crossing(VMASK gap, VREAL mu_v, VREAL u3, const scene_t *sc, rays_t *r,
                             stats_t *st, VREAL *sin_s)
{
    const REAL n_g = sc->gap_near, n2 = sc->gap_far_n, k2 = sc->gap_far_k;
    const VREAL sin_g = sqrt(max0((REAL)1 - mu_v * mu_v));
    const VREAL R = (n2 == (REAL)1 && k2 == (REAL)0)
                  ? fresnel_internal(mu_v, (VREAL)n_g)
                  : fresnel_external(mu_v, (VREAL)(n2 / n_g), (VREAL)(k2 / n_g));
    const VMASK enter = gap & !(n_g * sin_g >= n2) & (u3 > R);
    *sin_s = (sin_g * n_g) / n2;
    r->layer = SEL(r->layer, (VMASK)(sc->n_layers - 1), enter);
    load_layer(r, enter, sc);
    count_lanes(st, LSTAT_UP, enter, (VMASK)sc->n_layers);
    return enter;
}


/* Where a nadir score's view starts (walk.md §8.1), in the lanes' layers: the layer's HG g and
 * the view direction (sin_l, 0, -mu_l) inside it; tau and the path up from depth z, through
 * the layers above (VIEW_*_ABOVE) and the lane's own; the factor of a scattering's score
 * (with HG's (1 - g^2) / (4 pi)) and of a floor reflection's (with Lambert's mu_l / pi); tau
 * and the path down to the bottom of the layer (the mirror paths, walk.md §8.5); the lanes
 * in m in a mirror row's layer; the roulette's uniform v of a scattering's word x1, below the
 * layer's own threshold (walk.md §8.3); and whether a score bound loses every lane's score to
 * the roulette (a stack: none). */
WALK_STEP void view_angles(const scene_t *sc, const rays_t *r, VREAL *g, VREAL *sin_v,
                           VREAL *mu_v)
{
    *g = r->g;
    *sin_v = r->v_sin;
    *mu_v = r->v_mu;
}

WALK_STEP void view_at_depth(const scene_t *sc, const rays_t *r, VREAL *tau, VREAL *path)
{
    const VREAL depth = r->z - r->z_top;
    *tau = r->v_tau_above + r->v_tau_per_m * depth;
    *path = r->v_path_above + r->v_path_per_m * depth;
}

WALK_STEP VREAL scatter_factor(const scene_t *sc, const rays_t *r, VREAL g)
{
    return r->v_factor * ((REAL)1 - g * g) * (REAL)(0.25 / WARPE_PI);
}

WALK_STEP VREAL contact_factor(const scene_t *sc, const rays_t *r)
{
    return r->v_factor * r->v_mu * (REAL)(1.0 / WARPE_PI);
}

WALK_STEP void view_to_bottom(const scene_t *sc, const rays_t *r, VREAL *tau_down,
                              VREAL *path_down)
{
    const VREAL below = r->z_bottom - r->z;
    *tau_down = r->v_tau_per_m * below;
    *path_down = r->v_path_per_m * below;
}

WALK_STEP VMASK mirror_lanes(VMASK m, const rays_t *r, __global const REAL *row)
{
    return m & (r->layer == (VMASK)(int)row[MIRROR_LAYER]);
}

WALK_STEP VREAL medium_uniform(VUINT x1, const scene_t *sc, const rays_t *r)
{
    const VREAL words = SEL(CONVERT_VREAL(r->omega_lo), (VREAL)0x1p32, r->scatter_all);
    return (CONVERT_VREAL(x1) + (REAL)0.5) / words;
}

WALK_STEP int scores_lost(VMASK m, VREAL v, VREAL tau, const scene_t *sc)
{
    return 0;
}

#else
/* one layer: a value of the scenario's */
#define LAYERED_REAL REAL
#define SCENE_LAYERS
/* The view's row of the layer in scene_t (walk.md §8), phase_k = (1 - g^2) / (4 pi) and the
 * bound s_cap of score.h, from the kernel's arguments (nadir.h SCENE_NADIR); the gap's row
 * after the layer's */
#define SCENE_VIEW \
    .v_sin = view[VIEW_SIN], .v_mu = view[VIEW_MU], .v_tau_per_m = view[VIEW_TAU_PER_M], \
    .v_path_per_m = view[VIEW_PATH_PER_M], .v_factor = view[VIEW_FACTOR], \
    .phase_k = phase_k, .s_cap = score_cap(view[VIEW_FACTOR] * phase_k, g, nadir_min, n_mirror),
#define GAP_VIEW_ROW N_VIEW

/* the stack's steps: nothing to load or count */
WALK_STEP void load_new_layers(rays_t *r, VMASK had, const scene_t *sc) {}
WALK_STEP void fresh_layers(rays_t *r, VMASK fresh) {}
WALK_STEP void count_entries(stats_t *st, VMASK first, VMASK done) {}
WALK_STEP void count_layer_end(stats_t *st, int fj, int layer) {}
WALK_STEP void store_layers(const rays_t *r, IREAL *ly) {}
WALK_STEP void write_layer_stats(__global ulong *row, const stats_t *st) {}
WALK_STEP void rows_to_layers(const lane_rows_t *l, rays_t *r) {}

/* the one layer: layer 0 */
WALK_STEP int lane_layer(const IREAL *ly, int j)
{
    return 0;
}

WALK_STEP void layers_to_rows(const rays_t *r, lane_rows_t *l)
{
    for (int j = 0; j < WARPE_LANES; ++j)
        l->layer[j] = 0;
}

WALK_STEP VREAL lanes_g(const rays_t *r, const scene_t *sc)
{
    return (VREAL)sc->g;
}

WALK_STEP int top_is_fresnel(const scene_t *sc)
{
    return 1;                    /* a slab (a granular layer has no entry event) */
}

/* The flight of the lanes in fl to their next collision, s = l / E (l = -ln u0), or to the
 * boundary ahead (walk.md §3 step 3.2): sets *coll and *bnd to the lanes that collide and that
 * reach the boundary, moves them, and returns the path s. */
WALK_STEP VREAL flight_to_face(VMASK fl, VREAL u0, const scene_t *sc, rays_t *r, VMASK *coll,
                               VMASK *bnd)
{
    const VREAL s = SEL((VREAL)INFINITY, optical_step(u0) / sc->E,
                        (VMASK)(sc->E > (REAL)0 ? -1 : 0));
    /* the way to the boundary ahead: (h - z)/uz down, -z/uz up, none level (one division) */
    const VREAL s_b = SEL((VREAL)INFINITY, SEL(-r->z, sc->h - r->z, r->uz > (REAL)0) / r->uz,
                          (r->uz < (REAL)0) | (r->uz > (REAL)0));
    VMASK c = fl & (s < s_b);
    VMASK b = fl & !(s < s_b);
    const VREAL len = SEL(s_b, s, c);
    r->z = SEL(r->z, SEL(SEL((VREAL)0, (VREAL)sc->h, r->uz > (REAL)0), r->z + s * r->uz, c), fl);
    *coll = c;
    *bnd = b;
    return len;
}

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

WALK_STEP void boundary_event(VMASK bnd, VREAL u1, VUINT x1, VREAL u2, VREAL cos_psi,
                              VREAL sin_psi, const scene_t *sc, rays_t *r, ends_t *e,
                              stats_t *st)
{
    reach_boundary(bnd, u1, x1, u2, cos_psi, sin_psi, sc, r, e);
}

/* From the gap up through the slab's lower face (walk.md §3.1): the lanes in gap that the
 * face lets in, iff u3 > R_ext(mu_v; n, k), and sin theta_s = sin theta_v / n (Snell, real
 * part). */
WALK_STEP VMASK gap_crossing(VMASK gap, VREAL mu_v, VREAL u3, const scene_t *sc, rays_t *r,
                             stats_t *st, VREAL *sin_s)
{
    const VMASK enter = gap & (u3 > fresnel_external(mu_v, (VREAL)sc->n, (VREAL)sc->k));
    *sin_s = sqrt(max0((REAL)1 - mu_v * mu_v)) / sc->n;
    return enter;
}

/* one layer: the scenario's view row (see the stack's above) */
WALK_STEP void view_angles(const scene_t *sc, const rays_t *r, REAL *g, REAL *sin_v,
                           REAL *mu_v)
{
    *g = sc->g;
    *sin_v = sc->v_sin;
    *mu_v = sc->v_mu;
}

WALK_STEP void view_at_depth(const scene_t *sc, const rays_t *r, VREAL *tau, VREAL *path)
{
    *tau = sc->v_tau_per_m * r->z;
    *path = sc->v_path_per_m * r->z;
}

WALK_STEP REAL scatter_factor(const scene_t *sc, const rays_t *r, REAL g)
{
    return sc->v_factor * sc->phase_k;
}

WALK_STEP REAL contact_factor(const scene_t *sc, const rays_t *r)
{
    return sc->v_factor * sc->v_mu * (REAL)(1.0 / WARPE_PI);
}

WALK_STEP void view_to_bottom(const scene_t *sc, const rays_t *r, VREAL *tau_down,
                              VREAL *path_down)
{
    const VREAL below = (REAL)sc->h - r->z;
    *tau_down = sc->v_tau_per_m * below;
    *path_down = sc->v_path_per_m * below;
}

WALK_STEP VMASK mirror_lanes(VMASK m, const rays_t *r, __global const REAL *row)
{
    return m;                    /* one layer: every up and down row is its own */
}

WALK_STEP VREAL medium_uniform(VUINT x1, const scene_t *sc, const rays_t *r)
{
    return (CONVERT_VREAL(x1) + (REAL)0.5) * sc->inv_omega_words;
}

/* every lane's score lost to the roulette for certain (walk.md §8.3): v s_min above the bound
 * s_cap exp_neg_bound(tau) of the score s, so v s_min > s: nothing to add, and nothing to
 * compute (the events deep in a thick medium: most of them) */
WALK_STEP int scores_lost(VMASK m, VREAL v, VREAL tau, const scene_t *sc)
{
#ifndef WARPE_NO_SCORE_SKIP
    if (!ANY(m & !(v * sc->s_min > sc->s_cap * exp_neg_bound(tau))))
        return 1;
#endif
    return 0;
}
#endif

#ifdef WARPE_INTERFACES
/* ENTRY (walk.md §3 step 2, docs/physics.md §5.2): specular iff u0 <= R0, recorded at t = 0,
 * theta_e = 0; else the ray enters, and flies from its next event */
WALK_STEP void entry_event(VREAL u0, VREAL R0, rays_t *r, ends_t *e)
{
    const VMASK entry = r->alive & (r->phase == (VMASK)PHASE_ENTRY);
    finish(e, entry & (u0 <= R0), FATE_SPECULAR);
    r->phase = SEL(r->phase, (VMASK)PHASE_FLIGHT, entry);
}

/* The lanes whose next event is GAP. */
WALK_STEP VMASK gap_lanes(const rays_t *r)
{
    return r->alive & (r->phase == (VMASK)PHASE_GAP);
}

/* A new ray's first event: the entry where the top is a Fresnel face. */
WALK_STEP IREAL start_phase(const scene_t *sc)
{
    return top_is_fresnel(sc) ? PHASE_ENTRY : PHASE_FLIGHT;
}

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
    VREAL sin_s;
    const VMASK enter = gap_crossing(gap, mu_v, u3, sc, r, st, &sin_s);
    r->ux = SEL(r->ux, sin_s * c2, enter);
    r->uy = SEL(r->uy, sin_s * s2, enter);
    r->uz = SEL(r->uz, -sqrt((REAL)1 - sin_s * sin_s), enter);
    r->phase = SEL(r->phase, (VMASK)PHASE_FLIGHT, enter);
}
#else
/* a granular layer: no entry, no gap; a new ray flies */
WALK_STEP void entry_event(VREAL u0, VREAL R0, rays_t *r, ends_t *e) {}
WALK_STEP void gap_event(VMASK gap, VREAL u0, VUINT x0, VREAL u1, VREAL u2, VREAL u3,
                         const scene_t *sc, rays_t *r, ends_t *e, stats_t *st) {}

WALK_STEP VMASK gap_lanes(const rays_t *r)
{
    return (VMASK)0;
}

WALK_STEP IREAL start_phase(const scene_t *sc)
{
    return PHASE_FLIGHT;
}
#endif
