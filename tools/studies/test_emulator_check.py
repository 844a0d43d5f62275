"""The pure helpers of ``tools/studies/emulator_check.py``: the off-node draw and the refusals
of bad options. No simulation runs here. Outside the default run:
``python -m pytest tools/studies``."""
from __future__ import annotations

import sys

import numpy as np

from conftest import STUDIES

sys.path.insert(0, str(STUDIES))

import emulator_check as check  # noqa: E402

from warpe_cl.inversion.space import Axis  # noqa: E402


class _Space:
    def __init__(self, axes):
        self.axes = axes


def test_points_are_off_the_nodes_and_one_value_axes_keep_it():
    """An axis of one value once made the draw loop for ever (its cell fraction was NaN)."""
    space = _Space([Axis("a", np.array([1.0, 2.0, 4.0]), "m", "log"),
                    Axis("b", np.array([0.5]), "1"),
                    Axis("c", np.array([0.2, 0.6]), "1")])
    points = check.draw_points(space, 20, np.random.default_rng(3))
    assert len(points) == 20
    for p in points:
        assert p["b"] == 0.5
        u = np.log(p["a"])
        nodes = np.log([1.0, 2.0, 4.0])
        j = min(int(np.searchsorted(nodes, u, side="right")) - 1, 1)
        assert 0.1 < (u - nodes[j]) / (nodes[j + 1] - nodes[j]) < 0.9
        assert 0.24 < p["c"] < 0.56


def test_bad_options_are_one_line_and_exit_2(capsys, tmp_path):
    assert check.main(["--database", str(tmp_path), "--preset", str(tmp_path / "no.yaml")]) == 2
    assert check.main(["--database", str(tmp_path), "--preset", __file__, "--points", "0"]) == 2
    assert check.main(["--database", str(tmp_path), "--preset", __file__, "--shots", "x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("emulator_check: ") for line in err)
