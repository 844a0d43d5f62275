"""Engine.use_program and Engine.forget: a walk program built elsewhere installed for a kernel
structure, and the engine's own build given back. tools/bench/bench_ab.py --kernel-only times
other trees' kernels through this hook, and tests/conftest.py's ``walk_with_options`` walks
another build of a kernel with it; this is product behaviour, so it is tested here, in the
default run (the benchmarks' own tests are in tools/bench/, run on demand)."""
from __future__ import annotations


def test_engine_walks_with_the_program_it_is_given(engine):
    """tools/bench/bench_ab.py --kernel-only times other trees' kernels through Engine.use_program,
    so Engine.kernel must hand back the installed kernel for that structure (with a key of
    its own, bench_ab once timed the engine's own kernel under both names: issue 16's nadir
    switch had lengthened the engine's key); Engine.forget undoes it. A trivial program stands
    in for the walk."""
    import copy

    from warpe_cl.device import build_source
    from warpe_cl.engine import kernel_key
    e = copy.copy(engine)
    e._kernels, e._folds = {}, {}
    source = "__kernel void walk(void) {}\n__kernel void nadir_fold(void) {}\n"
    for nadir in (False, True):
        structure = ("slab", "single", False, 1, False, nadir)
        kern = e.use_program(build_source(e.context, source), kernel_key(*structure))
        assert e.kernel(*structure) is kern
        assert e.kernel("slab", "single", 0, 1, 0, int(nadir)) is kern    # the key normalises
        assert (kernel_key(*structure) in e._folds) == nadir
        e.forget(kernel_key(*structure))                 # and Engine.forget undoes it
        assert kernel_key(*structure) not in e._kernels and kernel_key(*structure) not in e._folds
