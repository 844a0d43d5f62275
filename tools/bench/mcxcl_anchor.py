#!/usr/bin/env python3
"""Run MCX-CL (pmcxcl) once and summarise it as JSON: the side of ``bench.py --compare mcxcl``
that lives in MCX-CL's own virtual environment.

MCX-CL (pmcxcl, Qianqian Fang's Monte Carlo eXtreme for OpenCL) run on PoCL is the project's
speed anchor (docs/performance.md, "MCX-CL anchor"), and this script is the anchor run. It imports
only numpy, pmcxcl and ``tools/bench/_common.py`` (standard library only); it is started
by ``tools/studies/mcxcl_compare.py`` with that venv's python and the two environment
workarounds pmcxcl needs on PoCL: OCL_ICD_VENDORS pointing its bundled ICD loader at the OpenCL
platform to use, and
LD_PRELOAD of the system libstdc++ (without it PoCL's build options are cut short inside pmcxcl
and every kernel build fails).
pmcxcl must never become a dependency of warpe-cl.

    python mcxcl_anchor.py devices RESULT.json
        the OpenCL devices MCX-CL sees, in its order (its ``gpuid`` is the 1-based index)
    python mcxcl_anchor.py run REQUEST.json RESULT.json LOG
        one pmcxcl.run; MCX's console output goes to LOG

REQUEST (written by ``mcxcl_compare.mcx_scene`` or ``mcxcl_compare.mcx_layers_scene``):
``cfg`` (the pmcxcl configuration without ``vol``), ``vol_shape`` (voxels), ``time_edges_ns``
(edges of the reflectance histogram), ``mua_per_mm`` and ``n`` (one number: every voxel is
medium 1; or one per medium, with ``labels_z``, the medium label of each z slice of voxels:
layers), optionally ``frame_label`` (the label of the voxels on the four side faces),
``clock`` (per medium, 1 if its path counts in the time, 0 for a vacuum padding) and
``radius_edges_mm`` (edges of the top face's radial histogram, distance of the exit from the
source axis).

RESULT of ``run``: timings (``kernel_ms`` from MCX's own speed line, which excludes the kernel
build; ``wall_s`` around ``pmcxcl.run``), the device line of MCX's log, per exit face
(``top`` = the z = 0 face the source is on, ``bottom``, ``side``) the number of photons and the sum
of their scattering counts, and (``face_weights``) the sums of their weights w and w² over the
photons whose time is below the last edge, the photons still inside at ``tend`` (never saved by
MCX), and the top face's reflectance histogram on ``time_edges_ns``: counts, weights
w = exp(-sum_i mua_i L_i) and w², with the time sum_i L_i n_i / c over the partial paths L_i in
each medium (each medium whose ``clock`` is 1).
"""
from __future__ import annotations

import json
import os
import re
import resource
import sys
import time

from _common import loadavg  # tools/bench/ is first on sys.path when run as a script

C_MM_PER_NS = 299.792458


def parse_mcx_log(text: str) -> dict:
    """The numbers MCX-CL prints: speed (photon/ms), build and kernel-complete times (ms), the
    device it ran on, its launch line (threads, blocks) and the detected-photon count."""
    out = {"mcx_photons_per_ms": None, "build_ms": None, "kernel_complete_ms": None,
           "mcx_device": None, "launch": None, "detected": None}
    for line in text.splitlines():
        m = re.search(r"MCX simulation speed:\s*([0-9.eE+-]+)\s*photon/ms", line)
        if m:
            out["mcx_photons_per_ms"] = float(m.group(1))
        m = re.search(r"build program complete\s*:\s*([0-9.]+)\s*ms", line)
        if m:
            out["build_ms"] = float(m.group(1))
        m = re.search(r"kernel complete:\s*([0-9.]+)\s*ms", line)
        if m:
            out["kernel_complete_ms"] = float(m.group(1))
        m = re.search(r"\[device \d+\(\d+\):\s*(.*?)\]\s*(threadph=.*)$", line.strip())
        if m:
            out["mcx_device"], out["launch"] = m.group(1).strip(), m.group(2).strip()
        m = re.search(r"detected\s+(\d+)\s+photons", line)
        if m:
            out["detected"] = int(m.group(1))
    return out


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


class _StdoutTo:
    """Send file descriptor 1 (where MCX's C++ code prints) to a file for the ``with`` block."""

    def __init__(self, path):
        self.path = path

    def __enter__(self):
        sys.stdout.flush()
        self.saved = os.dup(1)
        self.fh = open(self.path, "w")
        os.dup2(self.fh.fileno(), 1)
        return self

    def __exit__(self, *exc):
        sys.stdout.flush()
        os.dup2(self.saved, 1)
        os.close(self.saved)
        self.fh.close()


def list_devices(result_path: str) -> None:
    import pmcxcl
    with _StdoutTo(os.devnull):
        info = pmcxcl.gpuinfo()
    with open(result_path, "w") as fh:
        json.dump({"devices": [d.get("name", "").strip() for d in info],
                   "pmcxcl": getattr(pmcxcl, "__version__", None)}, fh)


def summarise_detected(detp, nz: int, mua_per_mm, n_index, edges_ns, centre=None,
                       radius_edges_mm=None, clock=None) -> dict:
    """Per-face counts, scattering sums and weights, and the top face's time histogram, from
    ``detp``.

    ``detp`` has the rows of ``savedetflag = "dspx"`` for M media: detector id, M scattering
    counts (int32 bits stored in a float32), M partial paths (mm), exit x, y, z (voxels = mm).
    ``mua_per_mm`` and ``n_index`` are one number (M = 1) or one per medium (label 1 first).
    With ``centre`` (x, y of the source, mm) and ``radius_edges_mm``, ``top_radial`` is the top
    face's weight per ring of distance from the source axis. ``clock`` (one 0 or 1 per medium,
    default all 1) says whose path the time counts: 0 for a vacuum padding outside the medium.
    ``face_weights`` sum the photons whose time is below the last edge.
    """
    import numpy as np
    mua = np.atleast_1d(np.asarray(mua_per_mm, dtype=np.float64))
    nidx = np.atleast_1d(np.asarray(n_index, dtype=np.float64))
    if mua.shape != nidx.shape:
        raise ValueError(f"one mua and one n per medium: got {mua.size} and {nidx.size}")
    nm = mua.size
    rows = 1 + 2 * nm + 3
    detp = np.asarray(detp)
    if detp.ndim != 2 or detp.shape[0] < rows:
        detp = np.zeros((rows, 0), dtype=np.float32)
    nscat = (np.ascontiguousarray(detp[1:1 + nm], dtype=np.float32).view(np.int32)
             .astype(np.int64).sum(axis=0))
    ppath = detp[1 + nm:1 + 2 * nm].astype(np.float64)           # (M, photons), mm
    x, y, z = (detp[1 + 2 * nm + i].astype(np.float64) for i in range(3))
    faces = {"top": z < 0.5, "bottom": z > nz - 0.5}
    faces["side"] = ~(faces["top"] | faces["bottom"])
    w_all = np.exp(-(mua[:, None] * ppath).sum(axis=0))          # MCX's absorption weight
    ck = np.ones(nm) if clock is None else np.asarray(clock, dtype=np.float64)
    t_all = (ppath * (nidx * ck)[:, None]).sum(axis=0) / C_MM_PER_NS   # time in the medium, ns
    edges = np.asarray(edges_ns, dtype=float)
    in_time = t_all < edges[-1]
    out = {"faces": {name: {"photons": int(m.sum()), "scatterings": int(nscat[m].sum()),
                            "scatterings_sq": int((nscat[m] ** 2).sum())}
                     for name, m in faces.items()},
           "face_weights": {name: {"w": float(w_all[m & in_time].sum()),
                                   "w2": float((w_all[m & in_time] ** 2).sum()),
                                   "photons": int((m & in_time).sum())}
                            for name, m in faces.items()}}
    top = faces["top"]
    t = t_all[top]
    w = w_all[top]
    out["top_tpsf"] = {"counts": np.histogram(t, edges)[0].tolist(),
                       "w": np.histogram(t, edges, weights=w)[0].tolist(),
                       "w2": np.histogram(t, edges, weights=w * w)[0].tolist()}
    if centre is not None and radius_edges_mm is not None:
        r = np.hypot(x[top] - centre[0], y[top] - centre[1])
        redges = np.asarray(radius_edges_mm, dtype=float)
        out["top_radial"] = {"edges_mm": redges.tolist(),
                             "w": np.histogram(r, redges, weights=w)[0].tolist(),
                             "counts": np.histogram(r, redges)[0].tolist()}
    out["top_mean_scatterings"] = float(nscat[top].mean()) if top.any() else None
    out["top_weighted_mean_scatterings"] = (float((w * nscat[top]).sum() / w.sum())
                                            if top.any() else None)
    return out


def run(request_path: str, result_path: str, log_path: str) -> None:
    import numpy as np
    import pmcxcl
    with open(request_path) as fh:
        req = json.load(fh)
    cfg = dict(req["cfg"])
    if req.get("labels_z") is not None:         # layers: one medium label per z slice
        vol = np.empty(req["vol_shape"], dtype="uint8")
        vol[:, :, :] = np.asarray(req["labels_z"], dtype="uint8")[None, None, :]
        if req.get("frame_label") is not None:  # a padding on the four side faces
            vol[0, :, :] = vol[-1, :, :] = vol[:, 0, :] = vol[:, -1, :] = req["frame_label"]
        cfg["vol"] = vol
    else:
        cfg["vol"] = np.ones(req["vol_shape"], dtype="uint8")
    load0 = loadavg()
    with _StdoutTo(log_path):
        c0, t0 = _cpu_s(), time.perf_counter()
        res = pmcxcl.run(cfg)
        t1, c1 = time.perf_counter(), _cpu_s()
    with open(log_path) as fh:
        log = parse_mcx_log(fh.read())
    n = int(cfg["nphoton"])
    speed = log["mcx_photons_per_ms"]
    out = {"nphoton": n, "wall_s": t1 - t0, "cpu_s": c1 - c0,
           "kernel_ms": n / speed if speed else None, "loadavg_before": load0,
           "loadavg_after": loadavg(), "pmcxcl": getattr(pmcxcl, "__version__", None), **log}
    summary = summarise_detected(res.get("detp"), int(req["vol_shape"][2]), req["mua_per_mm"],
                                 req["n"], req["time_edges_ns"], centre=cfg["srcpos"][:2],
                                 radius_edges_mm=req.get("radius_edges_mm"),
                                 clock=req.get("clock"))
    saved = sum(f["photons"] for f in summary["faces"].values())
    out.update(summary, saved=saved, inside_at_tend=n - saved)
    with open(result_path, "w") as fh:
        json.dump(out, fh)


def main(argv) -> int:
    if len(argv) >= 2 and argv[0] == "devices":
        list_devices(argv[1])
        return 0
    if len(argv) >= 4 and argv[0] == "run":
        run(argv[1], argv[2], argv[3])
        return 0
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
