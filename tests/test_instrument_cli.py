"""The `instrument` verb, the `instrument:` block of `run`, `plot --kind instrument`, and one
small OpenCL run through the chain (a Lambertian floor must give ∫R_d dt = A/π)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr

from warpe_cl.cli import main
from conftest import synthetic_surface

LAMBERT = """\
name: lambert
medium:
  texture: granular
  thickness: "1 mm"
  radiative: {tau0: 0.0, omega: 0.5, n: 1.0, k: 0.0}
  bottom_albedo: 0.5
simulation:
  photons: 20000
  fov: {bf_diffuse: "60 deg"}
  solid_angle: projected
  time_bins: {start: "1e-3 ns", stop: "100 ns", per_decade: 10}
instrument:
  name: bela
  altitude: "400 km"
  shots: 4
"""


@pytest.fixture
def surface_file(tmp_path):
    path = tmp_path / "surface.nc"
    synthetic_surface(diffuse_integral=0.05, f_spec=0.028, f_bf=0.026).to_netcdf(path, engine="h5netcdf")
    return path


def test_lambertian_floor_run_with_instrument_block(tmp_path, capsys, engine):
    """A transparent layer over a Lambertian floor of albedo A = 0.5: the walk's diffuse
    response integrates to A/π, and the `instrument:` block writes the chain into the same
    file. Rays in the 60° FOV ~ Binomial(N, A sin²60°), relative sd sqrt((1−p)/(Np)) = 0.91 %
    for N = 2e4: 5 sigma is 4.6 %."""
    preset = tmp_path / "lambert.yaml"
    preset.write_text(LAMBERT)
    out = tmp_path / "out.nc"
    rc = main(["run", str(preset), "--out", str(out), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    ds = xr.load_dataset(out, engine="h5netcdf")
    width = np.diff(ds["time_edges"].values)
    integral = float(((ds["reflectance"].sel(component="bf_diffuse")
                       + ds["reflectance"].sel(component="scattering")) * width).sum())
    p = 0.5 * math.sin(math.radians(60)) ** 2
    assert abs(integral / (0.5 / math.pi) - 1) < 5 * math.sqrt((1 - p) / (20000 * p))
    # the chain uses the nadir estimate (docs/walk.md §8), which this file has; it reads A/pi
    # too: every floor reflection (probability A) scores 1/pi, binomial relative sd
    # sqrt((1 - A) / (N A)) = 0.71 % for N = 2e4: 5 sigma is 3.5 %
    assert ds.attrs["instrument_diffuse_estimate"] == "nadir"
    integral = float(((ds["nadir_reflectance"].sel(component="bf_diffuse")
                       + ds["nadir_reflectance"].sel(component="scattering")) * width).sum())
    assert abs(integral / (0.5 / math.pi) - 1) < 5 * math.sqrt(0.5 / (20000 * 0.5))
    photons = float(ds["photons_at_aperture"].sel(part="diffuse"))
    from warpe_cl.instrument import load_instrument, radiometry
    assert photons == pytest.approx(radiometry.photons_per_reflectance(
        load_instrument("bela", {"geometry.altitude": "400 km"})) * integral, rel=1e-9)
    assert ds["signal_mv"].shape == (4, ds.sizes["sample_time"])
    assert ds.attrs["instrument_geometry_altitude"] == "400 km"
    assert "instrument_created_utc" in ds.attrs and "config" in ds.attrs


@pytest.mark.slow
def test_instrument_verb_writes_the_outputs(tmp_path, surface_file, capsys):
    out = tmp_path / "bela.nc"
    png = tmp_path / "bela.png"
    rc = main(["instrument", str(surface_file), "--instrument", "bela", "--altitude", "500km",
               "--roughness", "0.01 deg", "--shots", "3", "--seed", "2", "--out", str(out),
               "--plot", str(png)])
    assert rc == 0, capsys.readouterr().err
    ds = xr.load_dataset(out, engine="h5netcdf")
    for name in ("sample_time", "signal_mv", "expected_mv", "detected", "range_time",
                 "pulse_width", "reflectance"):
        assert name in ds.variables, name
    assert ds["signal_mv"].dims == ("shot", "sample_time")
    assert ds["sample_time"].attrs["units"] == "ns" and ds["signal_mv"].attrs["units"] == "mV"
    assert ds.attrs["instrument_geometry_roughness"] == "0.01 deg"
    assert ds.attrs["instrument_seed"] == 2
    assert png.stat().st_size > 10000
    png2 = tmp_path / "again.png"
    assert main(["plot", str(out), "--out", str(png2)]) == 0          # detects the kind
    assert main(["plot", str(out), "--out", str(png2), "--kind", "instrument",
                 "--overwrite"]) == 0


@pytest.mark.parametrize("extra, message", [
    (["--instrument", "bela", "--altitude", "-500 km"], "geometry.altitude: -500 km is not allowed"),
    (["--instrument", "bela", "--altitude", "500"], "bare number"),
    (["--instrument", "hubble"], "unknown instrument 'hubble'"),
    (["--instrument", "atlas"], "computed at 1064 nm but atlas works at 532 nm"),
    (["--instrument", "bela", "--shots", "0"], "--shots"),
    (["--instrument", "bela", "--shots", "1e30"], "--shots: 1e30 shots is not allowed; give a whole number of shots in [1, 1000000]"),
    (["--instrument", "bela", "--shots", "2000000"], "--shots: 2000000 shots is not allowed"),
    (["--instrument", "bela", "--shots", "nan"], "--shots: nan is not a finite number; give a whole number of shots in [1, 1000000]"),
    (["--instrument", "bela", "--shots", "inf"], "--shots: inf is not a finite number"),
    (["--instrument", "bela", "--shots", "1.5"], "--shots: 1.5 shots is not a whole number; give a whole number of shots in [1, 1000000]"),
    (["--instrument", "bela", "--seed", "1e30"], "--seed: 1e30 is not allowed"),
    (["--instrument", "bela", "--roughness", "0.1 mm"], "roughness"),
])
def test_bad_instrument_input_exits_2_with_one_line(tmp_path, surface_file, capsys, extra, message):
    rc = main(["instrument", str(surface_file), *extra, "--out", str(tmp_path / "x.nc")])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err and message in err, err
    assert not (tmp_path / "x.nc").exists()


def test_result_without_the_needed_variables_exits_2(tmp_path, capsys):
    bad = tmp_path / "bad.nc"
    synthetic_surface(0.05).drop_vars(["ray_count"]).to_netcdf(bad, engine="h5netcdf")
    rc = main(["instrument", str(bad), "--instrument", "bela", "--out", str(tmp_path / "x.nc")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "has no ray_count" in err, err
    rc = main(["instrument", str(tmp_path / "missing.nc"), "--instrument", "bela",
               "--out", str(tmp_path / "x.nc")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "no such file" in err


def test_bad_instrument_block_fails_before_the_walk(tmp_path, capsys):
    preset = tmp_path / "p.yaml"
    preset.write_text(LAMBERT.replace("name: bela", "name: belaa"))
    rc = main(["run", str(preset), "--out", str(tmp_path / "x.nc"), "--device", "numpy"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "unknown instrument" in err, err
    preset.write_text(LAMBERT.replace("shots: 4", "electronics: {transimpedance: 5}"))
    rc = main(["run", str(preset), "--out", str(tmp_path / "x.nc"), "--device", "numpy"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "electronics.transimpedance" in err and str(preset) in err, err


@pytest.mark.parametrize("shots", [0, 1e30, 2_000_000, float("nan"), float("inf"), 1.5, "many"])
def test_apply_instrument_checks_shots(shots):
    """The Python API has the instrument's limits too (shots in [1, 1e6]): a NaN used to raise
    ValueError from int(), 1e30 to try to allocate 1e30 shots."""
    from warpe_cl.errors import ConfigError
    from warpe_cl.instrument import apply_instrument
    with pytest.raises(ConfigError, match=r"^<dataset>: shots: .*(allowed|finite|whole|number)"):
        apply_instrument(synthetic_surface(0.05), "bela", shots=shots)


def test_nan_in_an_instrument_preset_is_a_config_error():
    from warpe_cl.errors import ConfigError
    from warpe_cl.instrument import load_instrument
    for key, value in (("shots", float("nan")), ("seed", float("inf")),
                       ("speckle.modes", float("nan"))):
        with pytest.raises(ConfigError, match=f"instrument.{key}"):
            load_instrument("bela", {key: value})


# --------------------------------------------------------------------------- issue 11

def _one_line_exit_2(capsys, argv, *fragments):
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for fragment in fragments:
        assert fragment in err, err
    return err


def test_duplicate_key_in_an_instrument_file_is_refused(tmp_path, surface_file, capsys):
    """yaml.safe_load kept the last of two keys: a bela.yaml copy with `shots: 100` then
    `shots: 5` ran 5 shots without a word. Instrument files are read as presets are."""
    from warpe_cl.errors import ConfigError
    from warpe_cl.instrument import load_instrument
    from warpe_cl.config.instrument_fields import instruments_dir
    text = (instruments_dir() / "bela.yaml").read_text()
    assert "\nshots: 100" in text
    dup = tmp_path / "bela_dup.yaml"
    dup.write_text(text.replace("\nshots: 100", "\nshots: 100\nshots: 5", 1))
    line = text[:text.index("\nshots: 100")].count("\n") + 3       # the second shots line
    with pytest.raises(ConfigError) as info:
        load_instrument(str(dup))
    assert str(info.value) == (f'{dup}: not valid YAML (line {line}, column 1: the key '
                               f'"shots" is given twice)')
    _one_line_exit_2(capsys, ["instrument", str(surface_file), "--instrument", str(dup),
                              "--out", str(tmp_path / "x.nc")],
                     str(dup), 'the key "shots" is given twice')
    assert not (tmp_path / "x.nc").exists()
    # the same file named by a scenario preset's block fails when the preset is loaded
    preset = tmp_path / "p.yaml"
    preset.write_text(LAMBERT.replace("name: bela", f"name: {dup}"))
    _one_line_exit_2(capsys, ["run", str(preset), "--out", str(tmp_path / "x.nc"),
                              "--device", "no-such-device"], 'the key "shots" is given twice')
    # a key given both in its section and dotted is refused too
    with pytest.raises(ConfigError, match=r"instrument\.geometry\.altitude: given twice"):
        load_instrument({**load_instrument_raw(), "geometry.altitude": "400 km"})


def load_instrument_raw() -> dict:
    import yaml
    from warpe_cl.config.instrument_fields import instruments_dir
    return yaml.safe_load((instruments_dir() / "bela.yaml").read_text())


@pytest.mark.parametrize("overrides, message", [
    ({"detector.type": "apdd"},
     "instrument.detector.type: apdd is not allowed; give one of apd, photon_counting "
     "(did you mean apd?)"),
    ({"electronics.filter": "besel4"},
     "instrument.electronics.filter: besel4 is not allowed; give one of gaussian, bessel4 "
     "(did you mean bessel4?)"),
    ({"geometry.lobe_modl": "gaussian"},
     "instrument.geometry.lobe_modl: unknown key; did you mean geometry.lobe_model?"),
    ({"altitude": "400 km"},
     "instrument.altitude: unknown key; did you mean geometry.altitude?"),
    ({"geometry.shots": 5}, "instrument.geometry.shots: unknown key here; did you mean shots?"),
    ({"geometry.altitude": "-5 km"},
     'instrument.geometry.altitude: -5 km is not allowed; give a length > 0 with a unit, '
     'e.g. "500 km"'),
    ({"transmitter.pulse_energy": "50 mj"},
     'instrument.transmitter.pulse_energy: "50 mj" has an unknown unit "mj" (did you mean mJ?)'),
    ({"electronics.bandwidth": "33 ns"},
     'instrument.electronics.bandwidth: "33 ns" is a time (ns), not a frequency; give a '
     'frequency > 0 with a unit, e.g. "3.3e+07 Hz" (units: Hz, kHz, MHz, GHz)'),
    ({"receiver.efficiency": 1.5},
     "instrument.receiver.efficiency: 1.5 is not allowed; give a number in [0, 1]"),
    ({"speckle.modes": "many"},
     "instrument.speckle.modes: many is not a number; give auto or a number >= 0"),
    ({"adc.random_phase": "yes please"},
     "instrument.adc.random_phase: yes please is not allowed; give true or false"),
    ({"geometry": 5}, "instrument.geometry: 5 is not a mapping; give a mapping with keys "
                      "among altitude, pointing"),
])
def test_instrument_messages_name_key_value_and_what_is_allowed(overrides, message):
    """Instrument values go through the presets' checks: one line with the key, the value
    as written, its unit and what is allowed, and a did-you-mean or choice hint."""
    from warpe_cl.errors import ConfigError
    from warpe_cl.instrument import load_instrument
    with pytest.raises(ConfigError) as info:
        load_instrument("bela", overrides, override_source="p.yaml")
    text = str(info.value)
    assert "\n" not in text and text.startswith("p.yaml: " + message), text


def test_instrument_block_hints_exit_2_before_the_walk(tmp_path, capsys):
    preset = tmp_path / "p.yaml"
    preset.write_text(LAMBERT.replace("shots: 4", "detector: {type: apdd}"))
    _one_line_exit_2(capsys, ["run", str(preset), "--out", str(tmp_path / "x.nc"),
                              "--device", "no-such-device"],
                     f"{preset}: instrument.detector.type: apdd is not allowed; give one of "
                     "apd, photon_counting (did you mean apd?)")
    preset.write_text(LAMBERT.replace("shots: 4", "shotz: 4"))
    _one_line_exit_2(capsys, ["show-config", str(preset)],
                     "instrument.shotz: unknown key; did you mean shots?")
    preset.write_text(LAMBERT.replace("  name: bela\n", ""))
    _one_line_exit_2(capsys, ["run", str(preset), "--out", str(tmp_path / "x.nc")],
                     "instrument.altitude: is given without instrument.name")
    preset.write_text(LAMBERT.replace("shots: 4", "geometry: {altitude: \"300 km\"}"))
    _one_line_exit_2(capsys, ["run", str(preset), "--out", str(tmp_path / "x.nc")],
                     "instrument.altitude: given twice (as instrument.altitude and "
                     "instrument.geometry.altitude)")
    preset.write_text(LAMBERT.replace("name: bela", "name: atlas"))
    _one_line_exit_2(capsys, ["run", str(preset), "--out", str(tmp_path / "x.nc")],
                     "instrument.name: atlas works at 532 nm but the surface is computed at "
                     "1064 nm")
    assert not (tmp_path / "x.nc").exists()


def test_instrument_block_defaults_are_the_instrument_presets():
    """Absent altitude and roughness: the instrument preset's own values (ATLAS 496 km, not
    a schema default of 500 km); given, they replace geometry.altitude / geometry.roughness.
    docs/config.md says the same (the default column of the schema table)."""
    from warpe_cl.config import FIELDS, load_preset
    from warpe_cl.instrument import load_instrument
    from warpe_cl.config.instrument_fields import scenario_instrument
    base = yaml_load(LAMBERT)
    for name, wavelength, altitude in (("bela", "1064 nm", 500e3), ("gala", "1064 nm", 500e3),
                                       ("atlas", "532 nm", 496e3)):
        raw = {**base, "wavelength": wavelength, "instrument": {"name": name}}
        cfg = load_preset(raw)
        assert cfg.get("instrument.altitude") is None and cfg.get("instrument.roughness") is None
        params = scenario_instrument(cfg)
        assert params == load_instrument(name)
        assert params["geometry.altitude"] == altitude
        shown = f"{name.upper()} {altitude / 1e3:g} km"
        assert shown in FIELDS["instrument.altitude"].default_doc
        assert f"{params['geometry.roughness']:g} deg" in FIELDS["instrument.roughness"].default_doc
        raw["instrument"].update(altitude="401.5 km", roughness="0.02 deg", shots=3)
        params = scenario_instrument(load_preset(raw))
        assert params["geometry.altitude"] == 401.5e3 and params["geometry.roughness"] == 0.02
        assert params["shots"] == 3
    assert scenario_instrument(load_preset({k: v for k, v in base.items()
                                            if k != "instrument"})) is None
    # the block's limits are the instrument table's: a bad value names the preset's key
    from warpe_cl.config.instrument_fields import PARAMS
    for key, target in (("altitude", "geometry.altitude"), ("roughness", "geometry.roughness")):
        mine, theirs = FIELDS[f"instrument.{key}"], PARAMS[target]
        assert (mine.kind, mine.low, mine.high, mine.low_open, mine.high_open) == \
            (theirs.kind, theirs.low, theirs.high, theirs.low_open, theirs.high_open)


def yaml_load(text: str) -> dict:
    import yaml
    return yaml.safe_load(text)


POINTS = LAMBERT.replace("photons: 20000", "photons: 3000").replace(
    "  shots: 4\n", "  shots: 3\n") + """\
sweep:
  medium.bottom_albedo: [0.3, 0.6]
  simulation.seed: [1, 2]
"""


@pytest.mark.slow
def test_point_instrument_bits_are_the_same_every_way(tmp_path, capsys, engine):
    """A point's instrument variables are the same bits from `warpe-cl run` of the whole grid,
    from warpe_cl.simulate and from `warpe-cl sweep` (each scenario's file): the noise of a
    shot is keyed by the point's seed and scenario key, not by its place in the grid."""
    import warpe_cl
    from warpe_cl.instrument.output import VARIABLES
    preset = tmp_path / "points.yaml"
    preset.write_text(POINTS)
    assert main(["run", str(preset), "--out", str(tmp_path / "run.nc"), "--quiet"]) == 0, \
        capsys.readouterr().err
    run = xr.load_dataset(tmp_path / "run.nc", engine="h5netcdf")
    api = warpe_cl.simulate(warpe_cl.load_preset(preset), progress=False)
    assert main(["sweep", str(preset), "--out", str(tmp_path / "db"), "--quiet"]) == 0, \
        capsys.readouterr().err
    files = sorted((tmp_path / "db").glob("s*.nc"))
    assert len(files) == run.sizes["scenario"] == 4
    names = [n for n in VARIABLES if n in run.variables]
    assert {"signal_mv", "speckle_factor", "sampling_phase", "range_time"} <= set(names)
    for i, path in enumerate(files):
        point = xr.load_dataset(path, engine="h5netcdf")
        assert point.attrs["instrument_geometry_altitude"] == "400 km"
        for name in names:
            a = run[name].isel(scenario=i).values if "scenario" in run[name].dims \
                else run[name].values
            b = api[name].isel(scenario=i).values if "scenario" in api[name].dims \
                else api[name].values
            assert np.array_equal(a, b, equal_nan=True), (i, name)
            assert np.array_equal(a, point[name].values, equal_nan=True), (i, name)
    # the two seeds of one albedo: the same scenario key, different noise
    assert run["scenario_key"].values[0] == run["scenario_key"].values[1]
    assert not np.array_equal(run["speckle_factor"].values[0], run["speckle_factor"].values[1])
    db = warpe_cl.open_database(tmp_path / "db")
    assert np.array_equal(db["signal_mv"].values, run["signal_mv"].values)


def test_combined_scenarios_pad_photon_time_tags():
    """Per-scenario instrument results of a photon-counting instrument hold different numbers
    of time tags: combining them pads with NaN, as the instrument's own output does."""
    from warpe_cl import dataset
    edges = ("time_edge", np.arange(3.0))
    a = xr.Dataset({"photon_time": (("shot", "photon"), np.ones((2, 3), np.float32)),
                    "time_edges": edges}, attrs={"seed": 1})
    b = xr.Dataset({"photon_time": (("shot", "photon"), np.full((2, 5), 2.0, np.float32)),
                    "time_edges": edges}, attrs={"seed": 1})
    out = dataset.combine_scenarios([a, b], [{"k": 1}, {"k": 2}])
    assert out["photon_time"].shape == (2, 2, 5) and out["photon_time"].dtype == np.float32
    assert np.isnan(out["photon_time"].values[0, :, 3:]).all()
    assert (out["photon_time"].values[1] == 2.0).all()


@pytest.mark.slow
def test_swept_altitude_is_reported_per_scenario(tmp_path, capsys):
    preset = tmp_path / "swept.yaml"
    preset.write_text('name: swept\nmedium: {texture: granular, thickness: "10 mm", '
                      'radiative: {tau0: 1.0, omega: 0.9, n: 1.3}}\nsimulation: {photons: 500}\n'
                      'instrument: {name: bela, shots: 2}\n'
                      'sweep: {instrument.altitude: ["400 km", "500 km"]}\n')
    assert main(["run", str(preset), "--out", str(tmp_path / "s.nc")]) == 0
    out = capsys.readouterr().out
    assert "instrument bela: altitude per scenario, roughness 0.1 deg, 2 shots" in out
    assert "None" not in out
    ds = xr.load_dataset(tmp_path / "s.nc")          # a swept instrument key is numeric too
    assert list(ds["instrument.altitude"].values) == [4e5, 5e5]
    assert ds["instrument.altitude"].attrs["units"] == "m"


# --------------------------------------------------------------------------- overrides

def test_an_instrument_file_starts_from_a_bundled_one_with_base(tmp_path, capsys):
    """`base: gala` plus a pulse width: GALA's every key, the file's on top."""
    from warpe_cl.instrument import load_instrument
    path = tmp_path / "short.yaml"
    path.write_text('base: gala\nname: gala-short\ntransmitter:\n  pulse_fwhm: "3 ns"\n')
    p, gala = load_instrument(str(path)), load_instrument("gala")
    assert p["name"] == "gala-short" and p["transmitter.pulse_fwhm"] == 3.0
    assert {k: v for k, v in p.items() if k not in ("name", "transmitter.pulse_fwhm")} == \
           {k: v for k, v in gala.items() if k not in ("name", "transmitter.pulse_fwhm")}
    # without base:, the missing key's line says how to start from one
    path.write_text('name: gala\ntransmitter:\n  pulse_fwhm: "3 ns"\n')
    with pytest.raises(Exception, match=r"missing; .*base: bela \| gala \| atlas"):
        load_instrument(str(path))
    path.write_text("base: hubble\n")
    with pytest.raises(Exception, match="instrument.base: hubble is not a bundled"):
        load_instrument(str(path))


def test_instrument_set_overrides_dotted_keys(tmp_path, surface_file, capsys):
    out = tmp_path / "o.nc"
    assert main(["instrument", str(surface_file), "--instrument", "bela", "--shots", "2",
                 "--set", 'transmitter.pulse_fwhm="3 ns"', "--set", "receiver.efficiency=0.4",
                 "--out", str(out), "--quiet"]) == 0, capsys.readouterr().err
    ds = xr.load_dataset(out, engine="h5netcdf")
    assert ds.attrs["instrument_transmitter_pulse_fwhm"] == "3 ns"
    assert ds.attrs["instrument_receiver_efficiency"] == 0.4
    assert main(["instrument", str(surface_file), "--instrument", "bela", "--set",
                 "transmitter.pulse_fwhmm=3ns", "--out", str(tmp_path / "p.nc")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "command line" in err and "pulse_fwhm" in err, err


def test_show_config_and_run_on_an_instrument_preset(tmp_path, capsys):
    assert main(["show-config", "instruments/bela"]) == 0
    out = capsys.readouterr().out
    assert "name: bela" in out and "transmitter.pulse_fwhm: 6.5 ns" in out, out
    for verb in ("run", "sweep"):
        assert main([verb, "instruments/bela", "--out", str(tmp_path / "x.nc")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        assert "is an instrument preset" in err and "--instrument bela" in err, err
    assert not list(tmp_path.glob("x*"))


def test_show_config_of_a_partial_instrument_file(tmp_path, capsys):
    path = tmp_path / "short.yaml"
    path.write_text('base: gala\ntransmitter:\n  pulse_fwhm: "3 ns"\n')
    assert main(["show-config", str(path), "--set", "shots=7"]) == 0
    out = capsys.readouterr().out
    assert "name: gala" in out and "transmitter.pulse_fwhm: 3 ns" in out and "shots: 7" in out
