"""warpe_cl.metrics against analytic distributions: synthetic histograms of exponential and
gamma times, each number within 5 of its own standard errors of the exact value."""
from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

import warpe_cl

RAYS = 100_000
EDGES = np.arange(0.0, 40.0 + 1e-9, 0.01)      # ns


def _synthetic(times, edges=EDGES, weight=1.0):
    """A one-component result holding the histogram of ``times`` (ns), as simulate writes it:
    reflectance per launched ray per ns, Poisson standard error, the ray counts."""
    counts = np.histogram(times, edges)[0].astype(float)
    width = np.diff(edges)
    return xr.Dataset({
        "time_edges": ("time_edge", edges),
        "reflectance": (("component", "time"), (weight * counts / RAYS / width)[None]),
        "reflectance_stderr": (("component", "time"),
                               (weight * np.sqrt(counts) / RAYS / width)[None]),
        "ray_count": (("component", "time"), counts[None]),
    }, coords={"component": ["scattering"]})


def test_exponential_moments_and_late_fraction():
    tau = 2.0
    rng = np.random.default_rng(11)
    m = warpe_cl.metrics(_synthetic(rng.exponential(tau, RAYS)), after=[1.0, 3.0])
    m = m.sel(component="scattering")
    # the standard errors are those of n draws: sigma/sqrt(n), sigma sqrt(2/n), binomial
    assert m["mean_delay_stderr"] == pytest.approx(tau / np.sqrt(RAYS), rel=0.05)
    assert m["rms_width_stderr"] == pytest.approx(tau * np.sqrt(2 / RAYS), rel=0.1)
    late = np.exp(-np.array([1.0, 3.0]) / tau)
    assert np.allclose(m["fraction_after_stderr"], np.sqrt(late * (1 - late) / RAYS), rtol=0.05)
    # bin centres are the arithmetic means here (the first edge is 0): the binning bias
    # (width^2/12 in the variance) is far below the errors
    assert abs(m["mean_delay"] - tau) < 5 * m["mean_delay_stderr"]
    assert abs(m["rms_width"] - tau) < 5 * m["rms_width_stderr"]
    assert np.all(np.abs(m["fraction_after"] - late) < 5 * m["fraction_after_stderr"])
    assert m["mean_delay"].attrs["units"] == "ns" and m["after"].attrs["units"] == "ns"
    # the peak of an exponential is at 0: the first merged bin (>= 100 rays)
    assert 0 <= m["peak_time"] < 5 * m["peak_time_stderr"] + 0.01


def test_gamma_peak_is_robust_to_sparse_bins():
    """A gamma distribution (shape 4, scale 0.5 ns: mode 1.5 ns) histogrammed in 0.01 ns bins
    (about 30 rays each at the peak): the rebinned peak lands within 5 sigma of the mode;
    on log bins too; and a weighted result (every ray weight 0.3) gives the same times."""
    rng = np.random.default_rng(12)
    times = rng.gamma(4.0, 0.5, RAYS)
    for edges in (EDGES, np.geomspace(1e-3, 40.0, 601)):
        m = warpe_cl.metrics(_synthetic(times, edges)).sel(component="scattering")
        assert 0 < m["peak_time_stderr"] < 0.3
        assert abs(m["peak_time"] - 1.5) < 5 * m["peak_time_stderr"]
        assert abs(m["mean_delay"] - 2.0) < 5 * m["mean_delay_stderr"] + 1e-3
        assert abs(m["rms_width"] - 1.0) < 5 * m["rms_width_stderr"] + 1e-3
    a = warpe_cl.metrics(_synthetic(times))
    b = warpe_cl.metrics(_synthetic(times, weight=0.3))
    for name in ("mean_delay", "mean_delay_stderr", "rms_width", "peak_time"):
        assert np.allclose(a[name], b[name], rtol=1e-12), name


def test_leading_dimensions_and_empty_waveforms():
    """Any leading dimensions are kept (a sweep's scenario, a grid's axes) with their
    coordinates; a waveform holding nothing (a scenario a grid lacks: NaN) gives NaN."""
    rng = np.random.default_rng(13)
    one = _synthetic(rng.exponential(1.0, RAYS))
    empty = one.copy(deep=True)
    for name in ("reflectance", "reflectance_stderr", "ray_count"):
        empty[name][:] = np.nan
    ds = xr.concat([one, empty], dim="scenario")
    ds["time_edges"] = one["time_edges"]
    ds = ds.assign_coords(thickness=("scenario", [0.01, 0.02], {"units": "m"}))
    m = warpe_cl.metrics(ds, after=2.0)
    assert m["mean_delay"].dims == ("scenario", "component")
    assert m["fraction_after"].dims == ("scenario", "component", "after")
    assert list(m["thickness"].values) == [0.01, 0.02]
    assert np.isfinite(m["mean_delay"][0, 0]) and np.isnan(m["mean_delay"][1, 0])
    assert np.isnan(m["peak_time"][1, 0]) and np.isnan(m["fraction_after"][1, 0, 0])


def test_hemispherical_reflectance_takes_the_analog_counts():
    """A result has no ``hemispherical_reflectance_stderr``: an analog one takes the Poisson
    errors of its counts (the same as reflectance_stderr for the same rays), a weighted one
    is refused."""
    rng = np.random.default_rng(14)
    ds = _synthetic(rng.exponential(1.0, RAYS))
    ds["hemispherical_reflectance"] = ds["reflectance"]
    ds["photons"] = RAYS
    ds.attrs["mode"] = "analog"
    fov = warpe_cl.metrics(ds)
    any_angle = warpe_cl.metrics(ds, variable="hemispherical_reflectance")
    for name in ("mean_delay", "mean_delay_stderr", "rms_width", "rms_width_stderr"):
        assert np.allclose(any_angle[name], fov[name], rtol=1e-9), name
    ds.attrs["mode"] = "weighted"
    with pytest.raises(ValueError, match="only in the analog mode"):
        warpe_cl.metrics(ds, variable="hemispherical_reflectance")


def test_reproduce_paper_metrics_table(tmp_path):
    """tools/reproduce_paper.py's metrics.csv: one row per scenario, variable and diffuse
    component holding rays, the numbers of warpe_cl.metrics; a run of some presets (--only)
    keeps the rows of the others."""
    import csv
    import sys
    from conftest import TOOLS
    sys.path.insert(0, str(TOOLS))
    import reproduce_paper as rp
    rng = np.random.default_rng(15)
    one = _synthetic(rng.exponential(1.0, RAYS))
    ds = one.reindex(component=["specular", "bf_direct", "bf_diffuse", "scattering"],
                     fill_value=0.0)
    ds["time_edges"] = one["time_edges"]
    ds["hemispherical_reflectance"] = ds["reflectance"]
    ds["photons"] = RAYS
    ds["fraction"] = ("component", [0.02, 0.0, 0.0, 1.0])
    ds.attrs.update(mode="analog", name="synthetic")
    rows = rp.metrics_rows("a", ds)
    assert [(r["variable"], r["component"]) for r in rows] == [
        ("reflectance", "scattering"), ("hemispherical_reflectance", "scattering")]
    m = warpe_cl.metrics(ds).sel(component="scattering")
    assert float(rows[0]["mean_delay_ns"]) == pytest.approx(float(m["mean_delay"]), rel=1e-3)
    assert float(rows[0]["mean_delay_stderr_ns"]) == pytest.approx(
        float(m["mean_delay_stderr"]), rel=0.05)   # 2 digits
    assert rows[0]["waveform_rays"] == rows[1]["waveform_rays"] == RAYS
    path = tmp_path / "metrics.csv"
    rp.write_metrics(rows + rp.metrics_rows("b", ds), path)
    rp.write_metrics([dict(r, mean_delay_ns="9") for r in rp.metrics_rows("b", ds)], path)
    with open(path, newline="", encoding="utf-8") as f:
        table = list(csv.DictReader(f))
    assert [r["preset"] for r in table] == ["a", "a", "b", "b"]
    assert [r["mean_delay_ns"] for r in table][2:] == ["9", "9"]
    assert list(table[0]) == list(rp.METRICS_COLUMNS)
