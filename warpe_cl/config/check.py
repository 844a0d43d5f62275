"""One pass over a raw preset: sections, lists, materials, time bins, the sweep block and the
medium, checked against :data:`~warpe_cl.config.schema.SCHEMA` and turned into the
canonical nested mapping :attr:`Config.data <warpe_cl.config.Config.data>`."""
from __future__ import annotations

import copy
import os

from ..errors import ConfigError
from ..units import format_quantity
from .bins import bin_count, edges
from .keys import schema_key, split_key
from .schema import (DEFAULTS, FIELDS, MAX_TIME_BINS, PHYSICAL_KEYS, SCALAR_KINDS, SCHEMA,
                     SWEEPABLE, Field, children)
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
        raw = self.mapping(given, "medium", where)
        out = self.section(raw, "medium", where, skip=("radiative",) + PHYSICAL_KEYS)
        physical = [k for k in PHYSICAL_KEYS if raw.get(k) is not None]
        radiative = raw.get("radiative") is not None
        if radiative and physical:
            raise ConfigError(f"given together with medium.{physical[0]}; describe the medium "
                              f"either radiatively (medium.radiative) or physically "
                              f"(medium.compacity, medium.inclusions and, for a slab, "
                              f"medium.matrix), not both", "medium.radiative")
        if not radiative and not physical:
            raise ConfigError("no composition given; give either medium.radiative: "
                              "{tau0, omega, n} or the physical form medium.compacity and "
                              "medium.inclusions (plus medium.matrix for a slab)", where)
        out["radiative"] = (self.value(FIELDS["medium.radiative"], raw, "radiative",
                                       "medium.radiative") if radiative else None)
        for name in PHYSICAL_KEYS:
            out[name] = None
        if physical:
            slab = out["texture"] == "slab"
            if not slab and raw.get("matrix") is not None:
                raise ConfigError(f"{show(raw['matrix'])} is not allowed for a granular "
                                  f"medium, whose grains are the inclusions and whose pores "
                                  f"are void; remove medium.matrix", "medium.matrix")
            for name in PHYSICAL_KEYS:
                field = FIELDS[f"medium.{name}"]
                if raw.get(name) is None and (name != "matrix" or slab):
                    need = ("give the slab's matrix material, e.g. H2O" if name == "matrix"
                            else f"the physical form needs it: give {allowed(field)}")
                    raise ConfigError(f"missing; {need}", f"medium.{name}")
                out[name] = self.value(field, raw, name, f"medium.{name}")
        return out

    # the whole preset -------------------------------------------------------------------
    def preset(self, raw) -> dict:
        if not isinstance(raw, dict):
            kind = "a list" if isinstance(raw, list) else f"the single value {show(raw)}"
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

