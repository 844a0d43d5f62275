"""``warpe-cl invert`` refuses what a referee would (issue 41, docs/inversion.md §1): an
incomplete database (a sweep stopped after 3 of 45 scenarios once inverted with exit 0 over a
grid of one grain size), a ``--fix`` quantity without its unit (read as metres without a
word, where ``run --set`` refuses it), and option typos found only after the database was
loaded (40-60 s). Each is one line, exit 2; a fixed value is echoed with its unit."""
from __future__ import annotations

import json
import shutil
import sys

import pytest

from conftest import tiny_grid
import warpe_cl.inversion.invert as invert_module
import warpe_cl.sweep as sweep_module
from warpe_cl.cli import main
from warpe_cl.database import load_result
from warpe_cl.instrument import apply_instrument


@pytest.fixture(scope="module")
def done(tmp_path_factory):
    """A complete tiny database (thickness 5, 10 mm x tau0 0.5, 2) and BELA shots of its
    scenario 0."""
    tmp = tmp_path_factory.mktemp("refusals")
    preset = tmp / "grid.yaml"
    preset.write_text(tiny_grid(photons=300, seed=1))
    summary = sweep_module.run_sweep(preset, tmp / "db", quiet=True, say=lambda line: None)
    assert summary.exit_code == 0 and summary.done == 4
    surface = load_result(sorted((tmp / "db").glob("s00000_*.nc"))[0])
    apply_instrument(surface, "bela", {"geometry.altitude": "20 km"}, shots=8,
                     seed=2).to_netcdf(tmp / "obs.nc", engine="h5netcdf")
    return tmp


def _argv(d, db, *extra):
    return ["invert", str(d / "obs.nc"), "--database", str(db), "--out",
            str(d / "fit.nc"), "--overwrite", *extra]


def _error(capsys) -> str:
    err = [x for x in capsys.readouterr().err.strip().splitlines()
           if not x.startswith(("warpe-cl: qualifying", "warpe-cl: warning:"))]
    assert len(err) == 1, err
    return err[0]


def test_an_incomplete_database_is_refused_with_the_missing_scenarios(done, tmp_path, capsys):
    """Scenarios 2 and 3 not done: the two finished ones (5 mm, tau0 0.5 and 2) fill a grid
    of one thickness, which the old check took for a complete 1 x 2 grid (exit 0)."""
    db = tmp_path / "db"
    shutil.copytree(done / "db", db)
    manifest = json.loads((db / "manifest.json").read_text())
    for row in manifest["scenarios"][2:]:
        row.update(status="pending", sha256=None)
    (db / "manifest.json").write_text(json.dumps(manifest))
    assert main(_argv(done, db)) == 2
    err = _error(capsys)
    assert "2 of its 4 scenarios are missing (indices 2, 3)" in err, err
    assert f"warpe-cl sweep PRESET --out {db} --resume" in err, err


def test_a_complete_database_inverts_and_echoes_the_fixed_value_with_its_unit(done, capsys):
    assert main(_argv(done, done / "db", "--fix", "medium.thickness=5mm")) == 0
    out = capsys.readouterr().out
    assert "fixed: medium.thickness = 5 mm" in out, out
    fit = load_result(done / "fit.nc")
    assert json.loads(fit.attrs["fixed"]) == {"medium.thickness": "5 mm"}
    assert list(fit["parameter"].values) == ["medium.radiative.tau0"]


def test_a_sweep_file_not_combined_yet_is_read_from_its_folder(done, tmp_path, capsys):
    """`--database X.nc` whose X.sweep/ is complete but X.nc was never written (its combining
    failed): the options were checked against X.sweep/, then the load said "no such file"."""
    import shutil
    shutil.copytree(done / "db", tmp_path / "x.sweep")
    argv = _argv(done, tmp_path / "x.nc", "--fix", "medium.thickness=5mm")
    argv[argv.index("--out") + 1] = str(tmp_path / "fit.nc")
    assert main(argv) == 0, capsys.readouterr().err
    assert list(load_result(tmp_path / "fit.nc")["parameter"].values) == ["medium.radiative.tau0"]


@pytest.mark.parametrize("fix, words", [
    ("medium.thickness=0.005", ["--fix: medium.thickness=0.005: 0.005 is a bare number with no unit",
                                "give a length with a unit (", "[5 mm, 10 mm]"]),
    ("medium.thickness=5", ["bare number", "length"]),
    ("medium.thickness=7 deg", ["is an angle", "length"]),
    ("medium.thickness=50 mm", ["50 mm is outside the database's range [5 mm, 10 mm]"]),
    ("pulse_fwhm=6.5", ["pulse_fwhm", "bare number", "a time with a unit"]),
    ("medium.radiative.tau0=thick", ["not a number", "medium.radiative.tau0"]),
])
def test_fix_follows_the_unit_rule_of_run_set(done, capsys, fix, words):
    assert main(_argv(done, done / "db", "--fix", fix)) == 2
    err = _error(capsys)
    for w in words:
        assert w in err, err


@pytest.mark.parametrize("extra, words", [
    (["--fix", "medium.thicknes=5 mm"], "--fix medium.thicknes: not a swept key"),
    (["--free", "medium.tau0"], "--free medium.tau0: not a free swept key"),
    (["--fix", "medium.thickness=5"], "bare number"),
    (["--fix", "medium.thickness=5 mm", "--fix", "medium.radiative.tau0=0.5"],
     "every swept key is fixed"),
    (["--jobs", "0"], "--jobs: '0' is not a number of worker processes (an integer >= 1)"),
    (["--jobs", "two"], "--jobs: 'two' is not a number of worker processes"),
])
def test_options_are_checked_before_the_scenario_files_are_read(done, capsys, monkeypatch,
                                                                 extra, words):
    """Only the manifest is read before the options are checked: loading the scenario files
    is made to fail, and the option's own error comes instead."""
    def no_loading(*args, **kwargs):
        raise AssertionError("the database was loaded before the options were checked")
    monkeypatch.setattr(invert_module, "load_result", no_loading)
    assert main(_argv(done, done / "db", *extra)) == 2
    err = _error(capsys)
    assert words in err, err


if __name__ == "__main__":          # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))
