"""The reference table docs/config.md, generated from :data:`~warpe_cl.config.schema.SCHEMA`."""
from __future__ import annotations

from ..units import unit_list
from .grid import MAX_GRID_POINTS
from .schema import MAX_K, MAX_N, MAX_TIME_BINS, QUANTITY_KINDS, SCALAR_KINDS, SCHEMA
from .validate import MAX_DEPTH, MAX_FILE_BYTES, MAX_NODES, MAX_TEXT, allowed

__all__ = ["schema_markdown", "reference_markdown", "limits_markdown", "REFERENCE_PATH"]


def schema_markdown() -> str:
    """The schema as a markdown table: key, kind and unit, default, allowed values, help."""
    kind_text = {"length": "length (m)", "time": "time (ns)", "angle": "angle (deg)",
                 "float": "number", "int": "integer", "str": "text", "choice": "choice",
                 "bool": "boolean", "section": "mapping", "open_section": "mapping",
                 "list": "list", "names": "mapping of names", "time_bins": "mapping",
                 "sweep": "mapping of lists"}
    lines = ["| key | kind (stored unit) | default | allowed | description |",
             "| --- | --- | --- | --- | --- |"]
    for f in SCHEMA:
        if f.required:
            default = "required"
        elif f.default_doc:
            default = f.default_doc
        elif f.default is None or f.default == {} or f.default == "":
            default = "—" if f.default != "" else '`""`'
        else:
            default = f"`{f.default}`"
        if f.kind in SCALAR_KINDS and f.kind != "str":
            allowed_text = allowed(f)
            if f.kind in QUANTITY_KINDS:
                allowed_text = allowed_text.split(" with a unit")[0] + f" ({unit_list(f.kind)})"
        else:
            allowed_text = ""
        kind = kind_text[f.kind] + (f" ({f.unit})" if f.unit else "")
        cells = [f"`{f.key}`", kind, default, allowed_text, f.help]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines) + "\n"


REFERENCE_PATH = "docs/config.md"


def reference_markdown() -> str:
    """The whole of docs/config.md: a title, how it is made, and :func:`schema_markdown`.

    ``python tools/config_docs.py`` writes it; tests/test_config.py fails when the file in
    the repository differs from it (the table was changed and the file not regenerated).
    """
    return ("# Preset reference\n\n"
            "Generated from the schema table in `warpe_cl/config/schema.py` by "
            "`python tools/config_docs.py` (do not edit by hand; a test fails when this file "
            "is out of date). Lengths are stored in metres, times in nanoseconds, angles in "
            "degrees.\n\n" + limits_markdown() + "\n## Keys\n\n" + schema_markdown())


def limits_markdown() -> str:
    """The limits every input file is read under (docs/config.md, "Limits")."""
    return (
        "## Limits\n\n"
        "Every file is checked before it is used, and a file outside these limits is refused "
        "with one line naming it (exit 2):\n\n"
        "- a preset, an instrument preset (`--instrument FILE`) and a material table "
        "(`materials.NAME.table`) are regular files (not a device such as `/dev/zero`, a "
        f"pipe or a folder) of at most {MAX_FILE_BYTES} bytes (1 MiB), in UTF-8;\n"
        f"- a YAML document nests mappings and lists at most {MAX_DEPTH} levels deep and "
        f"holds at most {MAX_NODES} values once its aliases (`*name`) are expanded; the "
        "value of a `--set KEY=VALUE` likewise;\n"
        f"- a text value (`description`, `name`, a file path) has at most {MAX_TEXT} "
        "characters;\n"
        "- a real refractive index n (`materials.*.n`, `medium.substrate.n`, "
        f"`medium.radiative.n`) is at most {MAX_N:g} and an extinction index k at most "
        f"{MAX_K:g} (what the walk's single-precision Fresnel terms hold without overflow, "
        "docs/materials.md §4); every cell of a material table is a finite number: "
        "wavelength_nm > 0 and strictly increasing, n > 0, k >= 0, and the n, k "
        f"interpolated at the run's wavelength are at most {MAX_N:g} and {MAX_K:g};\n"
        f"- a sweep has at most {MAX_GRID_POINTS:.0e} points (the product of its axes' "
        "lengths), and no axis gives the same value twice (compared after unit resolution: "
        "`\"10 mm\"` and `\"1 cm\"` are the same);\n"
        f"- the time bins (`simulation.time_bins`) number at most {MAX_TIME_BINS}, and fewer "
        "where the device cannot hold the walk's buffers: a run is refused before its walk, "
        "naming the largest count the device allows.\n")
