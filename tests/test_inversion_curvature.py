"""The curvature correction of the database's interpolation (warpe_cl/inversion/space.py,
docs/inversion.md §2).

Between nodes the response is the multilinear (displacement) interpolation plus, along every
axis of three values or more, the leave-one-out curvature term g (node m − its prediction
from m ± 1). For anything the interpolation combines linearly (the specular and
back-and-forth fractions) this is quadratic interpolation: exact for a fraction quadratic in
the axis' coordinate, on any spacing. Without it the interpolation of a convex response errs
with one sign everywhere in the cell, and at 1000 BELA shots that bias pulled the thickness of
granular CO2 0.025 dex high and left its 68 % interval holding the truth in half the cases.

The databases here are synthetic (tests/conftest.py): fractions as ray counts of 1e6 rays,
so a fraction is exact to 1e-6. No Monte Carlo.
"""
from __future__ import annotations

import numpy as np
import pytest

from conftest import sweep_of, synthetic_surface
from warpe_cl.inversion.space import Space

KEY = "medium.thickness"
PHOTONS = 10 ** 6


def quadratic(u):
    """A specular fraction quadratic in the ln-thickness coordinate u."""
    return 0.2 + 0.05 * u + 0.1 * u ** 2


def space_over(thicknesses):
    """A database of specular-only surfaces whose fraction is :func:`quadratic` of ln h."""
    hs = np.asarray(thicknesses, float)
    parts = [synthetic_surface(f_spec=quadratic(np.log(h)), photons=PHOTONS) for h in hs]
    space = Space(sweep_of(parts, hs, KEY))
    assert space.axes[0].log                      # the coordinate is ln h
    return space


def specular(surface) -> float:
    return sum(f for c, _, f in surface.returns if c == "specular")


GRIDS = {"even": (0.5, 1.0, 2.0), "uneven": (0.1, 1.0, 3.0), "four": (0.5, 1.0, 2.0, 4.0)}


@pytest.mark.parametrize("grid, h", [(g, h) for g, hs in (("even", (0.62, 0.9, 1.41, 1.9)),
                                                         ("uneven", (0.2, 0.62, 1.41, 2.5)),
                                                         ("four", (0.62, 1.41, 1.9, 3.1)))
                                     for h in hs])
def test_a_quadratic_fraction_is_interpolated_exactly(grid, h):
    """Evenly and unevenly spaced nodes, three and four of them: the fraction at an off-node
    thickness is the quadratic's to the ray counts' rounding (1e-6), where the multilinear
    interpolation alone is off by up to 0.012."""
    space = space_over(GRIDS[grid])
    assert specular(space.surface({KEY: h})) == pytest.approx(quadratic(np.log(h)), abs=2e-6)


def test_without_the_correction_the_same_point_is_off():
    """The check above can fail: the multilinear part alone misses the quadratic at 1.41 m by
    ½ c Δ² f (1 − f) = 0.012 (c = 0.2 the quadratic's second derivative, Δ = ln 2)."""
    space = space_over((0.5, 1.0, 2.0))
    u = np.log(1.41)
    x = space.axes[0].nodes
    f = (u - x[1]) / (x[2] - x[1])
    linear = (1 - f) * quadratic(x[1]) + f * quadratic(x[2])
    assert linear - quadratic(u) == pytest.approx(0.5 * 0.2 * (x[2] - x[1]) ** 2 * f * (1 - f),
                                                  rel=1e-9)
    assert abs(linear - quadratic(u)) > 0.01
    assert abs(specular(space.surface({KEY: 1.41})) - linear) > 0.01


@pytest.mark.parametrize("h", [0.3, 1.3, 2.5])
def test_node_weights_are_the_quadratic_lagrange_weights(h):
    """The nodes' weights in a response (what their Monte Carlo errors are carried by) are
    those of the quadratic through the three nodes, on uneven nodes too."""
    space = space_over(GRIDS["uneven"])
    x = space.axes[0].nodes
    u = np.log(h)
    lagrange = [np.prod([(u - x[j]) / (x[i] - x[j]) for j in range(3) if j != i])
                for i in range(3)]
    weights = space.node_weights({KEY: h})
    assert [weights.get((i,), 0.0) for i in range(3)] == pytest.approx(lagrange, abs=1e-12)


def test_the_nodes_are_untouched():
    """At a node the response is the node's own: no curvature term."""
    space = space_over((0.5, 1.0, 2.0))
    assert space.bends({KEY: 1.0}) == []
    assert specular(space.surface({KEY: 1.0})) == pytest.approx(quadratic(0.0), abs=1e-12)


# The diffuse total along an axis, in the coordinate that axis' nodes call for (space.py's
# total_scale): a floor's albedo A enters a slab's total almost in proportion.

ALBEDO = "medium.bottom_albedo"
ALBEDOS = (0.05, 0.15, 0.3, 0.45)             # the rough-slab study's floor albedos


def total_of(surface) -> float:
    return float(np.sum(surface.diffuse * np.diff(surface.edges)))


def albedo_space(total):
    """Diffuse-only surfaces of total ``total(A)`` (sr⁻¹) over ALBEDOS, the same shape at
    every node."""
    parts = [synthetic_surface(diffuse_integral=total(a)) for a in ALBEDOS]
    return Space(sweep_of(parts, ALBEDOS, ALBEDO, units="1"))


@pytest.mark.parametrize("a", [0.08, 0.1, 0.2, 0.4])
def test_a_total_in_proportion_to_the_albedo_is_interpolated_exactly(a):
    """A total proportional to A is combined linearly along the albedo and comes back exact
    (to float rounding) between nodes. In ln, even after the curvature term, it came back
    5.5 % low at A = 0.1 (the geometric mean of 0.05 and 0.15, 0.087, plus a sixth of node
    0.15's miss from 0.05 and 0.3, 0.048) and 1.3 % high at 0.2: what the rough-slab
    database gave against direct simulations (docs/inversion.md §2)."""
    space = albedo_space(lambda x: 0.3 * x)
    assert space.total_scales == ["linear"]
    assert total_of(space.surface({ALBEDO: a})) == pytest.approx(0.3 * a, rel=1e-9)


def test_the_total_coordinate_is_chosen_per_axis():
    """Along a thickness whose totals fall as a power of it the total is combined in ln,
    along the albedo of the same grid linearly: a total ∝ A h^(−0.7) comes back exact
    anywhere in the grid, where combining it in ln along both was 4.8 % low at (0.5 m, 0.1)."""
    rows = [(h, a) for h in (0.1, 0.3, 1.0) for a in ALBEDOS]

    def total(h, a):
        return a * h ** -0.7
    db = sweep_of([synthetic_surface(diffuse_integral=total(h, a)) for h, a in rows],
                  [h for h, _ in rows], KEY)
    space = Space(db.assign_coords({ALBEDO: ("scenario", [a for _, a in rows],
                                             {"sweep_key": ALBEDO, "units": "1"})}))
    assert space.total_scales == ["log", "linear"]
    for h, a in ((0.5, 0.1), (0.2, 0.35), (0.3, 0.1)):
        assert total_of(space.surface({KEY: h, ALBEDO: a})) == pytest.approx(total(h, a),
                                                                             rel=1e-9)


def test_a_total_falling_by_factors_keeps_the_log():
    """Totals 1e-4 ... 1e-1 by factors of ten across the albedo nodes: ln is kept, and the
    total halfway in ln between two nodes is their geometric mean."""
    values = dict(zip(ALBEDOS, (1e-4, 1e-3, 1e-2, 1e-1)))
    space = albedo_space(values.get)
    assert space.total_scales == ["log"]
    x = space.axes[0].nodes
    middle = {ALBEDO: 0.5 * (x[1] + x[2])}
    assert space.total(middle, bends=[]) == pytest.approx(np.sqrt(1e-5), rel=1e-12)


def test_the_totals_curvature_is_taken_in_its_coordinate():
    """With its curvature terms, a total combined in ln is the nodes' totals combined in ln
    with the nodes' Lagrange weights (:meth:`Space.node_weights`). Combined linearly with
    those weights, totals falling by factors of ten come out negative halfway between the
    middle nodes."""
    values = dict(zip(ALBEDOS, (1e-4, 1e-3, 1e-2, 1e-1)))
    space = albedo_space(values.get)
    x = space.axes[0].nodes
    point = {ALBEDO: 0.5 * (x[1] + x[2])}
    weights = space.node_weights(point)
    in_ln = np.exp(sum(w * np.log(values[ALBEDOS[i[0]]]) for i, w in weights.items()))
    linear = sum(w * values[ALBEDOS[i[0]]] for i, w in weights.items())
    assert space.total(point) == pytest.approx(in_ln, rel=1e-12)
    assert linear < 0.0


# A response that moves in time as a whole: its curvature is taken in ln t(q), where the
# interpolation combines its shape, and lands where the point's response is.

FINE = 1e-6 * 10 ** (np.arange(0, 2201) / 200)      # 200 bins per decade


def box_end(h):
    """T(h) = 5 exp(0.5 u + 0.3 u²) ns, u = ln h: ln T quadratic in the coordinate."""
    u = np.log(h)
    return 5.0 * np.exp(0.5 * u + 0.3 * u * u)


def box(h):
    """A diffuse response uniform over (0, T(h)] ns, 0.05 sr⁻¹ in all."""
    ds = synthetic_surface(diffuse_integral=0.05, edges=FINE)
    overlap = np.clip(np.minimum(FINE[1:], box_end(h)) - FINE[:-1], 0.0, None)
    ds["reflectance"][3] = 0.05 * overlap / box_end(h) / np.diff(FINE)
    return ds


@pytest.mark.parametrize("h", [1.4, 2.8])
def test_a_response_moving_in_time_is_interpolated_where_it_is(h):
    """Boxes ending at T(h) at h = 1, 2, 4: between them the response ends at T(h) and its
    median is T(h)/2, each to the 1.2 % of a time bin. Its curvature term taken in the
    density (node 2's box less its prediction, added where node 2's edges are) put 2.4 % of
    the amount beyond T(1.4) = 6.1 ns and 1.4 % beyond T(2.8) = 11.5 ns: tails the
    point's response does not have."""
    space = Space(sweep_of([box(x) for x in (1.0, 2.0, 4.0)], np.array([1.0, 2.0, 4.0]), KEY))
    r = space.surface({KEY: h})
    amount = r.diffuse * np.diff(r.edges)
    cdf = np.concatenate([[0.0], np.cumsum(amount)]) / amount.sum()
    step = 10 ** (1 / 200)                          # one bin's ratio of edges
    assert amount.sum() == pytest.approx(0.05, rel=1e-6)
    assert amount[r.edges[:-1] >= box_end(h) * step].sum() == 0.0
    assert amount[r.edges[1:] > box_end(h) / step].sum() > 0.0
    median = np.interp(0.5, cdf, r.edges)
    assert median == pytest.approx(box_end(h) / 2, rel=step - 1)


def test_quantiles_moved_past_the_last_edge_keep_the_amount():
    """Boxes ending at 1e3, 1e5 and 1e5 ns (the last time edge) at h = 1, 2, 4: the curvature
    term carries the point's quantiles past the last edge, and they are held on it, the whole
    amount kept. Left past it, 44 % of the amount was lost at h = 2.8."""
    def box_to(end):
        ds = synthetic_surface(diffuse_integral=0.05, edges=FINE)
        overlap = np.clip(np.minimum(FINE[1:], end) - FINE[:-1], 0.0, None)
        ds["reflectance"][3] = 0.05 * overlap / end / np.diff(FINE)
        return ds
    space = Space(sweep_of([box_to(x) for x in (1e3, 1e5, 1e5)], np.array([1.0, 2.0, 4.0]),
                           KEY))
    for h in (1.4, 2.8):
        r = space.surface({KEY: h})
        assert float(np.sum(r.diffuse * np.diff(r.edges))) == pytest.approx(0.05, rel=1e-9)


def test_a_node_without_a_diffuse_response_bends_no_shape():
    """Node 1 has no diffuse return (a specular one only), nodes 2 and 4 exponential decays of
    2 and 4 ns. Between 2 and 4 the curvature term, whose nodes include node 1, bends the
    total (the quadratic through the totals 0, 0.05, 0.05: 0.05625 at 2√2, combined
    linearly since one is 0) but not the shape: the decay is the corners' geometric
    τ = 2√2 ns, its median τ ln 2 to the binning (1 %; a bin-wide error of the CDF's
    curvature is 0.1 %). Before, the whole cell fell back to summing densities, and the
    median came 12 % early."""
    def decay(tau, amount):
        return synthetic_surface(diffuse_integral=amount, tau=tau, f_spec=0.1)
    space = Space(sweep_of([decay(1.0, 0.0), decay(2.0, 0.05), decay(4.0, 0.05)],
                           np.array([1.0, 2.0, 4.0]), KEY))
    r = space.surface({KEY: 2.0 * np.sqrt(2.0)})
    amount = r.diffuse * np.diff(r.edges)
    cdf = np.concatenate([[0.0], np.cumsum(amount)]) / amount.sum()
    median = np.interp(0.5, cdf, r.edges)
    assert median == pytest.approx(2.0 * np.sqrt(2.0) * np.log(2.0), rel=0.01)
    assert amount.sum() == pytest.approx(0.05625, rel=1e-9)


def test_a_passage_missing_at_a_corner_takes_the_other_corners_delay():
    """Echoes at 10 ns (node 1) and 40 ns (node 4), none at node 2 and no known round trips:
    in the cell [2, 4] the echo's delay is node 4's, the one corner that has it (node 2, with
    neither the echo nor a round trip, has no delay to give; its share of the fraction is 0
    there). Averaged over every node of the curvature terms, node 1's 10 ns outside the cell
    made it 26.5 ns."""
    parts = [synthetic_surface(diffuse_integral=0.05, tau=1.0, f_spec=0.02, f_bf=fb, t_bf=tb)
             for fb, tb in ((0.01, 10.0), (0.0, 20.0), (0.01, 40.0))]
    space = Space(sweep_of(parts, np.array([1.0, 2.0, 4.0]), KEY))
    assert all(not np.isfinite(n.first_bf) for n in space.nodes)
    delays = [t for c, t, _ in space.surface({KEY: 2.2}).returns if c == "bf_direct"]
    assert delays == [pytest.approx(40.0)]


def test_quantiles_held_on_the_first_edge_keep_the_amount():
    """Decays of 1, 3 and 30 ns at h = 1, 2, 4 on time edges that start at 1 ns (not near 0):
    at h = 1.2 (node weights 0.64, 0.46, −0.10) the combined quantiles fall below the first
    edge and are held on it, the whole amount kept. Held in ln t, exp(ln 1) rounded back onto
    the edge and np.interp gave the first edge the last of them: 3.3 % of the amount lost."""
    edges = 10 ** (np.arange(0, 101) / 20)              # 1 ns to 1e5 ns, 20 per decade
    parts = [synthetic_surface(diffuse_integral=0.05, tau=tau, edges=edges)
             for tau in (1.0, 3.0, 30.0)]
    space = Space(sweep_of(parts, np.array([1.0, 2.0, 4.0]), KEY))
    r = space.surface({KEY: 1.2})
    expected = space.total({KEY: 1.2})
    assert float(np.sum(r.diffuse * np.diff(r.edges))) == pytest.approx(expected, rel=1e-9)


def spike(h, share):
    """A slab floor's diffuse return: ``share`` of 0.05 sr⁻¹ in the bin of the round trip
    t = 9.357 h ns, the rest in the bin of twice that (the second passage)."""
    ds = synthetic_surface(diffuse_integral=0.05, edges=FINE)
    amount = np.zeros(FINE.size - 1)
    for t, part in ((9.357 * h, share), (2 * 9.357 * h, 1.0 - share)):
        amount[np.searchsorted(FINE, t) - 1] += 0.05 * part
    ds["reflectance"][3] = amount / np.diff(FINE)
    return ds


@pytest.mark.parametrize("h", [1.2, 2.2, 2.94])
def test_a_spike_stays_at_its_round_trip_where_quantiles_cross(h):
    """Floor returns holding 97.5 to 99.1 % of the amount in the bin of their round trip, at
    h = 1, 1.78, 3.16 m (the rough slabs' nodes): the point's spike lies in the bin of its
    round trip 9.357 h ns, to one bin (1.2 %). Where a node of negative weight leaves its
    spike for its second passage before the others, ln t(q) dips and crosses itself; the
    rearrangement sorted the quantile knots as if each held the same amount, and put the 97
    % of the spike, the span of one knot interval, where the dip was: at 2.94 m 5.3 % early,
    more than four bins (as it read the slabs' thickness 0.36 % high)."""
    hs = np.array([1.0, 1.78, 3.16])
    space = Space(sweep_of([spike(x, s) for x, s in zip(hs, (0.975, 0.991, 0.983))], hs, KEY))
    r = space.surface({KEY: h})
    amount = r.diffuse * np.diff(r.edges)
    cdf = np.concatenate([[0.0], np.cumsum(amount)]) / amount.sum()
    median = np.interp(0.5, cdf, r.edges)
    step = 10 ** (1 / 200)
    assert median == pytest.approx(9.357 * h, rel=step - 1)
    assert amount.sum() == pytest.approx(space.total({KEY: h}), rel=1e-9)


def test_the_rearranged_cdf_is_that_of_t_of_a_uniform_q():
    """rearranged_cdf against the empirical CDF of t(Q) on 2e6 evenly spaced q (t linear in
    q between the knots): a function that rises, dips and rises again, with knot intervals
    of very different lengths, and a flat stretch (a jump of the CDF). The grid's own error
    is 1e-6; a monotone t gives np.interp's CDF."""
    from warpe_cl.inversion.space import rearranged_cdf
    q = np.array([0.0, 0.9, 0.91, 0.95, 0.96, 0.97, 1.0])
    t = np.array([10.0, 12.0, 9.0, 9.5, 9.5, 13.0, 20.0])
    x = np.linspace(8.0, 21.0, 131)
    dense = np.linspace(0.0, 1.0, 2_000_001)
    values = np.interp(dense, q, t)
    expected = np.searchsorted(np.sort(values), x, side="right") / dense.size
    assert np.max(np.abs(rearranged_cdf(t, q, x) - expected)) < 2e-6
    rising = np.array([1.0, 2.0, 2.0, 5.0, 9.0])
    knots = np.array([0.0, 0.5, 0.6, 0.7, 1.0])
    assert np.allclose(rearranged_cdf(rising, knots, x / 2), np.interp(x / 2, rising, knots),
                       rtol=0, atol=1e-15)


def test_the_rearranged_cdf_never_passes_the_whole_amount():
    """Summed in the order of the intervals' upper ends, the whole amount could round to just
    above 1 (240 of 3000 random cases, by up to 4e-16), and combine's cdf[-1] = 1 then gave the
    last bin a negative density."""
    from warpe_cl.inversion.space import rearranged_cdf
    rng = np.random.default_rng(5)
    for _ in range(300):
        # the knots of two nodes' CDFs, as combine takes them
        one, two = (np.cumsum(rng.random(rng.integers(3, 30))) for _ in range(2))
        q = np.unique(np.concatenate([[0.0], one / one[-1], two / two[-1]]))
        t = np.exp(np.cumsum(rng.normal(0.0, 0.3, q.size)))
        cdf = rearranged_cdf(t, q, np.linspace(t.min(), 1.1 * t.max(), 50))
        assert cdf.max() <= 1.0 and np.all(np.diff(cdf) >= 0.0)
