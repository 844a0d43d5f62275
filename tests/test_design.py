"""``warpe-cl design`` (docs/design.md): the Fisher widths against the spread of noisy fits, the
ordering of receivers, the scaling with shots, and the refusals of bad study files.

Synthetic databases (tests/conftest.py): exponential responses R_d ∝ exp(−t/τ) at τ = 1, 2,
4, 8 ns stored as a "thickness" τ mm. Displacement interpolation of exponentials in ln τ is
exact (their quantile functions scale with τ), so the database is the truth between nodes.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr
from scipy.optimize import minimize_scalar

from conftest import sweep_of, synthetic_database, synthetic_surface
from warpe_cl.cli import main
from warpe_cl.design.expected import DISTINGUISHABLE, channel, combined, expected
from warpe_cl.catalog import presets_dir, resolve_preset
from warpe_cl.config import load_preset
from warpe_cl.design.family import Family
from warpe_cl.design.run import sweep_overrides
from warpe_cl.design.study import load_study
from warpe_cl.design.fisher import counting_information, linear_information
from warpe_cl.instrument import adc, apply_instrument, load_instrument, radiometry
from warpe_cl.inversion.counting import CountShots
from warpe_cl.inversion.forward import Forward
from warpe_cl.inversion.space import Space
from warpe_cl.surface import response

KEY = "medium.thickness"
TAUS = (1.0, 2.0, 4.0, 8.0)


@pytest.fixture(scope="module")
def database(tmp_path_factory):
    return synthetic_database(tmp_path_factory.mktemp("design") / "db.nc", taus=TAUS)


@pytest.fixture(scope="module")
def family(database):
    return Family("synthetic", xr.open_dataset(database))


@pytest.mark.parametrize("tau", [2.8, 5.6])
def test_fisher_sd_matches_the_spread_of_noisy_fits(database, tau):
    """Shots of the full chain (apply_instrument: Poisson-Gamma photoelectrons, speckle,
    electronic noise, quantisation) of a surface between nodes, fitted for ln τ with the
    nuisances known (each shot's sampling phase and speckle factor, v = 0): the sd of 30 fits
    agrees with the Fisher sd at fixed nuisances. The sample sd of R fits has the standard
    error sd / sqrt(2 (R - 1)) (13 % for R = 30); the tolerance is 3 of them. The Fisher sd
    is taken at a = 1 for every shot, the fits see E[a²] = 1 + 1/M (M = 78 for BELA): 1.3 %,
    well inside it."""
    space = Space(xr.open_dataset(database))
    params = load_instrument("bela")
    f = Forward(params)

    def wave(u):
        return f.waveform(f.photons(space.surface({KEY: math.exp(u)})), 0.0)
    u0, h = math.log(tau * 1e-3), 0.02
    mu, nu = wave(u0)
    (mp, np_), (mm, nm) = wave(u0 + h), wave(u0 - h)
    shots, runs = 20, 30
    info = linear_information(f, mu, nu, ((mp - mm) / (2 * h))[None],
                              ((np_ - nm) / (2 * h))[None], shots, nuisances=())
    fisher_sd = 1.0 / math.sqrt(info[0, 0])
    rec = apply_instrument(synthetic_surface(diffuse_integral=0.05, tau=tau), params,
                           shots=shots * runs, seed=3)
    x = rec["signal_mv"].values - f.baseline
    phase, factor = rec["sampling_phase"].values, rec["speckle_factor"].values
    at = rec["sample_time"].values[None, :] + phase[:, None]
    lo, hi = math.log(TAUS[0] * 1e-3), math.log(TAUS[-1] * 1e-3)
    fits = []
    for r in range(runs):
        s = slice(r * shots, (r + 1) * shots)

        def nll(u):
            m, n = wave(u)
            mean = factor[s, None] * np.interp(at[s], f.t, m)
            var = f.sigma_n ** 2 + factor[s, None] * np.interp(at[s], f.t, n)
            return 0.5 * np.sum((x[s] - mean) ** 2 / var + np.log(var))
        fits.append(minimize_scalar(nll, bounds=(lo, hi), method="bounded",
                                    options={"xatol": 1e-5}).x)
    sd = float(np.std(fits, ddof=1))
    se = sd / math.sqrt(2 * (runs - 1))
    assert abs(sd - fisher_sd) < 3 * se, (sd, fisher_sd, se)
    assert abs(np.mean(fits) - u0) < 3 * sd / math.sqrt(runs) + 0.01   # unbiased


def test_a_narrower_pulse_and_finer_sampling_never_widen_the_interval(family):
    """At equal photons (the same pulse energy and receiver), a 3 ns pulse sampled every 2.5 ns
    gives no wider expected interval than BELA's 6.5 ns pulse sampled every 12.5 ns, at every
    node, for every parameter."""
    wide = expected(family, load_instrument("bela"))
    narrow = expected(family, load_instrument("bela", {"transmitter.pulse_fwhm": "3 ns",
                                                       "adc.sampling_interval": "2.5 ns"}))
    assert np.all(narrow.width_ratio <= wide.width_ratio + 1e-12)
    assert np.all(narrow.sd <= wide.sd * (1 + 1e-9))
    assert np.all(narrow.min_delta_chi2 >= wide.min_delta_chi2 * (1 - 1e-9))
    assert np.any(narrow.width_ratio < wide.width_ratio - 0.05)      # and better somewhere


def noisy_family(error=0.05):
    """The synthetic family with a Monte Carlo standard error of ``error`` of the response in
    every log time bin."""
    parts = []
    for t in TAUS:
        ds = synthetic_surface(diffuse_integral=0.05, tau=t)
        ds["reflectance_stderr"] = error * ds["reflectance"]
        parts.append(ds)
    db = xr.concat(parts, dim="scenario", data_vars="different", compat="equals")
    db["time_edges"] = parts[0]["time_edges"]
    db = db.assign_coords({KEY: ("scenario", np.asarray(TAUS) * 1e-3,
                                 {"sweep_key": KEY, "units": "m"})})
    return Family("noisy", db)


def test_widths_fall_as_one_over_root_shots_unless_the_database_limits_them(family):
    """Without the database's own error the Fisher sd falls as 1/sqrt(shots) exactly; with it
    (a 5 % Monte Carlo error per log bin of every node) 100 times the shots give less than
    10 times narrower intervals: the error is common to the shots and does not average
    down."""
    few = expected(family, load_instrument("bela", {"shots": 100}), database_error=False)
    many = expected(family, load_instrument("bela", {"shots": 100000}), database_error=False)
    ok = np.isfinite(few.sd) & np.isfinite(many.sd)
    np.testing.assert_allclose(many.sd[ok] * math.sqrt(1000), few.sd[ok], rtol=1e-6)
    noisy = noisy_family()
    exact = expected(noisy, load_instrument("bela", {"shots": 100000}), database_error=False)
    capped = expected(noisy, load_instrument("bela", {"shots": 100000}))
    np.testing.assert_allclose(exact.sd[ok], many.sd[ok], rtol=1e-9)
    assert np.all(capped.sd[ok] >= many.sd[ok] * (1 - 1e-9))
    assert np.any(capped.sd[ok] > 2.0 * many.sd[ok])


def test_sampling_finer_than_the_databases_time_bins_is_handled(family):
    """A 0.1 ns pulse sampled every 0.05 ns, finer than the synthetic database's log time bins
    (20 per decade: 0.12 ns at 1 ns, 1.2 ns at 10 ns) over the whole response: the forward
    model's rebinning takes it (docs/design.md §2.6), nothing is refused, every width is
    finite and positive, none wider than the same receiver sampled every 0.5 ns, and the
    database's own error (5 % per log bin) widens them."""
    fast = {"transmitter.pulse_fwhm": "0.1 ns", "electronics.bandwidth": "3 GHz",
            "window.start": "-20 ns", "window.stop": "80 ns", "window.fine_step": "0.01 ns"}
    fine, coarse = (load_instrument("bela", dict(fast, **{"adc.sampling_interval": dt}))
                    for dt in ("0.05 ns", "0.5 ns"))
    sd_fine, sd_coarse = expected(family, fine).sd, expected(family, coarse).sd
    assert np.all(np.isfinite(sd_fine)) and np.all(sd_fine > 0)
    assert np.all(sd_fine <= sd_coarse * (1 + 1e-9))
    noisy = noisy_family()
    assert np.all(expected(noisy, fine).sd >= expected(noisy, fine, database_error=False).sd
                  * (1 - 1e-9))


def test_photon_counting_information_scales_with_shots(family):
    """A photon-counting receiver (ATLAS's, moved to the database's 1064 nm): Poisson
    information on the summed histogram, finite, and proportional to the shots with an exact
    database; with the database's error (5 % per log bin of every node), 1000 times the
    shots give much less than √1000 times narrower intervals (here, at 1e6 shots, over twice
    the exact database's width), since the error is common to the shots."""
    atlas = {"wavelength": "1064 nm"}
    a = expected(family, load_instrument("atlas", {**atlas, "shots": 1000}),
                 database_error=False)
    b = expected(family, load_instrument("atlas", {**atlas, "shots": 16000}),
                 database_error=False)
    assert np.all(np.isfinite(a.sd[:, 0]))
    np.testing.assert_allclose(b.sd * 4.0, a.sd, rtol=1e-6)
    noisy = noisy_family()
    exact = a.sd[:, 0] / math.sqrt(1000.0)             # the exact database's, at 1e6 shots
    capped = expected(noisy, load_instrument("atlas", {**atlas, "shots": 1000000}))
    assert np.all(capped.sd[:, 0] >= exact * (1 - 1e-9))
    assert np.any(capped.sd[:, 0] > 2.0 * exact)


def test_photon_counting_information_follows_the_recorded_counts():
    """The counting information about the amplitude, nothing marginalised, one arrival phase,
    is N Σ (∂m_k/∂A)² / m_k of the likelihood's own expected recorded counts (dead time,
    speckle and jitter, docs/inversion.md §4.2), ∂m/∂A by central differences (h = 1e-4,
    their error 1e-8 relative) over a bright surface whose dead time takes 28 % of the
    photons: the same to 1e-6, and a third of what the counts before the dead time would give
    (the recorded counts grow more slowly than A)."""
    forward = Forward(load_instrument("atlas"))
    surface = synthetic_surface(diffuse_integral=0.5, tau=2.0, wavelength="532 nm")
    mu, _ = forward.waveform(forward.photons(response(surface)), 0.0)
    p = forward.params
    ts = adc.sample_times(p["window.start"], p["window.stop"], forward.interval)
    shots = CountShots(ts, np.zeros((1, ts.size)), forward)
    at = np.array([-0.5 * forward.interval])           # the bins of phase 0.5

    def counts(a):
        return shots.b + shots._lambda(shots.recording.level(mu, a), at)[0]
    h = 1e-4
    slope = (counts(1.0 + h) - counts(1.0 - h)) / (2 * h)
    m = counts(1.0)
    ok = m > 1e-300
    numeric = 1000 * np.sum(slope[ok] ** 2 / m[ok])
    info = counting_information(forward, mu, mu[None, :], 1000, phases=1, nuisances=())
    assert float(info[0, 0]) == pytest.approx(numeric, rel=1e-6)
    before = 1000 * float(np.sum(mu * forward.step))    # Σ λ²/λ: the total before the losses
    assert float(info[0, 0]) < 0.5 * before             # 0.32: the losses grow with A


def _study(tmp_path, database, text):
    path = tmp_path / "study.yaml"
    path.write_text(text.replace("DB", str(database)))
    return path


GOOD = """\
name: t
families:
  - {name: syn, database: DB}
instruments:
  - {name: bela}
  - name: fast
    instrument: bela
    set: {transmitter.pulse_fwhm: "2 ns", adc.sampling_interval: "1 ns"}
"""


def test_design_writes_its_dataset_table_and_figures(tmp_path, database, capsys):
    """The verb end to end: design.nc with long_name and units on every variable and
    coordinate, summary.txt, a map per instrument and the ranking; a second run without
    --overwrite is refused."""
    study = _study(tmp_path, database, GOOD)
    out = tmp_path / "out"
    assert main(["design", str(study), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| bela |" in printed and "| fast |" in printed
    ds = xr.open_dataset(out / "design.nc")
    assert dict(ds.sizes) == {"point": 4, "instrument": 2, "parameter": 2}
    for name, var in {**ds.data_vars, **ds.coords}.items():
        assert "long_name" in var.attrs and "units" in var.attrs, name
    assert (out / "summary.txt").read_text().count("| ") > 4
    for name in ("map_syn_bela.png", "map_syn_fast.png", "ranking.png"):
        assert (out / name).stat().st_size > 1000
    ds.close()
    assert main(["design", str(study), "--out", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err


@pytest.mark.parametrize("text, words", [
    (GOOD.replace("database: DB", "datbase: DB"),
     ["families[0].datbase", "unknown key", "database, preset, photons"]),
    (GOOD.replace('"2 ns"', '"2 furlong"'),
     ["transmitter.pulse_fwhm", "2 furlong", "with a unit"]),
    (GOOD.replace("DB", "/nonexistent/db"),
     ["families[0].database", "/nonexistent/db", "no such database"]),
    (GOOD + "options: {phases: 0}\n", ["options.phases", "0", "[1, 64]"]),
    (GOOD.replace("- {name: bela}", "- {name: bela, instrument: atlas}"),
     ["532 nm", "1064 nm", "add a database computed at 532 nm"]),
    (GOOD + "combinations:\n  - {name: both, instruments: [bela, slow]}\n",
     ["combinations[0].instruments", "slow", "bela, fast"]),
    (GOOD.replace("database: DB", 'database: DB, wavelengths: ["532 nm"]'),
     ["families[0].wavelengths", "applies to a preset"]),
    (GOOD.replace("database: DB", "database: [DB, DB]"),
     ["syn", "same wavelength", "one database per wavelength"]),
])
def test_bad_study_files_exit_2_with_one_line(tmp_path, database, capsys, text, words):
    """An unknown key, a value with a unit not allowed, a missing database, an option out of
    range, an instrument at another wavelength than the database, a combination of an
    unknown instrument, wavelengths without a preset, two databases at one wavelength:
    exit 2, one line on stderr naming the key, the value and what is allowed, before any
    work."""
    study = _study(tmp_path, database, text)
    assert main(["design", str(study), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, (w, err)
    assert not (tmp_path / "out" / "design.nc").exists()


def test_a_combination_across_wavelengths_adds_the_instruments_information(tmp_path, database):
    """BELA reads the family's 1064 nm database, ATLAS its 532 nm one (same nodes); the
    combination's information about the one axis is the sum of theirs, so its Fisher
    variance is the harmonic sum: 1/sd² = 1/sd_BELA² + 1/sd_ATLAS² at every node (exact but
    for rounding), and it is never wider than either."""
    db532 = tmp_path / "db532.nc"
    parts = [synthetic_surface(diffuse_integral=0.05, tau=t, wavelength="532 nm")
             for t in TAUS]
    sweep_of(parts, np.asarray(TAUS) * 1e-3, KEY).to_netcdf(db532, engine="h5netcdf")
    text = f"""\
families:
  - {{name: syn, database: [{database}, {db532}]}}
instruments:
  - {{name: bela, set: {{shots: 40}}}}
  - {{name: atlas, set: {{shots: 400}}}}
combinations:
  - {{name: bela+atlas, instruments: [bela, atlas]}}
"""
    study = tmp_path / "study.yaml"
    study.write_text(text)
    out = tmp_path / "out"
    assert main(["design", str(study), "--out", str(out), "--quiet"]) == 0
    ds = xr.open_dataset(out / "design.nc")
    assert ds["instrument"].values.tolist() == ["bela", "atlas", "bela+atlas"]
    np.testing.assert_allclose(ds["wavelength"].values[:2], [1064.0, 532.0])
    sd = ds["sd"].sel(parameter=KEY).values          # (point, instrument)
    assert np.all(np.isfinite(sd)) and ds["detected"].values.all()
    np.testing.assert_allclose(sd[:, 2] ** -2, sd[:, 0] ** -2 + sd[:, 1] ** -2, rtol=1e-9)
    ratio = ds["width_ratio"].sel(parameter=KEY).values
    assert np.all(ratio[:, 2] <= ratio[:, :2].min(axis=1))
    assert (out / "map_syn_bela_atlas.png").stat().st_size > 1000
    ds.close()


def test_other_families_are_told_apart_by_shape_not_brightness(tmp_path, family):
    """The Δχ² from a node to another family's node compares shapes, the overall amplitude
    being free: to a surface a hundred times darker it is the same as to the same surface at
    full brightness (to rounding), where the linearised amplitude once took the dark one for
    a step along μ and put every surface next to it (Δχ² near 0); a surface found in both
    families is at Δχ² 0, never told apart; and a different shape is told apart."""
    def family_of(name, taus, scale):
        parts = [synthetic_surface(diffuse_integral=0.05 * scale, tau=t) for t in taus]
        path = tmp_path / f"{name}.nc"
        sweep_of(parts, np.asarray(taus) * 1e-3, KEY).to_netcdf(path, engine="h5netcdf")
        return Family(name, xr.open_dataset(path))
    bright = family_of("bright", (2.0, 8.0, 16.0), 1.0)
    dark = family_of("dark", (2.0, 8.0, 16.0), 0.01)
    params = load_instrument("bela", {"transmitter.pulse_fwhm": "2 ns",
                                      "adc.sampling_interval": "1 ns"})
    ch = channel(family, params, others=[bright, dark])
    i = 1                                               # A's node τ = 2 ns
    to_bright, to_dark = ch.texture[i][:3], ch.texture[i][3:]
    np.testing.assert_allclose(to_dark, to_bright, rtol=1e-6, atol=1e-9 * to_bright[1])
    assert to_bright[0] == pytest.approx(0.0, abs=1e-9 * to_bright[1])    # τ = 2 ns: A's own
    assert to_bright[1] > DISTINGUISHABLE                                 # τ = 8 ns
    e = combined(family, [ch])
    assert e.min_delta_chi2_texture[i] == pytest.approx(0.0, abs=1e-9 * to_bright[1])
    assert e.nearest_texture[i] in (0, 3)


@pytest.mark.parametrize("name", sorted(p.stem for p in (presets_dir() / "design").glob("*.yaml")))
def test_bundled_study_files_are_valid(name, tmp_path):
    """Every study file of presets/design/ reads and validates (families, wavelengths,
    instruments and their overrides, combinations) without sweeping anything: a typo there
    would surface only after minutes of sweeps."""
    study = load_study(presets_dir() / "design" / f"{name}.yaml", out=tmp_path)
    assert study.families and study.instruments
    for fam in study.families:
        assert len(fam.databases) == len(fam.wavelengths)


def test_atlas_at_belas_photons_holds_belas_photons_at_the_aperture(tmp_path):
    """presets/design/paper.yaml's atlas_bela_photons takes as many ATLAS shots as hold the
    photons at the aperture of BELA's shots (photons per unit reflectance times shots,
    docs/design.md §5.2): rounded to a whole shot, so within half a shot's photons."""
    study = load_study(presets_dir() / "design" / "paper.yaml", out=tmp_path)
    cand = {c.name: c for c in study.instruments}
    bela, atlas = cand["bela"].params, cand["atlas_bela_photons"].params
    assert atlas["wavelength"] == pytest.approx(532e-9)
    per_shot = radiometry.photons_per_reflectance(atlas)
    budget = bela["shots"] * radiometry.photons_per_reflectance(bela)
    assert abs(atlas["shots"] * per_shot - budget) <= 0.5 * per_shot
    assert cand["atlas"].params["shots"] < atlas["shots"]


def test_design_answers_writes_the_studies_tables_with_their_tree(tmp_path, database, capsys):
    """tools/design_answers.py --reuse: answers.txt holds each study's command, the tree that
    made it and its summary tables (those of `warpe-cl design`, which docs/design.md §5
    quotes); a study not in presets/design/, or --out naming a file, exits 2 with one
    line."""
    import sys
    from conftest import TOOLS
    sys.path.insert(0, str(TOOLS))
    import design_answers
    out = tmp_path / "answers"
    out.mkdir()
    assert main(["design", str(_study(tmp_path, database, GOOD)), "--out",
                 str(out / "paper"), "--quiet"]) == 0
    capsys.readouterr()
    assert design_answers.main(["--out", str(out), "--study", "paper", "--reuse"]) == 0
    text = (out / "answers.txt").read_text()
    tables = (out / "paper" / "summary.txt").read_text().split("\n## ", 1)[1]
    assert "Written by `python tools/design_answers.py` on tree " in text
    assert "reused (--reuse), not computed by this run" in text
    assert f"warpe-cl design presets/design/paper.yaml --out {out / 'paper'}" in text
    assert "### " + tables.strip() in text
    for argv in (["--out", str(out), "--study", "nope"], ["--out", str(out / "answers.txt")]):
        with pytest.raises(SystemExit) as err:
            design_answers.parse_args(argv)
        assert err.value.code == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_a_family_with_its_own_instrument_is_swept_at_another_wavelength():
    """A family preset with an instrument block (layers/lag_over_ice: BELA, 1064 nm) swept at
    532 nm moves its instrument there too; the sweep refused it ("bela works at 1064 nm but
    the surface is computed at 532 nm") after the other families' sweeps had run. At its own
    wavelength, and for a preset without an instrument, nothing but the wavelength is set."""
    lag, gran = resolve_preset("layers/lag_over_ice"), resolve_preset("study/gran_co2")
    moved = sweep_overrides(lag, 3e4, 532e-9)
    assert moved == ["simulation.photons=30000.0", "wavelength=532 nm",
                     "instrument.wavelength=532 nm"]
    config = load_preset(lag, overrides=dict(o.split("=", 1) for o in moved))
    assert config.get("wavelength") == pytest.approx(532e-9)
    assert sweep_overrides(lag, None, 1064e-9) == ["wavelength=1064 nm"]
    assert sweep_overrides(gran, None, 532e-9) == ["wavelength=532 nm"]
