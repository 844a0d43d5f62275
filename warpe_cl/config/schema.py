"""The preset schema: :class:`Field` and the table :data:`SCHEMA`, one row per key.

Every key a preset may hold is one row of :data:`SCHEMA`; that table is the single source of
the key names, kinds, units, defaults, limits and help texts. It drives validation
(:mod:`warpe_cl.config.check`), the defaults, the resolved YAML written by
:meth:`~warpe_cl.config.Config.to_yaml` and the reference table docs/config.md
(:mod:`warpe_cl.config.docs`). The instrument presets have a table of the same rows
(:mod:`warpe_cl.config.instrument_fields`), checked by the same functions
(:mod:`warpe_cl.config.validate`).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

from ..params import MAX_LAYERS
from ..units import parse_quantity
from .tables import MAX_K, MAX_N

__all__ = ["Field", "SCHEMA", "FIELDS", "DEFAULTS", "SWEEPABLE", "QUANTITY_KINDS",
           "SCALAR_KINDS", "MAX_PHOTONS", "MAX_TIME_BINS", "MAX_N", "MAX_K",
           "MIN_ROULETTE_SURVIVAL", "MAX_FLIGHTS", "children"]


@dataclass(frozen=True)
class Field:
    """One row of the preset schema.

    Attributes
    ----------
    key : str
        Dotted key. ``[]`` marks the items of a list (``medium.inclusions[].grain_size``) and
        ``*`` any name chosen by the user (``materials.*.n``).
    kind : str
        ``"length"``, ``"time"``, ``"angle"`` (strings with a unit, stored in m, ns, deg),
        ``"float"``, ``"int"``, ``"str"``, ``"choice"``, ``"bool"``; or a structured kind:
        ``"section"`` (a mapping of the keys listed under it), ``"open_section"`` (the same,
        other keys passed through unchecked), ``"list"`` (a list of sections),
        ``"names"`` (a mapping from user-chosen names to sections), ``"time_bins"``,
        ``"sweep"``.
    default : object
        The value used when the key is absent, as a user would write it (``"12 deg"``).
        For sections: ``{}`` means filled with defaults when absent, None means absent.
    required : bool
        The key must be given (inside its section, when that section is given).
        (``medium.texture`` and ``medium.thickness``: unless ``medium.layers`` is given.)
    low, high : float or None
        Limits in the canonical unit; ``low_open`` / ``high_open`` exclude them.
    choices : tuple of str or None
        The allowed values of a ``"choice"``.
    help : str
        User-facing description (shown by :func:`schema_markdown`).
    unit : str or None
        What a plain number counts (``"rays"``), named in messages and in the reference
        table; None for quantities (their unit is written with the value) and pure numbers.
    example : str or None
        A valid value shown in messages (``"500 km"``), when the default is none.
    default_doc : str or None
        The default column of the reference table, for a key whose default is not a fixed
        value (``instrument.altitude``: the instrument preset's own).

    Notes
    -----
    The kinds ``"length"``, ``"time"``, ``"angle"`` are those of a scenario preset; the
    instrument table (:mod:`warpe_cl.config.instrument_fields`) also uses the other dimensions of
    :mod:`warpe_cl.units` (``"energy"``, ``"frequency"`` ...) and writes its defaults in the
    canonical unit. A ``"float"`` or ``"int"`` with ``choices`` also takes those words
    (``speckle.modes``: a number or ``auto``).
    """

    key: str
    kind: str
    default: object = None
    required: bool = False
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple | None = None
    help: str = ""
    unit: str | None = None
    example: str | None = None
    default_doc: str | None = None


QUANTITY_KINDS = ("length", "time", "angle")
SCALAR_KINDS = QUANTITY_KINDS + ("float", "int", "str", "choice", "bool")
MAX_TIME_BINS = 1_000_000
#: MAX_N, MAX_K: the largest n and k a run may use (warpe_cl/config/tables.py gives their
#: derivation: what the walk's single-precision Fresnel terms hold without overflow)
#: Most rays a scenario may launch: 2^53, the largest count a YAML number (a float64) holds
#: exactly. The kernel's photon index (the Philox counter) is 64-bit and the host tallies are
#: int64 or exact integers, so every count up to here is walked and tallied exactly.
MAX_PHOTONS = 2 ** 53
#: Lowest ``simulation.roulette_survival``: a surviving weight stays below
#: roulette_weight / roulette_survival <= 1 / 1e-3 = 1e3 (see the help text).
MIN_ROULETTE_SURVIVAL = 1e-3
#: Largest ``simulation.max_flights``: the kernel holds the flight count in 31 bits.
MAX_FLIGHTS = 2 ** 31 - 1
_F = Field

SCHEMA: list[Field] = [
    _F("name", "str",
       help="Short identifier of the scenario, written into the output file. "
            "Default: the preset's file name without its extension."),
    _F("description", "str", "", help="Free text describing the scenario."),

    _F("medium", "section", required=True,
       help="The surface layer: texture, thickness, floor, and its composition given either "
            "physically (compacity, matrix, inclusions) or radiatively (radiative); or a "
            "stack of such layers (layers), optionally over a substrate."),
    _F("medium.texture", "choice", required=True, choices=("slab", "granular"),
       help="slab: a compact matrix (e.g. ice) holding inclusions, bounded by Fresnel "
            "interfaces; granular: grains with void pores between them, no interfaces. Not "
            "given with medium.layers (each layer has its own)."),
    _F("medium.thickness", "length", required=True, low=0.0, low_open=True,
       help="Physical thickness h of the layer above the floor. Not given with "
            "medium.layers (each layer has its own)."),
    _F("medium.bottom_albedo", "float", 0.15, low=0.0, high=1.0,
       help="Lambertian albedo A of the floor under the layer (0: a black floor; what "
            "reaches it leaves the layer)."),
    _F("medium.bottom_interface", "choice", "fresnel", choices=("fresnel", "none"),
       help="Slab only. fresnel: a slab / vacuum-gap interface above the floor "
            "(docs/physics.md §5.5); none: the floor is in optical contact with the slab. "
            "Accepted but ignored for a granular medium, which has no interfaces. With "
            "medium.layers: the floor under the last layer; none refuses a medium.substrate."),
    _F("medium.phase_g", "float", 0.8, low=-1.0, high=1.0, low_open=True, high_open=True,
       help="Henyey-Greenstein asymmetry parameter g of volume scattering (0: isotropic, "
            "close to 1: forward)."),
    _F("medium.extinction_efficiency", "float", 1.0, low=0.0, low_open=True,
       help="Physical form: extinction efficiency Q_e of the inclusions or grains "
            "(docs/physics.md A4: 1 in geometric optics, where Hapke's w is defined and the "
            "diffraction peak of packed or embedded particles is dropped; 2 counts it)."),
    _F("medium.matrix_absorption", "choice", "seed", choices=("seed", "volume_weighted"),
       help="Slab, physical form: the matrix absorption a_m = 4 pi k / lambda enters the "
            "extinction as in the paper (seed, the name of that rule), or weighted by the "
            "matrix volume fraction gamma_c (volume_weighted; docs/physics.md A5)."),
    _F("medium.inclusion_absorption", "choice", "absolute", choices=("absolute", "relative"),
       help="Physical form: the absorption inside an inclusion uses its own k (absolute, "
            "docs/physics.md A6) or its k relative to the matrix (relative)."),
    _F("medium.fresnel_integrals", "choice", "exact", choices=("exact", "hapke"),
       help="Physical form: S_e and S_i by quadrature of the exact Fresnel law (exact, "
            "docs/physics.md §3.6) or Hapke's approximations (hapke; invalid for n_rel < 1, "
            "refused there)."),
    _F("medium.radiative", "section",
       help="The medium in radiative terms, instead of compacity/matrix/inclusions: the "
            "same kernels run with these values."),
    _F("medium.radiative.tau0", "float", required=True, low=0.0,
       help="Total optical depth tau0 = E h of the layer (E: volume extinction, m^-1)."),
    _F("medium.radiative.omega", "float", required=True, low=0.0, high=1.0,
       help="Single-scattering albedo omega of the medium."),
    _F("medium.radiative.n", "float", required=True, low=1.0, high=MAX_N,
       help="Effective refractive index: sets the speed of light in the layer and, for a "
            "slab, its Fresnel interfaces."),
    _F("medium.radiative.k", "float", 0.0, low=0.0, high=MAX_K,
       help="Effective extinction index (imaginary part), used in the Fresnel reflectance "
            "of a slab seen from vacuum."),
    _F("medium.compacity", "float", low=0.0, high=1.0, low_open=True,
       help="Compacity gamma_c (filling factor), physical form only. Slab: volume fraction "
            "of the matrix; granular: volume fraction of the grains."),
    _F("medium.matrix", "str",
       help="Slab only, physical form: the matrix material (a built-in such as H2O or CO2, "
            "or a name defined under materials)."),
    _F("medium.inclusions", "list",
       help="Physical form: at least one species. Slab: the impurities in the matrix; "
            "granular: the grains (the pores are void)."),
    _F("medium.inclusions[].material", "str", required=True,
       help="Material of the inclusion or grain (built-in or defined under materials)."),
    _F("medium.inclusions[].proportion", "float", required=True, low=0.0, low_open=True,
       help="Relative volumetric proportion rho_v of this species among the inclusions."),
    _F("medium.inclusions[].grain_size", "length", required=True, low=0.0, low_open=True,
       help="Diameter d of the inclusions or grains of this species."),
    _F("medium.layers", "list",
       help=f"Optional stack of layers, top first (1 to {MAX_LAYERS}; docs/walk.md §7): each "
            "entry is a medium of the single-layer kind, with its own texture, thickness and "
            "composition (physical or radiative form) and optionally its own phase_g. With "
            "layers, medium.texture, medium.thickness and the composition keys are not given "
            "at the medium level; medium.bottom_albedo, medium.bottom_interface, "
            "medium.phase_g and the physical-form options (extinction_efficiency, "
            "matrix_absorption, inclusion_absorption, fresnel_integrals) apply to every "
            "layer. Only the analog walk is layered (simulation.mode: weighted is refused). "
            "A layer is addressed as medium.layers[0].thickness in a sweep or --set."),
    _F("medium.layers[].texture", "choice", required=True, choices=("slab", "granular"),
       help="Texture of this layer, as medium.texture: a slab shows its own index to its "
            "neighbours (Fresnel contacts), a granular layer its void pores."),
    _F("medium.layers[].thickness", "length", required=True, low=0.0,
       help="Physical thickness h_i of this layer. 0 is allowed: such a layer is no layer "
            "(it is left out of the walk; handy in a sweep), but at least one layer needs a "
            "thickness > 0."),
    _F("medium.layers[].phase_g", "float", low=-1.0, high=1.0, low_open=True,
       high_open=True, default_doc="medium.phase_g",
       help="Henyey-Greenstein asymmetry parameter g of volume scattering in this layer."),
    _F("medium.layers[].radiative", "section",
       help="This layer in radiative terms, instead of compacity/matrix/inclusions, as "
            "medium.radiative."),
    _F("medium.layers[].radiative.tau0", "float", required=True, low=0.0,
       help="Optical depth tau0 = E_i h_i of this layer."),
    _F("medium.layers[].radiative.omega", "float", required=True, low=0.0, high=1.0,
       help="Single-scattering albedo omega of this layer."),
    _F("medium.layers[].radiative.n", "float", required=True, low=1.0, high=MAX_N,
       help="Effective refractive index of this layer."),
    _F("medium.layers[].radiative.k", "float", 0.0, low=0.0, high=MAX_K,
       help="Effective extinction index of this layer (imaginary part)."),
    _F("medium.layers[].compacity", "float", low=0.0, high=1.0, low_open=True,
       help="Physical form: compacity gamma_c of this layer, as medium.compacity."),
    _F("medium.layers[].matrix", "str",
       help="Slab layer only, physical form: the matrix material of this layer."),
    _F("medium.layers[].inclusions", "list",
       help="Physical form: the species of this layer, as medium.inclusions."),
    _F("medium.layers[].inclusions[].material", "str", required=True,
       help="Material of the inclusion or grain (built-in or defined under materials)."),
    _F("medium.layers[].inclusions[].proportion", "float", required=True, low=0.0,
       low_open=True,
       help="Relative volumetric proportion rho_v of this species in this layer."),
    _F("medium.layers[].inclusions[].grain_size", "length", required=True, low=0.0,
       low_open=True,
       help="Diameter d of the inclusions or grains of this species."),
    _F("medium.substrate", "section",
       help="Optional substrate below the layer (or the last of medium.layers), above the "
            "Lambertian floor: {material: NAME} or {n: N, k: K}, not both. Its Fresnel "
            "contact with the layer above replaces the vacuum gap (docs/walk.md §7.1); not "
            "allowed with medium.bottom_interface: none, nor with simulation.mode: weighted."),
    _F("medium.substrate.material", "str",
       help="The substrate's material: a built-in or a name defined under materials."),
    _F("medium.substrate.n", "float", low=0.0, low_open=True, high=MAX_N,
       help="Real refractive index of the substrate (instead of material)."),
    _F("medium.substrate.k", "float", low=0.0, high=MAX_K, default_doc="`0` (with n)",
       help="Imaginary refractive index of the substrate (with n)."),

    _F("wavelength", "length", "1064 nm", low=0.0, low_open=True,
       help="Laser wavelength; selects the optical constants of the materials. The "
            "built-ins (void, H2O, CO2, S, tholin, regolith; docs/materials.md) exist at 532 nm "
            "and 1064 nm only: at another wavelength give each material but void under "
            "materials (n, k or a table)."),

    _F("materials", "names", {},
       help="Optional optical constants at the run's wavelength, added to or overriding "
            "the built-ins (names are case-insensitive): {n, k} or {table: FILE}."),
    _F("materials.*.n", "float", low=0.0, low_open=True, high=MAX_N,
       help="Real refractive index of the material."),
    _F("materials.*.k", "float", 0.0, low=0.0, high=MAX_K,
       help="Imaginary refractive index (extinction index) of the material."),
    _F("materials.*.table", "str",
       help="CSV file with columns wavelength_nm, n, k, interpolated at the wavelength; "
            "a relative path is read from the preset's folder. Not combined with n, k."),

    _F("simulation", "section", {}, help="How the Monte Carlo walk is run and tallied."),
    _F("simulation.photons", "int", 1_000_000, low=1, high=MAX_PHOTONS, unit="rays",
       help="Number of rays launched per scenario (1e6 and 1.0e6 are accepted). At most "
            "2^53 = 9.007e15: the largest count a YAML number (a 64-bit float) holds "
            "exactly; the photon index in the Philox counter is 64-bit and the host "
            "tallies are 64-bit or exact, so every ray up to it is walked and counted. The "
            "bound is one of representation, not of patience: at 1e8 rays/s (a few CPU "
            "cores) 2^53 rays take about 3 years, at 1e10 rays/s (a large GPU) about 10 "
            "days (1e9 rays: about 10 s at 1e8 rays/s). Ctrl-C stops a run (exit 130) "
            "without leaving a partial file."),
    _F("simulation.seed", "int", 1, low=0, high=2**32 - 1,
       help="Random seed: with the 64-bit scenario key (a hash of the resolved medium, "
            "materials, wavelength and simulation blocks, seed and photons left out), the key "
            "of the counter-based Philox generator. The same seed gives the same rays on any "
            "device."),
    _F("simulation.time_bins", "time_bins", {},
       help="Time-bin edges: log-spaced {start, stop, per_decade} or linear "
            "{start, stop, width}; never both per_decade and width."),
    _F("simulation.time_bins.start", "time", "1e-6 ns", low=0.0,
       help="First edge. Log-spaced: > 0, default 1e-6 ns; linear: >= 0, default 0 ns. "
            "Rays leaving earlier (the specular, at t = 0) are in no bin: they are counted "
            "apart, in the output's early_fraction (docs/interface.md §5.1)."),
    _F("simulation.time_bins.stop", "time", "1e5 ns", low=0.0, low_open=True,
       help="Last time to cover (> start); the last edge is the first one at or after it. "
            "Required for linear bins."),
    _F("simulation.time_bins.per_decade", "int", 20, low=1,
       help="Log-spaced bins: number of bins per factor of ten in time."),
    _F("simulation.time_bins.width", "time", low=0.0, low_open=True,
       help="Linear bins: width of every bin."),
    _F("simulation.max_time", "time", low=0.0, low_open=True,
       help="Rays still inside the medium after this time are stopped and counted as "
            "terminated. Default: the last time-bin edge."),
    _F("simulation.max_flights", "int", 10_000_000, low=1, high=MAX_FLIGHTS,
       unit="flights",
       help="Safety cap on free flights per ray; a ray reaching it is counted as "
            "terminated. At most 2^31 - 1, the largest cap the walk kernel takes (a larger "
            "value used to be cut to it without a word)."),
    _F("simulation.fov", "section", {},
       help="Numerical fields of view of the diffuse components (docs/physics.md §6.2): half "
            "angles from the zenith, in vacuum."),
    _F("simulation.fov.scattering", "angle", "12 deg", low=0.0, high=90.0, low_open=True,
       help="Field of view of the background (volume scattering) component."),
    _F("simulation.fov.bf_diffuse", "angle", "3 deg", low=0.0, high=90.0, low_open=True,
       help="Field of view of the BF diffuse (floor-reflected) component."),
    _F("simulation.nadir", "bool", True,
       help="Also estimate the reflectance in the exact view direction with a next-event "
            "estimator (docs/walk.md §8): the outputs nadir_reflectance and nadir_brdf next "
            "to the FOV reflectance, which the instrument chain then uses. The rays are the "
            "same with or without it."),
    _F("simulation.view_zenith", "angle", "0 deg", low=0.0, high=89.0,
       help="Zenith angle of the receiver for the nadir estimate, in vacuum (0: nadir; the "
            "laser beam is always vertical)."),
    _F("simulation.nadir_roulette", "float", 0.1, low=0.0, high=1.0,
       help="Analog walk: nadir scores below this fraction of the score of a scattering at "
            "the top straight back up play an unbiased roulette (docs/walk.md §8.3), which "
            "trades a little variance of deep events for speed; a score that would open a new "
            "time cell of its ray plays against a higher threshold where the phase function "
            "is forward (g > 0), at most that score itself; 0: every score counts."),
    _F("simulation.min_rays", "int", 3, low=0,
       help="Time bins holding fewer rays than this are flagged as under-sampled "
            "(the specular is exempt)."),
    _F("simulation.solid_angle", "choice", "cone", choices=("cone", "projected"),
       help="Solid angle that normalises a field of view theta: cone, 2 pi (1 - cos theta); "
            "or projected, pi sin^2 theta (a Lambertian floor then reads exactly A/pi)."),
    _F("simulation.component_rule", "choice", "history", choices=("history", "time_window"),
       help="How diffuse exits are split into bf_diffuse and scattering: history (a floor "
            "reflection makes bf_diffuse, docs/physics.md §6.1) or time_window (diffuse exits at "
            "or after the first back-and-forth time t1 = 2 h n / c are bf_diffuse)."),
    _F("simulation.precision", "choice", "single", choices=("single", "double"),
       help="Floating-point precision of the walk kernels: single (float32) or double "
            "(float64, on devices that support it)."),
    _F("simulation.specular_lobe", "angle", "0.25 deg", low=0.0, high=90.0,
       low_open=True, high_open=True,
       help="Half-angle of the roughness lobe that scales the specular and BF-direct "
            "reflectances (docs/physics.md §7.3)."),
    _F("simulation.mode", "choice", "analog", choices=("analog", "weighted"),
       help="Monte Carlo scheme: analog (every ray carries weight 1 and is absorbed or not; "
            "the paper's scheme, with its 3-ray threshold) or weighted (survival weighting: "
            "absorption applied as exp(-(1 - omega) E L) along the path and A at the floor, "
            "Russian roulette below simulation.roulette_weight; reaches deep tails, "
            "docs/walk.md §6)."),
    _F("simulation.roulette_weight", "float", 1e-4, low=0.0, high=1.0,
       help="Weighted mode: a ray whose weight falls below this at a scattering or a floor "
            "reflection plays Russian roulette (0: never). At most 1, the weight a ray starts "
            "with, so that with roulette_survival >= 1e-3 no weight ever exceeds "
            "roulette_weight / roulette_survival <= 1e3 (see roulette_survival)."),
    _F("simulation.roulette_survival", "float", 0.1, low=MIN_ROULETTE_SURVIVAL, high=1.0,
       help="Weighted mode: probability that a ray survives the roulette (its weight is then "
            "divided by it). At least 1e-3, so that weights stay bounded: a ray's weight "
            "starts at 1, only shrinks along its path, and grows only at a roulette it "
            "survives, from below roulette_weight to below roulette_weight / "
            "roulette_survival <= 1e3. The exact weighted tallies (cl/tally.h fixed_add) "
            "hold each weight (and its square, <= 1e6) only below 2^42 = 4.4e12 and drop "
            "larger ones; a launch of at most 2^31 rays then sums an expected weight "
            "squared of at most 2^31 x 1e3 = 2.1e12 per cell, below the same 2^42. A lower "
            "survival would only add variance: the roulette is unbiased at any value."),

    _F("sweep", "sweep", {},
       help="Optional grid: dotted keys mapped to lists of values, e.g. medium.thickness: "
            "[\"1 mm\", \"10 mm\"]. Several keys form the outer product, in the order "
            "given; a list item is addressed as medium.inclusions[0].grain_size (a layer's "
            "as medium.layers[0].thickness)."),

    _F("instrument", "open_section", {},
       help="Optional instrument applied after the surface simulation of each scenario, "
            "into the same result (by warpe-cl run, warpe-cl sweep and warpe_cl.simulate "
            "alike; docs/instrument.md). Keys other than those below are instrument keys as "
            "written in an instrument preset (shots, seed, sections such as electronics: "
            "{transimpedance: \"20 kohm\"}), checked against that table when the preset is "
            "loaded."),
    _F("instrument.name", "str",
       help="Instrument model: bela, gala, atlas, or an instrument YAML file. Absent: no "
            "instrument is applied, and no other instrument key may be given."),
    _F("instrument.altitude", "length", low=0.0, low_open=True, example="500 km",
       default_doc="the instrument preset's geometry.altitude (BELA 500 km, GALA 500 km, "
                   "ATLAS 496 km)",
       help="Spacecraft altitude above the surface; given, it replaces the instrument "
            "preset's geometry.altitude. It enters only the instrument chain: slant range, "
            "footprint width, the aperture's solid angle, hence the photons at the aperture "
            "and their timing. The surface simulation does not depend on it: its "
            "reflectances are per steradian (ns^-1 sr^-1), where the altitude cancels "
            "(docs/instrument.md)."),
    _F("instrument.roughness", "angle", low=0.0, high=30.0, example="0.1 deg",
       default_doc="the instrument preset's geometry.roughness (0.1 deg for BELA, GALA, "
                   "ATLAS)",
       help="Facet roughness (tilt angle) of the surface; given, it replaces the instrument "
            "preset's geometry.roughness. It sets the specular lobe of the instrument chain "
            "(lobe half-angle = geometry.lobe_factor x roughness), not the surface "
            "simulation's simulation.specular_lobe."),
]
del _F

FIELDS: dict[str, Field] = {f.key: f for f in SCHEMA}

#: The keys of the physical form of a medium.
PHYSICAL_KEYS = ("compacity", "matrix", "inclusions")
#: The keys of one layer's own description: with ``medium.layers`` they are given per layer
#: and must not be given at the medium level.
LAYER_KEYS = ("texture", "thickness", "radiative") + PHYSICAL_KEYS
#: The keys of a medium that exist only when given (a single-layer medium without them
#: resolves to the same data, hence the same scenario key, as before they existed).
STACK_KEYS = ("layers", "substrate")


def children(prefix: str) -> list[Field]:
    """The rows directly under ``prefix`` (``""`` for the top level), in table order."""
    out = []
    for f in SCHEMA:
        if prefix == "":
            if "." not in f.key and "[" not in f.key:
                out.append(f)
        elif f.key.startswith(prefix + ".") and "." not in f.key[len(prefix) + 1:]:
            out.append(f)
    return out


def canonical(field: Field, value):
    """A table default converted to the canonical unit."""
    if value is None or field.kind not in QUANTITY_KINDS:
        return copy.deepcopy(value)
    return parse_quantity(value, field.kind)


#: Defaults of the scalar keys in the canonical unit (None: no default).
DEFAULTS = {f.key: canonical(f, f.default) for f in SCHEMA if f.kind in SCALAR_KINDS}

#: Keys a sweep may name: every scalar, whole inclusion lists, and whole media (a list of
#: medium blocks: cases that differ in more than one key, such as the paper's BELA figure).
#: Instrument keys may be swept too (each scenario then has its own instrument).
SWEEPABLE = tuple(f.key for f in SCHEMA
                  if (f.kind in SCALAR_KINDS or f.kind == "list")
                  and not f.key.startswith(("materials", "sweep"))) + ("medium",)

