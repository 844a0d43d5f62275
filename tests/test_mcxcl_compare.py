"""The pure-Python parts of ``tools/bench.py --compare mcxcl``: the MCX scene built from B1, the
scattering-event count, the reflectance comparison and the parsing of MCX's output. MCX-CL itself
is never run here (it is a benchmark tool with its own venv)."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from conftest import TOOLS

sys.path.insert(0, str(TOOLS))

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
