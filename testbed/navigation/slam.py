"""Unsurveyed ground features in the GNSS/vision/INS filter: SLAM states with delayed initialisation by
stochastic cloning (docs/design/nav-filter.md §7), batched over trials.

The error state grows a *static block* after the 17 core states: J feature slots (δm, 3 each) and K pose
clones (δp, δψ of the IMU, 6 each), fixed in size; a free slot's rows and columns of P are zero, which makes
it inert in every predict and update (its gain rows are zero) at no bookkeeping cost.

* **Predict**: the static block does not move, so over an aiding interval with the core's transition Φ
  (accumulated by the compiled predict) ``P_cs ← Φ P_cs`` and ``P_ss`` stays — exact.
* **Clone** at a feature's first sighting (a free clone slot; the feature entering the image first): the
  clone's error is a copy of the core's δp, δψ, so its rows of P are theirs (exact).
* **Triangulate** when the bearing from the clone and the current bearing are ``parallax_deg`` apart: the
  point nearest both rays in the least-squares sense, ``m = (Σ Pᵢ)⁻¹ Σ Pᵢ cᵢ`` with ``Pᵢ = I − dᵢdᵢᵀ``
  (for two rays, the midpoint of their common perpendicular). The feature's error is the linear map of the
  two poses' errors and the two pixels' noise, ``δm = A_c δclone + A_x δx + A_z n``, so its block of P is
  ``A P Aᵀ + A_z R A_zᵀ`` and its cross-covariance ``A P`` (exact to first order). The two pixels are spent
  on the initialisation and never used again. No parallax after ``max_wait_frames``: discarded.
* **Update**: two pixel rows per feature in a slot, ``∂uv/∂δm = −∂uv/∂δp``.
* **Marginalise** a feature unseen for ``lost_frames`` frames: its rows and columns set to zero (exact).

Design choices (docs/design/nav-filter.md §10): the triangulation is the closed-form two-ray point, not midpoint then
Gauss–Newton over stored bearings (only the clone's pose is in the state, so only its bearing can be
used consistently); no first-estimate Jacobians (``fej``).

In the loop (the ``ekf`` monitor with ``[vision.features]``): the aiding epochs are the GNSS epochs; a block
that ends between epochs leaves the static block's transition pending (``SlamState.pending``) so that a live
flight forms the same products as one pass, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from testbed.frames import LocalFrame
from testbed.inertial import skew, so3_exp
from testbed.navigation.ekf import (N, CameraNoise, ClockNoise, ImuNoise, NavState, gain_update, inject, pixel_rows,
                                    rotation_rows)
from testbed.navigation.ekf import predict_compiled as predict
from testbed.navigation.run import gnss_rows, imu_block, vision_rows
from testbed.navigation.separation import Bank, augment, propagate, spawn, stack_subs
from testbed.navigation.separation import update as update_subs
from testbed.records import FeatureTracks, GnssEpochs, ImuSamples, VisionEpochs

#: the core states a clone copies: δp, δψ
_POSE = np.r_[0:3, 6:9]


@dataclass(frozen=True)
class FeatureSettings:
    """The SLAM front of the filter (defaults: docs/design/nav-filter.md §7)."""

    slots: int = 7
    clones: int = 2
    parallax_deg: float = 3.0
    max_wait_frames: int = 30
    lost_frames: int = 5

    def __post_init__(self) -> None:
        if self.slots < 1 or self.clones < 1 or not 0 < self.parallax_deg < 90 or self.max_wait_frames < 1 \
                or self.lost_frames < 0:
            raise ValueError(f"FeatureSettings: expected slots, clones, max_wait_frames ≥ 1, parallax_deg in "
                             f"(0, 90), lost_frames ≥ 0; got {self}")

    def size(self) -> int:
        """The error-state dimension with the static block."""
        return N + 3 * self.slots + 6 * self.clones


@dataclass(frozen=True)
class SlamState:
    """The core nominal state (its ``P`` unused), the full covariance and the slots (B trials)."""

    nav: NavState
    P: NDArray  # (B, n, n)
    f_id: NDArray  # (B, J) feature id in slot j, −1: free
    f_m: NDArray  # (B, J, 3) its estimated position (world)
    f_lost: NDArray  # (B, J) frames since last seen
    c_id: NDArray  # (B, K) feature a clone waits to triangulate, −1: free
    c_p: NDArray  # (B, K, 3) the cloned IMU position
    c_C: NDArray  # (B, K, 3, 3) and attitude
    c_uv: NDArray  # (B, K, 2) the first pixel
    c_age: NDArray  # (B, K) frames since the clone
    #: solution-separation sub-filters (separation.py) over the full state: one per satellite and one without
    #: every feature row (the camera mode); every linear map the main's static block takes, they take too
    bank: Bank | None = None
    #: the core's transition Φ accumulated since the last aiding epoch and the full P there, while the static
    #: block's cross-covariance (and the bank) wait for the epoch: a block that ends between epochs leaves
    #: them pending, so a live flight forms the same products as one pass
    pending: tuple[NDArray, NDArray] | None = None

    def core(self) -> NavState:
        return replace(self.nav, P=np.ascontiguousarray(self.P[:, :N, :N]))


def feature_cols(j: int) -> slice:
    return slice(N + 3 * j, N + 3 * j + 3)


def clone_cols(cfg: FeatureSettings, k: int) -> slice:
    o = N + 3 * cfg.slots + 6 * k
    return slice(o, o + 6)


def start(nav: NavState, cfg: FeatureSettings, n_sat_slots: int | None = None, per_landmark: bool = False
          ) -> SlamState:
    """The filter with empty slots (its core covariance ``nav.P``); with ``n_sat_slots`` (the GNSS records'
    satellite slots) also its solution-separation sub-filters: one per satellite and one without the feature
    rows, and for surveyed landmarks one per landmark (``per_landmark``) or none of their own (they share the
    feature rows' camera mode)."""
    B, n = nav.p.shape[0], cfg.size()
    P = np.zeros((B, n, n))
    P[:, :N, :N] = nav.P
    J, K = cfg.slots, cfg.clones
    return SlamState(nav=nav, P=P, f_id=np.full((B, J), -1), f_m=np.zeros((B, J, 3)), f_lost=np.zeros((B, J), int),
                     c_id=np.full((B, K), -1), c_p=np.zeros((B, K, 3)), c_C=np.broadcast_to(np.eye(3), (B, K, 3, 3)).copy(),
                     c_uv=np.zeros((B, K, 2)), c_age=np.zeros((B, K), int),
                     bank=None if n_sat_slots is None else Bank.empty(B, int(n_sat_slots), per_landmark, n=n))


def predict_static(s: SlamState, dtheta: NDArray, dvel: NDArray, dt: float, frame: LocalFrame, imu: ImuNoise,
                   clock: ClockNoise, earth_rotation: bool = True, settle: bool = True) -> SlamState:
    """Through K IMU steps (dtheta, dvel (B, K, 3)): the core by the compiled predict, the static block's
    cross-covariance by the accumulated transition (``settle``; else left pending, :func:`settle_static`)."""
    B = s.P.shape[0]
    Phi, P0 = s.pending if s.pending is not None else (np.broadcast_to(np.eye(N), (B, N, N)), s.P)
    Phi = np.array(Phi)
    nav = predict(s.core(), dtheta, dvel, dt, frame, imu, clock, earth_rotation, transition=Phi)
    P = s.P.copy()
    P[:, :N, :N] = nav.P
    s = replace(s, nav=nav, P=P, pending=(Phi, P0))
    return settle_static(s) if settle else s


def settle_static(s: SlamState) -> SlamState:
    """The pending transition applied: ``P_cs ← Φ P_cs`` (``P_ss`` stays), the sub-filters through the same Φ."""
    if s.pending is None:
        return s
    Phi, P0 = s.pending
    P = s.P.copy()
    P[:, :N, N:] = Phi @ P0[:, :N, N:]
    P[:, N:, :N] = np.swapaxes(P[:, :N, N:], -1, -2)
    bank = s.bank
    if bank is not None and bank.trial.size:
        F = np.broadcast_to(np.eye(P.shape[-1]), P.shape).copy()
        F[:, :N, :N] = Phi
        bank = propagate(bank, F, P0, P)
    return replace(s, P=P, bank=bank, pending=None)


def apply_update(s: SlamState, nu: NDArray, H: NDArray, R: NDArray, mask: NDArray, row_mode: NDArray | None = None
                 ) -> tuple[SlamState, NDArray, NDArray]:
    """One masked batched update with rows over the full state (H (B, M, n)); the NIS and its dof. The short
    form ``P − KHP`` (the 50-state Joseph form costs three times as much; the NEES tests hold with it).
    ``row_mode`` (M,): each row's fault mode, for the sub-filters (spawned at a mode's first use)."""
    bank = s.bank
    if bank is not None:
        bank = spawn(bank, s.P, row_mode[mask.any(0)])
    dx, P, nis, dof = gain_update(s.P, nu, H, R, mask, joseph=False)
    if bank is not None:
        bank = update_subs(bank, nu, H, R, mask, row_mode, dx)
    return inject_static(replace(s, nav=inject(s.nav, dx[:, :N]), P=P, bank=bank), dx), nis, dof


def inject_static(s: SlamState, dx: NDArray) -> SlamState:
    """The static block's share of a correction dx (B, n) (free slots get exactly 0: their P rows are 0)."""
    J = s.f_id.shape[1]
    f_m = s.f_m + dx[:, N:N + 3 * J].reshape(s.f_m.shape)
    dc = dx[:, N + 3 * J:].reshape(s.c_p.shape[:2] + (6,))
    return replace(s, f_m=f_m, c_p=s.c_p + dc[..., :3], c_C=so3_exp(dc[..., 3:]) @ s.c_C)


def widen(H: NDArray, n: int) -> NDArray:
    """Core rows (B, M, 17) as rows over the full state (B, M, n)."""
    out = np.zeros(H.shape[:-1] + (n,))
    out[..., :N] = H
    return out


def _lookup(tracks: FeatureTracks, k: int, ids: NDArray) -> NDArray:
    """The pixels (B, X, 2) of features ``ids`` (B, X) at epoch k (NaN where not in view, and for −1)."""
    row = tracks.ids[k]
    uv = np.full(ids.shape + (2,), np.nan)
    if not row.size:
        return uv
    order = np.argsort(row, kind="stable")
    srt = row[order]
    pos = np.clip(np.searchsorted(srt, ids), 0, row.size - 1)
    hit = (ids >= 0) & (srt[pos] == ids)
    got = tracks.uv[np.arange(ids.shape[0])[:, None], k, order[pos]]
    return np.where(hit[..., None], got, np.nan)


def feature_rows(s: SlamState, tracks: FeatureTracks, k: int, n: int):
    """Two pixel rows per feature in a slot seen at epoch k: ν, H (B, 2J, n), R of the tracker's noise, mask
    and the rows' camera-rotation Jacobian G (B, 2J, 3) — or None."""
    uv = _lookup(tracks, k, s.f_id)
    seen = np.isfinite(uv).all(-1)
    if not seen.any():
        return None
    B, J = s.f_id.shape
    lever = np.asarray(tracks.camera.lever_arm_body, float)
    h, Hc, Hm, ray = pixel_rows(s.nav, s.f_m, tracks.K, tracks.camera.R_sensor_to_body, lever)
    G = rotation_rows(Hm, s.f_m, s.nav.p + np.einsum("bij,j->bi", s.nav.C, lever))
    H = widen(Hc, n)
    for j in range(J):
        H[:, 2 * j:2 * j + 2, feature_cols(j)] = Hm[:, j]
    seen &= ray[..., 2] > 0
    mask = np.repeat(seen, 2, axis=-1) & np.isfinite(h)
    nu = np.where(mask, uv.reshape(B, 2 * J) - np.nan_to_num(h), 0.0)
    R = tracks.sigma_px**2 * np.broadcast_to(np.eye(2 * J), (B, 2 * J, 2 * J))
    return nu, np.where(mask[..., None], np.nan_to_num(H), 0.0), R, mask, np.where(mask[..., None], G, 0.0)


def camera_rows(s: SlamState, vision: VisionEpochs | None, tracks: FeatureTracks | None, k: int,
                frame: LocalFrame, camera: CameraNoise, survey_sigma_m: float):
    """One frame's pixel rows over the full state, the surveyed landmarks' and the slot features', as one
    update: the camera's dithering moves them all together, so their R is one dense block (sequential
    landmark and feature updates would each take the frame's rotation as independent of the other's). ν, H, R,
    mask and each row's fault mode (None without a bank) — or None."""
    n = s.P.shape[-1]
    parts = []
    if vision is not None:
        r = vision_rows(s.core(), vision, k, frame, survey_sigma_m)
        if r is not None:
            parts.append(r[:1] + (widen(r[1], n),) + r[2:5] + (None if s.bank is None else s.bank.vision_modes(r[5]),))
    if tracks is not None:
        r = feature_rows(s, tracks, k, n)
        if r is not None:
            parts.append(r + (None if s.bank is None else np.full(r[0].shape[-1], s.bank.vision_mode),))
    if not parts:
        return None
    nu, H, Rs, mask, G, modes = zip(*parts)
    R = np.zeros(Rs[0].shape[:1] + (sum(r.shape[-1] for r in Rs),) * 2)
    i = 0
    for r in Rs:  # block-diagonal: the detector's, the survey's and the tracker's noise are independent
        R[:, i:i + r.shape[-1], i:i + r.shape[-1]] = r
        i += r.shape[-1]
    R_cb = (vision if vision is not None else tracks).camera.R_sensor_to_body
    R = R + camera.covariance(np.concatenate(G, -2), s.nav.C, R_cb)
    return (np.concatenate(nu, -1), np.concatenate(H, -2), R, np.concatenate(mask, -1),
            None if s.bank is None else np.concatenate(modes))


def bearing(C: NDArray, R_cb: NDArray, K: NDArray, uv: NDArray) -> tuple[NDArray, NDArray]:
    """The world-frame unit bearing (..., 3) of pixel uv seen by a camera on attitude C, and ∂d/∂uv (..., 3, 2)."""
    r = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], -1) @ np.linalg.inv(K).T
    nr = np.linalg.norm(r, axis=-1, keepdims=True)
    rh = r / nr
    Rcw = C @ R_cb
    d = np.einsum("...ij,...j->...i", Rcw, rh)
    J_r = (np.eye(3) - rh[..., :, None] * rh[..., None, :]) / nr[..., None]
    dd_duv = Rcw @ J_r @ np.linalg.inv(K)[:, :2]
    return d, dd_duv


def triangulate(c1: NDArray, d1: NDArray, c2: NDArray, d2: NDArray) -> NDArray:
    """The point (..., 3) nearest two rays c + t·d (unit d) in the least-squares sense."""
    P1 = np.eye(3) - d1[..., :, None] * d1[..., None, :]
    P2 = np.eye(3) - d2[..., :, None] * d2[..., None, :]
    b = np.einsum("...ij,...j->...i", P1, c1) + np.einsum("...ij,...j->...i", P2, c2)
    return np.linalg.solve(P1 + P2, b[..., None])[..., 0]


def triangulation_jacobians(m: NDArray, poses: list[tuple[NDArray, NDArray, NDArray, NDArray, NDArray]],
                            lever_cam: NDArray) -> list[tuple[NDArray, NDArray, NDArray, NDArray]]:
    """∂m/∂δp, ∂m/∂δψ, ∂m/∂uv and ∂m/∂ψ_cam (each (..., 3, ·)) of the least-squares point for each ray's pose
    (ψ_cam: the camera alone turned by a world-frame rotation, its dithering).

    ``poses``: per ray (C, c, d, ∂d/∂uv, P = I − ddᵀ). With A = ΣPᵢ: ``δm = A⁻¹ Σ (Pᵢ δcᵢ − Gᵢ δdᵢ)``,
    ``Gᵢ = (dᵢ·wᵢ) I + dᵢwᵢᵀ``, wᵢ = cᵢ − m; ``δcᵢ = δp − [(Ĉl)×]δψ``, ``δdᵢ = −[dᵢ×](δψ + ψ_cam) + (∂d/∂uv) δuv``.
    """
    A = sum(P for *_, P in poses)
    Ainv = np.linalg.inv(A)
    out = []
    for C, c, d, dd_duv, P in poses:
        w = c - m
        G = np.einsum("...i,...i->...", d, w)[..., None, None] * np.eye(3) + d[..., :, None] * w[..., None, :]
        la = np.einsum("...ij,j->...i", C, lever_cam)
        J_rot = Ainv @ G @ skew(d)
        J_psi = -Ainv @ P @ skew(la) + J_rot
        J_uv = -Ainv @ G @ dd_duv
        out.append((Ainv @ P, J_psi, J_uv, J_rot))
    return out


def _map_slot(s: SlamState, b: NDArray, cols: slice, A: NDArray, noise: NDArray | None = None) -> SlamState:
    """For trials b: the slot ``cols`` becomes the linear map A (|b|, k, n) of the error state plus independent
    noise (|b|, k, k): rows ``A P``, block ``A P Aᵀ + noise`` (A = 0 clears it, exactly a marginalisation); the
    sub-filters take the same map of their own states (:func:`.separation.augment`)."""
    rows = A @ s.P[b]
    diag = rows @ np.swapaxes(A, -1, -2) + (0.0 if noise is None else noise)
    rows[:, :, cols] = 0.5 * (diag + np.swapaxes(diag, -1, -2))
    s.P[b, cols, :] = rows
    s.P[b, :, cols] = np.swapaxes(rows, -1, -2)
    return s if s.bank is None else replace(s, bank=augment(s.bank, b, cols, A, noise))


def _clear(s: SlamState, b: NDArray, cols: slice) -> SlamState:
    return _map_slot(s, b, cols, np.zeros((b.size, cols.stop - cols.start, s.P.shape[-1])))


def manage(s: SlamState, tracks: FeatureTracks, k: int, cfg: FeatureSettings, camera: CameraNoise = CameraNoise()
           ) -> SlamState:
    """After the epoch's updates: triangulate or drop the clones, marginalise lost features, start clones.
    ``camera``: its white noise and dithering, beside the tracker's noise, in both pixels a triangulation
    spends (each frame's rotation taken as independent of the state: the frame's other rows that saw it are
    not tracked)."""
    s = replace(s, P=s.P.copy(), f_id=s.f_id.copy(), f_m=s.f_m.copy(), f_lost=s.f_lost.copy(), c_id=s.c_id.copy(),
                c_p=s.c_p.copy(), c_C=s.c_C.copy(), c_uv=s.c_uv.copy(), c_age=s.c_age.copy())
    seen_f = np.isfinite(_lookup(tracks, k, s.f_id)).all(-1)
    s.f_lost[:] = np.where(seen_f, 0, s.f_lost + 1)
    s = _triangulate_clones(s, tracks, k, cfg, camera)
    lost = (s.f_id >= 0) & (s.f_lost > cfg.lost_frames)
    for j in range(cfg.slots):
        b = np.flatnonzero(lost[:, j])
        if b.size:
            s = _clear(s, b, feature_cols(j))
            s.f_id[b, j] = -1
    return _start_clones(s, tracks, k, cfg)


def _triangulate_clones(s: SlamState, tracks: FeatureTracks, k: int, cfg: FeatureSettings,
                        camera: CameraNoise = CameraNoise()) -> SlamState:
    K, R_cb = tracks.K, tracks.camera.R_sensor_to_body
    lc = np.asarray(tracks.camera.lever_arm_body, float)
    uv2 = _lookup(tracks, k, s.c_id)  # (B, K, 2)
    var = tracks.sigma_px**2 + camera.white_px**2
    for q in range(cfg.clones):
        active = s.c_id[:, q] >= 0
        seen = active & np.isfinite(uv2[:, q]).all(-1)
        s.c_age[:, q] += active
        drop = active & (~seen | (s.c_age[:, q] > cfg.max_wait_frames))
        b = np.flatnonzero(seen)
        if b.size:
            C1, C2 = s.c_C[b, q], s.nav.C[b]
            c1 = s.c_p[b, q] + C1 @ lc
            c2 = s.nav.p[b] + C2 @ lc
            d1, j1 = bearing(C1, R_cb, K, s.c_uv[b, q])
            d2, j2 = bearing(C2, R_cb, K, uv2[b, q])
            par = np.degrees(np.arccos(np.clip(np.einsum("bi,bi->b", d1, d2), -1.0, 1.0)))
            go = par >= cfg.parallax_deg
            m = triangulate(c1, d1, c2, d2)
            ahead = (np.einsum("bi,bi->b", m - c1, d1) > 0) & (np.einsum("bi,bi->b", m - c2, d2) > 0)
            go &= ahead
            free = s.f_id[b] < 0
            go &= free.any(-1)
            drop[b[~ahead & (par >= cfg.parallax_deg)]] = True
            if go.any():
                g = b[go]
                slot = np.argmax(free[go], axis=-1)  # lowest free slot
                Pm1 = np.eye(3) - d1[go, :, None] * d1[go, None, :]
                Pm2 = np.eye(3) - d2[go, :, None] * d2[go, None, :]
                (Jp1, Jq1, Ju1, Jr1), (Jp2, Jq2, Ju2, Jr2) = triangulation_jacobians(
                    m[go], [(C1[go], c1[go], d1[go], j1[go], Pm1), (C2[go], c2[go], d2[go], j2[go], Pm2)], lc)
                n = s.P.shape[-1]
                A = np.zeros((g.size, 3, n))
                cc = clone_cols(cfg, q)
                A[:, :, cc.start:cc.start + 3], A[:, :, cc.start + 3:cc.stop] = Jp1, Jq1
                A[:, :, 0:3], A[:, :, 6:9] = Jp2, Jq2
                noise = var * (Ju1 @ np.swapaxes(Ju1, -1, -2) + Ju2 @ np.swapaxes(Ju2, -1, -2))
                for Jr, Cq in ((Jr1, C1[go]), (Jr2, C2[go])):
                    noise = noise + Jr @ camera.rotation_cov(Cq, R_cb) @ np.swapaxes(Jr, -1, -2)
                for j in np.unique(slot):
                    sel = slot == j
                    gj = g[sel]
                    s = _map_slot(s, gj, feature_cols(int(j)), A[sel], noise[sel])
                    s.f_id[gj, j] = s.c_id[gj, q]
                    s.f_m[gj, j] = m[go][sel]
                    s.f_lost[gj, j] = 0
                drop[g] = True
        d = np.flatnonzero(drop)
        if d.size:
            s = _clear(s, d, clone_cols(cfg, q))
            s.c_id[d, q] = -1
            s.c_age[d, q] = 0
    return s


def _start_clones(s: SlamState, tracks: FeatureTracks, k: int, cfg: FeatureSettings) -> SlamState:
    ids = tracks.ids[k]
    if not ids.size:
        return s
    uv = tracks.uv[:, k]  # (B, W, 2)
    B = uv.shape[0]
    for q in range(cfg.clones):
        free_c = s.c_id[:, q] < 0
        spare = (s.f_id < 0).sum(-1) > (s.c_id >= 0).sum(-1)  # a feature slot for every pending clone
        want = free_c & spare
        if not want.any():
            continue
        taken = (ids[None, :, None] == s.f_id[:, None, :]).any(-1) | (ids[None, :, None] == s.c_id[:, None, :]).any(-1)
        cand = (ids[None] >= 0) & np.isfinite(uv).all(-1) & ~taken
        v = np.where(cand, uv[..., 1], np.inf)
        pick = np.argmin(v, axis=-1)  # entering the image: the smallest row
        b = np.flatnonzero(want & cand[np.arange(B), pick])
        if not b.size:
            continue
        E = np.zeros((b.size, 6, s.P.shape[-1]))  # the clone copies the core's δp, δψ
        E[:, np.arange(6), _POSE] = 1.0
        s = _map_slot(s, b, clone_cols(cfg, q), E)
        s.c_id[b, q] = ids[pick[b]]
        s.c_p[b, q], s.c_C[b, q] = s.nav.p[b], s.nav.C[b]
        s.c_uv[b, q] = uv[b, pick[b]]
        s.c_age[b, q] = 0
    return s


@dataclass(frozen=True)
class SlamTrace:
    """The filter at its aiding epochs (B, T, ...)."""

    t: NDArray
    p: NDArray  # (B, T, 3)
    P_pos: NDArray  # (B, T, 3, 3)
    n_features: NDArray  # (B, T)
    nis: NDArray  # (B, T)
    dof: NDArray  # (B, T)
    ba: NDArray  # (B, T, 3)
    bg: NDArray  # (B, T, 3)
    cb: NDArray  # (B, T)
    cd: NDArray  # (B, T)
    sub_dp: NDArray | None = None  # the sub-filters' position offsets (R, T, 3) (separation.py)
    sub_Pp: NDArray | None = None  # and position blocks (R, T, 3, 3)


def run_slam(s: SlamState, imu: ImuSamples, frame: LocalFrame, imu_noise: ImuNoise, cfg: FeatureSettings,
             tracks: FeatureTracks | None = None, gnss: GnssEpochs | None = None, clock: ClockNoise = ClockNoise(),
             t_aid: NDArray | None = None, range_rate_sigma_m_s: float | None = None,
             vision: VisionEpochs | None = None, camera: CameraNoise = CameraNoise(), survey_sigma_m: float = 0.05,
             through_end: bool = False) -> tuple[SlamTrace, SlamState]:
    """Predict through the IMU intervals, update at each aiding epoch (the tracks' epochs, else ``t_aid``):
    GNSS rows where a GNSS epoch falls (1e-6 s), then the frame's pixels in one update (:func:`camera_rows`:
    the surveyed landmarks' (``vision``, at the tracks' epochs) and the features in slots, with ``camera``'s
    noise common to them), then the slots' bookkeeping. ``through_end``: the state returned is
    after every IMU interval given (a block of a live run hands it on), not after the last aiding epoch."""
    t_aid = np.asarray(tracks.t if tracks is not None else t_aid, float)
    B, n = s.P.shape[0], s.P.shape[-1]
    k_g = None if gnss is None else {round(float(t) * 1e6): i for i, t in enumerate(gnss.t)}
    rec = {k: [] for k in ("p", "P_pos", "n_features", "nis", "dof", "ba", "bg", "cb", "cd")}
    sub_dp, sub_Pp = [], []
    k_imu = 0
    for k, t in enumerate(t_aid):
        k_end = int(np.searchsorted(imu.t, t + 1e-9, side="right"))
        if k_end > k_imu:
            s = predict_static(s, imu_block(imu.dtheta, B, k_imu, k_end), imu_block(imu.dvel, B, k_imu, k_end),
                               imu.dt, frame, imu_noise, clock, imu.earth_rotation)
            k_imu = k_end
        s = settle_static(s)  # (a block that ended between epochs left the last step pending)
        # the body rate the antenna's lever arm turns with: the last IMU interval's, bias-corrected
        omega = imu_block(imu.dtheta, B, k_end - 1, k_end)[:, 0] / imu.dt - s.nav.bg if k_end > 0 else np.zeros((B, 3))
        nis, dof = np.zeros(B), np.zeros(B, np.int64)
        stages = []
        kg = None if k_g is None else k_g.get(round(float(t) * 1e6))
        if kg is not None:
            stages.append(lambda s: _core_rows(gnss_rows(s.core(), gnss, kg, frame, omega, range_rate_sigma_m_s), n,
                                               None if s.bank is None else lambda r: r[4]))
        if vision is not None or tracks is not None:
            stages.append(lambda s: camera_rows(s, vision, tracks, k, frame, camera, survey_sigma_m))
        for rows_of in stages:  # sequential updates, each linearised at the state the last one left
            rows = rows_of(s)
            if rows is not None:
                s, a, b = apply_update(s, *rows)
                nis, dof = nis + a, dof + b
        if tracks is not None:
            s = manage(s, tracks, k, cfg, camera)
        for name, v in (("p", s.nav.p), ("P_pos", s.P[:, :3, :3].copy()), ("n_features", (s.f_id >= 0).sum(-1)),
                        ("nis", nis), ("dof", dof), ("ba", s.nav.ba), ("bg", s.nav.bg), ("cb", s.nav.cb),
                        ("cd", s.nav.cd)):
            rec[name].append(v)
        if s.bank is not None:
            sub_dp.append(s.bank.dx[:, :3].copy())  # copies: a view would keep the whole (R, n) array alive
            sub_Pp.append(s.bank.P[:, :3, :3].copy())
    if through_end and k_imu < imu.t.size:
        s = predict_static(s, imu_block(imu.dtheta, B, k_imu, None), imu_block(imu.dvel, B, k_imu, None),
                           imu.dt, frame, imu_noise, clock, imu.earth_rotation, settle=False)
    out = {k: np.stack(v, 1) if v else np.zeros((B, 0) + _TRACE_TAILS[k]) for k, v in rec.items()}
    if s.bank is not None:
        out["sub_dp"], out["sub_Pp"] = (stack_subs(sub_dp, sub_Pp, out["P_pos"], B) if sub_dp else
                                        (np.zeros((0, 0, 3)), np.zeros((0, 0, 3, 3))))
    return SlamTrace(t=t_aid, **out), s


_TRACE_TAILS = {"p": (3,), "P_pos": (3, 3), "n_features": (), "nis": (), "dof": (), "ba": (3,), "bg": (3,),
                "cb": (), "cd": ()}


def _core_rows(rows, n: int, modes_of):
    """Rows over the 17 core states (run.py's: ν, H, R, mask, row satellite, row landmark) as apply_update's
    arguments over the full state, with each row's fault mode (``modes_of(rows)``; None without a bank)."""
    if rows is None:
        return None
    nu, H, R, mask = rows[:4]
    return nu, widen(H, n), R, mask, None if modes_of is None else modes_of(rows)


__all__ = ["FeatureSettings", "SlamState", "SlamTrace", "apply_update", "bearing", "camera_rows", "feature_rows", "manage",
           "predict_static", "run_slam", "settle_static", "start", "triangulate", "triangulation_jacobians"]
