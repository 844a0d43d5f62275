"""The same shots inverted against several databases, ranked by log evidence
(docs/inversion.md §5.4): which texture or composition describes them.

``warpe-cl invert OBS --database A --database B --out FIT.nc`` writes one FIT file per
database, ``FIT_<label>.nc`` (:func:`output_paths`), and prints the ranking
(:func:`ranking_lines`); from Python, :func:`compare`.
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path

from ..errors import ConfigError
from .checks import fit_warnings
from .invert import invert
from .observed import Observed, load_observed
from .options import NUISANCES, check_complete, check_options, header

#: Jeffreys' scale in ln: a database whose ln Z lies this far below the best's is strongly
#: disfavoured (odds above 150 : 1).
STRONG = 5.0


def compare(observed, databases, instrument=None, *, free=None, fix=None, names=None,
            **options) -> list:
    """Invert the same shots against each database, and rank them by log evidence.

    Parameters
    ----------
    observed : Observed, path, or list of paths
        Recorded shots (:func:`warpe_cl.inversion.observed.load_observed`), read once.
    databases : list
        Two or more databases (folders, sweep files or Datasets), as ``invert``'s
        ``database``.
    instrument, free, fix, **options
        As :func:`warpe_cl.inversion.invert.invert`, the same for every database (a ``--fix``
        or ``--free`` key each database must have).
    names : list of str, optional
        A name per database for the ranking and the warnings (default: its path, or
        ``database <i>`` for a Dataset).

    Returns
    -------
    list of xarray.Dataset
        The FIT Datasets in the order of ``databases``, each with ``delta_log_evidence``
        (ln Z less the best database's ln Z; 0 for the best) and the attribute
        ``comparison`` (the ranking of :func:`ranking` as JSON).

    Raises
    ------
    ConfigError
        Fewer than two databases, or names not one per database; any refusal of ``invert``.
    """
    databases = list(databases)
    if len(databases) < 2:
        raise ConfigError(f"{len(databases)} database(s) given: a comparison needs two or "
                          "more (invert inverts against one)", key="--database")
    if names is None:
        names = [f"database {i}" if hasattr(d, "dims") else str(d)
                 for i, d in enumerate(databases)]
    if len(names) != len(databases):
        raise ConfigError(f"{len(names)} name(s) for {len(databases)} databases: give one "
                          "per database", key="names")
    # every database's options and completeness before the first inversion (minutes each)
    nuisance = {k: v for k, v in dict(fix or {}).items() if k in NUISANCES}
    swept = {k: v for k, v in dict(fix or {}).items() if k not in NUISANCES}
    for db, name in zip(databases, names):
        head = header(db, name)
        if head is not None:
            check_complete(head)
            check_options(head, free, dict(swept), dict(nuisance))
    obs = observed if isinstance(observed, Observed) else load_observed(observed)
    fits = [invert(obs, db, instrument, free=free, fix=fix, database_source=name, **options)
            for db, name in zip(databases, names)]
    rows = ranking(fits)
    top = rows[0]["log_evidence"]         # the best finite one (nan everywhere if none is)
    table = json.dumps(rows)
    for ds in fits:
        ds["delta_log_evidence"] = ((), float(ds["log_evidence"]) - top, {
            "long_name": "ln Z less the largest ln Z of the databases compared (0: the "
                         "best; below -5: strongly disfavoured)", "units": "1"})
        ds.attrs["comparison"] = table
    return fits


def ranking(fits) -> list:
    """The databases ranked by log evidence, best first.

    Parameters
    ----------
    fits : list of xarray.Dataset
        FIT Datasets of the same shots (:func:`compare`).

    Returns
    -------
    list of dict
        ``rank`` (1: the best), ``database``, ``log_evidence``, ``delta_log_evidence``,
        ``log_likelihood``, ``fit_p_value``, ``amplitude``, ``warnings`` (their count).
    """
    rows = []
    for ds in fits:
        rows.append({"database": str(ds.attrs.get("database", "")),
                     "log_evidence": float(ds["log_evidence"]),
                     "log_likelihood": float(ds["log_likelihood"]),
                     "fit_p_value": float(ds["fit_p_value"]),
                     "amplitude": float(ds["amplitude"]),
                     "warnings": len(fit_warnings(ds))})
    rows.sort(key=lambda r: -r["log_evidence"] if math.isfinite(r["log_evidence"]) else math.inf)
    top = rows[0]["log_evidence"]
    for i, r in enumerate(rows):
        r["rank"] = i + 1
        r["delta_log_evidence"] = r["log_evidence"] - top
    return rows


def ranking_lines(rows) -> list:
    """The ranking as the lines ``warpe-cl invert`` prints.

    Parameters
    ----------
    rows : list of dict
        :func:`ranking`'s rows.

    Returns
    -------
    list of str
    """
    width = max(8, *(len(r["database"]) for r in rows))
    lines = [f"comparison of {len(rows)} databases, ranked by log evidence (Δ ln Z below "
             f"-{STRONG:g}: strongly disfavoured)",
             f"  {'rank':<4}  {'database':<{width}}  {'ln Z':>11}  {'Δ ln Z':>9}  "
             f"{'ln L best':>11}  {'fit p':>8}  {'amplitude':>9}  warnings"]
    for r in rows:
        lines.append(f"  {r['rank']:<4}  {r['database']:<{width}}  {r['log_evidence']:>11.6g}  "
                     f"{r['delta_log_evidence']:>9.4g}  {r['log_likelihood']:>11.6g}  "
                     f"{r['fit_p_value']:>8.2g}  {r['amplitude']:>9.3g}  {r['warnings']}")
    return lines


def labels(databases) -> list:
    """A short label per database path for the names of its outputs: the last part of its
    path less ``.nc`` / ``.sweep``, characters other than letters, digits, ``-`` and ``_``
    replaced by ``_``; labels that repeat get ``_<i>`` (their place, from 1), and any label
    that would still meet another gets a further ``_<k>``: the labels are all different.

    Parameters
    ----------
    databases : list of str or Path

    Returns
    -------
    list of str
    """
    out = []
    for d in databases:
        name = Path(str(d).rstrip("/\\")).name
        for suffix in (".nc", ".sweep"):
            if name.lower().endswith(suffix):
                name = name[: -len(suffix)]
        out.append(re.sub(r"[^A-Za-z0-9_-]", "_", name)[:60] or "database")
    named = [f"{x}_{i + 1}" if out.count(x) > 1 else x for i, x in enumerate(out)]
    unique, seen = [], set()
    for x in named:          # a numbered label may meet a given one (a, a, a_1): number on
        label, k = x, 2
        while label in seen:
            label, k = f"{x}_{k}", k + 1
        seen.add(label)
        unique.append(label)
    return unique


def output_paths(path, names) -> list:
    """``STEM_<label>SUFFIX`` beside ``path`` for each label (``fit.nc`` -> ``fit_A.nc``).

    Parameters
    ----------
    path : str or Path
        ``--out`` or ``--plot``.
    names : list of str
        :func:`labels`.

    Returns
    -------
    list of Path
    """
    p = Path(path)
    return [p.with_name(f"{p.stem}_{name}{p.suffix}") for name in names]
