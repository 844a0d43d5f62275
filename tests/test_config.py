"""Tests of warpe_cl.config: the schema table, loading, overrides, validation and sweeps."""
import copy
import pickle
import textwrap

import numpy as np
import pytest
import yaml

from warpe_cl.config import (FIELDS, SCHEMA, Config, load_preset, schema_markdown,
                             time_edges)
from warpe_cl.errors import ConfigError, WarpeError

RADIATIVE = {
    "medium": {"texture": "slab", "thickness": "100 mm",
               "radiative": {"tau0": 1.0, "omega": 0.9, "n": 1.3}},
}

PHYSICAL_YAML = """\
name: slab_h2o_co2_thickness
description: Water-ice slab with 10 % CO2 inclusions of 100 um, thickness sweep.
medium:
  texture: slab
  thickness: "1000 mm"
  compacity: 0.9
  matrix: H2O
  inclusions:
    - material: CO2
      proportion: 1.0
      grain_size: "100 um"
  bottom_albedo: 0.15
  bottom_interface: fresnel
  phase_g: 0.8
wavelength: "1064 nm"
materials:
  CH4: {n: 1.3, k: 1.0e-5}
simulation:
  photons: 1.0e6
  seed: 1
  time_bins: {start: "1e-6 ns", stop: "1e5 ns", per_decade: 20}
  max_time: "1e5 ns"
  fov: {scattering: "12 deg", bf_diffuse: "3 deg"}
  min_rays: 3
sweep:
  medium.thickness: ["1 mm", "10 mm", "100 mm", "1000 mm"]
instrument:
  name: bela
  altitude: "500 km"
  roughness: "0.1 deg"
"""


def write(tmp_path, text, name="a.yaml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text), encoding="utf-8")
    return path


def radiative(**changes):
    """A valid radiative preset dict with dotted-key ``changes`` applied (None deletes)."""
    data = copy.deepcopy(RADIATIVE)
    for key, value in changes.items():
        *head, last = key.split("__")
        node = data
        for part in head:
            node = node.setdefault(part, {})
        if value is None:
            node.pop(last, None)
        else:
            node[last] = value
    return data


# --------------------------------------------------------------------------- malformed files

MALFORMED = {
    # name: (YAML text, key the message must name, fragment it must contain)
    "missing unit": (
        "medium: {texture: slab, thickness: 100, radiative: {tau0: 1, omega: 0.5, n: 1.3}}",
        "medium.thickness", "no unit"),
    "negative thickness": (
        'medium: {texture: slab, thickness: "-1 mm", radiative: {tau0: 1, omega: 0.5, n: 1.3}}',
        "medium.thickness", '-1 mm is not allowed; give a length > 0 with a unit, e.g. "100 mm"'),
    "wrong dimension": (
        'medium: {texture: slab, thickness: "12 deg", radiative: {tau0: 1, omega: 0.5, n: 1.3}}',
        "medium.thickness", "an angle"),
    "omega above 1": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 1.5, n: 1.3}}',
        "medium.radiative.omega", "1.5 is not allowed; give a number in [0, 1]"),
    "boolean for a float": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: yes, n: 1.3}}',
        "medium.radiative.omega", "boolean"),
    "unknown key": (
        'medium: {texture: slab, thikness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}',
        "medium.thikness", "did you mean medium.thickness?"),
    "unknown texture": (
        'medium: {texture: granualr, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1}}',
        "medium.texture", "did you mean granular?"),
    "missing medium": (
        "simulation: {photons: 10}", "medium", "medium.texture and medium.thickness"),
    "missing thickness": (
        "medium: {texture: slab, radiative: {tau0: 1, omega: 0.5, n: 1.3}}",
        "medium.thickness", "missing"),
    "radiative and physical": (
        'medium: {texture: slab, thickness: "1 m", compacity: 0.9,'
        ' radiative: {tau0: 1, omega: 0.5, n: 1.3}}',
        "medium.radiative", "not both"),
    "neither form": (
        'medium: {texture: slab, thickness: "1 m"}',
        "medium", "medium.radiative"),
    "radiative missing n": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5}}',
        "medium.radiative.n", "missing"),
    "granular with matrix": (
        'medium: {texture: granular, thickness: "1 m", compacity: 0.5, matrix: H2O,'
        ' inclusions: [{material: CO2, proportion: 1, grain_size: "1 mm"}]}',
        "medium.matrix", "granular"),
    "slab without matrix": (
        'medium: {texture: slab, thickness: "1 m", compacity: 0.5,'
        ' inclusions: [{material: CO2, proportion: 1, grain_size: "1 mm"}]}',
        "medium.matrix", "missing"),
    "no inclusions": (
        'medium: {texture: slab, thickness: "1 m", compacity: 0.5, matrix: H2O, inclusions: []}',
        "medium.inclusions", "non-empty list"),
    "inclusion without unit": (
        'medium: {texture: slab, thickness: "1 m", compacity: 0.5, matrix: H2O,'
        ' inclusions: [{material: CO2, proportion: 1, grain_size: 100}]}',
        "medium.inclusions[0].grain_size", "no unit"),
    "compacity zero": (
        'medium: {texture: slab, thickness: "1 m", compacity: 0, matrix: H2O,'
        ' inclusions: [{material: CO2, proportion: 1, grain_size: "1 mm"}]}',
        "medium.compacity", "(0, 1]"),
    "time bins width and per_decade": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        'simulation: {time_bins: {start: "0 ns", stop: "10 ns", width: "1 ns", per_decade: 5}}',
        "simulation.time_bins", "not both"),
    "time bins stop before start": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        'simulation: {time_bins: {start: "10 ns", stop: "1 ns", per_decade: 5}}',
        "simulation.time_bins.stop", "> start"),
    "log bins from zero": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        'simulation: {time_bins: {start: "0 ns", stop: "1 ns"}}',
        "simulation.time_bins.start", "log-spaced"),
    "seed too large": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        "simulation: {seed: 4294967296}",
        "simulation.seed", "[0, 4294967295]"),
    "photons zero": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        "simulation: {photons: 0}",
        "simulation.photons", "0 rays is not allowed; give a whole number of rays in [1, 2^53"),
    "photons not whole": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        "simulation: {photons: 2.5}",
        "simulation.photons", "whole"),
    "fov 95 deg": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        'simulation: {fov: {scattering: "95 deg"}}',
        "simulation.fov.scattering", "(0, 90] deg"),
    "unknown precision": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        "simulation: {precision: dubble}",
        "simulation.precision", "did you mean double?"),
    "key in the wrong section": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        "photons: 1000",
        "photons", "simulation.photons"),
    "unknown sweep key": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        'sweep: {medium.thikness: ["1 mm"]}',
        "sweep.medium.thikness", "did you mean medium.thickness?"),
    "sweep value invalid": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        'sweep: {medium.thickness: ["1 mm", "-2 mm"]}',
        "sweep.medium.thickness", "-2 mm is not allowed"),
    "sweep value not a list": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        'sweep: {medium.thickness: "1 mm"}',
        "sweep.medium.thickness", "non-empty list"),
    "material with table and n": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        "materials: {CH4: {n: 1.3, table: ch4.csv}}",
        "materials.CH4.n", "either n and k, or table"),
    "material table missing": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        "materials: {CH4: {table: nowhere.csv}}",
        "materials.CH4.table", "no such file"),
    "instrument altitude bare": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        "instrument: {name: bela, altitude: 500}",
        "instrument.altitude", "no unit"),
    "section not a mapping": (
        'medium: {texture: slab, thickness: "1 m", radiative: {tau0: 1, omega: 0.5, n: 1.3}}\n'
        "simulation: 5",
        "simulation", "not a mapping"),
}

FILE_LEVEL = {
    "empty file": ("", "the file is empty; a preset needs at least medium.texture and "
                       "medium.thickness"),
    "only a comment": ("# nothing here\n", "the file is empty"),
    "not YAML": ("medium:\n  texture: slab\n    thickness: 1\n",
                 "not valid YAML (line 3, column 14: "),
    "top-level list": ("- medium\n- simulation\n", "the top level is a list"),
    "top-level scalar": ("just some text\n", "the top level is one text of 14 characters"),
    "duplicate key": ("medium:\n  texture: slab\n  texture: granular\n",
                      'the key "texture" is given twice'),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_preset(tmp_path, case):
    text, key, fragment = MALFORMED[case]
    path = write(tmp_path, text + "\n")
    with pytest.raises(ConfigError) as info:
        load_preset(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: {key}: "), message
    assert fragment in message, message
    assert info.value.key == key
    assert info.value.source == str(path)


@pytest.mark.parametrize("case", sorted(FILE_LEVEL))
def test_malformed_file(tmp_path, case):
    text, fragment = FILE_LEVEL[case]
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_preset(str(path))
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: "), message
    assert fragment in message, message


def test_enough_malformed_cases():
    assert len(MALFORMED) + len(FILE_LEVEL) >= 14


def test_missing_file(tmp_path):
    path = tmp_path / "nowhere.yaml"
    with pytest.raises(ConfigError) as info:
        load_preset(path)
    assert str(info.value) == f"{path}: no such file"


def test_folder_instead_of_file(tmp_path):
    with pytest.raises(ConfigError, match="folder"):
        load_preset(tmp_path)


def test_not_utf8(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("name: caf\xe9\n".encode("latin-1"))
    with pytest.raises(ConfigError, match="UTF-8"):
        load_preset(path)


def test_config_error_is_warpe_error_and_picklable():
    err = ConfigError("1.5 is not allowed; give a number in [0, 1]", "medium.radiative.omega",
                      "a.yaml")
    assert isinstance(err, WarpeError)
    assert str(err) == "a.yaml: medium.radiative.omega: 1.5 is not allowed; give a number in [0, 1]"
    copy_ = pickle.loads(pickle.dumps(err))
    assert str(copy_) == str(err) and copy_.key == err.key and copy_.source == err.source
    assert str(ConfigError("x is wrong", "k")) == "k: x is wrong"
    assert str(ConfigError("two\nlines")) == "two lines"


def test_dict_source_is_named():
    with pytest.raises(ConfigError) as info:
        load_preset(radiative(medium__radiative__omega=-0.1))
    assert str(info.value).startswith("<dict>: medium.radiative.omega: -0.1 is not allowed")


def test_sweep_point_error_names_the_point():
    preset = radiative(sweep={"medium.texture": ["slab", "granular"]},
                       medium={"texture": "slab", "thickness": "1 m", "compacity": 0.9,
                               "matrix": "H2O", "inclusions": [
                                   {"material": "CO2", "proportion": 1, "grain_size": "1 mm"}]})
    cfg = load_preset(preset)
    with pytest.raises(ConfigError) as info:
        cfg.sweep_points()
    assert info.value.key == "medium.matrix"
    assert "medium.texture=granular" in str(info.value)
    assert "\n" not in str(info.value)


# --------------------------------------------------------------------------- defaults

def test_defaults_radiative():
    cfg = load_preset(copy.deepcopy(RADIATIVE))
    assert cfg.source == "<dict>"
    assert cfg.is_radiative
    assert cfg.name == "unnamed"
    d = cfg.data
    assert d["description"] == ""
    assert d["medium"] == {
        "texture": "slab", "thickness": 0.1, "bottom_albedo": 0.15,
        "bottom_interface": "fresnel", "phase_g": 0.8,
        "extinction_efficiency": 1.0, "matrix_absorption": "seed",
        "inclusion_absorption": "absolute", "fresnel_integrals": "exact",
        "radiative": {"tau0": 1.0, "omega": 0.9, "n": 1.3, "k": 0.0},
        "compacity": None, "matrix": None, "inclusions": None}
    assert d["wavelength"] == 1.064e-6
    assert d["materials"] == {}
    sim = d["simulation"]
    assert sim["photons"] == 1_000_000 and isinstance(sim["photons"], int)
    assert sim["seed"] == 1
    assert sim["time_bins"] == {"start": 1e-6, "stop": 1e5, "per_decade": 20}
    assert sim["max_time"] == pytest.approx(1e5)
    assert sim["max_time"] == time_edges(cfg)[-1]
    assert sim["max_flights"] == 10_000_000
    assert sim["fov"] == {"scattering": 12.0, "bf_diffuse": 3.0}
    assert sim["min_rays"] == 3
    assert sim["solid_angle"] == "cone"
    assert sim["component_rule"] == "history"
    assert sim["precision"] == "single"
    assert sim["specular_lobe"] == 0.25
    assert sim["mode"] == "analog"
    assert d["sweep"] == {}
    # no fixed default: absent, the instrument preset's own altitude and roughness stand
    assert d["instrument"] == {"name": None, "altitude": None, "roughness": None}


def test_physical_preset_file(tmp_path):
    path = write(tmp_path, PHYSICAL_YAML, "gran.yaml")
    cfg = load_preset(path)
    assert cfg.source == str(path)
    assert not cfg.is_radiative
    assert cfg.name == "slab_h2o_co2_thickness"
    assert cfg.get("medium.thickness") == 1.0
    assert cfg.get("medium.compacity") == 0.9
    assert cfg.get("medium.matrix") == "H2O"
    assert cfg.get("medium.inclusions") == [
        {"material": "CO2", "proportion": 1.0, "grain_size": 1e-4}]
    assert cfg.get("medium.inclusions[0].grain_size") == 1e-4
    assert cfg.get("medium.inclusions.0.grain_size") == 1e-4
    assert cfg.get("materials.CH4.k") == 1e-5
    assert cfg.get("simulation.photons") == 1_000_000      # "1.0e6" is a string to PyYAML
    assert cfg.get("instrument.name") == "bela"
    assert cfg.get("instrument.altitude") == 5e5
    assert cfg.raw["medium"]["thickness"] == "1000 mm"      # raw keeps what was written


def test_name_defaults_to_file_stem(tmp_path):
    path = write(tmp_path, yaml.safe_dump(RADIATIVE), "my_run.yaml")
    assert load_preset(path).name == "my_run"


def test_get_known_but_absent_keys_give_defaults():
    cfg = load_preset(copy.deepcopy(RADIATIVE))
    assert cfg.get("medium.compacity") is None
    assert cfg.get("medium.inclusions[0].grain_size") is None
    assert cfg.get("materials.XYZ.k") == 0.0
    assert cfg.get("simulation.time_bins.width") is None
    assert cfg.get("simulation.fov.bf_diffuse") == 3.0
    with pytest.raises(KeyError, match="did you mean medium.thickness"):
        cfg.get("medium.thikness")


def test_get_returns_copies():
    cfg = load_preset(copy.deepcopy(RADIATIVE))
    cfg.get("medium")["thickness"] = 5.0
    assert cfg.get("medium.thickness") == 0.1


def test_granular_accepts_bottom_interface():
    preset = radiative(medium__texture="granular", medium__bottom_interface="none")
    assert load_preset(preset).get("medium.bottom_interface") == "none"


def test_choices_are_case_insensitive():
    assert load_preset(radiative(medium__texture="Granular")).get("medium.texture") == "granular"


def test_numbers_written_as_strings_are_accepted():
    preset = radiative(simulation={"photons": "1e6", "seed": "7", "max_flights": 1e3},
                       medium__phase_g="0.5")
    cfg = load_preset(preset)
    assert cfg.get("simulation.photons") == 1_000_000
    assert cfg.get("simulation.seed") == 7
    assert cfg.get("simulation.max_flights") == 1000
    assert isinstance(cfg.get("simulation.max_flights"), int)
    assert cfg.get("medium.phase_g") == 0.5


def test_numpy_numbers_are_accepted():
    cfg = load_preset(radiative(simulation={"photons": np.int64(10), "seed": np.uint32(5)},
                                medium__phase_g=np.float32(0.5)))
    assert cfg.get("simulation.photons") == 10 and type(cfg.get("simulation.photons")) is int
    assert cfg.get("simulation.seed") == 5
    assert type(cfg.get("medium.phase_g")) is float


def test_linear_time_bins_default_start():
    cfg = load_preset(radiative(simulation={"time_bins": {"stop": "10 ns", "width": "2.5 ns"}}))
    assert cfg.get("simulation.time_bins") == {"start": 0.0, "stop": 10.0, "width": 2.5}
    np.testing.assert_allclose(time_edges(cfg), [0, 2.5, 5, 7.5, 10])


# --------------------------------------------------------------------------- time edges

def test_time_edges_log_default():
    edges = time_edges(load_preset(copy.deepcopy(RADIATIVE)))
    assert edges.dtype == np.float64
    assert len(edges) == 221                         # 11 decades x 20 + 1
    assert edges[0] == 1e-6
    assert edges[-1] == pytest.approx(1e5, rel=1e-12) and edges[-1] >= 1e5 * (1 - 1e-12)
    np.testing.assert_allclose(np.diff(np.log10(edges)), 0.05, rtol=1e-9)


def test_time_edges_log_partial_decade():
    edges = time_edges({"start": 1.0, "stop": 50.0, "per_decade": 2})
    np.testing.assert_allclose(edges, [1, 10**0.5, 10, 10**1.5, 100])
    assert edges[-1] >= 50


def test_time_edges_linear():
    cfg = load_preset(radiative(simulation={"time_bins": {"start": "0 ns", "stop": "200 ns",
                                                          "width": "0.5 ns"}}))
    edges = time_edges(cfg)
    assert len(edges) == 401
    assert edges[0] == 0.0 and edges[-1] == 200.0
    np.testing.assert_allclose(np.diff(edges), 0.5)
    # stop not on a multiple of the width: the last edge passes it
    edges = time_edges({"start": 1.0, "stop": 2.2, "width": 0.5})
    np.testing.assert_allclose(edges, [1.0, 1.5, 2.0, 2.5])


def test_max_time_default_follows_bins():
    cfg = load_preset(radiative(simulation={"time_bins": {"start": "0 ns", "stop": "20 ns",
                                                          "width": "1 ns"}}))
    assert cfg.get("simulation.max_time") == 20.0
    cfg = load_preset(radiative(simulation={"max_time": "1 us"}))
    assert cfg.get("simulation.max_time") == 1000.0


# --------------------------------------------------------------------------- overrides

def test_overrides_dict():
    cfg = load_preset(copy.deepcopy(RADIATIVE),
                      overrides={"simulation.photons": 1e5, "medium.thickness": "5 mm",
                                 "medium.radiative.omega": 0.5})
    assert cfg.get("simulation.photons") == 100_000
    assert cfg.get("medium.thickness") == 0.005
    assert cfg.get("medium.radiative.omega") == 0.5
    assert cfg.raw["simulation"]["photons"] == 1e5


def test_overrides_strings():
    cfg = load_preset(copy.deepcopy(RADIATIVE), overrides=[
        'medium.thickness="100 mm"', "simulation.photons=1e7", "simulation.seed=42",
        "simulation.fov.scattering=5 deg", "medium.phase_g=0.6",
        'sweep.medium.radiative.tau0=[0.1, 1, 10]'])
    assert cfg.get("medium.thickness") == 0.1
    assert cfg.get("simulation.photons") == 10_000_000
    assert cfg.get("simulation.seed") == 42
    assert cfg.get("simulation.fov.scattering") == 5.0
    assert cfg.get("medium.phase_g") == 0.6
    assert [c.get("medium.radiative.tau0") for _, c in cfg.sweep_points()] == [0.1, 1.0, 10.0]


def test_override_does_not_touch_the_given_dict():
    preset = copy.deepcopy(RADIATIVE)
    load_preset(preset, overrides={"medium.thickness": "5 mm"})
    assert preset == RADIATIVE


def test_override_list_item(tmp_path):
    cfg = load_preset(write(tmp_path, PHYSICAL_YAML),
                      overrides=["medium.inclusions[0].grain_size=20 um"])
    assert cfg.get("medium.inclusions[0].grain_size") == 2e-5


def test_override_file_preset(tmp_path):
    cfg = load_preset(write(tmp_path, PHYSICAL_YAML), overrides={"simulation.photons": "1e3"})
    assert cfg.get("simulation.photons") == 1000


@pytest.mark.parametrize("override, key, fragment", [
    ("medium.thikness=5 mm", "medium.thikness", "did you mean medium.thickness?"),
    ("medium.thickness", "medium.thickness", "KEY=VALUE"),
    ("medium.thickness=5", "medium.thickness", "no unit"),
    ("medium.thickness.x=1", "medium.thickness.x", "not a mapping"),
    ("simulation.photons=many", "simulation.photons", "not a number"),
])
def test_bad_overrides(tmp_path, override, key, fragment):
    path = write(tmp_path, PHYSICAL_YAML)
    with pytest.raises(ConfigError) as info:
        load_preset(path, overrides=[override])
    message = str(info.value)
    assert message.startswith(f"{path}: {key}: "), message
    assert fragment in message
    assert "\n" not in message


def test_with_overrides_and_config_source():
    cfg = load_preset(copy.deepcopy(RADIATIVE))
    other = load_preset(cfg, overrides={"simulation.seed": 9})
    assert other.get("simulation.seed") == 9
    assert cfg.get("simulation.seed") == 1
    assert isinstance(cfg.with_overrides(["simulation.seed=3"]), Config)


# --------------------------------------------------------------------------- YAML round trip

@pytest.mark.parametrize("variant", ["radiative", "physical", "linear", "everything"])
def test_to_yaml_round_trip(tmp_path, variant):
    if variant == "radiative":
        cfg = load_preset(copy.deepcopy(RADIATIVE))
    elif variant == "physical":
        cfg = load_preset(write(tmp_path, PHYSICAL_YAML))
    elif variant == "linear":
        cfg = load_preset(radiative(simulation={"time_bins": {"start": "0 ns", "stop": "3 ns",
                                                              "width": "0.1 ns"}}))
    else:
        table = write(tmp_path, "wavelength_nm,n,k\n1064,1.3,1e-5\n", "ch4.csv")
        cfg = load_preset(radiative(
            name="all", description="every block",
            wavelength="532 nm",
            materials={"CH4": {"table": str(table)}, "X": {"n": 1.5}},
            simulation={"photons": 12345, "seed": 2**32 - 1, "max_flights": 77,
                        "fov": {"scattering": "0.3 rad", "bf_diffuse": "530 urad"},
                        "solid_angle": "projected", "component_rule": "time_window",
                        "precision": "double", "specular_lobe": "2.5 deg", "min_rays": 0,
                        "time_bins": {"start": "1e-3 ns", "stop": "3 us", "per_decade": 7},
                        "max_time": "1234.5 ns"},
            instrument={"name": "atlas", "altitude": "400 km", "roughness": "0.5 deg",
                        "shots": 100},                      # ATLAS works at 532 nm
            sweep={"medium.thickness": ["1 mm", "1 m"], "medium.radiative.omega": [0, 1]}))
    text = cfg.to_yaml()
    again = load_preset(yaml.safe_load(text))
    assert again.data == cfg.data
    assert again.to_yaml().splitlines()[1:] == text.splitlines()[1:]


def test_to_yaml_writes_units():
    text = load_preset(copy.deepcopy(RADIATIVE)).to_yaml()
    doc = yaml.safe_load(text)
    assert doc["medium"]["thickness"] == "100 mm"
    assert doc["wavelength"] == "1064 nm"
    assert doc["simulation"]["fov"] == {"scattering": "12 deg", "bf_diffuse": "3 deg"}
    assert doc["simulation"]["time_bins"]["start"] == "1e-06 ns"
    assert "compacity" not in doc["medium"]          # None entries are left out
    assert doc["instrument"] == {}          # no instrument: nothing to resolve


def test_instrument_extra_keys_pass_through():
    cfg = load_preset(radiative(instrument={"name": "bela", "shots": 10, "adc": {"bits": 8}}))
    assert cfg.get("instrument.shots") == 10
    assert cfg.data["instrument"]["adc"] == {"bits": 8}
    assert cfg.get("instrument.not_there") is None
    # ... and are checked against the instrument's table when the preset is loaded
    with pytest.raises(ConfigError, match=r"^<dict>: instrument\.adc_bits: unknown key; did "
                                          r"you mean adc\.bits\?$"):
        load_preset(radiative(instrument={"name": "bela", "adc_bits": 8}))


def test_material_table_is_resolved_from_preset_folder(tmp_path):
    (tmp_path / "materials").mkdir()
    (tmp_path / "materials" / "ch4.csv").write_text("wavelength_nm,n,k\n1064,1.3,0\n")
    text = yaml.safe_dump({**RADIATIVE, "materials": {"CH4": {"table": "materials/ch4.csv"}}})
    cfg = load_preset(write(tmp_path, text))
    assert cfg.get("materials.CH4.table") == str(tmp_path / "materials" / "ch4.csv")


# --------------------------------------------------------------------------- sweeps

def test_no_sweep_gives_one_point():
    cfg = load_preset(copy.deepcopy(RADIATIVE))
    assert cfg.sweep_points() == [({}, cfg)]


def test_sweep_outer_product_in_key_order():
    cfg = load_preset(radiative(sweep={
        "medium.thickness": ["1 mm", "10 mm", "100 mm"],
        "medium.radiative.omega": [0.5, 1.0],
    }))
    points = cfg.sweep_points()
    assert [p for p, _ in points] == [
        {"medium.thickness": t, "medium.radiative.omega": w}
        for t in ["1 mm", "10 mm", "100 mm"] for w in [0.5, 1.0]]
    assert [(c.get("medium.thickness"), c.get("medium.radiative.omega")) for _, c in points] == [
        (t, w) for t in [1e-3, 1e-2, 0.1] for w in [0.5, 1.0]]
    for _, point in points:
        assert "sweep" not in point.raw and point.data["sweep"] == {}
        assert point.source == cfg.source
    assert cfg.data["sweep"] == {"medium.thickness": [1e-3, 1e-2, 0.1],
                                 "medium.radiative.omega": [0.5, 1.0]}


def test_sweep_fills_a_missing_required_key(tmp_path):
    text = """\
        medium: {texture: granular, radiative: {tau0: 1, omega: 0.99, n: 1.3}}
        sweep:
          medium.thickness: ["1 mm", "2 mm"]
          simulation.photons: [1e3, 1.0e4]
    """
    cfg = load_preset(write(tmp_path, text))
    assert cfg.get("medium.thickness") == 1e-3
    points = cfg.sweep_points()
    assert len(points) == 4
    assert [c.get("simulation.photons") for _, c in points] == [1000, 10000, 1000, 10000]


def test_sweep_list_item_and_texture(tmp_path):
    cfg = load_preset(write(tmp_path, PHYSICAL_YAML), overrides={
        "sweep": {"medium.inclusions[0].grain_size": ["10 um", "1 mm"],
                  "medium.bottom_interface": ["fresnel", "none"]}})
    points = cfg.sweep_points()
    assert len(points) == 4
    assert points[-1][1].get("medium.inclusions[0].grain_size") == 1e-3
    assert points[-1][1].get("medium.bottom_interface") == "none"


def test_sweep_unindexed_list_item_hint():
    with pytest.raises(ConfigError, match=r"did you mean medium.inclusions\[0\].grain_size\?"):
        load_preset(radiative(sweep={"medium.inclusions.grain_size": ["1 mm"]}))


# --------------------------------------------------------------------------- the table

def test_schema_table_is_consistent():
    kinds = {"length", "time", "angle", "float", "int", "str", "choice", "bool", "section",
             "open_section", "list", "names", "time_bins", "sweep"}
    assert len(FIELDS) == len(SCHEMA)
    for field in SCHEMA:
        assert field.kind in kinds, field.key
        assert field.help.strip().endswith("."), field.key
        if field.kind == "choice":
            assert field.default is None or field.default in field.choices
        if field.default is not None and field.kind in ("length", "time", "angle"):
            assert isinstance(field.default, str)    # written as a user would


@pytest.mark.parametrize("field", [f for f in SCHEMA if f.default not in (None, {})
                                   and "[]" not in f.key and "*" not in f.key],
                         ids=lambda f: f.key)
def test_every_default_is_valid(field):
    """Writing a default explicitly gives the same configuration as leaving it out."""
    implicit = load_preset(copy.deepcopy(RADIATIVE))
    explicit = load_preset(copy.deepcopy(RADIATIVE), overrides={field.key: field.default})
    assert explicit.data == implicit.data


def test_docstring_examples():
    import doctest

    import warpe_cl.config
    import warpe_cl.config.bins
    import warpe_cl.config.instrument_fields
    import warpe_cl.units
    for module in (warpe_cl.units, warpe_cl.config, warpe_cl.config.bins,
                   warpe_cl.config.instrument_fields):
        result = doctest.testmod(module)
        assert result.attempted > 0 and result.failed == 0, module.__name__


def test_schema_markdown():
    text = schema_markdown()
    lines = text.strip().splitlines()
    assert lines[0].startswith("| key |")
    assert len(lines) == len(SCHEMA) + 2
    assert "| `medium.thickness` | length (m) | required | a length > 0" in text
    assert "`1064 nm`" in text
    assert "one of slab, granular" in text


# --------------------------------------------------------------------------- limits (issue 10)

@pytest.mark.parametrize("value", [1e30, 2 ** 53 + 1, "1e30", 1.5, float("nan"), float("inf"),
                                   -float("inf"), -5, 0, "many", True])
def test_absurd_photon_counts_are_refused_in_one_line(value):
    """simulation.photons: 1e30 used to be accepted (and run forever). Every bad count is a
    ConfigError whose one line names the key, the value, the unit and the allowed range."""
    raw = copy.deepcopy(RADIATIVE)
    raw["simulation"] = {"photons": value}
    with pytest.raises(ConfigError) as info:
        load_preset(raw)
    text = str(info.value)
    assert "\n" not in text and text.startswith("<dict>: simulation.photons: ")
    assert "rays" in text and "[1, 2^53 = 9007199254740992]" in text, text


def test_photon_count_limit_is_2_to_the_53():
    from warpe_cl.config import MAX_PHOTONS
    assert MAX_PHOTONS == 2 ** 53 == FIELDS["simulation.photons"].high
    for given in (2 ** 53, float(2 ** 53), "9.007199254740992e15"):
        cfg = load_preset(RADIATIVE, overrides={"simulation.photons": given})
        assert cfg.get("simulation.photons") == 2 ** 53
    # the same limits through --set strings, the Python API and a sweep axis
    for override in (["simulation.photons=1e30"], ["simulation.photons=.nan"],
                     ["simulation.photons=1.5"], ["simulation.photons=-1"]):
        with pytest.raises(ConfigError, match=r"simulation\.photons: .* rays|simulation\.photons: .*finite"):
            load_preset(RADIATIVE, overrides=override)
    with pytest.raises(ConfigError, match="simulation.photons"):
        load_preset({**RADIATIVE, "sweep": {"simulation.photons": [100, 1e30]}})


def test_simulate_refuses_absurd_photon_counts_before_any_device():
    import warpe_cl
    raw = {**copy.deepcopy(RADIATIVE), "simulation": {"photons": 1e30}}
    with pytest.raises(ConfigError, match=r"simulation\.photons: 1e\+30 rays is not allowed"):
        warpe_cl.simulate(raw, device="no-such-device-anywhere")


@pytest.mark.parametrize("key, value", [
    ("simulation.roulette_survival", 1e-4), ("simulation.roulette_survival", 0),
    ("simulation.roulette_survival", -0.1), ("simulation.roulette_survival", 1.5),
    ("simulation.roulette_survival", float("nan")),
    ("simulation.roulette_weight", 1.5), ("simulation.roulette_weight", -1e-3),
    ("simulation.roulette_weight", float("inf")),
    ("simulation.max_flights", 2 ** 31),
])
def test_roulette_and_flight_limits(key, value):
    """roulette_survival had no lower bound: 1e-30 let a surviving weight reach 1e26, beyond
    the 2^42 the exact tallies hold (they drop such weights without a word)."""
    raw = copy.deepcopy(RADIATIVE)
    raw["simulation"] = {"mode": "weighted"}
    with pytest.raises(ConfigError) as info:
        load_preset(raw, overrides={key: value})
    text = str(info.value)
    assert "\n" not in text and f"{key}: " in text and "give " in text, text


def test_roulette_limits_bound_every_weight():
    """The schema's bounds keep the largest weight roulette can make, roulette_weight /
    roulette_survival, at 1e3: its square stays far below the 2^42 of cl/tally.h."""
    weight, survival = FIELDS["simulation.roulette_weight"], FIELDS["simulation.roulette_survival"]
    assert weight.high == 1.0 and not weight.high_open and survival.low == 1e-3
    assert (weight.high / survival.low) ** 2 < 2.0 ** 42
    for w, s in ((0.0, 1e-3), (1.0, 1e-3), (1.0, 1.0)):
        cfg = load_preset(RADIATIVE, overrides={"simulation.mode": "weighted",
                                                "simulation.roulette_weight": w,
                                                "simulation.roulette_survival": s})
        assert cfg.get("simulation.roulette_survival") == s
    assert "1e3" in survival.help and "2^42" in survival.help


def test_docs_config_md_is_up_to_date():
    """docs/config.md is generated (python tools/config_docs.py): a change to the schema
    table without regenerating it fails here."""
    from pathlib import Path

    from warpe_cl.config import REFERENCE_PATH, reference_markdown
    path = Path(__file__).resolve().parent.parent / REFERENCE_PATH
    assert path.read_text(encoding="utf-8") == reference_markdown(), \
        "docs/config.md is out of date: run python tools/config_docs.py"
    assert "2^53" in path.read_text(encoding="utf-8")


def test_a_bundled_preset_loads_by_name_as_on_the_command_line():
    from warpe_cl.catalog import presets_dir
    by_name = load_preset("radiative/slab_co2_1m")
    by_path = load_preset(presets_dir() / "radiative" / "slab_co2_1m.yaml")
    assert by_name.data == by_path.data
    assert load_preset("slab_co2_1m").data == by_path.data        # a unique stem
    with pytest.raises(ConfigError, match="no_such_preset"):
        load_preset("radiative/no_such_preset")


def test_a_builtin_material_at_another_wavelength_names_1064_nm_and_materials(capsys):
    """H2O at 800 nm: the one line says the built-ins exist at 532 and 1064 nm and how to give
    n, k."""
    from warpe_cl.cli import main
    assert main(["show-config", "paper/slab_h2o_thickness", "--set",
                 'wavelength="800 nm"']) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "medium.matrix: material 'H2O': built-in optical constants exist at 532 nm and " \
           "1064 nm only, not at 800 nm" in err, err
    assert "materials: H2O: {n: N, k: K}" in err and "{table: FILE}" in err, err
    # given under materials:, the same preset resolves at 800 nm
    from warpe_cl.radiative import radiative_parameters
    cfg = load_preset("paper/slab_h2o_thickness", overrides=[
        'wavelength="800 nm"', "materials.H2O.n=1.3049", "materials.H2O.k=1.34e-7"])
    for _, pcfg in cfg.sweep_points():
        radiative_parameters(pcfg)
