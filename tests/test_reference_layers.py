"""Tests of the reference's layered walk (docs/walk.md §7; warpe_cl/reference.py
``walk_ray_layers``) on its own.

Statistical assertions state their tolerance next to them, in Monte Carlo standard errors:
a count of independent rays is binomial, sigma = sqrt(N p (1 - p)) (conftest.binomial_sigma),
and two histograms of independent runs are compared by the two-sample chi-square described in
:func:`two_sample_chi2`. Seeds are fixed, so every test is deterministic; the 5-sigma bounds
say how far a correct walk could plausibly land, not a tuned margin.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import binomial_sigma

from warpe_cl.params import (C_M_PER_NS, FATES, LAYER_STATS, MAX_LAYERS, Layer, WalkParams,
                             stack_params)
from warpe_cl.reference import (LayeredRayOutcome, _StackConstants, simulate_reference,
                                walk_ray_layers)
from warpe_cl.rng import PhotonStream

SPECULAR, BF_DIRECT, BF_DIFFUSE, SCATTERING = range(4)
FATE = {name: i for i, name in enumerate(FATES)}
INT_FIELDS = ("fate", "component", "n_scat", "n_lamb", "n_bspec", "n_top", "time_bin",
              "emergence_bin")


def count_sigma(photons, probability):
    """Standard deviation of a binomial count, sqrt(N p (1 - p)) (floored as binomial_sigma)."""
    return photons * binomial_sigma(probability, photons)


def two_sample_chi2(a, b):
    """Two-sample chi-square of two histograms of the same number of independent rays.

    chi2 = sum over the cells with a + b > 0 of (a - b)^2 / (a + b), dof = the number of those
    cells. Given a cell's pooled count m = a + b, a is Binomial(m, 1/2) when both runs draw from
    the same distribution, so each term has mean exactly 1 and variance 2 - 2/m <= 2: chi2 has
    mean dof and standard deviation at most sqrt(2 dof). Returns (chi2, dof); the tests accept
    chi2 <= dof + 5 sqrt(2 dof), a 5-sigma bound."""
    a = np.asarray(a, dtype=float).ravel()
    b = np.asarray(b, dtype=float).ravel()
    used = (a + b) > 0
    chi2 = float(np.sum((a[used] - b[used]) ** 2 / (a[used] + b[used])))
    return chi2, int(used.sum())


def assert_same_distribution(a, b, label):
    chi2, dof = two_sample_chi2(a, b)
    assert dof > 0, label
    # 5 sigma of chi2 under the null: mean dof, standard deviation <= sqrt(2 dof).
    assert chi2 <= dof + 5.0 * math.sqrt(2.0 * dof), (label, chi2, dof)


COMMON = dict(albedo=0.5, time_edges=np.linspace(0.0, 10.0, 41), seed=11, scenario=4)


def single(texture, bottom_interface="fresnel", **kw):
    values = dict(texture=texture, thickness=0.3, extinction=3.0, omega=0.9, g=0.6, n=1.3,
                  k=1e-3, bottom_interface=bottom_interface)
    values.update(COMMON)
    values.update(kw)
    return WalkParams(**values)


def one_layer_stack(params: WalkParams) -> WalkParams:
    """The same medium as a one-layer stack (texture "layers")."""
    layer = Layer(params.texture, params.thickness, params.extinction, params.omega, params.g,
                  params.n, params.k)
    keep = ("albedo", "time_edges", "bottom_interface", "max_time", "max_flights", "fov", "rule",
            "seed", "scenario")
    return stack_params([layer], **{name: getattr(params, name) for name in keep})


# --------------------------------------------------------------------------------------------
# One layer: §7 reduces to §3 event for event
# --------------------------------------------------------------------------------------------

ONE_LAYER = {
    "slab_fresnel": single("slab", max_time=8.0),
    "slab_fresnel_tir": single("slab", n=1.92, k=9.5e-6, omega=0.95, max_time=8.0),
    "slab_none": single("slab", "none", max_time=8.0),
    "granular_time_window": single("granular", rule="time_window", max_time=8.0),
}


@pytest.mark.parametrize("name", sorted(ONE_LAYER))
def test_one_layer_stack_follows_the_single_layer_walk(name):
    """A one-layer stack has interface 0 Fresnel for a slab (entry event, Fresnel top) and
    transparent for granular (no entry event, exit with cos = -uz), and at interface 1 the gap
    of §3.1 (slab over vacuum: Fresnel) or the floor in contact: §7.2 is §3 event for event, so
    the same seed gives the same rays. Exact equality for the integers and times (L adds
    s * (n_0 / n_0) = s * 1.0); the exit cosine to 1e-12 relative, because §7.2 writes it
    sqrt((1 - n_0^2) + n_0^2 mu^2) and the single-layer reference sqrt(1 - n^2 (1 - mu^2)),
    equal in exact arithmetic. The record's layer: 0 in the single-layer walk, and by §7.2 N = 1
    for a floor absorption in the gap, N - 1 = 0 for any other end."""
    params = ONE_LAYER[name]
    photons = 3000
    ref = simulate_reference(params, photons, records=True)
    lay = simulate_reference(one_layer_stack(params), photons, records=True)
    a, b = ref.records, lay.records
    for field in INT_FIELDS:
        np.testing.assert_array_equal(b[field], a[field], err_msg=field)
    np.testing.assert_array_equal(b["time_ns"], a["time_ns"], err_msg="time_ns")  # NaN == NaN
    np.testing.assert_allclose(b["cos_exit"], a["cos_exit"], rtol=1e-12, atol=0,
                               equal_nan=True, err_msg="cos_exit")
    assert np.all(a["layer"] == 0)
    gap = params.texture == "slab" and params.bottom_interface == "fresnel"
    floor = a["fate"] == FATE["absorbed_floor"]
    np.testing.assert_array_equal(b["layer"], np.where(floor & gap, 1, 0))
    for tally in ("fates", "total", "early", "angular", "time_any", "time_in_fov"):
        np.testing.assert_array_equal(getattr(lay, tally), getattr(ref, tally), err_msg=tally)
    assert lay.scattering_events == ref.scattering_events
    assert lay.mixed_history == ref.mixed_history
    # every fate but (granular) specular happened, so the comparison covered every branch
    fates = ref.fates.copy()
    if params.texture == "granular":
        fates[FATE["specular"]] = 1
    assert np.all(fates > 0), fates
    # the per-layer statistics of one layer (walk.md §7.4)
    view = lay.layer_view(1)
    assert view["down"][0] == photons - lay.fates[FATE["specular"]]
    assert view["up"][0] == lay.fates[FATE["escaped"]]
    assert view["absorbed"][0] == lay.fates[FATE["absorbed_medium"]]
    assert view["terminated"][0] == lay.fates[FATE["terminated"]]
    if gap:
        assert view["down"][1] - view["up"][1] == lay.fates[FATE["absorbed_floor"]] > 0
    else:
        assert view["down"][1] == view["up"][1] == 0  # a floor in contact is no transmission
    assert np.all(ref.layer_stats == 0)


# --------------------------------------------------------------------------------------------
# Exact echoes of a two-slab stack
# --------------------------------------------------------------------------------------------

def test_two_slab_stack_direct_echoes():
    """Two slabs without scattering (omega = 0: every collision absorbs) over a black floor
    (A = 0) under a vacuum gap, k = 0. A ray starts straight down and meets only interfaces at
    normal incidence, so it stays vertical, and the probability of each history is a product of
    normal-incidence Fresnel factors, R_ab = ((n_a - n_b)/(n_a + n_b))^2 (the same from either
    side; T_ab = 1 - R_ab), and of e^-tau_i per crossing of layer i (tau_i = E_i h_i). With
    R01 (vacuum/slab 0, top), R12 (slab 0/slab 1), R2g (slab 1/vacuum gap):

    * specular: p = R01, t = 0;
    * echo of interface 1: enter, cross 0, reflect at 1, cross 0, exit:
      p_A = (1 - R01)^2 R12 e^-2tau0,  t_A = 2 h0 n0 / c;
    * echo of the bottom of the stack (the gap interface; the floor absorbs everything that
      crosses it): enter, cross 0, transmit at 1, cross 1, reflect at 2, cross 1, transmit at
      1, cross 0, exit:
      p_B = (1 - R01)^2 (1 - R12)^2 R2g e^-2(tau0 + tau1),  t_B = 2 (h0 n0 + h1 n1) / c;
    * double bounce in layer 0: enter, cross 0, reflect at 1, cross 0, reflect at the top
      (inside, R01), cross 0, reflect at 1, cross 0, exit:
      p_C = (1 - R01)^2 R12^2 R01 e^-4tau0,  t_C = 4 h0 n0 / c.

    Every exit crosses layer 0 2a times and layer 1 2b times (a >= 1, b >= 0) and leaves at
    t = 2 (a h0 n0 + b h1 n1) / c; h0 n0 = 0.35 m and h1 n1 = 0.255 m make the low orders
    distinct by > 0.3 ns, and A, B, C are the only histories of (a, b) = (1, 0), (1, 1), (2, 0).
    Each count in its 0.01 ns bin is Binomial(N, p): 5 sigma."""
    n0, h0, tau0 = 3.5, 0.1, 0.1
    n1, h1, tau1 = 1.5, 0.17, 0.1
    layers = [Layer("slab", h0, tau0 / h0, 0.0, 0.3, n0, 0.0),
              Layer("slab", h1, tau1 / h1, 0.0, 0.3, n1, 0.0)]
    edges = np.linspace(0.0, 12.0, 1201)
    params = stack_params(layers, albedo=0.0, time_edges=edges, bottom_interface="fresnel",
                          seed=5, scenario=9)
    photons = 40_000
    counts = simulate_reference(params, photons, records=True)
    rec = counts.records

    def reflectance(a, b):
        return ((a - b) / (a + b)) ** 2

    r01, r12, r2g = reflectance(1.0, n0), reflectance(n0, n1), reflectance(n1, 1.0)
    echoes = {  # name: (probability, time in ns)
        "A": ((1 - r01) ** 2 * r12 * math.exp(-2 * tau0), 2 * h0 * n0 / C_M_PER_NS),
        "B": ((1 - r01) ** 2 * (1 - r12) ** 2 * r2g * math.exp(-2 * (tau0 + tau1)),
              2 * (h0 * n0 + h1 * n1) / C_M_PER_NS),
        "C": ((1 - r01) ** 2 * r12 ** 2 * r01 * math.exp(-4 * tau0), 4 * h0 * n0 / C_M_PER_NS),
    }
    # Specular ~ Binomial(N, R01) (R01 = 0.309): 5 sigma = 5 sqrt(N R01 (1 - R01)) ~ 460.
    assert abs(counts.fates[FATE["specular"]] - photons * r01) <= 5 * count_sigma(photons, r01)

    # Exactly: no scattering, no floor reflection, every exit BF direct at an echo time.
    assert counts.scattering_events == 0 and rec["n_lamb"].sum() == 0
    exits = rec["fate"] == FATE["escaped"]
    assert np.all(rec["component"][exits] == BF_DIRECT)
    assert counts.total[BF_DIRECT] == exits.sum()
    allowed = np.array([2 * (a * h0 * n0 + b * h1 * n1) / C_M_PER_NS
                        for a in range(1, 20) for b in range(0, 20)])
    nearest = np.min(np.abs(rec["time_ns"][exits][:, None] - allowed[None, :]), axis=1)
    assert np.all(nearest <= 1e-12 * rec["time_ns"][exits])
    assert np.all(rec["cos_exit"][exits] == 1.0)

    for name, (p, t) in echoes.items():
        i = int(np.searchsorted(edges, t, side="right")) - 1
        assert min(t - edges[i], edges[i + 1] - t) > 1e-6  # the echo sits inside its bin
        observed = counts.time_any[BF_DIRECT, i]
        # N p_A ~ 2500, N p_B ~ 360, N p_C ~ 100: 5 binomial sigma each.
        assert abs(observed - photons * p) <= 5 * count_sigma(photons, p), (name, observed,
                                                                            photons * p)
    # the interface-1 echo bounced once at a buried interface and never at the top
    first = exits & (np.abs(rec["time_ns"] - echoes["A"][1]) < 1e-9)
    assert np.all(rec["n_bspec"][first] == 1) and np.all(rec["n_top"][first] == 0)
    # which layer each non-exit ended in: absorbed in 0 or 1, the floor in the gap (N = 2)
    assert set(np.unique(rec["layer"][rec["fate"] == FATE["absorbed_medium"]])) == {0, 1}
    assert np.all(rec["layer"][rec["fate"] == FATE["absorbed_floor"]] == 2)


# --------------------------------------------------------------------------------------------
# One oblique ray through scripted events: refraction, Fresnel sides, TIR, time
# --------------------------------------------------------------------------------------------

def fresnel_real(cos_i, n1, n2):
    """Unpolarised Fresnel reflectance from real index n1 into n2 at incidence cosine cos_i
    (textbook amplitudes, written here independently of the reference)."""
    sin_t = n1 / n2 * math.sqrt(1.0 - cos_i ** 2)
    cos_t = math.sqrt(1.0 - sin_t ** 2)
    r_s = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    r_p = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)
    return 0.5 * (r_s ** 2 + r_p ** 2)


def scripted(blocks, filler=(0.9, 0.9, 0.5, 0.5)):
    """A next_block that returns the given blocks, then ``filler``; and the list of blocks
    handed out (one per event, walk.md §2)."""
    queue = list(blocks)
    used = []

    def next_block():
        block = queue.pop(0) if queue else filler
        used.append(block)
        return block
    return next_block, used


# Two clear slabs (E = 0: every flight reaches a boundary) over a substrate; floor A = 0.5.
SCRIPT_NA, SCRIPT_NB, SCRIPT_NS = 1.3, 1.8, 1.5
SCRIPT_HA, SCRIPT_HB = 0.1, 0.2


def scripted_stack():
    layers = [Layer("slab", SCRIPT_HA, 0.0, 0.5, 0.0, SCRIPT_NA, 0.0),
              Layer("slab", SCRIPT_HB, 0.0, 0.5, 0.0, SCRIPT_NB, 0.0)]
    params = stack_params(layers, substrate=(SCRIPT_NS, 0.0), albedo=0.5,
                          time_edges=np.linspace(0.0, 10.0, 11))
    return _StackConstants.from_params(params)


@pytest.mark.parametrize("case", ["transmitted", "reflected", "total_internal"])
def test_scripted_oblique_ray_through_a_stack(case):
    """Events of walk.md §7.2 with chosen draws, for slab A (n = 1.3) over slab B (n = 1.8)
    over a substrate (n = 1.5), both slabs clear:
    0 entry (u0 = 0.9 > R0), 1 flight down A to interface 1 (Fresnel, u1 = 0.999: transmitted,
    still vertical), 2 flight down B to interface 2 (transmitted into the substrate), 3 gap
    event (x0 < T_A: the floor reflects; mu_g = sqrt(u1); u3 = 0.999: refracted into B with
    sin = n_s sin_g / n_B), 4 flight up B to interface 1, where, seen from B (near 1.8, far
    1.3), the ray is transmitted (u1 just above R), reflected (u1 just below R) or totally
    reflected (n_s sin_g >= 1.3: TIR whatever u1); transmitted, 5 flight up A to the top and
    exit with cos = sqrt(1 - (n_s sin_g)^2) (n sin theta is invariant), at
    t = (h_A n_A + h_B n_B + h_B n_B / cos_B + h_A n_A / cos_A) / c. A reflected ray goes back
    down B and through interface 2 (filler u1 = 0.9 > R), and the floor absorbs it in the gap
    (filler x0 >= T_A: layer N = 2). R is the textbook Fresnel reflectance (fresnel_real)."""
    mu_gap = 0.4 if case == "total_internal" else 0.8
    sin_gap = math.sqrt(1.0 - mu_gap ** 2)
    invariant = SCRIPT_NS * sin_gap                    # n sin(theta) along the whole path
    cos_b = math.sqrt(1.0 - (invariant / SCRIPT_NB) ** 2)
    if case == "total_internal":
        assert invariant >= SCRIPT_NA                   # TIR going up from B into A
        u_iface = 0.999999
    else:
        r_up = fresnel_real(cos_b, SCRIPT_NB, SCRIPT_NA)
        u_iface = r_up * (1 + 1e-9) if case == "transmitted" else r_up * (1 - 1e-9)
    blocks = [(0.9, 0.5, 0.5, 0.5), (0.5, 0.999, 0.5, 0.5), (0.5, 0.999, 0.5, 0.5),
              (0.1, mu_gap ** 2, 0.1, 0.999), (0.5, u_iface, 0.5, 0.5),
              (0.5, 0.999, 0.5, 0.5)]
    next_block, used = scripted(blocks)
    ray = walk_ray_layers(scripted_stack(), next_block)
    assert ray.n_lamb == 1 and ray.n_scat == 0 and ray.n_top == 0
    if case == "transmitted":
        assert len(used) == 6
        assert ray.fate == FATE["escaped"] and ray.layer == 0 and ray.n_bspec == 0
        cos_a = math.sqrt(1.0 - (invariant / SCRIPT_NA) ** 2)
        assert ray.cos_exit == pytest.approx(math.sqrt(1.0 - invariant ** 2), rel=1e-12)
        time_ns = (SCRIPT_HA * SCRIPT_NA + SCRIPT_HB * SCRIPT_NB + SCRIPT_HB * SCRIPT_NB / cos_b
                   + SCRIPT_HA * SCRIPT_NA / cos_a) / C_M_PER_NS
        # path counted at layer 0's speed: t = L n_0 / c
        assert ray.path_length * SCRIPT_NA / C_M_PER_NS == pytest.approx(time_ns, rel=1e-12)
        assert ray.down == (1, 1, 1) and ray.up == (1, 1, 1)
    else:
        # 4: reflected at interface 1; 5: down B, transmitted at 2; 6: gap, the floor absorbs
        assert len(used) == 7
        assert ray.fate == FATE["absorbed_floor"] and ray.layer == 2 and ray.n_bspec == 1
        assert ray.down == (1, 1, 2) and ray.up == (0, 0, 1)
        # L counts B's path at layer 0's speed (times n_B / n_A): h_A, then h_B down, h_B /
        # cos_B up and back down B; nothing in the gap
        scale = SCRIPT_NB / SCRIPT_NA
        path = SCRIPT_HA + SCRIPT_HB * scale + 2 * SCRIPT_HB * scale / cos_b
        assert ray.path_length == pytest.approx(path, rel=1e-12)


# --------------------------------------------------------------------------------------------
# Splitting a layer in two changes nothing
# --------------------------------------------------------------------------------------------

SPLIT = {
    "granular": dict(texture="granular", extinction=10.0, omega=0.95, g=0.5, n=1.3, k=0.0),
    "slab": dict(texture="slab", extinction=6.0, omega=0.95, g=0.7, n=1.31, k=1e-3),
}


@pytest.mark.parametrize("name", sorted(SPLIT))
def test_two_identical_layers_equal_one_layer(name):
    """Two identical layers of thickness h/2 meet at a transparent interface (equal faces);
    crossing it ends a flight, and the next one starts afresh from the same point, which
    changes nothing in distribution (the exponential flight is memoryless), only which draws
    the ray uses. So the stacked and the single layer of thickness h have the same time
    histograms (time_any, per component), angular histograms and fates. Independent seeds for
    the two runs; each histogram pair passes the two-sample chi-square of two_sample_chi2 at
    5 sigma."""
    m = SPLIT[name]
    h = 0.2
    common = dict(albedo=0.6, time_edges=np.linspace(0.0, 12.0, 49), max_time=12.0,
                  bottom_interface="fresnel", scenario=21)
    whole = stack_params([Layer(m["texture"], h, m["extinction"], m["omega"], m["g"], m["n"],
                                m["k"])], seed=1, **common)
    half = Layer(m["texture"], h / 2, m["extinction"], m["omega"], m["g"], m["n"], m["k"])
    split = stack_params([half, half], seed=2, **common)
    photons = 6000
    a = simulate_reference(whole, photons)
    b = simulate_reference(split, photons)
    view = b.layer_view(2)
    assert view["down"][1] > 0 and view["up"][1] > 0  # rays did cross the inner interface
    assert_same_distribution(a.fates, b.fates, "fates")
    assert_same_distribution(a.time_any, b.time_any, "time_any")
    assert_same_distribution(a.angular, b.angular, "angular")
    # the check has power: the same stack with the lower half twice as dense differs
    dense = Layer(m["texture"], h / 2, 2 * m["extinction"], m["omega"], m["g"], m["n"], m["k"])
    c = simulate_reference(stack_params([half, dense], seed=2, **common), photons)
    chi2, dof = two_sample_chi2(a.time_any, c.time_any)
    assert chi2 > dof + 5.0 * math.sqrt(2.0 * dof)


# --------------------------------------------------------------------------------------------
# Per-layer statistics close ray by ray (walk.md §7.4)
# --------------------------------------------------------------------------------------------

CLOSURE = {
    # slab / granular / slab over a substrate (a Fresnel gap under a slab), a time cap
    "substrate": (dict(layers=[Layer("slab", 0.05, 20.0, 0.95, 0.6, 1.31, 1e-4),
                               Layer("granular", 0.05, 40.0, 0.9, 0.5, 1.2, 0.0),
                               Layer("slab", 0.05, 10.0, 0.8, 0.3, 1.6, 1e-3)],
                       substrate=(2.0, 0.5)), dict(max_time=3.0)),
    # granular / slab / granular, the floor in contact with the granular bottom, a flight cap
    "contact": (dict(layers=[Layer("granular", 0.04, 30.0, 0.9, 0.5, 1.25, 0.0),
                             Layer("slab", 0.03, 20.0, 0.9, 0.2, 1.5, 1e-4),
                             Layer("granular", 0.05, 50.0, 0.9, 0.7, 1.3, 0.0)]),
                dict(max_time=100.0, max_flights=25)),
}


@pytest.mark.parametrize("name", sorted(CLOSURE))
def test_layer_statistics_close_ray_by_ray(name):
    """For every ray and every layer i (walk.md §7.4):
    down[i] + up[i+1] = up[i] + down[i+1] + absorbed[i] + terminated[i]
    (+ its floor absorption in contact, for i = N - 1), down[N] = up[N] + (its floor absorption
    in the gap), down[0] = 1 - specular, up[0] = escaped: a ray in layer i entered it once more
    than it left it iff it ended there. Exact; then the sums are the Counts.layer_stats of
    simulate_reference, in their LAYER_STATS slots, and the records' layer column agrees."""
    stack_kw, extra = CLOSURE[name]
    params = stack_params(albedo=0.7, time_edges=np.linspace(0.0, 5.0, 21), seed=3,
                          scenario=8, **stack_kw, **extra)
    n_layers = len(params.layers)
    photons = 2500
    constants = _StackConstants.from_params(params)
    streams = PhotonStream.many(params.seed, params.scenario, 0, photons)
    rays = [walk_ray_layers(constants, s.block) for s in streams]
    assert all(isinstance(r, LayeredRayOutcome) for r in rays)
    gap = constants.fresnel[n_layers]
    assert gap == (name == "substrate")
    absorbed = np.zeros(n_layers, np.int64)
    terminated = np.zeros(n_layers, np.int64)
    down = np.zeros(n_layers + 1, np.int64)
    up = np.zeros(n_layers + 1, np.int64)
    floor_ends = 0
    for r in rays:
        d, u = np.array(r.down), np.array(r.up)
        ends = np.zeros(n_layers, np.int64)   # 1 in the layer where the ray ended inside it
        if r.fate in (FATE["absorbed_medium"], FATE["terminated"]):
            ends[r.layer] = 1
        floor_in_gap = r.fate == FATE["absorbed_floor"] and gap
        if r.fate == FATE["absorbed_floor"]:
            floor_ends += 1
            assert r.layer == (n_layers if gap else n_layers - 1)
            if not gap:
                ends[n_layers - 1] = 1
        elif r.fate in (FATE["escaped"], FATE["specular"]):
            assert r.layer == 0
        np.testing.assert_array_equal(d[:-1] + u[1:], u[:-1] + d[1:] + ends)
        assert d[-1] == u[-1] + floor_in_gap
        assert d[0] == (r.fate != FATE["specular"]) and u[0] == (r.fate == FATE["escaped"])
        absorbed += ends * (r.fate == FATE["absorbed_medium"])
        terminated += ends * (r.fate == FATE["terminated"])
        down += d
        up += u
    # every term of the closure happened somewhere, so the check covered them
    assert np.all(absorbed > 0) and floor_ends > 0 and np.all(down[:n_layers] > 0)
    assert np.count_nonzero(terminated) >= 2
    assert (down[-1] > up[-1] > 0) if gap else (down[-1] == up[-1] == 0)

    counts = simulate_reference(params, photons, records=True)
    view = counts.layer_view(n_layers)
    np.testing.assert_array_equal(view["absorbed"], absorbed)
    np.testing.assert_array_equal(view["terminated"], terminated)
    np.testing.assert_array_equal(view["down"], down)
    np.testing.assert_array_equal(view["up"], up)
    stats = dict(zip(LAYER_STATS, counts.layer_stats.tolist()))
    assert stats[f"down_{n_layers}"] == down[-1] and stats["up_0"] == counts.fates[1]
    assert all(stats[f"absorbed_{i}"] == 0 for i in range(n_layers, MAX_LAYERS))
    np.testing.assert_array_equal(counts.records["layer"], [r.layer for r in rays])
    np.testing.assert_array_equal(counts.records["fate"], [r.fate for r in rays])


def test_time_window_rule_uses_the_floor_echo_of_the_stack():
    """With rule time_window, t1 is the floor's echo 2 sum h_i n_i / c (walk.md §7.2): every
    diffuse exit is bf_diffuse iff t >= t1."""
    layers = [Layer("slab", 0.05, 20.0, 0.95, 0.6, 1.31, 1e-4),
              Layer("granular", 0.1, 40.0, 0.95, 0.5, 1.2, 0.0)]
    params = stack_params(layers, albedo=0.7, time_edges=np.linspace(0.0, 5.0, 21), seed=3,
                          scenario=8, rule="time_window")
    t1 = 2 * (0.05 * 1.31 + 0.1 * 1.2) / C_M_PER_NS
    rec = simulate_reference(params, 1500, records=True).records
    diffuse = (rec["fate"] == FATE["escaped"]) & ((rec["n_scat"] > 0) | (rec["n_lamb"] > 0))
    expected = np.where(rec["time_ns"][diffuse] >= t1, BF_DIFFUSE, SCATTERING)
    np.testing.assert_array_equal(rec["component"][diffuse], expected)
    assert set(expected) == {BF_DIFFUSE, SCATTERING}


# --------------------------------------------------------------------------------------------
# A transparent, empty layer changes nothing time-integrated
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("texture", ["granular", "slab"])
def test_empty_layer_with_the_same_face_changes_nothing_time_integrated(texture):
    """A tau = 0 layer on top of a layer with the same face (granular over granular: pores;
    slab over slab of the same (n, k)) is crossed in straight lines through transparent
    interfaces; only the slab's top (same n_0, k_0: same entry and exit) sees vacuum. It delays
    rays but changes neither their fates nor their exit directions: fates and the angular
    histogram per component agree with the bare layer's (independent seeds, two-sample
    chi-square at 5 sigma, see two_sample_chi2). The time cap is out of reach."""
    below = Layer(texture, 0.2, 8.0, 0.93, 0.6, 1.3, 1e-3 if texture == "slab" else 0.0)
    empty = Layer(texture, 0.1, 0.0, 0.5, 0.0, 1.3 if texture == "slab" else 1.7,
                  below.k)
    common = dict(albedo=0.5, time_edges=np.linspace(0.0, 20.0, 21), max_time=1e6,
                  scenario=30)
    photons = 6000
    a = simulate_reference(stack_params([below], seed=1, **common), photons)
    b = simulate_reference(stack_params([empty, below], seed=2, **common), photons)
    assert a.fates[FATE["terminated"]] == b.fates[FATE["terminated"]] == 0
    assert_same_distribution(a.fates, b.fates, "fates")
    assert_same_distribution(a.angular, b.angular, "angular")
    assert_same_distribution(a.total, b.total, "total")
    # each fraction separately: the difference of two independent binomial counts,
    # 5 sigma = 5 sqrt(2 N p (1 - p)) with p their pooled fraction
    for i in range(len(FATES)):
        p = (a.fates[i] + b.fates[i]) / (2 * photons)
        assert abs(int(a.fates[i]) - int(b.fates[i])) <= 5 * math.sqrt(2) * count_sigma(
            photons, p), FATES[i]


# --------------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------------

def test_invalid_stacks_are_rejected():
    good = Layer("slab", 0.1, 1.0, 0.9, 0.5, 1.3, 0.0)
    edges = np.linspace(0.0, 5.0, 11)
    base = stack_params([good], albedo=0.5, time_edges=edges)
    simulate_reference(base, 5)  # valid
    bad = [
        stack_params([good], albedo=0.5, time_edges=edges, mode="weighted"),
        stack_params([Layer("foam", 0.1, 1.0, 0.9, 0.5, 1.3, 0.0)], albedo=0.5,
                     time_edges=edges),
        stack_params([good, Layer("granular", 0.0, 1.0, 0.9, 0.5, 1.3, 0.0)], albedo=0.5,
                     time_edges=edges),
        stack_params([good, Layer("granular", 0.1, -1.0, 0.9, 0.5, 1.3, 0.0)], albedo=0.5,
                     time_edges=edges),
        WalkParams(texture="layers", thickness=0.1, extinction=1.0, omega=0.9, g=0.5, n=1.3,
                   k=0.0, albedo=0.5, time_edges=edges),                # no layers
        WalkParams(texture="layers", thickness=0.9, extinction=1.0, omega=0.9, g=0.5, n=1.3,
                   k=0.0, albedo=0.5, time_edges=edges, layers=(good,) * (MAX_LAYERS + 1)),
        WalkParams(texture="slab", thickness=0.1, extinction=1.0, omega=0.9, g=0.5, n=1.3,
                   k=0.0, albedo=0.5, time_edges=edges, substrate=(2.0, 0.0)),
    ]
    for params in bad:
        with pytest.raises(ValueError):
            simulate_reference(params, 5)
