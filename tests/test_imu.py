"""The IMU sensor and the strapdown equations (testbed.inertial, testbed.sensors.imu;
docs/design/nav-filter.md §3–§4, test ids §12).

References: scipy's rotations, the published WGS84 normal gravity, JSBSim's own
CG specific force, closed-form noise statistics (Allan deviation of white
noise, Gauss–Markov variance and correlation) with their sampling error at
fixed seeds, and the truth a mechanisation must give back.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from testbed.api import load_approach
from testbed.flight.fly import fly
from testbed.flight.kinematic import straight_truth
from testbed.flight.settings import Gusts
from testbed.inertial import (body_to_world, earth_rate_world, gravity_world, local_to_world, mechanise,
                              normal_gravity, so3_exp, so3_log)
from testbed.sensors.imu import PRESETS, ImuErrorStream, ImuSettings, sample_imu, true_increments
from testbed.world.airport import runway_frame

FRAME = runway_frame()


def test_so3_exp_log_agree_with_scipy_and_round_trip():
    """Angles up to 3 rad (the log's domain is below π; increments are milliradians) and down to 1e-7 rad."""
    u = np.random.default_rng(0).normal(0.0, 1.0, (200, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    phi = u * np.r_[np.linspace(1e-3, 3.0, 100), np.full(100, 1e-7)][:, None]
    R = so3_exp(phi)
    np.testing.assert_allclose(R, Rotation.from_rotvec(phi).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(so3_log(R), phi, atol=1e-12, rtol=1e-9)


def test_normal_gravity_matches_the_published_wgs84_values():
    """NIMA TR8350.2: γ_e = 9.7803253359, γ_p = 9.8321849378 m/s²; free-air gradient ≈ −0.3086 mGal/m."""
    np.testing.assert_allclose(normal_gravity(0.0, 0.0), 9.7803253359, rtol=1e-10)
    np.testing.assert_allclose(normal_gravity(90.0, 0.0), 9.8321849378, rtol=1e-10)
    grad = (normal_gravity(45.0, 1000.0) - normal_gravity(45.0, 0.0)) / 1000.0
    np.testing.assert_allclose(grad, -3.086e-6, rtol=5e-3)
    g = gravity_world(FRAME, np.zeros(3))
    np.testing.assert_allclose(g[:2], 0.0, atol=1e-12)  # straight down at the frame origin


def _world_pose(truth, lever=(0.0, 0.0, 0.0)):
    C = body_to_world(FRAME, truth.pos_enu, truth.q_body_to_enu)
    v = local_to_world(FRAME, truth.pos_enu, truth.vel_enu)
    return C, v, truth.pos_enu + np.einsum("tij,j->ti", C, np.asarray(lever))


def _mechanise_truth(truth, settings):
    t, dth, dv, dt = true_increments(truth, settings)
    k = int(round(dt / np.median(np.diff(truth.t))))
    C, v, p = _world_pose(truth, settings.lever_arm_body_m)
    Ci, vi, pi = C[::k], v[::k], p[::k]
    if np.any(settings.lever_arm_body_m):  # the IMU point's Earth-relative velocity at the start
        w_ie = earth_rate_world(FRAME, settings.earth_rotation)
        vi0 = vi[0] + Ci[0] @ np.cross(truth.omega_body[0] - Ci[0].T @ w_ie, settings.lever_arm_body_m)
    else:
        vi0 = vi[0]
    Cm, vm, pm = mechanise(FRAME, Ci[0], vi0, pi[0], dth, dv, dt, settings.earth_rotation)
    att = np.linalg.norm(so3_log(np.swapaxes(Ci, -1, -2) @ Cm), axis=-1)
    return att, vm, pm, (Ci, vi, pi)


def _imu_point_velocity(truth, settings, Ci, vi):
    """The IMU point's Earth-relative velocity at the mechanised epochs: v + C (ω − Cᵀω_ie) × l."""
    k = int(round((1.0 / settings.rate_hz) / np.median(np.diff(truth.t))))
    w_ie = earth_rate_world(FRAME, settings.earth_rotation)
    w = truth.omega_body[::k] - np.einsum("tji,j->ti", Ci, w_ie)
    return vi + np.einsum("tij,tj->ti", Ci, np.cross(w, settings.lever_arm_body_m))


def test_error_free_imu_and_mechanisation_reproduce_a_straight_truth():
    """T-IMU-1 on the kinematic final: attitude and velocity to round-off, position to the trapezoid's
    error (zero jerk: round-off)."""
    tr = straight_truth(FRAME, [-13000.0, -9000.0, 700.0], [0.0, 0.0, 15.0], 40.0, rate_hz=120.0)
    for rot in (True, False):
        att, vm, pm, (_, vi, pi) = _mechanise_truth(tr, ImuSettings(grade="perfect", earth_rotation=rot))
        assert att.max() < 1e-9 and np.abs(vm - vi).max() < 1e-9 and np.abs(pm - pi).max() < 1e-6


def _last_40_s(gusts: str):
    ap = load_approach("zunz-rwy05-final")
    cfg = ap.config.model_copy(update={"gusts": Gusts(intensity=gusts, seed=3)})
    tr = fly(dataclasses.replace(ap, config=cfg).flight_plan).truth
    return tr.at_indices(np.flatnonzero(tr.t >= tr.t[-1] - 40.0))


@pytest.fixture(scope="module")
def gusty():
    """The runway-05 final flown by JSBSim in moderate gusts, last 40 s."""
    return _last_40_s("moderate")


@pytest.fixture(scope="module")
def calm():
    return _last_40_s("none")


def test_error_free_imu_and_mechanisation_reproduce_the_flown_truth(gusty):
    """T-IMU-1 on JSBSim's gusty flight, with a 5 m lever arm: attitude 1e-9 rad, the IMU point's velocity 5e-8 m/s;
    position within the trapezoid bound T·Δt²/12·max|jerk| (jerk of the truth by differences)."""
    st = ImuSettings(grade="perfect", lever_arm_body_m=(5.0, 0.5, -1.0))
    att, vm, pm, (Ci, vi, pi) = _mechanise_truth(gusty, st)
    dt = 1.0 / 120.0
    v_ned = gusty.vel_enu
    jerk = np.abs(np.diff(v_ned, 2, axis=0)).max() / dt**2
    bound = (gusty.t[-1] - gusty.t[0]) * dt**2 / 12.0 * jerk + 1e-6
    assert att.max() < 1e-9
    dv_max = np.abs(vm - _imu_point_velocity(gusty, st, Ci, vi)).max()
    assert dv_max < 5e-8, dv_max  # 1.4e-8 measured
    assert np.abs(pm - pi).max() < max(bound, 0.01)


def test_increments_match_jsbsim_cg_specific_force_and_the_eye_point_is_not_the_cg(calm, gusty):
    """T-IMU-2: in calm air Δv/Δt of the error-free IMU at the CG equals JSBSim's own CG specific force
    (load factors; the row read before a step carries the step before it, so interval i → i+1 meets
    row i + 1) to ≤ 2 mg RMS (measured 0.01 mg), and Δθ/Δt its inertial body rates to 1e-4 rad/s; in
    gusts the pilot-eye-point field (what the truth called "at the CG" before) is ≥ 10 mg off the CG's.
    (In gusts the CG comparison itself is limited by JSBSim's multistep integrator, whose effective
    acceleration over a step blends the last steps': 5 mg RMS.)"""
    t, dth, dv, dt = true_increments(calm, ImuSettings(grade="perfect"))
    f = dv / dt
    F = calm.specific_force_cg_body[1:]
    rms = np.sqrt(np.mean(np.sum((f - F) ** 2, -1)))
    assert rms < 2e-3 * 9.80665, rms
    w = dth / dt
    assert np.sqrt(np.mean(np.sum((w - calm.omega_body[1:]) ** 2, -1))) < 1e-4
    d = gusty.specific_force_eye_body - gusty.specific_force_cg_body
    assert np.sqrt(np.mean(np.sum(d**2, -1))) > 10e-3 * 9.80665


def _allan(x: np.ndarray, m: int) -> np.ndarray:
    """Overlapping Allan deviation of rate samples x (..., K) at cluster size m (per leading element)."""
    theta = np.cumsum(x, -1)
    d = theta[..., 2 * m:] - 2 * theta[..., m:-m] + theta[..., :-2 * m]
    return np.sqrt(np.mean(d**2, -1) / (2.0 * m * m))


def test_white_noise_allan_deviation_is_the_random_walk_figure():
    """T-IMU-3: the rate noise of an HG1700 at 120 Hz has ADEV = N/√τ (slope −½) at τ = 0.1, 1 s within 3 %
    (biases off: custom grade with the preset's random walks)."""
    f = PRESETS["hg1700"]
    st = ImuSettings(grade="custom", gyro_bias_sigma_rad_s=0.0, gyro_inrun_sigma_rad_s=0.0, arw_rad_sqrt_s=f[2],
                     accel_bias_sigma_m_s2=0.0, accel_inrun_sigma_m_s2=0.0, vrw_m_s_sqrt_s=f[5], gm_tau_s=3600.0)
    dt = 1.0 / 120.0
    s = ImuErrorStream(st, dt, np.random.default_rng(3), n_trials=64)
    e = s.draw(120 * 60)
    for key, N in (("white_g", f[2]), ("white_a", f[5])):
        rate = np.moveaxis(e[key] / dt, -2, -1)  # (B, 3, K)
        for tau in (0.1, 1.0):
            m = int(round(tau / dt))
            adev = float(np.mean(_allan(rate, m)))
            np.testing.assert_allclose(adev, N / np.sqrt(tau), rtol=0.03)


def test_bias_processes_have_their_variance_and_correlation_time():
    """T-IMU-3: turn-on + in-run bias variance σ_b0² + σ_GM² across trials, and the in-run part's
    correlation at lag τ equals e⁻¹ (ADIS16364 preset, τ = 100 s, 10 Hz, 400 trials × 300 s)."""
    st = ImuSettings(grade="adis16364", rate_hz=10.0)
    f = st.figures()
    s = ImuErrorStream(st, 0.1, np.random.default_rng(4), n_trials=400)
    e = s.draw(3000)
    b = e["bias_g"]  # (400, 3000, 3)
    np.testing.assert_allclose(b.std(axis=(0, 2)).mean(), np.hypot(f["gyro_bias"], f["gyro_inrun"]), rtol=0.05)
    beta = b - s.b0["g"][:, None, :]
    lag = 1000  # 100 s
    r = np.mean(beta[:, :-lag] * beta[:, lag:]) / np.mean(beta**2)
    np.testing.assert_allclose(r, np.exp(-1.0), atol=0.05)


def test_chunked_draws_equal_one_draw_and_one_trial_is_prefix_stable():
    """T-IMU-4: the error stream drawn in chunks of any size equals one draw, bit for bit; one IMU's
    first k intervals do not depend on how many follow."""
    st = ImuSettings(grade="adis16364", scale_factor_ppm=300.0)
    one = ImuErrorStream(st, 1 / 120, np.random.default_rng(5), n_trials=3).draw(1000)
    s = ImuErrorStream(st, 1 / 120, np.random.default_rng(5), n_trials=3)
    parts = [s.draw(k) for k in (1, 0, 313, 686)]
    for key in one:
        np.testing.assert_array_equal(np.concatenate([p[key] for p in parts], axis=-2), one[key])
    tr = straight_truth(FRAME, [-3000.0, -2000.0, 300.0], [0.0, 0.0, 15.0], 10.0, rate_hz=120.0)
    a, _ = sample_imu(tr, st, np.random.default_rng(6))
    b, _ = sample_imu(tr.at_indices(np.arange(500)), st, np.random.default_rng(6))
    np.testing.assert_array_equal(a.dtheta[:499], b.dtheta)
    np.testing.assert_array_equal(a.dvel[:499], b.dvel)


def test_sample_imu_applies_biases_scale_and_noise_as_stated():
    """Measured − (1 + s)·true − b·Δt is the white noise the truth record reports, to round-off."""
    tr = straight_truth(FRAME, [-3000.0, -2000.0, 300.0], [0.0, 0.0, 15.0], 5.0, rate_hz=120.0)
    st = ImuSettings(grade="consumer_mems", scale_factor_ppm=1000.0)
    imu, it = sample_imu(tr, st, np.random.default_rng(7), n_trials=4)
    res = imu.dvel - (1 + it.accel_scale[:, None, :]) * it.dvel - it.accel_bias * imu.dt
    np.testing.assert_allclose(res.std(), st.figures()["vrw"] * np.sqrt(imu.dt), rtol=0.1)
    assert imu.dtheta.shape == (4, tr.t.size - 1, 3) and imu.t[0] == pytest.approx(tr.t[1])


def test_bad_settings_name_the_key():
    with pytest.raises(ValueError, match="grade 'custom' needs every one of"):
        ImuSettings(grade="custom", arw_rad_sqrt_s=1e-4)
    with pytest.raises(ValueError, match="only read with grade = 'custom'"):
        ImuSettings(grade="hg1700", arw_rad_sqrt_s=1e-4)
    tr = straight_truth(FRAME, [0.0, -2000.0, 300.0], [0.0, 0.0, 15.0], 2.0, rate_hz=120.0)
    with pytest.raises(ValueError, match="imu.rate_hz = 50: expected a divisor of the truth rate 120 Hz"):
        true_increments(tr, ImuSettings(rate_hz=50.0))
