"""The GNSS/vision/INS EKF core (testbed.navigation.ekf, .run): Jacobians against finite differences through ⊕,
and Monte Carlo consistency (NEES, NIS) against χ² bands at fixed seeds (test ids: docs/design/nav-filter.md §12)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import stats

from test_integrity_core_helpers import make_gnss
from testbed.flight.kinematic import straight_truth
from testbed.inertial import body_to_world, local_to_world, so3_log
from testbed.navigation.ekf import (CB, N, ClockNoise, ImuNoise, NavState, inject,
                                    nominal_step, pixel_rows, pseudorange_rows, range_rate_rows, transition)
from testbed.navigation.run import run_ekf, state_from_init
from testbed.sensors.imu.alignment import align
from testbed.sensors.gnss.errors import receiver_clock
from testbed.sensors.imu import ImuSettings, sample_imu
from testbed.world.airport import runway_frame

FRAME = runway_frame()
IMU = ImuSettings(grade="hg1700")
NOISE = ImuNoise.from_figures(IMU.figures())


def _state(rng, B=3):
    C = body_to_world(FRAME, np.zeros((B, 3)), np.tile([0.02, -0.03, 0.4, 0.9], (B, 1)) / np.linalg.norm([0.02, -0.03, 0.4, 0.9]))
    return NavState(C=C, v=rng.normal(0, 50, (B, 3)), p=rng.normal(0, 3000, (B, 3)) + [0, 0, 800],
                    ba=rng.normal(0, 1e-2, (B, 3)), bg=rng.normal(0, 1e-5, (B, 3)), cb=rng.normal(0, 100, B),
                    cd=rng.normal(0, 1, B), P=np.broadcast_to(np.eye(N), (B, N, N)).copy())


def _minus(a: NavState, b: NavState) -> np.ndarray:
    """a ⊖ b (B, 17)."""
    dpsi = so3_log(a.C @ np.swapaxes(b.C, -1, -2))
    return np.concatenate([a.p - b.p, a.v - b.v, dpsi, a.ba - b.ba, a.bg - b.bg, (a.cb - b.cb)[:, None],
                           (a.cd - b.cd)[:, None]], -1)


def test_pseudorange_and_pixel_jacobians_match_central_differences():
    """T-JAC-1: every column of H against (h(x ⊕ εeᵢ) − h(x ⊖ εeᵢ)) / 2ε, lever arms included: pseudorange,
    pixel and range-rate rows (the last with a turning body, so the lever arm's ω × l and the gyro bias count)."""
    rng = np.random.default_rng(0)
    s = _state(rng)
    sats = rng.normal(0, 1, (3, 6, 3)) * 2e7
    lever = np.array([3.0, 0.4, -1.5])
    lm = np.array([[1500.0, 2000.0, 0.0], [1800.0, 2600.0, 5.0], [1200.0, 2400.0, -3.0]])
    K = np.array([[2000.0, 0, 960], [0, 2000.0, 540], [0, 0, 1]])
    Rcb = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    lc = np.array([14.0, 0.0, 1.2])
    # steps: position/velocity/clock, attitude (a pseudorange is 2e7 m: cancellation sets its step larger)
    # atol: a difference of two 2e7 m ranges loses 2e7·2.2e-16 m, i.e. 2e-5 per unit at a 2e-4 step
    sat_v = rng.normal(0, 1, (3, 6, 3)) * 3000.0
    omega_meas = rng.normal(0, 0.1, (3, 3)) + s.bg  # the gyro bias enters through ω = ω_measured − b_g
    for fn, eps_p, eps_a, atol in ((lambda x: pseudorange_rows(x, sats, lever)[:2], 1e-2, 1e-4, 1e-4),
                                   (lambda x: pixel_rows(x, lm, K, Rcb, lc)[:2], 1e-3, 1e-6, 1e-6),
                                   (lambda x: range_rate_rows(x, sats, sat_v, lever, omega_meas - x.bg), 1e-2, 1e-4,
                                    1e-6)):
        h, H = fn(s)
        for i in range(N):
            eps = eps_a if 6 <= i < 9 else (eps_p if i < 6 or i >= 15 else 1e-4)
            d = np.zeros((s.p.shape[0], N))
            d[:, i] = eps
            hp, _ = fn(inject(s, d))
            hm, _ = fn(inject(s, -d))
            fd = (hp - hm) / (2 * eps)
            np.testing.assert_allclose(H[..., i], fd, rtol=1e-5, atol=atol * np.abs(H).max(), err_msg=f"column {i}")


def test_the_cameras_dithering_covariance_matches_monte_carlo_of_the_sensors_convention():
    """CameraNoise: G Q Gᵀ over a frame's pixel rows against 20 000 frames whose camera is turned on its
    mount by δ ~ N(0, diag σ²) in camera axes, ``C R_cb Exp(δ)`` (the vision sensor's convention, projected
    here by hand): every element of the 6×6 pixel covariance within 5 Monte Carlo σ, the u–v and
    landmark-to-landmark correlations included (the frame moves as one)."""
    from testbed.inertial import so3_exp
    from testbed.navigation.ekf import CameraNoise, rotation_rows

    rng = np.random.default_rng(3)
    s = _state(rng, B=1)
    lm = np.array([[1500.0, 2000.0, 0.0], [1800.0, 2600.0, 5.0], [1200.0, 2400.0, -3.0]])
    K = np.array([[2000.0, 0, 960], [0, 2000.0, 540], [0, 0, 1]])
    Rcb = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    lc = np.array([14.0, 0.0, 1.2])
    sigma = np.array([4e-4, 3e-4, 2e-4])
    c = s.p[0] + s.C[0] @ lc

    def pixels(delta):  # (M, 3) -> (M, 6)
        Rc2w = s.C[0] @ Rcb @ so3_exp(delta)
        x = np.einsum("mji,lj->mli", Rc2w, lm - c) @ K.T
        return (x[..., :2] / x[..., 2:]).reshape(len(delta), -1)

    M = 20_000
    e = pixels(rng.standard_normal((M, 3)) * sigma) - pixels(np.zeros((1, 3)))
    sample = np.cov(e.T)
    _, _, Hm, _ = pixel_rows(s, lm, K, Rcb, lc)
    cov = CameraNoise(rotation_rad=tuple(sigma)).covariance(rotation_rows(Hm, lm, c[None]), s.C, Rcb)[0]
    d = np.diag(cov)
    tol = 5 * np.sqrt((np.outer(d, d) + cov**2) / M)
    assert np.all(np.abs(sample - cov) <= tol), (sample - cov) / tol
    assert np.abs(cov[0, 2]) > 0.5 * np.sqrt(d[0] * d[2])  # landmarks' pixels move together


def test_a_dithered_frames_nis_is_chi2_with_the_rotation_model_and_heavy_tailed_without():
    """4000 frames of 12 landmarks 2 km ahead, the camera turned on its mount by δ ~ N(0, diag σ²) (0.9 and
    0.8 px at f = 2000 px) and 1 px noise, the estimate a draw from P, as well known as a filter is after
    many frames (0.1 m, 3e-5 rad): with the camera's rotation in R the NIS is χ²(24) (KS p > 0.001; the
    0.999 quantile's exceedances inside their binomial 99.9 % band). With the same rms spread over the rows
    as per-pixel noise (the model before commit 8b0f7f4) its mean stays within 10 % of 24, but its variance
    is 2.4 times 2·24 and the 0.999 quantile is passed 20 times too often: the far tail the innovation
    test paid for. (With a loose P, 1 m and 2e-4 rad, HPHᵀ covers the common directions and both pass.)"""
    from testbed.inertial import so3_exp
    from testbed.navigation.ekf import PSI, CameraNoise, gain_update, rotation_rows

    rng = np.random.default_rng(11)
    B, L = 4000, 12
    truth = _state(np.random.default_rng(0), B=1)
    truth = NavState(*(np.broadcast_to(getattr(truth, f), (B,) + getattr(truth, f).shape[1:]).copy()
                       for f in ("C", "v", "p", "ba", "bg", "cb", "cd", "P")))
    K = np.array([[2000.0, 0, 960], [0, 2000.0, 540], [0, 0, 1]])
    Rcb = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    lc = np.array([14.0, 0.0, 1.2])
    c = truth.p[0] + truth.C[0] @ lc
    M = truth.C[0] @ Rcb
    lm = c + (np.array([[x, y, 2000.0] for x in (-300, -100, 100, 300) for y in (-200, 0, 200)]) @ M.T)
    sigma = np.array([4.5e-4, 4.0e-4, 2.0e-4])
    delta = rng.standard_normal((B, 3)) * sigma
    x = np.einsum("bji,lj->bli", M @ so3_exp(delta), lm - c) @ K.T
    z = (x[..., :2] / x[..., 2:]).reshape(B, 2 * L) + rng.standard_normal((B, 2 * L))
    sd = np.r_[np.full(3, 0.1), np.full(3, 0.1), np.full(3, 3e-5), np.full(8, 1e-9)]
    P = np.broadcast_to(np.diag(sd**2), (B, N, N)).copy()
    est = inject(truth, rng.standard_normal((B, N)) * sd)
    est = NavState(est.C, est.v, est.p, est.ba, est.bg, est.cb, est.cd, P)
    h, H, Hm, _ = pixel_rows(est, lm, K, Rcb, lc)
    mask = np.ones((B, 2 * L), bool)
    G = rotation_rows(Hm, lm, est.p + np.einsum("bij,j->bi", est.C, lc))
    R_rot = np.eye(2 * L) + CameraNoise(rotation_rad=tuple(sigma)).covariance(G, est.C, Rcb)
    R_pix = (1.0 + (K[0, 0] * sigma.max()) ** 2) * np.broadcast_to(np.eye(2 * L), (B, 2 * L, 2 * L))
    nis = {k: gain_update(P, z - h, H, R, mask)[2] for k, R in (("rotation", R_rot), ("pixel", R_pix))}
    assert stats.kstest(nis["rotation"], stats.chi2(2 * L).cdf).pvalue > 1e-3
    k = int((nis["rotation"] > stats.chi2.isf(1e-3, 2 * L)).sum())
    lo, hi = stats.binom.interval(0.999, B, 1e-3)
    assert lo <= k <= hi, k
    k_pix = int((nis["pixel"] > stats.chi2.isf(1e-3, 2 * L)).sum())
    assert abs(nis["pixel"].mean() / (2 * L) - 1) < 0.1 and nis["pixel"].var() > 1.8 * 2 * (2 * L) and k_pix > 5 * hi
    assert np.all(np.abs(H[..., PSI]) > 0)  # (the estimate's attitude is in the rows: S covers it)


def test_transition_matches_finite_differences_of_the_mechanisation():
    """T-JAC-2: Φ against (f(x ⊕ εeᵢ) ⊖ f(x ⊖ εeᵢ)) / 2ε for one 120 Hz step of the nominal mechanisation
    (biases entering through the corrected increments). Φ takes attitude and specific force constant over
    the step: its neglected terms are O(Δt·|ω|) of each entry (relative ≤ 1e-3 at 120 Hz here)."""
    rng = np.random.default_rng(1)
    s = _state(rng, 2)
    dt = 1 / 120
    dth = rng.normal(0, 0.2, (2, 3)) * dt
    dvl = (np.array([0.5, 0.1, -9.8]) + rng.normal(0, 1, (2, 3))) * dt
    s1, C_mid, f_w, g = nominal_step(s, dth, dvl, dt, FRAME, NOISE)
    from testbed.inertial import earth_rate_world

    Phi = transition(C_mid, f_w, dt, earth_rate_world(FRAME), NOISE.tau_gyro, NOISE.tau_accel,
                     np.linalg.norm(g, axis=-1))
    for i in range(N):
        eps = {0: 1e-2, 1: 1e-3, 2: 1e-6, 3: 1e-4, 4: 1e-6, 5: 1e-2, 6: 1e-3}[min(i // 3, 6) if i < 15 else 5]
        d = np.zeros((2, N))
        d[:, i] = eps
        fp = nominal_step(inject(s, d), dth, dvl, dt, FRAME, NOISE)[0]
        fm = nominal_step(inject(s, -d), dth, dvl, dt, FRAME, NOISE)[0]
        fd = _minus(fp, fm) / (2 * eps)
        scale = np.abs(Phi[..., i]).max()
        np.testing.assert_allclose(Phi[..., i], fd, atol=1e-3 * max(scale, 1e-9) + 1e-9, err_msg=f"column {i}")


def _final(B, duration=40.0, seed=0):
    """A kinematic straight segment of the final with an HG1700 IMU, 7 satellites with a two-state clock."""
    tr = straight_truth(FRAME, [-8000, -6000, 500], [-8000 + 100 * duration, -6000 + 75 * duration, 500 - 5 * duration],
                        duration, rate_hz=120.0)
    imu, _ = sample_imu(tr, IMU, np.random.default_rng(seed), n_trials=B)
    g1 = tr.decimate(1.0)
    gnss, rho0, sig = make_gnss(FRAME, g1.pos_enu, 344063.0 + g1.t, None)
    cb, cd = receiver_clock(np.random.default_rng(seed + 1), g1.t, (B,), bias0_sigma_m=100.0, drift0_sigma_m_s=1.0,
                            sf_m2_s=ClockNoise.sf, sg_m2_s3=ClockNoise.sg)
    noise = np.random.default_rng(seed + 2).standard_normal((B,) + rho0.shape) * sig
    pr = np.where(gnss.visible, rho0 - 1234.5 + cb[..., None] + noise, np.nan)
    gnss = replace(gnss, t=g1.t, pseudorange=pr)
    C0 = body_to_world(FRAME, tr.pos_enu[0], tr.q_body_to_enu[0])
    v0 = local_to_world(FRAME, tr.pos_enu[0], tr.vel_enu[0])
    init = align(tr.t[0], C0, v0, tr.pos_enu[0], cb[:, 0], cd[:, 0], IMU.figures(), np.random.default_rng(seed + 3), B)
    s0 = state_from_init(init)
    return tr, g1, gnss, imu, s0, cb, cd


def _with_range_rates(gnss, g1, cd, seed: int, sigma: float):
    """The segment's range rates: e·(v_sat − v_rx) + clock drift + white noise (ECEF, Earth-fixed velocities;
    the satellites' from a central difference of the helper's orbits)."""
    from test_integrity_core_helpers import sat_pos_ecef

    t = 344063.0 + g1.t
    sat = sat_pos_ecef(t)
    sat_v = sat_pos_ecef(t + 0.5) - sat_pos_ecef(t - 0.5)
    rx = FRAME.enu_to_ecef(g1.pos_enu)
    rx_v = FRAME.vec_enu_to_ecef(local_to_world(FRAME, g1.pos_enu, g1.vel_enu))
    d = sat - rx[:, None]
    e = d / np.linalg.norm(d, axis=-1, keepdims=True)
    rr0 = np.einsum("tsi,tsi->ts", e, sat_v - rx_v[:, None])
    B = cd.shape[0]
    noise = np.random.default_rng(seed).standard_normal((B,) + rr0.shape) * sigma
    rr = np.where(gnss.visible, rr0 + cd[..., None] + noise, np.nan)
    return replace(gnss, sat_vel_ecef=np.broadcast_to(sat_v, gnss.sat_pos_ecef.shape), range_rate=rr)


def _nees_blocks(trace, g1, cb) -> dict[str, np.ndarray]:
    """Mean NEES over the runs per epoch (T,) of position, velocity, attitude (3 dof each) and clock bias (1)."""
    Ct = body_to_world(FRAME, g1.pos_enu, g1.q_body_to_enu)
    vt = local_to_world(FRAME, g1.pos_enu, g1.vel_enu)
    blocks = {"p": (g1.pos_enu - trace.p, slice(0, 3)), "v": (vt - trace.v, slice(3, 6)),
              "psi": (so3_log(Ct @ np.swapaxes(trace.C, -1, -2)), slice(6, 9)),
              "cb": ((cb - trace.cb)[..., None], slice(CB, CB + 1))}
    out = {}
    for k, (e, sl) in blocks.items():
        P = trace.P[..., sl, sl]
        out[k] = np.einsum("bti,bti->bt", e, np.linalg.solve(P, e[..., None])[..., 0]).mean(0)
    return out


def _assert_consistent(trace, g1, cb, B: int) -> None:
    """The mean NEES blocks inside their two-sided 99 % χ² bands at ≥ 95 % of epochs; the NIS summed over
    runs and epochs (after the first) inside its band."""
    for k, m in _nees_blocks(trace, g1, cb).items():
        d = 1 if k == "cb" else 3
        lo, hi = stats.chi2.ppf([0.005, 0.995], d * B) / B
        assert ((m >= lo) & (m <= hi)).mean() >= 0.95, (k, m)
    dof = trace.dof[:, 1:].sum()
    lo, hi = stats.chi2.ppf([0.005, 0.995], dof)
    assert lo <= trace.nis[:, 1:].sum() <= hi


def test_nees_and_nis_inside_their_chi2_bands_with_seven_satellites():
    """T-NEES-1/T-NIS-1 (straight, 7 satellites, 80 runs from the alignment's P₀): the mean NEES of
    position, velocity and attitude (3 dof each) and of the clock bias (1 dof) is inside its two-sided
    99 % χ² band at ≥ 95 % of the 41 epochs, the NIS summed over runs and epochs inside its band, and
    the innovation test's false alarms at P_FA = 1e-2 inside their binomial interval."""
    B = 80
    tr, g1, gnss, imu, s0, cb, cd = _final(B)
    trace = run_ekf(s0, imu, FRAME, NOISE, gnss=gnss)
    _assert_consistent(trace, g1, cb, B)
    # the ekf monitor's innovation test at P_FA = 1e-2: alerts inside the binomial 99 % interval
    d = trace.dof[:, 1:]
    alerts = int((trace.nis[:, 1:] > stats.chi2.isf(1e-2, d)).sum())
    lo, hi = stats.binom.interval(0.99, d.size, 1e-2)
    assert lo <= alerts <= hi, (alerts, lo, hi, d.size)


def test_range_rate_rows_keep_the_filter_consistent_and_sharpen_the_velocity():
    """The same 80 runs with a range-rate row per satellite (0.05 m/s): NEES of position, velocity, attitude
    and clock bias inside their 99 % χ² bands at ≥ 95 % of epochs, the NIS (pseudorange + range-rate rows)
    in its band; the velocity σ at the end well below the pseudorange-only filter's."""
    B = 80
    tr, g1, gnss, imu, s0, cb, cd = _final(B)
    g_rr = _with_range_rates(gnss, g1, cd, seed=21, sigma=0.05)
    trace = run_ekf(s0, imu, FRAME, NOISE, gnss=g_rr, range_rate_sigma_m_s=0.05)
    _assert_consistent(trace, g1, cb, B)
    assert np.all(trace.dof[:, 1:] == 2 * gnss.visible[1:].sum(-1))  # both rows for every satellite
    plain = run_ekf(s0, imu, FRAME, NOISE, gnss=gnss)
    sv_rr = np.sqrt(np.trace(trace.P[:, -1, 3:6, 3:6], axis1=-2, axis2=-1)).mean()
    sv = np.sqrt(np.trace(plain.P[:, -1, 3:6, 3:6], axis1=-2, axis2=-1)).mean()
    print(f"\nvelocity σ after 40 s: {sv_rr * 100:.1f} cm/s with range rates, {sv * 100:.1f} cm/s without")
    assert sv_rr < 0.5 * sv


def test_the_filter_runs_with_zero_to_three_satellites_and_more_satellites_shrink_the_covariance():
    """Never four: with 0, 1, 2, 3 satellites the filter gives finite states; the position covariance
    after 30 s shrinks with each satellite added (trace), and with none it is the inertial drift."""
    B = 4
    tr, g1, gnss, imu, s0, cb, cd = _final(B, duration=30.0)
    traces = []
    for k in range(4):
        vis = np.array(gnss.visible)
        keep = np.cumsum(vis, -1) <= k
        g = replace(gnss, visible=vis & keep)
        traces.append(run_ekf(s0, imu, FRAME, NOISE, gnss=g))
    tr_pos = [np.trace(t.P[:, -1, :3, :3], axis1=-2, axis2=-1).mean() for t in traces]
    assert all(np.isfinite(t.p).all() for t in traces)
    assert tr_pos[0] > tr_pos[1] > tr_pos[2] > tr_pos[3], tr_pos


def _pixels(tr, g1, lm_w, K, Rcb, lc, B, sigma_px, rng):
    """Pixel detections of surveyed landmarks from the true pose at the aiding epochs (B, T, L, 2)."""
    from testbed.integrity.pixel_model import project_landmarks

    C = body_to_world(FRAME, g1.pos_enu, g1.q_body_to_enu)
    uv, _, ray = project_landmarks(g1.pos_enu, C @ Rcb, np.einsum("tij,j->ti", C, lc), lm_w, K)
    ok = (ray[..., 2] > 0) & (uv[..., 0] > 0) & (uv[..., 0] < 1920) & (uv[..., 1] > 0) & (uv[..., 1] < 1080)
    noisy = uv + rng.standard_normal((B,) + uv.shape) * sigma_px
    return np.where(ok[..., None], noisy, np.nan), np.broadcast_to(ok, (B,) + ok.shape)


def test_vision_rows_alone_keep_the_filter_consistent_and_bound_the_drift():
    """No satellite, 6 surveyed landmarks ahead on the ground, 1 px: NIS in its χ² band and the position
    error inside 3σ of the filter's covariance at the end, where dead reckoning alone drifts further
    (measured: 2.7 m RMS against 14.6 m after 30 s)."""
    from testbed.records import Mount, VisionEpochs

    B = 40
    tr, g1, gnss, imu, s0, cb, cd = _final(B, duration=30.0, seed=10)
    K = np.array([[2058.8, 0.0, 960.0], [0.0, 2058.8, 540.0], [0.0, 0.0, 1.0]])
    pitch = np.radians(-8.0)
    Ry = np.array([[np.cos(pitch), 0.0, np.sin(pitch)], [0.0, 1.0, 0.0], [-np.sin(pitch), 0.0, np.cos(pitch)]])
    Rcb = Ry @ np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    lc = np.array([14.0, 0.0, 1.2])
    ahead = tr.pos_enu[-1] + 2500.0 * (tr.pos_enu[-1] - tr.pos_enu[0]) / np.linalg.norm(tr.pos_enu[-1] - tr.pos_enu[0])
    lm_w = ahead + np.array([[0, 0, -400.0], [300, -200, -400.0], [-300, 200, -400.0], [600, 100, -400.0],
                             [-200, -500, -400.0], [100, 700, -400.0]])
    lm_w[:, 2] = 0.0
    uv, det = _pixels(tr, g1, lm_w, K, Rcb, lc, B, 1.0, np.random.default_rng(11))
    assert det.all()
    vision = VisionEpochs(t=g1.t, landmark_id=np.array([f"L{i}" for i in range(6)]),
                          landmark_pos_ecef=FRAME.enu_to_ecef(lm_w), pixel_uv=uv, detected=det,
                          reason=np.zeros(det.shape, np.int8), sigma_px=np.ones(det.shape), K=K,
                          camera=Mount(lever_arm_body=lc, R_sensor_to_body=Rcb), q_body_to_enu_ref=np.zeros(det.shape[:-1] + (4,)),
                          attitude_sigma=np.zeros(3))
    vis_ins = run_ekf(s0, imu, FRAME, NOISE, vision=vision, t_aid=g1.t)
    ins = run_ekf(s0, imu, FRAME, NOISE, t_aid=g1.t)
    dof = vis_ins.dof[:, 1:].sum()
    lo, hi = stats.chi2.ppf([0.005, 0.995], dof)
    assert lo <= vis_ins.nis[:, 1:].sum() <= hi
    e = g1.pos_enu[-1] - vis_ins.p[:, -1]
    sd = np.sqrt(np.diagonal(vis_ins.P[:, -1, :3, :3], axis1=-2, axis2=-1))
    assert (np.abs(e) <= 3 * sd).mean() > 0.97
    drift_vis = np.sqrt(np.mean(np.sum(e**2, -1)))
    drift_ins = np.sqrt(np.mean(np.sum((g1.pos_enu[-1] - ins.p[:, -1]) ** 2, -1)))
    assert drift_vis < drift_ins, (drift_vis, drift_ins)


def test_compiled_predict_equals_the_numpy_one():
    """The kernel the filter runs against the readable numpy predict: 240 steps, relative 1e-10."""
    from testbed.navigation.ekf import predict, predict_compiled

    rng = np.random.default_rng(9)
    s = _state(rng, 3)
    a = b = s
    clock = ClockNoise()
    for _ in range(240):
        dth = rng.normal(0, 0.3, (3, 3)) / 120
        dvl = (np.array([0.5, 0.1, -9.8]) + rng.normal(0, 1, (3, 3))) / 120
        a = predict(a, dth, dvl, 1 / 120, FRAME, NOISE, clock)
        b = predict_compiled(b, dth, dvl, 1 / 120, FRAME, NOISE, clock)
    for f in ("C", "v", "p", "ba", "bg", "cb", "cd", "P"):
        np.testing.assert_allclose(getattr(b, f), getattr(a, f), rtol=1e-10, atol=1e-12 * np.abs(getattr(a, f)).max(),
                                   err_msg=f)
