"""Driving the EKF core over a flight: predict through the IMU intervals, update at each aiding epoch.

:func:`initial_state` is the alignment pseudo-sensor of NAV_FILTER.md §3 (the start
pose ⊕ a draw from the published P₀); :func:`run_ekf` returns an :class:`EkfTrace`
at the GNSS epochs. Batched over trials; GNSS and vision records may or may not
carry the trial axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from testbed.frames import LocalFrame
from testbed.inertial import so3_exp
from testbed.navigation.ekf import BA, BG, CB, CD, N, P_, PSI, V_, ClockNoise, ImuNoise, NavState, pixel_rows, \
    predict, pseudorange_rows, update
from testbed.records import GnssEpochs, ImuSamples, VisionEpochs


@dataclass(frozen=True)
class InitSigmas:
    """The alignment's published 1σ (NAV_FILTER.md §3)."""

    pos_m: float = 3.0
    vel_m_s: float = 0.1
    roll_pitch_rad: float = np.radians(0.05)
    heading_rad: float = np.radians(0.2)
    clock_bias_m: float = 100.0
    clock_drift_m_s: float = 1.0


def initial_state(C: NDArray, v: NDArray, p: NDArray, clock: tuple[NDArray, NDArray], imu_bias_sigma: tuple[float, float],
                  rng: np.random.Generator, n_trials: int, sig: InitSigmas = InitSigmas()) -> tuple[NavState, NDArray]:
    """The true start (C (3, 3) body→world, v, p (3,), clock bias and drift (B,) or scalars) ⊕ ξ, ξ ~ N(0, P₀).

    Returns the state and the drawn ξ (B, 17) (the filter's initial error, for NEES).
    imu_bias_sigma : (accel, gyro) turn-on 1σ (the biases start at 0 with that uncertainty).
    """
    sd = np.zeros(N)
    sd[P_], sd[V_] = sig.pos_m, sig.vel_m_s
    # attitude: roll/pitch about the body's horizontal axes, heading about up (world)
    sd[PSI] = [sig.roll_pitch_rad, sig.roll_pitch_rad, sig.heading_rad]
    sd[BA], sd[BG] = imu_bias_sigma
    sd[CB], sd[CD] = sig.clock_bias_m, sig.clock_drift_m_s
    xi = rng.standard_normal((n_trials, N)) * sd
    xi[:, BA] = 0.0  # the true biases are the IMU's own draw: the filter starts at zero
    xi[:, BG] = 0.0
    cb, cd = (np.broadcast_to(np.asarray(c, float), (n_trials,)) for c in clock)
    s = NavState(C=so3_exp(-xi[:, PSI]) @ C, v=v - xi[:, V_], p=p - xi[:, P_], ba=np.zeros((n_trials, 3)),
                 bg=np.zeros((n_trials, 3)), cb=cb - xi[:, CB], cd=cd - xi[:, CD],
                 P=np.broadcast_to(np.diag(sd**2), (n_trials, N, N)).copy())
    return s, xi


@dataclass(frozen=True)
class EkfTrace:
    """The filter at the aiding epochs (B, T, ...)."""

    t: NDArray
    p: NDArray
    v: NDArray
    C: NDArray
    ba: NDArray
    bg: NDArray
    cb: NDArray
    cd: NDArray
    P: NDArray  # (B, T, 17, 17)
    nis: NDArray  # (B, T)
    dof: NDArray  # (B, T)


def run_ekf(s: NavState, imu: ImuSamples, frame: LocalFrame, imu_noise: ImuNoise, gnss: GnssEpochs | None = None,
            vision: VisionEpochs | None = None, clock: ClockNoise = ClockNoise(), t_aid: NDArray | None = None,
            dither_sigma_px: float = 0.0) -> EkfTrace:
    """Predict through every IMU interval and update at each aiding epoch (GNSS epochs, or ``t_aid``)."""
    B = s.p.shape[0]
    t_aid = np.asarray(gnss.t if gnss is not None else t_aid, float)
    T = t_aid.size
    out = {k: [] for k in ("p", "v", "C", "ba", "bg", "cb", "cd", "P", "nis", "dof")}
    k_imu = 0
    dth = np.broadcast_to(imu.dtheta, (B,) + imu.dtheta.shape[-2:])
    dvl = np.broadcast_to(imu.dvel, (B,) + imu.dvel.shape[-2:])
    for k in range(T):
        while k_imu < imu.t.size and imu.t[k_imu] <= t_aid[k] + 1e-9:
            s = predict(s, dth[:, k_imu], dvl[:, k_imu], imu.dt, frame, imu_noise, clock, imu.earth_rotation)
            k_imu += 1
        nis = np.zeros(B)
        dof = np.zeros(B, np.int64)
        if gnss is not None:
            s, a, b = _gnss_update(s, gnss, k, frame)
            nis, dof = nis + a, dof + b
        if vision is not None:
            s, a, b = _vision_update(s, vision, k, frame, dither_sigma_px)
            nis, dof = nis + a, dof + b
        for name in ("p", "v", "C", "ba", "bg", "cb", "cd", "P"):
            out[name].append(getattr(s, name))
        out["nis"].append(nis)
        out["dof"].append(dof)
    st = {k: np.stack(v, 1) for k, v in out.items()}
    return EkfTrace(t=t_aid, **st)


def _at(a: NDArray, k: int, tail: int, B: int) -> NDArray:
    """Epoch k of a record array (B, T, *tail) or (T, *tail), broadcast to (B, *tail)."""
    a = np.asarray(a)
    x = np.take(a, k, axis=a.ndim - 1 - tail)
    return np.broadcast_to(x, (B,) + x.shape[x.ndim - tail:])


def _gnss_update(s: NavState, g: GnssEpochs, k: int, frame: LocalFrame):
    B = s.p.shape[0]
    vis = _at(g.visible, k, 1, B)
    if not vis.any():
        return s, np.zeros(B), np.zeros(B, np.int64)
    z = _at(g.pseudorange, k, 1, B)
    sat_w = frame.ecef_to_enu(_at(g.sat_pos_ecef, k, 2, B))
    sig = _at(g.sigma, k, 1, B)
    h, H = pseudorange_rows(s, sat_w, np.asarray(g.antenna.lever_arm_body, float))
    R = np.where(vis, sig, 1.0) ** 2
    return update(s, z - h, H, R[..., None] * np.eye(R.shape[-1]), vis & np.isfinite(z))


def _vision_update(s: NavState, vis: VisionEpochs, k: int, frame: LocalFrame, dither_sigma_px: float):
    B = s.p.shape[0]
    det = _at(vis.detected, k, 1, B)
    if not det.any():
        return s, np.zeros(B), np.zeros(B, np.int64)
    uv = _at(vis.pixel_uv, k, 2, B)
    lm = frame.ecef_to_enu(np.asarray(vis.landmark_pos_ecef, float))
    h, H, Hm, _ = pixel_rows(s, lm, np.asarray(vis.K, float), vis.camera.R_sensor_to_body,
                             np.asarray(vis.camera.lever_arm_body, float))
    L = det.shape[-1]
    sp = _at(vis.sigma_px, k, 1, B)
    var = np.repeat(np.where(det, sp, 1.0) ** 2 + dither_sigma_px**2, 2, axis=-1)
    R = var[..., None] * np.eye(2 * L)
    # the landmark survey error (5 cm at kilometres: a small addition, kept for consistency)
    lpe = 0.05
    Hm_ = Hm.reshape(B, L, 2, 3)
    for j in range(L):
        R[:, 2 * j:2 * j + 2, 2 * j:2 * j + 2] += lpe**2 * Hm_[:, j] @ np.swapaxes(Hm_[:, j], -1, -2)
    m = np.repeat(det, 2, axis=-1) & np.isfinite(uv.reshape(B, 2 * L)) & np.isfinite(h)
    return update(s, np.nan_to_num(uv.reshape(B, 2 * L) - h), np.nan_to_num(H), R, m)
