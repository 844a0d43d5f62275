"""DIR/design.nc and the summary table of a design study (docs/design.md §5).

design.nc has the dimensions ``point`` (every node of every family, the family named by the
coordinate ``family``), ``instrument`` and ``parameter`` (the union of the families' swept keys
and derived quantities; NaN where a family has no such parameter).
"""
from __future__ import annotations

import json

import numpy as np
import xarray as xr

from ..inversion.identifiability import CONSTRAINED
from ..io import provenance
from .expected import DISTINGUISHABLE
from .family import SYMBOLS


def parameter_table(families: list) -> list:
    """(name, kind, units, scale, symbol) of every parameter of the study, swept keys first,
    each once, in the order met."""
    rows, seen = [], set()
    for fam in families:
        for a in fam.axes:
            if a.key not in seen:
                seen.add(a.key)
                rows.append((a.key, "swept", a.units, a.scale, a.short))
    for fam in families:
        for d in fam.derived:
            q = d.quantity
            if q.name not in seen:
                seen.add(q.name)
                rows.append((q.name, "derived", q.units, q.scale, SYMBOLS.get(q.name, q.name)))
    return rows


def build_dataset(study, families: list, results: dict) -> xr.Dataset:
    """The Dataset of the module docstring.

    Parameters
    ----------
    study : Study
    families : list of Family
    results : dict
        (family name, instrument name) -> :class:`~.expected.Expected`.

    Returns
    -------
    xarray.Dataset
    """
    table = parameter_table(families)
    names = [r[0] for r in table]
    where = {n: i for i, n in enumerate(names)}
    n_pt = sum(len(f.nodes) for f in families)
    columns = study.instruments + study.combinations
    n_in, n_par = len(columns), len(names)
    ratio = np.full((n_pt, n_in, n_par), np.nan)
    exact = np.full((n_pt, n_in, n_par), np.nan)
    sd = np.full((n_pt, n_in, n_par), np.nan)
    value = np.full((n_pt, n_par), np.nan)
    detected = np.zeros((n_pt, n_in), np.int8)
    snr = np.full((n_pt, n_in), np.nan)
    chi2 = np.full((n_pt, n_in), np.nan)
    nearest = np.full((n_pt, n_in), -1, np.int64)
    chi2_texture = np.full((n_pt, n_in), np.nan)
    nearest_texture = np.full((n_pt, n_in), -1, np.int64)
    starts = np.cumsum([0] + [len(f.nodes) for f in families])
    family = []
    node = []
    start = 0
    for fam in families:
        cols = [where[a.key] for a in fam.axes] + [where[d.quantity.name] for d in fam.derived]
        rows = slice(start, start + len(fam.nodes))
        for k, n in enumerate(fam.nodes):
            family.append(fam.name)
            node.append(json.dumps({key: float(v) for key, v in n.point.items()}))
            value[start + k, cols] = [n.point[a.key] for a in fam.axes] + list(n.derived_here)
        for j, cand in enumerate(columns):
            e = results[(fam.name, cand.name)]
            ratio[rows, j][:, cols] = e.width_ratio
            exact[rows, j][:, cols] = e.width_ratio_exact
            sd[rows, j][:, cols] = e.sd
            detected[rows, j] = e.detected
            snr[rows, j] = e.peak_snr
            chi2[rows, j] = e.min_delta_chi2
            nearest[rows, j] = np.where(e.nearest >= 0, e.nearest + start, -1)
            if e.min_delta_chi2_texture is not None:
                # the other families' nodes in order -> their points in design.nc
                theirs = np.concatenate([np.arange(starts[k], starts[k + 1])
                                         for k, f in enumerate(families) if f is not fam])
                chi2_texture[rows, j] = e.min_delta_chi2_texture
                nearest_texture[rows, j] = np.where(e.nearest_texture >= 0,
                                                    theirs[e.nearest_texture], -1)
        start += len(fam.nodes)
    per_par = "per parameter: see parameter_units"
    flag = {"flag_values": np.array([0, 1], np.int8), "flag_meanings": "no yes"}
    ds = xr.Dataset(
        {
            "width_ratio": (("point", "instrument", "parameter"), ratio, {
                "long_name": "expected posterior 95 % width over the prior's 95 % width, in the "
                             "prior's coordinate (Fisher information, capped at 1: 1 = nothing "
                             "learnt)", "units": "1"}),
            "width_ratio_exact_database": (("point", "instrument", "parameter"), exact, {
                "long_name": "width_ratio with the database taken as exact (its own error "
                             "left out)", "units": "1"}),
            "sd": (("point", "instrument", "parameter"), sd, {
                "long_name": "Fisher standard deviation in the parameter's comparison "
                             "coordinate (ln of the value for scale log; inf: not "
                             "constrained)", "units": "1"}),
            "constrained": (("point", "instrument", "parameter"),
                            np.where(np.isfinite(ratio), ratio < CONSTRAINED, False)
                            .astype(np.int8), {
                "long_name": f"expected width_ratio below {CONSTRAINED:g}", "units": "1",
                **flag}),
            "node_value": (("point", "parameter"), value, {
                "long_name": "the parameter's value at the point (a swept key's grid value, a "
                             "derived quantity's value there); NaN where the family has no "
                             "such parameter", "units": per_par}),
            "detected": (("point", "instrument"), detected, {
                "long_name": "the expected return is detected (linear mode: peak above 5 "
                             "sigma_n; counting: 10 signal counts in all shots)", "units": "1",
                **flag}),
            "peak_snr": (("point", "instrument"), snr, {
                "long_name": "linear mode: expected peak over the per-sample noise sigma_n; "
                             "photon counting: expected recorded signal counts of all "
                             "shots (after the dead time)",
                "units": "1"}),
            "min_delta_chi2": (("point", "instrument"), chi2, {
                "long_name": "least expected (Asimov) delta chi2 between the point and a "
                             "neighbouring node, nuisances marginalised", "units": "1"}),
            "distinguishable": (("point", "instrument"),
                                np.where(np.isfinite(chi2), chi2 >= DISTINGUISHABLE, False)
                                .astype(np.int8), {
                "long_name": f"min_delta_chi2 reaches {DISTINGUISHABLE:.2f} (95 % point of "
                             "chi2 with one degree of freedom)", "units": "1", **flag}),
            "nearest_neighbour": (("point", "instrument"), nearest, {
                "long_name": "the point whose delta chi2 is the least (-1: none)",
                "units": "1"}),
            "min_delta_chi2_texture": (("point", "instrument"), chi2_texture, {
                "long_name": "least expected (Asimov) delta chi2 between the point and any "
                             "point of another family of the study, nuisances marginalised "
                             "(NaN: a study of one family)", "units": "1"}),
            "texture_distinguishable": (("point", "instrument"),
                                        np.where(np.isfinite(chi2_texture),
                                                 chi2_texture >= DISTINGUISHABLE, False)
                                        .astype(np.int8), {
                "long_name": f"min_delta_chi2_texture reaches {DISTINGUISHABLE:.2f}: the "
                             "surface is told from every surface of the other families",
                "units": "1", **flag}),
            "nearest_texture_point": (("point", "instrument"), nearest_texture, {
                "long_name": "the point of another family whose delta chi2 is the least "
                             "(-1: none)", "units": "1"}),
            "shots": ("instrument", np.array([_total(study, c, "shots") for c in columns],
                                             np.int64), {
                "long_name": "shots of the observation (a combination: of all its "
                             "instruments)", "units": "1"}),
            "pulse_fwhm": ("instrument", _each(study, columns, "transmitter.pulse_fwhm"), {
                "long_name": "transmitted pulse FWHM (NaN: a combination)", "units": "ns"}),
            "sampling_interval": ("instrument", _each(study, columns,
                                                      "adc.sampling_interval"), {
                "long_name": "sampling interval (histogram bin of a photon-counting "
                             "receiver; NaN: a combination)", "units": "ns"}),
            "pulse_energy": ("instrument", _each(study, columns, "transmitter.pulse_energy"), {
                "long_name": "transmitted pulse energy (NaN: a combination)", "units": "J"}),
            "wavelength": ("instrument", _each(study, columns, "wavelength") * 1e9, {
                "long_name": "laser wavelength (NaN: a combination)", "units": "nm"}),
            "photon_counting": ("instrument", np.array(
                [any(p["detector.type"] == "photon_counting" for p in _params(study, c))
                 for c in columns], np.int8), {
                "long_name": "a photon-counting receiver (a combination: one of its "
                             "instruments)", "units": "1", **flag}),
            "elapsed": ("instrument", np.array(
                [sum(results[(f.name, c.name)].elapsed_s for f in families)
                 for c in columns]), {
                "long_name": "time taken for the instrument's expected widths (a "
                             "combination: its instruments' and the sum)", "units": "s"}),
        },
        coords={
            "point": ("point", np.arange(n_pt), {"long_name": "surface (node of a family)",
                                                 "units": "1"}),
            "family": ("point", np.array(family), {"long_name": "surface family", "units": "1"}),
            "point_values": ("point", np.array(node), {
                "long_name": "the point's swept values (JSON, axis units)", "units": "1"}),
            "instrument": ("instrument", np.array([c.name for c in columns]), {
                "long_name": "candidate instrument, or combination of instruments observing "
                             "together", "units": "1"}),
            "instrument_spec": ("instrument", np.array(
                [getattr(c, "spec", "+".join(getattr(c, "members", []))) for c in columns]), {
                "long_name": "the instrument it starts from (a combination: its instruments "
                             "joined by +)", "units": "1"}),
            "instrument_overrides": ("instrument", np.array(
                [json.dumps(getattr(c, "overrides", {}), default=str) for c in columns]), {
                "long_name": "instrument keys set by the study (JSON)", "units": "1"}),
            "parameter": ("parameter", np.array(names), {
                "long_name": "swept key or derived quantity", "units": "1"}),
            "parameter_kind": ("parameter", np.array([r[1] for r in table]), {
                "long_name": "swept or derived", "units": "1"}),
            "parameter_units": ("parameter", np.array([r[2] for r in table]), {
                "long_name": "unit of the parameter's values", "units": "1"}),
            "parameter_scale": ("parameter", np.array([r[3] for r in table]), {
                "long_name": "the prior's coordinate: log (ln of the value), log1m "
                             "(-ln(1 - value)) or linear", "units": "1"}),
            "parameter_symbol": ("parameter", np.array([r[4] for r in table]), {
                "long_name": "short name in tables and figures", "units": "1"}),
        },
        attrs={
            "title": f"warpe-cl design study {study.name}",
            "study": study.source,
            "families": json.dumps({f.name: f.source for f in families}),
            "method": "Fisher information of the calibrated likelihood at the noiseless "
                      "expected samples, nuisances marginalised (docs/design.md)",
            "options": json.dumps(study.options),
            "distinguishable_delta_chi2": DISTINGUISHABLE,
            "constrained_width_ratio": CONSTRAINED,
            **provenance(),
        })
    return ds


def _params(study, column) -> list:
    """The instrument parameters of a study's column: one instrument's, or a combination's
    instruments' in its order."""
    if hasattr(column, "params"):
        return [column.params]
    named = {c.name: c for c in study.instruments}
    return [named[m].params for m in column.members]


def _total(study, column, key: str):
    """The sum of ``key`` over a column's instruments."""
    return sum(p[key] for p in _params(study, column))


def _each(study, columns, key: str) -> np.ndarray:
    """``key`` of each column's instrument (NaN for a combination)."""
    return np.array([float(c.params[key]) if hasattr(c, "params") else np.nan
                     for c in columns])


def summary_rows(ds: xr.Dataset) -> list:
    """Per family and instrument: the median width ratio and the share of points constrained
    per parameter, and the share of points distinguishable from their neighbours."""
    rows = []
    for fam in dict.fromkeys(ds["family"].values.tolist()):
        sub = ds.isel(point=np.flatnonzero(ds["family"].values == fam))
        present = [p for p in range(ds.sizes["parameter"])
                   if np.any(np.isfinite(sub["node_value"].values[:, p]))]
        for j, name in enumerate(ds["instrument"].values.tolist()):
            r = sub["width_ratio"].values[:, j, :]
            cells = []
            for p in present:
                col = r[:, p]
                col = col[np.isfinite(col)]
                med = float(np.median(col)) if col.size else np.nan
                share = float(np.mean(col < CONSTRAINED)) if col.size else np.nan
                cells.append((str(ds["parameter_symbol"].values[p]), med, share))
            texture = sub["min_delta_chi2_texture"].values[:, j]
            rows.append({"family": fam, "instrument": name, "cells": cells,
                         "distinguishable": float(np.mean(sub["distinguishable"].values[:, j])),
                         "texture": float(np.mean(texture >= DISTINGUISHABLE))
                         if np.isfinite(texture).all() else np.nan,
                         "detected": float(np.mean(sub["detected"].values[:, j])),
                         "points": sub.sizes["point"]})
    return rows


def summary_markdown(ds: xr.Dataset) -> str:
    """The summary table (one per family) as Markdown: per instrument, the median width ratio
    of each parameter over the family with the share of its points where it is constrained
    (width ratio < 0.5), and the shares detected and distinguishable."""
    rows = summary_rows(ds)
    out = [f"# {ds.attrs.get('title', 'design study')}", "",
           "Median expected width ratio over the family (posterior 95 % width / prior's, in the "
           f"prior's coordinate; 1 = nothing learnt) and, in brackets, the share of points "
           f"where the parameter is constrained (width ratio < {CONSTRAINED:g}); detected and "
           f"distinguishable (Asimov delta chi2 >= {DISTINGUISHABLE:.2f} to every neighbour) "
           "and, with several families, told from the other families (the same to every "
           "point of theirs): shares of points.", ""]
    for fam in dict.fromkeys(r["family"] for r in rows):
        mine = [r for r in rows if r["family"] == fam]
        symbols = [c[0] for c in mine[0]["cells"]]
        textures = np.isfinite(mine[0]["texture"])
        out += [f"## {fam} ({mine[0]['points']} points)", "",
                "| instrument | " + " | ".join(symbols) + " | detected | distinguishable |"
                + (" other families |" if textures else ""),
                "| --- | " + " | ".join("---" for _ in symbols) + " | --- | --- |"
                + (" --- |" if textures else "")]
        for r in mine:
            cells = [f"{m:.2f} ({100 * s:.0f} %)" for _, m, s in r["cells"]]
            out.append(f"| {r['instrument']} | " + " | ".join(cells)
                       + f" | {100 * r['detected']:.0f} % | {100 * r['distinguishable']:.0f} % |"
                       + (f" {100 * r['texture']:.0f} % |" if textures else ""))
        out.append("")
    return "\n".join(out)
