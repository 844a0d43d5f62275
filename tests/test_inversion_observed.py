"""The reader of observed waveforms for ``warpe-cl invert`` (docs/interface.md §5.7): instrument
files (one scenario, a sweep, photon counting), the CSV format and its exact round trip, and
one ConfigError line, naming the file and the place, for every input it refuses."""
from __future__ import annotations

import numpy as np
import pytest

from warpe_cl.errors import ConfigError
from warpe_cl.instrument import apply_instrument
from warpe_cl.inversion.observed import Observed, load_observed, write_csv
from warpe_cl.io import write_netcdf

from conftest import synthetic_surface


@pytest.fixture(scope="module")
def bela_file(tmp_path_factory):
    """A one-scenario BELA file of 3 shots, as `warpe-cl instrument` writes it."""
    ds = apply_instrument(synthetic_surface(0.05), "bela", shots=3, seed=9)
    return write_netcdf(ds, tmp_path_factory.mktemp("nc") / "bela.nc"), ds


@pytest.fixture(scope="module")
def sweep_file(tmp_path_factory):
    """A sweep of 3 scenarios through GALA, 2 shots each, swept in medium.thickness."""
    ds = apply_instrument(synthetic_surface(0.05, scenarios=3), "gala", shots=2, seed=4)
    key = {"sweep_key": "medium.thickness"}
    ds = ds.assign_coords({"medium.thickness": ("scenario", [1e-3, 2e-3, 5e-3], key),
                           "medium.thickness_text": ("scenario", ["1 mm", "2 mm", "5 mm"], key)})
    return write_netcdf(ds, tmp_path_factory.mktemp("nc") / "sweep.nc"), ds


def test_instrument_file_gives_its_samples_and_attributes(bela_file):
    path, ds = bela_file
    obs = load_observed(path)
    assert obs.kind == "mv" and obs.instrument == "bela" and obs.source == str(path)
    np.testing.assert_array_equal(obs.time_ns, ds["sample_time"].values)
    np.testing.assert_array_equal(obs.shots, ds["signal_mv"].values)
    assert obs.shots.dtype == np.float64 and obs.shots.shape == (3, ds.sizes["sample_time"])
    assert obs.interval_ns == pytest.approx(12.5)
    assert obs.attrs["instrument_seed"] == 9 and obs.attrs["seed"] == 3
    assert obs.attrs["config"] == ds.attrs["config"]
    assert obs.attrs["instrument_adc_sampling_interval"] == "12.5 ns"
    assert "scenario" not in obs.attrs


def test_photon_counting_file_gives_counts(tmp_path):
    ds = apply_instrument(synthetic_surface(0.05, wavelength="532 nm"), "atlas", shots=2)
    obs = load_observed(write_netcdf(ds, tmp_path / "atlas.nc"))
    assert obs.kind == "counts" and obs.instrument == "atlas"
    np.testing.assert_array_equal(obs.shots, ds["signal_counts"].values.astype(float))
    with pytest.raises(ConfigError, match="not written to CSV"):
        write_csv(tmp_path / "atlas.csv", obs)


def test_sweep_file_needs_and_takes_a_scenario(sweep_file):
    path, ds = sweep_file
    with pytest.raises(ConfigError) as err:
        load_observed(path)
    assert str(path) in str(err.value) and "3 scenarios" in str(err.value) \
        and "--scenario I" in str(err.value)
    obs = load_observed(path, scenario=2)
    np.testing.assert_array_equal(obs.shots, ds["signal_mv"].values[2])
    assert obs.attrs["scenario"] == 2 and obs.instrument == "gala"
    assert obs.attrs["sweep_point"] == {"medium.thickness": "5 mm"}
    assert not np.array_equal(obs.shots, load_observed(path, scenario=np.int64(0)).shots)
    with pytest.raises(ConfigError, match="--scenario 3 is out of range; give an index in 0..2"):
        load_observed(path, scenario=3)


@pytest.mark.parametrize("bad", [-1, True, "1", 1.0])
def test_scenario_must_be_an_integer_index(bad, tmp_path):
    path = tmp_path / "never_read.nc"
    path.write_bytes(b"")
    with pytest.raises(ConfigError, match="integer >= 0") as err:
        load_observed(path, scenario=bad)
    assert str(path) in str(err.value)


def test_one_scenario_file_takes_scenario_zero_only(bela_file):
    path, _ = bela_file
    assert load_observed(path, scenario=0).n_shots == 3
    with pytest.raises(ConfigError, match="--scenario 1"):
        load_observed(path, scenario=1)


def test_csv_round_trip_is_bit_exact(bela_file, tmp_path):
    path, _ = bela_file
    obs = load_observed(path)
    obs.shots = obs.shots + np.array([[0.1], [1 / 3], [-1e-300]])   # digits repr must keep
    back = load_observed(write_csv(tmp_path / "obs.csv", obs))
    assert back.kind == "mv" and back.instrument is None
    assert back.time_ns.tobytes() == obs.time_ns.tobytes()
    assert back.shots.tobytes() == obs.shots.tobytes()
    assert back.attrs == {"format": "csv", "files": [str(tmp_path / "obs.csv")]}
    with pytest.raises(ConfigError, match="cannot be written"):
        write_csv(tmp_path / "obs.csv" / "in_a_file.csv", obs)   # parent is a file
    text = (tmp_path / "obs.csv").read_text()
    assert text.startswith("#") and str(path) in text.splitlines()[1]


def test_one_file_per_shot_equals_one_column_per_shot(tmp_path):
    t = -10.0 + 0.5 * np.arange(6)
    shots = np.arange(18.0).reshape(3, 6) / 7
    write_csv(tmp_path / "all.csv", Observed("mv", t, shots, "test"))
    names = []
    for i, s in enumerate(shots):
        names.append(write_csv(tmp_path / f"shot{i}.csv", Observed("mv", t, s[None], "test")))
    a, b = load_observed(tmp_path / "all.csv"), load_observed(names)
    assert a.time_ns.tobytes() == b.time_ns.tobytes() and a.shots.tobytes() == b.shots.tobytes()
    assert b.source == ", ".join(map(str, names)) and b.n_shots == 3


def test_csv_comments_blank_lines_spaces_and_column_names(tmp_path):
    path = tmp_path / "hand.CSV"
    path.write_text("# a comment\n\n  # indented comment\nmv, time_ns ,mvB\n"
                    "1, 0, 4\n2,1e0,5\n\n3,2,6\n")
    obs = load_observed(str(path))
    np.testing.assert_array_equal(obs.time_ns, [0, 1, 2])
    np.testing.assert_array_equal(obs.shots, [[1, 2, 3], [4, 5, 6]])
    assert obs.interval_ns == 1.0


GOOD = "time_ns,mv_0\n0,1\n1,2\n2,3\n"

#: name -> (file name -> text, what the message must hold besides the file's name)
BAD_CSV = {
    "no time_ns": ({"a.csv": "t,mv\n0,1\n1,1\n2,1\n"}, "column 1 't'"),
    "time_ns missing": ({"a.csv": "mv_0,mv_1\n0,1\n1,1\n2,1\n"}, "no time_ns column"),
    "no shot column": ({"a.csv": "time_ns\n0\n1\n2\n"}, "no shot column"),
    "unknown column": ({"a.csv": "time_ns,mv,volts\n0,1,1\n1,1,1\n2,1,1\n"}, "'volts'"),
    "column twice": ({"a.csv": "time_ns,mv,mv\n0,1,1\n1,1,1\n2,1,1\n"}, "given twice"),
    "text value": ({"a.csv": "time_ns,mv_0\n0,1\n1,abc\n2,3\n"}, "line 3, column mv_0: 'abc'"),
    "empty value": ({"a.csv": "time_ns,mv_0\n0,1\n1,\n2,3\n"}, "line 3, column mv_0: ''"),
    "nan value": ({"a.csv": "#c\ntime_ns,mv_0\n0,1\n1,nan\n2,3\n"}, "line 4, column mv_0: 'nan'"),
    "inf time": ({"a.csv": "time_ns,mv_0\ninf,1\n1,2\n2,3\n"}, "line 2, column time_ns: 'inf'"),
    "short row": ({"a.csv": "time_ns,mv_0,mv_1\n0,1,1\n1,2\n2,3,3\n"}, "line 3: 2 value(s)"),
    "two samples": ({"a.csv": "time_ns,mv_0\n0,1\n1,2\n"}, "2 sample(s)"),
    "header only": ({"a.csv": "time_ns,mv_0\n"}, "0 sample(s)"),
    "decreasing": ({"a.csv": "time_ns,mv\n0,1\n2,1\n1,1\n3,1\n"},
                   "line 4, column time_ns: 1.0 ns does not follow 2.0 ns"),
    "repeated time": ({"a.csv": "time_ns,mv\n0,1\n1,1\n1,1\n"}, "strictly increasing"),
    "not uniform": ({"a.csv": "time_ns,mv\n0,1\n1,1\n2.001,1\n3,1\n"}, "uniformly spaced"),
    "empty file": ({"a.csv": ""}, "is empty"),
    "comments only": ({"a.csv": "# nothing\n\n"}, "is empty"),
    "times differ": ({"a.csv": GOOD, "b.csv": "time_ns,mv\n0,1\n1.5,2\n3,3\n"},
                     "time_ns: sample 1 is at 1.5 ns, in "),
    "lengths differ": ({"a.csv": GOOD, "b.csv": GOOD + "3,4\n"}, "4 samples"),
    "not utf-8": ({"a.csv": b"time_ns,mv\n0,\xff\n"}, "not UTF-8"),
}


def _write(folder, files: dict) -> list:
    paths = []
    for name, text in files.items():
        path = folder / name
        if isinstance(text, bytes):
            path.write_bytes(text)
        else:
            path.write_text(text)
        paths.append(path)
    return paths


@pytest.mark.parametrize("case", list(BAD_CSV))
def test_bad_csv_is_one_config_error_naming_the_file_and_place(case, tmp_path):
    files, expected = BAD_CSV[case]
    paths = _write(tmp_path, files)
    with pytest.raises(ConfigError) as err:
        load_observed(paths)
    message = str(err.value)
    assert "\n" not in message and expected in message
    assert str(paths[-1]) in message


@pytest.mark.parametrize("case", ["extension", "no extension", "missing", "folder", "mixed",
                                  "two nc", "nothing", "not netcdf", "no signal",
                                  "scenario with csv", "surface file",
                                  "nan sample"])
def test_bad_files_are_refused(case, tmp_path, bela_file):
    nc, ds = bela_file
    good = _write(tmp_path, {"g.csv": GOOD})[0]
    given, expected = {
        "extension": (lambda: _write(tmp_path, {"a.txt": GOOD}), "'.txt' is not allowed"),
        "no extension": (lambda: _write(tmp_path, {"a": GOOD}), "'(none)' is not allowed"),
        "missing": (lambda: [tmp_path / "none.csv"], "no such file"),
        "folder": (lambda: [tmp_path / "dir.nc"], "is a folder"),
        "mixed": (lambda: [good, nc], "mixes .nc and .csv"),
        "two nc": (lambda: [nc, nc], "2 NetCDF files"),
        "nothing": (lambda: [], "no observed file given"),
        "not netcdf": (lambda: _write(tmp_path, {"a.nc": GOOD}), "cannot be read as NetCDF"),
        "no signal": (lambda: [write_netcdf(ds.drop_vars("signal_mv"), tmp_path / "s.nc")],
                      "has no signal_mv or signal_counts: give a file written by "
                      "`warpe-cl instrument`"),
        "scenario with csv": (lambda: [good], "--scenario 0 applies to a sweep file"),
        "surface file": (lambda: [write_netcdf(synthetic_surface(0.05), tmp_path / "r.nc")],
                         "has no signal_mv or signal_counts"),
        "nan sample": (lambda: [write_netcdf(ds.assign(signal_mv=ds["signal_mv"].where(
            ds["shot"] != 1)), tmp_path / "nan.nc")],
                       "signal_mv: nan at shot 1, sample 0 is not allowed; give finite"),
    }[case]
    given = given()
    (tmp_path / "dir.nc").mkdir(exist_ok=True)
    with pytest.raises(ConfigError) as err:
        load_observed(given, scenario=0 if case == "scenario with csv" else None)
    message = str(err.value)
    assert "\n" not in message and expected in message
    assert all(str(p) in message for p in given)
