"""Figures in the seed paper's style.

``plot_waveform``: log–log reflectance (ns⁻¹ sr⁻¹) against time (ns), one colour per sweep value;
scattering as solid lines, BF diffuse dashed, specular (drawn at 1e-6 ns) and BF-direct peaks
as markers (the specular leaves at t = 0, before log bins start: its marker is its fraction as if
spread over the first bin, the seed's convention; no other component's early exits are drawn:
they are in no bin, ``early_fraction``); under each curve a shaded domain where a bin would
hold fewer than ``min_rays`` rays (the Monte Carlo limit the seed shades), and the first back-and-forth time 2 h n_eff / c
as a dashed vertical line.

``plot_angular``: the seed's FOV figure: time-integrated angular reflectance of the
background scattering and the BF diffuse, with their numerical FOVs.
"""
from __future__ import annotations

import numpy as np

SPECULAR_TIME_NS = 1e-6   # the seed draws the t = 0 specular return at 1e-6 ns


def _scenarios(ds):
    """(label, single-scenario Dataset) for each scenario."""
    if "scenario" not in ds.dims:
        yield str(ds.attrs.get("name", "")), ds
        return
    swept = [c for c in ds.coords if ds[c].dims == ("scenario",) and c != "scenario"]
    for i in range(ds.sizes["scenario"]):
        label = ", ".join(f"{c.split('.')[-1]} = {ds[c].values[i]}" for c in swept)
        yield (label if len(label) < 60 else f"scenario {i}"), ds.isel(scenario=i)


def _value(sc, name):
    if name in sc.variables:
        return float(sc[name])
    return float(sc.attrs.get(name, np.nan))


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_waveform(ds, path, title: str | None = None):
    """Draw the reflectance of every component against time and save it to ``path`` (PNG)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8.5, 5.5), constrained_layout=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    t = ds["time"].values
    width = np.diff(ds["time_edges"].values)
    lows = []
    for i, (label, sc) in enumerate(_scenarios(ds)):
        colour = colours[i % len(colours)]
        photons = float(sc["photons"])
        min_rays = 3
        for comp, style in (("scattering", "-"), ("bf_diffuse", "--")):
            r = sc["reflectance"].sel(component=comp).values
            if np.any(r > 0):
                ax.plot(t, np.where(r > 0, r, np.nan), ls=style, color=colour, lw=1.4,
                        marker=".", ms=3)   # markers: isolated bins have no line
                omega = float(sc["solid_angle"].sel(component=comp))
                floor = min_rays / (photons * omega * width)
                ax.fill_between(t, 1e-30, floor, color=colour, alpha=0.07, lw=0)
                lows.append(np.nanmin(np.where(r > 0, r, np.nan)))
        for comp, marker in (("specular", "o"), ("bf_direct", "^")):
            r = sc["reflectance"].sel(component=comp).values
            if comp == "specular" and "early_fraction" in sc.variables:
                spec = float(sc["early_fraction"].sel(component=comp))
                omega = float(sc["solid_angle"].sel(component=comp))
                r = r.copy()
                r[0] += spec / (omega * width[0])   # t = 0 < edges[0]: drawn at the first bin
            hit = r > 0
            if hit.any():
                tt = np.maximum(t[hit], SPECULAR_TIME_NS) if comp == "specular" else t[hit]
                ax.plot(tt, r[hit], ls="none", marker=marker, color=colour, ms=6,
                        mfc="none" if comp == "bf_direct" else colour)
                lows.append(r[hit].min())
        t1 = _value(sc, "first_bf_time_ns")
        if np.isfinite(t1):
            ax.axvline(t1, color=colour, ls=":", lw=1.0)
        ax.plot([], [], color=colour, lw=6, alpha=0.6, label=label)
    for comp, style in (("scattering (12°)", "-"), ("BF diffuse (3°)", "--")):
        ax.plot([], [], color="k", ls=style, label=comp)
    ax.plot([], [], "ko", label="specular (at 1e-6 ns)")
    ax.plot([], [], "k^", mfc="none", label="BF direct")
    ax.plot([], [], "k:", label="first BF time 2hn/c")
    ax.set_xscale("log")
    ax.set_yscale("log")
    if lows:
        ax.set_ylim(bottom=max(min(lows) / 10, 1e-12))
    ax.set_xlim(SPECULAR_TIME_NS / 2, t[-1])
    ax.set_xlabel("time (ns)")
    ax.set_ylabel("reflectance (ns$^{-1}$ sr$^{-1}$)")
    ax.set_title(title or str(ds.attrs.get("name", "")))
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_angular(ds, path, title: str | None = None):
    """The seed's FOV figure: angular reflectance (sr⁻¹) of the background scattering and the
    BF diffuse against emergence, with the 12° and 3° numerical FOVs."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), constrained_layout=True)
    fovs = {"scattering": 12.0, "bf_diffuse": 3.0}
    for ax, comp in zip(axes, ("scattering", "bf_diffuse")):
        for label, sc in _scenarios(ds):
            r = sc["angular_reflectance"].sel(component=comp).values
            ax.plot(sc["emergence"].values, r, marker=".", label=label or None)
        ax.axvline(fovs[comp], color="k", ls="--", lw=1)
        ax.set_xlabel("emergence (deg)")
        ax.set_ylabel("reflectance (sr$^{-1}$)")
        ax.set_title(f"{comp}: numerical FOV {fovs[comp]:g}°")
        ax.grid(True, alpha=0.3)
    fig.suptitle(title or str(ds.attrs.get("name", "")))
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
