"""Device qualification (warpe_cl/qualify.py, docs/devices.md): a known-answer walk against the
NumPy reference, in a child process, cached per user, with a fallback through lane widths.

The faults of real drivers are reproduced with ``$WARPE_CL_QUALIFY_FAULT``: ``abort`` kills the
child as pip's PoCL 3.0 did while building 16 lanes on an AVX-512 CPU; ``wrong`` reports every
ray specular as it did at 8 lanes. Each test uses its own cache folder.
"""
from __future__ import annotations

import dataclasses
import multiprocessing
import subprocess
import sys
import types

import numpy as np
import pytest

from warpe_cl import device as devmod
from warpe_cl import qualify
from warpe_cl.errors import DeviceError, WarpeWarning


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("WARPE_CL_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("WARPE_CL_LANES", raising=False)
    qualify._qualifiers.clear()
    yield qualify.VerdictCache(tmp_path)
    qualify._qualifiers.clear()


def _fresh_engine(engine):
    """An Engine on the session's device whose qualifier reads the test's cache."""
    from warpe_cl.engine import Engine
    e = Engine.__new__(Engine)
    e.__dict__.update(engine.__dict__)
    e._kernels = {}
    e.choose_lanes = qualify.LaneChooser(
        qualify.Qualifier(engine.info, cache=qualify.VerdictCache(), say=lambda m: None))
    return e


def test_compare_records_catches_a_wrong_kernel(engine):
    """The check itself: the reference against itself passes; every ray 'specular' (the
    8-lane PoCL 3.0 bug), one changed bin, or shifted times fail, in both precisions."""
    from warpe_cl.reference import simulate_reference
    params = qualify._scenes(qualify.Combo("slab", "double", False))["slab_fresnel"]
    ref = simulate_reference(params, 500, records=True)
    assert qualify.compare_records(ref, ref, "double", False) is None
    assert qualify.compare_counts(ref, ref, "double") is None

    def altered(**changes):
        rec = {k: v.copy() for k, v in ref.records.items()}
        for k, f in changes.items():
            rec[k] = f(rec[k])
        return types.SimpleNamespace(records=rec)

    all_specular = altered(fate=lambda a: np.zeros_like(a), component=lambda a: np.zeros_like(a))
    one_bin = altered(time_bin=lambda a: np.where(np.arange(a.size) == 3, a + 1, a))
    late = altered(time_ns=lambda a: a * (1 + 1e-3))
    for precision in ("single", "double"):
        assert qualify.compare_records(all_specular, ref, precision, False) is not None
        assert qualify.compare_records(late, ref, precision, False) is not None
    assert qualify.compare_records(one_bin, ref, "double", False) is not None


@pytest.mark.slow
def test_the_session_device_passes_every_combination_in_process(engine):
    """The known-answer walk of every kernel combination passes on the device the suite runs
    on, at the lane width the engine walks (measure off: no timing in unit tests)."""
    for combo in qualify.all_combos(engine.info.fp64):
        lanes = engine.lanes_for(combo.texture, combo.precision, combo.weighted)
        entry = qualify.check(engine, lanes, combo, measure=False)
        assert entry["passed"], (combo.label, lanes, entry["reason"])


@pytest.mark.slow
def test_a_crash_or_a_wrong_kernel_falls_back_and_says_so(engine, cache, monkeypatch):
    """The widest lane width aborts the child (16 with Intel's runtime), the next computes
    wrong rays: the walk runs at the third, gives the reference's counts, and warns once in
    one line naming both failures."""
    if engine.info.kind == "gpu":
        pytest.skip("GPUs walk one ray per work-item: there is no lane width to fall back to")
    first, second, third = qualify.Qualifier(engine.info).lane_chain("single")[:3]
    monkeypatch.setenv(qualify.FAULT_ENV, f"{first}:abort,{second}:wrong")
    e = _fresh_engine(engine)
    params = qualify._scenes(qualify.Combo("granular", "single", False))["granular"]
    with pytest.warns(WarpeWarning) as caught:
        counts = e.run(params, 3000, precision="single")
    messages = [str(w.message) for w in caught if issubclass(w.category, WarpeWarning)]
    assert len(messages) == 1 and "\n" not in messages[0]
    assert ("SIGABRT" in messages[0] and f"{first}, {second} lanes" in messages[0]
            and f"walking {third} lanes" in messages[0])
    assert e.lanes_for("granular", "single", False) == third
    direct = engine.run(params, 3000, precision="single", lanes=third)
    assert counts.same_as(direct)
    # the verdicts are on disk, each under a key that names the injected fault
    stored = cache._read()
    assert len(stored) == 3 and all(v["key"].get("fault") or v["passed"] for v in stored.values())


def test_an_explicit_lane_width_that_fails_is_an_error(engine, cache, monkeypatch):
    if engine.info.kind == "gpu":
        pytest.skip("GPUs walk one ray per work-item")
    monkeypatch.setenv(qualify.FAULT_ENV, "8:wrong")
    e = _fresh_engine(engine)
    params = qualify._scenes(qualify.Combo("slab", "single", False))["slab_contact"]
    with pytest.raises(DeviceError, match="failed qualification at 8 lanes.*follow the reference"):
        e.run(params, 100, precision="single", lanes=8)


def test_verdicts_are_cached_and_invalidated_by_any_key(engine, cache, monkeypatch):
    combo = qualify.Combo("slab", "single", False)
    q = qualify.Qualifier(engine.info, cache=cache, say=lambda m: None)
    first = q.verdicts(1, [combo], measure=False)[combo]
    assert first["passed"]

    def no_child(*a, **k):
        raise AssertionError("a cached verdict must not run the check again")
    monkeypatch.setattr(qualify, "run_child", no_child)
    again = qualify.Qualifier(engine.info, cache=qualify.VerdictCache(cache.folder))
    assert again.verdicts(1, [combo], measure=False)[combo]["passed"]
    # a new driver version, another lane width or changed sources: a new check
    newer = dataclasses.replace(engine.info, driver=engine.info.driver + "-new")
    for info, lanes in ((newer, 1), (engine.info, 2)):
        with pytest.raises(AssertionError, match="cached verdict"):
            qualify.Qualifier(info, cache=cache).verdicts(lanes, [combo], measure=False)
    monkeypatch.setattr(qualify, "QUALIFY_VERSION", qualify.QUALIFY_VERSION + 1)
    with pytest.raises(AssertionError, match="cached verdict"):
        qualify.Qualifier(engine.info, cache=cache).verdicts(1, [combo], measure=False)


def test_a_verdict_is_keyed_by_the_options_its_walk_is_built_with(engine):
    """The key of a verdict holds the build options of the walk it judged, as every build of
    that walk makes them (warpe_cl.engine.walk_options, Engine.program_options): a change of a
    driver's options (WARPE_BUILTINS) is a new check."""
    from warpe_cl.engine import kernel_key
    for combo, lanes in ((qualify.Combo("slab", "single", False), 4),
                         (qualify.Combo("granular", "double", True), 1)):
        key = qualify.combo_key(engine.info, lanes, combo)
        structure = kernel_key(combo.texture, combo.precision, False, lanes, combo.weighted)
        assert key["options"] == list(engine.program_options(structure))
    if engine.info.platform.startswith("Intel"):
        other = dataclasses.replace(engine.info, platform="Portable Computing Language")
    else:
        other = dataclasses.replace(engine.info, platform="Intel(R) OpenCL", kind="cpu")
    combo = qualify.Combo("slab", "single", False)
    options = [qualify.combo_key(info, 4, combo)["options"] for info in (engine.info, other)]
    assert options[0] != options[1]


def _put_many(folder, tag, n):
    c = qualify.VerdictCache(folder)
    for i in range(n):
        c.put([({"tag": tag, "i": i}, {"passed": True})])


def test_the_cache_is_safe_for_concurrent_processes(tmp_path):
    """Two processes writing 40 verdicts each at once: all 80 are kept (lock + atomic replace)."""
    ctx = multiprocessing.get_context("spawn")
    procs = [ctx.Process(target=_put_many, args=(str(tmp_path), t, 40)) for t in ("a", "b")]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
    assert all(p.exitcode == 0 for p in procs)
    assert len(qualify.VerdictCache(tmp_path)._read()) == 80


def test_auto_picks_the_fastest_qualified_device(monkeypatch):
    infos = [devmod.DeviceInfo(0, 0, "P", "1", f"dev{i}", "cpu", "d", 2, True) for i in range(3)]
    monkeypatch.setattr(devmod, "list_devices", lambda: [(i, i.device) for i in infos])
    monkeypatch.setattr(devmod, "probe", lambda dev: None)
    speeds = {"dev0": 1e8, "dev1": 3e8, "dev2": None}
    monkeypatch.setattr(qualify, "qualification", lambda info, say=None: qualify.Qualification(
        speeds[info.device] is not None, 16, speeds[info.device],
        None if speeds[info.device] else "wrong rays"))
    assert qualify.select_device("auto")[0].device == "dev1"
    assert qualify.select_device("dev0")[0].device == "dev0"
    with pytest.raises(DeviceError, match="dev2.*wrong rays"):
        qualify.select_device("dev2")


def test_devices_shows_the_verdicts(engine):
    """`warpe-cl devices` (the session's own cache, conftest.py): each device's verdict, a
    line for every kernel combination under a usable device (what the cache knows of it), and
    the device `auto` picks."""
    out = subprocess.run([sys.executable, "-m", "warpe_cl", "devices"], capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert "qualified:" in out.stdout and "scattering events/s" in out.stdout
    assert "picks" in out.stdout
    for combo in qualify.all_combos(engine.info.fp64):
        assert f"        {combo.label}" in out.stdout, out.stdout


class _TalkativeProgram:
    """A pyopencl Program whose build succeeds and warns, as Intel's compiler always does."""

    options = None

    def __init__(self, ctx, source):
        pass

    def build(self, options):
        import warnings

        import pyopencl
        _TalkativeProgram.options = list(options)
        warnings.warn("Non-empty compiler output encountered.", pyopencl.CompilerWarning)
        warnings.warn("something else", UserWarning)
        return "built"


@pytest.mark.parametrize("debug", ["", "1"])
def test_the_compilers_chatter_is_quiet_unless_debugging(monkeypatch, debug):
    """build_program, where every kernel is built (API, CLI, tools), drops pyopencl's
    "Non-empty compiler output" warning and no other; WARPE_CL_DEBUG=1 keeps it. A device
    that offers correctly rounded division and square root gets the option that asks for
    them (device.EXACT_DIVIDE_SQRT), and -w unless debugging."""
    import warnings
    exact = 1 << 7                      # CL_FP_CORRECTLY_ROUNDED_DIVIDE_SQRT
    fake = types.SimpleNamespace(
        Program=_TalkativeProgram,
        device_fp_config=types.SimpleNamespace(CORRECTLY_ROUNDED_DIVIDE_SQRT=exact))
    ctx = types.SimpleNamespace(devices=[types.SimpleNamespace(single_fp_config=exact | 1)])
    monkeypatch.setattr(devmod, "_cl", lambda: fake)
    monkeypatch.setattr(devmod, "context_and_queue", lambda device: (ctx, "queue"))
    monkeypatch.setenv("WARPE_CL_DEBUG", debug)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        assert devmod.build_program.__wrapped__("device", ("real.h",), ()) == "built"
    messages = [str(w.message) for w in seen]
    assert ("Non-empty compiler output encountered." in messages) == (debug == "1")
    assert "something else" in messages
    assert devmod.EXACT_DIVIDE_SQRT in _TalkativeProgram.options
    assert ("-w" in _TalkativeProgram.options) == (debug != "1")
    ctx.devices[0].single_fp_config = 1          # a device without it: not asked for
    devmod.build_program.__wrapped__("device", ("real.h",), ())
    assert devmod.EXACT_DIVIDE_SQRT not in _TalkativeProgram.options


@pytest.mark.filterwarnings("ignore:Non-empty compiler output")
@pytest.mark.parametrize("debug", ["", "1"])
def test_the_compilers_warnings_are_quiet_unless_debugging(capfd, monkeypatch, debug):
    """build_source builds with -w: on every device here, a source that warns (#warning) builds
    with no warning in its build log and nothing on the terminal (PoCL's clang prints "N
    warnings generated." on stderr itself); WARPE_CL_DEBUG=1 keeps the warning where the
    compiler reports ``#warning`` at all: NVIDIA's does not, with or without -w (its debug log
    on an H200, driver 580, held only its own note on the kernel's inlining; issue 43). A
    comment unique to this run keeps pyopencl's and PoCL's caches from answering."""
    import uuid

    import pyopencl as cl
    monkeypatch.setenv("WARPE_CL_DEBUG", debug)
    devices = devmod.list_devices()
    assert devices, "no OpenCL device: pip's PoCL comes with the package"
    for info, dev in devices:
        ctx, _ = devmod.context_and_queue(dev)
        source = (f"// {uuid.uuid4()}\n#warning warpe_probe_of_warnings\n"
                  "__kernel void nothing(__global int *x) { x[0] = 1; }\n")
        prg = devmod.build_source(ctx, source)
        log = prg.get_build_info(dev, cl.program_build_info.LOG)
        relays = not info.platform.startswith("NVIDIA")
        assert ("warpe_probe_of_warnings" in log) == (debug == "1" and relays), \
            (info.platform, log)
    err = capfd.readouterr().err
    if debug != "1":
        assert "warning" not in err, err


@pytest.mark.parametrize("kind, precision, preferred, widest", [
    ("cpu", "single", 1, 16),      # Intel's runtime: it vectorises scalar code itself
    ("cpu", "single", 8, 8),       # PoCL on AVX2
    ("cpu", "single", 16, 16),     # PoCL on AVX-512
    ("cpu", "single", 32, 16),     # never wider than 512 bits
    ("cpu", "single", 6, 4),       # an odd width: the widest of ours below it
    ("cpu", "double", 1, 8),
    ("cpu", "double", 4, 4),       # PoCL on AVX2
    ("cpu", "double", 8, 8),
    ("cpu", "double", 2, 2),       # SSE2: 2 doubles, then 1
    ("gpu", "single", 4, 1),       # a GPU's work-items are its lanes
])
def test_the_widest_lanes_follow_the_drivers_preferred_vector(kind, precision, preferred, widest):
    """engine.widest_lanes, and the qualifier's chain that starts there: 512 bits on CPUs, or
    the driver's preferred vector width where narrower (docs/performance.md: pip's PoCL on
    AVX2 walks 1.4x faster at 8 lanes than at 16)."""
    from warpe_cl.engine import widest_lanes
    assert widest_lanes(kind, precision, preferred) == widest
    info = devmod.DeviceInfo(0, 0, "P", "1", "dev", kind, "d", 2, True,
                             vector_float=preferred, vector_double=preferred)
    chain = qualify.Qualifier(info).lane_chain(precision)
    assert chain[0] == widest and list(chain) == sorted(chain, reverse=True) and chain[-1] == 1
