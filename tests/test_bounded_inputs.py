"""Issue 39: bounded, checked inputs. Every input a user can give (a material table, a preset
file, a ``--scenarios`` range, a time grid, a result or an observed waveform read back) is
checked before use, and a bad one is refused with one line (ConfigError, exit 2) instead of
a NaN result, a traceback or a run out of memory."""
from __future__ import annotations

import textwrap

import numpy as np
import pytest

from warpe_cl.cli import main
from warpe_cl.config import load_preset
from warpe_cl.errors import ConfigError

PRESET = textwrap.dedent("""\
    name: t
    wavelength: "1064 nm"
    materials:
      X: {table: t.csv}
    medium:
      texture: granular
      thickness: "10 mm"
      compacity: 0.5
      inclusions:
        - {material: X, proportion: 1.0, grain_size: "100 um"}
    simulation:
      photons: 200
    """)
GOOD_TABLE = "wavelength_nm, n, k\n1000, 1.3, 1e-6\n1100, 1.3, 2e-6\n"


def _table_preset(tmp_path, table: str | bytes):
    path = tmp_path / "t.csv"
    if isinstance(table, bytes):
        path.write_bytes(table)
    else:
        path.write_text(table)
    preset = tmp_path / "p.yaml"
    preset.write_text(PRESET)
    return preset


# --------------------------------------------------------------------------- 1. material tables

@pytest.mark.parametrize("row, column, value", [
    ("1100, 1.3, nan", "k", "nan"),            # ran to exit 0 with k_eff = nan
    ("1100, inf, 1e-6", "n", "inf"),           # ZeroDivisionError
    ("1100, 1.3, -1e-6", "k", "-1e-6"),
    ("1100, 0, 1e-6", "n", "0"),
    ("inf, 1.3, 1e-6", "wavelength_nm", "inf"),
    ("-inf, 1.3, 1e-6", "wavelength_nm", "-inf"),
    ("1000, 1.3, 1e-6", "wavelength_nm", "1000"),   # not increasing
])
def test_table_cells_are_checked(tmp_path, row, column, value):
    preset = _table_preset(tmp_path, f"wavelength_nm, n, k\n1000, 1.3, 1e-6\n{row}\n")
    with pytest.raises(ConfigError) as err:
        load_preset(preset)
    text = str(err.value)
    assert "materials.X.table" in text and "t.csv" in text and "line 3" in text
    assert f"column {column}: {value} is not allowed" in text


#: aluminium, 500 nm - 20 um (Rakic 1995, rounded): n ~ 27 and k ~ 90-150 in the thermal IR
ALUMINIUM = ("wavelength_nm, n, k\n500, 0.77, 6.08\n1000, 1.21, 10.4\n1100, 1.36, 11.2\n"
             "10000, 25.3, 89.8\n20000, 27.1, 150.4\n")


def test_a_table_beyond_the_run_s_wavelength_is_not_bounded(tmp_path):
    """A 500 nm - 20 um aluminium table was refused at 1064 nm for its thermal-infrared cells
    (n > 20, k > 100): only the value the run interpolates is bounded."""
    from warpe_cl.materials import optical_constants
    cfg = load_preset(_table_preset(tmp_path, ALUMINIUM))
    n, k = optical_constants(cfg)["X"]
    assert n == pytest.approx(1.21 + 0.64 * 0.15) and k == pytest.approx(10.4 + 0.64 * 0.8)


@pytest.mark.parametrize("row, symbol", [("1100, 1.3, 1e300", "k"), ("1100, 1e300, 1e-6", "n")])
def test_the_interpolated_value_is_bounded(tmp_path, row, symbol):
    """1e300 gave ZeroDivisionError and NaN albedos: the value used at 1064 nm is refused with
    the bound the walk computes without overflow (1e9)."""
    from warpe_cl.config.tables import MAX_K, MAX_N
    from warpe_cl.materials import optical_constants
    assert MAX_N == MAX_K == 1e9
    cfg = load_preset(_table_preset(tmp_path, f"wavelength_nm, n, k\n1000, 1.3, 1e-6\n{row}\n"))
    with pytest.raises(ConfigError) as err:
        optical_constants(cfg)
    text = str(err.value)
    assert "materials.X.table" in text and f"{symbol} = " in text and "1064 nm" in text
    assert "at most 1e+09" in text and "\n" not in text


def test_config_and_materials_do_not_import_each_other():
    """config/check.py imported ..materials (in a function) while materials imported the
    config at top: no module of warpe_cl/config imports warpe_cl.materials, at any level."""
    import ast
    from pathlib import Path

    import warpe_cl.config
    folder = Path(warpe_cl.config.__file__).parent
    for path in sorted(folder.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                names = [(node.module or "")] + [f"{node.module or ''}.{a.name}"
                                                 for a in node.names]
                assert not any(n.split(".")[-1] == "materials" or ".materials" in n
                               for n in names if node.level), f"{path.name}: {ast.dump(node)}"
            elif isinstance(node, ast.Import):
                assert not any("materials" in a.name for a in node.names), path.name


def test_a_table_is_read_once_and_the_record_is_what_was_used(tmp_path, monkeypatch):
    """The table was read three times per point (the check, the constants, the record), so
    that the recorded SHA-256 came from another read than the n, k walked: one read now."""
    import hashlib

    from warpe_cl.config import tables
    from warpe_cl.materials import optical_constants, table_attrs
    reads = []
    real = tables.read_input_bytes

    def counted(path, what="a preset"):
        reads.append(str(path))
        return real(path, what)
    monkeypatch.setattr(tables, "read_input_bytes", counted)
    monkeypatch.setattr(tables, "_TABLES", {})
    preset = _table_preset(tmp_path, GOOD_TABLE)
    cfg = load_preset(preset)
    n, k = optical_constants(cfg)["X"]
    (tmp_path / "t.csv").write_text(GOOD_TABLE.replace("1100, 1.3", "1100, 1.4"))
    text = table_attrs(cfg)["material_tables"]
    assert len(reads) == 1, reads
    assert hashlib.sha256(GOOD_TABLE.encode()).hexdigest() in text
    assert f"n = {n!r}, k = {k!r}" in text


def test_binary_table_is_refused(tmp_path, capsys):
    preset = _table_preset(tmp_path, bytes(range(256)) * 4)
    assert main(["show-config", str(preset)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not UTF-8 text" in err and "t.csv" in err


def test_table_is_recorded_in_the_output(tmp_path):
    """The output keeps the table's SHA-256 and the n, k used, not only its path."""
    import hashlib

    from warpe_cl.materials import optical_constants, table_attrs
    preset = _table_preset(tmp_path, GOOD_TABLE)
    cfg = load_preset(preset)
    n, k = optical_constants(cfg)["X"]
    assert (n, k) == (1.3, float(np.interp(1064, [1000, 1100], [1e-6, 2e-6])))
    text = table_attrs(cfg)["material_tables"]
    digest = hashlib.sha256(GOOD_TABLE.encode()).hexdigest()
    assert digest in text and f"n = {n!r}, k = {k!r}" in text and "1064 nm" in text
    assert table_attrs(load_preset(preset, ["materials.X={n: 1.3}"])) == {}


def test_table_record_reaches_the_file(tmp_path):
    import xarray as xr
    preset = _table_preset(tmp_path, GOOD_TABLE)
    out = tmp_path / "o.nc"
    assert main(["run", str(preset), "--out", str(out), "--quiet"]) == 0
    with xr.open_dataset(out) as ds:
        assert "sha256" in ds.attrs["material_tables"]


@pytest.mark.parametrize("override", ["materials.X={n: 1e300}", "materials.X={n: 1.3, k: 1e300}",
                                      "medium.substrate={n: 1.5, k: 1e300}"])
def test_constants_are_bounded(tmp_path, override):
    preset = _table_preset(tmp_path, GOOD_TABLE)
    with pytest.raises(ConfigError, match="is not"):
        load_preset(preset, [override])


# --------------------------------------------------------------------------- 3. preset files

def test_preset_must_be_a_regular_file(capsys):
    assert main(["show-config", "/dev/zero"]) == 2          # read until memory ran out
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not a regular file" in err


def test_preset_size_is_capped(tmp_path, capsys):
    from warpe_cl.config.validate import MAX_FILE_BYTES
    big = tmp_path / "big.yaml"
    big.write_text("name: big\n# " + "x" * MAX_FILE_BYTES + "\n")
    assert main(["show-config", str(big)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "too large" in err and "1 MiB" in err


def test_description_is_capped(tmp_path):
    from warpe_cl.config.validate import MAX_TEXT
    preset = _table_preset(tmp_path, GOOD_TABLE)
    load_preset(preset, {"description": "d" * MAX_TEXT})
    with pytest.raises(ConfigError, match=f"description: a text of {MAX_TEXT + 1} characters"):
        load_preset(preset, {"description": "d" * (MAX_TEXT + 1)})


@pytest.mark.parametrize("levels", [40, 1000])
def test_deep_nesting_is_refused(tmp_path, capsys, levels):
    deep = tmp_path / "deep.yaml"
    deep.write_text("name: deep\ndescription: " + "[" * levels + "]" * levels + "\n")
    assert main(["show-config", str(deep)]) == 2              # RecursionError, exit 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "nested" in err and "at most 32 levels" in err


def test_alias_bomb_is_refused(tmp_path):
    lines = ['a0: &a0 ["x", "x", "x", "x", "x", "x", "x", "x", "x", "x"]']
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("\n".join(lines) + "\n")
    with pytest.raises(ConfigError, match="aliases"):
        load_preset(bomb)


def test_deep_override_is_refused(tmp_path):
    preset = _table_preset(tmp_path, GOOD_TABLE)
    with pytest.raises(ConfigError, match="nested"):
        load_preset(preset, ["description=" + "[" * 1000 + "]" * 1000])


def test_instrument_file_is_capped(tmp_path, capsys):
    from warpe_cl.config.instrument_fields import resolve_instrument
    from warpe_cl.config.validate import MAX_FILE_BYTES
    big = tmp_path / "big.yaml"
    big.write_text("name: big\n# " + "x" * MAX_FILE_BYTES + "\n")
    with pytest.raises(ConfigError, match="too large for an instrument preset"):
        resolve_instrument(str(big))
    deep = tmp_path / "inst.yaml"
    deep.write_text("name: i\nlaser: " + "[" * 1000 + "]" * 1000 + "\n")
    with pytest.raises(ConfigError, match="nested"):
        resolve_instrument(str(deep))


# --------------------------------------------------------------------------- 2. --scenarios

_SELECT = """
import numpy as np, xarray as xr
from warpe_cl.plot import select_scenarios
ds = xr.Dataset({"x": ("scenario", np.arange(12.0))}, coords={"scenario": np.arange(12)})
try:
    print(select_scenarios(ds, SELECTION)["scenario"].values.tolist())
except Exception as err:
    print(type(err).__name__, err)
"""


@pytest.mark.parametrize("selection, want", [
    ("0:999999999", list(range(12))),                   # OOM-killed at 24 GB
    ("-99999999999999999999:3, 10:99999999999999999999", [0, 1, 2, 10, 11]),
    ("5, 99999999999999999999, 7:8", [5, 7]),
    ("100:999999999999", "ConfigError --scenarios: '100:999999999999' selects no scenario "
                         "(indices 0..11)"),
])
def test_scenario_ranges_are_not_expanded(selection, want):
    """In a child process whose address space is capped at 2 GiB, so that a selection that
    builds its range in memory fails there instead of taking the host down."""
    import resource
    import subprocess
    import sys

    def cap():
        resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
    code = _SELECT.replace("SELECTION", repr(selection))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, preexec_fn=cap)
    assert done.returncode == 0, done.stderr[-500:]
    assert done.stdout.strip() == str(want)


# --------------------------------------------------------------------------- 4. device buffers

def _sizes(nadir_slices):
    from warpe_cl.buffers import walk_buffer_bytes
    return lambda n: walk_buffer_bytes(n, ["time_in_fov", "time_any"], [], 32, 32 * 80, 4,
                                       nadir_slices)


def test_time_bins_allowed_is_the_largest_that_fits():
    from warpe_cl.buffers import time_bins_allowed
    sizes = _sizes(32)                     # a CPU walk: a nadir slice per work-item
    max_alloc, global_mem = 8 << 30, 21 << 30
    n = time_bins_allowed(sizes, max_alloc, global_mem)
    assert max(sizes(n).values()) <= max_alloc < max(sizes(n + 1).values())
    assert sizes(n)["nadir_sum"] == max(sizes(n).values())
    assert time_bins_allowed(_sizes(0), max_alloc, global_mem) > 10 * n   # nadir: false


def test_buffer_check_names_the_key_and_the_limit():
    from warpe_cl.buffers import check_walk_buffers, time_bins_allowed
    sizes = _sizes(32)
    limit = time_bins_allowed(sizes, 64 << 20, 1 << 30)    # a fake device of 64 MiB buffers
    check_walk_buffers(sizes, limit, 64 << 20, 1 << 30, "fake")
    with pytest.raises(ConfigError) as err:
        check_walk_buffers(sizes, limit + 1, 64 << 20, 1 << 30, "fake")
    text = str(err.value)
    assert text.startswith(f"simulation.time_bins: {limit + 1} time bins is not allowed on fake")
    assert f"give at most {limit} time bins here" in text and "nadir_sum" in text
    with pytest.raises(ConfigError, match="more than the device's 2 MiB"):
        check_walk_buffers(_sizes(0), 100_000, 64 << 20, 2 << 20, "fake")


def test_engine_refuses_buffers_before_the_walk(engine):
    """220,000 bins (under the 1e6 cap) failed with INVALID_BUFFER_SIZE from the nadir sums on
    a CPU; here a grid of the cap's size with a nadir slice per work-item, which no device
    holds, is refused before any buffer is made."""
    import dataclasses

    from conftest import medium
    from warpe_cl.config import MAX_TIME_BINS
    params = dataclasses.replace(medium(), nadir=True,
                                 time_edges=np.linspace(0.0, 1e3, MAX_TIME_BINS + 1))
    with pytest.raises(ConfigError, match=f"simulation.time_bins: {MAX_TIME_BINS} time bins"):
        engine.run(params, 10, global_size=1 << 14, shared_nadir=False, qualified=True)


# --------------------------------------------------------------------------- 5. results read back

def _surface():
    from conftest import synthetic_surface
    return synthetic_surface(0.05)


@pytest.mark.parametrize("edit, name", [
    (lambda ds: ds.assign(time_edges=ds["time_edges"][::-1]), "time_edges"),
    (lambda ds: ds.assign(first_bf_time_ns=np.nan), "first_bf_time_ns"),
    (lambda ds: ds.assign(ray_count=ds["ray_count"] * 0 - 5), "ray_count"),
    (lambda ds: ds.assign(reflectance=ds["reflectance"] * np.nan), "reflectance"),
    (lambda ds: ds.assign(photons=ds["photons"] * 0), "photons"),
])
def test_instrument_checks_the_surface_values(edit, name):
    from warpe_cl.instrument import apply_instrument
    ds = edit(_surface())
    with pytest.raises(ConfigError) as err:
        apply_instrument(ds, "bela", shots=2, seed=1, source="s.nc")
    text = str(err.value)
    assert text.startswith(f"s.nc: {name}: "), text
    assert "is not allowed" in text or "strictly increasing" in text, text


def _database():
    from conftest import synthetic_surface
    ds = synthetic_surface(0.05, scenarios=3)
    key = {"sweep_key": "medium.thickness"}
    return ds.assign_coords({"medium.thickness": ("scenario", [1e-3, 2e-3, 5e-3], key)})


def _observed(instrument="bela", scale=1.0):
    from warpe_cl.instrument import apply_instrument
    from warpe_cl.inversion.observed import Observed
    ds = apply_instrument(_surface(), "bela", shots=2, seed=3)
    return Observed("mv", ds["sample_time"].values, ds["signal_mv"].values * scale, "obs.nc",
                    instrument, {})


def test_instrument_name_from_a_file_must_be_bundled():
    """instrument_name: /etc/shadow made invert open that path and echo its first line."""
    from warpe_cl.inversion.invert import invert
    with pytest.raises(ConfigError) as err:
        invert(_observed("/etc/shadow"), _database())
    text = str(err.value)
    assert "'/etc/shadow' is not a bundled instrument" in text and "--instrument FILE" in text


def test_absurd_samples_are_refused():
    """Samples at 1e30 mV printed confident intervals with chi2/dof nan (-44 dof)."""
    from warpe_cl.inversion.invert import invert
    with pytest.raises(ConfigError, match="at shot 0, sample .* is not allowed"):
        invert(_observed(scale=1e30), _database())


def test_unfit_results_are_refused():
    from warpe_cl.inversion.result import _check_fit
    _check_fit(10.0, -5.0, 3, 2, 1, "obs.nc")
    with pytest.raises(ConfigError, match="chi2 nan"):
        _check_fit(np.nan, -5.0, 3, 2, 1, "obs.nc")
    with pytest.raises(ConfigError, match="-44 degrees of freedom"):
        _check_fit(10.0, -5.0, -44, 2, 1, "obs.nc")


def test_a_bundled_instrument_named_by_the_file_is_the_bundled_file(tmp_path, monkeypatch):
    """instrument_name: bela with a file ./bela in the current folder: the bundled preset is
    read, never the decoy (load_instrument tries a name as a path first)."""
    from warpe_cl.instrument import load_instrument
    from warpe_cl.config.instrument_fields import instruments_dir
    from warpe_cl.inversion.invert import _named_instrument
    obs = _observed("BELA")
    (tmp_path / "bela").write_text("name: decoy\ngarbage: [\n")
    monkeypatch.chdir(tmp_path)
    spec = _named_instrument(obs)
    assert spec == instruments_dir() / "bela.yaml"
    assert load_instrument(spec) == load_instrument(instruments_dir() / "bela.yaml")


def test_a_bundled_name_is_the_bundled_instrument_whatever_the_folder_holds(tmp_path,
                                                                            monkeypatch):
    """`--instrument bela` (and apply_instrument(ds, "bela")) with a file ./bela in the
    current folder read that file; a bundled name is now always the bundled preset, and a
    file of that name is given as ./bela."""
    from warpe_cl.instrument import load_instrument
    from warpe_cl.config.instrument_fields import instruments_dir
    bundled = load_instrument(instruments_dir() / "bela.yaml")
    (tmp_path / "bela").write_text("name: decoy\ngarbage: [\n")
    monkeypatch.chdir(tmp_path)
    assert load_instrument("bela") == bundled
    assert load_instrument("BELA") == bundled
    with pytest.raises(ConfigError, match="bela"):
        load_instrument("./bela")            # the file, explicitly: read, and refused


def _receiver(ceiling=100.0, sigma_n=2.0, baseline=10.0):
    import types
    return types.SimpleNamespace(ceiling=ceiling, sigma_n=sigma_n, baseline=baseline)


@pytest.mark.parametrize("value, ceiling", [(np.nan, 100.0), (np.inf, np.inf),
                                            (-np.inf, np.inf), (np.nan, np.inf)])
def test_non_finite_samples_are_refused(value, ceiling):
    """NaN passed (|nan| > limit is False), and ±inf where the receiver does not clip."""
    from warpe_cl.inversion.invert import _check_samples
    from warpe_cl.inversion.observed import Observed
    shots = np.full((2, 4), 20.0)
    shots[1, 2] = value
    obs = Observed("mv", np.arange(4.0), shots, "obs.nc", "bela", {})
    with pytest.raises(ConfigError) as err:
        _check_samples(obs, _receiver(ceiling=ceiling))
    text = str(err.value)
    assert text.startswith(f"obs.nc: signal_mv: {value:g} mV at shot 1, sample 2 is not "
                           "allowed; give finite samples"), text


def test_samples_are_bounded_by_the_clipped_level_and_the_noise():
    """A receiver records nothing above its clipped level but noise: ceiling + 6 σ_n."""
    from warpe_cl.inversion.invert import SAMPLE_NOISE_SIGMAS, _check_samples
    from warpe_cl.inversion.observed import Observed
    assert SAMPLE_NOISE_SIGMAS == 6.0
    shots = np.full((1, 3), 20.0)
    shots[0, 1] = 100.0 + 5.9 * 2.0                              # within: allowed
    shots[0, 2] = -5.9 * 2.0
    _check_samples(Observed("mv", np.arange(3.0), shots, "obs.nc", None, {}), _receiver())
    for bad in (100.0 + 6.1 * 2.0, -6.1 * 2.0, 3 * 100.0):
        shots[0, 1] = bad
        with pytest.raises(ConfigError, match=r"in \[-12, 112\] mV: the receiver's clipped "
                                              r"level 100 mV plus 6 σ_n \(2 mV\)"):
            _check_samples(Observed("mv", np.arange(3.0), shots, "obs.nc", None, {}),
                           _receiver())


def test_negative_degrees_of_freedom_are_refused_before_the_search(monkeypatch):
    """2 shots of 3 samples: 6 samples, 4 per-shot parameters, 2 nuisances and 1 free key:
    -1 degrees of freedom, known before the search, which must not start."""
    from warpe_cl.inversion import invert as inv
    from warpe_cl.inversion.observed import Observed

    def no_search(*a, **k):
        raise AssertionError("the search ran")
    monkeypatch.setattr(inv, "refine", no_search)
    full = _observed()
    peak = int(np.argmax(full.shots[0]))
    cut = slice(peak - 1, peak + 2)
    obs = Observed("mv", full.time_ns[cut], full.shots[:, cut], "obs.nc", "bela", {})
    with pytest.raises(ConfigError) as err:
        inv.invert(obs, _database())
    text = str(err.value)
    assert "would have -1 degrees of freedom" in text and "2 for each shot" in text, text
    assert "per shot and" not in text
