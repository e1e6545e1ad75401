"""VA-RAIM: calibration, calibrated covariances, false-alarm rate, detection power, degenerate epochs.

The scenario is the VA-RAIM paper §3.1 (tests/test_va_raim_scenario.py). References:
Monte Carlo sample statistics with binomial / standard-error bounds at fixed
seeds, the non-central chi-square detection probability (scipy), and a
brute-force calibration epoch choice.
"""

from __future__ import annotations

import numpy as np
from record_checks import assert_records_equal
import pytest
from scipy import stats
from test_va_raim_scenario import (K_CAM, make_scenario, project, seed_frame, seed_landmarks_enu, seed_truth,
                                   sensor_positions)

from testbed.integrity.calibration import calibrate, calibration_epochs, landmark_set_key
from testbed.integrity.settings import IntegritySettings
from testbed.integrity.va_raim import VaRaimSettings, va_raim
from testbed.integrity.vision_ranges import VisionReason, vision_pseudoranges

P_FA_TEST = 1e-2


def outward_survey_error(per_axis_m: float = 0.05) -> np.ndarray:
    """A fixed landmark survey error: each landmark √3·5 cm radially outward (the norm of a 5 cm-per-axis
    error), i.e. the triangle surveyed 0.087% too large — the worst direction for the ranges."""
    p = seed_landmarks_enu(3)
    return per_axis_m * np.sqrt(3) * p / np.linalg.norm(p, axis=1, keepdims=True)


# --------------------------------------------------------------------------- calibration epoch choice


def test_calibration_epochs_match_brute_force():
    rng = np.random.default_rng(4)
    cand = rng.random((50, 40)) < 0.3
    key = rng.integers(-1, 3, (50, 40))
    got = calibration_epochs(cand, key)
    for b in range(50):  # brute force, one trial and epoch at a time
        for k in range(40):
            first = [j for j in range(k + 1) if cand[b, j] and key[b, j] == key[b, k] and key[b, k] >= 0]
            assert got[b, k] == (first[0] if first else -1)


def test_landmark_set_key_distinguishes_sets():
    used = np.array([[True, True, True, False], [True, True, False, True], [True, True, True, False]])
    key = landmark_set_key(used, np.array([True, True, False]))
    assert key[0] != key[1] and key[2] == -1


# --------------------------------------------------------------------------- calibrated covariance


@pytest.mark.parametrize("n_landmarks", [3, 4])
def test_calibrated_covariance_matches_monte_carlo(n_landmarks):
    """ẑ_V(k) − r(x(k)) (r from the surveyed landmarks: the monitor's model) against Σ̂_V(k).

    Calibration at t = 40 s (≈3 km), evaluation at t = 60 s (≈2 km) of the seed path; errors from the
    pixels at both epochs and from the GPS fix at the calibration epoch (Δ_G = diag(1, 1.5, 4) m²).
    """
    rng = np.random.default_rng(20 + n_landmarks)
    n = 20_000
    frame = seed_frame()
    truth = seed_truth(frame, 0.05, 40.0, 60.0)
    cam, _, Rc = sensor_positions(frame, truth)
    p = seed_landmarks_enu(n_landmarks)
    survey_sigma = 0.05 if n_landmarks == 3 else 0.0  # N_V > 3: residual survey term tested below
    ps = p + (outward_survey_error()[:n_landmarks] if n_landmarks == 3 else 0.0)
    uv = project(p, cam, Rc)[None] + rng.standard_normal((n, 2, n_landmarks, 2))
    m_surv = np.linalg.norm(ps - cam[:, None, :], axis=-1)
    vr = vision_pseudoranges(uv, np.ones((n, 2, n_landmarks), bool), K_CAM, 1.0, ps,
                             np.broadcast_to(m_surv, (n, 2, n_landmarks)))
    assert vr.ok.all()
    Pg = np.diag([1.0, 1.5, 4.0])
    xg = np.broadcast_to(truth.pos_enu, (n, 2, 3)).copy()
    xg[:, 0] += rng.multivariate_normal(np.zeros(3), Pg, n)
    off = cam - truth.pos_enu
    cr = calibrate(vr, np.zeros((n, 2), int), xg, np.broadcast_to(Pg, (n, 2, 3, 3)),
                   np.broadcast_to(off, (n, 2, 3)), ps, survey_sigma)
    err = cr.z_hat[:, 1] - m_surv[1]
    S = cr.Sigma_hat[:, 1].mean(0)
    lam, V = np.linalg.eigh(S)
    proj = err @ V
    ratio = proj.var(0, ddof=1) / lam
    tol = 5 * np.sqrt(2 / n) + 0.02  # 5 standard errors of a variance + 2% linearisation
    assert np.all(np.abs(ratio - 1) < tol), ratio
    # no bias left along any eigen-direction (5 standard errors)
    assert np.all(np.abs(proj.mean(0)) < 5 * np.sqrt(lam / n) + 0.02), (proj.mean(0), np.sqrt(lam / n))
    # NEES ~ chi2(N_V): mean N_V within 5 standard errors sqrt(2 N_V / n) (+2%)
    w = np.linalg.solve(cr.Sigma_hat[:, 1], err[..., None])[..., 0]
    nees = np.mean(np.sum(err * w, -1))
    assert abs(nees / n_landmarks - 1) < 5 * np.sqrt(2 / (n_landmarks * n)) + 0.02


def test_residual_survey_term_for_more_than_three_landmarks():
    """N_V = 4, no pixel or GPS noise: the calibrated error is the linear survey term L_d δd² — not zero
    (the seed's cancellation is exact for N_V = 3 only) — and matches its first-order prediction."""
    frame = seed_frame()
    truth = seed_truth(frame, 0.05, 40.0, 60.0)
    cam, _, Rc = sensor_positions(frame, truth)
    p = seed_landmarks_enu(4)
    dp = np.array([[0.05, -0.03, 0.02], [-0.04, 0.05, -0.05], [0.03, 0.04, 0.05], [-0.05, -0.05, 0.01]])
    errs = []
    for scale in (1.0, 2.0):
        ps = p + scale * dp
        uv = project(p, cam, Rc)[None]
        m_surv = np.linalg.norm(ps - cam[:, None, :], axis=-1)
        vr = vision_pseudoranges(uv, np.ones((1, 2, 4), bool), K_CAM, 1.0, ps, m_surv[None])
        xg = truth.pos_enu[None]
        cr = calibrate(vr, np.zeros((1, 2), int), xg, np.zeros((1, 2, 3, 3)), (cam - truth.pos_enu)[None], ps,
                       0.05)
        errs.append(cr.z_hat[0, 1] - m_surv[1])
    # first order: doubling the survey error doubles the residual (to a few %)
    assert np.abs(errs[0]).max() > 1e-3
    np.testing.assert_allclose(errs[1], 2 * errs[0], rtol=0.05, atol=2e-4)


# --------------------------------------------------------------------------- calibration removes survey bias


def test_calibration_removes_landmark_survey_bias(record_property):
    """Seed scenario, LPE 5 cm per axis (fixed, radially outward), 1 px, 3000 trials.

    Calibration at t = 40 s (GPS RAIM available), evaluated at t = 60 s against the *true* ranges.
    """
    rng = np.random.default_rng(7)
    n = 3000
    sc = make_scenario(rng, (n,), t0=40.0, t1=60.0, rate_hz=0.1, survey_error=outward_survey_error())
    out = va_raim(sc.gnss, sc.vision, sc.frame, VaRaimSettings(variant="seed"))  # the seed's own rows
    d = out.diagnostics
    assert np.all(d.cal_t[:, -1] == sc.gnss.t[0])
    raw = d.vision_m[:, -1] - sc.m_true[-1]
    cal = d.z_hat[:, -1] - sc.m_true[-1]
    se_raw = raw.std(0, ddof=1) / np.sqrt(n)
    se_cal = cal.std(0, ddof=1) / np.sqrt(n)
    record_property("raw_mean_m", raw.mean(0).round(3).tolist())
    record_property("raw_se_m", se_raw.round(3).tolist())
    record_property("cal_mean_m", cal.mean(0).round(3).tolist())
    record_property("cal_se_m", se_cal.round(3).tolist())
    # before: the survey bias (≈ range × 8.7e-4 ≈ 1.7 m at 2 km) stands out of the noise
    assert np.all(np.abs(raw.mean(0)) > 5 * se_raw)
    assert np.all(np.abs(raw.mean(0) - 2000 * 8.66e-4) < 1.0)
    # after: consistent with zero
    assert np.all(np.abs(cal.mean(0)) < 3 * se_cal)


# --------------------------------------------------------------------------- false alarms and detection


def _fa_run(seed: int, n: int, **kw):
    rng = np.random.default_rng(seed)
    sc = make_scenario(rng, (n,), t0=40.0, t1=60.0, rate_hz=0.1, survey_error=outward_survey_error(), **kw)
    st = VaRaimSettings(integrity=IntegritySettings(p_fa=P_FA_TEST))
    return sc, va_raim(sc.gnss, sc.vision, sc.frame, st)


def test_false_alarm_rate_within_binomial_interval(record_property):
    """P_FA = 1e-2, calibrated vision rows with their covariances: one epoch per trial (t = 60 s) so
    the trials are independent; the alert count must fall in the binomial 99% interval."""
    n = 4000
    sc, out = _fa_run(8, n)
    d = out.diagnostics
    k = -1
    assert d.vision_rows_used[:, k].mean() > 0.99
    assert np.all(out.reason[:, k] == 0)
    alerts = int(out.alert[:, k].sum())
    lo, hi = stats.binom.interval(0.99, n, P_FA_TEST)
    record_property("va_raim_alerts", alerts)
    record_property("gps_alerts", int(d.gps.alert[:, k].sum()))
    record_property("binomial_99", (float(lo), float(hi)))
    assert lo <= alerts <= hi, (alerts, lo, hi)
    # the SSE has the chi-square law with N - 4 dof (KS test at the 1% level)
    dof = int(out.n_used[0, k]) - 4
    assert np.all(out.n_used[:, k] - 4 == dof)
    assert stats.kstest(out.test_stat[:, k], stats.chi2(dof).cdf).pvalue > 0.01


def test_gps_bias_detection_power_matches_noncentral_chi_square(record_property):
    """A step on one satellite sized for λ ≈ 12 (detection probability ≈ 0.6): the VA-RAIM alert rate
    matches 1 − F_ncx2(T²; N−4, λ = b²(WS)_ii) within the binomial 99% interval."""
    n = 3000
    sc0, out0 = _fa_run(9, 1, gps_noise=False)
    k = -1
    vis = sc0.gnss.visible[0, k]
    slot = int(np.nonzero(vis)[0][2])
    row = slot  # stacked-row diagnostics keep the satellite slots
    b = float(np.sqrt(12.0 / out0.diagnostics.ws_diag[0, k, row]))
    bias = np.zeros((n, 3, vis.size))
    bias[:, k, slot] = b
    sc, out = _fa_run(10, n, gps_bias=bias)
    d = out.diagnostics
    lam = b**2 * d.ws_diag[:, k, row]
    assert np.std(lam) < 0.05 * lam.mean()  # geometry and weights barely vary across trials
    dof = out.n_used[0, k] - 4
    p_det = 1 - stats.ncx2.cdf(out.threshold[0, k], dof, lam.mean())
    det = int(out.alert[:, k].sum())
    lo, hi = stats.binom.interval(0.99, n, p_det)
    record_property("bias_m", round(b, 2))
    record_property("va_raim_detections", det)
    record_property("predicted_p_det", round(float(p_det), 4))
    record_property("gps_only_detections", int(d.gps.alert[:, k].sum()))
    assert 0.2 < p_det < 0.95
    assert lo <= det <= hi, (det, lo, hi, p_det)


# --------------------------------------------------------------------------- availability and degenerate epochs


def test_vision_unavailable_epochs_fall_back_to_gps_rows_without_spoiling_the_batch():
    rng = np.random.default_rng(12)
    sc = make_scenario(rng, (4,), t0=40.0, t1=60.0, rate_hz=0.5)
    uv = sc.vision.pixel_uv.copy()
    det = sc.vision.detected.copy()
    det[1, 5, 1:] = False  # < 3 landmarks
    uv[2, 6, :2] = np.nan  # NaN pixels
    from dataclasses import replace
    vis = replace(sc.vision, pixel_uv=uv, detected=det)
    out = va_raim(sc.gnss, vis, sc.frame)
    d = out.diagnostics
    assert d.vision_reason[1, 5] == VisionReason.TOO_FEW_LANDMARKS
    assert d.vision_reason[2, 6] == VisionReason.NAN_PIXELS
    assert not d.vision_rows_used[1, 5] and not d.vision_rows_used[2, 6]
    assert out.reason[1, 5] == 0 and out.n_used[1, 5] == d.n_gps[1, 5]
    # the other trials are untouched: same numbers as the unmodified run
    ref = va_raim(sc.gnss, sc.vision, sc.frame)
    np.testing.assert_array_equal(out.test_stat[[0, 3]], ref.test_stat[[0, 3]])
    np.testing.assert_array_equal(out.hpl[[0, 3]], ref.hpl[[0, 3]])


def test_vision_adds_rows_and_lowers_protection_levels():
    rng = np.random.default_rng(13)
    sc = make_scenario(rng, (50,), t0=40.0, t1=60.0, rate_hz=0.1)
    out = va_raim(sc.gnss, sc.vision, sc.frame, VaRaimSettings(variant="seed"))
    gps = out.diagnostics.gps
    k = -1
    assert np.all(out.n_used[:, k] == gps.n_used[:, k] + 3)
    assert np.all(out.diagnostics.modified[:, k])
    # more rows never loosen the (pbias) slope bound on the GPS rows' fault-free part; check the fix sigma
    assert np.all(out.diagnostics.lam_det[:, k] > 0)


def test_modified_equation_changes_slopes_not_fix_or_sse():
    rng = np.random.default_rng(14)
    sc = make_scenario(rng, (20,), t0=40.0, t1=60.0, rate_hz=0.1)
    a = va_raim(sc.gnss, sc.vision, sc.frame, VaRaimSettings(modified_equation=True, variant="seed"))
    b = va_raim(sc.gnss, sc.vision, sc.frame, VaRaimSettings(modified_equation=False, variant="seed"))
    np.testing.assert_allclose(a.pos_enu, b.pos_enu, atol=1e-6)
    np.testing.assert_allclose(a.test_stat, b.test_stat, rtol=1e-6, atol=1e-9)
    assert not np.allclose(a.diagnostics.hslope[:, -1], b.diagnostics.hslope[:, -1], equal_nan=True)


def test_rerun_is_bit_identical():
    sc = make_scenario(np.random.default_rng(15), (3,), t0=40.0, t1=60.0, rate_hz=0.2)
    a = va_raim(sc.gnss, sc.vision, sc.frame)
    b = va_raim(sc.gnss, sc.vision, sc.frame)
    for f in ("pos_enu", "hpl", "vpl", "test_stat"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))


def test_settings_reject_impossible_values():
    with pytest.raises(ValueError, match="calibration_level"):
        VaRaimSettings(calibration_level="CAT-III")
    with pytest.raises(ValueError):
        VaRaimSettings(landmark_survey_sigma_m=-1.0)
    with pytest.raises(ValueError):
        VaRaimSettings(unknown_key=1)


def test_gps_baseline_equals_the_gps_raim_module():
    """VA-RAIM's step 1 *is* the GPS RAIM monitor: bit-identical output, diagnostics included
    (so a campaign may reuse it), and its fix moved through the lever arm is the reference point."""
    from testbed.frames import q_to_R
    from testbed.integrity.raim import gps_raim
    sc = make_scenario(np.random.default_rng(16), (5,), t0=40.0, t1=60.0, rate_hz=0.5)
    out = va_raim(sc.gnss, sc.vision, sc.frame)
    ref = gps_raim(sc.gnss, sc.frame, IntegritySettings())
    assert_records_equal(out.diagnostics.gps, ref)
    off = q_to_R(sc.vision.q_body_to_enu_ref) @ sc.gnss.antenna.lever_arm_body
    at_cg = gps_raim(sc.gnss, sc.frame, IntegritySettings(), antenna_offset_enu=off)
    np.testing.assert_allclose(ref.pos_enu - off, at_cg.pos_enu, atol=1e-6)  # the same fix, 1e-6 m
    for f in ("hpl", "vpl", "test_stat", "threshold"):
        np.testing.assert_allclose(getattr(ref, f), getattr(at_cg, f), rtol=1e-6, atol=1e-9, err_msg=f)


def test_epochs_without_a_vision_row_are_gps_raims_fix_bit_for_bit(monkeypatch):
    """Where no vision row is used (the calibration epoch, too few landmarks, a trial without any), VA-RAIM's
    rows are GPS RAIM's, and so is its answer, bit for bit: PLs, SSE, threshold, alert, reason, slopes, and
    the fix moved through the lever arm. The integrated solve of those same rows (what it ran before it took
    step 1's answer there) agrees within its iteration tolerance, and every other epoch is untouched."""
    from dataclasses import replace

    from testbed.frames import q_to_R
    from testbed.integrity import va_raim as va_raim_module
    sc = make_scenario(np.random.default_rng(31), (6,), t0=30.0, t1=60.0, rate_hz=1.0)
    det = sc.vision.detected.copy()
    det[1, 5:9, 2] = False  # too few landmarks
    det[3] = False  # no landmark in the whole sortie
    pr = sc.gnss.pseudorange.copy()
    pr[3, 12:, np.flatnonzero(sc.gnss.visible[3, 12])[0]] += 80.0  # a GPS step where vision is not used
    gnss, vision = replace(sc.gnss, pseudorange=pr), replace(sc.vision, detected=det)
    out = va_raim(gnss, vision, sc.frame, VaRaimSettings(variant="seed"))
    d, gps = out.diagnostics, out.diagnostics.gps
    gps_only = ~d.vision_rows_used
    assert 30 < gps_only.sum() < gps_only.size - 60 and gps_only[3].all() and gps_only[:, 0].all()
    assert (gps.alert & gps_only).any()  # the step is seen
    for f in ("hpl", "vpl", "test_stat", "threshold", "alert", "reason", "n_used", "clock"):
        np.testing.assert_array_equal(getattr(out, f)[gps_only], getattr(gps, f)[gps_only], err_msg=f)
    S = gps.diagnostics.hslope.shape[-1]
    for f in ("hslope", "vslope", "residual", "hpl_seed", "vpl_seed", "hpl_pbias", "vpl_pbias", "lam_det", "cond"):
        a, b = getattr(d, f), getattr(gps.diagnostics, f)
        np.testing.assert_array_equal(a[gps_only][..., :S] if a.ndim > 2 else a[gps_only], b[gps_only], err_msg=f)
    assert np.isnan(d.hslope[gps_only][:, S:]).all()
    off = q_to_R(sc.vision.q_body_to_enu_ref) @ gnss.antenna.lever_arm_body
    np.testing.assert_array_equal(out.pos_enu[gps_only], (gps.pos_enu - off)[gps_only])

    solve_all = va_raim_module._integrated_fix
    monkeypatch.setattr(va_raim_module, "_integrated_fix", lambda need, *a: solve_all(np.ones_like(need), *a))
    solved = va_raim(gnss, vision, sc.frame, VaRaimSettings(variant="seed"))
    np.testing.assert_allclose(solved.pos_enu[gps_only], out.pos_enu[gps_only], atol=1e-6)
    for f in ("hpl", "vpl", "test_stat", "threshold"):
        np.testing.assert_allclose(getattr(solved, f)[gps_only], getattr(out, f)[gps_only], rtol=1e-6, err_msg=f)
    for f in ("alert", "reason", "n_used"):
        np.testing.assert_array_equal(getattr(solved, f), getattr(out, f), err_msg=f)
    for f in ("pos_enu", "hpl", "vpl", "test_stat", "threshold"):
        np.testing.assert_array_equal(getattr(solved, f)[~gps_only], getattr(out, f)[~gps_only], err_msg=f)


def test_a_batch_without_any_vision_row_is_gps_raim_and_one_with_all_of_them_solves_every_epoch():
    """The two ends of the step-1 substitution: no landmark anywhere (nothing to solve: every epoch is GPS
    RAIM's, bit for bit), and no calibration with every epoch's rows used (every epoch solved)."""
    from dataclasses import replace

    from testbed.frames import q_to_R
    sc = make_scenario(np.random.default_rng(32), (3,), t0=30.0, t1=50.0, rate_hz=1.0)
    blind = va_raim(sc.gnss, replace(sc.vision, detected=np.zeros_like(sc.vision.detected)), sc.frame)
    gps = blind.diagnostics.gps
    assert not blind.diagnostics.vision_rows_used.any()
    for f in ("hpl", "vpl", "test_stat", "threshold", "alert", "reason", "n_used"):
        np.testing.assert_array_equal(getattr(blind, f), getattr(gps, f), err_msg=f)
    off = q_to_R(sc.vision.q_body_to_enu_ref) @ sc.gnss.antenna.lever_arm_body
    np.testing.assert_array_equal(blind.pos_enu, gps.pos_enu - off)
    every = va_raim(sc.gnss, sc.vision, sc.frame, VaRaimSettings(variant="seed", calibration="none"))
    d = every.diagnostics
    assert d.vision_rows_used.all() and (every.n_used == d.n_gps + d.n_vision_rows).all()
    assert not np.array_equal(every.hpl, d.gps.hpl)


# --------------------------------------------------------------------------- batching


def _assert_outputs_identical(a, b) -> None:
    """Every array of two MonitorOutputs (diagnostics included, recursively) bit-identical (NaN == NaN)."""
    assert assert_records_equal(a, b) > 25  # every field of the output and its diagnostics


def test_chunks_and_threads_give_bit_identical_output(monkeypatch):
    """Cut into chunks of trials on two threads, the batch gives exactly the numbers of one piece
    on one thread, unavailable and faulted epochs included (every epoch is computed on its own)."""
    from dataclasses import replace

    from testbed.integrity import batching
    rng = np.random.default_rng(21)
    bias = np.zeros(8)
    bias[3] = 40.0
    sc = make_scenario(rng, (9,), t0=30.0, t1=60.0, rate_hz=1.0)
    uv = sc.vision.pixel_uv.copy()
    det = sc.vision.detected.copy()
    det[1, 5:9, 2] = False  # too few landmarks
    uv[4, 10, 0] = np.nan  # NaN pixels
    uv[7, 20:, 1] += 25.0  # a vision fault
    pr = sc.gnss.pseudorange.copy()
    pr[2, 12:, np.flatnonzero(sc.gnss.visible[2, 12])[0]] += 60.0  # a GPS step
    pr[5, 3, :] = np.nan
    gnss, vision = replace(sc.gnss, pseudorange=pr), replace(sc.vision, pixel_uv=uv, detected=det)
    whole = va_raim(gnss, vision, sc.frame, threads=1)  # 9 × 31 epochs < one chunk
    monkeypatch.setattr(batching, "CHUNK_EPOCHS", 2 * 31)
    assert len(batching.trial_chunks(pr.shape[:-1], multiple_of=2)) >= 4
    pieces = va_raim(gnss, vision, sc.frame, threads=2)
    _assert_outputs_identical(whole, pieces)
    assert np.any(whole.alert) and np.any(whole.reason != 0)  # the faults and gaps were exercised


def test_batched_monitor_equals_the_per_epoch_reference():
    """The batched monitor against tests/va_raim_reference.py (a plain per-epoch loop, textbook
    formulas): position, SSE, threshold, PLs, alerts, raw and calibrated vision ranges."""
    from va_raim_reference import check_same_numbers
    sc = make_scenario(np.random.default_rng(22), (3,))
    st = VaRaimSettings(variant="seed")  # the reference implements the seed's method
    out = va_raim(sc.gnss, sc.vision, sc.frame, st)
    check_same_numbers(sc, out, st, [0, 1, 2])
