"""Driving the EKF core over a flight: predict through the IMU intervals, update at each aiding epoch.

:func:`state_from_init` starts the filter from the alignment pseudo-sensor
(:func:`testbed.sensors.imu.alignment.align`); :func:`run_ekf` returns an
:class:`EkfTrace` at the aiding epochs and the state after them. Batched over trials; GNSS and vision records may or may not
carry the trial axis.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from testbed.frames import LocalFrame
from testbed.navigation.ekf import (N, CameraNoise, ClockNoise, ImuNoise, NavState, gain_update, inject, pixel_rows,
                                    pseudorange_rows, range_rate_rows, rotation_rows)
from testbed.navigation.ekf import predict_compiled as predict
from testbed.navigation.separation import Bank, spawn, stack_subs
from testbed.navigation.separation import settle as settle_subs
from testbed.navigation.separation import update as update_subs
from testbed.navigation.snapshot import gnss_snapshot
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
    sub_dp: NDArray | None = None  # solution-separation sub-filters' position offsets (R, T, 3)
    sub_Pp: NDArray | None = None  # and position covariance blocks (R, T, 3, 3)
    snap_p: NDArray | None = None  # the IMU-free (pseudorange) position (B, T, 3), NaN below four rows
    snap_P: NDArray | None = None  # and its covariance (B, T, 3, 3) (:mod:`.snapshot`)

    @property
    def P_pos(self) -> NDArray:
        """The position covariance (B, T, 3, 3)."""
        return self.P[..., :3, :3]


def run_ekf(s: NavState, imu: ImuSamples, frame: LocalFrame, imu_noise: ImuNoise, gnss: GnssEpochs | None = None,
            vision: VisionEpochs | None = None, clock: ClockNoise = ClockNoise(), t_aid: NDArray | None = None,
            camera: CameraNoise = CameraNoise(), survey_sigma_m: float = 0.05,
            range_rate_sigma_m_s: float | None = None) -> EkfTrace:
    """Predict through the IMU intervals and update at each aiding epoch (GNSS epochs, or ``t_aid``)."""
    return filter_epochs(s, imu, frame, imu_noise, gnss, vision, clock, t_aid, camera, survey_sigma_m,
                         range_rate_sigma_m_s=range_rate_sigma_m_s)[0]


def filter_epochs(s: NavState, imu: ImuSamples, frame: LocalFrame, imu_noise: ImuNoise, gnss: GnssEpochs | None,
                  vision: VisionEpochs | None, clock: ClockNoise, t_aid: NDArray | None = None,
                  camera: CameraNoise = CameraNoise(), survey_sigma_m: float = 0.05,
                  through_end: bool = False, range_rate_sigma_m_s: float | None = None,
                  bank: Bank | None = None, snapshot: bool = False) -> tuple[EkfTrace, NavState, Bank | None]:
    """:func:`run_ekf`, and the state after the last aiding epoch (``through_end``: after every IMU
    interval given, as a block of a live run needs to hand on). ``range_rate_sigma_m_s``: also a
    range-rate row per satellite with that 1σ (None: pseudoranges only).

    ``bank``: also run the solution-separation sub-filters (:mod:`.separation`), spawning one per
    measurement mode at its first use; the trace then holds their position offsets and blocks, and the
    grown bank is returned (None in, None out). ``snapshot``: also the epoch's position without the IMU, from its
    pseudoranges alone (:mod:`.snapshot`), in the trace.
    """
    B = s.p.shape[0]
    t_aid = np.asarray(gnss.t if gnss is not None else t_aid, float)
    T = t_aid.size
    out = {k: [] for k in ("p", "v", "C", "ba", "bg", "cb", "cd", "P", "nis", "dof")}
    sub_dp, sub_Pp, snaps = [], [], []
    k_imu = 0
    for k in range(T):
        k_end = int(np.searchsorted(imu.t, t_aid[k] + 1e-9, side="right"))
        if k_end > k_imu:  # every IMU interval up to this epoch, in one compiled pass
            s, bank = _predict(s, bank, imu, k_imu, k_end, frame, imu_noise, clock)
            k_imu = k_end
        if bank is not None:  # (a block that ended between epochs left the sub-filters' last step pending)
            bank = settle_subs(bank, s.P)
        nis = np.zeros(B)
        dof = np.zeros(B, np.int64)
        stages = []
        snap = (np.full((B, 3), np.nan), np.full((B, 3, 3), np.nan))
        if gnss is not None:
            # the body rate the antenna's lever arm turns with: the last IMU interval's, bias-corrected
            omega = imu_block(imu.dtheta, B, k_end - 1, k_end)[:, 0] / imu.dt - s.bg if k_end > 0 else np.zeros((B, 3))
            stages.append(lambda s: gnss_rows(s, gnss, k, frame, omega, range_rate_sigma_m_s))
        if vision is not None:
            stages.append(lambda s: camera_frame(s.C, vision.camera.R_sensor_to_body, camera,
                                                 vision_rows(s, vision, k, frame, survey_sigma_m)))
        for rows_of in stages:  # sequential updates, each linearised at the state the last one left
            rows = rows_of(s)
            if rows is None:
                continue
            nu, H, R, mask, row_sat, row_landmark = rows
            if snapshot and row_landmark is None:
                snap = gnss_snapshot(s.p, s.P, nu, H, R, mask)
            if bank is not None:  # a mode first used now: its sub-filter is the mains as they stand (exact)
                row_mode = row_sat if row_landmark is None else bank.vision_modes(row_landmark)
                bank = spawn(bank, s.P, row_mode[mask.any(0)])
            dx, P, a, b = gain_update(s.P, nu, H, R, mask)
            s = inject(replace(s, P=P), dx)
            if bank is not None:
                bank = update_subs(bank, nu, H, R, mask, row_mode, dx)
            nis, dof = nis + a, dof + b
        for name in ("p", "v", "C", "ba", "bg", "cb", "cd", "P"):
            out[name].append(getattr(s, name))
        out["nis"].append(nis)
        out["dof"].append(dof)
        snaps.append(snap)
        if bank is not None:
            sub_dp.append(bank.dx[:, :3].copy())  # copies: a view would keep the whole bank alive per epoch
            sub_Pp.append(bank.P[:, :3, :3].copy())
    if through_end and k_imu < imu.t.size:
        s, bank = _predict(s, bank, imu, k_imu, None, frame, imu_noise, clock, settle=False)
    st = {k: (np.stack(v, 1) if v else np.zeros((B, 0) + _SHAPES[k])) for k, v in out.items()}
    subs = {}
    if bank is not None:
        subs = dict(zip(("sub_dp", "sub_Pp"), stack_subs(sub_dp, sub_Pp, st["P"][..., :3, :3], B) if T else
                        (np.zeros((0, 0, 3)), np.zeros((0, 0, 3, 3)))))
    if snapshot:
        subs.update(snap_p=np.stack([a for a, _ in snaps], 1) if T else np.zeros((B, 0, 3)),
                    snap_P=np.stack([b for _, b in snaps], 1) if T else np.zeros((B, 0, 3, 3)))
    return EkfTrace(t=t_aid, **st, **subs), s, bank


def _predict(s: NavState, bank: Bank | None, imu: ImuSamples, k0: int, k1: int | None, frame: LocalFrame,
             imu_noise: ImuNoise, clock: ClockNoise, settle: bool = True) -> tuple[NavState, Bank | None]:
    """The mains through IMU intervals k0:k1, and the sub-filters through the same transition and noise
    (``settle``; else the transition so far is kept pending in the bank for the next call to finish)."""
    B = s.p.shape[0]
    dth, dvl = imu_block(imu.dtheta, B, k0, k1), imu_block(imu.dvel, B, k0, k1)
    if bank is None or not bank.trial.size:
        return predict(s, dth, dvl, imu.dt, frame, imu_noise, clock, imu.earth_rotation), bank
    Phi, P_before = bank.pending if bank.pending is not None else (np.broadcast_to(np.eye(N), (B, N, N)).copy(), s.P)
    s1 = predict(s, dth, dvl, imu.dt, frame, imu_noise, clock, imu.earth_rotation, transition=Phi)
    bank = replace(bank, pending=(Phi, P_before))
    return s1, (settle_subs(bank, s1.P) if settle else bank)


def imu_block(a: NDArray, B: int, k0: int, k1: int | None) -> NDArray:
    """IMU increments k0:k1 of (K, 3) or (B, K, 3) records, for every trial (B, K', 3)."""
    a = np.asarray(a)[..., k0:k1, :]
    return np.broadcast_to(a, (B,) + a.shape[-2:])


_SHAPES = {"p": (3,), "v": (3,), "C": (3, 3), "ba": (3,), "bg": (3,), "cb": (), "cd": (), "P": (N, N), "nis": (),
           "dof": ()}


def _at(a: NDArray, k: int, tail: int, B: int) -> NDArray:
    """Epoch k of a record array (B, T, *tail) or (T, *tail), broadcast to (B, *tail)."""
    a = np.asarray(a)
    x = np.take(a, k, axis=a.ndim - 1 - tail)
    return np.broadcast_to(x, (B,) + x.shape[x.ndim - tail:])


def gnss_rows(s: NavState, g: GnssEpochs, k: int, frame: LocalFrame, omega_b: NDArray,
               range_rate_sigma_m_s: float | None):
    """The pseudorange (and range-rate) rows of the satellites any trial sees at epoch k — ν, H, R, mask, each
    row's satellite slot and None (no landmark) — or None when none is visible. (Only those slots: the
    update's cost grows with the cube of the rows.)"""
    B = s.p.shape[0]
    vis = _at(g.visible, k, 1, B)
    slot = np.flatnonzero(vis.any(0))
    if not slot.size:
        return None
    vis = vis[:, slot]
    lever = np.asarray(g.antenna.lever_arm_body, float)
    z = _at(g.pseudorange, k, 1, B)[:, slot]
    sat_w = frame.ecef_to_enu(_at(g.sat_pos_ecef, k, 2, B)[:, slot])
    sig = _at(g.sigma, k, 1, B)[:, slot]
    h, H = pseudorange_rows(s, sat_w, lever)
    nu, var, mask = z - h, np.where(vis, sig, 1.0) ** 2, vis & np.isfinite(z)
    if range_rate_sigma_m_s is not None:
        zr = _at(g.range_rate, k, 1, B)[:, slot]
        sat_v = frame.vec_ecef_to_enu(_at(g.sat_vel_ecef, k, 2, B)[:, slot])
        hr, Hr = range_rate_rows(s, sat_w, sat_v, lever, omega_b)
        nu, H = np.concatenate([nu, zr - hr], -1), np.concatenate([H, Hr], -2)
        var = np.concatenate([var, np.full(var.shape, range_rate_sigma_m_s**2)], -1)
        mask = np.concatenate([mask, vis & np.isfinite(zr)], -1)
        slot = np.concatenate([slot, slot])
    return np.where(mask, nu, 0.0), np.nan_to_num(H), var[..., None] * np.eye(var.shape[-1]), mask, slot, None


def camera_frame(C: NDArray, R_cam_to_body: NDArray, camera: CameraNoise, rows):
    """One frame's pixel rows (ν, H, R, mask, G, tag) as an update's rows (ν, H, R, mask, None, tag): the
    camera's noise common to all of them (:class:`CameraNoise`) added to R. None stays None."""
    if rows is None:
        return None
    nu, H, R, mask, G, tag = rows
    return nu, H, R + camera.covariance(G, C, R_cam_to_body), mask, None, tag


def vision_rows(s: NavState, vis: VisionEpochs, k: int, frame: LocalFrame, survey_sigma_m: float):
    """Two pixel rows per landmark any trial detects at epoch k: ν, H, R of the detections and the survey,
    mask, the rows' camera-rotation Jacobian G (B, 2L, 3) (for :meth:`CameraNoise.covariance`) and each
    row's landmark index — or None."""
    B = s.p.shape[0]
    det = _at(vis.detected, k, 1, B)
    seen = np.flatnonzero(det.any(0))
    if not seen.size:
        return None
    det = det[:, seen]
    uv = _at(vis.pixel_uv, k, 2, B)[:, seen]
    lm = frame.ecef_to_enu(np.asarray(vis.landmark_pos_ecef, float)[..., seen, :])
    lever = np.asarray(vis.camera.lever_arm_body, float)
    h, H, Hm, _ = pixel_rows(s, lm, np.asarray(vis.K, float), vis.camera.R_sensor_to_body, lever)
    G = rotation_rows(Hm, lm, s.p + np.einsum("bij,j->bi", s.C, lever))
    L = seen.size
    sp = _at(vis.sigma_px, k, 1, B)[:, seen]
    var = np.repeat(np.where(det, sp, 1.0) ** 2, 2, axis=-1)
    # each landmark's survey error moves its own pixel pair: a 2×2 block per landmark
    blocks = survey_sigma_m**2 * Hm @ np.swapaxes(Hm, -1, -2)  # (B, L, 2, 2)
    R = np.zeros((B, L, 2, L, 2))
    R[:, np.arange(L), :, np.arange(L), :] = np.moveaxis(blocks, 1, 0)
    R = R.reshape(B, 2 * L, 2 * L) + var[..., None] * np.eye(2 * L)
    m = np.repeat(det, 2, axis=-1) & np.isfinite(uv.reshape(B, 2 * L)) & np.isfinite(h)
    return (np.nan_to_num(uv.reshape(B, 2 * L) - h), np.nan_to_num(H), R, m, np.nan_to_num(G),
            np.repeat(seen, 2))
