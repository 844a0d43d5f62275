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
from ..config import load_preset
from ..config.instrument_fields import at_wavelength
from ..errors import ConfigError, WarpeError
from ..io import Outputs
from ..sweep import run_sweep
from .expected import channel, combined
from .family import Family
from .figures import plot_map, plot_ranking
from .result import build_dataset, summary_markdown, summary_rows
from .study import load_study, member_for


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
        preset = resolve_preset(spec.preset)
        for database, wavelength in zip(spec.databases, spec.wavelengths):
            database.parent.mkdir(parents=True, exist_ok=True)
            say(f"family {spec.name}: sweeping {spec.preset} into {database} (resumed)")
            summary = run_sweep(preset, database,
                                overrides=sweep_overrides(preset, spec.photons, wavelength),
                                resume=True, quiet=quiet, say=say, device=device)
            if summary.exit_code != 0:
                raise WarpeError(f"family {spec.name}: the sweep of {spec.preset} did not "
                                 f"finish (see its manifest in {database}); run the study "
                                 "again to resume it")
    members = {spec.name: family_members(spec, study.source) for spec in study.families}
    families = [members[spec.name][0] for spec in study.families]
    reads = {(name, cand.name): member_for(fams, cand, name, study.source)
             for name, fams in members.items() for cand in study.instruments}
    results, started = {}, time.perf_counter()
    for fam in families:
        channels = {}
        for cand in study.instruments:
            others = [reads[(o.name, cand.name)] for o in families if o.name != fam.name]
            channels[cand.name] = channel(reads[(fam.name, cand.name)], cand.params,
                                          phases=study.options["phases"],
                                          database_error=study.options["database_error"],
                                          nuisances=study.options["nuisances"],
                                          others=others)
            e = combined(reads[(fam.name, cand.name)], [channels[cand.name]])
            results[(fam.name, cand.name)] = e
            say(f"{fam.name} x {cand.name}: {len(fam.nodes)} points in {e.elapsed_s:.2f} s")
        for combo in study.combinations:
            e = combined(reads[(fam.name, combo.members[0])],
                         [channels[m] for m in combo.members])
            results[(fam.name, combo.name)] = e
            say(f"{fam.name} x {combo.name} ({' + '.join(combo.members)}): {len(fam.nodes)} "
                "points")
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
            for cand in study.instruments + study.combinations:
                name = out / f"map_{_safe(fam.name)}_{_safe(cand.name)}.png"
                plot_map(ds, fam.name, cand.name, outputs.stage(name))
                files.append(name)
        plot_ranking(ds, rows, outputs.stage(out / "ranking.png"))
        files.append(out / "ranking.png")
    return {"dataset": ds, "files": files, "elapsed_s": elapsed, "summary": text}


def sweep_overrides(preset, photons, wavelength) -> list:
    """The ``--set`` values of a family's sweep: its rays per scenario (None: the preset's)
    and, where the study gives one, its wavelength (m). A preset's own instrument (its
    ``instrument:`` block, which ``run`` uses and a database does not need) goes to that
    wavelength with it where it differs from the preset's: the chain refuses a surface at
    another wavelength than its instrument's (presets/layers/lag_over_ice.yaml at 532 nm)."""
    overrides = [] if photons is None else [f"simulation.photons={photons}"]
    if wavelength is not None:
        text = f"{wavelength * 1e9:.9g} nm"
        overrides.append(f"wavelength={text}")
        own = load_preset(preset)
        lam = own.get("wavelength")
        if own.get("instrument")["name"] and (lam is None or not at_wavelength(wavelength, lam)):
            overrides.append(f"instrument.wavelength={text}")
    return overrides


def family_members(spec, source: str) -> list:
    """A family's databases as :class:`~.family.Family` objects, one per wavelength, checked
    to sweep the same keys over the same nodes at different wavelengths.

    Raises
    ------
    ConfigError
        Databases on other nodes, or two at one wavelength (one line naming both).
    """
    members = [Family(spec.name, d, str(d)) for d in spec.databases]
    first = members[0]
    for fam in members[1:]:
        same = len(fam.axes) == len(first.axes) and all(
            a.same_nodes(b) for a, b in zip(fam.axes, first.axes))
        if not same or fam.parameters != first.parameters:
            raise ConfigError(f"{fam.source} does not sweep the nodes of {first.source} (or "
                              "varies other derived quantities): the databases of one family "
                              "must be one sweep run at each wavelength",
                              key=f"families: {spec.name}", source=source)
        if fam.wavelength is None or first.wavelength is None or \
                at_wavelength(fam.wavelength, first.wavelength):
            raise ConfigError(f"{fam.source} and {first.source} are at the same wavelength: "
                              "give one database per wavelength",
                              key=f"families: {spec.name}", source=source)
    return members


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name)
