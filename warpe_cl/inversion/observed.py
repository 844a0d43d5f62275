"""Observed waveforms, the input of ``warpe-cl invert OBSERVED ...`` (docs/interface.md §5.7).

Two kinds of file are read:

- a NetCDF file written by ``warpe-cl instrument`` (or ``run`` with an ``instrument:`` block):
  its ``signal_mv`` (shot, sample_time; mV) or, for a photon-counting instrument,
  its ``signal_counts`` (shot, sample_time; photons per bin), with ``sample_time`` (ns). A sweep
  (a leading ``scenario`` dimension) needs ``--scenario I`` unless it holds one scenario;
- CSV files of recorded samples, in this format::

      # lines whose first character (after blanks) is '#' are comments; blank lines are skipped
      time_ns,mv_0,mv_1,mv_2
      -50,5.01,4.87,5.13
      -37.5,5.22,4.95,5.08
      ...

  The first line that is not a comment is the header. One column is ``time_ns``: the sample
  times in ns, strictly increasing and uniformly spaced (every step within 1e-6, relative, of
  the mean step). Every other column is a shot: its name is ``mv`` or starts with ``mv``
  (``mv``, ``mv_0``, ``mv_1``, ``mv_shot7``), its values are the recorded samples in mV. Values
  are finite numbers separated by commas, at least 3 samples. The shots may also come in
  several files, each with its ``time_ns`` column and its shot columns, all with the same
  ``time_ns`` values exactly; the shots are taken in the order of the files, then of the
  columns. Photon counts are not read from CSV: give the NetCDF file of ``warpe-cl
  instrument`` for a photon-counting instrument.

The times are the nominal sample times; the phase of each shot's sampling is not known
(docs/instrument.md §3.7.5). Anything else is refused with one
:class:`~warpe_cl.errors.ConfigError` line naming the file, the line and column, the value and
what is allowed. :func:`write_csv` writes the format above with every value exact, so that
``load_observed(write_csv(path, observed))`` gives the same bits back.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..io import write_text

__all__ = ["Observed", "load_observed", "write_csv", "UNIFORM_TOLERANCE", "MIN_SAMPLES"]

#: Largest relative departure of a time step from the mean step.
UNIFORM_TOLERANCE = 1e-6
#: Fewest samples a waveform may have.
MIN_SAMPLES = 3
#: The time column of the CSV format, and the prefix of its shot columns.
TIME_COLUMN = "time_ns"
SHOT_PREFIX = "mv"
#: Signal variables of an instrument file, in the order they are looked for -> kind.
SIGNALS = {"signal_mv": "mv", "signal_counts": "counts"}
#: Attributes of an instrument file kept in ``Observed.attrs`` (besides ``instrument_*``).
KEPT_ATTRS = ("seed", "config", "name", "scenario_key")


@dataclass
class Observed:
    """Recorded waveforms: the shots of one instrument, sampled at common nominal times.

    Parameters
    ----------
    kind : str
        ``"mv"`` (linear-mode samples, mV) or ``"counts"`` (photon-counting histogram of each
        shot, photons per bin).
    time_ns : numpy.ndarray
        (samples,) nominal sample times, ns: uniform, increasing. The per-shot sampling phase
        is unknown.
    shots : numpy.ndarray
        (shots, samples) float64: mV, or counts.
    source : str
        The file name(s) given, comma-separated, for messages and provenance.
    instrument : str or None
        The instrument's name when the file says it (attribute ``instrument_name``), else
        None.
    attrs : dict
        What the file says about itself: for an instrument file its ``instrument_*``
        attributes, ``seed``, ``config`` (and ``scenario``, ``sweep_point`` for a scenario of a
        sweep); for CSV ``{"format": "csv", "files": [...]}``.
    """

    kind: str
    time_ns: np.ndarray
    shots: np.ndarray
    source: str
    instrument: str | None = None
    attrs: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.kind not in ("mv", "counts"):
            raise ConfigError(f"kind {self.kind!r} is not allowed; give 'mv' or 'counts'",
                              source=self.source)
        self.time_ns = np.asarray(self.time_ns, dtype=np.float64)
        self.shots = np.atleast_2d(np.asarray(self.shots, dtype=np.float64))
        if self.time_ns.ndim != 1 or self.shots.ndim != 2 \
                or self.shots.shape[1] != self.time_ns.size:
            raise ConfigError(f"shots of shape {self.shots.shape} do not match "
                              f"{self.time_ns.size} sample times; give (shots, samples)",
                              source=self.source)

    @property
    def interval_ns(self) -> float:
        """The sampling interval, ns: (last time − first time) / (samples − 1)."""
        return float((self.time_ns[-1] - self.time_ns[0]) / (self.time_ns.size - 1))

    @property
    def n_shots(self) -> int:
        """The number of shots."""
        return int(self.shots.shape[0])

    @property
    def n_samples(self) -> int:
        """The number of samples per shot."""
        return int(self.time_ns.size)


def load_observed(paths, scenario: int | None = None) -> Observed:
    """Read observed waveforms: one ``warpe-cl instrument`` NetCDF file or CSV files.

    Parameters
    ----------
    paths : str, path or list of them
        One ``.nc`` file, or one or more ``.csv`` files (the format of the module docstring,
        docs/interface.md §5.7).
    scenario : int, optional
        The scenario of a sweep file (its index along ``scenario``). Needed when the file
        holds more than one; 0 or None for a file of one scenario; not allowed with CSV.

    Returns
    -------
    Observed

    Raises
    ------
    ConfigError
        One line naming the file (and line, column, value) for anything that cannot be read
        as observed waveforms: no file, an unknown extension, .nc and .csv mixed, an
        unreadable or empty file, a missing ``time_ns`` or shot column, a value that is not a
        finite number, fewer than 3 samples, times not uniform or not increasing, files whose
        times differ, a NetCDF file without ``signal_mv`` or ``signal_counts``, a sweep
        without ``--scenario``.
    """
    files = _as_paths(paths)
    kinds = {_extension(p) for p in files}
    if kinds == {".nc"}:
        if len(files) > 1:
            raise ConfigError(f"{len(files)} NetCDF files given; give one file written by "
                              "`warpe-cl instrument` (or CSV files, one or more shots each)",
                              source=_names(files))
        return _load_netcdf(files[0], scenario)
    if kinds == {".csv"}:
        if scenario is not None:
            raise ConfigError(f"--scenario {scenario} applies to a sweep file written by "
                              "`warpe-cl instrument`, not to CSV; leave it out",
                              source=_names(files))
        return _load_csv_files(files)
    raise ConfigError("mixes .nc and .csv files; give one .nc file written by `warpe-cl "
                      "instrument`, or .csv files only", source=_names(files))


def write_csv(path, observed: Observed) -> Path:
    """Write linear-mode waveforms as CSV (docs/interface.md §5.7), every value exact.

    Parameters
    ----------
    path : str or path
        Destination, written atomically (``warpe_cl.io.write_text``).
    observed : Observed
        Of kind ``"mv"``; one column ``mv_<i>`` per shot.

    Returns
    -------
    pathlib.Path
        ``path``, so that ``load_observed(write_csv(path, obs))`` reads it back, bit-exact.

    Raises
    ------
    ConfigError
        For photon counts (kind ``"counts"``): they are not written to CSV; for a path that
        cannot be written.
    """

    if observed.kind != "mv":
        raise ConfigError(f"{observed.kind} waveforms are not written to CSV (only mV "
                          "samples are); keep the NetCDF file of `warpe-cl instrument`",
                          source=observed.source)
    header = [TIME_COLUMN] + [f"{SHOT_PREFIX}_{i}" for i in range(observed.n_shots)]
    lines = [f"# observed waveforms (docs/interface.md §5.7): {observed.n_shots} shot(s), "
             f"{observed.n_samples} samples, time in ns, samples in mV",
             f"# from: {' '.join(observed.source.splitlines())}"]
    if observed.instrument:
        lines.append(f"# instrument: {observed.instrument}")
    lines.append(",".join(header))
    for t, row in zip(observed.time_ns, observed.shots.T):
        lines.append(",".join(repr(float(v)) for v in (t, *row)))
    try:
        return write_text(path, "\n".join(lines) + "\n")
    except OSError as err:
        raise ConfigError(f"cannot be written ({err.strerror or type(err).__name__}); give a "
                          "path in a writable folder", source=str(path)) from None


# --- files -------------------------------------------------------------------------------

def _as_paths(paths) -> list:
    """``paths`` as a non-empty list of Paths; ConfigError for none."""
    if isinstance(paths, (str, Path)):
        paths = [paths]
    files = [Path(p) for p in paths]
    if not files:
        raise ConfigError("no observed file given; give a .nc file written by `warpe-cl "
                          "instrument` or one or more .csv files")
    return files


def _names(files: list) -> str:
    """The files as the user gave them, comma-separated."""
    return ", ".join(str(p) for p in files)


def _extension(path: Path) -> str:
    """``.nc`` or ``.csv`` (any case); ConfigError for another extension."""
    suffix = path.suffix.lower()
    if suffix not in (".nc", ".csv"):
        raise ConfigError(f"extension {path.suffix or '(none)'!r} is not allowed; give a .nc "
                          "file written by `warpe-cl instrument` or .csv files of samples "
                          "(docs/interface.md §5.7)", source=str(path))
    return suffix


def _check_readable(path: Path) -> None:
    """ConfigError for a path that is not an existing file."""
    if path.is_dir():
        raise ConfigError("is a folder; give a .nc or .csv file", source=str(path))
    if not path.is_file():
        raise ConfigError("no such file", source=str(path))


# --- NetCDF ------------------------------------------------------------------------------

def _load_netcdf(path: Path, scenario: int | None) -> Observed:
    """One instrument file's recorded signal (one scenario of a sweep).

    Read with h5netcdf, only the variables needed: a tenth of the time xarray takes to open
    a file of this many variables."""
    import h5netcdf

    _check_readable(path)
    if scenario is not None:
        _check_index(scenario, path)
    try:
        with h5netcdf.File(path, "r") as f:
            name, signal, time, attrs = _read_netcdf(f, path)
            if "scenario" in signal.dimensions:
                index = _pick_scenario(signal.shape[signal.dimensions.index("scenario")],
                                       scenario, path)
                attrs["scenario"] = index
                attrs["sweep_point"] = _sweep_point(f, index)
            elif scenario not in (None, 0):
                raise ConfigError(f"holds one scenario; --scenario {scenario} is out of range "
                                  "(give 0 or leave it out)", source=str(path))
            values, dims = np.asarray(signal[...]), list(signal.dimensions)
    except ConfigError:
        raise
    except Exception as err:  # noqa: BLE001  (any reader failure is bad input)
        raise ConfigError(f"cannot be read as NetCDF ({type(err).__name__}); give a file "
                          "written by `warpe-cl instrument`", source=str(path)) from None
    if "scenario" in dims:
        values = np.take(values, attrs["scenario"], axis=dims.index("scenario"))
        dims.remove("scenario")
    shots = np.transpose(values, [dims.index("shot"), dims.index("sample_time")])
    shots = shots.astype(np.float64)
    _check_signal(name, shots, time, path)
    instrument = attrs.get("instrument_name")
    return Observed(SIGNALS[name], time, shots, str(path),
                    str(instrument) if instrument not in (None, "") else None, attrs)


def _read_netcdf(f, path: Path) -> tuple:
    """(name, signal variable, sample times, kept attributes) of an open instrument file."""
    name = next((n for n in SIGNALS if n in f.variables), None)
    if name is None or "sample_time" not in f.variables:
        raise ConfigError("has no signal_mv or signal_counts: give a file written by "
                          "`warpe-cl instrument`", source=str(path))
    signal = f.variables[name]
    if set(signal.dimensions) - {"scenario"} != {"shot", "sample_time"}:
        raise ConfigError(f"{name} has dimensions {signal.dimensions}; give a file written "
                          "by `warpe-cl instrument` (shot, sample_time)", source=str(path))
    time = np.asarray(f.variables["sample_time"][...], dtype=np.float64)
    return name, signal, time, _netcdf_attrs(f.attrs, path)


def _check_signal(name: str, shots: np.ndarray, time: np.ndarray, path: Path) -> None:
    """ConfigError for no shot, bad sample times or a sample that is not finite."""
    _check_times(time, str(path), "sample_time")
    if shots.shape[0] == 0:
        raise ConfigError(f"{name} holds no shot; give a file with at least one",
                          source=str(path))
    bad = np.argwhere(~np.isfinite(shots))
    if bad.size:
        s, k = bad[0]
        raise ConfigError(f"{_num(shots[s, k])} at shot {s}, sample {k} is not allowed; give "
                          "finite samples", key=name, source=str(path))


def _check_index(scenario, path: Path) -> None:
    """ConfigError for a scenario index that is not a non-negative integer."""
    if isinstance(scenario, bool) or not isinstance(scenario, (int, np.integer)) \
            or int(scenario) < 0:
        shown = repr(scenario) if isinstance(scenario, str) else scenario
        raise ConfigError(f"--scenario {shown} is not allowed; give the index of a scenario "
                          "of the sweep, an integer >= 0", source=str(path))


def _pick_scenario(count: int, scenario, path: Path) -> int:
    """The index of the scenario to read from a sweep of ``count`` scenarios."""
    if scenario is None:
        if count == 1:
            return 0
        raise ConfigError(f"holds {count} scenarios (a sweep); pick one with --scenario I, "
                          f"I in 0..{count - 1}", source=str(path))
    if int(scenario) >= count:
        raise ConfigError(f"--scenario {scenario} is out of range; give an index in "
                          f"0..{count - 1} (the file holds {count} scenarios)",
                          source=str(path))
    return int(scenario)


def _plain(value):
    """An attribute value as a Python object (numpy scalars and arrays converted, bytes
    decoded)."""
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    return value


def _netcdf_attrs(file_attrs, path: Path) -> dict:
    """The attributes kept in ``Observed.attrs``: ``instrument_*``, seed, config, name."""
    attrs = {"format": "netcdf", "files": [str(path)]}
    for key, value in file_attrs.items():
        if key.startswith("instrument_") or key in KEPT_ATTRS:
            attrs[key] = _plain(value)
    return attrs


def _sweep_point(f, index: int) -> dict:
    """Swept key -> its value in scenario ``index`` of an open file, as written (``"50 um"``)
    when the file keeps the text (docs/interface.md §5.3)."""
    point = {}
    for name, var in f.variables.items():
        key = var.attrs.get("sweep_key")
        if key is None or var.dimensions != ("scenario",) or name.endswith("_text"):
            continue
        text = f.variables.get(f"{name}_text")
        point[_plain(key)] = _plain((text if text is not None else var)[index])
    return point


# --- CSV ---------------------------------------------------------------------------------

def _load_csv_files(files: list) -> Observed:
    """The shots of one or more CSV files sharing their ``time_ns``."""
    time, shots = None, []
    for path in files:
        t, s = _read_csv(path)
        if time is not None and not np.array_equal(t, time):
            raise ConfigError(_differ(t, time, files[0]), key=TIME_COLUMN, source=str(path))
        time = t if time is None else time
        shots.append(s)
    return Observed("mv", time, np.concatenate(shots, axis=0), _names(files), None,
                    {"format": "csv", "files": [str(p) for p in files]})


def _differ(t: np.ndarray, first: np.ndarray, first_file: Path) -> str:
    """Why times ``t`` are not those of the first file."""
    if t.size != first.size:
        return (f"{t.size} samples, {first_file} has {first.size}; give every file the same "
                "time_ns values")
    k = int(np.flatnonzero(t != first)[0])
    return (f"sample {k} is at {_num(t[k])} ns, in {first_file} at {_num(first[k])} ns; give every "
            "file the same time_ns values exactly")


def _read_csv(path: Path) -> tuple:
    """(time_ns, shots (shots, samples)) of one CSV file, checked."""
    _check_readable(path)
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            lines = f.read().splitlines()
    except UnicodeDecodeError:
        raise ConfigError("is not UTF-8 text; give a CSV text file of samples",
                          source=str(path)) from None
    except OSError as err:
        raise ConfigError(f"cannot be read ({err.strerror or type(err).__name__})",
                          source=str(path)) from None
    rows = [(n, line) for n, line in enumerate(lines, 1)
            if line.strip() and not line.lstrip().startswith("#")]
    if not rows:
        raise ConfigError("is empty (no header, no samples); give a header time_ns,mv_0,... "
                          "and one line per sample", source=str(path))
    header_line, header = rows[0][0], _fields(rows[0][1])
    time_col, shot_cols = _columns(header, path, header_line)
    values = np.empty((len(rows) - 1, len(header)))
    for i, (n, line) in enumerate(rows[1:]):
        values[i] = _row(_fields(line), header, path, n)
    if values.shape[0] < MIN_SAMPLES:
        raise ConfigError(f"{values.shape[0]} sample(s); give at least {MIN_SAMPLES} lines of "
                          "samples after the header", source=str(path))
    time = values[:, time_col].copy()
    _check_times(time, str(path), TIME_COLUMN, [n for n, _ in rows[1:]])
    return time, np.ascontiguousarray(values[:, shot_cols].T)


def _fields(line: str) -> list:
    """The comma-separated fields of one line, blanks around them removed."""
    return [f.strip() for f in next(csv.reader([line]))]


def _columns(header: list, path: Path, line: int) -> tuple:
    """(index of time_ns, indices of the shot columns) of a header; ConfigError else."""
    where = f"line {line} (header)"
    seen = set()
    for k, name in enumerate(header, 1):
        if name in seen:
            raise ConfigError(f"column {k} {name!r} is given twice; give each column once",
                              key=where, source=str(path))
        seen.add(name)
        if name != TIME_COLUMN and not name.startswith(SHOT_PREFIX):
            raise ConfigError(f"column {k} {name!r} is not allowed; give time_ns and shot "
                              "columns named mv or starting with mv (mv_0, mv_1, ...), in mV",
                              key=where, source=str(path))
    if TIME_COLUMN not in header:
        raise ConfigError(f"no time_ns column (header {','.join(header)!r}); give a column "
                          "time_ns of sample times in ns", key=where, source=str(path))
    shots = [k for k, name in enumerate(header) if name.startswith(SHOT_PREFIX)]
    if not shots:
        raise ConfigError(f"no shot column (header {','.join(header)!r}); give one or more "
                          "columns named mv or starting with mv (mv_0, mv_1, ...), in mV "
                          "(photon counts are not read from CSV)", key=where, source=str(path))
    return header.index(TIME_COLUMN), shots


def _row(fields: list, header: list, path: Path, line: int) -> list:
    """The numbers of one line of samples; ConfigError naming the line and column else."""
    if len(fields) != len(header):
        raise ConfigError(f"{len(fields)} value(s), the header has {len(header)} columns; give "
                          "one value per column", key=f"line {line}", source=str(path))
    out = []
    for name, text in zip(header, fields):
        unit = "ns" if name == TIME_COLUMN else "mV"
        try:
            value = float(text)
        except ValueError:
            value = None
        if value is None or not np.isfinite(value):
            raise ConfigError(f"{text!r} is not allowed; give a finite number ({unit})",
                              key=f"line {line}, column {name}", source=str(path))
        out.append(value)
    return out


# --- checks shared by both formats -------------------------------------------------------

def _num(value) -> str:
    """A number as Python writes it, exactly (``2.5``, not ``np.float64(2.5)``)."""
    return repr(float(value))


def _check_times(time: np.ndarray, source: str, column: str, lines: list | None = None) -> None:
    """ConfigError unless ``time`` has at least 3 strictly increasing, uniform values.

    ``lines`` (CSV) gives each sample's line number, for the message; else the sample index
    is named."""
    def where(k: int) -> str:
        return f"line {lines[k]}, column {column}" if lines else f"{column}[{k}]"

    if time.size < MIN_SAMPLES:
        raise ConfigError(f"{time.size} sample(s); give at least {MIN_SAMPLES}", key=column,
                          source=source)
    bad = np.flatnonzero(~np.isfinite(time))
    if bad.size:
        raise ConfigError(f"{_num(time[bad[0]])} is not allowed; give finite times (ns)",
                          key=where(int(bad[0])), source=source)
    steps = np.diff(time)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0])
        raise ConfigError(f"{_num(time[k + 1])} ns does not follow {_num(time[k])} ns; give "
                          "strictly increasing times", key=where(k + 1), source=source)
    mean = (time[-1] - time[0]) / (time.size - 1)
    off = np.abs(steps - mean) / mean
    if np.any(off > UNIFORM_TOLERANCE):
        k = int(np.argmax(off))
        raise ConfigError(f"{_num(time[k + 1])} ns is {_num(steps[k])} ns after "
                          f"{_num(time[k])} ns, the mean step is {_num(mean)} ns; give uniformly "
                          f"spaced times (every step within {UNIFORM_TOLERANCE:g} of the mean, "
                          "relative)",
                          key=where(k + 1), source=source)
