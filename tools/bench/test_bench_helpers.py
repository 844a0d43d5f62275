"""The pure-Python helpers of ``tools/bench/bench.py``: the heavy-tail scene T1, the statistics
over rounds and the reading of the toy walk's output; ``tools/bench/bench_ab.py``'s paired
ratios; ``tools/bench/nadir_fom.py``'s order of rounds; ``tools/bench/bench_invert.py``'s grid
and rounds. Nothing here is timed and no toy is run
(speed is measured by the tools, never in the unit tests). Outside the default run: ``python -m
pytest tools/bench`` (this folder's conftest.py gives tests/conftest.py's helpers); the engine
hook that ``bench_ab.py --kernel-only`` times other kernels through is product behaviour,
tested in tests/test_engine_programs.py."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from types import SimpleNamespace

import pytest

from conftest import BENCH

sys.path.insert(0, str(BENCH))

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
             "walk_seconds": 0.5 * s, "launches": 2 + s,
             "figure_of_merit": [{"t_min_ns": 0.0, "value": 0.1, "relative_stderr": 0.1,
                                  "fom_per_s": 100 / s}]} for s in (1.0, 2.0, 4.0)]
    out = bench.summarize_runs(runs)
    assert out["scattering_events_per_s"] == 450.0 and out["photons_per_s"] == 5.0
    assert out["walk_seconds"] == 1.0 and out["range"]["launches"] == [3.0, 6.0]
    assert "launches 4 [3–6], their time 1 [0.5–2] s of 2 [1–4] s" in bench.scene_line(
        "B1", "analog", runs)
    for r in runs:      # an older tree's engine keeps no launch record: no zeros printed
        r["launches"], r["walk_seconds"] = 0, 0.0
    assert "launches" not in bench.scene_line("B1", "analog", runs)
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


def test_paired_ratios_of_the_rounds():
    """tools/bench/bench_ab.py's paired summary: the ratio B / A of each round, then their
    median, quartiles and range; a drift common to both runs of a round cancels."""
    import bench_ab
    a = [1.0, 2.0, 4.0, 1.0, 3.0]               # the machine's speed drifts round to round
    b = [1.1 * x for x in a[:4]] + [0.9 * a[4]]
    p = bench_ab.paired_ratios(a, b)
    assert p["median"] == pytest.approx(1.1)
    assert (p["min"], p["max"]) == (pytest.approx(0.9), pytest.approx(1.1))
    assert p["q1"] == pytest.approx(1.1) and len(p["values"]) == 5


def test_nadir_fom_rounds_alternate(monkeypatch, capsys):
    """tools/bench/nadir_fom.py: after the warm-up, the rounds walk the configurations in one
    order, then in the reverse, round i with seed i in all of them, each configuration's runs kept
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


def test_bench_invert_grid_and_rounds():
    """tools/bench/bench_invert.py: ``--grid`` as one size or three, the preset it sweeps,
    the interleaved order of the measured variants and the text of a median and range."""
    import bench_invert
    assert bench_invert.grid_shape("10") == (10, 10, 10)
    assert bench_invert.grid_shape("8,5,5") == (8, 5, 5)
    for bad in ("1", "8,5", "8,5,5,2"):
        with pytest.raises(SystemExit):
            bench_invert.grid_shape(bad)
    sweep = bench_invert.bench_preset("8,5,5")["sweep"]
    assert [len(v) for v in sweep.values()] == [8, 5, 5]          # 200 scenarios
    assert sweep["medium.inclusions[0].grain_size"][0] == "25 um"
    assert sweep["medium.thickness"][-1] == "1000 mm"
    assert bench_invert.bench_preset(10)["name"] == "bench_invert_10x10x10"
    assert bench_invert.interleaved(["store", "files"], 3) == \
        ["store", "files", "files", "store", "store", "files"]
    assert bench_invert.spread_text([3.0, 1.0, 2.0]) == "2 s [1, 3] (3 rounds)"
    assert bench_invert.spread([0.5]) == {"median": 0.5, "min": 0.5, "max": 0.5, "n": 1}


# --------------------------------------------------------------------------- gpu_check.py

import gpu_check  # noqa: E402


def test_gpu_check_plan_has_every_step_on_the_device(tmp_path):
    """The seven steps in order, each pointed at the device (the tests through
    $WARPE_CL_DEVICE, the tools through --device); MCX skipped, and said so, without pmcx;
    the whole suite only with --suite."""
    steps = gpu_check.plan("2:0", tmp_path, quick=False, mcx=None, python="py")
    assert [s.name for s in steps] == ["devices", "tests", "bench", "fill", "mcx", "paper",
                                       "suite"]
    assert all(s.env["WARPE_CL_DEVICE"] == "2:0" for s in steps)
    devices, tests, bench_, fill, mcx, paper, suite = steps
    assert suite.skip
    assert fill.command[fill.command.index("--photons") + 1] == "1e+07"
    assert fill.command[fill.command.index("--scenes") + 1] == "B1,T1"
    assert devices.command[-3:] == ["--requalify", "--device", "2:0"]
    assert set(gpu_check.TEST_FILES) <= set(tests.command) and "-k" not in tests.command
    assert "analog,weighted" in bench_.command and "--scenes" not in bench_.command
    assert bench_.command[bench_.command.index("--rounds") + 1] == "3"
    assert mcx.skip and "pmcx" in mcx.skip
    assert paper.command[paper.command.index("--photons") + 1] == "1e+06"
    assert "--only" not in paper.command and str(tmp_path / "paper" / "data") in paper.command
    quick = gpu_check.plan("0:0", tmp_path, quick=True, mcx="pmcx", python="py")
    assert "-k" in quick[1].command and quick[4].skip is None and "--only" in quick[5].command


def test_gpu_check_keeps_the_callers_pythonpath(tmp_path):
    """The wheels carried to a lent GPU are installed with --target and found through
    PYTHONPATH: every step sees them after the repository (the steps replaced PYTHONPATH with
    the repository, so pyopencl could not be imported)."""
    steps = gpu_check.plan("0:0", tmp_path, quick=True, mcx=None, python="py",
                           pythonpath=os.pathsep.join(["/tmp/site", "/opt/venv"]))
    assert all(s.env["PYTHONPATH"].split(os.pathsep) ==
               [str(gpu_check.REPO), "/tmp/site", "/opt/venv"] for s in steps)
    bare = gpu_check.plan("0:0", tmp_path, quick=True, mcx=None, python="py", pythonpath="")
    assert bare[0].env["PYTHONPATH"] == str(gpu_check.REPO)


def test_gpu_check_reads_pytest_and_bench():
    assert gpu_check.pytest_counts("...\n3 failed, 131 passed, 2 skipped in 9.10s\n") == {
        "failed": 3, "passed": 131, "skipped": 2}
    assert gpu_check.pytest_counts("no summary") == {}
    result = {"scenes": {"B1": {"opencl": {"scattering_events_per_s": 2e10},
                                "opencl_weighted": {"scattering_events_per_s": 3e10},
                                "ratio_to_mcxcl": 2.5},
                         "T1": {"opencl": {"scattering_events_per_s": 1.8e10}}},
              "tail_over_b1": {"ratio_events_per_s": {"median": 0.9, "min": 0.8, "max": 1.0}}}
    figures = gpu_check.bench_figures(result)
    assert figures == {"B1 analog": 2e10, "B1 weighted": 3e10, "ours/MCX": 2.5,
                       "T1 analog": 1.8e10, "T1/B1": 0.9}
    rows = gpu_check.verdicts(figures, paper_s=29.5)
    assert [ok for _, _, ok in rows] == [True, True, False]
    lines = gpu_check.summary_lines("2:0", [{"name": "mcx", "skip": "no pmcx"},
                                            {"name": "paper", "rc": 0, "wall_s": 29.5}],
                                    figures, quick=False)
    assert "| mcx | skipped | 0.0 | no pmcx |" in lines and "| paper < 5.0 s | 29.5 | NO |" in lines


def test_gpu_check_mcx_venv_sees_the_callers_packages():
    """MCX's venv is told where this Python's packages are: PYTHONPATH's folders (the wheels
    carried to a lent GPU, pmcx among them) and its site-packages; bench.py drops PYTHONPATH
    for MCX's runs, so that pmcx could not be imported there."""
    paths = gpu_check.caller_paths(os.pathsep.join(["/tmp/site", "", "/opt/x"]),
                                   ["/opt/venv/site-packages", "/tmp/site"])
    assert paths == ["/tmp/site", "/opt/x", "/opt/venv/site-packages"]


def test_gpu_check_refuses_bad_input(capsys):
    for argv in (["--device", "gpu0"], ["--photons", "0"], ["--limit", "0"]):
        with pytest.raises(SystemExit) as err:
            gpu_check.parse_args(argv)
        assert err.value.code == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert gpu_check.mcx_available(lambda name: None) is None
    assert gpu_check.mcx_available(lambda name: name == "pmcx" or None) == "pmcx"


def test_gpu_check_makes_the_mcx_venv_where_warpe_cl_is_not_installed(tmp_path):
    """On a lent GPU the project is not installed, only its wheels: the pmcx stand-in's
    version comes from tools/studies/mcxcl_compare.py, which imports warpe_cl, and the check
    stopped there (ModuleNotFoundError) before its first step. A Python started with -S
    (no site-packages, so no installed warpe_cl, editable or not) that sees numpy alone,
    through a folder of links to numpy's own, makes the venv."""
    import numpy
    site = os.path.dirname(os.path.dirname(numpy.__file__))
    alone = tmp_path / "numpy_alone"
    alone.mkdir()
    for name in ("numpy", "numpy.libs"):
        if os.path.exists(os.path.join(site, name)):
            (alone / name).symlink_to(os.path.join(site, name))
    code = ("import sys; from pathlib import Path; "
            f"sys.path[:0] = [{str(BENCH)!r}, {str(alone)!r}]; import gpu_check; "
            "gpu_check.mcx_venv(Path('venv'), 'pmcx')")
    out = subprocess.run([sys.executable, "-S", "-c", code], cwd=tmp_path, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    shim = list(tmp_path.glob("venv/lib/python*/site-packages/pmcxcl.py"))
    assert len(shim) == 1 and "from pmcx import *" in shim[0].read_text()


def test_gpu_check_suite_step_is_asked_for_and_names_its_failures(tmp_path):
    """--suite adds the whole test run on the device (-v, a worker per core); without it the
    step is skipped and says how to ask. A run stopped before pytest's summary line (the H200's
    second suite run, at its time limit) still names the tests that failed."""
    steps = gpu_check.plan("0:0", tmp_path, quick=False, mcx=None, python="py", suite=True)
    assert [s.name for s in steps][-1] == "suite" and steps[-1].skip is None
    suite = steps[-1].command
    assert "-v" in suite and suite[suite.index("-n") + 1] == "auto" and "-k" not in suite
    assert steps[-1].env["WARPE_CL_DEVICE"] == "0:0"
    plain = gpu_check.plan("0:0", tmp_path, quick=False, mcx=None, python="py")
    assert "--suite" in plain[-1].skip
    spaced = "tests/test_sweep.py::test_bad[extra2---scheduler: local:0 is not allowed]"
    log = ("[gw0] [ 10%] PASSED tests/test_a.py::test_one\n"
           "[gw1] [ 20%] FAILED tests/test_b.py::test_two[1-x]\n"
           "tests/test_c.py::test_three SKIPPED (no GPU) [ 30%]\n"
           "[gw2] [ 40%] ERROR tests/test_d.py::test_four\n"
           f"[gw3] [ 45%] FAILED {spaced}\n"
           "tests/test_e.py::test_five[ERROR case] PASSED [ 50%]\n"
           "FAILED tests/test_b.py::test_two[1-x] - AssertionError\n"
           "=== 2 failed, 2 passed, 1 skipped, 1 error in 3.0s ===\n")
    counts, failed = gpu_check.pytest_outcomes(log)
    assert counts == {"passed": 2, "failed": 2, "skipped": 1, "error": 1}
    assert failed == ["tests/test_b.py::test_two[1-x]", "tests/test_d.py::test_four", spaced]
    records = [{"name": "suite", "rc": 1, "wall_s": 9.0, "failed_tests": failed}]
    lines = gpu_check.summary_lines("0:0", records, {}, quick=False)
    assert "- tests/test_d.py::test_four" in lines
