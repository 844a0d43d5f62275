"""One pass over a raw preset: sections, lists, materials, time bins, the sweep block and the
medium, checked against :data:`~warpe_cl.config.schema.SCHEMA` and turned into the
canonical nested mapping :attr:`Config.data <warpe_cl.config.Config.data>`."""
from __future__ import annotations

import copy
import os

from ..errors import ConfigError
from ..params import MAX_LAYERS
from ..units import format_quantity
from .bins import bin_count, edges
from .keys import schema_key, split_key
from .schema import (DEFAULTS, FIELDS, LAYER_KEYS, MAX_TIME_BINS, PHYSICAL_KEYS, SCALAR_KINDS,
                     SCHEMA, STACK_KEYS, SWEEPABLE, Field, children)
from .tables import load_table
from .validate import allowed, check_scalar, did_you_mean, show, unknown_key

__all__ = ["PresetValidator", "sweep_field", "NEEDS"]

NEEDS = "a preset needs at least medium.texture and medium.thickness"
_ALL_KEYS = [f.key for f in SCHEMA]


class PresetValidator:
    """One pass over a raw preset, producing the canonical nested dict.

    Parameters
    ----------
    name_default : str
        The scenario name when the preset gives none (the file stem).
    base_dir : str or None
        The preset's folder, where relative material tables are read from.

    Each ``kind_*`` method checks one structured kind of the table (``section``, ``list``,
    ``names``, ``time_bins``, ``sweep``, the medium); :meth:`preset` checks a whole preset.
    """

    def __init__(self, name_default: str, base_dir: str | None):
        self.name_default = name_default
        self.base_dir = base_dir

    # generic pieces -------------------------------------------------------------------
    def mapping(self, value, prefix: str, where: str, open_: bool = False) -> dict:
        """Check that ``value`` is a mapping whose keys are rows under ``prefix``."""
        if not isinstance(value, dict):
            names = ", ".join(f.key.rsplit(".", 1)[-1] for f in children(prefix))
            raise ConfigError(f"{show(value)} is not a mapping; give a mapping with keys "
                              f"among {names}", where)
        siblings = [f.key.rsplit(".", 1)[-1] for f in children(prefix)]
        for key in value:
            if not isinstance(key, str):
                raise ConfigError("keys must be text", f"{where}.{show(key)}" if where
                                  else show(key))
            if key not in siblings and not open_:
                display = f"{where}.{key}" if where else key
                raise unknown_key(display, key, siblings, where, _ALL_KEYS)
        return value

    def value(self, field: Field, raw: dict, name: str, where: str):
        """The canonical value of child ``name`` of ``raw`` described by ``field``."""
        given = raw.get(name)
        if given is None:
            if field.required:
                raise ConfigError(f"missing; give {allowed(field)}", where)
            if field.kind in SCALAR_KINDS:
                return copy.deepcopy(DEFAULTS[field.key])
            if field.default is None:
                return None
            given = copy.deepcopy(field.default)
        if field.kind in SCALAR_KINDS:
            return check_scalar(field, given, where)
        handler = getattr(self, "kind_" + field.kind)
        return handler(field, given, where)

    def section(self, raw, prefix: str, where: str, skip=(), open_=False) -> dict:
        raw = self.mapping(raw, prefix, where, open_)
        out = {}
        for field in children(prefix):
            name = field.key.rsplit(".", 1)[-1]
            if name in skip:
                continue
            sub = f"{where}.{name}" if where else name
            out[name] = self.value(field, raw, name, sub)
        if open_:
            known = {f.key.rsplit(".", 1)[-1] for f in children(prefix)}
            out.update({k: copy.deepcopy(v) for k, v in raw.items() if k not in known})
        return out

    # structured kinds -----------------------------------------------------------------
    def kind_section(self, field, given, where):
        return self.section(given, field.key, where)

    def kind_open_section(self, field, given, where):
        return self.section(given, field.key, where, open_=True)

    def kind_list(self, field, given, where):
        if field.key == "medium.layers":      # swept whole: the medium's phase_g is unknown
            return self.layers(given, where, None)
        if not isinstance(given, list) or not given:
            raise ConfigError(f"{show(given)} is not allowed; give a non-empty list of "
                              f"mappings, e.g. [{{material: CO2, proportion: 1.0, "
                              f"grain_size: \"100 um\"}}]", where)
        return [self.section(item, field.key + "[]", f"{where}[{i}]")
                for i, item in enumerate(given)]

    def kind_names(self, field, given, where):
        """``materials``: NAME -> {n, k} or {table}."""
        if not isinstance(given, dict):
            raise ConfigError(f"{show(given)} is not a mapping; give NAME: {{n: ..., k: ...}}"
                              f" or NAME: {{table: FILE}}", where)
        out, seen = {}, {}
        for name, entry in given.items():
            sub = f"{where}.{name}"
            if not isinstance(name, str) or not name.strip():
                raise ConfigError("material names must be text", f"{where}.{show(name)}")
            if name.lower() in seen:
                raise ConfigError(f"defined twice (also as {seen[name.lower()]}); names are "
                                  f"case-insensitive", sub)
            seen[name.lower()] = name
            prefix = field.key + ".*"
            entry = self.mapping(entry, prefix, sub)
            if entry.get("table") is not None:
                extra = [k for k in ("n", "k") if entry.get(k) is not None]
                if extra:
                    raise ConfigError("given together with table; give either n and k, or "
                                      "table", f"{sub}.{extra[0]}")
                path = check_scalar(FIELDS[prefix + ".table"], entry["table"], f"{sub}.table")
                out[name] = {"table": self.table_path(path, f"{sub}.table")}
                load_table(out[name]["table"], name)  # every cell checked, read once
            else:
                if entry.get("n") is None:
                    raise ConfigError("missing; give the optical constants {n: ..., k: ...} "
                                      "or {table: FILE}", f"{sub}.n")
                out[name] = self.section(entry, prefix, sub, skip=("table",))
        return out

    def table_path(self, path: str, where: str) -> str:
        full = path
        if not os.path.isabs(path) and self.base_dir is not None:
            full = os.path.join(self.base_dir, path)
        if not os.path.isfile(full):
            raise ConfigError(f"{path}: no such file (a relative path is read from the "
                              f"preset's folder)", where)
        return full

    def kind_time_bins(self, field, given, where):
        raw = self.mapping(given, field.key, where)
        rows = {f.key.rsplit(".", 1)[-1]: f for f in children(field.key)}
        get = {k: raw.get(k) for k in rows}
        if get["per_decade"] is not None and get["width"] is not None:
            raise ConfigError("per_decade and width are both given; give per_decade for "
                              "log-spaced bins or width for linear bins, not both", where)
        linear = get["width"] is not None
        out = {}
        start_field = rows["start"]
        if get["start"] is None:
            out["start"] = 0.0 if linear else DEFAULTS[start_field.key]
        else:
            out["start"] = check_scalar(start_field, get["start"], f"{where}.start")
        if not linear and out["start"] <= 0:
            raise ConfigError(f"{show(get['start'])} is not allowed; log-spaced bins need "
                              f'a time > 0 with a unit, e.g. "1e-6 ns"', f"{where}.start")
        if linear and get["stop"] is None:
            raise ConfigError('missing; linear bins (width) need a stop time, e.g. "200 ns"',
                              f"{where}.stop")
        out["stop"] = self.value(rows["stop"], raw, "stop", f"{where}.stop")
        if out["stop"] <= out["start"]:
            shown = get["stop"] if get["stop"] is not None else rows["stop"].default
            raise ConfigError(f"{show(shown)} is not allowed; give a time > start "
                              f"({format_quantity(out['start'], 'time')})", f"{where}.stop")
        if linear:
            out["width"] = check_scalar(rows["width"], get["width"], f"{where}.width")
        else:
            out["per_decade"] = self.value(rows["per_decade"], raw, "per_decade",
                                           f"{where}.per_decade")
        count = bin_count(out)
        if count > MAX_TIME_BINS:
            raise ConfigError(f"these bins number {count}; at most {MAX_TIME_BINS} are "
                              f"allowed (widen the bins or shorten the range)", where)
        return out

    def kind_sweep(self, field, given, where):
        if not isinstance(given, dict):
            raise ConfigError(f"{show(given)} is not a mapping; give KEY: [VALUE, ...], "
                              f'e.g. medium.thickness: ["1 mm", "10 mm"]', where)
        out = {}
        for key, values in given.items():
            sub = f"{where}.{key}"
            target = sweep_field(key, sub)
            if not isinstance(values, list) or not values:
                raise ConfigError(f"{show(values)} is not allowed; give a non-empty list of "
                                  f"values, each {allowed(target)}", sub)
            if target.key == "medium":
                out[key] = [self.kind_medium(v, sub) for v in values]
                continue
            out[key] = [self.value(target, {"v": v}, "v", sub) if v is not None else
                        _raise_empty(target, sub) for v in values]
        return out

    # the medium -----------------------------------------------------------------------
    def kind_medium(self, given, where="medium"):
        """``medium``: one layer (texture, thickness, composition), or a stack
        (``layers``), optionally over a ``substrate``.

        The keys ``layers`` and ``substrate`` appear in the result only when given, so that a
        single-layer medium resolves to the same data (hence the same scenario key) as
        before they existed. With ``layers``, the medium-level :data:`LAYER_KEYS` are None.
        """
        raw = self.mapping(given, "medium", where)
        layered = raw.get("layers") is not None
        skip = LAYER_KEYS + STACK_KEYS
        if layered:
            for name in LAYER_KEYS:
                if raw.get(name) is not None:
                    raise ConfigError(
                        f"given together with medium.layers; with layers, each layer has its "
                        f"own {name} (medium.layers[i].{name}): remove medium.{name} or "
                        f"medium.layers", f"medium.{name}")
            out = {name: None for name in ("texture", "thickness")}
            out.update(self.section(raw, "medium", where, skip=skip))
            for name in ("radiative",) + PHYSICAL_KEYS:
                out[name] = None
            out["layers"] = self.layers(raw["layers"], "medium.layers", out["phase_g"])
        else:
            out = {}
            for name in ("texture", "thickness"):      # required without layers
                field = FIELDS[f"medium.{name}"]
                if raw.get(name) is None:
                    raise ConfigError(f"missing; give {allowed(field)}", f"{where}.{name}")
                out[name] = check_scalar(field, raw[name], f"{where}.{name}")
            out.update(self.section(raw, "medium", where, skip=skip))
            out.update(self.composition(raw, "medium", out["texture"], "medium"))
        if raw.get("substrate") is not None:
            out["substrate"] = self.substrate(raw["substrate"], "medium.substrate",
                                              out["bottom_interface"])
        return out

    def composition(self, raw: dict, prefix: str, texture: str, keyp: str) -> dict:
        """The composition of one medium or layer: ``radiative`` or the physical form
        (:data:`PHYSICAL_KEYS`), never both.

        Parameters
        ----------
        raw : dict
            The medium or layer as written.
        prefix : str
            Its table key (``"medium"``, ``"medium.layers[]"``).
        texture : str
            Its (checked) texture.
        keyp : str
            Its key in messages (``"medium"``, ``"medium.layers[1]"``).
        """
        what = "medium" if prefix == "medium" else "layer"
        physical = [k for k in PHYSICAL_KEYS if raw.get(k) is not None]
        radiative = raw.get("radiative") is not None
        if radiative and physical:
            raise ConfigError(f"given together with {keyp}.{physical[0]}; describe the {what} "
                              f"either radiatively ({keyp}.radiative) or physically "
                              f"({keyp}.compacity, {keyp}.inclusions and, for a slab, "
                              f"{keyp}.matrix), not both", f"{keyp}.radiative")
        if not radiative and not physical:
            raise ConfigError(f"no composition given; give either {keyp}.radiative: "
                              f"{{tau0, omega, n}} or the physical form {keyp}.compacity and "
                              f"{keyp}.inclusions (plus {keyp}.matrix for a slab)", keyp)
        out = {"radiative": (self.value(FIELDS[f"{prefix}.radiative"], raw, "radiative",
                                        f"{keyp}.radiative") if radiative else None)}
        for name in PHYSICAL_KEYS:
            out[name] = None
        if physical:
            slab = texture == "slab"
            if not slab and raw.get("matrix") is not None:
                raise ConfigError(f"{show(raw['matrix'])} is not allowed for a granular "
                                  f"{what}, whose grains are the inclusions and whose pores "
                                  f"are void; remove {keyp}.matrix", f"{keyp}.matrix")
            for name in PHYSICAL_KEYS:
                field = FIELDS[f"{prefix}.{name}"]
                if raw.get(name) is None and (name != "matrix" or slab):
                    need = ("give the slab's matrix material, e.g. H2O" if name == "matrix"
                            else f"the physical form needs it: give {allowed(field)}")
                    raise ConfigError(f"missing; {need}", f"{keyp}.{name}")
                out[name] = self.value(field, raw, name, f"{keyp}.{name}")
        return out

    def layers(self, given, where: str, phase_g) -> list:
        """``medium.layers``: 1 to :data:`~warpe_cl.params.MAX_LAYERS` layers, top first,
        at least one of thickness > 0; a layer's ``phase_g`` defaults to ``phase_g`` (the
        medium's; None where unknown: a swept list of stacks)."""
        if not isinstance(given, list) or not given:
            raise ConfigError(f"{show(given)} is not allowed; give a non-empty list of layers, "
                              f"top first, e.g. [{{texture: granular, thickness: \"10 cm\", "
                              f"radiative: {{tau0: 1.0, omega: 0.9, n: 1.3}}}}]", where)
        if len(given) > MAX_LAYERS:
            raise ConfigError(f"{len(given)} layers are given; a stack holds at most "
                              f"{MAX_LAYERS} (the walk kernel's limit)", where)
        out = [self.layer(item, f"{where}[{i}]", phase_g) for i, item in enumerate(given)]
        if not any(layer["thickness"] > 0 for layer in out):
            raise ConfigError("every layer has thickness 0; at least one layer needs a "
                              "thickness > 0 (a layer of thickness 0 is no layer)", where)
        return out

    def layer(self, given, where: str, phase_g) -> dict:
        """One entry of ``medium.layers``: texture, thickness, phase_g and composition."""
        prefix = "medium.layers[]"
        raw = self.mapping(given, prefix, where)
        out = {}
        for name in ("texture", "thickness", "phase_g"):
            out[name] = self.value(FIELDS[f"{prefix}.{name}"], raw, name, f"{where}.{name}")
        if out["phase_g"] is None:
            out["phase_g"] = phase_g
        out.update(self.composition(raw, prefix, out["texture"], where))
        return out

    def substrate(self, given, where: str, bottom_interface: str) -> dict:
        """``medium.substrate``: ``{material}`` or ``{n, k}``; refused with
        ``bottom_interface: none``."""
        raw = self.mapping(given, "medium.substrate", where)
        if bottom_interface == "none":
            raise ConfigError("given together with medium.bottom_interface: none, which puts "
                              "the floor in optical contact with the layer above it; a "
                              "substrate's Fresnel contact replaces the vacuum gap of "
                              "bottom_interface: fresnel: remove medium.substrate or give "
                              "medium.bottom_interface: fresnel", where)
        if raw.get("material") is not None:
            extra = [k for k in ("n", "k") if raw.get(k) is not None]
            if extra:
                raise ConfigError(f"given together with {where}.material; give either "
                                  f"material or n and k, not both", f"{where}.{extra[0]}")
            return {"material": self.value(FIELDS["medium.substrate.material"], raw,
                                           "material", f"{where}.material"),
                    "n": None, "k": None}
        if raw.get("n") is None:
            raise ConfigError("no index given; give {material: NAME} (a built-in or a name "
                              "defined under materials) or {n: N, k: K}",
                              f"{where}.n" if raw.get("k") is not None else where)
        out = {"material": None, **self.section(raw, "medium.substrate", where,
                                                skip=("material",))}
        if out["k"] is None:
            out["k"] = 0.0
        return out

    # the whole preset -------------------------------------------------------------------
    def preset(self, raw) -> dict:
        if not isinstance(raw, dict):
            # a text is not echoed: it is often a whole file that is no preset (/etc/passwd)
            kind = ("a list" if isinstance(raw, list) else
                    f"one text of {len(raw):,} characters" if isinstance(raw, str) else
                    f"the single value {show(raw)}")
            raise ConfigError(f"the top level is {kind}; a preset must be a mapping of keys "
                              f"(medium:, simulation:, ...) with at least medium.texture and "
                              f"medium.thickness")
        if not raw:
            raise ConfigError(f"the preset is empty; {NEEDS}")
        self.mapping(raw, "", "")
        sweep = self.value(FIELDS["sweep"], raw, "sweep", "sweep")  # first: it fills gaps
        if raw.get("medium") is None:
            raise ConfigError(f"missing; {NEEDS}", "medium")
        out = {}
        for field in children(""):
            if field.key == "sweep":
                out["sweep"] = sweep
            elif field.key == "medium":
                out["medium"] = self.kind_medium(raw["medium"])
            elif field.key == "name" and raw.get("name") is None:
                out["name"] = self.name_default
            else:
                out[field.key] = self.value(field, raw, field.key, field.key)
        sim = out["simulation"]
        stack = [k for k in STACK_KEYS if out["medium"].get(k) is not None]
        if stack and sim["mode"] == "weighted":
            raise ConfigError(f"weighted is not allowed with medium.{stack[0]}: only the analog "
                              f"walk is layered (docs/walk.md §7); give simulation.mode: "
                              f"analog", "simulation.mode")
        if sim["max_time"] is None:
            sim["max_time"] = float(edges(sim["time_bins"])[-1])
        return out


def _raise_empty(field: Field, where: str):
    raise ConfigError(f"an empty value is not allowed; give {allowed(field)}", where)


def sweep_field(key, where: str) -> Field:
    """The schema row a sweep key refers to (``medium.inclusions[0].grain_size`` ...)."""
    if not isinstance(key, str):
        raise ConfigError("sweep keys must be dotted keys such as medium.thickness", where)
    skey = schema_key(split_key(key))
    if skey in SWEEPABLE:
        return FIELDS[skey]
    candidates = [k.replace("[]", "[0]") for k in SWEEPABLE]
    guess = did_you_mean(key, candidates)
    hint = f"did you mean {guess}?" if guess else "give a dotted key of the schema, e.g. " \
                                                   "medium.thickness"
    raise ConfigError(f"unknown key; {hint}", where)

