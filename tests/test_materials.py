"""Built-in optical constants at 532 nm and 1064 nm, the lag materials, user materials at any
wavelength, and the refusal of a built-in at a wavelength that has none (docs/materials.md)."""
from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

import warpe_cl
from warpe_cl import materials
from warpe_cl.cli import main
from warpe_cl.errors import ConfigError

DOCS = Path(__file__).resolve().parent.parent / "docs" / "materials.md"
NEW = ("tholin", "regolith")


def granular(material, wavelength, compacity=0.5, **preset):
    """A granular layer of one material, its radiative parameters at ``wavelength``."""
    spec = {"medium": {"texture": "granular", "thickness": "10 mm", "compacity": compacity,
                       "inclusions": [{"material": material, "proportion": 1,
                                       "grain_size": "100 um"}]},
            "wavelength": wavelength, **preset}
    return warpe_cl.radiative_parameters(warpe_cl.load_preset(spec))


def slab(matrix, wavelength, **preset):
    spec = {"medium": {"texture": "slab", "thickness": "1 m", "compacity": 0.9, "matrix": matrix,
                       "inclusions": [{"material": "void", "proportion": 1,
                                       "grain_size": "100 um"}]},
            "wavelength": wavelength, **preset}
    return warpe_cl.radiative_parameters(warpe_cl.load_preset(spec))


def refusal(call) -> str:
    with pytest.raises(ConfigError) as info:
        call()
    text = str(info.value)
    assert "\n" not in text
    return text


def test_the_paper_constants_at_1064_nm_are_unchanged():
    assert materials.BUILTIN_1064NM == {"void": (1.0, 0.0), "H2O": (1.30042, 1.272e-6),
                                        "CO2": (1.4026, 8.47e-10), "S": (1.92, 9.5e-6)}
    assert materials.BUILTIN_WAVELENGTH == 1064e-9
    at_1064 = materials.builtin_constants(1064e-9)
    for name, nk in materials.BUILTIN_1064NM.items():
        assert at_1064[name] == nk
    r = granular("H2O", "1064 nm")
    assert (r["n_eff"], r["k_eff"]) == (0.5 * 1.30042 + 0.5, 0.5 * 1.272e-6)


def test_builtin_wavelengths_and_tolerance():
    assert materials.builtin_wavelengths() == (532e-9, 1064e-9)
    assert materials.builtin_wavelengths("THOLIN") == (532e-9, 1064e-9)
    assert materials.builtin_wavelengths("CH4") == ()
    assert set(materials.BUILTIN) == {532e-9, 1064e-9}
    assert materials.builtin_constants(532.4e-9) is materials.BUILTIN_532NM   # within 0.1 %
    assert materials.builtin_constants(531.6e-9) is materials.BUILTIN_532NM
    assert materials.builtin_constants(533e-9) is None
    assert materials.builtin_constants(800e-9) is None


@pytest.mark.parametrize("wavelength", ["532 nm", "0.532 um", "532.2 nm"])
@pytest.mark.parametrize("name", ["H2O", "CO2", "S", "tholin", "regolith"])
def test_the_532_nm_constants_are_used_at_532_nm(name, wavelength):
    n, k = materials.BUILTIN_532NM[name]
    r = granular(name, wavelength)
    assert r["n_eff"] == pytest.approx(0.5 * n + 0.5, rel=1e-12)
    assert r["k_eff"] == pytest.approx(0.5 * k, rel=1e-12)


def test_532_nm_differs_from_1064_nm():
    """Water ice absorbs about a thousand times less at 532 nm: omega moves towards 1."""
    r532, r1064 = granular("H2O", "532 nm"), granular("H2O", "1064 nm")
    assert r532["n_eff"] == pytest.approx(0.5 * 1.31164 + 0.5)
    assert 1 - r532["omega"] < 0.01 * (1 - r1064["omega"])
    assert r532["tau0"] == pytest.approx(r1064["tau0"])            # geometric optics: same E


@pytest.mark.parametrize("wavelength", ["532 nm", "1064 nm"])
@pytest.mark.parametrize("name", NEW)
def test_each_lag_material_resolves_at_both_wavelengths(name, wavelength):
    n, k = materials.builtin_constants(float(wavelength.split()[0]) * 1e-9)[name]
    assert 1.5 < n < 1.8 and 1e-4 < k < 0.1
    r = granular(name, wavelength)
    assert r["n_eff"] == pytest.approx(0.5 * n + 0.5, rel=1e-12)
    assert 0 < r["omega"] < 1
    assert slab(name, wavelength)["matrix_absorption_per_m"] == pytest.approx(
        4 * math.pi * k / (float(wavelength.split()[0]) * 1e-9), rel=1e-9)


def test_lag_materials_absorb_more_in_the_visible():
    for name in NEW:
        assert materials.BUILTIN_532NM[name][1] > materials.BUILTIN[1064e-9][name][1]


@pytest.mark.parametrize("spelling", ["h2o", "H2o", "Tholin", "REGOLITH", "Void", "co2", "s"])
@pytest.mark.parametrize("wavelength", ["532 nm", "1064 nm"])
def test_names_are_case_insensitive(spelling, wavelength):
    table = materials.builtin_constants(float(wavelength.split()[0]) * 1e-9)
    n, k = next(v for name, v in table.items() if name.upper() == spelling.upper())
    r = granular(spelling, wavelength)
    assert r["n_eff"] == pytest.approx(0.5 * n + 0.5, rel=1e-12)


@pytest.mark.parametrize("name", ["H2O", "co2", "S", "tholin", "Regolith"])
def test_a_builtin_at_800_nm_is_refused_naming_532_and_1064_nm(name):
    text = refusal(lambda: granular(name, "800 nm"))
    assert text.startswith("<dict>: medium.inclusions[0].material: ")
    assert f"material {name!r}: built-in optical constants exist at 532 nm and 1064 nm only, " \
           "not at 800 nm" in text
    assert f"materials: {name}: {{n: N, k: K}}" in text and "{table: FILE}" in text
    assert "docs/materials.md" in text
    text = refusal(lambda: slab(name, "800 nm"))
    assert "medium.matrix: " in text and "exist at 532 nm and 1064 nm only" in text


def test_just_outside_the_tolerance_is_refused():
    text = refusal(lambda: granular("H2O", "533 nm"))
    assert "exist at 532 nm and 1064 nm only, not at 533 nm" in text


def test_void_and_unknown_names_at_800_nm():
    assert granular("void", "800 nm", compacity=0.5)["n_eff"] == 1.0
    text = refusal(lambda: granular("CH4", "800 nm"))
    assert "unknown material 'CH4'" in text and "known: VOID" in text


def test_user_materials_work_at_800_nm(tmp_path):
    r = granular("H2O", "800 nm", materials={"H2O": {"n": 1.3049, "k": 1.34e-7}})
    assert (r["n_eff"], r["k_eff"]) == pytest.approx((0.5 * 1.3049 + 0.5, 0.5 * 1.34e-7))
    table = tmp_path / "ice.csv"
    table.write_text("# Warren & Brandt 2008\nwavelength_nm, n, k\n780, 1.3053, 1.020e-7\n"
                     "800, 1.3049, 1.340e-7\n820, 1.3046, 1.430e-7\n")
    r = granular("ice", "810 nm", materials={"ICE": {"table": str(table)}})
    assert r["n_eff"] == pytest.approx(0.5 * (1.3049 + 1.3046) / 2 + 0.5, rel=1e-12)
    r = granular("tholin", "800 nm", materials={"Tholin": {"n": 1.67, "k": 3e-3}})
    assert r["n_eff"] == pytest.approx(0.5 * 1.67 + 0.5)


def test_user_materials_override_the_532_nm_builtins():
    r = granular("H2O", "532 nm", materials={"h2o": {"n": 1.31164, "k": 2.0e-9}})
    assert r["k_eff"] == pytest.approx(1.0e-9)
    assert granular("H2O", "532 nm")["k_eff"] == pytest.approx(0.5 * 1.48e-9)


def test_the_cli_takes_the_532_nm_builtins(capsys):
    """The same preset that 800 nm refuses in one line with exit 2
    (tests/test_config.py::test_a_builtin_material_at_another_wavelength_names_1064_nm_and_materials)
    resolves at 532 nm."""
    assert main(["show-config", "paper/slab_h2o_thickness", "--set",
                 'wavelength="532 nm"']) == 0
    capsys.readouterr()


def test_docs_list_every_builtin_with_its_value():
    """docs/materials.md has a row for every built-in at each wavelength, with its n."""
    text = DOCS.read_text(encoding="utf-8")
    sections = re.split(r"^## ", text, flags=re.M)
    by_heading = {s.split("\n", 1)[0]: s for s in sections}
    for heading, table in (("1. Built-ins at 1064 nm", materials.BUILTIN[1064e-9]),
                           ("2. Built-ins at 532 nm", materials.BUILTIN_532NM)):
        body = by_heading[heading]
        for name, (n, _) in table.items():
            row = re.search(rf"^\| `{re.escape(name)}` \| ([0-9.]+) \|", body, flags=re.M)
            assert row, f"{heading}: no row for {name}"
            assert float(row.group(1)) == n, f"{heading}: {name} n {row.group(1)} != {n}"
