"""tools/studies/inversion_recovery.py's arithmetic: coverage with its binomial error, bias in
the axis' coordinate, optical-depth classes, the Markdown report, the instrument lookup.
Outside the default run: ``python -m pytest tools/studies``."""
from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from conftest import STUDIES

sys.path.insert(0, str(STUDIES))

import inversion_recovery as recovery  # noqa: E402
from inversion_study import StudyError  # noqa: E402

KEY = "medium.thickness"


def rows(truths, lows, highs, medians, scale="log", tau=None):
    out = []
    for i, (t, lo, hi, med) in enumerate(zip(truths, lows, highs, medians)):
        r = {"index": float(i), "tau0": float(tau[i] if tau is not None else 10.0 + i),
             f"{KEY}.scale": scale, f"{KEY}.truth": t, f"{KEY}.median": med,
             f"{KEY}.best": med, f"{KEY}.low68": lo, f"{KEY}.high68": hi,
             f"{KEY}.low95": lo / 2 if scale == "log" else lo - 0.05,
             f"{KEY}.high95": hi * 2 if scale == "log" else hi + 0.05,
             f"{KEY}.prior_low": 1e-3 if scale == "log" else 0.1,
             f"{KEY}.prior_high": 1.0 if scale == "log" else 0.9,
             "elapsed_s": 1.0 + i, "evaluations": 700.0, "chi2_per_dof": 1.0,
             "p_value": 0.5, "dchi2_interp": 1.0, "dchi2_nearest": 2.0}
        out.append(r)
    return out


def test_coverage_bias_and_width_of_a_log_axis():
    # 4 injections: the 68 % interval holds the truth in 3; medians 10^±0.1 off
    r = rows([0.01, 0.01, 0.01, 0.01], [0.005, 0.005, 0.005, 0.02], [0.02, 0.02, 0.02, 0.04],
             [0.01 * 10 ** 0.1, 0.01 * 10 ** 0.1, 0.01 * 10 ** -0.1, 0.03])
    s = recovery.key_stats(r, KEY)
    assert s["cover68"] == pytest.approx((0.75, math.sqrt(0.75 * 0.25 / 4)))
    assert s["cover95"][0] == 1.0            # [lo/2, 2 hi] holds 0.01 in all four
    errors = np.log10([10 ** 0.1, 10 ** 0.1, 10 ** -0.1, 3.0])
    assert s["bias"] == pytest.approx(np.median(errors))
    # widths in decades over the prior's 3 decades
    assert s["width68"][0] == pytest.approx(np.log10(4.0) / 3.0)


def test_log1m_axis_is_measured_in_decades_of_one_minus_x():
    assert recovery._coord(0.99, "log1m") == pytest.approx(2.0)
    assert recovery._coord(0.5, "linear") == 0.5 and recovery._coord(100.0, "log") == 2.0


def test_optical_depth_classes_split_in_thirds():
    classes = recovery.tau_classes(np.arange(1.0, 31.0))
    counts = [np.sum((np.arange(1.0, 31.0) >= lo) & (np.arange(1.0, 31.0) < hi))
              for _, lo, hi in classes]
    assert sum(counts) == 30 and max(counts) - min(counts) <= 2


def test_report_compares_instruments_injection_by_injection():
    bela = rows([0.01] * 3, [0.005] * 3, [0.02] * 3, [0.01] * 3)
    narrow = rows([0.01] * 3, [0.01 / 2 ** 0.5] * 3, [0.01 * 2 ** 0.5] * 3, [0.01] * 3)  # half
    lines = recovery.report_tables("fam", {"bela": ([KEY], bela), "gala": ([KEY], narrow)})
    text = "\n".join(lines)
    assert "| BELA | thickness | 3 |" in text and "| GALA | thickness | 3 |" in text
    assert "| thickness | 0.50 [0.50, 0.50] (n = 3) |" in text


def test_unknown_instrument_label_is_refused():
    assert recovery.instrument_source("gala") == "gala"
    assert recovery.instrument_source("bela_5ns").endswith("bela_5ns.yaml")
    with pytest.raises(StudyError):
        recovery.instrument_source("mla")


def test_an_instrument_file_from_anywhere(tmp_path):
    """Issue 41: the instrument of a label is the file given with --instrument, else the copy
    inject kept in the family folder; not only bundled or study instruments."""
    mla = "name: mla\nbase: bela\nadc:\n  sampling_interval: \"5 ns\"\n"
    family = tmp_path / "gran_co2"
    (family / "instruments").mkdir(parents=True)
    (family / "instruments" / "mla.yaml").write_text(mla)
    assert recovery.instrument_source("mla", family) == str(family / "instruments" / "mla.yaml")
    own = tmp_path / "mine" / "mla.yaml"
    own.parent.mkdir()
    own.write_text(mla)
    given = recovery.given_instruments([str(own), "bela"])
    assert given == {"mla": str(own.resolve()), "bela": None}
    assert recovery.instrument_source("mla", family, {"mla": given["mla"]}) == str(own.resolve())
    assert recovery.instrument_source("bela", family) == "bela"
    with pytest.raises(StudyError, match="--instrument FILE"):
        recovery.instrument_source("other", family)


def test_bad_instrument_files_are_refused_before_any_inversion(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nbase: bela\nadcc: {}\n")
    with pytest.raises(StudyError, match="adcc"):
        recovery.given_instruments([str(bad)])
    with pytest.raises(StudyError, match="no such file"):
        recovery.given_instruments([str(tmp_path / "missing.yaml")])
    rc = recovery.main(["invert", "gran_co2", "--work", str(tmp_path), "--instrument",
                        str(bad)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "adcc" in err[0]


def fit_with_posterior(values, mass, key="medium.thickness", scale="log"):
    """A FIT-like Dataset: the refined-grid posterior of one key."""
    import xarray as xr
    return xr.Dataset({"posterior": (("posterior_thickness",), np.asarray(mass, float))},
                      coords={"posterior_thickness": ("posterior_thickness",
                                                      np.asarray(values, float),
                                                      {"sweep_key": key})})


def test_rank_of_the_truth_is_the_marginal_cdf_at_the_truth():
    """Uniform mass on points evenly spaced in ln h: the CDF is linear in ln h between the
    first and last points (each point's mass spread over its trapezoid cell), 0.5 at the
    geometric middle, 0 and 1 at the ends."""
    values = np.exp(np.linspace(0.0, 4.0, 9)) * 1e-3
    fit = fit_with_posterior(values, np.ones(9))
    assert recovery.rank_of_truth(fit, "medium.thickness", values[4], "log") == pytest.approx(0.5)
    assert recovery.rank_of_truth(fit, "medium.thickness", values[0] / 2, "log") == 0.0
    assert recovery.rank_of_truth(fit, "medium.thickness", values[-1] * 2, "log") == 1.0


def test_calibration_tables_flag_undercoverage_and_uneven_ranks():
    """Twenty injections whose 95 % intervals all miss and whose ranks all sit in the top
    bin: the coverage is flagged (0 against 0.95 ± 0.05) and the rank histogram's χ² is 80
    on 4 dof (p ~ 0)."""
    base = rows([1.0] * 20, [3.0] * 20, [4.0] * 20, [3.5] * 20)
    for r in base:
        r["medium.thickness.width_ratio"] = 0.3
        r["medium.thickness.rank"] = 0.99
    text = "\n".join(recovery.calibration_tables({"bela": (["medium.thickness"], base)}))
    assert "0.00 ± 0.05 (n 20) !" in text
    assert "| 0 0 0 0 20 | 80.0 | 0.000 |" in text


def test_calibration_tables_split_by_the_databases_adequacy():
    """Twenty injections, the first eight inverted against a database adequate for their shots
    (stated error of log L 0.5 <= 1) whose intervals hold the truth, the other twelve
    against one that is not (sd 6) whose intervals miss: the strata count 8 and 12 and
    their coverages are 1 and 0; a row without the column (an older recovery file) falls in
    neither."""
    base = rows([1.0] * 21, [0.5] * 8 + [3.0] * 13, [2.0] * 8 + [4.0] * 13, [1.0] * 21)
    for i, r in enumerate(base[:20]):
        r["medium.thickness.width_ratio"] = 0.3
        r["loglike_database_sd"] = 0.5 if i < 8 else 6.0
    base[20]["medium.thickness.width_ratio"] = 0.3
    text = "\n".join(recovery.calibration_tables({"bela": (["medium.thickness"], base)}))
    assert "| BELA | thickness | database adequate | 1.00 ± 0.16 (n 8) | 1.00 ± 0.08 (n 8) |" \
        in text
    assert "| BELA | thickness | database not adequate | 0.00 ± 0.13 (n 12) ! | " \
        "0.00 ± 0.06 (n 12) ! |" in text
    assert "| BELA | thickness | all | 0.38 ± 0.10 (n 21) ! |" in text


def test_the_printed_95_statement_takes_the_bound_at_an_open_edge():
    """Four truths near the prior's edges whose equal-tailed 95 % intervals all miss: a
    lower bound (open upper edge) below the truth, an upper bound above it, both edges
    open, and a plain interval. The printed statements hold the first three, not the
    fourth; rows without ``bound`` are judged by their interval."""
    base = rows([0.89, 0.11, 0.89, 0.5], [0.3] * 4, [0.4] * 4, [0.35] * 4, scale="linear")
    for r, (bound, edge) in zip(base, [(1, 0.3), (2, 0.6), (3, math.nan), (0, math.nan)]):
        r[f"{KEY}.bound"], r[f"{KEY}.bound95"] = bound, edge
    get = lambda s: np.array([r.get(f"{KEY}.{s}", math.nan) for r in base])  # noqa: E731
    assert recovery.printed_95(get).tolist() == [True, True, True, False]
    for r in base:
        del r[f"{KEY}.bound"], r[f"{KEY}.bound95"]
    assert recovery.printed_95(get).tolist() == [False] * 4
    base[0][f"{KEY}.bound"], base[0][f"{KEY}.bound95"] = 1, 0.3
    text = "\n".join(recovery.calibration_tables({"bela": ([KEY], base)}))
    assert "| BELA | thickness | all | 0.00 ± 0.23 (n 4) ! | 0.00 ± 0.11 (n 4) ! | " \
        "0.25 ± 0.11 (n 4) ! |" in text
