"""Shots of one surface at two wavelengths inverted together (issue 42, docs/inversion.md §5.5):
BELA at 1064 nm against a 1064 nm database with ATLAS at 532 nm against a 532 nm one.

The databases are synthetic (tests/test_inversion.py): diffuse responses R_d(t) ∝ exp(−t/τ)/τ
whose delay τ stands for ``medium.thickness``, the same at both wavelengths. The joint log L is
the sum of the channels' at every grid point (exactly, each channel's nuisances its own); the
joint posterior holds the truth and is no wider than either channel's; what does not make one
surface seen twice is refused before any work, in one line with exit 2.
"""
from __future__ import annotations

import numpy as np
import pytest

from conftest import sweep_of, synthetic_surface
from warpe_cl.cli import main
from warpe_cl.instrument import apply_instrument
from warpe_cl.inversion.invert import invert, prepare
from warpe_cl.inversion.joint import JointProblem, invert_joint

KEY = "medium.thickness"
TAUS = np.array([0.5, 1.0, 2.0, 4.0, 8.0, 16.0])      # ns: the delay each "thickness" gives
TRUE_TAU = 3.0                                         # ns, between two nodes
BUDGET = 40                                            # refined grid points: a fast test


def database(wavelength, taus=TAUS):
    """The synthetic sweep along KEY at ``wavelength``."""
    return sweep_of([synthetic_surface(diffuse_integral=0.05, tau=t, wavelength=wavelength)
                     for t in taus], np.asarray(taus) * 1e-3, KEY)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """BELA (1064 nm, 40 shots) and ATLAS (532 nm, 200 shots) files of the surface τ = 3 ns,
    and the two databases, on disk."""
    d = tmp_path_factory.mktemp("joint")
    bela = apply_instrument(synthetic_surface(diffuse_integral=0.05, tau=TRUE_TAU), "bela",
                            None, shots=40, seed=4)
    atlas = apply_instrument(synthetic_surface(diffuse_integral=0.05, tau=TRUE_TAU,
                                               wavelength="532 nm"), "atlas", None, shots=200,
                             seed=5)
    bela.to_netcdf(d / "bela.nc", engine="h5netcdf")
    atlas.to_netcdf(d / "atlas.nc", engine="h5netcdf")
    database("1064 nm").to_netcdf(d / "db1064.nc", engine="h5netcdf")
    database("532 nm").to_netcdf(d / "db532.nc", engine="h5netcdf")
    return d


def test_joint_log_likelihood_is_the_sum_of_the_channels(files):
    """On the same grid, the joint log L equals BELA's plus ATLAS's, point for point, and
    each channel's own evaluation is what it gives alone."""
    coords = [np.linspace(np.log(1e-3), np.log(8e-3), 9)]
    alone = [prepare(files / "bela.nc", files / "db1064.nc"),
             prepare(files / "atlas.nc", files / "db532.nc")]
    grids = [c.problem.grid(coords) for c in alone]
    joint = JointProblem([prepare(files / "bela.nc", files / "db1064.nc").problem,
                          prepare(files / "atlas.nc", files / "db532.nc").problem])
    both = joint.grid(coords)
    np.testing.assert_array_equal(both.loglike, grids[0].loglike + grids[1].loglike)
    for index, e in both.evaluations.items():
        assert [p.loglike for p in e.parts] == [g.evaluations[index].loglike for g in grids]
    assert joint.count == sum(c.problem.count for c in alone)


def test_joint_posterior_holds_the_truth_and_is_no_wider_than_either(files):
    """Both channels read τ; their joint 68 % interval is narrower than each alone (a
    product of two log-concave posteriors of the same parameter), and holds the truth at
    95 %. Widths are compared in the prior's coordinate, ln thickness: in metres a posterior
    of the same shape centred 1.5 % higher is 1.5 % wider (the joint's median moves from
    ATLAS's towards BELA's). The intervals of the seeds used here: BELA's about 6 times
    ATLAS's."""
    fits = invert_joint([files / "bela.nc", files / "atlas.nc"],
                        [files / "db1064.nc", files / "db532.nc"], budget=BUDGET)
    alone = [invert(files / "bela.nc", files / "db1064.nc", budget=BUDGET),
             invert(files / "atlas.nc", files / "db532.nc", budget=BUDGET)]
    r = fits[0].sel(parameter=KEY)
    assert float(r["low95"]) <= TRUE_TAU * 1e-3 <= float(r["high95"])
    width = float(np.log(r["high68"] / r["low68"]))
    for a in alone:
        s = a.sel(parameter=KEY)
        assert width < float(np.log(s["high68"] / s["low68"]))
    # every channel's file holds the same joint posterior, its own fit and the joint ln Z
    for name in ("median", "low68", "high68", "low95", "high95", "posterior"):
        np.testing.assert_array_equal(fits[0][name].values, fits[1][name].values)
    assert float(fits[0]["log_evidence"]) == float(fits[1]["log_evidence"])
    assert fits[0].attrs["instrument_name"] == "bela" and fits[1].attrs["instrument_name"] == "atlas"
    assert "expected_counts" in fits[1] and "expected_mv" in fits[0]
    total = float(fits[0]["loglike"]) + float(fits[1]["loglike"])
    assert float(fits[0]["joint_log_likelihood"]) == pytest.approx(total, abs=1e-9)


def test_joint_evidence_is_the_integral_of_the_summed_likelihood(files):
    """With every amplitude fixed at 1 (no amplitude prior terms) the joint ln Z is
    ln ∫ L_a(θ) L_b(θ) π(θ) dθ: here against the trapezoid integral of the channels' own
    log L on a fine grid of 121 points in ln thickness (a step of 0.03 against a posterior
    sd of 0.08: within 0.004 of the sum at 241 points). The joint grid (40 points, refined
    where the mass is) agrees within 0.05 (quadrature, not Monte Carlo: both use the same
    shots)."""
    fix = {"amplitude": 1}
    fits = invert_joint([files / "bela.nc", files / "atlas.nc"],
                        [files / "db1064.nc", files / "db532.nc"], fix=fix, budget=BUDGET)
    coords = [np.linspace(np.log(0.5e-3), np.log(16e-3), 121)]
    grids = [prepare(o, d, fix=fix).problem.grid(coords) for o, d in
             ((files / "bela.nc", files / "db1064.nc"), (files / "atlas.nc", files / "db532.nc"))]
    u = coords[0]
    span = u[-1] - u[0]

    def ln_integral(f):         # ln ∫ e^f du / span, trapezoid rule
        top = f.max()
        g = np.exp(f - top)
        return top + np.log(float(np.sum(0.5 * (g[1:] + g[:-1]) * np.diff(u))) / span)
    expected = ln_integral(grids[0].loglike + grids[1].loglike)
    assert float(fits[0]["log_evidence"]) == pytest.approx(expected, abs=0.05)


def _one_line(capsys) -> str:
    err = [x for x in capsys.readouterr().err.strip().splitlines()
           if not x.startswith(("warpe-cl: qualifying", "warpe-cl: warning:"))]
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("argv, words", [
    (["{d}/bela.nc", "{d}/atlas.nc", "--database", "{d}/db1064.nc", "--joint"],
     "2 observed files but 1 --database"),
    (["{d}/bela.nc", "{d}/atlas.nc", "--database", "{d}/db1064.nc", "--database",
      "{d}/db532.nc", "--joint", "--instrument", "bela"], "2 observed files but 1 --instrument"),
    (["{d}/bela.nc", "{d}/atlas.nc", "--database", "{d}/db1064.nc", "--database",
      "{d}/db532.nc", "--joint", "--fix", 'pulse_fwhm="6.5 ns"'], "its own pulse"),
    (["{d}/bela.nc", "{d}/atlas.nc", "--database", "{d}/db1064.nc", "--database",
      "{d}/db1064.nc", "--joint"], "computed at 1064 nm but atlas works at 532 nm"),
    (["{d}/bela.nc", "{d}/atlas.nc", "--database", "{d}/db1064.nc", "--database",
      "{d}/fewer.nc", "--joint"], "needs the same nodes in every database"),
    (["{d}/bela.nc", "--database", "{d}/db1064.nc", "--instrument", "bela", "--instrument",
      "gala"], "--instrument given 2 times"),
])
def test_joint_refusals_are_one_line_with_exit_2(files, capsys, argv, words):
    """Counts that differ, a per-instrument nuisance fixed, a database at the other
    wavelength, databases on other nodes, and two instruments without --joint."""
    fewer = files / "fewer.nc"
    if not fewer.exists():
        database("532 nm", taus=TAUS[::2]).to_netcdf(fewer, engine="h5netcdf")
    args = ["invert", *(a.format(d=files) for a in argv), "--out", str(files / "fit.nc"),
            "--overwrite"]
    assert main(args) == 2
    err = _one_line(capsys)
    assert words in err, err
    assert not list(files.glob("fit*.nc"))


def test_joint_command_writes_one_file_per_channel(files, capsys, monkeypatch):
    """``warpe-cl invert bela.nc atlas.nc --database ... --joint``: FIT_<label>.nc per channel,
    each naming both channels; the summary says each channel's wavelength. The budget is
    made small through the module's default to keep the test short."""
    import warpe_cl.inversion.joint as joint_module
    defaults = list(joint_module.invert_joint.__kwdefaults__.items())
    monkeypatch.setattr(joint_module.invert_joint, "__kwdefaults__",
                        {**dict(defaults), "budget": BUDGET})
    out = files / "cli" / "fit.nc"
    out.parent.mkdir()
    assert main(["invert", str(files / "bela.nc"), str(files / "atlas.nc"), "--database",
                 str(files / "db1064.nc"), "--database", str(files / "db532.nc"), "--joint",
                 "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "joint inversion of 2 channels" in said
    assert "channel at 1064 nm" in said and "channel at 532 nm" in said
    names = sorted(p.name for p in out.parent.glob("*.nc"))
    assert names == ["fit_atlas_db532.nc", "fit_bela_db1064.nc"]
