"""Driving the EKF core over a flight: predict through the IMU intervals, update at each aiding epoch.

:func:`state_from_init` starts the filter from the alignment pseudo-sensor
(:func:`testbed.sensors.imu.alignment.align`); :func:`run_ekf` returns an
:class:`EkfTrace` at the aiding epochs and the state after them. Batched over trials; GNSS and vision records may or may not
carry the trial axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from testbed.frames import LocalFrame
from testbed.navigation.ekf import (N, ClockNoise, ImuNoise, NavState, pixel_rows, pseudorange_rows,
                                    range_rate_rows, update)
from testbed.navigation.ekf import predict_compiled as predict
from testbed.records import GnssEpochs, ImuSamples, NavInit, VisionEpochs


def state_from_init(init: NavInit, n_trials: int | None = None) -> NavState:
    """The filter's state at the alignment: its estimate, biases at zero, P₀ = diag(σ²)."""
    C = np.asarray(init.C, float)
    B = C.shape[0] if C.ndim == 3 else (1 if n_trials is None else int(n_trials))
    bc = lambda a, tail: np.broadcast_to(np.asarray(a, float), (B,) + tail).copy()  # noqa: E731
    return NavState(C=bc(C, (3, 3)), v=bc(init.v, (3,)), p=bc(init.p, (3,)), ba=np.zeros((B, 3)),
                    bg=np.zeros((B, 3)), cb=bc(init.clock_bias, ()), cd=bc(init.clock_drift, ()),
                    P=np.broadcast_to(np.diag(np.asarray(init.sigma, float) ** 2), (B, N, N)).copy())


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
            dither_sigma_px: float = 0.0, survey_sigma_m: float = 0.05,
            range_rate_sigma_m_s: float | None = None) -> EkfTrace:
    """Predict through the IMU intervals and update at each aiding epoch (GNSS epochs, or ``t_aid``)."""
    return filter_epochs(s, imu, frame, imu_noise, gnss, vision, clock, t_aid, dither_sigma_px, survey_sigma_m,
                         range_rate_sigma_m_s=range_rate_sigma_m_s)[0]


def filter_epochs(s: NavState, imu: ImuSamples, frame: LocalFrame, imu_noise: ImuNoise, gnss: GnssEpochs | None,
                  vision: VisionEpochs | None, clock: ClockNoise, t_aid: NDArray | None = None,
                  dither_sigma_px: float = 0.0, survey_sigma_m: float = 0.05,
                  through_end: bool = False, range_rate_sigma_m_s: float | None = None) -> tuple[EkfTrace, NavState]:
    """:func:`run_ekf`, and the state after the last aiding epoch (``through_end``: after every IMU
    interval given, as a block of a live run needs to hand on). ``range_rate_sigma_m_s``: also a
    range-rate row per satellite with that 1σ (None: pseudoranges only)."""
    B = s.p.shape[0]
    t_aid = np.asarray(gnss.t if gnss is not None else t_aid, float)
    T = t_aid.size
    out = {k: [] for k in ("p", "v", "C", "ba", "bg", "cb", "cd", "P", "nis", "dof")}
    k_imu = 0
    dth = np.broadcast_to(imu.dtheta, (B,) + imu.dtheta.shape[-2:])
    dvl = np.broadcast_to(imu.dvel, (B,) + imu.dvel.shape[-2:])
    for k in range(T):
        k_end = int(np.searchsorted(imu.t, t_aid[k] + 1e-9, side="right"))
        if k_end > k_imu:  # every IMU interval up to this epoch, in one compiled pass
            s = predict(s, dth[:, k_imu:k_end], dvl[:, k_imu:k_end], imu.dt, frame, imu_noise, clock,
                        imu.earth_rotation)
            k_imu = k_end
        nis = np.zeros(B)
        dof = np.zeros(B, np.int64)
        if gnss is not None:
            # the body rate the antenna's lever arm turns with: the last IMU interval's, bias-corrected
            omega = dth[:, k_end - 1] / imu.dt - s.bg if k_end > 0 else np.zeros((B, 3))
            s, a, b = _gnss_update(s, gnss, k, frame, omega, range_rate_sigma_m_s)
            nis, dof = nis + a, dof + b
        if vision is not None:
            s, a, b = _vision_update(s, vision, k, frame, dither_sigma_px, survey_sigma_m)
            nis, dof = nis + a, dof + b
        for name in ("p", "v", "C", "ba", "bg", "cb", "cd", "P"):
            out[name].append(getattr(s, name))
        out["nis"].append(nis)
        out["dof"].append(dof)
    if through_end and k_imu < imu.t.size:
        s = predict(s, dth[:, k_imu:], dvl[:, k_imu:], imu.dt, frame, imu_noise, clock, imu.earth_rotation)
    st = {k: (np.stack(v, 1) if v else np.zeros((B, 0) + _SHAPES[k])) for k, v in out.items()}
    return EkfTrace(t=t_aid, **st), s


_SHAPES = {"p": (3,), "v": (3,), "C": (3, 3), "ba": (3,), "bg": (3,), "cb": (), "cd": (), "P": (N, N), "nis": (),
           "dof": ()}


def _at(a: NDArray, k: int, tail: int, B: int) -> NDArray:
    """Epoch k of a record array (B, T, *tail) or (T, *tail), broadcast to (B, *tail)."""
    a = np.asarray(a)
    x = np.take(a, k, axis=a.ndim - 1 - tail)
    return np.broadcast_to(x, (B,) + x.shape[x.ndim - tail:])


def _gnss_update(s: NavState, g: GnssEpochs, k: int, frame: LocalFrame, omega_b: NDArray,
                 range_rate_sigma_m_s: float | None):
    """One update with every visible satellite's pseudorange (and range rate) row."""
    B = s.p.shape[0]
    vis = _at(g.visible, k, 1, B)
    if not vis.any():
        return s, np.zeros(B), np.zeros(B, np.int64)
    lever = np.asarray(g.antenna.lever_arm_body, float)
    z = _at(g.pseudorange, k, 1, B)
    sat_w = frame.ecef_to_enu(_at(g.sat_pos_ecef, k, 2, B))
    sig = _at(g.sigma, k, 1, B)
    h, H = pseudorange_rows(s, sat_w, lever)
    nu, var, mask = z - h, np.where(vis, sig, 1.0) ** 2, vis & np.isfinite(z)
    if range_rate_sigma_m_s is not None:
        zr = _at(g.range_rate, k, 1, B)
        hr, Hr = range_rate_rows(s, sat_w, frame.vec_ecef_to_enu(_at(g.sat_vel_ecef, k, 2, B)), lever, omega_b)
        nu, H = np.concatenate([nu, zr - hr], -1), np.concatenate([H, Hr], -2)
        var = np.concatenate([var, np.full(var.shape, range_rate_sigma_m_s**2)], -1)
        mask = np.concatenate([mask, vis & np.isfinite(zr)], -1)
    return update(s, np.where(mask, nu, 0.0), np.nan_to_num(H), var[..., None] * np.eye(var.shape[-1]), mask)


def _vision_update(s: NavState, vis: VisionEpochs, k: int, frame: LocalFrame, dither_sigma_px: float,
                   survey_sigma_m: float):
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
    # each landmark's survey error moves its own pixel pair: a 2×2 block per landmark
    blocks = survey_sigma_m**2 * Hm @ np.swapaxes(Hm, -1, -2)  # (B, L, 2, 2)
    R = np.zeros((B, L, 2, L, 2))
    R[:, np.arange(L), :, np.arange(L), :] = np.moveaxis(blocks, 1, 0)
    R = R.reshape(B, 2 * L, 2 * L) + var[..., None] * np.eye(2 * L)
    m = np.repeat(det, 2, axis=-1) & np.isfinite(uv.reshape(B, 2 * L)) & np.isfinite(h)
    return update(s, np.nan_to_num(uv.reshape(B, 2 * L) - h), np.nan_to_num(H), R, m)
