"""What an instrument records from a simulated surface (docs/instrument.md §3).

One module per stage of the chain:

==================  ==========================================================================
module              stage
==================  ==========================================================================
``scenario``        a scenario preset's ``instrument:`` block, applied to each scenario
``pulse``           §3.1 transmitted pulse (Gaussian FWHM or tabulated)
``footprint``       §3.2 footprint and slope/roughness kernel g(t)
``specular``        §3.4 aperture fraction κ of the specular and BF-direct returns
``radiometry``      §3.3, §3.5 lidar equation, background, speckle modes
``speckle``         §3.3 per-shot speckle factor
``detector``        §3.6 APD photoelectrons and avalanche gain (excess noise F)
``electronics``     §3.7 analog filter, electronic noise, saturation
``adc``             §3.7.5 random sampling phase, quantisation
``detection``       §3.8 matched-filter detection, range and width
``photon_counting`` §3.9 ATLAS branch with dead time
``chain``           the stages in order, one scenario; per-shot random generators
``output``          the output Dataset
``plot``            the paper's three-panel BELA figure
==================  ==========================================================================

The instrument presets' parameter table and loading are configuration
(:mod:`warpe_cl.config.instrument_fields`), and what the surface result hands over (R_d(t),
the specular and BF-direct fractions) is :mod:`warpe_cl.surface`, read by the figures and the
inversion too.
"""
from __future__ import annotations

import numpy as np

from .. import io, surface
from ..config.instrument_fields import BUILTIN, InstrumentParams, check_parameter, load_instrument
from ..dataset import VARYING_TEXT
from ..scenario_keys import parse_key
from . import chain, output

__all__ = ["apply_instrument", "load_instrument", "InstrumentParams", "BUILTIN"]


def apply_instrument(ds, instrument="bela", overrides: dict | None = None, *,
                     shots: int | None = None, seed: int | None = None,
                     source: str = "<dataset>"):
    """Run the instrument chain on a surface result.

    Parameters
    ----------
    ds : xarray.Dataset
        A result of :func:`warpe_cl.simulate` or a file written by ``warpe-cl run`` (one
        scenario or a sweep).
    instrument : str, path, dict or InstrumentParams
        ``bela``, ``gala``, ``atlas``, an instrument YAML file or mapping.
    overrides : dict, optional
        Instrument keys to change, as written in a preset, e.g.
        ``{"geometry.altitude": "400 km", "geometry.roughness": "0.01 deg"}``.
    shots, seed : int, optional
        Default: the instrument's ``shots``; the instrument's ``seed``, else the surface
        result's seed, else 1. Checked against the instrument's limits (shots in
        [1, 1e6]); a bad value raises :class:`~warpe_cl.errors.ConfigError`.
    source : str
        Name of the input, for error messages.

    Returns
    -------
    xarray.Dataset
        ``ds`` plus ``sample_time``, ``signal_mv`` (shot, sample_time), ``expected_mv``
        (sample_time), the detection, range and width outputs (docs/instrument.md), the
        instrument parameters as ``instrument_*`` attributes and provenance.
    """
    params = instrument if isinstance(instrument, InstrumentParams) else \
        load_instrument(instrument, overrides)
    surface.check_variables(ds, source)
    shots = int(params["shots"] if shots is None else
                check_parameter("shots", shots, source, "shots"))
    if seed is not None:
        seed = check_parameter("seed", seed, source, "seed")
    if seed is None:
        seed = params["seed"] if params["seed"] is not None else int(ds.attrs.get("seed", 1))
    sweep = "scenario" in ds.dims
    indices = list(range(ds.sizes["scenario"])) if sweep else [None]
    # the arrays are read once for all scenarios (surface.response would read them per call)
    responses = surface.responses(ds) if sweep else [surface.response(ds)]
    results = []
    for i, response in zip(indices, responses):
        if sweep:
            key = parse_key(ds["scenario_key"].values[i]) if "scenario_key" in ds.variables \
                else i
        else:
            key = parse_key(ds.attrs.get("scenario_key", 0))
        results.append(chain.run_scenario(response, params, shots, int(seed), key))
    prov = {f"instrument_{k}": v for k, v in io.provenance().items()
            if k in ("warpe_cl_version", "created_utc", "command", "numpy_version", "host")}
    prov.update({"instrument_seed": int(seed), "instrument_shots": shots})
    estimates = [r.estimate for r in responses]
    prov["instrument_diffuse_estimate"] = surface.diffuse_estimate(ds, estimates)
    out = output.build(ds, results, params, sweep, prov)
    if sweep:                  # which estimate each scenario used ("mixed" above: some of each)
        name, meaning = VARYING_TEXT["instrument_diffuse_estimate"]
        out[name] = ("scenario", np.array(estimates), {"long_name": meaning})
    return out
