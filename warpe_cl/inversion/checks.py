"""Model checking of one inversion: the log evidence, a goodness of fit that includes every
term of the likelihood, and the warnings (docs/inversion.md §5.1-§5.3).

- **Evidence** (:func:`log_evidence`): ln Z = ln ∫ L(θ) π(θ) dθ over the grid posterior, the
  prior uniform in each axis' interpolation coordinate over the database's range, the
  per-shot amplitudes and arrivals marginalised as the likelihood does, the pulse-width
  nuisance v profiled, and the overall amplitude A integrated against a log-normal prior
  (:data:`AMPLITUDE_PRIOR_SIGMA`) by Laplace's method in ln A (:func:`amplitude_curvature`).
- **Goodness of fit** (:func:`amplitude_test`, :func:`check`): the samples' χ² (the Gaussian
  terms of the likelihood) and the per-shot amplitudes against the speckle prior N(A, A²/M)
  (the amplitude term), each with its p-value, combined by Bonferroni into ``fit_p_value``.
- **Warnings** (:func:`warnings_of`): the amplitude far from 1, the posterior piling up at a
  grid edge, a poor fit. One line each; the inversion goes on (exit 0).
"""
from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtrc     # chi2's survival function, without scipy.stats

from ..errors import WarpeWarning
from .likelihood import MODES_CAP
from .posterior import cell_widths, marginal, nearest_node_mass

#: Standard deviation of the prior on ln A, the overall amplitude relative to the instrument's
#: radiometry: a factor 3 at one standard deviation. The link budget (pulse energy, optics,
#: detector gain, range) is known to tens of percent and pointing or slope losses reach a
#: factor 2 at most, so this prior is broad against what A absorbs on a right database and
#: does not pull it (ln 1.3 = 0.26 costs 0.03 in ln Z), while a model 1000x too bright
#: (ln 1000 = 6.3 sigma) pays 20 in ln Z (docs/inversion.md §5.1).
AMPLITUDE_PRIOR_SIGMA = math.log(3.0)
#: The overall amplitude (or, with ``--fix amplitude``, the shots' median amplitude) is
#: reported as far from 1 outside this range: a factor 3, beyond what the link budget and
#: pointing losses explain (above), so that A is then absorbing a model of the wrong
#: brightness (another texture or composition) rather than a calibration error.
AMPLITUDE_RANGE = (1.0 / 3.0, 3.0)
#: The posterior piles up at a grid edge when its marginal density is largest at the edge and
#: the marginal mass gathered on the edge node (``marginal_<key>`` of FIT.nc: the half cell
#: next to the edge) exceeds this fraction and twice what a flat posterior puts there (half a
#: cell of the range: 0.25 for 3 nodes, 0.125 for 5); an axis of two nodes (a flat posterior
#: puts 0.5 on each) is never flagged. A sharp posterior inside the edge node's half cell
#: (700 mm between nodes 500 and 1000 mm) has its largest density inside, and is not flagged.
EDGE_MASS = 0.25
#: "Largest at the edge": the marginal density at the edge's grid point is at least this share
#: of the largest. Not exactly the largest: on a grid refined against the edge the density is
#: nearly flat there, and log L carries a few 0.01 of noise from the profiled nuisances.
EDGE_PEAK = 0.8
#: A fit is poor when its complete goodness of fit p-value is below this: a right database
#: is flagged once in a thousand inversions (the false alarm rate, if the p-value is
#: calibrated; the interpolation error of a coarse database adds misfit, §7).
FIT_P = 1e-3
#: Steps in ln A of the amplitude-curvature fits: the first, and the bounds.
AMPLITUDE_STEP = (0.05, 1e-4, 1.0)


@dataclass
class Checks:
    """What :func:`check` finds for one inversion (names as stored in FIT.nc).

    Attributes
    ----------
    log_evidence, log_evidence_nodes : float
        ln Z on the refined grid and on the database's nodes alone (their difference
        indicates the quadrature error).
    log_likelihood : float
        ln L at the best point (nuisances handled as in the likelihood).
    amplitude : float
        The overall amplitude A at the best point (profiled, or as fixed).
    amplitude_log_prior : float
        The Laplace part of the amplitude in ln Z: −x̂²/(2(σ² + 1/H)) − ½ ln(1 + H σ²) at the
        best point, x̂ = ln A, 0 with A fixed.
    amplitude_curvature : float
        H, −d² ln L / d(ln A)² at the best point (0 with A fixed).
    amplitude_chi2, amplitude_dof, amplitude_p_value : float, int, float
        Σ z_s² of the shots' standardised amplitudes, its degrees of freedom and P(χ² ≥ it)
        (NaN, 0, NaN where not tested).
    amplitude_spread, amplitude_spread_expected : float
        Standard deviation of the shots' amplitudes a_s / A, and what speckle and noise give.
    shots_amplitude : float
        Median of the shots' data amplitudes (from their samples alone).
    fit_p_value : float
        The complete goodness of fit: min(1, parts × the smallest part's p-value).
    warnings : list of str
    """
    log_evidence: float
    log_evidence_nodes: float
    log_likelihood: float
    amplitude: float = math.nan
    amplitude_log_prior: float = 0.0
    amplitude_curvature: float = 0.0
    amplitude_chi2: float = math.nan
    amplitude_dof: int = 0
    amplitude_p_value: float = math.nan
    amplitude_spread: float = math.nan
    amplitude_spread_expected: float = math.nan
    shots_amplitude: float = math.nan
    fit_p_value: float = math.nan
    edges: list = field(default_factory=list)
    warnings: list = field(default_factory=list)


def amplitude_log_prior(x, sigma: float, h: float):
    """The amplitude's part of ln Z at profiled ln Â = ``x`` (a number or an array): the
    likelihood taken as quadratic in ln A with curvature ``h`` around ``x``, integrated
    against the prior ln A ~ N(0, ``sigma``²) (Laplace, §5.1):
    −x² / (2 (σ² + 1/h)) − ½ ln(1 + h σ²)."""
    return -x * x / (2.0 * (sigma ** 2 + 1.0 / max(h, 1e-300))) - 0.5 * math.log1p(h * sigma ** 2)


def log_evidence(post, axes, amplitude: tuple | None = None) -> float:
    """ln Z = ln ∫ L(θ) π(θ) dθ of a grid posterior, by the trapezoid rule in the
    interpolation coordinates, with the prior uniform in them over the database's range.

    Parameters
    ----------
    post : GridPosterior
        ln L on a rectangular grid (:mod:`.posterior`), which must hold the posterior's mass
        (the refined grid spans every node within 20 in ln L of the best).
    axes : list of Axis
        The free axes (their ``nodes`` give the prior range in the coordinate).
    amplitude : (float, float) or list of them, optional
        (σ of the ln A prior, H = −d² ln L/d(ln A)²): add at each point the Gaussian
        integral over ln A of ln L (quadratic in ln A around the profiled ln Â of that point)
        times the prior N(0, σ²): −ln²Â/(2(σ² + 1/H)) − ½ ln(1 + H σ²). None: A fixed. A
        list: one per channel of a joint inversion (each evaluation's ``parts``, each
        channel's own A; None for a channel whose A is fixed).

    Returns
    -------
    float
        ln Z (natural log; the likelihood's density units, the same for every database
        inverted from the same shots with the same instrument).
    """
    log_w = np.zeros(post.loglike.shape)
    volume = 0.0
    for i, (c, axis) in enumerate(zip(post.coords, axes)):
        shape = [-1 if j == i else 1 for j in range(post.loglike.ndim)]
        log_w = log_w + np.log(np.maximum(cell_widths(np.asarray(c, float)), 1e-300)).reshape(shape)
        span = float(axis.nodes[-1] - axis.nodes[0])
        volume += math.log(span) if span > 0 else 0.0
    terms = np.where(np.isfinite(post.loglike), post.loglike, -np.inf) + log_w
    channels = amplitude if isinstance(amplitude, list) else [amplitude]
    for i, part in enumerate(channels):
        if part is None:
            continue
        sigma, h = part
        x = np.full(post.loglike.shape, 0.0)
        for index, e in post.evaluations.items():
            fit = e.parts[i].fit if isinstance(amplitude, list) else e.fit
            x[index] = math.log(max(float(fit.overall), 1e-300))
        terms = terms + amplitude_log_prior(x, sigma, h)
    top = float(np.max(terms))
    if not math.isfinite(top):
        return -math.inf
    return top + math.log(float(np.sum(np.exp(terms - top)))) - volume


def _model(problem, u, v):
    """μ and ν (or the count rate and None) at free coordinates ``u`` and nuisance ``v``."""
    f = problem.forward
    return f.waveform(f.photons(problem.space.surface(problem.point(u))), v)


def amplitude_curvature(problem, u, best) -> float:
    """H = −d² ln L / d(ln A)² at the best point: fits with A held at Â e^{±h}, h adapted
    until the drop in ln L is about 1 (a parabola through three fits).

    Parameters
    ----------
    problem : Problem
    u : array
        The best point's free coordinates.
    best : Evaluation
        Its evaluation (ln L, v and the fit with Â).

    Returns
    -------
    float
        H ≥ 0 (1/(ln A)²); 0 where ln L does not fall away from Â (A unconstrained: the
        evidence then pays the prior's full width).
    """
    mu, nu = _model(problem, u, best.v)
    shots = problem.shots
    x0 = math.log(max(float(best.fit.overall), 1e-300))
    shots.start(mu)                 # as Problem.evaluate: each fit afresh, from this scan
    start = shots.arrival, shots.amplitude

    def ll(x):
        shots.arrival, shots.amplitude = start      # a fit leaves its own result there
        return shots.fit(mu, nu, math.exp(x)).loglike

    f0 = ll(x0)
    h, h_min, h_max = AMPLITUDE_STEP
    curvature = 0.0
    for _ in range(4):
        drop = f0 - 0.5 * (ll(x0 + h) + ll(x0 - h))
        curvature = max(2.0 * drop / (h * h), 0.0)
        if 0.2 < drop < 5.0 or (drop <= 0.2 and h >= h_max) or (drop >= 5.0 and h <= h_min):
            break
        h = min(max(h / math.sqrt(max(drop, 1e-6)), h_min), h_max)
    return curvature


def amplitude_test(problem, u, best) -> dict:
    """The amplitude term of the likelihood tested: each shot's amplitude from its own
    unclipped samples (weighted least squares at its fitted arrival, precision P_s),
    standardised by what speckle and noise give, z_s = (a_s − A) / √(A²/M + 1/P_s), which
    is N(0, 1) under the model; Σ z_s² against χ² of n − 1 degrees of freedom (n with A fixed).

    Shots with clipped samples are left out (their amplitude is bounded, not measured);
    photon counts have no per-shot amplitude (their likelihood averages over the speckle).

    Returns
    -------
    dict
        ``chi2``, ``dof``, ``p``, ``spread`` (std of a_s/A), ``expected`` (what speckle and
        noise give), ``median`` (median a_s); NaN and 0 where nothing is tested.
    """
    nothing = {"chi2": math.nan, "dof": 0, "p": math.nan, "spread": math.nan,
               "expected": math.nan, "median": math.nan}
    f, shots, fit = problem.forward, problem.shots, best.fit
    if f.counting:
        return nothing
    keep = ~np.asarray(shots.censored).any(axis=1)
    if not keep.any():
        return nothing
    mu, nu = _model(problem, u, best.v)
    m = shots._interp(mu, fit.arrival)[keep]
    n_var = shots._interp(nu, fit.arrival)[keep]
    var = f.sigma_n ** 2 + fit.amplitude[keep, None] * n_var
    y = shots.y[keep]
    precision = np.einsum("sk,sk->s", m, m / var)
    ok = precision > 0
    if not ok.any():
        return nothing
    a = np.einsum("sk,sk->s", y, m / var)[ok] / precision[ok]
    big_a = float(fit.overall)
    modes = min(f.modes, MODES_CAP)
    spread_var = big_a ** 2 / modes + 1.0 / precision[ok]
    z = (a - big_a) / np.sqrt(spread_var)
    dof = int(z.size - (1 if problem.overall is None else 0))
    chi2 = float(np.sum(z * z))
    return {"chi2": chi2, "dof": dof,
            "p": float(chdtrc(dof, chi2)) if dof > 0 else math.nan,
            "spread": float(np.std(a / big_a, ddof=1)) if a.size > 1 else math.nan,
            "expected": float(math.sqrt(np.mean(spread_var)) / big_a),
            "median": float(np.median(a))}


def edge_masses(final, axes) -> list:
    """Per free axis of three nodes or more, each edge at which the posterior piles up: the
    marginal's density on the refined grid is largest at that edge, within :data:`EDGE_PEAK`
    (the mass is pressed against it, not merely near it), and the marginal mass gathered on
    the edge node (its half cell next to the edge, ``marginal_<key>`` of FIT.nc) exceeds
    :data:`EDGE_MASS` and twice a flat posterior's share there.

    Returns
    -------
    list of dict
        ``key``, ``units``, ``side`` (``lowest`` / ``highest``), ``value`` (the edge's grid
        value), ``mass``, ``threshold``.
    """
    out = []
    for j, axis in enumerate(axes):
        nodes = axis.nodes
        if nodes.size < 3:
            continue
        u, mass = marginal(final, j)
        gathered = nearest_node_mass(u, mass, nodes)
        span = nodes[-1] - nodes[0]
        density = mass / np.maximum(cell_widths(u), 1e-300)
        for side, i, cell in (("lowest", 0, nodes[1] - nodes[0]),
                              ("highest", -1, nodes[-1] - nodes[-2])):
            threshold = max(EDGE_MASS, 2.0 * 0.5 * cell / span)
            at_edge = (abs(u[i] - nodes[i]) <= 1e-9 * span
                       and density[i] >= EDGE_PEAK * density.max())
            if at_edge and gathered[i] > threshold:
                out.append({"key": axis.key, "units": axis.units, "side": side,
                            "value": float(axis.values[i]), "mass": float(gathered[i]),
                            "threshold": threshold})
    return out


def _show(value: float, units: str) -> str:
    return f"{value:.4g}" + ("" if units in ("", "1") else f" {units}")


def warnings_of(c: Checks, *, fixed_amplitude: float | None, chi2: float, dof: int,
                p_value: float) -> list:
    """The warnings' lines (module docstring): amplitude far from 1, mass at a grid edge,
    poor complete fit."""
    lines = []
    lo, hi = AMPLITUDE_RANGE
    if fixed_amplitude is None:
        amplitude, what = c.amplitude, "the overall amplitude A"
    else:
        amplitude, what = c.shots_amplitude, (f"the shots' median amplitude (A fixed at "
                                              f"{fixed_amplitude:g})")
    if math.isfinite(amplitude) and not lo <= amplitude <= hi:
        ratio = (f"the model is {1 / amplitude:.3g}x the shots' brightness" if amplitude > 0
                 else "the shots hold no signal the model can scale to")
        lines.append(f"amplitude: {what} is {amplitude:.3g}, outside [1/3, 3] of the "
                     f"instrument's radiometry: {ratio} (another texture or composition than "
                     "the database's, or a wrong link budget)")
    for e in c.edges:
        lines.append(f"edge: {e['mass']:.0%} of the posterior of {e['key']} lies in the "
                     f"grid's edge cell at its {e['side']} value {_show(e['value'], e['units'])} "
                     f"(more than {e['threshold']:.0%}): the surface may lie beyond the "
                     "database's range, or the database may not describe these shots")
    if math.isfinite(c.fit_p_value) and c.fit_p_value < FIT_P:
        parts = f"samples chi2/dof {chi2 / dof:.4g} (p = {p_value:.3g})" if dof > 0 else \
            "samples: no degree of freedom"
        if c.amplitude_dof > 0:
            parts += (f", shots' amplitudes chi2 {c.amplitude_chi2:.4g} on {c.amplitude_dof} "
                      f"dof (p = {c.amplitude_p_value:.3g}; spread {c.amplitude_spread:.3g} "
                      f"of A against {c.amplitude_spread_expected:.3g} from speckle and noise)")
        lines.append(f"poor fit: complete goodness of fit p = {c.fit_p_value:.3g} < {FIT_P:g} "
                     f"({parts}): the database does not describe these shots")
    return lines


def check(problem, nodes, final, *, chi2: float, dof: int, p_value: float) -> Checks:
    """Evidence, complete goodness of fit and warnings of an inversion.

    Parameters
    ----------
    problem : Problem
        The inversion's problem (space, forward, shots; ``overall`` set when A is fixed).
    nodes, final : GridPosterior
        The posterior at the database's nodes and on the refined grid.
    chi2, dof, p_value : float, int, float
        The samples' χ² (Pearson's for photon counts), its degrees of freedom and p-value
        at the best point, as FIT.nc's ``chi2``, ``dof``, ``p_value``.

    Returns
    -------
    Checks
    """
    axes = problem.space.free_axes
    index = final.best()
    best = final.evaluations[index]
    u = np.array([c[i] for c, i in zip(final.coords, index)])
    amplitude = None
    curvature = 0.0
    x = 0.0
    if problem.overall is None:
        curvature = amplitude_curvature(problem, u, best)
        amplitude = (AMPLITUDE_PRIOR_SIGMA, curvature)
        x = math.log(max(float(best.fit.overall), 1e-300))
    prior_part = 0.0 if amplitude is None else \
        amplitude_log_prior(x, AMPLITUDE_PRIOR_SIGMA, curvature)
    test = amplitude_test(problem, u, best)
    parts = [p for p in (p_value, test["p"]) if math.isfinite(p)]
    c = Checks(log_evidence=log_evidence(final, axes, amplitude),
               log_evidence_nodes=log_evidence(nodes, axes, amplitude),
               log_likelihood=float(best.loglike), amplitude_log_prior=prior_part,
               amplitude_curvature=curvature, amplitude_chi2=test["chi2"],
               amplitude_dof=test["dof"], amplitude_p_value=test["p"],
               amplitude_spread=test["spread"], amplitude_spread_expected=test["expected"],
               shots_amplitude=test["median"], amplitude=float(best.fit.overall),
               fit_p_value=min(1.0, len(parts) * min(parts)) if parts else math.nan,
               edges=edge_masses(final, axes))
    c.warnings = warnings_of(c, fixed_amplitude=problem.overall, chi2=chi2, dof=dof,
                             p_value=p_value)
    if problem.forward.counting and not problem.shots.recording.exact:
        c.warnings.append("inexact dead time: detector.digital_dead_time exceeds twice "
                          "detector.analog_dead_time, and the expected counts leave out the "
                          "timing channels' own losses (an upper bound; docs/instrument.md "
                          "§3.9)")
    return c


#: FIT.nc variables :func:`annotate` writes: name -> (Checks attribute, long_name, units).
VARIABLES = {
    "log_evidence": ("log_evidence", "log evidence ln Z = ln of the integral of L(theta) "
                     "pi(theta): prior uniform in each axis' interpolation coordinate over the "
                     "database's range, per-shot amplitudes and arrivals marginalised, pulse "
                     "width profiled, ln A integrated against N(0, ln(3)^2) (natural log, "
                     "comparable between databases for the same shots and instrument)", "1"),
    "log_evidence_nodes": ("log_evidence_nodes", "ln Z on the database's nodes alone (its "
                           "difference from log_evidence indicates the quadrature error)", "1"),
    "log_likelihood": ("log_likelihood", "ln L at the best point (per-shot nuisances "
                       "marginalised, A and pulse width profiled)", "1"),
    "amplitude_log_prior": ("amplitude_log_prior", "the amplitude's part of ln Z at the best "
                            "point: its log-normal prior and Laplace width (0 with A fixed)",
                            "1"),
    "amplitude_curvature": ("amplitude_curvature", "H = -d2 ln L / d(ln A)2 at the best point "
                            "(0 with A fixed)", "1"),
    "amplitude_chi2": ("amplitude_chi2", "sum of the squared standardised shot amplitudes "
                       "(a_s - A)/sqrt(A2/M + 1/P_s) of the unclipped shots", "1"),
    "amplitude_dof": ("amplitude_dof", "degrees of freedom of amplitude_chi2", "1"),
    "amplitude_p_value": ("amplitude_p_value", "P(chi2 >= amplitude_chi2): the shots' "
                          "amplitudes against the speckle prior", "1"),
    "amplitude_spread": ("amplitude_spread", "standard deviation of the unclipped shots' "
                         "amplitudes a_s / A, each from its own samples", "1"),
    "amplitude_spread_expected": ("amplitude_spread_expected", "the spread of a_s / A that "
                                  "speckle (1/M) and the samples' noise (1/P_s) give", "1"),
    "shots_amplitude": ("shots_amplitude", "median of the unclipped shots' amplitudes, each "
                        "from its own samples, relative to the instrument's radiometry", "1"),
    "fit_p_value": ("fit_p_value", "complete goodness of fit: min(1, k min(p_value, "
                    "amplitude_p_value)) over the k parts tested (Bonferroni)", "1"),
}


def annotate(ds, c: Checks):
    """Store ``c`` in a FIT Dataset: the :data:`VARIABLES`, and the attributes ``warnings``
    (the lines joined by newlines, empty when none), ``amplitude_prior`` and
    ``fit_p_threshold``.

    Parameters
    ----------
    ds : xarray.Dataset
        A FIT Dataset (:func:`.result.build_result`).
    c : Checks

    Returns
    -------
    xarray.Dataset
        ``ds``, with the variables and attributes added.
    """
    for name, (attr, long_name, units) in VARIABLES.items():
        ds[name] = ((), getattr(c, attr), {"long_name": long_name, "units": units})
    ds.attrs["warnings"] = "\n".join(c.warnings)
    ds.attrs["amplitude_prior"] = (f"ln A ~ N(0, {AMPLITUDE_PRIOR_SIGMA:.4g}^2) (a factor 3 "
                                   "at one standard deviation); none with A fixed")
    ds.attrs["checks"] = json.dumps({"amplitude_range": list(AMPLITUDE_RANGE),
                                     "edge_mass": EDGE_MASS, "fit_p": FIT_P})
    return ds


def checked(ds, problem, nodes, final, source: str):
    """Check an inversion (:func:`check`), store what it finds in its FIT Dataset
    (:func:`annotate`) and issue each warning as a :class:`~warpe_cl.errors.WarpeWarning`
    (``SOURCE: line``; the command line prints it as one line on stderr).

    Parameters
    ----------
    ds : xarray.Dataset
        The FIT Dataset of :func:`.result.build_result` (its ``chi2``, ``dof``, ``p_value``).
    problem : Problem
    nodes, final : GridPosterior
    source : str
        The database's name, for the warnings.

    Returns
    -------
    xarray.Dataset
        ``ds``, annotated.
    """
    c = check(problem, nodes, final, chi2=float(ds["chi2"]), dof=int(ds["dof"]),
              p_value=float(ds["p_value"]))
    for line in c.warnings:
        warnings.warn(f"{source}: {line}", WarpeWarning, stacklevel=3)
    return annotate(ds, c)


def fit_warnings(ds) -> list:
    """The warnings of a FIT Dataset (attribute ``warnings``), one line each.

    Parameters
    ----------
    ds : xarray.Dataset

    Returns
    -------
    list of str
    """
    text = str(ds.attrs.get("warnings", ""))
    return [line for line in text.split("\n") if line.strip()]


def check_lines(ds) -> list:
    """The lines ``warpe-cl invert`` prints for the checks: evidence, complete fit, the
    shots' amplitudes.

    Parameters
    ----------
    ds : xarray.Dataset
        A FIT Dataset with the :data:`VARIABLES`.

    Returns
    -------
    list of str
    """
    if "log_evidence" not in ds:
        return []
    lines = [f"  evidence: ln Z {float(ds['log_evidence']):.6g} (nodes alone "
             f"{float(ds['log_evidence_nodes']):.6g}), ln L at the best "
             f"{float(ds['log_likelihood']):.6g}"]
    fit = f"  complete fit: p = {float(ds['fit_p_value']):.3g}"
    if int(ds["amplitude_dof"]) > 0:
        fit += (f" (shots' amplitudes chi2 {float(ds['amplitude_chi2']):.4g} on "
                f"{int(ds['amplitude_dof'])} dof, p = {float(ds['amplitude_p_value']):.3g}; "
                f"spread {float(ds['amplitude_spread']):.3g} of A against "
                f"{float(ds['amplitude_spread_expected']):.3g} from speckle and noise)")
    lines.append(fit)
    return lines
