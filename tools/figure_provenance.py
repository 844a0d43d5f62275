"""Which tree, rays and results made the figures of ``docs/figures/``.

``tools/reproduce_paper.py`` and ``tools/layer_figures.py`` record, for each preset they draw,
an entry of ``docs/figures/provenance.json``: the tree (``git describe --always --dirty``),
the rays per scenario, the device, the command, and the preset's **check bits**: one SHA-256
of every numeric output of the preset walked at :data:`CHECK_PHOTONS` rays with seed
:data:`CHECK_SEED` (``tools/preset_bits.py``). The walk is keyed by (seed, scenario) on every
device (docs/walk.md §2), so those bits change exactly when a change of the kernel, the
physics, the configuration or the preset moves a result, and not for a change of structure.

``tests/test_metrics.py::test_the_figures_were_made_by_these_results`` walks the presets
again and compares: figures whose numbers the code no longer gives fail the suite until they
are made again (docs/figures/README.md says how).
"""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

from preset_bits import combined, fingerprints

#: Rays per scenario and seed of the check walk: a few seconds for every preset.
CHECK_PHOTONS = 2000
CHECK_SEED = 1
REPO = Path(__file__).resolve().parent.parent


def check_bits(folder: str, names, device: str | None = None) -> dict:
    """``{preset: sha256 hex}`` of the presets ``names`` of ``presets/FOLDER`` walked at
    CHECK_PHOTONS rays, seed CHECK_SEED."""
    wanted = {f"{folder}/{name}" for name in names}
    prints = fingerprints(CHECK_PHOTONS, CHECK_SEED, device, folders=(folder,), names=wanted,
                          quiet=True)
    return {name.split("/", 1)[1]: combined(variables) for name, variables in prints.items()}


def tree_name(repo: Path = REPO, outputs: Path | None = None) -> str:
    """The commit of ``repo`` (``git describe --always``), with ``-dirty`` when a tracked file
    other than those under ``outputs`` (the figures being written) differs from it; ``unknown``
    outside a checkout."""
    def git(*args):
        return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True,
                              check=True).stdout.strip()
    try:
        name = git("describe", "--always", "--abbrev=12")
        spec = ["--", "."]
        if outputs is not None:
            spec.append(f":(exclude){Path(outputs).resolve().relative_to(repo.resolve())}")
        changed = git("status", "--porcelain", "--untracked-files=no", *spec)
    except (OSError, ValueError, subprocess.CalledProcessError):
        return "unknown"
    return name + ("-dirty" if changed else "")


def write_provenance(path: Path, folder: str, presets: list, photons, device: str,
                     command: str) -> Path:
    """Record the presets ``presets`` of ``presets/FOLDER`` in ``path`` (provenance.json),
    keeping the entries of the other presets.

    Parameters
    ----------
    path : Path
        ``provenance.json`` in the figures' folder.
    folder : str
        ``paper`` or ``layers``.
    presets : list of str
        The presets just drawn.
    photons : float or None
        Rays per scenario of the figures (None: each preset's own).
    device : str
        The device that walked them.
    command : str
        The command that made them.
    """
    entries = {}
    if path.is_file():
        try:
            entries = dict(json.loads(path.read_text(encoding="utf-8")).get("presets", {}))
        except (OSError, ValueError, AttributeError):
            entries = {}
    bits = check_bits(folder, presets)
    tree = tree_name(outputs=path.parent)
    for name in presets:
        entries[f"{folder}/{name}"] = {
            "tree": tree, "photons": photons, "device": device, "command": command,
            "check_photons": CHECK_PHOTONS, "check_seed": CHECK_SEED, "check_bits": bits[name]}
    path.write_text(json.dumps({"presets": dict(sorted(entries.items()))}, indent=1) + "\n",
                    encoding="utf-8")
    return path
