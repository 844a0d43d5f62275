"""Presets: the schema table, YAML loading, ``--set`` overrides and validation.

A preset is a YAML file (or a plain dict of the same shape, interface.md §3). Every key it
may hold is one row of :data:`SCHEMA`; that table is the single source of the key names,
kinds, units, defaults, limits and help texts. It drives validation, the defaults, the
resolved YAML written by :meth:`Config.to_yaml` and the reference table of
:func:`schema_markdown`.

>>> cfg = load_preset({"medium": {"texture": "granular", "thickness": "100 mm",
...                               "radiative": {"tau0": 1.0, "omega": 0.9, "n": 1.3}}})
>>> cfg.get("medium.thickness")          # metres
0.1
>>> cfg.get("simulation.fov.scattering")  # degrees
12.0
>>> cfg.get("simulation.photons")
1000000

Canonical units in :attr:`Config.data` and :meth:`Config.get`: lengths in metres, times in
nanoseconds, angles in degrees. Every mistake raises :class:`~warpe_cl.errors.ConfigError`
with one line naming the file, the key, the value and what is allowed.
"""
from __future__ import annotations

import copy
import difflib
import itertools
import math
import os
import re
from dataclasses import dataclass

import numpy as np
import yaml

from .errors import ConfigError
from .units import UnitError, format_quantity, parse_quantity, unit_list

__all__ = ["Field", "SCHEMA", "FIELDS", "Config", "load_preset", "time_edges",
           "schema_markdown", "reference_markdown", "Grid", "load_grid", "MAX_PHOTONS"]


# --------------------------------------------------------------------------- the table

@dataclass(frozen=True)
class Field:
    """One row of the preset schema.

    Attributes
    ----------
    key : str
        Dotted key. ``[]`` marks the items of a list (``medium.inclusions[].grain_size``) and
        ``*`` any name chosen by the user (``materials.*.n``).
    kind : str
        ``"length"``, ``"time"``, ``"angle"`` (strings with a unit, stored in m, ns, deg),
        ``"float"``, ``"int"``, ``"str"``, ``"choice"``, ``"bool"``; or a structured kind:
        ``"section"`` (a mapping of the keys listed under it), ``"open_section"`` (the same,
        other keys passed through unchecked), ``"list"`` (a list of sections),
        ``"names"`` (a mapping from user-chosen names to sections), ``"time_bins"``,
        ``"sweep"``.
    default : object
        The value used when the key is absent, as a user would write it (``"12 deg"``).
        For sections: ``{}`` means filled with defaults when absent, None means absent.
    required : bool
        The key must be given (inside its section, when that section is given).
    low, high : float or None
        Limits in the canonical unit; ``low_open`` / ``high_open`` exclude them.
    choices : tuple of str or None
        The allowed values of a ``"choice"``.
    help : str
        User-facing description (shown by :func:`schema_markdown`).
    unit : str or None
        What a plain number counts (``"rays"``), named in messages and in the reference
        table; None for quantities (their unit is written with the value) and pure numbers.
    """

    key: str
    kind: str
    default: object = None
    required: bool = False
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple | None = None
    help: str = ""
    unit: str | None = None


QUANTITY_KINDS = ("length", "time", "angle")
SCALAR_KINDS = QUANTITY_KINDS + ("float", "int", "str", "choice", "bool")
_CANONICAL_UNIT = {"length": "m", "time": "ns", "angle": "deg"}
_EXAMPLE = {"length": "100 mm", "time": "12.5 ns", "angle": "12 deg"}
MAX_TIME_BINS = 1_000_000
#: Most rays a scenario may launch: 2^53, the largest count a YAML number (a float64) holds
#: exactly. The kernel's photon index (the Philox counter) is 64-bit and the host tallies are
#: int64 or exact integers, so every count up to here is walked and tallied exactly.
MAX_PHOTONS = 2 ** 53
#: Lowest ``simulation.roulette_survival``: a surviving weight stays below
#: roulette_weight / roulette_survival <= 1 / 1e-3 = 1e3 (see the help text).
MIN_ROULETTE_SURVIVAL = 1e-3
#: Largest ``simulation.max_flights``: the kernel holds the flight count in 31 bits.
MAX_FLIGHTS = 2 ** 31 - 1
_F = Field

SCHEMA: list[Field] = [
    _F("name", "str",
       help="Short identifier of the scenario, written into the output file. "
            "Default: the preset's file name without its extension."),
    _F("description", "str", "", help="Free text describing the scenario."),

    _F("medium", "section", required=True,
       help="The surface layer: texture, thickness, floor, and its composition given either "
            "physically (compacity, matrix, inclusions) or radiatively (radiative)."),
    _F("medium.texture", "choice", required=True, choices=("slab", "granular"),
       help="slab: a compact matrix (e.g. ice) holding inclusions, bounded by Fresnel "
            "interfaces; granular: grains with void pores between them, no interfaces."),
    _F("medium.thickness", "length", required=True, low=0.0, low_open=True,
       help="Physical thickness h of the layer above the floor."),
    _F("medium.bottom_albedo", "float", 0.15, low=0.0, high=1.0,
       help="Lambertian albedo A of the floor under the layer (0: a black floor; what "
            "reaches it leaves the layer)."),
    _F("medium.bottom_interface", "choice", "fresnel", choices=("fresnel", "none"),
       help="Slab only. fresnel: a slab / vacuum-gap interface above the floor "
            "(physics.md §5.5); none: the floor is in optical contact with the slab. "
            "Accepted but ignored for a granular medium, which has no interfaces."),
    _F("medium.phase_g", "float", 0.8, low=-1.0, high=1.0, low_open=True, high_open=True,
       help="Henyey-Greenstein asymmetry parameter g of volume scattering (0: isotropic, "
            "close to 1: forward)."),
    _F("medium.extinction_efficiency", "float", 1.0, low=0.0, low_open=True,
       help="Physical form: extinction efficiency Q_e of the inclusions or grains "
            "(physics.md A4: 1 in geometric optics, where Hapke's w is defined and the "
            "diffraction peak of packed or embedded particles is dropped; 2 counts it)."),
    _F("medium.matrix_absorption", "choice", "seed", choices=("seed", "volume_weighted"),
       help="Slab, physical form: the matrix absorption a_m = 4 pi k / lambda enters the "
            "extinction as in the seed (seed), or weighted by the matrix volume fraction "
            "gamma_c (volume_weighted; physics.md A5)."),
    _F("medium.inclusion_absorption", "choice", "absolute", choices=("absolute", "relative"),
       help="Physical form: the absorption inside an inclusion uses its own k (absolute, "
            "physics.md A6) or its k relative to the matrix (relative)."),
    _F("medium.fresnel_integrals", "choice", "exact", choices=("exact", "hapke"),
       help="Physical form: S_e and S_i by quadrature of the exact Fresnel law (exact, "
            "physics.md §3.6) or Hapke's approximations (hapke; invalid for n_rel < 1, "
            "refused there)."),
    _F("medium.radiative", "section",
       help="The medium in radiative terms, instead of compacity/matrix/inclusions: the "
            "same kernels run with these values."),
    _F("medium.radiative.tau0", "float", required=True, low=0.0,
       help="Total optical depth tau0 = E h of the layer (E: volume extinction, m^-1)."),
    _F("medium.radiative.omega", "float", required=True, low=0.0, high=1.0,
       help="Single-scattering albedo omega of the medium."),
    _F("medium.radiative.n", "float", required=True, low=1.0,
       help="Effective refractive index: sets the speed of light in the layer and, for a "
            "slab, its Fresnel interfaces."),
    _F("medium.radiative.k", "float", 0.0, low=0.0,
       help="Effective extinction index (imaginary part), used in the Fresnel reflectance "
            "of a slab seen from vacuum."),
    _F("medium.compacity", "float", low=0.0, high=1.0, low_open=True,
       help="Compacity gamma_c (filling factor), physical form only. Slab: volume fraction "
            "of the matrix; granular: volume fraction of the grains."),
    _F("medium.matrix", "str",
       help="Slab only, physical form: the matrix material (a built-in such as H2O or CO2, "
            "or a name defined under materials)."),
    _F("medium.inclusions", "list",
       help="Physical form: at least one species. Slab: the impurities in the matrix; "
            "granular: the grains (the pores are void)."),
    _F("medium.inclusions[].material", "str", required=True,
       help="Material of the inclusion or grain (built-in or defined under materials)."),
    _F("medium.inclusions[].proportion", "float", required=True, low=0.0, low_open=True,
       help="Relative volumetric proportion rho_v of this species among the inclusions."),
    _F("medium.inclusions[].grain_size", "length", required=True, low=0.0, low_open=True,
       help="Diameter d of the inclusions or grains of this species."),

    _F("wavelength", "length", "1064 nm", low=0.0, low_open=True,
       help="Laser wavelength; selects the optical constants of the materials."),

    _F("materials", "names", {},
       help="Optional optical constants at the run's wavelength, added to or overriding "
            "the built-ins (names are case-insensitive): {n, k} or {table: FILE}."),
    _F("materials.*.n", "float", low=0.0, low_open=True,
       help="Real refractive index of the material."),
    _F("materials.*.k", "float", 0.0, low=0.0,
       help="Imaginary refractive index (extinction index) of the material."),
    _F("materials.*.table", "str",
       help="CSV file with columns wavelength_nm, n, k, interpolated at the wavelength; "
            "a relative path is read from the preset's folder. Not combined with n, k."),

    _F("simulation", "section", {}, help="How the Monte Carlo walk is run and tallied."),
    _F("simulation.photons", "int", 1_000_000, low=1, high=MAX_PHOTONS, unit="rays",
       help="Number of rays launched per scenario (1e6 and 1.0e6 are accepted). At most "
            "2^53 = 9.007e15: the largest count a YAML number (a 64-bit float) holds "
            "exactly; the photon index in the Philox counter is 64-bit and the host "
            "tallies are 64-bit or exact, so every ray up to it is walked and counted. The "
            "bound is one of representation, not of patience: at 1e8 rays/s (a few CPU "
            "cores) 2^53 rays take about 3 years, at 1e10 rays/s (a large GPU) about 10 "
            "days (1e9 rays: about 10 s at 1e8 rays/s). Ctrl-C stops a run (exit 130) "
            "without leaving a partial file."),
    _F("simulation.seed", "int", 1, low=0, high=2**32 - 1,
       help="Random seed: with the 64-bit scenario key (a hash of the resolved medium, "
            "materials, wavelength and simulation blocks, seed and photons left out), the key "
            "of the counter-based Philox generator. The same seed gives the same rays on any "
            "device."),
    _F("simulation.time_bins", "time_bins", {},
       help="Time-bin edges: log-spaced {start, stop, per_decade} or linear "
            "{start, stop, width}; never both per_decade and width."),
    _F("simulation.time_bins.start", "time", "1e-6 ns", low=0.0,
       help="First edge. Log-spaced: > 0, default 1e-6 ns; linear: >= 0, default 0 ns. "
            "Rays leaving earlier (the specular, at t = 0) count in the first bin."),
    _F("simulation.time_bins.stop", "time", "1e5 ns", low=0.0, low_open=True,
       help="Last time to cover (> start); the last edge is the first one at or after it. "
            "Required for linear bins."),
    _F("simulation.time_bins.per_decade", "int", 20, low=1,
       help="Log-spaced bins: number of bins per factor of ten in time."),
    _F("simulation.time_bins.width", "time", low=0.0, low_open=True,
       help="Linear bins: width of every bin."),
    _F("simulation.max_time", "time", low=0.0, low_open=True,
       help="Rays still inside the medium after this time are stopped and counted as "
            "terminated. Default: the last time-bin edge."),
    _F("simulation.max_flights", "int", 10_000_000, low=1, high=MAX_FLIGHTS,
       unit="flights",
       help="Safety cap on free flights per ray; a ray reaching it is counted as "
            "terminated. At most 2^31 - 1, the largest cap the walk kernel takes (a larger "
            "value used to be cut to it without a word)."),
    _F("simulation.fov", "section", {},
       help="Numerical fields of view of the diffuse components (physics.md §6.2): half "
            "angles from the zenith, in vacuum."),
    _F("simulation.fov.scattering", "angle", "12 deg", low=0.0, high=90.0, low_open=True,
       help="Field of view of the background (volume scattering) component."),
    _F("simulation.fov.bf_diffuse", "angle", "3 deg", low=0.0, high=90.0, low_open=True,
       help="Field of view of the BF diffuse (floor-reflected) component."),
    _F("simulation.min_rays", "int", 3, low=0,
       help="Time bins holding fewer rays than this are flagged as under-sampled "
            "(the specular is exempt)."),
    _F("simulation.solid_angle", "choice", "cone", choices=("cone", "projected"),
       help="Solid angle that normalises a field of view theta: cone, 2 pi (1 - cos theta); "
            "or projected, pi sin^2 theta (a Lambertian floor then reads exactly A/pi)."),
    _F("simulation.component_rule", "choice", "history", choices=("history", "time_window"),
       help="How diffuse exits are split into bf_diffuse and scattering: history (a floor "
            "reflection makes bf_diffuse, physics.md §6.1) or time_window (diffuse exits at "
            "or after the first back-and-forth time t1 = 2 h n / c are bf_diffuse)."),
    _F("simulation.precision", "choice", "single", choices=("single", "double"),
       help="Floating-point precision of the walk kernels: single (float32) or double "
            "(float64, on devices that support it)."),
    _F("simulation.specular_lobe", "angle", "0.25 deg", low=0.0, high=90.0,
       low_open=True, high_open=True,
       help="Half-angle of the roughness lobe that scales the specular and BF-direct "
            "reflectances (physics.md §7.3)."),
    _F("simulation.mode", "choice", "analog", choices=("analog", "weighted"),
       help="Monte Carlo scheme: analog (every ray carries weight 1 and is absorbed or not; "
            "the seed's scheme, with its 3-ray threshold) or weighted (survival weighting: "
            "absorption applied as exp(-(1 - omega) E L) along the path and A at the floor, "
            "Russian roulette below simulation.roulette_weight; reaches deep tails, "
            "docs/walk.md §6)."),
    _F("simulation.roulette_weight", "float", 1e-4, low=0.0, high=1.0,
       help="Weighted mode: a ray whose weight falls below this at a scattering or a floor "
            "reflection plays Russian roulette (0: never). At most 1, the weight a ray starts "
            "with, so that with roulette_survival >= 1e-3 no weight ever exceeds "
            "roulette_weight / roulette_survival <= 1e3 (see roulette_survival)."),
    _F("simulation.roulette_survival", "float", 0.1, low=MIN_ROULETTE_SURVIVAL, high=1.0,
       help="Weighted mode: probability that a ray survives the roulette (its weight is then "
            "divided by it). At least 1e-3, so that weights stay bounded: a ray's weight "
            "starts at 1, only shrinks along its path, and grows only at a roulette it "
            "survives, from below roulette_weight to below roulette_weight / "
            "roulette_survival <= 1e3. The exact weighted tallies (cl/tally.h fixed_add) "
            "hold each weight (and its square, <= 1e6) only below 2^42 = 4.4e12 and drop "
            "larger ones; a launch of at most 2^31 rays then sums an expected weight "
            "squared of at most 2^31 x 1e3 = 2.1e12 per cell, below the same 2^42. A lower "
            "survival would only add variance: the roulette is unbiased at any value."),

    _F("sweep", "sweep", {},
       help="Optional grid: dotted keys mapped to lists of values, e.g. medium.thickness: "
            "[\"1 mm\", \"10 mm\"]. Several keys form the outer product, in the order "
            "given; a list item is addressed as medium.inclusions[0].grain_size."),

    _F("instrument", "open_section", {},
       help="Optional instrument applied after the surface simulation; keys other than "
            "those below are passed to the instrument model."),
    _F("instrument.name", "str",
       help="Instrument model, e.g. bela. Absent: no instrument is applied."),
    _F("instrument.altitude", "length", "500 km", low=0.0, low_open=True,
       help="Spacecraft altitude above the surface; also sets the aperture scaling of the "
            "specular and BF-direct reflectances."),
    _F("instrument.roughness", "angle", "0.1 deg", low=0.0,
       help="Facet roughness (tilt angle) of the surface."),
]
del _F

FIELDS: dict[str, Field] = {f.key: f for f in SCHEMA}

_PHYSICAL_KEYS = ("compacity", "matrix", "inclusions")


def _children(prefix: str) -> list[Field]:
    """The rows directly under ``prefix`` (``""`` for the top level), in table order."""
    out = []
    for f in SCHEMA:
        if prefix == "":
            if "." not in f.key and "[" not in f.key:
                out.append(f)
        elif f.key.startswith(prefix + ".") and "." not in f.key[len(prefix) + 1:]:
            out.append(f)
    return out


def _canonical(field: Field, value):
    """A table default converted to the canonical unit."""
    if value is None or field.kind not in QUANTITY_KINDS:
        return copy.deepcopy(value)
    return parse_quantity(value, field.kind)


DEFAULTS = {f.key: _canonical(f, f.default) for f in SCHEMA if f.kind in SCALAR_KINDS}

# Keys a sweep may name: every scalar, whole inclusion lists, and whole media (a list of
# medium blocks: cases that differ in more than one key, such as the seed's BELA figure).
_SWEEPABLE = tuple(f.key for f in SCHEMA
                   if (f.kind in SCALAR_KINDS or f.kind == "list")
                   and not f.key.startswith(("materials", "sweep"))) + ("medium",)


# --------------------------------------------------------------------------- messages

def _number_text(x) -> str:
    if isinstance(x, float) and x.is_integer() and abs(x) < 1e16:
        return str(int(x))
    return repr(x) if isinstance(x, float) else str(x)


def _show(value) -> str:
    """A value as a user would recognise it from their YAML, on one line."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "an empty value"
    if isinstance(value, str):
        return value if value.strip() else '""'
    if isinstance(value, (int, float)):
        return _number_text(value)
    text = yaml.safe_dump(value, default_flow_style=True, allow_unicode=True, width=1e9)
    text = " ".join(text.split())
    return text if len(text) <= 60 else text[:57] + "..."


def _limit_text(x) -> str:
    """A limit of the table as written in messages; large powers of two also as 2^k."""
    if isinstance(x, int) and x >= 2 ** 20 and x & (x - 1) == 0:
        return f"2^{x.bit_length() - 1} = {x}"
    return _number_text(x)


def _range_text(field: Field) -> str:
    low, high = field.low, field.high
    unit = ""
    if field.kind in QUANTITY_KINDS and any(b not in (None, 0) for b in (low, high)):
        unit = " " + _CANONICAL_UNIT[field.kind]
    if low is not None and high is not None:
        return (f"in {'(' if field.low_open else '['}{_limit_text(low)}, "
                f"{_limit_text(high)}{')' if field.high_open else ']'}{unit}")
    if low is not None:
        return f"{'>' if field.low_open else '>='} {_limit_text(low)}{unit}"
    if high is not None:
        return f"{'<' if field.high_open else '<='} {_limit_text(high)}{unit}"
    return ""


def _with_unit(field: Field, value) -> str:
    """``value`` as the user wrote it, followed by what it counts (``1e+30 rays``)."""
    return _show(value) + (f" {field.unit}" if field.unit else "")


def _allowed(field: Field) -> str:
    """What a valid value of ``field`` looks like, e.g. 'a number in [0, 1]'."""
    rng = _range_text(field)
    rng = " " + rng if rng else ""
    if field.kind in QUANTITY_KINDS:
        article = "an" if field.kind == "angle" else "a"
        example = field.default if isinstance(field.default, str) else _EXAMPLE[field.kind]
        return f'{article} {field.kind}{rng} with a unit, e.g. "{example}"'
    if field.kind == "float":
        return f"a number{rng}"
    if field.kind == "int":
        return f"a whole number of {field.unit}{rng}" if field.unit else f"an integer{rng}"
    if field.kind == "choice":
        return "one of " + ", ".join(field.choices)
    if field.kind == "bool":
        return "true or false"
    if field.kind == "str":
        return "a text string"
    if field.kind == "list":
        return "a list of mappings"
    return "a mapping"


def _did_you_mean(word: str, candidates, cutoff: float = 0.6) -> str | None:
    match = difflib.get_close_matches(word, list(candidates), n=1, cutoff=cutoff)
    return match[0] if match else None


def _unknown_key(where: str, name: str, siblings: list[str], prefix: str) -> ConfigError:
    """'unknown key; did you mean ...?' for key ``name`` of the section at ``prefix``."""
    guess = _did_you_mean(name, siblings)
    if guess is not None:
        full = f"{prefix}.{guess}" if prefix else guess
        return ConfigError(f"unknown key; did you mean {full}?", where)
    # The right name in the wrong section (e.g. photons at the top level).
    elsewhere = [f.key for f in SCHEMA if f.key.rsplit(".", 1)[-1] == name]
    if elsewhere:
        return ConfigError(f"unknown key here; did you mean {elsewhere[0].replace('[]', '[0]')}?",
                           where)
    allowed = ", ".join(siblings)
    return ConfigError(f"unknown key; the keys allowed here are {allowed}", where)


# --------------------------------------------------------------------------- dotted keys

_INDEX = re.compile(r"\[(\d+)\]")


def _split(key: str) -> list:
    """``"medium.inclusions[0].grain_size"`` -> ``["medium", "inclusions", 0, "grain_size"]``.

    ``medium.inclusions.0.grain_size`` is read the same way. After ``sweep`` the rest of the
    key is one name (the swept key).
    """
    key = key.strip()
    if key.startswith("sweep.") and len(key) > len("sweep."):
        return ["sweep", key[len("sweep."):]]
    parts = []
    for part in _INDEX.sub(r".\1", key).split("."):
        parts.append(int(part) if part.isdigit() else part)
    return parts


def _display(parts) -> str:
    """The inverse of :func:`_split`, list indices written ``[i]``."""
    text = ""
    for p in parts:
        if isinstance(p, int):
            text += f"[{p}]"
        else:
            text += f".{p}" if text else str(p)
    return text


def _schema_key(parts) -> str:
    """Table key of a concrete path: indices become ``[]``, material names ``*``."""
    text = ""
    for i, p in enumerate(parts):
        if isinstance(p, int):
            text += "[]"
        else:
            name = "*" if (i == 1 and parts[0] == "materials") else str(p)
            text += f".{name}" if text else name
    return text


def _set_path(tree: dict, key: str, value) -> None:
    """Set dotted ``key`` in the nested ``tree``, creating mappings on the way."""
    parts = _split(key)
    if not parts or any(p == "" for p in parts):
        raise ConfigError("not a valid dotted key; write e.g. medium.thickness", key)
    node = tree
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        where = _display(parts[:depth + 1])
        if isinstance(part, int):
            if not isinstance(node, list):
                raise ConfigError(f"{_display(parts[:depth])} is not a list", where)
            if part >= len(node):
                raise ConfigError(f"no such item: the list has {len(node)} item(s)", where)
        elif not isinstance(node, dict):
            raise ConfigError(f"{_display(parts[:depth])} is not a mapping", where)
        if last:
            node[part] = value
        else:
            child = node[part] if (isinstance(node, list) or part in node) else None
            if child is None:
                child = {}
                node[part] = child
            node = child


def _get_path(tree, parts):
    """The value at ``parts`` in ``tree``, or raise KeyError."""
    node = tree
    for part in parts:
        if isinstance(part, int):
            if not isinstance(node, list) or part >= len(node):
                raise KeyError(part)
        elif not isinstance(node, dict) or part not in node:
            raise KeyError(part)
        node = node[part]
    return node


def _parse_overrides(overrides) -> dict:
    """``{key: value}`` from a dict or from ``["KEY=VALUE", ...]`` strings."""
    if overrides is None:
        return {}
    if isinstance(overrides, dict):
        for key in overrides:
            if not isinstance(key, str):
                raise ConfigError("override keys must be dotted strings such as "
                                  "medium.thickness", _show(key))
        return dict(overrides)
    if isinstance(overrides, str):
        overrides = [overrides]
    out = {}
    for item in overrides:
        if not isinstance(item, str) or "=" not in item:
            raise ConfigError('an override is written KEY=VALUE, e.g. '
                              'medium.thickness="100 mm"', _show(item))
        key, text = item.split("=", 1)
        key = key.strip()
        try:
            value = yaml.safe_load(text) if text.strip() else None
        except yaml.YAMLError:
            value = text.strip()  # e.g. "a: b: c": take the text as it is
        out[key] = value
    return out


# --------------------------------------------------------------------------- YAML reading

class _Loader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys instead of silently keeping the last."""


def _construct_mapping(loader, node, deep=False):
    loader.flatten_mapping(node)
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            duplicate = key in seen
            seen.add(key)
        except TypeError:  # unhashable key: let SafeLoader report it
            break
        if duplicate:
            raise yaml.constructor.ConstructorError(
                None, None, f'the key "{key}" is given twice', key_node.start_mark)
    return loader.construct_mapping(node, deep=deep)


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)

_NEEDS = "a preset needs at least medium.texture and medium.thickness"


def _read_yaml(path: str):
    """The YAML document in ``path``; file-level problems become ConfigErrors."""
    if not os.path.exists(path):
        raise ConfigError("no such file", source=path)
    if os.path.isdir(path):
        raise ConfigError("is a folder, not a preset file", source=path)
    try:
        with open(path, encoding="utf-8") as stream:
            text = stream.read()
    except UnicodeDecodeError:
        raise ConfigError("not UTF-8 text; a preset is a YAML text file", source=path) from None
    except OSError as exc:
        raise ConfigError(f"cannot be read ({exc.strerror})", source=path) from None
    try:
        document = yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        raise ConfigError(f"not valid YAML ({where}{problem})", source=path) from None
    if document is None:
        raise ConfigError(f"the file is empty; {_NEEDS}", source=path)
    return document


# --------------------------------------------------------------------------- validation

def _number(field: Field, value, where: str) -> float:
    """A finite float from a YAML number or a numeric string ("1e6")."""
    if isinstance(value, bool):
        raise ConfigError(f"{_show(value)} is a boolean (YAML reads yes/no/on/off as "
                          f"booleans), not a number; give {_allowed(field)}", where)
    if isinstance(value, (int, float, np.integer, np.floating)):
        x = value
    elif isinstance(value, str):
        try:
            x = float(value.strip().replace("_", ""))
        except ValueError:
            raise ConfigError(f"{_show(value)} is not a number; give {_allowed(field)}",
                              where) from None
    else:
        raise ConfigError(f"{_show(value)} is not a number; give {_allowed(field)}", where)
    if not math.isfinite(x):
        raise ConfigError(f"{_show(value)} is not a finite number; give {_allowed(field)}",
                          where)
    return x


def _integer(field: Field, value, where: str) -> int:
    """An int from 3, 1e6, 1.0e6 or "1e6"; refuses 2.5."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return int(value)
    if isinstance(value, str) and value.strip().lstrip("+-").isdigit():
        return int(value)
    x = _number(field, value, where)
    if not float(x).is_integer():
        raise ConfigError(f"{_with_unit(field, value)} is not a whole number; give "
                          f"{_allowed(field)}", where)
    return int(x)


def _in_range(field: Field, x) -> bool:
    if field.low is not None and (x < field.low or (field.low_open and x == field.low)):
        return False
    if field.high is not None and (x > field.high or (field.high_open and x == field.high)):
        return False
    return True


def _scalar(field: Field, value, where: str):
    """Validate one scalar value of ``field`` and return it in the canonical unit."""
    kind = field.kind
    if kind in QUANTITY_KINDS:
        try:
            x = parse_quantity(value, kind)
        except UnitError as exc:
            raise ConfigError(f"{exc.problem}; give {_allowed(field)} "
                              f"(units: {unit_list(kind)})", where) from None
    elif kind == "float":
        x = float(_number(field, value, where))  # plain float, also from numpy
    elif kind == "int":
        x = _integer(field, value, where)
    elif kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{_show(value)} is not allowed; give true or false", where)
        return value
    elif kind == "str":
        if not isinstance(value, str) or (not value.strip() and field.default != ""):
            raise ConfigError(f"{_show(value)} is not allowed; give {_allowed(field)}"
                              + (' (quote it: "...")' if isinstance(value, (int, float))
                                 else ""), where)
        return value
    elif kind == "choice":
        if isinstance(value, str) and value.strip().lower() in field.choices:
            return value.strip().lower()
        guess = _did_you_mean(str(value).lower(), field.choices) if isinstance(value, str) \
            else None
        hint = f" (did you mean {guess}?)" if guess else ""
        raise ConfigError(f"{_show(value)} is not allowed; give {_allowed(field)}{hint}", where)
    else:  # pragma: no cover - table error
        raise TypeError(f"{field.key}: {kind} is not a scalar kind")
    if not _in_range(field, x):
        raise ConfigError(f"{_with_unit(field, value)} is not allowed; give {_allowed(field)}",
                          where)
    return x


class _Validator:
    """One pass over a raw preset, producing the canonical nested dict."""

    def __init__(self, name_default: str, base_dir: str | None):
        self.name_default = name_default
        self.base_dir = base_dir

    # generic pieces -------------------------------------------------------------------
    def mapping(self, value, prefix: str, where: str, open_: bool = False) -> dict:
        """Check that ``value`` is a mapping whose keys are rows under ``prefix``."""
        if not isinstance(value, dict):
            names = ", ".join(f.key.rsplit(".", 1)[-1] for f in _children(prefix))
            raise ConfigError(f"{_show(value)} is not a mapping; give a mapping with keys "
                              f"among {names}", where)
        siblings = [f.key.rsplit(".", 1)[-1] for f in _children(prefix)]
        for key in value:
            if not isinstance(key, str):
                raise ConfigError("keys must be text", f"{where}.{_show(key)}" if where
                                  else _show(key))
            if key not in siblings and not open_:
                display = f"{where}.{key}" if where else key
                raise _unknown_key(display, key, siblings, where)
        return value

    def value(self, field: Field, raw: dict, name: str, where: str):
        """The canonical value of child ``name`` of ``raw`` described by ``field``."""
        given = raw.get(name)
        if given is None:
            if field.required:
                raise ConfigError(f"missing; give {_allowed(field)}", where)
            if field.kind in SCALAR_KINDS:
                return copy.deepcopy(DEFAULTS[field.key])
            if field.default is None:
                return None
            given = copy.deepcopy(field.default)
        if field.kind in SCALAR_KINDS:
            return _scalar(field, given, where)
        handler = getattr(self, "kind_" + field.kind)
        return handler(field, given, where)

    def section(self, raw, prefix: str, where: str, skip=(), open_=False) -> dict:
        raw = self.mapping(raw, prefix, where, open_)
        out = {}
        for field in _children(prefix):
            name = field.key.rsplit(".", 1)[-1]
            if name in skip:
                continue
            sub = f"{where}.{name}" if where else name
            out[name] = self.value(field, raw, name, sub)
        if open_:
            known = {f.key.rsplit(".", 1)[-1] for f in _children(prefix)}
            out.update({k: copy.deepcopy(v) for k, v in raw.items() if k not in known})
        return out

    # structured kinds -----------------------------------------------------------------
    def kind_section(self, field, given, where):
        return self.section(given, field.key, where)

    def kind_open_section(self, field, given, where):
        return self.section(given, field.key, where, open_=True)

    def kind_list(self, field, given, where):
        if not isinstance(given, list) or not given:
            raise ConfigError(f"{_show(given)} is not allowed; give a non-empty list of "
                              f"mappings, e.g. [{{material: CO2, proportion: 1.0, "
                              f"grain_size: \"100 um\"}}]", where)
        return [self.section(item, field.key + "[]", f"{where}[{i}]")
                for i, item in enumerate(given)]

    def kind_names(self, field, given, where):
        """``materials``: NAME -> {n, k} or {table}."""
        if not isinstance(given, dict):
            raise ConfigError(f"{_show(given)} is not a mapping; give NAME: {{n: ..., k: ...}}"
                              f" or NAME: {{table: FILE}}", where)
        out, seen = {}, {}
        for name, entry in given.items():
            sub = f"{where}.{name}"
            if not isinstance(name, str) or not name.strip():
                raise ConfigError("material names must be text", f"{where}.{_show(name)}")
            if name.lower() in seen:
                raise ConfigError(f"defined twice (also as {seen[name.lower()]}); names are "
                                  f"case-insensitive", sub)
            seen[name.lower()] = name
            prefix = field.key + ".*"
            entry = self.mapping(entry, prefix, sub)
            if entry.get("table") is not None:
                extra = [k for k in ("n", "k") if entry.get(k) is not None]
                if extra:
                    raise ConfigError("given together with table; give either n and k, or "
                                      "table", f"{sub}.{extra[0]}")
                path = _scalar(FIELDS[prefix + ".table"], entry["table"], f"{sub}.table")
                out[name] = {"table": self.table_path(path, f"{sub}.table")}
            else:
                if entry.get("n") is None:
                    raise ConfigError("missing; give the optical constants {n: ..., k: ...} "
                                      "or {table: FILE}", f"{sub}.n")
                out[name] = self.section(entry, prefix, sub, skip=("table",))
        return out

    def table_path(self, path: str, where: str) -> str:
        full = path
        if not os.path.isabs(path) and self.base_dir is not None:
            full = os.path.join(self.base_dir, path)
        if not os.path.isfile(full):
            raise ConfigError(f"{path}: no such file (a relative path is read from the "
                              f"preset's folder)", where)
        return full

    def kind_time_bins(self, field, given, where):
        raw = self.mapping(given, field.key, where)
        rows = {f.key.rsplit(".", 1)[-1]: f for f in _children(field.key)}
        get = {k: raw.get(k) for k in rows}
        if get["per_decade"] is not None and get["width"] is not None:
            raise ConfigError("per_decade and width are both given; give per_decade for "
                              "log-spaced bins or width for linear bins, not both", where)
        linear = get["width"] is not None
        out = {}
        start_field = rows["start"]
        if get["start"] is None:
            out["start"] = 0.0 if linear else DEFAULTS[start_field.key]
        else:
            out["start"] = _scalar(start_field, get["start"], f"{where}.start")
        if not linear and out["start"] <= 0:
            raise ConfigError(f"{_show(get['start'])} is not allowed; log-spaced bins need "
                              f'a time > 0 with a unit, e.g. "1e-6 ns"', f"{where}.start")
        if linear and get["stop"] is None:
            raise ConfigError('missing; linear bins (width) need a stop time, e.g. "200 ns"',
                              f"{where}.stop")
        out["stop"] = self.value(rows["stop"], raw, "stop", f"{where}.stop")
        if out["stop"] <= out["start"]:
            shown = get["stop"] if get["stop"] is not None else rows["stop"].default
            raise ConfigError(f"{_show(shown)} is not allowed; give a time > start "
                              f"({format_quantity(out['start'], 'time')})", f"{where}.stop")
        if linear:
            out["width"] = _scalar(rows["width"], get["width"], f"{where}.width")
            count = math.ceil((out["stop"] - out["start"]) / out["width"] - 1e-9)
        else:
            out["per_decade"] = self.value(rows["per_decade"], raw, "per_decade",
                                           f"{where}.per_decade")
            count = math.ceil(out["per_decade"] * math.log10(out["stop"] / out["start"])
                              - 1e-9)
        if count > MAX_TIME_BINS:
            raise ConfigError(f"these bins number {count}; at most {MAX_TIME_BINS} are "
                              f"allowed (widen the bins or shorten the range)", where)
        return out

    def kind_sweep(self, field, given, where):
        if not isinstance(given, dict):
            raise ConfigError(f"{_show(given)} is not a mapping; give KEY: [VALUE, ...], "
                              f'e.g. medium.thickness: ["1 mm", "10 mm"]', where)
        out = {}
        for key, values in given.items():
            sub = f"{where}.{key}"
            target = _sweep_field(key, sub)
            if not isinstance(values, list) or not values:
                raise ConfigError(f"{_show(values)} is not allowed; give a non-empty list of "
                                  f"values, each {_allowed(target)}", sub)
            if target.key == "medium":
                out[key] = [self.kind_medium(v, sub) for v in values]
                continue
            out[key] = [self.value(target, {"v": v}, "v", sub) if v is not None else
                        _raise_empty(target, sub) for v in values]
        return out

    # the medium -----------------------------------------------------------------------
    def kind_medium(self, given, where="medium"):
        raw = self.mapping(given, "medium", where)
        out = self.section(raw, "medium", where, skip=("radiative",) + _PHYSICAL_KEYS)
        physical = [k for k in _PHYSICAL_KEYS if raw.get(k) is not None]
        radiative = raw.get("radiative") is not None
        if radiative and physical:
            raise ConfigError(f"given together with medium.{physical[0]}; describe the medium "
                              f"either radiatively (medium.radiative) or physically "
                              f"(medium.compacity, medium.inclusions and, for a slab, "
                              f"medium.matrix), not both", "medium.radiative")
        if not radiative and not physical:
            raise ConfigError("no composition given; give either medium.radiative: "
                              "{tau0, omega, n} or the physical form medium.compacity and "
                              "medium.inclusions (plus medium.matrix for a slab)", where)
        out["radiative"] = (self.value(FIELDS["medium.radiative"], raw, "radiative",
                                       "medium.radiative") if radiative else None)
        for name in _PHYSICAL_KEYS:
            out[name] = None
        if physical:
            slab = out["texture"] == "slab"
            if not slab and raw.get("matrix") is not None:
                raise ConfigError(f"{_show(raw['matrix'])} is not allowed for a granular "
                                  f"medium, whose grains are the inclusions and whose pores "
                                  f"are void; remove medium.matrix", "medium.matrix")
            for name in _PHYSICAL_KEYS:
                field = FIELDS[f"medium.{name}"]
                if raw.get(name) is None and (name != "matrix" or slab):
                    need = ("give the slab's matrix material, e.g. H2O" if name == "matrix"
                            else f"the physical form needs it: give {_allowed(field)}")
                    raise ConfigError(f"missing; {need}", f"medium.{name}")
                out[name] = self.value(field, raw, name, f"medium.{name}")
        return out

    # the whole preset -------------------------------------------------------------------
    def preset(self, raw) -> dict:
        if not isinstance(raw, dict):
            kind = "a list" if isinstance(raw, list) else f"the single value {_show(raw)}"
            raise ConfigError(f"the top level is {kind}; a preset must be a mapping of keys "
                              f"(medium:, simulation:, ...) with at least medium.texture and "
                              f"medium.thickness")
        if not raw:
            raise ConfigError(f"the preset is empty; {_NEEDS}")
        self.mapping(raw, "", "")
        sweep = self.value(FIELDS["sweep"], raw, "sweep", "sweep")  # first: it fills gaps
        if raw.get("medium") is None:
            raise ConfigError(f"missing; {_NEEDS}", "medium")
        out = {}
        for field in _children(""):
            if field.key == "sweep":
                out["sweep"] = sweep
            elif field.key == "medium":
                out["medium"] = self.kind_medium(raw["medium"])
            elif field.key == "name" and raw.get("name") is None:
                out["name"] = self.name_default
            else:
                out[field.key] = self.value(field, raw, field.key, field.key)
        sim = out["simulation"]
        if sim["max_time"] is None:
            sim["max_time"] = float(_edges(sim["time_bins"])[-1])
        return out


def _raise_empty(field: Field, where: str):
    raise ConfigError(f"an empty value is not allowed; give {_allowed(field)}", where)


def _sweep_field(key, where: str) -> Field:
    """The schema row a sweep key refers to (``medium.inclusions[0].grain_size`` ...)."""
    if not isinstance(key, str):
        raise ConfigError("sweep keys must be dotted keys such as medium.thickness", where)
    skey = _schema_key(_split(key))
    if skey in _SWEEPABLE:
        return FIELDS[skey]
    candidates = [k.replace("[]", "[0]") for k in _SWEEPABLE]
    guess = _did_you_mean(key, candidates)
    hint = f"did you mean {guess}?" if guess else "give a dotted key of the schema, e.g. " \
                                                   "medium.thickness"
    raise ConfigError(f"unknown key; {hint}", where)


# --------------------------------------------------------------------------- time bins

def _edges(bins: dict) -> np.ndarray:
    if "width" in bins:
        count = math.ceil((bins["stop"] - bins["start"]) / bins["width"] - 1e-9)
        return bins["start"] + bins["width"] * np.arange(0, count + 1, dtype=float)
    count = math.ceil(bins["per_decade"] * math.log10(bins["stop"] / bins["start"]) - 1e-9)
    return bins["start"] * 10.0 ** (np.arange(0, count + 1, dtype=float) / bins["per_decade"])


def time_edges(cfg) -> np.ndarray:
    """Time-bin edges of a configuration, ns.

    Parameters
    ----------
    cfg : Config or dict
        A configuration, or its canonical ``simulation.time_bins`` mapping.

    Returns
    -------
    numpy.ndarray of float64
        Increasing edges, ns. Log-spaced bins: ``start * 10**(i / per_decade)`` for
        ``i = 0 .. n`` with ``n = ceil(per_decade * log10(stop / start))``; linear bins:
        ``start + width * i`` for ``i = 0 .. ceil((stop - start) / width)``. The last edge
        is at or just after ``stop``.

    Examples
    --------
    >>> edges = time_edges({"start": 1.0, "stop": 100.0, "per_decade": 2})
    >>> edges.round(3).tolist()
    [1.0, 3.162, 10.0, 31.623, 100.0]
    """
    bins = cfg.data["simulation"]["time_bins"] if isinstance(cfg, Config) else cfg
    return _edges(bins)


# --------------------------------------------------------------------------- Config

class Config:
    """A validated preset.

    Build one with :func:`load_preset`. The constructor validates ``raw`` and raises
    :class:`~warpe_cl.errors.ConfigError` on the first problem.

    Attributes
    ----------
    source : str
        The preset's path as given, or ``"<dict>"``.
    raw : dict
        The nested mapping as written, overrides applied (a private copy).
    data : dict
        The same with every default filled in and every quantity converted to the
        canonical unit: lengths in m, times in ns, angles in degrees. Absent optional
        parts (``medium.radiative`` in the physical form, ``instrument.name``) are None.
    """

    def __init__(self, raw: dict, source: str = "<dict>", *, name_default: str = "unnamed",
                 base_dir: str | None = None):
        self.source = source
        self.raw = raw
        self._name_default = name_default
        self._base_dir = base_dir
        try:
            self.data = _Validator(name_default, base_dir).preset(self._with_swept_defaults())
        except ConfigError as exc:
            raise exc.with_source(source) from None

    def _with_swept_defaults(self):
        """``raw``, where a key missing from the base but swept takes its first value."""
        sweep = self.raw.get("sweep") if isinstance(self.raw, dict) else None
        if not isinstance(sweep, dict) or not sweep:
            return self.raw
        work = copy.deepcopy(self.raw)
        for key, values in sweep.items():
            if (not isinstance(key, str) or not isinstance(values, list) or not values
                    or _schema_key(_split(key)) not in _SWEEPABLE):
                continue  # reported by the sweep validation
            try:
                _get_path(work, _split(key))
            except KeyError:
                try:
                    _set_path(work, key, copy.deepcopy(values[0]))
                except ConfigError:
                    pass  # e.g. an index into a missing list: reported later
        return work

    def __repr__(self) -> str:
        return f"Config(name={self.data['name']!r}, source={self.source!r})"

    @property
    def name(self) -> str:
        """The scenario name (``name`` key, default: the file stem)."""
        return self.data["name"]

    @property
    def is_radiative(self) -> bool:
        """True when the medium is given in radiative form (``medium.radiative``)."""
        return self.data["medium"]["radiative"] is not None

    def get(self, key: str):
        """The canonical value at dotted ``key`` (m, ns, deg).

        Known keys that are absent (``medium.radiative.tau0`` in the physical form, a
        material's ``k``) give the table default, or None when there is none. Mappings and
        lists are returned as copies. An unknown key raises KeyError with a hint.

        Examples: ``cfg.get("medium.thickness")``, ``cfg.get("simulation.fov.scattering")``,
        ``cfg.get("medium.inclusions[0].grain_size")``.
        """
        parts = _split(key)
        try:
            value = _get_path(self.data, parts)
            if value is not None:
                return copy.deepcopy(value)
        except KeyError:
            pass
        skey = _schema_key(parts)
        if skey in FIELDS:
            return copy.deepcopy(DEFAULTS.get(skey))
        if parts and parts[0] == "sweep":
            return None
        if parts and parts[0] == "instrument" and len(parts) == 2:
            return None  # pass-through instrument keys
        guess = _did_you_mean(key, [k.replace("[]", "[0]") for k in FIELDS])
        raise KeyError(f"{key}: unknown key" + (f"; did you mean {guess}?" if guess else ""))

    def with_overrides(self, overrides) -> "Config":
        """A new Config with ``overrides`` (dict or ``"KEY=VALUE"`` strings) applied."""
        raw = copy.deepcopy(self.raw)
        try:
            _apply_overrides(raw, _parse_overrides(overrides))
        except ConfigError as exc:
            raise exc.with_source(self.source) from None
        return Config(raw, self.source, name_default=self._name_default,
                      base_dir=self._base_dir)

    def sweep_points(self) -> list:
        """The scenarios of the ``sweep`` block, outer product in the order keys appear.

        Returns
        -------
        list of (dict, Config)
            For each point, the swept values as written in the preset (``{"medium.thickness":
            "10 mm"}``) and the validated configuration of that point (no ``sweep`` block).
            A configuration without a sweep gives ``[({}, self)]``.
        """
        sweep = self.raw.get("sweep") or {}
        if not sweep:
            return [({}, self)]
        base = {k: v for k, v in self.raw.items() if k != "sweep"}
        keys = list(sweep)
        points = []
        for combo in itertools.product(*(sweep[k] for k in keys)):
            point = dict(zip(keys, combo))
            raw = copy.deepcopy(base)
            try:
                _apply_overrides(raw, copy.deepcopy(point))
                cfg = Config(raw, self.source, name_default=self._name_default,
                             base_dir=self._base_dir)
            except ConfigError as exc:
                where = ", ".join(f"{k}={_show(v)}" for k, v in point.items())
                raise ConfigError(f"{exc.message} (in the sweep point {where})", exc.key,
                                  self.source) from None
            points.append((point, cfg))
        return points

    def to_yaml(self) -> str:
        """The resolved configuration as YAML text, quantities written with units.

        ``load_preset(yaml.safe_load(cfg.to_yaml())).data == cfg.data``.
        """
        body = _export(self.data, "")
        text = yaml.safe_dump(body, sort_keys=False, allow_unicode=True,
                              default_flow_style=False, width=100)
        return f"# warpe-cl resolved configuration of {self.source}\n{text}"


def _apply_overrides(raw: dict, overrides: dict) -> None:
    for key, value in overrides.items():
        _set_path(raw, key, value)


def _export(value, skey: str):
    """Canonical data -> YAML-ready data (quantities as strings); None entries dropped."""
    if isinstance(value, dict):
        out = {}
        for name, item in value.items():
            if item is None:
                continue
            if skey == "sweep":
                target = _schema_key(_split(name))
                out[name] = [_export(v, target) for v in item]
                continue
            if skey == "materials":
                child = "materials.*"
            else:
                child = f"{skey}.{name}" if skey else name
            out[name] = _export(item, child)
        return out
    if isinstance(value, list):
        return [_export(v, skey + "[]") for v in value]
    field = FIELDS.get(skey)
    if field is not None and field.kind in QUANTITY_KINDS:
        return format_quantity(value, field.kind)
    return value


def _read_source(source) -> tuple:
    """A preset given as a dict or a YAML path: (name, raw mapping, base folder for relative
    paths or None, default preset name)."""
    if isinstance(source, dict):
        return "<dict>", copy.deepcopy(source), None, "unnamed"
    if isinstance(source, (str, os.PathLike)):
        name = os.fspath(source)
        return (name, _read_yaml(name), os.path.dirname(os.path.abspath(name)),
                os.path.splitext(os.path.basename(name))[0])
    raise ConfigError(f"a preset is a YAML file path or a dict, not {type(source).__name__}")


def load_preset(source, overrides=None) -> Config:
    """Load, complete and validate a preset.

    Parameters
    ----------
    source : str, os.PathLike, dict or Config
        Path to a YAML preset, or a dict of the same shape (``name`` then defaults to
        ``"unnamed"``), or an existing Config (overrides are applied to its ``raw``).
    overrides : dict or list of str, optional
        ``{"simulation.photons": 1e5}`` or ``["simulation.photons=1e5",
        'medium.thickness="100 mm"']``; values of ``KEY=VALUE`` strings are read as YAML.
        Dotted keys address list items as ``medium.inclusions[0].grain_size`` and sweeps as
        ``sweep.medium.thickness``.

    Returns
    -------
    Config

    Raises
    ------
    ConfigError
        One line naming the file, the key, the value and what is allowed.
    """
    if isinstance(source, Config):
        return source.with_overrides(overrides)
    name, raw, base_dir, name_default = _read_source(source)
    if overrides and isinstance(raw, dict):  # a non-mapping is reported by Config
        try:
            _apply_overrides(raw, _parse_overrides(overrides))
        except ConfigError as exc:
            raise exc.with_source(name) from None
    return Config(raw, name, name_default=name_default, base_dir=base_dir)



# --------------------------------------------------------------------------- sweep grids

@dataclass
class Grid:
    """A preset's sweep grid with every point validated on its own (``warpe-cl sweep``).

    Attributes
    ----------
    source : str
        The preset's path as given, or ``"<dict>"``.
    raw : dict
        The preset as written, overrides applied and list overrides turned into sweep axes.
    keys : list of str
        The swept keys, in the order of the outer product (empty without a sweep).
    points : list of (dict, Config or ConfigError)
        For each point of the outer product (the order of :meth:`Config.sweep_points`), the
        swept values as written and that point's validated configuration, or the one-line
        error that rejects it.
    """

    source: str
    raw: dict
    keys: list
    points: list

    def to_yaml(self) -> str:
        """The resolved preset (with its sweep block) when every point is valid, else the
        preset as written (overrides applied)."""
        try:
            return Config(copy.deepcopy(self.raw), self.source).to_yaml()
        except ConfigError:
            text = yaml.safe_dump(self.raw, sort_keys=False, allow_unicode=True, width=100)
            return f"# warpe-cl preset {self.source} as written (a sweep point is invalid)\n{text}"


def load_grid(source, overrides=None) -> Grid:
    """Load a preset as a grid of independent points, for a resumable sweep.

    Unlike :func:`load_preset`, a value that rejects one point (a compacity of 1.2) does not
    reject the preset: that point carries its :class:`ConfigError`, the others stand. Each
    valid point's Config is built exactly as :meth:`Config.sweep_points` builds it, so it
    gives the same scenario (and the same bits) as ``warpe-cl run``.

    Parameters
    ----------
    source : str, os.PathLike or dict
        A YAML preset or a dict of the same shape.
    overrides : dict or list of str, optional
        As for :func:`load_preset`. An override whose value is a list, on a key that a sweep
        may name and that is not itself a list (``medium.thickness=["1 mm", "10 mm"]``),
        becomes a sweep axis: it replaces a swept key of the same name, or is added after
        the preset's own.

    Raises
    ------
    ConfigError
        For what no point can survive: an unreadable file, a malformed sweep block, an
        unknown sweep key; or, without a sweep, the single point's error.
    """
    name, raw, base_dir, name_default = _read_source(source)
    if not isinstance(raw, dict):
        Config(raw, name, name_default=name_default, base_dir=base_dir)  # raises its message
    try:
        axes = {}
        plain = {}
        for key, value in _parse_overrides(overrides).items():
            skey = _schema_key(_split(key))
            if (isinstance(value, list) and skey in _SWEEPABLE
                    and (skey == "medium" or FIELDS[skey].kind in SCALAR_KINDS)):
                axes[key] = value
            else:
                plain[key] = value
        _apply_overrides(raw, plain)
        if axes:
            sweep = raw.get("sweep") if isinstance(raw.get("sweep"), dict) else {}
            raw["sweep"] = {**{k: v for k, v in sweep.items() if k not in axes}, **axes}
        sweep = raw.get("sweep") or {}
        if not isinstance(sweep, dict):
            raise ConfigError(f"{_show(sweep)} is not a mapping; give KEY: [VALUE, ...], "
                              f'e.g. medium.thickness: ["1 mm", "10 mm"]', "sweep")
        for key, values in sweep.items():
            target = _sweep_field(key, f"sweep.{key}")
            if not isinstance(values, list) or not values:
                raise ConfigError(f"{_show(values)} is not allowed; give a non-empty list of "
                                  f"values, each {_allowed(target)}", f"sweep.{key}")
    except ConfigError as exc:
        raise exc.with_source(name) from None
    base = {k: v for k, v in raw.items() if k != "sweep"}
    keys = list(sweep)
    points = []
    for combo in itertools.product(*(sweep[k] for k in keys)):
        point = dict(zip(keys, combo))
        point_raw = copy.deepcopy(base)
        try:
            _apply_overrides(point_raw, copy.deepcopy(point))
            cfg = Config(point_raw, name, name_default=name_default, base_dir=base_dir)
        except ConfigError as exc:
            if not keys:
                raise
            where = ", ".join(f"{k}={_show(v)}" for k, v in point.items())
            cfg = ConfigError(f"{exc.message} (in the sweep point {where})", exc.key, name)
        points.append((point, cfg))
    return Grid(name, raw, keys, points)


# --------------------------------------------------------------------------- docs

def schema_markdown() -> str:
    """The schema as a markdown table: key, kind and unit, default, allowed values, help."""
    kind_text = {"length": "length (m)", "time": "time (ns)", "angle": "angle (deg)",
                 "float": "number", "int": "integer", "str": "text", "choice": "choice",
                 "bool": "boolean", "section": "mapping", "open_section": "mapping",
                 "list": "list", "names": "mapping of names", "time_bins": "mapping",
                 "sweep": "mapping of lists"}
    lines = ["| key | kind (stored unit) | default | allowed | description |",
             "| --- | --- | --- | --- | --- |"]
    for f in SCHEMA:
        if f.required:
            default = "required"
        elif f.default is None or f.default == {} or f.default == "":
            default = "—" if f.default != "" else '`""`'
        else:
            default = f"`{f.default}`"
        if f.kind in SCALAR_KINDS and f.kind != "str":
            allowed = _allowed(f)
            if f.kind in QUANTITY_KINDS:
                allowed = allowed.split(" with a unit")[0] + f" ({unit_list(f.kind)})"
        else:
            allowed = ""
        kind = kind_text[f.kind] + (f" ({f.unit})" if f.unit else "")
        cells = [f"`{f.key}`", kind, default, allowed, f.help]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines) + "\n"


REFERENCE_PATH = "docs/config.md"


def reference_markdown() -> str:
    """The whole of docs/config.md: a title, how it is made, and :func:`schema_markdown`.

    ``python tools/config_docs.py`` writes it; tests/test_config.py fails when the file in
    the repository differs from it (the table was changed and the file not regenerated).
    """
    return ("# Preset reference\n\n"
            "Generated from the schema table in `warpe_cl/config.py` by "
            "`python tools/config_docs.py` (do not edit by hand; a test fails when this file "
            "is out of date). Lengths are stored in metres, times in nanoseconds, angles in "
            "degrees.\n\n" + schema_markdown())
