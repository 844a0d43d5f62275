"""The per-layer outputs of a walk: where rays are absorbed, and when the direct echoes arrive.

A result carries one entry per layer of its configuration, top first (dimension ``layer``),
also for a single medium (one layer) and for the layers of zero thickness a sweep may hold
(``medium.layers[0].thickness: ["0 cm", ...]``): such a layer is no layer for the walk
(docs/physics-layers.md §5), absorbs nothing, and its echo coincides with the one above it,
so that every scenario of a sweep has the same ``layer`` dimension.

* ``layer_fate_fraction`` (layer): rays absorbed by the medium of each layer, per launched
  ray (their sum is ``fate_fraction`` of ``absorbed_medium``, ray for ray: docs/walk.md §7.4);
* ``echo_time`` (layer): the direct-echo delay of the bottom of each layer at nadir,
  2 sum_{i<=j} h_i n_i / c, ns (docs/physics-layers.md §4).
"""
from __future__ import annotations

import numpy as np

from .params import FATES, Counts, WalkParams

__all__ = ["configured_layers", "layer_variables"]

#: The radiative parameters a result gives per layer (``layer_`` + name).
RADIATIVE = ("tau0", "omega", "n_eff", "k_eff")


def configured_layers(params: WalkParams, derived: dict) -> list:
    """The layers of the configuration, top first, each a dict with ``texture``,
    ``thickness_m``, ``walk_index`` (its index in ``params.stack``, or None for a layer of zero
    thickness, which the walk leaves out) and the radiative parameters :data:`RADIATIVE`.

    Parameters
    ----------
    params : WalkParams
        The walk (:func:`warpe_cl.api.walk_params`).
    derived : dict
        Its radiative parameters (:func:`warpe_cl.radiative.radiative_parameters`): a stack's
        hold ``layers``, one dict per configured layer.
    """
    stack = params.stack
    listed = derived.get("layers")
    if not listed:      # one medium: the walk's own values
        layer = stack[0]
        return [{"texture": layer.texture, "thickness_m": float(layer.thickness),
                 "walk_index": 0, "tau0": float(layer.extinction * layer.thickness),
                 "omega": float(layer.omega), "n_eff": float(layer.n),
                 "k_eff": float(layer.k)}]
    out, k = [], 0
    for entry in listed:
        thick = float(entry["thickness_m"])
        index = None
        if thick > 0:
            index, k = k, k + 1
        out.append({"texture": entry["texture"], "thickness_m": thick, "walk_index": index,
                    **{key: float(entry[key]) for key in RADIATIVE}})
    if k != len(stack):
        raise ValueError(f"{k} configured layers of thickness > 0, but the walk has "
                         f"{len(stack)}")
    return out


def layer_variables(counts: Counts, params: WalkParams, derived: dict) -> tuple:
    """The per-layer variables and coordinates of a result (see the module docstring).

    Returns
    -------
    (dict, dict)
        Data variables and coordinates, as ``(dims, values, attrs)`` tuples for
        :class:`xarray.Dataset`.
    """
    layers = configured_layers(params, derived)
    n_walk = len(params.stack)
    if params.layered:
        absorbed = counts.layer_view(n_walk)["absorbed"]
    else:   # one layer: every medium absorption is in it
        absorbed = np.array([counts.fates[FATES.index("absorbed_medium")]], dtype=np.int64)
    fraction = np.array([absorbed[x["walk_index"]] / counts.photons
                         if x["walk_index"] is not None else 0.0 for x in layers])
    # a stack's echoes come with its radiative parameters; one layer's is its t1
    echoes = derived.get("echo_times_ns") or [params.first_bf_time]
    variables = {
        "layer_fate_fraction": ("layer", fraction, {
            "units": "1", "long_name": "rays absorbed by the medium of the layer, per launched "
                                      "ray (sums to fate_fraction of absorbed_medium)"}),
        "echo_time": ("layer", np.asarray(echoes, dtype=float), {
            "units": "ns", "long_name": "direct-echo delay of the bottom of the layer at "
                                       "nadir, 2 sum h_i n_i / c"}),
        **{f"layer_{key}": ("layer", np.array([x[key] for x in layers]), {
            "units": "1", "long_name": f"{key} of the layer (docs/physics.md)"})
           for key in RADIATIVE},
    }
    coords = {
        "layer": ("layer", np.arange(len(layers)), {"long_name": "layer, 0 at the top"}),
        "layer_texture": ("layer", [x["texture"] for x in layers]),
        "layer_thickness": ("layer", np.array([x["thickness_m"] for x in layers]), {
            "units": "m", "long_name": "physical thickness of the layer"}),
    }
    return variables, coords
