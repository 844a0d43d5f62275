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

from ..config.instrument_fields import InstrumentParams
from . import apply_instrument

__all__ = ["apply_scenario_instrument"]


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
        The instrument; default: the one ``cfg`` resolved when it was loaded
        (:attr:`warpe_cl.config.Config.instrument`,
        :func:`warpe_cl.config.instrument_fields.scenario_instrument`).

    Returns
    -------
    xarray.Dataset
        As :func:`warpe_cl.instrument.apply_instrument` returns it: the surface variables
        plus the chain's (docs/instrument.md), the instrument as ``instrument_*`` attributes.
    """
    params = cfg.instrument if params is None else params
    if params is None:
        return ds
    return apply_instrument(ds, params, source=str(cfg.source))
