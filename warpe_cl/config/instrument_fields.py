"""Instrument presets: the parameter table, loading and validation, and a scenario preset's
``instrument:`` block resolved.

The instrument table is configuration, as the scenario table (:mod:`warpe_cl.config.schema`)
is: it lives here, below the chain (:mod:`warpe_cl.instrument`), which reads the
:class:`InstrumentParams` built from it. :func:`field_for` answers for both tables, and
:func:`scenario_instrument` resolves a preset's ``instrument:`` block once, when the preset
is loaded (:attr:`warpe_cl.config.Config.instrument`).

An instrument preset (``presets/instruments/bela.yaml``) is a YAML mapping of sections; every
dimensioned value is a string with a unit, as in scenario presets, read by
:mod:`warpe_cl.units` (lengths, times, angles, and the energy, voltage, current, current noise
density, frequency, resistance, irradiance and astronomical distance the chain needs). Every
value is checked by the functions that check scenario presets
(:mod:`warpe_cl.config.validate`): a mistake is one line naming the key, the value, what it
counts and what is allowed, with a did-you-mean hint for a near-miss key or choice. A key given
twice in a file is refused.

Canonical units inside the chain: m, ns, deg, J, V, A, A/√Hz, Hz, ohm, W m⁻² nm⁻¹, AU. The
defaults of :data:`SCHEMA` are written in them.

>>> p = load_instrument("bela")
>>> p["transmitter.pulse_energy"]
0.05
>>> p["adc.sampling_interval"]
12.5
"""
from __future__ import annotations

import copy
import functools
import math
import os
from pathlib import Path

from ..catalog import presets_dir
from ..errors import ConfigError
from ..units import format_attribute, format_quantity
from .keys import schema_key, split_key
from .schema import FIELDS, Field
from .validate import allowed, check_scalar, read_yaml, show, unknown_key

# ----------------------------------------------------------------------------- schema

_P = Field


#: Every parameter of the chain (docs/instrument.md §3), canonical defaults.
SCHEMA: list[Field] = [
    _P("name", "str", required=True, help="instrument name"),
    _P("description", "str", "", help="free text"),
    _P("wavelength", "length", required=True, low=0.0, low_open=True,
       help="laser wavelength; the surface response must have been computed at it"),
    _P("shots", "int", 100, low=1, high=1_000_000, unit="shots", help="shots simulated"),
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
    _P("transmitter.efficiency", "float", 0.9, low=0.0, high=1.0, help="η_t"),
    # receiver
    _P("receiver.aperture", "length", required=True, low=0.0, low_open=True, help="telescope diameter D_r"),
    _P("receiver.fov", "angle", 530e-6 * 180 / math.pi, low=0.0, low_open=True, help="full-cone field of view"),
    _P("receiver.efficiency", "float", 0.5, low=0.0, high=1.0, help="η_r, optics and filter"),
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
    _P("geometry.lobe_factor", "float", 2.5, low=0.0,
       help="specular lobe half-angle θ_L = lobe_factor × roughness (seed: 0.1° → 0.25°)"),
    _P("geometry.bf_lobe_factor", "float", 1.0, low=0.0,
       help="BF-direct lobe half-angle relative to the specular lobe"),
    _P("geometry.lobe_model", "choice", "uniform_cone", choices=("uniform_cone", "gaussian"),
       help="uniform_cone (paper eqs. 7-11) or gaussian (docs/instrument.md §3.4 option 2)"),
    _P("geometry.atmosphere_transmission", "float", 1.0, low=0.0, high=1.0,
       help="one-way T_atm"),
    # §3.5 background
    _P("background.solar_irradiance", "irradiance", 0.64, low=0.0,
       help="solar spectral irradiance at 1 AU at the wavelength"),
    _P("background.sun_distance", "distance", 0.387, low=0.0, low_open=True, help="heliocentric distance"),
    _P("background.albedo", "float", 0.15, low=0.0, high=1.0, help="surface albedo seen by the sun"),
    _P("background.solar_incidence", "angle", 90.0, low=0.0, high=90.0,
       help="solar incidence angle; 90 deg: no direct sunlight (PSR)"),
    _P("background.scale", "float", 1.0, low=0.0,
       help="multiplies the solar radiance (e.g. 1e-3 for PSR secondary light)"),
    _P("background.count_rate", "frequency", None, low=0.0,
       help="if given: background photoelectron rate, replacing the solar formula"),
    # §3.3 speckle
    _P("speckle.modes", "float", "auto", low=0.0, choices=("auto",),
       help="speckle modes M (Gamma shape); auto: A_r π θ_div² / (4 λ²); 0: no speckle"),
    # §3.6 detector
    _P("detector.type", "choice", "apd", choices=("apd", "photon_counting")),
    _P("detector.quantum_efficiency", "float", 0.35, low=0.0, high=1.0, help="η_q"),
    _P("detector.gain", "float", 100.0, low=1.0, help="APD mean gain M"),
    _P("detector.k_eff", "float", 0.02, low=0.0, high=1.0, help="ionisation ratio"),
    _P("detector.excess_noise", "float", None, low=1.0,
       help="excess noise factor F (default: k M + (1 - k)(2 - 1/M))"),
    _P("detector.bulk_dark_current", "current", 1e-9, low=0.0, help="I_db (multiplied)"),
    _P("detector.surface_dark_current", "current", 10e-9, low=0.0, help="I_ds (not multiplied)"),
    _P("detector.dark_count_rate", "frequency", 0.0, low=0.0, help="photon counting: dark rate"),
    _P("detector.channels", "int", 16, low=1, help="photon counting: detector channels"),
    _P("detector.analog_dead_time", "time", 3.0, low=0.0, help="paralyzable, per channel"),
    _P("detector.digital_dead_time", "time", 3.0, low=0.0,
       help="non-paralyzable, per timing channel (two alternating per channel)"),
    _P("detector.timing_jitter", "time", 0.2, low=0.0, help="photon counting: rms jitter"),
    _P("detector.max_photoelectrons", "float", 1e6, low=1.0,
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
    _P("detection.threshold_sigma", "float", 4.5, low=0.0, help="threshold m in noise sigmas"),
    # numerical grid
    _P("window.start", "time", -50.0, help="first sample time (WARPE t = 0 is the surface)"),
    _P("window.stop", "time", 250.0, help="end of the recorded window"),
    _P("window.fine_step", "time", 0.1, low=0.0, low_open=True, help="fine simulation grid δt"),
]
PARAMS: dict[str, Field] = {p.key: p for p in SCHEMA}
SECTIONS = sorted({p.key.split(".")[0] for p in SCHEMA if "." in p.key})
BUILTIN = ("bela", "gala", "atlas")
_TOP = [p.key for p in SCHEMA if "." not in p.key]
_LISTING = (f"the keys allowed are {', '.join(_TOP)} and the sections "
            f"{', '.join(SECTIONS)} (docs/instrument.md)")


@functools.lru_cache(maxsize=1)
def instruments_dir() -> Path:
    """Folder of the bundled instrument presets (looked up once per process)."""
    return presets_dir() / "instruments"


def field_for(key: str) -> Field | None:
    """The table row of a dotted key, scenario or instrument.

    Parameters
    ----------
    key : str
        A scenario preset's dotted key (``medium.inclusions[0].grain_size``,
        ``instrument.altitude``), or ``instrument.`` followed by an instrument key
        (``instrument.electronics.transimpedance``).

    Returns
    -------
    Field or None
        The scenario table's row (:data:`warpe_cl.config.schema.FIELDS`) when it has the
        key, else the instrument table's (:data:`PARAMS`) for an ``instrument.`` key; None
        for a key neither table has (``medium``: whole media).
    """
    field = FIELDS.get(schema_key(split_key(key)))
    if field is None and key.startswith("instrument."):
        field = PARAMS.get(key[len("instrument."):])
    return field


#: Relative tolerance on the wavelength: a surface computed within it of the instrument's is
#: at the instrument's wavelength.
WAVELENGTH_RTOL = 1e-3


def at_wavelength(surface_m: float, instrument_m: float) -> bool:
    """Whether a surface computed at ``surface_m`` (m) is at the instrument's ``instrument_m``
    (m), to :data:`WAVELENGTH_RTOL`."""
    return abs(surface_m - instrument_m) <= WAVELENGTH_RTOL * instrument_m


# ----------------------------------------------------------------------------- loading

class InstrumentParams(dict):
    """Validated parameters: dotted key -> canonical value; ``.source`` names the preset."""

    source: str = "<dict>"

    def readable(self) -> dict:
        """``section.key`` -> the value as a preset writes it (``"5.5 ns"``); absent values
        left out (``warpe-cl show-config instruments/bela``)."""
        out = {}
        for key, value in self.items():
            if value is None:
                continue
            p = PARAMS[key]
            if p.kind in ("str", "choice"):
                out[key] = str(value)
            elif p.kind == "bool":
                out[key] = int(bool(value))
            elif p.kind in ("float", "int"):
                out[key] = value            # dimensionless (or "auto")
            else:
                out[key] = format_attribute(value, p.kind)
        return out

    def describe(self) -> dict:
        """Attributes for the output file: ``instrument_<section>_<key>`` -> readable value."""
        return {"instrument_" + key.replace(".", "_"): value
                for key, value in self.readable().items()}


def _flatten(mapping: dict, where: str = "instrument") -> dict:
    """``{section: {key: v}}`` and ``{"section.key": v}`` alike as ``{"section.key": v}``.

    Raises ConfigError for a section that is not a mapping and for a key given twice (once
    in its section, once dotted)."""
    out = {}
    for k, v in mapping.items():
        name = str(k)
        if name in SECTIONS:
            if not isinstance(v, dict):
                keys = ", ".join(p.key.split(".", 1)[1] for p in SCHEMA
                                 if p.key.startswith(name + "."))
                raise ConfigError(f"{show(v)} is not a mapping; give a mapping with keys "
                                  f"among {keys}", f"{where}.{name}")
            items = {f"{name}.{sub}": value for sub, value in v.items()}
        else:
            items = {name: v}
        for key, value in items.items():
            if key in out:
                raise ConfigError("given twice (once dotted, once in its section); give it "
                                  "once", f"{where}.{key}")
            out[key] = value
    return out


def _check_keys(flat: dict, where: str = "instrument") -> None:
    """ConfigError for the first key of ``flat`` that is not a parameter, with a hint: the
    closest key (``did you mean electronics.transimpedance?``), the same name in its section
    (``altitude`` -> ``geometry.altitude``), or what is allowed."""
    for key in flat:
        if key in PARAMS:
            continue
        section, _, name = key.rpartition(".")
        if section in SECTIONS:             # a known section: its own keys
            siblings = [p.key.rpartition(".")[2] for p in SCHEMA
                        if p.key.rpartition(".")[0] == section]
            raise unknown_key(f"{where}.{key}", name, siblings, section, list(PARAMS))
        raise unknown_key(f"{where}.{key}", key, list(PARAMS), "", list(PARAMS), _LISTING)


@functools.lru_cache(maxsize=32)
def _read(path: str, stamp: tuple):
    """The document of an instrument file, read once per version (``stamp``: its mtime and
    size), so that every point of a sweep does not read it again."""
    return read_yaml(path, what="an instrument preset")


def resolve_instrument(spec, spec_key: str = "--instrument") -> tuple[dict, str]:
    """The raw mapping and source of ``spec``: a bundled name (bela, gala, atlas), a YAML path,
    or a mapping. ``spec_key`` names where ``spec`` was given, for messages.

    Raises
    ------
    ConfigError
        An unknown name, an unreadable file, invalid YAML (a key given twice included) or a
        document that is not a mapping.
    """
    raw, source = _resolve(spec, spec_key)
    return copy.deepcopy(raw), source


def _resolve(spec, spec_key: str) -> tuple[dict, str]:
    """:func:`resolve_instrument` without the copy: a file's document is shared by every
    caller (the cache of :func:`_read`), to be read, never changed."""
    if isinstance(spec, dict):
        return spec, "<dict>"
    text = str(spec)
    path = Path(text)
    bundled = instruments_dir() / f"{text.lower()}.yaml"
    if text.lower() in BUILTIN and bundled.is_file():
        path = bundled     # a bundled name is the bundled instrument: a file bela is ./bela
    elif not path.is_file():
        raise ConfigError(f"unknown instrument {text!r}; give one of {', '.join(BUILTIN)} "
                          "or an instrument YAML file", key=spec_key)
    stat = path.stat()
    raw = _read(str(path), (stat.st_mtime_ns, stat.st_size))
    if not isinstance(raw, dict):
        raise ConfigError("an instrument preset must be a mapping of sections", source=str(path))
    return raw, str(path)


def _base(raw: dict, source: str) -> tuple[dict, dict | None]:
    """``raw`` without its ``base:`` key, and the bundled instrument it names (None without
    one): an instrument file ``base: gala`` with a few keys starts from GALA's every key
    (docs/instrument.md §2)."""
    if "base" not in raw:
        return raw, None
    name = raw["base"]
    if not isinstance(name, str) or name.lower() not in BUILTIN:
        raise ConfigError(f"{show(name)} is not a bundled instrument; give one of "
                          f"{', '.join(BUILTIN)}", key="instrument.base", source=source)
    base, _ = _resolve(name.lower(), "instrument.base")
    return {k: v for k, v in raw.items() if k != "base"}, base


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
        The value in its canonical form (an int for ``shots``); None for an absent value
        of an optional parameter.

    Raises
    ------
    ConfigError
        One line with the value and what is allowed (e.g. shots in [1, 1000000]).
    """
    p = PARAMS[key]
    where = where or f"instrument.{key}"
    if value is None:
        if p.required:
            raise ConfigError(f"missing; give {allowed(p)}", where, source)
        return None
    try:
        return check_scalar(p, value, where)
    except ConfigError as exc:
        raise exc.with_source(source) from None


def load_instrument(spec, overrides: dict | None = None,
                    override_source: str | None = None, *,
                    spec_key: str = "--instrument") -> InstrumentParams:
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
    spec_key : str
        Where ``spec`` was given (``--instrument``, ``instrument.name``), for messages.

    Returns
    -------
    InstrumentParams

    Raises
    ------
    ConfigError
        One line naming the file (or ``override_source``), the key ``instrument.KEY``, the
        value and what is allowed.
    """
    raw, source = _resolve(spec, spec_key)     # only read here
    over_source = override_source or source
    raw, base = _base(raw, source)
    try:
        flat = _flatten(raw)
        _check_keys(flat)
    except ConfigError as exc:
        raise exc.with_source(source) from None
    if base is not None:       # the bundled instrument's keys, those of the file on top
        flat = {**_flatten(base), **{k: v for k, v in flat.items() if v is not None}}
    try:
        over = _flatten(overrides or {})
        _check_keys(over)
    except ConfigError as exc:
        raise exc.with_source(over_source) from None
    out = InstrumentParams()
    out.source = source
    for p in SCHEMA:               # an empty value (None) is an absent one, as in presets
        if over.get(p.key) is not None:
            out[p.key] = check_parameter(p.key, over[p.key], over_source)
        elif flat.get(p.key) is not None:
            out[p.key] = check_parameter(p.key, flat[p.key], source)
        elif p.required:
            raise ConfigError(f"missing; give {allowed(p)}" + (
                "" if base is not None else
                f", or start from a bundled instrument with base: {' | '.join(BUILTIN)}"),
                f"instrument.{p.key}", source)
        else:
            out[p.key] = p.default          # canonical already
    if out["window.stop"] <= out["window.start"]:
        raise ConfigError("window.stop must be after window.start", key="instrument.window",
                          source=source)
    if out["adc.full_scale"] is None:
        out["adc.full_scale"] = out["electronics.saturation"]
    return out


# ----------------------------------------------------------------------------- a preset's block

#: Keys of the preset's block that stand for a key of the instrument preset.
BLOCK_KEYS = {"altitude": "geometry.altitude", "roughness": "geometry.roughness"}


def _spec(name: str, base_dir: str | None) -> str:
    """``name`` as given, or a file of that name in the preset's folder when there is one."""
    if name.lower() in BUILTIN or os.path.isfile(name) or base_dir is None:
        return name
    beside = os.path.join(base_dir, name)
    return beside if os.path.isfile(beside) else name


def scenario_instrument(cfg) -> InstrumentParams | None:
    """The validated instrument of a preset's ``instrument:`` block, or None without one.

    Parameters
    ----------
    cfg : Config
        A validated configuration (of one scenario, or of a preset: the block is the same
        unless instrument keys are swept). The block is read from the resolved
        ``cfg.data["instrument"]`` (canonical altitude in m, roughness in deg).

    Returns
    -------
    InstrumentParams or None
        None when the block names no instrument (``instrument.name`` absent).

    Raises
    ------
    ConfigError
        One line naming the preset, the key, the value and what is allowed: an unknown
        instrument or key, a bad value, an instrument key given without ``instrument.name``,
        a key given twice (``altitude`` and ``geometry.altitude``), or a preset wavelength
        the instrument does not work at.
    """
    block = dict(cfg.data.get("instrument") or {})
    source = str(cfg.source)
    name = block.pop("name", None)
    given = [key for key, value in block.items() if value is not None]
    if name is None:
        if given:
            raise ConfigError("is given without instrument.name; name the instrument (bela, "
                              "gala, atlas or an instrument YAML file) or remove the key",
                              f"instrument.{given[0]}", source)
        return None
    overrides = {key: value for key, value in block.items() if key not in BLOCK_KEYS}
    for key, target in BLOCK_KEYS.items():
        value = block.get(key)
        if value is None:
            continue                  # absent: the instrument preset's own value
        if target in overrides or target.split(".")[1] in (overrides.get("geometry") or {}):
            raise ConfigError(f"given twice (as instrument.{key} and instrument.{target}); "
                              "give it once", f"instrument.{key}", source)
        # canonical -> text: format_quantity round-trips exactly
        overrides[target] = format_quantity(value, field_for(f"instrument.{key}").kind)
    params = load_instrument(_spec(name, getattr(cfg, "_base_dir", None)), overrides,
                             override_source=source, spec_key="instrument.name")
    _check_wavelength(cfg, params, source)
    return params


def _check_wavelength(cfg, params: InstrumentParams, source: str) -> None:
    """ConfigError unless the preset's wavelength is the instrument's, by the chain's own test
    (:func:`at_wavelength`, 0.1 %), before any walk."""
    lam = params["wavelength"]
    surface = cfg.get("wavelength")
    if not at_wavelength(surface, lam):
        raise ConfigError(f"{params['name']} works at {lam * 1e9:g} nm but the surface is "
                          f"computed at {surface * 1e9:g} nm; give wavelength: "
                          f"\"{lam * 1e9:g} nm\" (with optical constants at it) or another "
                          f"instrument", "instrument.name", source)
