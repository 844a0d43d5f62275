"""The figures of a design study (docs/design.md §5): a detectability map per family and
instrument, and one figure ranking the instruments.

**Detectability map.** The plane of the family's first two swept keys (their grid values, on a
log axis where the prior's coordinate is ln), coloured by the expected width ratio of up to
three parameters, the thickness, E and the grain size where the family has them (else its
first parameters): the median over the other swept keys. 1 (dark) is nothing learnt, 0
(yellow) a parameter pinned; the dotted contour is 0.5, where a parameter counts as
constrained.

**Ranking.** Per family, the instruments sorted by the mean over the parameters of their
median width ratio, each parameter's median a bar.
"""
from __future__ import annotations

import json

import numpy as np

#: What a detectability map shows, in order of preference: a key or derived name ending.
MAP_PREFERENCE = ("thickness", "extinction_per_m", "grain_size")


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def map_parameters(ds, family: str) -> list:
    """The indices (on ``parameter``) a family's map shows: the thickness, E and the grain
    size where present, else the first parameters, three at most."""
    rows = np.flatnonzero(ds["family"].values == family)
    present = [p for p in range(ds.sizes["parameter"])
               if np.any(np.isfinite(ds["node_value"].values[rows, p]))]
    names = [str(ds["parameter"].values[p]) for p in present]
    chosen = []
    for end in MAP_PREFERENCE:
        for p, n in zip(present, names):
            if n.endswith(end) and p not in chosen:
                chosen.append(p)
                break
    for p in present:
        if len(chosen) >= 3:
            break
        if p not in chosen:
            chosen.append(p)
    return chosen[:3]


def plot_map(ds, family: str, instrument: str, path) -> None:
    """Draw the detectability map of one family and one instrument to ``path``."""
    plt = _plt()
    from matplotlib.ticker import NullFormatter
    rows = np.flatnonzero(ds["family"].values == family)
    j = int(np.flatnonzero(ds["instrument"].values == instrument)[0])
    points = [json.loads(s) for s in ds["point_values"].values[rows]]
    keys = list(points[0])
    shown = map_parameters(ds, family)
    fig, axes = plt.subplots(1, len(shown), figsize=(4.2 * len(shown), 3.6), squeeze=False)
    kx = keys[0]
    ky = keys[1] if len(keys) > 1 else None
    xs = np.unique([p[kx] for p in points])
    ys = np.unique([p[ky] for p in points]) if ky else np.array([0.0])
    scale = {str(n): str(s) for n, s in zip(ds["parameter"].values,
                                            ds["parameter_scale"].values)}
    for ax, p in zip(axes[0], shown):
        grid = np.full((ys.size, xs.size), np.nan)
        values = ds["width_ratio"].values[rows, j, p]
        for iy, y in enumerate(ys):
            for ix, x in enumerate(xs):
                sel = [k for k, q in enumerate(points)
                       if q[kx] == x and (ky is None or q[ky] == y)]
                v = values[sel]
                v = v[np.isfinite(v)]
                if v.size:
                    grid[iy, ix] = np.median(v)
        mesh = ax.pcolormesh(_edges(xs, scale.get(kx)), _edges(ys, scale.get(ky)), grid,
                             vmin=0.0, vmax=1.0, cmap="viridis_r", shading="flat")
        if np.isfinite(grid).sum() >= 4 and xs.size > 1 and ys.size > 1:
            ax.contour(xs, ys, grid, levels=[0.5], colors="w", linestyles=":")
        if scale.get(kx) == "log":
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(NullFormatter())
        if ky and scale.get(ky) == "log":
            ax.set_yscale("log")
            ax.yaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel(f"{kx.rsplit('.', 1)[-1]} ({_unit(ds, kx)})")
        ax.set_ylabel(f"{ky.rsplit('.', 1)[-1]} ({_unit(ds, ky)})" if ky else "")
        ax.set_title(f"width ratio of {ds['parameter_symbol'].values[p]}")
        fig.colorbar(mesh, ax=ax, shrink=0.85)
    others = ", ".join(k.rsplit(".", 1)[-1] for k in keys[2:])
    fig.suptitle(f"{family}, {instrument} ({int(ds['shots'].values[j])} shots)"
                 + (f": median over {others}" if others else ""), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _unit(ds, key) -> str:
    if key is None:
        return ""
    i = np.flatnonzero(ds["parameter"].values == key)
    return str(ds["parameter_units"].values[i[0]]) if i.size else ""


def _edges(values: np.ndarray, scale) -> np.ndarray:
    """Cell edges around grid values: midpoints in the axis' coordinate."""
    v = np.asarray(values, float)
    if v.size == 1:
        return np.array([v[0] * 0.9, v[0] * 1.1]) if v[0] != 0 else np.array([-0.5, 0.5])
    c = np.log(v) if scale == "log" else v
    mid = 0.5 * (c[1:] + c[:-1])
    e = np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])
    return np.exp(e) if scale == "log" else e


def plot_ranking(ds, rows: list, path) -> None:
    """Draw the ranking of the instruments (module docstring) to ``path``.

    Parameters
    ----------
    ds : xarray.Dataset
        design.nc.
    rows : list of dict
        :func:`warpe_cl.design.result.summary_rows`.
    path : path
    """
    plt = _plt()
    families = list(dict.fromkeys(r["family"] for r in rows))
    fig, axes = plt.subplots(len(families), 1, figsize=(8.5, 1.2 + 0.55 * len(rows)),
                             squeeze=False)
    for ax, fam in zip(axes[:, 0], families):
        mine = [r for r in rows if r["family"] == fam]
        mine.sort(key=lambda r: np.nanmean([m for _, m, _ in r["cells"]]))
        symbols = [c[0] for c in mine[0]["cells"]]
        height = 0.8 / max(len(symbols), 1)
        for k, sym in enumerate(symbols):
            y = np.arange(len(mine)) + (k - (len(symbols) - 1) / 2) * height
            ax.barh(y, [r["cells"][k][1] for r in mine], height=height, label=sym)
        ax.set_yticks(np.arange(len(mine)))
        ax.set_yticklabels([f"{r['instrument']} ({100 * r['distinguishable']:.0f} % dist.)"
                            for r in mine])
        ax.invert_yaxis()
        ax.axvline(0.5, color="k", ls=":", lw=0.8)
        ax.set_xlim(0, 1.02)
        ax.set_xlabel("median expected width ratio (posterior / prior 95 %; best first)")
        ax.set_title(fam, fontsize=10)
        ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
