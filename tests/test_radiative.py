"""Physical -> radiative parameters (docs/physics.md §3-§4): the worked values of §4.6, the paper's
tau, limits and trends, and bad or doubtful physical input."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from warpe_cl import radiative
from warpe_cl.cli import main
from warpe_cl.config import load_preset
from warpe_cl.errors import ConfigError, WarpeWarning


def slab(matrix, inclusion, compacity, grain_um, thickness_m, **extra):
    medium = {"texture": "slab", "thickness": f"{thickness_m} m", "compacity": compacity,
              "matrix": matrix, "inclusions": [{"material": inclusion, "proportion": 1.0,
                                                "grain_size": f"{grain_um} um"}]}
    medium.update(extra)
    return load_preset({"medium": medium})


def granular(material, compacity, grain_um, thickness_m):
    return load_preset({"medium": {"texture": "granular", "thickness": f"{thickness_m} m",
                                   "compacity": compacity,
                                   "inclusions": [{"material": material, "proportion": 1.0,
                                                   "grain_size": f"{grain_um} um"}]}})


# docs/physics.md §4.6: case -> (N, C_gamma, w, E, tau0, omega, n_eff); None where the table has "-"
WORKED = [
    (lambda: slab("H2O", "CO2", 1.0, 100, 1), (0, None, None, 15.023, 15.02, 0, 1.30042)),
    (lambda: slab("CO2", "CO2", 1.0, 100, 1), (0, None, None, 0.0100, 0.0100, 0, 1.4026)),
    (lambda: slab("H2O", "CO2", 0.9, 100, 1),
     (1.910e11, 1.0536, 0.999999, 1595.4, 1595, 0.99058, 1.31064)),
    (lambda: slab("H2O", "S", 0.9, 100, 1),
     (1.910e11, 1.0536, 0.9790, 1595.4, 1595, 0.96978, 1.36238)),
    (lambda: slab("H2O", "void", 0.9, 100, 1),
     (1.910e11, 1.0536, 1, 1595.4, 1595, 0.99058, 1.27038)),
    (lambda: slab("H2O", "CO2", 0.99, 25, 0.001),
     (1.222e12, 1.0050, 1, 618.0, 0.618, 0.97569, 1.30144)),
    (lambda: granular("CO2", 0.9, 200, 0.1),
     (2.149e11, 2.5584, 0.999997, 17269, 1727, 0.999997, 1.36234)),
    (lambda: granular("H2O", 0.9, 100, 1),
     (1.719e12, 2.5584, 0.99789, 34539, 34539, 0.99789, 1.27038)),
    (lambda: granular("H2O", 0.1, 100, 1),
     (1.910e11, 1.0536, 0.99789, 1580, 1580, 0.99789, 1.03004)),
]


def _close(value, expected, digits_of_table):
    """Agreement to 1e-3 relative, or to the table's last printed digit where it shows fewer."""
    tol = max(1e-3 * abs(expected), 0.5 * 10.0 ** digits_of_table)
    return abs(value - expected) <= tol


def _last_digit(x):
    text = f"{x:.6g}"
    if "e" in text:
        mant, exp = text.split("e")
        decimals = len(mant.split(".")[1]) if "." in mant else 0
        return int(exp) - decimals
    return -(len(text.split(".")[1]) if "." in text else 0)


@pytest.mark.parametrize("index", range(len(WORKED)))
def test_worked_values_of_section_4_6(index):
    make, (N, C, w, E, tau0, omega, n_eff) = WORKED[index]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", WarpeWarning)
        r = radiative.radiative_parameters(make())
    sp = r["species"][0]
    checks = [(r["extinction_per_m"], E), (r["tau0"], tau0), (r["omega"], omega),
              (r["n_eff"], n_eff), (sp["number_density_per_m3"] if N else 0.0, N)]
    if C is not None:
        checks += [(r["porosity_factor"], C), (sp["w"], w)]
    for value, expected in checks:
        assert _close(value, expected, _last_digit(expected)), (value, expected)


def test_paper_optical_depths():
    """'tau = 15' for 1 m of water ice and 'tau = 0.01' for CO2 ice (a_m = 4 pi k / lambda)."""
    assert radiative.radiative_parameters(slab("H2O", "CO2", 1.0, 100, 1))["tau0"] == \
        pytest.approx(15.023, abs=1e-3)
    assert radiative.radiative_parameters(slab("CO2", "CO2", 1.0, 100, 1))["tau0"] == \
        pytest.approx(0.010003, abs=1e-6)


def test_limits_and_trends():
    """gamma_c -> 1 gives omega -> 0 (the paper's 'at 0.9999, omega tends to 0'); larger grains
    give a smaller omega and a smaller tau0; C_gamma -> 1 as the particle fraction vanishes."""
    omegas = [radiative.radiative_parameters(slab("H2O", "S", g, 100, 1))["omega"]
              for g in (0.9, 0.99, 0.999, 0.9999)]
    assert all(a > b for a, b in zip(omegas, omegas[1:])) and omegas[-1] < 0.5
    grains = [radiative.radiative_parameters(slab("H2O", "S", 0.9, d, 1)) for d in (25, 100, 400)]
    assert grains[0]["omega"] > grains[1]["omega"] > grains[2]["omega"]
    assert grains[0]["tau0"] > grains[1]["tau0"] > grains[2]["tau0"]
    assert radiative.porosity_factor(1e-9, "granular") == pytest.approx(1.0)
    assert radiative.porosity_factor(1 - 1e-9, "slab") == pytest.approx(1.0)
    assert radiative.porosity_factor(0.9, "granular") == pytest.approx(2.5584, abs=1e-4)


def test_bubble_fresnel_integrals_and_path():
    """Void in H2O (n_rel = 0.769): S_e = 0.4448, S_i = 0.0612 (§3.6 table), <D> = 2d/3."""
    n_rel, k_rel = radiative.relative_index(1.0, 0.0, 1.30042, 1.272e-6)
    assert n_rel == pytest.approx(0.769, abs=1e-3) and k_rel < 0
    p = radiative.particle_albedo(n_rel, k_rel, 0.0, 1e-4)
    assert p["s_e"] == pytest.approx(0.4448, abs=1e-4)
    assert p["s_i"] == pytest.approx(0.0612, abs=1e-4)
    assert p["mean_path_m"] == pytest.approx(2e-4 / 3)
    assert p["w"] == pytest.approx(1.0)


def test_options_of_section_9():
    base = radiative.radiative_parameters(slab("H2O", "S", 0.9, 100, 1))
    q2 = radiative.radiative_parameters(slab("H2O", "S", 0.9, 100, 1, extinction_efficiency=2))
    a_m = base["matrix_absorption_per_m"]
    assert q2["tau0"] - a_m == pytest.approx(2 * (base["tau0"] - a_m), rel=1e-9)
    weighted = radiative.radiative_parameters(
        slab("H2O", "S", 0.9, 100, 1, matrix_absorption="volume_weighted"))
    assert weighted["matrix_absorption_per_m"] == pytest.approx(0.9 * 15.023, rel=1e-4)
    hapke = radiative.radiative_parameters(slab("H2O", "S", 0.9, 100, 1, fresnel_integrals="hapke"))
    assert hapke["omega"] == pytest.approx(base["omega"], rel=4e-3)   # docs/physics.md §3.6
    with pytest.raises(ConfigError, match="n_rel"):
        radiative.radiative_parameters(slab("H2O", "void", 0.9, 100, 1, fresnel_integrals="hapke"))


def test_user_materials_constant_and_table(tmp_path):
    table = tmp_path / "ch4.csv"
    table.write_text("wavelength_nm,n,k\n1000,1.30,1e-5\n1100,1.32,3e-5\n")
    medium = {"texture": "granular", "thickness": "10 mm", "compacity": 0.5,
              "inclusions": [{"material": "ch4", "proportion": 1, "grain_size": "100 um"}]}
    cfg = load_preset({"medium": medium, "materials": {"CH4": {"table": str(table)}}})
    r = radiative.radiative_parameters(cfg)
    n_expected = 1.30 + 0.02 * 0.64
    assert r["n_eff"] == pytest.approx(0.5 * n_expected + 0.5, rel=1e-12)
    cfg = load_preset({"medium": medium, "materials": {"CH4": {"table": str(table)}},
                       "wavelength": "1200 nm"})
    with pytest.raises(ConfigError, match="outside the table's range"):
        radiative.radiative_parameters(cfg)
    cfg = load_preset({"medium": medium, "materials": {"CH4": {"n": 1.31}}})
    assert radiative.radiative_parameters(cfg)["n_eff"] == pytest.approx(0.5 * 1.31 + 0.5)


PHYS = """\
medium:
  texture: {texture}
  thickness: "{thickness}"
  compacity: {compacity}
{matrix}  inclusions:
    - {{material: {material}, proportion: {proportion}, grain_size: "{grain}"}}
{extra}simulation:
  photons: 1000
"""


def _phys(**kw):
    base = dict(texture="slab", thickness="100 mm", compacity=0.9, matrix="  matrix: H2O\n",
                material="CO2", proportion=1.0, grain="100 um", extra="")
    base.update(kw)
    return PHYS.format(**base)


BAD_PHYSICAL = {
    "compacity_above_one": _phys(compacity=1.2),
    "compacity_zero": _phys(compacity=0),
    "granular_compacity_one": _phys(texture="granular", matrix="", compacity=1.0),
    "proportion_zero": _phys(proportion=0),
    "unknown_material": _phys(material="CO3"),
    "unknown_matrix": _phys(matrix="  matrix: H20\n"),
    "negative_k": _phys(material="X", extra="materials:\n  X: {n: 1.5, k: -1e-3}\n"),
    "grain_without_unit": _phys(grain="100"),
    "matrix_on_granular": _phys(texture="granular"),
    "no_builtin_at_other_wavelength": _phys(extra='wavelength: "800 nm"\n'),
}


@pytest.mark.parametrize("case", sorted(BAD_PHYSICAL))
def test_bad_physical_input_exits_2(tmp_path, capsys, case):
    path = tmp_path / f"{case}.yaml"
    path.write_text(BAD_PHYSICAL[case])
    rc = main(["run", str(path), "--out", str(tmp_path / "x.nc"), "--device", "numpy"])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err


@pytest.mark.parametrize("grain,thickness,words", [("50 mm", "100 mm", "tenth of the thickness"),
                                                   ("2 um", "100 mm", "wavelength")])
def test_doubtful_input_warns(tmp_path, capsys, grain, thickness, words):
    path = tmp_path / "doubt.yaml"
    path.write_text(_phys(grain=grain, thickness=thickness))
    with pytest.warns(WarpeWarning, match=words):
        radiative.radiative_parameters(load_preset(path))
    assert main(["show-config", str(path)]) == 0
    assert words in capsys.readouterr().err


def test_several_species_with_their_own_grain_sizes():
    """docs/physics.md A14: per-species N_i and w_i, rho_v-weighted indices, one C_gamma from the
    total inclusion fraction; checked against the formulas written out here."""
    cfg = load_preset({"medium": {
        "texture": "slab", "thickness": "0.5 m", "compacity": 0.8, "matrix": "H2O",
        "inclusions": [{"material": "CO2", "proportion": 3.0, "grain_size": "50 um"},
                       {"material": "S", "proportion": 1.0, "grain_size": "200 um"}]}})
    r = radiative.radiative_parameters(cfg)
    lam, phi = 1.064e-6, 0.2
    c_gamma = np.log(0.8) / (0.8 - 1)
    ext = sca = 0.0
    for (n_i, k_i), rho, d, sp in zip(((1.4026, 8.47e-10), (1.92, 9.5e-6)), (0.75, 0.25),
                                      (50e-6, 200e-6), r["species"]):
        n_rel, k_rel = radiative.relative_index(n_i, k_i, 1.30042, 1.272e-6)
        w = radiative.particle_albedo(n_rel, k_rel, 4 * np.pi * k_i / lam, d)["w"]
        number = phi * rho / (np.pi * d ** 3 / 6)
        assert sp["number_density_per_m3"] == pytest.approx(number, rel=1e-12)
        ext += number * np.pi * d ** 2 / 4
        sca += number * np.pi * d ** 2 / 4 * w
    a_m = 4 * np.pi * 1.272e-6 / lam
    assert r["extinction_per_m"] == pytest.approx(c_gamma * ext + a_m, rel=1e-12)
    assert r["omega"] == pytest.approx(c_gamma * sca / (c_gamma * ext + a_m), rel=1e-12)
    assert r["n_eff"] == pytest.approx(1.30042 * 0.8 + (0.75 * 1.4026 + 0.25 * 1.92) * 0.2)
    assert r["tau0"] == pytest.approx(0.5 * r["extinction_per_m"])


def test_equivalent_slab_absorbs_more_than_a_single_pass():
    """docs/physics.md §4.4, decision A16: for 100 um ice at compacity 0.4, (1 - omega) E =
    16.2 m-1 where a single pass per grain, E alpha <D>, gives 9.6 m-1; the ratio is the
    internal-reflection factor (1 - S_e)/(1 - S_i) to O(alpha <D>) = 1.3e-3."""
    from warpe_cl import load_preset, radiative_parameters
    cfg = load_preset({"medium": {"texture": "granular", "thickness": "1000 mm", "compacity": 0.4,
                                  "inclusions": [{"material": "H2O", "proportion": 1.0,
                                                  "grain_size": "100 um"}]}})
    d = radiative_parameters(cfg)
    sp = d["species"][0]
    alpha = 4 * np.pi * 1.272e-6 / 1064e-9
    hapke = (1 - d["omega"]) * d["extinction_per_m"]
    single = d["extinction_per_m"] * alpha * sp["mean_path_m"]
    assert hapke == pytest.approx(16.19, abs=0.01) and single == pytest.approx(9.59, abs=0.01)
    assert hapke / single == pytest.approx((1 - sp["s_e"]) / (1 - sp["s_i"]), rel=3e-3)
