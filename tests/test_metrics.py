"""warpe_cl.metrics against analytic distributions: synthetic histograms of exponential and
gamma times, each number within 5 of its own standard errors of the exact value."""
from __future__ import annotations

import json

import numpy as np
import pytest
import xarray as xr

import warpe_cl
from warpe_cl.errors import ConfigError
from conftest import REPO

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


# --- after the instrument chain --------------------------------------------------------------

T0, SIGMA, AMPLITUDE, NOISE, BASE, DT = 3.0, 4.0, 50.0, 1.5, 10.0, 12.5   # ns, ns, mV, mV, mV, ns
FINE = np.arange(-60.0, 120.0, 0.1) + 0.05                                   # ns


def _gauss(t):
    return np.exp(-0.5 * ((t - T0) / SIGMA) ** 2)


def _linear_record(shots, scenarios, seed=21):
    """A linear-mode instrument result built by hand: a Gaussian return (T0, SIGMA) of
    AMPLITUDE mV over a baseline, sampled every DT ns at a uniform random phase per shot, with
    Gaussian noise of NOISE mV; the noiseless analog voltage on a 0.1 ns fine grid."""
    rng = np.random.default_rng(seed)
    sample_time = np.arange(-50.0, 100.0, DT)
    phase = rng.uniform(0.0, DT, (scenarios, shots))
    t = sample_time + phase[..., None]
    signal = BASE + AMPLITUDE * _gauss(t) + rng.normal(0.0, NOISE, t.shape)
    return xr.Dataset({
        "signal_mv": (("scenario", "shot", "sample_time"), signal, {"units": "mV"}),
        "sampling_phase": (("scenario", "shot"), phase),
        "baseline_mv": ((), BASE),
        "expected_analog_mv": (("fine_time",), BASE + AMPLITUDE * _gauss(FINE)),
        "detected": (("scenario", "shot"), np.ones(phase.shape, bool)),
    }, coords={"sample_time": sample_time, "fine_time": FINE,
               "scenario": np.arange(scenarios)})


def _truncated(lo, hi, after=None):
    """Mean, RMS width (ns) and share after ``after`` of the Gaussian (T0, SIGMA) on [lo, hi]."""
    from scipy.stats import truncnorm
    a, b = (lo - T0) / SIGMA, (hi - T0) / SIGMA
    dist = truncnorm(a, b, loc=T0, scale=SIGMA)
    late = None if after is None else float(dist.sf(after))
    return float(dist.mean()), float(dist.std()), late


def test_instrument_expected_values_are_the_analytic_ones():
    """The noiseless values are the truncated Gaussian's over the window (the fine points
    from lo to hi stand for [lo - 0.05, hi + 0.05] ns); the window is where the Gaussian
    reaches 1e-3 of its peak, +-sqrt(2 ln 1000) sigma to within a fine step; the peak is
    the Gaussian's vertex, exact for a Gaussian. Tolerances: the midpoint rule's error on the
    0.1 ns grid (rel. ~1e-5 here) and round-off."""
    m = warpe_cl.metrics(_linear_record(shots=4, scenarios=1), after=[5.0]).isel(scenario=0)
    lo, hi = float(m["window_start"]), float(m["window_stop"])
    half = SIGMA * np.sqrt(2 * np.log(1e3))
    assert abs(lo - (T0 - half)) <= 0.1 and abs(hi - (T0 + half)) <= 0.1
    mean, rms, late = _truncated(lo - 0.05, hi + 0.05, after=5.0)
    assert float(m["expected_mean_delay"]) == pytest.approx(mean, abs=1e-9)
    assert float(m["expected_rms_width"]) == pytest.approx(rms, rel=1e-4)
    assert float(m["expected_fraction_after"][0]) == pytest.approx(late, rel=1e-4)
    assert float(m["expected_peak_time"]) == pytest.approx(T0, abs=1e-9)
    assert m.attrs["metrics_stage"] == "instrument" and "component" not in m.dims
    assert m["expected_mean_delay"].attrs["units"] == "ns"


def test_instrument_numbers_agree_with_the_truth_and_their_errors_with_the_scatter():
    """100 independent records of 100 shots: each number within 5 of its standard errors of
    the truth (the truncated Gaussian on the window); the spread of the 100 values matches
    their standard errors: the ratio of the two is 1 within 5 x 1/sqrt(2 x 99) (the relative
    error of a standard deviation of 100 values)."""
    records = 100
    m = warpe_cl.metrics(_linear_record(shots=100, scenarios=records), after=[5.0])
    assert m["mean_delay"].dims == ("scenario",) and int(m["shots_used"][0]) == 100
    lo, hi = float(m["window_start"][0]), float(m["window_stop"][0])
    mean, rms, late = _truncated(lo, hi, after=5.0)
    truth = {"mean_delay": mean, "rms_width": rms, "peak_time": T0, "fraction_after": late}
    tolerance = 5 / np.sqrt(2 * (records - 1))
    for name, value in truth.items():
        got = m[name].values.reshape(records)
        err = m[f"{name}_stderr"].values.reshape(records)
        assert np.all(np.abs(got - value) < 5 * err), name
        # and their mean, 100 times more precise, within 5 of its standard errors too
        assert abs(got.mean() - value) < 5 * np.sqrt(np.mean(err ** 2) / records), name
        assert abs(got.std(ddof=1) / np.sqrt(np.mean(err ** 2)) - 1) < tolerance, name


def test_instrument_shots_not_detected_are_left_out():
    """Only detected shots count: undetected ones holding garbage change nothing, and a
    scenario without a detected shot gives NaN."""
    ds = _linear_record(shots=40, scenarios=2)
    clean = warpe_cl.metrics(ds.isel(shot=slice(0, 20)))
    ds["signal_mv"][:, 20:] = 999.0
    ds["detected"][:, 20:] = False
    ds["detected"][1] = False
    m = warpe_cl.metrics(ds)
    assert float(m["mean_delay"][0]) == pytest.approx(float(clean["mean_delay"][0]), rel=1e-12)
    assert list(m["shots_used"].values) == [20, 0]
    assert np.isnan(m["mean_delay"][1]) and np.isnan(m["peak_time"][1])


def _counting_record(shots, scenarios, seed=5):
    """A photon-counting result built by hand: Poisson counts of a Gaussian return (mean 5 ns,
    rms 1 ns, 10 photons a shot, as ATLAS) over a background of 0.05 per ns, in 0.1 ns bins."""
    rng = np.random.default_rng(seed)
    step, background = 0.1, 0.05
    lo = np.arange(-20.0, 40.0, step)
    rate = 10.0 * np.exp(-0.5 * (lo + 0.5 * step - 5.0) ** 2) / np.sqrt(2 * np.pi) + background
    fine = np.arange(-20.0, 40.0, 0.05) + 0.025
    return xr.Dataset({
        "signal_counts": (("scenario", "shot", "sample_time"),
                          rng.poisson(rate * step, (scenarios, shots, lo.size))),
        "photon_rate": (("fine_time",), np.exp(-0.5 * (fine - 5.0) ** 2)),
        "background_rate": ((), background),
        "detected": (("scenario", "shot"), np.ones((scenarios, shots), bool)),
    }, coords={"sample_time": lo, "fine_time": fine, "scenario": np.arange(scenarios)})


def test_photon_counting_histogram_of_all_shots():
    """60 independent records of 200 shots of photon counting: the numbers of the
    background-subtracted histogram of all shots within 5 of their standard errors of the truth
    (the Gaussian truncated to the window, which is the expected values'; the peak to within
    a 0.1 ns bin), and the spread of the 60 values matches those errors (ratio 1 within
    5 / sqrt(2 x 59)); the mean delay's error is the Poisson one of the photons."""
    records, shots = 60, 200
    m = warpe_cl.metrics(_counting_record(shots, records), after=[5.0], resamples=20)
    assert int(m["shots_used"][0]) == shots
    assert float(m["expected_mean_delay"][0]) == pytest.approx(5.0, abs=1e-6)
    truth = {"mean_delay": 5.0, "rms_width": float(m["expected_rms_width"][0]),
             "fraction_after": 0.5, "peak_time": 5.0}
    tolerance = 5 / np.sqrt(2 * (records - 1))
    for name, value in truth.items():
        got = m[name].values.reshape(records)
        err = m[f"{name}_stderr"].values.reshape(records)
        slack = 0.1 if name == "peak_time" else 0.0          # the peak is a bin's centre
        assert np.all(np.abs(got - value) < 5 * err + slack), name
        assert abs(got.std(ddof=1) / np.sqrt(np.mean(err ** 2)) - 1) < tolerance, name
    # Poisson: var = (n sigma^2 + b half^2 / 3) / n^2 for n signal photons and b background
    # counts spread evenly over the window +-half; to 10 % (the counts' own fluctuation)
    n = 10.0 * shots
    half = 0.5 * float(m["window_stop"][0] - m["window_start"][0])
    b = 0.05 * 2 * half * shots
    assert np.allclose(m["mean_delay_stderr"], np.sqrt(n + b * half ** 2 / 3) / n, rtol=0.1)


def test_the_instrument_chain_output_and_the_stages():
    """On the chain's real output (BELA and ATLAS, a few shots of a synthetic surface): the
    numbers come with their expected values, per scenario; stage="surface" gives the surface
    numbers of the same file, per component; a Dataset without what a stage needs is refused
    with a ConfigError."""
    from conftest import synthetic_surface
    from warpe_cl.instrument import apply_instrument
    ds = apply_instrument(synthetic_surface(diffuse_integral=0.05, scenarios=2), "bela",
                          shots=8, seed=1)
    m = warpe_cl.metrics(ds, after=[2.0])
    assert m["mean_delay"].dims == ("scenario",)
    assert m["fraction_after"].dims == ("scenario", "after")
    for name in ("mean_delay", "rms_width", "peak_time"):
        assert np.all(np.isfinite(m[name])) and np.all(np.isfinite(m[f"expected_{name}"]))
    ds["reflectance_stderr"] = xr.zeros_like(ds["reflectance"])
    surface = warpe_cl.metrics(ds, stage="surface", resamples=0)
    assert surface["mean_delay"].dims == ("scenario", "component")
    atlas = apply_instrument(synthetic_surface(diffuse_integral=0.05, wavelength="532 nm"),
                             "atlas", shots=50, seed=1)
    m = warpe_cl.metrics(atlas)
    assert m["mean_delay"].dims == () and np.isfinite(float(m["mean_delay"]))
    assert "photon counting" in m.attrs["metrics_method"]
    with pytest.raises(ConfigError, match="has no time_edges"):
        warpe_cl.metrics(xr.Dataset({"x": ("time", np.zeros(3))}))
    with pytest.raises(ConfigError, match="has no recorded signal"):
        warpe_cl.metrics(_synthetic(np.ones(3)), stage="instrument")
    with pytest.raises(ConfigError, match="not a stage"):
        warpe_cl.metrics(ds, stage="detector")

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
    with pytest.raises(ConfigError, match="only in the analog mode"):
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
    # a result that went through the instrument (bela_cases) still gives the surface's rows
    recorded = ds.assign(signal_mv=(("shot", "sample_time"), np.zeros((2, 3))))
    assert rp.metrics_rows("a", recorded) == rows
    path = tmp_path / "metrics.csv"
    rp.write_metrics(rows + rp.metrics_rows("b", ds), path)
    rp.write_metrics([dict(r, mean_delay_ns="9") for r in rp.metrics_rows("b", ds)], path)
    with open(path, newline="", encoding="utf-8") as f:
        table = list(csv.DictReader(f))
    assert [r["preset"] for r in table] == ["a", "a", "b", "b"]
    assert [r["mean_delay_ns"] for r in table][2:] == ["9", "9"]
    assert list(table[0]) == list(rp.METRICS_COLUMNS)


def test_peak_of_a_late_return_on_log_bins():
    """All rays in 10-30 ns, on log bins from 1e-6 ns: the merging starts at the first bin that
    holds a ray, so the peak lies inside the return (it fell at the geometric middle of the
    empty span, ~0.3 ns, when the first merged bin began at 1e-6 ns)."""
    from warpe_cl.metrics import _peak
    edges = np.logspace(-6, 5, 221)
    lo, hi = edges[:-1], edges[1:]
    centre = np.sqrt(lo * hi)
    n = np.where((centre > 10) & (centre < 30), 150.0, 0.0)
    n[(centre > 15) & (centre < 20)] = 600.0
    s = n.copy()                          # what each bin holds: one unit per ray
    peak = _peak(s, n, lo, hi, 100)
    assert 10.0 < peak < 30.0


def test_reproduce_paper_writes_files_in_as_many_workers_as_cores_allow(capsys):
    """tools/reproduce_paper.py: where the walks run on a GPU, the files and figures go to the
    machine's cores less the one that drives them (a 16-core GPU machine wrote twelve presets'
    files in one process, 14 s against 6 s of walks, issue 43); one worker where a CPU device
    takes every core; never more than the presets after the first; --workers 0 is refused
    with one line and exit 2."""
    import sys
    from conftest import TOOLS
    sys.path.insert(0, str(TOOLS))
    import reproduce_paper as rp
    assert rp.file_workers(12, cores=16, gpu=True) == 11
    assert rp.file_workers(12, cores=2, gpu=True) == 1
    assert rp.file_workers(12, cores=16) == 1 and rp.file_workers(3, cores=16, gpu=True) == 2
    assert rp.file_workers(12, asked=4, cores=2) == 4 and rp.file_workers(2, cores=1) == 1
    assert rp.main(["--workers", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--workers 0" in err[0]


def test_reproduce_paper_bela_figure_runs(tmp_path):
    """tools/reproduce_paper.py --only bela_cases end to end, at 300 rays per curve: the preset
    (a granular layer and a slab over a vacuum gap), its figure, and the BELA instrument figure
    on that sweep, with the nadir estimate of both (it once failed there, when the slab had
    none: the chain read its NaN nadir_reflectance)."""
    import sys

    import xarray as xr
    from conftest import TOOLS
    sys.path.insert(0, str(TOOLS))
    import reproduce_paper as rp
    out, data = tmp_path / "fig", tmp_path / "data"
    assert rp.main(["--photons", "300", "--only", "bela_cases", "--out", str(out),
                    "--data", str(data)]) == 0
    assert (out / "bela_cases_instrument.png").is_file() and (out / "bela_cases.png").is_file()
    entry = json.loads((out / "provenance.json").read_text())["presets"]["paper/bela_cases"]
    assert entry["photons"] == 300 and "--only bela_cases" in entry["command"]
    import figure_provenance
    assert entry["check_bits"] == figure_provenance.check_bits("paper", ["bela_cases"])[
        "bela_cases"]
    with xr.open_dataset(data / "bela_cases_instrument_0.01deg.nc") as ds:
        assert ds.attrs["instrument_diffuse_estimate"] == "nadir"
        assert list(ds["diffuse_estimate"].values) == ["nadir", "nadir"]
        assert np.isfinite(ds["expected_mv"].values).all()


def test_reproduce_paper_second_process_writes_the_same(tmp_path):
    """tools/reproduce_paper.py makes each preset's files and figures in a second process
    while the next preset walks: the same NetCDF results and metrics.csv as --serial (each in
    this process, after its walk), every preset reported in order."""
    import contextlib
    import io
    import sys

    import xarray as xr
    from conftest import TOOLS
    sys.path.insert(0, str(TOOLS))
    import reproduce_paper as rp
    names = ["fov_numerical", "slab_co2_thickness"]
    printed = {}
    for mode in ("serial", "second"):
        out, data = tmp_path / mode / "fig", tmp_path / mode / "data"
        args = ["--photons", "300", "--only", *names, "--out", str(out), "--data", str(data)]
        text = io.StringIO()
        with contextlib.redirect_stdout(text):
            assert rp.main(args + (["--serial"] if mode == "serial" else [])) == 0
        printed[mode] = [line.split()[0] for line in text.getvalue().splitlines()
                         if line.split() and line.split()[0] in names]
        assert all((out / f"{n}.png").is_file() for n in names)
    assert printed["serial"] == printed["second"] == names
    for n in names:
        with xr.open_dataset(tmp_path / "serial" / "data" / f"{n}.nc") as a, \
                xr.open_dataset(tmp_path / "second" / "data" / f"{n}.nc") as b:
            assert a["reflectance"].equals(b["reflectance"])
            assert a["nadir_reflectance"].equals(b["nadir_reflectance"])
    assert ((tmp_path / "serial" / "fig" / "metrics.csv").read_text()
            == (tmp_path / "second" / "fig" / "metrics.csv").read_text())


def test_reproduce_paper_without_the_nadir_estimate(tmp_path):
    """--no-nadir walks as the paper did (simulation.nadir: false): no nadir_reflectance."""
    import sys

    import xarray as xr
    from conftest import TOOLS
    sys.path.insert(0, str(TOOLS))
    import reproduce_paper as rp
    data = tmp_path / "data"
    assert rp.main(["--photons", "300", "--only", "fov_numerical", "--no-nadir", "--out",
                    str(tmp_path / "fig"), "--data", str(data)]) == 0
    with xr.open_dataset(data / "fov_numerical.nc") as ds:
        assert "reflectance" in ds and "nadir_reflectance" not in ds


def test_the_figures_were_made_by_these_results():
    """docs/figures/ (the paper's and the layered presets' figures, metrics.csv) holds what
    this tree computes: every preset drawn there has its entry in provenance.json, and its
    check bits (the preset walked at 2000 rays, seed 1: tools/figure_provenance.py) are the
    ones the code gives now. metrics.csv once outlived three days of kernel changes (26 of
    its 96 rows differed when made again). After a change that moves a result, make the
    figures again (docs/figures/README.md)."""
    import csv
    import sys

    from conftest import TOOLS
    sys.path.insert(0, str(TOOLS))
    import figure_provenance
    figures = REPO / "docs" / "figures"
    entries = json.loads((figures / "provenance.json").read_text())["presets"]
    with open(figures / "metrics.csv", newline="", encoding="utf-8") as f:
        in_table = {f"paper/{row['preset']}" for row in csv.DictReader(f)}
    drawn = {f"{folder}/{p.stem}" for folder in ("paper", "layers")
             for p in (REPO / "presets" / folder).glob("*.yaml")}
    assert drawn | in_table <= set(entries), sorted((drawn | in_table) - set(entries))
    stale = []
    for folder in ("paper", "layers"):
        names = [name.split("/", 1)[1] for name in entries if name.startswith(folder + "/")]
        now = figure_provenance.check_bits(folder, names)
        stale += [f"{folder}/{n}" for n in names
                  if entries[f"{folder}/{n}"]["check_bits"] != now.get(n)]
    assert not stale, ("these figures show results the code no longer gives; make them "
                       f"again (docs/figures/README.md): {stale}")
