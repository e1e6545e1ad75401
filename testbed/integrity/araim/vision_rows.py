"""Landmark pixels as ARAIM rows with their own fault modes (docs/design/araim.md §11).

Each tracked landmark gives two rows (u, v) of a linear model in the antenna position, linearised at the
all-in-view GNSS fix, with the pixel residuals there. The two small rotations the pixel model does not know
(:func:`testbed.integrity.pixel_model.attitude_pixel_jacobians`: the attitude reference error δφ and the
camera's dithering δ) are *states* of the solution, each axis with a prior row (the pseudo-measurement
δ = 0 with its sigma). Given those states the landmarks' pixel errors are independent (σ_px² I), so every row
has its own variance and

* "landmark j faulty" removes landmark j's two rows: the subset is free of that fault (the rotations are
  still estimated from the other landmarks and their priors);
* "camera faulty" removes every pixel row and the rotation prior rows: the rotation states have no row left
  and are pinned, as a removed constellation's clock is.

Marginalising the rotation states gives back the full pixel covariance σ_px² I + Σ J diag(σ²) Jᵀ of
:func:`testbed.integrity.pixel_model.pixel_covariance` exactly (tests/test_araim_vision.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from testbed.frames import LocalFrame
from testbed.inertial import body_to_world
from testbed.integrity.araim.fault_modes import AID_CAMERA, AID_LANDMARK
from testbed.integrity.pixel import _spread_landmarks
from testbed.integrity.pixel_model import attitude_pixel_jacobians, project_landmarks
from testbed.records import Mount, VisionEpochs


@dataclass(frozen=True)
class CameraEpochs:
    """The vision observations of P flat epochs that the rows are built from (world frame ENU).

    uv : (P, L, 2) px detected pixels.  detected : (P, L) bool.  landmarks : (P, L, 3) m surveyed positions.
    sigma_px : (P, L) px.  q_ref : (P, 4) the attitude reference.  K : (3, 3).  camera : the camera mount.
    lever_ant : (3,) m the GNSS antenna's lever arm (body axes).  rotation_sigma : (6,) rad, σ of the
    attitude-reference error (roll, pitch, yaw) then of the dithering (camera x, y, z); an axis with σ = 0 is
    known and gets no state.
    """

    uv: NDArray
    detected: NDArray
    landmarks: NDArray
    sigma_px: NDArray
    q_ref: NDArray
    K: NDArray
    camera: Mount
    lever_ant: NDArray
    rotation_sigma: NDArray
    frame: LocalFrame

    def take(self, sel: NDArray) -> "CameraEpochs":
        """The epochs ``sel``."""
        return CameraEpochs(self.uv[sel], self.detected[sel], self.landmarks[sel], self.sigma_px[sel],
                            self.q_ref[sel], self.K, self.camera, self.lever_ant, self.rotation_sigma, self.frame)


def camera_epochs(vision: VisionEpochs, frame: LocalFrame, lever_ant: NDArray, lead: tuple,
                  sigma_px: float | None = None) -> CameraEpochs:
    """``vision`` (B..., T, L) flattened to the P = prod(lead) epochs of the GNSS rows.

    sigma_px : a pixel sigma replacing the front end's per-detection one (None: the front end's).
    """
    P = int(np.prod(lead, dtype=np.int64))
    uv = np.asarray(vision.pixel_uv, float)
    L = uv.shape[-2]
    flat = lambda a, tail: np.broadcast_to(np.asarray(a), lead + tail).reshape((P,) + tail)  # noqa: E731
    survey = np.asarray(vision.landmark_pos_ecef, float)
    if survey.ndim > 2:  # one survey per trial (B..., L, 3): the same at every epoch of the trial
        survey = survey[..., None, :, :]
    sig = flat(vision.sigma_px, (L,)) if sigma_px is None else np.full((P, L), float(sigma_px))
    return CameraEpochs(uv=flat(uv, (L, 2)), detected=flat(np.asarray(vision.detected, bool), (L,)),
                        landmarks=frame.ecef_to_enu(flat(survey, (L, 3))), sigma_px=sig,
                        q_ref=flat(vision.q_body_to_enu_ref, (4,)), K=np.asarray(vision.K, float),
                        camera=vision.camera, lever_ant=np.asarray(lever_ant, float),
                        rotation_sigma=np.concatenate([np.asarray(vision.attitude_sigma, float).reshape(3),
                                                       np.asarray(vision.dither_sigma, float).reshape(3)]),
                        frame=frame)


def camera_rows(cam: CameraEpochs, p_ant: NDArray, max_landmarks: int) -> dict[str, NDArray]:
    """The aid rows (:class:`~testbed.integrity.araim.core.AraimRows`' ``aid_*`` fields, batch P) of the
    camera at the antenna positions ``p_ant`` (P, 3) m, where the residuals are taken (NaN: no rows).

    Rows: the pixel rows (u, v) of at most ``max_landmarks`` detected landmarks in front of the camera, spread
    over the image (landmark j = rows 2j, 2j + 1), then one prior row per rotation state (σ > 0), used where
    some pixel row is. A detected landmark with a NaN pixel or sigma makes its rows non-finite (the epoch is
    then unavailable, as for a NaN pseudorange).
    """
    P, L = cam.detected.shape
    known = np.isfinite(p_ant).all(-1)
    det = cam.detected & known[:, None]
    p = np.where(known[:, None], p_ant, 0.0)
    Lc = max(min(int(det.sum(-1).max(initial=0)), max_landmarks), 1)
    slot = _spread_landmarks(np.nan_to_num(cam.uv), det, np.linalg.norm(cam.landmarks - p[:, None, :], axis=-1), Lc)
    take = lambda a: np.take_along_axis(a, slot.reshape((P, Lc) + (1,) * (a.ndim - 2)), 1)  # noqa: E731
    uv, lm, tracked, sig = take(cam.uv), take(cam.landmarks), take(det), take(cam.sigma_px)
    Rb = body_to_world(cam.frame, p, cam.q_ref)
    p_ref = p - np.einsum("pij,j->pi", Rb, cam.lever_ant)  # the aircraft rotates about its reference point
    uv_hat, H, s = project_landmarks(p_ref, Rb @ cam.camera.R_sensor_to_body,
                                     np.einsum("pij,j->pi", Rb, cam.camera.lever_arm_body), lm, cam.K)
    J_att, J_dith = attitude_pixel_jacobians(p_ref, Rb, cam.camera, lm, cam.K)
    states = np.flatnonzero(cam.rotation_sigma > 0.0)
    K = states.size
    J = np.concatenate([J_att, J_dith], -1)[..., states]  # (P, Lc, 2, K)
    tracked = tracked & (s[..., 2] > 0.0)  # a landmark behind the camera has no pixel
    g_pix = np.concatenate([H, J], -1).reshape(P, 2 * Lc, 3 + K)
    g_prior = np.broadcast_to(np.concatenate([np.zeros((K, 3)), np.eye(K)], -1), (P, K, 3 + K))
    pix_used = np.repeat(tracked, 2, -1)
    g = np.concatenate([g_pix, g_prior], 1)
    sig = np.where(np.isfinite(uv).all(-1), sig, np.nan)  # a detection without a pixel: a NaN row, never dropped
    c = np.concatenate([np.repeat(sig, 2, -1) ** 2, np.broadcast_to(cam.rotation_sigma[states] ** 2, (P, K))], -1)
    residual = np.concatenate([(uv - uv_hat).reshape(P, 2 * Lc), np.zeros((P, K))], -1)
    used = np.concatenate([pix_used, np.broadcast_to(pix_used.any(-1, keepdims=True), (P, K))], -1)
    state = np.concatenate([np.ones((2 * Lc, K), bool), np.eye(K, dtype=bool)], 0)
    label = np.array([(AID_LANDMARK, j) for j in range(Lc) for _ in range(2)] + [(AID_CAMERA, k) for k in range(K)],
                     int).reshape(-1, 2)
    g = np.where(used[..., None], g, 0.0)  # unused rows: finite, never read
    c = np.where(used, c, 1.0)  # a used NaN row stays NaN: the epoch is unavailable (NAN_INPUT)
    residual = np.where(used, residual, 0.0)
    return dict(aid_g=g, aid_state=state, aid_label=label, aid_used=used, aid_c=c, aid_residual=residual)
