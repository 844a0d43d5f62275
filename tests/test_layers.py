"""The layered walk on the OpenCL kernel (docs/walk.md §7, docs/physics.md §11).

Every Monte Carlo assertion states its tolerance next to it: 5 standard errors of a binomial
count (conftest.binomial_sigma), or a two-sample chi-square at the 5-sigma level.
"""
from __future__ import annotations

import numpy as np
import pytest

from conftest import LOG_EDGES, binomial_sigma
from warpe_cl.engine import STATS_PARTS
from warpe_cl.params import C_M_PER_NS, FATES, Layer, WalkParams, stack_params

SINGLE = {   # one medium and the bottom it sits on: each path of the single-layer kernels
    "slab_gap": (Layer("slab", 0.01, 100.0, 0.9, 0.8, 1.3, 1e-4), "fresnel"),
    "slab_contact": (Layer("slab", 0.01, 50.0, 0.97, 0.6, 1.45, 0.0), "none"),
    "granular": (Layer("granular", 0.01, 200.0, 0.95, 0.5, 1.36, 0.0), "fresnel"),
}


def run(engine, params, photons, **kw):
    return engine.run(params, photons, qualified=True, **kw)


def two_sample_chi2(a, b) -> tuple:
    """chi2 = sum (a - b)^2 / (a + b) over the cells with a + b > 0 and its degrees of freedom:
    for two Poisson counts of the same mean, each term is ~chi2(1). The 5-sigma bound is
    dof + 5 sqrt(2 dof) (the chi2(dof) mean plus 5 of its standard deviations)."""
    a, b = np.asarray(a, float).ravel(), np.asarray(b, float).ravel()
    keep = (a + b) > 0
    chi2 = float(np.sum((a[keep] - b[keep]) ** 2 / (a[keep] + b[keep])))
    return chi2, int(keep.sum())


def assert_same_distribution(x, y, what):
    chi2, dof = two_sample_chi2(x, y)
    bound = dof + 5.0 * np.sqrt(2.0 * dof)          # 5 sigma of chi2(dof)
    assert chi2 <= bound, f"{what}: chi2 = {chi2:.1f} over {dof} cells > {bound:.1f}"


@pytest.mark.parametrize("name", sorted(SINGLE))
@pytest.mark.parametrize("precision", ["single", "double"])
def test_one_layer_stack_is_the_single_layer_walk(engine, name, precision):
    """With one layer §7 reduces to §3 event for event (docs/walk.md §7.1): the layered build
    walks every ray exactly as the slab or granular build, at 1 lane and at the device's
    widest vector width where it has one (conftest.scalar_and_vector)."""
    from conftest import scalar_and_vector
    layer, bottom = SINGLE[name]
    common = dict(albedo=0.5, time_edges=LOG_EDGES, seed=7, bottom_interface=bottom)
    single = WalkParams(texture=layer.texture, thickness=layer.thickness,
                        extinction=layer.extinction, omega=layer.omega, g=layer.g, n=layer.n,
                        k=layer.k, **common)
    stack = stack_params([layer], **common)
    for lanes in scalar_and_vector(engine, precision):
        a = run(engine, single, 3000, precision=precision, records=True, lanes=lanes)
        b = run(engine, stack, 3000, precision=precision, records=True, lanes=lanes)
        for field in a.records:
            if field == "layer":
                continue
            np.testing.assert_array_equal(a.records[field], b.records[field], err_msg=field)
        for tally in ("fates", "total", "time_any", "time_in_fov", "angular", "early"):
            np.testing.assert_array_equal(getattr(a, tally), getattr(b, tally))


def r_normal(a: float, b: float) -> float:
    """Fresnel reflectance at normal incidence between real indices a and b."""
    return ((a - b) / (a + b)) ** 2


def test_exact_direct_echoes_of_two_slabs(engine):
    """docs/physics.md §11.4: without scattering (omega = 0) the rays stay vertical and
    each echo's fraction is a product of Fresnel factors and exp(-2 tau) terms; h n of the two
    slabs are incommensurate, so each echo has its own time bin. 5 sigma of the binomial."""
    n0, n1, h0, h1, e0, e1 = 1.3, 1.6, 0.01, 0.0137, 5.0, 8.0
    edges = np.linspace(0.0, 0.5, 2001)        # 0.25 ps bins
    stack = stack_params([Layer("slab", h0, e0, 0.0, 0.0, n0), Layer("slab", h1, e1, 0.0, 0.0, n1)],
                         albedo=0.0, time_edges=edges, seed=3, bottom_interface="fresnel")
    photons = 400_000
    counts = run(engine, stack, photons, precision="double")
    r01, r12, r1v = r_normal(1.0, n0), r_normal(n0, n1), r_normal(n1, 1.0)
    t0, t1 = np.exp(-e0 * h0), np.exp(-e1 * h1)
    leg0, leg1 = 2 * h0 * n0 / C_M_PER_NS, 2 * h1 * n1 / C_M_PER_NS
    echoes = {
        "interface 1": (leg0, (1 - r01) ** 2 * r12 * t0 ** 2),
        "bottom over the gap": (leg0 + leg1, (1 - r01) ** 2 * (1 - r12) ** 2 * r1v
                                * t0 ** 2 * t1 ** 2),
        "twice in slab 0": (2 * leg0, (1 - r01) ** 2 * r12 ** 2 * r01 * t0 ** 4),
    }
    direct = counts.time_any[1]
    for name, (t, p) in echoes.items():
        i = int(np.searchsorted(edges, t)) - 1
        got = direct[i - 1:i + 2].sum() / photons
        assert abs(got - p) <= 5 * binomial_sigma(p, photons), (name, got, p)
    assert abs(counts.fates[0] / photons - r01) <= 5 * binomial_sigma(r01, photons)


@pytest.mark.parametrize("texture", ["granular", "slab"])
def test_two_identical_layers_are_one(engine, texture):
    """docs/physics.md §11.5: the contact between equal faces is transparent; time and
    angular histograms of the split layer and of the whole one agree (two-sample chi2, 5 sigma)."""
    whole = Layer(texture, 0.02, 150.0, 0.97, 0.6, 1.31, 1e-5)
    half = Layer(texture, 0.01, 150.0, 0.97, 0.6, 1.31, 1e-5)
    common = dict(albedo=0.5, time_edges=LOG_EDGES, bottom_interface="fresnel")
    one = run(engine, stack_params([whole], seed=1, **common), 100_000)
    two = run(engine, stack_params([half, half], seed=2, **common), 100_000)
    assert_same_distribution(one.time_any, two.time_any, "time")
    assert_same_distribution(one.angular, two.angular, "angular")
    assert_same_distribution(one.fates, two.fates, "fates")


def test_transparent_layer_of_no_extinction_only_delays(engine):
    """docs/physics.md §11.5: a tau = 0 layer with the face of the slab under it adds path
    and nothing else: the same fractions and angles (chi2, 5 sigma), and the bf_direct rays of
    a non-scattering slab, which stay vertical, arrive exactly 2 h n / c later."""
    ice = Layer("slab", 0.01, 30.0, 0.0, 0.0, 1.31, 0.0)
    clear = Layer("slab", 0.004, 0.0, 1.0, 0.0, 1.31, 0.0)
    edges = np.linspace(0.0, 0.5, 2001)
    common = dict(albedo=0.0, time_edges=edges, bottom_interface="fresnel")
    bare = run(engine, stack_params([ice], seed=1, **common), 100_000, precision="double")
    covered = run(engine, stack_params([clear, ice], seed=2, **common), 100_000,
                  precision="double")
    assert_same_distribution(bare.fates, covered.fates, "fates")
    assert_same_distribution(bare.angular, covered.angular, "angular")
    shift = 2 * 0.004 * 1.31 / C_M_PER_NS
    t_bare = 2 * 0.01 * 1.31 / C_M_PER_NS
    i, j = (int(np.searchsorted(edges, t)) - 1 for t in (t_bare, t_bare + shift))
    assert bare.time_any[1, i] > 0 and covered.time_any[1, i] == 0
    assert_same_distribution(bare.time_any[1, i - 1:i + 2], covered.time_any[1, j - 1:j + 2],
                             "the first echo, shifted")


def test_per_layer_statistics_close_ray_by_ray(engine):
    """docs/walk.md §7.4: what enters a layer leaves it, or is absorbed or stopped in it;
    the gap's entries are its exits and the floor's absorptions; entries at the top are the
    rays that were not specular, exits the escaped ones. Exact integers."""
    layers = [Layer("slab", 0.003, 200.0, 0.95, 0.7, 1.31, 1e-5),
              Layer("granular", 0.004, 300.0, 0.99, 0.4, 1.36),
              Layer("slab", 0.005, 100.0, 0.9, 0.8, 1.6, 1e-3)]
    params = stack_params(layers, substrate=(1.7, 1e-3), albedo=0.5, time_edges=LOG_EDGES,
                          seed=5, max_time=1.0)
    counts = run(engine, params, 20_000)
    v = counts.layer_view(3)
    fates = dict(zip(FATES, counts.fates))
    assert v["down"][0] == counts.photons - fates["specular"]
    assert v["up"][0] == fates["escaped"]
    assert v["absorbed"].sum() == fates["absorbed_medium"]
    assert v["terminated"].sum() == fates["terminated"] > 0      # max_time stops some
    for i in range(3):
        into = v["down"][i] + v["up"][i + 1]
        out = v["up"][i] + v["down"][i + 1] + v["absorbed"][i] + v["terminated"][i]
        assert into == out, (i, into, out)
    assert v["down"][3] == v["up"][3] + fates["absorbed_floor"]


def test_layered_walk_is_reproducible_across_lanes_and_budgets(engine):
    """docs/walk.md §5: the same bits for every lane width and event budget (rays parked with
    their layer and resumed), at the widths of the device's chain (conftest.lane_chain): the
    widest, a narrower one with a short budget and one lane."""
    from conftest import lane_chain
    layers = [Layer("granular", 0.003, 400.0, 0.98, 0.6, 1.2),
              Layer("slab", 0.004, 250.0, 0.95, 0.2, 1.4, 1e-4)]
    params = stack_params(layers, substrate=(1.7, 1e-3), albedo=0.6, time_edges=LOG_EDGES,
                          seed=9)
    chain = lane_chain(engine)
    wide, narrow = chain[0], chain[min(2, len(chain) - 1)]    # 16 and 4 on a CPU, 1 on a GPU
    ref = run(engine, params, 6000, lanes=wide)
    for kw in (dict(lanes=1), dict(lanes=narrow, event_budget=3),
               dict(lanes=wide, event_budget=29),
               # more work-items than engine.STATS_PARTS: the per-layer statistics (and the
               # fates) folded on the device before they are read
               dict(lanes=1, global_size=STATS_PARTS + 7, event_budget=3)):
        assert run(engine, params, 6000, **kw).same_as(ref), kw


@pytest.mark.parametrize("precision", ["double", "single"])
def test_kernel_follows_the_reference_ray_for_ray(engine, precision):
    """The qualification stacks (warpe_cl/qualify.py: every contact of docs/walk.md §7) walked
    by the kernel and by the NumPy reference: in double precision every ray's record is the
    same (times and cosines to 1e-9), in single at least 99.5 % of the histories
    (qualify.compare_records)."""
    from warpe_cl.qualify import Combo, _scenes, compare_records
    from warpe_cl.reference import simulate_reference
    for name, params in _scenes(Combo("layers", precision, False)).items():
        ker = run(engine, params, 2000, precision=precision, records=True)
        ref = simulate_reference(params, 2000, records=True)
        assert compare_records(ker, ref, precision, False) is None, name
        if precision == "double":
            np.testing.assert_array_equal(ker.layer_stats, ref.layer_stats, err_msg=name)


def test_result_has_the_layers_of_its_configuration():
    """A stack's result (warpe_cl/stack.py): one entry per configured layer, the zero-thickness
    one included with no absorption and the echo of the layer above; the layers' absorptions
    sum to the medium's; echo_time is 2 sum h n / c; the walk of the stack without the empty
    layer is the same walk (the same WalkParams)."""
    import warpe_cl
    from warpe_cl.api import walk_params
    cfg = warpe_cl.load_preset("layers/frost_over_ice", overrides={
        "simulation.photons": 2000, "sweep": None})
    empty = warpe_cl.load_preset("layers/frost_over_ice", overrides={
        "simulation.photons": 2000, "sweep": None, "medium.layers[0].thickness": "0 mm"})
    ds = warpe_cl.simulate(empty, device="auto", progress=False)
    assert list(ds["layer_texture"].values) == ["granular", "slab"]
    assert ds["layer_fate_fraction"].values[0] == 0.0
    absorbed = ds["fate_fraction"].sel(fate="absorbed_medium").item()
    assert ds["layer_fate_fraction"].values.sum() == pytest.approx(absorbed, rel=1e-12)
    n_ice = ds["layer_n_eff"].values[1]
    assert ds["echo_time"].values == pytest.approx([0.0, 2 * 1.0 * n_ice / C_M_PER_NS])
    bare = warpe_cl.load_preset({"medium": {
        "texture": "slab", "thickness": "1000 mm", "compacity": 0.95, "matrix": "H2O",
        "inclusions": [{"material": "void", "proportion": 1.0, "grain_size": "200 um"}],
        "bottom_albedo": 0.15, "phase_g": 0.8, "substrate": {"n": 1.0, "k": 0.0}}})
    assert walk_params(empty)[0].layers == walk_params(bare)[0].layers
    full = warpe_cl.simulate(cfg, device="auto", progress=False)
    assert full["layer_fate_fraction"].values.sum() == pytest.approx(
        full["fate_fraction"].sel(fate="absorbed_medium").item(), rel=1e-12)
    # the first back-and-forth time of a stack is its floor's echo (docs/walk.md §7.2)
    assert full.attrs["first_bf_time_ns"] == pytest.approx(full["echo_time"].values[-1],
                                                            rel=1e-12)
