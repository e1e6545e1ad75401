"""The vision-integrity patent's pixel measurement model: projection, its Jacobians, the pixel covariance,
a vision-only fix (docs/design/integrity.md §10).

Everything here is geometry of one camera and a set of surveyed landmarks,
batched over leading axes; the monitor (:mod:`.pixel`) stacks it with the GPS
rows. Camera axes: x right, y down, z forward.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.inertial import skew
from testbed.records import Mount


def _projection_jacobian(Ks: NDArray, uv: NDArray, K: NDArray) -> NDArray:
    """∂π/∂s ``(..., L, 2, 3)`` of ``π(s) = (K s)[:2] / (K s)[2]`` at ``Ks = K s`` and its pixels ``uv``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return (K[:2, :] - uv[..., :, None] * K[2, :]) / Ks[..., 2:3, None]


def project_landmarks(pos_enu: ArrayLike, R_cam_to_world: ArrayLike, cam_offset_world: ArrayLike,
                      landmarks_enu: ArrayLike, K: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
    """Pinhole pixels of landmarks and their Jacobian w.r.t. the reference position.

    Parameters
    ----------
    pos_enu : (..., 3) m, aircraft reference position (world frame).
    R_cam_to_world : (..., 3, 3) camera axes -> world ENU.
    cam_offset_world : (..., 3) m, camera centre minus ``pos_enu`` (world axes).
    landmarks_enu : (L, 3) or (..., L, 3) m, landmark positions (world frame).
    K : (3, 3) intrinsics.

    Returns
    -------
    uv : (..., L, 2) px, ``π(s) = (K s)[:2] / (K s)[2]``, s = R_c→wᵀ (t − c).
    H : (..., L, 2, 3) px/m, ``∂uv/∂pos = −∂π/∂s · R_c→wᵀ`` (patent step 3).
    s_cam : (..., L, 3) m, line of sight in camera axes (s_z ≤ 0: behind the camera).
    """
    p = np.asarray(pos_enu, float)
    R = np.asarray(R_cam_to_world, float)
    K = np.asarray(K, float)
    c = p + np.asarray(cam_offset_world, float)
    d = np.asarray(landmarks_enu, float) - c[..., None, :]
    s = np.einsum("...ji,...lj->...li", R, d)  # R_c→wᵀ d
    Ks = s @ K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = Ks[..., :2] / Ks[..., 2:3]
    H = -np.einsum("...lij,...kj->...lik", _projection_jacobian(Ks, uv, K), R)  # −Jπ R_c→wᵀ
    return uv, H, s


def attitude_pixel_jacobians(pos_enu: ArrayLike, R_body_to_world: ArrayLike, camera: Mount,
                             landmarks_enu: ArrayLike, K: ArrayLike) -> tuple[NDArray, NDArray]:
    """Pixel Jacobians ``(..., L, 2, 3)`` px/rad of the two small rotations the model does not know.

    * ``J_att``, a body-frame attitude-reference error δφ: with ``R_b→w,true = R_b→w,ref (I + [δφ]×)``
      the body-frame line of sight from the camera changes by ``[R_b→wᵀ (t − p)]× δφ``
      (the aircraft rotates about its reference point: lever arm included);
    * ``J_dither``, the camera's dithering δ on its mount (camera axes, about the camera
      centre): ``R_c→w,true = R_c→w (I + [δ]×)`` so ``s_true = s + [s]× δ``.
    """
    p = np.asarray(pos_enu, float)
    Rb = np.asarray(R_body_to_world, float)
    K = np.asarray(K, float)
    off = np.einsum("...ij,j->...i", Rb, camera.lever_arm_body)
    uv, _, s = project_landmarks(p, Rb @ camera.R_sensor_to_body, off, landmarks_enu, K)
    Jpi = _projection_jacobian(s @ K.T, uv, K)
    r_b = np.einsum("...ji,...lj->...li", Rb, np.asarray(landmarks_enu, float) - p[..., None, :])
    ds_dphi = np.einsum("ji,...ljk->...lik", camera.R_sensor_to_body, skew(r_b))  # R_c→bᵀ [r_b]×
    return Jpi @ ds_dphi, Jpi @ skew(s)


def attitude_pixel_jacobian(pos_enu: ArrayLike, R_body_to_world: ArrayLike, camera: Mount,
                            landmarks_enu: ArrayLike, K: ArrayLike) -> NDArray:
    """∂uv/∂δφ ``(..., L, 2, 3)`` px/rad for a small body-frame attitude error δφ (:func:`attitude_pixel_jacobians`)."""
    return attitude_pixel_jacobians(pos_enu, R_body_to_world, camera, landmarks_enu, K)[0]


def pixel_covariance(sigma_px: ArrayLike, rotations: list[tuple[NDArray, ArrayLike]] = ()) -> NDArray:
    """Full pixel covariance ``(..., 2L, 2L)`` px²: ``σ_px² I + Σₖ Jₖ diag(σₖ²) Jₖᵀ``.

    sigma_px : (..., L).  rotations : pairs (Jₖ (..., L, 2, 3) px/rad, σₖ (3,) rad) of small
    rotation errors common to every landmark (attitude reference, dithering), so the
    landmarks' pixels are correlated.
    """
    sp = np.asarray(sigma_px, float)
    L = sp.shape[-1]
    d = np.repeat(sp**2, 2, axis=-1)
    Sig = d[..., :, None] * np.eye(2 * L)
    for J, sig in rotations:
        Ja = J.reshape(J.shape[:-3] + (2 * L, 3))
        Sig = Sig + np.einsum("...ik,k,...jk->...ij", Ja, np.asarray(sig, float) ** 2, Ja)
    return Sig


def bearing_fix(uv: NDArray, detected: NDArray, K: ArrayLike, R_cam_to_world: NDArray,
                landmarks_enu: NDArray, max_cond: float = 1e8) -> tuple[NDArray, NDArray]:
    """Vision-only camera position from the landmarks' bearings (the patent's step 1), linear.

    With the attitude known (the reference), each detected landmark gives a world-frame
    bearing dᵢ, and the camera centre c is the point closest to every line
    ``pᵢ − t dᵢ``: ``(Σ Pᵢ) c = Σ Pᵢ pᵢ`` with ``Pᵢ = I − dᵢdᵢᵀ``. Needs two non-parallel
    bearings. Returns c (..., 3) (NaN where not solvable) and a solvable flag (...).
    """
    K = np.asarray(K, float)
    ones = np.ones(uv.shape[:-1] + (1,))
    b = np.einsum("ij,...j->...i", np.linalg.inv(K), np.concatenate([np.nan_to_num(uv), ones], -1))
    d = np.einsum("...ij,...lj->...li", R_cam_to_world, b)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    Pm = np.eye(3) - d[..., :, None] * d[..., None, :]
    Pm = np.where(detected[..., None, None], Pm, 0.0)
    A = Pm.sum(-3)
    rhs = np.einsum("...lij,...lj->...i", Pm, landmarks_enu).reshape(A.shape[:-1])
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = (detected.sum(-1) >= 2) & (np.linalg.cond(A) < max_cond)
    A_safe = np.where(ok[..., None, None], A, np.eye(3))
    c = np.linalg.solve(A_safe, rhs[..., None])[..., 0]
    return np.where(ok[..., None], c, np.nan), ok
