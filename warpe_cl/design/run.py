"""``warpe-cl design``: a study file -> DIR/design.nc, DIR/summary.txt and the figures
(docs/design.md).

The families' presets are swept first (``warpe-cl sweep``, resumed: a database already
complete costs nothing), then every input is checked (databases complete, wavelengths the
instruments'), then the expected widths are computed family by family, instrument by
instrument.
"""
from __future__ import annotations

import re
import time
from pathlib import Path

from ..catalog import resolve_preset
from ..errors import ConfigError, WarpeError
from ..io import Outputs
from ..sweep import run_sweep
from .expected import expected
from .family import Family
from .figures import plot_map, plot_ranking
from .result import build_dataset, summary_markdown, summary_rows
from .study import check_wavelengths, load_study


def check_out(out, overwrite: bool) -> Path:
    """The output folder, checked before any work: a folder (or a name to create in a folder
    that exists), holding no design.nc unless ``overwrite``."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out} is a file; give a folder", key="--out")
    if not out.exists() and not out.parent.resolve().is_dir():
        raise ConfigError(f"folder {out.parent} does not exist", key="--out")
    if (out / "design.nc").exists() and not overwrite:
        raise ConfigError(f"{out / 'design.nc'} exists; give --overwrite to replace it, or "
                          "another folder", key="--out")
    return out


def run_study(path, out, *, overwrite: bool = False, say=print, quiet: bool = False,
              device=None) -> dict:
    """Run a design study (module docstring).

    Parameters
    ----------
    path : path
        The study file (:mod:`warpe_cl.design.study`).
    out : path
        The output folder.
    overwrite : bool
        Replace the files of an earlier study in ``out``.
    say : callable
        Prints progress lines.
    quiet : bool
        No progress of the sweeps.
    device : str, optional
        The device of the sweeps (``warpe-cl sweep --device``).

    Returns
    -------
    dict
        ``dataset`` (design.nc's), ``files`` (paths written), ``elapsed_s`` (of the expected
        widths, s), ``summary`` (the Markdown table).

    Raises
    ------
    ConfigError
        A bad study file, database or output folder, or an instrument at another wavelength
        than a database: one line, before any work.
    """
    out = check_out(out, overwrite)
    study = load_study(path, out)
    for spec in study.families:
        if spec.preset is None:
            continue
        overrides = [] if spec.photons is None else [f"simulation.photons={spec.photons}"]
        spec.database.parent.mkdir(parents=True, exist_ok=True)
        say(f"family {spec.name}: sweeping {spec.preset} into {spec.database} (resumed)")
        summary = run_sweep(resolve_preset(spec.preset), spec.database, overrides=overrides,
                            resume=True, quiet=quiet, say=say, device=device)
        if summary.exit_code != 0:
            raise WarpeError(f"family {spec.name}: the sweep of {spec.preset} did not finish "
                             f"(see its manifest in {spec.database}); run the study again to "
                             "resume it")
    families = [Family(spec.name, spec.database, str(spec.database))
                for spec in study.families]
    check_wavelengths(families, study)
    results, started = {}, time.perf_counter()
    for fam in families:
        for cand in study.instruments:
            e = expected(fam, cand.params, phases=study.options["phases"],
                         database_error=study.options["database_error"],
                         nuisances=study.options["nuisances"])
            results[(fam.name, cand.name)] = e
            say(f"{fam.name} x {cand.name}: {len(fam.nodes)} points in {e.elapsed_s:.2f} s")
    elapsed = time.perf_counter() - started
    ds = build_dataset(study, families, results)
    text = summary_markdown(ds)
    out.mkdir(exist_ok=True)
    files = [out / "design.nc", out / "summary.txt"]
    with Outputs() as outputs:
        outputs.netcdf(ds, files[0], key="--out")
        outputs.text(files[1], text + "\n")
    rows = summary_rows(ds)
    with Outputs() as outputs:
        for fam in families:
            for cand in study.instruments:
                name = out / f"map_{_safe(fam.name)}_{_safe(cand.name)}.png"
                plot_map(ds, fam.name, cand.name, outputs.stage(name))
                files.append(name)
        plot_ranking(ds, rows, outputs.stage(out / "ranking.png"))
        files.append(out / "ranking.png")
    return {"dataset": ds, "files": files, "elapsed_s": elapsed, "summary": text}


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name)
