"""MCX-CL side by side with our walk: the host side of ``bench.py --compare mcxcl``.

MCX-CL (pmcxcl 0.7.5, Qianqian Fang), run on PoCL, is the project's speed anchor
(docs/performance.md, "MCX-CL anchor"). It runs in its own virtual environment
(``$WARPE_MCXCL_VENV``, default ``/tmp/mcxcl-venv``, created on first use), never as a dependency
of warpe-cl, through ``tools/mcxcl_anchor.py`` started in a subprocess with the two environment
workarounds that running pmcxcl on PoCL needs:

- ``OCL_ICD_VENDORS`` names the OpenCL platform(s) pmcxcl's bundled ICD loader may load, so that
  MCX runs on the same device as our kernels (``--mcxcl-icd``);
- ``LD_PRELOAD`` of the system libstdc++: without it PoCL's build-option string is truncated inside
  pmcxcl and every kernel build fails with "'stdint.h' file not found".

The scene (:func:`mcx_scene`): our slab in a box of 1 mm voxels, lateral size ``box_mm`` (60 mm,
as the anchor), pencil beam at the centre of the z = 0 face along +z, Fresnel reflection on all
faces with n = 1 outside (MCX's ``isreflect``), no fluence output, every face a detector (so that
the scattering count of every photon that leaves is known), time gate ``max_time``.
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
HELPER = Path(__file__).resolve().parent / "mcxcl_anchor.py"
#: the anchor's time gates (0.05 ns; they cost MCX time even without fluence output)
ANCHOR_TSTEP_NS = 0.05
#: MCX's fixed seed in the anchor script
ANCHOR_SEED = 1648335518


class McxclUnavailable(RuntimeError):
    """MCX-CL could not be installed or started; the message says why and what to do."""


# ---------------------------------------------------------------------------------------------
# the scene and the numbers (pure: tested in tests/test_mcxcl_compare.py)

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
    if params.k != 0.0:
        raise ValueError(f"MCX-CL takes a real refractive index; this scene has k = {params.k}")
    thickness_mm = params.thickness * 1e3
    nz = int(round(thickness_mm))
    if abs(nz - thickness_mm) > 1e-6 or nz < 1:
        raise ValueError(f"the slab thickness must be a whole number of 1 mm voxels, got "
                         f"{thickness_mm} mm")
    nxy = int(round(box_mm if box_mm is not None else thickness_mm))
    ext_per_mm = params.extinction * 1e-3             # E = tau0 / h
    mus = ext_per_mm * params.omega        # omega = mus / (mus + mua): docs/physics.md §4.5
    mua = ext_per_mm * (1.0 - params.omega)
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
           "venv_path", "ensure_venv", "choose_platform", "run_mcx", "workdir"]
