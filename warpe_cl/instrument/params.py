"""Instrument presets: the parameter table, units, loading and validation.

An instrument preset (``presets/instruments/bela.yaml``) is a YAML mapping of sections; every
dimensioned value is a string with a unit, as in scenario presets. Lengths, times and angles use
:mod:`warpe_cl.units`; the other dimensions the chain needs (energy, voltage, current, current
noise density, frequency, resistance, irradiance, astronomical distance) are read here.

Canonical units inside the chain: m, ns, deg (as :mod:`warpe_cl.units`), J, V, A, A/√Hz, Hz,
ohm, W m⁻² nm⁻¹, AU.

>>> p = load_instrument("bela")
>>> p["transmitter.pulse_energy"]
0.05
>>> p["adc.sampling_interval"]
12.5
"""
from __future__ import annotations

import copy
import difflib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ConfigError
from ..units import UnitError, format_quantity, parse_quantity

# ----------------------------------------------------------------------------- units

#: Extra dimensions: unit -> factor to the canonical unit (first entry).
EXTRA_UNITS: dict[str, dict[str, float]] = {
    "energy": {"J": 1.0, "mJ": 1e-3, "uJ": 1e-6, "µJ": 1e-6, "nJ": 1e-9},
    "voltage": {"V": 1.0, "mV": 1e-3, "uV": 1e-6, "µV": 1e-6},
    "current": {"A": 1.0, "mA": 1e-3, "uA": 1e-6, "µA": 1e-6, "nA": 1e-9, "pA": 1e-12},
    "current_noise": {"A/rtHz": 1.0, "nA/rtHz": 1e-9, "pA/rtHz": 1e-12, "fA/rtHz": 1e-15},
    "frequency": {"Hz": 1.0, "kHz": 1e3, "MHz": 1e6, "GHz": 1e9},
    "resistance": {"ohm": 1.0, "kohm": 1e3, "Mohm": 1e6},
    "irradiance": {"W/m2/nm": 1.0},
    "distance": {"AU": 1.0},
}
_NUMBER = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"
_QUANTITY = re.compile(rf"^\s*({_NUMBER})\s*(.*?)\s*$")


def parse_value(text, dimension: str) -> float:
    """A quantity string in the canonical unit of ``dimension``.

    Parameters
    ----------
    text : str
        E.g. ``"50 mJ"``, ``"2 pA/rtHz"``, ``"500 km"``.
    dimension : str
        ``length``, ``time``, ``angle`` (:mod:`warpe_cl.units`) or a key of :data:`EXTRA_UNITS`.

    Raises
    ------
    ValueError
        With a one-line message naming the value and the accepted units.
    """
    if dimension not in EXTRA_UNITS:
        return parse_quantity(text, dimension)
    units = EXTRA_UNITS[dimension]
    allowed = ", ".join(units)
    if not isinstance(text, str) or isinstance(text, bool):
        raise ValueError(f"{text!r} has no unit; give a {dimension} with a unit ({allowed})")
    match = _QUANTITY.match(text)
    if match is None or match.group(2) not in units:
        raise ValueError(f'"{text}" is not a {dimension}; give a number and a unit ({allowed})')
    value = float(match.group(1)) * units[match.group(2)]
    if not math.isfinite(value):
        raise ValueError(f'"{text}" is not finite')
    return value


def format_value(value: float, dimension: str) -> str:
    """The canonical value as a string with its canonical unit (for attributes)."""
    if dimension == "angle" and 0 < abs(value) < 0.01:
        return f"{math.radians(value) * 1e6:.6g} urad"
    if dimension in ("length", "time", "angle"):
        return format_quantity(value, dimension)
    return f"{value:.6g} {next(iter(EXTRA_UNITS[dimension]))}"


# ----------------------------------------------------------------------------- schema

@dataclass(frozen=True)
class Param:
    """One instrument parameter: dotted key, kind, default (None: required or absent), limits."""
    key: str
    kind: str                    # a dimension name, "number", "int", "choice", "str", "modes"
    default: object = None
    low: float | None = None
    high: float | None = None
    low_open: bool = False       # True: the value must be > low
    choices: tuple = ()
    required: bool = False
    help: str = ""


def _P(*a, **k):
    return Param(*a, **k)


#: Every parameter of the chain (instruments.md §3), canonical defaults.
SCHEMA: list[Param] = [
    _P("name", "str", required=True, help="instrument name"),
    _P("description", "str", "", help="free text"),
    _P("wavelength", "length", required=True, low=0.0, low_open=True,
       help="laser wavelength; the surface response must have been computed at it"),
    _P("shots", "int", 100, low=1, high=1_000_000, help="shots simulated"),
    _P("seed", "int", None, low=0, high=2**63 - 1,
       help="noise seed (default: the surface file's seed)"),
    # §3.1 transmitter
    _P("transmitter.pulse_energy", "energy", required=True, low=0.0, low_open=True, help="E_t"),
    _P("transmitter.repetition_rate", "frequency", 10.0, low=0.0, help="informative only"),
    _P("transmitter.pulse_fwhm", "time", 6.5, low=0.0, help="Gaussian pulse FWHM"),
    _P("transmitter.pulse_fwhm_jitter", "time", 0.0, low=0.0, help="per-shot rms of the FWHM"),
    _P("transmitter.pulse_shape", "str", "gaussian",
       help="gaussian, or a CSV file with columns time_ns, power (origin: its centroid)"),
    _P("transmitter.divergence", "angle", required=True, low=0.0, low_open=True,
       help="full-cone divergence, read as the 1/e² full angle: beam half-angle δ = half of it, "
            "σ_θ = a quarter"),
    _P("transmitter.efficiency", "number", 0.9, low=0.0, high=1.0, help="η_t"),
    # receiver
    _P("receiver.aperture", "length", required=True, low=0.0, low_open=True, help="telescope diameter D_r"),
    _P("receiver.fov", "angle", 530e-6 * 180 / math.pi, low=0.0, low_open=True, help="full-cone field of view"),
    _P("receiver.efficiency", "number", 0.5, low=0.0, high=1.0, help="η_r, optics and filter"),
    _P("receiver.filter_width", "length", 2e-9, low=0.0, help="optical filter width Δλ"),
    # §3.2, §3.4 geometry
    _P("geometry.altitude", "length", 500e3, low=0.0, low_open=True, help="spacecraft altitude H"),
    _P("geometry.pointing", "angle", 0.0, low=-89.0, high=89.0, help="off-nadir pointing φ"),
    _P("geometry.slope", "angle", 0.0, low=-89.0, high=89.0,
       help="regional surface slope in the pointing plane"),
    _P("geometry.rms_height", "length", 0.0, low=0.0,
       help="Gardner roughness σ_ξ: rms height within the footprint"),
    _P("geometry.roughness", "angle", 0.1, low=0.0, high=30.0,
       help="facet roughness (tilt angle): sets the specular lobe"),
    _P("geometry.lobe_factor", "number", 2.5, low=0.0,
       help="specular lobe half-angle θ_L = lobe_factor × roughness (seed: 0.1° → 0.25°)"),
    _P("geometry.bf_lobe_factor", "number", 1.0, low=0.0,
       help="BF-direct lobe half-angle relative to the specular lobe"),
    _P("geometry.lobe_model", "choice", "uniform_cone", choices=("uniform_cone", "gaussian"),
       help="uniform_cone (seed eqs. 7-11) or gaussian (instruments.md §3.4 option 2)"),
    _P("geometry.atmosphere_transmission", "number", 1.0, low=0.0, high=1.0,
       help="one-way T_atm"),
    # §3.5 background
    _P("background.solar_irradiance", "irradiance", 0.64, low=0.0,
       help="solar spectral irradiance at 1 AU at the wavelength"),
    _P("background.sun_distance", "distance", 0.387, low=0.0, low_open=True, help="heliocentric distance"),
    _P("background.albedo", "number", 0.15, low=0.0, high=1.0, help="surface albedo seen by the sun"),
    _P("background.solar_incidence", "angle", 90.0, low=0.0, high=90.0,
       help="solar incidence angle; 90 deg: no direct sunlight (PSR)"),
    _P("background.scale", "number", 1.0, low=0.0,
       help="multiplies the solar radiance (e.g. 1e-3 for PSR secondary light)"),
    _P("background.count_rate", "frequency", None, low=0.0,
       help="if given: background photoelectron rate, replacing the solar formula"),
    # §3.3 speckle
    _P("speckle.modes", "modes", "auto",
       help="speckle modes M (Gamma shape); auto: A_r π θ_div² / (4 λ²); 0: no speckle"),
    # §3.6 detector
    _P("detector.type", "choice", "apd", choices=("apd", "photon_counting")),
    _P("detector.quantum_efficiency", "number", 0.35, low=0.0, high=1.0, help="η_q"),
    _P("detector.gain", "number", 100.0, low=1.0, help="APD mean gain M"),
    _P("detector.k_eff", "number", 0.02, low=0.0, high=1.0, help="ionisation ratio"),
    _P("detector.excess_noise", "number", None, low=1.0,
       help="excess noise factor F (default: k M + (1 - k)(2 - 1/M))"),
    _P("detector.bulk_dark_current", "current", 1e-9, low=0.0, help="I_db (multiplied)"),
    _P("detector.surface_dark_current", "current", 10e-9, low=0.0, help="I_ds (not multiplied)"),
    _P("detector.dark_count_rate", "frequency", 0.0, low=0.0, help="photon counting: dark rate"),
    _P("detector.channels", "int", 16, low=1, help="photon counting: detector channels"),
    _P("detector.analog_dead_time", "time", 3.0, low=0.0, help="paralyzable, per channel"),
    _P("detector.digital_dead_time", "time", 3.0, low=0.0,
       help="non-paralyzable, per timing channel (two alternating per channel)"),
    _P("detector.timing_jitter", "time", 0.2, low=0.0, help="photon counting: rms jitter"),
    _P("detector.max_photoelectrons", "number", 1e6, low=1.0,
       help="photon counting: refuse shots expecting more photoelectrons than this"),
    # §3.7 electronics
    _P("electronics.transimpedance", "resistance", 50e3, low=0.0, help="G_T (V/A)"),
    _P("electronics.filter", "choice", "gaussian", choices=("gaussian", "bessel4")),
    _P("electronics.bandwidth", "frequency", 33e6, low=0.0, low_open=True, help="f_3dB of the analog filter"),
    _P("electronics.current_noise", "current_noise", 2e-12, low=0.0, help="white input noise i_n"),
    _P("electronics.saturation", "voltage", 1.0, low=0.0, low_open=True, help="V_sat"),
    _P("electronics.offset", "voltage", 0.005, help="baseline offset"),
    # §3.7.5 ADC
    _P("adc.sampling_interval", "time", 12.5, low=0.0, low_open=True, help="Δt_s"),
    _P("adc.bits", "int", 10, low=1, high=24, help="resolution over 0 .. full scale"),
    _P("adc.full_scale", "voltage", None, low=0.0, low_open=True, help="default: the saturation voltage"),
    _P("adc.random_phase", "bool", True, help="draw the sampling phase per shot"),
    # §3.8 detection
    _P("detection.threshold_sigma", "number", 4.5, low=0.0, help="threshold m in noise sigmas"),
    # numerical grid
    _P("window.start", "time", -50.0, help="first sample time (WARPE t = 0 is the surface)"),
    _P("window.stop", "time", 250.0, help="end of the recorded window"),
    _P("window.fine_step", "time", 0.1, low=0.0, low_open=True, help="fine simulation grid δt"),
]
PARAMS: dict[str, Param] = {p.key: p for p in SCHEMA}
SECTIONS = sorted({p.key.split(".")[0] for p in SCHEMA if "." in p.key})
BUILTIN = ("bela", "gala", "atlas")


def instruments_dir() -> Path:
    """Folder of the bundled instrument presets."""
    from ..catalog import presets_dir
    return presets_dir() / "instruments"


# ----------------------------------------------------------------------------- loading

class InstrumentParams(dict):
    """Validated parameters: dotted key -> canonical value; ``.source`` names the preset."""

    source: str = "<dict>"

    def describe(self) -> dict:
        """Attributes for the output file: ``instrument_<section>_<key>`` -> readable value."""
        out = {}
        for key, value in self.items():
            if value is None:
                continue
            p = PARAMS[key]
            name = "instrument_" + key.replace(".", "_")
            if p.kind in ("str", "choice"):
                out[name] = str(value)
            elif p.kind == "bool":
                out[name] = int(bool(value))
            elif p.kind in ("number", "int", "modes"):
                out[name] = value            # dimensionless (or "auto")
            else:
                out[name] = format_value(value, p.kind)
        return out


def _flatten(mapping: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in mapping.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and str(k) in SECTIONS and not prefix:
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def _check(key: str, value, source: str | None, where: str | None = None):
    """``value`` of parameter ``key`` validated and in the canonical unit; a ConfigError
    naming ``source`` and ``where`` (default ``instrument.KEY``) otherwise."""
    p = PARAMS[key]
    where = where or f"instrument.{key}"

    def bad(msg):
        raise ConfigError(msg, key=where, source=source)

    given = value
    if value is None:
        if p.required:
            bad("is required")
        return None
    if p.kind == "str":
        if not isinstance(value, str):
            bad(f"{value!r} is not text")
        return value
    if p.kind == "choice":
        if value not in p.choices:
            bad(f"{value!r} is not one of {', '.join(p.choices)}")
        return value
    if p.kind == "bool":
        if not isinstance(value, bool):
            bad(f"{value!r} is not true or false")
        return value
    if p.kind == "modes":
        if value == "auto":
            return value
        if (isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0
                or not math.isfinite(value)):
            bad(f"{value!r}: give auto or a number >= 0 (0: no speckle)")
        return float(value)
    if p.kind in ("number", "int"):
        if isinstance(value, str):          # PyYAML reads 1.0e6 (no sign) as text
            try:
                value = float(value)
            except ValueError:
                pass
        allowed = _allowed_number(p)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            bad(f"{value!r} is not a number; give {allowed}")
        if isinstance(value, float) and not math.isfinite(value):   # int(nan) would raise
            bad(f"{_typed(given)} is not finite; give {allowed}")
        if p.kind == "int":
            if float(value) != int(value):
                bad(f"{_typed(given)} is not a whole number; give {allowed}")
            value = int(value)
        else:
            value = float(value)
    else:
        try:
            value = parse_value(value, p.kind)
        except (ValueError, UnitError) as err:
            bad(str(err))
    shown = value if p.kind in ("number", "int") else format_value(value, p.kind)
    if p.kind == "int" and isinstance(given, str):
        shown = given.strip()               # "1e30" as typed, not its 31 digits
    limit = (lambda x: f"{int(x)}") if p.kind == "int" else (lambda x: f"{x:g}")
    if p.low is not None and (value < p.low or (p.low_open and value <= p.low)):
        bad(f"{shown} is not allowed; give a value {'>' if p.low_open else '>='} {limit(p.low)}"
            + ("" if p.kind in ("number", "int") else f" {_canonical_unit(p.kind)}"))
    if p.high is not None and value > p.high:
        bad(f"{shown} is not allowed; give a value <= {limit(p.high)}"
            + ("" if p.kind in ("number", "int") else f" {_canonical_unit(p.kind)}"))
    return value


def _typed(value) -> str:
    """A value as typed: text as it is (``1.5`` from the command line), others as repr."""
    return value.strip() if isinstance(value, str) else repr(value)


def _allowed_number(p: Param) -> str:
    """What a valid value of a number or int parameter looks like: 'a whole number in
    [1, 1000000]'."""
    what = "a whole number" if p.kind == "int" else "a number"
    limit = (lambda x: f"{int(x)}") if p.kind == "int" else (lambda x: f"{x:g}")
    if p.low is not None and p.high is not None:
        return f"{what} in {'(' if p.low_open else '['}{limit(p.low)}, {limit(p.high)}]"
    if p.low is not None:
        return f"{what} {'>' if p.low_open else '>='} {limit(p.low)}"
    if p.high is not None:
        return f"{what} <= {limit(p.high)}"
    return what


def _canonical_unit(kind: str) -> str:
    return {"length": "m", "time": "ns", "angle": "deg"}.get(kind) or next(iter(EXTRA_UNITS[kind]))


def _did_you_mean(key: str) -> str:
    guess = difflib.get_close_matches(key, list(PARAMS), n=1)
    return f"; did you mean {guess[0]}?" if guess else ""


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def resolve_instrument(spec) -> tuple[dict, str]:
    """The raw mapping and source of ``spec``: a bundled name (bela, gala, atlas), a YAML path,
    or a mapping."""
    import yaml
    if isinstance(spec, dict):
        return copy.deepcopy(spec), "<dict>"
    text = str(spec)
    path = Path(text)
    if not path.is_file():
        bundled = instruments_dir() / f"{text.lower()}.yaml"
        if text.lower() in BUILTIN and bundled.is_file():
            path = bundled
        else:
            raise ConfigError(f"unknown instrument {text!r}; give one of {', '.join(BUILTIN)} "
                              "or an instrument YAML file", key="--instrument")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        line = getattr(getattr(err, "problem_mark", None), "line", None)
        raise ConfigError("not valid YAML" + (f" (line {line + 1})" if line is not None else ""),
                          source=str(path)) from None
    if not isinstance(raw, dict):
        raise ConfigError("an instrument preset must be a mapping of sections", source=str(path))
    return raw, str(path)


def check_parameter(key: str, value, source: str | None = None, where: str | None = None):
    """Validate one instrument parameter given apart from a preset (``--shots``, the
    ``shots`` argument of :func:`~warpe_cl.instrument.apply_instrument`).

    Parameters
    ----------
    key : str
        The parameter (``"shots"``, ``"seed"``).
    value : object
        As a user wrote it: ``100``, ``1e3``, ``"1e3"``.
    source, where : str, optional
        Named by the error: where the value came from and under which name
        (default ``instrument.KEY``).

    Returns
    -------
    object
        The value in its canonical form (an int for ``shots``).

    Raises
    ------
    ConfigError
        One line with the value and what is allowed (e.g. shots in [1, 1000000]).
    """
    return _check(key, value, source, where)


def load_instrument(spec, overrides: dict | None = None,
                    override_source: str | None = None) -> InstrumentParams:
    """Load and validate an instrument.

    Parameters
    ----------
    spec : str, Path or dict
        ``bela``, ``gala``, ``atlas``, a YAML file, or a mapping of the same shape.
    overrides : dict, optional
        Nested or dotted keys applied on top (e.g. ``{"geometry.altitude": "400 km"}`` or the
        keys of a scenario's ``instrument:`` block), written as in a preset (strings with units).
    override_source : str, optional
        Where the overrides come from (``"command line"``, a scenario preset), for messages.

    Returns
    -------
    InstrumentParams
    """
    raw, source = resolve_instrument(spec)
    flat = _flatten(raw)
    over = {}
    for k, v in (overrides or {}).items():
        over.update(_flatten({k: v}) if isinstance(v, dict) else {k: v})
    for key in list(flat) + list(over):
        if key not in PARAMS:
            raise ConfigError(f"unknown key{_did_you_mean(key)}", key=f"instrument.{key}",
                              source=override_source if key in over and override_source else source)
    out = InstrumentParams()
    out.source = source
    for p in SCHEMA:
        if p.key in over:
            out[p.key] = _check(p.key, over[p.key], override_source or source)
        elif p.key in flat:
            out[p.key] = _check(p.key, flat[p.key], source)
        elif p.required:
            raise ConfigError("is required", key=f"instrument.{p.key}", source=source)
        else:
            out[p.key] = p.default          # canonical already
    if out["window.stop"] <= out["window.start"]:
        raise ConfigError("window.stop must be after window.start", key="instrument.window",
                          source=source)
    if out["adc.full_scale"] is None:
        out["adc.full_scale"] = out["electronics.saturation"]
    return out
