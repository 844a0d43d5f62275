#!/usr/bin/env python3
"""The injection-recovery study of issue 14, simulation side: the databases that
``warpe-cl invert`` searches and the injected waveforms it is asked to recover.

    python tools/studies/inversion_study.py build FAMILY --work DIR [--photons N]
    python tools/studies/inversion_study.py inject FAMILY --work DIR [--count 50] [--seed 7]
                                           [--photons N] [--per-decade N]
                                           [--instruments bela,gala]
                                           [--instrument NAME|FILE.yaml ...]

``FAMILY`` names a preset of ``presets/study/`` (``gran_co2``, ``slab_h2o_co2``, ``gran_h2o``),
a scenario preset with a ``sweep:`` block; ``--preset FILE`` takes another file instead.
Everything lands in ``DIR/FAMILY/``:

- ``db/``: the sweep database (``warpe-cl sweep ... --out DIR/FAMILY/db``, docs/cluster.md),
  resumed when the folder exists;
- ``inj/iNNN/``: injection NNN: ``preset.yaml`` (the family's preset without its sweep block,
  the drawn values set), ``surface.nc`` (``warpe-cl run``), one ``INSTRUMENT.nc`` per
  instrument (``warpe-cl instrument``) and ``log.txt`` (the commands and what they printed);
- ``injections.csv``: one row per injection (columns in :func:`csv_columns`);
- ``instruments/LABEL.yaml``: a copy of every instrument given as a file, which the
  injections are simulated with and ``tools/studies/inversion_recovery.py`` inverts with.

The instruments are bundled names (``bela``, ``gala``, ``atlas``), files of
``presets/study/instruments/`` by name (``bela_5ns``), or any instrument YAML file
(``--instrument path/to/mla.yaml``, repeatable; ``--instruments`` takes a comma-separated
list of either). Each is checked (:func:`resolve_instruments`) before anything runs; a file's
label, its file and column stem, is its name without ``.yaml``.

The injected points are drawn uniformly inside the grid's range of every swept key, in the
coordinate the key's nodes are evenly spaced in (:func:`detect_spacing`: linear, log, or log of
1 - x, as for slab compacities 0.9 ... 0.999), and never at a grid node: a draw within 2 % of
the range (in that coordinate) of a node in every dimension is drawn again
(:func:`draw_points`). Points are drawn one at a time from ``Generator(PCG64(seed))``, so the
first k points of ``--count 50`` are those of ``--count k``. Injection i runs the surface with
seed 1000 + i and the j-th instrument (0-based, in the order of ``--instruments``) with seed
2000 + 1000 j + i (bela 2000 + i, gala 3000 + i for ``bela,gala``), so no two instruments
share noise. ``--photons`` defaults to the database's own count (its manifest), so
injections and database agree; without a database, to the preset's. ``--per-decade`` sets the
injected surfaces' log time bins per decade (default the preset's): a truth in finer bins than
the database's places a return sharper than a bin (a slab floor's) where it arrives, as a real
surface does (docs/inversion.md §4.3).

Both verbs are resumable: ``build`` passes ``--resume`` to an existing database, ``inject``
skips every file that exists and refuses an ``injections.csv`` that disagrees with the draw
(another seed, photon count, time bins or preset). Every warpe-cl call is a child process of this
Python (``sys.executable -m warpe_cl``), so the tool works in any virtual environment.
Exit codes: 0 all done, 1 a warpe-cl call failed (named on stderr, the others go on), 2 bad
input.
"""
from __future__ import annotations

import argparse
import copy
import csv
import json
import math
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

#: The repository's presets of the study (the repository is three folders up).
STUDY_PRESETS = Path(__file__).resolve().parents[2] / "presets" / "study"
#: A draw this close to a node in every dimension, as a fraction of each range, is redrawn.
NODE_TOLERANCE = 0.02
#: Seeds: surface of injection i = SURFACE_SEED + i; instrument j: INSTRUMENT_SEED + 1000 j + i.
SURFACE_SEED = 1000
INSTRUMENT_SEED = 2000
#: Significant digits of an injected value as written in its preset.
DIGITS = {"quantity": 6, "float": 8}
#: The coordinates a swept key may be drawn uniformly in: name -> (forward, inverse).
TRANSFORMS = {
    "linear": (lambda x: np.asarray(x, float), lambda u: np.asarray(u, float)),
    "log": (lambda x: np.log10(x), lambda u: 10.0 ** np.asarray(u, float)),
    "log1m": (lambda x: -np.log10(1.0 - np.asarray(x, float)),
              lambda u: 1.0 - 10.0 ** (-np.asarray(u, float))),
}


class StudyError(Exception):
    """Bad input for the study (exit 2): a missing preset, a sweep that cannot be drawn in,
    an ``injections.csv`` of another draw."""


# --------------------------------------------------------------------------- the grid


@dataclass
class Axis:
    """One swept key of a preset.

    Attributes
    ----------
    key : str
        The dotted key, as written in the sweep block (``medium.inclusions[0].grain_size``).
    texts : list
        The nodes as written (``"25 um"``, or numbers).
    values : numpy.ndarray
        The nodes in SI units (m for lengths), sorted increasing.
    dimension : str or None
        The dimension of a quantity (``"length"``), None for a plain number.
    unit : str
        The unit injected values are written in (the first node's), ``""`` for a number.
    """

    key: str
    texts: list
    values: np.ndarray
    dimension: str | None
    unit: str


def key_dimension(key: str) -> str | None:
    """The dimension of a dotted preset key (``"length"``), or None when it is a number.

    Parameters
    ----------
    key : str
        A dotted key such as ``medium.thickness`` or ``medium.inclusions[0].grain_size``.

    Raises
    ------
    StudyError
        For a key that is neither a quantity nor a number (a choice, a list, a block): it
        cannot be drawn from.
    """
    from warpe_cl.config.keys import schema_key, split_key
    from warpe_cl.config.schema import FIELDS
    from warpe_cl.units import UNITS
    field = FIELDS.get(schema_key(split_key(key)))
    if field is None:
        raise StudyError(f"sweep key {key} is not a key of the preset schema")
    if field.kind in UNITS:
        return field.kind
    if field.kind in ("float", "int"):
        return None
    raise StudyError(f"sweep key {key} is a {field.kind}, not a number: it cannot be drawn from")


def node_value(text, dimension: str | None) -> float:
    """A node as written (``"25 um"`` or ``0.3``) in SI units."""
    from warpe_cl.units import parse_quantity
    return parse_quantity(text, dimension) if dimension else float(text)


def sweep_axes(raw: dict) -> list:
    """The :class:`Axis` of every swept key of the preset ``raw``, in the order written.

    Raises
    ------
    StudyError
        Without a sweep block, or for a key with fewer than two distinct nodes.
    """
    from warpe_cl.units import split_quantity
    sweep = raw.get("sweep") or {}
    if not sweep:
        raise StudyError("the preset has no sweep block: there is no grid to draw in")
    axes = []
    for key, texts in sweep.items():
        dimension = key_dimension(key)
        values = np.array(sorted(node_value(t, dimension) for t in texts))
        if len(np.unique(values)) < 2:
            raise StudyError(f"sweep key {key} needs two distinct values to draw between")
        unit = split_quantity(str(texts[0]))[1] if dimension else ""
        axes.append(Axis(key, list(texts), values, dimension, unit))
    return axes


def detect_spacing(nodes) -> str:
    """The coordinate in which grid nodes are most evenly spaced.

    Candidates are ``"linear"`` (x), ``"log"`` (log x, all nodes > 0) and ``"log1m"``
    (-log(1 - x), all nodes < 1: compacities 0.9, 0.99, 0.999); the one whose successive
    spacings have the smallest coefficient of variation wins, ties going to that order.
    Two nodes say nothing about spacing: log when both are positive and a factor 10 or more
    apart, linear otherwise.

    Parameters
    ----------
    nodes : array_like
        The node values (any order, at least two distinct).

    Returns
    -------
    str
        A key of :data:`TRANSFORMS`.

    Examples
    --------
    >>> detect_spacing([0.1, 0.3, 0.5, 0.7, 0.9]), detect_spacing([25e-6, 50e-6, 100e-6])
    ('linear', 'log')
    >>> detect_spacing([0.9, 0.95, 0.99, 0.995, 0.999])
    'log1m'
    """
    x = np.unique(np.asarray(nodes, float))
    if len(x) < 2:
        raise ValueError("a spacing needs two distinct nodes")
    if len(x) == 2:
        return "log" if x[0] > 0 and x[1] / x[0] >= 10 else "linear"
    best, best_cv = "linear", math.inf
    for name, (forward, _) in TRANSFORMS.items():
        if (name == "log" and x[0] <= 0) or (name == "log1m" and x[-1] >= 1):
            continue
        steps = np.diff(forward(x))
        cv = float(np.std(steps) / np.mean(steps))
        if cv < best_cv - 1e-9:
            best, best_cv = name, cv
    return best


def at_node(u, nodes_u: list, spans, tolerance: float = NODE_TOLERANCE) -> bool:
    """Whether the point ``u`` lies within ``tolerance`` × span of a node in every dimension.

    Parameters
    ----------
    u : array_like
        The point, one coordinate per dimension (already transformed).
    nodes_u : list of numpy.ndarray
        The nodes of each dimension in the same coordinates.
    spans : array_like
        The range (last node - first node) of each dimension in those coordinates.
    tolerance : float
        Fraction of the span.
    """
    return all(np.min(np.abs(n - ui)) < tolerance * s for ui, n, s in zip(u, nodes_u, spans))


def draw_points(nodes: list, spacings: list, count: int, seed: int,
                tolerance: float = NODE_TOLERANCE) -> np.ndarray:
    """Points drawn uniformly inside a grid's range, off its nodes.

    Each coordinate is uniform between the first and last node in the coordinate its spacing
    names (log for a log-spaced key); a point within ``tolerance`` of the span of a node in
    every dimension (:func:`at_node`) is drawn again. Points are drawn one after another from
    ``numpy.random.Generator(PCG64(seed))``, so a smaller ``count`` gives the first points of
    a larger one.

    Parameters
    ----------
    nodes : list of array_like
        The node values of each dimension.
    spacings : list of str
        Each dimension's key of :data:`TRANSFORMS`.
    count : int
        Points to draw.
    seed : int
        Seed of the PCG64 generator.
    tolerance : float
        Fraction of each span that counts as "at a node".

    Returns
    -------
    numpy.ndarray
        Shape (count, dimensions), in the nodes' units.
    """
    rng = np.random.Generator(np.random.PCG64(seed))
    forward = [TRANSFORMS[s][0] for s in spacings]
    inverse = [TRANSFORMS[s][1] for s in spacings]
    nodes_u = [np.sort(f(np.asarray(n, float))) for f, n in zip(forward, nodes)]
    low = np.array([n[0] for n in nodes_u])
    high = np.array([n[-1] for n in nodes_u])
    points = np.empty((count, len(nodes)))
    for i in range(count):
        u = rng.uniform(low, high)
        while at_node(u, nodes_u, high - low, tolerance):
            u = rng.uniform(low, high)
        points[i] = [float(inv(ui)) for inv, ui in zip(inverse, u)]
    return points


def value_text(value: float, axis: Axis):
    """An injected value as a preset writes it: ``"137.214 um"`` in the axis's unit, or a
    number rounded to :data:`DIGITS` significant digits."""
    if axis.dimension is None:
        return float(f"{value:.{DIGITS['float']}g}")
    scale = node_value(f"1 {axis.unit}", axis.dimension)
    return f"{value / scale:.{DIGITS['quantity']}g} {axis.unit}"


# --------------------------------------------------------------------------- the plan


def read_preset(path: Path) -> dict:
    """The preset file ``path`` as a dict (StudyError when it is missing or not a mapping)."""
    if not path.is_file():
        raise StudyError(f"{path}: no such preset")
    raw = yaml.safe_load(path.read_text())
    if not isinstance(raw, dict):
        raise StudyError(f"{path}: not a preset (a YAML mapping)")
    return raw


def preset_path(family: str, preset: str | None) -> Path:
    """``--preset`` when given, else ``presets/study/FAMILY.yaml`` of this repository."""
    return Path(preset) if preset else STUDY_PRESETS / f"{family}.yaml"


def parse_spacings(items: list) -> dict:
    """``["KEY=KIND", ...]`` (``--spacing``) as a dict, each KIND a key of TRANSFORMS."""
    out = {}
    for item in items or []:
        key, _, kind = item.partition("=")
        if kind not in TRANSFORMS:
            raise StudyError(f"--spacing {item}: give KEY=KIND with KIND one of "
                             f"{', '.join(TRANSFORMS)}")
        out[key.strip()] = kind
    return out


def instrument_label(instrument: str) -> str:
    """File and column stem of an instrument: its name, or a YAML file's stem."""
    return Path(instrument).stem if instrument.endswith((".yaml", ".yml")) else instrument


#: Instrument files of the study, found by their name (``bela_5ns``).
STUDY_INSTRUMENTS = STUDY_PRESETS / "instruments"


def is_instrument_file(instrument: str) -> bool:
    """Whether ``--instrument`` names a file: a ``.yaml``/``.yml`` name or a path."""
    return str(instrument).endswith((".yaml", ".yml")) or "/" in str(instrument) \
        or os.sep in str(instrument)


def resolve_instruments(instruments: list) -> list:
    """Every instrument of a study checked before anything runs: (label, what ``warpe-cl
    instrument --instrument`` takes).

    Parameters
    ----------
    instruments : list of str
        Bundled names (``bela``), names of ``presets/study/instruments/`` (``bela_5ns``), or
        instrument YAML files (any path).

    Returns
    -------
    list of (str, str)
        The label (name, or file stem) and the bundled name or the file's absolute path.

    Raises
    ------
    StudyError
        A file that is missing or not a valid instrument (the one line of warpe-cl's
        :class:`~warpe_cl.errors.ConfigError`), a name that is neither bundled nor a study
        instrument, or two instruments of one label.
    """
    from warpe_cl.config.instrument_fields import BUILTIN
    from warpe_cl.errors import ConfigError
    from warpe_cl.instrument import load_instrument
    out = []
    for instrument in instruments:
        label = instrument_label(str(instrument))
        if is_instrument_file(instrument):
            path = Path(instrument).expanduser().resolve()
            if not path.is_file():
                raise StudyError(f"--instrument {instrument}: no such file; give a bundled "
                                 f"instrument ({', '.join(BUILTIN)}) or an instrument YAML "
                                 f"file")
            source = str(path)
        elif label in BUILTIN:
            source = label
        elif (STUDY_INSTRUMENTS / f"{label}.yaml").is_file():
            source = str(STUDY_INSTRUMENTS / f"{label}.yaml")
        else:
            raise StudyError(f"--instrument {instrument}: neither a bundled instrument "
                             f"({', '.join(BUILTIN)}), nor one of {STUDY_INSTRUMENTS}, nor "
                             f"a YAML file")
        try:
            load_instrument(source)
        except ConfigError as exc:
            raise StudyError(f"--instrument {instrument}: {exc}") from None
        if label in {lb for lb, _ in out}:
            raise StudyError(f"--instrument {instrument}: a second instrument labelled "
                             f"{label!r}; rename one of the files")
        out.append((label, source))
    return out


def stage_instruments(family_dir: Path, resolved: list) -> list:
    """Copy every instrument given as a file into ``family_dir/instruments/LABEL.yaml``
    (the study's own record of it) and return (label, what ``warpe-cl instrument`` takes):
    bundled names unchanged, files as their copy.

    Raises
    ------
    StudyError
        ``instruments/LABEL.yaml`` already holds another file (a study keeps the instrument
        its injections were simulated with).
    """
    out = []
    for label, source in resolved:
        if not Path(source).is_file():
            out.append((label, source))
            continue
        copy_path = family_dir / "instruments" / f"{label}.yaml"
        text = Path(source).read_text(encoding="utf-8")
        if copy_path.is_file() and copy_path.read_text(encoding="utf-8") != text:
            raise StudyError(f"{copy_path} holds another instrument {label!r} than {source}: "
                             f"the study's injections were simulated with it; give the file "
                             f"another name, or another --work")
        copy_path.parent.mkdir(parents=True, exist_ok=True)
        if not copy_path.is_file():
            tmp = copy_path.with_name(f".{copy_path.name}.tmp")
            tmp.write_text(text, encoding="utf-8")
            tmp.replace(copy_path)
        out.append((label, str(copy_path)))
    return out


def plan_injections(raw: dict, count: int, seed: int, photons: int, instruments: list,
                    spacing: dict | None = None, per_decade: int | None = None) -> tuple:
    """The injections of a study: their values, seeds and files, before anything runs.

    Parameters
    ----------
    raw : dict
        The family's preset (with its sweep block).
    count, seed : int
        Injections to draw and the seed of the draw.
    photons : int
        Rays of each injected surface.
    instruments : list of str
        Instrument names (or files) each surface goes through.
    spacing : dict, optional
        ``{key: kind}`` overriding :func:`detect_spacing` for some keys.
    per_decade : int, optional
        Log time bins per decade of the injected surfaces (default: the preset's).

    Returns
    -------
    (list of Axis, dict, list of dict)
        The axes, the spacing used for each key, and one row per injection holding the
        columns of :func:`csv_columns` (paths relative to the family folder) plus
        ``"point"``: the values as written, for its preset.
    """
    spacing = dict(spacing or {})
    axes = sweep_axes(raw)
    unknown = set(spacing) - {a.key for a in axes}
    if unknown:
        raise StudyError(f"--spacing names keys that are not swept: {', '.join(sorted(unknown))}")
    kinds = {a.key: spacing.get(a.key) or detect_spacing(a.values) for a in axes}
    bins = per_decade if per_decade is not None else preset_per_decade(raw)
    points = draw_points([a.values for a in axes], [kinds[a.key] for a in axes], count, seed)
    rows = []
    for i, values in enumerate(points):
        folder = f"inj/i{i:03d}"
        row = {"index": i, "name": f"{raw.get('name', 'study')}_i{i:03d}", "point": {}}
        for axis, value in zip(axes, values):
            text = value_text(value, axis)
            row["point"][axis.key] = text
            row[axis.key] = repr(node_value(text, axis.dimension))
            row[f"{axis.key}_text"] = str(text)
        row.update(surface_seed=SURFACE_SEED + i, photons=int(photons), per_decade=bins,
                   surface=f"{folder}/surface.nc")
        for j, instrument in enumerate(instruments):
            label = instrument_label(instrument)
            row[f"{label}_seed"] = INSTRUMENT_SEED + 1000 * j + i
            row[label] = f"{folder}/{label}.nc"
        rows.append(row)
    return axes, kinds, rows


def csv_columns(axes: list, instruments: list) -> list:
    """The columns of ``injections.csv``: ``index``, ``name``; per swept key its true value
    in SI units (column named by the dotted key; m for lengths) and ``KEY_text`` as
    simulated; ``surface_seed``, ``photons``, ``per_decade`` (log time bins per decade),
    ``surface`` (path relative to the CSV's folder); per instrument ``LABEL_seed`` and ``LABEL`` (path); ``status`` (``done``,
    ``pending``, or ``failed: STEP: error``)."""
    cols = ["index", "name"]
    for axis in axes:
        cols += [axis.key, f"{axis.key}_text"]
    cols += ["surface_seed", "photons", "per_decade", "surface"]
    for instrument in instruments:
        label = instrument_label(instrument)
        cols += [f"{label}_seed", label]
    return cols + ["status"]


def preset_per_decade(raw: dict):
    """The log time bins per decade of a preset (the schema's default where it names none),
    or None for linear bins."""
    from warpe_cl.config.schema import DEFAULTS
    bins = (raw.get("simulation") or {}).get("time_bins") or {}
    if "width" in bins:
        return None
    return int(bins.get("per_decade", DEFAULTS["simulation.time_bins.per_decade"]))


def injection_preset(raw: dict, point: dict, name: str, per_decade=None) -> dict:
    """The family's preset for one injection: no sweep block, ``point`` (dotted key -> value
    as written) set, ``name`` given, and ``per_decade`` log time bins per decade when it
    differs from the preset's."""
    from warpe_cl.config.keys import apply_overrides
    one = {k: copy.deepcopy(v) for k, v in raw.items() if k != "sweep"}
    apply_overrides(one, dict(point))
    if per_decade is not None and per_decade != preset_per_decade(raw):
        apply_overrides(one, {"simulation.time_bins.per_decade": int(per_decade)})
    one["name"] = name
    one["description"] = (f"Injection {name} of tools/studies/inversion_study.py: "
                          + ", ".join(f"{k} = {v}" for k, v in point.items()))
    return one


def check_previous(csv_path: Path, rows: list, columns: list) -> None:
    """Refuse to resume into an ``injections.csv`` written for another draw: every row it
    shares with ``rows`` must agree on every column of both but ``status`` (columns it lacks,
    an instrument added to the study, are new)."""
    if not csv_path.is_file():
        return
    with open(csv_path, newline="") as fh:
        reader = csv.DictReader(fh)
        old = {r["index"]: r for r in reader}
        columns = [c for c in columns if c in (reader.fieldnames or [])]
    for row in rows:
        prev = old.get(str(row["index"]))
        if prev is None:
            continue
        for col in columns:
            if col != "status" and prev.get(col) != str(row[col]):
                raise StudyError(f"{csv_path}: injection {row['index']} has {col} = "
                                 f"{prev.get(col)!r}, this draw {row[col]!r}; use another "
                                 "--work or remove the folder")


def write_csv(path: Path, rows: list, columns: list) -> None:
    """``rows`` (dicts) as CSV with ``columns``, written atomically."""
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)


# --------------------------------------------------------------------------- running


def warpe_cl_command(*args) -> list:
    """``warpe-cl ARGS`` as this Python runs it (any virtual environment)."""
    return [sys.executable, "-m", "warpe_cl", *map(str, args)]


def run_logged(cmd: list, log: Path) -> tuple:
    """Run ``cmd``, appending the command and its output to ``log``.

    Returns
    -------
    (int, float, str)
        The exit code, the seconds it took and the last ``warpe-cl: error`` line (else the
        last line of its output; empty on success).
    """
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    with open(log, "a") as fh:
        fh.write(f"$ {' '.join(cmd)}\n{proc.stdout}{proc.stderr}"
                 f"# exit {proc.returncode}, {seconds:.1f} s\n")
    lines = (proc.stdout + proc.stderr).strip().splitlines()
    errors = [ln for ln in lines if "error" in ln]
    message = "" if proc.returncode == 0 else ((errors or lines or ["(no output)"])[-1])
    return proc.returncode, seconds, message


def database_photons(db: Path) -> int | None:
    """The photon count of the sweep database ``db`` (its manifest), None without one."""
    manifests = sorted(db.glob("manifest*.json"))
    return int(json.loads(manifests[0].read_text())["photons"]) if manifests else None


def default_photons(raw: dict, db: Path, photons: float | None) -> int:
    """``--photons`` when given, else the database's count, else the preset's."""
    if photons is not None:
        return int(photons)
    found = database_photons(db)
    return found if found is not None else int(float(raw["simulation"]["photons"]))


def run_injection(row: dict, raw: dict, family_dir: Path, instruments: list,
                  sources: dict | None = None) -> str:
    """Simulate one injection (its preset, surface and instrument files), skipping the files
    that exist. Returns its status and prints one line. ``instruments``: labels;
    ``sources``: label -> what ``warpe-cl instrument --instrument`` takes (default: the
    label)."""
    sources = sources or {}
    folder = family_dir / row["surface"].rsplit("/", 1)[0]
    folder.mkdir(parents=True, exist_ok=True)
    log = folder / "log.txt"
    preset = folder / "preset.yaml"
    if not preset.exists():
        preset.write_text(yaml.safe_dump(injection_preset(raw, row["point"], row["name"],
                                                          row.get("per_decade")),
                                         sort_keys=False, width=100))
    surface = family_dir / row["surface"]
    times = []
    if not surface.exists():
        rc, seconds, message = run_logged(warpe_cl_command(
            "run", preset, "--seed", row["surface_seed"], "--photons", row["photons"],
            "--out", surface, "--quiet"), log)
        times.append(f"surface {seconds:.1f} s")
        if rc:
            print(f"i{row['index']:03d} surface failed (exit {rc}): {message}", file=sys.stderr)
            return f"failed: surface: {message}"
    failures = []
    for instrument in instruments:
        label = instrument_label(instrument)
        out = family_dir / row[label]
        if out.exists():
            continue
        rc, seconds, message = run_logged(warpe_cl_command(
            "instrument", surface, "--instrument", sources.get(label, instrument),
            "--seed", row[f"{label}_seed"],
            "--out", out, "--quiet"), log)
        times.append(f"{label} {seconds:.1f} s")
        if rc:
            print(f"i{row['index']:03d} {label} failed (exit {rc}): {message}", file=sys.stderr)
            failures.append(f"{label}: {message}")
    print(f"i{row['index']:03d} " + (", ".join(times) or "already done"), flush=True)
    return f"failed: {'; '.join(failures)}" if failures else "done"


# --------------------------------------------------------------------------- verbs


def cmd_build(args) -> int:
    """``build``: the family's sweep database in WORK/FAMILY/db (resumed if it exists)."""
    path = preset_path(args.family, args.preset)
    read_preset(path)
    db = Path(args.work) / args.family / "db"
    cmd = warpe_cl_command("sweep", path, "--out", db, "--quiet")
    if args.photons is not None:
        cmd += ["--photons", str(int(args.photons))]
    if db.exists():
        cmd.append("--resume")
    db.parent.mkdir(parents=True, exist_ok=True)
    print("$ " + " ".join(cmd), flush=True)
    start = time.perf_counter()
    rc = subprocess.run(cmd).returncode
    print(f"build {args.family}: exit {rc}, {time.perf_counter() - start:.1f} s", flush=True)
    return rc


def chosen_instruments(instruments: str | None, instrument: list | None) -> list:
    """The instruments of ``inject``: ``--instruments A,B`` then every ``--instrument``;
    ``bela,gala`` when neither is given."""
    if instruments is None:
        instruments = "" if instrument else "bela,gala"
    return [s.strip() for s in instruments.split(",") if s.strip()] + list(instrument or [])


def cmd_inject(args) -> int:
    """``inject``: draw the injections, write their presets, surfaces, instrument files and
    ``injections.csv`` in WORK/FAMILY."""
    raw = read_preset(preset_path(args.family, args.preset))
    family_dir = Path(args.work) / args.family
    resolved = resolve_instruments(chosen_instruments(args.instruments, args.instrument))
    instruments = [label for label, _ in resolved]
    photons = default_photons(raw, family_dir / "db", args.photons)
    if args.per_decade is not None and args.per_decade < 1:
        raise StudyError(f"--per-decade {args.per_decade}: time bins per decade, an integer "
                         ">= 1")
    if args.per_decade is not None and preset_per_decade(raw) is None:
        raise StudyError(f"--per-decade {args.per_decade}: the preset's time bins are linear "
                         "(simulation.time_bins.width), not per decade")
    axes, kinds, rows = plan_injections(raw, args.count, args.seed, photons, instruments,
                                        parse_spacings(args.spacing), args.per_decade)
    columns = csv_columns(axes, instruments)
    csv_path = family_dir / "injections.csv"
    check_previous(csv_path, rows, columns)
    family_dir.mkdir(parents=True, exist_ok=True)
    sources = dict(stage_instruments(family_dir, resolved))
    print(f"inject {args.family}: {args.count} points, seed {args.seed}, {photons} photons, "
          f"{rows[0]['per_decade'] if rows else '-'} time bins per decade, "
          f"instruments {', '.join(instruments) or 'none'}; spacing "
          + ", ".join(f"{k} {v}" for k, v in kinds.items()), flush=True)
    for row in rows:
        row["status"] = "pending"
    write_csv(csv_path, rows, columns)
    start = time.perf_counter()
    for row in rows:
        row["status"] = run_injection(row, raw, family_dir, instruments, sources)
        write_csv(csv_path, rows, columns)
    failed = [r["index"] for r in rows if r["status"] != "done"]
    which = f" (injections {', '.join(map(str, failed))})" if failed else ""
    print(f"inject {args.family}: {len(rows) - len(failed)} done, {len(failed)} failed{which}, "
          f"{time.perf_counter() - start:.1f} s; wrote {csv_path}", flush=True)
    return 1 if failed else 0


def parser() -> argparse.ArgumentParser:
    """The command line: ``build`` and ``inject``."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="verb", required=True)

    def common(q):
        q.add_argument("family", help="a preset of presets/study/ (gran_co2, slab_h2o_co2, ...)")
        q.add_argument("--work", required=True, help="work folder; results go to WORK/FAMILY/")
        q.add_argument("--preset", help="a preset file instead of presets/study/FAMILY.yaml")
        q.add_argument("--photons", type=float,
                       help="rays per scenario (inject: default the database's, else the preset's)")

    b = sub.add_parser("build", help="the family's sweep database, WORK/FAMILY/db")
    common(b)
    b.set_defaults(func=cmd_build)
    i = sub.add_parser("inject", help="injected surfaces and instrument files, WORK/FAMILY/inj")
    common(i)
    i.add_argument("--count", type=int, default=50, help="injections to draw (50)")
    i.add_argument("--seed", type=int, default=7, help="seed of the draw (7)")
    i.add_argument("--instruments", default=None,
                   help="comma-separated instruments (names or YAML files; default bela,gala "
                        "unless --instrument is given); '' for none")
    i.add_argument("--instrument", action="append", metavar="NAME|FILE",
                   help="one more instrument: a bundled name or any instrument YAML file "
                        "(repeatable)")
    i.add_argument("--per-decade", type=int, metavar="N",
                   help="log time bins per decade of the injected surfaces (default: the "
                        "preset's); finer than the database's, a truth resolves returns "
                        "sharper than its bins")
    i.add_argument("--spacing", action="append", metavar="KEY=KIND",
                   help="draw KEY in linear, log or log1m coordinates instead of the "
                        "detected one (repeatable)")
    i.set_defaults(func=cmd_inject)
    return p


def run_verbs(arg_parser: argparse.ArgumentParser, argv, name: str) -> int:
    """Parse ``argv`` and run the chosen verb; a StudyError is one line on stderr and exit 2
    (shared with tools/studies/inversion_recovery.py)."""
    args = arg_parser.parse_args(argv)
    try:
        return args.func(args)
    except StudyError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 2


def main(argv=None) -> int:
    """Run the tool; returns the exit code."""
    return run_verbs(parser(), argv, "inversion_study")


if __name__ == "__main__":
    sys.exit(main())
