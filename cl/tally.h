/* tally.h: integer histograms of exits (docs/walk.md §4).
 *
 * Histograms are uint32 per launch, updated with atomic_inc (exact integer accumulation: no
 * float atomics); the host bounds each launch below 2^32 rays and adds them into int64.
 */
#ifndef WARPE_TALLY_H
#define WARPE_TALLY_H

#define N_COMPONENTS 4
#define N_EMERGENCE 90
#define COMPONENT_SPECULAR 0
#define COMPONENT_BF_DIRECT 1
#define COMPONENT_BF_DIFFUSE 2
#define COMPONENT_SCATTERING 3

#define FATE_SPECULAR 0
#define FATE_ESCAPED 1
#define FATE_ABSORBED_MEDIUM 2
#define FATE_ABSORBED_FLOOR 3
#define FATE_TERMINATED 4
#define N_FATES 5

/* Index i with edges[i] <= t < edges[i+1]; 0 if t < edges[0]; -1 if t >= edges[n_edges-1]. */
inline int time_bin(REAL t, __global const REAL *edges, int n_edges)
{
    int lo = 0, hi = n_edges - 1;
    if (t >= edges[hi])
        return -1;
    if (t < edges[0])
        return 0;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (edges[mid] <= t)
            lo = mid;
        else
            hi = mid;
    }
    return lo;
}

/* Emergence bin: min(floor(theta_e in degrees), 89). */
inline int emergence_bin(REAL cos_exit)
{
    REAL deg = acos(clamp(cos_exit, (REAL)0, (REAL)1)) * (REAL)(180.0 / WARPE_PI);
    return min((int)floor(deg), N_EMERGENCE - 1);
}

#endif /* WARPE_TALLY_H */
