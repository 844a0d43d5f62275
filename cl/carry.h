/* carry.h: the launch carry (walk.md §5, "Launches bounded by events"): a launch stops each
 * work-item after its event budget and parks the rays still walking, with the photons left in
 * its pool, one row of the state buffers each; the next launch resumes them before it takes new
 * photons, from the same event block, so that no result depends on where launches cut a ray.
 *
 * The host module that pairs with it is warpe_cl/engine.py (the event budget of each launch,
 * the two state buffers it alternates); the row's columns are STATE_*_COLUMNS of
 * warpe_cl/params.py. Each feature moves its own fields of a row (rays.h the weight, layers.h
 * the layer, nadir.h the pending score), a stand-in where it is compiled out. After rays.h,
 * layers.h and nadir.h; before walk.cl.
 */

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

WALK_STEP void rays_to_rows(const rays_t *r, lane_rows_t *l)
{
    VSTORE(r->z, l->z);
    VSTORE(r->ux, l->ux);
    VSTORE(r->uy, l->uy);
    VSTORE(r->uz, l->uz);
    VSTORE(r->Ls, l->Ls);
    VSTORE(r->Lc, l->Lc);
    weight_to_rows(r, l);
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
    layers_to_rows(r, l);
    nadir_to_rows(r, l);
}

WALK_STEP void rows_to_rays(const lane_rows_t *l, rays_t *r)
{
    r->z = VLOAD(l->z);
    r->ux = VLOAD(l->ux);
    r->uy = VLOAD(l->uy);
    r->uz = VLOAD(l->uz);
    r->Ls = VLOAD(l->Ls);
    r->Lc = VLOAD(l->Lc);
    rows_to_weight(l, r);
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
    rows_to_layers(l, r);
    rows_to_nadir(l, r);
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
        rr[STATE_W] = lane_weight(l.w, j);      /* rays.h: 1 in the analog walk */
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
