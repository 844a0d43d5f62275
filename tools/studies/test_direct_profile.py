"""The pure helpers of ``tools/studies/direct_profile.py``: the key's grid, the profile, the
summary and the refusals of bad options. No simulation runs here. Outside the default run:
``python -m pytest tools/studies``."""
from __future__ import annotations

import sys

import numpy as np

from conftest import STUDIES

sys.path.insert(0, str(STUDIES))

import direct_profile as dp  # noqa: E402

from warpe_cl.inversion.space import Axis  # noqa: E402


def test_the_grid_is_even_in_the_axis_coordinate_and_holds_the_truth():
    axis = Axis("medium.thickness", np.array([0.1, 1.0, 10.0]), "m", "log")
    grid = dp.key_grid(axis, 3, None, 0.5)
    assert np.allclose(grid, [0.1, 0.5, 1.0, 10.0])
    assert np.array_equal(dp.key_grid(axis, 3, "0.2,0.1", 0.2), [0.1, 0.2])  # once, sorted
    linear = Axis("medium.compacity", np.array([0.2, 0.6]), "1")
    assert np.allclose(dp.key_grid(linear, 5, None, 0.6), [0.2, 0.3, 0.4, 0.5, 0.6])


def test_the_profile_is_the_best_over_the_other_keys():
    loglike = np.array([[[1.0, 5.0], [2.0, 0.0]], [[-1.0, -2.0], [-3.0, 4.0]]])
    assert np.array_equal(dp.profile(loglike), [5.0, 4.0])


def test_the_summary_reads_peaks_and_deltas_at_the_truth():
    grid = np.array([0.1, 0.2, 0.3])
    own = np.array([0.0, 1.0, 3.0])             # peaks at 0.3, 1.0 above the truth's 0.2
    fresh = [np.array([0.0, 2.0, 1.0]), np.array([0.5, 0.0, 0.0])]
    out = dp.summary(grid, 0.2, [own, *fresh])
    assert out["own_best"] == 0.3 and out["own_delta"] == 2.0
    assert out["best"][1:] == [0.2, 0.1] and out["delta"][1:] == [0.0, 0.5]
    assert out["fresh_above"] == 0.0 and np.isclose(out["fresh_median_best"], 0.15)
    assert out["fresh_mean_2delta"] == 0.5 and out["fresh_max_delta"] == 0.5
    assert out["own_rank"] == 1.0               # above both fresh deltas
    assert "fresh_median_best" not in dp.summary(grid, 0.2, [own])


def test_bad_options_are_one_line_and_exit_2(capsys, tmp_path):
    folder = tmp_path / "fam" / "inj" / "i003"
    base = ["fam", "--work", str(tmp_path), "--injection", "3", "--instrument", "bela",
            "--key", "medium.thickness"]
    assert dp.main(base) == 2                                   # no injection folder
    folder.mkdir(parents=True)
    assert dp.main(base) == 2                                   # no shots of that instrument
    (folder / "bela.nc").write_text("")
    assert dp.main(base) == 2                                   # no truth's surface, preset
    for name in ("surface.nc", "preset.yaml"):
        (folder / name).write_text("")
    assert dp.main(base + ["--values", "0.1,x"]) == 2
    assert dp.main(base + ["--profile-points", "1"]) == 2
    assert dp.main(base + ["--photons", "0"]) == 2
    assert dp.main(base + ["--out", str(tmp_path / "no" / "rows.json")]) == 2
    assert dp.main(base) == 2                                   # no injections.csv
    (tmp_path / "fam" / "injections.csv").write_text("index,medium.thickness_text\n1,1 m\n")
    assert dp.main(base) == 2                                   # injection 3 not a row
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 9 and all(line.startswith("direct_profile: ") for line in err)
    assert "not a row" in err[-1] and "no injections" in err[-2]
