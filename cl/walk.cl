/* walk.cl: the analog random walk of one ray through a slab or a granular layer, and the
 * kernel that walks a range of photons and tallies their exits.
 *
 * The rules, step by step, are docs/walk.md; the physics is shared/docs/physics.md §5-§6.
 * Structure switches (-D): WARPE_TEXTURE_SLAB or WARPE_TEXTURE_GRANULAR (exactly one),
 * WARPE_DOUBLE (precision), WARPE_RECORD (write one record per photon, for the parity tests).
 * Every physical value is a kernel argument, so a new scenario never recompiles.
 */
#if defined(WARPE_TEXTURE_SLAB) == defined(WARPE_TEXTURE_GRANULAR)
#error "define exactly one of WARPE_TEXTURE_SLAB and WARPE_TEXTURE_GRANULAR"
#endif

typedef struct {
    REAL h;          /* thickness, m */
    REAL E;          /* extinction coefficient tau0/h, 1/m (0: none) */
    REAL omega;      /* single-scattering albedo */
    REAL g;          /* Henyey-Greenstein asymmetry */
    REAL n, k;       /* effective index */
    REAL A;          /* Lambertian floor albedo */
    REAL L_max;      /* path cap max_time * c / n, m */
    uint max_flights;
    int bottom_fresnel; /* slab: 1 = Fresnel interface above the floor, 0 = optical contact */
} medium_t;

typedef struct {
    REAL t;          /* exit time, ns */
    REAL cos_exit;   /* cos of the emergence angle in vacuum */
    uint n_scat, n_lamb, n_bspec, n_top;
} ray_t;

/* Walk one ray; returns its fate and fills `ray` (docs/walk.md §3). */
inline int walk_ray(const medium_t *m, rng_t *r, ray_t *ray)
{
    ray->n_scat = ray->n_lamb = ray->n_bspec = ray->n_top = 0;
    ray->t = (REAL)0;
    ray->cos_exit = (REAL)1;

#ifdef WARPE_TEXTURE_SLAB
    /* §5.2: specular reflection at the top with R0(n_eff, k_eff), recorded at t = 0, theta_e = 0 */
    if (uniform(r) <= fresnel_external((REAL)1, m->n, m->k))
        return FATE_SPECULAR;
#endif

    REAL z = (REAL)0, ux = (REAL)0, uy = (REAL)0, uz = (REAL)1;  /* §5.1: normal incidence */
    path_t L = {0, 0};
    uint flights = 0;

    for (;;) {
        if (flights == m->max_flights)
            return FATE_TERMINATED;   /* §5.8 safety cap */
        flights += 1;

        /* §5.3 free flight: optical step -ln U, physical step s = l/E (seed eq. 3) */
        REAL ell = -log(uniform(r));
        REAL s = m->E > (REAL)0 ? ell / m->E : (REAL)INFINITY;
        REAL s_b = uz > (REAL)0 ? (m->h - z) / uz : (uz < (REAL)0 ? -z / uz : (REAL)INFINITY);

        if (s < s_b) {
            /* §5.4 collision */
            z += s * uz;
            path_add(&L, s);
            if (L.sum > (PATH)m->L_max)
                return FATE_TERMINATED;
            if (uniform(r) > m->omega)
                return FATE_ABSORBED_MEDIUM;
            ray->n_scat += 1;
            REAL cos_theta = hg_cos_theta(m->g, uniform(r));
            REAL psi = (REAL)(2.0 * WARPE_PI) * uniform(r);
            rotate_direction(&ux, &uy, &uz, cos_theta, psi);
            continue;
        }

        path_add(&L, s_b);
        if (L.sum > (PATH)m->L_max)
            return FATE_TERMINATED;

        if (uz > (REAL)0) {
            /* §5.5 bottom */
            z = m->h;
#ifdef WARPE_TEXTURE_SLAB
            if (m->bottom_fresnel) {
                REAL mu = uz;
                if (m->n * sqrt(fmax((REAL)1 - mu * mu, (REAL)0)) >= (REAL)1
                    || uniform(r) <= fresnel_internal(mu, m->n)) {
                    uz = -uz;              /* specular at the bottom interface */
                    ray->n_bspec += 1;
                    continue;
                }
                /* through the zero-thickness gap to the floor, and back (no time added) */
                for (;;) {
                    if (uniform(r) > m->A)
                        return FATE_ABSORBED_FLOOR;
                    ray->n_lamb += 1;
                    REAL mu_v = sqrt(uniform(r));
                    REAL psi = (REAL)(2.0 * WARPE_PI) * uniform(r);
                    if (uniform(r) <= fresnel_external(mu_v, m->n, m->k))
                        continue;          /* reflected by the slab's lower face: floor again */
                    /* refraction in (Snell, real part): sin(theta_s) = sin(theta_v)/n */
                    REAL sin_s = sqrt(fmax((REAL)1 - mu_v * mu_v, (REAL)0)) / m->n;
                    REAL c, sn = sincos(psi, &c);
                    ux = sin_s * c;
                    uy = sin_s * sn;
                    uz = -sqrt((REAL)1 - sin_s * sin_s);
                    break;
                }
                continue;
            }
#endif
            /* Lambertian floor in optical contact (granular, or slab with bottom_interface none) */
            if (uniform(r) > m->A)
                return FATE_ABSORBED_FLOOR;
            ray->n_lamb += 1;
            lambert_up(r, &ux, &uy, &uz);
            continue;
        }

        /* §5.6 top, from inside */
        z = (REAL)0;
        REAL mu = -uz;
#ifdef WARPE_TEXTURE_SLAB
        if (m->n * sqrt(fmax((REAL)1 - mu * mu, (REAL)0)) >= (REAL)1
            || uniform(r) <= fresnel_internal(mu, m->n)) {
            uz = -uz;
            ray->n_top += 1;
            continue;
        }
        ray->cos_exit = sqrt(fmax(((REAL)1 - m->n * m->n) + m->n * m->n * mu * mu, (REAL)0));
#else
        ray->cos_exit = mu;
#endif
        /* §5.7 seed eq. 4: t = L n_eff / c */
        ray->t = (REAL)(L.sum * (PATH)m->n / (PATH)WARPE_C_M_PER_NS);
        return FATE_ESCAPED;
    }
}

/* Walk photons first_photon .. first_photon + n_photons - 1, each work-item taking every
 * get_global_size(0)-th photon. Histograms are accumulated with integer atomics; per work-item
 * totals (fates, scattering events, mixed histories) go to item_stats[gid * 8 + i]. */
__kernel void walk(const uint seed, const uint scenario,
                   const ulong first_photon, const ulong n_photons,
                   const REAL h, const REAL E, const REAL omega, const REAL g,
                   const REAL n, const REAL k, const REAL A,
                   const REAL L_max, const uint max_flights, const int bottom_fresnel,
                   const int rule_time_window, const REAL t1,
                   __global const REAL *time_edges, const int n_edges,
                   const REAL cos_fov_specular, const REAL cos_fov_bf_direct,
                   const REAL cos_fov_bf_diffuse, const REAL cos_fov_scattering,
                   __global uint *time_in_fov,   /* [4][n_edges - 1] */
                   __global uint *time_any,      /* [4][n_edges - 1] */
                   __global uint *angular,       /* [4][90] */
                   __global uint *total,         /* [4] */
                   __global ulong *item_stats    /* [global size][8] */
#ifdef WARPE_RECORD
                   , __global int *rec_int       /* [n_photons][8] */
                   , __global REAL *rec_real     /* [n_photons][2] */
#endif
                   )
{
    const medium_t m = {h, E, omega, g, n, k, A, L_max, max_flights, bottom_fresnel};
    const REAL cos_fov[4] = {cos_fov_specular, cos_fov_bf_direct, cos_fov_bf_diffuse,
                             cos_fov_scattering};
    const int n_time = n_edges - 1;
    const size_t gid = get_global_id(0), stride = get_global_size(0);
    ulong fates[N_FATES] = {0, 0, 0, 0, 0};
    ulong scattering_events = 0, mixed = 0;

    for (ulong i = gid; i < n_photons; i += stride) {
        rng_t r;
        ray_t ray;
        rng_init(&r, seed, scenario, first_photon + i);
        int fate = walk_ray(&m, &r, &ray);
        fates[fate] += 1;
        scattering_events += ray.n_scat;
        int component = -1, tb = -1, eb = -1;
        if (fate == FATE_SPECULAR || fate == FATE_ESCAPED) {
            /* §6.1 components */
            if (fate == FATE_SPECULAR)
                component = COMPONENT_SPECULAR;
            else if (ray.n_scat == 0 && ray.n_lamb == 0)
                component = COMPONENT_BF_DIRECT;
            else if (rule_time_window)
                component = ray.t >= t1 ? COMPONENT_BF_DIFFUSE : COMPONENT_SCATTERING;
            else
                component = ray.n_lamb > 0 ? COMPONENT_BF_DIFFUSE : COMPONENT_SCATTERING;
            if (ray.n_scat > 0 && ray.n_lamb > 0)
                mixed += 1;
            eb = emergence_bin(ray.cos_exit);
            tb = time_bin(ray.t, time_edges, n_edges);
            atomic_inc(&total[component]);
            atomic_inc(&angular[component * N_EMERGENCE + eb]);
            if (tb >= 0) {
                atomic_inc(&time_any[component * n_time + tb]);
                if (ray.cos_exit >= cos_fov[component])
                    atomic_inc(&time_in_fov[component * n_time + tb]);
            }
        }
#ifdef WARPE_RECORD
        __global int *ri = rec_int + 8 * i;
        ri[0] = fate; ri[1] = component;
        ri[2] = (int)ray.n_scat; ri[3] = (int)ray.n_lamb;
        ri[4] = (int)ray.n_bspec; ri[5] = (int)ray.n_top;
        ri[6] = tb; ri[7] = eb;
        rec_real[2 * i] = ray.t;
        rec_real[2 * i + 1] = ray.cos_exit;
#endif
    }

    __global ulong *st = item_stats + 8 * gid;
    for (int f = 0; f < N_FATES; ++f)
        st[f] = fates[f];
    st[5] = scattering_events;
    st[6] = mixed;
    st[7] = 0;
}
