"""Solution separation for the GNSS/vision/INS filter (testbed.navigation.separation, docs/design/nav-filter.md §8.3):
the linearised sub-filter bank against independently run filters, the separations' distribution against
N(0, P_i − P₀) over Monte Carlo runs, detection of a satellite step, the PLs bounding the faulted error,
and the windowed test catching a ramp the snapshot test lets through."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from test_ekf import FRAME, NOISE, _final
from testbed.navigation.ekf import ClockNoise
from testbed.navigation.run import filter_epochs
from testbed.navigation.separation import Bank, separation


def _run(s0, imu, gnss, bank=True):
    b = Bank.empty(s0.p.shape[0], np.shape(gnss.prn)[0]) if bank else None
    return filter_epochs(s0, imu, FRAME, NOISE, gnss, None, ClockNoise(), bank=b)


def test_each_sub_filter_is_the_filter_without_its_satellite():
    """The bank's sub-filter without slot j (linearised about the main) against an EKF run on its own with slot
    j removed: positions within 2 % of σ_Δ and the position covariance within 0.5 % (off-diagonal: 1e-5 of its largest entry) at every epoch (measured:
    about 0.1 % and 1e-5; the gap is the linearisation about the main's trajectory), and P_i − P₀ positive
    semi-definite throughout."""
    B = 6
    tr, g1, gnss, imu, s0, cb, cd = _final(B, duration=30.0, seed=4)
    trace, _, bank = _run(s0, imu, gnss)
    slots = np.flatnonzero(np.asarray(gnss.visible).any(0))
    assert sorted(bank.modes.tolist()) == sorted(slots.tolist())
    for i, j in enumerate(bank.modes):
        alone = filter_epochs(s0, imu, FRAME, NOISE, replace(gnss, visible=np.asarray(gnss.visible) &
                                                             (np.arange(gnss.prn.size) != j)), None, ClockNoise())[0]
        rows = slice(i * B, (i + 1) * B)
        p_sub = trace.p + trace.sub_dp[rows]
        D = trace.sub_Pp[rows] - trace.P[..., :3, :3]
        sig_d = np.sqrt(np.diagonal(D, axis1=-2, axis2=-1))
        assert np.all(np.linalg.eigvalsh(D) > -1e-9 * np.abs(D).max())
        np.testing.assert_array_less(np.abs(p_sub - alone.p)[:, 1:], 0.02 * sig_d[:, 1:] + 1e-9)
        np.testing.assert_allclose(trace.sub_Pp[rows], alone.P[..., :3, :3], rtol=5e-3, atol=1e-5 * np.abs(alone.P[..., :3, :3]).max())


@pytest.mark.slow
def test_separations_and_tests_are_distributed_as_their_covariance_says():
    """200 fault-free runs, 7 satellites (T-INT-1, T-INT-4): at the last epoch, per mode and axis,
    Σ_runs (Δ/σ_Δ)² inside the two-sided 99.9 % χ²(200) band (21 cells; none may be outside); at
    P_FA = 1e-2 each, the innovation test's alerts over the 5800 epochs after the first inside the binomial
    99 % interval, the windowed test's over non-overlapping 10 s windows (independent: 600) inside theirs,
    and the separation test's at the last epoch no more than its binomial bound (its K_fa splits P_FA over
    modes and axes, so it sits below)."""
    from testbed.navigation.monitor import windowed_chi2

    B = 200
    tr, g1, gnss, imu, s0, cb, cd = _final(B, duration=30.0, seed=7)
    trace, _, bank = _run(s0, imu, gnss)
    q = trace.nis[:, 1:] > stats.chi2.isf(1e-2, np.maximum(trace.dof[:, 1:], 1))
    lo, hi = stats.binom.interval(0.99, q.size, 1e-2)
    assert lo <= q.sum() <= hi, (q.sum(), lo, hi)
    w, thr, _ = windowed_chi2(g1.t, trace.nis, trace.dof, None, 10.0, 1e-2)
    ends = np.flatnonzero((g1.t % 10.0 == 9.0))  # windows (t − 10, t] that do not overlap
    lo, hi = stats.binom.interval(0.99, B * ends.size, 1e-2)
    assert lo <= (w[:, ends] > thr[:, ends]).sum() <= hi
    M = bank.modes.size
    dp = trace.sub_dp[:, -1].reshape(M, B, 3)
    var_d = (np.diagonal(trace.sub_Pp[:, -1], axis1=-2, axis2=-1).reshape(M, B, 3)
             - np.diagonal(trace.P[:, -1, :3, :3], axis1=-2, axis2=-1))
    q = (dp**2 / var_d).sum(1)  # (M, 3)
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], B)
    assert np.all((q > lo) & (q < hi)), q
    sep = separation(trace.P[..., :3, :3], trace.sub_dp, trace.sub_Pp, 1e-2, 1e-3, 1e-7)
    alerts = int((sep.ratio[:, -1] > 1).sum())
    lo, hi = stats.binom.interval(0.99, B, 1e-2)
    assert alerts <= hi, (alerts, hi)


@pytest.mark.slow  # moved out of the default set: its run time (the default set stays within 8 min)
def test_the_innovation_test_detects_a_step_as_the_noncentral_chi2_predicts():
    """T-INT-2: a step b on one satellite's pseudorange at epoch k shifts that epoch's innovation by b eⱼ,
    so its NIS is non-central χ²(m, λ = b² (S⁻¹)ⱼⱼ) with S = HP⁻Hᵀ + R from the filter just before. Over
    400 runs, the detections at P_FA = 1e-3 at the onset epoch inside the 99 % interval of the
    Poisson-binomial with those per-run probabilities (normal approximation)."""
    from testbed.navigation.ekf import pseudorange_rows

    B, b_m = 400, 6.0
    tr, g1, gnss, imu, s0, cb, cd = _final(B, duration=16.0, seed=9)
    k = 15
    slot = int(np.flatnonzero(np.asarray(gnss.visible)[k])[2])
    bias = np.zeros(gnss.pseudorange.shape)
    bias[:, k:, slot] = b_m
    trace, _, _ = _run(s0, imu, replace(gnss, pseudorange=gnss.pseudorange + bias), bank=False)
    thr = stats.chi2.isf(1e-3, trace.dof[:, k])
    detected = int((trace.nis[:, k] > thr).sum())
    # the filter just before the onset epoch: the first k epochs and the IMU up to epoch k
    from testbed.navigation.run import _at
    keep = np.asarray(imu.t) <= g1.t[k] + 1e-9
    imu_k = replace(imu, t=imu.t[keep], dtheta=imu.dtheta[:, keep], dvel=imu.dvel[:, keep])
    g_k = replace(gnss, t=gnss.t[:k], pseudorange=gnss.pseudorange[:, :k], sat_pos_ecef=gnss.sat_pos_ecef[:k],
                  sat_vel_ecef=gnss.sat_vel_ecef[:k], range_rate=gnss.range_rate[:k], sigma=gnss.sigma[:k],
                  visible=gnss.visible[:k], reason=gnss.reason[:k], t_gps=gnss.t_gps[:k])
    _, s_minus, _ = filter_epochs(s0, imu_k, FRAME, NOISE, g_k, None, ClockNoise(), through_end=True)
    vis = np.asarray(gnss.visible)[k]
    sat_w = FRAME.ecef_to_enu(_at(gnss.sat_pos_ecef, k, 2, B)[:, vis])
    _, H = pseudorange_rows(s_minus, sat_w, np.asarray(gnss.antenna.lever_arm_body, float))
    S = H @ s_minus.P @ np.swapaxes(H, -1, -2) + np.asarray(gnss.sigma)[k][vis] ** 2 * np.eye(vis.sum())
    j = int(np.flatnonzero(np.flatnonzero(vis) == slot)[0])
    lam = b_m**2 * np.linalg.inv(S)[:, j, j]
    p = stats.ncx2.sf(thr, trace.dof[:, k], lam)
    mean, sd = p.sum(), np.sqrt((p * (1 - p)).sum())
    print(f"\ndetections {detected} of {B}, predicted {mean:.1f} ± {sd:.1f} (λ median {np.median(lam):.1f})")
    assert abs(detected - mean) <= 2.58 * sd + 1


def test_a_satellite_step_is_detected_by_its_mode_and_the_pls_bound_the_error():
    """A 25 m step on the highest satellite's pseudorange from 15 s: the separation test alerts within 3 s on
    every run, the largest separation is that satellite's mode, and the faulted main filter's error stays
    inside the PLs at every epoch before the alert (no hazardous misleading information)."""
    B = 20
    tr, g1, gnss, imu, s0, cb, cd = _final(B, duration=30.0, seed=5)
    slot = int(np.flatnonzero(np.asarray(gnss.visible).any(0))[0])
    bias = np.zeros(gnss.pseudorange.shape)
    bias[:, g1.t >= 15.0, slot] = 25.0
    faulty = replace(gnss, pseudorange=gnss.pseudorange + bias)
    trace, _, bank = _run(s0, imu, faulty)
    sep = separation(trace.P[..., :3, :3], trace.sub_dp, trace.sub_Pp, 1e-5, 1e-3, 1e-7)
    alert = sep.ratio > 1
    onset = int(np.searchsorted(g1.t, 15.0))
    assert not alert[:, :onset].any()
    first = onset + np.argmax(alert[:, onset:], axis=1)
    assert alert[:, onset:].any(1).all() and np.all(g1.t[first] <= 18.0), g1.t[first]
    # the faulted satellite's mode carries the largest normalised separation at the alert
    M = bank.modes.size
    var_d = (np.diagonal(trace.sub_Pp, axis1=-2, axis2=-1).reshape(M, B, -1, 3)
             - np.diagonal(trace.P[..., :3, :3], axis1=-2, axis2=-1))
    z = np.abs(trace.sub_dp.reshape(M, B, -1, 3)) / np.sqrt(np.maximum(var_d, 1e-30))
    at = z[:, np.arange(B), first].max(-1)  # (M, B)
    assert np.all(bank.modes[np.argmax(at, 0)] == slot)
    err = g1.pos_enu - trace.p
    for b in range(B):
        k = slice(0, first[b])  # the epochs without an alert
        assert np.all(np.hypot(err[b, k, 0], err[b, k, 1]) <= np.hypot(sep.pl_enu[b, k, 0], sep.pl_enu[b, k, 1]))
        assert np.all(np.abs(err[b, k, 2]) <= sep.pl_enu[b, k, 2])


def test_the_windowed_test_sums_its_span_and_blocks_do_not_change_it():
    """Q_k against a brute-force sum over (t_k − 10 s, t_k]; split into blocks of 7 epochs, bit-identical."""
    from testbed.navigation.monitor import windowed_chi2

    rng = np.random.default_rng(0)
    t = np.arange(40.0)
    dof = rng.integers(0, 9, (3, 40))
    nis = rng.chisquare(np.maximum(dof, 1)) * (dof > 0)
    q, thr, _ = windowed_chi2(t, nis, dof, None, 10.0, 1e-3)
    for k in range(40):
        j = max(0, k - 9)
        np.testing.assert_allclose(q[:, k], np.where(dof[:, j:k + 1].sum(1) > 0, nis[:, j:k + 1].sum(1), np.nan))
        np.testing.assert_allclose(thr[:, k], stats.chi2.isf(1e-3, np.maximum(dof[:, j:k + 1].sum(1), 1)))
    carry, parts = None, []
    for a in range(0, 40, 7):
        qa, _, carry = windowed_chi2(t[a:a + 7], nis[:, a:a + 7], dof[:, a:a + 7], carry, 10.0, 1e-3)
        parts.append(qa)
    np.testing.assert_array_equal(np.concatenate(parts, 1), q)


def test_the_windowed_test_catches_a_ramp_before_the_snapshot_test():
    """A 0.5 m/s ramp on the highest satellite from 5 s: the windowed test (10 s) alerts first on most runs —
    the filter absorbs a slow ramp into its clock and position, so each epoch's innovation stays small while
    their sum over the window grows. Both tests at P_FA/2 = 5e-6."""
    from testbed.navigation.monitor import windowed_chi2

    B = 20
    tr, g1, gnss, imu, s0, cb, cd = _final(B, duration=40.0, seed=6)
    slot = int(np.flatnonzero(np.asarray(gnss.visible).any(0))[0])
    bias = np.zeros(gnss.pseudorange.shape)
    bias[:, :, slot] = 0.5 * np.maximum(g1.t - 5.0, 0.0)
    trace, _, _ = _run(s0, imu, replace(gnss, pseudorange=gnss.pseudorange + bias), bank=False)
    snap = trace.nis > stats.chi2.isf(5e-6, np.maximum(trace.dof, 1))
    q, thr, _ = windowed_chi2(g1.t, trace.nis, trace.dof, None, 10.0, 5e-6)
    win = q > thr
    never = g1.t.size
    t_snap = np.where(snap.any(1), snap.argmax(1), never)
    t_win = np.where(win.any(1), win.argmax(1), never)
    print(f"\nfirst alert (s after the onset): window {np.median(t_win) - 5:.0f}, snapshot {np.median(t_snap) - 5:.0f}")
    assert not win[:, :5].any() and not snap[:, :5].any()
    assert (t_win < t_snap).mean() >= 0.75 and (t_win <= t_snap).all()


@pytest.mark.slow
def test_nees_on_the_approach_over_200_sorties():
    """T-NEES-3 on the shipped zunz-rwy05-ekf (JSBSim's flight, the sensor layer's GNSS with range rates and
    camera, an HG1700 IMU, each sortie its own draws; the first 40 s: 8 satellites, then 3): the mean
    position NEES over 200 sorties inside its two-sided 99 % χ²(600)/200 band at ≥ 95 % of the epochs, and
    no alert at the default P_FA."""
    from testbed.campaign.blocks import draw_block
    from testbed.campaign.context import cell_context
    from testbed.campaign.spec import CampaignSpec, expand_cells, resolve_spec
    from testbed.resources import campaigns_dir

    spec = CampaignSpec.model_validate({"name": "nees", "approaches": ["zunz-rwy05-ekf"], "monitors": ["ekf"],
                                        "trials": 200, "block_trials": 200, "chunk_trials": 200, "base_seed": 3,
                                        "per_epoch_trials": 0, "duration_s": 40.0, "faults": [{"kind": "none"}]})
    loaded = resolve_spec(spec, campaigns_dir() / "nees.toml")
    ctx = cell_context(expand_cells(loaded)[0], loaded.spec)
    d = draw_block(ctx, loaded.spec, 0)
    mon = ctx.setup.monitors[0]
    out, _ = mon.step(d.obs, mon.initial_state())
    e = ctx.truth_cg_enu - out.pos_enu  # the IMU at the CG (zero lever arm)
    nees = np.einsum("bti,bti->bt", e, np.linalg.solve(out.diagnostics.cov_enu, e[..., None])[..., 0]).mean(0)
    lo, hi = stats.chi2.ppf([0.005, 0.995], 3 * 200) / 200
    inside = (nees >= lo) & (nees <= hi)
    print(f"\nposition NEES inside [{lo:.2f}, {hi:.2f}] at {inside.mean():.0%} of epochs (median {np.median(nees):.2f})")
    assert inside.mean() >= 0.95
    assert not out.alert.any()


def test_innovations_are_white(monkeypatch):
    """T-NIS-1: 100 runs, 7 satellites, 40 s: each satellite's standardised pseudorange innovation has sample
    autocorrelation at lags 1–5 (pooled over runs) inside ±2.58/√(MT) (35 values; one outside allowed)."""
    import testbed.navigation.run as run

    seen = []
    real = run.gain_update

    def spy(P, nu, H, R, mask):
        S = H @ P @ np.swapaxes(H, -1, -2) + R
        seen.append(np.where(mask, nu / np.sqrt(np.diagonal(S, axis1=-2, axis2=-1)), np.nan))
        return real(P, nu, H, R, mask)

    monkeypatch.setattr(run, "gain_update", spy)
    B = 100
    tr, g1, gnss, imu, s0, cb, cd = _final(B, duration=40.0, seed=12)
    _run(s0, imu, gnss, bank=False)
    z = np.stack(seen[5:], 1)  # (B, T, 7) after the alignment transient
    assert np.isfinite(z).all()
    M, T = z.shape[:2]
    # (no de-meaning: zero mean under H0, and a per-run mean would bias every lag by −1/T)
    bound = 2.58 / np.sqrt(M * T)
    rho = np.array([[np.sum(z[:, :-k, j] * z[:, k:, j]) / np.sqrt(np.sum(z[:, :-k, j] ** 2) * np.sum(z[:, k:, j] ** 2))
                     for j in range(z.shape[-1])] for k in range(1, 6)])
    print(f"\nlag 1-5 autocorrelation: max |ρ| {np.abs(rho).max():.3f} against ±{bound:.3f}; mean per lag "
          f"{np.round(rho.mean(1), 3)}")
    assert (np.abs(rho) > bound).sum() <= 1
