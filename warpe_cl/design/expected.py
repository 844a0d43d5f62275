"""Expected posterior widths and distinguishability at every node of a family for one
instrument (docs/design.md §2-§3).

For each node: the information matrix of :mod:`.fisher` about the swept keys (in their
interpolation coordinates), its inverse as the posterior covariance, and

- per swept key, the width ratio 2 z₉₇.₅ sd / (0.95 × range), the posterior 95 % width over the
  prior's in the prior's coordinate (the inversion's ``width_ratio``, docs/inversion.md §5),
  capped at 1: a Fisher width wider than the prior means the prior, not the data, bounds it;
- per derived quantity (E, τ0, ⟨t⟩), the same with the sd of its comparison coordinate (ln of
  the value) along its gradient, over its prior 95 % width;
- the Asimov Δχ² to each neighbouring node: the information along the step from the node to
  the neighbour, nuisances marginalised (linear in the step); its least over the neighbours,
  and whether it reaches :data:`DISTINGUISHABLE`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..inversion.emulator import Emulator
from ..inversion.forward import Forward
from ..inversion.invert import DETECTION_SIGMA
from ..inversion.recording import Recording
from .family import slope
from .fisher import NUISANCES, counting_information, covariance, linear_information, sd_along

#: z of the 97.5 % point of a Gaussian: a 95 % interval is ± this many sd.
Z95 = 1.959963984540054
#: Δχ² from which a node is told apart from a neighbour: the 95 % point of χ² with one
#: degree of freedom.
DISTINGUISHABLE = 3.841458820694124
#: A photon-counting observation with fewer expected signal counts (all shots) is not
#: detected.
COUNTS_DETECTED = 10.0
#: Step of the pulse-broadening nuisance v for its derivative, in units of the pulse's σ².
PULSE_STEP = 0.1
#: Directions per information matrix when the Δχ² to the other families' nodes are computed
#: (only the diagonal is kept; a batch costs its size squared times the samples).
TEXTURE_BATCH = 32


@dataclass
class Expected:
    """What :func:`expected` finds for one family and one instrument (arrays over the
    family's nodes, in the order of ``family.nodes``).

    Attributes
    ----------
    width_ratio : array (nodes, parameters)
        Expected 95 % width over the prior's, capped at 1 (NaN: no range).
    width_ratio_exact : array (nodes, parameters)
        The same with the database taken as exact.
    sd : array (nodes, parameters)
        Fisher standard deviation in the comparison coordinate (inf: not constrained).
    detected : array of bool (nodes,)
    peak_snr : array (nodes,)
        Linear mode: the expected peak over σ_n; counting: the expected recorded signal
        counts of all shots (after the dead time).
    min_delta_chi2 : array (nodes,)
        The least Asimov Δχ² to a neighbouring node.
    nearest : array of int (nodes,)
        The index (in ``family.nodes``) of that neighbour (-1 for none).
    elapsed_s : float
    min_delta_chi2_texture : array (nodes,)
        The least Asimov Δχ² to a node of another family of the study (NaN: none given).
    nearest_texture : array of int (nodes,)
        Its index in the other families' nodes taken in order (-1 for none).
    """
    width_ratio: np.ndarray
    width_ratio_exact: np.ndarray
    sd: np.ndarray
    detected: np.ndarray
    peak_snr: np.ndarray
    min_delta_chi2: np.ndarray
    nearest: np.ndarray
    elapsed_s: float
    min_delta_chi2_texture: np.ndarray = None
    nearest_texture: np.ndarray = None


@dataclass
class Channel:
    """One instrument's information about a family, node by node (:func:`channel`).

    Attributes
    ----------
    full : list of arrays
        Per node, the information matrix (nuisances marginalised) over the swept axes' and
        the neighbour steps' directions, the database's error counted.
    exact : list of arrays
        The same with the database taken as exact (``full`` where its error is not counted).
    detected : array of bool
    strength : array
        Per node, the expected peak over σ_n (linear mode) or recorded signal counts
        (counting).
    near : list of list of int
        Per node, the positions of its neighbouring nodes (the steps' order in ``full``).
    elapsed_s : float
    texture : list of arrays
        Per node, the Asimov Δχ² to every node of the other families (in their order), the
        nuisances and the database's error marginalised; empty without other families.
    """
    full: list
    exact: list
    detected: np.ndarray
    strength: np.ndarray
    near: list
    elapsed_s: float
    texture: list = None


def expected(family, params, *, phases: int = 8, database_error: bool = True,
             nuisances=NUISANCES) -> Expected:
    """Expected widths and distinguishability at every node of ``family`` for one instrument.

    Parameters
    ----------
    family : Family
    params : InstrumentParams
        The instrument, its ``shots`` the observation's.
    phases : int
        Sampling phases averaged (:func:`.fisher.linear_information`).
    database_error : bool
        Count the database's own error (linear mode; docs/inversion.md §4.3).
    nuisances : iterable of str
        The nuisances marginalised (:data:`.fisher.NUISANCES`).

    Returns
    -------
    Expected
    """
    return combined(family, [channel(family, params, phases=phases,
                                     database_error=database_error, nuisances=nuisances)])


def channel(family, params, *, phases: int = 8, database_error: bool = True,
            nuisances=NUISANCES, others=()) -> Channel:
    """One instrument's information matrices at every node of ``family`` (the parameters
    are :func:`expected`'s), and with ``others`` (other families, each the database at this
    instrument's wavelength) the Asimov Δχ² from every node to every node of theirs: the
    information along the difference of the two surfaces' expected samples, the nuisances
    and the database's error marginalised, linear in the difference once the other surface is
    scaled to this one's brightness (:func:`_scaled_step`; docs/design.md §2.5)."""
    started = time.perf_counter()
    forward = Forward(params)
    shots = int(params["shots"])
    counting = forward.counting
    emulator = Emulator(family.space, forward) if database_error else None
    recording = Recording(forward) if counting else None    # counts after the dead time
    n_nodes, n_axes = len(family.nodes), len(family.axes)
    out = Channel([], [], np.zeros(n_nodes, bool), np.zeros(n_nodes), [], 0.0, [])
    position = {node.index: i for i, node in enumerate(family.nodes)}
    waves = [_expected(forward, node.surface) for node in family.nodes]
    theirs = [_expected(forward, node.surface) for other in others for node in other.nodes]
    h = PULSE_STEP * forward.sigma_p ** 2

    def information(mu, nu, d_mu, d_nu, pulse, variance, marginalised=nuisances):
        if counting:
            return counting_information(forward, mu, d_mu, shots, pulse=pulse[0],
                                        phases=phases, nuisances=marginalised,
                                        variance=variance)
        return linear_information(forward, mu, nu, d_mu, d_nu, shots, pulse=pulse,
                                  variance=variance, phases=phases, nuisances=marginalised)

    # the steps to other families' surfaces have the amplitude profiled already, exactly
    # (_scaled_step): marginalising it again, linearly, along μ would take up part of the
    # step itself (all of it for a surface that does not overlap this one)
    shape_only = tuple(n for n in nuisances if n != "amplitude")

    for i, node in enumerate(family.nodes):
        mu, nu = waves[i]
        if counting:
            strength = shots * float(np.sum(recording.level(mu, 1.0))) * forward.step
            detected = strength >= COUNTS_DETECTED
        else:
            strength = float(mu.max()) / forward.sigma_n
            detected = strength >= DETECTION_SIGMA
        out.strength[i], out.detected[i] = strength, detected
        photons = forward.photons(node.surface)
        d_mu, d_nu = [], []
        for j in range(n_axes):
            sides = []
            for moved in (node.below[j], node.above[j]):
                if moved is None:
                    sides.append(None)
                    continue
                sides.append((_expected(forward, moved[0]), moved[1]))
            d_mu.append(slope(mu, *[None if s is None else (s[0][0], s[1]) for s in sides]))
            d_nu.append(slope(nu, *[None if s is None else (s[0][1], s[1]) for s in sides]))
        d_mu, d_nu = np.array(d_mu), np.array(d_nu)
        pulse = _pulse_derivative(forward, photons, mu, nu, h)
        variance = None
        if emulator is not None:
            points = [m[2] for m in node.below + node.above if m is not None]
            variance = sum(emulator.variance(p) for p in points) / max(len(points), 1)
        # one information matrix holds the axes and the steps to the neighbours: its
        # diagonal element of a step is the Asimov Δχ² of that step alone (the nuisances
        # marginalised, the other directions held)
        near = [position[nb] for nb in family.neighbours(node.index)]
        steps_mu = [waves[k][0] - mu for k in near]
        steps_nu = [waves[k][1] - nu for k in near]
        all_mu = np.concatenate([d_mu, np.array(steps_mu).reshape(-1, mu.size)])
        all_nu = np.concatenate([d_nu, np.array(steps_nu).reshape(-1, mu.size)])
        full = information(mu, nu, all_mu, all_nu, pulse, variance)
        out.full.append(full)
        out.exact.append(full if emulator is None else
                         information(mu, nu, all_mu, all_nu, pulse, None))
        out.near.append(near)
        if theirs:      # the diagonal only, in batches: each Δχ² needs no cross term
            steps = [_scaled_step(mu, nu, m, n, forward) for m, n in theirs]
            out.texture.append(np.concatenate([
                np.diag(information(mu, nu, np.array([m for m, _ in part]),
                                    np.array([n for _, n in part]), pulse, variance,
                                    shape_only))
                for part in (steps[k:k + TEXTURE_BATCH]
                             for k in range(0, len(steps), TEXTURE_BATCH))]))
    out.elapsed_s = time.perf_counter() - started
    return out


def combined(family, channels: list) -> Expected:
    """Expected widths and distinguishability from one or more instruments' information
    about the same surfaces: their matrices add (the instruments' noises and nuisances are
    independent), each counted only where that instrument detects the return.

    Parameters
    ----------
    family : Family
        The nodes, axes and derived quantities (of the first instrument's database, for a
        combination across wavelengths: the same nodes in each).
    channels : list of Channel
        One per instrument, over the same nodes.

    Returns
    -------
    Expected
        ``peak_snr`` and the detection of a combination: its first instrument's, and
        detected where any of its instruments detects.
    """
    started = time.perf_counter()
    n_nodes, n_axes = len(family.nodes), len(family.axes)
    n_par = n_axes + len(family.derived)
    out = Expected(np.full((n_nodes, n_par), np.nan), np.full((n_nodes, n_par), np.nan),
                   np.full((n_nodes, n_par), np.nan), np.zeros(n_nodes, bool),
                   np.zeros(n_nodes), np.zeros(n_nodes), np.full(n_nodes, -1), 0.0)
    widths = [family.prior_width(a) for a in family.axes] + \
        [d.prior_width for d in family.derived]
    textures = bool(channels[0].texture)
    if textures:
        out.min_delta_chi2_texture = np.full(n_nodes, np.nan)
        out.nearest_texture = np.full(n_nodes, -1)
    for i, node in enumerate(family.nodes):
        seen = [c for c in channels if c.detected[i]]
        detected = bool(seen)
        out.detected[i], out.peak_snr[i] = detected, channels[0].strength[i]
        near = channels[0].near[i]
        ratios = {}
        for label in ("model", "exact"):
            full = sum((c.full[i] if label == "model" else c.exact[i])
                       for c in seen or channels[:1])
            cov = covariance(full[:n_axes, :n_axes])
            sd = np.full(n_par, np.inf)
            for j, axis in enumerate(family.axes):
                sd[j] = sd_along(cov, np.eye(n_axes)[j])
            for k, der in enumerate(family.derived):
                q = der.quantity
                here = q.coord(node.derived_here[k])
                gradient = np.array([
                    slope(here, None if node.below[j] is None else
                          (q.coord(node.derived_below[j][k]), node.below[j][1]),
                          None if node.above[j] is None else
                          (q.coord(node.derived_above[j][k]), node.above[j][1]))
                    for j in range(n_axes)])
                sd[n_axes + k] = sd_along(cov, gradient)
            ratio = np.array([min(1.0, 2.0 * Z95 * s / w) if w > 0 else np.nan
                              for s, w in zip(sd, widths)])
            if not detected:
                ratio = np.where(np.isfinite(ratio), 1.0, ratio)
            ratios[label] = ratio
            if label == "model":
                out.sd[i] = sd
                chi2 = np.diag(full)[n_axes:] if detected else np.zeros(len(near))
                if near:
                    k = int(np.argmin(chi2))
                    out.min_delta_chi2[i], out.nearest[i] = float(chi2[k]), near[k]
                else:
                    out.min_delta_chi2[i] = np.nan
        out.width_ratio[i], out.width_ratio_exact[i] = ratios["model"], ratios["exact"]
        if textures:
            chi2 = sum(c.texture[i] for c in seen) if seen else \
                np.zeros_like(channels[0].texture[i])
            k = int(np.argmin(chi2))
            out.min_delta_chi2_texture[i], out.nearest_texture[i] = float(chi2[k]), k
    out.elapsed_s = sum(c.elapsed_s for c in channels) + time.perf_counter() - started
    return out


def _scaled_step(mu, nu, other_mu, other_nu, forward) -> tuple:
    """The step from a surface's expected samples (μ, ν) to another's scaled to the same
    brightness: the overall amplitude is free, so the other surface is first brought to its
    best-fitting scale s (weighted least squares, weights 1/(σ_n² + ν) or, for counts,
    1/(μ + background)), exactly; the step (s μ' − μ, s ν' − ν) then holds the difference of
    shape alone, and the amplitude is not marginalised again for it (the per-shot amplitudes
    are then held at the overall one). Without it a surface a hundred times darker lay along
    μ itself, which the linearised amplitude absorbed whole: every surface seemed like a dark
    one."""
    floor = forward.dc_rate if forward.counting else forward.sigma_n ** 2
    weight = 1.0 / np.maximum((mu if forward.counting else nu) + floor, 1e-300)
    norm = float(np.sum(weight * other_mu * other_mu))
    scale = float(np.sum(weight * other_mu * mu)) / norm if norm > 0 else 0.0
    return scale * other_mu - mu, scale * other_nu - nu


def _expected(forward, surface) -> tuple:
    """μ and ν of a surface's expected samples at v = 0, ν zeros where the receiver has none
    (photon counting)."""
    mu, nu = forward.waveform(forward.photons(surface), 0.0)
    return mu, (np.zeros_like(mu) if nu is None else nu)


def _pulse_derivative(forward, photons, mu, nu, h):
    """∂μ/∂v and ∂ν/∂v at v = 0 (central, or forward where v cannot go below 0 by h)."""
    up = forward.waveform(photons, h)
    if forward.v_bounds[0] <= -h:
        down = forward.waveform(photons, -h)
        dm = (up[0] - down[0]) / (2 * h)
        dn = None if up[1] is None else (up[1] - down[1]) / (2 * h)
    else:
        dm = (up[0] - mu) / h
        dn = None if up[1] is None else (up[1] - nu) / h
    return dm, (np.zeros_like(dm) if dn is None else dn)
