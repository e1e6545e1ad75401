"""The campaign report's statistics and figures on tables built here (no campaign run): faults that were
never exercised, the minimal detectable bias against closed-form detection curves, what the figures draw."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

from testbed.campaign.detection import binomial_interval, detection_table, minimal_detectable_bias
from testbed.campaign.report import detection_figure, group_mdbs, vision_range_figure

POWER = 0.99


def _cell(i: int, kind: str, size: float) -> dict:
    return {"cell": i, "fault_kind": kind, "fault_sweep_kind": "gps_step", "fault_size": size, "fault_unit": "m",
            "fault_family": 0}


def test_trials_that_never_exercise_their_fault_are_counted_apart_not_missed():
    """A faulty trial with no faulty epoch at which the monitor has a solution (onset_epochs 0) is neither
    a detection (its alert after the onset is a false alarm) nor a miss: it leaves the rate and is counted
    in not_exercised. A cell none of whose trials exercised its fault has no rate at all (it was
    "0 of 4 detected"). Fault-free cells count every trial."""
    cells = [_cell(0, "none", 0.0), _cell(1, "gps_step", 20.0), _cell(2, "gps_step", 20.0)]
    trials = {"cell": np.repeat([0, 1, 2], 4), "monitor": np.array(["m"] * 12),
              "detected": np.array([0, 1, 0, 0, 1, 1, 0, 0, 0, 1, 0, 0], bool),
              "onset_epochs": np.array([40, 40, 0, 40, 25, 0, 12, 0, 0, 0, 0, 0]),
              "onset_alerts": np.array([0, 2, 0, 0, 20, 0, 0, 0, 0, 0, 0, 0])}
    free, partial, never = detection_table(cells, trials)
    assert (free["n"], free["n_ex"], free["not_exercised"], free["k"]) == (4, 4, 0, 1)
    assert (partial["n"], partial["n_ex"], partial["not_exercised"], partial["k"]) == (4, 2, 2, 1)
    assert partial["rate"] == 0.5  # 1 of the 2 exercised, not 2 of 4 (trial 5 alerted with no fault present)
    lo, hi = binomial_interval(np.array([1]), np.array([2]))
    assert (partial["lo"], partial["hi"]) == (float(lo[0]), float(hi[0]))
    assert (partial["n_ep"], partial["k_ep"]) == (37, 20) and partial["rate_ep"] == 20 / 37
    assert (never["n_ex"], never["not_exercised"], never["k"]) == (0, 4, 0)
    assert all(np.isnan(never[k]) for k in ("rate", "lo", "hi", "rate_ep", "lo_ep", "hi_ep"))
    # a size whose fault was never exercised is not a measured point of the MDB
    assert not minimal_detectable_bias([0, 20], [0.0, never["rate"]], POWER).reached


def test_the_mdb_is_a_bracket_unless_adjacent_sizes_resolve_it():
    """Two swept sizes, 0 and 20 m, give "between 0 and 20 m", not the 19.8 m a line across the whole rise
    of the curve gives; not reached, reached at once, a size not exercised in the bracket."""
    m = minimal_detectable_bias([0, 20], [0.0, 1.0], POWER)
    assert not m.resolved and (m.low, m.high) == (0, 20) and m.text("m") == "between 0 and 20 m"
    assert minimal_detectable_bias([0, 10, 20], [0.0, 0.5, 1.0], POWER).value == pytest.approx(19.8)
    assert minimal_detectable_bias([0, 10, 20], [0.0, 0.4, 1.0], POWER).text("m") == "between 10 and 20 m"
    assert minimal_detectable_bias([0, 10], [0.0, 0.5], POWER).text("m") == "> 10 m (not reached)"
    assert minimal_detectable_bias([5, 10], [0.995, 1.0], POWER).text("m") == "≤ 5 m (the smallest size)"
    gap = minimal_detectable_bias([0, 10, 15, 20], [0.0, 0.9, np.nan, 1.0], POWER)  # 15 not exercised
    assert not gap.resolved and (gap.low, gap.high) == (10, 20)
    assert minimal_detectable_bias([10, 20], [np.nan, np.nan], POWER).text() == "-"


def test_the_mdb_brackets_the_true_one_and_its_interpolation_errs_on_the_large_side():
    """Against closed-form detection curves P_D(s) = Φ((s − μ)/σ) (a Gaussian test statistic's), true MDB
    μ + σ·Φ⁻¹(P), sampled exactly at random sweeps: the bracket always holds the true MDB, and the
    interpolated value, where given, lies between the true MDB and the bracket's top."""
    rng = np.random.default_rng(4)
    resolved = brackets = 0
    for _ in range(2000):
        mu, sd = rng.uniform(2.0, 40.0), rng.uniform(0.3, 10.0)
        true = mu + sd * norm.ppf(POWER)
        sizes = np.sort(rng.choice(np.arange(0.0, 100.0, 2.5), size=int(rng.integers(2, 10)), replace=False))
        m = minimal_detectable_bias(sizes, norm.cdf((sizes - mu) / sd), POWER)
        if not m.reached:
            assert true > m.low
            continue
        assert (np.isnan(m.low) or m.low < true) and true <= m.high
        if m.resolved:
            resolved += 1
            assert true - 1e-9 <= m.value <= m.high
        else:
            brackets += 1
    assert resolved > 200 and brackets > 200  # both kinds were exercised


def test_the_mdbs_confidence_bracket_covers_the_true_mdb():
    """Binomial draws of n trials per size from a known curve: the Clopper-Pearson bracket (ci_low, ci_high]
    holds the true MDB in at least 90 % of 400 campaigns (each bound fails at a size with probability
    ≤ 2.5 %), and the measured bracket without the confidence bounds does markedly less often."""
    rng = np.random.default_rng(9)
    sizes = np.array([0.0, 5.0, 10.0, 15.0, 20.0, 30.0])
    mu, sd, n = 9.0, 3.0, 400
    true = mu + sd * norm.ppf(POWER)  # 15.98 m: the measured bracket (15, 20] is right only by luck of the draw
    p = norm.cdf((sizes - mu) / sd)
    ci = measured = 0
    for _ in range(400):
        k = rng.binomial(n, p)
        lo, hi = binomial_interval(k, np.full(k.shape, n))
        m = minimal_detectable_bias(sizes, k / n, POWER, lo, hi)
        ci += (np.isnan(m.ci_low) or m.ci_low < true) and true <= m.ci_high
        measured += (np.isnan(m.low) or m.low < true) and true <= m.high
    assert ci / 400 >= 0.9 and measured / 400 < ci / 400


def _groups(rates: dict[float, float], n: int = 100) -> dict[str, list[dict]]:
    rows = []
    for size, r in rates.items():
        k = np.nan if np.isnan(r) else round(r * n)
        lo, hi = (np.nan, np.nan) if np.isnan(r) else (float(v[0]) for v in binomial_interval([k], [n]))
        rows.append({**_cell(len(rows), "none" if size == 0 else "gps_step", size), "rate": r, "lo": lo, "hi": hi,
                     "rate_ep": r, "lo_ep": lo, "hi_ep": hi})
    return {"gps_raim": rows}


def test_the_detection_figure_draws_measured_points_and_no_line_across_an_unexercised_size():
    """Only what was measured: points at the measured sizes, a dotted join broken at a size whose fault was
    not exercised (marked x on the axis), and the MDB on the power line as its bracket (0-20 m here), with no
    tick at an interpolated value the sizes do not resolve."""
    from matplotlib.collections import LineCollection

    groups = _groups({0.0: 0.0, 10.0: np.nan, 20.0: 1.0})
    mdbs = {lab: group_mdbs(rs, POWER) for lab, rs in groups.items()}
    assert (mdbs["gps_raim"]["sortie"].low, mdbs["gps_raim"]["sortie"].high) == (0, 20)
    fig = detection_figure("gps_step size (m)", groups, mdbs, POWER, "test")
    for ax in fig.axes:
        joins = [ln for ln in ax.get_lines() if ln.get_linestyle() == ":" and len(ln.get_xdata()) == 3]
        assert len(joins) == 1
        x, y = np.asarray(joins[0].get_xdata(), float), np.asarray(joins[0].get_ydata(), float)
        assert np.isnan(y[x == 10.0]).all()  # the join stops at 10 m: no segment from 0 to 20 m
        marks = [ln for ln in ax.get_lines() if ln.get_marker() == "x"]
        assert len(marks) == 1 and list(marks[0].get_xdata()) == [10.0]
        bracket = [ln for ln in ax.get_lines() if ln.get_linewidth() >= 5]
        assert len(bracket) == 1 and list(bracket[0].get_xdata()) == [0.0, 20.0]
        assert not [ln for ln in ax.get_lines() if ln.get_marker() == "|"]  # no interpolated MDB
        bars = [c for c in ax.collections if isinstance(c, LineCollection)]
        assert bars and all(len(c.get_segments()) == 2 for c in bars)  # an interval at each measured size


def _vr_row(cell: int, calibration: str, lpe: float, cal_mean: float) -> dict:
    return {"cell": cell, "fault_kind": "none", "lpe_sigma_m": lpe, "dpi": 720.0, "sigma_px": 1.0,
            "calibration": calibration, "raw_mean": 3.0, "raw_std": 300.0, "cal_mean": cal_mean,
            "cal_std": 0.5 if cal_mean == cal_mean else np.nan}


@pytest.mark.parametrize("calibration, cal_mean, want, unwanted", [
    ("gps", np.nan, "raw ranges (before GPS calibration)", "uncalibrated"),
    ("gps", 0.1, "after GPS calibration", "uncalibrated"),
    ("none", np.nan, "raw ranges (uncalibrated: calibration = none)", "before GPS calibration"),
])
def test_the_vision_range_figure_says_what_the_spec_calibrates_and_spreads_one_setting(calibration, cal_mean,
                                                                                       want, unwanted):
    """Its series are named after the cells' calibration setting (a calibrating spec's raw ranges were
    labelled "uncalibrated"), a calibrating spec with no calibrated epoch says so, and one LPE value is a
    category on a readable axis, not a window of 0.048-0.052 m around one point."""
    fig = vision_range_figure([_vr_row(0, calibration, 0.05, cal_mean), {**_vr_row(1, calibration, 0.05, cal_mean),
                                                                         "fault_kind": "gps_step"}])
    (ax,) = fig.axes
    labels = ax.get_legend_handles_labels()[1]
    assert any(want in lab for lab in labels) and not any(unwanted in lab for lab in labels)
    notes = [t.get_text() for t in ax.texts]
    assert any("no epoch was calibrated" in t for t in notes) == (calibration == "gps" and cal_mean != cal_mean)
    lo, hi = ax.get_xlim()
    assert hi - lo >= 1.0 and "0.05" in ax.get_xlabel()
    many = vision_range_figure([_vr_row(k, calibration, lpe, cal_mean) for k, lpe in enumerate((0.0, 0.05, 0.1))])
    lo, hi = many.axes[0].get_xlim()
    assert lo <= 0.0 and hi >= 0.1  # a swept axis spans its values


def test_a_trial_whose_fault_reached_no_observation_is_not_exercised_whatever_its_epochs_say():
    """A block whose fault hit no satellite or landmark (fault_target -1) has all its epochs marked as
    carrying the fault by the runner's fault-free convention; such trials are not exercised, in both the
    per-sortie and the per-epoch counts."""
    cells = [_cell(0, "gps_step", 20.0)]
    trials = {"cell": np.zeros(3, int), "monitor": np.array(["m"] * 3), "detected": np.array([1, 0, 0], bool),
              "onset_epochs": np.array([26, 26, 26]), "onset_alerts": np.array([10, 0, 0]),
              "fault_target": np.array([5, -1, -1])}
    (r,) = detection_table(cells, trials)
    assert (r["n_ex"], r["not_exercised"], r["k"], r["n_ep"], r["k_ep"]) == (1, 2, 1, 26, 10)


def test_availability_over_the_day_from_sorties_spread_over_a_day(tmp_path):
    """Sorties spread over a day get the availability-over-the-day section: each sortie's start hour is its cell's
    UTC start plus its offset, and the table's day-long figure is the mean of the trials' availability column."""
    import datetime as dt

    import pyarrow.parquet as pq

    from testbed.campaign.report import hour_of_day, write_report
    from testbed.campaign.runner import run_campaign

    spec = tmp_path / "day.toml"
    spec.write_text('name = "day"\napproaches = ["zunz-rwy05-final"]\nmonitors = ["gps_raim"]\ntrials = 12\n'
                    'base_seed = 3\nduration_s = 2.0\n[sorties]\nstart = "uniform"\nspan_s = 86400.0\n'
                    'window_s = 900.0\nsortie_s = 5.0\n')
    out = run_campaign(spec, tmp_path / "o", progress=False).out_dir
    cells = pq.read_table(out / "cells.parquet").to_pylist()
    tr = pq.read_table(out / "trials.parquet").to_pydict()
    t0 = dt.datetime.fromisoformat(cells[0]["start_time_utc"])
    midnight = t0.replace(hour=0, minute=0, second=0, microsecond=0)
    expected = [(t0 + dt.timedelta(seconds=s) - midnight).total_seconds() / 3600.0 for s in tr["start_offset_s"]]
    got = hour_of_day(cells, np.asarray(tr["cell"]), np.asarray(tr["start_offset_s"]))
    assert np.allclose(got, np.mod(expected, 24.0), atol=1e-6)
    text = write_report(out).read_text()
    assert "## Availability over the day" in text and (out / "figures" / "availability_over_day.png").is_file()
    day = text[text.index("## Availability over the day"):]
    row = next(line for line in day.splitlines() if line.startswith("| all cells | gps_raim |"))
    assert f"{100 * np.mean(tr['avail_LPV-200']):.1f} %" == row.split("|")[4].strip()
