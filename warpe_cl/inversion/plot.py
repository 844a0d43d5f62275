"""The figure of ``warpe-cl invert --plot``: the recorded shots with the best fit and its 68 %
band, and the pairwise posterior (corner style, drawn with matplotlib: the grid posterior is
already a density on a grid, which is what a corner plot of samples would first have to
estimate). The diagonal panels carry their own scale, the median (dashed), the 68 % and 95 %
intervals and the truth when the result knows it (red line; a red star in the pairwise
panels, where the median is an orange cross)."""
from __future__ import annotations

import json
import textwrap

import numpy as np

from .posterior import cell_widths
from .space import SCALES, axis_scale


def _label(ds, dim: str) -> tuple[str, float, str]:
    """(axis label, scale, key) of a posterior dimension: lengths in mm or um."""
    coord = ds[dim]
    key = coord.attrs.get("sweep_key", dim)
    units = coord.attrs.get("units", "1")
    short = key.rsplit(".", 1)[-1]
    if units == "m":
        scale, unit = (1e3, "mm") if float(coord.max()) >= 1e-3 else (1e6, "um")
        return f"{short} ({unit})", scale, key
    return short if units in ("1", "") else f"{short} ({units})", 1.0, key


def plot_fit(ds, path) -> None:
    """Draw the fit (top) and the corner plot (below) of an inversion result to ``path``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dims = list(ds["posterior"].dims)
    n = len(dims)
    fig = plt.figure(figsize=(3.0 * max(n, 2) + 1.0, 3.0 * n + 3.2))
    grid = fig.add_gridspec(n + 1, max(n, 1), height_ratios=[1.3] + [1.0] * n)
    ax = fig.add_subplot(grid[0, :])
    if "fit_counts" in ds:
        _counts_panel(ax, ds)
    else:
        _mv_panel(ax, ds)
    ax.set_title(f"{ds.attrs.get('instrument_name', '')}: {ds.attrs.get('observed', '')}",
                 fontsize=9)
    ax.legend(fontsize=7, loc="upper right")
    post = ds["posterior"].values
    for i in range(n):
        for j in range(i + 1):
            axc = fig.add_subplot(grid[i + 1, j])
            xi_label, xi_scale, _ = _label(ds, dims[j])
            x = ds[dims[j]].values * xi_scale
            if i == j:
                other = tuple(k for k in range(n) if k != i)
                m = (post.sum(axis=other) if other else post) / _cells(ds[dims[i]].values,
                                                                      _scale_of(ds, dims[i]))
                axc.plot(x, m / m.max(), "-o", ms=2, color="C0")
                axc.set_ylim(0.0, 1.08)          # densities from zero: a flat one looks flat
                name = str(ds[dims[i]].attrs.get("sweep_key", dims[i]))
                if name in ds["parameter"].values:
                    r = ds.sel(parameter=name)
                    for lo, hi, alpha in (("low95", "high95", 0.15), ("low68", "high68", 0.3)):
                        axc.axvspan(float(r[lo]) * xi_scale, float(r[hi]) * xi_scale,
                                    color="C0", alpha=alpha)
                    axc.axvline(float(r["median"]) * xi_scale, color="C0", ls="--", lw=1.2,
                                label="median")
                    axc.set_title(_headline(r, xi_scale), fontsize=7)
                    truth = _truth(ds, name)
                    if truth is not None:
                        axc.axvline(truth * xi_scale, color="C3", lw=1.4, label="truth")
                    if i == 0:
                        axc.legend(fontsize=6, loc="upper left", frameon=False)
                axc.set_yticks([])
                axc.set_ylabel("density" if i == 0 else "")
                # every diagonal panel carries its own scale (values and unit)
                axc.tick_params(axis="x", labelbottom=True, labelsize=7)
                axc.set_xlabel(xi_label, fontsize=8)
            else:
                yl, ys, _ = _label(ds, dims[i])
                other = tuple(k for k in range(n) if k not in (i, j))
                # the remaining axes are (j, i), j < i: pcolormesh wants (y, x) = (i, j)
                m = (post.sum(axis=other) if other else post).T
                axc.pcolormesh(x, ds[dims[i]].values * ys, m, shading="nearest", cmap="Blues")
                axc.set_ylabel(yl if j == 0 else "")
                _set_scale(axc.set_yscale, ds, dims[i])
                kx = str(ds[dims[j]].attrs.get("sweep_key", dims[j]))
                ky = str(ds[dims[i]].attrs.get("sweep_key", dims[i]))
                keys = list(ds["parameter"].values)
                if kx in keys and ky in keys:
                    axc.plot(float(ds["median"].sel(parameter=kx)) * xi_scale,
                             float(ds["median"].sel(parameter=ky)) * ys, "+", color="C1",
                             ms=9, mew=1.6)
                    tx, ty = _truth(ds, kx), _truth(ds, ky)
                    if tx is not None and ty is not None:
                        axc.plot(tx * xi_scale, ty * ys, "*", color="C3", ms=10,
                                 mec="white", mew=0.6)
                axc.set_xlabel(xi_label if i == n - 1 else "")
            _set_scale(axc.set_xscale, ds, dims[j])
    if n >= 2:              # the empty upper right of the corner: what the data measure
        axt = fig.add_subplot(grid[1, n - 1])
        axt.axis("off")
        axt.text(0.0, 1.0, "\n".join(_measured_lines(ds)), va="top", ha="left", fontsize=7,
                 transform=axt.transAxes)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _measured_lines(ds) -> list:
    """The derived quantities' medians and 68 % intervals and the degeneracies, wrapped for
    the corner's empty panel."""
    lines = []
    if "derived" in ds.coords:
        lines.append("derived (median, 68 %):")
        for name in ds["derived"].values:
            r = ds.sel(derived=name)
            u = str(r["derived_units"].values)
            u = "" if u in ("1", "") else f" {u}"
            lines.append(f"  {name} {float(r['derived_median']):.3g} "
                         f"[{float(r['derived_low68']):.3g}, {float(r['derived_high68']):.3g}]{u}")
    for text in json.loads(ds.attrs.get("degeneracy", "[]")):
        lines.extend(textwrap.wrap(text, 48))
    return lines


def _truth(ds, key: str):
    """The true value of ``key`` stored in the result (``truth``), or None when unknown."""
    if "truth" not in ds or key not in ds["parameter"].values:
        return None
    value = float(ds["truth"].sel(parameter=key))
    return value if np.isfinite(value) else None


def _headline(r, scale: float) -> str:
    """A diagonal panel's title: the one-sided bound, or the median and its 68 % interval, in
    the panel's unit."""
    def f(x):
        return f"{float(x) * scale:.3g}"
    kind = int(r["bound"]) if "bound" in r else 0
    if kind in (1, 2):
        return f"{'>' if kind == 1 else '<'} {f(r['bound95'])} (95 %), median {f(r['median'])}"
    return f"median {f(r['median'])} [{f(r['low68'])}, {f(r['high68'])}] (68 %)"


def _mv_panel(ax, ds) -> None:
    """Linear-mode shots aligned on their arrivals and scaled to amplitude A, the best fit and
    its 68 % band."""
    amp = ds["shot_amplitude"].values
    big_a = float(ds["amplitude"])
    base = float(ds["fit_mv"].values[0])
    t = ds["sample_time"].values[None, :] - ds["shot_arrival"].values[:, None]
    y = base + (ds["observed_mv"].values - base) * (big_a / amp)[:, None]
    ax.plot(t.ravel(), y.ravel(), ".", ms=2, color="0.5", alpha=0.5,
            label=f"{ds.sizes['shot']} shots, aligned on their arrival, scaled to amplitude A")
    ft = ds["fit_time"].values
    ax.fill_between(ft, ds["fit_low68_mv"].values, ds["fit_high68_mv"].values, color="C1",
                    alpha=0.35, label="68 % band of the posterior")
    ax.plot(ft, ds["fit_mv"].values, color="C3", lw=1.2,
            label=f"best fit (chi2/dof {float(ds['chi2_per_dof']):.2f})")
    peak = ft[np.argmax(ds["fit_mv"].values)]
    ax.set_xlim(peak - 40, peak + 80)
    ax.set_xlabel("time from the shot's arrival (ns)")
    ax.set_ylabel("signal (mV)")


def _counts_panel(ax, ds) -> None:
    """Photon counts of all shots summed per histogram bin against the best fit (the
    expected counts of a bin of the same width, all shots) and its 68 % band."""
    n = ds.sizes["shot"]
    width = float(np.diff(ds["sample_time"].values[:2])[0])
    t = ds["sample_time"].values + 0.5 * width - float(ds["arrival_time"])
    ax.step(t, ds["observed_counts"].values.sum(axis=0), where="mid", color="0.4", lw=0.8,
            label=f"time tags of {n} shots per {width:g} ns bin")
    ft = ds["fit_time"].values
    ax.fill_between(ft, n * ds["fit_low68_counts"].values, n * ds["fit_high68_counts"].values,
                    color="C1", alpha=0.35, label="68 % band of the posterior")
    ax.plot(ft, n * ds["fit_counts"].values, color="C3", lw=1.2,
            label=f"best fit (chi2/dof {float(ds['chi2_per_dof']):.2f})")
    peak = ft[np.argmax(ds["fit_counts"].values)]
    ax.set_xlim(peak - 10, peak + 30)
    ax.set_xlabel("time from the fitted arrival (ns)")
    ax.set_ylabel("counts per bin (all shots)")


def _scale_of(ds, dim: str) -> str:
    """The interpolation coordinate of the posterior axis ``dim`` (its parameter's ``scale``;
    ``log_scale`` in files written before it; else detected from the values)."""
    key = ds[dim].attrs.get("sweep_key")
    if key in ds["parameter"].values:
        if "scale" in ds:
            return str(ds["scale"].sel(parameter=key).values)
        return "log" if bool(ds["log_scale"].sel(parameter=key)) else "linear"
    return axis_scale(ds[dim].values)


def _set_scale(setter, ds, dim: str) -> None:
    """A log axis for ln-interpolated values (ticks at 1, 2, 5 times the powers of ten,
    written out), a logit axis for -ln(1 - x) ones; labels on the major ticks only (a decade
    and a half of grain sizes would label every minor tick)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter
    scale, values = _scale_of(ds, dim), ds[dim].values
    if scale == "log" and values.min() > 0:
        setter("log")
    elif scale == "log1m" and values.min() > 0 and values.max() < 1:
        setter("logit")
    else:
        return
    axis = setter.__self__.xaxis if setter.__name__ == "set_xscale" else setter.__self__.yaxis
    axis.set_minor_formatter(NullFormatter())
    if scale == "log":      # 1-2-5 values written out: a grid spans a decade or two at most
        axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))


def _cells(values: np.ndarray, scale: str) -> np.ndarray:
    """Trapezoid widths of the points in their interpolation coordinate: mass / width is the
    density the prior is uniform in."""
    return cell_widths(SCALES[scale][0](values)) if values.size > 1 else np.ones(1)
