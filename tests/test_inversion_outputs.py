"""FIT.nc as a referee reads it (issue 41): every variable and coordinate has a CF-style
``long_name`` and ``units``, and the median arrival in metres is named for what it is, the
range offset plus the unknown ADC sampling phase (-0.87 m for BELA, -0.37 m for GALA on the
same surface), not ``range_offset``."""
from __future__ import annotations

import xarray as xr

from test_inversion import database, observation
from warpe_cl.cli import main


def test_every_fit_variable_has_a_long_name_and_units(tmp_path):
    obs = observation(2.0, shots=8)
    obs.to_netcdf(tmp_path / "obs.nc", engine="h5netcdf")
    database().to_netcdf(tmp_path / "db.nc", engine="h5netcdf")
    assert main(["invert", str(tmp_path / "obs.nc"), "--database", str(tmp_path / "db.nc"),
                 "--out", str(tmp_path / "fit.nc"), "--quiet"]) == 0
    fit = xr.load_dataset(tmp_path / "fit.nc", engine="h5netcdf")
    lacking = [name for name in fit.variables
               if not str(fit[name].attrs.get("long_name", "")).strip()
               or not str(fit[name].attrs.get("units", "")).strip()]
    assert not lacking, lacking
    assert "range_offset" not in fit
    phase = fit["arrival_plus_sampling_phase"]
    assert phase.attrs["units"] == "m" and "sampling phase" in phase.attrs["long_name"]
    assert "sampling phase" in fit["arrival_time"].attrs["long_name"]
    assert fit["best"].attrs["units"] == "m"          # the one parameter's unit
