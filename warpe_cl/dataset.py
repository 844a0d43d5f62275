"""Assembling the output Dataset (docs/interface.md §5) and a sweep's grid.

One scenario's Dataset (:func:`build_dataset`), the derived parameters as variables
(:func:`derived_variables`), the scenarios of a sweep stacked along ``scenario``
(:func:`combine_scenarios`) with their swept values as coordinates
(:func:`sweep_coordinates`), and that dimension unstacked into one per swept key
(:func:`as_grid`, :func:`grid_name`). Writing the files is :mod:`warpe_cl.io`'s, reading
them back :mod:`warpe_cl.database`'s.
"""
from __future__ import annotations

import json

import numpy as np

from .config.instrument_fields import field_for
from .config.keys import split_key
from .params import COMPONENTS, FATES, N_EMERGENCE
from .stack import layer_variables
from .units import DIMENSIONS, canonical_unit, parse_quantity


DERIVED = ("tau0", "omega", "extinction_per_m", "n_eff", "k_eff", "first_bf_time_ns",
           "specular_r0", "thickness_m", "porosity_factor", "matrix_absorption_per_m")


#: Units and meanings of the derived parameters (docs/physics.md §4.5), which a result holds
#: as variables (and, for one scenario, as attributes of the same name too).
DERIVED_META = {
    "tau0": ("1", "optical thickness of the layer"),
    "omega": ("1", "single-scattering albedo"),
    "extinction_per_m": ("m-1", "extinction coefficient"),
    "n_eff": ("1", "effective refractive index of the medium"),
    "k_eff": ("1", "effective absorption index of the medium"),
    "first_bf_time_ns": ("ns", "time of the first back-and-forth (floor) return"),
    "specular_r0": ("1", "Fresnel reflectance of the top interface at the incidence"),
    "thickness_m": ("m", "layer thickness"),
    "porosity_factor": ("1", "porosity factor of the granular medium"),
    "matrix_absorption_per_m": ("m-1", "absorption coefficient of the matrix"),
}


#: The per-species derived parameters kept, as variables along ``species``: key in
#: :func:`warpe_cl.radiative.radiative_parameters`'s ``species`` -> (units, meaning).
SPECIES_META = {
    "w": ("1", "single-scattering albedo of the species' grains"),
    "number_density_per_m3": ("m-3", "number density of the species' grains"),
    "n_rel": ("1", "refractive index of the species relative to the matrix"),
}


def derived_variables(derived: dict) -> dict:
    """The derived parameters as Dataset variables with units.

    Parameters
    ----------
    derived : dict
        :func:`warpe_cl.radiative.radiative_parameters` of one scenario.

    Returns
    -------
    dict
        ``{name: (dims, value, attrs)}``: each of :data:`DERIVED` present, a scalar with
        ``units`` (m, m-1, ns or 1) and ``long_name``; for a physical medium
        ``species_w``, ``species_number_density_per_m3`` (m-3) and ``species_n_rel`` along
        ``species`` (one value per inclusion species, in the preset's order).
    """
    out = {}
    for k in DERIVED:
        if derived.get(k) is not None:
            units, meaning = DERIVED_META[k]
            out[k] = ((), float(derived[k]), {"units": units, "long_name": meaning})
    species = derived.get("species") or []
    for key, (units, meaning) in SPECIES_META.items():
        if species and all(sp.get(key) is not None for sp in species):
            out[f"species_{key}"] = ("species", np.asarray([float(sp[key]) for sp in species]),
                                     {"units": units, "long_name": meaning})
    return out


def build_dataset(arrays: dict, counts, params, derived: dict, attrs: dict):
    """One scenario's Dataset.

    Parameters
    ----------
    arrays : dict
        Output of :func:`warpe_cl.tally.reduce_counts`.
    counts : Counts
        For ``photons`` and ``scattering_events``.
    params : WalkParams
        For the time edges (ns).
    derived : dict
        Derived radiative parameters (:func:`warpe_cl.radiative.radiative_parameters`).
    attrs : dict
        Provenance and configuration attributes.
    """
    import xarray as xr

    edges = np.asarray(params.time_edges, dtype=float)
    centres = np.sqrt(edges[:-1] * edges[1:]) if edges[0] > 0 else 0.5 * (edges[:-1] + edges[1:])
    ct = ("component", "time")
    ds = xr.Dataset(
        {
            "time_edges": ("time_edge", edges, {"units": "ns", "long_name": "time bin edges"}),
            "reflectance": (ct, arrays["reflectance"], {
                "units": "ns-1 sr-1",
                "long_name": "rays of the component leaving inside its FOV, per launched ray, "
                             "per sr, per ns (specular and bf_direct scaled by the roughness lobe)"}),
            "reflectance_stderr": (ct, arrays["reflectance_stderr"], {
                "units": "ns-1 sr-1", "long_name": "Poisson standard error of reflectance"}),
            "ray_count": (ct, arrays["ray_count"], {"units": "1", "long_name": "rays behind reflectance"}),
            "undersampled": (ct, arrays["undersampled"], {
                "long_name": "ray_count < min_rays (specular exempt)"}),
            "hemispherical_reflectance": (ct, arrays["hemispherical_reflectance"], {
                "units": "ns-1", "long_name": "rays of the component leaving at any angle, per "
                                              "launched ray, per ns"}),
            "fraction": ("component", arrays["fraction"], {
                "units": "1", "long_name": "rays of the component leaving at any angle and time, "
                                          "per launched ray"}),
            "early_fraction": ("component", arrays["early_fraction"], {
                "units": "1", "long_name": "rays of the component leaving before the first time "
                                          "edge, per launched ray (in fraction, in no time "
                                          "bin)"}),
            "solid_angle": ("component", arrays["omega_sr"], {
                "units": "sr", "long_name": "solid angle that reflectance is divided by"}),
            "fate_fraction": ("fate", arrays["fate_fraction"], {
                "units": "1", "long_name": "launched rays by fate (sums to 1)"}),
            "angular_reflectance": (("component", "emergence"), arrays["angular_reflectance"], {
                "units": "sr-1", "long_name": "time-integrated azimuth-averaged bidirectional "
                                              "reflectance, per 1 degree emergence bin"}),
            "photons": ((), np.int64(counts.photons), {"units": "1", "long_name": "rays launched"}),
            "scattering_events": ((), np.int64(counts.scattering_events), {
                "units": "1", "long_name": "volume scattering events over all rays"}),
            "mixed_history_fraction": ((), counts.mixed_history / counts.photons, {
                "units": "1", "long_name": "exits with both a volume scattering and a floor "
                                          "reflection (where the history and time-window rules "
                                          "can disagree), per launched ray"}),
        },
        coords={
            "time": ("time", centres, {"units": "ns", "long_name": "bin centre (geometric mean "
                                                                 "of the edges)"}),
            "component": ("component", list(COMPONENTS)),
            "fate": ("fate", list(FATES)),
            "emergence": ("emergence", np.arange(N_EMERGENCE) + 0.5, {
                "units": "deg", "long_name": "emergence angle in vacuum, bin centre"}),
        },
    )
    if "nadir_reflectance" in arrays:
        ds = ds.assign(nadir_variables(arrays))
    layer_vars, layer_coords = layer_variables(counts, params, derived)
    ds = ds.assign_coords(layer_coords).assign(layer_vars)
    ds = ds.assign(derived_variables(derived))
    ds.attrs.update({k: derived[k] for k in DERIVED if k in derived})
    for key in ("material", "w", "number_density_per_m3", "n_rel"):
        values = [sp[key] for sp in derived.get("species", [])]
        if values:
            ds.attrs[f"species_{key}"] = values if key == "material" else np.asarray(values)
    ds.attrs.update(attrs)
    return ds


def nadir_variables(arrays: dict) -> dict:
    """The next-event estimator's output variables (docs/interface.md §5.1, docs/walk.md §8)."""
    ct = ("component", "time")
    exact = ("bidirectional reflectance toward the view direction (next-event estimate; "
             "specular and bf_direct: the lobe-scaled FOV values)")
    return {
        "nadir_reflectance": (ct, arrays["nadir_reflectance"], {
            "units": "ns-1 sr-1", "long_name": exact + ", per ns"}),
        "nadir_reflectance_stderr": (ct, arrays["nadir_reflectance_stderr"], {
            "units": "ns-1 sr-1",
            "long_name": "standard error of nadir_reflectance (spread of 32 photon batches)"}),
        "nadir_ray_count": (ct, arrays["nadir_ray_count"], {
            "units": "1", "long_name": "ray visits behind nadir_reflectance (a ray's "
                                       "consecutive scores in one bin are one visit)"}),
        "nadir_brdf": ("component", arrays["nadir_brdf"], {
            "units": "sr-1", "long_name": exact + ", integrated over all times"}),
        "nadir_brdf_stderr": ("component", arrays["nadir_brdf_stderr"], {
            "units": "sr-1", "long_name": "standard error of nadir_brdf"}),
        "nadir_order_reflectance": (("order", "time"), arrays["nadir_order_reflectance"], {
            "units": "ns-1 sr-1",
            "long_name": "nadir_reflectance of the paths with one scattering or floor "
                         "reflection (order 1), every diffuse component"}),
        "nadir_order_reflectance_stderr": (("order", "time"),
                                           arrays["nadir_order_reflectance_stderr"], {
            "units": "ns-1 sr-1", "long_name": "standard error of nadir_order_reflectance"}),
        "nadir_order_brdf": ("order", arrays["nadir_order_brdf"], {
            "units": "sr-1", "long_name": "nadir_brdf of the order-1 paths"}),
        "nadir_order_brdf_stderr": ("order", arrays["nadir_order_brdf_stderr"], {
            "units": "sr-1", "long_name": "standard error of nadir_order_brdf"}),
        "order": ("order", np.array([1]), {"long_name": "scatterings and floor reflections "
                                                        "of a path"}),
    }


def _same_attr(a, b) -> bool:
    """Attribute equality that also holds for array attributes (species_w, ...)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return a is not None and b is not None and np.array_equal(a, b)
    return a == b


def _pad(ds, longest: dict):
    """``ds`` with each dimension of ``longest`` it has padded at its end, with NaN, to that
    length (``ds`` itself when none is shorter)."""
    widths = {d: (0, n - ds.sizes[d]) for d, n in longest.items()
              if d in ds.sizes and ds.sizes[d] < n}
    return ds.pad(widths, constant_values=np.nan) if widths else ds


def combine_scenarios(datasets: list, points: list, attrs: dict | None = None):
    """Stack scenario Datasets along ``scenario``.

    The swept values become coordinates (:func:`sweep_coordinates`: numbers in the canonical
    unit, the written text beside them), the per-scenario derived parameters (tau0, omega, ...,
    :func:`derived_variables`, stacked as every variable; from the attributes of a file written
    before they were variables) and Philox scenario keys become variables, attributes shared
    by every scenario stay attributes (those of :data:`VARYING_TEXT` that differ become
    per-scenario variables), and ``attrs`` (e.g. the whole preset with its sweep block) is
    added last.
    A dimension without coordinate whose length differs between scenarios (``photon``, the
    time tags of a photon-counting instrument) is padded at its end to the longest with NaN,
    as :func:`warpe_cl.instrument.output.build` pads it.
    """
    import xarray as xr

    longest = {}
    for ds in datasets:
        for dim, size in ds.sizes.items():
            if dim not in ds.indexes:
                longest[dim] = max(longest.get(dim, 0), size)
    datasets = [_pad(ds, longest) for ds in datasets]
    datasets = _fill_missing(datasets)
    first = datasets[0].attrs            # an attribute varies if any scenario differs from
    varying = {k for k in {k for ds in datasets for k in ds.attrs}   # the first: O(N), not N^2
               if any(not _same_attr(ds.attrs.get(k), first.get(k)) for ds in datasets)}
    stripped = []
    for ds in datasets:
        ds = ds.copy()
        ds.attrs = {}               # dataset attributes only: variables keep their units
        stripped.append(ds)
    out = xr.concat(stripped, dim="scenario")
    out["time_edges"] = datasets[0]["time_edges"]   # shared by every scenario of a sweep
    out.attrs.update({k: v for k, v in datasets[0].attrs.items()
                      if k not in varying and k not in DERIVED})
    for k in DERIVED + ("scenario_key",):      # files written before they were variables
        values = [ds.attrs.get(k) for ds in datasets]
        if k not in out.variables and all(v is not None for v in values):
            units, meaning = DERIVED_META.get(k, (None, "Philox key of the scenario's random "
                                                        "streams (16 hexadecimal digits)"))
            out[k] = ("scenario", np.asarray(values),
                      {"long_name": meaning, **({"units": units} if units else {})})
    for k, (name, meaning) in VARYING_TEXT.items():   # what differs per scenario, kept
        if k in varying:
            out[name] = ("scenario", np.asarray([str(ds.attrs.get(k, "")) for ds in datasets]),
                         {"long_name": meaning})
            if k == "instrument_diffuse_estimate":
                out.attrs[k] = "mixed"
    for key in points[0]:
        out = out.assign_coords(sweep_coordinates(key, [p[key] for p in points]))
    out = out.assign_coords(scenario=np.arange(len(datasets)))
    out.attrs.update(attrs or {})
    return out


#: Attributes of one scenario that become a per-scenario variable (name, meaning) when they
#: differ between the scenarios of a sweep, instead of being dropped with the other varying
#: attributes.
VARYING_TEXT = {
    "nadir_estimator": ("nadir_estimator", "what nadir_reflectance is, or why the scenario has "
                                           "none (docs/walk.md §8)"),
    "instrument_diffuse_estimate": ("diffuse_estimate", "diffuse reflectance the instrument "
                                    "used: nadir (nadir_reflectance) or fov (reflectance)"),
}


def _fill_missing(datasets: list) -> list:
    """Scenarios that lack a variable others have (the nadir estimate, where a scenario has
    ``simulation.nadir: false`` or its faces reflect more paths than the estimator follows:
    docs/walk.md §8.5) get it filled with NaN, so that the sweep stacks."""
    import xarray as xr
    template = {}
    for ds in datasets:
        for name, var in ds.data_vars.items():
            template.setdefault(name, ds[name])
    out = []
    for ds in datasets:
        missing = {name: xr.full_like(t, np.nan, dtype=float)
                   for name, t in template.items() if name not in ds.data_vars}
        out.append(ds.assign(missing) if missing else ds)
    return out


def _field_kind(key: str):
    """The schema kind of a swept dotted key (``"length"``, ``"float"``, ``"choice"`` ...;
    an instrument key's from the instrument table), or None for a key the tables lack
    (``medium``: whole media)."""
    field = field_for(key)
    return None if field is None else field.kind


def sweep_coordinates(key: str, values: list) -> dict:
    """The coordinates of one swept key along ``scenario``.

    Parameters
    ----------
    key : str
        The swept dotted key (``medium.inclusions[0].grain_size``).
    values : list
        Its value at each scenario, as the preset writes it (``"50 um"``, ``0.3``, a list).

    Returns
    -------
    dict
        ``{key: ("scenario", values, attrs)}``. A quantity (schema kind ``length``, ``time``,
        ``angle``, or an instrument dimension) is a float in the canonical unit of
        :mod:`warpe_cl.units` (m, ns, deg, J ...), with ``units`` and a second coordinate
        ``<key>_text`` holding the values as written (``"50 um"``); a ``float`` or ``int`` is a
        float (``units`` "1"); anything else (choices, whole media, lists) stays text, lists
        and mappings as JSON. Every one has the attribute ``sweep_key`` (the dotted key),
        which :func:`as_grid` looks for.
    """
    kind = _field_kind(key)
    text = [json.dumps(v, sort_keys=True) if isinstance(v, (dict, list)) else str(v)
            for v in values]
    attrs = {"sweep_key": key, "long_name": f"swept {key}"}
    if kind in DIMENSIONS:
        numbers = [float(parse_quantity(v, kind)) if isinstance(v, str) else float(v)
                   for v in values]
        attrs["units"] = canonical_unit(kind)
        return {key: ("scenario", np.asarray(numbers, dtype=float), attrs),
                f"{key}_text": ("scenario", np.asarray(text), {
                    "long_name": f"swept {key}, as written in the preset"})}
    if kind in ("float", "int") and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                        for v in values):
        attrs["units"] = "1"
        return {key: ("scenario", np.asarray(values, dtype=float), attrs)}
    return {key: ("scenario", np.asarray(text), attrs)}


def grid_name(key: str, keys, taken=()) -> str:
    """The dimension name of swept ``key`` in :func:`as_grid`.

    The shortest tail of the key's parts, joined by ``_``, that no other key of ``keys``
    shares and that names no variable of ``taken``: ``medium.inclusions[0].grain_size`` ->
    ``grain_size``; ``medium.radiative.tau0`` -> ``radiative_tau0`` (``tau0`` is a derived
    variable); two inclusions' grain sizes -> ``inclusions_0_grain_size`` and
    ``inclusions_1_grain_size``.
    """
    def parts(k):
        return [str(p) for p in split_key(k)]

    def tail(k, n):
        return "_".join(parts(k)[-n:])
    reserved = set(taken) | {"scenario"}
    for n in range(1, len(parts(key)) + 1):
        name = tail(key, n)
        if (not name[0].isdigit() and name not in reserved
                and all(tail(k, n) != name for k in keys if k != key)):
            return name
    return "_".join(parts(key)) + "_swept"


def as_grid(ds):
    """A sweep's ``scenario`` dimension unstacked into one dimension per swept key.

    Parameters
    ----------
    ds : xarray.Dataset
        A sweep (``warpe-cl run`` of a preset with a ``sweep:`` block, or
        :func:`warpe_cl.open_database`), whose swept coordinates carry ``sweep_key``.

    Returns
    -------
    xarray.Dataset
        One dimension per swept key, named by :func:`grid_name` (``grain_size``, with the
        dotted key as its ``sweep_key`` attribute), in the order the keys are written, each
        sorted in increasing value (numbers in their canonical unit). ``scenario`` becomes a
        variable over those dimensions (the grid index; NaN where a database lacks the
        scenario, as every other variable), and ``<key>_text`` too.

    Raises
    ------
    ValueError
        ``ds`` has no swept coordinate.
    """
    keys = [name for name, c in ds.coords.items()
            if c.dims == ("scenario",) and "sweep_key" in c.attrs]
    if not keys:
        raise ValueError("not a sweep: no coordinate along scenario has a sweep_key attribute")
    taken = set(ds.variables) - set(keys)
    names = {k: grid_name(k, keys, taken) for k in keys}
    texts = [f"{k}_text" for k in keys if f"{k}_text" in ds.coords]
    out = ds.drop_vars(texts).reset_index("scenario").reset_coords("scenario")
    out = out.rename_vars({"scenario": "_grid_index", **names})
    if len(keys) == 1:
        out = out.swap_dims(scenario=names[keys[0]])
    else:
        out = out.set_index(scenario=[names[k] for k in keys]).unstack("scenario")
    dims = [names[k] for k in keys]
    out = out.rename_vars({"_grid_index": "scenario"})
    out["scenario"].attrs = dict(ds["scenario"].attrs, long_name="index of the scenario in "
                                 "the sweep grid (outer product order)")
    for k in keys:
        out = out.sortby(names[k])
        out[names[k]].attrs.update(ds[k].attrs)
        if f"{k}_text" in texts:        # one written form per value, along the new dimension
            written = dict(zip(ds[k].values.tolist(), ds[f"{k}_text"].values.tolist()))
            out = out.assign_coords({f"{names[k]}_text": (names[k], np.asarray(
                [written[v] for v in out[names[k]].values.tolist()]),
                ds[f"{k}_text"].attrs)})
    return out.transpose(*dims, ...)
