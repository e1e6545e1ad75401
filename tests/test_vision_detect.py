"""Detection synthesis: hand-computed view, visibility rules, noise statistics, faults, scenarios."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from testbed.flight.kinematic import straight_truth
from testbed.frames import LocalFrame, R_ecef_to_enu
from testbed.records import NotVisible
from testbed.sensors.faults import LandmarkMoved, Misassociation, PixelBias
from testbed.sensors.vision import (FaultKind, LandmarkSettings, VisionSettings, approach_camera,
                                    build_landmarks, synthesize_vision,
                                    seed_triangle_settings, zunz_runway_settings)
from testbed.sensors.vision.attitude_ref import q_to_euler
from testbed.world import airport

P_TAIL = 1e-4  # two-sided tail probability of every statistical bound here
PX_ROUNDOFF = 1e-6
FRAME = LocalFrame(29.30, 94.30, 2950.0)

CLEAN = dict(dithering={"enabled": False}, detection={"sigma_px": 0.0, "exposure_s": 0.0},
             mount={"lever_arm_body_m": (0.0, 0.0, 0.0)})


def points(enu: dict[str, tuple], frame: LocalFrame = FRAME, size_m: float = 2.0, lpe: float = 0.0) -> LandmarkSettings:
    pts = []
    for name, p in enu.items():
        lat, lon, h = frame.enu_to_geodetic(np.asarray(p, float))
        pts.append({"id": name, "lat_deg": float(lat), "lon_deg": float(lon), "h": float(h), "size_m": size_m})
    return LandmarkSettings(sets=[{"kind": "points", "points": pts}], lpe_sigma_m=lpe)


class WallTerrain:
    """Stub terrain: a vertical wall across north = n_wall, east in [e0, e1], top at u_top (frame ENU)."""

    def __init__(self, frame, n_wall, e0, e1, u_top):
        self.frame, self.n, self.e0, self.e1, self.top = frame, n_wall, e0, e1, u_top
        self.calls = 0

    def line_of_sight(self, origin_ecef, target_ecef):
        self.calls += 1
        o, t = self.frame.ecef_to_enu(origin_ecef), self.frame.ecef_to_enu(target_ecef)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (self.n - o[..., 1]) / (t[..., 1] - o[..., 1])
        x = o + s[..., None] * (t - o)
        hit = (s > 0) & (s < 1) & (x[..., 0] >= self.e0) & (x[..., 0] <= self.e1) & (x[..., 2] < self.top)
        return ~hit


def level_north(n0=-5000.0, n1=-4000.0, up=500.0, duration=10.0, rate=10.0):
    return straight_truth(FRAME, [0.0, n0, up], [0.0, n1, up], duration, rate_hz=rate, alpha_deg=0.0)


def seed_truth(rate_hz=10.0):
    fr = LocalFrame(*airport.VA_RAIM_CENTRE)
    a = fr.geodetic_to_enu(29.3065, 94.2539, 3650.0)
    b = fr.geodetic_to_enu(29.3065, 94.3144, 3150.0)
    return straight_truth(fr, a, b, 60.0, rate_hz=rate_hz)


def bearings_cos(uv, K):
    """cos of the angles between lines of sight from pixels (..., L, 2): b = normalise(K^-1 [u, v, 1])."""
    h = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], -1) @ np.linalg.inv(K).T
    b = h / np.linalg.norm(h, axis=-1, keepdims=True)
    return np.einsum("...id,...jd->...ij", b, b)


# ------------------------------------------------------------------ hand-computed view
def test_hand_computed_view_through_the_whole_chain():
    """Aircraft level, heading north at the frame origin; camera pitched 9 deg down, no lever arm.

    Landmark 100 m east, 1000 m north, 200 m below. Body FRD: (1000, 100, 200).
    Camera (x right, y down, z fwd) for a 9 deg down mount:
      X = 100
      Y = -sin9 * 1000 + cos9 * 200 = -156.43447 + 197.53767 = 41.10320
      Z =  cos9 * 1000 + sin9 * 200 =  987.68834 +  31.28689 = 1018.97523
    f = 960 / tan 25 = 2058.72664 px, (cx, cy) = (959.5, 539.5):
      u = 2058.72664 * 100 / 1018.97523 + 959.5 = 202.03893 + 959.5 = 1161.53893
      v = 2058.72664 * 41.10320 / 1018.97523 + 539.5 = 83.04447 + 539.5 = 622.54447
    """
    tr = straight_truth(FRAME, [0.0, 0.0, 0.0], [0.0, 100.0, 0.0], 10.0, rate_hz=10.0, alpha_deg=0.0)
    ep, vt = synthesize_vision(tr, VisionSettings(**CLEAN), landmarks=points({"P": (100.0, 1000.0, -200.0)}),
                               rng=np.random.default_rng(0))
    np.testing.assert_allclose(ep.pixel_uv[0, 0], [1161.53893, 622.54447], atol=2e-5)
    np.testing.assert_allclose(vt.pixel_true[0, 0], ep.pixel_uv[0, 0], atol=PX_ROUNDOFF)
    assert ep.detected[0, 0] and ep.reason[0, 0] == NotVisible.VISIBLE


def test_lever_arm_moves_the_camera():
    tr = level_north()
    s = VisionSettings(**{**CLEAN, "mount": {"lever_arm_body_m": (12.0, -1.0, 2.0)}})
    _, vt = synthesize_vision(tr, s, landmarks=points({"P": (0.0, 0.0, 0.0)}), rng=np.random.default_rng(0))
    # heading north, level: body (x fwd, y right, z down) = ENU (north, east, -up)
    d = FRAME.ecef_to_enu(vt.cam_pos_ecef) - tr.decimate(10).pos_enu
    np.testing.assert_allclose(d, np.tile([-1.0, 12.0, -2.0], (len(d), 1)), atol=0.02)  # curvature over 1 km: < 2 cm


# ------------------------------------------------------------------ visibility rules
SCENE = {"ahead": (0.0, 0.0, 0.0), "behind": (0.0, -8000.0, 0.0), "side": (3000.0, 0.0, 0.0),
         "far": (0.0, 20000.0, 0.0), "walled": (400.0, 500.0, 0.0), "tiny": (-50.0, 0.0, 0.0)}


def run_scene(terrain=None, **det):
    lms = points(SCENE)
    lm = build_landmarks(lms)
    lm = replace(lm, size_m=np.where(lm.id == "tiny", 0.01, 2.0))
    s = VisionSettings(**{**CLEAN, "detection": {**CLEAN["detection"], **det}})
    ep, _ = synthesize_vision(level_north(), s, landmarks=lm, terrain=terrain, rng=np.random.default_rng(1))
    return {k: ep.reason[:, i] for i, k in enumerate(ep.landmark_id)}, ep


def test_each_visibility_rule():
    wall = WallTerrain(FRAME, -100.0, 300.0, 500.0, 400.0)
    reasons, ep = run_scene(wall, max_range_m=10_000.0, min_size_px=0.5)
    assert (reasons["ahead"] == NotVisible.VISIBLE).all()
    assert (reasons["behind"] == NotVisible.AIRFRAME).all()
    assert (reasons["side"] == NotVisible.OUT_OF_IMAGE).all()
    assert (reasons["far"] == NotVisible.TOO_FAR).all()
    assert (reasons["walled"] == NotVisible.TERRAIN).all()
    assert (reasons["tiny"] == NotVisible.TOO_SMALL).all()
    assert wall.calls >= 1
    hidden = ep.landmark_id != "ahead"
    assert not ep.detected[:, hidden].any() and np.isnan(ep.pixel_uv[:, hidden]).all()
    assert np.isfinite(ep.pixel_uv[:, ~hidden]).all()


def test_each_rule_is_the_cause():
    """Lifting a rule makes exactly its landmark visible (the rules are not accidents of geometry)."""
    reasons, _ = run_scene(None, max_range_m=30_000.0, min_size_px=0.0)
    for k in ("ahead", "far", "walled", "tiny"):
        assert (reasons[k] == NotVisible.VISIBLE).all(), k
    assert (reasons["behind"] == NotVisible.AIRFRAME).all()
    assert (reasons["side"] == NotVisible.OUT_OF_IMAGE).all()
    # a wider camera sees the side landmark (34 deg off the nose)
    lms = points({"side": SCENE["side"]})
    s = VisionSettings(**{**CLEAN, "camera": {"preset": "approach-1080p", "hfov_deg": 80.0}})
    ep, _ = synthesize_vision(level_north(), s, landmarks=lms, rng=np.random.default_rng(1))
    assert ep.detected.all()


def test_image_margin():
    cam = approach_camera()
    # put a landmark so it projects 3 px inside the right border at t = 0 (camera at the CG, level, north)
    z = 4500.0 * math.cos(math.radians(9)) + 500.0 * math.sin(math.radians(9))
    u_target = cam.width_px - 0.5 - 3.0
    east = (u_target - cam.cx) * z / cam.fx
    tr = straight_truth(FRAME, [0.0, -4500.0, 500.0], [0.0, -4499.0, 500.0], 1.0, rate_hz=1.0, alpha_deg=0.0)
    for margin, ok in ((0.0, True), (5.0, False)):
        s = VisionSettings(**{**CLEAN, "detection": {**CLEAN["detection"], "margin_px": margin}})
        ep, vt = synthesize_vision(tr, s, landmarks=points({"E": (east, 0.0, 0.0)}), rng=np.random.default_rng(0))
        assert vt.pixel_true[0, 0, 0] == pytest.approx(u_target, abs=0.05)
        assert ep.detected[0, 0] == ok


# ------------------------------------------------------------------ attitude invariance
def test_bearing_angles_invariant_to_dithering():
    tr = seed_truth()
    lms = seed_triangle_settings(lpe_sigma_m=0.0)
    strong = {"tones": [{"axis": "pitch", "freq_hz": 3.0, "amplitude_deg": 0.5},
                        {"axis": "yaw", "freq_hz": 1.3, "amplitude_deg": 0.3}],
              "noise_rms_deg": (0.3, 0.2, 0.2), "noise_bandwidth_hz": 2.0}
    base = dict(camera={"preset": "va-raim-2015", "dpi": 720}, mount={"lever_arm_body_m": (0.0, 0.0, 0.0)})
    runs = {}
    for name, dith, sig in (("still", {"enabled": False}, 0.0), ("dith", strong, 0.0), ("dith_noisy", strong, 0.5)):
        s = VisionSettings(**base, dithering=dith, detection={"sigma_px": sig, "exposure_s": 0.0})
        runs[name] = synthesize_vision(tr, s, landmarks=lms, rng=np.random.default_rng(5))
    ep0, vt0 = runs["still"]
    # true angles from geometry
    lm = build_landmarks(lms)
    los = lm.pos_ecef[None] - vt0.cam_pos_ecef[:, None]
    los /= np.linalg.norm(los, axis=-1, keepdims=True)
    c_true = np.einsum("tid,tjd->tij", los, los)
    th = lambda c: np.arccos(np.clip(c, -1, 1))
    iu = np.triu_indices(3, 1)
    for name in runs:
        assert runs[name][0].detected.all(), name
    moved_px = np.nanmax(np.abs(runs["dith"][0].pixel_uv - ep0.pixel_uv))
    assert moved_px > 10.0  # dithering moves the pixels (0.5 deg ~ 8.7 px at 992 px focal)
    for name in ("still", "dith"):
        d = th(bearings_cos(runs[name][0].pixel_uv, ep0.K)) - th(c_true)
        assert np.abs(d[:, iu[0], iu[1]]).max() < 1e-9, name  # exact invariance without noise
    # with 0.5 px noise: angle error ~ N(0, ~sqrt(2) * 0.5 px / f); 5-sigma bound per sample
    f = ep0.K[0, 0]
    d = th(bearings_cos(runs["dith_noisy"][0].pixel_uv, ep0.K)) - th(c_true)
    assert np.abs(d[:, iu[0], iu[1]]).max() < 5 * math.sqrt(2) * 0.5 / f


# ------------------------------------------------------------------ noise statistics
def test_detection_noise_statistics():
    tr = seed_truth(rate_hz=10.0)
    s = VisionSettings(camera={"preset": "va-raim-2015", "dpi": 480}, detection={"sigma_px": 2.0, "exposure_s": 0.0})
    ep, vt = synthesize_vision(tr, s, landmarks=seed_triangle_settings(), rng=np.random.default_rng(11), n_trials=100)
    assert ep.detected.all()
    r = (ep.pixel_uv - vt.pixel_true).ravel()
    n = r.size  # 100 * 601 * 3 * 2 = 360600 independent draws
    assert abs(r.mean()) < stats.norm.ppf(1 - P_TAIL / 2) * 2.0 / math.sqrt(n)
    chi = np.sum(r**2) / 2.0**2
    assert stats.chi2.ppf(P_TAIL / 2, n) < chi < stats.chi2.ppf(1 - P_TAIL / 2, n)
    assert stats.kstest(r[:20000] / 2.0, "norm").pvalue > P_TAIL
    np.testing.assert_array_equal(ep.sigma_px, 2.0)
    np.testing.assert_allclose(r, (vt.noise_px).ravel(), atol=PX_ROUNDOFF)


def test_motion_blur_model():
    """Blur std = (1/sqrt 12) |omega| t_exp f; the reported sigma and the noise follow it (the per-landmark
    model, blur_model = "independent")."""
    tr = seed_truth(rate_hz=10.0)
    tr = replace(tr, omega_body=np.tile([0.0, 0.1, 0.0], (len(tr.t), 1)))  # 0.1 rad/s pitch rate
    s = VisionSettings(camera={"preset": "va-raim-2015", "dpi": 720}, dithering={"enabled": False},
                       detection={"sigma_px": 1.0, "exposure_s": 0.01, "blur_model": "independent"})
    ep, vt = synthesize_vision(tr, s, landmarks=seed_triangle_settings(), rng=np.random.default_rng(3), n_trials=60)
    f = ep.K[0, 0]
    blur = 0.1 * 0.01 * f / math.sqrt(12.0)  # = 0.2864 px at f = 992.1 px
    np.testing.assert_allclose(vt.blur_sigma_px, blur, rtol=1e-12)
    np.testing.assert_allclose(ep.sigma_px, math.hypot(1.0, blur), rtol=1e-12)
    r = (ep.pixel_uv - vt.pixel_true).ravel()
    chi = np.sum(r**2) / (1.0 + blur**2)
    assert stats.chi2.ppf(P_TAIL / 2, r.size) < chi < stats.chi2.ppf(1 - P_TAIL / 2, r.size)
    # and the chi-square would reject the model without blur (the test can fail)
    assert np.sum(r**2) > stats.chi2.ppf(1 - P_TAIL / 2, r.size)


#: a long-focus camera (f = 1e4 px, 33° field of view): ranges in their linear regime, the blur (3 px) above the DE
PRECISE = {"preset": "custom", "width_px": 6000, "height_px": 4000, "focal_px": 1e4}


def _frame_residuals(blur_model, n_trials=3000, k=30, sigma_px=0.3, camera=None):
    """Pixel errors (n, 6) of the seed triangle at epoch k, with the pinhole frame quantities to predict them:
    camera-axes landmark vectors (3, 3), the camera rate (3,) rad/s in camera axes, focal length."""
    tr = seed_truth(rate_hz=1.0)
    tr = replace(tr, omega_body=np.tile([0.02, 0.1, -0.03], (len(tr.t), 1)))  # rad/s, body axes
    s = VisionSettings(camera=camera or {"preset": "va-raim-2015", "dpi": 720}, dithering={"enabled": False},
                       detection={"sigma_px": sigma_px, "exposure_s": 0.01, "blur_model": blur_model})
    ep, vt = synthesize_vision(tr, s, landmarks=seed_triangle_settings(), rng=np.random.default_rng(5),
                               n_trials=n_trials)
    assert ep.detected[:, k].all()
    r = (ep.pixel_uv - vt.pixel_true)[:, k].reshape(n_trials, 6)
    from scipy.spatial.transform import Rotation

    R_c2e = Rotation.from_quat(vt.q_cam_to_ecef[0, k]).as_matrix()  # dithering off: one attitude for every trial
    p_cam = (vt.landmark_true_ecef - vt.cam_pos_ecef[k]) @ R_c2e  # (3, 3): rows R_c2eᵀ (m − c)
    w_cam = ep.camera.R_sensor_to_body.T @ tr.omega_body[0]
    return r, p_cam, w_cam, ep.K[0, 0], ep, vt, k


def _rotation_frame_cov(p_cam, w_cam, f, sigma_ind, bf=1 / math.sqrt(12.0), t_exp=0.01):
    """Pinhole closed form: a camera turned by ε (camera axes) sees p as p + p × ε, so
    ∂uv/∂ε = (f/z) [[1, 0, −x/z], [0, 1, −y/z]] [p]×; ε = u·bf·t_exp·ω, u ~ N(0, 1)."""
    G = []
    for x, y, z in p_cam:
        J = f / z * np.array([[1.0, 0.0, -x / z], [0.0, 1.0, -y / z]])
        G.append(J @ np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]]))
    g = np.vstack(G) @ (bf * t_exp * w_cam)  # (6,) px per unit u
    return sigma_ind**2 * np.eye(6) + np.outer(g, g)


def test_rotation_blur_moves_a_frame_together_as_the_closed_form_says():
    """blur_model = "rotation": the frame's pixel covariance against Monte Carlo of the sensor (whitened by the
    closed form it must be the identity) and the told σ the per-landmark part; the per-landmark model fails the
    same check (the test can fail)."""
    r, p_cam, w, f, ep, vt, k = _frame_residuals("rotation", camera=PRECISE)
    blur = (1 / math.sqrt(12.0)) * np.linalg.norm(w) * 0.01 * f
    assert blur > 2.5  # the common part dominates the 0.3 px detection error
    sigma_ind = math.hypot(0.3, 0.1 * blur)
    np.testing.assert_allclose(ep.sigma_px[:, k], sigma_ind, rtol=1e-9)
    C = _rotation_frame_cov(p_cam, w, f, sigma_ind)
    Lc = np.linalg.cholesky(C)
    z = np.linalg.solve(Lc, r.T).T
    n = len(z)
    assert np.abs(np.cov(z.T) - np.eye(6)).max() < 6.0 * math.sqrt(2.0 / n)  # ~6 σ of a sample covariance entry
    # the same sensor drawing blur per landmark is not this covariance
    r_i, *_ = _frame_residuals("independent", camera=PRECISE)
    z_i = np.linalg.solve(Lc, r_i.T).T
    assert np.abs(np.cov(z_i.T) - np.eye(6)).max() > 1.0


def test_common_blur_cancels_in_the_cosine_rule_ranges():
    """The vision-range σ on the seed triangle under each blur model against a brute-force Monte Carlo of the
    ranges: with the rotation model the blur's common part drops out of the angles between lines of sight,
    so the ranges' spread follows the per-landmark σ alone; drawn per landmark it follows the whole blur."""
    from testbed.integrity.vision_ranges import vision_pseudoranges

    out = {}
    for model in ("rotation", "independent"):
        r, p_cam, w, f, ep, vt, k = _frame_residuals(model, n_trials=2000, camera=PRECISE)
        lm = vt.landmark_true_ecef
        truth = np.linalg.norm(lm - vt.cam_pos_ecef[k], axis=-1)
        vr = vision_pseudoranges(ep.pixel_uv[:, k], ep.detected[:, k], ep.K, ep.sigma_px[:, k], lm,
                                 np.broadcast_to(truth, (len(r), 3)))
        err = vr.m - truth
        ok = np.isfinite(err).all(-1)
        assert ok.mean() > 0.99
        mc = err[ok].std(0)
        predicted = np.sqrt(np.diagonal(vr.Sigma_V[ok], axis1=-2, axis2=-1)).mean(0)  # from the told σ
        out[model] = mc
        np.testing.assert_allclose(mc, predicted, rtol=0.1)  # the told σ predicts the ranges' spread
    assert np.all(out["independent"] > 3.0 * out["rotation"])


def test_sigma_told_override():
    s = VisionSettings(detection={"sigma_px": 2.0, "sigma_told_px": 3.0})
    ep, _ = synthesize_vision(seed_truth(), s, landmarks=seed_triangle_settings(), rng=np.random.default_rng(0))
    np.testing.assert_array_equal(ep.sigma_px, 3.0)


# ------------------------------------------------------------------ survey error, attitude reference
def test_survey_error_statistics():
    s = VisionSettings()
    lms = seed_triangle_settings(lpe_sigma_m=0.05)
    ep, vt = synthesize_vision(level_north(duration=1.0), s, landmarks=lms, rng=np.random.default_rng(2), n_trials=2000)
    e = ep.landmark_pos_ecef - vt.landmark_true_ecef  # (2000, 3, 3), per trial, constant over the flight
    assert ep.landmark_pos_ecef.shape == (2000, 3, 3)
    chi = np.sum(e**2) / 0.05**2
    assert stats.chi2.ppf(P_TAIL / 2, e.size) < chi < stats.chi2.ppf(1 - P_TAIL / 2, e.size)


def test_attitude_reference_errors():
    tr = seed_truth(rate_hz=10.0)
    s = VisionSettings(attitude_ref={"bias_sigma_deg": (0.1, 0.2, 0.5), "noise_sigma_deg": (0.02, 0.03, 0.04)})
    ep, vt = synthesize_vision(tr, s, landmarks=seed_triangle_settings(), rng=np.random.default_rng(4), n_trials=1000)
    err = q_to_euler(ep.q_body_to_enu_ref) - q_to_euler(tr.q_body_to_enu)  # (B, T, 3)
    err[..., 2] = (err[..., 2] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(err, vt.attitude_ref_error, atol=1e-9)
    bias = err.mean(axis=1)  # per-trial bias estimate (plus noise / sqrt(601))
    resid = err - bias[:, None]
    sb, sn = np.radians([0.1, 0.2, 0.5]), np.radians([0.02, 0.03, 0.04])
    T = err.shape[1]
    for k in range(3):
        v_b = sb[k] ** 2 + sn[k] ** 2 / T
        chi = np.sum(bias[:, k] ** 2) / v_b
        assert stats.chi2.ppf(P_TAIL / 2, 1000) < chi < stats.chi2.ppf(1 - P_TAIL / 2, 1000), k
        chi = np.sum(resid[..., k] ** 2) / sn[k] ** 2
        dof = 1000 * (T - 1)
        assert stats.chi2.ppf(P_TAIL / 2, dof) < chi < stats.chi2.ppf(1 - P_TAIL / 2, dof), k
    np.testing.assert_allclose(ep.attitude_sigma, np.hypot(sb, sn))


# ------------------------------------------------------------------ faults
def clean_seed(**kw):
    s = VisionSettings(camera={"preset": "va-raim-2015", "dpi": 720}, dithering={"enabled": False},
                       detection={"sigma_px": 0.0, "exposure_s": 0.0})
    return synthesize_vision(seed_truth(), s, landmarks=seed_triangle_settings(lpe_sigma_m=0.0),
                             rng=np.random.default_rng(7), **kw)


def test_pixel_bias_fault():
    ep0, _ = clean_seed()
    f = PixelBias(kind="pixel_bias", landmark="T2", magnitude_px=5.0, angle_deg=30.0, onset_s=20.0, end_s=40.0)
    ep, vt = clean_seed(faults=[f])
    on = (ep.t >= 20.0) & (ep.t < 40.0)
    d = ep.pixel_uv - ep0.pixel_uv
    np.testing.assert_allclose(d[on, 1], np.tile([5 * math.cos(math.radians(30)), 5 * math.sin(math.radians(30))],
                                                 (on.sum(), 1)), atol=PX_ROUNDOFF)
    assert np.abs(d[~on]).max() < PX_ROUNDOFF and np.abs(d[:, [0, 2]]).max() < PX_ROUNDOFF
    assert (vt.faulty[:, 1] == on).all() and not vt.faulty[:, [0, 2]].any()
    assert (vt.fault_kind[on, 1] == FaultKind.PIXEL_BIAS).all()


def test_pixel_bias_random_target_per_trial():
    f = PixelBias(kind="pixel_bias", magnitude_px=5.0, onset_s=10.0)
    ep, vt = clean_seed(faults=[f], n_trials=300)
    hit = vt.faulty.any(axis=1)  # (300, 3)
    assert (hit.sum(axis=1) == 1).all()
    counts = hit.sum(axis=0)  # uniform over the 3 detected landmarks
    assert stats.chisquare(counts).pvalue > P_TAIL


def test_landmark_moved_fault_pixel_follows_the_real_landmark():
    """Moving T1 by delta equals a scene where T1 stands at the moved point (zero survey error)."""
    delta = (10.0, -5.0, 2.0)
    f = LandmarkMoved(kind="landmark_moved", landmark="T1", delta_enu_m=delta, onset_s=30.0)
    ep, vt = clean_seed(faults=[f])
    lm = build_landmarks(seed_triangle_settings(lpe_sigma_m=0.0))
    lat, lon = 29.3065, 94.3359  # centre: R_ecef_to_enu varies < 2e-5 rad over 100 m (< 0.3 mm here)
    moved_ecef = lm.pos_ecef[0] + R_ecef_to_enu(lat, lon).T @ np.asarray(delta)
    lm2 = replace(lm, pos_ecef=np.vstack([moved_ecef, lm.pos_ecef[1:]]))
    s = VisionSettings(camera={"preset": "va-raim-2015", "dpi": 720}, dithering={"enabled": False},
                       detection={"sigma_px": 0.0, "exposure_s": 0.0})
    ep2, _ = synthesize_vision(seed_truth(), s, landmarks=lm2, rng=np.random.default_rng(7))
    on = ep.t >= 30.0
    np.testing.assert_allclose(ep.pixel_uv[on, 0], ep2.pixel_uv[on, 0], atol=1e-3)
    assert np.abs(ep.pixel_uv[on, 0] - ep2.pixel_uv[on, 0]).max() < 1e-3
    assert np.abs(ep.pixel_uv[~on, 0] - ep2.pixel_uv[~on, 0]).min() > 0.1  # before onset: the survey point
    np.testing.assert_allclose(ep.landmark_pos_ecef, lm.pos_ecef)  # the survey is unchanged
    assert (vt.landmark_moved[:, 0] == on).all() and (vt.fault_kind[on, 0] == FaultKind.LANDMARK_MOVED).all()


def test_misassociation_swaps_two_slots():
    ep0, _ = clean_seed()
    f = Misassociation(kind="misassociation", landmarks=("T1", "T3"), onset_s=5.0, end_s=15.0)
    ep, vt = clean_seed(faults=[f])
    on = (ep.t >= 5.0) & (ep.t < 15.0)
    np.testing.assert_array_equal(ep.pixel_uv[on][:, [0, 1, 2]], ep0.pixel_uv[on][:, [2, 1, 0]])
    np.testing.assert_array_equal(ep.pixel_uv[~on], ep0.pixel_uv[~on])
    assert (vt.faulty[on][:, [0, 2]]).all() and not vt.faulty[on][:, 1].any() and not vt.faulty[~on].any()
    with pytest.raises(ValueError, match="not in the scene"):
        clean_seed(faults=[Misassociation(kind="misassociation", landmarks=("T1", "X9"))])


# ------------------------------------------------------------------ determinism and batching
def test_rerun_is_bit_identical_and_trials_differ():
    s = VisionSettings()
    args = dict(landmarks=seed_triangle_settings(), n_trials=4)
    a, ta = synthesize_vision(seed_truth(), s, rng=np.random.default_rng(99), **args)
    b, tb = synthesize_vision(seed_truth(), s, rng=np.random.default_rng(99), **args)
    for x, y in ((a.pixel_uv, b.pixel_uv), (a.q_body_to_enu_ref, b.q_body_to_enu_ref), (ta.dither_cam, tb.dither_cam)):
        assert np.array_equal(x, y, equal_nan=True)
    assert a.pixel_uv.shape == (4, 601, 3, 2) and a.detected.shape == (4, 601, 3)
    assert not np.allclose(a.pixel_uv[0], a.pixel_uv[1])
    np.testing.assert_array_equal(ta.cam_pos_ecef, tb.cam_pos_ecef)
    assert ta.cam_pos_ecef.shape == (601, 3)  # geometry once


def test_rate_decimation_and_bad_inputs():
    tr = seed_truth(rate_hz=50.0)
    ep, _ = synthesize_vision(tr, VisionSettings(rate_hz=5.0), landmarks=seed_triangle_settings(),
                              rng=np.random.default_rng(0))
    np.testing.assert_allclose(np.diff(ep.t), 0.2)
    with pytest.raises(TypeError, match="Generator"):
        synthesize_vision(tr, VisionSettings(), landmarks=seed_triangle_settings(), rng=0)
    with pytest.raises(ValueError, match="n_trials"):
        synthesize_vision(tr, VisionSettings(), landmarks=seed_triangle_settings(), rng=np.random.default_rng(0),
                          n_trials=0)


# ------------------------------------------------------------------ scenarios
@pytest.mark.parametrize("dpi", [120, 300, 480, 720])
def test_seed_scenario_triangle_in_view_whole_sortie(dpi):
    s = VisionSettings(camera={"preset": "va-raim-2015", "dpi": dpi})
    ep, vt = synthesize_vision(seed_truth(), s, landmarks=seed_triangle_settings(), rng=np.random.default_rng(dpi),
                               n_trials=20)
    assert ep.detected.all(), np.unique(ep.reason)
    assert 2000 < vt.range_m.min() and vt.range_m.max() < 8100  # 2.09-7.99 km along the path


def runway_final(distance_m=13_000.0, tch_m=15.0, speed=72.0):
    """Straight 3 deg final to ZUNZ 05 on the reciprocal of 054.65 deg, crossing the threshold at tch_m."""
    fr = airport.runway_frame()
    c = math.radians(airport.RWY05_COURSE_DEG)
    along = np.array([math.sin(c), math.cos(c), 0.0])
    start = -distance_m * along + [0.0, 0.0, tch_m + distance_m * math.tan(math.radians(3.0))]
    end = np.array([0.0, 0.0, tch_m])
    return straight_truth(fr, start, end, float(np.linalg.norm(end - start)) / speed, rate_hz=10.0)


def test_runway_final_points_come_into_view():
    tr = runway_final()
    ep, vt = synthesize_vision(tr, VisionSettings(), landmarks=zunz_runway_settings(), rng=np.random.default_rng(0))
    assert ep.detected[0].all()  # geometrically all in view from 13 km (ranges 13.0-16.0 km < 20 km)
    # with the apparent-size rule (5 m features, >= 2 px): first seen at range f * 5 / 2
    s = VisionSettings(detection={"min_size_px": 2.0})
    ep, vt = synthesize_vision(tr, s, landmarks=zunz_runway_settings(), rng=np.random.default_rng(0))
    r_on = ep.K[0, 0] * 5.0 / 2.0  # 5146.8 m
    step = 72.0 * 0.1 * 1.01
    for k in range(len(ep.landmark_id)):
        i = np.argmax(ep.detected[:, k])
        assert ep.detected[i:, k].sum() > 0 and not ep.detected[:i, k].any()
        assert r_on - step <= vt.range_m[i, k] <= r_on
        assert (ep.reason[:i, k] == NotVisible.TOO_SMALL).all()


def test_distortion_is_removed_from_reported_pixels():
    """With lens distortion the detector works in the raw image; reported pixels are ideal pinhole ones."""
    base = dict(dithering={"enabled": False}, detection={"sigma_px": 0.0, "exposure_s": 0.0})
    lms = seed_triangle_settings(lpe_sigma_m=0.0)
    ep0, _ = synthesize_vision(seed_truth(), VisionSettings(**base), landmarks=lms, rng=np.random.default_rng(0))
    s = VisionSettings(**base, camera={"preset": "approach-1080p", "k1": -0.2, "k2": 0.05, "p1": 1e-3})
    ep, vt = synthesize_vision(seed_truth(), s, landmarks=lms, rng=np.random.default_rng(0))
    assert ep.detected.all()
    np.testing.assert_allclose(ep.pixel_uv, ep0.pixel_uv, atol=1e-6)
    np.testing.assert_allclose(ep.pixel_uv, vt.pixel_true, atol=1e-6)


def test_seed_scenario_with_the_two_ridge_terrain():
    terrain_mod = pytest.importorskip("testbed.world.terrain")
    s = VisionSettings(camera={"preset": "va-raim-2015", "dpi": 120})
    ep, _ = synthesize_vision(seed_truth(), s, landmarks=seed_triangle_settings(), terrain=terrain_mod.TwoRidges(),
                              rng=np.random.default_rng(0))
    assert ep.detected.all(), np.unique(ep.reason)
