"""What the data measure (issue 41, docs/inversion.md §6): derived quantities' posteriors, an
identifiability measure in the prior's coordinate, one-sided bounds at a prior edge, the
degeneracy of keys that act through one combination, a summary that leads with the median
and intervals, and the figure's truth and median.

The databases are synthetic (conftest.synthetic_surface: R_d ∝ exp(−t/τ)/τ). In the
two-key one, grain size d and compacity c act only through E = 1.5 c / d, the delay being
τ = 8 ns × 3000 m⁻¹ / E: the waveform measures E and not d nor c, as a granular layer does.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import xarray as xr
import yaml

from conftest import synthetic_surface
from test_inversion import KEY, database, observation
from warpe_cl.cli import main
from warpe_cl.config import load_preset
from warpe_cl.errors import ConfigError
from warpe_cl.instrument import apply_instrument
from warpe_cl.inversion.derived import _response_values, quantities, truth_values
from warpe_cl.inversion.invert import invert
from warpe_cl.inversion.observed import Observed
from warpe_cl.inversion.space import Space
from warpe_cl.report import inversion_lines

SIZE, COMP = "medium.grain_size", "medium.compacity"
SIZES = np.geomspace(50e-6, 400e-6, 4)        # m
COMPS = np.geomspace(0.1, 0.8, 4)


def ridge_database():
    """Grain size x compacity, acting only through E = 1.5 c / d (m⁻¹); stores E and τ0."""
    parts, d, c = [], [], []
    for size in SIZES:
        for comp in COMPS:
            parts.append(synthetic_surface(diffuse_integral=0.05, tau=8.0 * 3000.0 * size
                                           / (1.5 * comp)))
            d.append(size)
            c.append(comp)
    ds = xr.concat(parts, dim="scenario", data_vars="different", compat="equals")
    ds["time_edges"] = parts[0]["time_edges"]
    ds = ds.assign_coords({SIZE: ("scenario", np.array(d), {"sweep_key": SIZE, "units": "m"}),
                           COMP: ("scenario", np.array(c), {"sweep_key": COMP, "units": "1"})})
    e = 1.5 * np.array(c) / np.array(d)
    ds["extinction_per_m"] = ("scenario", e, {"units": "m-1"})
    ds["tau0"] = ("scenario", e * 0.01, {"units": "1"})          # a 10 mm layer
    ds["scenario_key"] = ("scenario", np.arange(len(parts)) + 100)
    return ds


def _fit(tau, db, shots=20, seed=5, **kw):
    obs = observation(tau, shots=shots, seed=seed)
    return invert(Observed("mv", obs["sample_time"].values, obs["signal_mv"].values, "obs",
                           "bela"), db, "bela", **kw)


@pytest.fixture(scope="module")
def ridge():
    """d = 150 µm, c = 0.3: E = 3000 m⁻¹, τ = 8 ns."""
    return _fit(8.0, ridge_database(), budget=250,
                truth={SIZE: "150 um", COMP: 0.3})


@pytest.fixture(scope="module")
def single():
    """τ = 5.6 ns between the nodes of the one-key database (thickness 5.6 mm): a tail as long
    as the pulse, which no change of the pulse width mimics. (Below 3 ns the profiled pulse
    width absorbs the delay: log L is flat to within 0.7 from 0.5 to 4 mm.)"""
    return _fit(5.6, database(), shots=60, seed=4, truth={KEY: "5.6 mm"})


def test_derived_quantities_at_the_nodes_are_known():
    """The mean delay of R_d ∝ exp(−t/τ)/τ is τ, its tail beyond the pulse FWHM T is
    exp(−T/τ) (to the time grid's resolution), and E is the stored value."""
    db = ridge_database()
    space = Space(db)
    found = {q.name: q for q in quantities(space, db, 6.5)}
    assert set(found) == {"extinction_per_m", "tau0", "mean_delay_ns", "tail_fraction"}
    tau = 8.0 * 3000.0 * SIZES[:, None] / (1.5 * COMPS[None, :])
    np.testing.assert_allclose(found["mean_delay_ns"].nodes, tau, rtol=0.03)
    np.testing.assert_allclose(found["tail_fraction"].nodes, np.exp(-6.5 / tau), atol=0.02)
    np.testing.assert_allclose(found["extinction_per_m"].nodes,
                               1.5 * COMPS[None, :] / SIZES[:, None], rtol=1e-12)


def test_degenerate_keys_measure_their_extinction(ridge):
    """Neither key is constrained (width ratio ≈ 1), E is (≪ 1) and holds the truth, and the
    summary says that the pair is degenerate and what the data fix."""
    for key in (SIZE, COMP):
        r = ridge.sel(parameter=key)
        assert float(r["width_ratio"]) > 0.85 and not bool(r["constrained"]), key
    e = ridge.sel(derived="extinction_per_m")
    assert float(e["derived_low95"]) <= 3000.0 <= float(e["derived_high95"])
    assert float(e["derived_width_ratio"]) < 0.35
    assert float(e["derived_kl_divergence"]) > 1.0
    np.testing.assert_allclose(float(e["derived_truth"]), 3000.0, rtol=1e-9)
    assert str(e["derived_units"].values) == "m-1"
    degeneracy = " ".join(__import__("json").loads(ridge.attrs["degeneracy"]))
    assert "grain_size and compacity are degenerate" in degeneracy
    assert "E = " in degeneracy and "(68 %)" in degeneracy
    assert abs(float(ridge["correlation"].sel(free_key=SIZE, free_key_other=COMP))) > 0.8
    lines = inversion_lines(ridge)
    assert any("are degenerate" in line for line in lines)


def test_a_read_key_is_constrained_with_a_small_ratio(single):
    r = single.sel(parameter=KEY)
    assert bool(r["constrained"]) and float(r["width_ratio"]) < 0.4
    assert float(r["kl_divergence"]) > 1.0
    assert int(r["bound"]) == 0 and np.isnan(float(r["bound95"]))
    d = single.sel(derived="mean_delay_ns")       # ⟨t⟩ = τ = 5.6 ns
    assert float(d["derived_low95"]) <= 5.6 <= float(d["derived_high95"])
    np.testing.assert_allclose(float(d["derived_truth"]), 5.6, rtol=0.03)


def test_a_semi_infinite_end_gives_a_one_sided_bound():
    """Delays stop growing beyond 8 mm (τ = 8 ns for 8, 16 and 32 mm: the layer looks
    semi-infinite); shots of τ = 8 ns, a "thickness" beyond the grid, give a lower bound."""
    taus = np.array([1.0, 2.0, 4.0, 8.0, 16.0, 32.0])
    parts = [synthetic_surface(diffuse_integral=0.05, tau=min(t, 8.0)) for t in taus]
    db = xr.concat(parts, dim="scenario", data_vars="different", compat="equals")
    db["time_edges"] = parts[0]["time_edges"]
    db = db.assign_coords({KEY: ("scenario", taus * 1e-3, {"sweep_key": KEY, "units": "m"})})
    db["scenario_key"] = ("scenario", np.arange(taus.size) + 100)
    fit = _fit(8.0, db, shots=40)
    r = fit.sel(parameter=KEY)
    assert int(r["bound"]) == 1, fit["bound"].attrs["flag_meanings"]        # lower_bound
    assert 2e-3 < float(r["bound95"]) < 16e-3
    line = next(x for x in inversion_lines(fit) if KEY in x)
    assert f"{KEY}" in line and "> " in line and "(95 %)" in line
    assert line.index("> ") < line.index("median")


def test_summary_leads_with_median_and_intervals(single):
    lines = inversion_lines(single)
    row = next(i for i, x in enumerate(lines) if x.strip().startswith(KEY))
    best = next(i for i, x in enumerate(lines) if "best grid point" in x)
    assert "median" in lines[row] and " best " not in lines[row] and best > row
    assert lines[row].index("median") < lines[row].index("68 %") < lines[row].index("95 %")
    names = list(single.data_vars)
    assert names[:5] == ["median", "low68", "high68", "low95", "high95"]
    assert names.index("best") > names.index("width_ratio")
    assert "best grid point" in single["best"].attrs["long_name"]


def test_figure_marks_the_truth_and_the_median(tmp_path, monkeypatch, capsys):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    figures = []
    monkeypatch.setattr(plt, "close", lambda fig=None: figures.append(fig))
    obs = observation(2.0, shots=8)
    obs.to_netcdf(tmp_path / "obs.nc", engine="h5netcdf")
    database().to_netcdf(tmp_path / "db.nc", engine="h5netcdf")
    assert main(["invert", str(tmp_path / "obs.nc"), "--database", str(tmp_path / "db.nc"),
                 "--out", str(tmp_path / "fit.nc"), "--plot", str(tmp_path / "fit.png"),
                 "--truth", f'{KEY}="2 mm"']) == 0
    assert (tmp_path / "fit.png").stat().st_size > 10_000
    assert "truth (--truth): medium.thickness 2 mm" in capsys.readouterr().out
    fit = xr.load_dataset(tmp_path / "fit.nc", engine="h5netcdf")
    assert float(fit["truth"].sel(parameter=KEY)) == pytest.approx(2e-3)
    diagonal = [ax for ax in figures[-1].axes if "median" in ax.get_title()]
    assert diagonal, [ax.get_title() for ax in figures[-1].axes]
    labels = {line.get_label() for line in diagonal[0].get_lines()}
    assert {"median", "truth"} <= labels
    truth = next(x for x in diagonal[0].get_lines() if x.get_label() == "truth")
    assert truth.get_xdata()[0] == pytest.approx(2.0)          # mm, the panel's unit
    assert diagonal[0].get_xlabel() and diagonal[0].get_xticklabels()


def test_truth_is_read_from_the_observed_configuration():
    space = Space(database())
    preset = {"name": "t", "medium": {"texture": "slab", "thickness": "3 mm",
                                      "radiative": {"tau0": 1.0, "omega": 0.9, "n": 1.3,
                                                    "k": 0.0}}}
    config = load_preset(preset).to_yaml()
    found, source = truth_values({"config": config}, space)
    assert found == {KEY: pytest.approx(3e-3)} and source == "observed config"
    found, source = truth_values({"sweep_point": {KEY: "4 mm"}}, space)
    assert found == {KEY: pytest.approx(4e-3)} and source == "observed sweep_point"
    assert truth_values({"config": "wavelength: 1064 nm\n"}, space)[0] == {}
    assert yaml.safe_load(config)["medium"]["thickness"]


@pytest.mark.parametrize("given, words", [
    ({"medium.compacity": 0.5}, "not a numeric swept key"),
    ({KEY: 0.002}, "with a unit"),
])
def test_bad_truth_is_refused(given, words):
    with pytest.raises(ConfigError, match=words):
        truth_values({}, Space(database()), given)


def test_cli_refuses_a_bad_truth_in_one_line(tmp_path, capsys):
    observation(2.0, shots=4).to_netcdf(tmp_path / "obs.nc", engine="h5netcdf")
    database().to_netcdf(tmp_path / "db.nc", engine="h5netcdf")
    assert main(["invert", str(tmp_path / "obs.nc"), "--database", str(tmp_path / "db.nc"),
                 "--out", str(tmp_path / "fit.nc"), "--truth", f"{KEY}=2"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--truth" in err, err


def test_a_response_without_tail_has_a_tail_fraction_of_zero():
    """All of the diffuse return before the cut: a tail fraction of exactly 0, not 1 less a
    sum rounded above 1 (−2.2e-16, which the summary printed as a 95 % bound); all of it
    after: exactly 1."""
    edges = np.geomspace(1e-3, 100.0, 401)
    diffuse = np.random.default_rng(0).random(400)
    found = _response_values(SimpleNamespace(diffuse=diffuse, edges=edges), 200.0)
    assert found["tail_fraction"] == 0.0
    whole = _response_values(SimpleNamespace(diffuse=diffuse, edges=edges), 1e-4)
    assert whole["tail_fraction"] == 1.0
