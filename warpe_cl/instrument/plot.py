"""The paper's BELA figure (Barron et al. 2026, fig. WARPE_BELA) from instrument results.

Three panels, one colour per case: (top) the surface response of a perfect instrument, log–log,
diffuse R_d (ns⁻¹ sr⁻¹) as a line, the specular (drawn at 1e-6 ns) and BF-direct returns as
markers on the right-hand axis, as the fraction of the rays they hold (docs/interface.md §5.6);
cases with the same surface result (they differ only in the instrument: the BELA figure's
perfect slab and the same slab with 0.01° of roughness, since roughness acts only in the
chain) share one curve and one legend entry that says so;
(middle) the received reflectance, ``received_reflectance``: the surface response seen through
the pulse and the footprint kernel (ns⁻¹ sr⁻¹; specular and BF-direct scaled by their aperture
fraction), log scale, the expected photons at the aperture per shot in the legend;
(bottom) the sampled electric signal: the noiseless analog voltage clipped at saturation
(line), the recorded samples of one shot (dots, at their true sampling times) and the
saturation voltage (dotted); the unclipped shape scaled under saturation (dashed), whose
legend entry names the case whose identical shape it is drawn over. Photon counting (ATLAS): the histogram of time tags over all shots
against the expected photoelectrons.
"""
from __future__ import annotations

import numpy as np

from ..config.instrument_fields import SECTIONS
from ..plot import (_colours, _pyplot, cases_of, clear_of_legend, delta_fractions, fit_legend,
                    save_figure)

SPECULAR_TIME_NS = 1e-6


#: Attributes of an instrument result that are provenance, not parameters of the chain.
_PROVENANCE = {"instrument_" + k for k in ("source", "warpe_cl_version", "created_utc",
                                           "numpy_version", "host", "command", "seed", "shots")}


def _same_surface(a, b) -> bool:
    """Whether two cases hold the same surface result (the same rays, whatever instrument)."""
    if a["time"].shape != b["time"].shape or not np.array_equal(a["time"].values,
                                                                 b["time"].values):
        return False
    return all(np.array_equal(np.asarray(a[v].values), np.asarray(b[v].values), equal_nan=True)
               for v in ("reflectance", "early_fraction", "ray_count", "photons")
               if v in a.variables or v in b.variables)


def surface_groups(cases) -> list:
    """The cases (label, Dataset) grouped by surface result: a list of lists of case indices,
    in order of first appearance. Cases that differ only in the instrument (the BELA figure's
    perfect slab and the same slab with 0.01° of roughness: roughness acts only in the chain)
    share one surface response, which the top panel draws once."""
    groups = []
    for i, (_, sc) in enumerate(cases):
        for group in groups:
            if _same_surface(cases[group[0]][1], sc):
                group.append(i)
                break
        else:
            groups.append([i])
    return groups


def _instrument_differences(datasets) -> list:
    """The instrument parameters (``geometry.roughness``) whose values differ between results
    of the chain, read from their ``instrument_*`` attributes."""
    names = sorted({k for ds in datasets for k in ds.attrs
                    if k.startswith("instrument_") and k not in _PROVENANCE})
    out = []
    for name in names:
        if len({str(ds.attrs.get(name)) for ds in datasets}) > 1:
            key = name[len("instrument_"):]
            section = next((x for x in SECTIONS if key.startswith(x + "_")), None)
            out.append(f"{section}.{key[len(section) + 1:]}" if section else key)
    return out


def _shared_label(cases, group) -> str:
    """The top panel's legend label of a surface response shared by several cases."""
    labels = " = ".join(cases[i][0] for i in group)
    keys = _instrument_differences([cases[i][1] for i in group])
    what = (" and ".join(keys) + " acts" if len(keys) == 1 else
            " and ".join(keys) + " act" if keys else "they differ")
    return f"{labels}:\none surface response ({what} only in the instrument chain)"


def _xlim(cases):
    lo, hi = np.inf, -np.inf
    for _, sc in cases:
        t = sc["fine_time"].values
        r = sc["photon_rate"].values
        if np.any(r > 0):
            on = t[r > 1e-3 * r.max()]
            lo, hi = min(lo, on[0]), max(hi, on[-1])
    if not np.isfinite(lo):
        return None
    pad = 0.15 * (hi - lo) + 10.0
    return lo - pad, hi + pad


def plot_instrument(cases, path, title: str | None = None, shot: int = 0):
    """Draw the three panels for ``cases`` (a Dataset, or a list of (label, Dataset)) to ``path``.

    See ``instrument_figure``. Returns ``path``.
    """
    return save_figure(instrument_figure(cases, title, shot), path)


def instrument_figure(cases, title: str | None = None, shot: int = 0):
    """The three panels as a matplotlib Figure.

    Parameters
    ----------
    cases : xarray.Dataset or list of (str, xarray.Dataset)
        An instrument result (docs/interface.md §5.4), one case per scenario labelled by its
        swept values, or labelled single-scenario results.
    title : str, optional
        Defaults to the result's name and the instrument's.
    shot : int
        The shot whose samples are drawn.

    Returns
    -------
    matplotlib.figure.Figure
        ``fig.axes``: top, middle, bottom, then the top panel's right-hand axis (fractions of
        the rays in the specular and BF-direct returns), then, for more than six scenarios of
        one numeric swept key (colours from viridis), the colour bar. Every legend lies inside
        its panel.
    """
    plt = _pyplot()
    bar = None
    if not isinstance(cases, list):
        ds = cases
        title = title or f"{ds.attrs.get('name', '')} — {ds.attrs.get('instrument_name', '')}"
        cases = cases_of(ds)
        colours, bar = _colours(plt, ds, len(cases))   # > MAX_CYCLE of a numeric key: viridis
    else:
        cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        colours = [cycle[i % len(cycle)] for i in range(len(cases))]
    from matplotlib.legend_handler import HandlerTuple
    fig, axes = plt.subplots(3, 1, figsize=(8.5, 11), constrained_layout=True)
    top, mid, bot = axes
    frac_ax = top.twinx()
    lows, highs, fractions = [], [], []
    sat = None
    shared = {g[0]: g for g in surface_groups(cases) if len(g) > 1}   # first case -> group
    following = {i for g in shared.values() for i in g[1:]}
    top_handles, top_labels = [], []
    shapes = []   # (label, the unclipped shape scaled under saturation) drawn so far
    for i, (label, sc) in enumerate(cases):
        colour = colours[i]
        style = dict(color=colour, lw=1.3, marker=".", ms=3, ls=("-", "--", ":")[i % 3])
        # top: the surface response, drawn once for the cases that share it
        t = sc["time"].values
        rd = sum(sc["reflectance"].sel(component=c).values for c in ("scattering", "bf_diffuse"))
        if i not in following:
            line, = top.plot(t, np.where(rd > 0, rd, np.nan), **style)
            if np.any(rd > 0):
                lows.append(np.nanmin(np.where(rd > 0, rd, np.nan)))
                highs.append(rd.max())
            if i in shared:   # one entry, a line per case in its colour and style
                top_handles.append(tuple(
                    plt.Line2D([], [], **dict(style, color=colours[k], ls=("-", "--", ":")[k % 3]))
                    for k in shared[i]))
                top_labels.append(_shared_label(cases, shared[i]))
            else:
                top_handles.append(line)
                top_labels.append(label)
        for comp, marker in (("specular", "o"), ("bf_direct", "^")):
            tt, ff = delta_fractions(sc, comp)
            if ff.size:
                frac_ax.plot(tt, ff, ls="none", marker=marker, color=colour, ms=9 - 2 * (i % 3),
                             mfc="none" if comp == "bf_direct" else colour)
                fractions += list(ff)
        # middle: the received reflectance
        rr = sc["received_reflectance"].values
        mid.plot(sc["fine_time"].values, np.where(rr > 0, rr, np.nan), color=colour, lw=1.3,
                 label=f"{label}: {float(sc['photons_at_aperture'].sum()):.3g} photons at the aperture")
        # bottom: the recorded signal
        if "signal_mv" in sc:
            sat = float(sc["saturation_mv"])
            analog = sc["expected_analog_mv"].values
            base = float(sc["baseline_mv"])
            top_mv = analog.max() - base
            k = 0.9 * (sat - base) / top_mv if top_mv > 0 else None
            shape = base + (analog - base) * k if k else None
            # a scaled shape that another case's hides (the same surface, another gain) says so
            under = next((other for other, drawn in shapes
                          if drawn.shape == shape.shape and np.allclose(drawn, shape, rtol=1e-3,
                                                                        atol=1e-3 * sat)),
                         None) if k else None
            bot.plot(sc["fine_time"].values, np.minimum(analog, sat), color=colour, lw=1.3,
                     label=f"{label}: unclipped peak {analog.max():.4g} mV"
                           + (f", shape x {k:.2g}" if k else "")
                           + (f"\n(dashed: the same shape as {under}, drawn over it)" if under else ""))
            at = sc["sample_time"].values + float(sc["sampling_phase"].values[shot])
            bot.plot(at, sc["signal_mv"].values[shot], ls="none", marker="o", ms=4, color=colour)
            if k:
                bot.plot(sc["fine_time"].values, shape, color=colour, ls="--", lw=0.9)
                shapes.append((label, shape))
        else:
            shots = sc.sizes["shot"]
            hist = sc["signal_counts"].values.sum(axis=0)
            bot.step(sc["sample_time"].values, hist, where="post", color=colour,
                     label=f"{label}: {int(hist.sum())} photons in {shots} shots")
            mid_bin = sc["sample_time"].values + 0.5 * np.diff(sc["sample_time"].values[:2])
            bot.plot(mid_bin, sc["expected_counts"].values * shots, color=colour, ls=":", lw=0.8)
            if "expected_recorded_counts" in sc:
                bot.plot(mid_bin, sc["expected_recorded_counts"].values * shots, color=colour,
                         ls="--", lw=0.8)
    for a in (top, frac_ax):
        a.set_xscale("log")
        a.set_yscale("log")
    # the diffuse curves set the left range (headroom for the legend); the deltas the right
    top.set_ylim(*((max(min(lows) / 10, 1e-12), max(highs) * 1e3) if lows else (1e-6, 1.0)))
    frac_ax.set_ylim(*((min(fractions) / 10, min(max(fractions) * 10, 10.0)) if fractions
                       else (1e-6, 1.0)))
    top.set_xlabel("time (ns)")
    top.set_ylabel("diffuse reflectance (ns$^{-1}$ sr$^{-1}$)")
    frac_ax.set_ylabel("fraction of the rays", fontsize=8)
    top.set_title("surface response (perfect instrument): line = diffuse; right axis: "
                  "o specular (t = 0, at 1e-6 ns), △ BF direct", fontsize=9)
    mid.set_yscale("log")
    mid.set_xlabel("time (ns)")
    mid.set_ylabel("received reflectance (ns$^{-1}$ sr$^{-1}$)")
    mid.set_title("received reflectance: surface response through the pulse and the footprint "
                  "(specular, BF direct x aperture fraction)", fontsize=9)
    peaks = [np.nanmax(np.where(sc["received_reflectance"].values > 0,
                                sc["received_reflectance"].values, np.nan))
             for _, sc in cases if np.any(sc["received_reflectance"].values > 0)]
    if peaks:
        mid.set_ylim(min(peaks) * 1e-3, max(peaks) * 300)   # headroom for the legend
    lim = _xlim(cases)
    if lim:
        mid.set_xlim(*lim)
        bot.set_xlim(*lim)
    bot.set_xlabel("time (ns)")
    if sat is not None:
        bot.axhline(sat, color="purple", ls=":", lw=1.5, label=f"saturation {sat:g} mV")
        bot.set_ylim(0, 1.45 * sat)   # headroom for the legend
        bot.set_ylabel("electric signal (mV)")
        bot.set_title(f"sampled signal: line = noiseless analog (clipped), dots = shot {shot}, "
                      "dashed = unclipped shape x the factor shown", fontsize=9)
    else:
        bot.set_ylabel("photons per bin (all shots)")
        recorded = any("expected_recorded_counts" in sc for _, sc in cases)
        bot.set_title("photon-counting histogram (" + ("dashed: expected recorded; dotted: "
                      "expected before dead time)" if recorded else "dotted: expected, before "
                      "dead time)"), fontsize=9)
    for ax in axes:
        ax.grid(True, alpha=0.3)
        if ax is not top:
            fit_legend(ax, ax.legend(fontsize=7, loc="upper right", framealpha=0.85))
    if bar is None:
        legend = fit_legend(frac_ax, frac_ax.legend(
            top_handles, top_labels, fontsize=7, loc="upper right", framealpha=0.85,
            handler_map={tuple: HandlerTuple(ndivide=None, pad=0.4)}))   # over the markers
        clear_of_legend(legend, (top, frac_ax))
    else:
        fig.colorbar(bar[0], ax=list(axes), label=bar[1], pad=0.02, shrink=0.6)
    fig.suptitle(title or "")
    return fig
