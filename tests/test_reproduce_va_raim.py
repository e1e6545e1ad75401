"""``testbed reproduce va-raim-2015``: the baseline-matched scenario against the paper's GPS-only figures, the
verdict rules of the claims table (each flips when its figures cross its threshold), and the per-survey
calibration bias against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import fsolve

from testbed.integrity.vision_ranges import vision_pseudoranges
from testbed.studies import reproduce as R
from testbed.studies.baseline_match import (FAITHFUL, MATCHED, PAPER, baseline_figures, ratios, score, search_spec)
from testbed.studies.campaign_tables import survey_biases, tables
from test_vision_ranges import CAM, K, landmarks, look_at, pixels


# ----------------------------------------------------------------------------- the baseline

def test_the_matched_reading_brings_gps_raim_near_the_papers_baseline_and_the_faithful_one_does_not(tmp_path):
    """At 40 sorties (40 min of sky; the quick run's 200 give HPL 29, VPL 55, MDB 70 m): the matched reading's
    GPS RAIM within a factor 2 of the paper on HPL, VPL and MDB and detecting a 50 m step at ≥ 80 %, scoring
    under half the faithful reading's, whose PLs are a quarter of the paper's."""
    from testbed.campaign.runner import run_campaign

    figs = {}
    for reading in (MATCHED, FAITHFUL):
        loaded = search_spec(40, reading)
        d = tmp_path / loaded.spec.name
        run_campaign(loaded, d, progress=False)
        tb = tables(d)
        figs[reading] = baseline_figures(tb, tb["cells"])
    m, f = ratios(figs[MATCHED]), ratios(figs[FAITHFUL])
    assert all(0.5 < m[k] < 2.0 for k in ("hpl", "vpl", "mdb")), m
    assert figs[MATCHED]["det50"] >= 0.8
    assert f["hpl"] < 0.45 and f["vpl"] < 0.45  # the faithful baseline is the stronger one
    assert score(figs[MATCHED]) < 0.5 * score(figs[FAITHFUL])


def test_the_readings_change_what_the_run_loads():
    from testbed.campaign.spec import expand_cells

    exps = R.loaded_experiments(200)
    cells = expand_cells(exps["baseline-matched"])
    g, t = cells[0].config.gnss, cells[0].config.terrain
    assert (g.elevation_mask_deg, g.sigma_ura_m) == (MATCHED.mask_deg, MATCHED.sigma_ura_m)
    assert t.kind == "two_ridges"
    floor = expand_cells(exps["blur-floor"])
    assert [c.config.vision.detection.blur_model for c in floor] == list(R.BLUR_MODELS)


def test_score_is_zero_at_the_papers_figures_and_grows_with_the_distance():
    assert score(dict(PAPER)) == 0.0
    assert score({**PAPER, "hpl": PAPER["hpl"] * np.e}) == pytest.approx(1 / np.sqrt(len(PAPER)))
    assert score({**PAPER, "mdb": float("inf")}) == float("inf")


# ----------------------------------------------------------------------------- the verdict rules flip

def _det_rows(k_va, k_gps, n=1000, size=10.0):
    from testbed.studies.verdicts import cp_interval

    rows = []
    for m, k in (("va_raim", k_va), ("gps_raim", k_gps)):
        lo, hi = cp_interval(k, n)
        rows.append({"cell": 1, "monitor": m, "fault_size": size, "rate_ep": k / n, "lo_ep": lo, "hi_ep": hi})
    return {"cells": [{"cell": 1, "fault_size": size}], "detection": rows}


def test_detection_verdict_flips_with_the_rates_bands():
    tb = _det_rows(900, 800)
    assert R._detection_claim(tb, tb["cells"], 10.0)[1] is True
    tb = _det_rows(810, 800)  # bands overlap: not a win
    assert R._detection_claim(tb, tb["cells"], 10.0)[1] is False


def test_pl_and_accuracy_rules_flip_at_their_margins():
    assert R._compare(9.8, 10.0, "lower", 0.01) is True and R._compare(9.95, 10.0, "lower", 0.01) is False
    assert R._compare(0.999, 0.998, "higher") is True and R._compare(0.998, 0.998, "higher") is False
    assert R._compare(float("nan"), 1.0, "lower") is None


def _survey_tb(raw, cal, block=10, n_epochs=100):
    """Trials of one GPS-calibrated cell whose surveys (blocks of ``block`` sorties) have the given mean errors."""
    G = len(raw)
    trial = np.arange(G * block)
    g = trial // block
    cols = {"cell": np.zeros(G * block, int), "monitor": np.full(G * block, "va_raim", object), "trial": trial}
    for tag, b in (("raw", np.asarray(raw, float)), ("cal", np.asarray(cal, float))):
        w = 1.0 + (trial % 3)  # unequal epoch counts per sortie: the bias is a weighted mean
        cols[f"vre_{tag}_n"] = (n_epochs * w).astype(float)
        cols[f"vre_{tag}_sum"] = b[g] * n_epochs * w
    return {"cells": [{"cell": 0, "calibration": "gps", "lpe_sigma_m": 0.1}], "trials": cols, "block_trials": block}


def test_calibration_verdict_follows_each_surveys_bias():
    rng = np.random.default_rng(0)
    raw = rng.normal(0.0, 4.7, 20)
    holds = _survey_tb(raw, 0.1 * raw)
    assert R._calibration_claim(holds)[1] is True
    fails = _survey_tb(raw, 3.0 * raw)
    assert R._calibration_claim(fails)[1] is False
    few = _survey_tb(raw[:3], 0.1 * raw[:3])  # 3 surveys: the paired test cannot reach 5 %
    assert R._calibration_claim(few)[1] is None


def test_vision_fault_verdict_and_its_mechanism_follow_the_measured_counts():
    from testbed.studies.verdicts import cp_interval

    def tb(rate_at_big):
        rows = []
        for cell, size in enumerate((0.0, 10.0, 50.0)):
            k = int(1000 * (rate_at_big if size == 50.0 else 0.5 if size else 0.0))
            lo, hi = cp_interval(k, 1000)
            rows.append({"cell": cell, "monitor": "va_raim", "fault_size": size, "rate_ep": k / 1000, "lo_ep": lo,
                         "hi_ep": hi})
        cells = [{"cell": i, "fault_size": s, "fault_kind": "none" if s == 0 else "pixel_bias"}
                 for i, s in enumerate((0.0, 10.0, 50.0))]
        trials = {"cell": np.array([2]), "monitor": np.array(["va_raim"], object), "vf_epochs": np.array([200]),
                  "vf_gate_dropped": np.array([150]), "vf_rows_used": np.array([20])}
        return {"cells": cells, "detection": rows, "trials": trials}

    txt, ok, why = R._vision_fault_claim(tb(0.995))
    assert ok is True
    txt, ok, why = R._vision_fault_claim(tb(0.2))
    assert ok is False and "150 of 200 faulty epochs (75.0 %)" in why and "at 20 (10.0 %)" in why


# ----------------------------------------------------------------------------- per-survey bias, closed forms

def test_survey_biases_recover_each_surveys_weighted_mean():
    raw = np.array([4.7, -1.0, 0.3])
    tb = _survey_tb(raw, raw / 10)
    sb = survey_biases(tb, tb["cells"][0])
    np.testing.assert_allclose(sb["raw"], raw, rtol=1e-12)
    np.testing.assert_allclose(sb["cal"], raw / 10, rtol=1e-12)
    assert list(sb["survey"]) == [0, 1, 2]


def test_a_known_survey_error_biases_the_ranges_as_the_cosine_rule_solved_independently_says():
    """Noise-free pixels of the true landmarks, ranges solved with surveyed ones off by a known error: the
    ranges' error (the survey's bias on them) equals the brute-force solution of the three cosine-rule
    equations with the surveyed distances (scipy's fsolve), and to first order (A δm = B δd²)."""
    P = landmarks(3)
    delta = np.array([[0.07, -0.02, 0.01], [-0.05, 0.04, 0.0], [0.02, 0.06, -0.03]])  # a 5-7 cm survey error
    S = P + delta
    uv = pixels(P, CAM, look_at(CAM, np.zeros(3)))
    m_true = np.linalg.norm(P - CAM, axis=1)
    out = vision_pseudoranges(uv, np.ones(3, bool), K, np.ones(3), S, m_true)
    b = (P - CAM) / m_true[:, None]
    pairs = ((0, 1), (0, 2), (1, 2))
    c = np.array([b[i] @ b[j] for i, j in pairs])
    d2 = np.array([np.sum((S[i] - S[j]) ** 2) for i, j in pairs])
    f = lambda m: [m[i] ** 2 + m[j] ** 2 - 2 * m[i] * m[j] * c[k] - d2[k] for k, (i, j) in enumerate(pairs)]  # noqa: E731
    m_brute = fsolve(f, m_true, xtol=1e-13)
    np.testing.assert_allclose(out.m, m_brute, atol=1e-4)
    assert np.abs(out.m - m_true).max() > 0.5  # cm of survey error: metres of range bias at 2 km
    A = np.zeros((3, 3))
    for k, (i, j) in enumerate(pairs):
        A[k, i], A[k, j] = 1 / m_true[j] - c[k] / m_true[i], 1 / m_true[i] - c[k] / m_true[j]
    d2_true = np.array([np.sum((P[i] - P[j]) ** 2) for i, j in pairs])
    B = np.array([1 / (2 * m_true[i] * m_true[j]) for i, j in pairs])
    np.testing.assert_allclose(out.m - m_true, np.linalg.solve(A, B * (d2 - d2_true)), rtol=0.02)
