"""The ``warpe-cl`` command line (interface.md §2).

Exit codes: 0 success; 2 bad input (configuration, units, files); 3 no usable OpenCL
device; 1 anything else. Errors are one readable line on stderr, never a traceback
(``WARPE_CL_DEBUG=1`` shows it).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from .errors import ConfigError, DeviceError, WarpeError

EXIT_OK, EXIT_OTHER, EXIT_INPUT, EXIT_DEVICE = 0, 1, 2, 3


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


def _load(args):
    from .config import load_preset
    from .catalog import resolve_preset
    return load_preset(resolve_preset(args.preset), overrides=_overrides(args))


def _check_writable(path: Path, what: str):
    folder = path.resolve().parent
    if path.is_dir():
        raise ConfigError(f"{path} is a folder; give a file name", key=what)
    if not folder.exists():
        raise ConfigError(f"folder {folder} does not exist", key=what)
    if not os.access(folder, os.W_OK):
        raise ConfigError(f"cannot write in {folder}", key=what)


def _fmt_derived(d: dict) -> list:
    return [
        f"  tau0              {d['tau0']:.6g}",
        f"  omega             {d['omega']:.6g}",
        f"  extinction        {d['extinction_per_m']:.6g} m-1",
        f"  n_eff, k_eff      {d['n_eff']:.6g}, {d['k_eff']:.4g}",
        f"  thickness         {d['thickness_m'] * 1e3:.6g} mm",
        f"  first BF time     {d['first_bf_time_ns']:.6g} ns  (2 h n_eff / c)",
        f"  specular R0       {d['specular_r0']:.6g}",
    ] + ([f"  porosity factor   {d['porosity_factor']:.6g}   matrix absorption "
          f"{d['matrix_absorption_per_m']:.6g} m-1"] if "porosity_factor" in d else []) + [
        f"  {sp['material']:<8s}          rho_v {sp['proportion']:.4g}  d {sp['grain_size_m'] * 1e6:.4g} um"
        f"  N {sp['number_density_per_m3']:.4g} m-3  n_rel {sp['n_rel']:.5g}  w {sp['w']:.6g}"
        for sp in d.get("species", [])]


def cmd_run(args) -> int:
    from . import api, io
    from .radiative import radiative_parameters

    cfg = _load(args)
    out = Path(args.out)
    _check_writable(out, "--out")
    if args.plot:
        _check_writable(Path(args.plot), "--plot")
    points = cfg.sweep_points()
    for _, pcfg in points:
        radiative_parameters(pcfg)    # bad input fails (exit 2) before a device is sought
    api.get_engine(args.device)       # no usable device fails (exit 3) before any output
    # flushed: a wrapper reading the lines (a GUI, a test sending Ctrl-C) sees them as printed
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    say(f"warpe-cl run: {cfg.get('name')} ({cfg.source}), {len(points)} scenario(s), "
        f"{int(cfg.get('simulation.photons')):,} rays each, seed {cfg.get('simulation.seed')}")
    t0 = time.perf_counter()

    def before(i, point, pcfg):
        if point:
            say(f"scenario {i}: " + ", ".join(f"{k}={v}" for k, v in point.items()))
        for line in _fmt_derived(radiative_parameters(pcfg)):
            say(line)

    ds = api.simulate(cfg, device=args.device, progress=None if not args.quiet else False,
                      before_point=before, after_point=lambda d: _print_summary(d, say))
    if cfg.get("instrument.name"):   # applied by simulate, scenario by scenario
        _print_instrument(ds, say)
    # The file and the figure are written all or nothing: Ctrl-C or an error while writing
    # either leaves neither (nor a temporary file), and the destinations as they were.
    with io.Outputs() as outputs:
        outputs.netcdf(ds, out)
        if args.plot:
            from .plot import plot_waveform
            plot_waveform(ds, outputs.stage(args.plot))
    say(f"wrote {out} ({time.perf_counter() - t0:.2f} s in all)")
    if args.plot:
        say(f"wrote {args.plot}")
    return EXIT_OK


def _print_summary(ds, say):
    photons = int(ds["photons"])
    wall = float(ds["wall_time"])
    events = int(ds["scattering_events"])
    say(f"  device            {ds.attrs.get('opencl_device', '?')} ({ds.attrs.get('engine')}, "
        f"{ds.attrs.get('precision')} precision)")
    say("  fates             " + "  ".join(
        f"{f} {v:.5f}" for f, v in zip(ds["fate"].values, ds["fate_fraction"].values)))
    say("  components        " + "  ".join(
        f"{c} {v:.5f}" for c, v in zip(ds["component"].values, ds["fraction"].values)))
    say(f"  time              {wall:.2f} s   {photons / wall:,.0f} photons/s   "
        f"{events / wall:,.0f} scattering events/s")


def _print_instrument(ds, say):
    import numpy as np
    from .instrument.plot import cases_of
    say(f"instrument {ds.attrs.get('instrument_name')}: altitude "
        f"{ds.attrs.get('instrument_geometry_altitude')}, roughness "
        f"{ds.attrs.get('instrument_geometry_roughness')}, {ds.sizes.get('shot', 0)} shots")
    for label, sc in cases_of(ds):
        parts = "  ".join(f"{p} {v:.3g}" for p, v in zip(sc["part"].values,
                                                       sc["photons_at_aperture"].values))
        say(f"  {label or 'scenario'}")
        say(f"    photons at aperture   {parts}")
        if "signal_mv" in sc:
            say(f"    expected peak         {float(sc['expected_analog_mv'].max()):.4g} mV (unclipped), "
                f"noise {float(sc['noise_mv']):.3g} mV, saturated shots "
                f"{float(sc['saturated'].mean()):.2f}")
        else:
            say(f"    photons recorded      {float(sc['photon_count'].mean()):.3g} per shot")
        say(f"    detected              {float(sc['detected'].mean()):.2f} of shots; range "
            f"{float(np.nanmean(sc['range_time'])) if sc['detected'].any() else float('nan'):.3g} ns, "
            f"width {float(np.nanmean(sc['pulse_width'])) if sc['detected'].any() else float('nan'):.3g} ns")


def _load_result(path: Path):
    import xarray as xr
    if not path.is_file():
        raise ConfigError("no such file", key=str(path))
    try:
        return xr.load_dataset(path, engine="h5netcdf")
    except Exception as err:  # noqa: BLE001
        raise ConfigError(f"not a warpe-cl NetCDF file ({type(err).__name__})", key=str(path))


def cmd_instrument(args) -> int:
    from . import io
    from .instrument import apply_instrument, check_parameter, load_instrument
    overrides = {}
    if args.altitude is not None:
        overrides["geometry.altitude"] = args.altitude
    if args.roughness is not None:
        overrides["geometry.roughness"] = args.roughness
    params = load_instrument(args.instrument, overrides, override_source="command line")
    # the instrument's own limits (shots in [1, 1e6], seed in [0, 2^63 - 1]), before reading
    shots = None if args.shots is None else check_parameter("shots", args.shots, where="--shots")
    seed = None if args.seed is None else check_parameter("seed", args.seed, where="--seed")
    path = Path(args.file)
    ds = _load_result(path)
    out = Path(args.out)
    _check_writable(out, "--out")
    if args.plot:
        _check_writable(Path(args.plot), "--plot")
    say = (lambda *a: None) if args.quiet else print
    ds = apply_instrument(ds, params, shots=shots, seed=seed, source=str(path))
    _print_instrument(ds, say)
    with io.Outputs() as outputs:           # all or nothing, as for run
        outputs.netcdf(ds, out)
        if args.plot:
            from .instrument.plot import plot_instrument
            plot_instrument(ds, outputs.stage(args.plot))
    say(f"wrote {out}")
    if args.plot:
        say(f"wrote {args.plot}")
    return EXIT_OK


def cmd_sweep(args) -> int:
    """``warpe-cl sweep``: a grid as a resumable database (warpe_cl/sweep.py, docs/cluster.md).

    Exit codes: 0 every scenario of this run (this shard) is done; 1 some failed (each is
    recorded in the manifest with its error) or did not finish; 2 bad input found before any
    scenario ran; 3 no usable device.
    """
    from .sweep import parse_shard, run_sweep, summary_lines
    from .catalog import resolve_preset
    shard = parse_shard(args.shard)
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    summary = run_sweep(resolve_preset(args.preset), args.out, overrides=_overrides(args),
                        shard=shard, scheduler=args.scheduler, resume=args.resume,
                        device=args.device, quiet=args.quiet, say=say)
    for line in summary_lines(summary):
        say(line)
    return summary.exit_code


def cmd_devices(args) -> int:
    from .device import INSTALL_HINT, list_devices, probe, qualification, resolve_spec, select_device
    devices = list_devices()
    if not devices:
        print(f"no OpenCL platform found; {INSTALL_HINT}")
        return EXIT_DEVICE
    if args.requalify:
        from .qualify import VerdictCache
        VerdictCache().clear()
    for info, dev in devices:
        print(info.describe(), flush=True)
        reason = probe(dev)
        if reason is not None:
            print(f"      NOT usable: {reason}")
            continue
        status = qualification(info)
        if not status.usable:
            print(f"      NOT usable: {status.reason}")
            continue
        speed = (f"{status.events_per_s:.3g} scattering events/s on scene B1"
                 if status.events_per_s else "speed not measured")
        print(f"      qualified: {status.lanes} lane{'s' if status.lanes > 1 else ''}, {speed} "
              f"(single precision; checked {status.date or '?'} in {status.seconds or 0:.1f} s)")
        for lanes, why in status.failures:
            print(f"      failed at {lanes} lanes: {why}")
        if args.all:
            _print_all_verdicts(info)
    spec = resolve_spec(args.device)
    try:
        info, _ = select_device(spec)
        print(f"--device {spec} picks {info.spec} ({info.device}, {info.platform} "
              f"{info.platform_version})")
    except DeviceError as err:
        print(err)
        return EXIT_DEVICE
    return EXIT_OK


def _print_all_verdicts(info):
    """Every kernel combination's widest qualified lane width (``devices --all``)."""
    from .qualify import all_combos, qualifier_for
    q = qualifier_for(info)
    for combo in all_combos(info.fp64):
        lanes, failures = q.best_lanes(combo)
        verdict = (f"{lanes} lanes" if lanes else "NOT usable") + "".join(
            f"; failed at {w}: {r}" for w, r in failures)
        print(f"        {combo.label:26s} {verdict}")


def cmd_show_config(args) -> int:
    from .radiative import radiative_parameters
    cfg = _load(args)
    print(cfg.to_yaml().rstrip())
    for point, pcfg in cfg.sweep_points():
        print("# derived" + (" for " + ", ".join(f"{k}={v}" for k, v in point.items()) if point else ""))
        for line in _fmt_derived(radiative_parameters(pcfg)):
            print("#" + line)
    return EXIT_OK


def cmd_presets(args) -> int:
    import yaml
    from .catalog import bundled_presets
    for name, path in bundled_presets().items():
        try:
            desc = " ".join(str(yaml.safe_load(path.read_text()).get("description", "")).split())
        except Exception:  # noqa: BLE001 - a listing must not stop on one bad file
            desc = "(unreadable)"
        print(f"{name:34s} {desc[:100]}")
    return EXIT_OK


def cmd_plot(args) -> int:
    from .plot import plot_angular, plot_waveform
    path = Path(args.file)
    ds = _load_result(path)
    kind = args.kind or ("instrument" if "received_reflectance" in ds else "waveform")
    if kind == "instrument":
        if "received_reflectance" not in ds:
            raise ConfigError("has no instrument variables; give a file written by "
                              "`warpe-cl instrument`", key=str(path))
        _check_writable(Path(args.out), "--out")
        from .instrument.plot import plot_instrument
        from .io import Outputs
        with Outputs() as outputs:
            plot_instrument(ds, outputs.stage(args.out))
        print(f"wrote {args.out}")
        return EXIT_OK
    if "reflectance" not in ds:
        raise ConfigError("has no reflectance variable; give a file written by `warpe-cl run`",
                          key=str(path))
    _check_writable(Path(args.out), "--out")
    from .io import Outputs
    with Outputs() as outputs:
        (plot_angular if kind == "angular" else plot_waveform)(ds, outputs.stage(args.out))
    print(f"wrote {args.out}")
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
    r.add_argument("--plot", help="also draw the waveform to this PNG")
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
    ps.set_defaults(func=cmd_presets)

    pl = sub.add_parser("plot", help="draw the waveform of a result file")
    pl.add_argument("file", help="a NetCDF file written by `warpe-cl run`")
    pl.add_argument("--out", required=True, help="output PNG")
    pl.add_argument("--kind", choices=("waveform", "angular", "instrument"), default=None,
                    help="waveform: reflectance against time; angular: the FOV figure; "
                         "instrument: the seed's three-panel BELA figure (default for a file "
                         "written by `warpe-cl instrument`, else waveform)")
    pl.set_defaults(func=cmd_plot)

    ins = sub.add_parser("instrument", help="what an instrument records from a surface result")
    ins.add_argument("file", help="a NetCDF file written by `warpe-cl run`")
    ins.add_argument("--instrument", required=True,
                     help="bela, gala, atlas, or an instrument YAML file")
    ins.add_argument("--altitude", help='spacecraft altitude, e.g. "500 km" or 500km')
    ins.add_argument("--roughness", help='facet roughness, e.g. "0.1 deg" or 0.1deg')
    ins.add_argument("--shots", help="shots to simulate (default: the instrument's)")
    ins.add_argument("--seed", help="noise seed (default: the surface result's)")
    ins.add_argument("--out", required=True, help="output NetCDF file (surface + instrument)")
    ins.add_argument("--plot", help="also draw the three-panel figure to this PNG")
    ins.add_argument("--quiet", action="store_true", help="print nothing but errors")
    ins.set_defaults(func=cmd_instrument)
    return p


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    print(f"warpe-cl: warning: {message}", file=sys.stderr)


def main(argv=None) -> int:
    import warnings
    warnings.showwarning = _one_line_warning
    # pyopencl's "Non-empty compiler output" (Intel's compiler always talks): the build's
    # correctness is what the qualification checks (docs/devices.md); WARPE_CL_DEBUG=1 shows it
    if os.environ.get("WARPE_CL_DEBUG", "") != "1":
        warnings.filterwarnings("ignore", message="Non-empty compiler output")
    parser = make_parser()
    try:
        args = parser.parse_args(argv)
        if not getattr(args, "verb", None):
            parser.print_help()
            return EXIT_INPUT
        return args.func(args)
    except ConfigError as err:
        print(f"warpe-cl: error: {err}", file=sys.stderr)
        return EXIT_INPUT
    except DeviceError as err:
        print(f"warpe-cl: error: {err}", file=sys.stderr)
        return EXIT_DEVICE
    except KeyboardInterrupt:
        print("warpe-cl: interrupted", file=sys.stderr)
        return 130
    except WarpeError as err:
        print(f"warpe-cl: error: {err}", file=sys.stderr)
        return EXIT_OTHER
    except Exception as err:  # noqa: BLE001 - one line, never a traceback
        if os.environ.get("WARPE_CL_DEBUG"):
            raise
        print(f"warpe-cl: error: {type(err).__name__}: {err} (set WARPE_CL_DEBUG=1 for the traceback)",
              file=sys.stderr)
        return EXIT_OTHER


if __name__ == "__main__":
    sys.exit(main())
