"""The NumPy reference walk: docs/walk.md written out literally, one photon at a time.

This module is the second, independent implementation of ``docs/walk.md`` (the first is the
OpenCL kernel). It shares no code with the kernel or its host driver: only the random streams
(:mod:`warpe_cl.rng`) and the plain input/output values (:mod:`warpe_cl.params`). Because it
consumes each photon's draws in exactly the order the contract fixes, a kernel run and a
reference run with the same seed follow the same rays through the same events, which is what
the per-photon parity tests compare. It is also the slow fallback engine (``--device numpy``).

Reading guide
-------------
* :func:`walk_ray` is the whole random walk of one ray (walk.md §3), in the order of the
  contract, and returns what happened to it;
* :func:`walk_ray_layers` is the walk of one ray through a stack of layers (texture
  ``layers``, walk.md §7), with the layer it ended in and its transmissions through each
  interface (the per-layer statistics of walk.md §7.4);
* :func:`simulate_reference` launches the photons, classifies every exit into a component and
  fills the tallies of walk.md §4;
* the physics helpers are the Fresnel reflectances (walk.md §3.3; docs/physics.md §3.4, §3.5), the
  Henyey–Greenstein deflection and the MCML direction update (docs/physics.md §5.4).

Everything inside the per-photon loop is plain Python floats and :mod:`math` / :mod:`cmath`
calls (no NumPy scalars), for speed. Lengths are in metres, times in nanoseconds.

Two guards against rounding appear below and change nothing in exact arithmetic: sin² terms
computed as 1 − cos² are clamped at 0 before a square root (a direction cosine can exceed 1 by
an ulp after many rotations), and the emergence bin clamps cos θ_e to [0, 1] before it counts
the whole degrees k with cos θ_e <= cos(k°) (:func:`warpe_cl.params.emergence_bin`).

Examples
--------
>>> import numpy as np
>>> from warpe_cl.params import WalkParams
>>> params = WalkParams(texture="slab", thickness=1.0, extinction=0.01, omega=0.0, g=0.8,
...                     n=1.4026, k=0.0, albedo=0.15, time_edges=np.linspace(0, 20, 41))
>>> counts = simulate_reference(params, photons=200)
>>> int(counts.fates.sum())
200
"""
from __future__ import annotations

import bisect
import cmath
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .errors import WeightError
from .params import (BOTTOM_INTERFACES, C_M_PER_NS, COMPONENTS, FATES, LAYER_STATS,
                     MAX_LAYERS, MIRROR_KINDS, N_EMERGENCE, NADIR_BATCHES, NADIR_ROWS,
                     RECORD_FIELDS, RULES,
                     TEXTURES, TIME_BIN_EARLY, TIME_BIN_LATE, Counts, WalkParams,
                     batch_photons, emergence_bin, fixed_point, lost_weight)
from .nadir import mirror_table
from .rng import PhotonStream

__all__ = ["simulate_reference", "walk_ray", "RayOutcome", "walk_ray_layers",
           "LayeredRayOutcome", "normal_incidence_reflectance",
           "external_reflectance", "internal_reflectance", "henyey_greenstein_cosine",
           "rotate_direction", "RECORD_FIELDS"]

# Component and fate indices (walk.md §4).
SPECULAR, BF_DIRECT, BF_DIFFUSE, SCATTERING = (COMPONENTS.index(name) for name in (
    "specular", "bf_direct", "bf_diffuse", "scattering"))
FATE_SPECULAR, FATE_ESCAPED, FATE_ABSORBED_MEDIUM, FATE_ABSORBED_FLOOR, FATE_TERMINATED = (
    FATES.index(name) for name in (
        "specular", "escaped", "absorbed_medium", "absorbed_floor", "terminated"))

ROW_BF_DIFFUSE, ROW_SCATTERING, ROW_ORDER_1 = (NADIR_ROWS.index(name) for name in (
    "bf_diffuse", "scattering", "order_1"))

TWO_PI = 2.0 * math.pi
TWO_POW_32 = 4294967296.0


# --------------------------------------------------------------------------------------------
# Physics helpers
# --------------------------------------------------------------------------------------------

def normal_incidence_reflectance(n: float, k: float) -> float:
    """R0 = ((n − 1)² + k²)/((n + 1)² + k²), from vacuum at normal incidence (walk.md §3 step 2).

    Parameters
    ----------
    n, k : float
        Real and imaginary parts of the index (dimensionless).

    Returns
    -------
    float
        Reflectance (dimensionless).
    """
    return ((n - 1.0) ** 2 + k * k) / ((n + 1.0) ** 2 + k * k)


def external_reflectance(mu: float, n: float, k: float) -> float:
    """R_ext(μ; n, k): unpolarised Fresnel reflectance from vacuum into the complex index n + ik.

    Deliberately computed by plain complex arithmetic (complex Snell's law and the Fresnel
    amplitudes), not by Hapke's G1/G2 form of docs/physics.md §3.4 that the kernel uses, so the two
    implementations cross-check each other.

    Parameters
    ----------
    mu : float
        Cosine of the incidence angle in vacuum, in [0, 1].
    n, k : float
        Real and imaginary parts of the index of the medium (k ≥ 0).

    Returns
    -------
    float
        (|r_s|² + |r_p|²)/2 (dimensionless).

    Notes
    -----
    With m = n + ik, complex Snell gives cos θ_t = sqrt(1 − sin²θ/m²) (principal root). For
    k ≥ 0, both m and cos θ_t lie in the first quadrant, so m cos θ_t = sqrt(m² − sin²θ) is the
    root with non-negative real and imaginary parts: the transmitted wave decays into the medium
    and no branch choice is needed.
    """
    m = complex(n, k)
    sin_sq = max(0.0, 1.0 - mu * mu)
    cos_t = cmath.sqrt(1.0 - sin_sq / (m * m))
    r_s = (mu - m * cos_t) / (mu + m * cos_t)
    r_p = (m * mu - cos_t) / (m * mu + cos_t)
    return 0.5 * (abs(r_s) ** 2 + abs(r_p) ** 2)


def internal_reflectance(mu: float, n: float) -> float:
    """R_int(μ): real-index Fresnel reflectance from inside the slab (index n) into vacuum.

    walk.md §3.3, docs/physics.md §3.5 and A12. Only called when there is no total internal
    reflection, n·sqrt(1 − μ²) < 1.

    Parameters
    ----------
    mu : float
        Cosine of the incidence angle inside the slab, in (0, 1].
    n : float
        Real index of the slab.

    Returns
    -------
    float
        (r_s² + r_p²)/2 (dimensionless).
    """
    cos_t = math.sqrt(1.0 - n * n * max(0.0, 1.0 - mu * mu))
    r_s = (n * mu - cos_t) / (n * mu + cos_t)
    r_p = (mu - n * cos_t) / (mu + n * cos_t)
    return 0.5 * (r_s * r_s + r_p * r_p)


def henyey_greenstein_cosine(g: float, u: float) -> float:
    """Deflection cosine cos Θ drawn from Henyey–Greenstein of asymmetry g (docs/physics.md §5.4).

    Parameters
    ----------
    g : float
        Asymmetry parameter, in (−1, 1).
    u : float
        A uniform draw in (0, 1].

    Returns
    -------
    float
        cos Θ = s + g (1 − s²)(3 + 2gs − g²) / (2 (1 + gs)²), with s = 2u − 1,
        1 − s² = 4u(1 − u) and 1 + gs = (1 − g) + 2gu (docs/walk.md §3): the classic
        [1 + g² − ((1 − g²)/(1 − g + 2gu))²]/(2g) rewritten without its cancellation at small
        |g| (it is s at g = 0), clamped to [−1, 1].
    """
    s = 2.0 * u - 1.0
    q = 4.0 * u * (1.0 - u)
    d = (1.0 - g) + 2.0 * g * u
    c = s + g * q * ((3.0 - g * g) + 2.0 * g * s) / (2.0 * d * d)
    return min(1.0, max(-1.0, c))


def rotate_direction(ux: float, uy: float, uz: float, cos_theta: float, psi: float):
    """Turn the direction u by the polar angle Θ and azimuth ψ (MCML; docs/physics.md §5.4).

    Parameters
    ----------
    ux, uy, uz : float
        Current unit direction (uz > 0 is downwards).
    cos_theta : float
        Cosine of the deflection angle Θ.
    psi : float
        Azimuth of the deflection, rad.

    Returns
    -------
    tuple of 3 floats
        The new direction (ux', uy', uz').
    """
    sin_theta = math.sqrt(max(0.0, 1.0 - cos_theta * cos_theta))
    cos_psi = math.cos(psi)
    sin_psi = math.sin(psi)
    if abs(uz) > 0.99999:
        # Nearly vertical: u' = (sinΘ cosψ, sinΘ sinψ, sign(uz) cosΘ).
        return (sin_theta * cos_psi, sin_theta * sin_psi, cos_theta if uz > 0.0 else -cos_theta)
    d = math.sqrt(1.0 - uz * uz)
    return (sin_theta * (ux * uz * cos_psi - uy * sin_psi) / d + ux * cos_theta,
            sin_theta * (uy * uz * cos_psi + ux * sin_psi) / d + uy * cos_theta,
            -sin_theta * cos_psi * d + uz * cos_theta)



# --------------------------------------------------------------------------------------------
# The next-event (nadir) estimator (walk.md §8)
# --------------------------------------------------------------------------------------------

def henyey_greenstein_phase(g: float, cos_theta: float) -> float:
    """The HG phase function normalised to 1 over the sphere, sr⁻¹:
    p(Θ) = (1 − g²) / (4π (1 + g² − 2g cos Θ)^(3/2))."""
    return (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g - 2.0 * g * cos_theta) ** 1.5)


class NadirScorer:
    """The estimator of walk.md §8 written out literally: at every scattering and floor
    reflection, the virtual path from there up to vacuum along the view direction is followed
    layer by layer, interface by interface, and its score goes to the ray's pending cell.

    The layers are given top first as (texture, face (m, k), index n, extinction E, thickness
    h, g), the interfaces as (Fresnel?, up face (near, far_n, far_k)) for j = 0..N (j = N:
    from the gap medium of index ``gap_n`` into the last layer), as :class:`_StackConstants`
    holds them.
    """

    def __init__(self, params: WalkParams, layers, fresnel, up_face, gap_n: float,
                 edges: list, omega_words, albedo_words: int):
        sin_v = math.sin(math.radians(float(params.view_zenith)))
        self.sin_v = sin_v
        self.layers = layers
        self.fresnel = fresnel
        self.up_face = up_face
        self.gap_n = gap_n
        self.edges = edges
        self.n_time = len(edges) - 1
        self.cols = self.n_time + 2
        self.n0 = float(layers[0][2])
        self.ns_per_metre = self.n0 / C_M_PER_NS
        self.history_rule = params.rule == "history"
        self.t1 = float(params.first_bf_time)
        self.weighted = params.weighted
        self.omega_words = omega_words
        self.albedo_words = albedo_words
        # the roulette's s_min: a fraction of the score of a scattering at the top straight
        # back up, p(pi) T_0 / (m_0^2 mu_0) (walk.md §8.3)
        top_m = layers[0][1][0]
        mu0 = math.sqrt(1.0 - (sin_v / top_m) ** 2)
        back = henyey_greenstein_phase(layers[0][5], -1.0)          # p(pi)
        top = self._transmission(0, mu0) / (top_m * top_m * mu0) * back
        self.s_min = (0.0 if self.weighted or not params.nadir_roulette > 0
                      else float(params.nadir_roulette) * top)
        # s_new, for a score that would open a new pending cell: s_min times the phase
        # function's mean over its backscatter, 1 / (4 pi p(pi)), within [s_min, top]
        ratio = 1.0 / (4.0 * math.pi * back)
        self.s_new = min(max(self.s_min * ratio, self.s_min), top) if self.s_min > 0 else 0.0
        self.sums = [[[0] * self.cols for _ in NADIR_ROWS] for _ in range(NADIR_BATCHES)]
        self.visits = [[0] * self.cols for _ in NADIR_ROWS]
        # the mirror paths of a slab over a vacuum gap or of a stack, (kind, layer, factor,
        # extra path) (walk.md §8.5)
        self.mirror = [(MIRROR_KINDS[int(k)], int(layer), float(f), float(d))
                       for k, layer, f, d in mirror_table(params)]

    def _transmission(self, j: int, mu: float) -> float:
        """1 − R of interface j crossed upwards at incidence μ (walk.md §7.1)."""
        if not self.fresnel[j]:
            return 1.0
        near, far_n, far_k = self.up_face[j]
        if near * math.sqrt(max(0.0, 1.0 - mu * mu)) >= far_n:
            return 0.0
        if far_n == 1.0 and far_k == 0.0:
            return 1.0 - internal_reflectance(mu, near)
        return 1.0 - external_reflectance(mu, far_n / near, far_k / near)

    def _up(self, layer: int, height: float):
        """The virtual path from ``height`` m below the top of ``layer`` up to vacuum:
        (τ, path at layer 0's speed (m), product of the transmissions)."""
        tau = path = 0.0
        trans = 1.0
        for i in range(layer, -1, -1):
            _, face, n_i, extinction, thickness, _ = self.layers[i]
            s = self.sin_v / face[0]
            mu = math.sqrt(max(0.0, 1.0 - s * s))
            d = height if i == layer else thickness
            tau += extinction * d / mu
            path += d * (n_i / self.n0) / mu
            trans *= self._transmission(i, mu)
        return tau, path, trans

    def new_ray(self, photon: int):
        self.batch = photon % NADIR_BATCHES
        self.cell = -1
        self.pending = 0.0
        self.total = 0.0

    def _column(self, t: float) -> int:
        i = bisect.bisect_right(self.edges, t) - 1
        return 0 if i < 0 else (self.cols - 1 if i >= self.n_time else i + 1)

    def _add(self, s: float, t: float, lamb: bool, order_1: bool, word: int, words: int):
        if self.history_rule:
            row = ROW_BF_DIFFUSE if lamb else ROW_SCATTERING
        else:
            # a path with a floor reflection arrives at t >= t1 exactly, the straight ones
            # down to the lower face and back at t1 itself, within rounding (walk.md §8.1)
            row = ROW_BF_DIFFUSE if (lamb or t >= self.t1 * (1.0 - 2.0 ** -16)) \
                else ROW_SCATTERING
        col = self._column(t)
        cell = row * self.cols + col
        # roulette (walk.md §8.3) against s_new where the score would open a new cell (not the
        # ray's first), else s_min; the uniform (x + 1/2) / T of the surviving word x < T
        threshold = self.s_new if (cell != self.cell and not order_1) else self.s_min
        if not self.weighted and s < threshold:
            if ((word + 0.5) / words) * threshold < s:
                s = threshold
            else:
                return
        if not s > 0.0:
            return
        self.total += s
        if order_1:
            self.sums[self.batch][ROW_ORDER_1][col] += fixed_point(s)
            self.visits[ROW_ORDER_1][col] += 1
        if cell == self.cell:
            self.pending += s
        else:
            self.flush()
            self.cell = cell
            self.pending = s

    def flush(self):
        """The pending cell into the batch's sums (walk.md §8.2)."""
        if self.cell >= 0:
            row, col = divmod(self.cell, self.cols)
            self.sums[self.batch][row][col] += fixed_point(self.pending)
            self.visits[row][col] += 1
            self.cell = -1

    def scatter(self, layer, z, z_top, ux, uz, path, n_scat, n_lamb, weight, word):
        """A volume scattering at depth z in ``layer``, direction (ux, ·, uz) before it."""
        tau, up_path, trans = self._up(layer, z - z_top)
        _, face, _, _, _, g = self.layers[layer]
        s_in = self.sin_v / face[0]
        mu = math.sqrt(max(0.0, 1.0 - s_in * s_in))
        cos_theta = ux * s_in - uz * mu       # toward (sin, 0, −μ), z downwards
        score = (henyey_greenstein_phase(g, cos_theta) * trans * math.exp(-tau)
                 / (face[0] * face[0] * mu) * weight)
        t = (path + up_path) * self.ns_per_metre
        order_1 = n_scat == 0 and n_lamb == 0
        self._add(score, t, n_lamb > 0, order_1, word, self.omega_words[layer])
        for kind, row_layer, factor, extra in self.mirror:
            if row_layer != layer:
                continue
            if kind == "up":                         # up, reflected on the way
                self._add(score * factor, (path + (up_path + extra)) * self.ns_per_metre,
                          n_lamb > 0, order_1, word, self.omega_words[layer])
            elif kind == "down":                     # down, reflected by a face below
                _, _, n_i, extinction, thickness, _ = self.layers[layer]
                below = z_top + thickness - z
                down = ux * s_in + uz * mu           # toward (sin, 0, +μ)
                mirrored = (henyey_greenstein_phase(g, down) * factor
                            * math.exp(-extinction * below / mu) * trans
                            / (face[0] * face[0] * mu) * weight)
                t_down = (path + (below * (n_i / self.n0) / mu + extra)) * self.ns_per_metre
                self._add(mirrored, t_down, n_lamb > 0, order_1, word, self.omega_words[layer])

    def contact(self, layer, path, n_scat, n_lamb, weight, word):
        """A reflection by a floor in contact with ``layer`` (its bottom); n_lamb counts it."""
        _, face, _, _, thickness, _ = self.layers[layer]
        tau, up_path, trans = self._up(layer, thickness)
        s_in = self.sin_v / face[0]
        mu = math.sqrt(max(0.0, 1.0 - s_in * s_in))
        score = (mu / math.pi) * trans * math.exp(-tau) / (face[0] * face[0] * mu) * weight
        t = (path + up_path) * self.ns_per_metre
        self._add(score, t, True, n_scat == 0 and n_lamb == 1, word, self.albedo_words)
        for kind, row_layer, factor, extra in self.mirror:   # a stack: up, reflected above
            if kind == "up" and row_layer == layer:
                self._add(score * factor, (path + (up_path + extra)) * self.ns_per_metre,
                          True, n_scat == 0 and n_lamb == 1, word, self.albedo_words)

    def gap(self, path, n_scat, n_lamb, weight, word):
        """A reflection by the floor below the gap medium; n_lamb counts it."""
        last = len(self.layers) - 1
        tau, up_path, trans = self._up(last, self.layers[last][4])
        m = self.gap_n
        if m <= self.sin_v:
            return
        mu = math.sqrt(max(0.0, 1.0 - (self.sin_v / m) ** 2))
        trans *= self._transmission(last + 1, mu)
        score = (mu / math.pi) * trans * math.exp(-tau) / (m * m * mu) * weight
        t = (path + up_path) * self.ns_per_metre
        self._add(score, t, True, n_scat == 0 and n_lamb == 1, word, self.albedo_words)
        for kind, _, factor, extra in self.mirror:   # reflected by the faces above
            if kind == "gap":
                self._add(score * factor, (path + (up_path + extra)) * self.ns_per_metre,
                          True, n_scat == 0 and n_lamb == 1, word, self.albedo_words)


# --------------------------------------------------------------------------------------------
# One ray (walk.md §3)
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _WalkConstants:
    """The numbers one ray's walk needs, as plain Python floats (walk.md §1)."""

    is_slab: bool
    fresnel_bottom: bool  # slab with a Fresnel interface above the floor (docs/physics.md §5.5)
    thickness: float      # h, m
    extinction: float     # E, 1/m (0: infinite free flight)
    omega: float          # single-scattering albedo
    omega_words: int      # absorbed iff the collision's word x1 >= omega_words (walk.md §2)
    g: float              # Henyey–Greenstein asymmetry
    n: float              # effective index (real part)
    k: float              # effective index (imaginary part)
    albedo: float         # Lambertian albedo A of the floor
    albedo_words: int     # analog floor absorbs iff its word x >= albedo_words
    path_cap: float       # L_max, m
    max_flights: int      # safety cap on free flights
    entry_reflectance: float  # R0, walk.md §3 step 2
    weighted: bool = False    # survival weighting (walk.md §6)
    absorption: float = 0.0   # a = (1 − ω) E, 1/m, applied as exp(−a s) when weighted
    roulette_weight: float = 0.0
    roulette_survival: float = 1.0

    @classmethod
    def from_params(cls, params: WalkParams) -> "_WalkConstants":
        is_slab = params.texture == "slab"
        return cls(is_slab=is_slab,
                   fresnel_bottom=is_slab and params.bottom_interface == "fresnel",
                   thickness=float(params.thickness),
                   extinction=float(params.flight_extinction),
                   omega=float(params.omega), omega_words=params.omega_words,
                   g=float(params.g), n=float(params.n),
                   k=float(params.k), albedo=float(params.albedo),
                   albedo_words=params.albedo_words,
                   path_cap=float(params.path_cap), max_flights=int(params.max_flights),
                   entry_reflectance=normal_incidence_reflectance(float(params.n),
                                                                  float(params.k)),
                   weighted=params.weighted, absorption=float(params.absorption),
                   roulette_weight=float(params.roulette_weight),
                   roulette_survival=float(params.roulette_survival))


class RayOutcome(NamedTuple):
    """What happened to one ray.

    Attributes
    ----------
    fate : int
        Index into :data:`warpe_cl.params.FATES`.
    cos_exit : float
        cos θ_e in vacuum (1 for specular; NaN if the ray did not exit).
    path_length : float
        Path length L inside the medium, m (0 for specular).
    n_scat, n_lamb, n_bspec, n_top : int
        Volume scatterings, floor reflections, bottom specular reflections, top internal
        reflections.
    weight : float
        The ray's weight (walk.md §6); always 1 in the analog walk.
    """

    fate: int
    cos_exit: float
    path_length: float
    n_scat: int
    n_lamb: int
    n_bspec: int
    n_top: int
    weight: float = 1.0


def walk_ray(walk: _WalkConstants, next_block, nadir: NadirScorer | None = None) -> RayOutcome:
    """Walk one ray from launch to its fate, exactly as docs/walk.md §3 says.

    Parameters
    ----------
    walk : _WalkConstants
        The walk's constants (see :func:`simulate_reference`).
    next_block : callable
        Returns the four uniforms (u0, u1, u2, u3) in (0, 1] of the ray's next event
        (``PhotonStream.block``): event k of a ray uses Philox block k (walk.md §2).
    nadir : NadirScorer, optional
        Scores every scattering and floor reflection toward the view direction (walk.md §8).

    Returns
    -------
    RayOutcome
    """
    h = walk.thickness
    extinction = walk.extinction
    omega_words = walk.omega_words
    albedo_words = walk.albedo_words
    g = walk.g
    n = walk.n
    k = walk.k
    albedo = walk.albedo
    path_cap = walk.path_cap
    max_flights = walk.max_flights
    weighted = walk.weighted
    mu_a = walk.absorption
    roulette_weight = walk.roulette_weight
    roulette_survival = walk.roulette_survival
    nan = math.nan

    # 1. Launch (docs/physics.md §5.1): top of the layer, straight down, no path, no events.
    z = 0.0
    ux, uy, uz = 0.0, 0.0, 1.0
    path = 0.0
    weight = 1.0
    n_scat = n_lamb = n_bspec = n_top = 0

    def ended(fate, cos_exit=nan):
        return RayOutcome(fate, cos_exit, path, n_scat, n_lamb, n_bspec, n_top, weight)

    def survives_roulette(u):
        """walk.md §6: below roulette_weight the ray lives on iff u <= roulette_survival."""
        nonlocal weight
        if weight < roulette_weight:
            if u > roulette_survival:
                return False
            weight /= roulette_survival
        return True

    def floor_reflects(u):
        """The floor's toll (walk.md §3.1, §6): analog, reflected iff the event's word is
        below albedo_words (U <= A, decided exactly on the word, walk.md §2); weighted, the
        weight times A (A = 0 ends the ray), then the roulette on u."""
        nonlocal weight
        if not weighted:
            return int(u * TWO_POW_32) < albedo_words
        if albedo == 0.0:
            return False
        weight *= albedo
        return survives_roulette(u)

    # 2. Entry (docs/physics.md §5.2), event 0 of a slab: u0 decides the specular reflection.
    #    "An event of probability P happens iff U <= P" (walk.md §2).
    if walk.is_slab:
        u0, _, _, _ = next_block()
        if u0 <= walk.entry_reflectance:
            return RayOutcome(FATE_SPECULAR, 1.0, 0.0, 0, 0, 0, 0, 1.0)
    # Granular: no interface; the first event is already a flight.

    # 3. One flight per event (walk.md §3 step 3), and one event per floor reflection in the gap.
    flights = 0
    while True:
        # 3.1 Safety cap on the number of flights.
        if flights == max_flights:
            return ended(FATE_TERMINATED)
        flights += 1
        u0, u1, u2, u3 = next_block()

        # 3.2 Free flight (docs/physics.md §5.3): optical step −ln u0, physical step ℓ/E.
        optical_step = -math.log(u0)
        step = optical_step / extinction if extinction > 0.0 else math.inf

        # 3.3 Distance to the boundary the ray is heading for.
        if uz > 0.0:
            to_boundary = (h - z) / uz
        elif uz < 0.0:
            to_boundary = -z / uz
        else:
            to_boundary = math.inf

        if step < to_boundary:
            # 3.4 Collision: move, check the path cap, then scatter or be absorbed.
            z += step * uz
            path += step
            if path > path_cap:
                return ended(FATE_TERMINATED)
            if weighted:
                # walk.md §6: absorption along the flight; every collision scatters, and the
                # roulette draws on u1.
                weight *= math.exp(-mu_a * step)
                if not survives_roulette(u1):
                    return ended(FATE_ABSORBED_MEDIUM)
            elif int(u1 * TWO_POW_32) >= omega_words:
                # U1 > omega decided on the word x1 (walk.md §2): the double uniform is
                # (x1 + 1/2) 2^-32 exactly, so int(u1 2^32) is x1 itself.
                return ended(FATE_ABSORBED_MEDIUM)
            if nadir is not None:   # walk.md §8: with the direction before the scattering
                nadir.scatter(0, z, 0.0, ux, uz, path, n_scat, n_lamb, weight,
                              int(u1 * TWO_POW_32))
            n_scat += 1
            cos_theta = henyey_greenstein_cosine(g, u2)
            psi = TWO_PI * u3
            ux, uy, uz = rotate_direction(ux, uy, uz, cos_theta, psi)
            continue

        # 3.5 Boundary: move onto it, check the path cap, then apply its rule.
        #     (uz == 0 gives an infinite distance, so the path cap has already stopped it.)
        z = h if uz > 0.0 else 0.0
        path += to_boundary
        if path > path_cap:
            return ended(FATE_TERMINATED)
        if weighted:
            weight *= math.exp(-mu_a * to_boundary)

        if uz > 0.0:
            # 3.1 (walk.md) Bottom boundary.
            if walk.fresnel_bottom:
                # Slab over a vacuum gap over the floor (docs/physics.md §5.5).
                mu = uz
                total_internal = n * math.sqrt(max(0.0, 1.0 - mu * mu)) >= 1.0
                # TIR is decided without looking at u1; a partial reflection iff u1 <= R.
                if total_internal or u1 <= internal_reflectance(mu, n):
                    uz = -uz
                    n_bspec += 1
                    continue
                # The ray crosses into the gap: one event per floor reflection, no path length.
                while True:
                    g0, g1, g2, g3 = next_block()
                    # (1) the floor absorbs with probability 1 − A (weighted: weight × A)
                    if not floor_reflects(g0):
                        return ended(FATE_ABSORBED_FLOOR)
                    # (2) Lambertian reflection into vacuum: μ_v = sqrt(g1), ψ = 2π g2
                    n_lamb += 1
                    if nadir is not None:
                        nadir.gap(path, n_scat, n_lamb, weight, int(g0 * TWO_POW_32))
                    mu_vacuum = math.sqrt(g1)
                    psi = TWO_PI * g2
                    # (3) the slab's lower face reflects it back to the floor, or it refracts in
                    if g3 <= external_reflectance(mu_vacuum, n, k):
                        continue
                    sin_slab = math.sqrt(1.0 - mu_vacuum * mu_vacuum) / n
                    ux = sin_slab * math.cos(psi)
                    uy = sin_slab * math.sin(psi)
                    uz = -math.sqrt(1.0 - sin_slab * sin_slab)
                    break
            else:
                # Floor in contact with the medium (slab "none", granular): bare Lambertian,
                # absorbed iff u1 > A (weighted: weight × A), μ = sqrt(u2), ψ = 2π u3.
                if not floor_reflects(u1):
                    return ended(FATE_ABSORBED_FLOOR)
                n_lamb += 1
                if nadir is not None:
                    nadir.contact(0, path, n_scat, n_lamb, weight, int(u1 * TWO_POW_32))
                mu = math.sqrt(u2)
                psi = TWO_PI * u3
                sin_floor = math.sqrt(1.0 - mu * mu)
                ux = sin_floor * math.cos(psi)
                uy = sin_floor * math.sin(psi)
                uz = -mu
            continue

        # 3.2 (walk.md) Top boundary, reached from inside.
        if walk.is_slab:
            # docs/physics.md §5.6: TIR, else reflect iff u1 <= R_int; a reflection sends it down.
            mu = -uz
            sin_sq = max(0.0, 1.0 - mu * mu)
            total_internal = n * math.sqrt(sin_sq) >= 1.0
            if total_internal or u1 <= internal_reflectance(mu, n):
                uz = -uz
                n_top += 1
                continue
            cos_exit = math.sqrt(1.0 - n * n * sin_sq)  # Snell: sin θ_e = n sin θ
        else:
            cos_exit = -uz  # granular: no interface
        return ended(FATE_ESCAPED, cos_exit)


# --------------------------------------------------------------------------------------------
# A stack of layers (walk.md §7)
# --------------------------------------------------------------------------------------------

_VACUUM = (1.0, 0.0)  # the face (n, k) of vacuum, and of a granular layer's pores (walk.md §7.1)


def _face(texture: str, n: float, k: float) -> tuple:
    """The index (n, k) a neighbour sees at a layer's faces (walk.md §7.1 "Faces"): a slab's
    own, a granular layer's pores (1, 0)."""
    return (float(n), float(k)) if texture == "slab" else _VACUUM


def _fresnel_reflects(mu: float, near: float, far_n: float, far_k: float, u: float) -> bool:
    """Reflection at a Fresnel interface (walk.md §7.1), reached at incidence cosine μ from the
    side of real index ``near`` (n₁), the far face being (n₂, k₂) = (far_n, far_k).

    Total internal reflection if n₁ √(1 − μ²) ≥ n₂ (decided without looking at u); otherwise
    reflected iff u ≤ R, with R = R_int(μ; n₁) if the far face is vacuum and
    R_ext(μ; n₂/n₁, k₂/n₁) (the relative complex index) if not.
    """
    if near * math.sqrt(max(0.0, 1.0 - mu * mu)) >= far_n:
        return True
    if far_n == 1.0 and far_k == 0.0:
        reflectance = internal_reflectance(mu, near)
    else:
        reflectance = external_reflectance(mu, far_n / near, far_k / near)
    return u <= reflectance


@dataclass(frozen=True)
class _StackConstants:
    """The numbers a stack's walk needs, as plain Python floats and tuples (walk.md §7.1).

    Per layer i = 0..N−1: ``z_top[i]`` = z_i and ``z_bottom[i]`` = z_{i+1} (m), extinction E_i,
    word threshold T_ω,i, g_i and ``time_scale[i]`` = n_i / n_0. Per interface j = 0..N:
    ``fresnel[j]`` (False: transparent), and the (near n, far n, far k) a ray sees there going
    down (``down_face[j]``) and going up (``up_face[j]``; for j = N, a ray in the gap).
    """

    n_layers: int
    z_top: tuple
    z_bottom: tuple
    extinction: tuple
    omega_words: tuple
    g: tuple
    time_scale: tuple
    fresnel: tuple
    down_face: tuple
    up_face: tuple
    gap_n: float               # real index n_g of the gap medium below the stack
    n0: float                  # layer 0's index: L counts path at its speed
    entry_reflectance: float   # R0 of layer 0 (walk.md §7.2 step 2)
    albedo_words: int
    path_cap: float
    max_flights: int

    @classmethod
    def from_params(cls, params: WalkParams) -> "_StackConstants":
        layers = tuple(params.layers)
        count = len(layers)
        faces = [_face(layer.texture, layer.n, layer.k) for layer in layers]
        # The gap medium (walk.md §7.1 "Faces"): the substrate; else vacuum under a slab with
        # a Fresnel bottom; else the last layer's own face (a floor in optical contact).
        last = layers[-1]
        if params.substrate is not None:
            gap = (float(params.substrate[0]), float(params.substrate[1]))
        elif last.texture == "slab" and params.bottom_interface == "fresnel":
            gap = _VACUUM
        else:
            gap = faces[-1]
        above = [_VACUUM] + faces          # the face above interface j
        below = faces + [gap]             # the face below interface j
        fresnel = tuple(above[j] != below[j] for j in range(count + 1))
        down_face = tuple((above[j][0], below[j][0], below[j][1]) for j in range(count + 1))
        up_face = tuple((below[j][0], above[j][0], above[j][1]) for j in range(count + 1))
        z = [0.0]
        for layer in layers:
            z.append(z[-1] + float(layer.thickness))
        n0 = float(layers[0].n)
        return cls(n_layers=count, z_top=tuple(z[:-1]), z_bottom=tuple(z[1:]),
                   extinction=tuple(float(layer.extinction) for layer in layers),
                   omega_words=tuple(layer.omega_words for layer in layers),
                   g=tuple(float(layer.g) for layer in layers),
                   time_scale=tuple(float(layer.n) / n0 for layer in layers),
                   fresnel=fresnel, down_face=down_face, up_face=up_face, gap_n=gap[0],
                   n0=n0, entry_reflectance=normal_incidence_reflectance(
                       n0, float(layers[0].k)),
                   albedo_words=params.albedo_words, path_cap=float(params.path_cap),
                   max_flights=int(params.max_flights))


class LayeredRayOutcome(NamedTuple):
    """What happened to one ray of a stack (walk.md §7.2): the fields of :class:`RayOutcome`,
    plus the layer it ended in and its transmissions through each interface.

    Attributes
    ----------
    fate, cos_exit, path_length, n_scat, n_lamb, n_bspec, n_top, weight
        As :class:`RayOutcome`; ``path_length`` is L, path counted at layer 0's speed (m),
        and ``weight`` is always 1 (the layered walk is analog only).
    layer : int
        ℓ at the end (the record's ``layer``): the layer the ray was absorbed or terminated
        in, N if the floor absorbed it in the gap, N − 1 if a floor in contact did, 0 for an
        exit and for the specular reflection.
    down, up : tuple of int, length N + 1
        Transmissions of this ray down and up through each interface j (walk.md §7.4):
        j = 0 its entry and its exit, j = N into and out of the gap.
    """

    fate: int
    cos_exit: float
    path_length: float
    n_scat: int
    n_lamb: int
    n_bspec: int
    n_top: int
    weight: float
    layer: int
    down: tuple
    up: tuple


def walk_ray_layers(stack: _StackConstants, next_block,
                    nadir: NadirScorer | None = None) -> LayeredRayOutcome:
    """Walk one ray through a stack of layers from launch to its fate (walk.md §7.2).

    Parameters
    ----------
    stack : _StackConstants
        The stack's constants (:meth:`_StackConstants.from_params`).
    next_block : callable
        Returns the four uniforms (u0, u1, u2, u3) of the ray's next event (walk.md §2).
    nadir : NadirScorer, optional
        Scores every scattering and floor reflection toward the view direction (walk.md §8).

    Returns
    -------
    LayeredRayOutcome
    """
    count = stack.n_layers
    z_top = stack.z_top
    z_bottom = stack.z_bottom
    extinctions = stack.extinction
    omega_words = stack.omega_words
    gs = stack.g
    time_scale = stack.time_scale
    fresnel = stack.fresnel
    down_face = stack.down_face
    up_face = stack.up_face
    n0 = stack.n0
    albedo_words = stack.albedo_words
    path_cap = stack.path_cap
    max_flights = stack.max_flights
    nan = math.nan

    # 1. Launch: top of the stack, straight down, no path, layer 0, no events.
    z = 0.0
    ux, uy, uz = 0.0, 0.0, 1.0
    path = 0.0
    layer = 0
    n_scat = n_lamb = n_bspec = n_top = 0
    down = [0] * (count + 1)
    up = [0] * (count + 1)

    def ended(fate, cos_exit=nan):
        return LayeredRayOutcome(fate, cos_exit, path, n_scat, n_lamb, n_bspec, n_top, 1.0,
                                 layer, tuple(down), tuple(up))

    # 2. Entry event (event 0) iff interface 0 is Fresnel: specular iff u0 <= R0.
    if fresnel[0]:
        u0, _, _, _ = next_block()
        if u0 <= stack.entry_reflectance:
            return ended(FATE_SPECULAR, 1.0)
    down[0] += 1  # the ray enters the stack (a transparent top: every launched ray)

    # 3. Flight events, and gap events below the stack.
    flights = 0
    while True:
        # 3.1 Safety cap on the number of flights.
        if flights == max_flights:
            return ended(FATE_TERMINATED)
        flights += 1
        u0, u1, u2, u3 = next_block()

        # 3.2 Free flight with layer ℓ's extinction.
        extinction = extinctions[layer]
        optical_step = -math.log(u0)
        step = optical_step / extinction if extinction > 0.0 else math.inf

        # 3.3 Distance to layer ℓ's boundary the ray is heading for.
        if uz > 0.0:
            to_boundary = (z_bottom[layer] - z) / uz
        elif uz < 0.0:
            to_boundary = (z_top[layer] - z) / uz
        else:
            to_boundary = math.inf
        scale = time_scale[layer]

        if step < to_boundary:
            # 3.4 Collision: move (L counts path at layer 0's speed), cap, scatter or absorb.
            z += step * uz
            path += step * scale
            if path > path_cap:
                return ended(FATE_TERMINATED)
            if int(u1 * TWO_POW_32) >= omega_words[layer]:
                return ended(FATE_ABSORBED_MEDIUM)
            if nadir is not None:
                nadir.scatter(layer, z, z_top[layer], ux, uz, path, n_scat, n_lamb, 1.0,
                              int(u1 * TWO_POW_32))
            n_scat += 1
            cos_theta = henyey_greenstein_cosine(gs[layer], u2)
            psi = TWO_PI * u3
            ux, uy, uz = rotate_direction(ux, uy, uz, cos_theta, psi)
            continue

        # 3.5 Boundary: move onto it, cap, then the rule of interface j.
        going_down = uz > 0.0
        if going_down:
            z = z_bottom[layer]
            j = layer + 1
        else:
            z = z_top[layer]
            j = layer
        path += to_boundary * scale
        if path > path_cap:
            return ended(FATE_TERMINATED)

        if going_down and j == count:
            # The bottom of the stack.
            if not fresnel[j]:
                # The floor in contact (§3.1 second rule): toll on x1, μ = √u2, ψ = 2π u3.
                if int(u1 * TWO_POW_32) >= albedo_words:
                    return ended(FATE_ABSORBED_FLOOR)  # ℓ = N − 1
                n_lamb += 1
                if nadir is not None:
                    nadir.contact(layer, path, n_scat, n_lamb, 1.0, int(u1 * TWO_POW_32))
                mu = math.sqrt(u2)
                psi = TWO_PI * u3
                sin_floor = math.sqrt(max(0.0, 1.0 - mu * mu))
                ux = sin_floor * math.cos(psi)
                uy = sin_floor * math.sin(psi)
                uz = -mu
                continue
            near, far_n, far_k = down_face[j]
            if _fresnel_reflects(uz, near, far_n, far_k, u1):
                uz = -uz
                n_bspec += 1
                continue
            # Into the gap: one gap event (one block) per floor reflection, no path length.
            down[j] += 1
            layer = count
            gap_n, last_n, last_k = up_face[count]  # near n_g, far the last layer's face
            while True:
                g0, g1, g2, g3 = next_block()
                # (1) the floor's toll on the word x0
                if int(g0 * TWO_POW_32) >= albedo_words:
                    return ended(FATE_ABSORBED_FLOOR)  # ℓ = N
                # (2) a Lambertian direction in the gap medium: μ_g = √u1, ψ = 2π u2
                n_lamb += 1
                if nadir is not None:
                    nadir.gap(path, n_scat, n_lamb, 1.0, int(g0 * TWO_POW_32))
                mu_gap = math.sqrt(g1)
                psi = TWO_PI * g2
                # (3) back to the floor (TIR, or u3 <= R), or refracted into the last layer
                if _fresnel_reflects(mu_gap, gap_n, last_n, last_k, g3):
                    continue
                sin_in = (math.sqrt(max(0.0, 1.0 - mu_gap * mu_gap)) * gap_n) / last_n
                ux = sin_in * math.cos(psi)
                uy = sin_in * math.sin(psi)
                uz = -math.sqrt(max(0.0, 1.0 - sin_in * sin_in))
                layer = count - 1
                up[count] += 1
                break
            continue

        if not going_down and j == 0:
            # The top of the stack: a slab's Fresnel face (§3.2 with n_0), or none.
            if fresnel[0]:
                mu = -uz
                near, far_n, far_k = up_face[0]
                if _fresnel_reflects(mu, near, far_n, far_k, u1):
                    uz = -uz
                    n_top += 1
                    continue
                cos_exit = math.sqrt(max(0.0, (1.0 - n0 * n0) + n0 * n0 * mu * mu))
            else:
                cos_exit = -uz
            up[0] += 1
            return ended(FATE_ESCAPED, cos_exit)

        # A buried interface 0 < j < N: transparent, or Fresnel (reflect or refract).
        if fresnel[j]:
            near, far_n, far_k = down_face[j] if going_down else up_face[j]
            if _fresnel_reflects(abs(uz), near, far_n, far_k, u1):
                uz = -uz
                n_bspec += 1
                continue
            r = near / far_n
            ux *= r
            uy *= r
            root = math.sqrt(max(0.0, (1.0 - r * r) + r * r * uz * uz))
            uz = root if going_down else -root
        if going_down:
            down[j] += 1
            layer += 1
        else:
            up[j] += 1
            layer -= 1


# --------------------------------------------------------------------------------------------
# Many rays and the tallies (walk.md §4)
# --------------------------------------------------------------------------------------------

def _check_params(params: WalkParams) -> np.ndarray:
    """Validate what the reference relies on; return the time edges as float64."""
    if params.layered:
        _check_stack(params)
    else:
        if params.texture not in TEXTURES:
            raise ValueError(f"texture must be one of {TEXTURES + ('layers',)}, "
                             f"got {params.texture!r}")
        if params.layers or params.substrate is not None:
            raise ValueError("layers and a substrate need texture 'layers' (walk.md §7), "
                             f"got texture {params.texture!r}")
    if params.bottom_interface not in BOTTOM_INTERFACES:
        raise ValueError(f"bottom_interface must be one of {BOTTOM_INTERFACES}, "
                         f"got {params.bottom_interface!r}")
    if params.rule not in RULES:
        raise ValueError(f"rule must be one of {RULES}, got {params.rule!r}")
    edges = np.asarray(params.time_edges, dtype=np.float64)
    if edges.ndim != 1 or len(edges) < 2 or not np.all(np.diff(edges) > 0):
        raise ValueError("time_edges (ns) must be a 1-D increasing array of at least 2 edges")
    if not params.thickness > 0:
        raise ValueError(f"thickness must be > 0 m, got {params.thickness}")
    if not params.extinction >= 0:
        raise ValueError(f"extinction must be >= 0 1/m, got {params.extinction}")
    return edges


def _check_stack(params: WalkParams) -> None:
    """Validate a stack (walk.md §7.1): 1..MAX_LAYERS slab or granular layers of thickness
    > 0 and extinction >= 0, the analog mode, layer 0's index in ``n`` (L_max and t = L n_0/c
    use it) and a substrate (n > 0, k >= 0) if any."""
    layers = tuple(params.layers)
    if not 1 <= len(layers) <= MAX_LAYERS:
        raise ValueError(f"a stack holds 1 to {MAX_LAYERS} layers, got {len(layers)}")
    for i, layer in enumerate(layers):
        if layer.texture not in TEXTURES:
            raise ValueError(f"layer {i}: texture must be one of {TEXTURES}, "
                             f"got {layer.texture!r}")
        if not layer.thickness > 0:
            raise ValueError(f"layer {i}: thickness must be > 0 m, got {layer.thickness}")
        if not layer.extinction >= 0:
            raise ValueError(f"layer {i}: extinction must be >= 0 1/m, "
                             f"got {layer.extinction}")
    if params.weighted:
        raise ValueError("only the analog walk is layered (walk.md §7): mode 'weighted' "
                         "refuses a stack")
    if float(params.n) != float(layers[0].n):
        raise ValueError(f"a stack's n must be layer 0's index ({layers[0].n}): L_max and "
                         f"t = L n_0 / c use it, got {params.n}")
    if params.substrate is not None:
        n_s, k_s = params.substrate
        if not (n_s > 0 and k_s >= 0):
            raise ValueError(f"substrate (n, k) needs n > 0 and k >= 0, got {params.substrate}")


def simulate_reference(params: WalkParams, photons: int, first_photon: int = 0,
                       records: bool = False, progress=None) -> Counts:
    """Walk photons ``first_photon .. first_photon + photons − 1`` and tally them (walk.md).

    Parameters
    ----------
    params : WalkParams
        The scenario (docs/walk.md §1).
    photons : int
        Number of rays.
    first_photon : int, optional
        Index of the first ray; photon p always draws from counter (block, p_lo, p_hi, 0), so
        splitting a run into calls changes nothing.
    records : bool, optional
        Also return per-photon records in ``Counts.records`` (see :data:`RECORD_FIELDS`).
    progress : callable, optional
        Called as ``progress(n_done)`` every 1000 photons and at the end.

    Returns
    -------
    Counts
        All tallies of walk.md §4; ``n_time = len(time_edges) − 1``.

    Raises
    ------
    WeightError
        Weighted mode: some exiting ray's weight was NaN, negative or >= 2**21 (walk.md §6).
    """
    edges_array = _check_params(params)
    edges = edges_array.tolist()
    n_time = len(edges) - 1
    layered = params.layered
    if layered:
        walk = _StackConstants.from_params(params)
        walk_one = walk_ray_layers
    else:
        walk = _WalkConstants.from_params(params)
        walk_one = walk_ray
    cos_fov = [float(c) for c in params.cos_fov]
    use_history_rule = params.rule == "history"
    first_bf_time = float(params.first_bf_time)  # t1 = 2 h n / c (stack: 2 Σ h_i n_i / c), ns
    ns_per_metre = float(params.n) / C_M_PER_NS  # t = L n / c (stack: n = n_0, walk.md §7.2)

    counts = Counts(n_time=n_time, photons=int(photons), weighted=params.weighted,
                    nadir=bool(params.nadir))
    nadir = _nadir_scorer(params, walk, edges) if params.nadir else None
    weighted = params.weighted
    fates = [0] * len(FATES)
    total = [0] * len(COMPONENTS)
    angular = [[0] * N_EMERGENCE for _ in COMPONENTS]
    time_any = [[0] * n_time for _ in COMPONENTS]
    time_in_fov = [[0] * n_time for _ in COMPONENTS]
    early = [0] * len(COMPONENTS)
    lost = 0  # weighted exits whose weight the exact sums cannot hold
    scattering_events = 0
    mixed_history = 0
    # walk.md §7.4: the per-layer statistics, in the slots of LAYER_STATS
    layer_stats = [0] * len(LAYER_STATS)
    slot_absorbed = LAYER_STATS.index("absorbed_0")
    slot_terminated = LAYER_STATS.index("terminated_0")
    slot_down = LAYER_STATS.index("down_0")
    slot_up = LAYER_STATS.index("up_0")
    rows = {name: [] for name in RECORD_FIELDS} if records else None

    batch = 1000
    done = 0
    while done < photons:
        streams = PhotonStream.many(params.seed, params.scenario, first_photon + done,
                                    min(batch, photons - done), precision="double")
        for i, stream in enumerate(streams):
            if nadir is not None:
                nadir.new_ray(first_photon + done + i)
            ray = walk_one(walk, stream.block, nadir)
            if nadir is not None:
                nadir.flush()
            fates[ray.fate] += 1
            if layered:
                if ray.fate == FATE_ABSORBED_MEDIUM:
                    layer_stats[slot_absorbed + ray.layer] += 1
                elif ray.fate == FATE_TERMINATED:
                    layer_stats[slot_terminated + ray.layer] += 1
                for j, (d, u) in enumerate(zip(ray.down, ray.up)):
                    layer_stats[slot_down + j] += d
                    layer_stats[slot_up + j] += u
            scattering_events += ray.n_scat
            component = -1
            time_ns = math.nan
            time_bin = -1
            angle_bin = -1
            if ray.fate == FATE_SPECULAR or ray.fate == FATE_ESCAPED:
                # Component of the exit (walk.md §4, docs/physics.md §6.1).
                if ray.fate == FATE_SPECULAR:
                    component = SPECULAR
                    time_ns = 0.0
                else:
                    time_ns = ray.path_length * ns_per_metre
                    if ray.n_scat == 0 and ray.n_lamb == 0:
                        component = BF_DIRECT
                    elif use_history_rule:
                        component = BF_DIFFUSE if ray.n_lamb >= 1 else SCATTERING
                    else:
                        component = BF_DIFFUSE if time_ns >= first_bf_time else SCATTERING
                    if ray.n_scat >= 1 and ray.n_lamb >= 1:
                        mixed_history += 1
                # Emergence bin: min(floor(θ_e in degrees), 89), by the table of cos(k°)
                angle_bin = emergence_bin(ray.cos_exit)
                # Time bin i with edges[i] <= t < edges[i+1] (searchsorted(side="right") - 1);
                # before edges[0]: an early exit, counted apart and never in a bin; at or
                # after edges[-1]: no bin (walk.md §4).
                time_bin = bisect.bisect_right(edges, time_ns) - 1
                if time_bin < 0:
                    time_bin = TIME_BIN_EARLY
                elif time_bin >= n_time:
                    time_bin = TIME_BIN_LATE
                in_fov = ray.cos_exit >= cos_fov[component]
                total[component] += 1
                angular[component][angle_bin] += 1
                if time_bin >= 0:
                    time_any[component][time_bin] += 1
                    if in_fov:
                        time_in_fov[component][time_bin] += 1
                elif time_bin == TIME_BIN_EARLY:
                    early[component] += 1
                if weighted and lost_weight(ray.weight):
                    lost += 1          # the exact sums cannot hold it: refused below
                elif weighted:
                    # walk.md §6: exact fixed-point sums of w and w^2
                    w1, w2 = fixed_point(ray.weight), fixed_point(ray.weight * ray.weight)
                    counts.w_total[component] += w1
                    counts.w2_total[component] += w2
                    counts.w_angular[component, angle_bin] += w1
                    if time_bin == TIME_BIN_EARLY:
                        counts.w_early[component] += w1
                    if time_bin >= 0:
                        counts.w_time_any[component, time_bin] += w1
                        if in_fov:
                            counts.w_time_in_fov[component, time_bin] += w1
                            counts.w2_time_in_fov[component, time_bin] += w2
            if rows is not None:
                rows["fate"].append(ray.fate)
                rows["component"].append(component)
                rows["time_ns"].append(time_ns)
                rows["cos_exit"].append(ray.cos_exit)
                rows["weight"].append(ray.weight)
                rows["n_scat"].append(ray.n_scat)
                rows["n_lamb"].append(ray.n_lamb)
                rows["n_bspec"].append(ray.n_bspec)
                rows["n_top"].append(ray.n_top)
                rows["time_bin"].append(time_bin)
                rows["emergence_bin"].append(angle_bin)
                rows["layer"].append(ray.layer if layered else 0)
                rows["nadir"].append(nadir.total if nadir is not None else 0.0)
        done += len(streams)
        if progress is not None:
            progress(done)

    if lost:
        raise WeightError(lost)
    counts.fates[:] = fates
    counts.total[:] = total
    counts.early[:] = early
    counts.angular[:] = angular
    counts.time_any[:] = time_any
    counts.time_in_fov[:] = time_in_fov
    counts.scattering_events = int(scattering_events)
    counts.mixed_history = int(mixed_history)
    counts.layer_stats[:] = layer_stats
    if nadir is not None:
        for b in range(NADIR_BATCHES):
            for r in range(len(NADIR_ROWS)):
                counts.nadir_sum[b, r, :] = nadir.sums[b][r]
        counts.nadir_visits[...] = nadir.visits
        counts.nadir_batch_photons[...] = batch_photons(first_photon, photons)
    if rows is not None:
        counts.records = {name: np.asarray(values, dtype=dtype)
                          for (name, values), dtype in zip(rows.items(),
                                                           RECORD_FIELDS.values())}
    return counts


def _nadir_scorer(params: WalkParams, walk, edges: list) -> NadirScorer:
    """The estimator of a walk (walk.md §8): its layers, top first, as (texture, face, n, E,
    h, g) with the true extinction E (both modes), and its interfaces."""
    if params.layered:
        layers = [(x.texture, _face(x.texture, x.n, x.k), float(x.n), float(x.extinction),
                   float(x.thickness), float(x.g)) for x in params.layers]
        return NadirScorer(params, layers, walk.fresnel, walk.up_face, walk.gap_n, edges,
                           walk.omega_words, walk.albedo_words)
    face = _face(params.texture, params.n, params.k)
    layers = [(params.texture, face, float(params.n), float(params.extinction),
               float(params.thickness), float(params.g))]
    gap_fresnel = params.texture == "slab" and params.bottom_interface == "fresnel"
    fresnel = (params.texture == "slab", gap_fresnel)
    up_face = ((face[0], 1.0, 0.0), (1.0, face[0], face[1]))
    return NadirScorer(params, layers, fresnel, up_face, 1.0, edges, (params.omega_words,),
                       params.albedo_words)


class ReferenceEngine:
    """The reference walk behind the engine interface: ``--device numpy``, no OpenCL needed.

    Always double precision; slow (about 1e5 photons/s for an optically thin layer on one
    core), meant for checks and for machines without any OpenCL driver.
    """

    name = "numpy"
    kernel_hash = ""
    #: The precision every reference walk runs in, whatever simulation.precision asks.
    fixed_precision = "double"
    provenance = {"opencl_platform": "none", "opencl_device": "numpy reference walk",
                  "opencl_driver": "none", "opencl_device_type": "none"}

    def run(self, params: WalkParams, photons: int, precision: str = "double",
            first_photon: int = 0, records: bool = False, progress=None, **_launch) -> Counts:
        """Walk ``photons`` rays from ``first_photon`` (launch options are ignored)."""
        return simulate_reference(params, photons, first_photon=first_photon, records=records,
                                  progress=progress)
