"""Unsurveyed ground features as a feature tracker reports them (seed 002's monocular front end).

Points whose positions nobody surveyed (texture on the ground) are tracked from frame to frame and reported
with an identity that persists while the point stays in view (a KLT tracker's tracks; association is
perfect here). Unlike :mod:`.detect`'s landmarks, a scene holds thousands of them and a frame sees a few
dozen, so the record is compact: per epoch the ids in view (padded with −1) and their noisy pixels.

The geometry (which points are in view, their true pixels) is the truth's; the pixel noise is drawn
time-major, so the first k epochs of a trial never depend on later ones (prefix stable, as the other
sensors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.frames import LocalFrame
from testbed.inertial import body_to_world
from testbed.records import Mount, Truth

from .camera import PinholeCamera


@dataclass(frozen=True)
class FeatureTracks:
    """Tracked unsurveyed features at the vision epochs.

    t : (T,) s.  ids : (T, W) int, the features in view (−1: padding), the same for every trial.
    uv : (B, T, W, 2) px, reported pixels (NaN on padding).  sigma_px : the pixel noise 1σ per axis.
    K : (3, 3) intrinsics.  camera : the mount (lever arm, R_cam_to_body).
    """

    t: NDArray
    ids: NDArray
    uv: NDArray
    sigma_px: float
    K: NDArray
    camera: Mount


def ground_features(n: int, east_m: tuple[float, float], north_m: tuple[float, float], rng: np.random.Generator,
                    up_m: float = 0.0) -> NDArray:
    """``n`` points (n, 3) uniform over a flat rectangle of the world frame at height ``up_m``."""
    if n < 1 or east_m[1] <= east_m[0] or north_m[1] <= north_m[0]:
        raise ValueError(f"ground_features: expected n ≥ 1 and non-empty ranges, got n = {n}, east {east_m}, "
                         f"north {north_m}")
    e = rng.uniform(*east_m, n)
    nn = rng.uniform(*north_m, n)
    return np.stack([e, nn, np.full(n, float(up_m))], -1)


def true_pixels(truth: Truth, camera: PinholeCamera, mount: Mount, points_w: ArrayLike, *, margin_px: float = 5.0,
                max_range_m: float = 200.0, min_depth_m: float = 1.0, chunk: int = 256) -> tuple[NDArray, NDArray]:
    """Which points each epoch of ``truth`` sees and where: ids (T, W) (−1 padded, nearest first) and
    true pixels (T, W, 2)."""
    frame = LocalFrame(*map(float, truth.frame_origin))
    m = np.asarray(points_w, float)
    p = np.asarray(truth.pos_enu, float)
    C = body_to_world(frame, p, np.asarray(truth.q_body_to_enu, float))
    K = camera.K
    ids, uvs = [], []
    for k0 in range(0, p.shape[0], chunk):
        Ck, pk = C[k0:k0 + chunk], p[k0:k0 + chunk]
        c = pk + Ck @ np.asarray(mount.lever_arm_body, float)
        R = Ck @ mount.R_sensor_to_body  # camera → world
        d = m[None] - c[:, None]  # (t, L, 3)
        s = np.einsum("tji,tlj->tli", R, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (s @ K.T)[..., :2] / s[..., 2:3]
        rng_m = np.linalg.norm(d, axis=-1)
        seen = ((s[..., 2] > min_depth_m) & (rng_m <= max_range_m)
                & (uv[..., 0] >= margin_px) & (uv[..., 0] <= camera.width_px - 1 - margin_px)
                & (uv[..., 1] >= margin_px) & (uv[..., 1] <= camera.height_px - 1 - margin_px))
        for row in range(seen.shape[0]):
            idx = np.flatnonzero(seen[row])
            idx = idx[np.argsort(rng_m[row, idx], kind="stable")]
            ids.append(idx)
            uvs.append(uv[row, idx])
    W = max((i.size for i in ids), default=0)
    out_id = np.full((len(ids), W), -1, np.int64)
    out_uv = np.full((len(ids), W, 2), np.nan)
    for k, (i, u) in enumerate(zip(ids, uvs)):
        out_id[k, :i.size], out_uv[k, :i.size] = i, u
    return out_id, out_uv


def track_features(truth: Truth, camera: PinholeCamera, mount: Mount, points_w: ArrayLike, sigma_px: float,
                   rng: np.random.Generator, n_trials: int, *, margin_px: float = 5.0, max_range_m: float = 200.0
                   ) -> FeatureTracks:
    """The tracker's output for ``n_trials`` trials along the shared ``truth`` (at the vision epochs)."""
    if sigma_px < 0 or n_trials < 1:
        raise ValueError(f"track_features: expected sigma_px ≥ 0 and n_trials ≥ 1, got {sigma_px}, {n_trials}")
    ids, uv = true_pixels(truth, camera, mount, points_w, margin_px=margin_px, max_range_m=max_range_m)
    noise = rng.standard_normal((ids.shape[0], n_trials) + ids.shape[1:] + (2,)) * sigma_px  # time-major
    uv = uv[:, None] + noise
    uv[np.broadcast_to((ids < 0)[:, None, :, None], uv.shape)] = np.nan
    return FeatureTracks(t=np.asarray(truth.t, float), ids=ids, uv=np.moveaxis(uv, 1, 0), sigma_px=float(sigma_px),
                         K=camera.K, camera=mount)
