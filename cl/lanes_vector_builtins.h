/* lanes_vector_builtins.h: SEL, VSTORE and VLOAD of vector lanes as OpenCL's built-ins, on
 * Intel's CPU runtime (WARPE_BUILTINS, warpe_cl/engine.py driver_options), whose built-ins are
 * inline (the host appends it after lanes_vector.h there, docs/walk.md §5.1; every other driver
 * gets lanes_vector_inline.h). Both give the same bits. */

/* SEL(a, b, m): b where m, else a */
#define SEL(a, b, m) select((a), (b), (m))
/* VSTORE(v, p) / VLOAD(p): a vector to and from a private array of its lanes (the walk's
 * per-lane arrays) */
#define VSTORE(v, p) WARPE_CAT(vstore, WARPE_LANES)((v), 0, (p))
#define VLOAD(p) WARPE_CAT(vload, WARPE_LANES)(0, (p))
