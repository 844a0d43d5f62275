"""A validated preset: :class:`Config` and :func:`load_preset`."""
from __future__ import annotations

import copy
import os

import yaml

from ..catalog import resolve_preset
from ..errors import ConfigError
from ..units import format_quantity
from .check import NEEDS, PresetValidator
from .instrument_fields import scenario_instrument
from .keys import (apply_overrides, expand_points, get_path, parse_overrides, schema_key,
                   set_path, split_key)
from .schema import DEFAULTS, FIELDS, QUANTITY_KINDS, SWEEPABLE
from .validate import did_you_mean, read_yaml

__all__ = ["Config", "load_preset", "read_source"]


class Config:
    """A validated preset.

    Build one with :func:`load_preset`. The constructor validates ``raw`` and raises
    :class:`~warpe_cl.errors.ConfigError` on the first problem.

    Attributes
    ----------
    source : str
        The preset's path as given, or ``"<dict>"``.
    raw : dict
        The nested mapping as written, overrides applied (a private copy).
    data : dict
        The same with every default filled in and every quantity converted to the
        canonical unit: lengths in m, times in ns, angles in degrees. Absent optional
        parts (``medium.radiative`` in the physical form, ``instrument.name``) are None;
        ``medium.layers`` and ``medium.substrate`` are there only when given (with layers,
        the medium's own texture, thickness and composition are None).
    instrument : InstrumentParams or None
        The instrument of the ``instrument:`` block, validated and resolved when the preset
        is loaded (:func:`~warpe_cl.config.instrument_fields.scenario_instrument`); None
        without ``instrument.name``.
    """

    def __init__(self, raw: dict, source: str = "<dict>", *, name_default: str = "unnamed",
                 base_dir: str | None = None):
        self.source = source
        self.raw = raw
        self._name_default = name_default
        self._base_dir = base_dir
        try:
            self.data = PresetValidator(name_default, base_dir).preset(self._with_swept_defaults())
            # resolved once, against the instrument's own table: a bad block fails when the
            # preset is loaded (exit 2), before any walk
            self.instrument = scenario_instrument(self)
        except ConfigError as exc:
            raise exc.with_source(source) from None

    def _with_swept_defaults(self):
        """``raw``, where a key missing from the base but swept takes its first value."""
        sweep = self.raw.get("sweep") if isinstance(self.raw, dict) else None
        if not isinstance(sweep, dict) or not sweep:
            return self.raw
        work = copy.deepcopy(self.raw)
        for key, values in sweep.items():
            if (not isinstance(key, str) or not isinstance(values, list) or not values
                    or schema_key(split_key(key)) not in SWEEPABLE):
                continue  # reported by the sweep validation
            try:
                get_path(work, split_key(key))
            except KeyError:
                try:
                    set_path(work, key, copy.deepcopy(values[0]))
                except ConfigError:
                    pass  # e.g. an index into a missing list: reported later
        return work

    def __repr__(self) -> str:
        return f"Config(name={self.data['name']!r}, source={self.source!r})"

    @property
    def name(self) -> str:
        """The scenario name (``name`` key, default: the file stem)."""
        return self.data["name"]

    @property
    def is_radiative(self) -> bool:
        """True when the (single-layer) medium is given in radiative form
        (``medium.radiative``); False for a stack (``medium.layers``), whose layers each have
        their form."""
        return self.data["medium"]["radiative"] is not None

    def get(self, key: str):
        """The canonical value at dotted ``key`` (m, ns, deg).

        Known keys that are absent (``medium.radiative.tau0`` in the physical form, a
        material's ``k``) give the table default, or None when there is none. Mappings and
        lists are returned as copies. An unknown key raises KeyError with a hint.

        Examples: ``cfg.get("medium.thickness")``, ``cfg.get("simulation.fov.scattering")``,
        ``cfg.get("medium.inclusions[0].grain_size")``.
        """
        parts = split_key(key)
        try:
            value = get_path(self.data, parts)
            if value is not None:
                return copy.deepcopy(value)
        except KeyError:
            pass
        skey = schema_key(parts)
        if skey in FIELDS:
            return copy.deepcopy(DEFAULTS.get(skey))
        if parts and parts[0] == "sweep":
            return None
        if parts and parts[0] == "instrument" and len(parts) == 2:
            return None  # pass-through instrument keys
        guess = did_you_mean(key, [k.replace("[]", "[0]") for k in FIELDS])
        raise KeyError(f"{key}: unknown key" + (f"; did you mean {guess}?" if guess else ""))

    def with_overrides(self, overrides) -> "Config":
        """A new Config with ``overrides`` (dict or ``"KEY=VALUE"`` strings) applied."""
        raw = copy.deepcopy(self.raw)
        try:
            apply_overrides(raw, parse_overrides(overrides))
        except ConfigError as exc:
            raise exc.with_source(self.source) from None
        return self._point(raw)

    def sweep_points(self) -> list:
        """The scenarios of the ``sweep`` block, outer product in the order keys appear.

        Returns
        -------
        list of (dict, Config)
            For each point, the swept values as written in the preset (``{"medium.thickness":
            "10 mm"}``) and the validated configuration of that point (no ``sweep`` block).
            A configuration without a sweep gives ``[({}, self)]``.

        Raises
        ------
        ConfigError
            The first point that is invalid, its message ending in ``(in the sweep point
            KEY=VALUE, ...)``.
        """
        if not self.raw.get("sweep"):
            return [({}, self)]
        return expand_points(self.raw, self.source, self._point, keep_errors=False)

    def _point(self, raw: dict) -> "Config":
        """The Config of one sweep point's ``raw`` mapping, read like this preset."""
        return Config(raw, self.source, name_default=self._name_default,
                      base_dir=self._base_dir)

    def to_yaml(self, omit=()) -> str:
        """The resolved configuration as YAML text, quantities written with units.

        ``load_preset(yaml.safe_load(cfg.to_yaml())).data == cfg.data``. ``omit``: dotted
        keys left out (show-config leaves out what does not apply, e.g. a granular medium's
        ``medium.bottom_interface``).
        """
        body = _export(self.data, "")
        for key in omit:
            *parents, last = key.split(".")
            node = body
            for name in parents:
                node = node.get(name) if isinstance(node, dict) else None
            if isinstance(node, dict):
                node.pop(last, None)
        text = yaml.safe_dump(body, sort_keys=False, allow_unicode=True,
                              default_flow_style=False, width=100)
        return f"# warpe-cl resolved configuration of {self.source}\n{text}"
def _export(value, skey: str):
    """Canonical data -> YAML-ready data (quantities as strings); None entries dropped."""
    if isinstance(value, dict):
        out = {}
        for name, item in value.items():
            if item is None:
                continue
            if skey == "sweep":
                target = schema_key(split_key(name))
                out[name] = [_export(v, target) for v in item]
                continue
            if skey == "materials":
                child = "materials.*"
            else:
                child = f"{skey}.{name}" if skey else name
            out[name] = _export(item, child)
        return out
    if isinstance(value, list):
        return [_export(v, skey + "[]") for v in value]
    field = FIELDS.get(skey)
    if field is not None and field.kind in QUANTITY_KINDS:
        return format_quantity(value, field.kind)
    return value


def read_source(source) -> tuple:
    """A preset given as a dict, a YAML path or a bundled preset's name (``radiative/slab_co2_1m``,
    as the command line takes it: catalog.resolve_preset): (name, raw mapping, base folder for
    relative paths or None, default preset name)."""
    if isinstance(source, dict):
        return "<dict>", copy.deepcopy(source), None, "unnamed"
    if isinstance(source, (str, os.PathLike)):
        name = os.fspath(resolve_preset(os.fspath(source)))
        return (name, read_yaml(name, empty=NEEDS), os.path.dirname(os.path.abspath(name)),
                os.path.splitext(os.path.basename(name))[0])
    raise ConfigError(f"a preset is a YAML file path or a dict, not {type(source).__name__}")


def load_preset(source, overrides=None) -> Config:
    """Load, complete and validate a preset.

    Parameters
    ----------
    source : str, os.PathLike, dict or Config
        Path to a YAML preset, a bundled preset's name (``"radiative/slab_co2_1m"``, as on the
        command line), a dict of the same shape (``name`` then defaults to ``"unnamed"``), or
        an existing Config (overrides are applied to its ``raw``).
    overrides : dict or list of str, optional
        ``{"simulation.photons": 1e5}`` or ``["simulation.photons=1e5",
        'medium.thickness="100 mm"']``; values of ``KEY=VALUE`` strings are read as YAML.
        Dotted keys address list items as ``medium.inclusions[0].grain_size`` and sweeps as
        ``sweep.medium.thickness``.

    Returns
    -------
    Config

    Raises
    ------
    ConfigError
        One line naming the file, the key, the value and what is allowed.
    """
    if isinstance(source, Config):
        return source.with_overrides(overrides)
    name, raw, base_dir, name_default = read_source(source)
    if overrides and isinstance(raw, dict):  # a non-mapping is reported by Config
        try:
            apply_overrides(raw, parse_overrides(overrides))
        except ConfigError as exc:
            raise exc.with_source(name) from None
    return Config(raw, name, name_default=name_default, base_dir=base_dir)

