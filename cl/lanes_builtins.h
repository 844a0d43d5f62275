/* lanes_builtins.h: fmax(x, 0), clamp, fabs and rint of the lanes as OpenCL's built-ins, on
 * Intel's CPU runtime (WARPE_BUILTINS, warpe_cl/engine.py driver_options), whose built-ins are
 * inline instructions (the host appends it to the lane types, docs/walk.md §5.1; every other
 * driver gets lanes_inline.h). The same values for every number the walk gives them
 * (tests/test_kernel_blocks.py). */
#define max0(x) fmax((x), (REAL)0)
#define clamp_lanes(x, lo, hi) clamp((x), (lo), (hi))
#define abs_lanes(x) fabs(x)
#define rint_lanes(x) rint(x)
