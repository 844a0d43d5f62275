"""The figures (issue 12 §3): what the specular's height means, legends, colour bars, labels,
``warpe-cl plot --scenarios`` and sweep database folders."""
from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from warpe_cl.cli import main
from warpe_cl.plot import (MIN_RAYS, delta_fractions, numeric_sweep, scenario_labels,
                           select_scenarios, waveform_figure)

SLAB = """\
medium:
  texture: slab
  thickness: "10 mm"
  radiative: {tau0: 1.0, omega: 0.9, n: 1.3, k: 0.0}
simulation:
  photons: 3000
  seed: 2
"""
THICKNESSES = ["1 mm", "2 mm", "5 mm", "10 mm", "20 mm", "50 mm", "100 mm", "200 mm"]


def _run(tmp_path, text, name, photons=None):
    preset = tmp_path / f"{name}.yaml"
    preset.write_text(text)
    out = tmp_path / f"{name}.nc"
    extra = ["--photons", str(photons)] if photons else []
    assert main(["run", str(preset), "--out", str(out), "--quiet"] + extra) == 0
    return xr.load_dataset(out)


@pytest.fixture(scope="module")
def single(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("single"), SLAB, "single", photons=20000)


@pytest.fixture(scope="module")
def fine_start(tmp_path_factory):
    text = SLAB + '  time_bins: {start: "1e-3 ns", stop: "1e5 ns", per_decade: 20}\n'
    return _run(tmp_path_factory.mktemp("fine"), text, "fine", photons=20000)


@pytest.fixture(scope="module")
def many(tmp_path_factory):
    text = SLAB + "sweep:\n  medium.thickness: [" + ", ".join(f'"{t}"' for t in THICKNESSES) + "]\n"
    return _run(tmp_path_factory.mktemp("many"), text, "many")


def _legend_texts(fig):
    return [t.get_text() for ax in fig.axes if ax.get_legend()
            for t in ax.get_legend().get_texts()]


@pytest.mark.slow
def test_specular_is_a_fraction_of_the_rays_whatever_the_bins(single, fine_start):
    """The specular's plotted value is its fraction of the rays (right axis), the same for
    any first bin; the diffuse axis is not stretched by it."""
    for ds in (single, fine_start):
        t, f = delta_fractions(ds, "specular")
        assert t.size == 1 and 0.01 < f[0] < 0.05     # Fresnel of n = 1.3 at normal incidence
        fig = waveform_figure(ds)
        ax, frac_ax = fig.axes[:2]
        lo, hi = ax.get_ylim()
        r = ds["reflectance"].sel(component=["scattering", "bf_diffuse"]).values
        assert hi <= 10 * r.max() * 1.0001 and np.log10(hi / lo) < 10
        ydata = np.concatenate([ln.get_ydata() for ln in frac_ax.get_lines() if len(ln.get_ydata())])
        assert np.any(np.isclose(ydata, f[0]))
        assert "fraction of the rays" in frac_ax.get_ylabel()
        assert any(f"specular {f[0]:.3g}" in a.get_text() for a in frac_ax.texts)
    assert np.isclose(delta_fractions(single, "specular")[1][0],
                      delta_fractions(fine_start, "specular")[1][0], rtol=0.2)


@pytest.mark.slow
def test_legend_lists_only_drawn_components_and_the_shaded_domain(single):
    fig = waveform_figure(single)
    texts = _legend_texts(fig)
    assert f"fewer than {MIN_RAYS} rays per bin (shaded)" in texts
    drawn = [c for c in ("scattering", "bf_diffuse")
             if np.any(single["reflectance"].sel(component=c).values > 0)]
    assert any(t.startswith("scattering") for t in texts) == ("scattering" in drawn)
    assert any(t.startswith("BF diffuse") for t in texts) == ("bf_diffuse" in drawn)


@pytest.mark.slow
def test_many_numeric_scenarios_take_a_colour_bar(many):
    values, key, unit = numeric_sweep(many)
    assert key == "medium.thickness" and unit == "mm"
    np.testing.assert_allclose(values, [1, 2, 5, 10, 20, 50, 100, 200])
    fig = waveform_figure(many)
    assert len(fig.axes) == 3 and fig.axes[2].get_ylabel() == "medium.thickness (mm)"
    assert not any("thickness=" in t for t in _legend_texts(fig))
    few = waveform_figure(many.isel(scenario=[0, 1, 2]))
    assert len(few.axes) == 2 and "thickness=1 mm" in _legend_texts(few)


def test_labels_are_swept_key_values():
    ds = xr.Dataset(coords={"scenario": [0, 1], "medium": ("scenario", [
        '{"texture": "granular", "thickness": "1000 mm", "compacity": 0.9, "phase_g": 0.8}',
        '{"texture": "slab", "thickness": "1500 mm", "compacity": 1.0, "phase_g": 0.8}'])})
    assert scenario_labels(ds) == ["texture=granular, thickness=1000 mm, compacity=0.9",
                                   "texture=slab, thickness=1500 mm, compacity=1"]
    ds = xr.Dataset(coords={"scenario": [0, 1], "medium.thickness": ("scenario", ["1 mm", "2 mm"]),
                            "wavelength": ("scenario", ["1064 nm", "532 nm"])})
    assert scenario_labels(ds) == ["thickness=1 mm, wavelength=1064 nm",
                                   "thickness=2 mm, wavelength=532 nm"]


@pytest.mark.slow
def test_no_diffuse_ray_still_draws(single, tmp_path):
    """A low-count run whose diffuse bins are all empty: a figure, not a log-scale error."""
    from warpe_cl.plot import plot_waveform
    ds = single.copy(deep=True)
    r = ds["reflectance"]
    ds["reflectance"] = r.where(~r.component.isin(["scattering", "bf_diffuse"]), 0.0)
    plot_waveform(ds, tmp_path / "x.png")
    assert (tmp_path / "x.png").stat().st_size > 10_000


def test_select_scenarios(many):
    assert list(select_scenarios(many, "0,3,5")["scenario"].values) == [0, 3, 5]
    assert list(select_scenarios(many, "0:2, 7")["scenario"].values) == [0, 1, 7]
    assert list(select_scenarios(many, "6:")["scenario"].values) == [6, 7]
    for sel in ("medium.thickness=10mm", "thickness=10 mm", "thickness=0.01 m"):
        assert list(select_scenarios(many, sel)["scenario"].values) == [3]
    from warpe_cl.errors import ConfigError
    for bad in ("9", "a:b", "foo=1", "thickness=3 mm", "", "1.5"):
        with pytest.raises(ConfigError):
            select_scenarios(many, bad)


@pytest.mark.slow
def test_plot_verb_scenarios_and_database_folder(tmp_path, capsys):
    preset = tmp_path / "grid.yaml"
    preset.write_text(SLAB.replace("photons: 3000", "photons: 1000")
                      + 'sweep:\n  medium.thickness: ["1 mm", "10 mm", "100 mm"]\n')
    db = tmp_path / "db"
    assert main(["sweep", str(preset), "--out", str(db), "--quiet"]) == 0
    png = tmp_path / "db.png"
    assert main(["plot", str(db), "--out", str(png)]) == 0          # a folder, not "no such file"
    assert png.stat().st_size > 10_000
    assert main(["plot", str(db), "--scenarios", "0,2", "--out", str(tmp_path / "s.png")]) == 0
    assert main(["plot", str(db), "--scenarios", "thickness=10mm",
                 "--out", str(tmp_path / "v.png")]) == 0
    capsys.readouterr()
    for bad in ("7", "x:y", "colour=red"):
        assert main(["plot", str(db), "--scenarios", bad, "--out", str(tmp_path / "b.png")]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "--scenarios" in err
    assert not (tmp_path / "b.png").exists()
    # the instrument reads a database folder too
    out = tmp_path / "bela.nc"
    assert main(["instrument", str(db), "--instrument", "bela", "--shots", "2", "--out", str(out),
                 "--quiet"]) == 0, capsys.readouterr().err
    import xarray as xr
    assert xr.load_dataset(out, engine="h5netcdf").sizes["scenario"] == 3


def _inside(fig):
    """Every legend lies inside its axes (drawn once, in display pixels)."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes:
        legend = ax.get_legend()
        if legend is None:
            continue
        box, leg = ax.get_window_extent(renderer), legend.get_window_extent(renderer)
        assert (leg.x0 >= box.x0 - 1 and leg.x1 <= box.x1 + 1 and leg.y0 >= box.y0 - 1
                and leg.y1 <= box.y1 + 1), (ax.get_title(), leg, box)


@pytest.mark.slow
def test_instrument_figure_titles_legends_and_deltas(tmp_path):
    from warpe_cl.instrument.plot import instrument_figure
    from conftest import REPO
    out = tmp_path / "bela.nc"
    assert main(["run", str(REPO / "presets" / "paper" / "bela_cases.yaml"), "--out", str(out),
                 "--photons", "5000", "--quiet"]) == 0
    ds = xr.load_dataset(out)
    fig = instrument_figure(ds)
    top, mid, bot, frac_ax = fig.axes
    assert "received reflectance" in mid.get_title() and "received reflectance" in mid.get_ylabel()
    assert "photon rate" not in mid.get_title()
    _inside(fig)
    texts = _legend_texts(fig)
    assert any(t.startswith("texture=granular, thickness=1000 mm") for t in texts)
    assert not any(t.startswith("scenario ") for t in texts)
    spec = delta_fractions(ds.isel(scenario=1), "specular")[1][0]   # the slab: 0.028 of the rays
    assert 0.02 < spec < 0.04
    ydata = np.concatenate([ln.get_ydata() for ln in frac_ax.get_lines() if len(ln.get_ydata())])
    assert np.any(np.isclose(ydata, spec))
    assert top.get_ylim()[1] < 1e8                                   # not stretched by it
    _nothing_under_legends(fig)
    _nothing_under_legends(waveform_figure(ds))      # the slab's BF direct, 0.026 at 14 ns
    long = "texture=slab, thickness=1500 mm, compacity=1, matrix=CO2, " * 3   # shrunk to fit
    _inside(instrument_figure([(long, ds.isel(scenario=1)), ("short", ds.isel(scenario=0))]))


@pytest.mark.slow
def test_waveform_legends_inside(many):
    _inside(waveform_figure(many))
    _inside(waveform_figure(many.isel(scenario=[0, 1, 2])))


def test_several_speculars_written_one_line_each(many):
    """A few scenarios: each specular fraction written once, on its own line (no overlap)."""
    sub = many.isel(scenario=[0, 1, 2])
    fig = waveform_figure(sub)
    lines = [t for t in fig.axes[1].texts if t.get_text().startswith("specular ")]
    assert len(lines) == 3
    assert len({round(t.get_position()[1], 3) for t in lines}) == 3
    for t, i in zip(lines, range(3)):
        f = delta_fractions(sub.isel(scenario=i), "specular")[1][0]
        assert t.get_text() == f"specular {f:.3g} of the rays at t = 0"


@pytest.mark.slow
def test_angular_figure_legend_or_colour_bar(many, tmp_path):
    from warpe_cl.plot import angular_figure, plot_angular
    fig = angular_figure(many)
    assert len(fig.axes) == 3 and fig.axes[2].get_ylabel() == "medium.thickness (mm)"
    few = angular_figure(many.isel(scenario=[0, 3]))
    assert "thickness=10 mm" in _legend_texts(few)
    _inside(few)
    assert plot_angular(many, tmp_path / "a.png").stat().st_size > 10_000


@pytest.mark.slow
def test_instrument_figure_many_scenarios_colour_bar(many):
    from warpe_cl.instrument import apply_instrument
    from warpe_cl.instrument.plot import instrument_figure
    fig = instrument_figure(apply_instrument(many, "bela", shots=5))
    assert len(fig.axes) == 5 and fig.axes[4].get_ylabel() == "medium.thickness (mm)"
    assert fig.axes[3].get_legend() is None      # the colour bar names the top panel's colours
    _inside(fig)


def _nothing_under_legends(fig):
    """No point of a data line (a curve's bin, a delta return's marker) lies under a legend."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    for ax in fig.axes:
        for line in ax.get_lines():
            if line.get_transform() != ax.transData:
                continue
            xy = np.asarray(line.get_xydata(), dtype=float).reshape(-1, 2)
            xy = xy[np.all(np.isfinite(xy), axis=1)]
            if ax.get_yscale() == "log":
                xy = xy[xy[:, 1] > 0]
            at = ax.transData.transform(xy) if len(xy) else xy
            inside = ax.get_window_extent(renderer)
            for legend in legends:
                if legend.axes.get_window_extent(renderer) != inside:   # another panel
                    continue
                box = legend.get_window_extent(renderer)
                hidden = [(x, y) for (x, y), (px, py) in zip(xy, at)
                          if box.x0 <= px <= box.x1 and box.y0 <= py <= box.y1]
                assert not hidden, (ax.get_title(), line.get_label(), hidden[:3])


@pytest.mark.slow
def test_no_curve_or_marker_under_the_legend(single, many):
    _nothing_under_legends(waveform_figure(single))
    _nothing_under_legends(waveform_figure(many.isel(scenario=[0, 1, 2])))


def test_waveform_figure_is_laid_out_when_returned(single, many, tmp_path):
    """plot_waveform saves without laying the figure out again (save_figure(laid_out=True)):
    the figure waveform_figure returns already sits where a new layout puts it, to within a
    pixel (constrained layout moves by fractions of a pixel from one pass to the next), and the
    save moves nothing."""
    from warpe_cl.plot import save_figure
    for ds in (single, many.isel(scenario=[0, 1, 2])):
        fig = waveform_figure(ds)
        returned = np.array([ax.get_position().bounds for ax in fig.axes])
        pixel = 1.0 / (fig.get_size_inches() * fig.dpi).min()
        fig.draw_without_rendering()              # a new layout pass
        again = np.array([ax.get_position().bounds for ax in fig.axes])
        assert np.abs(again - returned).max() < pixel
        save_figure(fig, tmp_path / "w.png", laid_out=True)
        assert np.array_equal([ax.get_position().bounds for ax in fig.axes], again)


@pytest.mark.slow
def test_instrument_figure_one_curve_per_surface_result(single):
    """Cases that differ only in the instrument (a flat and a rough slab: roughness acts only
    in the chain) share one surface response: the top panel draws it once, with one legend
    entry that says so, and a scaled shape drawn over an identical one names it."""
    from warpe_cl.instrument import apply_instrument
    from warpe_cl.instrument.plot import instrument_figure, surface_groups
    flat = apply_instrument(single, "bela", {"geometry.roughness": "0 deg"}, shots=2)
    rough = apply_instrument(single, "bela", {"geometry.roughness": "0.01 deg"}, shots=2)
    other = apply_instrument(single.isel(time=slice(None, None, -1)).assign_coords(
        time=single["time"]), "bela", shots=2)   # another surface: the waveform reversed
    cases = [("flat", flat), ("other", other), ("rough", rough)]
    assert surface_groups(cases) == [[0, 2], [1]]
    fig = instrument_figure(cases)
    top, mid, bot, frac_ax = fig.axes
    texts = [t.get_text() for t in frac_ax.get_legend().get_texts()]
    assert texts == ["flat = rough:\none surface response (geometry.roughness acts only in the "
                     "instrument chain)", "other"]
    assert len(top.get_lines()) == 2                 # one curve per surface result
    assert len(mid.get_lines()) == 3                 # the chain's panels: one per case
    _inside(fig)
    _nothing_under_legends(fig)
    twice = [t.get_text() for t in instrument_figure([("a", flat), ("b", flat)]).axes[2]
             .get_legend().get_texts()]
    assert "\n(dashed: the same shape as a, drawn over it)" in twice[1]
    assert "same shape" not in twice[0]
