"""The `instrument` verb, the `instrument:` block of `run`, `plot --kind instrument`, and one
small OpenCL run through the chain (a Lambertian floor must give ∫R_d dt = A/π)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr

from warpe_cl.cli import main
from test_instrument import synthetic_surface

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
    assert main(["plot", str(out), "--out", str(png2), "--kind", "instrument"]) == 0


@pytest.mark.parametrize("extra, message", [
    (["--instrument", "bela", "--altitude", "-500 km"], "geometry.altitude: -500 km is not allowed"),
    (["--instrument", "bela", "--altitude", "500"], "bare number"),
    (["--instrument", "hubble"], "unknown instrument 'hubble'"),
    (["--instrument", "atlas"], "computed at 1064 nm but atlas works at 532 nm"),
    (["--instrument", "bela", "--shots", "0"], "--shots"),
    (["--instrument", "bela", "--shots", "1e30"], "--shots: 1e30 is not allowed; give a value <= 1000000"),
    (["--instrument", "bela", "--shots", "2000000"], "--shots: 2000000 is not allowed"),
    (["--instrument", "bela", "--shots", "nan"], "--shots: nan is not finite; give a whole number in [1, 1000000]"),
    (["--instrument", "bela", "--shots", "inf"], "--shots: inf is not finite"),
    (["--instrument", "bela", "--shots", "1.5"], "--shots: 1.5 is not a whole number; give a whole number in [1, 1000000]"),
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
