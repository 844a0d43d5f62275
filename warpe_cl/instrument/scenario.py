"""The ``instrument:`` block of a scenario preset: the instrument it names, built from the
resolved configuration, and applied to a scenario's surface result.

Whichever way a scenario is computed (``warpe-cl run`` of a whole grid,
:func:`warpe_cl.simulate`, ``warpe-cl sweep``), :func:`warpe_cl.api.simulate_point` applies
the block to that scenario alone, so a point's instrument variables are the same bits every
way: each shot's noise is keyed by the instrument seed (else the point's
``simulation.seed``) and the point's 64-bit scenario key, never by its place in a grid
(:func:`warpe_cl.instrument.chain.shot_rng`).

The block's ``altitude`` and ``roughness``, when given, replace the instrument preset's
``geometry.altitude`` and ``geometry.roughness``; absent, the preset's own values stand (BELA
500 km, GALA 500 km, ATLAS 496 km). Every other key is an instrument key, as written in an
instrument preset (``shots``, ``seed``, ``electronics: {transimpedance: "20 kohm"}``).
"""
from __future__ import annotations

import os

from ..config.schema import FIELDS
from ..errors import ConfigError
from ..units import format_quantity
from .params import BUILTIN, InstrumentParams, load_instrument

__all__ = ["scenario_instrument", "apply_scenario_instrument", "BLOCK_KEYS"]

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
        overrides[target] = format_quantity(value, FIELDS[f"instrument.{key}"].kind)
    params = load_instrument(_spec(name, getattr(cfg, "_base_dir", None)), overrides,
                             override_source=source, spec_key="instrument.name")
    _check_wavelength(cfg, params, source)
    return params


def _check_wavelength(cfg, params: InstrumentParams, source: str) -> None:
    """ConfigError unless the preset's wavelength is the instrument's, by the chain's own test
    (:func:`warpe_cl.instrument.chain.at_wavelength`, 0.1 %), before any walk."""
    from .chain import at_wavelength
    lam = params["wavelength"]
    surface = cfg.get("wavelength")
    if not at_wavelength(surface, lam):
        raise ConfigError(f"{params['name']} works at {lam * 1e9:g} nm but the surface is "
                          f"computed at {surface * 1e9:g} nm; give wavelength: "
                          f"\"{lam * 1e9:g} nm\" (with optical constants at it) or another "
                          f"instrument", "instrument.name", source)


def apply_scenario_instrument(ds, cfg, params: InstrumentParams | None = None):
    """``ds`` with the instrument of ``cfg``'s ``instrument:`` block applied, or ``ds`` as it
    is without one.

    Parameters
    ----------
    ds : xarray.Dataset
        One scenario's surface result (:func:`warpe_cl.api.simulate_point`).
    cfg : Config
        That scenario's configuration.
    params : InstrumentParams, optional
        The instrument, when already built by :func:`scenario_instrument`.

    Returns
    -------
    xarray.Dataset
        As :func:`warpe_cl.instrument.apply_instrument` returns it: the surface variables
        plus the chain's (docs/instrument.md), the instrument as ``instrument_*`` attributes.
    """
    params = scenario_instrument(cfg) if params is None else params
    if params is None:
        return ds
    from . import apply_instrument
    return apply_instrument(ds, params, source=str(cfg.source))
