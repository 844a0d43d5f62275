"""A layered stack's physics on the host: the faces and tables the layered walk reads, and the
per-layer outputs of a walk (where rays are absorbed, when the direct echoes arrive).

:func:`gap_face` and :func:`layer_tables` give the medium under the last layer and the
per-layer, per-interface tables of the layered kernel (docs/walk.md §7), which
:class:`~warpe_cl.engine.Engine` uploads and :mod:`warpe_cl.nadir` mirrors.

A result carries one entry per layer of its configuration, top first (dimension ``layer``),
also for a single medium (one layer) and for the layers of zero thickness a sweep may hold
(``medium.layers[0].thickness: ["0 cm", ...]``): such a layer is no layer for the walk
(docs/physics.md §11.5), absorbs nothing, and its echo coincides with the one above it,
so that every scenario of a sweep has the same ``layer`` dimension.

* ``layer_fate_fraction`` (layer): rays absorbed by the medium of each layer, per launched
  ray (their sum is ``fate_fraction`` of ``absorbed_medium``, ray for ray: docs/walk.md §7.4);
* ``echo_time`` (layer): the direct-echo delay of the bottom of each layer at nadir,
  2 sum_{i<=j} h_i n_i / c, ns (docs/physics.md §11.4).
"""
from __future__ import annotations

import numpy as np

from .params import FATES, IFACE_REAL_COLUMNS, LAYER_REAL_COLUMNS, Counts, WalkParams

__all__ = ["configured_layers", "gap_face", "layer_tables", "layer_variables"]

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


def gap_face(params: WalkParams) -> tuple:
    """The index (n, k) of the gap medium under a stack's last layer (docs/walk.md §7.1): the
    substrate's; vacuum under a slab over a vacuum gap; the last layer's own face (a floor in
    contact, no interface) under a slab with ``bottom_interface: none`` or a granular layer."""
    last = params.stack[-1]
    if params.substrate is not None:
        return (float(params.substrate[0]), float(params.substrate[1]))
    if last.texture == "slab" and params.bottom_interface == "fresnel":
        return (1.0, 0.0)
    return last.face


def layer_tables(params: WalkParams, real) -> dict:
    """The tables the layered kernel reads (docs/walk.md §7.3), as NumPy arrays.

    Returns
    -------
    dict
        ``layer_real`` (N, len(LAYER_REAL_COLUMNS)) of dtype ``real``: z_top, z_bottom (m),
        E (1/m), g, n_i / n_0; ``layer_words`` (N,) uint64: T_omega; ``iface_real``
        (N + 1, len(IFACE_REAL_COLUMNS)) of dtype ``real``: for a ray going down, then up,
        the real index on its side and the complex index of the far side; ``iface_kind``
        (N + 1,) int32: 0 transparent (equal faces), 1 Fresnel.
    """
    layers = params.stack
    depth = np.concatenate([[0.0], np.cumsum([x.thickness for x in layers])]).astype(real)
    n0 = float(layers[0].n)
    rows = {"z_top": depth[:-1], "z_bottom": depth[1:],
            "extinction": [x.extinction for x in layers], "g": [x.g for x in layers],
            "time_scale": [float(x.n) / n0 for x in layers]}
    layer_real = np.stack([np.asarray(rows[c], dtype=real) for c in LAYER_REAL_COLUMNS], axis=1)
    faces = [(1.0, 0.0)] + [x.face for x in layers] + [gap_face(params)]
    iface, kind = [], []
    for j in range(len(layers) + 1):
        above, below = faces[j], faces[j + 1]
        cols = {"down_near": above[0], "down_far_n": below[0], "down_far_k": below[1],
                "up_near": below[0], "up_far_n": above[0], "up_far_k": above[1]}
        iface.append([cols[c] for c in IFACE_REAL_COLUMNS])
        kind.append(0 if above == below else 1)
    return {"layer_real": np.ascontiguousarray(layer_real),
            "layer_words": np.array([x.omega_words for x in layers], dtype=np.uint64),
            "iface_real": np.asarray(iface, dtype=real),
            "iface_kind": np.asarray(kind, dtype=np.int32)}
