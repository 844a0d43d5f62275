#!/usr/bin/env python3
"""The injection-recovery study of issue 14, recovery side: invert every injection of
``tools/studies/inversion_study.py`` and report bias, coverage, identifiability and time.

    python tools/studies/inversion_recovery.py invert FAMILY --work DIR
                                               [--instruments bela,gala] [--jobs 1] [--budget 600]
                                               [--instrument NAME|FILE.yaml ...]
    python tools/studies/inversion_recovery.py report FAMILY [FAMILY ...] --work DIR
                                               [--out TABLES]

``invert`` reads ``DIR/FAMILY/injections.csv`` and the database ``DIR/FAMILY/db`` (both written
by ``tools/studies/inversion_study.py``). For every finished injection and instrument it writes

- ``inj/iNNN/fit_LABEL.nc``: ``warpe_cl.invert`` of the injection's ``LABEL.nc`` against the
  database, every swept key free (skipped when it exists: the verb resumes);
- ``recovery_LABEL.csv``: one row per injection (:func:`recovery_row`): the truth, the best
  point, the posterior median and the 68 % and 95 % intervals of every key, the optical depth
  of the injected layer, the fit's χ²/dof and p-value, the inversion's time, and the
  interpolation error (:func:`interpolation_error`).

An instrument label of ``injections.csv`` is inverted with (:func:`instrument_source`): the
file given as ``--instrument FILE`` whose name (without ``.yaml``) is the label, else the copy
``inject`` kept in ``DIR/FAMILY/instruments/LABEL.yaml``, else the bundled instrument or the
study's ``presets/study/instruments/LABEL.yaml``. ``--instrument`` (a bundled name or any
instrument YAML file, repeatable) also chooses the instruments to invert, with
``--instruments``.

``report`` prints Markdown tables (docs/inversion.md §7) from the ``recovery_*.csv`` files:

- bias: the median error of the posterior median, in decades (dex) for log-spaced keys and in
  the value otherwise, with the half-width of the 16-84 % range of the errors as their spread;
- coverage: the fraction of injections whose 68 % (95 %) interval holds the truth, with its
  binomial standard error sqrt(p (1 - p) / n), for all injections, those the data inform or
  not, and those whose database was adequate for the shots or not (FIT.nc
  ``loglike_database_sd`` at most 1, docs/inversion.md §4.3; the column
  ``loglike_database_sd`` of ``recovery_LABEL.csv``), and of the 95 % statement the summary
  prints: a one-sided bound where a prior edge is open, the prior where both are
  (docs/inversion.md §6.3; columns ``KEY.bound`` and ``KEY.bound95``);
- identifiability: the median width of the 68 % interval as a fraction of the prior range,
  and the share of injections whose 95 % interval covers more than 90 % of the prior range
  (the data do not constrain the key), overall and by the optical depth of the injected layer
  (thirds of the injections);
- the 68 % widths of every other instrument relative to the first one's (BELA's), injection
  by injection;
- the inversion time (median and range) and the interpolation error.

Exit codes: 0 done, 1 an inversion failed (named on stderr, the others go on), 2 bad input.
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from inversion_study import (StudyError, instrument_label, is_instrument_file,  # noqa: E402
                             run_verbs, write_csv)

#: A 95 % interval wider than this fraction of the prior range: the key is not constrained.
UNCONSTRAINED = 0.9
#: Shots of the interpolation-error figure Δχ² (those of a BELA observation of the study).
SHOTS = 100


def read_injections(family_dir: Path) -> tuple:
    """(rows, swept keys, instrument labels) of ``family_dir/injections.csv``."""
    path = family_dir / "injections.csv"
    if not path.is_file():
        raise StudyError(f"{path}: no injections; run tools/studies/inversion_study.py "
                         "inject first")
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        rows, cols = list(reader), reader.fieldnames
    keys = [c[:-5] for c in cols if c.endswith("_text")]
    labels = [c[:-5] for c in cols if c.endswith("_seed") and c != "surface_seed"]
    return rows, keys, labels


# --------------------------------------------------------------------------- invert


def interpolation_error(space, forward, truth: dict, direct) -> dict:
    """How far the database's interpolated response at ``truth`` is from the directly
    simulated one, as the instrument sees them.

    Both go through the noiseless forward model (nominal pulse). The mismatch is the
    Δχ² that ``SHOTS`` shots would see between the two expected waveforms,

        Δχ² = SHOTS · Σ_t (μ_interp - μ_direct)² / (σ_n² + ν_direct) · δt / Δt

    (fine bins δt weighted to samples Δt; only where neither waveform reaches the clipping
    level, since a clipped sample says only that it is clipped), next to the same figure for
    the nearest grid node (what interpolation improves on), and the relative L2 error of the
    interpolated waveform. It includes the Monte Carlo noise of the database and of the
    injection.
    """
    mu_d, nu_d = forward.waveform(forward.photons(direct))
    mu_i, _ = forward.waveform(forward.photons(space.surface(truth)))
    coords = space.coords_of(truth)
    nearest = tuple(int(np.argmin(np.abs(a.nodes - c))) for a, c in zip(space.axes, coords))
    mu_n, _ = forward.waveform(forward.photons(space.nodes[nearest].surface))
    var = forward.sigma_n ** 2 + nu_d
    per_sample = forward.step / forward.interval
    top = forward.ceiling - forward.baseline
    chi = {name: SHOTS * per_sample * float(np.sum(np.where(np.maximum(mu, mu_d) < top,
                                                            (mu - mu_d) ** 2 / var, 0.0)))
           for name, mu in (("interp", mu_i), ("nearest", mu_n))}
    return {"dchi2_interp": chi["interp"], "dchi2_nearest": chi["nearest"],
            "l2_interp": float(np.linalg.norm(mu_i - mu_d) / np.linalg.norm(mu_d)),
            "l2_nearest": float(np.linalg.norm(mu_n - mu_d) / np.linalg.norm(mu_d))}


#: Per swept key, the FIT.nc variables on ``parameter`` copied to ``recovery_LABEL.csv``.
FIT_STATS = ("best", "median", "low68", "high68", "low95", "high95", "prior_low", "prior_high")
#: Per swept key, how FIT.nc states its 95 % statement at an open prior edge
#: (docs/inversion.md §6.3): ``bound`` the index of its kind in
#: ``warpe_cl.inversion.derived.BOUND_KINDS`` (an interval, a lower bound ``bound95``, an upper
#: bound ``bound95``, both edges open: the prior's range); NaN where a fit has none.
BOUND_STATS = ("bound", "bound95")
#: Scalars of FIT.nc copied (NaN where a fit has none: ``loglike_database_sd``, the stated
#: error of log L from the database, is absent when the database was taken as exact), its
#: attributes copied, and the interpolation error's columns.
FIT_SCALARS = ("chi2_per_dof", "p_value", "censored_samples", "amplitude", "pulse_fwhm",
               "loglike_database_sd")
FIT_ATTRS = {"shots_used": int, "evaluations": int, "elapsed_s": float}
INTERP_COLUMNS = ("dchi2_interp", "dchi2_nearest", "l2_interp", "l2_nearest")


def recovery_row(row: dict, keys: list, fit, surface_ds, interp: dict) -> dict:
    """One row of ``recovery_LABEL.csv``."""
    out = {"index": row["index"], "tau0": float(surface_ds["tau0"].values)}
    names = [str(p) for p in fit["parameter"].values]
    for key in keys:
        j = names.index(key)
        out[f"{key}.truth"] = float(row[key])
        for stat in FIT_STATS:
            out[f"{key}.{stat}"] = float(fit[stat].values[j])
        out[f"{key}.scale"] = (str(fit["scale"].values[j]) if "scale" in fit else
                               "log" if bool(fit["log_scale"].values[j]) else "linear")
        for name in ("width_ratio", *BOUND_STATS):
            out[f"{key}.{name}"] = float(fit[name].values[j]) if name in fit else math.nan
        out[f"{key}.rank"] = rank_of_truth(fit, key, float(row[key]), out[f"{key}.scale"])
    for name in FIT_SCALARS:
        out[name] = float(fit[name].values) if name in fit else math.nan
    for name, kind in FIT_ATTRS.items():
        out[name] = kind(fit.attrs[name])
    out.update(interp)
    return out


def rank_of_truth(fit, key: str, truth: float, scale: str) -> float:
    """The posterior's marginal CDF of ``key`` at the truth, in [0, 1]: the normalised rank
    of the truth among posterior draws, uniform over injections drawn from the prior when
    the posteriors are calibrated (simulation-based calibration). The marginal of FIT.nc's
    refined grid, each point's mass spread over its trapezoid cell in the interpolation
    coordinate ``scale``, as ``warpe_cl.inversion.posterior.intervals`` does."""
    from warpe_cl.inversion.space import SCALES
    coord = SCALES[scale][0]
    dims = list(fit["posterior"].dims)
    dim = next(d for d in dims if fit.coords[d].attrs.get("sweep_key") == key)
    mass = fit["posterior"].sum([d for d in dims if d != dim]).values
    u = coord(np.asarray(fit.coords[dim].values, float))
    if u.size == 1:
        return 0.5
    bounds = np.concatenate([[u[0]], 0.5 * (u[1:] + u[:-1]), [u[-1]]])
    cdf = np.concatenate([[0.0], np.cumsum(mass)])
    return float(np.interp(coord(truth), bounds, cdf / cdf[-1]))


def recovery_columns(keys: list) -> list:
    """The columns of ``recovery_LABEL.csv``."""
    cols = ["index", "tau0"]
    for key in keys:
        cols += [f"{key}.{s}" for s in ("truth", *FIT_STATS, "scale", "width_ratio",
                                        *BOUND_STATS, "rank")]
    return cols + [*FIT_SCALARS, *FIT_ATTRS, *INTERP_COLUMNS]


_STATE = {}
#: Instrument files of the study, for labels that are not bundled instruments.
STUDY_INSTRUMENTS = Path(__file__).resolve().parents[2] / "presets" / "study" / "instruments"


def instrument_source(label: str, family_dir: Path | None = None,
                      given: dict | None = None) -> str:
    """What ``load_instrument`` takes for an instrument label of ``injections.csv``.

    Parameters
    ----------
    label : str
        The label (a bundled name, or an instrument file's name without ``.yaml``).
    family_dir : Path, optional
        The study's family folder: ``instruments/LABEL.yaml`` there is the copy ``inject``
        simulated the injections with.
    given : dict, optional
        Label -> an instrument file given with ``--instrument FILE`` (first choice).

    Returns
    -------
    str
        The file given, the family's copy, the bundled name, or
        ``presets/study/instruments/LABEL.yaml``, first found.

    Raises
    ------
    StudyError
        None of these.
    """
    from warpe_cl.config.instrument_fields import BUILTIN
    if given and label in given:
        return str(given[label])
    if family_dir is not None and (family_dir / "instruments" / f"{label}.yaml").is_file():
        return str(family_dir / "instruments" / f"{label}.yaml")
    if label in BUILTIN:
        return label
    path = STUDY_INSTRUMENTS / f"{label}.yaml"
    if not path.is_file():
        raise StudyError(f"instrument {label!r} is neither bundled ({', '.join(BUILTIN)}) nor "
                         f"in {STUDY_INSTRUMENTS}; give its file with --instrument FILE")
    return str(path)


def given_instruments(values: list | None) -> dict:
    """``--instrument`` values -> label -> the file (absolute) or the bundled name.

    Raises
    ------
    StudyError
        A file that is missing or not a valid instrument (warpe-cl's one line), or two of one
        label.
    """
    from warpe_cl.errors import ConfigError
    from warpe_cl.instrument import load_instrument
    out = {}
    for value in values or []:
        label = instrument_label(str(value))
        source = str(Path(value).expanduser().resolve()) if is_instrument_file(value) else value
        if is_instrument_file(value) and not Path(source).is_file():
            raise StudyError(f"--instrument {value}: no such file")
        if label in out:
            raise StudyError(f"--instrument {value}: a second instrument labelled {label!r}")
        if is_instrument_file(value):
            try:
                load_instrument(source)
            except ConfigError as exc:
                raise StudyError(f"--instrument {value}: {exc}") from None
            out[label] = source
        else:
            out[label] = None           # a label: found by instrument_source
    return out


def _setup(db_path: str):
    """Per-process state: the database, its interpolation space, the forward models."""
    from warpe_cl.database import load_result
    from warpe_cl.inversion.space import Space
    db = load_result(db_path)
    _STATE.update(db=db, space=Space(db, source=db_path), forward={})


def _forward(label: str, source: str):
    if label not in _STATE["forward"]:
        from warpe_cl.instrument import load_instrument
        from warpe_cl.inversion.forward import Forward
        _STATE["forward"][label] = Forward(load_instrument(source))
    return _STATE["forward"][label]


def _invert_one(task) -> tuple:
    """Invert one (injection, instrument); returns (label, index, row or None, message)."""
    import xarray as xr
    from warpe_cl import invert
    from warpe_cl.surface import response
    family_dir, row, keys, label, source, budget = task
    folder = family_dir / row[label].rsplit("/", 1)[0]
    fit_path = folder / f"fit_{label}.nc"
    try:
        if fit_path.exists():
            fit = xr.load_dataset(fit_path)
        else:
            fit = invert(family_dir / row[label], _STATE["db"], source,
                         budget=budget, database_source=str(family_dir / "db"))
            tmp = fit_path.with_name(f".{fit_path.name}.tmp")
            fit.to_netcdf(tmp, engine="h5netcdf")
            tmp.replace(fit_path)
        surface = xr.load_dataset(family_dir / row["surface"])
        truth = {k: float(row[k]) for k in keys}
        interp = interpolation_error(_STATE["space"], _forward(label, source), truth,
                                     response(surface))
        return label, row["index"], recovery_row(row, keys, fit, surface, interp), ""
    except Exception as exc:            # one failure must not stop the study
        return label, row["index"], None, f"{type(exc).__name__}: {exc}"


def cmd_invert(args) -> int:
    """``invert``: fit files and ``recovery_LABEL.csv`` of a family."""
    family_dir = Path(args.work) / args.family
    given = given_instruments(args.instrument)
    rows, keys, labels = read_injections(family_dir)
    wanted = [s.strip() for s in args.instruments.split(",") if s.strip()] + \
        [label for label in given if label not in args.instruments.split(",")]
    wanted = wanted or labels
    missing = [w for w in wanted if w not in labels]
    if missing:
        raise StudyError(f"{family_dir}/injections.csv has no {missing[0]} files "
                         f"(instruments: {', '.join(labels)})")
    files = {label: source for label, source in given.items() if source is not None}
    sources = {label: instrument_source(label, family_dir, files) for label in wanted}
    db = family_dir / "db"
    if not db.is_dir():
        raise StudyError(f"{db}: no database; run tools/studies/inversion_study.py build first")
    done = [r for r in rows if r["status"] == "done"]
    tasks = [(family_dir, r, keys, label, sources[label], args.budget)
             for label in wanted for r in done]
    results = {label: {} for label in wanted}
    failed = 0
    start = time.perf_counter()
    with Pool(args.jobs, initializer=_setup, initargs=(str(db),)) as pool:
        for label, index, out, message in pool.imap(_invert_one, tasks):
            if out is None:
                failed += 1
                print(f"i{int(index):03d} {label} failed: {message}", file=sys.stderr)
                continue
            results[label][index] = out
            print(f"i{int(index):03d} {label}: {out['elapsed_s']:.1f} s, chi2/dof "
                  f"{out['chi2_per_dof']:.3f}", flush=True)
    for label in wanted:
        path = family_dir / f"recovery_{label}.csv"
        write_csv(path, [results[label][k] for k in sorted(results[label], key=int)],
                  recovery_columns(keys))
        print(f"wrote {path} ({len(results[label])} injections)")
    print(f"invert {args.family}: {len(tasks) - failed} done, {failed} failed, "
          f"{time.perf_counter() - start:.0f} s", flush=True)
    return 1 if failed else 0


# --------------------------------------------------------------------------- report


def read_recovery(path: Path) -> tuple:
    """(keys, rows with floats) of a ``recovery_LABEL.csv``."""
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        rows = [{k: (v if k.endswith(".scale") else float(v)) for k, v in r.items()}
                for r in reader]
        cols = reader.fieldnames
    return [c[:-6] for c in cols if c.endswith(".truth")], rows


#: Units of the errors in each interpolation coordinate (warpe_cl.inversion.space.SCALES),
#: and the coordinate they are taken in: decades of x, of 1 - x, or x itself.
ERROR_UNITS = {"log": " dex", "log1m": " dex(1-x)", "linear": ""}


def _coord(x, scale: str):
    x = np.asarray(x, float)
    return {"log": np.log10, "log1m": lambda v: -np.log10(1.0 - v)}.get(scale, lambda v: v)(x)


def key_stats(rows: list, key: str) -> dict:
    """Bias, spread, coverage and widths of one key over the injections ``rows``."""
    scale = rows[0][f"{key}.scale"]
    get = lambda s: np.array([r[f"{key}.{s}"] for r in rows])  # noqa: E731
    truth = get("truth")
    err = _coord(get("median"), scale) - _coord(truth, scale)
    span = _coord(get("prior_high"), scale) - _coord(get("prior_low"), scale)
    n = len(rows)
    out = {"n": n, "scale": scale, "bias": float(np.median(err)),
           "spread": float(np.subtract(*np.percentile(err, [84, 16])) / 2)}
    for level in ("68", "95"):
        hold = (get(f"low{level}") <= truth) & (truth <= get(f"high{level}"))
        p = hold.mean()
        out[f"cover{level}"] = (float(p), math.sqrt(p * (1 - p) / n))
        width = (_coord(get(f"high{level}"), scale) - _coord(get(f"low{level}"), scale)) / span
        out[f"width{level}"] = width
    out["unconstrained"] = out["width95"] > UNCONSTRAINED
    return out


def tau_classes(tau: np.ndarray) -> list:
    """Three optical-depth classes holding a third of the injections each: (label, low,
    high)."""
    a, b = (float(f"{q:.2g}") for q in np.percentile(tau, [100 / 3, 200 / 3]))
    return [(f"τ0 < {a:g}", 0.0, a), (f"{a:g} ≤ τ0 < {b:g}", a, b), (f"τ0 ≥ {b:g}", b, math.inf)]


def _short(key: str) -> str:
    return key.rsplit(".", 1)[-1]


#: A key is informed by the data where its 95 % interval is under half the prior's
#: (``width_ratio``, docs/inversion.md §6.2).
INFORMED = 0.5
#: Bins of the rank histograms.
RANK_BINS = 5


def coverage_cell(hold: np.ndarray, nominal: float) -> str:
    """``p ± σ`` of a coverage with its binomial error, ``!`` when p is more than 2σ (the
    error at the nominal rate) from nominal."""
    if hold.size == 0:
        return "–"
    p = hold.mean()
    sigma = math.sqrt(nominal * (1 - nominal) / hold.size)
    flag = " !" if abs(p - nominal) > 2 * sigma else ""
    return f"{p:.2f} ± {sigma:.2f} (n {hold.size}){flag}"


def printed_95(get) -> np.ndarray:
    """Whether the 95 % statement the summary prints holds the truth, per injection: the
    lower (upper) bound where the upper (lower) prior edge is open, the whole prior where
    both are, else the equal-tailed interval (docs/inversion.md §6.3). A calibrated posterior
    holds the truth in a one-sided 95 % bound 95 % of the time, in the prior always. Rows
    without ``bound`` (older recovery files) are judged by their interval."""
    from warpe_cl.inversion.derived import BOUND_KINDS
    truth, bound, edge = get("truth"), get("bound"), get("bound95")
    lower, upper, both = (bound == BOUND_KINDS.index(k)
                          for k in ("lower_bound", "upper_bound", "both_edges"))
    low = np.select([lower, upper | both], [edge, get("prior_low")], get("low95"))
    high = np.select([upper, lower | both], [edge, get("prior_high")], get("high95"))
    return (low <= truth) & (truth <= high)


def calibration_tables(recoveries: dict) -> list:
    """Coverage stratified by how informative the data are and by whether the database was
    adequate for the shots (the stated error of log L from the database at most
    ``ADEQUATE_SD``, docs/inversion.md §4.3), with the coverage of the 95 % statement as
    printed (:func:`printed_95`), and the rank histograms of simulation-based calibration, as
    Markdown lines."""
    from scipy.special import chdtrc
    from warpe_cl.inversion.emulator import ADEQUATE_SD
    lines = ["", f"Coverage by how informative the data are (informed: width ratio < "
             f"{INFORMED:g}) and by whether the database was adequate for the shots (its "
             f"stated error of log L at most {ADEQUATE_SD:g}); binomial error at the nominal "
             f"rate, `!` beyond 2σ.", "",
             "| instrument | key | stratum | 68 % coverage | 95 % coverage | 95 % as printed |",
             "|---|---|---|---|---|---|"]
    ranks = ["", f"Rank of the truth in its posterior (marginal CDF at the truth), "
             f"{RANK_BINS} bins of 0.2; uniform when calibrated: χ² on {RANK_BINS - 1} dof.", "",
             "| instrument | key | counts per bin | χ² | p |", "|---|---|---|---|---|"]
    for label, (keys, rows) in recoveries.items():
        sd = np.array([r.get("loglike_database_sd", math.nan) for r in rows])
        for key in keys:
            get = lambda s: np.array([r.get(f"{key}.{s}", math.nan) for r in rows])  # noqa: E731
            truth, ratio = get("truth"), get("width_ratio")
            for name, m in (("all", np.ones(truth.size, bool)),
                            ("informed", ratio < INFORMED), ("not informed", ratio >= INFORMED),
                            ("database adequate", sd <= ADEQUATE_SD),
                            ("database not adequate", sd > ADEQUATE_SD)):
                cells = [coverage_cell(((get(f"low{lv}") <= truth) & (truth <= get(f"high{lv}")))[m],
                                       int(lv) / 100) for lv in ("68", "95")]
                cells.append(coverage_cell(printed_95(get)[m], 0.95))
                lines.append(f"| {label.upper()} | {_short(key)} | {name} | "
                             + " | ".join(cells) + " |")
            rank = get("rank")
            rank = rank[np.isfinite(rank)]
            if rank.size:
                counts = np.histogram(rank, bins=RANK_BINS, range=(0.0, 1.0))[0]
                expect = rank.size / RANK_BINS
                chi2 = float(np.sum((counts - expect) ** 2 / expect))
                ranks.append(f"| {label.upper()} | {_short(key)} | {' '.join(map(str, counts))} "
                             f"| {chi2:.1f} | {float(chdtrc(RANK_BINS - 1, chi2)):.3f} |")
    return lines + ranks + [""]


def report_tables(family: str, recoveries: dict) -> list:
    """Markdown lines for one family: ``recoveries`` maps instrument label -> (keys, rows)."""
    lines = [f"### {family}", ""]
    labels = list(recoveries)
    lines += ["| instrument | key | n | bias of the median | spread (±1σ) | 68 % coverage | "
              "95 % coverage | 68 % width / prior | unconstrained (95 % > 90 % of prior) |",
              "|---|---|---|---|---|---|---|---|---|"]
    for label in labels:
        keys, rows = recoveries[label]
        for key in keys:
            s = key_stats(rows, key)
            unit = ERROR_UNITS[s["scale"]]
            c68, c95 = s["cover68"], s["cover95"]
            lines.append(
                f"| {label.upper()} | {_short(key)} | {s['n']} | {s['bias']:+.3f}{unit} | "
                f"{s['spread']:.3f}{unit} | {c68[0]:.2f} ± {c68[1]:.2f} | "
                f"{c95[0]:.2f} ± {c95[1]:.2f} | {np.median(s['width68']):.2f} | "
                f"{s['unconstrained'].sum()}/{s['n']} |")
    lines += calibration_tables(recoveries)
    classes = tau_classes(np.array([r["tau0"] for r in recoveries[labels[0]][1]]))
    lines += ["", "Identifiability by optical depth τ0 of the injected layer (thirds of the "
              "injections): median 68 % width / prior range, and how many injections leave the "
              "key unconstrained.", "",
              "| instrument | key | " + " | ".join(c[0] for c in classes) + " |",
              "|---|---|" + "---|" * len(classes)]
    for label in labels:
        keys, rows = recoveries[label]
        tau = np.array([r["tau0"] for r in rows])
        for key in keys:
            s = key_stats(rows, key)
            cells = []
            for _, lo, hi in classes:
                m = (tau >= lo) & (tau < hi)
                cells.append("–" if not m.any() else
                             f"{np.median(s['width68'][m]):.2f} ({s['unconstrained'][m].sum()}"
                             f"/{m.sum()})")
            lines.append(f"| {label.upper()} | {_short(key)} | " + " | ".join(cells) + " |")
    if len(labels) > 1:
        base, others = labels[0], labels[1:]
        lines += ["", f"68 % width relative to {base.upper()}, injection by injection (median "
                  "and 16-84 % range of the ratio; < 1: narrower).", "",
                  "| key | " + " | ".join(o.upper() for o in others) + " |",
                  "|---|" + "---|" * len(others)]
        keys, rows0 = recoveries[base]
        by0 = {r["index"]: r for r in rows0}
        for key in keys:
            w0 = dict(zip([r["index"] for r in rows0], key_stats(rows0, key)["width68"]))
            cells = []
            for o in others:
                _, rows1 = recoveries[o]
                w1 = dict(zip([r["index"] for r in rows1], key_stats(rows1, key)["width68"]))
                common = [i for i in w1 if i in by0 and w0[i] > 0]
                ratio = np.array([w1[i] / w0[i] for i in common])
                cells.append("–" if ratio.size == 0 else
                             f"{np.median(ratio):.2f} [{np.percentile(ratio, 16):.2f}, "
                             f"{np.percentile(ratio, 84):.2f}] (n = {ratio.size})")
            lines.append(f"| {_short(key)} | " + " | ".join(cells) + " |")
    lines += ["", "| instrument | time per inversion, s: median [range] | evaluations (median) | "
              "χ²/dof (median) | p < 0.01 | interpolation Δχ² (100 shots): median [90 %] | "
              "nearest node Δχ²: median [90 %] |",
              "|---|---|---|---|---|---|---|"]
    for label in labels:
        _, rows = recoveries[label]
        col = lambda k: np.array([r[k] for r in rows])  # noqa: E731
        t, di, dn = col("elapsed_s"), col("dchi2_interp"), col("dchi2_nearest")
        lines.append(
            f"| {label.upper()} | {np.median(t):.1f} [{t.min():.1f}, {t.max():.1f}] | "
            f"{np.median(col('evaluations')):.0f} | {np.median(col('chi2_per_dof')):.3f} | "
            f"{int((col('p_value') < 0.01).sum())}/{len(rows)} | "
            f"{np.median(di):.3g} [{np.percentile(di, 90):.3g}] | "
            f"{np.median(dn):.3g} [{np.percentile(dn, 90):.3g}] |")
    return lines + [""]


def cmd_report(args) -> int:
    """``report``: Markdown tables of one or more families."""
    lines = []
    for family in args.family:
        family_dir = Path(args.work) / family
        found = {p.stem[len("recovery_"):]: read_recovery(p)
                 for p in sorted(family_dir.glob("recovery_*.csv"), key=_bela_first)}
        found = {k: v for k, v in found.items() if v[1]}
        if not found:
            raise StudyError(f"{family_dir}: no recovery_*.csv; run the invert verb first")
        lines += report_tables(family, found)
    text = "\n".join(lines)
    if args.out:
        Path(args.out).write_text(text + "\n")
        print(f"wrote {args.out}")
    else:
        print(text)
    return 0


def _bela_first(path: Path):
    return (0 if path.stem.endswith("bela") else 1, path.stem)


def parser() -> argparse.ArgumentParser:
    """The command line: ``invert`` and ``report``."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="verb", required=True)
    i = sub.add_parser("invert", help="invert every injection of WORK/FAMILY")
    i.add_argument("family")
    i.add_argument("--work", required=True)
    i.add_argument("--instruments", default="",
                   help="comma-separated labels (default: every instrument of the injections)")
    i.add_argument("--instrument", action="append", metavar="NAME|FILE",
                   help="an instrument to invert with: a label of the injections or any "
                        "instrument YAML file, whose name is its label (repeatable)")
    i.add_argument("--jobs", type=int, default=1, help="inversions at once (1)")
    i.add_argument("--budget", type=int, default=600, help="refined grid points (600)")
    i.set_defaults(func=cmd_invert)
    r = sub.add_parser("report", help="Markdown tables of WORK/FAMILY/recovery_*.csv")
    r.add_argument("family", nargs="+")
    r.add_argument("--work", required=True)
    r.add_argument("--out", help="write the tables to this file instead of stdout")
    r.set_defaults(func=cmd_report)
    return p


def main(argv=None) -> int:
    """Run the tool; returns the exit code."""
    return run_verbs(parser(), argv, "inversion_recovery")


if __name__ == "__main__":
    sys.exit(main())
