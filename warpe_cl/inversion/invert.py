"""``warpe_cl.invert``: recorded shots + a sweep database -> the parameters compatible with them
(docs/inversion.md).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config.instrument_fields import (BUILTIN, InstrumentParams, at_wavelength,
                                        instruments_dir, load_instrument)
from ..database import database_folder, load_result
from ..errors import ConfigError
from ..instrument.pulse import sigma_from_fwhm
from .checks import checked
from .counting import CountShots
from .derived import measure, truth_values
from .emulator import Emulator, adequacy
from .forward import BROADENING_MAX_NS, PULSE_RANGE, Forward
from .likelihood import Shots
from .observed import Observed, load_observed
from .options import NUISANCES, dataset_header, check_complete, check_options, header, \
    parse_value
from .posterior import Problem, intervals, marginal, nearest_node_mass, refine
from .result import build_result, check_dof, dof_bound
from .space import Space

#: A shot is used when its largest sample rises this many σ_n above the baseline.
DETECTION_SIGMA = 5.0


def invert(observed, database, instrument=None, *, free=None, fix=None, budget: int = 600,
           pulse_range=PULSE_RANGE, broadening_max: float = BROADENING_MAX_NS,
           database_error: bool = True,
           observed_source: str | None = None, database_source: str | None = None,
           truth: dict | None = None, jobs: int = 1):
    """The surface parameters compatible with recorded shots.

    Parameters
    ----------
    observed : Observed, path, or list of paths
        Recorded shots (:func:`warpe_cl.inversion.observed.load_observed`): a
        ``warpe-cl instrument`` file or CSV files.
    database : xarray.Dataset or path
        A ``warpe-cl sweep`` database (folder) or sweep file; its swept keys are the
        parameters.
    instrument : str, path, dict or InstrumentParams, optional
        The receiving instrument (``bela``, ``gala``, a YAML file); default: the one named by
        the observed file. Refused if it does not match the observed sampling.
    free : list of str, optional
        Swept keys to report (default: every swept key not fixed). Swept keys neither free nor
        fixed are marginalised.
    fix : dict, optional
        Dotted key -> value to hold a swept key, by the unit rule of ``run --set``: a
        quantity with its unit (``"100 um"``; a bare number is refused), a plain number for a
        key without dimension (compacity), text for a non-numeric key; or a nuisance:
        ``amplitude`` (1: the instrument's radiometry is trusted), ``pulse_fwhm``
        (``"6.5 ns"``), ``broadening`` (ns², a number). Checked, with ``free``, against the
        database's manifests before its scenario files are read
        (:mod:`warpe_cl.inversion.options`).
    budget : int
        Largest number of points of a refined grid.
    pulse_range : (float, float)
        Prior range of the pulse FWHM relative to the instrument's.
    broadening_max : float
        Largest extra footprint broadening σ, ns.
    database_error : bool
        Integrate the database's own error (its nodes' Monte Carlo errors and the
        leave-one-out interpolation error, :mod:`warpe_cl.inversion.emulator`) out of the
        likelihood; False takes the database as exact.
    truth : dict, optional
        Swept key -> its true value (``--truth``: ``"10 mm"``, a plain number without
        dimension); default: what the observed file says (its ``sweep_point`` or ``config``,
        :func:`warpe_cl.inversion.derived.truth_values`). Shown, never used by the fit.
    jobs : int
        Worker processes the grid's points are spread over (Linux; elsewhere this process):
        the result is the same bits with any number (:meth:`~.posterior.Problem.grid`).

    Returns
    -------
    xarray.Dataset
        docs/inversion.md §6: ``median``, ``low68``, ``high68``, ``low95``, ``high95`` (then
        the ``best`` grid point) on the ``parameter`` coordinate, identifiability and bounds,
        derived quantities on ``derived``, marginal posteriors, nuisances, the best-fit
        waveform and the goodness of fit.
    """
    started = time.perf_counter()
    channel = prepare(observed, database, instrument, free=free, fix=fix,
                      pulse_range=pulse_range, broadening_max=broadening_max,
                      database_error=database_error, observed_source=observed_source,
                      database_source=database_source, truth=truth)
    nodes, final = refine(channel.problem, budget=budget, jobs=jobs)
    return conclude(channel, nodes, final, started)


@dataclass
class Channel:
    """One set of recorded shots ready to be inverted: what :func:`prepare` read and checked.

    Attributes
    ----------
    obs : Observed
        The recorded shots.
    params : InstrumentParams
        The receiving instrument.
    space : Space
        The database's surface at any point of its grid.
    db : xarray.Dataset
        The database.
    db_source : str
        Its name (path) for messages and FIT.nc.
    problem : Problem
        log L of these shots at any point of the grid.
    used : array of bool
        The shots used (detected).
    echoed : dict
        The fixed keys as read, with their units (FIT.nc attribute ``fixed``).
    report : list of str
        The keys reported (the others are marginalised).
    truth : dict
        Swept key -> true value, when known; ``truth_source`` where it came from.
    """
    obs: Observed
    params: InstrumentParams
    space: Space
    db: object
    db_source: str
    problem: Problem
    used: np.ndarray
    echoed: dict
    report: list
    truth: dict
    truth_source: str


def prepare(observed, database, instrument=None, *, free=None, fix=None,
            pulse_range=PULSE_RANGE, broadening_max: float = BROADENING_MAX_NS,
            database_error: bool = True, observed_source: str | None = None,
            database_source: str | None = None, truth: dict | None = None) -> Channel:
    """Read and check everything :func:`invert` needs before its posterior: the options
    against the database's manifests (before its scenario files are read), the shots against
    the instrument, the database's wavelength against the instrument's; then build the
    likelihood. The parameters are :func:`invert`'s.

    Returns
    -------
    Channel

    Raises
    ------
    ConfigError
        One line naming what is refused and what is allowed.
    """
    fix = dict(fix or {})
    nuisance = {k: fix.pop(k) for k in list(fix) if k in NUISANCES}
    # every option is checked against the database's manifests before the database is read
    # (its store, or every scenario file of a folder without one)
    head = header(database, database_source)
    if head is not None:
        check_complete(head)
        fixed, echoed = check_options(head, free, fix, nuisance)
    obs = observed if isinstance(observed, Observed) else load_observed(observed)
    db, db_source = _database(database, database_source)
    if head is None:
        head = dataset_header(db, db_source)
        check_complete(head)
        fixed, echoed = check_options(head, free, fix, nuisance)
    params = instrument if isinstance(instrument, InstrumentParams) else \
        load_instrument(instrument or _named_instrument(obs))
    counting = params["detector.type"] == "photon_counting"
    if counting != (obs.kind == "counts"):
        kind = "photon-counting" if counting else "linear-mode"
        raise ConfigError(f"{params['name']} is a {kind} receiver but the observed shots are "
                          f"{'photon counts' if obs.kind == 'counts' else 'samples in mV'}: give "
                          "the instrument that recorded them (--instrument)",
                          key=observed_source or obs.source)
    if abs(obs.interval_ns - params["adc.sampling_interval"]) > 1e-6 * obs.interval_ns:
        raise ConfigError(f"the observed samples are {obs.interval_ns:g} ns apart but "
                          f"{params['name']} samples every {params['adc.sampling_interval']:g} "
                          "ns: give the instrument that recorded them (--instrument)",
                          key=observed_source or obs.source)
    space = Space(db, fixed, source=db_source)
    keys = [a.key for a in space.free_axes]
    report = list(free) if free else keys
    truth, truth_source = truth_values(obs.attrs, space, truth)
    if space.wavelength is not None:
        if not at_wavelength(space.wavelength, params["wavelength"]):
            raise ConfigError(f"the database was computed at {space.wavelength * 1e9:g} nm but "
                              f"{params['name']} works at {params['wavelength'] * 1e9:g} nm",
                              key=db_source)
    forward = Forward(params, pulse_range, broadening_max)
    _check_samples(obs, forward)
    v_fixed = _fixed_v(nuisance, forward)
    if counting:
        used = np.ones(obs.shots.shape[0], bool)     # a shot without tags counts too
        if not obs.shots.sum() > 0:
            raise ConfigError("the shots hold no photon: nothing to invert", key=obs.source)
        shots = CountShots(obs.time_ns, obs.shots, forward)
    else:
        used = _detected(obs.shots, forward)
        if not used.any():
            raise ConfigError(f"no shot rises {DETECTION_SIGMA:g} σ_n ({forward.sigma_n:.3g} "
                              "mV) above the baseline: nothing to invert", key=obs.source)
        shots = Shots(obs.time_ns, obs.shots[used], forward)
    # degrees of freedom are known from the counts before any work (result.check_dof)
    n_used = int(used.sum())
    check_dof(dof_bound(counting, n_used, obs.time_ns.size, len(keys)), n_used,
              obs.time_ns.size, len(keys), counting, obs.source)
    overall = nuisance.get("amplitude")
    overall = None if overall is None else parse_value("amplitude", overall, None, "(> 0)")
    emulator = Emulator(space, forward) if database_error else None
    problem = Problem(space, forward, shots, overall=overall, v=v_fixed, emulator=emulator)
    return Channel(obs, params, space, db, db_source, problem, used, echoed, report, truth,
                   truth_source)


def conclude(channel: Channel, nodes, final, started: float):
    """The FIT Dataset of a channel from its posterior: intervals, derived quantities, the
    database's adequacy for these shots, the evidence, goodness of fit and warnings
    (docs/inversion.md §5-§6).

    Parameters
    ----------
    channel : Channel
    nodes, final : GridPosterior
        The posterior at the database's nodes and on the refined grid; their evaluations are
        this channel's.
    started : float
        ``time.perf_counter()`` when the inversion began (FIT.nc ``elapsed_s``).

    Returns
    -------
    xarray.Dataset
    """
    problem, space, forward = channel.problem, channel.space, channel.problem.forward
    summary = _summarise(problem, final, channel.report)
    summary["measure"] = measure(problem, final, channel.db, channel.truth)
    if problem.emulator is not None:      # is the database good enough for these shots? (§4.3)
        best = summary["best"]
        point = problem.point(summary["best_u"])
        mu, nu = forward.waveform(forward.photons(space.surface(point)), best.v)
        summary["adequacy"] = adequacy(problem.emulator, problem.shots, best.fit, point, mu, nu,
                                       problem.overall is None)
    summary["measure"]["truth_source"] = channel.truth_source
    summary["elapsed_s"] = time.perf_counter() - started
    summary["evaluations"] = problem.count
    ds = build_result(channel.obs, channel.params, space, problem, nodes, final, summary,
                      channel.used, db_source=channel.db_source, db_attrs=dict(channel.db.attrs),
                      fixed=channel.echoed)
    # evidence, complete goodness of fit and warnings (docs/inversion.md §5.1-§5.3)
    return checked(ds, problem, nodes, final, channel.db_source)


#: How many per-sample noise standard deviations σ_n an observed sample may lie beyond the
#: receiver's clipped level (saturation or top ADC code) before it is refused as not recorded
#: by that receiver. A receiver records nothing above its clipped level but the noise added
#: after it (a saturated sample is the saturation voltage plus noise): 6 σ_n is exceeded by
#: Gaussian noise with probability 1e-9 per sample, so a file of 1e6 saturated samples is
#: wrongly refused once in a thousand; below, the bound is the lower of 0 (the lowest ADC
#: code) and the baseline, less the same 6 σ_n (docs/inversion.md §2).
SAMPLE_NOISE_SIGMAS = 6.0


def sample_range(forward) -> tuple:
    """The observed samples (mV) a linear-mode receiver can record: ``(low, high)``.

    Parameters
    ----------
    forward : Forward
        Its ``ceiling`` (clipped level, mV), ``baseline`` (mV) and ``sigma_n`` (per-sample
        noise, mV).

    Returns
    -------
    (float, float)
        ``min(0, baseline) - k σ_n`` and ``ceiling + k σ_n`` (mV), k =
        :data:`SAMPLE_NOISE_SIGMAS`; ``(-inf, inf)`` where the receiver does not clip.
    """
    if not (np.isfinite(forward.ceiling) and np.isfinite(forward.sigma_n)):
        return -np.inf, np.inf
    pad = SAMPLE_NOISE_SIGMAS * forward.sigma_n
    return min(0.0, forward.baseline) - pad, forward.ceiling + pad


def _check_samples(obs, forward) -> None:
    """Refuse observed samples the receiver cannot have recorded: any sample not finite
    (NaN, ±inf); counts below 0 or not whole; samples in mV outside :func:`sample_range`
    (1e30 mV once gave confident intervals from a fit with chi2/dof nan).

    Raises
    ------
    ConfigError
        One line: the variable, the value and its unit, the shot and sample, what is allowed.
    """
    shots = np.asarray(obs.shots, float)
    counts = obs.kind == "counts"
    name, unit = ("signal_counts", "counts") if counts else ("signal_mv", "mV")
    if counts:
        bad = (shots < 0) | (shots != np.round(shots))
        allowed = "finite, whole photon counts >= 0"
    else:
        low, high = sample_range(forward)
        bad = (shots < low) | (shots > high)
        allowed = (f"finite samples in [{low:.6g}, {high:.6g}] mV: the receiver's clipped "
                   f"level {forward.ceiling:.6g} mV plus {SAMPLE_NOISE_SIGMAS:g} σ_n "
                   f"({forward.sigma_n:.3g} mV) of noise at most"
                   if np.isfinite(high) else "finite samples in mV")
    bad = bad | ~np.isfinite(shots)
    if np.any(bad):
        s, k = np.argwhere(bad)[0]
        raise ConfigError(f"{name}: {shots[s, k]:g} {unit} at shot {s}, sample {k} is not "
                          f"allowed; give {allowed}, as recorded by the instrument",
                          key=obs.source)


def _named_instrument(obs):
    """The file of the bundled instrument the observed file names (attribute
    ``instrument_name``): its path in :func:`~warpe_cl.config.instrument_fields.instruments_dir`,
    never the bare name, which :func:`~warpe_cl.instrument.load_instrument` would first try as
    a file of the current folder.

    A name read from a file is data, not a path: only the bundled names
    (:data:`warpe_cl.config.instrument_fields.BUILTIN`) are taken from it, so that a file saying
    ``instrument_name: /etc/shadow`` opens nothing. Any other instrument is given with
    ``--instrument FILE``.
    """
    name = obs.instrument
    if name is None:
        raise ConfigError("the observed file does not name its instrument: give --instrument",
                          key=obs.source)
    if str(name).strip().lower() not in BUILTIN:
        shown = str(name) if len(str(name)) <= 60 else str(name)[:57] + "..."
        raise ConfigError(f"the file's instrument_name {shown!r} is not a bundled instrument "
                          f"({', '.join(BUILTIN)}); pass the instrument explicitly with "
                          "--instrument FILE", key=obs.source)
    return instruments_dir() / f"{str(name).strip().lower()}.yaml"


def _database(database, source):
    """(Dataset, name) of a database folder, a sweep file or a Dataset."""
    if hasattr(database, "dims"):
        return database, source or "<database>"
    path = Path(database)
    if path.suffix == ".nc" and not path.is_file():     # X.nc not combined yet: its X.sweep/
        path = database_folder(path)[0]
    return load_result(path), source or str(database)


def _fixed_v(nuisance: dict, forward: Forward):
    """The broadening nuisance v (ns²) that ``--fix pulse_fwhm=`` or ``broadening=`` sets."""
    if "pulse_fwhm" in nuisance:
        value = nuisance["pulse_fwhm"]
        fwhm = parse_value("pulse_fwhm", value, "time", "(a pulse FWHM > 0)")
        if not forward.gaussian_pulse or not 0 < fwhm:
            raise ConfigError(f"--fix pulse_fwhm={value}: needs a Gaussian pulse and a positive "
                              "width with a unit (e.g. \"6.5 ns\")", key="--fix")
        return sigma_from_fwhm(fwhm) ** 2 - forward.sigma_p ** 2
    if "broadening" in nuisance:
        return parse_value("broadening", nuisance["broadening"], None, "(ns2)")
    return None


def _detected(samples: np.ndarray, forward: Forward) -> np.ndarray:
    """Shots whose largest sample rises DETECTION_SIGMA σ_n above the baseline."""
    return (samples - forward.baseline).max(axis=1) > DETECTION_SIGMA * forward.sigma_n


def _summarise(problem, final, report) -> dict:
    """Best point, intervals and marginals of the reported axes."""
    axes = problem.space.free_axes
    best_index = final.best()
    best_u = np.array([c[i] for c, i in zip(final.coords, best_index)])
    rows = []
    for j, axis in enumerate(axes):
        u, mass = marginal(final, j)
        iv = intervals(u, mass)
        lo_u, hi_u = axis.nodes[0], axis.nodes[-1]
        span = hi_u - lo_u
        width95 = (iv[0.95][1] - iv[0.95][0]) / span if span > 0 else 0.0
        rows.append({
            "key": axis.key, "units": axis.units, "scale": axis.scale,
            "best": float(axis.value(best_u[j])), "median": float(axis.value(iv[0.5])),
            "low68": float(axis.value(iv[0.68][0])), "high68": float(axis.value(iv[0.68][1])),
            "low95": float(axis.value(iv[0.95][0])), "high95": float(axis.value(iv[0.95][1])),
            "prior_low": float(axis.values[0]), "prior_high": float(axis.values[-1]),
            "interval_fraction": float(width95),
            "node_mass": nearest_node_mass(u, mass, axis.nodes),
            "reported": axis.key in report,
        })
    return {"rows": rows, "best_u": best_u, "best": final.evaluations[best_index]}
