"""The pure-Python helpers of ``tools/bench.py``: the heavy-tail scene T1, the statistics over
rounds and the reading of the toy walk's output; and the engine hook that ``tools/bench_ab.py
--kernel-only`` times other kernels through. Nothing here is timed and no toy is run (speed is
measured by the tools, never in the unit tests)."""
from __future__ import annotations

import json
import sys
from types import SimpleNamespace

import pytest

from conftest import TOOLS

sys.path.insert(0, str(TOOLS))

import bench  # noqa: E402

from warpe_cl.api import walk_params  # noqa: E402
from warpe_cl.config import load_preset  # noqa: E402


def test_t1_is_the_heavy_tail_scene():
    sim = bench.SCENES["T1"]["simulation"]
    assert "max_time" not in sim and "max_flights" not in sim      # defaults: no 5 ns cap
    p = walk_params(load_preset(bench.SCENES["T1"]))[0]
    assert p.texture == "granular" and (p.g, p.n, p.albedo) == (0.0, 1.0, 0.0)
    assert p.extinction * p.thickness == pytest.approx(1e5)
    assert 1.0 - p.omega == pytest.approx(3e-7)
    assert p.max_time == pytest.approx(1e5)                          # the last bin edge, ns
    # a ray lives far longer than absorption lets it: 1e5 ns holds 5e10 flights of 0.6 um
    flights_in_cap = p.max_time * 0.299792458 * p.extinction
    assert flights_in_cap > 1e3 / (1.0 - p.omega)
    assert p.max_flights >= 1e7


def test_tail_scene_photons():
    args = SimpleNamespace(photons=1e6, tail_photons=1e5, numpy_photons=2e3)
    assert bench.scene_photons("B1", args) == (1_000_000, 2000)
    assert bench.scene_photons("T1", args) == (100_000, 200)


def test_spread_and_its_text():
    s = bench.spread([3.0, 1.0, 2.0, 10.0, 2.5])
    assert (s["median"], s["min"], s["max"]) == (2.5, 1.0, 10.0)
    assert bench.fmt_spread(s, ".2f") == "2.50 [1.00–10.00]"
    assert bench.fmt_spread(bench.spread([4.0])) == "4"
    r = bench.ratios([{"x": 2.0}, {"x": 9.0}], [{"x": 1.0}, {"x": 3.0}], "x")
    assert r["values"] == [2.0, 3.0] and r["median"] == 2.5
    assert bench.rounds_text(1) == "1 round" and bench.rounds_text(5) == "5 rounds"


def test_summary_keeps_the_keys_bench_ab_reads():
    runs = [{"photons": 10, "seconds": s, "cpu_seconds": s, "photons_per_s": 10 / s,
             "scattering_events_per_s": 900 / s, "scatterings_per_photon": 90.0,
             "figure_of_merit": [{"t_min_ns": 0.0, "value": 0.1, "relative_stderr": 0.1,
                                  "fom_per_s": 100 / s}]} for s in (1.0, 2.0, 4.0)]
    out = bench.summarize_runs(runs)
    assert out["scattering_events_per_s"] == 450.0 and out["photons_per_s"] == 5.0
    assert out["range"]["scattering_events_per_s"] == [225.0, 900.0]
    assert out["figure_of_merit"][0]["fom_per_s"] == 50.0
    assert out["rounds"] == 3 and out["runs"] is runs


def test_toy_speed_from_its_json():
    doc = {"args": {"device_desc": "AMD EPYC | OpenCL 3.1 LINUX"},
           "results": [{"variant": "vec8", "wall": 1.0, "nscat": 1, "nphot": 1},
                       {"variant": "vec16", "wall": 2.0, "cpu": 3.5, "nscat": 8_000_000,
                        "nexit": 1, "nbnd": 1, "stats_valid": True, "nphot": 40_000}]}
    got = bench.parse_toy_output("", json.dumps(doc))
    assert got["scat_per_s"] == 4e6 and got["photons_per_s"] == 2e4
    assert got["scatterings_per_photon"] == 200.0 and got["device"].startswith("AMD EPYC")
    assert got["source"] == "json"


def test_toy_speed_from_its_report_line():
    out = ("# device: AMD EPYC | OpenCL 3.1 LINUX | CUs=2\n"
           "vec16        N=4e+06 wall=3.125s cpu=6.10s photons/s=1.28e+06 "
           "photons/cpu-s=6.557e+05 scat/ph=213.1 bnd/ph=1.52 det=0.2010 scat/s=2.727e+08\n")
    got = bench.parse_toy_output(out)
    assert got["scat_per_s"] == 2.727e8 and got["photons_per_s"] == 1.28e6
    assert got["scatterings_per_photon"] == 213.1 and got["photons"] == 4_000_000
    assert got["seconds"] == 3.125 and got["source"] == "stdout"
    with pytest.raises(bench.ToyUnavailable):
        bench.parse_toy_output("vec16 N=1e+06 wall=1s photons/s=1e+06\n")


def test_toy_script_path(tmp_path, monkeypatch):
    script = tmp_path / "toy_walk.py"
    script.write_text("")
    monkeypatch.setenv("WARPE_TOY_WALK", str(script))
    assert bench.toy_script_path(None) == script.resolve()
    with pytest.raises(bench.ToyUnavailable, match="--toy-script"):
        bench.toy_script_path(str(tmp_path / "missing.py"))
    monkeypatch.delenv("WARPE_TOY_WALK")
    with pytest.raises(bench.ToyUnavailable, match="WARPE_TOY_WALK"):
        bench.toy_script_path(None)


def test_toy_command_has_b1s_medium(tmp_path):
    b1 = walk_params(load_preset(bench.SCENES["B1"]))[0]
    cmd = bench.toy_command(tmp_path / "toy_walk.py", b1, 4_000_000, "Intel(R) OpenCL", "f.json")
    opt = dict(zip(cmd[2::2], cmd[3::2]))
    assert cmd[0] == sys.executable and opt["--variants"] == "vec16"
    assert opt["--photons"] == "4e+06" and opt["--platform"] == "Intel(R) OpenCL"
    assert opt["--wait"] == "block"      # the toy on every core, as ours
    assert float(opt["--mus"]) == pytest.approx(1.0, rel=1e-5)
    assert float(opt["--mua"]) == pytest.approx(0.005, rel=1e-3)
    assert (opt["--g"], opt["--n"], opt["--h"], opt["--albedo"]) == ("0.8", "1.3", "60", "0.15")
    assert (opt["--tend"], opt["--nbins"]) == ("5", "100")


def test_engine_walks_with_the_program_it_is_given(engine):
    """tools/bench_ab.py --kernel-only times other trees' kernels through Engine.use_program,
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


def test_paired_ratios_of_the_rounds():
    """tools/bench_ab.py's paired summary: the ratio B / A of each round, then their median,
    quartiles and range; a drift common to both runs of a round cancels."""
    import bench_ab
    a = [1.0, 2.0, 4.0, 1.0, 3.0]               # the machine's speed drifts round to round
    b = [1.1 * x for x in a[:4]] + [0.9 * a[4]]
    p = bench_ab.paired_ratios(a, b)
    assert p["median"] == pytest.approx(1.1)
    assert (p["min"], p["max"]) == (pytest.approx(0.9), pytest.approx(1.1))
    assert p["q1"] == pytest.approx(1.1) and len(p["values"]) == 5


def test_nadir_vs_tree_scene_and_order(monkeypatch):
    """tools/nadir_vs_tree.py: B1 with simulation.nadir as asked; an older tree whose loader
    rejects the key walks B1 without it, but only for the walk without the estimate, and this
    tree never; each configuration comes first, second and third in turn."""
    import nadir_vs_tree as nvt

    import warpe_cl
    from warpe_cl.errors import ConfigError
    for nadir in (False, True):
        assert nvt.b1_config(nadir, older=False).data["simulation"]["nadir"] is nadir
    loaded = []

    def before_the_key(scene):
        if "nadir" in scene["simulation"]:
            raise ConfigError("simulation.nadir: unknown key")
        loaded.append(scene)
        return scene
    monkeypatch.setattr(warpe_cl, "load_preset", before_the_key)
    nvt.b1_config(False, older=True)
    assert len(loaded) == 1 and "nadir" not in loaded[0]["simulation"]
    b1 = {k: v for k, v in bench.SCENES["B1"].items() if k != "simulation"}
    assert {k: v for k, v in loaded[0].items() if k != "simulation"} == b1
    for nadir, older in ((True, True), (False, False)):
        with pytest.raises(ConfigError):
            nvt.b1_config(nadir, older)
    orders = [nvt.round_order(r) for r in range(3)]
    assert orders == [[0, 1, 2], [1, 2, 0], [2, 0, 1]]
    assert all(sorted(o[k] for o in orders) == [0, 1, 2] for k in range(3))


def test_nadir_fom_rounds_alternate(monkeypatch, capsys):
    """tools/nadir_fom.py: after the warm-up, the rounds walk the configurations in one order,
    then in the reverse, round i with seed i in all of them, each configuration's runs kept
    under its own label, and each round's line lists them in the usual order."""
    import nadir_fom

    walked, seeds = [], []

    def fake_run(overrides, photons, cones, device=None, scene_name="B1"):
        walked.append((photons, overrides.get("simulation.nadir_roulette", "off")))
        seeds.append(overrides.get("simulation.seed"))
        return {"events_per_s": float(len(walked)), "walk_s": float(len(walked))}
    monkeypatch.setattr(nadir_fom, "one_run", fake_run)
    args = SimpleNamespace(roulettes=[0.1, 1.0], photons=50_000, cones=[12], device=None,
                           scene_name="B1", rounds=3)
    runs = nadir_fom.measure(args)
    labels = ["nadir off", "nadir, roulette 0.1", "nadir, roulette 1"]
    timed = [r for p, r in walked if p == 50_000]
    assert [p for p, _ in walked[:3]] == [10_000] * 3           # the warm-up, untimed
    assert timed == ["off", 0.1, 1.0, 1.0, 0.1, "off", "off", 0.1, 1.0]
    assert seeds == [None] * 3 + [1, 1, 1, 2, 2, 2, 3, 3, 3]     # a round's rays, shared
    assert list(runs) == labels and all(len(runs[k]) == 3 for k in labels)
    assert [row["events_per_s"] for row in runs["nadir off"]] == [4.0, 9.0, 10.0]
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("round")]
    assert lines[1] == ("round 2/3: scattering events/s: nadir off 9, "
                        "nadir, roulette 0.1 8, nadir, roulette 1 7; "
                        "T / T(off): nadir, roulette 0.1 0.8889, nadir, roulette 1 0.7778")


def test_nadir_variance_ab_ratios():
    """tools/nadir_variance_ab.py: variance ratios after / before, per bin over the bins where
    both errors are positive, and of the time-integrated estimate; cells opened as counted."""
    import nadir_variance_ab as nv
    before = {"walk_s": 1.0,
              "scattering": {"brdf_stderr": 2.0, "stderr": [1.0, 2.0, 0.0, 4.0], "cells": 10},
              "bf_diffuse": {"brdf_stderr": 0.0, "stderr": [0.0, 0.0, 0.0, 0.0], "cells": 0}}
    after = {"walk_s": 1.0,
             "scattering": {"brdf_stderr": 3.0, "stderr": [1.0, 3.0, 5.0, 2.0], "cells": 6},
             "bf_diffuse": {"brdf_stderr": 0.0, "stderr": [0.0, 0.0, 0.0, 0.0], "cells": 0}}
    r = nv.variance_ratios(before, after)
    s = r["scattering"]
    assert s["cells"] == (10, 6) and s["bins"] == 3
    assert s["whole"] == pytest.approx(2.25)
    assert list(s["ratio"]) == pytest.approx([1.0, 2.25, 0.25])
    assert s["above"] == [(1, pytest.approx(2.25))]
    assert r["bf_diffuse"]["bins"] == 0
    lines = nv.report("B1", before, after)
    assert "cells opened 10 -> 6 (0.600)" in lines[1] and "bins above 1.05: 1: 2.25" in lines[2]
    assert "no bin with an error in both" in lines[3]


def test_run_in_tree(tmp_path):
    """tools/_common.py run_in_tree: the child sees the tree first on PYTHONPATH and its last
    line of output comes back as JSON; a failing child, or a folder that is no checkout, ends
    the tool with one line naming the tree."""
    from _common import run_in_tree
    tree = tmp_path / "tree"
    (tree / "warpe_cl").mkdir(parents=True)
    script = tmp_path / "child.py"
    script.write_text("import json, os, sys\n"
                      "if sys.argv[1] == 'fail':\n    raise ValueError('no such key')\n"
                      "print('noise')\n"
                      "print(json.dumps({'path': os.environ['PYTHONPATH'], 'n': sys.argv[2]}))\n")
    assert run_in_tree(script, tree, ["ok", 3]) == {"path": str(tree), "n": "3"}
    with pytest.raises(SystemExit, match=r"tree: ValueError: no such key$"):
        run_in_tree(script, tree, ["fail", 0])
    with pytest.raises(SystemExit, match="not a warpe-cl checkout"):
        run_in_tree(script, tmp_path / "nowhere", ["ok", 1])


def test_kernel_icount_reads_the_walk_kernel_only():
    """tools/kernel_icount.py: the instructions of a cachegrind file counted in the walk
    kernel's functions only (every line of each, nothing from a file's other functions or from
    another kernel), and its ratios: nadir on / off per tree, each tree / the first."""
    import kernel_icount
    text = "\n".join([
        "events: Ir", "fl=???", "fn=_pocl_kernel_walk_workgroup", "0 1000", "12 234",
        "fn=_pocl_kernel_nadir_fold_workgroup", "0 77", "fn=_pocl_kernel_walk", "0 5",
        "fl=/usr/lib/libc.so", "fn=memcpy", "0 999", "fn=_pocl_kernel_walk_workgroup_fast",
        "3 10", "summary: 2560"])
    assert kernel_icount.kernel_instructions(text) == 1000 + 234 + 5 + 10

    def walk(per_event):
        return {"per_event": per_event, "per_photon": 89 * per_event, "lanes": 8,
                "kernel_instructions": int(per_event * 1000), "scattering_events": 1000}
    results = {("A", "B1", False): walk(100.0), ("A", "B1", True): walk(140.0),
               ("B", "B1", False): walk(100.0), ("B", "B1", True): walk(133.0)}
    lines = kernel_icount.report(results, ["A", "B"], ["B1"], [False, True])
    assert "A B1 nadir on / off: 1.4000" in lines
    assert "B B1 nadir on / off: 1.3300" in lines
    assert "B1 nadir on: B / A: 0.9500" in lines
    assert "B1 nadir off: B / A: 1.0000" in lines


def test_print_report_prints_and_writes(tmp_path, capsys):
    """tools/_common.py print_report: the lines printed, and the same lines written to the
    file only when one is given."""
    from _common import print_report
    print_report(["a", "b"])
    assert capsys.readouterr().out == "a\nb\n"
    out = tmp_path / "r.txt"
    print_report(["c"], out)
    assert capsys.readouterr().out == "c\n"
    assert out.read_text() == "c\n"


def test_pool_rounds_reads_both_round_lines_and_pools():
    """tools/pool_rounds.py: a round's T / T(off) is the exact one where the line prints it,
    else events/s off over on; labels hold commas and numbers; the pooled median is over
    every round, its intervals hold it, and an unknown --config is named."""
    import pool_rounds as pr
    old = ("# vm | ...\n"
           "round 1/2: scattering events/s: nadir off 1.5e+08, nadir, roulette 0.1 1e+08\n"
           "round 2/2: scattering events/s: nadir off 1.2e+08, nadir, roulette 0.1 1e+08\n"
           "# B1 (tools/bench.py) ...\n")
    new = ("round 1/1: scattering events/s: nadir off 9, nadir, roulette 0.1 8, nadir, "
           "roulette 1 7; T / T(off): nadir, roulette 0.1 1.1250, nadir, roulette 1 1.2857\n")
    assert pr.round_ratios(old) == pytest.approx([1.5, 1.2])
    assert pr.round_ratios(new) == [1.125]
    assert pr.round_ratios(new, "nadir, roulette 1") == [1.2857]
    with pytest.raises(ValueError, match="nadir, roulette 0.1, nadir, roulette 1"):
        pr.round_ratios(new, "nadir, roulette 0.5")
    p = pr.pooled([[1.0, 2.0, 3.0], [4.0, 5.0]], resamples=200, seed=3)
    assert p["rounds"] == 5 and p["median"] == 3.0 and p["session_medians"] == [2.0, 4.5]
    for lo, hi in (p["ci_rounds"], p["ci_sessions"]):
        assert 1.0 <= lo <= 3.0 <= hi <= 5.0
