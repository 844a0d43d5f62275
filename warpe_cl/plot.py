"""Figures in the seed paper's style: log–log reflectance (ns⁻¹ sr⁻¹) against time (ns)."""
from __future__ import annotations

import numpy as np

COLOURS = {"specular": "tab:red", "bf_direct": "tab:purple", "bf_diffuse": "tab:green",
           "scattering": "tab:blue"}
SPECULAR_TIME_NS = 1e-6   # the seed draws the t = 0 specular return at 1e-6 ns


def _scenarios(ds):
    if "scenario" in ds.dims:
        swept = [c for c in ds.coords if ds[c].dims == ("scenario",) and c != "scenario"]
        for i in range(ds.sizes["scenario"]):
            label = ", ".join(f"{c.split('.')[-1]}={ds[c].values[i]}" for c in swept)
            yield label, ds.isel(scenario=i)
    else:
        yield "", ds


def plot_waveform(ds, path, title: str | None = None):
    """Draw the reflectance of every component against time and save it to ``path``.

    Specular returns sit at 1e-6 ns; bins with fewer than ``min_rays`` rays are drawn faint;
    the first back-and-forth time 2 h n_eff / c is a dashed line per scenario.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5.5), constrained_layout=True)
    styles = ["-", "--", ":", "-."]
    for si, (label, sc) in enumerate(_scenarios(ds)):
        ls = styles[si % len(styles)]
        t = sc["time"].values
        for comp in sc["component"].values:
            r = sc["reflectance"].sel(component=comp).values
            under = sc["undersampled"].sel(component=comp).values.astype(bool)
            name = f"{comp}" + (f" ({label})" if label else "")
            colour = COLOURS.get(str(comp), None)
            if comp in ("specular", "bf_direct"):
                mask = r > 0
                tt = np.where(t[mask] < SPECULAR_TIME_NS, SPECULAR_TIME_NS, t[mask]) \
                    if comp == "specular" else t[mask]
                if mask.any():
                    ax.plot(tt, r[mask], ls="none", marker="o" if comp == "specular" else "^",
                            color=colour, label=name)
                continue
            good = np.where(~under & (r > 0), r, np.nan)
            faint = np.where(r > 0, r, np.nan)
            ax.plot(t, faint, ls=ls, color=colour, alpha=0.25, lw=1)
            ax.plot(t, good, ls=ls, color=colour, lw=1.6, marker=".", ms=4, label=name)
        t1 = float(np.atleast_1d(sc.attrs.get("first_bf_time_ns", sc.get("first_bf_time_ns", np.nan)))[0]) \
            if ("first_bf_time_ns" in sc.attrs or "first_bf_time_ns" in sc) else np.nan
        if np.isfinite(t1):
            ax.axvline(t1, color="grey", ls=ls, lw=0.8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time (ns)")
    ax.set_ylabel("reflectance (ns$^{-1}$ sr$^{-1}$)")
    ax.set_title(title or str(ds.attrs.get("name", "")))
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
