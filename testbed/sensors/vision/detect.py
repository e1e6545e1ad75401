"""Landmark detections: from the true aircraft pose to what the vision front end reports.

:func:`synthesize_vision` is a pure function of (truth, settings, landmarks,
terrain, faults, rng). Per vision epoch (the truth decimated to
``settings.rate_hz``):

1. camera pose: truth attitude × mount × dithering (:mod:`.dithering`), camera
   position = CG + R_body_to_ecef · lever arm;
2. ideal pixel of each landmark's *actual* position (true, or surveyed + Δ
   while a :class:`~testbed.sensors.faults.LandmarkMoved` fault is active),
   then the lens distortion (the detector works in the raw image);
3. visibility, first failing rule gives the reason (:class:`~testbed.records.NotVisible`):
   behind the camera (AIRFRAME), outside the image less a margin (OUT_OF_IMAGE),
   beyond the maximum range (TOO_FAR), terrain between camera and landmark
   (TERRAIN), apparent size f·size/range below ``min_size_px`` (TOO_SMALL);
4. detected pixel = raw pixel + N(0, σ²) per axis with
   σ² = σ_DE² + (blur_factor · |ω_cam| · t_exp · f)² (motion blur as extra
   Gaussian noise, ω_cam the camera's angular rate: body rate + dithering rate),
   + a pixel-bias fault; then undistorted back to the ideal pinhole image the
   monitors use (``VisionEpochs.K``); a misassociation swaps two slots last.

With ``n_trials`` every random quantity (survey error, dithering, attitude
reference error, noise, random fault targets) gets a leading trial axis; the
terrain line-of-sight is computed once per trajectory.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from testbed.frames import R_ecef_to_enu, R_to_q, ecef_to_geodetic
from testbed.records import NotVisible, Truth, VisionEpochs
from testbed.sensors.faults import LandmarkMoved, Misassociation, PixelBias, VISION_KINDS, active

from .attitude_ref import attitude_reference
from .camera import PinholeCamera
from .dithering import camera_pose, dithering_angles, mount_from_settings
from .landmarks import Landmarks, build_landmarks, survey
from .settings import DetectionSettings, LandmarkSettings, VisionSettings


class FaultKind:
    """Codes of ``VisionTruth.fault_kind`` (0 = none)."""

    NONE, PIXEL_BIAS, LANDMARK_MOVED, MISASSOCIATION = 0, 1, 2, 3


@dataclass(frozen=True)
class VisionTruth:
    """Truth side of the vision synthesis (evaluation only; monitors never see it).

    Attributes
    ----------
    t : (T,) s, vision epochs.
    cam_pos_ecef : (T, 3) m, true camera position.
    q_cam_to_ecef : (B..., T, 4) true camera attitude (with dithering), scalar last.
    dither_cam : (B..., T, 3) rad, dithering rotation vector in camera axes (x pitch, y yaw, z roll).
    attitude_ref_error : (B..., T, 3) rad, (roll, pitch, heading) error of the attitude reference.
    landmark_true_ecef : (L, 3) m, true landmark positions.
    landmark_survey_ecef : (B..., L, 3) m, surveyed positions (what the monitor gets).
    landmark_moved_ecef : (B..., L, 3) m, where a moved landmark stands during its fault
        (= true position for landmarks no fault moves).
    landmark_moved : (B..., T, L) bool, landmark displaced by a LandmarkMoved fault at that epoch.
    pixel_true : (B..., T, L, 2) px, ideal pinhole pixel of the actual landmark under the true
        camera pose (before noise and faults; NaN behind the camera).
    range_m : (B..., T, L) m, true camera-to-landmark distance.
    visible : (B..., T, L) bool, nominal visibility of each slot (before a misassociation swap).
    noise_px : (B..., T, L, 2) px, drawn nominal detection error (DE + blur), in the raw image.
    blur_sigma_px : (B..., T) px, motion-blur std.
    fault_pixel_bias : (B..., T, L, 2) px, injected pixel bias.
    faulty : (B..., T, L) bool, the reported measurement in this slot is faulty.
    fault_kind : (B..., T, L) int8 :class:`FaultKind` code.
    """

    t: NDArray
    cam_pos_ecef: NDArray
    q_cam_to_ecef: NDArray
    dither_cam: NDArray
    attitude_ref_error: NDArray
    landmark_true_ecef: NDArray
    landmark_survey_ecef: NDArray
    landmark_moved_ecef: NDArray
    landmark_moved: NDArray
    pixel_true: NDArray
    range_m: NDArray
    visible: NDArray
    noise_px: NDArray
    blur_sigma_px: NDArray
    fault_pixel_bias: NDArray
    faulty: NDArray
    fault_kind: NDArray


def visibility(camera: PinholeCamera, det: DetectionSettings, p_cam: NDArray, range_m: NDArray,
               size_m: NDArray, los: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Apply the visibility rules to points in camera axes.

    Parameters
    ----------
    p_cam : (..., L, 3) m, landmark in camera axes.  range_m : (..., L) m.
    size_m : (L,) m.  los : (..., L) bool, terrain line of sight clear.

    Returns
    -------
    uv_raw : (..., L, 2) px, pixel in the raw (distorted) image (NaN behind the camera).
    visible : (..., L) bool.  reason : (..., L) int8 :class:`NotVisible` code (first failing rule).
    """
    uv_ideal, in_front = camera.project(p_cam, min_depth=det.min_depth_m)
    uv_raw = camera.distort(uv_ideal)
    in_img = camera.in_image(uv_raw, det.margin_px)
    too_far = range_m > det.max_range_m
    size_px = camera.fx * size_m / np.maximum(range_m, 1e-9)
    too_small = (det.min_size_px > 0) & (size_px < det.min_size_px)
    reason = np.select([~in_front, ~in_img, too_far, ~los, too_small],
                       [NotVisible.AIRFRAME, NotVisible.OUT_OF_IMAGE, NotVisible.TOO_FAR, NotVisible.TERRAIN,
                        NotVisible.TOO_SMALL], NotVisible.VISIBLE).astype(np.int8)
    return uv_raw, reason == NotVisible.VISIBLE, reason


def _line_of_sight(terrain, cam_pos: NDArray, lm_pos: NDArray, candidates: NDArray) -> NDArray:
    """Terrain LOS ``(T, L)`` for camera ``(T, 3)`` and landmarks ``(L, 3)`` or ``(T, L, 3)``.

    Only ``candidates`` (T, L) pairs are asked (others count as clear: another rule
    already hides them); ``terrain`` None = no terrain.
    """
    T, L = candidates.shape
    los = np.ones((T, L), bool)
    if terrain is None or not candidates.any():
        return los
    ti, li = np.nonzero(candidates)
    tgt = lm_pos[li] if lm_pos.ndim == 2 else lm_pos[ti, li]
    res = np.asarray(terrain.line_of_sight(cam_pos[ti], tgt), bool)
    if res.shape != ti.shape:
        raise ValueError(f"terrain.line_of_sight: expected a result of shape {ti.shape}, got {res.shape}")
    los[ti, li] = res
    return los


def _select(fault, name: str, lm: Landmarks, det_at_onset: NDArray, rng: np.random.Generator) -> NDArray:
    """Slot index per trial ``(B...,)`` a fault targets; -1 = none (random and nothing detected)."""
    batch = det_at_onset.shape[:-1]
    if name != "random":
        return np.full(batch, lm.index(name), int)
    score = rng.random(det_at_onset.shape)
    score = np.where(det_at_onset, score, -1.0)
    k = np.argmax(score, axis=-1)
    return np.where(np.take_along_axis(score, k[..., None], -1)[..., 0] >= 0, k, -1)


def synthesize_vision(truth: Truth, settings: VisionSettings, *, landmarks: Landmarks | LandmarkSettings,
                      terrain=None, faults: list | None = None, rng: np.random.Generator,
                      n_trials: int | None = None) -> tuple[VisionEpochs, VisionTruth]:
    """Synthesize camera landmark detections along a flight.

    Parameters
    ----------
    truth : the flight (any rate; decimated to ``settings.rate_hz``).
    settings : camera, mount, dithering, attitude reference, detector.
    landmarks : the scene (built :class:`Landmarks` or its settings).
    terrain : an object with ``line_of_sight(origin_ecef (..., 3), target_ecef (..., 3)) -> bool (...)``,
        or None (no terrain masking).
    faults : a fault schedule; only the vision kinds (pixel_bias, landmark_moved,
        misassociation) are used.
    rng : the only source of randomness. Draw order: survey error, dithering,
        attitude reference, detection noise, random fault targets.
    n_trials : when given, a leading trial axis B = (n_trials,) on every random output.

    Returns
    -------
    (VisionEpochs, VisionTruth); shapes as documented there, with B = () when
    ``n_trials`` is None. ``VisionEpochs.landmark_pos_ecef`` is ``(B..., L, 3)``:
    the survey error is drawn per trial.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: expected numpy.random.Generator, got {type(rng).__name__}")
    if n_trials is not None and int(n_trials) < 1:
        raise ValueError(f"n_trials: expected >= 1 or None, got {n_trials}")
    lm = build_landmarks(landmarks) if isinstance(landmarks, LandmarkSettings) else landmarks
    faults = [f for f in (faults or []) if getattr(f, "kind", None) in VISION_KINDS]
    batch = () if n_trials is None else (int(n_trials),)
    det = settings.detection
    cam = settings.camera.build()
    mount = mount_from_settings(settings.mount)
    tr = truth.decimate(settings.rate_hz)
    t = tr.t
    T, L = t.size, len(lm)

    # Random draws, in the documented order.
    lm_survey = survey(lm, rng, n_trials)  # (B..., L, 3)
    delta, delta_rate = dithering_angles(t, settings.dithering, rng, n_trials)  # (B..., T, 3)
    q_ref, att_err, att_sigma = attitude_reference(tr.q_body_to_enu, settings.attitude_ref, rng, n_trials)
    noise_std = rng.standard_normal(batch + (T, L, 2))

    # True camera pose (position is not dithered; the lever arm uses the true attitude).
    cam_pos, R_c2e0 = camera_pose(tr.pos_ecef, tr.q_body_to_enu, mount)  # (T, 3), (T, 3, 3)
    R_d = Rotation.from_rotvec(delta.reshape(-1, 3)).as_matrix().reshape(delta.shape[:-1] + (3, 3))
    R_c2e = R_c2e0 @ R_d  # (B..., T, 3, 3)

    # Landmark positions: true, or surveyed + delta where a LandmarkMoved fault is active.
    diff0 = lm.pos_ecef[None, :, :] - cam_pos[:, None, :]  # (T, L, 3)
    range0 = np.linalg.norm(diff0, axis=-1)
    los0 = _line_of_sight(terrain, cam_pos, lm.pos_ecef, range0 <= det.max_range_m)
    p_cam0 = np.einsum("...tji,tlj->...tli", R_c2e, diff0)
    uv0, vis0, _ = visibility(cam, det, p_cam0, np.broadcast_to(range0, batch + (T, L)), lm.size_m, los0)

    moved = np.zeros(batch + (T, L), bool)
    moved_pos = np.broadcast_to(lm.pos_ecef, batch + (L, 3)).copy()
    los = np.broadcast_to(los0, batch + (T, L)).copy()
    for f in faults:
        if not isinstance(f, LandmarkMoved):
            continue
        on = active(f, t)
        if not on.any():
            continue
        k = _select(f, f.landmark, lm, vis0[..., np.argmax(on), :], rng)  # (B...,)
        lat, lon, _ = ecef_to_geodetic(lm.pos_ecef)
        d_ecef = np.einsum("lji,j->li", R_ecef_to_enu(lat, lon), np.asarray(f.delta_enu_m, float))  # (L, 3)
        hit = (np.arange(L) == k[..., None])  # (B..., L)
        moved_pos = np.where(hit[..., None], lm_survey + d_ecef, moved_pos)
        moved |= on[:, None] & hit[..., None, :]
        # Terrain for the moved position, once per trajectory (cm survey errors do not matter to it).
        los_m = _line_of_sight(terrain, cam_pos, lm.pos_ecef + d_ecef, np.ones((T, L), bool))
        los = np.where(on[:, None] & hit[..., None, :], los_m, los)

    actual = np.where(moved[..., None], moved_pos[..., None, :, :], lm.pos_ecef)  # (B..., T, L, 3)
    diff = actual - cam_pos[:, None, :]
    range_m = np.linalg.norm(diff, axis=-1)
    p_cam = np.einsum("...tji,...tlj->...tli", R_c2e, diff)
    uv_raw, vis, reason = visibility(cam, det, p_cam, range_m, lm.size_m, los)
    uv_true, _ = cam.project(p_cam, min_depth=det.min_depth_m)

    # Detection noise with motion blur: camera rate = mount-rotated body rate + dithering rate.
    omega_cam = np.einsum("...tji,tj->...ti", R_d, tr.omega_body @ mount.R_sensor_to_body) + delta_rate
    blur = det.blur_factor * np.linalg.norm(omega_cam, axis=-1) * det.exposure_s * cam.fx  # (B..., T)
    sigma = np.sqrt(det.sigma_px**2 + blur**2)  # (B..., T)
    noise = noise_std * sigma[..., None, None]
    uv_meas = uv_raw + noise

    # Pixel-bias faults (in the raw image, on detected slots).
    bias = np.zeros(batch + (T, L, 2))
    kind = np.where(moved & vis, FaultKind.LANDMARK_MOVED, FaultKind.NONE).astype(np.int8)
    for f in faults:
        if not isinstance(f, PixelBias):
            continue
        on = active(f, t)
        if not on.any():
            continue
        k = _select(f, f.landmark, lm, vis[..., np.argmax(on), :], rng)
        hit = on[:, None] & (np.arange(L) == k[..., None])[..., None, :] & vis  # (B..., T, L)
        a = np.radians(f.angle_deg)
        bias += np.where(hit[..., None], f.magnitude_px * np.array([np.cos(a), np.sin(a)]), 0.0)
        kind = np.where(hit, FaultKind.PIXEL_BIAS, kind).astype(np.int8)
    uv_meas = cam.undistort(uv_meas + bias)

    sigma_told = np.broadcast_to((sigma if det.sigma_told_px is None else np.full_like(sigma, det.sigma_told_px))
                                 [..., None], batch + (T, L)).copy()
    detected = vis.copy()
    rep_reason = reason.copy()
    for f in faults:  # misassociation last: the matcher swaps two slots' reports
        if not isinstance(f, Misassociation):
            continue
        i, j = lm.index(f.landmarks[0]), lm.index(f.landmarks[1])
        on = active(f, t)
        perm = np.arange(L)
        perm[[i, j]] = [j, i]
        uv_meas = np.where(on[:, None, None], uv_meas[..., perm, :], uv_meas)
        detected = np.where(on[:, None], detected[..., perm], detected)
        rep_reason = np.where(on[:, None], rep_reason[..., perm], rep_reason)
        sigma_told = np.where(on[:, None], sigma_told[..., perm], sigma_told)
        swapped = np.zeros((T, L), bool)
        swapped[on, i] = swapped[on, j] = True
        kind = np.where(swapped & detected, FaultKind.MISASSOCIATION, kind).astype(np.int8)

    uv_meas = np.where(detected[..., None], uv_meas, np.nan)
    faulty = (kind != FaultKind.NONE) & detected
    kind = np.where(detected, kind, FaultKind.NONE).astype(np.int8)

    epochs = VisionEpochs(t=t, landmark_id=lm.id.copy(), landmark_pos_ecef=lm_survey, pixel_uv=uv_meas,
                          detected=detected, reason=rep_reason, sigma_px=sigma_told, K=cam.K, camera=mount,
                          q_body_to_enu_ref=q_ref, attitude_sigma=att_sigma)
    vtruth = VisionTruth(t=t, cam_pos_ecef=cam_pos, q_cam_to_ecef=R_to_q(R_c2e), dither_cam=delta,
                         attitude_ref_error=att_err, landmark_true_ecef=lm.pos_ecef.copy(),
                         landmark_survey_ecef=lm_survey, landmark_moved_ecef=moved_pos, landmark_moved=moved,
                         pixel_true=uv_true, range_m=range_m, visible=vis, noise_px=noise, blur_sigma_px=blur,
                         fault_pixel_bias=bias, faulty=faulty, fault_kind=kind)
    return epochs, vtruth

