#!/usr/bin/env python3
"""The limit of small cones: the FOV estimate of the diffuse reflectance against the nadir one.

    python tools/studies/nadir_cones.py [--preset PATH] [--photons N] [--cones 1,3,6,12]
                                        [--rules history,time_window]
                                        [--solid-angle cone|projected]
                                        [--set KEY=VALUE ...] [--device SPEC]
                                        [--figure docs/figures/nadir_cones.png]

The paper estimates the diffuse reflectance (``bf_diffuse`` + ``scattering``) by counting the
rays that leave inside a cone of half-angle theta about the zenith (12 deg for the background,
3 deg for the BF diffuse); the next-event ("nadir") estimator scores the exact view direction.
As theta -> 0 the cone's count per solid angle tends to the bidirectional reflectance at
nadir, ``nadir_brdf``; at a finite theta it differs from it by the angular variation of the
reflectance over the cone, O(theta^2). This tool measures that difference on a preset
(default presets/paper/fov_numerical.yaml, the paper's FOV study), once per component rule
(``--rules``; the diffuse sum does not depend on the rule, but each rule walks its own random
numbers, so the two are independent replicas, and the nadir split into components is checked
against the FOV one under each rule):

(a) time-integrated, from ONE run's ``angular_reflectance``: the diffuse rows summed over the
    1-degree rings below the cone angle, the ring counts recovered as
    angular_reflectance x N x pi (sin^2 e2 - sin^2 e1), and renormalised to the cone's solid
    angle, counts / (N Omega) (Omega = 2 pi (1 - cos theta) or pi sin^2 theta, the preset's
    ``simulation.solid_angle`` unless --solid-angle); Poisson error sqrt(counts) / (N Omega);
    against the diffuse sum of ``nadir_brdf``, whose standard error is the spread of the
    walk's 32 batches of the *summed* rows (both rows come from the same rays, so their errors
    are not added in quadrature: the tool reads the walk's batch sums for it);
(b) time-resolved, one run per cone with ``fov.scattering = fov.bf_diffuse = theta``: the
    diffuse sum of ``reflectance`` against that of ``nadir_reflectance``, bin by bin (bins
    holding at least --min-rays FOV rays): the ratio FOV / nadir per bin with its error
    (errors of FOV and nadir combined in quadrature), its chi^2 / dof against the flat-BRDF
    expectation and the ratio of the sums over those bins.

A slab over its vacuum gap (the paper's presets) and a stack are estimated with the mirror
paths of their Fresnel faces (docs/walk.md §8.5). warpe-cl makes no nadir estimate where the
faces reflect more paths than the estimator follows (warpe_cl/nadir.py, ``mirror_below``):
the tool stops there with the reason.

With ``cone`` normalisation a reflectance flat in angle reads (1 + cos theta) / 2 of the BRDF
in the cone (counts / N = f pi sin^2 theta); the tables print that expectation (``flat``) next
to each ratio, 1 with ``projected``. Prints the tables with the machine and the OpenCL device
and draws the two-panel figure (--figure; ``--figure ''`` draws none).
"""
from __future__ import annotations

import argparse
import datetime as dt
import math
import os
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import warpe_cl
from warpe_cl.api import get_engine, walk_params
from warpe_cl.errors import WarpeWarning
from warpe_cl.nadir import _batch_error, mirror_below
from warpe_cl.params import NADIR_ROWS, fixed_to_float

# the load average is read as the benchmarks read it: tools/bench/_common.py
sys.path.append(str(Path(__file__).resolve().parent.parent / "bench"))
from _common import loadavg  # noqa: E402

DEFAULT_PRESET = Path("presets/paper/fov_numerical.yaml")
DIFFUSE = ("bf_diffuse", "scattering")


# ---------------------------------------------------------------- runs

def run_with_counts(cfg, device=None):
    """``warpe_cl.simulate(cfg)`` and the walk's raw counts (for the batch sums of the nadir
    rows), with the seconds the engine spent walking.

    Parameters
    ----------
    cfg : Config
    device : str, optional
        Device spec (``None``: the default OpenCL device).

    Returns
    -------
    (xarray.Dataset, Counts, float)
    """
    engine = get_engine(device)
    kept = []
    run = engine.run

    def spy(*args, **kwargs):
        counts = run(*args, **kwargs)
        kept.append(counts)
        return counts

    engine.run = spy                       # an instance attribute: the class is untouched
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", WarpeWarning)
            ds = warpe_cl.simulate(cfg, device=device, progress=False)
    finally:
        del engine.run
    return ds, kept[-1], float(engine.last_walk_s)


def machine_line(device=None) -> str:
    """Host, CPU, cores, OpenCL device / platform / driver, load average, date."""
    prov = get_engine(device).provenance
    return (f"{platform.node()} | {platform.processor() or platform.machine()} | "
            f"{os.cpu_count()} cores | {prov.get('opencl_device', '?')} | "
            f"{prov.get('opencl_platform', '?')} | driver {prov.get('opencl_driver', '?')} | "
            f"load average {loadavg()} | "
            f"{dt.datetime.now(dt.timezone.utc).isoformat(timespec='seconds')}")


def nadir_refusal(preset, overrides: dict) -> str | None:
    """Why warpe-cl declines the nadir estimate for ``preset`` with ``overrides`` (Fresnel
    faces that reflect more mirror paths than the estimator follows: what the result's
    ``nadir_estimator`` attribute says), or None where it makes it."""
    cfg = warpe_cl.load_preset(preset, overrides={**overrides, "simulation.nadir": True})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # doubtful-input warnings: not the question here
        params, _ = walk_params(cfg)
    if getattr(params, "nadir", False):
        return None
    return f"no nadir estimate: {mirror_below(params)} (docs/walk.md §8.5)"


def check_estimator(preset, overrides: dict) -> None:
    """SystemExit with the reason where warpe-cl makes no nadir estimate for ``preset`` with
    ``overrides`` (faces that reflect more mirror paths than the estimator follows,
    docs/walk.md §8.5)."""
    reason = nadir_refusal(preset, overrides)
    if reason is not None:
        raise SystemExit(f"no nadir estimate for {preset}: {reason}")


# ---------------------------------------------------------------- estimates

def cone_solid_angle(theta_deg: float, kind: str) -> float:
    """Solid angle of a cone of half-angle theta: ``cone`` 2 pi (1 - cos), ``projected``
    pi sin^2."""
    t = math.radians(theta_deg)
    return 2 * math.pi * (1 - math.cos(t)) if kind == "cone" else math.pi * math.sin(t) ** 2


def flat_ratio(theta_deg: float, kind: str) -> float:
    """What counts / (N Omega) reads, as a fraction of the BRDF, for a reflectance flat over
    the cone: (1 + cos theta) / 2 with ``cone``, 1 with ``projected``."""
    return (1 + math.cos(math.radians(theta_deg))) / 2 if kind == "cone" else 1.0


def ring_counts(ds, components=DIFFUSE) -> np.ndarray:
    """Rays per 1-degree emergence ring (time-integrated) of the summed components, recovered
    from ``angular_reflectance`` (per projected solid angle): A x N x pi (sin^2 e2 - sin^2 e1)."""
    e = np.radians(np.arange(ds.sizes["emergence"] + 1, dtype=float))
    proj = np.pi * (np.sin(e[1:]) ** 2 - np.sin(e[:-1]) ** 2)
    ar = ds["angular_reflectance"].sel(component=list(components)).sum("component").values
    return ar * float(ds["photons"]) * proj


def fov_cone(ds, theta_deg: int, kind: str, components=DIFFUSE) -> tuple:
    """Time-integrated FOV estimate in a cone of ``theta_deg`` whole degrees from the rings:
    (value, Poisson sigma, rays), value = rays / (N Omega), sigma = sqrt(rays) / (N Omega)."""
    rays = float(np.rint(ring_counts(ds, components)[:int(theta_deg)]).sum())
    norm = float(ds["photons"]) * cone_solid_angle(theta_deg, kind)
    return rays / norm, math.sqrt(rays) / norm, rays


def nadir_sum(ds, counts, components=DIFFUSE) -> dict:
    """The nadir estimate of the summed components: ``brdf`` and ``brdf_err`` (sr^-1, every
    time), ``refl`` and ``refl_err`` (n_time, ns^-1 sr^-1), the errors from the spread of the
    walk's batches of the summed rows (warpe_cl/nadir.py, _batch_error); ``bin_sums``
    (batches, n_time) and ``batch`` (photons per batch), for the error of a sum over bins."""
    rows = [NADIR_ROWS.index(c) for c in components]
    sums = fixed_to_float(counts.nadir_sum)[:, rows].sum(axis=1)        # (B, n_time + 2)
    batch = counts.nadir_batch_photons
    width = np.diff(ds["time_edges"].values)
    n_time = len(width)
    err = _batch_error(sums, batch)
    return {"brdf": float(ds["nadir_brdf"].sel(component=list(components)).sum()),
            "brdf_err": float(_batch_error(sums.sum(axis=-1), batch)),
            "refl": ds["nadir_reflectance"].sel(component=list(components)).sum("component").values,
            "refl_err": err[1:n_time + 1] / width,
            "bin_sums": sums[:, 1:n_time + 1], "batch": batch}


def fov_time(ds, components=DIFFUSE) -> tuple:
    """The FOV ``reflectance`` of the summed components per time bin, its Poisson error (the
    components' rays are disjoint: errors in quadrature) and the rays per bin."""
    sel = ds.sel(component=list(components))
    value = sel["reflectance"].sum("component").values
    err = np.sqrt((sel["reflectance_stderr"] ** 2).sum("component").values)
    return value, err, sel["ray_count"].sum("component").values


def time_compare(ds, nad: dict, expect: float, min_rays: int) -> dict:
    """Bin-by-bin FOV / nadir of the diffuse sum over the bins with >= min_rays FOV rays and a
    positive nadir estimate: ratio and error per bin, chi^2 / dof of the ratio against
    ``expect``, the largest |z| and the ratio of the sums (x bin width) over those bins."""
    fov, ferr, rays = fov_time(ds)
    width = np.diff(ds["time_edges"].values)
    use = (rays >= min_rays) & (nad["refl"] > 0)
    ratio = np.full_like(fov, np.nan)
    rerr = np.full_like(fov, np.nan)
    ratio[use] = fov[use] / nad["refl"][use]
    rerr[use] = ratio[use] * np.hypot(ferr[use] / fov[use], nad["refl_err"][use] / nad["refl"][use])
    z = (ratio[use] - expect) / rerr[use]
    fs, ns = np.sum(fov[use] * width[use]), np.sum(nad["refl"][use] * width[use])
    fse = math.sqrt(np.sum((ferr[use] * width[use]) ** 2))
    # the nadir error of a sum over bins: the batches of the summed bins (not in quadrature:
    # one ray scores in many bins)
    nse = float(_batch_error(nad["bin_sums"][:, use].sum(axis=-1), nad["batch"]))
    sum_ratio = fs / ns if ns > 0 and fs > 0 else float("nan")
    return {"time": ds["time"].values, "ratio": ratio, "ratio_err": rerr, "use": use,
            "bins": int(use.sum()), "chi2_dof": float(np.sum(z ** 2) / max(len(z), 1)),
            "max_abs_z": float(np.max(np.abs(z))) if len(z) else float("nan"),
            "sum_ratio": sum_ratio,
            "sum_ratio_err": sum_ratio * math.hypot(fse / fs, nse / ns) if use.any() else math.nan}


# ---------------------------------------------------------------- the study

def study(args) -> dict:
    """Every run of the tool: per rule, (a) one run and the cone estimates from its rings, the
    per-component split at 3 deg; (b) one run per cone and its time-resolved comparison."""
    out = {}
    for rule in args.rules:
        base = {"simulation.photons": args.photons, "simulation.component_rule": rule,
                **args.overrides}
        check_estimator(args.preset, base)
        cfg = warpe_cl.load_preset(args.preset, overrides=base)
        kind = args.solid_angle or cfg.get("simulation.solid_angle")
        t0 = time.perf_counter()
        ds, counts, walk = run_with_counts(cfg, args.device)
        nad = nadir_sum(ds, counts)
        rows = []
        for theta in args.cones:
            value, sigma, rays = fov_cone(ds, theta, kind)
            rows.append({"cone": theta, "fov": value, "fov_err": sigma, "rays": rays,
                         "flat": flat_ratio(theta, kind)})
        split = []
        for comp in DIFFUSE:
            value, sigma, _ = fov_cone(ds, 3, kind, (comp,))
            split.append({"component": comp, "fov": value, "fov_err": sigma,
                          "nadir": float(ds["nadir_brdf"].sel(component=comp)),
                          "nadir_err": float(ds["nadir_brdf_stderr"].sel(component=comp))})
        timed = []
        for theta in args.cones:
            over = {**base, "simulation.fov.scattering": f"{theta} deg",
                    "simulation.fov.bf_diffuse": f"{theta} deg", "simulation.solid_angle": kind}
            dsc, cc, _ = run_with_counts(warpe_cl.load_preset(args.preset, overrides=over),
                                         args.device)
            timed.append({"cone": theta, **time_compare(dsc, nadir_sum(dsc, cc),
                                                       flat_ratio(theta, kind), args.min_rays)})
        out[rule] = {"kind": kind, "nadir": nad, "cones": rows, "split": split, "timed": timed,
                     "walk_s": walk, "seconds": time.perf_counter() - t0,
                     "t1": float(ds.attrs.get("first_bf_time_ns", float("nan"))),
                     "name": ds.attrs.get("name", "")}
    return out


def print_tables(res: dict, args) -> None:
    """The tables of (a), the split at 3 deg and (b), per rule."""
    for rule, r in res.items():
        nad = r["nadir"]
        print(f"\n== {r['name']} | component_rule {rule} | {args.photons:.3g} photons | "
              f"solid angle {r['kind']} | walk {r['walk_s']:.2f} s, {r['seconds']:.1f} s in all")
        print(f"(a) time-integrated diffuse (bf_diffuse + scattering), sr^-1; nadir_brdf "
              f"{nad['brdf']:.5g} +- {nad['brdf_err']:.2g}")
        print(f"  {'cone':>6} {'rays':>9} {'FOV':>10} {'+-':>8} {'nadir':>10} {'+-':>8} "
              f"{'FOV/nadir':>10} {'+-':>7} {'flat':>7} {'z':>6}")
        for c in r["cones"]:
            ratio = c["fov"] / nad["brdf"]
            rerr = ratio * math.hypot(c["fov_err"] / c["fov"], nad["brdf_err"] / nad["brdf"])
            z = (c["fov"] - c["flat"] * nad["brdf"]) / math.hypot(c["fov_err"],
                                                                  c["flat"] * nad["brdf_err"])
            c.update(ratio=ratio, ratio_err=rerr, z=z)
            print(f"  {c['cone']:>4} deg {c['rays']:>9.0f} {c['fov']:>10.5g} {c['fov_err']:>8.2g} "
                  f"{nad['brdf']:>10.5g} {nad['brdf_err']:>8.2g} {ratio:>10.4f} {rerr:>7.4f} "
                  f"{c['flat']:>7.4f} {z:>6.2f}")
        print("  split at 3 deg (each component, time-integrated, sr^-1):")
        for s in r["split"]:
            z = (s["fov"] - flat_ratio(3, r["kind"]) * s["nadir"]) / math.hypot(s["fov_err"],
                                                                                s["nadir_err"])
            print(f"    {s['component']:<11} FOV {s['fov']:.5g} +- {s['fov_err']:.2g}   nadir "
                  f"{s['nadir']:.5g} +- {s['nadir_err']:.2g}   z {z:+.2f}")
        print(f"(b) time-resolved diffuse, FOV / nadir per bin (bins with >= {args.min_rays} FOV "
              f"rays; first back-and-forth time t1 = {r['t1']:.4g} ns)")
        print(f"  {'cone':>6} {'bins':>5} {'sum FOV/sum nadir':>18} {'+-':>7} {'flat':>7} "
              f"{'chi2/dof':>9} {'max|z|':>7}")
        for t in r["timed"]:
            print(f"  {t['cone']:>4} deg {t['bins']:>5} {t['sum_ratio']:>18.4f} "
                  f"{t['sum_ratio_err']:>7.4f} {flat_ratio(t['cone'], r['kind']):>7.4f} "
                  f"{t['chi2_dof']:>9.2f} {t['max_abs_z']:>7.2f}")
    print("\nz = (FOV - flat x nadir) / sigma, errors of FOV (Poisson) and nadir (spread of "
          "the walk's 32 batches) in quadrature; flat: FOV / nadir for a reflectance flat over "
          "the cone.")


def draw(res: dict, path: Path, args) -> None:
    """(a) FOV / nadir against the cone angle, per rule; (b) FOV / nadir per time bin, per
    cone, for the first rule."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.6))
    first = next(iter(res))
    for k, (rule, r) in enumerate(res.items()):
        cones = np.array([c["cone"] for c in r["cones"]], dtype=float)
        ratio = np.array([c["ratio"] for c in r["cones"]])
        err = np.array([c["ratio_err"] for c in r["cones"]])
        ax1.errorbar(cones * (1 + 0.03 * k), ratio, err, marker="os"[k % 2], capsize=3,
                     ls="none", label=f"FOV / nadir, {rule}")
    grid = np.linspace(0.5, max(args.cones) * 1.1, 100)
    kind = res[first]["kind"]
    ax1.plot(grid, [flat_ratio(t, kind) for t in grid], "k--", lw=1,
             label=f"flat BRDF ({kind} normalisation)")
    ax1.axhline(1.0, color="0.6", lw=0.8)
    ax1.set_xscale("log")
    ax1.set_xticks(args.cones)
    ax1.set_xticklabels([str(c) for c in args.cones])
    ax1.set_xlabel("cone half-angle (deg)")
    ax1.set_ylabel("diffuse reflectance, FOV / nadir (time-integrated)")
    ax1.set_title("(a) angular_reflectance rings vs nadir_brdf")
    ax1.legend(fontsize=8)
    r = res[first]
    for k, t in enumerate(r["timed"]):
        use = t["use"]
        ax2.errorbar(t["time"][use] * (1 + 0.015 * k), t["ratio"][use], t["ratio_err"][use],
                     fmt="o", ms=3, capsize=2, lw=0.8, label=f"{t['cone']} deg")
    ax2.axhline(1.0, color="0.6", lw=0.8)
    if np.isfinite(r["t1"]):
        ax2.axvline(r["t1"], color="0.4", ls=":", lw=1, label="t1 = 2 h n / c")
    ax2.set_xscale("log")
    ax2.set_ylim(0, 2.5)
    ax2.set_xlabel("time (ns)")
    ax2.set_ylabel("diffuse reflectance, FOV / nadir (per bin)")
    ax2.set_title(f"(b) reflectance vs nadir_reflectance ({first})")
    ax2.legend(fontsize=8)
    fig.suptitle(f"{r['name']}: the limit of small cones "
                 f"({args.photons:.3g} photons per run)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def parse_set(items) -> dict:
    """``KEY=VALUE`` overrides (VALUE read as YAML: numbers, booleans, quoted strings)."""
    import yaml
    out = {}
    for item in items or []:
        key, _, value = item.partition("=")
        out[key.strip()] = yaml.safe_load(value)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--preset", default=str(DEFAULT_PRESET))
    p.add_argument("--photons", type=float, default=1e6, help="rays per run (default 1e6)")
    p.add_argument("--cones", default="1,3,6,12", help="cone half-angles, whole degrees")
    p.add_argument("--rules", default="history,time_window", help="component rules to run")
    p.add_argument("--solid-angle", choices=("cone", "projected"), default=None,
                   help="the FOV normalisation (default: the preset's simulation.solid_angle)")
    p.add_argument("--min-rays", type=int, default=20,
                   help="(b): bins with fewer FOV rays are left out (default 20)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="more overrides, e.g. --set medium.bottom_interface=none")
    p.add_argument("--device", default=None)
    p.add_argument("--figure", default="docs/figures/nadir_cones.png")
    args = p.parse_args(argv)
    args.photons = int(args.photons)
    args.cones = [int(c) for c in args.cones.split(",")]
    args.rules = [r.strip() for r in args.rules.split(",") if r.strip()]
    args.overrides = parse_set(args.set)
    t0 = time.perf_counter()
    res = study(args)
    print(f"# {machine_line(args.device)}")
    print(f"# preset {args.preset}" + (f", overrides {args.overrides}" if args.overrides else ""))
    print_tables(res, args)
    if args.figure:
        draw(res, Path(args.figure), args)
        print(f"figure: {args.figure}")
    print(f"total {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
