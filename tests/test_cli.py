"""The command line: exit codes, one-line errors, the output file of docs/interface.md §5."""
from __future__ import annotations

import shutil
import subprocess
import sys

import numpy as np
import pytest
import xarray as xr

from warpe_cl.cli import main

from conftest import REPO
PRESET = REPO / "presets" / "radiative" / "slab_co2_1m.yaml"

GOOD = """\
medium:
  texture: slab
  thickness: "10 mm"
  radiative: {tau0: 1.0, omega: 0.9, n: 1.3, k: 0.0}
simulation:
  photons: 2000
"""

BAD = {
    "missing_unit": GOOD.replace('"10 mm"', "10"),
    "negative_thickness": GOOD.replace('"10 mm"', '"-10 mm"'),
    "omega_above_one": GOOD.replace("omega: 0.9", "omega: 1.2"),
    "unknown_key": GOOD.replace("texture: slab", "texture: slab\n  thikness: 3"),
    "unknown_texture": GOOD.replace("texture: slab", "texture: slabb"),
    "empty_file": "",
    "not_yaml": "medium: [unclosed\n  texture: : :",
    "top_level_list": "- 1\n- 2\n",
    "wrong_unit_dimension": GOOD.replace('"10 mm"', '"10 deg"'),
    "negative_tau": GOOD.replace("tau0: 1.0", "tau0: -1.0"),
    "n_below_one": GOOD.replace("n: 1.3", "n: 0.5"),
    "photons_zero": GOOD.replace("photons: 2000", "photons: 0"),
    "fov_too_wide": GOOD + "  fov: {scattering: \"95 deg\"}\n",
    "bad_time_bins": GOOD + "  time_bins: {start: \"1 ns\", stop: \"0.1 ns\", per_decade: 10}\n",
    "missing_medium": "simulation:\n  photons: 10\n",
    "unknown_sweep_key": GOOD + "sweep:\n  medium.thicknes: [\"1 mm\"]\n",
    "albedo_text": GOOD.replace("texture: slab", "texture: slab\n  bottom_albedo: high"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_preset_exits_2_with_one_line(tmp_path, capsys, case):
    path = tmp_path / f"{case}.yaml"
    path.write_text(BAD[case])
    rc = main(["run", str(path), "--out", str(tmp_path / "x.nc"), "--device", "numpy"])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err and str(path) in err
    assert not (tmp_path / "x.nc").exists()


@pytest.mark.parametrize("argv", [
    ["run", "no_such_preset.yaml", "--out", "x.nc"],
    ["run", str(PRESET), "--out", "/no/such/folder/x.nc"],
    ["run", str(PRESET), "--out", "x.nc", "--set", "medium.thickness=12"],
    ["run", str(PRESET), "--out", "x.nc", "--set", "nonsense"],
    ["run", str(PRESET), "--out", "x.nc", "--photons", "many"],
    ["run", str(PRESET)],
    ["frobnicate"],
])
def test_bad_command_lines_exit_2(tmp_path, capsys, monkeypatch, argv):
    monkeypatch.chdir(tmp_path)
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err


def test_unknown_device_exits_3(tmp_path, capsys):
    rc = main(["run", str(PRESET), "--out", str(tmp_path / "x.nc"), "--photons", "100",
               "--device", "no-such-device-anywhere"])
    err = capsys.readouterr().err.strip()
    assert rc == 3 and len(err.splitlines()) == 1 and "no OpenCL device matches" in err


@pytest.mark.slow
def test_run_writes_the_dataset_of_the_interface(tmp_path, capsys):
    out, png = tmp_path / "demo.nc", tmp_path / "demo.png"
    rc = main(["run", str(PRESET), "--out", str(out), "--plot", str(png), "--photons", "20000",
               "--seed", "3"])
    text = capsys.readouterr().out
    assert rc == 0
    for word in ("tau0", "first BF time", "fates", "components", "photons/s"):
        assert word in text
    assert png.stat().st_size > 10_000
    ds = xr.load_dataset(out)
    for name in ("time", "time_edges", "component", "reflectance", "ray_count", "undersampled",
                 "hemispherical_reflectance", "fraction", "fate_fraction", "emergence",
                 "angular_reflectance", "photons", "scattering_events", "wall_time"):
        assert name in ds.variables, name
    assert list(ds.component.values) == ["specular", "bf_direct", "bf_diffuse", "scattering"]
    assert list(ds.fate.values) == ["specular", "escaped", "absorbed_medium", "absorbed_floor",
                                    "terminated"]
    assert int(ds.photons) == 20000 and ds.attrs["seed"] == 3
    # The fractions in the file are integer counts over 20000 rays: every ray has one fate, and
    # every ray that left (specular or escaped) is in exactly one component.
    fates = ds.fate_fraction.values * 20000
    components = ds.fraction.values * 20000
    np.testing.assert_allclose(fates, np.rint(fates), rtol=0, atol=1e-6)
    np.testing.assert_allclose(components, np.rint(components), rtol=0, atol=1e-6)
    fates, components = np.rint(fates).astype(int), np.rint(components).astype(int)
    assert fates.sum() == 20000, fates
    assert components.sum() == fates[0] + fates[1], (components, fates)
    for attr in ("tau0", "omega", "n_eff", "k_eff", "extinction_per_m", "first_bf_time_ns",
                 "config", "warpe_cl_version", "opencl_platform", "opencl_device",
                 "opencl_driver", "kernel_sha256"):
        assert attr in ds.attrs, attr
    assert ds.attrs["first_bf_time_ns"] == pytest.approx(9.35714, rel=1e-5)
    assert ds.undersampled.dtype == bool
    # the specular leaves at t = 0, before the first edge (1e-6 ns): an early exit, in no
    # time bin (docs/walk.md §4)
    assert int(ds.ray_count.sel(component="specular").sum()) == 0
    assert float(ds.early_fraction.sel(component="specular")) == float(
        ds.fraction.sel(component="specular")) > 0
    assert not list(tmp_path.glob(".*.tmp*"))  # atomic write left nothing behind


def test_numpy_device_runs_without_opencl(tmp_path, capsys):
    out = tmp_path / "ref.nc"
    rc = main(["run", str(PRESET), "--out", str(out), "--photons", "3000", "--device", "numpy",
               "--quiet"])
    assert rc == 0 and capsys.readouterr().out == ""
    ds = xr.load_dataset(out)
    assert ds.attrs["engine"] == "numpy" and int(ds.photons) == 3000
    assert ds.attrs["precision"] == "double"      # the reference walk's, not the preset's single


def test_sweep_preset_gives_a_scenario_dimension(tmp_path, capsys):
    out = tmp_path / "sweep.nc"
    rc = main(["run", "radiative/slab_tau_sweep", "--out", str(out), "--photons", "3000"])
    assert rc == 0
    ds = xr.load_dataset(out)
    assert ds.sizes["scenario"] == 3
    np.testing.assert_allclose(ds["tau0"].values, [0.2, 2.0, 20.0])
    assert "medium.radiative.tau0" in ds.coords
    assert ds.reflectance.dims == ("scenario", "component", "time")


@pytest.mark.slow
def test_plot_verb(tmp_path, capsys):
    out = tmp_path / "a.nc"
    assert main(["run", str(PRESET), "--out", str(out), "--photons", "5000", "--quiet"]) == 0
    assert main(["plot", str(out), "--out", str(tmp_path / "a.png")]) == 0
    assert (tmp_path / "a.png").stat().st_size > 10_000
    assert main(["plot", str(tmp_path / "missing.nc"), "--out", str(tmp_path / "b.png")]) == 2


def test_show_config_presets_devices(capsys):
    assert main(["show-config", str(PRESET), "--set", "medium.thickness=500 mm"]) == 0
    text = capsys.readouterr().out
    assert "500 mm" in text and "first BF time" in text and "4.67857" in text
    assert main(["presets"]) == 0
    assert "radiative/slab_co2_1m" in capsys.readouterr().out
    assert main(["devices"]) == 0
    assert "picks" in capsys.readouterr().out


def _fake_gpu(monkeypatch, tmp_path, node=True, library=True):
    """A fake NVIDIA GPU for warpe_cl.drivers.unregistered_gpu_hint: its device node and its
    OpenCL library under tmp_path (the probe's places monkeypatched); returns the library."""
    from warpe_cl import drivers
    lib_dir = tmp_path / "lib64"
    lib_dir.mkdir()
    lib = lib_dir / "libnvidia-opencl.so.1"
    if library:
        lib.write_bytes(b"\x7fELF")
    dev = tmp_path / "nvidia0"
    if node:
        dev.write_text("")
    monkeypatch.setattr(drivers, "GPU_DRIVERS", (
        ("NVIDIA", (str(dev),), ("libnvidia-opencl.so.1",), "nvidia.icd"),))
    monkeypatch.setattr(drivers, "GPU_LIBRARY_DIRS", (str(tmp_path / "none"), str(lib_dir)))
    return lib


def test_hint_for_a_gpu_the_loader_does_not_see(monkeypatch, tmp_path):
    """A GPU in /dev and its driver's OpenCL library on disk, but no OpenCL GPU: one line
    naming the library and the OCL_ICD_VENDORS recipe; nothing where OpenCL lists a GPU or
    no GPU is there; what to install where only the device node is."""
    from warpe_cl.drivers import unregistered_gpu_hint
    lib = _fake_gpu(monkeypatch, tmp_path)
    hint = unregistered_gpu_hint(gpu_listed=False)
    assert len(hint.splitlines()) == 1 and str(lib) in hint
    assert "OCL_ICD_VENDORS=" in hint and f"echo {lib} > " in hint and ".icd" in hint
    assert unregistered_gpu_hint(gpu_listed=True) is None
    lib.unlink()
    hint = unregistered_gpu_hint(gpu_listed=False)
    assert "no libnvidia-opencl.so.1 was found" in hint and "nvidia0" in hint


def test_no_hint_without_a_gpu(monkeypatch, tmp_path):
    from warpe_cl.drivers import unregistered_gpu_hint
    _fake_gpu(monkeypatch, tmp_path, node=False, library=False)
    assert unregistered_gpu_hint(gpu_listed=False) is None


def test_devices_says_the_gpu_is_unregistered(monkeypatch, tmp_path, capsys):
    """`warpe-cl devices` with no OpenCL device at all and a GPU on the system: exit 3, the
    install line and the hint."""
    import warpe_cl.device
    lib = _fake_gpu(monkeypatch, tmp_path)
    monkeypatch.setattr(warpe_cl.device, "list_devices", lambda: [])
    assert main(["devices"]) == 3
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("no OpenCL platform found")
    assert lines[1].startswith("hint: an NVIDIA GPU") and str(lib) in lines[1]


def test_python_dash_m_entry_point():
    res = subprocess.run([sys.executable, "-m", "warpe_cl", "show-config", str(PRESET)],
                         capture_output=True, text=True, cwd=REPO)
    assert res.returncode == 0 and "slab_co2_1m" in res.stdout
    res = subprocess.run([sys.executable, "-m", "warpe_cl", "run", "missing.yaml", "--out", "x.nc"],
                         capture_output=True, text=True, cwd=REPO)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1


def test_sweep_file_keeps_units_and_the_whole_preset(tmp_path, capsys):
    out = tmp_path / "sweep.nc"
    assert main(["run", "radiative/slab_tau_sweep", "--out", str(out), "--photons", "2000",
                 "--quiet"]) == 0
    ds = xr.load_dataset(out)
    assert ds["reflectance"].attrs["units"] == "ns-1 sr-1"
    assert ds["time_edges"].dims == ("time_edge",)
    assert "sweep:" in ds.attrs["config"] and ds["scenario_key"].sizes["scenario"] == 3
    assert ds["wall_time"].dims == ("scenario",)


# --------------------------------------------------------------------------- limits, Ctrl-C

@pytest.mark.parametrize("verb", ["run", "sweep"])
@pytest.mark.parametrize("how", [["--photons", "1e30"], ["--photons", "nan"],
                                 ["--photons", "1.5"], ["--photons", "-3"],
                                 ["--set", "simulation.photons=9007199254740993"]])
def test_absurd_photon_counts_exit_2_with_one_line(tmp_path, capsys, verb, how):
    """`--photons 1e30` used to start a run that never ends."""
    out = tmp_path / ("x.nc" if verb == "run" else "db")
    rc = main([verb, str(PRESET), "--out", str(out), "--device", "numpy", *how])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert str(PRESET) in err and "simulation.photons" in err and "rays" in err, err
    assert "2^53" in err, err
    assert not list(tmp_path.iterdir())


def test_ctrl_c_while_drawing_keeps_the_result_and_the_old_figure(tmp_path, capsys, monkeypatch):
    """`run --out X.nc --plot X.png`: the result is written (renamed into place) before the
    figure is drawn; Ctrl-C while drawing leaves X.nc, the older figure as it was and no
    half-written PNG or temporary file, and its one line says what was written."""
    import warpe_cl.plot

    def interrupted(ds, path, title=None):
        with open(path, "wb") as stream:
            stream.write(b"\x89PNG half")
        raise KeyboardInterrupt

    monkeypatch.setattr(warpe_cl.plot, "plot_waveform", interrupted)
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "x.png").write_bytes(b"an older figure")
    rc = main(["run", str(PRESET), "--out", str(folder / "x.nc"), "--plot",
               str(folder / "x.png"), "--photons", "200", "--device", "numpy", "--quiet",
               "--overwrite"])
    err = capsys.readouterr().err.strip()
    assert rc == 130, err
    assert err == f"warpe-cl: interrupted while drawing {folder / 'x.png'}; the result " \
                  f"{folder / 'x.nc'} was written", err
    assert sorted(p.name for p in folder.iterdir()) == ["x.nc", "x.png"]   # no temp file
    assert (folder / "x.png").read_bytes() == b"an older figure"       # left as it was
    assert int(xr.load_dataset(folder / "x.nc").photons) == 200


@pytest.mark.slow
@pytest.mark.parametrize("signame, rc, line", [
    ("SIGINT", 130, "warpe-cl: interrupted"),
    ("SIGTERM", 143, "warpe-cl: stopped by SIGTERM")])
def test_ctrl_c_during_the_walk_exits_130_and_writes_nothing(tmp_path, signame, rc, line):
    """A real `warpe-cl run` walking 1e12 rays (hours) gets SIGINT once it has printed the
    derived parameters, the last lines before the walk: exit 130, one line, no file."""
    import os
    import queue
    import signal
    import threading
    import time

    folder = tmp_path / "out"
    folder.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # a real pipe
    proc = subprocess.Popen(
        [sys.executable, "-m", "warpe_cl", "run", str(PRESET), "--photons", "1e12",
         "--out", str(folder / "x.nc"), "--plot", str(folder / "x.png")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=env)
    lines = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout], daemon=True).start()
    try:
        seen = []
        deadline = time.monotonic() + 30     # the lines must come as printed (flushed)
        while not any("specular R0" in x for x in seen) and time.monotonic() < deadline:
            try:
                seen.append(lines.get(timeout=max(0.0, deadline - time.monotonic())))
            except queue.Empty:
                break
        assert any("specular R0" in x for x in seen), "no derived parameters: " + "".join(seen)
        time.sleep(0.5)                      # into the walk: it prints nothing more until done
        assert proc.poll() is None, "the run ended before it was interrupted"
        t0 = time.monotonic()
        proc.send_signal(getattr(signal, signame))
        proc.wait(timeout=30)                # stdout is drained by the thread above
        err = proc.stderr.read()
        elapsed = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == rc, err
    # a device's first use qualifies it and says so (two lines per combination, cached
    # after): on a fresh cache the signal may land there, as it may in the walk
    said = [x for x in err.splitlines() if not x.startswith(("warpe-cl: warning:",
                                                             "warpe-cl: qualifying "))
            and not x.strip().startswith("qualified:")]
    assert said == [line], err                                    # one line, no traceback
    assert list(folder.iterdir()) == []                           # no .nc, .png or temp file
    assert elapsed < 5                                            # stops within a launch


@pytest.mark.parametrize("verb", ["run", "instrument"])
def test_out_must_be_a_netcdf_name(tmp_path, capsys, verb):
    """`run --out x.png` used to write NetCDF into x.png and exit 0."""
    out = tmp_path / "x.png"
    args = (["run", str(PRESET), "--device", "numpy"] if verb == "run" else
            ["instrument", str(tmp_path / "surface.nc"), "--instrument", "bela"])
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"warpe-cl: error: --out: {out} is not a NetCDF file name; give a name " \
                  "ending in .nc", err
    assert not list(tmp_path.iterdir())


def test_presets_show_prints_a_bundled_preset(capsys):
    from warpe_cl.catalog import bundled_presets
    assert main(["presets", "--show", "paper/slab_h2o_thickness"]) == 0
    out = capsys.readouterr().out
    assert out == bundled_presets()["paper/slab_h2o_thickness"].read_text().rstrip() + "\n"
    assert main(["presets", "--show", "bela"]) == 0                  # a unique stem
    assert "name: bela" in capsys.readouterr().out
    assert main(["presets", "--show", "paper/slab_h2o_thicknes"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "did you mean paper/slab_h2o_thickness" in err, err


def test_show_config_derived_lengths_one_minus_omega_and_what_applies(capsys):
    """omega 0.999997 hides 1 - omega: printed, with the mean free path and the absorption
    length; a granular medium shows no bottom_interface (it has no interfaces)."""
    assert main(["show-config", "paper/gran_co2_thickness"]) == 0
    out = capsys.readouterr().out
    assert "bottom_interface" not in out
    derived = [x[3:] for x in out.splitlines() if x.startswith("#  ")]
    lines = {label: next(x for x in derived if x.startswith(label + " "))
             for label in ("omega", "1 - omega", "extinction", "mean free path",
                           "absorption length")}
    omega = float(lines["omega"].split()[-1])
    one_minus = float(lines["1 - omega"].split()[-1])
    assert omega > 0.999 and 0 < one_minus < 1e-3
    ext = float(lines["extinction"].split()[-2])
    mfp = lines["mean free path"].split()
    assert mfp[-2] == "um" and float(mfp[-3]) == pytest.approx(1e6 / ext, rel=1e-3)
    absl = lines["absorption length"].split()
    assert absl[-5] == "m" and float(absl[-6]) == pytest.approx(1 / (one_minus * ext), rel=1e-2)
    assert main(["show-config", "paper/slab_h2o_thickness"]) == 0
    assert "bottom_interface: fresnel" in capsys.readouterr().out       # a slab: it applies


def test_show_config_says_when_proportions_are_rescaled(capsys):
    inc = ('medium.inclusions=[{material: CO2, proportion: 3, grain_size: "200 um"}, '
           '{material: H2O, proportion: 1, grain_size: "200 um"}]')
    assert main(["show-config", "paper/gran_co2_thickness", "--set", inc]) == 0
    out = capsys.readouterr().out
    assert "proportions given sum to 4: rescaled to sum to 1 (3 -> 0.75, 1 -> 0.25)" in out
    assert main(["show-config", "paper/gran_co2_thickness"]) == 0
    assert "rescaled" not in capsys.readouterr().out


def test_the_speed_excludes_the_kernel_build():
    """First use: 2 s of kernel build, 0.5 s of walk for 1e6 rays: 2,000,000 photons/s,
    not 1e6 / 2.6 s; the build is said apart."""
    from warpe_cl import report
    ds = xr.Dataset({"photons": ((), 1_000_000), "wall_time": ((), 2.6),
                     "scattering_events": ((), 5_000_000),
                     "fate_fraction": (("fate",), [1.0]), "fraction": (("component",), [1.0])},
                    coords={"fate": ["reflected"], "component": ["diffuse"]})
    line = report.scenario_lines(ds, build_s=2.0, walk_s=0.5)[-1]
    assert "2.60 s, kernel build 2.0 s (first use), walk 0.50 s" in line, line
    assert "2,000,000 photons/s" in line and "10,000,000 scattering events/s" in line, line
    line = report.scenario_lines(ds, build_s=2.0)[-1]          # no walk time: wall less build
    assert "1,666,667 photons/s" in line, line
    line = report.scenario_lines(ds, build_s=0.001, walk_s=None)[-1]   # built: nothing said
    assert "kernel build" not in line and "384,615 photons/s" in line, line


def test_run_reports_the_walk_and_the_engine_times_it(tmp_path, capsys):
    from warpe_cl import api
    assert main(["run", str(PRESET), "--out", str(tmp_path / "a.nc"), "--photons", "20000"]) == 0
    out = capsys.readouterr().out
    engine = api.get_engine(None)
    assert engine.last_walk_s is not None and engine.last_build_s >= 0
    ds = xr.load_dataset(tmp_path / "a.nc")
    assert engine.last_build_s + engine.last_walk_s <= float(ds["wall_time"])
    time_line = next(x for x in out.splitlines() if x.startswith("  time "))
    assert f"walk {engine.last_walk_s:.2f} s" in time_line, time_line


def test_renames_hold_back_both_stopping_signals():
    """Outputs renames its staged files with SIGINT and SIGTERM (which the command line turns
    into the same KeyboardInterrupt) held back, so neither splits a run's .nc from its .png."""
    import signal
    from warpe_cl.io import _stops_held
    with _stops_held():
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, set())
    assert {signal.SIGINT, signal.SIGTERM} <= set(blocked)
    assert not {signal.SIGINT, signal.SIGTERM} & set(signal.pthread_sigmask(signal.SIG_BLOCK, set()))


@pytest.mark.slow
def test_plot_metrics_of_a_sweep_and_of_an_instrument_file(tmp_path, capsys):
    """`plot --metrics` draws the metrics of a numeric sweep against the swept key (one line
    per component holding something: no specular, which is in no time bin) and those of a
    file written by `instrument`, after the chain, with the noiseless expected values."""
    from conftest import synthetic_surface
    from warpe_cl.plot import metrics_figure
    sweep = tmp_path / "sweep.nc"
    assert main(["run", "radiative/slab_tau_sweep", "--out", str(sweep), "--photons", "3000",
                 "--quiet"]) == 0
    png = tmp_path / "sweep.png"
    assert main(["plot", str(sweep), "--metrics", "--after", "0.1 ns,1 ns",
                 "--out", str(png)]) == 0
    assert png.stat().st_size > 10_000
    fig = metrics_figure(xr.load_dataset(sweep), after=[0.1])
    assert len(fig.axes) == 4 and fig.axes[-1].get_xlabel() == "medium.radiative.tau0"
    legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "scattering" in legend and "specular" not in legend
    surface = tmp_path / "surface.nc"
    synthetic_surface(diffuse_integral=0.05, scenarios=2).to_netcdf(surface, engine="h5netcdf")
    recorded = tmp_path / "bela.nc"
    assert main(["instrument", str(surface), "--instrument", "bela", "--shots", "20",
                 "--out", str(recorded), "--quiet"]) == 0
    png = tmp_path / "bela.png"
    assert main(["plot", str(recorded), "--metrics", "--out", str(png)]) == 0
    assert png.stat().st_size > 10_000
    legend = [t.get_text() for t in metrics_figure(xr.load_dataset(recorded)).axes[0]
              .get_legend().get_texts()]
    assert legend == ["recorded signal", "noiseless expected signal"]


@pytest.mark.parametrize("extra, message", [
    (["--metrics"], "bad.nc: has no time_edges, reflectance"),
    (["--metrics", "--kind", "instrument"], "bad.nc: has no recorded signal"),
    (["--metrics", "--kind", "angular"], "--kind: --metrics draws the waveform metrics"),
    (["--metrics", "--after", "5"], "--after: \"5\" is a bare number with no unit"),
    (["--after", "5 ns"], "--after: applies to --metrics only"),
])
def test_plot_metrics_bad_input_exits_2_with_one_line(tmp_path, capsys, extra, message):
    bad = tmp_path / "bad.nc"
    xr.Dataset({"x": ("y", [1.0, 2.0])}).to_netcdf(bad, engine="h5netcdf")
    rc = main(["plot", str(bad), "--out", str(tmp_path / "x.png"), *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "x.png").exists()


def test_import_leaves_the_inversion_for_later():
    """``import warpe_cl`` (every command's start) does not import the inversion, whose
    scipy imports take time; ``warpe_cl.invert`` loads it on first use. Nor
    do the modules of a run or a sweep worker import scipy (the instrument chain imports it
    where it fits or integrates): 0.24 s against 0.60 s with it."""
    code = ("import sys, warpe_cl\n"
            "assert 'warpe_cl.inversion' not in sys.modules, 'inversion imported'\n"
            "assert 'scipy.signal' not in sys.modules, 'scipy.signal imported'\n"
            "import warpe_cl.api, warpe_cl.sweep\n"      # every run and every sweep worker
            "assert not [m for m in sys.modules if m.startswith('scipy')], 'scipy imported'\n"
            "assert warpe_cl.invert.__module__ == 'warpe_cl.inversion.invert'\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


# --------------------------------------------------------------------------- no signal lost

class _Dropped:
    """An object whose ``__del__`` receives ``signum``: Python drops the exception the
    handler raises there ("Exception ignored in: ..."), as it does in weakref callbacks."""

    def __init__(self, signum):
        self.signum = signum

    def __del__(self):
        import signal
        signal.raise_signal(self.signum)


def _drop_a_signal_in_launch(monkeypatch, signum, launches):
    """Patch the engine so that its first launch's tallies come with ``signum`` delivered
    inside a ``__del__``; ``launches`` counts the launches (one Counts each, after the
    walk's total)."""
    import warpe_cl.engine

    class Counts(warpe_cl.engine.Counts):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            launches.append(1)
            if len(launches) == 2:           # the first launch's part
                _Dropped(signum)             # made and dropped at once: its __del__ runs

    monkeypatch.setattr(warpe_cl.engine, "Counts", Counts)


@pytest.mark.parametrize("signame, rc, line", [
    ("SIGTERM", 143, "warpe-cl: stopped by SIGTERM"),
    ("SIGINT", 130, "warpe-cl: interrupted")])
def test_a_signal_dropped_in_a_del_still_stops_the_run(tmp_path, capsys, monkeypatch,
                                                        signame, rc, line):
    """A SIGTERM whose exception Python dropped (it arrived in a __del__) used to be lost:
    the run went on to exit 0 and wrote its file. It stops the run now, with its one line
    and no "Exception ignored" report, and nothing is written."""
    import signal
    warm = tmp_path / "warm"        # the device qualified and the kernel built beforehand
    warm.mkdir()
    assert main(["run", str(PRESET), "--out", str(warm / "x.nc"), "--photons", "200",
                 "--quiet"]) == 0
    shutil.rmtree(warm)
    capsys.readouterr()
    launches = []
    _drop_a_signal_in_launch(monkeypatch, getattr(signal, signame), launches)
    code = main(["run", str(PRESET), "--out", str(tmp_path / "x.nc"), "--photons", "2000",
                 "--quiet"])
    err = capsys.readouterr().err.strip()
    assert len(launches) >= 2, "the walk did not launch"
    assert code == rc and err == line, err
    assert list(tmp_path.iterdir()) == []
    from warpe_cl import stops
    assert stops.pending() is None                        # said once, then forgotten
    assert signal.getsignal(signal.SIGTERM) is not stops._handler    # handlers put back


def test_the_engine_stops_within_a_launch_after_a_dropped_signal(engine, monkeypatch):
    """Engine.run checks for a stop between its launches: a SIGTERM dropped in the first of
    four launches (batch 500 of 2000 rays) ends the walk before the second."""
    import signal
    from conftest import medium
    from warpe_cl import stops
    launches = []
    _drop_a_signal_in_launch(monkeypatch, signal.SIGTERM, launches)
    previous = stops.install()
    try:
        with pytest.raises(stops.Terminated):
            engine.run(medium(), 2000, batch=500)
    finally:
        stops.restore(previous)
        stops.clear()
    assert len(launches) == 2                             # the total, and one launch


@pytest.mark.parametrize("entry", [["-m", "warpe_cl"],
                                   ["-c", "import sys; from warpe_cl.cli import main; "
                                          "sys.exit(main())"]])
def test_ctrl_c_while_the_modules_load_is_one_line(tmp_path, entry):
    """Ctrl-C while NumPy loads (the first half second of every command) used to print a
    traceback from `import warpe_cl`: one line and 130, by `python -m warpe_cl` and by the
    console entry (which imports warpe_cl.cli, then calls main)."""
    import os
    (tmp_path / "numpy").mkdir()
    (tmp_path / "numpy" / "__init__.py").write_text("raise KeyboardInterrupt\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(tmp_path), *filter(None, [os.environ.get("PYTHONPATH")])])}
    done = subprocess.run([sys.executable, *entry, "run", str(PRESET), "--out",
                           str(tmp_path / "x.nc")], capture_output=True, text=True,
                          cwd=tmp_path, env=env, timeout=60)
    assert done.returncode == 130 and done.stderr == "warpe-cl: interrupted\n", done.stderr
    assert not (tmp_path / "x.nc").exists()


@pytest.mark.parametrize("raised, rc, line", [
    ("CancelledError", 1, "warpe-cl: error: CancelledError: the scheduler went away (set "
                          "WARPE_CL_DEBUG=1 for the traceback)"),
    ("KeyboardInterrupt", 130, "warpe-cl: interrupted")])
def test_a_dask_shutdown_is_one_line(tmp_path, capsys, monkeypatch, raised, rc, line):
    """A Dask client closing under Ctrl-C raises asyncio's CancelledError (a BaseException)
    or a KeyboardInterrupt from its clean-up: one line, never a traceback."""
    import asyncio
    import warpe_cl.sweep

    def run_sweep(*args, **kwargs):
        if raised == "CancelledError":
            raise asyncio.CancelledError("the scheduler\nwent away")
        raise KeyboardInterrupt
    monkeypatch.setattr(warpe_cl.sweep, "run_sweep", run_sweep)
    assert main(["sweep", str(PRESET), "--out", str(tmp_path / "db")]) == rc
    assert capsys.readouterr().err == line + "\n"


# --------------------------------------------------------------------------- inert, bounded lines

def test_an_error_line_is_escaped_and_bounded(tmp_path, capsys):
    """A 1 MB value used to give a 1 MB error line, and an escape sequence in it reached the
    terminal: the line is now at most 500 characters, control characters written as \\x1b,
    and it still names the file, the key and what is allowed."""
    value = "\x1b[31m" + "x" * 1_000_000
    rc = main(["run", str(PRESET), "--out", str(tmp_path / "x.nc"), "--device", "numpy",
               "--set", f"medium.texture={value}"])
    err = capsys.readouterr().err
    assert rc == 2 and err.endswith("\n") and len(err.splitlines()) == 1, err[:1000]
    line = err.rstrip("\n")
    assert len(line) <= 500, len(line)
    assert "\x1b" not in line and "\\x1b[31mxxx" in line, line
    assert line.startswith(f"warpe-cl: error: {PRESET}: medium.texture: "), line
    assert "characters)" in line and line.endswith("give one of slab, granular"), line


def test_a_file_echoed_in_an_error_is_bounded(tmp_path, capsys):
    """`run /etc/passwd` printed the whole file in its error line; a text that is the whole
    preset is now named by its length, not echoed."""
    preset = tmp_path / "passwd"
    preset.write_text(" ".join(f"user{i}:x:{i}:{i}::/home/user{i}:/bin/sh" for i in range(200)))
    rc = main(["run", str(preset), "--out", str(tmp_path / "x.nc"), "--device", "numpy"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and len(err) <= 500, err
    assert str(preset) in err and "one text of 7," in err and "user" not in err, err


def test_names_read_from_a_file_reach_the_terminal_inert(tmp_path, capsys):
    """The instrument's name and the scenarios' labels that `instrument` and `invert` print
    come from files; an ESC or a line break in them is printed escaped."""
    from conftest import synthetic_database, synthetic_surface
    from warpe_cl import report
    from warpe_cl.instrument import apply_instrument
    ds = apply_instrument(synthetic_surface(diffuse_integral=0.05), "bela", shots=4, seed=1)
    ds.attrs["instrument_name"] = "bela\x1b]0;title\x07\nfake line"
    lines = report.instrument_lines(ds)
    assert lines[0].startswith("instrument bela\\x1b]0;title\\x07\\nfake line:"), lines[0]
    assert not any(ch in "".join(lines) for ch in "\x1b\x07\n")
    ds.to_netcdf(tmp_path / "obs.nc", engine="h5netcdf")
    # a name that would clear the screen
    database = synthetic_database(tmp_path / "db\x1b[2J.nc")
    rc = main(["invert", str(tmp_path / "obs.nc"), "--database", str(database), "--instrument",
               "bela", "--out", str(tmp_path / "fit.nc")])
    out = capsys.readouterr().out
    assert rc == 0 and "\x1b" not in out, out
    assert f"database {tmp_path}/db\\x1b[2J.nc" in out.splitlines()[0], out
