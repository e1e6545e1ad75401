"""Camera mount and attitude dithering: the camera's true pose on the airframe.

True camera attitude (camera axes x right, y down, z forward)::

    R_cam_to_ecef = R_enu_to_ecef(at the camera) · R_body_to_enu (truth)
                    · R_cam_to_body (mount) · R_dither

``R_dither = exp([δ]×)`` with δ a small rotation vector in camera axes:
δ_x = "pitch" (about image right), δ_y = "yaw" (about image down),
δ_z = "roll" (about the optical axis). δ(t) = Σ tones + band-limited noise.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal
from scipy.spatial.transform import Rotation

from testbed.frames import R_ecef_to_enu, ecef_to_geodetic, q_to_R
from testbed.records import Mount

from .settings import DitheringSettings, MountSettings

# Named axis -> camera-frame component of the dithering rotation vector.
AXIS_TO_CAM = {"pitch": 0, "yaw": 1, "roll": 2}
# Settings triples are (roll, pitch, yaw): their camera components.
RPY_TO_CAM = np.array([2, 0, 1])  # cam component of roll, pitch, yaw

# Camera axes (x right, y down, z fwd) -> body FRD for a camera looking along body x.
R_CAM0_TO_BODY = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def mount_from_settings(settings: MountSettings) -> Mount:
    """The camera :class:`~testbed.records.Mount` (lever arm, R_cam_to_body) from its settings."""
    R_mount = Rotation.from_euler("ZYX", [settings.yaw_deg, settings.pitch_deg, settings.roll_deg],
                                  degrees=True).as_matrix()
    return Mount(lever_arm_body=np.asarray(settings.lever_arm_body_m, float),
                 R_sensor_to_body=R_mount @ R_CAM0_TO_BODY)


def _lowpass_noise(t: NDArray, rms: NDArray, bandwidth_hz: float, rng: np.random.Generator,
                   batch: tuple[int, ...], sample_rate_hz: float | None = None) -> tuple[NDArray, NDArray]:
    """Band-limited Gaussian noise and its time derivative sampled at ``t``.

    White noise on a fine grid (fs = max(10 × the bandwidth, 2 × the sample
    rate)) through a 2nd-order Butterworth low-pass, scaled by the filter's
    impulse-response energy so the stationary std is ``rms`` per component.
    The grid starts 20 / bandwidth seconds before ``t[0]`` (burn-in: the causal
    filter is stationary by ``t[0]``, its start-up transient decays as
    exp(-2π·0.7·20) ≈ 1e-38), the rate is the central difference on the grid,
    linearly interpolated like the angle.

    Prefix stable: the white noise is drawn time-major ``(*batch, n, 3)``, the
    filter is causal and the grid depends only on ``t[0]``, the bandwidth and
    ``sample_rate_hz``, so with ``batch = ()`` the output at ``t[:k]`` does not
    depend on the samples after ``t[k - 1]`` (bit for bit).

    Parameters
    ----------
    t : (T,) s.  rms : (3,) per-component stationary std.
    sample_rate_hz : nominal rate of ``t``; None = 1 / min Δt of ``t`` (1 Hz for a
        single sample). Give it when ``t`` grows block by block.

    Returns
    -------
    (*batch, T, 3) noise and (*batch, T, 3) its rate (rad, rad/s for angle rms).
    """
    T = t.size
    if T == 0:
        z = np.zeros(batch + (0, 3))
        return z, z
    if sample_rate_hz is None:
        sample_rate_hz = 1.0 / np.min(np.diff(t)) if T > 1 else 1.0
    fs = max(10.0 * bandwidth_hz, 2.0 * float(sample_rate_hz))
    sos = signal.butter(2, bandwidth_hz, fs=fs, output="sos") if bandwidth_hz < 0.45 * fs else None
    burn = 20.0 / bandwidth_hz
    t0 = t[0] - burn
    # + 3: the two grid points around every sample are inner points (central differences)
    n = int(np.ceil((t[-1] - t0) * fs)) + 3
    w = rng.standard_normal(batch + (n, 3))  # time-major: its first rows do not depend on n
    if sos is not None:
        h = signal.sosfilt(sos, np.r_[1.0, np.zeros(int(50 * fs / bandwidth_hz))])
        gain = 1.0 / np.sqrt(np.sum(h * h))
        y = signal.sosfilt(sos, w, axis=-2)
    else:
        y = w
    pos = (t - t0) * fs
    i = np.clip(np.floor(pos).astype(int), 0, n - 2)
    f = (pos - i)[:, None]

    def x(j: NDArray) -> NDArray:  # the scaled noise on grid points j only (the grid is ~50x the samples)
        return (y[..., j, :] * gain if sos is not None else y[..., j, :]) * rms

    def xdot(j: NDArray) -> NDArray:  # np.gradient's central difference (every j is an inner point)
        return (x(j + 1) - x(j - 1)) / (2. * (1.0 / fs))

    samp = x(i) * (1 - f) + x(i + 1) * f
    sampd = xdot(i) * (1 - f) + xdot(i + 1) * f
    return samp, sampd


def dithering_angles(t: ArrayLike, settings: DitheringSettings, rng: np.random.Generator,
                     n_trials: int | None = None, *, sample_rate_hz: float | None = None) -> tuple[NDArray, NDArray]:
    """Dithering rotation vectors and their rates at times ``t``.

    Parameters
    ----------
    t : (T,) s.
    settings : tones and band-limited noise.
    rng : source of tone phases (when not given; one per tone, fixed count) and then
        of the noise (one time-major draw), so without ``n_trials`` the result at
        ``t[:k]`` is the same for every longer ``t`` with the same ``t[0]`` and
        ``sample_rate_hz`` (prefix stable).
    n_trials : leading trial axis (independent draws per trial) when given.
    sample_rate_hz : nominal rate of ``t`` for the noise grid (see :func:`_lowpass_noise`);
        None = from ``t``. Give it for block-by-block use.

    Returns
    -------
    delta_cam : (B..., T, 3) rad, rotation vector in camera axes (x: pitch, y: yaw, z: roll).
    rate_cam : (B..., T, 3) rad/s, its time derivative.
    """
    t = np.asarray(t, float)
    batch = () if n_trials is None else (int(n_trials),)
    delta = np.zeros(batch + (t.size, 3))
    rate = np.zeros_like(delta)
    if not settings.enabled:
        return delta, rate
    for tone in settings.tones:
        k = AXIS_TO_CAM[tone.axis]
        if tone.phase_deg is None:
            phase = rng.uniform(0.0, 2 * np.pi, size=batch + (1,))
        else:
            phase = np.full(batch + (1,), np.radians(tone.phase_deg))
        a = np.radians(tone.amplitude_deg)
        w = 2 * np.pi * tone.freq_hz
        delta[..., k] += a * np.sin(w * t + phase)
        rate[..., k] += a * w * np.cos(w * t + phase)
    rms_cam = np.zeros(3)
    rms_cam[RPY_TO_CAM] = np.radians(settings.noise_rms_deg)
    if np.any(rms_cam > 0):
        nz, nzd = _lowpass_noise(t, rms_cam, settings.noise_bandwidth_hz, rng, batch, sample_rate_hz)
        delta += nz
        rate += nzd
    return delta, rate


def dither_rms_cam(settings: DitheringSettings) -> NDArray:
    """Stationary rms (3,) rad of the dithering rotation per camera axis: what a monitor may know of it.

    Tones contribute amplitude/√2 each (random phase), the band-limited noise its rms.
    """
    ms = np.zeros(3)
    if not settings.enabled:
        return ms
    for tone in settings.tones:
        ms[AXIS_TO_CAM[tone.axis]] += np.radians(tone.amplitude_deg) ** 2 / 2
    ms[RPY_TO_CAM] += np.radians(np.asarray(settings.noise_rms_deg, float)) ** 2
    return np.sqrt(ms)


def camera_pose(pos_ecef: ArrayLike, q_body_to_enu: ArrayLike, mount: Mount,
                delta_cam: ArrayLike | None = None) -> tuple[NDArray, NDArray]:
    """Camera position and attitude from the aircraft pose.

    Parameters
    ----------
    pos_ecef : (T, 3) m, aircraft reference point (CG).
    q_body_to_enu : (B..., T, 4) body FRD -> local ENU at the aircraft.
    mount : lever arm (body, m) and R_cam_to_body.
    delta_cam : (B..., T, 3) rad, dithering rotation vector in camera axes, or None.

    Returns
    -------
    cam_pos_ecef : (B..., T, 3) m (the lever arm rotated by the given attitude).
    R_cam_to_ecef : (B..., T, 3, 3).
    """
    pos = np.asarray(pos_ecef, float)
    lat, lon, _ = ecef_to_geodetic(pos)
    R_enu_to_ecef = np.swapaxes(R_ecef_to_enu(lat, lon), -1, -2)  # (T,3,3)
    R_b2e = R_enu_to_ecef @ q_to_R(q_body_to_enu)  # (B...,T,3,3)
    cam_pos = pos + np.einsum("...ij,j->...i", R_b2e, mount.lever_arm_body)
    R_c2e = R_b2e @ mount.R_sensor_to_body
    if delta_cam is not None:
        d = np.asarray(delta_cam, float)
        R_d = Rotation.from_rotvec(d.reshape(-1, 3)).as_matrix().reshape(d.shape[:-1] + (3, 3))
        R_c2e = R_c2e @ R_d
    return cam_pos, R_c2e
