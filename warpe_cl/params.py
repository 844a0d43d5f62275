"""The plain values a walk needs: :class:`WalkParams` (input) and :class:`Counts` (output).

Both the OpenCL engine (:mod:`warpe_cl.engine`) and the NumPy reference
(:mod:`warpe_cl.reference`) take a :class:`WalkParams` and return a :class:`Counts`; the
rules that connect the two are written out in ``docs/walk.md``.
"""
from __future__ import annotations

import bisect
import math
from fractions import Fraction
from dataclasses import dataclass, field

import numpy as np

#: speed of light in vacuum, m/ns
C_M_PER_NS = 0.299792458

COMPONENTS = ("specular", "bf_direct", "bf_diffuse", "scattering")
N_COMPONENTS = len(COMPONENTS)
FATES = ("specular", "escaped", "absorbed_medium", "absorbed_floor", "terminated")
N_FATES = len(FATES)
N_EMERGENCE = 90  # 1-degree emergence bins, 0..90 deg
#: cos(k degrees), k = 0 .. N_EMERGENCE - 1: the emergence bins' edges in cosine. cl/tally.h
#: holds the same doubles (and their floats, for the single-precision walk) as COS_DEGREE.
COS_DEGREE = tuple(math.cos(math.radians(k)) for k in range(N_EMERGENCE))
_MINUS_COS_DEGREE = tuple(-c for c in COS_DEGREE[1:])        # increasing, for bisect


def emergence_bin(cos_exit: float) -> int:
    """The emergence bin of an exit (docs/walk.md §4): min(floor(θ_e in degrees), 89) with
    θ_e = acos(cos_exit), counted as the whole degrees k in 1 .. 89 with cos_exit <= cos(k°)
    (:data:`COS_DEGREE`): the rule of cl/tally.h ``emergence_bin``, whose table decides
    where each driver's acos differs in its last bits."""
    c = min(max(cos_exit, 0.0), 1.0)
    return bisect.bisect_right(_MINUS_COS_DEGREE, -c)


TEXTURES = ("slab", "granular")
#: The kernel builds: one per texture of a single layer, and one for a stack of layers (or a
#: layer over a substrate), whose textures are per-layer values (docs/walk.md §7).
KERNEL_TEXTURES = TEXTURES + ("layers",)
#: Most layers a stack may hold (the per-layer statistics of the kernel, ``LAYER_STATS``).
MAX_LAYERS = 8
BOTTOM_INTERFACES = ("fresnel", "none")
RULES = ("history", "time_window")
#: time_bin of an exit at or after the last edge (or of a ray that did not exit), and of an
#: early exit, before the first edge (docs/walk.md §4)
TIME_BIN_LATE, TIME_BIN_EARLY = -1, -2

#: Weighted tallies are exact sums of floor(w * 2**FIXED_SHIFT) (docs/walk.md §6), each held
#: in FIXED_WORDS 64-bit words (low, middle, high: 192 bits, cl/tally.h fixed_add).
FIXED_SHIFT = 150
FIXED_WORDS = 3
#: The histograms the kernel fills (uint32 per launch), each over the cells of
#: :func:`tally_shapes`.
HISTOGRAMS = ("time_in_fov", "time_any", "angular", "total", "early")
#: The analog tallies of :class:`Counts`: the histograms, and the fates (from ``item_stats``).
COUNT_TALLIES = HISTOGRAMS + ("fates",)
#: The weighted sums (docs/walk.md §6), each over the cells of the histogram it names.
WEIGHT_TALLIES = {"w_time_in_fov": "time_in_fov", "w_time_any": "time_any",
                  "w_angular": "angular", "w_total": "total", "w2_time_in_fov": "time_in_fov",
                  "w2_total": "total", "w_early": "early"}
#: A weighted ray whose weight reaches this (or is NaN) cannot be tallied exactly: its square
#: would pass 2**42, the top of the 192-bit sums (docs/walk.md §6).
MAX_WEIGHT = 2.0 ** 21

#: The slots of the kernel's per-work-item statistics (``item_stats[work-item][slot]``, uint64),
#: in slot order: rays per fate, volume scatterings, mixed-history exits, and weighted exits
#: whose weight the exact sums cannot hold (:func:`lost_weight`).
ITEM_STATS = tuple(f"fate_{f}" for f in FATES) + ("scattering_events", "mixed_history",
                                                    "lost_weights")
#: The columns of a per-photon record (``Counts.records``, for the parity tests): the kernel
#: writes ``rec_int[photon][RECORD_INT_COLUMNS]`` (int32) and
#: ``rec_real[photon][RECORD_REAL_COLUMNS]`` (REAL).
RECORD_INT_COLUMNS = ("fate", "component", "n_scat", "n_lamb", "n_bspec", "n_top", "time_bin",
                      "emergence_bin", "layer")
RECORD_REAL_COLUMNS = ("time_ns", "cos_exit", "weight", "nadir")
#: The columns of a parked ray (cl/walk.cl ``carry_t``): a launch that spends its event budget
#: writes each unfinished ray as a row of ``STATE_REAL_COLUMNS`` (REAL) and ``STATE_INT_COLUMNS``
#: (uint32), and the next launch resumes it from there (docs/walk.md §5).
STATE_REAL_COLUMNS = ("z", "ux", "uy", "uz", "ls", "lc", "w", "nadir_pending", "nadir_lo",
                      "nadir_hi", "nadir_sum")
STATE_INT_COLUMNS = ("flights", "n_scat", "n_lamb", "n_bspec", "n_top", "phase", "event",
                     "p_lo", "p_hi", "layer", "nadir_cell")
#: The rows of the next-event (nadir) tallies (docs/walk.md §8): the two diffuse components of
#: the virtual paths, then the virtual paths of order 1 (one scattering or floor reflection)
#: whatever their component. Each row has n_time + 2 columns: before the first edge, the time
#: bins, at or after the last edge.
NADIR_ROWS = ("bf_diffuse", "scattering", "order_1")
#: The photons of a walk fall into this many batches, photon p into batch p mod NADIR_BATCHES:
#: the nadir sums are kept per batch, whose spread gives their standard error (docs/walk.md §8)
NADIR_BATCHES = 32
#: The columns of the view table (``view[l][...]``, REAL; docs/walk.md §8): for each layer l
#: (then the gap medium below the stack), the view direction inside it (sin, mu: the sine and
#: cosine of its angle to the vertical), the optical depth and the path (at layer 0's speed)
#: per metre of depth along it, those of the layers above l, and the factor T / (m^2 mu) that
#: turns a density per steradian inside l into the reflectance in vacuum.
VIEW_COLUMNS = ("sin", "mu", "tau_per_m", "path_per_m", "tau_above", "path_above", "factor")
#: Columns of the nadir estimator's mirror table (warpe_cl.nadir.mirror_table): the kind of
#: virtual path (MIRROR_UP, MIRROR_DOWN, MIRROR_GAP), the layer whose events it starts from (N:
#: the floor below the gap), its factor and its extra path (m, at layer 0's speed).
MIRROR_COLUMNS = ("kind", "layer", "factor", "path")
MIRROR_KINDS = ("up", "down", "gap")
#: The per-layer statistics of the layered walk (docs/walk.md §7.4), per work-item
#: (``layer_stats[work-item][slot]``, uint64): rays absorbed in the medium of layer i, rays
#: terminated in layer i, and transmissions down and up through interface j (j = 0: the top of
#: the stack, j = N: the contact with the gap or substrate below the last layer).
LAYER_STATS = (tuple(f"absorbed_{i}" for i in range(MAX_LAYERS))
               + tuple(f"terminated_{i}" for i in range(MAX_LAYERS))
               + tuple(f"down_{j}" for j in range(MAX_LAYERS + 1))
               + tuple(f"up_{j}" for j in range(MAX_LAYERS + 1)))
#: The columns of the layer table the layered kernel reads (``layer_real[i][...]``, REAL):
#: the top and bottom depths (m), the flight extinction (1/m), HG g, and n_i / n_0, the factor
#: that turns a path in layer i into path of layer 0's speed (docs/walk.md §7.2).
LAYER_REAL_COLUMNS = ("z_top", "z_bottom", "extinction", "g", "time_scale")
#: The columns of the interface table (``iface_real[j][...]``, REAL; docs/walk.md §7.1): for a
#: ray going down through interface j and for one going up, the real index on its side
#: (near), and the complex index of the far side.
IFACE_REAL_COLUMNS = ("down_near", "down_far_n", "down_far_k", "up_near", "up_far_n",
                      "up_far_k")
#: Per-photon record fields and their dtypes (``Counts.records`` when asked for).
RECORD_FIELDS = {
    "fate": np.int8,            # index into FATES
    "component": np.int8,       # index into COMPONENTS, -1 if the ray did not exit
    "time_ns": np.float64,      # exit time, ns (0 for specular, NaN if not exited)
    "cos_exit": np.float64,     # cos of the emergence angle in vacuum (NaN if not exited)
    "weight": np.float64,       # the ray's weight at its end (1 in the analog walk)
    "nadir": np.float64,        # the ray's next-event scores toward the view direction, summed
                                # over its events, sr^-1 (0 without the estimator; walk.md §8)
    "n_scat": np.int64,         # volume scatterings
    "n_lamb": np.int64,         # floor (Lambertian) reflections
    "n_bspec": np.int64,        # specular reflections at the bottom interface (a stack: at
                                # any interface but the top, from either side)
    "n_top": np.int64,          # internal reflections at the top
    "time_bin": np.int64,       # TIME_BIN_LATE if t >= edges[-1] or not exited, TIME_BIN_EARLY
                                # if t < edges[0]
    "emergence_bin": np.int64,  # 1-degree bin, -1 if not exited
    "layer": np.int64,          # layered walk: the layer the ray ended in (N: the gap below the
                                # stack); 0 in a single layer's walk
}


def tally_shapes(n_time: int) -> dict:
    """The shape of every tally of :class:`Counts`: the histograms, ``fates``, and the
    weighted sums (one cell of a weighted sum holds one exact integer; the kernel keeps it in
    :data:`FIXED_WORDS` words).

    Parameters
    ----------
    n_time : int
        Number of time bins (``len(time_edges) - 1``).

    Returns
    -------
    dict
        Tally name -> shape.
    """
    cells = {"time_in_fov": (N_COMPONENTS, n_time), "time_any": (N_COMPONENTS, n_time),
             "angular": (N_COMPONENTS, N_EMERGENCE), "total": (N_COMPONENTS,),
             "early": (N_COMPONENTS,), "fates": (N_FATES,)}
    return {**cells, **{w: cells[h] for w, h in WEIGHT_TALLIES.items()}}


def kernel_layout() -> dict:
    """The layouts the host and the kernel share, as the ``-D`` macros of the walk kernel
    (warpe_cl/engine.py build_options): component, fate, statistics-slot, record-column and
    parked-ray-column indices, table sizes, the time-bin sentinels and the fixed-point format.
    They are defined here only; cl/tally.h and cl/walk.cl use the names.

    Returns
    -------
    dict
        Macro name -> its value, as OpenCL C source text.
    """
    out = {"N_COMPONENTS": N_COMPONENTS}
    out.update({f"COMPONENT_{c.upper()}": i for i, c in enumerate(COMPONENTS)})
    out["N_FATES"] = N_FATES
    out.update({f"FATE_{f.upper()}": i for i, f in enumerate(FATES)})
    out["N_EMERGENCE"] = N_EMERGENCE
    out.update(TIME_BIN_LATE=TIME_BIN_LATE, TIME_BIN_EARLY=TIME_BIN_EARLY)
    out["N_ITEM_STATS"] = len(ITEM_STATS)
    out.update({f"STAT_{s.upper()}": i for i, s in enumerate(ITEM_STATS)})
    out["N_RECORD_INT"] = len(RECORD_INT_COLUMNS)
    out.update({f"RECORD_{c.upper()}": i for i, c in enumerate(RECORD_INT_COLUMNS)})
    out["N_RECORD_REAL"] = len(RECORD_REAL_COLUMNS)
    out.update({f"RECORD_{c.upper()}": i for i, c in enumerate(RECORD_REAL_COLUMNS)})
    out["N_STATE_REAL"] = len(STATE_REAL_COLUMNS)
    out.update({f"STATE_{c.upper()}": i for i, c in enumerate(STATE_REAL_COLUMNS)})
    out["N_STATE_INT"] = len(STATE_INT_COLUMNS)
    out.update({f"STATE_{c.upper()}": i for i, c in enumerate(STATE_INT_COLUMNS)})
    out["N_LAYER_STATS"] = len(LAYER_STATS)
    out.update(LSTAT_ABSORBED=0, LSTAT_TERMINATED=MAX_LAYERS, LSTAT_DOWN=2 * MAX_LAYERS,
               LSTAT_UP=3 * MAX_LAYERS + 1)
    out["N_LAYER_REAL"] = len(LAYER_REAL_COLUMNS)
    out.update({f"LAYER_{c.upper()}": i for i, c in enumerate(LAYER_REAL_COLUMNS)})
    out["N_IFACE_REAL"] = len(IFACE_REAL_COLUMNS)
    out.update({f"IFACE_{c.upper()}": i for i, c in enumerate(IFACE_REAL_COLUMNS)})
    out.update(FIXED_SHIFT=FIXED_SHIFT, FIXED_WORDS=FIXED_WORDS)
    out["N_NADIR_ROWS"] = len(NADIR_ROWS)
    out.update({f"NADIR_ROW_{c.upper()}": i for i, c in enumerate(NADIR_ROWS)})
    out["NADIR_BATCHES"] = NADIR_BATCHES
    out["N_VIEW"] = len(VIEW_COLUMNS)
    out.update({f"VIEW_{c.upper()}": i for i, c in enumerate(VIEW_COLUMNS)})
    out["N_MIRROR"] = len(MIRROR_COLUMNS)
    out.update({f"MIRROR_{c.upper()}": i for i, c in enumerate(MIRROR_COLUMNS)})
    out.update({f"MIRROR_{k.upper()}": i for i, k in enumerate(MIRROR_KINDS)})
    text = {k: (f"({v})" if v < 0 else str(v)) for k, v in out.items()}
    text["MAX_WEIGHT"] = float.hex(MAX_WEIGHT)     # exact: a C99 hexadecimal literal
    return text


def lost_weight(weight: float) -> bool:
    """True for a weight the exact sums would drop (the kernel's ``weight_lost``, cl/tally.h):
    NaN, negative, or >= :data:`MAX_WEIGHT`."""
    return not (0.0 <= weight < MAX_WEIGHT)


def word_threshold(probability: float) -> int:
    """T = floor(P 2**32 + 1/2), exactly: the words x with x < T are the x whose uniform
    U = (x + 1/2) 2**-32 satisfies U <= P (docs/walk.md §2).

    The walk decides an event "U > P" (absorption in the medium, P = omega; absorption by the
    floor, P = A) as ``x >= T`` on the raw 32-bit Philox word, in every precision, so that
    its probability (2**32 - T) 2**-32 is within 2**-33 of 1 - P.

    Parameters
    ----------
    probability : float
        P (dimensionless); values outside [0, 1] are clipped.

    Returns
    -------
    int
        T in [0, 2**32]: 0 for P = 0 (the event always happens), 2**32 for P = 1 (never).
    """
    p = float(probability)
    if not p > 0.0:          # 0, negative or NaN: the event always happens
        return 0
    if p >= 1.0:
        return 2 ** 32
    return math.floor(Fraction(p) * 2 ** 32 + Fraction(1, 2))


@dataclass(frozen=True)
class Layer:
    """One layer of a stack (docs/walk.md §7), top first in :attr:`WalkParams.layers`.

    Parameters
    ----------
    texture : {"slab", "granular"}
        A slab has flat faces: Fresnel contacts with its neighbours of another index. A
        granular layer shows its pores (index 1) to its neighbours (docs/physics.md §11).
    thickness : float
        Physical thickness h_i, m (> 0).
    extinction : float
        Volume extinction coefficient E_i, 1/m (0: no extinction).
    omega : float
        Single-scattering albedo.
    g : float
        Henyey-Greenstein asymmetry parameter.
    n, k : float
        Effective index of the layer: n sets the speed of light in it (both textures) and,
        for a slab, with k its Fresnel contacts.
    """

    texture: str
    thickness: float
    extinction: float
    omega: float
    g: float
    n: float
    k: float = 0.0

    @property
    def omega_words(self) -> int:
        """Word threshold of the analog absorption in this layer (:func:`word_threshold`)."""
        return word_threshold(self.omega)

    @property
    def face(self) -> tuple:
        """The index (n, k) a neighbour sees at this layer's faces: its own for a slab, the
        pores' (1, 0) for a granular layer (docs/physics.md §11.2)."""
        return (float(self.n), float(self.k)) if self.texture == "slab" else (1.0, 0.0)


@dataclass(frozen=True)
class WalkParams:
    """Everything one scenario's random walk depends on (docs/walk.md §1).

    Parameters
    ----------
    texture : {"slab", "granular"}
    bottom_interface : {"fresnel", "none"}
        Slab only; granular media always behave as ``"none"``.
    thickness : float
        Layer thickness h, m.
    extinction : float
        Volume extinction coefficient E = tau0 / h, m^-1 (0: no extinction).
    omega : float
        Single-scattering albedo of the medium.
    g : float
        Henyey-Greenstein asymmetry parameter.
    n, k : float
        Effective refractive index (real, imaginary).
    albedo : float
        Lambertian albedo A of the floor.
    max_time : float
        Rays still inside after this time are terminated, ns.
    max_flights : int
        Safety cap on free flights per ray.
    time_edges : numpy.ndarray
        Increasing time-bin edges, ns.
    fov : tuple of 4 floats
        Field of view per component (specular, bf_direct, bf_diffuse, scattering), degrees;
        90 or more means any angle.
    rule : {"history", "time_window"}
        How diffuse exits are split between ``bf_diffuse`` and ``scattering``.
    seed : int
        Philox key word (uint32).
    scenario : int
        The scenario's 64-bit key (:func:`warpe_cl.api.scenario_key`): its low word is the
        second Philox key word, its high word the fourth counter word (docs/walk.md §2).
    mode : {"analog", "weighted"}
        Analog walk, or survival weighting with Russian roulette (docs/walk.md §6).
    roulette_weight, roulette_survival : float
        Weighted mode: below ``roulette_weight`` a ray survives a scattering or a floor
        reflection with probability ``roulette_survival`` (its weight divided by it).
    layers : tuple of Layer
        A stack, top first (``texture="layers"``; docs/walk.md §7); empty for one layer,
        which the other fields describe. :func:`stack_params` builds layered parameters.
    substrate : tuple of 2 floats or None
        (n, k) of a substrate below the stack, whose Fresnel contact replaces the vacuum gap
        above the floor (``texture="layers"`` only); None: the floor as for one layer.
    nadir : bool
        Also tally the next-event estimate of the reflectance toward the view direction
        (docs/walk.md §8): the ``nadir`` build of the kernel. The rays are the same bits
        with or without it.
    view_zenith : float
        The receiver's zenith angle in vacuum, degrees in [0, 90) (0: nadir), for the
        estimator; the incident beam is always vertical.
    nadir_roulette : float
        Analog walk: nadir scores below this fraction of the score of a scattering at the
        top straight back up (:func:`warpe_cl.nadir.nadir_min_score`) play an unbiased roulette
        (docs/walk.md §8.3), those that would open a new pending cell against
        :func:`warpe_cl.nadir.nadir_new_cell_score`; 0: every score counts.
    """

    texture: str
    thickness: float
    extinction: float
    omega: float
    g: float
    n: float
    k: float
    albedo: float
    time_edges: np.ndarray
    bottom_interface: str = "fresnel"
    max_time: float | None = None
    max_flights: int = 1_000_000
    fov: tuple = (90.0, 90.0, 3.0, 12.0)
    rule: str = "history"
    seed: int = 1
    scenario: int = 0
    mode: str = "analog"
    roulette_weight: float = 1e-4
    roulette_survival: float = 0.1
    layers: tuple = ()
    substrate: tuple | None = None
    nadir: bool = False
    view_zenith: float = 0.0
    nadir_roulette: float = 0.0

    @property
    def layered(self) -> bool:
        """The walk of a stack (the ``layers`` kernel build, docs/walk.md §7)."""
        return self.texture == "layers"

    @property
    def stack(self) -> tuple:
        """The layers, top first: :attr:`layers`, or the one layer the fields describe."""
        if self.layers:
            return tuple(self.layers)
        return (Layer(self.texture, self.thickness, self.extinction, self.omega, self.g,
                      self.n, self.k),)

    @property
    def echo_times(self) -> np.ndarray:
        """Direct-echo delays 2 sum_{i<=j} h_i n_i / c of the bottom of each layer j, ns
        (docs/physics.md §11.4): where the back-and-forth echoes of the interfaces and
        of the floor arrive at nadir."""
        legs = [2.0 * layer.thickness * layer.n / C_M_PER_NS for layer in self.stack]
        return np.cumsum(legs)

    @property
    def weighted(self) -> bool:
        return self.mode == "weighted"

    @property
    def omega_words(self) -> int:
        """Word threshold of the analog absorption in the medium: absorbed iff x1 >= it
        (:func:`word_threshold` of omega; docs/walk.md §3)."""
        return word_threshold(self.omega)

    @property
    def albedo_words(self) -> int:
        """Word threshold of the analog absorption by the floor: absorbed iff x >= it
        (:func:`word_threshold` of A; docs/walk.md §3.1)."""
        return word_threshold(self.albedo)

    @property
    def flight_extinction(self) -> float:
        """Coefficient that draws the free flights, 1/m: E (analog) or omega E (weighted,
        where absorption (1 - omega) E is applied as a weight along the path, walk.md §6)."""
        return self.omega * self.extinction if self.weighted else self.extinction

    @property
    def absorption(self) -> float:
        """Absorption coefficient applied as exp(-a L) in the weighted mode, 1/m (0 in analog)."""
        return (1.0 - self.omega) * self.extinction if self.weighted else 0.0

    @property
    def path_cap(self) -> float:
        """Path-length cap L_max = max_time * c / n, m."""
        t = self.max_time if self.max_time is not None else float(self.time_edges[-1])
        return t * C_M_PER_NS / self.n

    @property
    def first_bf_time(self) -> float:
        """First back-and-forth time t1 = 2 h n / c, ns (docs/physics.md §5.7); for a stack,
        the floor's echo 2 sum h_i n_i / c (docs/walk.md §7)."""
        if self.layered:
            return float(self.echo_times[-1])
        return 2.0 * self.thickness * self.n / C_M_PER_NS

    @property
    def cos_fov(self) -> np.ndarray:
        """cos of each component's field of view; -1 for 'any angle' (fov >= 90 deg)."""
        f = np.asarray(self.fov, dtype=float)
        return np.where(f >= 90.0, -1.0, np.cos(np.radians(f)))


def stack_params(layers, substrate=None, **common) -> WalkParams:
    """The :class:`WalkParams` of a stack of :class:`Layer` (top first) over the floor, or
    over a substrate (n, k) above it (docs/walk.md §7).

    The single-layer fields take layer 0's values: ``n`` is the index whose speed the path L
    counts in (L_max = max_time c / n_0), and ``thickness`` the stack's total.

    Parameters
    ----------
    layers : sequence of Layer
        One to :data:`MAX_LAYERS` layers of thickness > 0 (a zero-thickness layer is no
        layer: leave it out, as the configuration does).
    substrate : tuple of 2 floats or None
        (n, k) of the substrate, or None.
    **common
        The other fields of :class:`WalkParams` (albedo, time_edges, seed, ...).
    """
    layers = tuple(layers)
    if not 1 <= len(layers) <= MAX_LAYERS:
        raise ValueError(f"a stack holds 1 to {MAX_LAYERS} layers, got {len(layers)}")
    top = layers[0]
    return WalkParams(texture="layers", thickness=float(sum(x.thickness for x in layers)),
                      extinction=top.extinction, omega=top.omega, g=top.g, n=top.n, k=top.k,
                      layers=layers, substrate=None if substrate is None else
                      (float(substrate[0]), float(substrate[1])), **common)


def batch_photons(first_photon: int, photons: int) -> np.ndarray:
    """Photons of the range first_photon .. first_photon + photons - 1 in each batch
    (photon p in batch p mod :data:`NADIR_BATCHES`), shape (NADIR_BATCHES,)."""
    b = np.arange(NADIR_BATCHES)
    first = (b - first_photon) % NADIR_BATCHES      # offset of batch b's first photon
    return np.maximum(0, (photons - first + NADIR_BATCHES - 1) // NADIR_BATCHES).astype(np.int64)


def _zeros(*shape):
    return np.zeros(shape, dtype=np.int64)


def _exact_zeros(*shape):
    """Python-int zeros: exact, unbounded sums of fixed-point weights."""
    out = np.empty(shape, dtype=object)
    out.fill(0)
    return out


def fixed_point(weight: float) -> int:
    """floor(weight * 2**FIXED_SHIFT), the integer a weighted tally adds (weight >= 0)."""
    return int(math.ldexp(weight, FIXED_SHIFT)) if weight > 0 else 0


def fixed_to_float(values) -> np.ndarray:
    """Weighted tallies (Python ints, units of 2**-FIXED_SHIFT) as float64 (correctly rounded).

    ``float`` of each int (correctly rounded, in NumPy's C loop over the objects: 20 times
    faster than a Python loop on the 13 000 nadir sums of a run), times 2**-FIXED_SHIFT, which
    is exact for every int >= 1 (the products stay normal). An int of 2**1024 or more, which
    no walk reaches, is shifted first."""
    arr = np.asarray(values, dtype=object)
    try:
        return arr.astype(np.float64) * 2.0 ** -FIXED_SHIFT
    except OverflowError:
        flat = [float(v) * 2.0 ** -FIXED_SHIFT if v < 2 ** 1000 else
                float(v >> FIXED_SHIFT) for v in arr.ravel()]
        return np.asarray(flat, dtype=np.float64).reshape(arr.shape)


@dataclass
class Counts:
    """Integer tallies of a walk (docs/walk.md §4). All counts are int64.

    Attributes
    ----------
    photons : int
        Rays launched.
    time_in_fov, time_any : numpy.ndarray, shape (4, n_time)
        Exits per component and time bin, inside the component's FOV / at any angle.
    angular : numpy.ndarray, shape (4, 90)
        Exits per component and 1-degree emergence bin, any time.
    total : numpy.ndarray, shape (4,)
        Exits per component, any angle, any time.
    early : numpy.ndarray, shape (4,)
        Exits per component before the first time edge (t < time_edges[0]): counted in
        ``total`` and ``angular``, never in a time bin (docs/walk.md §4).
    fates : numpy.ndarray, shape (5,)
        Rays per fate, in the order of :data:`FATES`; sums to ``photons``.
    scattering_events : int
        Volume scatterings over all rays.
    mixed_history : int
        Exits with both a volume scattering and a floor reflection in their history.
    layer_stats : numpy.ndarray, shape (len(LAYER_STATS),)
        The layered walk's per-layer statistics (:data:`LAYER_STATS`, docs/walk.md §7.4):
        rays absorbed and terminated per layer, transmissions down and up per interface;
        zeros for one layer. :meth:`layer_view` names them.
    records : dict of numpy.ndarray or None
        Per-photon records (fate, component, time_ns, cos_exit, weight, n_scat, n_lamb,
        n_bspec, n_top, time_bin, emergence_bin) when asked for; component is -1 for rays that
        did not exit.
    nadir_sum : numpy.ndarray or None, shape (NADIR_BATCHES, len(NADIR_ROWS), n_time + 2)
        The next-event estimator's exact sums (docs/walk.md §8): per photon batch, row of
        :data:`NADIR_ROWS` and column (before the first edge, the time bins, after the last
        edge), the sum of floor(score 2^150) (Python ints; :func:`fixed_to_float`); None
        without the estimator.
    nadir_visits : numpy.ndarray or None, shape (len(NADIR_ROWS), n_time + 2)
        Ray visits that scored in each cell (a ray's consecutive scores in one cell are one
        visit).
    nadir_batch_photons : numpy.ndarray, shape (NADIR_BATCHES,)
        Photons walked in each batch (photon p in batch p mod NADIR_BATCHES).
    weighted : bool
        Weighted walk (docs/walk.md §6): the ``w_*`` and ``w2_*`` tallies hold exact sums of
        floor(w 2^150) and floor(w^2 2^150) (Python ints, object arrays) over the same cells as
        ``time_in_fov``, ``time_any``, ``angular``, ``total`` and ``early``; use
        :func:`fixed_to_float`.
    """

    n_time: int
    photons: int = 0
    time_in_fov: np.ndarray = None
    time_any: np.ndarray = None
    angular: np.ndarray = None
    total: np.ndarray = None
    early: np.ndarray = None
    fates: np.ndarray = None
    scattering_events: int = 0
    mixed_history: int = 0
    layer_stats: np.ndarray = field(default=None, repr=False)
    records: dict | None = field(default=None, repr=False)
    weighted: bool = False
    w_time_in_fov: np.ndarray = field(default=None, repr=False)
    w_time_any: np.ndarray = field(default=None, repr=False)
    w_angular: np.ndarray = field(default=None, repr=False)
    w_total: np.ndarray = field(default=None, repr=False)
    w2_time_in_fov: np.ndarray = field(default=None, repr=False)
    w2_total: np.ndarray = field(default=None, repr=False)
    w_early: np.ndarray = field(default=None, repr=False)
    nadir: bool = False
    nadir_sum: np.ndarray = field(default=None, repr=False)
    nadir_visits: np.ndarray = field(default=None, repr=False)
    nadir_batch_photons: np.ndarray = field(default=None, repr=False)

    def __post_init__(self):
        if self.layer_stats is None:
            self.layer_stats = _zeros(len(LAYER_STATS))
        if self.nadir:
            cols = self.n_time + 2
            if self.nadir_sum is None:
                self.nadir_sum = _exact_zeros(NADIR_BATCHES, len(NADIR_ROWS), cols)
            if self.nadir_visits is None:
                self.nadir_visits = _zeros(len(NADIR_ROWS), cols)
            if self.nadir_batch_photons is None:
                self.nadir_batch_photons = _zeros(NADIR_BATCHES)
        for name, shape in tally_shapes(self.n_time).items():
            if name in WEIGHT_TALLIES:
                if self.weighted and getattr(self, name) is None:
                    setattr(self, name, _exact_zeros(*shape))
            elif getattr(self, name) is None:
                setattr(self, name, _zeros(*shape))

    def __iadd__(self, other: "Counts") -> "Counts":
        """Add another batch's counts (records are concatenated)."""
        self.photons += other.photons
        for name in COUNT_TALLIES:
            getattr(self, name)[...] += getattr(other, name)
        self.scattering_events += other.scattering_events
        self.mixed_history += other.mixed_history
        self.layer_stats += other.layer_stats
        if self.weighted != other.weighted:
            raise ValueError("cannot add weighted and analog counts")
        if self.weighted:
            for name in WEIGHT_TALLIES:
                setattr(self, name, getattr(self, name) + getattr(other, name))
        if self.nadir != other.nadir:
            raise ValueError("cannot add counts with and without the nadir estimator")
        if self.nadir:
            self.nadir_sum = self.nadir_sum + other.nadir_sum
            self.nadir_visits += other.nadir_visits
            self.nadir_batch_photons += other.nadir_batch_photons
        if other.records is not None:
            if self.records is None:
                self.records = {k: v.copy() for k, v in other.records.items()}
            else:
                self.records = {k: np.concatenate([self.records[k], other.records[k]])
                                for k in self.records}
        return self

    def add_walk(self, other: "Counts") -> "Counts":
        """Add a launch's counts, which hold no nadir sums (the engine reads those once per
        walk), to a walk's."""
        nadir = self.nadir
        self.nadir = False
        try:
            self += other
        finally:
            self.nadir = nadir
        return self

    def layer_view(self, n_layers: int) -> dict:
        """The per-layer statistics of a stack of ``n_layers``: ``absorbed`` and
        ``terminated`` (n_layers,), ``down`` and ``up`` (n_layers + 1,) transmissions per
        interface (0: the top of the stack, n_layers: the contact with the gap below)."""
        st = np.asarray(self.layer_stats, dtype=np.int64)
        m = MAX_LAYERS
        return {"absorbed": st[:n_layers], "terminated": st[m:m + n_layers],
                "down": st[2 * m:2 * m + n_layers + 1],
                "up": st[3 * m + 1:3 * m + 2 + n_layers]}

    def same_as(self, other: "Counts") -> bool:
        """True when every tally (not the records) is identical."""
        return (self.photons == other.photons
                and all(np.array_equal(getattr(self, n), getattr(other, n))
                        for n in COUNT_TALLIES)
                and self.scattering_events == other.scattering_events
                and self.mixed_history == other.mixed_history
                and np.array_equal(self.layer_stats, other.layer_stats)
                and self.weighted == other.weighted
                and (not self.weighted
                     or all(np.array_equal(getattr(self, n), getattr(other, n))
                            for n in WEIGHT_TALLIES))
                and self.nadir == other.nadir
                and (not self.nadir
                     or all(np.array_equal(getattr(self, n), getattr(other, n))
                            for n in ("nadir_sum", "nadir_visits", "nadir_batch_photons"))))
