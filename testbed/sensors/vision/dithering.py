"""Camera mount and attitude dithering: the camera's true pose on the airframe.

True camera attitude (camera axes x right, y down, z forward)::

    R_cam_to_ecef = R_enu_to_ecef(at the camera) · R_body_to_enu (truth)
                    · R_cam_to_body (mount) · R_dither

``R_dither = exp([δ]×)`` with δ a small rotation vector in camera axes:
δ_x = "pitch" (about image right), δ_y = "yaw" (about image down),
δ_z = "roll" (about the optical axis). δ(t) = Σ tones + band-limited noise.
"""

from __future__ import annotations

from dataclasses import dataclass

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
                   batch: tuple[int, ...], sample_rate_hz: float | None = None,
                   shift: NDArray | None = None) -> tuple[NDArray, NDArray, NDArray]:
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

    The sample at ``t`` is ``g_t · w`` times the scale, ``w`` the white grid: its standard value is
    ``ζ_t = g_t·w / |g_t|``, standard normal. ``shift`` (*batch, T, 3) moves ``ζ_t`` by its value through the
    white grid itself, ``w += δ g_t/|g_t|`` (an importance-sampling proposal: the process stays the
    filter's, its likelihood ratio is that of ``ζ_t`` alone, ``exp(δ ζ_t − δ²/2)``; the samples at other
    times move by their correlation with it).

    Parameters
    ----------
    t : (T,) s.  rms : (3,) per-component stationary std.
    sample_rate_hz : nominal rate of ``t``; None = 1 / min Δt of ``t`` (1 Hz for a
        single sample). Give it when ``t`` grows block by block.

    Returns
    -------
    (*batch, T, 3) noise, (*batch, T, 3) its rate (rad, rad/s for angle rms), and (*batch, T, 3) its
    standard values ζ (0 on a component of zero rms).
    """
    T = t.size
    if T == 0:
        z = np.zeros(batch + (0, 3))
        return z, z, z
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
    else:
        h, gain = np.ones(1), 1.0
    pos = (t - t0) * fs
    i = np.clip(np.floor(pos).astype(int), 0, n - 2)
    f = (pos - i)[:, None]
    g_norm = np.sqrt(np.sum(((1 - f) * np.r_[0.0, h] + f * np.r_[h, 0.0]) ** 2, axis=-1))  # (T,) |g_t|
    if shift is not None and np.any(shift):
        w = w.copy()
        for idx in zip(*np.nonzero(shift)):  # a proposal moves one epoch of a trial: few of them
            *b, k, ax = idx
            g = f[k, 0] * np.r_[h, 0.0] + (1 - f[k, 0]) * np.r_[0.0, h]  # coefficients on w[i+1], w[i], w[i-1], ...
            j = i[k] + 1 - np.arange(g.size)
            keep = (j >= 0) & (j < n)
            w[tuple(b) + (j[keep], ax)] += shift[idx] * g[keep] / g_norm[k]
    y = signal.sosfilt(sos, w, axis=-2) if sos is not None else w

    def x(j: NDArray) -> NDArray:  # the scaled noise on grid points j only (the grid is ~50x the samples)
        return (y[..., j, :] * gain if sos is not None else y[..., j, :]) * rms

    def xdot(j: NDArray) -> NDArray:  # np.gradient's central difference (every j is an inner point)
        return (x(j + 1) - x(j - 1)) / (2. * (1.0 / fs))

    samp = x(i) * (1 - f) + x(i + 1) * f
    sampd = xdot(i) * (1 - f) + xdot(i + 1) * f
    with np.errstate(divide="ignore", invalid="ignore"):
        zeta = np.where(rms > 0, samp / (np.where(rms > 0, rms, 1.0) * gain * g_norm[:, None]), 0.0)
    return samp, sampd, zeta


@dataclass(frozen=True)
class DitherParts:
    """The dithering of :func:`dithering_parts`: the tones' angles and rates, the band-limited noise's, and the
    noise's standard values at the samples (``ζ``, :func:`_lowpass_noise`), each (B..., T, 3) in camera axes."""

    tone_angle: NDArray
    tone_rate: NDArray
    noise_angle: NDArray
    noise_rate: NDArray
    noise_z: NDArray

    @property
    def angle(self) -> NDArray:
        return self.tone_angle + self.noise_angle

    @property
    def rate(self) -> NDArray:
        return self.tone_rate + self.noise_rate


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
    d = dithering_parts(t, settings, rng, n_trials, sample_rate_hz=sample_rate_hz)
    return d.angle, d.rate


def dithering_parts(t: ArrayLike, settings: DitheringSettings, rng: np.random.Generator,
                    n_trials: int | None = None, *, sample_rate_hz: float | None = None,
                    noise_shift: NDArray | None = None) -> DitherParts:
    """:func:`dithering_angles` in its parts (:class:`DitherParts`), the noise's standard values moved by
    ``noise_shift`` (B..., T, 3) through its white grid (:func:`_lowpass_noise`; None: as drawn)."""
    t = np.asarray(t, float)
    batch = () if n_trials is None else (int(n_trials),)
    tone = np.zeros(batch + (t.size, 3))
    tone_rate = np.zeros_like(tone)
    zero = np.zeros_like(tone)
    if not settings.enabled:
        return DitherParts(tone, tone_rate, zero, zero, zero)
    for tn in settings.tones:
        k = AXIS_TO_CAM[tn.axis]
        if tn.phase_deg is None:
            phase = rng.uniform(0.0, 2 * np.pi, size=batch + (1,))
        else:
            phase = np.full(batch + (1,), np.radians(tn.phase_deg))
        a = np.radians(tn.amplitude_deg)
        w = 2 * np.pi * tn.freq_hz
        tone[..., k] += a * np.sin(w * t + phase)
        tone_rate[..., k] += a * w * np.cos(w * t + phase)
    rms_cam = np.zeros(3)
    rms_cam[RPY_TO_CAM] = np.radians(settings.noise_rms_deg)
    if not np.any(rms_cam > 0):
        return DitherParts(tone, tone_rate, zero, zero, zero)
    nz, nzd, zeta = _lowpass_noise(t, rms_cam, settings.noise_bandwidth_hz, rng, batch, sample_rate_hz,
                                   shift=noise_shift)
    return DitherParts(tone, tone_rate, nz, nzd, zeta)


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
