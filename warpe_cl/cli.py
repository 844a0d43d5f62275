"""The ``warpe-cl`` command line (docs/interface.md §2).

Exit codes: 0 success; 2 bad input (configuration, units, files); 3 no usable OpenCL
device; 1 anything else; 130 Ctrl-C; 143 SIGTERM. Errors are one readable line on stderr,
escaped and bounded (:func:`warpe_cl.errors.printable`), never a traceback
(``WARPE_CL_DEBUG=1`` shows it).

Every output is checked before any work: its format, its folder, that it is none of the inputs,
and that it does not exist unless ``--overwrite`` is given. The NetCDF result is written (and
renamed into place) before the figure is drawn, so a figure that fails never costs the result.

Only light modules are imported here: NumPy, xarray and the package's own modules are
imported inside :func:`main`, so that Ctrl-C while they load is one line and exit 130 too.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path

from . import stops
from .errors import ConfigError, DeviceError, WarpeError, one_line, printable
from .stops import Terminated

EXIT_OK, EXIT_OTHER, EXIT_INPUT, EXIT_DEVICE = 0, 1, 2, 3
EXIT_SIGINT, EXIT_SIGTERM = 130, 143

__all__ = ["main", "make_parser", "Terminated"]


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors as bad input (exit 2) in one line."""

    def error(self, message):
        raise ConfigError(f"{message} (see `{self.prog} --help`)")


def _overrides(args) -> list:
    sets = list(args.set or [])
    if getattr(args, "photons", None) is not None:
        sets.append(f"simulation.photons={args.photons}")
    if getattr(args, "seed", None) is not None:
        sets.append(f"simulation.seed={args.seed}")
    return sets


def _instrument_preset(text: str):
    """The path of ``text`` when it names an instrument preset (a bundled
    ``instruments/bela``, or a file with no medium and a base or an instrument section such as
    transmitter), else None."""
    from .catalog import resolve_preset
    from .config.instrument_fields import instruments_dir
    path = resolve_preset(text)
    if not path.is_file():
        return None
    if path.resolve().parent == instruments_dir().resolve():
        return path
    try:
        import yaml
        doc = yaml.safe_load(path.read_text())
    except Exception:  # noqa: BLE001 - loading the preset reports it
        return None
    instrumental = ("base", "transmitter", "receiver", "detector", "electronics")
    return path if isinstance(doc, dict) and "medium" not in doc \
        and any(k in doc for k in instrumental) else None


def _not_an_instrument(args):
    """Bad input (exit 2) when ``run``/``sweep`` is given an instrument preset."""
    path = _instrument_preset(args.preset)
    if path is not None:
        from .config.instrument_fields import BUILTIN
        if path.stem in BUILTIN and path.parent.name == "instruments":
            path = path.stem                 # bundled: its short name
        raise ConfigError(
            "is an instrument preset, not a surface scenario; apply it to a result with "
            f"`warpe-cl instrument RESULT.nc --instrument {path}`, or name it in a scenario "
            "preset's instrument: block (docs/instrument.md)", key=args.preset)


def _instrument_sets(args) -> dict:
    """``--set KEY=VALUE`` of an instrument command as instrument keys (an ``instrument.``
    prefix, as in a scenario's block, is dropped)."""
    from .config.keys import parse_overrides
    return {k.removeprefix("instrument."): v for k, v in parse_overrides(args.set or []).items()}


def _load(args):
    from .config import load_preset
    return load_preset(args.preset, overrides=_overrides(args))   # a path or a bundled name


def _check_writable(path: Path, what: str):
    folder = Path(os.path.realpath(path)).parent
    if path.is_dir():
        raise ConfigError(f"{path} is a folder; give a file name", key=what)
    if not folder.exists():
        raise ConfigError(f"folder {folder} does not exist", key=what)
    if not os.access(folder, os.W_OK):
        raise ConfigError(f"cannot write in {folder}", key=what)


def _figure_formats() -> list:
    """The figure formats matplotlib writes here, by file extension (``png``, ``pdf``,
    ``svg``, ...); ``pgf`` only where its TeX program is installed."""
    import shutil
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    formats = set(FigureCanvasAgg.get_supported_filetypes())
    if shutil.which(str(matplotlib.rcParams.get("pgf.texsystem", "xelatex"))) is None:
        formats.discard("pgf")
    return sorted(formats)


def _check_figure_name(path: Path, what: str):
    """Bad input (exit 2) when ``path``'s extension is no figure format matplotlib writes:
    the format is taken from it."""
    formats = _figure_formats()
    ext = path.suffix.lower().removeprefix(".")
    if ext not in formats:
        said = f"'.{ext}' is not a figure format" if ext else "it has no extension"
        raise ConfigError(f"{path}: {said}; give a name ending in "
                          + ", ".join("." + f for f in formats)
                          + " (the format is taken from the extension)", key=what)


def _same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name the same file (links and hard links followed)."""
    try:
        if os.path.samefile(a, b):
            return True
    except OSError:        # one of them does not exist (yet)
        pass
    return os.path.realpath(a) == os.path.realpath(b)


def _check_new(path: Path, what: str, overwrite: bool, inputs=()):
    """Bad input (exit 2) when ``path`` is one of ``inputs`` (always, ``--overwrite`` or not),
    or exists without ``overwrite``."""
    for source in inputs:
        if source is not None and _same_file(path, Path(source)):
            raise ConfigError(f"{path} is an input of this command ({source}); give another "
                              "name (--overwrite never replaces an input)", key=what)
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise ConfigError(f"{path} exists; give --overwrite to replace it, or another name",
                          key=what)


def _check_outputs(args, inputs=()) -> Path:
    """``--out`` (returned) and ``--plot``, if given, can be written: bad input (exit 2)
    before any work.

    Each must name a file of its format (``--out`` ending in .nc, ``--plot`` in an extension
    matplotlib writes) in a folder that exists and can be written, must not be one of
    ``inputs`` (the files the command reads), and must not exist unless ``--overwrite``.
    """
    out = Path(args.out)
    if out.suffix.lower() != ".nc":
        raise ConfigError(f"{out} is not a NetCDF file name; give a name ending in .nc",
                          key="--out")
    _check_writable(out, "--out")
    _check_new(out, "--out", args.overwrite, inputs)
    if args.plot:
        plot = Path(args.plot)
        _check_figure_name(plot, "--plot")
        _check_writable(plot, "--plot")
        _check_new(plot, "--plot", args.overwrite, [*inputs, out])
    return out


def _inputs(*paths) -> list:
    """The paths among ``paths`` (None, strings, lists of strings) that exist: the files a
    command reads, which no output may replace."""
    found = []
    for p in paths:
        for q in (p if isinstance(p, (list, tuple)) else [p]):
            if q is not None and Path(q).exists():
                found.append(Path(q))
    return found


def _say(args):
    """print, flushed (a wrapper reading the lines, a GUI or a test sending Ctrl-C, sees them
    as printed), or nothing with ``--quiet``."""
    return (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))


class FigureError(WarpeError):
    """The result was written, its figure could not be drawn (exit 1)."""


def _write_outputs(ds, out: Path, plot, draw, say, started: float | None = None):
    """Write ``ds`` to ``out`` and, with ``plot``, ``draw(ds, path)`` to it; then say so.

    Each file is written whole or not at all (:class:`warpe_cl.io.Outputs`), the NetCDF file
    first: a stop (Ctrl-C, SIGTERM, even one whose exception was dropped) before it is renamed
    into place leaves no file, and the destinations as they were. The figure is drawn after,
    so that its failure never costs the result: :class:`FigureError` (exit 1) says the NetCDF
    file was written; a stop while drawing carries ``written`` (the NetCDF path) for the
    line that reports it. ``started`` (``time.perf_counter()``) adds the time taken in all,
    in s.
    """
    from .io import Outputs
    with Outputs() as outputs:
        outputs.netcdf(ds, out, key="--out")
        stops.check()               # a stop whose exception was dropped: nothing written
    say(f"wrote {out}" + ("" if started is None else
                          f" ({time.perf_counter() - started:.2f} s in all)"))
    if plot:
        _draw_figure(ds, out, plot, draw, say)


def _draw_figure(ds, out: Path, plot, draw, say):
    """``draw(ds, plot)``, written whole or not at all, after the result ``out`` was written:
    :class:`FigureError` (exit 1) says the result was kept; a stop while drawing carries
    ``written``."""
    from .io import Outputs
    try:
        with Outputs() as outputs:
            draw(ds, outputs.stage(plot))
            stops.check()
    except KeyboardInterrupt as err:
        err.written = (out, plot)
        raise
    except Exception as err:  # noqa: BLE001 - the result is kept; one line says so
        if os.environ.get("WARPE_CL_DEBUG"):
            raise
        raise FigureError(f"--plot: the figure {plot} could not be drawn ({one_line(err)}); "
                          f"the result {out} was written") from None
    say(f"wrote {plot}")


def cmd_run(args) -> int:
    from . import api, report
    from .plot import plot_waveform
    from .radiative import radiative_parameters

    from .catalog import resolve_preset
    _not_an_instrument(args)
    cfg = _load(args)
    out = _check_outputs(args, _inputs(resolve_preset(args.preset)))
    points = cfg.sweep_points()
    for _, pcfg in points:
        radiative_parameters(pcfg)    # bad input fails (exit 2) before a device is sought
    engine = api.get_engine(args.device)   # no usable device fails (exit 3) before any output
    say = _say(args)
    say(report.run_header(cfg, len(points)))
    t0 = time.perf_counter()

    def before(i, point, pcfg):
        if point:
            say(f"scenario {i}: " + report.point_text(point))
        for line in report.derived_lines(radiative_parameters(pcfg)):
            say(line)

    def after(ds):
        for line in report.scenario_lines(ds, getattr(engine, "last_build_s", 0.0),
                                          getattr(engine, "last_walk_s", None)):
            say(line)

    ds = api.simulate(cfg, device=args.device, progress=None if not args.quiet else False,
                      before_point=before, after_point=after)
    if cfg.get("instrument.name"):   # applied by simulate, scenario by scenario
        for line in report.instrument_lines(ds):
            say(line)
    _write_outputs(ds, out, args.plot, plot_waveform, say, started=t0)
    return EXIT_OK


def cmd_instrument(args) -> int:
    from . import report
    from .instrument import apply_instrument, check_parameter, load_instrument
    from .database import load_result
    from .instrument.plot import plot_instrument
    overrides = _instrument_sets(args)
    if args.altitude is not None:
        overrides["geometry.altitude"] = args.altitude
    if args.roughness is not None:
        overrides["geometry.roughness"] = args.roughness
    params = load_instrument(args.instrument, overrides, override_source="command line")
    # the instrument's own limits (shots in [1, 1e6], seed in [0, 2^63 - 1]), before reading
    shots = None if args.shots is None else check_parameter("shots", args.shots, where="--shots")
    seed = None if args.seed is None else check_parameter("seed", args.seed, where="--seed")
    out = _check_outputs(args, _inputs(args.file, args.instrument))
    path = Path(args.file)
    ds = load_result(path)
    say = _say(args)
    ds = apply_instrument(ds, params, shots=shots, seed=seed, source=str(path))
    for line in report.instrument_lines(ds):
        say(line)
    _write_outputs(ds, out, args.plot, plot_instrument, say)
    return EXIT_OK


def cmd_invert(args) -> int:
    """``warpe-cl invert``: recorded shots + a sweep database -> FIT.nc (docs/inversion.md);
    with several ``--database``, one FIT file per database and their ranking by log evidence
    (docs/inversion.md §5.4)."""
    from . import report
    from .inversion.checks import check_lines
    from .inversion.invert import invert
    from .inversion.observed import load_observed
    from .inversion.plot import plot_fit
    databases = list(args.database)
    instruments = list(args.instrument or [])
    inputs = _inputs(args.observed, databases, instruments)
    if args.joint:
        return _invert_joint(args, databases, instruments, inputs)
    if len(instruments) > 1:
        raise ConfigError(f"--instrument given {len(instruments)} times: one instrument for "
                          "the observed shots (one per observed file with --joint)",
                          key="--instrument")
    if len(databases) > 1:
        return _invert_many(args, databases, inputs)
    out = _check_outputs(args, inputs)
    scenario = _scenario(args)
    free, fix, truth = _fit_options(args)
    jobs = _jobs(args)
    t0 = time.perf_counter()
    obs = load_observed(args.observed, scenario=scenario)
    ds = invert(obs, databases[0], instruments[0] if instruments else None, free=free, fix=fix,
                truth=truth, jobs=jobs)
    say = _say(args)
    for line in report.inversion_lines(ds) + check_lines(ds) + _fixed_lines(ds):
        say(line)
    _write_outputs(ds, out, args.plot, plot_fit, say, started=t0)
    return EXIT_OK


def cmd_design(args) -> int:
    """``warpe-cl design STUDY.yaml --out DIR``: expected posterior widths of surface families
    for candidate instruments (docs/design.md)."""
    from .design.run import run_study
    say = _say(args)
    t0 = time.perf_counter()
    done = run_study(args.study, args.out, overwrite=args.overwrite, say=say, quiet=args.quiet,
                     device=args.device)
    for line in done["summary"].splitlines():
        say(line)
    for path in done["files"]:
        say(f"wrote {path}")
    say(f"expected widths in {done['elapsed_s']:.2f} s ({time.perf_counter() - t0:.2f} s in "
        "all)")
    return EXIT_OK


def _scenario(args):
    """``--scenario`` as an index, or None."""
    if args.scenario is None:
        return None
    try:
        return int(args.scenario)
    except ValueError:
        raise ConfigError(f"{args.scenario!r} is not a scenario index (an integer >= 0)",
                          key="--scenario") from None


def _jobs(args) -> int:
    """``--jobs`` of ``invert`` as a number of worker processes (default: the CPUs this
    process may use)."""
    from .cpus import allocated_cpus
    if args.jobs is None:
        return allocated_cpus()
    try:
        jobs = int(args.jobs)
    except ValueError:
        jobs = 0
    if jobs < 1:
        raise ConfigError(f"{args.jobs!r} is not a number of worker processes (an integer "
                          ">= 1)", key="--jobs")
    return jobs


def _invert_many(args, databases, inputs) -> int:
    """``warpe-cl invert OBS --database A --database B ...``: one FIT file per database,
    ``--out`` FIT.nc giving FIT_<label>.nc (and ``--plot`` likewise), every one checked before
    any work as ``--out`` is; then the ranking by log evidence."""
    from . import report
    from .inversion.checks import check_lines
    from .inversion.comparison import compare, labels, ranking, ranking_lines
    from .inversion.observed import load_observed
    outs, plots = _labelled_outputs(args, labels(databases), inputs)
    free, fix, truth = _fit_options(args)
    jobs = _jobs(args)
    t0 = time.perf_counter()
    obs = load_observed(args.observed, scenario=_scenario(args))
    fits = compare(obs, databases, args.instrument[0] if args.instrument else None, free=free,
                   fix=fix, truth=truth, jobs=jobs)
    say = _say(args)
    lines = [line for ds in fits for line in report.inversion_lines(ds) + check_lines(ds)]
    lines += [printable(line) for line in ranking_lines(ranking(fits))]
    _write_labelled(fits, outs, plots, lines, say)
    say(f"compared {len(fits)} databases in {time.perf_counter() - t0:.2f} s")
    return EXIT_OK


def _invert_joint(args, databases, instruments, inputs) -> int:
    """``warpe-cl invert A.nc B.nc --database DB_A --database DB_B --joint``: the shots of one
    surface by several instruments or at several wavelengths, each file against its own
    database (in the order given), inverted together (docs/inversion.md §5.5); one FIT file
    per channel, ``--out`` FIT.nc giving FIT_<label>.nc."""
    from . import report
    from .inversion.checks import check_lines
    from .inversion.comparison import labels
    from .inversion.joint import check_counts, invert_joint
    observed = list(args.observed)
    if args.scenario is not None:
        raise ConfigError("--scenario picks one scenario of one file; with --joint give one "
                          "single-scenario file per channel", key="--scenario")
    check_counts(len(observed), len(databases), len(instruments))   # before any output check
    names = labels([Path(o).stem + "_" + Path(str(d).rstrip("/\\")).name
                    for o, d in zip(observed, databases)])
    outs, plots = _labelled_outputs(args, names, inputs)
    free, fix, truth = _fit_options(args)
    fits = invert_joint(observed, databases, instruments or None, free=free, fix=fix,
                        truth=truth, names=databases, jobs=_jobs(args))
    lines = report.joint_lines(fits, [check_lines(ds) for ds in fits]) + _fixed_lines(fits[0])
    _write_labelled(fits, outs, plots, lines, _say(args))
    return EXIT_OK


def _fit_options(args) -> tuple:
    """``--free``, ``--fix`` and ``--truth`` of ``invert`` as :func:`warpe_cl.invert` takes
    them: (keys or None, key -> value, key -> value or None)."""
    from .config.keys import parse_overrides
    free = [k.strip() for k in ",".join(args.free or []).split(",") if k.strip()] or None
    fix = parse_overrides(args.fix or [])
    truth = parse_overrides(args.truth or []) if args.truth else None
    return free, fix, truth


def _fixed_lines(ds) -> list:
    """Each ``--fix`` echoed with its unit, as it was read (FIT.nc attribute ``fixed``): one
    line, or none."""
    import json
    held = json.loads(ds.attrs.get("fixed", "{}"))
    return [printable("  fixed: " + ", ".join(f"{k} = {v}" for k, v in held.items()))] \
        if held else []


def _labelled_outputs(args, names, inputs) -> tuple:
    """``--out`` FIT.nc (and ``--plot``) as one file per label, FIT_<label>.nc, every one
    checked before any work as ``--out`` is: (outputs, figures or Nones)."""
    from .inversion.comparison import output_paths
    if Path(args.out).suffix.lower() != ".nc":         # the pattern: its format and folder
        raise ConfigError(f"{args.out} is not a NetCDF file name; give a name ending in .nc",
                          key="--out")
    _check_writable(Path(args.out), "--out")
    if args.plot:
        _check_figure_name(Path(args.plot), "--plot")
        _check_writable(Path(args.plot), "--plot")
    outs = output_paths(args.out, names)
    plots = output_paths(args.plot, names) if args.plot else [None] * len(outs)
    for out, plot in zip(outs, plots):          # each file: not an input, new or --overwrite
        _check_new(out, "--out", args.overwrite, inputs)
        if plot is not None:
            _check_new(plot, "--plot", args.overwrite, [*inputs, out])
    return outs, plots


def _write_labelled(fits, outs, plots, lines, say) -> None:
    """Say ``lines``, write every FIT file, then draw the figures (a figure's failure costs
    no result)."""
    from .inversion.plot import plot_fit
    for line in lines:
        say(line)
    for ds, out in zip(fits, outs):
        _write_outputs(ds, out, None, plot_fit, say)
    failed = []
    for ds, out, plot in zip(fits, outs, plots):
        if plot is None:
            continue
        try:
            _draw_figure(ds, out, plot, plot_fit, say)
        except FigureError as err:
            failed.append(str(err))
    if failed:
        raise FigureError("; ".join(failed))


def cmd_sweep(args) -> int:
    """``warpe-cl sweep``: a grid as a resumable database (warpe_cl/sweep.py, docs/cluster.md).

    Exit codes: 0 every scenario of this run (this shard) is done; 1 some failed (each is
    recorded in the manifest with its error) or did not finish; 2 bad input found before any
    scenario ran; 3 no usable device.
    """
    from . import report
    from .sweep import parse_shard, run_sweep
    from .catalog import resolve_preset
    _not_an_instrument(args)
    shard = parse_shard(args.shard)
    say = _say(args)
    summary = run_sweep(resolve_preset(args.preset), args.out, overrides=_overrides(args),
                        shard=shard, scheduler=args.scheduler, resume=args.resume,
                        device=args.device, quiet=args.quiet, say=say,
                        overwrite=args.overwrite)
    for line in report.sweep_summary_lines(summary):
        say(line)
    return summary.exit_code


def cmd_devices(args) -> int:
    from . import report
    from .device import INSTALL_HINT, list_devices, probe, resolve_spec
    from .qualify import qualification, select_device
    from .drivers import unregistered_gpu_hint
    devices = list_devices()
    hint = unregistered_gpu_hint(any(info.kind == "gpu" for info, _ in devices))
    if not devices:
        print(f"no OpenCL platform found; {INSTALL_HINT}")
        if hint:
            print(hint)
        return EXIT_DEVICE
    if args.requalify:
        from .qualify import VerdictCache
        VerdictCache().clear()
    for info, dev in devices:
        print(info.describe(), flush=True)          # before the probe and qualification
        reason = probe(dev)
        status = qualification(info) if reason is None else None
        for line in report.device_status_lines(reason, status):
            print(line)
        if status is not None:
            _print_all_verdicts(info, check=args.all and status.usable)
    if hint:
        print(hint)
    spec = resolve_spec(args.device)
    try:
        info, _ = select_device(spec)
        print(report.device_choice_line(spec, info))
    except DeviceError as err:
        print(err)
        return EXIT_DEVICE
    return EXIT_OK


def _print_all_verdicts(info, check: bool = False):
    """Every kernel combination's verdicts, one line each, printed as soon as it is known:
    its widest qualified lane width, the widths that failed, those not checked yet. Plain
    ``devices`` shows what is cached and checks nothing (it stays cheap); ``check``
    (``devices --all``) checks the widths not known yet."""
    from . import report
    from .qualify import all_combos, qualifier_for
    q = qualifier_for(info)
    for combo in all_combos(info.fp64):
        choice = q.choose(combo, check=check)
        print(report.verdict_line(combo, choice.lanes, choice.failures, choice.unchecked),
              flush=True)


def cmd_show_config(args) -> int:
    from . import report
    from .radiative import radiative_parameters
    instrument = _instrument_preset(args.preset)
    if instrument is not None:     # its resolved parameters (a base: filled in), with units
        from .instrument import load_instrument
        params = load_instrument(str(instrument), _instrument_sets(args),
                                 override_source="command line")
        print(f"# instrument preset {instrument}")
        for key, value in params.readable().items():
            print(f"{key}: {value}")
        return EXIT_OK
    cfg = _load(args)
    # what does not apply is not shown: a granular medium has no interfaces
    granular = all(pcfg.get("medium.texture") == "granular" for _, pcfg in cfg.sweep_points())
    print(cfg.to_yaml(omit=("medium.bottom_interface",) if granular else ()).rstrip())
    for point, pcfg in cfg.sweep_points():
        print("# derived" + (" for " + report.point_text(point) if point else ""))
        for line in report.derived_lines(radiative_parameters(pcfg)):
            print("#" + line)
    return EXIT_OK


def cmd_presets(args) -> int:
    import yaml
    from .catalog import bundled_preset, bundled_presets
    presets = bundled_presets()
    if args.show:        # its text, comments included, to copy and edit
        path = bundled_preset(args.show, presets)
        if path is None:
            import difflib
            name = args.show.removeprefix("presets/").removesuffix(".yaml")
            hint = difflib.get_close_matches(name, list(presets), n=1)
            raise ConfigError(f"{args.show!r} is not a bundled preset"
                              + (f" (did you mean {hint[0]}?)" if hint else "")
                              + "; `warpe-cl presets` lists them", key="--show")
        print(path.read_text().rstrip())
        return EXIT_OK
    for name, path in presets.items():
        try:
            desc = " ".join(str(yaml.safe_load(path.read_text()).get("description", "")).split())
        except Exception:  # noqa: BLE001 - a listing must not stop on one bad file
            desc = "(unreadable)"
        print(f"{name:34s} {desc[:100]}")
    return EXIT_OK


def _after_times(values) -> list:
    """The times of ``plot --after`` in ns: quantities with a unit (``"10 ns"``), the option
    repeated or the times joined by commas; bad input (exit 2) otherwise."""
    from .units import UnitError, parse_quantity
    times = []
    for text in values or []:
        for part in filter(None, (p.strip() for p in str(text).split(","))):
            try:
                times.append(parse_quantity(part, "time"))
            except UnitError as err:
                raise ConfigError(str(err), key="--after") from None
    return times


def _metrics_drawer(args, path: Path):
    """``plot --metrics``: the function drawing the metrics figure; ``--kind waveform`` picks
    the surface's numbers, ``--kind instrument`` those after the chain (docs/interface.md §2)."""
    from .plot import plot_metrics
    if args.kind == "angular":
        raise ConfigError("--metrics draws the waveform metrics: give --kind waveform (the "
                          "surface's), --kind instrument (after the chain) or no --kind",
                          key="--kind")
    stage = {"waveform": "surface", "instrument": "instrument"}.get(args.kind)
    after = _after_times(args.after)

    def draw(ds, out):
        try:
            return plot_metrics(ds, out, after=after, stage=stage)
        except ConfigError as err:
            raise err.with_source(str(path)) from None
    return draw


def cmd_plot(args) -> int:
    from .database import load_result
    from .io import Outputs
    from .plot import plot_angular, plot_waveform
    path = Path(args.file)
    out = Path(args.out)
    _check_figure_name(out, "--out")
    _check_writable(out, "--out")
    _check_new(out, "--out", args.overwrite, _inputs(path))
    if args.after and not args.metrics:
        raise ConfigError("applies to --metrics only", key="--after")
    ds = load_result(path)           # a file, or a sweep database folder
    if args.scenarios is not None:
        from .plot import select_scenarios
        ds = select_scenarios(ds, args.scenarios)
    kind = args.kind or ("instrument" if "received_reflectance" in ds else "waveform")
    if args.metrics:
        draw = _metrics_drawer(args, path)
    elif kind == "instrument":
        if "received_reflectance" not in ds:
            raise ConfigError("has no instrument variables; give a file written by "
                              "`warpe-cl instrument`", key=str(path))
        from .instrument.plot import plot_instrument as draw
    else:
        if "reflectance" not in ds:
            raise ConfigError("has no reflectance variable; give a file written by "
                              "`warpe-cl run`", key=str(path))
        draw = plot_angular if kind == "angular" else plot_waveform
    with Outputs() as outputs:
        draw(ds, outputs.stage(out))
        stops.check()
    print(f"wrote {out}")
    return EXIT_OK


def make_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="warpe-cl", description="Laser travel time in icy and granular surfaces "
                                             "(Monte Carlo in OpenCL).")
    from .io import package_version
    p.add_argument("--version", action="version", version=f"warpe-cl {package_version()}")
    sub = p.add_subparsers(dest="verb", parser_class=_Parser)

    def common(sp, device=True):
        sp.add_argument("preset", help="a preset file, or a bundled preset's name (see `presets`)")
        sp.add_argument("--set", action="append", metavar="KEY=VALUE",
                        help='override a key, e.g. --set medium.thickness="100 mm" (repeatable)')
        if device:
            sp.add_argument("--device", default=None,
                            help="auto, cpu, gpu, P:D, a name substring, or numpy "
                                 "(default: $WARPE_CL_DEVICE, $PYOPENCL_CTX, auto)")

    r = sub.add_parser("run", help="simulate a preset and write a NetCDF file")
    common(r)
    r.add_argument("--photons", help="rays per scenario (simulation.photons)")
    r.add_argument("--seed", help="random seed (simulation.seed)")
    r.add_argument("--out", required=True, help="output NetCDF file")
    r.add_argument("--plot", help="also draw the waveform to this figure (PNG, PDF, SVG, ...: "
                                  "the format is taken from the extension)")
    r.add_argument("--overwrite", action="store_true",
                   help="replace --out and --plot files that exist (never an input)")
    r.add_argument("--quiet", action="store_true", help="print nothing but errors")
    r.set_defaults(func=cmd_run)

    sw = sub.add_parser("sweep", help="run a preset's sweep grid as a resumable database "
                                      "(one file per scenario; shards; Dask)")
    common(sw, device=False)
    sw.add_argument("--device", default=None,
                    help="as for run; or a comma-separated list (0:0,0:1), or all (every GPU): "
                         "one worker process per device")
    sw.add_argument("--out", required=True,
                    help="database folder (or X.nc: scenarios in X.sweep/, all of them "
                         "combined in X.nc once the grid is complete)")
    sw.add_argument("--shard", metavar="I/N",
                    help="run only the scenarios i with i %% N == I (job arrays)")
    sw.add_argument("--scheduler", metavar="ADDRESS",
                    help="Dask scheduler address, or local:N for N local worker processes "
                         "(needs pip install 'warpe-cl[cluster]')")
    sw.add_argument("--resume", action="store_true",
                    help="keep the scenarios already in the folder, compute the rest")
    sw.add_argument("--overwrite", action="store_true",
                    help="--out X.nc: replace an existing X.nc that is not this grid's "
                         "combined file, once the grid is complete (refused otherwise)")
    sw.add_argument("--photons", help="rays per scenario (simulation.photons)")
    sw.add_argument("--seed", help="random seed (simulation.seed)")
    sw.add_argument("--quiet", action="store_true", help="print nothing but errors")
    sw.set_defaults(func=cmd_sweep)

    d = sub.add_parser("devices", help="list OpenCL devices, their qualification (a known-answer "
                       "walk against the NumPy reference) and the one `auto` picks")
    d.add_argument("--device", default=None, help="a device spec to resolve")
    d.add_argument("--all", action="store_true",
                   help="qualify and show every kernel combination (texture, precision, mode)")
    d.add_argument("--requalify", action="store_true",
                   help="forget every cached verdict and check the devices again")
    d.set_defaults(func=cmd_devices)

    s = sub.add_parser("show-config", help="print the resolved configuration and derived parameters")
    common(s, device=False)
    s.set_defaults(func=cmd_show_config)

    ps = sub.add_parser("presets", help="list the bundled presets")
    ps.add_argument("--show", metavar="NAME",
                    help="print a bundled preset's YAML text (to copy: > my.yaml)")
    ps.set_defaults(func=cmd_presets)

    pl = sub.add_parser("plot", help="draw the waveform of a result file")
    pl.add_argument("file", help="a NetCDF file written by `warpe-cl run` or `instrument`, or a "
                                 "database folder written by `warpe-cl sweep`")
    pl.add_argument("--scenarios", default=None, metavar="SEL",
                    help="draw only these scenarios: indices 0,3,5, a range 0:4 (4 excluded), "
                         "or a swept value medium.thickness=10mm")
    pl.add_argument("--out", required=True, help="output figure (PNG, PDF, SVG, ...: the "
                                                 "format is taken from the extension)")
    pl.add_argument("--overwrite", action="store_true",
                    help="replace an --out file that exists (never the input)")
    pl.add_argument("--kind", choices=("waveform", "angular", "instrument"), default=None,
                    help="waveform: reflectance against time; angular: the FOV figure; "
                         "instrument: the paper's three-panel BELA figure (default for a file "
                         "written by `warpe-cl instrument`, else waveform)")
    pl.add_argument("--metrics", action="store_true",
                    help="draw the waveform metrics instead (mean delay, RMS width, peak time "
                         "with their standard errors) against the swept value or the scenario; "
                         "after the instrument chain for a file written by `instrument` "
                         "(--kind waveform: the surface's)")
    pl.add_argument("--after", action="append", metavar="T",
                    help='with --metrics, also the fraction returned after T, e.g. "10 ns" '
                         "(repeatable, or T1,T2)")
    pl.set_defaults(func=cmd_plot)

    ins = sub.add_parser("instrument", help="what an instrument records from a surface result")
    ins.add_argument("file", help="a NetCDF file written by `warpe-cl run`")
    ins.add_argument("--instrument", required=True,
                     help="bela, gala, atlas, or an instrument YAML file")
    ins.add_argument("--set", action="append", metavar="KEY=VALUE",
                     help='override an instrument key, e.g. --set transmitter.pulse_fwhm="3 ns" '
                          "(repeatable; dotted keys as in an instrument preset)")
    ins.add_argument("--altitude", help='spacecraft altitude, e.g. "500 km" or 500km')
    ins.add_argument("--roughness", help='facet roughness, e.g. "0.1 deg" or 0.1deg')
    ins.add_argument("--shots", help="shots to simulate (default: the instrument's)")
    ins.add_argument("--seed", help="noise seed (default: the surface result's)")
    ins.add_argument("--out", required=True, help="output NetCDF file (surface + instrument)")
    ins.add_argument("--plot", help="also draw the three-panel figure to this figure file "
                                    "(PNG, PDF, SVG, ...)")
    ins.add_argument("--overwrite", action="store_true",
                     help="replace --out and --plot files that exist (never the input)")
    ins.add_argument("--quiet", action="store_true", help="print nothing but errors")
    ins.set_defaults(func=cmd_instrument)

    inv = sub.add_parser("invert", help="the surface parameters compatible with recorded "
                                        "shots, from a sweep database")
    inv.add_argument("observed", nargs="+",
                     help="a `warpe-cl instrument` file, or CSV files of samples "
                          "(docs/interface.md §5.7)")
    inv.add_argument("--database", required=True, action="append",
                     help="a `warpe-cl sweep` database folder (or sweep file); repeated, the "
                          "shots are inverted against each and the databases ranked by log "
                          "evidence")
    inv.add_argument("--out", required=True,
                     help="output NetCDF file (FIT.nc); with several --database, FIT_<label>.nc "
                          "per database (label: the database's name)")
    inv.add_argument("--plot", help="also draw the fit and the pairwise posterior to this "
                                    "figure file (PNG, PDF, SVG, ...)")
    inv.add_argument("--overwrite", action="store_true",
                     help="replace --out and --plot files that exist (never an input)")
    inv.add_argument("--instrument", action="append",
                     help="bela, gala, atlas, or an instrument YAML file (default: the observed "
                          "file's instrument); with --joint, one per observed file")
    inv.add_argument("--joint", action="store_true",
                     help="the observed files are shots of one surface by several instruments "
                          "or at several wavelengths: invert them together, the i-th file "
                          "against the i-th --database (the same swept keys and nodes), "
                          "writing FIT_<label>.nc per file")
    inv.add_argument("--free", action="append", metavar="KEY[,KEY...]",
                     help="swept keys to report (default: all not fixed; the others are "
                          "marginalised)")
    inv.add_argument("--fix", action="append", metavar="KEY=VALUE",
                     help='hold a swept key, e.g. --fix medium.compacity=0.5 or '
                          'medium.thickness="500 mm" (a quantity needs its unit, as for run '
                          '--set), or a nuisance: amplitude=1, pulse_fwhm="6.5 ns" (repeatable)')
    inv.add_argument("--truth", action="append", metavar="KEY=VALUE",
                     help='the true value of a swept key, shown in the summary, FIT.nc and the '
                          'figure, never used by the fit, e.g. --truth medium.thickness="10 mm" '
                          "(default: the observed file's own configuration; repeatable)")
    inv.add_argument("--scenario", help="the scenario of an instrument file holding a sweep")
    inv.add_argument("--jobs", metavar="N",
                     help="worker processes the grid's points are spread over (Linux; default: "
                          "the CPUs this process may use); the result is the same with any N")
    inv.add_argument("--quiet", action="store_true", help="print nothing but errors")
    inv.set_defaults(func=cmd_invert)

    de = sub.add_parser("design", help="expected posterior widths of surface families for "
                                       "candidate instruments (an instrument-design study)")
    de.add_argument("study", help="a design study YAML file (docs/design.md)")
    de.add_argument("--out", required=True,
                    help="output folder: design.nc, summary.txt and the figures")
    de.add_argument("--overwrite", action="store_true",
                    help="replace the files of an earlier study in --out")
    de.add_argument("--device", default=None,
                    help="device of the sweeps of families given by a preset (as for sweep)")
    de.add_argument("--quiet", action="store_true", help="print nothing but errors")
    de.set_defaults(func=cmd_design)
    return p


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    print(printable(f"warpe-cl: warning: {message}"), file=sys.stderr)


def _error(text: str) -> None:
    """Print ``warpe-cl: error: TEXT`` as one inert, bounded line on stderr."""
    print(printable(f"warpe-cl: error: {text}"), file=sys.stderr)


def _stopped(err: KeyboardInterrupt) -> int:
    """The one line of a stop (Ctrl-C or SIGTERM) and its exit code; the stop is forgotten
    (:func:`warpe_cl.stops.clear`) once said."""
    term = isinstance(err, Terminated) or stops.pending() == signal.SIGTERM
    summary = getattr(err, "summary", None)
    written = getattr(err, "written", None)
    line = "warpe-cl: stopped by SIGTERM" if term else "warpe-cl: interrupted"
    if summary is not None:
        line += (f" after {summary.done + summary.skipped} of {summary.owned} scenarios; run "
                 "the same command with --resume to go on")
    elif written is not None:
        line += f" while drawing {written[1]}; the result {written[0]} was written"
    print(printable(line), file=sys.stderr)
    stops.clear()
    return EXIT_SIGTERM if term else EXIT_SIGINT



def main(argv=None) -> int:
    """Run ``warpe-cl`` with ``argv`` (``sys.argv[1:]`` by default); returns the exit code.

    Everything, the imports of the verb's modules included, runs with SIGINT and SIGTERM
    routed through :mod:`warpe_cl.stops`, so that every stop, even one whose exception Python
    dropped in a ``__del__``, ends the command with its one line and 130 or 143.
    """
    previous = {}
    try:
        previous = stops.install()
        import warnings
        warnings.showwarning = _one_line_warning
        parser = make_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "verb", None):
            parser.print_help()
            return EXIT_INPUT
        code = args.func(args)
        stops.check()           # a stop whose exception was dropped on the way: said
        return code
    except ConfigError as err:
        _error(err)
        return EXIT_INPUT
    except DeviceError as err:
        _error(err)
        return EXIT_DEVICE
    except KeyboardInterrupt as err:    # Ctrl-C, or SIGTERM (Terminated)
        return _stopped(err)
    except WarpeError as err:
        _error(err)
        return EXIT_OTHER
    except SystemExit:                  # --help, --version
        raise
    except BaseException as err:  # noqa: BLE001 - one line, never a traceback
        if os.environ.get("WARPE_CL_DEBUG"):
            raise
        _error(f"{type(err).__name__}: {' '.join(str(err).split())} "
               "(set WARPE_CL_DEBUG=1 for the traceback)")
        return EXIT_OTHER
    finally:
        stops.restore(previous)


if __name__ == "__main__":
    sys.exit(main())
