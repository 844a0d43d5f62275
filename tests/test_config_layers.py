"""Layered surfaces in the preset (issue 15): ``medium.layers``, ``medium.substrate``, their
errors, their sweeps, and the parameters they give the walk (docs/walk.md §7). No walk is run:
everything here is the configuration, the radiative parameters and ``walk_params``."""
import copy
import dataclasses

import numpy as np
import pytest
import yaml

import warpe_cl
from warpe_cl.api import scenario_key, walk_params
from warpe_cl.cli import main
from warpe_cl.config import load_grid, load_preset
from warpe_cl.errors import ConfigError
from warpe_cl.params import C_M_PER_NS, MAX_LAYERS, Layer, WalkParams
from warpe_cl.radiative import medium_parameters, radiative_parameters

from conftest import REPO

#: Granular CO2 ice over a compact water-ice slab holding void bubbles, physical form.
CO2_GRAINS = {"texture": "granular", "thickness": "10 cm", "compacity": 0.5,
              "inclusions": [{"material": "CO2", "proportion": 1.0, "grain_size": "1 mm"}]}
H2O_SLAB = {"texture": "slab", "thickness": "1 m", "compacity": 0.9, "matrix": "H2O",
            "inclusions": [{"material": "void", "proportion": 1.0, "grain_size": "1 mm"}]}
PHYSICAL = {"medium": {"phase_g": 0.7, "bottom_albedo": 0.2,
                       "layers": [CO2_GRAINS, H2O_SLAB]}}
#: The same kind of stack in radiative form, the second layer with its own phase_g.
RADIATIVE = {"medium": {"phase_g": 0.8, "layers": [
    {"texture": "granular", "thickness": "20 cm",
     "radiative": {"tau0": 2.0, "omega": 0.99, "n": 1.2}},
    {"texture": "slab", "thickness": "50 cm", "phase_g": 0.3,
     "radiative": {"tau0": 0.5, "omega": 0.9, "n": 1.31, "k": 1e-6}}]}}
#: Today's single layer, radiative form.
SINGLE = {"medium": {"texture": "slab", "thickness": "100 mm",
                     "radiative": {"tau0": 1.0, "omega": 0.9, "n": 1.3}}}


def preset(base, **changes):
    """A deep copy of ``base`` with dotted-key ``changes`` applied (None deletes the key)."""
    raw = copy.deepcopy(base)
    for key, value in changes.items():
        *parents, last = key.split(".")
        node = raw
        for name in parents:
            node = node[int(name)] if isinstance(node, list) else node.setdefault(name, {})
        if value is None:
            node.pop(last, None)
        elif isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value
    return raw


def single_of(layer: dict) -> dict:
    """The single-layer preset of one layer's texture, thickness and composition."""
    return {"medium": {k: copy.deepcopy(v) for k, v in layer.items() if k != "phase_g"}}


# --------------------------------------------------------------------------- stacks

def test_physical_stack_layers_are_computed_as_single_media():
    cfg = load_preset(PHYSICAL)
    med = cfg.data["medium"]
    assert med["texture"] is None and med["thickness"] is None and med["inclusions"] is None
    assert [layer["texture"] for layer in med["layers"]] == ["granular", "slab"]
    assert [layer["phase_g"] for layer in med["layers"]] == [0.7, 0.7]    # medium.phase_g
    assert "substrate" not in med
    params, derived = walk_params(cfg)
    assert params.texture == "layers" and params.layered and params.substrate is None
    assert len(params.layers) == 2 and len(derived["layers"]) == 2
    for layer, spec in zip(params.layers, (CO2_GRAINS, H2O_SLAB)):
        alone = radiative_parameters(load_preset(single_of(spec)))
        assert layer == Layer(spec["texture"], alone["thickness_m"], alone["extinction_per_m"],
                              alone["omega"], 0.7, alone["n_eff"], alone["k_eff"])
    # top-level keys: layer 0's, so that single-layer readers keep working; but the stack's
    # thickness, and its floor's echo as the first back-and-forth time (docs/walk.md §7.2)
    top = derived["layers"][0]
    for key in ("tau0", "omega", "extinction_per_m", "n_eff", "k_eff", "species"):
        assert derived[key] == top[key]
    assert derived["thickness_m"] == params.thickness == pytest.approx(1.1)
    assert derived["first_bf_time_ns"] == derived["echo_times_ns"][-1] == params.first_bf_time
    assert params.albedo == 0.2 and params.bottom_interface == "fresnel"
    legs = [2 * d["thickness_m"] * d["n_eff"] / C_M_PER_NS for d in derived["layers"]]
    assert derived["echo_times_ns"] == pytest.approx(np.cumsum(legs), rel=1e-15)
    assert np.array_equal(params.echo_times, derived["echo_times_ns"])


def test_radiative_stack_and_per_layer_phase_g():
    cfg = load_preset(RADIATIVE)
    assert cfg.get("medium.layers[0].phase_g") == 0.8
    assert cfg.get("medium.layers[1].phase_g") == 0.3
    params, derived = walk_params(cfg)
    assert params.layers == (Layer("granular", 0.2, 2.0 / 0.2, 0.99, 0.8, 1.2, 0.0),
                             Layer("slab", 0.5, 0.5 / 0.5, 0.9, 0.3, 1.31, 1e-6))
    assert (params.extinction, params.omega, params.g, params.n) == (10.0, 0.99, 0.8, 1.2)
    assert derived["layers"][1]["specular_r0"] > 0 and derived["layers"][0]["specular_r0"] == 0
    assert derived["echo_times_ns"][-1] == pytest.approx(
        2 * (0.2 * 1.2 + 0.5 * 1.31) / C_M_PER_NS, rel=1e-14)


def test_a_stack_resolves_and_round_trips():
    cfg = load_preset(PHYSICAL)
    again = load_preset(yaml.safe_load(cfg.to_yaml()))
    assert again.data == cfg.data
    assert scenario_key(None, again) == scenario_key(None, cfg)
    other = load_preset(preset(PHYSICAL, **{"medium.layers.1.phase_g": 0.5}))
    assert scenario_key(None, other) != scenario_key(None, cfg)


# --------------------------------------------------------------------------- substrates

@pytest.mark.parametrize("substrate, index", [
    ({"material": "S"}, (1.92, 9.5e-6)),                          # a built-in
    ({"material": "Regolith"}, (1.7, 1e-3)),                      # defined under materials
    ({"n": 1.6, "k": 2e-4}, (1.6, 2e-4)),
    ({"n": 1.6}, (1.6, 0.0)),
])
def test_substrate_under_a_stack(substrate, index):
    raw = preset(RADIATIVE, **{"medium.substrate": substrate,
                               "materials": {"regolith": {"n": 1.7, "k": 1e-3}}})
    params, derived = walk_params(load_preset(raw))
    assert params.substrate == index
    assert (derived["substrate_n"], derived["substrate_k"]) == index
    assert len(params.layers) == 2


def test_substrate_under_a_single_layer():
    cfg = load_preset(preset(SINGLE, **{"medium.substrate": {"n": 1.6, "k": 1e-4}}))
    plain, plain_derived = walk_params(load_preset(SINGLE))
    params, derived = walk_params(cfg)
    assert params.texture == "layers" and params.substrate == (1.6, 1e-4)
    assert params.layers == (Layer("slab", plain.thickness, plain.extinction, plain.omega,
                                   plain.g, plain.n, plain.k),)
    assert {k: derived[k] for k in plain_derived} == plain_derived
    assert derived["echo_times_ns"] == [plain_derived["first_bf_time_ns"]]


# --------------------------------------------------------------------------- errors

def _many(n):
    return [copy.deepcopy(RADIATIVE["medium"]["layers"][0]) for _ in range(n)]


ERRORS = {
    "empty_list": ({"medium.layers": []}, r"medium\.layers: \[\] is not allowed; give a "
                                          r"non-empty list of layers"),
    "empty_entry": ({"medium.layers": [None] + _many(1)},     # a layer of nothing
                    r"medium\.layers\[0\]: an empty value is not a mapping"),
    "missing_thickness": ({"medium.layers.1.thickness": None},
                          r"medium\.layers\[1\]\.thickness: missing; give a length >= 0"),
    "negative_thickness": ({"medium.layers.0.thickness": "-1 cm"},
                           r"medium\.layers\[0\]\.thickness: -1 cm is not allowed"),
    "missing_texture": ({"medium.layers.0.texture": None},
                        r"medium\.layers\[0\]\.texture: missing; give one of slab, granular"),
    "no_composition": ({"medium.layers.1.radiative": None},
                       r"medium\.layers\[1\]: no composition given; give either "
                       r"medium\.layers\[1\]\.radiative"),
    "both_forms": ({"medium.layers.0.compacity": 0.5},
                   r"medium\.layers\[0\]\.radiative: given together with "
                   r"medium\.layers\[0\]\.compacity; describe the layer either radiatively"),
    "unknown_layer_key": ({"medium.layers.0.thicknes": "1 m"},
                          r"medium\.layers\[0\]\.thicknes: unknown key; did you mean "
                          r"medium\.layers\[0\]\.thickness\?"),
    "medium_key_in_a_layer": ({"medium.layers.1.bottom_albedo": 0.3},
                              r"medium\.layers\[1\]\.bottom_albedo: unknown key here; did you "
                              r"mean medium\.bottom_albedo\?"),
    "too_many": ({"medium.layers": _many(MAX_LAYERS + 1)},
                 rf"medium\.layers: {MAX_LAYERS + 1} layers are given; a stack holds at most "
                 rf"{MAX_LAYERS}"),
    "all_zero": ({"medium.layers.0.thickness": "0 m", "medium.layers.1.thickness": "0 cm"},
                 r"medium\.layers: every layer has thickness 0"),
    "weighted": ({"simulation": {"mode": "weighted"}},
                 r"simulation\.mode: weighted is not allowed with medium\.layers: only the "
                 r"analog walk is layered"),
    "medium_texture": ({"medium.texture": "slab"},
                       r"medium\.texture: given together with medium\.layers; "),
    "medium_thickness": ({"medium.thickness": "1 m"},
                         r"medium\.thickness: given together with medium\.layers; "),
    "medium_radiative": ({"medium.radiative": {"tau0": 1, "omega": 0.5, "n": 1.3}},
                         r"medium\.radiative: given together with medium\.layers; "),
    "medium_inclusions": ({"medium.inclusions": [{"material": "CO2", "proportion": 1,
                                                   "grain_size": "1 mm"}]},
                          r"medium\.inclusions: given together with medium\.layers; "),
    "substrate_both": ({"medium.substrate": {"material": "S", "n": 1.5}},
                       r"medium\.substrate\.n: given together with medium\.substrate\.material"),
    "substrate_empty": ({"medium.substrate": {}},
                        r"medium\.substrate: no index given; give \{material: NAME\}"),
    "substrate_k_alone": ({"medium.substrate": {"k": 0.1}}, r"medium\.substrate\.n: no index"),
    "substrate_contact": ({"medium.substrate": {"n": 1.5}, "medium.bottom_interface": "none"},
                          r"medium\.substrate: given together with medium\.bottom_interface: "
                          r"none"),
    "weighted_substrate": ({"medium.layers": None, "medium.texture": "slab",
                            "medium.thickness": "1 m",
                            "medium.radiative": {"tau0": 1, "omega": 0.5, "n": 1.3},
                            "medium.substrate": {"n": 1.5},
                            "simulation": {"mode": "weighted"}},
                           r"simulation\.mode: weighted is not allowed with medium\.substrate"),
}


@pytest.mark.parametrize("case", sorted(ERRORS))
def test_layer_errors_name_the_index_and_key(case):
    changes, message = ERRORS[case]
    with pytest.raises(ConfigError, match=message) as err:
        load_preset(preset(RADIATIVE, **changes))
    assert "\n" not in str(err.value)


def test_matrix_on_a_granular_layer():
    raw = preset(PHYSICAL, **{"medium.layers.0.matrix": "H2O"})
    with pytest.raises(ConfigError, match=r"medium\.layers\[0\]\.matrix: H2O is not allowed "
                                          r"for a granular layer"):
        load_preset(raw)
    raw = preset(PHYSICAL, **{"medium.layers.1.matrix": None})
    with pytest.raises(ConfigError, match=r"medium\.layers\[1\]\.matrix: missing; give the "
                                          r"slab's matrix material"):
        load_preset(raw)


@pytest.mark.parametrize("key, where", [
    ("medium.layers.1.matrix", r"medium\.layers\[1\]\.matrix"),
    ("medium.layers.0.inclusions.0.material", r"medium\.layers\[0\]\.inclusions\[0\]\.material"),
])
def test_unknown_material_names_the_layer(key, where):
    raw = preset(PHYSICAL)
    node = raw["medium"]["layers"][int(key.split(".")[2])]
    if "inclusions" in key:
        node["inclusions"][0]["material"] = "CO3"
    else:
        node["matrix"] = "CO3"
    cfg = load_preset(raw)     # materials are looked up with the radiative parameters
    with pytest.raises(ConfigError, match=where + r": unknown material 'CO3' \(did you mean "
                                                  r"CO2\?\); known: "):
        walk_params(cfg)


def test_unknown_substrate_material():
    cfg = load_preset(preset(RADIATIVE, **{"medium.substrate": {"material": "regolit"}}))
    with pytest.raises(ConfigError, match=r"medium\.substrate\.material: unknown material "
                                          r"'regolit'"):
        radiative_parameters(cfg)


@pytest.mark.parametrize("changes, key", [
    ({"medium.layers.1.thickness": None}, "medium.layers[1].thickness: missing"),
    ({"simulation": {"mode": "weighted"}}, "simulation.mode: weighted is not allowed"),
    ({"medium.layers.0.compacity": 0.5}, "medium.layers[0].radiative: given together"),
    ({"medium.substrate": {"material": "nope"}}, "medium.substrate.material: unknown material"),
])
def test_cli_exits_2_with_one_line(tmp_path, capsys, changes, key):
    path = tmp_path / "stack.yaml"
    path.write_text(yaml.safe_dump(preset(RADIATIVE, **changes)))
    rc = main(["show-config", str(path)])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and key in err and str(path) in err, err


def test_cli_shows_a_stack(tmp_path, capsys):
    path = tmp_path / "stack.yaml"
    path.write_text(yaml.safe_dump(RADIATIVE))
    assert main(["show-config", str(path)]) == 0
    out = capsys.readouterr().out
    assert "layers:" in out and "tau0              2" in out


# --------------------------------------------------------------------------- zero thickness

def test_a_zero_thickness_layer_is_no_layer():
    middle = {"texture": "slab", "thickness": "0 m",
              "radiative": {"tau0": 3.0, "omega": 0.5, "n": 1.5}}
    layers = RADIATIVE["medium"]["layers"]
    cfg = load_preset(preset(RADIATIVE, **{"medium.layers": [layers[0], middle, layers[1]]}))
    params, derived = walk_params(cfg)
    reference, _ = walk_params(load_preset(RADIATIVE))
    assert params.layers == reference.layers
    assert len(derived["layers"]) == 3 and derived["layers"][1]["thickness_m"] == 0.0
    assert derived["layers"][1]["extinction_per_m"] == 0.0
    echoes = derived["echo_times_ns"]
    assert echoes[1] == echoes[0] and np.array_equal(params.echo_times, [echoes[0], echoes[2]])


def test_a_zero_thickness_top_layer():
    cfg = load_preset(preset(RADIATIVE, **{"medium.layers.0.thickness": "0 cm"}))
    params, derived = walk_params(cfg)
    assert len(params.layers) == 1 and params.layers[0].texture == "slab"
    assert derived["thickness_m"] == 0.5 and derived["n_eff"] == 1.31   # the walk's top layer
    assert params.n == 1.31


# --------------------------------------------------------------------------- sweeps

def test_sweep_over_a_layer_thickness():
    raw = preset(RADIATIVE, sweep={"medium.layers[0].thickness": ["0 cm", "10 cm", "30 cm"]})
    cfg = load_preset(raw)
    points = cfg.sweep_points()
    assert [p for p, _ in points] == [{"medium.layers[0].thickness": v}
                                      for v in ("0 cm", "10 cm", "30 cm")]
    walks = [walk_params(pcfg)[0] for _, pcfg in points]
    assert [len(w.layers) for w in walks] == [1, 2, 2]
    assert [w.layers[0].thickness for w in walks[1:]] == pytest.approx([0.1, 0.3])
    assert [w.thickness for w in walks] == pytest.approx([0.5, 0.6, 0.8])
    keys = {scenario_key(p, pcfg) for p, pcfg in points}
    assert len(keys) == 3
    grid = load_grid(raw)               # warpe-cl sweep: the same points
    assert [c.data for _, c in grid.points] == [c.data for _, c in points]


def test_sweep_over_a_layer_grain_size_and_set():
    raw = preset(PHYSICAL, sweep={"medium.layers[0].inclusions[0].grain_size":
                                  ["0.5 mm", "2 mm"]})
    points = load_preset(raw).sweep_points()
    sizes = [pcfg.get("medium.layers[0].inclusions[0].grain_size") for _, pcfg in points]
    assert sizes == pytest.approx([5e-4, 2e-3])
    omegas = [walk_params(pcfg)[0].layers[0].extinction for _, pcfg in points]
    assert omegas[0] > omegas[1]        # smaller grains: more extinction
    cfg = load_preset(PHYSICAL, overrides=['medium.layers[1].thickness="2 m"',
                                           "medium.layers[1].phase_g=0.1"])
    assert cfg.get("medium.layers[1].thickness") == 2.0
    assert walk_params(cfg)[0].layers[1].g == 0.1


def test_sweep_of_whole_stacks():
    stacks = [RADIATIVE["medium"]["layers"][:1], RADIATIVE["medium"]["layers"]]
    points = load_preset(preset(RADIATIVE, sweep={"medium.layers": stacks})).sweep_points()
    assert [len(walk_params(pcfg)[0].layers) for _, pcfg in points] == [1, 2]


def test_sweep_value_errors_name_the_key():
    raw = preset(RADIATIVE, sweep={"medium.layers[1].thickness": ["1 cm", "-1 cm"]})
    with pytest.raises(ConfigError, match=r"sweep\.medium\.layers\[1\]\.thickness: -1 cm is "
                                          r"not allowed; give a length >= 0"):
        load_preset(raw)
    raw = preset(RADIATIVE, sweep={"medium.layers[0].thicknes": ["1 cm"]})
    with pytest.raises(ConfigError, match=r"did you mean medium\.layers\[0\]\.thickness\?"):
        load_preset(raw)


# --------------------------------------------------------------------------- single layers

#: Scenario keys and walk parameters of bundled single-layer presets, as they were before
#: layers existed (first sweep point): a single layer must resolve exactly as before.
BEFORE = {
    "radiative/slab_co2_1m": (0xc4ced555216e7558, dict(
        texture="slab", thickness=1.0, extinction=0.010003, omega=0.0, g=0.8, n=1.4026,
        k=8.47e-10, albedo=0.15, bottom_interface="fresnel")),
    "paper/slab_h2o_co2_thickness": (0x47e5f71027e55c33, dict(
        texture="slab", thickness=0.001, extinction=1595.4306892108762,
        omega=0.9905829154626804, g=0.8, n=1.310638, k=1.1448847e-06, albedo=0.15,
        bottom_interface="fresnel")),
    "paper/gran_h2o_compacity": (0xb4ed6360b6958b42, dict(
        texture="granular", thickness=1.0, extinction=1580.407734867394,
        omega=0.9978875294004997, g=0.8, n=1.030042, k=1.272e-07, albedo=0.15,
        bottom_interface="fresnel")),
}


@pytest.mark.parametrize("name", sorted(BEFORE))
def test_single_layer_presets_unchanged(name):
    key, expected = BEFORE[name]
    cfg = load_preset(REPO / "presets" / f"{name}.yaml")
    point, pcfg = cfg.sweep_points()[0]
    assert "layers" not in pcfg.data["medium"] and "substrate" not in pcfg.data["medium"]
    assert scenario_key(point, pcfg) == key
    params, derived = walk_params(pcfg, key)
    assert "layers" not in derived and "echo_times_ns" not in derived
    assert derived == medium_parameters(pcfg)
    assert params.layers == () and params.substrate is None
    for field, value in expected.items():
        assert getattr(params, field) == value, field      # bit for bit
    # the parameters today's walk_params built, field by field
    old = WalkParams(texture=pcfg.get("medium.texture"),
                     bottom_interface=pcfg.get("medium.bottom_interface"),
                     thickness=derived["thickness_m"], extinction=derived["extinction_per_m"],
                     omega=derived["omega"], g=pcfg.get("medium.phase_g"), n=derived["n_eff"],
                     k=derived["k_eff"], albedo=pcfg.get("medium.bottom_albedo"),
                     time_edges=params.time_edges, max_time=pcfg.get("simulation.max_time"),
                     max_flights=int(pcfg.get("simulation.max_flights")),
                     fov=(90.0, 90.0, pcfg.get("simulation.fov.bf_diffuse"),
                          pcfg.get("simulation.fov.scattering")),
                     rule=pcfg.get("simulation.component_rule"),
                     seed=int(pcfg.get("simulation.seed")), scenario=key,
                     mode=pcfg.get("simulation.mode"),
                     roulette_weight=float(pcfg.get("simulation.roulette_weight")),
                     roulette_survival=float(pcfg.get("simulation.roulette_survival")))
    # and the nadir estimator's keys (issue 16), which change no ray and no other parameter
    assert dataclasses.replace(params, nadir=False, view_zenith=0.0, nadir_roulette=0.0) == old


def test_single_layer_messages_unchanged():
    with pytest.raises(ConfigError, match=r"medium\.texture: missing; give one of slab, "
                                          r"granular"):
        load_preset(preset(SINGLE, **{"medium.texture": None}))
    with pytest.raises(ConfigError, match=r"medium\.radiative: given together with "
                                          r"medium\.compacity; describe the medium either"):
        load_preset(preset(SINGLE, **{"medium.compacity": 0.5}))
    with pytest.raises(ConfigError, match=r"medium: no composition given; give either "
                                          r"medium\.radiative"):
        load_preset(preset(SINGLE, **{"medium.radiative": None}))


def test_package_entry_point():
    assert warpe_cl.radiative_parameters(load_preset(RADIATIVE))["layers"][1]["phase_g"] == 0.3
