"""The pure-Python parts of ``tools/studies/mcxcl_compare.py`` (the host side of
``tools/bench/bench.py --compare mcxcl`` and the layered study): the MCX scene built from B1,
the scattering-event count, the reflectance comparison and the parsing of MCX's output
(``tools/bench/mcxcl_anchor.py``). MCX-CL itself is never run here (it is a benchmark tool with
its own venv). Outside the default run: ``python -m pytest tools/studies``."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from conftest import BENCH, STUDIES

# the study, and the benchmark folder it shares the anchor and scene B1 with
sys.path[:0] = [str(STUDIES), str(BENCH)]

import mcxcl_anchor  # noqa: E402
import mcxcl_compare as mc  # noqa: E402
from bench import SCENES  # noqa: E402

from warpe_cl.api import walk_params  # noqa: E402
from warpe_cl.config import load_preset  # noqa: E402
from warpe_cl.params import Counts  # noqa: E402


@pytest.fixture(scope="module")
def b1():
    return walk_params(load_preset(SCENES["B1"]))[0]


def test_b1_scene_is_the_anchors_slab(b1):
    s = mc.mcx_scene(b1, 1000)
    cfg = s["cfg"]
    mua, mus, g, n = cfg["prop"][1]
    # tau0 = 60.3 over 60 mm, omega = 0.99502: E = 1.005 /mm, mus = 0.999995, mua = 0.0050049
    assert mus == pytest.approx(1.0, rel=1e-5)
    assert mua == pytest.approx(0.005, rel=1e-3)
    assert (g, n) == (0.8, 1.3)
    assert cfg["prop"][0] == [0.0, 0.0, 1.0, 1.0]            # outside: n = 1
    assert s["vol_shape"] == [60, 60, 60]                   # the anchor's 60 mm cube of 1 mm voxels
    assert cfg["srcpos"] == [30.0, 30.0, 0.0] and cfg["srcdir"] == [0.0, 0.0, 1.0]
    assert cfg["tend"] == pytest.approx(5e-9) and cfg["tstep"] == pytest.approx(5e-11)
    assert cfg["bc"] == "______111111" and cfg["isreflect"] == 1
    assert cfg["issave2pt"] == 0 and cfg["savedetflag"] == "dspx"
    assert cfg["maxdetphoton"] >= cfg["nphoton"]            # every photon can be saved
    assert s["path_cap_mm"] == pytest.approx(5 * 299.792458 / 1.3)
    assert s["time_edges_ns"] == [float(e) for e in b1.time_edges]


def test_scene_box_gates_and_refusals(b1):
    import dataclasses
    s = mc.mcx_scene(b1, 10, box_mm=400, tstep_ns=1e9, gpuid=2)
    assert s["vol_shape"] == [400, 400, 60] and s["cfg"]["srcpos"][:2] == [200.0, 200.0]
    assert s["cfg"]["tstep"] == s["cfg"]["tend"] and s["cfg"]["gpuid"] == 2
    with pytest.raises(ValueError, match="slab"):
        mc.mcx_scene(dataclasses.replace(b1, texture="granular"), 10)
    with pytest.raises(ValueError, match="real refractive index"):
        mc.mcx_scene(dataclasses.replace(b1, k=1e-4), 10)
    with pytest.raises(ValueError, match="whole number"):
        mc.mcx_scene(dataclasses.replace(b1, thickness=0.0605), 10)


def test_events_count_every_launched_photon():
    res = {"nphoton": 10, "kernel_ms": 2.0, "wall_s": 0.5, "inside_at_tend": 1,
           "faces": {"top": {"photons": 6, "scatterings": 60, "scatterings_sq": 700},
                     "side": {"photons": 3, "scatterings": 300, "scatterings_sq": 30100},
                     "bottom": {"photons": 0, "scatterings": 0, "scatterings_sq": 0}}}
    ev = mc.mcx_events(res, mus_per_mm=1.0, path_cap_mm=100.0)
    assert ev["events_estimated_inside"] == 100.0
    assert ev["scattering_events"] == 460.0
    assert ev["scatterings_per_photon"] == 46.0
    assert ev["photons_per_s"] == 5000.0 and ev["scattering_events_per_s"] == 230000.0
    assert ev["photons_per_s_wall"] == 20.0
    mean_sq = (700 + 30100 + 100 ** 2) / 10
    assert ev["scatterings_per_photon_err"] == pytest.approx(np.sqrt((mean_sq - 46 ** 2) / 10))


def test_tpsf_comparison_arithmetic(b1):
    nt = len(b1.time_edges) - 1
    c = Counts(n_time=nt, photons=1000)
    c.fates[0] = 20                                    # 980 rays entered
    i_early = int(np.searchsorted(b1.time_edges, 0.05)) - 1   # a bin inside 0-0.1 ns
    i_late = int(np.searchsorted(b1.time_edges, 1.5)) - 1     # a bin inside 1-2 ns
    c.time_any[3, i_early] = 98                        # scattering component
    c.time_any[2, i_late] = 49                         # bf_diffuse
    c.time_any[0, i_early] = 20                        # specular: not a diffuse escape
    w = np.zeros(nt)
    w2 = np.zeros(nt)
    w[i_early], w2[i_early] = 50.0, 40.0
    w[i_late], w2[i_late] = 10.0, 4.0
    res = {"nphoton": 500, "top_tpsf": {"w": w.tolist(), "w2": w2.tolist()}}
    cmp = mc.compare_tpsf(c, b1, res)
    first, total = cmp["windows"][0], cmp["total"]
    assert first["t1_ns"] == pytest.approx(0.1, rel=0.07)     # nearest log edge (20 per decade)
    assert first["ours"] == pytest.approx(0.1) and first["mcx"] == pytest.approx(0.1)
    assert first["ours_err"] == pytest.approx(np.sqrt(98) / 980)
    assert first["mcx_err"] == pytest.approx(np.sqrt(40.0) / 500)
    assert first["ratio"] == pytest.approx(1.0) and first["z"] == pytest.approx(0.0)
    assert total["ours"] == pytest.approx(147 / 980) and total["mcx"] == pytest.approx(60 / 500)
    assert sum(r["ours"] for r in cmp["windows"]) == pytest.approx(total["ours"])
    assert sum(r["mcx"] for r in cmp["windows"]) == pytest.approx(total["mcx"])
    late = [r for r in cmp["windows"] if r["t0_ns"] <= 1.5 < r["t1_ns"]][0]
    expect_z = (0.05 - 0.02) / np.hypot(np.sqrt(49) / 980, 2.0 / 500)
    assert late["z"] == pytest.approx(expect_z)
    assert "all" in mc.format_tpsf(cmp)


MCX_LOG = """\
build program complete : 587 ms
- [device 0(1): pthread-skylake-avx512-AMD EPYC] threadph=78 extra=16 np=10000 nthread=128 nblock=64 sharedbuf=1792
set kernel arguments complete : 587 ms
kernel complete:  	1139 ms
retrieving fields ... 	detected 6123 photons, total: 6123	simulated 10000 photons (10000) with 1 devices (repeat x1)
MCX simulation speed: 18.12 photon/ms
"""


def test_parse_mcx_log():
    out = mcxcl_anchor.parse_mcx_log(MCX_LOG)
    assert out["mcx_photons_per_ms"] == 18.12 and out["build_ms"] == 587.0
    assert out["kernel_complete_ms"] == 1139.0 and out["detected"] == 6123
    assert out["mcx_device"] == "pthread-skylake-avx512-AMD EPYC"
    assert out["launch"].startswith("threadph=78") and "nblock=64" in out["launch"]


def test_summarise_detected_faces_and_weights():
    nscat = np.array([3, 5, 7, 11], dtype=np.int32).view(np.float32)   # MCX stores int bits
    ppath = np.array([10.0, 20.0, 30.0, 40.0], dtype=np.float32)
    z = np.array([-1e-7, 0.0, 60.0, 12.0], dtype=np.float32)          # top, top, bottom, side
    detp = np.vstack([np.ones(4, np.float32), nscat, ppath, np.zeros(4, np.float32),
                      np.zeros(4, np.float32), z])
    c = 299.792458
    edges = [0.0, 15 * 1.3 / c, 1.0]                                   # splits the two top rays
    out = mcxcl_anchor.summarise_detected(detp, 60, 0.01, 1.3, edges)
    assert out["faces"]["top"] == {"photons": 2, "scatterings": 8, "scatterings_sq": 34}
    assert out["faces"]["bottom"]["scatterings"] == 7 and out["faces"]["side"]["scatterings"] == 11
    assert out["top_tpsf"]["counts"] == [1, 1]
    assert out["top_tpsf"]["w"] == pytest.approx([np.exp(-0.1), np.exp(-0.2)], rel=1e-6)
    assert out["top_tpsf"]["w2"] == pytest.approx([np.exp(-0.2), np.exp(-0.4)], rel=1e-6)
    assert out["top_mean_scatterings"] == 4.0
    assert out["top_weighted_mean_scatterings"] == pytest.approx(
        (3 * np.exp(-0.1) + 5 * np.exp(-0.2)) / (np.exp(-0.1) + np.exp(-0.2)), rel=1e-6)


def test_scattering_census_per_fate():
    c = Counts(n_time=1, photons=5)
    c.records = {"n_scat": np.array([0, 10, 20, 30, 40]),
                 "fate": np.array([0, 1, 1, 2, 3], dtype=np.int8)}
    out = mc.scattering_census(c)
    assert out["per_launched"] == 20.0 and out["per_entered"] == 25.0
    assert out["per_entered_err"] == pytest.approx(np.std([10, 20, 30, 40]) / 2.0)
    assert out["fates"]["specular"] == {"fraction": 0.2, "mean_scatterings": 0.0}
    assert out["fates"]["escaped"] == {"fraction": 0.4, "mean_scatterings": 15.0}
    assert out["fates"]["terminated"] == {"fraction": 0.0, "mean_scatterings": None}
    assert "escaped 0.4000 (15)" in mc.format_census("x", out)


# ---------------------------------------------------------------------------------------------
# two layers against MCX-CL (python tools/studies/mcxcl_compare.py layers)

def test_layered_params_are_mcx_media():
    p = mc.layered_params()
    assert p.layered and len(p.stack) == 2 and p.albedo == 0.0
    assert p.bottom_interface == "fresnel" and p.substrate is None
    assert p.max_time == mc.LAYER_T_MAX_NS == p.time_edges[-1] and p.time_edges[0] == 0.0
    assert np.allclose(np.diff(p.time_edges), mc.LAYER_DT_NS)
    assert p.cos_fov.tolist() == [-1.0] * 4                     # any angle
    for layer, (h, mus, mua, g, n) in zip(p.stack, mc.LAYERS_MM):
        # analog: E = mus + mua per m, omega = mus / (mus + mua)
        assert layer.thickness == pytest.approx(h * 1e-3)
        assert layer.extinction == pytest.approx((mus + mua) * 1e3)
        assert layer.omega * layer.extinction == pytest.approx(mus * 1e3)
        assert (layer.g, layer.n, layer.texture) == (g, n, "slab")
    assert p.stack[0].n != p.stack[1].n                         # a Fresnel contact
    ctrl = mc.layered_params(mc.control_layers())
    assert ctrl.stack[1].n == ctrl.stack[0].n == mc.LAYERS_MM[0][4]
    assert ctrl.stack[1].extinction == p.stack[1].extinction    # only the index changes


def test_layers_scene_labels_and_padding():
    p = mc.layered_params()
    s = mc.mcx_layers_scene(p, 1000, box_mm=300, gpuid=2)
    cfg = s["cfg"]
    # one vacuum voxel (label 3) above and below: 3 mm of label 1 then 5 mm of label 2
    assert s["labels_z"] == [3] + [1] * 3 + [2] * 5 + [3]
    assert s["vol_shape"] == [302, 302, 10] and s["frame_label"] == 3
    assert s["stack_box_mm"] == 300
    assert cfg["prop"][0] == [0.0, 0.0, 1.0, 1.0] and cfg["prop"][3] == [0.0, 0.0, 1.0, 1.0]
    for row, (h, mus, mua, g, n) in zip(cfg["prop"][1:3], mc.LAYERS_MM):
        assert row == pytest.approx([mua, mus, g, n])
    assert s["mua_per_mm"] == pytest.approx([0.005, 0.02, 0.0])
    assert s["n"] == pytest.approx([1.31, 1.5, 1.0]) and s["clock"] == [1, 1, 0]
    # the source at the centre of the stack's top (z = 1: the top of the first slab voxel)
    assert cfg["srcpos"] == [151.0, 151.0, 1.0] and cfg["srcdir"] == [0.0, 0.0, 1.0]
    assert cfg["isreflect"] == 1 and cfg["bc"] == "______111111"
    assert cfg["tend"] == pytest.approx(2e-9 * (1 + mc.GATE_MARGIN)) and cfg["tstep"] == cfg["tend"]
    assert cfg["savedetflag"] == "dspx" and cfg["gpuid"] == 2
    assert s["time_edges_ns"][-1] == pytest.approx(2.0)
    bare = mc.mcx_layers_scene(p, 10, box_mm=60, pad="none")
    assert bare["labels_z"] == [1] * 3 + [2] * 5 and bare["frame_label"] is None
    assert bare["vol_shape"] == [60, 60, 8] and bare["cfg"]["srcpos"] == [30.0, 30.0, 0.0]
    assert len(bare["cfg"]["prop"]) == 3 and bare["clock"] == [1, 1]
    assert bare["cfg"]["tend"] == pytest.approx(2e-9)


def test_layers_scene_refusals():
    import dataclasses
    p = mc.layered_params()
    with pytest.raises(ValueError, match="A = 0"):
        mc.mcx_layers_scene(dataclasses.replace(p, albedo=0.1), 10)
    with pytest.raises(ValueError, match="A = 0"):
        mc.mcx_layers_scene(dataclasses.replace(p, substrate=(1.6, 0.0)), 10)
    with pytest.raises(ValueError, match="whole number"):
        mc.mcx_layers_scene(mc.layered_params(((2.5, 1.0, 0.0, 0.8, 1.3),)), 10)
    with pytest.raises(ValueError, match="granular"):
        lay = dataclasses.replace(p.stack[1], texture="granular")
        mc.mcx_layers_scene(dataclasses.replace(p, layers=(p.stack[0], lay)), 10)
    with pytest.raises(ValueError, match="real refractive index"):
        lay = dataclasses.replace(p.stack[1], k=1e-5)
        mc.mcx_layers_scene(dataclasses.replace(p, layers=(p.stack[0], lay)), 10)
    with pytest.raises(ValueError, match="pad"):
        mc.mcx_layers_scene(p, 10, pad="mirror")


def test_mean_and_se_is_the_sample_standard_error():
    rng = np.random.default_rng(3)
    # a weighted case: 1000 photons, 300 of which leave with a weight, the rest 0
    x = np.zeros(1000)
    x[:300] = rng.uniform(0.2, 1.0, 300)
    m, se = mc.mean_and_se(x.sum(), (x ** 2).sum(), len(x))
    assert m == pytest.approx(x.mean())
    assert se == pytest.approx(x.std(ddof=1) / np.sqrt(len(x)))
    # analog counts: the binomial error sqrt(p (1 - p) / (n - 1))
    m, se = mc.mean_and_se(250, 250, 1000)
    assert m == 0.25 and se == pytest.approx(np.sqrt(0.25 * 0.75 / 999))
    assert mc.mean_and_se(0, 0, 10) == (0.0, 0.0)
    assert mc.z_score(1.0, 0.3, 0.5, 0.4) == pytest.approx(1.0)
    assert mc.z_score(1.0, 0.0, 1.0, 0.0) is None


def test_mean_and_se_covers_the_truth_on_synthetic_weights():
    """z of a synthetic MCX-like weighted estimate against the exact mean: about unit variance."""
    rng = np.random.default_rng(7)
    zs = []
    for _ in range(400):
        leave = rng.random(2000) < 0.3
        w = np.where(leave, rng.exponential(0.5, 2000).clip(max=1.0), 0.0)
        m, se = mc.mean_and_se(w.sum(), (w ** 2).sum(), len(w))
        truth = 0.3 * 0.5 * (1 - np.exp(-2.0))                  # E[min(Exp(0.5), 1)] · 0.3
        zs.append((m - truth) / se)
    assert abs(np.mean(zs)) < 0.2 and 0.85 < np.std(zs) < 1.15


def _fake_layers(p, ours_bins, fates, w, w2, mc_counts, bottom, photons=1000, n_mcx=500):
    c = Counts(n_time=len(p.time_edges) - 1, photons=photons)
    c.fates[:] = fates
    c.time_any[3] = ours_bins
    res = {"nphoton": n_mcx, "top_tpsf": {"w": list(w), "w2": list(w2), "counts": list(mc_counts)},
           "faces": {"top": {"photons": int(sum(mc_counts))}, "bottom": {"photons": bottom[2]},
                     "side": {"photons": 1}},
           "face_weights": {"bottom": {"w": bottom[0], "w2": bottom[1], "photons": bottom[2]},
                            "side": {"w": 0.5, "w2": 0.25, "photons": 1}},
           "inside_at_tend": 0,
           "top_radial": {"edges_mm": [0.0, 10.0, 1e9], "w": [3.0, 1.0], "counts": [5, 2]}}
    return c, res


def test_compare_layers_windows_totals_and_verdict():
    p = mc.layered_params()
    nt = len(p.time_edges) - 1
    ours = np.zeros(nt, dtype=np.int64)
    w, w2, cnt = np.zeros(nt), np.zeros(nt), np.zeros(nt, dtype=np.int64)
    i = int(np.searchsorted(p.time_edges, 0.15)) - 1             # a bin inside 0.1-0.2 ns
    ours[i], w[i], w2[i], cnt[i] = 90, 45.0, 30.0, 60            # 90/900 against 45/500
    j = int(np.searchsorted(p.time_edges, 0.6)) - 1              # inside 0.5-0.75 ns: few
    ours[j], w[j], w2[j], cnt[j] = 10, 2.0, 1.0, 5
    fates = [100, 100, 500, 300, 0]                              # 900 rays entered
    c, res = _fake_layers(p, ours, fates, w, w2, cnt, bottom=(150.0, 100.0, 200))
    cmp = mc.compare_layers(c, p, res)
    assert [r["t0_ns"] for r in cmp["windows"]] == pytest.approx(list(mc.LAYER_WINDOWS_NS[:-1]))
    row = [r for r in cmp["windows"] if r["t0_ns"] <= 0.15 < r["t1_ns"]][0]
    assert row["ours"] == pytest.approx(0.1) and row["mcx"] == pytest.approx(0.09)
    assert row["ours_err"] == pytest.approx(np.sqrt(90 * (1 - 0.1) / 899) / np.sqrt(900))
    assert row["mcx_err"] == pytest.approx(np.sqrt((30.0 - 45.0 ** 2 / 500) / 499 / 500))
    assert row["z"] == pytest.approx((0.1 - 0.09) / np.hypot(row["ours_err"], row["mcx_err"]))
    assert row["judged"] and (row["ours_counts"], row["mcx_counts"]) == (90, 60)
    few = [r for r in cmp["windows"] if r["t0_ns"] <= 0.6 < r["t1_ns"]][0]
    assert not few["judged"]                                     # 5 MCX photons < 25
    assert cmp["total"]["ours"] == pytest.approx(100 / 900)
    assert cmp["total"]["mcx"] == pytest.approx(47 / 500)
    t = cmp["transmittance"]
    assert t["ours"] == pytest.approx(300 / 900) and t["mcx"] == pytest.approx(150 / 500)
    assert cmp["side"]["weight"] == pytest.approx(0.5 / 500) and cmp["side"]["photons"] == 1
    assert cmp["radial"]["fraction"] == pytest.approx([0.75, 0.25])
    judged = [r for r in cmp["windows"] + [cmp["total"], t] if r["judged"]]
    assert cmp["max_abs_z"] == pytest.approx(max(abs(r["z"]) for r in judged))
    assert cmp["passed"] == (cmp["max_abs_z"] <= 5.0) and not cmp["failed"]
    text = mc.format_layers(cmp)
    assert "not judged" in text and "PASS" in text and "bottom (T)" in text


def test_compare_layers_flags_a_window_beyond_the_limit():
    p = mc.layered_params()
    nt = len(p.time_edges) - 1
    ours = np.zeros(nt, dtype=np.int64)
    w, w2, cnt = np.zeros(nt), np.zeros(nt), np.zeros(nt, dtype=np.int64)
    i = int(np.searchsorted(p.time_edges, 0.3)) - 1              # inside 0.2-0.35 ns
    ours[i], w[i], w2[i], cnt[i] = 400, 100.0, 80.0, 120         # 0.44 against 0.2
    c, res = _fake_layers(p, ours, [100, 400, 200, 300, 0], w, w2, cnt, bottom=(150.0, 100.0, 200))
    cmp = mc.compare_layers(c, p, res)
    assert not cmp["passed"] and "0.2-0.35 ns" in cmp["failed"] and "all" in cmp["failed"]
    assert "beyond 5σ" in mc.format_layers(cmp) and "FAIL" in mc.format_layers(cmp)


def test_summarise_detected_layers_time_weight_and_clock():
    # two media and a vacuum padding (medium 3, clock 0): rows d, s1..s3, p1..p3, x, y, z
    c = 299.792458
    ppath = np.array([[3.0, 1.0, 2.0], [0.0, 4.0, 6.0], [1.0, 1.0, 1.0]], dtype=np.float32)
    nscat = np.array([[2, 1, 3], [0, 4, 5], [0, 0, 0]], dtype=np.int32).view(np.float32)
    x = np.array([101.0, 150.0, 101.0], dtype=np.float32)
    y = np.array([101.0, 101.0, 101.0], dtype=np.float32)
    z = np.array([0.0, 0.0, 10.0], dtype=np.float32)                 # top, top, bottom
    detp = np.vstack([np.ones((1, 3), np.float32), nscat, ppath, x, y, z])
    mua, n = [0.01, 0.02, 0.0], [1.31, 1.5, 1.0]
    t = (ppath[0] * 1.31 + ppath[1] * 1.5) / c                       # the vacuum does not count
    edges = [0.0, (t[0] + t[1]) / 2, 1.0]
    out = mcxcl_anchor.summarise_detected(detp, 10, mua, n, edges, centre=(101.0, 101.0),
                                          radius_edges_mm=[0.0, 10.0, 1e9], clock=[1, 1, 0])
    wt = np.exp(-(0.01 * ppath[0] + 0.02 * ppath[1]))
    assert out["faces"]["top"] == {"photons": 2, "scatterings": 2 + 0 + 1 + 4,
                                   "scatterings_sq": 4 + 25}
    assert out["faces"]["bottom"]["scatterings"] == 8
    assert out["top_tpsf"]["counts"] == [1, 1]
    assert out["top_tpsf"]["w"] == pytest.approx(wt[:2], rel=1e-6)
    assert out["top_tpsf"]["w2"] == pytest.approx(wt[:2] ** 2, rel=1e-6)
    assert out["face_weights"]["bottom"]["w"] == pytest.approx(wt[2], rel=1e-6)
    assert out["face_weights"]["bottom"]["photons"] == 1
    assert out["top_radial"]["w"] == pytest.approx([wt[0], wt[1]], rel=1e-6)
    # a photon whose time passes the last edge is left out of the face weights
    late = mcxcl_anchor.summarise_detected(detp, 10, mua, n, [0.0, t[0] * 1.01], clock=[1, 1, 0])
    assert late["face_weights"]["top"]["photons"] == 1 and late["top_tpsf"]["counts"] == [1]
    with pytest.raises(ValueError, match="one mua and one n"):
        mcxcl_anchor.summarise_detected(detp, 10, [0.01], [1.3, 1.5], edges)


def test_probe_expectation_and_row():
    e = mc.probe_expectation(1.5)
    assert e["R"] == pytest.approx(0.04) and e["top"] + e["bottom"] == pytest.approx(1.0)
    res = {"nphoton": 10000, "faces": {"top": {"photons": 385}, "bottom": {"photons": 9615},
                                       "side": {"photons": 0}}}
    r = mc.probe_row("one medium", "vacuum", res)
    assert r["top"] == 0.0385 and abs(r["z"]) < 0.1 and r["bottom"] == 0.9615
    res["faces"]["top"]["photons"] = 0
    assert mc.probe_row("two", "none", res)["z"] < -15
