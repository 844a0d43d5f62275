"""Figures in the style of the paper (Barron et al. 2026, "Simulation of laser travel-time on
Mercury for BELA").

``plot_waveform`` (drawn by ``waveform_figure``): log–log reflectance (ns⁻¹ sr⁻¹) against time
(ns) of the diffuse components, one colour per scenario: scattering as solid lines, BF diffuse
dashed; under each curve a shaded domain where a bin would hold fewer than ``MIN_RAYS`` rays
(the Monte Carlo limit the paper shades), and the first back-and-forth time 2 h n_eff / c as a
dotted vertical line. The delta-like returns (the specular, which leaves at t = 0 before the
first log bin, drawn at 1e-6 ns, and the BF-direct peaks) are drawn as markers on a secondary,
right-hand axis as the fraction of the launched rays they hold, and the specular's fraction is
written on the figure: divided by a bin width, their height would only measure that width
(docs/interface.md §5.6). The left y-range is set by the diffuse curves alone, and both
are raised where the legend would hide a curve or a marker. Up to
``MAX_CYCLE`` scenarios take the colour cycle and a legend entry each; more scenarios of one
numeric swept key take a sequential colormap and a colour bar labelled with the key and unit.

``plot_angular``: the paper's FOV figure: time-integrated angular reflectance of the
background scattering and the BF diffuse, with their numerical FOVs.

``select_scenarios``: the ``--scenarios`` selection of ``warpe-cl plot``.
"""
from __future__ import annotations

import json
import textwrap

import numpy as np

from .errors import ConfigError
from .metrics import metrics
from .surface import response
from .units import same_quantity, split_quantity

SPECULAR_TIME_NS = 1e-6   # the paper draws the t = 0 specular return at 1e-6 ns
MIN_RAYS = 3              # the shaded Monte Carlo limit: fewer rays than this in a bin
_FIRST = ("texture", "thickness")   # a swept block's entries shown first
MAX_CYCLE = 6             # more scenarios of a numeric sweep: a colormap and a colour bar


def _swept(ds) -> list:
    """The swept keys: the coordinates along ``scenario`` but the index itself and the
    ``<key>_text`` companions of numeric ones (docs/interface.md §5.3)."""
    along = [c for c in ds.coords if ds[c].dims == ("scenario",) and c != "scenario"]
    return [c for c in along if not (c.endswith("_text") and c[:-len("_text")] in along)]


def _written(ds, key):
    """A swept key's values as written (``"10 mm"``): its ``<key>_text`` coordinate when the
    file stores the key as numbers in canonical units, else the coordinate itself."""
    return ds[f"{key}_text"] if f"{key}_text" in ds.coords else ds[key]


def _as_dict(value):
    """A swept value given as a block (stored as JSON text), as a dict; else None."""
    if isinstance(value, str) and value.lstrip().startswith("{"):
        try:
            out = json.loads(value)
        except ValueError:
            return None
        return out if isinstance(out, dict) else None
    return None


def _short(value) -> str:
    """A value as written in a legend: numbers with 6 significant digits, lists compact."""
    if isinstance(value, (float, np.floating)):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_short(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_short(v)}" for k, v in value.items()) + "}"
    return str(value)


def scenario_labels(ds) -> list:
    """One legend label per scenario: the swept values as ``key=value`` with their units.

    Parameters
    ----------
    ds : xarray.Dataset
        A result (docs/interface.md §5); swept keys are the coordinates along ``scenario``.

    Returns
    -------
    list of str
        ``"thickness=10 mm"`` for a sweep of ``medium.thickness``; for a swept block (e.g. a
        list of whole ``medium:`` blocks, stored as JSON text) only the entries that differ
        between scenarios, e.g. ``"texture=granular, thickness=1000 mm, compacity=0.9"``. The
        key is shortened to its last part unless two swept keys share it. Without a scenario
        dimension: the result's name.
    """
    if "scenario" not in ds.dims:
        return [str(ds.attrs.get("name", ""))]
    n = ds.sizes["scenario"]
    swept = _swept(ds)
    lasts = [c.split(".")[-1] for c in swept]
    parts = [[] for _ in range(n)]
    for c, last in zip(swept, lasts):
        name = last if lasts.count(last) == 1 else c
        values = [v.item() if hasattr(v, "item") else v for v in _written(ds, c).values]
        blocks = [_as_dict(v) for v in values]
        if all(b is not None for b in blocks):
            keys = list(dict.fromkeys(k for b in blocks for k in b))
            keys.sort(key=lambda k: _FIRST.index(k) if k in _FIRST else len(_FIRST))
            varying = [k for k in keys
                       if len({json.dumps(b.get(k), sort_keys=True) for b in blocks}) > 1]
            for i, b in enumerate(blocks):
                parts[i] += [f"{k}={_short(b[k])}" for k in varying if k in b]
        else:
            for i, v in enumerate(values):
                parts[i].append(f"{name}={_short(v)}")
    return [", ".join(p) if p else f"scenario {int(ds['scenario'].values[i])}"
            for i, p in enumerate(parts)]


def _scenarios(ds):
    """(label, single-scenario Dataset) for each scenario."""
    if "scenario" not in ds.dims:
        yield str(ds.attrs.get("name", "")), ds
        return
    for i, label in enumerate(scenario_labels(ds)):
        yield label, ds.isel(scenario=i)


def cases_of(ds) -> list:
    """(label, single-scenario Dataset) for each scenario of a result.

    Parameters
    ----------
    ds : xarray.Dataset
        One scenario, or a sweep along ``scenario``.

    Returns
    -------
    list of (str, xarray.Dataset)
        The scenarios labelled by their swept values (one, labelled by the result's name,
        without a sweep).
    """
    return list(_scenarios(ds))


def numeric_sweep(ds):
    """The values, key and unit of a sweep of one numeric key, for a colour bar; else None.

    Returns
    -------
    (numpy.ndarray, str, str) or None
        The swept numbers (``"10 mm"`` gives 10.0), the key and the unit (``""`` for a pure
        number). None if not exactly one key is swept, or its values are not numbers of one
        unit.
    """
    if "scenario" not in ds.dims:
        return None
    swept = _swept(ds)
    if len(swept) != 1:
        return None
    numbers, units = [], set()
    for v in _written(ds, swept[0]).values:
        v = v.item() if hasattr(v, "item") else v
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            numbers.append(float(v))
            units.add("")
            continue
        q = split_quantity(str(v))
        if q is None:
            return None
        numbers.append(q[0])
        units.add(q[1])
    if len(units) != 1:
        return None
    return np.asarray(numbers), swept[0], units.pop()


def select_scenarios(ds, selection: str):
    """The scenarios of ``ds`` named by ``selection`` (``warpe-cl plot --scenarios``).

    Parameters
    ----------
    ds : xarray.Dataset
        A result with a ``scenario`` dimension (a file of ``warpe-cl run`` or a sweep database).
    selection : str
        Scenario indices (the ``scenario`` coordinate, which is the grid index of a database):
        a list ``"0,3,5"``, a range ``"0:4"`` (4 excluded, as in Python; ``"2:"`` to the end)
        or both ``"0:2,7"``, a range selecting the scenarios present within it (it may reach
        beyond them: it is compared with the indices, never expanded into a list); or a swept
        value ``"medium.thickness=10mm"`` (the key in full or its last part; a value with a
        unit is compared as a quantity, so ``10mm`` matches ``10 mm``), several joined by
        ``,`` all holding.

    Returns
    -------
    xarray.Dataset
        The selected scenarios, in the file's order.

    Raises
    ------
    ConfigError
        A selection that cannot be read, or that selects no scenario (one line: exit 2).
    """
    text = str(selection).strip()
    if "scenario" not in ds.dims:
        raise ConfigError("the result has a single scenario: nothing to select",
                          key="--scenarios")
    index = np.asarray(ds["scenario"].values)
    if "=" in text:
        keep = np.ones(index.size, bool)
        swept = _swept(ds)
        for term in filter(None, (t.strip() for t in text.split(","))):
            if "=" not in term:
                raise ConfigError(f"'{term}' is not KEY=VALUE", key="--scenarios")
            key, want = (s.strip() for s in term.split("=", 1))
            found = [c for c in swept if c == key] or [c for c in swept
                                                      if c.split(".")[-1] == key.split(".")[-1]]
            if len(found) != 1:
                raise ConfigError(f"'{key}' is not a swept key (swept: {', '.join(swept) or 'none'})",
                                  key="--scenarios")
            keep &= np.array([_same_value(v, want) for v in _written(ds, found[0]).values])
    else:
        # ranges are compared with the indices present, never expanded: "0:999999999" on a
        # 12-scenario database once built a list of 1e9 indices (killed at 24 GB)
        keep, singles = np.zeros(index.size, bool), set()
        for term in filter(None, (t.strip() for t in text.split(","))):
            try:
                if ":" in term:
                    lo, hi = term.split(":", 1)
                    lo = int(lo) if lo.strip() else int(index.min())
                    hi = int(hi) if hi.strip() else int(index.max()) + 1
                    if lo < hi:
                        keep |= (index >= max(lo, int(index.min()))) \
                            & (index < min(hi, int(index.max()) + 1))
                else:
                    singles.add(int(term))
            except ValueError:
                raise ConfigError(f"'{term}' is not an index, a range I:J or KEY=VALUE",
                                  key="--scenarios") from None
        keep |= np.isin(index, [i for i in singles if index.min() <= i <= index.max()])
    if not keep.any():
        raise ConfigError(f"'{text}' selects no scenario (indices {index.min()}..{index.max()})",
                          key="--scenarios")
    return ds.isel(scenario=np.flatnonzero(keep))


def _same_value(value, want: str) -> bool:
    value = value.item() if hasattr(value, "item") else value
    if str(value).replace(" ", "") == want.replace(" ", ""):
        return True
    return same_quantity(str(value), want)


def _value(sc, name):
    if name in sc.variables:
        return float(sc[name])
    return float(sc.attrs.get(name, np.nan))


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save_figure(fig, path, laid_out: bool = False):
    """Save ``fig`` to ``path`` (PNG, 120 dpi), close it, and return ``path``.

    ``laid_out``: the figure's layout is final (``clear_of_legend`` laid it out and nothing
    changed since): saved without another layout pass (about 0.1 s less per waveform figure;
    the axes stay within a pixel of where another pass would put them).
    """
    if laid_out:
        fig.set_layout_engine("none")      # keeps the axes where the last layout put them
    fig.savefig(path, dpi=120)
    _pyplot().close(fig)
    return path


def fit_legend(ax, legend, smallest: float = 5.5):
    """Keep ``legend`` inside ``ax`` (long scenario labels): shrink its font down to
    ``smallest``, then wrap its longest labels onto several lines."""
    renderer = ax.figure.canvas.get_renderer()
    box = ax.get_window_extent(renderer)
    texts = legend.get_texts()
    if not texts:
        return legend

    def too_wide():
        return legend.get_window_extent(renderer).width > 0.98 * box.width

    size = texts[0].get_fontsize()
    while too_wide() and size > smallest:
        size -= 0.5
        for text in texts:
            text.set_fontsize(size)
    originals = [text.get_text() for text in texts]
    chars = max(len(o) for o in originals)
    while too_wide() and chars > 20:
        chars = int(chars * 0.85)
        for text, original in zip(texts, originals):
            text.set_text(textwrap.fill(original, chars))
    return legend


def clear_of_legend(legend, axes, margin: float = 0.03):
    """Raise the upper limit of each log-y axis of ``axes`` until none of the points of its
    data lines lies under ``legend`` (the legend, drawn in front with little transparency,
    would hide them: a slab's BF-direct peak at 0.03 of the rays sat under the waveform
    figure's legend). ``margin``: the gap kept below the legend, in axes height. The figure
    is laid out for its final limits on return (``save_figure(..., laid_out=True)``)."""
    fig = legend.figure
    fig.draw_without_rendering()   # the final layout and legend size
    raised = False
    for ax in axes:
        to_axes = ax.transAxes.inverted()
        box = legend.get_window_extent().transformed(to_axes)
        bottom = box.y0 - margin
        if bottom < 0.2:           # a legend as tall as the panel: nothing to gain
            continue
        highest = -np.inf
        for line in ax.get_lines():
            if line.get_transform() != ax.transData:   # axvline and the like
                continue
            xy = np.asarray(line.get_xydata(), dtype=float).reshape(-1, 2)
            xy = xy[np.all(np.isfinite(xy), axis=1) & (xy[:, 1] > 0)]
            if not len(xy):
                continue
            at = to_axes.transform(ax.transData.transform(xy))
            under = ((at[:, 0] >= box.x0) & (at[:, 0] <= box.x1) & (at[:, 1] >= bottom)
                     & (at[:, 1] <= 1.0))
            if under.any():
                highest = max(highest, float(np.log10(xy[under, 1].max())))
        if np.isfinite(highest):
            lo, hi = np.log10(ax.get_ylim())
            ax.set_ylim(10 ** lo, 10 ** max(hi, lo + (highest - lo) / bottom))
            raised = True
    engine = fig.get_layout_engine()
    if raised and engine is not None:
        engine.execute(fig)        # the new limits' tick labels
    return legend


def delta_fractions(sc, comp: str):
    """Times (ns) and fractions of the launched rays of a delta-like return of one scenario.

    The same returns the instrument chain takes (:func:`warpe_cl.surface.response`:
    the specular's whole fraction, the BF-direct rays per bin over the rays launched, at the
    exact passage times 2 k h n_eff / c), so the figure and the chain cannot disagree; these
    fractions do not depend on the binning (docs/interface.md §5.6). The specular, which leaves
    at t = 0 before the first log bin, is placed at ``SPECULAR_TIME_NS``.
    """
    pairs = [(t, f) for c, t, f in response(sc).returns if c == comp]
    if comp == "specular":
        pairs = [(SPECULAR_TIME_NS, f) for _, f in pairs]
    return (np.asarray([t for t, _ in pairs], float), np.asarray([f for _, f in pairs], float))


def _colours(plt, ds, n):
    """A colour per scenario and, for more than MAX_CYCLE of one numeric key, the colour bar's
    (mappable, label)."""
    sweep = numeric_sweep(ds) if n > MAX_CYCLE else None
    if sweep is None:
        cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        return [cycle[i % len(cycle)] for i in range(n)], None
    import matplotlib as mpl
    values, key, unit = sweep
    positive = np.all(values > 0) and values.max() / values.min() > 20
    norm = (mpl.colors.LogNorm if positive else mpl.colors.Normalize)(values.min(), values.max())
    cmap = mpl.colormaps["viridis"]
    mappable = mpl.cm.ScalarMappable(norm=norm, cmap=cmap)
    return [cmap(norm(v)) for v in values], (mappable, f"{key} ({unit})" if unit else key)


def buried_echoes(sc) -> list:
    """The direct-echo delays (ns) of a stack's buried interfaces: ``echo_time`` of every
    layer but the last (whose echo is the floor's, ``first_bf_time_ns``), once each, > 0."""
    if "echo_time" not in sc:
        return []
    echoes = np.asarray(sc["echo_time"].values, dtype=float)
    return sorted({float(t) for t in echoes[:-1] if np.isfinite(t) and 0 < t < echoes[-1]})


def waveform_figure(ds, title: str | None = None):
    """The waveform figure of ``ds`` as a matplotlib Figure (``plot_waveform`` saves it).

    Parameters
    ----------
    ds : xarray.Dataset
        A result of ``warpe-cl run`` or ``warpe_cl.simulate`` (docs/interface.md §5).
    title : str, optional
        Defaults to the result's name.

    Returns
    -------
    matplotlib.figure.Figure
        ``fig.axes[0]``: the diffuse reflectance (ns⁻¹ sr⁻¹), whose y-range the diffuse
        curves alone set; ``fig.axes[1]``: its twin, the fractions of the rays in the specular
        and BF-direct returns; a colour bar axis follows for a numeric sweep of more than
        ``MAX_CYCLE`` scenarios. Each y-range is raised where the legend would hide a point
        (``clear_of_legend``).
    """
    plt = _pyplot()
    from matplotlib.patches import Patch
    fig, ax = plt.subplots(figsize=(8.5, 5.5), constrained_layout=True)
    frac_ax = ax.twinx()
    cases = list(_scenarios(ds))
    colours, bar = _colours(plt, ds, len(cases))
    t = ds["time"].values
    width = np.diff(ds["time_edges"].values)
    lows, highs, drawn, fractions, shaded = [], [], set(), [], []
    speculars = []   # (fraction, time, colour): written on the figure
    counts = {float(sc["photons"]) for _, sc in cases}   # one count: one limit, shaded once
    for (label, sc), colour in zip(cases, colours):
        photons = float(sc["photons"])
        for comp, style in (("scattering", "-"), ("bf_diffuse", "--")):
            r = sc["reflectance"].sel(component=comp).values
            if np.any(r > 0):
                ax.plot(t, np.where(r > 0, r, np.nan), ls=style, color=colour, lw=1.4,
                        marker=".", ms=3)   # markers: isolated bins have no line
                omega = float(sc["solid_angle"].sel(component=comp))
                floor = MIN_RAYS / (photons * omega * width)
                shade = colour if bar is None and len(counts) > 1 else "grey"   # else the same
                if not any(np.allclose(floor, f) and shade == c for f, c in shaded):
                    ax.fill_between(t, 1e-30, floor, color=shade, alpha=0.07, lw=0)
                    shaded.append((floor, shade))   # one shade per distinct limit
                lows.append(np.nanmin(np.where(r > 0, r, np.nan)))
                highs.append(r.max())
                drawn.add(comp)
        for comp, marker in (("specular", "o"), ("bf_direct", "^")):
            tt, ff = delta_fractions(sc, comp)
            if ff.size:
                frac_ax.plot(tt, ff, ls="none", marker=marker, color=colour, ms=6,
                             mfc="none" if comp == "bf_direct" else colour)
                drawn.add(comp)
                fractions += list(ff)
                if comp == "specular":
                    speculars.append((ff[0], tt[0], colour))
        t1 = _value(sc, "first_bf_time_ns")
        if np.isfinite(t1):
            ax.axvline(t1, color=colour, ls=":", lw=1.0)
            drawn.add("first_bf")
        for te in buried_echoes(sc):     # a stack: the echoes of its buried interfaces
            ax.axvline(te, color=colour, ls="-.", lw=0.9)
            drawn.add("echo")
        if bar is None:
            ax.plot([], [], color=colour, lw=6, alpha=0.6, label=label)
    keys = {"scattering": dict(color="k", ls="-", label="scattering (12°)"),
            "bf_diffuse": dict(color="k", ls="--", label="BF diffuse (3°)"),
            "specular": dict(color="k", marker="o", ls="none",
                             label="specular, t = 0 (right axis: fraction)"),
            "bf_direct": dict(color="k", marker="^", mfc="none", ls="none",
                              label="BF direct (right axis: fraction)"),
            "first_bf": dict(color="k", ls=":", label="first BF time 2hn/c"
                             + (" of the floor" if "echo" in drawn else "")),
            "echo": dict(color="k", ls="-.", label="echo of a buried interface 2Σhn/c")}
    for comp, kw in keys.items():
        if comp in drawn:
            ax.plot([], [], **kw)
    handles, labels = ax.get_legend_handles_labels()
    if drawn & {"scattering", "bf_diffuse"}:
        handles.append(Patch(color="grey", alpha=0.25, lw=0))
        labels.append(f"fewer than {MIN_RAYS} rays per bin (shaded)")
    for a in (ax, frac_ax):
        a.set_xscale("log")
        a.set_yscale("log")
    # without data a log axis has no range: a nominal one (nothing to stretch it)
    ax.set_ylim(max(min(lows) / 10, 1e-12), max(highs) * 10) if lows else ax.set_ylim(1e-6, 1.0)
    frac_ax.set_ylim(*((min(fractions) / 10, min(max(fractions) * 10, 10.0)) if fractions
                       else (1e-6, 1.0)))
    ax.set_xlim(SPECULAR_TIME_NS / 2, t[-1])
    ax.set_xlabel("time (ns)")
    ax.set_ylabel("diffuse reflectance (ns$^{-1}$ sr$^{-1}$)")
    frac_ax.set_ylabel("fraction of the rays: specular (o), BF direct (△)")
    frac_ax.yaxis.set_visible(bool(fractions))   # no delta return: no right-hand axis
    ax.set_title(title or str(ds.attrs.get("name", "")))
    ax.grid(True, which="major", alpha=0.3)
    if len(speculars) == 1:
        f, t0, colour = speculars[0]
        frac_ax.annotate(f"specular {f:.3g}\nof the rays at t = 0", (t0, f), xytext=(8, 0),
                         textcoords="offset points", fontsize=7, color=colour, va="center")
    elif 1 < len(speculars) <= MAX_CYCLE:   # one line each, stacked: the markers overlap
        for k, (f, _, colour) in enumerate(speculars):
            frac_ax.text(0.02, 0.03 + 0.04 * (len(speculars) - 1 - k),
                         f"specular {f:.3g} of the rays at t = 0", transform=frac_ax.transAxes,
                         fontsize=7, color=colour)
    if bar is not None:
        fig.colorbar(bar[0], ax=[ax, frac_ax], label=bar[1], pad=0.02)
    legend = fit_legend(frac_ax, frac_ax.legend(handles, labels, fontsize=7, loc="upper right",
                                                framealpha=0.85))
    clear_of_legend(legend, (ax, frac_ax))   # no curve nor marker hidden under the legend
    return fig


def plot_waveform(ds, path, title: str | None = None):
    """Draw the reflectance of every component against time and save it to ``path`` (PNG).

    See ``waveform_figure`` for what is drawn. Returns ``path``.
    """
    return save_figure(waveform_figure(ds, title), path, laid_out=True)


def plot_angular(ds, path, title: str | None = None):
    """The paper's FOV figure: angular reflectance (sr⁻¹) of the background scattering and the
    BF diffuse against emergence, with the 12° and 3° numerical FOVs.

    Scenarios are coloured and labelled as in ``waveform_figure`` (a legend, or a colour bar for
    more than ``MAX_CYCLE`` scenarios of one numeric key). Returns ``path``.
    """
    return save_figure(angular_figure(ds, title), path)


def angular_figure(ds, title: str | None = None):
    """The FOV figure of ``plot_angular`` as a matplotlib Figure (two panels, then a colour
    bar axis for more than ``MAX_CYCLE`` scenarios of one numeric key)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), constrained_layout=True)
    fovs = {"scattering": 12.0, "bf_diffuse": 3.0}
    cases = list(_scenarios(ds))
    colours, bar = _colours(plt, ds, len(cases))
    for ax, comp in zip(axes, ("scattering", "bf_diffuse")):
        for (label, sc), colour in zip(cases, colours):
            r = sc["angular_reflectance"].sel(component=comp).values
            ax.plot(sc["emergence"].values, r, marker=".", color=colour,
                    label=(label or None) if bar is None else None)
        ax.axvline(fovs[comp], color="k", ls="--", lw=1, label=f"numerical FOV {fovs[comp]:g}°")
        ax.set_xlabel("emergence (deg)")
        ax.set_ylabel("reflectance (sr$^{-1}$)")
        ax.set_title(f"{comp}: numerical FOV {fovs[comp]:g}°")
        ax.grid(True, alpha=0.3)
        fit_legend(ax, ax.legend(fontsize=7, loc="upper right", framealpha=0.85))
    if bar is not None:
        fig.colorbar(bar[0], ax=list(axes), label=bar[1], pad=0.02)
    fig.suptitle(title or str(ds.attrs.get("name", "")))
    return fig


#: The panels of the metrics figure: (metric, y label).
METRIC_PANELS = (("mean_delay", "mean delay (ns)"), ("rms_width", "RMS width (ns)"),
                 ("peak_time", "peak time (ns)"))
_MARKERS = ("o", "s", "^", "v", "D")


def _metrics_x(ds):
    """Where each scenario goes on the metrics figure's x axis: (positions, tick labels or
    None, axis label, log scale). A sweep of one numeric key: its values (log for positive
    values spanning more than a factor 20); else one position per scenario, labelled by its
    swept values (by the result's name for a single scenario)."""
    sweep = numeric_sweep(ds)
    if sweep is not None:
        values, key, unit = sweep
        log = bool(np.all(values > 0) and values.max() / values.min() > 20)
        return values, None, f"{key} ({unit})" if unit else key, log
    labels = scenario_labels(ds)
    return np.arange(len(labels), dtype=float), labels, "scenario", False


def _metrics_series(m):
    """The lines of the metrics figure: (label, component or None, prefix, with error bars,
    style). Surface: one per component that holds something. Instrument: the recorded signal,
    with its errors, and the noiseless expected signal, dashed."""
    if m.attrs.get("metrics_stage") == "instrument":
        return [("recorded signal", None, "", True, dict(color="C0", ls="-")),
                ("noiseless expected signal", None, "expected_", False,
                 dict(color="k", ls="--", lw=1.0, marker="x"))]
    return [(str(c), str(c), "", True, dict(color=f"C{i}", ls="-"))
            for i, c in enumerate(m["component"].values)
            if np.any(np.isfinite(m["mean_delay"].sel(component=c)))]


def metrics_figure(ds, after=(), title: str | None = None, stage: str | None = None):
    """The waveform metrics of ``ds`` (:func:`warpe_cl.metrics`) against the sweep, as a
    matplotlib Figure (``plot_metrics`` saves it).

    Parameters
    ----------
    ds : xarray.Dataset
        A result of ``warpe-cl run`` or ``warpe-cl instrument`` (one scenario or a sweep along
        ``scenario``; docs/interface.md §5).
    after : sequence of float
        Times (ns) of a fourth panel, ``fraction_after``; none by default.
    title : str, optional
        Defaults to the result's name (and the instrument's).
    stage : {None, "surface", "instrument"}
        Passed to :func:`warpe_cl.metrics`: None draws the recorded signal's numbers for an
        instrument result, the surface's otherwise.

    Returns
    -------
    matplotlib.figure.Figure
        One panel per metric, sharing x: mean delay, RMS width and peak time (ns), then the
        fraction after each time of ``after``, with error bars of one standard error. x is the
        swept value for a sweep of one numeric key, else the scenario's label. Surface: one
        line per component holding something (the specular, in no time bin, is left out).
        Instrument: the recorded signal with its errors, and the noiseless expected signal
        dashed (the components are summed by then).

    Raises
    ------
    ConfigError
        ``ds`` lacks what the metrics need, or is a grid (``as_grid``) rather than scenarios.
    """
    m = metrics(ds, after, stage=stage)
    extra = [d for d in m["mean_delay"].dims if d not in ("scenario", "component")]
    if extra:
        raise ConfigError(f"the metrics figure draws scenarios, not a grid along "
                          f"{', '.join(extra)}; give the result as written (not as_grid)")
    x, ticks, xlabel, log = _metrics_x(ds)
    order = np.argsort(x, kind="stable")
    panels = list(METRIC_PANELS) + ([("fraction_after", "fraction after t")]
                                    if "after" in m.dims else [])
    plt = _pyplot()
    fig, axes = plt.subplots(len(panels), 1, sharex=True, figsize=(7.5, 1.2 + 2.2 * len(panels)),
                             constrained_layout=True)
    line = "-" if ticks is None else "none"       # categories: markers, not lines between them
    for ax, (name, ylabel) in zip(axes, panels):
        for label, comp, prefix, errors, style in _metrics_series(m):
            values = m[prefix + name] if comp is None else m[prefix + name].sel(component=comp)
            for j, a in enumerate(m["after"].values if name == "fraction_after" else [None]):
                y = values if a is None else values.sel(after=a)
                err = (m[f"{name}_stderr"] if comp is None
                       else m[f"{name}_stderr"].sel(component=comp)) if errors else None
                if err is not None and a is not None:
                    err = err.sel(after=a)
                y = np.atleast_1d(y.values)[order]
                err = None if err is None else np.nan_to_num(np.atleast_1d(err.values)[order])
                ax.errorbar(x[order], y, yerr=err, capsize=3, ms=4,
                            **{"marker": _MARKERS[j % len(_MARKERS)], **style,
                               "ls": style["ls"] if line == "-" else "none"},
                            label=label if a is None else f"{label}, t = {a:g} ns")
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
    for ax in (axes[0], axes[-1]) if "after" in m.dims else axes[:1]:   # the lines' keys
        if ax.get_legend_handles_labels()[0]:
            fit_legend(ax, ax.legend(fontsize=7, loc="best", framealpha=0.85))
    bottom = axes[-1]
    if log:
        bottom.set_xscale("log")
    if ticks is not None:
        long = max(len(t) for t in ticks) > 12 or len(ticks) > 6
        bottom.set_xticks(x, ticks, rotation=30 if long else 0, ha="right" if long else "center",
                          fontsize=7)
        bottom.set_xlim(x.min() - 0.5, x.max() + 0.5)
    bottom.set_xlabel(xlabel)
    name = str(ds.attrs.get("name", ""))
    if m.attrs.get("metrics_stage") == "instrument":
        name += f" — after {ds.attrs.get('instrument_name', 'the instrument')}"
    axes[0].set_title(title or name)
    return fig


def plot_metrics(ds, path, after=(), title: str | None = None, stage: str | None = None):
    """Draw the waveform metrics of ``ds`` against its sweep and save them to ``path`` (PNG).

    See ``metrics_figure`` for what is drawn. Returns ``path``.
    """
    return save_figure(metrics_figure(ds, after, title, stage), path)
