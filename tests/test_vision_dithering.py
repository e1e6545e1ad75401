"""Mount, attitude dithering (tones and band-limited noise), attitude-reference helpers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal, stats

from testbed.frames import euler_to_q_body_to_enu
from testbed.sensors.vision import DitheringSettings, MountSettings, dithering_angles, mount_from_settings
from testbed.sensors.vision.attitude_ref import euler_to_q_fast, q_to_euler
from testbed.sensors.vision.camera import approach_camera

P_TAIL = 1e-4
DEG = math.pi / 180


def test_mount_orientation():
    m = mount_from_settings(MountSettings())
    np.testing.assert_allclose(m.R_sensor_to_body @ [0, 0, 1], [math.cos(9 * DEG), 0, math.sin(9 * DEG)], atol=1e-15)
    np.testing.assert_allclose(m.R_sensor_to_body @ [1, 0, 0], [0, 1, 0], atol=1e-15)  # image right = right wing
    np.testing.assert_allclose(m.lever_arm_body, [12.0, 0.0, 1.0])
    m = mount_from_settings(MountSettings(pitch_deg=0.0, yaw_deg=10.0))
    np.testing.assert_allclose(m.R_sensor_to_body @ [0, 0, 1], [math.cos(10 * DEG), math.sin(10 * DEG), 0], atol=1e-15)
    assert np.linalg.det(m.R_sensor_to_body) == pytest.approx(1.0)


def test_tones_fft_amplitude_phase():
    fs, dur = 200.0, 60.0
    t = np.arange(0, dur, 1 / fs)
    s = DitheringSettings(tones=[{"axis": "pitch", "freq_hz": 12.0, "amplitude_deg": 0.1, "phase_deg": 30.0},
                                 {"axis": "yaw", "freq_hz": 7.0, "amplitude_deg": 0.05},
                                 {"axis": "roll", "freq_hz": 23.5, "amplitude_deg": 0.2}],
                          noise_rms_deg=(0.0, 0.0, 0.0))
    d, r = dithering_angles(t, s, np.random.default_rng(0))
    assert d.shape == (t.size, 3)
    freqs = np.fft.rfftfreq(t.size, 1 / fs)
    for k, (f0, amp) in enumerate([(12.0, 0.1), (7.0, 0.05), (23.5, 0.2)]):  # camera x=pitch, y=yaw, z=roll
        X = np.abs(np.fft.rfft(d[:, k])) * 2 / t.size
        assert freqs[np.argmax(X)] == pytest.approx(f0)
        assert X.max() == pytest.approx(amp * DEG, rel=1e-9)  # integer number of cycles: no leakage
    assert d[0, 0] == pytest.approx(0.1 * DEG * math.sin(30 * DEG), rel=1e-12)
    # the rate is the derivative: central difference with h = 1 us (same seed -> same phases)
    h = 1e-6
    dp, _ = dithering_angles(t + h, s, np.random.default_rng(0))
    dm, _ = dithering_angles(t - h, s, np.random.default_rng(0))
    np.testing.assert_allclose(r, (dp - dm) / (2 * h), atol=1e-6 * np.abs(r).max())


def test_band_limited_noise_statistics_and_bandwidth():
    fs, dur, bw = 50.0, 40.0, 2.0
    t = np.arange(0, dur, 1 / fs)
    rms = (0.03, 0.05, 0.08)  # roll, pitch, yaw
    s = DitheringSettings(tones=[], noise_rms_deg=rms, noise_bandwidth_hz=bw)
    d, r = dithering_angles(t, s, np.random.default_rng(1), n_trials=400)
    assert d.shape == (400, t.size, 3)
    cam_rms = np.radians([rms[1], rms[2], rms[0]])  # camera x = pitch, y = yaw, z = roll
    # across trials at one epoch the samples are independent N(0, rms^2)
    x = d[:, t.size // 2, :]
    for k in range(3):
        z = x[:, k] / cam_rms[k]
        assert abs(z.mean()) < stats.norm.ppf(1 - P_TAIL / 2) / math.sqrt(400)
        chi = np.sum(z**2)
        assert stats.chi2.ppf(P_TAIL / 2, 400) < chi < stats.chi2.ppf(1 - P_TAIL / 2, 400)
        assert stats.kstest(z, "norm").pvalue > P_TAIL
    # PSD: 2nd-order Butterworth |H|^2 = 1 / (1 + (f/bw)^4): half power at bw, 1/17 at 2 bw
    f, P = signal.welch(d[..., 1], fs=fs, nperseg=512, axis=-1)
    P = P.mean(axis=0)
    low = P[(f > 0.1) & (f < 0.5)].mean()
    at = lambda f0: np.interp(f0, f, P) / low
    assert 0.42 < at(bw) < 0.58
    assert 0.04 < at(2 * bw) < 0.08
    # the total power equals the configured rms^2 (Parseval on the averaged PSD)
    assert np.trapezoid(P, f) == pytest.approx(cam_rms[1] ** 2, rel=0.05)
    # the rate is the derivative of the angle (interpolated on the fine grid)
    fd = (d[:, 2:, 1] - d[:, :-2, 1]) * fs / 2
    assert np.corrcoef(fd.ravel(), r[:, 1:-1, 1].ravel())[0, 1] > 0.95


def test_tone_plus_noise_dominant_frequency():
    fs = 100.0
    t = np.arange(0, 30, 1 / fs)
    s = DitheringSettings(tones=[{"axis": "pitch", "freq_hz": 12.0, "amplitude_deg": 0.03}],
                          noise_rms_deg=(0.02, 0.02, 0.02), noise_bandwidth_hz=5.0)
    d, _ = dithering_angles(t, s, np.random.default_rng(2))
    X = np.abs(np.fft.rfft(d[:, 0] - d[:, 0].mean()))
    assert np.fft.rfftfreq(t.size, 1 / fs)[np.argmax(X)] == pytest.approx(12.0)


def test_dithering_seeded_and_disabled():
    t = np.linspace(0, 10, 101)
    s = DitheringSettings()
    a, _ = dithering_angles(t, s, np.random.default_rng(5), n_trials=3)
    b, _ = dithering_angles(t, s, np.random.default_rng(5), n_trials=3)
    assert np.array_equal(a, b) and not np.allclose(a[0], a[1])
    z, zr = dithering_angles(t, DitheringSettings(enabled=False), np.random.default_rng(5))
    assert not z.any() and not zr.any()


@pytest.mark.parametrize("axis,du,dv", [("pitch", 0.0, +1.0), ("yaw", -1.0, 0.0)])
def test_dither_axis_meaning_in_the_image(axis, du, dv):
    """+pitch tilts the camera up (scene moves down the image); +yaw turns it right (scene moves left)."""
    from scipy.spatial.transform import Rotation
    cam = approach_camera()
    delta = 0.2 * DEG
    vec = np.zeros(3)
    vec[{"pitch": 0, "yaw": 1}[axis]] = delta
    R_d = Rotation.from_rotvec(vec).as_matrix()  # camera_true = camera_nominal · R_d
    p_nom = np.array([0.0, 0.0, 1000.0])
    uv, _ = cam.project(R_d.T @ p_nom)
    np.testing.assert_allclose(uv - [cam.cx, cam.cy], [du * cam.fx * math.tan(delta), dv * cam.fy * math.tan(delta)],
                               atol=1e-9)


def test_fast_euler_quaternion_matches_frames():
    rng = np.random.default_rng(0)
    e = rng.uniform([-1.5, -1.5, -3.1], [1.5, 1.5, 3.1], size=(500, 3))
    a = euler_to_q_fast(e)
    b = euler_to_q_body_to_enu(e[:, 0], e[:, 1], e[:, 2])
    np.testing.assert_allclose(np.abs(np.sum(a * b, axis=-1)), 1.0, atol=1e-12)  # same rotation (q ~ -q)
    np.testing.assert_allclose(q_to_euler(b), e, atol=1e-12)
