"""The catalogue of bundled presets (``presets/`` of the repository, installed as the package
data ``warpe_cl.presets``)."""
from __future__ import annotations

from pathlib import Path


def presets_dir() -> Path:
    """Folder of the bundled presets (installed package data, or ``presets/`` of a checkout)."""
    try:
        from importlib.resources import files
        path = Path(str(files("warpe_cl.presets")))
        if path.is_dir() and any(path.rglob("*.yaml")):
            return path
    except (ImportError, ModuleNotFoundError, TypeError):
        pass
    return Path(__file__).resolve().parent.parent / "presets"


def bundled_presets() -> dict:
    """``{name: path}`` for every bundled preset, name = path below the folder without ``.yaml``."""
    root = presets_dir()
    return {str(p.relative_to(root).with_suffix("")): p for p in sorted(root.rglob("*.yaml"))}


def resolve_preset(text: str) -> Path:
    """A preset argument as a path: an existing file, else a bundled preset's name
    (``radiative/slab_co2_1m``, with or without ``presets/`` and ``.yaml``, or ``slab_co2_1m`` when
    that stem is unique). Unknown names are
    returned unchanged, so that loading reports the missing file."""
    path = Path(text)
    if path.is_file():
        return path
    return bundled_preset(text) or path


def bundled_preset(text: str, presets: dict | None = None):
    """The bundled preset named ``text`` (``radiative/slab_co2_1m``, with or without
    ``presets/`` and ``.yaml``, or a stem that only one preset has), or None.

    ``presets``: :func:`bundled_presets`, when the caller already has it."""
    name = text.removeprefix("presets/").removesuffix(".yaml")
    presets = bundled_presets() if presets is None else presets
    if name in presets:
        return presets[name]
    by_stem = [p for key, p in presets.items() if key.rsplit("/", 1)[-1] == name]
    return by_stem[0] if len(by_stem) == 1 else None
