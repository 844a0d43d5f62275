"""The reference table docs/config.md, generated from :data:`~warpe_cl.config.schema.SCHEMA`."""
from __future__ import annotations

from ..units import unit_list
from .schema import QUANTITY_KINDS, SCALAR_KINDS, SCHEMA
from .validate import allowed

__all__ = ["schema_markdown", "reference_markdown", "REFERENCE_PATH"]


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
            "degrees.\n\n" + schema_markdown())
