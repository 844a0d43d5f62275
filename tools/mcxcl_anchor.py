#!/usr/bin/env python3
"""Run MCX-CL (pmcxcl) once and summarise it as JSON: the side of ``bench.py --compare mcxcl``
that lives in MCX-CL's own virtual environment.

MCX-CL (pmcxcl, Qianqian Fang's Monte Carlo eXtreme for OpenCL) run on PoCL is the project's
speed anchor (docs/performance.md, "MCX-CL anchor"), and this script is the anchor run. It imports
only numpy, pmcxcl and ``tools/_common.py`` (standard library only); it is started by
``tools/mcxcl_compare.py`` with that venv's python and the two environment workarounds pmcxcl
needs on PoCL: OCL_ICD_VENDORS pointing its bundled ICD loader at the OpenCL platform to use, and
LD_PRELOAD of the system libstdc++ (without it PoCL's build options are cut short inside pmcxcl
and every kernel build fails).
pmcxcl must never become a dependency of warpe-cl.

    python mcxcl_anchor.py devices RESULT.json
        the OpenCL devices MCX-CL sees, in its order (its ``gpuid`` is the 1-based index)
    python mcxcl_anchor.py run REQUEST.json RESULT.json LOG
        one pmcxcl.run; MCX's console output goes to LOG

REQUEST (written by ``mcxcl_compare.mcx_request``): ``cfg`` (the pmcxcl configuration without
``vol``), ``vol_shape`` (voxels, all of medium 1), ``time_edges_ns`` (edges of the reflectance
histogram), ``mua_per_mm``, ``n``.

RESULT of ``run``: timings (``kernel_ms`` from MCX's own speed line, which excludes the kernel
build; ``wall_s`` around ``pmcxcl.run``), the device line of MCX's log, per exit face
(``top`` = the z = 0 face the source is on, ``bottom``, ``side``) the number of photons and the sum
of their scattering counts, the photons still inside at ``tend`` (never saved by MCX), and the
top face's reflectance histogram on ``time_edges_ns``: counts, weights w = exp(-mua L) and w².
"""
from __future__ import annotations

import json
import os
import re
import resource
import sys
import time

from _common import loadavg  # tools/ is first on sys.path when run as a script

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


def summarise_detected(detp, nz: int, mua_per_mm: float, n_index: float, edges_ns) -> dict:
    """Per-face counts and scattering sums, and the top face's time histogram, from ``detp``.

    ``detp`` has the rows of ``savedetflag = "dspx"``: detector id, scattering count (int32 bits
    stored in a float32), partial path in medium 1 (mm), exit x, y, z (voxels = mm).
    """
    import numpy as np
    detp = np.asarray(detp)
    if detp.ndim != 2 or detp.shape[0] < 6:
        detp = np.zeros((6, 0), dtype=np.float32)
    nscat = np.ascontiguousarray(detp[1], dtype=np.float32).view(np.int32).astype(np.int64)
    ppath = detp[2].astype(np.float64)
    z = detp[5].astype(np.float64)
    faces = {"top": z < 0.5, "bottom": z > nz - 0.5}
    faces["side"] = ~(faces["top"] | faces["bottom"])
    out = {"faces": {name: {"photons": int(m.sum()), "scatterings": int(nscat[m].sum()),
                            "scatterings_sq": int((nscat[m] ** 2).sum())}
                     for name, m in faces.items()}}
    top = faces["top"]
    t = ppath[top] * n_index / C_MM_PER_NS          # time inside the medium, ns
    w = np.exp(-mua_per_mm * ppath[top])            # MCX's absorption weight
    edges = np.asarray(edges_ns, dtype=float)
    out["top_tpsf"] = {"counts": np.histogram(t, edges)[0].tolist(),
                       "w": np.histogram(t, edges, weights=w)[0].tolist(),
                       "w2": np.histogram(t, edges, weights=w * w)[0].tolist()}
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
                                 req["n"], req["time_edges_ns"])
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
