"""MCX-CL side by side with our walk: the host side of ``bench.py --compare mcxcl``, and the
two-layer check of issue 15 as a command of its own::

    python tools/studies/mcxcl_compare.py layers [--photons 1e6] [--box 400] [--no-control]
                                                 [--json F]
    python tools/studies/mcxcl_compare.py faces [--photons 1e5]

``layers`` runs a stack of two slabs of different index (:data:`LAYERS_MM`) through MCX-CL and our
walk, prints the time-resolved reflectance per photon entering window by window with z-scores,
and exits with status 1 if a judged window (or the total reflectance, or the bottom's
transmittance) differs by more than 5 standard errors (3 if MCX-CL cannot run). ``faces`` is the
probe that shows why the stack lies in a frame of vacuum voxels in MCX's box. Both are described,
with their results, in docs/validation.md §5.

MCX-CL (pmcxcl 0.7.5, Qianqian Fang), run on PoCL, is the project's speed anchor
(docs/performance.md, "MCX-CL anchor"). It runs in its own virtual environment
(``$WARPE_MCXCL_VENV``, default ``/tmp/mcxcl-venv``, created on first use), never as a dependency
of warpe-cl, through ``tools/bench/mcxcl_anchor.py`` started in a subprocess with the two
environment workarounds that running pmcxcl on PoCL needs:

- ``OCL_ICD_VENDORS`` names the OpenCL platform(s) pmcxcl's bundled ICD loader may load, so that
  MCX runs on the same device as our kernels (``--mcxcl-icd``);
- ``LD_PRELOAD`` of the system libstdc++: without it PoCL's build-option string is truncated inside
  pmcxcl and every kernel build fails with "'stdint.h' file not found".

The one-layer scene (:func:`mcx_scene`): our slab in a box of 1 mm voxels, lateral size
``box_mm`` (60 mm, as the anchor), pencil beam at the centre of the z = 0 face along +z, Fresnel
reflection on all faces with n = 1 outside (MCX's ``isreflect``), no fluence output, every face a
detector (so that the scattering count of every photon that leaves is known), time gate
``max_time``.
MCX cannot model our Lambertian floor: its box bottom is a Fresnel face to vacuum, i.e. our
``bottom_interface: fresnel`` with A = 0.

Scattering events (:func:`mcx_events`): the sum of MCX's per-photon scattering counts over all
launched photons = the detected photons' counts on the six faces plus, for photons still inside
at the time gate (MCX saves nothing for them), the expected count mus * L_max of a path of the
capped length L_max = c t_max / n. MCX carries absorption as a weight exp(-mua L), so its photons
are not ended by absorption; our analog walk ends them. Events per second divide by MCX's kernel
time (``nphoton`` / its printed "MCX simulation speed", which excludes the kernel build).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from warpe_cl.params import C_M_PER_NS

PMCXCL_VERSION = "0.7.5"
DEFAULT_VENV = "/tmp/mcxcl-venv"
SYSTEM_ICD_DIR = "/etc/OpenCL/vendors"
#: The anchor run in MCX-CL's venv, a benchmark: tools/bench/mcxcl_anchor.py (run as a script,
#: so that its folder is on its sys.path and it finds tools/bench/_common.py).
HELPER = Path(__file__).resolve().parent.parent / "bench" / "mcxcl_anchor.py"
#: the anchor's time gates (0.05 ns; they cost MCX time even without fluence output)
ANCHOR_TSTEP_NS = 0.05
#: MCX's fixed seed in the anchor script
ANCHOR_SEED = 1648335518


class McxclUnavailable(RuntimeError):
    """MCX-CL could not be installed or started; the message says why and what to do."""


# ---------------------------------------------------------------------------------------------
# the scene and the numbers (pure: tested in tests/test_mcxcl_compare.py)

def voxel_medium(layer, who: str, what: str) -> tuple:
    """A slab layer (``warpe_cl.params.Layer``) as MCX voxels: ``(nz, mus, mua)``, its
    thickness in 1 mm voxels and its coefficients in 1/mm, with E = mus + mua and
    omega = mus / (mus + mua) (docs/physics.md §4.5). Refuses a complex index (``who`` has
    k = ...) and a thickness that is not a whole number of voxels (``what`` must be ...)."""
    if layer.k != 0.0:
        raise ValueError(f"MCX-CL takes a real refractive index; {who} has k = {layer.k}")
    h_mm = layer.thickness * 1e3
    nz = int(round(h_mm))
    if abs(nz - h_mm) > 1e-6 or nz < 1:
        raise ValueError(f"{what} must be a whole number of 1 mm voxels, got {h_mm} mm")
    ext_per_mm = layer.extinction * 1e-3             # E = tau0 / h
    return nz, ext_per_mm * layer.omega, ext_per_mm * (1.0 - layer.omega)


def mcx_scene(params, nphoton: int, box_mm: float | None = None, tstep_ns: float = ANCHOR_TSTEP_NS,
              seed: int = ANCHOR_SEED, gpuid: int = 1) -> dict:
    """The pmcxcl request for a slab :class:`~warpe_cl.params.WalkParams`.

    Parameters
    ----------
    params : WalkParams
        A slab (``texture == "slab"``) with a real index (k = 0).
    nphoton : int
        Photons launched.
    box_mm : float, optional
        Lateral size of the voxel box, mm (default: the slab thickness, the anchor's cube).
    tstep_ns : float
        Width of MCX's time gates, ns (the anchor: 0.05 ns, 100 gates up to 5 ns).
    seed, gpuid : int
        MCX's RNG seed and its 1-based device index.

    Returns
    -------
    dict
        ``cfg`` (pmcxcl configuration without ``vol``), ``vol_shape`` (nx, ny, nz voxels of 1 mm),
        ``mua_per_mm``, ``mus_per_mm``, ``n``, ``path_cap_mm`` and ``time_edges_ns`` (ours).
    """
    if params.texture != "slab":
        raise ValueError("MCX-CL can only be compared on a slab scene (B1): a granular medium has "
                         "no interface, which MCX's voxel box cannot represent")
    nz, mus, mua = voxel_medium(params.stack[0], "this scene", "the slab thickness")
    nxy = int(round(box_mm if box_mm is not None else nz))
    t_max = params.max_time if params.max_time is not None else float(params.time_edges[-1])
    tend = t_max * 1e-9
    # whole number of gates; one gate when tstep >= t_max
    ngates = max(1, int(round(t_max / tstep_ns))) if tstep_ns < t_max else 1
    cfg = {
        "nphoton": int(nphoton),
        "tstart": 0.0, "tend": tend, "tstep": tend / ngates,
        "srcpos": [nxy / 2.0, nxy / 2.0, 0.0], "srcdir": [0.0, 0.0, 1.0], "issrcfrom0": 1,
        "prop": [[0.0, 0.0, 1.0, 1.0], [mua, mus, params.g, params.n]],   # mua mus g n, 1/mm
        "isreflect": 1,                   # Fresnel on every face, n = 1 outside
        "bc": "______111111",             # every face detects: the scattering count of each exit
        "savedetflag": "dspx",            # detector id, nscat, partial path, exit position
        "issavedet": 1, "maxdetphoton": int(nphoton) + 1000,
        "issave2pt": 0,                   # detected photons only: no fluence output
        "seed": int(seed), "gpuid": int(gpuid),
    }
    return {"cfg": cfg, "vol_shape": [nxy, nxy, nz], "mua_per_mm": mua, "mus_per_mm": mus,
            "n": params.n, "path_cap_mm": t_max * C_M_PER_NS * 1e3 / params.n,
            "time_edges_ns": [float(e) for e in params.time_edges]}


def mcx_events(result: dict, mus_per_mm: float, path_cap_mm: float) -> dict:
    """MCX's scattering events over all launched photons, and their rates.

    Parameters
    ----------
    result : dict
        The helper's ``run`` result (``faces``, ``inside_at_tend``, ``nphoton``, ``kernel_ms``,
        ``wall_s``).
    mus_per_mm : float
        Scattering coefficient, mm⁻¹.
    path_cap_mm : float
        Path length at the time gate, mm.

    Returns
    -------
    dict
        ``scattering_events`` (the detected photons' sum, plus ``inside_at_tend`` × mus·L_max,
        given separately as ``events_estimated_inside``), ``scatterings_per_photon`` and its
        standard error ``scatterings_per_photon_err``,
        ``photons_per_s`` and ``scattering_events_per_s`` (kernel time), ``photons_per_s_wall``.
    """
    n = int(result["nphoton"])
    detected = sum(int(f["scatterings"]) for f in result["faces"].values())
    inside = int(result["inside_at_tend"]) * mus_per_mm * path_cap_mm
    events = detected + inside
    # standard error of the mean count per photon, from the per-face sums of squares
    sq = (sum(int(f.get("scatterings_sq", 0)) for f in result["faces"].values())
          + int(result["inside_at_tend"]) * (mus_per_mm * path_cap_mm) ** 2)
    var = max(sq / n - (events / n) ** 2, 0.0)
    kernel_s = result["kernel_ms"] / 1e3
    return {"scattering_events": events, "events_estimated_inside": inside,
            "scatterings_per_photon": events / n,
            "scatterings_per_photon_err": float(np.sqrt(var / n)), "photons_per_s": n / kernel_s,
            "scattering_events_per_s": events / kernel_s, "photons_per_s_wall": n / result["wall_s"]}


def scattering_census(counts) -> dict:
    """Scatterings per ray of one of our walks run with ``records=True``.

    Returns
    -------
    dict
        ``per_launched`` (all rays), ``per_entered`` (all but specular: MCX's normalisation) with
        its standard error ``per_entered_err``, and per fate (docs/physics.md §5.8: specular,
        escaped, absorbed_medium, absorbed_floor, terminated) the fraction of launched rays and
        their mean scattering count.
    """
    from warpe_cl.params import FATES
    rec = counts.records
    nsc = np.asarray(rec["n_scat"], dtype=np.int64)
    fate = np.asarray(rec["fate"])
    entered = nsc[fate != 0]
    out = {"photons": int(len(nsc)), "per_launched": float(nsc.mean()),
           "per_entered": float(entered.mean()),
           "per_entered_err": float(entered.std() / np.sqrt(len(entered))), "fates": {}}
    for i, name in enumerate(FATES):
        m = fate == i
        out["fates"][name] = {"fraction": float(m.mean()),
                              "mean_scatterings": float(nsc[m].mean()) if m.any() else None}
    return out


def format_census(label: str, c: dict, indent: str = "    ") -> str:
    fates = ", ".join(f"{k} {v['fraction']:.4f}" + (f" ({v['mean_scatterings']:.0f})"
                                                       if v["mean_scatterings"] is not None else "")
                      for k, v in c["fates"].items() if v["fraction"] > 0)
    return (f"{indent}{label}: {c['per_launched']:.1f} scatterings per launched ray, "
            f"{c['per_entered']:.1f} ± {c['per_entered_err']:.1f} per ray entering; fates "
            f"(mean scatterings): {fates}")


#: boundaries of the time windows of the reflectance comparison, ns
TPSF_WINDOWS_NS = (0.0, 0.1, 0.25, 0.5, 1.0, 2.0, 3.0, 5.0)


def compare_tpsf(counts, params, result: dict, windows_ns=TPSF_WINDOWS_NS) -> dict:
    """Our time-resolved reflectance against MCX's from its top-face photons.

    Ours: the rays that escaped through the top after entering (every component but specular),
    per ray that entered the medium (N − N_specular: MCX starts its photons inside, with no
    specular loss), binned on our time edges. MCX: the sum of the top-face photons' weights
    exp(−mua L) per launched photon, on the same edges. Both are summed over windows whose
    boundaries are our edges nearest to ``windows_ns``.

    Returns
    -------
    dict
        ``windows`` (list of rows: ``t0_ns``, ``t1_ns``, ``ours``, ``ours_err``, ``mcx``,
        ``mcx_err``, ``ratio``, ``z`` = difference / combined standard error) and ``total`` (the
        same over all times). Standard errors: √k / N for our counts k; √Σw² / N for MCX's weights.
    """
    edges = np.asarray(params.time_edges, dtype=float)
    n_in = counts.photons - int(counts.fates[0])
    ours = np.asarray(counts.time_any, dtype=np.int64)[1:].sum(axis=0)
    n_mcx = int(result["nphoton"])
    w = np.asarray(result["top_tpsf"]["w"], dtype=float)
    w2 = np.asarray(result["top_tpsf"]["w2"], dtype=float)
    idx = sorted({int(np.argmin(np.abs(edges - t))) for t in windows_ns})

    def row(i0, i1):
        k = ours[i0:i1].sum()
        o, oe = k / n_in, np.sqrt(k) / n_in
        m, me = w[i0:i1].sum() / n_mcx, np.sqrt(w2[i0:i1].sum()) / n_mcx
        err = np.hypot(oe, me)
        return {"t0_ns": float(edges[i0]), "t1_ns": float(edges[i1]), "ours": float(o),
                "ours_err": float(oe), "mcx": float(m), "mcx_err": float(me),
                "ratio": float(o / m) if m > 0 else None,
                "z": float((o - m) / err) if err > 0 else None}

    return {"windows": [row(a, b) for a, b in zip(idx[:-1], idx[1:])],
            "total": row(0, len(edges) - 1), "ours_photons_entered": int(n_in),
            "mcx_photons": n_mcx}


def format_tpsf(cmp: dict, indent: str = "    ") -> str:
    """The comparison as a small table."""
    lines = [f"{indent}{'window, ns':>14} {'ours':>18} {'MCX-CL':>18} {'ratio':>7} {'z':>6}"]
    for r in cmp["windows"] + [dict(cmp["total"], label="all")]:
        label = r.get("label") or f"{r['t0_ns']:.3g}-{r['t1_ns']:.3g}"
        ratio = f"{r['ratio']:.3f}" if r["ratio"] is not None else "-"
        z = f"{r['z']:+.1f}" if r["z"] is not None else "-"
        lines.append(f"{indent}{label:>14} {r['ours']:.4e}±{r['ours_err']:.1e} "
                     f"{r['mcx']:.4e}±{r['mcx_err']:.1e} {ratio:>7} {z:>6}")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# two slab layers against MCX-CL (issue 15): the scene, the statistics (pure: tested in
# tools/studies/test_mcxcl_compare.py), and the command
# ``python tools/studies/mcxcl_compare.py layers``

#: The two-layer scene, top first: (thickness mm, mus 1/mm, mua 1/mm, g, n). The indices
#: differ, so the contact between the slabs is a Fresnel interface in both codes.
LAYERS_MM = ((3, 1.0, 0.005, 0.8, 1.31), (5, 2.0, 0.02, 0.9, 1.5))
#: The time gate of the layered comparison (ns) and the width of our time bins (ns).
LAYER_T_MAX_NS = 2.0
LAYER_DT_NS = 0.01
#: Boundaries of its time windows, ns (the interface's nadir echo, 0.026 ns, and the bottom's,
#: 0.076 ns, fall inside windows, not on their edges).
LAYER_WINDOWS_NS = (0.0, 0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.75, 1.0, 1.5, 2.0)
#: Lateral size of MCX's box, mm, and the rings of the top face's radial census, mm.
LAYER_BOX_MM = 400
LAYER_RADII_MM = (0.0, 10.0, 25.0, 50.0, 100.0, 150.0, 1e9)
#: A window is judged when each code has at least this many photons in it.
MIN_WINDOW_COUNTS = 25
#: Agreement: |z| at most this in every judged window (and in the totals).
Z_LIMIT = 5.0
#: How the stack meets the outside in MCX's box. ``vacuum`` (the default): a one-voxel frame of a
#: vacuum medium (label N + 1: mua = mus = 0, n = 1) on all six faces, so that every face of the
#: stack is an internal voxel boundary, where MCX-CL applies Fresnel for every medium;
#: ``none``: the stack touches the box's faces, where this MCX-CL (pmcxcl 0.7.5 on PoCL)
#: applies Fresnel only to medium 1 (docs/validation.md §5.3).
PADDINGS = ("vacuum", "none")
#: MCX's time gate is this much longer than ours, so that a photon that left the stack before
#: our gate and crosses the vacuum padding after it is still saved (its time is the stack's).
GATE_MARGIN = 0.05


def layer_from_mm(h_mm: float, mus: float, mua: float, g: float, n: float):
    """Our slab :class:`~warpe_cl.params.Layer` of MCX's medium (mus, mua per mm): the analog
    walk's E = mus + mua (per m) and omega = mus / (mus + mua) (docs/physics.md §4.5)."""
    from warpe_cl.params import Layer
    ext = mus + mua
    return Layer("slab", h_mm * 1e-3, ext * 1e3, mus / ext if ext > 0 else 1.0, g, n)


def layered_params(layers_mm=LAYERS_MM, t_max_ns: float = LAYER_T_MAX_NS,
                   dt_ns: float = LAYER_DT_NS, seed: int = 1):
    """The :class:`~warpe_cl.params.WalkParams` of a stack of slabs given as MCX media: a black
    floor (A = 0) under a Fresnel face to vacuum (MCX's box bottom with n = 1 outside), time
    bins of ``dt_ns`` from 0 to the gate ``t_max_ns``, every FOV any angle."""
    from warpe_cl.params import stack_params
    nbins = int(round(t_max_ns / dt_ns))
    return stack_params([layer_from_mm(*row) for row in layers_mm], albedo=0.0,
                        bottom_interface="fresnel", max_time=float(t_max_ns),
                        time_edges=np.linspace(0.0, t_max_ns, nbins + 1),
                        fov=(90.0, 90.0, 90.0, 90.0), seed=int(seed))


def control_layers(layers_mm=LAYERS_MM) -> tuple:
    """The control: the same stack with every layer at the top layer's index, so that each
    contact is transparent (docs/physics.md §11.2) and only the media change."""
    n0 = layers_mm[0][4]
    return tuple(tuple(row[:4]) + (n0,) for row in layers_mm)


def mcx_layers_scene(params, nphoton: int, box_mm: float = LAYER_BOX_MM, pad: str = "vacuum",
                     seed: int = ANCHOR_SEED, gpuid: int = 1,
                     radius_edges_mm=LAYER_RADII_MM) -> dict:
    """The pmcxcl request for a stack of slabs (``stack_params``) in a box of 1 mm voxels.

    Layer i is medium i + 1 (prop row [mua, mus, g, n], per mm) over the z range of its
    thickness; label 0 is the outside, n = 1. MCX applies Fresnel at every change of index
    between voxels (``isreflect``): our Fresnel contacts between slabs, our top, and our bottom
    face over a black floor (A = 0: what crosses it is lost). With ``pad`` (:data:`PADDINGS`)
    ``vacuum`` the stack lies in a one-voxel frame of vacuum (medium N + 1, n = 1, no
    scattering or absorption), so its top, bottom and sides are internal boundaries; its path in
    the vacuum does not count in the time (``clock``). The source is a pencil beam at the
    centre of the stack's top along +z; every face of the box detects; one time gate of our
    ``max_time`` × (1 + :data:`GATE_MARGIN`).

    Returns
    -------
    dict
        The helper's request: ``cfg``, ``vol_shape``, ``labels_z`` (the label of each z slice),
        ``frame_label`` (the side frame's label, or None), ``mua_per_mm``, ``n`` and ``clock``
        (per medium), ``time_edges_ns``, ``radius_edges_mm``; and ``layers_mm`` (thickness, mus,
        mua, g, n per layer), ``pad`` and ``stack_box_mm`` (the stack's lateral size) for the
        report.
    """
    if params.substrate is not None or params.albedo != 0.0 or params.bottom_interface != "fresnel":
        raise ValueError("MCX's box bottom is a Fresnel face to vacuum with nothing under it: "
                         "compare a stack without substrate, with bottom_interface fresnel "
                         "and A = 0")
    if pad not in PADDINGS:
        raise ValueError(f"pad must be one of {PADDINGS}, got {pad!r}")
    labels, prop, media = [], [[0.0, 0.0, 1.0, 1.0]], []
    for i, layer in enumerate(params.stack):
        if layer.texture != "slab":
            raise ValueError(f"layer {i} is {layer.texture}: MCX's voxels hold slabs only (a "
                             "granular layer has no face of its own)")
        nz, mus, mua = voxel_medium(layer, f"layer {i}", f"layer {i}: the thickness")
        prop.append([mua, mus, float(layer.g), float(layer.n)])
        media.append([nz, mus, mua, float(layer.g), float(layer.n)])
        labels += [i + 1] * nz
    clock = [1] * len(media)
    nxy = int(round(box_mm))
    frame, z0 = None, 0.0
    if pad == "vacuum":
        vac = len(prop)
        prop.append([0.0, 0.0, 1.0, 1.0])
        clock.append(0)
        labels = [vac] + labels + [vac]
        frame = vac
        z0 = 1.0
        nxy += 2
    if len(prop) > 128:
        raise ValueError("at most 127 media in MCX's byte label volume")
    t_max = params.max_time if params.max_time is not None else float(params.time_edges[-1])
    tend = t_max * 1e-9 * (1.0 + (GATE_MARGIN if pad == "vacuum" else 0.0))
    cfg = {
        "nphoton": int(nphoton),
        "tstart": 0.0, "tend": tend, "tstep": tend,        # one gate: the fluence buffer is small
        "srcpos": [nxy / 2.0, nxy / 2.0, z0], "srcdir": [0.0, 0.0, 1.0], "issrcfrom0": 1,
        "prop": prop,
        "isreflect": 1,                   # Fresnel at every index change, and n = 1 outside
        "bc": "______111111",             # every face detects
        "savedetflag": "dspx",            # detector id, nscat and partial path per medium, exit
        "issavedet": 1, "maxdetphoton": int(nphoton) + 1000,
        "issave2pt": 0,
        "seed": int(seed), "gpuid": int(gpuid),
    }
    return {"cfg": cfg, "vol_shape": [nxy, nxy, len(labels)], "labels_z": labels,
            "frame_label": frame, "mua_per_mm": [row[0] for row in prop[1:]],
            "n": [row[3] for row in prop[1:]], "clock": clock,
            "time_edges_ns": [float(e) for e in params.time_edges],
            "radius_edges_mm": [float(r) for r in radius_edges_mm], "layers_mm": media,
            "pad": pad, "stack_box_mm": int(round(box_mm))}


def mean_and_se(total: float, total_sq: float, n: int) -> tuple:
    """Mean of a per-photon quantity over ``n`` photons from its sum and sum of squares, and the
    standard error of that mean: sqrt(s² / n) with s² = (Σx² − (Σx)²/n) / (n − 1).

    For our analog counts x is 0 or 1 (Σx² = Σx = k: the binomial error √(k(1 − k/n)/(n − 1)));
    for MCX's photons x is the weight exp(−Σ mua_i L_i) of a photon leaving in the window, 0 for
    every other launched photon (the weights' second moment)."""
    n = int(n)
    mean = total / n
    var = max(total_sq - total * total / n, 0.0) / (n - 1) if n > 1 else 0.0
    return float(mean), float(np.sqrt(var / n))


def z_score(a: float, a_err: float, b: float, b_err: float):
    """(a − b) over the combined standard error; None when both errors are 0."""
    err = float(np.hypot(a_err, b_err))
    return float((a - b) / err) if err > 0 else None


def compare_layers(counts, params, result: dict, windows_ns=LAYER_WINDOWS_NS,
                   min_counts: int = MIN_WINDOW_COUNTS, z_limit: float = Z_LIMIT) -> dict:
    """Our time-resolved reflectance per ray entering against MCX's per photon launched.

    Ours: rays that left through the top after entering (every component but specular, any
    angle), per ray entering (N − N_specular), in windows whose boundaries are our time edges
    nearest to ``windows_ns``. MCX: the top-face photons' weights per launched photon (MCX
    starts its photons inside, with no specular loss). Standard errors: :func:`mean_and_se`. A
    window is judged if both codes have ``min_counts`` photons in it; it passes if
    |z| ≤ ``z_limit``.

    Also: the whole (total diffuse reflectance up to the gate, judged like a window), the
    transmittance through the bottom (our rays absorbed by the black floor against MCX's
    bottom-face weights, judged), and MCX's side-face weight and the top face's radial census
    (the box's lateral leakage, reported).

    Returns
    -------
    dict
        ``windows`` (rows: ``t0_ns``, ``t1_ns``, ``ours``, ``ours_err``, ``ours_counts``,
        ``mcx``, ``mcx_err``, ``mcx_counts``, ``ratio``, ``z``, ``judged``), ``total``,
        ``transmittance``, ``side`` (MCX's side-face weight per photon and its error),
        ``radial``, ``max_abs_z`` (over judged rows), ``failed`` (labels of judged rows beyond
        ``z_limit``), ``passed``.
    """
    from warpe_cl.params import FATES
    edges = np.asarray(params.time_edges, dtype=float)
    n_in = counts.photons - int(counts.fates[0])
    ours = np.asarray(counts.time_any, dtype=np.int64)[1:].sum(axis=0)
    n_mcx = int(result["nphoton"])
    tp = result["top_tpsf"]
    w, w2 = np.asarray(tp["w"], dtype=float), np.asarray(tp["w2"], dtype=float)
    mc_counts = np.asarray(tp["counts"], dtype=np.int64)
    idx = sorted({int(np.argmin(np.abs(edges - t))) for t in windows_ns})

    def row(k, k_n, m_w, m_w2, m_n, **extra):
        o, oe = mean_and_se(float(k), float(k), n_in)
        m, me = mean_and_se(float(m_w), float(m_w2), n_mcx)
        judged = bool(k_n >= min_counts and m_n >= min_counts)
        return {**extra, "ours": o, "ours_err": oe, "ours_counts": int(k_n), "mcx": m,
                "mcx_err": me, "mcx_counts": int(m_n), "ratio": float(o / m) if m > 0 else None,
                "z": z_score(o, oe, m, me), "judged": judged}

    def window(i0, i1, **extra):
        k = int(ours[i0:i1].sum())
        return row(k, k, w[i0:i1].sum(), w2[i0:i1].sum(), int(mc_counts[i0:i1].sum()),
                   t0_ns=float(edges[i0]), t1_ns=float(edges[i1]), **extra)

    windows = [window(a, b) for a, b in zip(idx[:-1], idx[1:])]
    total = window(0, len(edges) - 1, label="all")
    floor = int(counts.fates[FATES.index("absorbed_floor")])
    fw = result.get("face_weights", {})
    bottom = fw.get("bottom", {"w": 0.0, "w2": 0.0})
    trans = row(floor, floor, bottom["w"], bottom["w2"],
                int(bottom.get("photons", result["faces"]["bottom"]["photons"])), label="bottom")
    side_w = fw.get("side", {"w": 0.0, "w2": 0.0})
    side_m, side_e = mean_and_se(side_w["w"], side_w["w2"], n_mcx)
    side = {"photons": int(result["faces"]["side"]["photons"]), "weight": side_m,
            "weight_err": side_e}
    radial = None
    if "top_radial" in result:
        rw = np.asarray(result["top_radial"]["w"], dtype=float)
        radial = {"edges_mm": result["top_radial"]["edges_mm"],
                  "fraction": (rw / rw.sum()).tolist() if rw.sum() > 0 else None,
                  "counts": result["top_radial"]["counts"]}
    judged = [r for r in windows + [total, trans] if r["judged"] and r["z"] is not None]
    failed = [r.get("label") or f"{r['t0_ns']:.3g}-{r['t1_ns']:.3g} ns" for r in judged
              if abs(r["z"]) > z_limit]
    return {"windows": windows, "total": total, "transmittance": trans, "side": side,
            "radial": radial, "ours_photons_entered": int(n_in),
            "ours_photons": int(counts.photons),
            "mcx_photons": n_mcx, "mcx_inside_at_tend": int(result.get("inside_at_tend", 0)),
            "max_abs_z": max((abs(r["z"]) for r in judged), default=None),
            "z_limit": float(z_limit), "min_counts": int(min_counts), "failed": failed,
            "passed": not failed and bool(judged)}


def format_layers(cmp: dict, indent: str = "  ") -> str:
    """The layered comparison as a table: windows, the whole, the bottom, MCX's side leakage."""
    lines = [f"{indent}{'window, ns':>12} {'ours':>21} {'MCX-CL':>21} {'ratio':>7} {'z':>6}"
             f"  {'counts ours/MCX':>17}"]
    for r in cmp["windows"] + [cmp["total"], dict(cmp["transmittance"], label="bottom (T)")]:
        label = r.get("label") or f"{r['t0_ns']:.3g}-{r['t1_ns']:.3g}"
        ratio = f"{r['ratio']:.4f}" if r["ratio"] is not None else "-"
        z = f"{r['z']:+.2f}" if r["z"] is not None else "-"
        mark = "" if r["judged"] else "  (not judged: < %d photons)" % cmp["min_counts"]
        if r["judged"] and r["z"] is not None and abs(r["z"]) > cmp["z_limit"]:
            mark = "  <-- beyond %gσ" % cmp["z_limit"]
        lines.append(f"{indent}{label:>12} {r['ours']:.5e}±{r['ours_err']:.1e} "
                     f"{r['mcx']:.5e}±{r['mcx_err']:.1e} {ratio:>7} {z:>6}  "
                     f"{r['ours_counts']:>8}/{r['mcx_counts']:<8}{mark}")
    s = cmp["side"]
    lines.append(f"{indent}MCX side faces (the box's leakage): {s['photons']} photons, weight "
                 f"{s['weight']:.2e} ± {s['weight_err']:.1e} per photon; "
                 f"{cmp['mcx_inside_at_tend']} photons still inside at the gate")
    if cmp.get("radial") and cmp["radial"]["fraction"]:
        e = cmp["radial"]["edges_mm"]
        parts = [f"{e[i]:g}-{e[i + 1]:g}: {f:.2e}" if e[i + 1] < 1e8 else f">{e[i]:g}: {f:.2e}"
                 for i, f in enumerate(cmp["radial"]["fraction"])]
        lines.append(f"{indent}MCX top-face weight by distance from the beam, mm: "
                     + ", ".join(parts))
    verdict = "PASS" if cmp["passed"] else "FAIL (" + ", ".join(cmp["failed"]) + ")"
    mz = cmp["max_abs_z"]
    lines.append(f"{indent}max |z| over judged rows {mz:.2f} (limit {cmp['z_limit']:g}): {verdict}"
                 if mz is not None else f"{indent}no row judged: FAIL")
    return "\n".join(lines)


def first_mcx_device(python: Path, choice: str, workdir_: Path, gpuid: int | None = None):
    """The ICD folder and MCX ``gpuid`` for the layered comparison, which times nothing and so
    needs no device of the same name as ours: ``choice`` ``system`` (/etc/OpenCL/vendors, the
    default), ``pip`` or a folder of ``.icd`` files; ``gpuid`` (1-based) or the first device
    MCX sees there. Returns (folder, gpuid, device name)."""
    if choice == "system":
        folder = SYSTEM_ICD_DIR
    elif choice == "pip":
        folder = pip_pocl_icd_dir(workdir_)
        if folder is None:
            raise McxclUnavailable("--mcxcl-icd pip: our pyopencl wheel bundles no PoCL library")
    else:
        folder = choice
    names = mcx_devices(python, folder, workdir_)
    if not names:
        raise McxclUnavailable(f"MCX-CL sees no OpenCL device through {folder}; choose another "
                               "--mcxcl-icd")
    g = int(gpuid) if gpuid else 1
    if not 1 <= g <= len(names):
        raise McxclUnavailable(f"--mcxcl-gpuid {g}: MCX-CL sees {len(names)} device(s): {names}")
    return str(folder), g, names[g - 1]


def run_layers_case(label: str, layers_mm, args, engine, python, icd, gpuid, wd, log=print) -> dict:
    """One stack through both codes, compared; the case's JSON row (``report``: its text)."""
    import time
    params = layered_params(layers_mm, t_max_ns=args.t_max, dt_ns=args.dt, seed=args.seed)
    n_mcx = int(args.photons)
    n_ours = int(args.ours_photons) if args.ours_photons else 4 * n_mcx
    scene = mcx_layers_scene(params, n_mcx, box_mm=args.box, pad=args.pad,
                             seed=args.mcx_seed, gpuid=gpuid)
    log(f"# {label}: MCX-CL, {n_mcx:.3g} photons in a {scene['vol_shape'][0]} x "
        f"{scene['vol_shape'][1]} x {scene['vol_shape'][2]} mm box (padding: {args.pad}) ...")
    case_dir = Path(wd) / "".join(c if c.isalnum() else "_" for c in label)
    case_dir.mkdir(parents=True, exist_ok=True)
    res = run_mcx(python, icd, scene, case_dir, timeout=args.timeout)
    log(f"#   MCX-CL: {res['wall_s']:.1f} s wall on {res.get('mcx_device')} "
        f"({res.get('detected')} photons detected)")
    log(f"# {label}: ours, {n_ours:.3g} rays on {engine.info.device} ...")
    t0 = time.perf_counter()
    counts = engine.run(params, n_ours, precision=args.precision)
    ours_s = time.perf_counter() - t0
    cmp = compare_layers(counts, params, res, min_counts=args.min_counts, z_limit=args.z_limit)
    head = (f"{label}: layers (h mm, mus, mua 1/mm, g, n) = "
            + "; ".join("(%g, %g, %g, %g, %g)" % tuple(r) for r in layers_mm)
            + f"; gate {args.t_max:g} ns; A = 0, Fresnel bottom\n"
            f"  ours {n_ours:.3g} rays ({cmp['ours_photons_entered']} entering) on "
            f"{engine.info.device} ({engine.info.platform}), {ours_s:.1f} s; MCX-CL "
            f"{res.get('pmcxcl')} {n_mcx:.3g} photons on {res.get('mcx_device')}, "
            f"{res['wall_s']:.1f} s wall, stack {scene['stack_box_mm']} mm wide, padding "
            f"{args.pad}\n"
            "  reflectance per photon entering (any angle), and the bottom's transmittance:")
    report = head + "\n" + format_layers(cmp)
    return {"label": label, "layers_mm": [list(r) for r in layers_mm],
            "box_mm": scene["vol_shape"], "pad": args.pad, "t_max_ns": args.t_max,
            "ours_seconds": ours_s, "ours_device": engine.info.device,
            "mcx": {k: res.get(k) for k in ("nphoton", "wall_s", "kernel_ms", "mcx_device",
                                             "pmcxcl", "faces", "face_weights", "inside_at_tend",
                                             "detected", "log")},
            "compare": cmp, "report": report}


def parse_layers_args(argv):
    import argparse
    p = argparse.ArgumentParser(
        prog="python tools/studies/mcxcl_compare.py layers",
        description="Two slab layers against MCX-CL: time-resolved reflectance per photon "
                    "entering, window by window (docs/validation.md §5). Exit status 0 if "
                    "every judged row agrees within --z-limit standard errors, 1 if one does "
                    "not, 3 if MCX-CL cannot run.")
    p.add_argument("--photons", type=float, default=1e6, help="MCX-CL photons (default 1e6)")
    p.add_argument("--ours-photons", type=float, default=None,
                   help="our rays (default 4x --photons: our analog walk is the cheaper side)")
    p.add_argument("--box", type=float, default=LAYER_BOX_MM,
                   help=f"lateral size of the stack in MCX's box, mm (default {LAYER_BOX_MM})")
    p.add_argument("--pad", choices=PADDINGS, default="vacuum",
                   help="how the stack meets the outside in MCX's box: vacuum (a one-voxel "
                        "vacuum frame, default) or none (the box's faces)")
    p.add_argument("--no-control", action="store_true",
                   help="skip the control (every layer at the top layer's index)")
    p.add_argument("--t-max", type=float, default=LAYER_T_MAX_NS, help="time gate, ns")
    p.add_argument("--dt", type=float, default=LAYER_DT_NS, help="our time bins, ns")
    p.add_argument("--min-counts", type=int, default=MIN_WINDOW_COUNTS)
    p.add_argument("--z-limit", type=float, default=Z_LIMIT)
    p.add_argument("--seed", type=int, default=1, help="our Philox key")
    p.add_argument("--mcx-seed", type=int, default=ANCHOR_SEED)
    p.add_argument("--device", default=None, help="our OpenCL device (default: the default)")
    p.add_argument("--precision", choices=("single", "double"), default="single")
    p.add_argument("--mcxcl-icd", default="system",
                   help="system (default), pip, or a folder of .icd files for MCX-CL")
    p.add_argument("--mcxcl-gpuid", type=int, default=None,
                   help="MCX's 1-based device index there (default: the first)")
    p.add_argument("--mcxcl-venv", default=None)
    p.add_argument("--timeout", type=float, default=3600.0, help="seconds per MCX-CL run")
    p.add_argument("--json", default=None, help="write the rows here")
    return p.parse_args(argv)


def main_layers(argv) -> int:
    import time
    args = parse_layers_args(argv)
    t_start = time.perf_counter()
    from warpe_cl.api import get_engine
    try:
        python = ensure_venv(venv_path(args.mcxcl_venv))
        wd = workdir()
        icd, gpuid, _name = first_mcx_device(python, args.mcxcl_icd, wd, args.mcxcl_gpuid)
    except McxclUnavailable as err:
        print(f"mcxcl_compare layers: {err}", file=sys.stderr)
        return 3
    engine = get_engine(args.device)
    cases = [("two layers", LAYERS_MM)]
    if not args.no_control:
        cases.append(("control, one index", control_layers(LAYERS_MM)))
    rows = []
    for label, layers_mm in cases:
        try:
            rows.append(run_layers_case(label, layers_mm, args, engine, python, icd, gpuid, wd))
        except McxclUnavailable as err:
            print(f"mcxcl_compare layers: {err}", file=sys.stderr)
            return 3
        print(rows[-1]["report"], flush=True)
    wall = time.perf_counter() - t_start
    passed = all(r["compare"]["passed"] for r in rows)
    print(f"total {wall:.0f} s; " + ("PASS" if passed else "FAIL"))
    if args.json:
        Path(args.json).write_text(json.dumps({"argv": argv, "wall_s": wall, "passed": passed,
                                               "cases": [{k: v for k, v in r.items()
                                                          if k != "report"} for r in rows]},
                                              indent=1))
    return 0 if passed else 1


#: The box-face probe: a non-scattering slab of n = 1.5, 8 mm, as one medium or as two equal
#: media (3 + 5 mm), so that only the medium's label changes (``faces``).
PROBE_N = 1.5
PROBE_STACKS = {"one medium": ((8, 1e-5, 0.0, 0.0, PROBE_N),),
                "two equal media": ((3, 1e-5, 0.0, 0.0, PROBE_N), (5, 1e-5, 0.0, 0.0, PROBE_N))}


def probe_expectation(n: float = PROBE_N) -> dict:
    """A photon launched inside a non-scattering, non-absorbing slab along the normal, between
    two Fresnel faces of reflectance R = ((n − 1)/(n + 1))²: it leaves through the far face
    with probability 1/(1 + R) and back through its own with R/(1 + R)."""
    r = ((n - 1.0) / (n + 1.0)) ** 2
    return {"R": r, "top": r / (1.0 + r), "bottom": 1.0 / (1.0 + r)}


def probe_row(label: str, pad: str, result: dict, n: float = PROBE_N) -> dict:
    """The probe's fractions leaving through the top and the bottom, against
    :func:`probe_expectation` (binomial standard errors)."""
    n_ph = int(result["nphoton"])
    exp = probe_expectation(n)
    top = int(result["faces"]["top"]["photons"])
    m, se = mean_and_se(top, top, n_ph)
    se_exp = float(np.sqrt(exp["top"] * (1 - exp["top"]) / n_ph))
    return {"label": label, "pad": pad, "photons": n_ph, "top": m, "top_err": se,
            "bottom": int(result["faces"]["bottom"]["photons"]) / n_ph,
            "side": int(result["faces"]["side"]["photons"]) / n_ph, "expected_top": exp["top"],
            "z": float((m - exp["top"]) / se_exp)}


def main_faces(argv) -> int:
    """``faces``: the box-face probe (why the layered comparison pads the stack with vacuum)."""
    import argparse
    p = argparse.ArgumentParser(prog="python tools/studies/mcxcl_compare.py faces",
                                description="MCX-CL's Fresnel at the box's faces, medium by "
                                            "medium: a non-scattering slab of n = 1.5 as one "
                                            "or two media, at the box's faces or padded with "
                                            "vacuum. Exit status 1 if a padded case misses the "
                                            "expected reflectance by more than 5 sigma.")
    p.add_argument("--photons", type=float, default=1e5)
    p.add_argument("--box", type=float, default=60.0)
    p.add_argument("--mcxcl-icd", default="system")
    p.add_argument("--mcxcl-gpuid", type=int, default=None)
    p.add_argument("--mcxcl-venv", default=None)
    args = p.parse_args(argv)
    try:
        python = ensure_venv(venv_path(args.mcxcl_venv))
        wd = workdir()
        icd, gpuid, name = first_mcx_device(python, args.mcxcl_icd, wd, args.mcxcl_gpuid)
        rows = []
        for label, stack in PROBE_STACKS.items():
            for pad in ("none", "vacuum"):
                params = layered_params(stack)
                scene = mcx_layers_scene(params, int(args.photons), box_mm=args.box, pad=pad,
                                         gpuid=gpuid)
                case_dir = Path(wd) / f"faces_{len(stack)}_{pad}"
                case_dir.mkdir(parents=True, exist_ok=True)
                rows.append(probe_row(label, pad, run_mcx(python, icd, scene, case_dir)))
    except McxclUnavailable as err:
        print(f"mcxcl_compare faces: {err}", file=sys.stderr)
        return 3
    exp = probe_expectation()
    print(f"MCX-CL on {name}: photons launched inside along the normal of a non-scattering slab "
          f"of n = {PROBE_N} (R = {exp['R']:.4f} per face); expected top {exp['top']:.5f}, "
          f"bottom {exp['bottom']:.5f}")
    print(f"  {'stack':>16} {'padding':>8} {'top':>17} {'bottom':>8} {'side':>7} {'z':>7}")
    for r in rows:
        print(f"  {r['label']:>16} {r['pad']:>8} {r['top']:.5f} ± {r['top_err']:.5f} "
              f"{r['bottom']:.5f} {r['side']:.5f} {r['z']:+7.1f}")
    bad = [r for r in rows if r["pad"] == "vacuum" and abs(r["z"]) > Z_LIMIT]
    return 1 if bad else 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["layers"]:
        return main_layers(argv[1:])
    if argv[:1] == ["faces"]:
        return main_faces(argv[1:])
    print("usage: python tools/studies/mcxcl_compare.py layers|faces [options] (--help for "
          "the options); the one-layer comparison runs from "
          "python tools/bench/bench.py --compare mcxcl",
          file=sys.stderr)
    return 2


# ---------------------------------------------------------------------------------------------
# MCX-CL's own environment

def venv_path(option: str | None = None) -> Path:
    """The MCX-CL venv: the option, else ``$WARPE_MCXCL_VENV``, else /tmp/mcxcl-venv."""
    return Path(option or os.environ.get("WARPE_MCXCL_VENV") or DEFAULT_VENV)


def ensure_venv(path: Path, log=print) -> Path:
    """A venv at ``path`` with numpy and pmcxcl 0.7.5 (created on first use); its python.

    Raises
    ------
    McxclUnavailable
        When the venv cannot be created or pmcxcl cannot be installed or imported.
    """
    python = path / "bin" / "python"

    def check():
        probe = subprocess.run([str(python), "-c", "import numpy, pmcxcl; print(pmcxcl.__version__)"],
                               capture_output=True, text=True)
        # pmcxcl prints a hint about the optional pmcx package first: read the last line
        return probe.returncode == 0 and probe.stdout.strip().splitlines()[-1:] == [PMCXCL_VERSION]

    if python.exists() and check():
        return python
    log(f"# creating MCX-CL's venv at {path} (numpy, pmcxcl=={PMCXCL_VERSION}) ...")
    steps = []
    if not python.exists():
        steps.append([_base_python(), "-m", "venv", str(path)])
    steps.append([str(python), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                  "numpy", f"pmcxcl=={PMCXCL_VERSION}"])
    for cmd in steps:
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["(no output)"]
            raise McxclUnavailable(
                f"could not prepare MCX-CL's venv at {path}: `{' '.join(cmd)}` failed: {tail[0]}; "
                f"point $WARPE_MCXCL_VENV (or --mcxcl-venv) at a venv with numpy and "
                f"pmcxcl=={PMCXCL_VERSION}, or leave out --compare mcxcl")
    if not check():
        raise McxclUnavailable(f"{python} cannot import pmcxcl {PMCXCL_VERSION} after installing "
                               "it; remove the venv and try again")
    return python


def _base_python() -> str:
    """A python that can make venvs (the base interpreter of ours when we run in a venv)."""
    base = Path(sys.base_prefix) / "bin" / "python3"
    return str(base) if base.exists() else sys.executable


def system_libstdcxx() -> str | None:
    """The system's 64-bit libstdc++.so.6 (``ldconfig -p``), for LD_PRELOAD."""
    try:
        text = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True).stdout
    except OSError:
        text = ""
    for line in text.splitlines():
        if "libstdc++.so.6 " in line and "x86-64" in line and "=>" in line:
            return line.split("=>")[-1].strip()
    for cand in ("/lib/x86_64-linux-gnu/libstdc++.so.6", "/usr/lib64/libstdc++.so.6"):
        if os.path.exists(cand):
            return cand
    return None


def pip_pocl_icd_dir(workdir: Path) -> Path | None:
    """An ICD folder naming the PoCL library bundled with our pyopencl wheel (pip PoCL), or None."""
    try:
        import pyopencl
    except ImportError:
        return None
    libs = sorted((Path(pyopencl.__file__).parent / ".libs").glob("libpocl*.so*"))
    if not libs:
        return None
    folder = workdir / "icd-pip"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "pocl-pip.icd").write_text(f"{libs[0]}\n")
    return folder


def mcx_env(icd_dir: Path | str) -> dict:
    """The environment of the helper: OCL_ICD_VENDORS and LD_PRELOAD (see the module doc)."""
    env = dict(os.environ)
    env["OCL_ICD_VENDORS"] = str(icd_dir)
    stdcxx = system_libstdcxx()
    if stdcxx:
        env["LD_PRELOAD"] = stdcxx
    env.pop("PYTHONPATH", None)
    return env


def _helper(python: Path, args: list, env: dict, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run([str(python), str(HELPER), *args], env=env, capture_output=True,
                          text=True, timeout=timeout)


def mcx_devices(python: Path, icd_dir, workdir: Path) -> list:
    """Device names MCX-CL sees with ``OCL_ICD_VENDORS=icd_dir`` (empty if it sees none)."""
    out = workdir / "devices.json"
    proc = _helper(python, ["devices", str(out)], mcx_env(icd_dir), timeout=120)
    if proc.returncode != 0 or not out.exists():
        return []
    return json.loads(out.read_text())["devices"]


def choose_platform(choice: str, device_name: str, python: Path, workdir: Path):
    """The ICD folder and MCX ``gpuid`` (1-based) for the device named ``device_name``.

    ``choice``: ``auto`` (the system ICDs, then the pip PoCL, whichever shows a device with
    exactly our device's name), ``system`` (/etc/OpenCL/vendors), ``pip`` (the PoCL of our pyopencl
    wheel) or a folder of ``.icd`` files.
    """
    candidates = []
    if choice in ("auto", "system"):
        candidates.append(("system", SYSTEM_ICD_DIR))
    if choice in ("auto", "pip"):
        pip_dir = pip_pocl_icd_dir(workdir)
        if pip_dir is not None:
            candidates.append(("pip", pip_dir))
        elif choice == "pip":
            raise McxclUnavailable("--mcxcl-icd pip: our pyopencl wheel bundles no PoCL library")
    if choice not in ("auto", "system", "pip"):
        candidates.append((choice, choice))
    seen = []
    for label, folder in candidates:
        names = mcx_devices(python, folder, workdir)
        seen.append(f"{label} ({folder}): {names or 'no device'}")
        if device_name in names:
            return label, str(folder), names.index(device_name) + 1
    raise McxclUnavailable(f"MCX-CL sees no device named {device_name!r} (our device); it sees "
                           + "; ".join(seen) + ". Choose another --mcxcl-icd, or run our kernels "
                           "on a device MCX-CL can use (--device)")


def run_mcx(python: Path, icd_dir, request: dict, workdir: Path, timeout: float = 3600) -> dict:
    """One MCX-CL run through the helper; its JSON result (with ``log`` = the log file)."""
    req = workdir / "request.json"
    res = workdir / "result.json"
    log = workdir / f"mcx_{request['cfg']['nphoton']}_{request['vol_shape'][0]}mm.log"
    req.write_text(json.dumps(request))
    if res.exists():
        res.unlink()
    proc = _helper(python, ["run", str(req), str(res), str(log)], mcx_env(icd_dir), timeout)
    if proc.returncode != 0 or not res.exists():
        logtail = log.read_text().strip().splitlines()[-3:] if log.exists() else []
        msg = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise McxclUnavailable(f"MCX-CL failed: {msg} {' | '.join(logtail)} (log: {log})")
    out = json.loads(res.read_text())
    out["log"] = str(log)
    return out


def workdir() -> Path:
    """A folder for the helper's request, result and log files (kept, for inspection)."""
    return Path(tempfile.mkdtemp(prefix="warpe-mcxcl-"))


__all__ = ["McxclUnavailable", "mcx_scene", "mcx_events", "compare_tpsf", "format_tpsf",
           "layered_params", "control_layers", "mcx_layers_scene", "mean_and_se", "z_score",
           "compare_layers", "format_layers", "venv_path", "ensure_venv", "choose_platform",
           "run_mcx", "workdir", "main"]


if __name__ == "__main__":
    sys.exit(main())
