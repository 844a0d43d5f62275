"""The study file of ``warpe-cl design`` (docs/design.md §4): surface families, candidate
instruments and options, checked whole before any work.

    name: example                           # optional
    families:
      - name: gran_co2                      # a label: letters, digits, _ and -
        database: db/                       # a sweep folder or sweep file (relative to this file)
        preset: example/gran_co2_db         # optional: swept first (resumed) into the database
        photons: 3e4                        # optional, with preset: rays per scenario
        wavelengths: ["1064 nm", "532 nm"]  # optional, with preset: swept at each
    instruments:
      - name: bela                          # a label
        instrument: bela                    # bela, gala, atlas or a YAML file (default: name)
        set: {shots: 100, transmitter.pulse_fwhm: "1 ns"}   # instrument keys, as --set
    combinations:                           # optional: instruments observing together
      - name: bela+atlas                    # a label
        instruments: [bela, atlas]          # two or more labels of instruments:
    options:
      phases: 8                             # sampling phases averaged
      database_error: true                  # count the database's own error
      nuisances: [amplitude, arrival, pulse]

A family with a ``preset`` and no ``database`` is swept into ``OUT/databases/NAME/``, or, with
``wavelengths``, at each wavelength into ``OUT/databases/NAME_<nm>nm/``. A family's
``database`` may also be a list, one database per wavelength (the same swept keys and nodes).
Each instrument reads the family's database at its own wavelength; a combination adds its
instruments' information (docs/design.md §2.4).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..config.instrument_fields import at_wavelength, load_instrument
from ..config.validate import read_yaml, show
from ..units import UnitError, parse_quantity
from ..errors import ConfigError
from .fisher import NUISANCES

TOP_KEYS = ("name", "description", "families", "instruments", "combinations", "options")
FAMILY_KEYS = ("name", "database", "preset", "photons", "wavelengths")
INSTRUMENT_KEYS = ("name", "instrument", "set")
COMBINATION_KEYS = ("name", "instruments")
#: Options: name -> (default, what is allowed).
OPTIONS = {
    "phases": (8, "a whole number of sampling phases in [1, 64]"),
    "database_error": (True, "true or false"),
    "nuisances": (list(NUISANCES), f"a list of nuisances among {', '.join(NUISANCES)}"),
}
LABEL = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}$")


@dataclass
class FamilySpec:
    """One family of the study file: its label, its databases (one per wavelength), and the
    preset to sweep into them with the wavelength each is swept at (None: the preset's)."""
    name: str
    databases: list
    preset: str | None = None
    photons: object = None
    wavelengths: list = field(default_factory=lambda: [None])


@dataclass
class Candidate:
    """One candidate instrument: its label, what it was loaded from and with which keys set,
    and its validated parameters."""
    name: str
    spec: str
    overrides: dict
    params: object


@dataclass
class Combination:
    """Instruments observing the same surfaces together: its label and the labels of its
    instruments (:class:`Candidate`)."""
    name: str
    members: list


@dataclass
class Study:
    """A checked study file."""
    name: str
    source: str
    families: list
    instruments: list
    options: dict = field(default_factory=dict)
    combinations: list = field(default_factory=list)


def _mapping(value, key: str, source: str, keys: tuple) -> dict:
    """``value`` as a mapping whose keys are among ``keys`` (ConfigError otherwise)."""
    if not isinstance(value, dict):
        raise ConfigError(f"{show(value)} is not a mapping; give a mapping with keys among "
                          f"{', '.join(keys)}", key=key, source=source)
    for k in value:
        if k not in keys:
            raise ConfigError(f"unknown key {show(k)}; the keys allowed are {', '.join(keys)}",
                              key=f"{key}.{k}" if key else str(k), source=source)
    return value


def _list(value, key: str, source: str) -> list:
    if not isinstance(value, list) or not value:
        raise ConfigError(f"{show(value)} is not a list of one or more entries; give a list",
                          key=key, source=source)
    return value


def _label(value, key: str, source: str, seen: set) -> str:
    if not isinstance(value, str) or not LABEL.match(value):
        raise ConfigError(f"{show(value)} is not a label; give letters, digits, _, ., + or - "
                          "(64 at most, starting with a letter or digit)", key=key,
                          source=source)
    if value in seen:
        raise ConfigError(f"{value} is given twice; give each a different name", key=key,
                          source=source)
    seen.add(value)
    return value


def load_study(path, out=None) -> Study:
    """Read and check a study file (module docstring); the instruments are loaded and
    validated, the databases are not read.

    Parameters
    ----------
    path : path
        The study YAML.
    out : path, optional
        The study's output folder: where a family with a preset and no database is swept.

    Returns
    -------
    Study

    Raises
    ------
    ConfigError
        One line naming the file, the key, the value (with its unit) and what is allowed.
    """
    path = Path(path)
    source = str(path)
    doc = read_yaml(path, what="a design study file", empty="; give families: and "
                                                         "instruments:")
    doc = _mapping(doc, "", source, TOP_KEYS)
    for key in ("families", "instruments"):
        if key not in doc:
            raise ConfigError(f"missing; give a list of {key}", key=key, source=source)
    here = path.resolve().parent
    families, seen = [], set()
    for i, entry in enumerate(_list(doc["families"], "families", source)):
        where = f"families[{i}]"
        entry = _mapping(entry, where, source, FAMILY_KEYS)
        name = _label(entry.get("name"), f"{where}.name", source, seen)
        preset = entry.get("preset")
        if preset is not None and not isinstance(preset, str):
            raise ConfigError(f"{show(preset)} is not a preset; give a preset file or a "
                              "bundled preset's name", key=f"{where}.preset", source=source)
        if preset is not None and (here / preset).is_file():
            preset = str(here / preset)          # relative to the study file, else bundled
        photons = entry.get("photons")
        if photons is not None and preset is None:
            raise ConfigError("applies to a preset that is swept; give preset: too, or leave "
                              "photons out", key=f"{where}.photons", source=source)
        wavelengths = _wavelengths(entry.get("wavelengths"), preset, f"{where}.wavelengths",
                                   source)
        database = entry.get("database")
        if database is None:
            if preset is None:
                raise ConfigError("missing; give database: (a `warpe-cl sweep` folder or sweep "
                                  "file, or a list of them, one per wavelength) or preset: "
                                  "(swept first)", key=f"{where}.database", source=source)
            root = Path(out or ".") / "databases"
            databases = [root / (name if w is None else f"{name}_{_nm(w)}nm")
                         for w in wavelengths]
        else:
            if wavelengths != [None]:
                raise ConfigError("applies to a preset that is swept; give one database per "
                                  "wavelength instead (database: [A, B])",
                                  key=f"{where}.wavelengths", source=source)
            given = database if isinstance(database, list) and database else [database]
            databases = []
            for k, d in enumerate(given):
                if not isinstance(d, str) or not d.strip():
                    raise ConfigError(f"{show(d)} is not a path; give a sweep folder or file "
                                      "(or a list of them, one per wavelength)",
                                      key=f"{where}.database", source=source)
                d = Path(d)
                d = d if d.is_absolute() else here / d
                if preset is None and not d.exists():
                    raise ConfigError(f"{d}: no such database; give a `warpe-cl sweep` "
                                      "folder or sweep file, or a preset: to sweep it first",
                                      key=f"{where}.database", source=source)
                databases.append(d)
            if preset is not None and len(databases) > 1:
                raise ConfigError("a preset is swept into one database; give one database, or "
                                  "wavelengths: to sweep it at several",
                                  key=f"{where}.database", source=source)
        families.append(FamilySpec(name, databases, preset, photons, wavelengths))
    instruments, seen = [], set()
    for i, entry in enumerate(_list(doc["instruments"], "instruments", source)):
        where = f"instruments[{i}]"
        entry = _mapping(entry, where, source, INSTRUMENT_KEYS)
        name = _label(entry.get("name"), f"{where}.name", source, seen)
        spec = entry.get("instrument", name)
        if not isinstance(spec, str):
            raise ConfigError(f"{show(spec)} is not an instrument; give bela, gala, atlas or "
                              "an instrument YAML file", key=f"{where}.instrument",
                              source=source)
        overrides = entry.get("set") or {}
        if not isinstance(overrides, dict):
            raise ConfigError(f"{show(overrides)} is not a mapping; give instrument keys and "
                              'values, e.g. {transmitter.pulse_fwhm: "1 ns"}',
                              key=f"{where}.set", source=source)
        spec_path = Path(spec)
        if spec.lower() not in ("bela", "gala", "atlas") and not spec_path.is_absolute():
            spec_path = here / spec_path
            spec = str(spec_path) if spec_path.is_file() else spec
        try:
            params = load_instrument(spec, {str(k): v for k, v in overrides.items()},
                                     override_source=f"{source}: {where}.set",
                                     spec_key=f"{where}.instrument")
        except ConfigError as err:
            raise err.with_source(source) from None
        instruments.append(Candidate(name, spec, dict(overrides), params))
    combinations = _combinations(doc.get("combinations"), instruments, source)
    options = _options(doc.get("options") or {}, source)
    return Study(str(doc.get("name") or path.stem), source, families, instruments, options,
                 combinations)


def _nm(wavelength: float) -> str:
    """A wavelength (m) as a name part: ``532`` for 532 nm, ``1064.5`` for 1064.5 nm."""
    return f"{wavelength * 1e9:.6g}"


def _wavelengths(value, preset, key: str, source: str) -> list:
    """``wavelengths:`` of a family, in m (``[None]`` when not given: the preset's own)."""
    if value is None:
        return [None]
    if preset is None:
        raise ConfigError("applies to a preset that is swept; give preset: too, or one "
                          "database per wavelength (database: [A, B])", key=key, source=source)
    out = []
    for v in _list(value, key, source):
        try:
            metres = parse_quantity(v, "length") if isinstance(v, str) else None
        except UnitError:
            metres = None
        if metres is None or not math.isfinite(metres) or not 100e-9 <= metres <= 20e-6:
            raise ConfigError(f"{show(v)} is not a wavelength; give a list of wavelengths with "
                              'their unit between 100 nm and 20 um, e.g. ["1064 nm", "532 nm"]',
                              key=key, source=source)
        if any(at_wavelength(metres, w) for w in out):
            raise ConfigError(f"{show(v)} is given twice; give each wavelength once", key=key,
                              source=source)
        out.append(metres)
    return out


def _combinations(value, instruments: list, source: str) -> list:
    """``combinations:``, checked: labels new, two or more instruments of the study each."""
    if value is None:
        return []
    labels = [c.name for c in instruments]
    out, seen = [], set(labels)
    for i, entry in enumerate(_list(value, "combinations", source)):
        where = f"combinations[{i}]"
        entry = _mapping(entry, where, source, COMBINATION_KEYS)
        name = _label(entry.get("name"), f"{where}.name", source, seen)
        members = entry.get("instruments")
        if not isinstance(members, list) or len(members) < 2 or \
                any(m not in labels for m in members) or len(set(members)) != len(members):
            raise ConfigError(f"{show(members)} is not allowed; give a list of two or more "
                              f"different instruments of the study ({', '.join(labels)})",
                              key=f"{where}.instruments", source=source)
        out.append(Combination(name, list(members)))
    return out


def _options(raw, source: str) -> dict:
    """The options with their defaults (:data:`OPTIONS`), checked."""
    raw = _mapping(raw, "options", source, tuple(OPTIONS))
    out = {k: v[0] for k, v in OPTIONS.items()}
    for key, value in raw.items():
        wanted = OPTIONS[key][1]
        bad = ConfigError(f"{show(value)} is not allowed; give {wanted}", key=f"options.{key}",
                          source=source)
        if key == "phases":
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value) or value != int(value) or not 1 <= value <= 64:
                raise bad
            value = int(value)
        elif key == "database_error":
            if not isinstance(value, bool):
                raise bad
        elif key == "nuisances":
            if not isinstance(value, list) or any(v not in NUISANCES for v in value):
                raise bad
        out[key] = value
    return out


def member_for(members: list, cand: Candidate, family: str, source: str):
    """The database of a family (one :class:`~.family.Family` per wavelength) that an
    instrument reads: the one computed at its wavelength (or one that names none).

    Raises
    ------
    ConfigError
        No database of the family at the instrument's wavelength (one line: the wavelengths
        there are, the instrument's, and what to do).
    """
    lam = cand.params["wavelength"]
    for fam in members:
        if fam.wavelength is None or at_wavelength(fam.wavelength, lam):
            return fam
    there = ", ".join(f"{f.wavelength * 1e9:g} nm" for f in members)
    raise ConfigError(f"{cand.name} works at {lam * 1e9:g} nm but family {family} has "
                      f"databases at {there}; add a database computed at {lam * 1e9:g} nm "
                      "(database: [A, B], or wavelengths: with a preset), or leave "
                      f"{cand.name} out", key="instruments", source=source)
