"""Same seed, same counts: whatever the batch size, global size, work-group size or split."""
from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest

from conftest import SCATTERING, lanes_of, medium, vector_widths
from warpe_cl.api import scenario_key
from warpe_cl.config import load_preset
from warpe_cl.engine import STATS_PARTS, kernel_key, sum_rows
from warpe_cl.qualify import compare_records
from warpe_cl.reference import simulate_reference



@pytest.mark.parametrize("precision", ["single", "double"])
def test_counts_do_not_depend_on_launch_geometry(engine, precision):
    p = medium(**SCATTERING)
    n = 60_000
    reference = engine.run(p, n, precision=precision)
    for kw in (dict(batch=7_777), dict(batch=60_000, global_size=33),
               dict(global_size=1000, local_size=8), dict(global_size=64, local_size=64),
               dict(batch=1_000_003),
               # more work-items than STATS_PARTS: their statistics folded on the device
               dict(global_size=3 * STATS_PARTS + 5, lanes=1, qualified=True)):
        other = engine.run(p, n, precision=precision, **kw)
        assert other.same_as(reference), kw


@pytest.mark.parametrize("items, parts", [(1000, 7), (997, 4096), (4097, 4096), (1, 1)])
def test_statistics_folded_on_the_device_add_exactly(engine, items, parts):
    """engine.sum_rows (cl/walk.cl stats_fold): the column sums of a launch's per-work-item
    statistics, folded into ``parts`` rows on the device where there are more rows, equal
    NumPy's exact sums; rows past ``items`` (stale rows of earlier launches) never count."""
    key = kernel_key("slab", "single", False, 1)
    engine.kernel(*key)
    # counts below 2^40, so that 4100 rows' sums stay far inside int64
    rows = np.random.default_rng(7).integers(0, 2 ** 40, (items + 3, 9), dtype=np.uint64)
    table = cl.Buffer(engine.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR,
                      hostbuf=rows)
    exact = rows[:items].astype(np.int64).sum(axis=0)
    # no fold kernel (a program of an older tree, tools/bench/bench_ab.py): every row read
    np.testing.assert_array_equal(sum_rows(engine.queue, None, table, items, 9, parts=parts),
                                  exact)
    sums = sum_rows(engine.queue, engine._stats_folds[key], table, items, 9, parts=parts)
    np.testing.assert_array_equal(sums, exact)


@pytest.mark.parametrize("precision", ["single", "double"])
@pytest.mark.parametrize("texture", ["slab", "granular"])
def test_counts_do_not_depend_on_lane_width(engine, precision, texture):
    """The vector form (several photons per work-item) and the one-photon-per-work-item form
    (what GPUs run) are one kernel source: every lane width of the device's chain
    (conftest.vector_widths) gives the same bits."""
    p = medium(**{**SCATTERING, "texture": texture})
    n = 20_000
    widths = vector_widths(engine, precision)
    reference = engine.run(p, n, precision=precision, lanes=1, qualified=True)
    for lanes in widths:
        other = engine.run(p, n, precision=precision, lanes=lanes, qualified=True)
        assert other.same_as(reference), lanes


BUDGET_CASES = [pytest.param(mode, texture, form, marks=() if fast else pytest.mark.slow)
                for mode, texture, form, fast in (
                    ("analog", "slab", "vector", True), ("weighted", "granular", "scalar", True),
                    ("weighted", "slab", "vector", False),
                    ("analog", "granular", "vector", False),
                    ("analog", "slab", "scalar", False), ("weighted", "slab", "scalar", False),
                    ("analog", "granular", "scalar", False),
                    ("weighted", "granular", "vector", False))]
#: the event budget of the long case, and the launches it must take at least
BUDGET, MIN_LAUNCHES = 29, 4


def budget_photons(engine, lanes: int, events_per_ray: float, budget: int = BUDGET,
                   launches: int = MIN_LAUNCHES) -> int:
    """Rays enough that a walk on an event budget of ``budget`` takes at least ``launches``
    launches on this device, whatever its launch size.

    A launch runs at most ``engine.default_global_size()`` work-items of ``lanes`` lanes, each
    for at most ``budget`` steps of one event per lane (cl/walk.cl), so it walks at most
    ``global_size * lanes * budget`` scattering events; a walk of ``n`` rays of
    ``events_per_ray`` scattering events each takes at least
    ``n * events_per_ray / (global_size * lanes * budget)`` launches. On a 2-core CPU (32
    work-items of 16 lanes) that is 3000 rays, on a GPU (2^20 work-items of 1 lane, issue 43)
    millions.

    Parameters
    ----------
    engine : warpe_cl.engine.Engine
    lanes : int
        Photons per work-item of the walk.
    events_per_ray : float
        Mean scattering events per ray of the medium (measured on a short walk), > 0.
    budget : int
        Events per work-item and launch.
    launches : int
        Launches wanted at least.

    Returns
    -------
    int
        Rays, at least 3000 (the reference walk's check), with 25 % to spare for the
        statistical error of ``events_per_ray``.
    """
    per_launch = engine.default_global_size() * lanes * budget
    return max(3000, int(np.ceil(1.25 * launches * per_launch / events_per_ray)))


@pytest.mark.parametrize("mode, texture, form", BUDGET_CASES)
def test_counts_and_rays_do_not_depend_on_the_event_budget(engine, mode, texture, form):
    """A launch stops each work-item after event_budget events and parks its unfinished rays;
    the next launch resumes them (docs/walk.md §5). Whatever the budget, down to one event per
    launch (every ray parked after each event: its position, direction, path, counters,
    phase, weight and event block carried), every tally and every ray's record is the same
    bits as one unbounded launch; the slab has a vacuum gap, so rays are parked in it too.
    The unbounded launch itself follows the NumPy reference ray for ray (qualification's own
    check of this lane width, warpe_cl.qualify.compare_records). The long case has rays
    enough for more than 3 launches at this device's launch size (budget_photons), and the
    lanes are the device's own (conftest.lanes_of)."""
    lanes = lanes_of(engine, form, "double")
    p = medium(**{**SCATTERING, "texture": texture, "mode": mode})
    unbounded = dict(precision="double", lanes=lanes, records=True, event_budget=2 ** 32 - 1,
                     qualified=True)
    short = engine.run(p, 300, **unbounded)
    assert short.scattering_events > 0
    many = budget_photons(engine, lanes, short.scattering_events / 300)
    checked = engine.run(p, 3000, **unbounded)
    walk = simulate_reference(p, 3000, records=True)
    assert compare_records(checked, walk, "double", mode == "weighted") is None
    for n, budgets in ((300, (1, 3)), (many, (BUDGET,))):
        reference = {300: short, 3000: checked}.get(n) or engine.run(p, n, **unbounded)
        for budget in budgets:
            launches = []
            other = engine.run(p, n, precision="double", lanes=lanes, records=True,
                               event_budget=budget, progress=launches.append, qualified=True)
            assert other.same_as(reference), budget
            assert len(launches) >= MIN_LAUNCHES and launches[-1] == n, launches[:5]
            # the engine's own account of the launches (what tools/bench/bench.py reports)
            log = engine.last_launches
            assert len(log) == len(launches) and sum(x["photons"] for x in log) == n
            assert {x["event_budget"] for x in log} == {budget} and log[-1]["parked"] == 0
            assert all(x["seconds"] > 0 for x in log)
            for field, value in reference.records.items():
                assert np.array_equal(other.records[field], value, equal_nan=True), field


def test_split_runs_add_up_to_the_whole(engine):
    p = medium(**SCATTERING)
    whole = engine.run(p, 50_000)
    part = engine.run(p, 12_345)
    part += engine.run(p, 50_000 - 12_345, first_photon=12_345)
    assert part.same_as(whole)


def test_seed_and_scenario_change_the_streams(engine):
    a = engine.run(medium(**SCATTERING, seed=1), 20_000)
    b = engine.run(medium(**SCATTERING, seed=2), 20_000)
    c = engine.run(medium(**SCATTERING, seed=1, scenario=5), 20_000)
    assert not a.same_as(b) and not a.same_as(c)


def test_scenario_key_is_deterministic_and_grid_independent():
    cfg = load_preset({"medium": {"texture": "slab", "thickness": "10 mm",
                                  "radiative": {"tau0": 1.0, "omega": 0.5, "n": 1.3}},
                       "sweep": {"medium.thickness": ["1 mm", "10 mm"]}})
    keys = [scenario_key(point, pcfg) for point, pcfg in cfg.sweep_points()]
    assert len(set(keys)) == 2
    other = load_preset({"medium": {"texture": "slab", "thickness": "10 mm",
                                    "radiative": {"tau0": 1.0, "omega": 0.5, "n": 1.3}},
                         "sweep": {"medium.thickness": ["10 mm", "0.001 m", "5 mm"]}})
    other_keys = {str(pcfg.get("medium.thickness")): scenario_key(point, pcfg)
                  for point, pcfg in other.sweep_points()}
    assert other_keys["0.001"] == keys[0] and other_keys["0.01"] == keys[1]


def test_lane_width_from_the_environment(monkeypatch):
    from warpe_cl.engine import default_lanes
    from warpe_cl.errors import ConfigError
    monkeypatch.setenv("WARPE_CL_LANES", "4")
    assert default_lanes("cpu", "single") == 4 and default_lanes("gpu", "double") == 4
    monkeypatch.setenv("WARPE_CL_LANES", "3")
    with pytest.raises(ConfigError, match="WARPE_CL_LANES"):
        default_lanes("cpu", "single")
    monkeypatch.delenv("WARPE_CL_LANES")
    assert default_lanes("cpu", "single") == 16 and default_lanes("gpu", "single") == 1


def test_reusing_walks_walks_a_repeated_scenario_once(monkeypatch):
    """Inside ``reusing_walks`` a walk that repeats one already made (same walk parameters,
    seed, scenario key, photons, precision) reuses its counts, the same bits as walking it
    again; another photon count, or another scenario key, walks; outside the block nothing is
    kept."""
    import warpe_cl
    from warpe_cl import api
    engine = api.get_engine("numpy")
    walked = []
    run = engine.run

    def spy(params, photons, **kw):
        walked.append((params.scenario, photons))
        return run(params, photons, **kw)

    monkeypatch.setattr(engine, "run", spy)
    cfg = load_preset("radiative/slab_co2_1m", overrides={"simulation.photons": 300,
                                                          "medium.bottom_interface": "none"})

    def simulate(c):
        return warpe_cl.simulate(c, device="numpy", progress=False)

    fresh = simulate(cfg)
    with api.reusing_walks():
        first = simulate(cfg)
        again = simulate(cfg)
        simulate(cfg.with_overrides({"simulation.photons": 301}))
        simulate(cfg.with_overrides({"simulation.seed": 2}))
    simulate(cfg)
    assert len(walked) == 5                    # fresh, first, 301 photons, seed 2, last
    for name in ("reflectance", "ray_count", "nadir_reflectance", "fraction"):
        np.testing.assert_array_equal(again[name].values, first[name].values)
        np.testing.assert_array_equal(fresh[name].values, first[name].values)
    assert api._walks is None
