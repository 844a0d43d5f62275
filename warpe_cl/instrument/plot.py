"""The seed's BELA figure (Barron et al. 2026, fig. WARPE_BELA) from instrument results.

Three panels, one colour per case: (top) the surface response of a perfect instrument, log–log,
diffuse R_d as a line, the specular (drawn at 1e-6 ns) and BF-direct returns as markers;
(middle) the photon rate at the receiver, as reflectance seen through the pulse and the footprint
kernel (ns⁻¹ sr⁻¹; specular and BF-direct scaled by their aperture fraction), log scale;
(bottom) the sampled electric signal: the noiseless analog voltage clipped at saturation
(line), the recorded samples of one shot (dots, at their true sampling times) and the
saturation voltage (dotted). Photon counting (ATLAS): the histogram of time tags over all shots
against the expected photoelectrons.
"""
from __future__ import annotations

import numpy as np

SPECULAR_TIME_NS = 1e-6


def cases_of(ds) -> list:
    """(label, single-scenario Dataset) for each scenario of an instrument result."""
    from ..plot import _scenarios
    return list(_scenarios(ds))


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
    """Draw the three panels for ``cases`` (a Dataset, or a list of (label, Dataset)) to ``path``."""
    from ..plot import _pyplot
    if not isinstance(cases, list):
        title = title or f"{cases.attrs.get('name', '')} — {cases.attrs.get('instrument_name', '')}"
        cases = cases_of(cases)
    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(8.5, 11), constrained_layout=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    top, mid, bot = axes
    lows = []
    sat = None
    for i, (label, sc) in enumerate(cases):
        colour = colours[i % len(colours)]
        # top: the surface response
        t = sc["time"].values
        rd = sum(sc["reflectance"].sel(component=c).values for c in ("scattering", "bf_diffuse"))
        if np.any(rd > 0):
            top.plot(t, np.where(rd > 0, rd, np.nan), color=colour, lw=1.3, label=label,
                     marker=".", ms=3, ls=("-", "--", ":")[i % 3])
            lows.append(np.nanmin(np.where(rd > 0, rd, np.nan)))
        else:
            top.plot([], [], color=colour, lw=1.3, label=label)
        for comp, marker in (("specular", "o"), ("bf_direct", "^")):
            r = sc["reflectance"].sel(component=comp).values
            hit = r > 0
            if hit.any():
                tt = np.full(hit.sum(), SPECULAR_TIME_NS) if comp == "specular" else t[hit]
                top.plot(tt, r[hit], ls="none", marker=marker, color=colour, ms=9 - 2 * (i % 3),
                         mfc="none" if comp == "bf_direct" else colour)
        # middle: photon rate at the receiver
        rr = sc["received_reflectance"].values
        mid.plot(sc["fine_time"].values, np.where(rr > 0, rr, np.nan), color=colour, lw=1.3,
                 label=f"{label}: {float(sc['photons_at_aperture'].sum()):.3g} photons at the aperture")
        # bottom: the recorded signal
        if "signal_mv" in sc:
            sat = float(sc["saturation_mv"])
            analog = sc["expected_analog_mv"].values
            bot.plot(sc["fine_time"].values, np.minimum(analog, sat), color=colour, lw=1.3,
                     label=f"{label}: unclipped peak {analog.max():.4g} mV")
            at = sc["sample_time"].values + float(sc["sampling_phase"].values[shot])
            bot.plot(at, sc["signal_mv"].values[shot], ls="none", marker="o", ms=4, color=colour)
            base = float(sc["baseline_mv"])
            top_mv = analog.max() - base
            if top_mv > 0:
                k = 0.9 * (sat - base) / top_mv
                bot.plot(sc["fine_time"].values, base + (analog - base) * k, color=colour, ls="--",
                         lw=0.9, label=f"shape (unclipped) x {k:.2g}")
        else:
            shots = sc.sizes["shot"]
            hist = sc["signal_counts"].values.sum(axis=0)
            bot.step(sc["sample_time"].values, hist, where="post", color=colour,
                     label=f"{label}: {int(hist.sum())} photons in {shots} shots")
            bot.plot(sc["sample_time"].values + 0.5 * np.diff(sc["sample_time"].values[:2]),
                     sc["expected_counts"].values * shots, color=colour, ls="--", lw=0.8)
    top.set_xscale("log")
    top.set_yscale("log")
    if lows:
        top.set_ylim(bottom=max(min(lows) / 10, 1e-12))
    top.set_xlabel("time (ns)")
    top.set_ylabel("reflectance (ns$^{-1}$ sr$^{-1}$)")
    top.set_title("surface response (perfect instrument); o specular at 1e-6 ns, △ BF direct",
                  fontsize=9)
    mid.set_yscale("log")
    mid.set_xlabel("time (ns)")
    mid.set_ylabel("reflectance at the receiver (ns$^{-1}$ sr$^{-1}$)")
    mid.set_title("photon rate at the receiver: pulse and footprint applied", fontsize=9)
    peaks = [np.nanmax(np.where(sc["received_reflectance"].values > 0,
                                sc["received_reflectance"].values, np.nan))
             for _, sc in cases if np.any(sc["received_reflectance"].values > 0)]
    if peaks:
        mid.set_ylim(min(peaks) * 1e-3, max(peaks) * 3)
    lim = _xlim(cases)
    if lim:
        mid.set_xlim(*lim)
        bot.set_xlim(*lim)
    bot.set_xlabel("time (ns)")
    if sat is not None:
        bot.axhline(sat, color="purple", ls=":", lw=1.5, label=f"saturation {sat:g} mV")
        bot.set_ylim(0, 1.1 * sat)
        bot.set_ylabel("electric signal (mV)")
        bot.set_title(f"sampled signal: line = noiseless analog (clipped), dots = shot {shot}, "
                      "dashed = unclipped shape scaled by the factor shown", fontsize=9)
    else:
        bot.set_ylabel("photons per bin (all shots)")
        bot.set_title("photon-counting histogram (dashed: expected, before dead time)", fontsize=9)
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    fig.suptitle(title or "")
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
