"""Shots of one surface recorded by several instruments, or at several wavelengths, inverted
together (docs/inversion.md §5.5): BELA at 1064 nm with ATLAS at 532 nm, each against its own
wavelength's database, or BELA with GALA against the same one.

The channels share the surface: the swept keys are the same parameters, with one prior, and
log L is the sum of the channels' log L at every point of the grid. Each channel keeps its own
nuisances (amplitude A, pulse width and footprint broadening v, per-shot amplitudes and
arrivals), since the instruments' radiometry, pulses and clocks are independent, and its own
database error. The databases must sweep the same keys over the same nodes (one sweep file
run at each wavelength).

``warpe-cl invert A.nc B.nc --database DB_A --database DB_B --joint --out FIT.nc`` writes one
FIT file per channel, ``FIT_<label>.nc``, each holding the joint posterior, that channel's fit
and the joint log evidence; from Python, :func:`invert_joint`.
"""
from __future__ import annotations

import json
import time

import numpy as np

from ..errors import ConfigError
from .checks import AMPLITUDE_PRIOR_SIGMA, log_evidence
from .invert import prepare, conclude
from .posterior import Evaluation, GridPosterior, Problem, refine

#: Nuisances that name one instrument's pulse: refused in a joint inversion, whose channels
#: have their own pulses.
PER_INSTRUMENT = ("pulse_fwhm", "broadening")


class JointProblem:
    """log L of several channels at the same point: their sum, each channel's nuisances its
    own. Has :class:`~.posterior.Problem`'s interface for :func:`~.posterior.refine`.

    Parameters
    ----------
    problems : list of Problem
        One per channel, over databases with the same free axes.
    """

    grid = Problem.grid

    def __init__(self, problems):
        self.parts = list(problems)
        self.space = self.parts[0].space

    @property
    def count(self) -> int:
        """Model evaluations of every channel together."""
        return sum(p.count for p in self.parts)

    def counts(self) -> list:
        """Model evaluations so far, per channel."""
        return [p.count for p in self.parts]

    def add_counts(self, extra) -> None:
        """Add ``extra`` (per channel) to the channels' model evaluations."""
        for p, n in zip(self.parts, extra):
            p.count += int(n)

    def point(self, u: np.ndarray) -> dict:
        """The free keys' values at coordinates ``u``."""
        return self.parts[0].point(u)

    def evaluate(self, u: np.ndarray) -> Evaluation:
        """The channels' log L summed at ``u``; the first channel's v and fit, each
        channel's own evaluation in ``parts``."""
        parts = tuple(p.evaluate(u) for p in self.parts)
        return Evaluation(float(sum(e.loglike for e in parts)), parts[0].v, parts[0].fit,
                          parts=parts)


def channel_view(post: GridPosterior, i: int) -> GridPosterior:
    """The joint posterior with channel ``i``'s own evaluations (its fits and ln L at every
    point): what :func:`~.invert.conclude` reads for that channel's FIT Dataset."""
    return GridPosterior(post.coords, post.loglike,
                         {k: e.parts[i] for k, e in post.evaluations.items()})


def check_axes(channels, names) -> None:
    """Refuse channels whose databases do not share their free axes: the same keys, spacing
    and node values (one line naming both databases and what differs).

    Raises
    ------
    ConfigError
    """
    first = channels[0].space.free_axes
    for ch, name in zip(channels[1:], names[1:]):
        axes = ch.space.free_axes
        keys_a, keys_b = [a.key for a in first], [a.key for a in axes]
        if keys_a != keys_b:
            raise ConfigError(f"{names[0]} leaves free {', '.join(keys_a) or 'nothing'} but "
                              f"{name} {', '.join(keys_b) or 'nothing'}: a joint inversion "
                              "needs the same swept keys in every database", key="--database")
        for a, b in zip(first, axes):
            if not a.same_nodes(b):
                raise ConfigError(
                    f"{a.key}: {names[0]} sweeps {_values(a)} {a.units} but {name} sweeps "
                    f"{_values(b)} {b.units}: a joint inversion needs the same nodes in every "
                    "database (run one sweep file at each wavelength)", key="--database")


def _values(axis) -> str:
    """An axis' node values, short."""
    v = [f"{x:g}" for x in axis.values]
    return "[" + ", ".join(v if len(v) <= 6 else v[:3] + ["..."] + v[-2:]) + "]"


def check_counts(observed: int, databases: int, instruments: int) -> None:
    """Refuse a joint inversion whose channels are not one to one: two observed sets or
    more, one database each and none or one instrument each (in the same order).

    Raises
    ------
    ConfigError
        One line naming the option and the counts.
    """
    if observed < 2:
        raise ConfigError(f"{observed} observed file(s): a joint inversion needs two or more "
                          "(one per instrument or wavelength)", key="--joint")
    if databases != observed:
        raise ConfigError(f"{observed} observed files but {databases} --database: a joint "
                          "inversion needs one database per observed file, in the same order",
                          key="--database")
    if instruments and instruments != observed:
        raise ConfigError(f"{observed} observed files but {instruments} --instrument: give none "
                          "(each file's own) or one per observed file, in the same order",
                          key="--instrument")


def invert_joint(observed, databases, instruments=None, *, free=None, fix=None,
                 budget: int = 600, names=None, truth=None, jobs: int = 1, **options) -> list:
    """Several channels' shots of one surface inverted together.

    Parameters
    ----------
    observed : list
        One recorded set of shots per channel (an Observed, a ``warpe-cl instrument`` file,
        or a list of CSV files).
    databases : list
        One database per channel (folder, sweep file or Dataset), the same swept keys and
        nodes in each; for channels at several wavelengths, each its own wavelength's.
    instruments : list, optional
        One instrument per channel (name, YAML file or InstrumentParams; None: the one its
        observed file names); default: each file's own.
    free, fix, truth, budget, jobs, **options
        As :func:`~.invert.invert`, the same for every channel; ``fix`` may hold the swept
        keys and ``amplitude`` (every channel's A), not a pulse width or broadening.
    names : list of str, optional
        A name per database for messages and FIT.nc (default: its path).

    Returns
    -------
    list of xarray.Dataset
        One FIT Dataset per channel, in order: the joint posterior's intervals, marginals and
        derived quantities; that channel's best fit, nuisances, goodness of fit and warnings;
        ``log_evidence`` and ``log_evidence_nodes`` of the joint likelihood (every channel's
        amplitude prior included), ``joint_log_likelihood`` at the best point, and the
        attribute ``joint`` (JSON: every channel's observed file, instrument, database,
        wavelength and ln L at the best point).

    Raises
    ------
    ConfigError
        Fewer than two channels, counts that differ, a per-instrument nuisance fixed,
        databases with different axes; any refusal of :func:`~.invert.invert`.
    """
    started = time.perf_counter()
    observed, databases = list(observed), list(databases)
    check_counts(len(observed), len(databases), len(instruments or []))
    instruments = list(instruments or [None] * len(observed))
    held = [k for k in PER_INSTRUMENT if k in dict(fix or {})]
    if held:
        raise ConfigError(f"--fix {held[0]}: each channel of a joint inversion has its own "
                          "pulse; fix swept keys or amplitude only", key="--fix")
    if names is None:
        names = [f"database {i}" if hasattr(d, "dims") else str(d)
                 for i, d in enumerate(databases)]
    channels = [prepare(o, d, ins, free=free, fix=fix, database_source=name, truth=truth,
                        **options)
                for o, d, ins, name in zip(observed, databases, instruments, names)]
    check_axes(channels, names)
    joint = JointProblem([c.problem for c in channels])
    nodes, final = refine(joint, budget=budget, jobs=jobs)
    fits = [conclude(c, channel_view(nodes, i), channel_view(final, i), started)
            for i, c in enumerate(channels)]
    amplitude = [None if c.problem.overall is not None else
                 (AMPLITUDE_PRIOR_SIGMA, float(ds["amplitude_curvature"]))
                 for c, ds in zip(channels, fits)]
    axes = channels[0].space.free_axes
    evidence = log_evidence(final, axes, amplitude)
    evidence_nodes = log_evidence(nodes, axes, amplitude)
    best = final.evaluations[final.best()]
    table = json.dumps([{"observed": c.obs.source, "instrument": c.params["name"],
                         "database": c.db_source,
                         "wavelength_nm": round(float(c.params["wavelength"]) * 1e9, 6),
                         "log_likelihood": float(e.loglike)}
                        for c, e in zip(channels, best.parts)])
    for ds in fits:
        ds["log_evidence"] = ((), evidence, {
            "long_name": "joint log evidence ln Z of every channel's shots: the prior uniform "
                         "in each axis' interpolation coordinate, each channel's per-shot "
                         "nuisances marginalised, pulse width profiled and ln A integrated "
                         "against N(0, ln(3)^2)", "units": "1"})
        ds["log_evidence_nodes"] = ((), evidence_nodes, {
            "long_name": "joint ln Z on the database's nodes alone", "units": "1"})
        ds["joint_log_likelihood"] = ((), float(best.loglike), {
            "long_name": "sum of the channels' ln L at the best point", "units": "1"})
        ds.attrs["joint"] = table
        ds.attrs["joint_evaluations"] = int(joint.count)
    return fits
