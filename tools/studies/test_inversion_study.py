"""The pure helpers of ``tools/studies/inversion_study.py``: the spacing of a sweep axis, the
off-grid draw of the injected points, the values as written, the plan of an injection and its
preset. No simulation runs here (the tool's build and inject verbs call warpe-cl as child
processes). Outside the default run: ``python -m pytest tools/studies``."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from conftest import REPO, STUDIES

sys.path.insert(0, str(STUDIES))

import inversion_study as study  # noqa: E402

from warpe_cl.config import load_preset  # noqa: E402

GRAINS = [25e-6, 50e-6, 100e-6, 200e-6, 400e-6]
COMPACITY = [0.1, 0.3, 0.5, 0.7, 0.9]
THICKNESS = [1e-3, 3.16e-3, 10e-3, 31.6e-3, 100e-3, 316e-3, 1.0]
SLAB_COMPACITY = [0.9, 0.95, 0.99, 0.995, 0.999]
FAMILIES = ("gran_co2", "slab_h2o_co2", "gran_h2o")


@pytest.mark.parametrize("nodes, kind", [
    (GRAINS, "log"), (THICKNESS, "log"), (COMPACITY, "linear"),
    (SLAB_COMPACITY, "log1m"), ([1.0, 2.0, 3.0], "linear"), (list(reversed(GRAINS)), "log"),
    ([0.001, 0.01, 0.1, 1.0], "log"), ([-1.0, 0.0, 1.0], "linear"),
    ([1.0, 2.0], "linear"), ([1.0, 100.0], "log")])
def test_spacing_detection(nodes, kind):
    assert study.detect_spacing(nodes) == kind


def test_spacing_needs_two_nodes():
    with pytest.raises(ValueError):
        study.detect_spacing([0.5, 0.5])


def _draw(count=400, seed=7, tolerance=study.NODE_TOLERANCE):
    nodes = [GRAINS, COMPACITY, THICKNESS]
    return nodes, study.draw_points(nodes, ["log", "linear", "log"], count, seed, tolerance)


def test_draw_is_inside_the_range():
    nodes, pts = _draw()
    assert pts.shape == (400, 3)
    for j, n in enumerate(nodes):
        assert np.all(pts[:, j] > min(n)) and np.all(pts[:, j] < max(n))


def test_draw_is_never_at_a_node():
    nodes, pts = _draw(count=2000)
    fwd = [np.log10, np.asarray, np.log10]
    nodes_u = [f(np.array(n)) for f, n in zip(fwd, nodes)]
    spans = [u[-1] - u[0] for u in nodes_u]
    for p in pts:
        u = [f(np.array(x)) for f, x in zip(fwd, p)]
        assert not study.at_node(u, nodes_u, spans)


def test_at_node_needs_every_dimension():
    nodes_u, spans = [np.array([0.0, 1.0]), np.array([0.0, 1.0])], [1.0, 1.0]
    assert study.at_node([0.01, 0.99], nodes_u, spans)         # next to the node (0, 1)
    assert not study.at_node([0.01, 0.5], nodes_u, spans)      # on a node line, not at a node
    assert not study.at_node([0.03, 0.0], nodes_u, spans)      # 3 % away in one dimension


def test_a_large_tolerance_forces_redraws():
    # with 45 % of the span around each of two nodes, only the middle 10 % of one axis is off
    # the nodes: every point must have one coordinate there
    pts = study.draw_points([[0.0, 1.0], [0.0, 1.0]], ["linear", "linear"], 200, 3, 0.45)
    middle = (pts > 0.45) & (pts < 0.55)
    assert np.all(middle.any(axis=1))


def test_log_draw_is_uniform_in_log():
    # uniform in log10 between 25 and 400 um: each factor 2 holds a quarter of the points
    _, pts = _draw(count=4000)
    counts = np.histogram(np.log2(pts[:, 0] / 25e-6), bins=4, range=(0, 4))[0]
    assert np.all(np.abs(counts - 1000) < 5 * np.sqrt(1000 * 0.75))     # 5 binomial sigmas
    lin = np.histogram(pts[:, 1], bins=4, range=(0.1, 0.9))[0]
    assert np.all(np.abs(lin - 1000) < 5 * np.sqrt(1000 * 0.75))


def test_log1m_draw():
    pts = study.draw_points([SLAB_COMPACITY], ["log1m"], 2000, 1)[:, 0]
    assert np.all((pts > 0.9) & (pts < 0.999))
    # uniform in -log10(1 - c) over [1, 3]: half the points have 1 - c below 1e-2
    assert abs(np.mean(1 - pts < 1e-2) - 0.5) < 5 * np.sqrt(0.25 / 2000)


def test_draw_is_deterministic_and_a_prefix():
    _, a = _draw(count=50, seed=7)
    _, b = _draw(count=50, seed=7)
    _, c = _draw(count=20, seed=7)
    _, d = _draw(count=50, seed=8)
    assert np.array_equal(a, b)
    assert np.array_equal(a[:20], c)
    assert not np.array_equal(a, d)


def test_value_text_round_trips_in_the_nodes_unit():
    raw = study.read_preset(study.STUDY_PRESETS / "gran_co2.yaml")
    grain, compacity, thickness = study.sweep_axes(raw)
    assert study.value_text(137.2e-6, grain) == "137.2 um"
    assert study.value_text(0.21235212, thickness) == "212.352 mm"
    assert study.value_text(0.123456789012, compacity) == pytest.approx(0.12345679, abs=0)


def test_sweep_axes_of_the_study_presets():
    raw = study.read_preset(study.STUDY_PRESETS / "gran_co2.yaml")
    axes = study.sweep_axes(raw)
    assert [a.key for a in axes] == ["medium.inclusions[0].grain_size", "medium.compacity",
                                     "medium.thickness"]
    assert [a.dimension for a in axes] == ["length", None, "length"]
    assert np.allclose(axes[0].values, GRAINS) and np.allclose(axes[2].values, THICKNESS)


def test_a_preset_without_sweep_is_refused():
    with pytest.raises(study.StudyError, match="no sweep"):
        study.sweep_axes({"medium": {}})
    with pytest.raises(study.StudyError, match="not a number"):
        study.sweep_axes({"sweep": {"medium.texture": ["slab", "granular"]}})


@pytest.mark.parametrize("family", FAMILIES)
def test_plan_and_injection_presets(family):
    raw = study.read_preset(study.STUDY_PRESETS / f"{family}.yaml")
    axes, kinds, rows = study.plan_injections(raw, 5, 7, 1000, ["bela", "gala"])
    columns = study.csv_columns(axes, ["bela", "gala"])
    assert [r["index"] for r in rows] == list(range(5))
    assert {"surface", "bela", "gala", "bela_seed", "photons", "status"} <= set(columns)
    assert [r["surface_seed"] for r in rows] == [1000, 1001, 1002, 1003, 1004]
    assert [r["gala_seed"] for r in rows] == [3000, 3001, 3002, 3003, 3004]
    assert rows[3]["bela"] == "inj/i003/bela.nc"
    for row in rows:
        for axis in axes:
            assert axis.values[0] < float(row[axis.key]) < axis.values[-1]
            assert set(columns) - {"status"} <= set(row)
        # the injection's own preset: no sweep, the drawn values, valid for warpe-cl
        one = study.injection_preset(raw, row["point"], row["name"])
        assert "sweep" not in one and "sweep" in raw
        cfg = load_preset(one)
        for axis in axes:
            assert cfg.get(axis.key) == pytest.approx(float(row[axis.key]), rel=1e-12)


def test_spacing_override_and_unknown_key():
    raw = study.read_preset(study.STUDY_PRESETS / "gran_h2o.yaml")
    _, kinds, _ = study.plan_injections(raw, 2, 7, 1000, [],
                                        study.parse_spacings(["medium.compacity=log"]))
    assert kinds["medium.compacity"] == "log"
    with pytest.raises(study.StudyError):
        study.plan_injections(raw, 2, 7, 1000, [], {"medium.thickness": "log"})
    with pytest.raises(study.StudyError):
        study.parse_spacings(["medium.compacity=cubic"])


def test_a_csv_of_another_draw_is_refused(tmp_path):
    raw = study.read_preset(study.STUDY_PRESETS / "gran_h2o.yaml")
    axes, _, rows = study.plan_injections(raw, 3, 7, 1000, ["bela"])
    columns = study.csv_columns(axes, ["bela"])
    for row in rows:
        row["status"] = "pending"
    path = tmp_path / "injections.csv"
    study.write_csv(path, rows, columns)
    study.check_previous(path, rows, columns)                     # the same draw: fine
    _, _, longer = study.plan_injections(raw, 5, 7, 1000, ["bela"])
    study.check_previous(path, longer, columns)                   # a longer one: a prefix
    _, _, more = study.plan_injections(raw, 3, 7, 1000, ["bela", "gala"])
    study.check_previous(path, more, study.csv_columns(axes, ["bela", "gala"]))  # + an instrument
    for other in (study.plan_injections(raw, 3, 8, 1000, ["bela"])[2],
                  study.plan_injections(raw, 3, 7, 2000, ["bela"])[2],
                  study.plan_injections(raw, 3, 7, 1000, ["bela"], per_decade=2000)[2]):
        with pytest.raises(study.StudyError):
            study.check_previous(path, other, columns)


def test_command_uses_this_python():
    cmd = study.warpe_cl_command("run", REPO / "x.yaml", "--seed", 3)
    assert cmd[:3] == [sys.executable, "-m", "warpe_cl"] and cmd[-1] == "3"


def test_photons_default_to_the_database(tmp_path):
    raw = study.read_preset(study.STUDY_PRESETS / "gran_h2o.yaml")
    db = tmp_path / "db"
    assert study.default_photons(raw, db, None) == 50000              # the preset's
    db.mkdir()
    (db / "manifest.json").write_text('{"photons": 400000}')
    assert study.database_photons(db) == 400000
    assert study.default_photons(raw, db, None) == 400000             # the database's
    assert study.default_photons(raw, db, 1e5) == 100000              # --photons


# --------------------------------------------------------------------------- instruments

MLA = """\
name: mla
description: a user's instrument, BELA's chain sampled every 5 ns
base: bela
adc:
  sampling_interval: "5 ns"
"""


def test_any_instrument_file_is_accepted_and_kept_with_the_study(tmp_path):
    """Issue 41: an instrument file from anywhere, beside bundled and study names; a file is
    copied into the family's instruments/ folder, which the injections are simulated with."""
    mla = tmp_path / "elsewhere" / "mla.yaml"
    mla.parent.mkdir()
    mla.write_text(MLA)
    resolved = study.resolve_instruments(["bela", str(mla), "bela_5ns"])
    assert [label for label, _ in resolved] == ["bela", "mla", "bela_5ns"]
    assert resolved[0][1] == "bela" and resolved[1][1] == str(mla.resolve())
    assert resolved[2][1].endswith("presets/study/instruments/bela_5ns.yaml")
    family = tmp_path / "work" / "gran_co2"
    staged = dict(study.stage_instruments(family, resolved))
    assert staged["bela"] == "bela"
    assert staged["mla"] == str(family / "instruments" / "mla.yaml")
    assert (family / "instruments" / "mla.yaml").read_text() == MLA
    assert (family / "instruments" / "bela_5ns.yaml").is_file()
    assert dict(study.stage_instruments(family, resolved)) == staged     # again: unchanged
    mla.write_text(MLA.replace("5 ns", "2 ns"))
    with pytest.raises(study.StudyError, match="another instrument 'mla'"):
        study.stage_instruments(family, study.resolve_instruments([str(mla)]))


def test_chosen_instruments():
    assert study.chosen_instruments(None, None) == ["bela", "gala"]
    assert study.chosen_instruments(None, ["a.yaml"]) == ["a.yaml"]
    assert study.chosen_instruments("bela", ["a.yaml"]) == ["bela", "a.yaml"]
    assert study.chosen_instruments("", None) == []


@pytest.mark.parametrize("content, name, message", [
    (None, "missing.yaml", "no such file"),
    (MLA.replace("adc:", "adcc:"), "bad.yaml", "adcc"),
    (MLA.replace('"5 ns"', "5"), "unitless.yaml", "sampling_interval"),
    (None, "mla", "neither a bundled instrument"),
])
def test_bad_instruments_are_refused_in_one_line(tmp_path, capsys, content, name, message):
    path = tmp_path / name
    if content is not None:
        path.write_text(content)
    value = str(path) if name.endswith(".yaml") else name
    with pytest.raises(study.StudyError, match=message) as caught:
        study.resolve_instruments([value])
    assert "\n" not in str(caught.value)
    rc = study.main(["inject", "gran_co2", "--work", str(tmp_path / "w"), "--instrument", value])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and message in err[0]
    assert not (tmp_path / "w").exists()                      # refused before anything


def test_two_instruments_of_one_label_are_refused(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "bela.yaml").write_text(MLA.replace("name: mla", "name: bela"))
    with pytest.raises(study.StudyError, match="second instrument labelled 'bela'"):
        study.resolve_instruments(["bela", str(tmp_path / "a" / "bela.yaml")])


def test_injections_in_finer_time_bins():
    """``--per-decade``: the injected surfaces' time bins, recorded per row, set in their
    presets (only where they differ from the family's), part of the draw a CSV must agree
    with, and refused in one line when not a count >= 1."""
    raw = study.read_preset(study.STUDY_PRESETS / "slab_co2_rough.yaml")
    own = raw["simulation"]["time_bins"]["per_decade"]
    assert study.preset_per_decade(raw) == own
    assert study.preset_per_decade({"name": "x"}) == 20                 # the schema's default
    axes, _, rows = study.plan_injections(raw, 2, 7, 1000, ["bela"])
    assert [r["per_decade"] for r in rows] == [own, own]
    same = study.injection_preset(raw, rows[0]["point"], rows[0]["name"], own)
    assert same["simulation"] == raw["simulation"]
    _, _, fine = study.plan_injections(raw, 2, 7, 1000, ["bela"], per_decade=2000)
    one = study.injection_preset(raw, fine[0]["point"], fine[0]["name"], fine[0]["per_decade"])
    assert load_preset(one).get("simulation.time_bins.per_decade") == 2000
    assert raw["simulation"]["time_bins"]["per_decade"] == own        # the family's untouched
    assert "per_decade" in study.csv_columns(axes, ["bela"])


@pytest.mark.parametrize("value", ["0", "-3"])
def test_bad_per_decade_is_refused_in_one_line(tmp_path, capsys, value):
    rc = study.main(["inject", "slab_co2_rough", "--work", str(tmp_path / "w"),
                     "--per-decade", value, "--instruments", ""])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--per-decade" in err[0]
    assert not (tmp_path / "w").exists()
