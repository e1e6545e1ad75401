"""Unsurveyed ground features as a feature tracker reports them (the Won et al. paper's monocular front end).

Points whose positions nobody surveyed (texture on the ground) are tracked from frame to frame and reported
with an identity that persists while the point stays in view (a KLT tracker's tracks; association is
perfect here). Unlike :mod:`.detect`'s landmarks, a scene holds thousands of them and a frame sees a few
dozen, so the record is compact: per epoch the ids in view (padded with −1) and their noisy pixels.

* **The scene** (:func:`corridor_features`): points uniform over the approach corridor (a swath about the
  planned ground track, continued past the path's end), on the terrain; fixed by the scene's own seed.
* **Which points** (:func:`features_in_view`): in the image (inside a margin), in front of the camera,
  within range and, with a terrain model, not masked by it; the ``max_tracks`` nearest. Decided on the
  camera's nominal pose (the airframe's truth and the mount), so every trial tracks the same points.
* **Where** (:func:`project`): the pinhole pixels under the camera's *true* pose — with the platform's
  dithering when the vision truth gives one, as the landmarks see it.
* **Noise**: white per axis, drawn per epoch from its own generator (:mod:`testbed.sensors.streams`), so a
  live flight's blocks draw what one pass draws (:func:`observe`); :func:`track_features` (the won-2013
  reproduction's one-pass form) draws time-major from one generator.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.frames import LocalFrame, q_to_R
from testbed.inertial import body_to_world
from testbed.records import FeatureTracks, Mount, Truth
from testbed.sensors.streams import epoch_generator

from .camera import PinholeCamera


def ground_features(n: int, east_m: tuple[float, float], north_m: tuple[float, float], rng: np.random.Generator,
                    up_m: float = 0.0) -> NDArray:
    """``n`` points (n, 3) uniform over a flat rectangle of the world frame at height ``up_m``."""
    if n < 1 or east_m[1] <= east_m[0] or north_m[1] <= north_m[0]:
        raise ValueError(f"ground_features: expected n ≥ 1 and non-empty ranges, got n = {n}, east {east_m}, "
                         f"north {north_m}")
    e = rng.uniform(*east_m, n)
    nn = rng.uniform(*north_m, n)
    return np.stack([e, nn, np.full(n, float(up_m))], -1)


def _corridor_axis(track_en: ArrayLike, beyond_m: float) -> NDArray:
    """The ground track (K, 2) without repeated points, continued straight for ``beyond_m``."""
    en = np.asarray(track_en, float)
    seg = np.diff(en, axis=0)
    keep = np.linalg.norm(seg, axis=-1) > 0
    if en.shape[0] < 2 or not keep.any():
        raise ValueError(f"corridor_features: expected a ground track of at least two distinct points, got {en.shape[0]}")
    en = np.concatenate([en[:1], en[1:][keep]])
    last = en[-1] - en[-2]
    return np.concatenate([en, en[-1:] + beyond_m * last / np.linalg.norm(last)])


def corridor_size(track_en: ArrayLike, settings) -> int:
    """How many points :func:`corridor_features` draws (before dropping those without a terrain height),
    computed without drawing them."""
    en = _corridor_axis(track_en, settings.beyond_m)
    area_km2 = np.cumsum(np.linalg.norm(np.diff(en, axis=0), axis=-1))[-1] * 2 * settings.half_width_m / 1e6
    return max(1, int(round(settings.density_per_km2 * area_km2)))


def corridor_features(track_en: ArrayLike, settings, frame: LocalFrame, terrain=None) -> NDArray:
    """The scene (n, 3), world frame: ``settings.density_per_km2`` points per km², uniform over the swath of
    half width ``settings.half_width_m`` about the ground track ``track_en`` (K, 2) continued straight for
    ``settings.beyond_m``, each on the terrain (flat at the frame's height without one; dropped where the
    model has no height). ``settings``: :class:`~.settings.FeatureSceneSettings`."""
    en = _corridor_axis(track_en, settings.beyond_m)
    seg = np.diff(en, axis=0)
    length = np.linalg.norm(seg, axis=-1)
    s_cum = np.concatenate([[0.0], np.cumsum(length)])
    n = corridor_size(track_en, settings)
    rng = np.random.default_rng(np.random.SeedSequence(settings.seed))
    s = rng.uniform(0.0, s_cum[-1], n)
    off = rng.uniform(-settings.half_width_m, settings.half_width_m, n)
    i = np.clip(np.searchsorted(s_cum, s, side="right") - 1, 0, seg.shape[0] - 1)
    along = seg[i] / length[i, None]
    left = np.stack([-along[:, 1], along[:, 0]], -1)
    xy = en[i] + (s - s_cum[i])[:, None] * along + off[:, None] * left
    lat, lon, _ = frame.enu_to_geodetic(np.column_stack([xy, np.zeros(n)]))
    h = np.full(n, frame.h) if terrain is None else np.asarray(terrain.height(lat, lon), float)
    ok = np.isfinite(h)
    return frame.geodetic_to_enu(lat[ok], lon[ok], h[ok])


def nominal_camera(truth: Truth, mount: Mount) -> tuple[NDArray, NDArray]:
    """The camera's position (T, 3) and camera → world rotation (T, 3, 3) on the airframe's true pose,
    without dithering."""
    frame = LocalFrame(*map(float, truth.frame_origin))
    p = np.asarray(truth.pos_enu, float)
    C = body_to_world(frame, p, np.asarray(truth.q_body_to_enu, float))
    return p + C @ np.asarray(mount.lever_arm_body, float), C @ mount.R_sensor_to_body


def features_in_view(cam_w: NDArray, R_cw: NDArray, camera: PinholeCamera, points_w: ArrayLike, *,
                     margin_px: float = 5.0, max_range_m: float = 200.0, min_depth_m: float = 1.0,
                     max_tracks: int | None = None, terrain=None, frame: LocalFrame | None = None,
                     chunk: int = 256) -> NDArray:
    """The points (ids (T, W), −1 padded, nearest first) a camera at ``cam_w`` (T, 3) with attitude ``R_cw``
    (T, 3, 3) sees: in the image, in front, within ``max_range_m``; with ``terrain`` (and the world
    ``frame``) not masked by it; at most ``max_tracks``."""
    m = np.asarray(points_w, float)
    K = camera.K
    ids = []
    for k0 in range(0, cam_w.shape[0], chunk):
        c, R = cam_w[k0:k0 + chunk], R_cw[k0:k0 + chunk]
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
            if terrain is not None and idx.size:
                idx = _unmasked(idx, c[row], m, terrain, frame, max_tracks)
            ids.append(idx[:max_tracks])
    W = max((i.size for i in ids), default=0)
    out = np.full((len(ids), W), -1, np.int64)
    for k, i in enumerate(ids):
        out[k, :i.size] = i
    return out


def _unmasked(idx: NDArray, c: NDArray, m: NDArray, terrain, frame: LocalFrame, keep: int | None) -> NDArray:
    """The points ``idx`` (nearest first) whose segment from the camera ``c`` clears the terrain, tested in
    batches from the nearest until ``keep`` are found (rays cost; the far ones are rarely needed)."""
    out, step = [], len(idx) if keep is None else 3 * keep
    for i in range(0, len(idx), step):
        part = idx[i:i + step]
        out.append(part[terrain.line_of_sight(frame.enu_to_ecef(c), frame.enu_to_ecef(m[part]), margin_m=5.0)])
        if keep is not None and sum(o.size for o in out) >= keep:
            break
    return np.concatenate(out)


def project(points_w: ArrayLike, ids: NDArray, cam_w: NDArray, R_cw: NDArray, K: NDArray) -> NDArray:
    """The pinhole pixels (B..., T, W, 2) of points ``ids`` (T, W) seen from ``cam_w`` (T, 3) with attitude
    ``R_cw`` (B..., T, 3, 3) (NaN on padding)."""
    m = np.asarray(points_w, float)[np.maximum(ids, 0)]  # (T, W, 3)
    d = m - cam_w[:, None]
    s = np.einsum("...tji,twj->...twi", R_cw, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (s @ K.T)[..., :2] / s[..., 2:3]
    return np.where((ids >= 0)[..., None], uv, np.nan)


def true_pixels(truth: Truth, camera: PinholeCamera, mount: Mount, points_w: ArrayLike, *, margin_px: float = 5.0,
                max_range_m: float = 200.0, min_depth_m: float = 1.0, chunk: int = 256) -> tuple[NDArray, NDArray]:
    """Which points each epoch of ``truth`` sees and where (the nominal camera): ids (T, W) (−1 padded,
    nearest first) and true pixels (T, W, 2)."""
    c, R = nominal_camera(truth, mount)
    ids = features_in_view(c, R, camera, points_w, margin_px=margin_px, max_range_m=max_range_m,
                           min_depth_m=min_depth_m, chunk=chunk)
    return ids, project(points_w, ids, c, R, camera.K)


def observe(t: NDArray, ids: NDArray, points_w: ArrayLike, cam_w: NDArray, R_cw: NDArray, camera: PinholeCamera,
            mount: Mount, sigma_px: float, seed_words: NDArray, first_epoch: int = 0, n_trials: int = 1
            ) -> FeatureTracks:
    """The tracker's report of points ``ids`` (T, W) at epochs ``t``: pixels under the camera's true pose
    (``R_cw`` (T, 3, 3) for one flight, (B, T, 3, 3) for B trials) plus white noise of 1σ ``sigma_px``, epoch
    k's from the stream ``seed_words`` at index ``first_epoch + k`` (blocks of a flight draw what one pass
    draws). Always batched: uv (B, T, W, 2), B = ``n_trials`` (a shared attitude serves them all)."""
    R = np.broadcast_to(R_cw, (n_trials,) + R_cw.shape[-3:]) if R_cw.ndim == 3 else R_cw
    uv = project(points_w, ids, cam_w, R, camera.K)
    for k in range(ids.shape[0]):
        w = int((ids[k] >= 0).sum())  # ids are packed: the tracked first, then padding
        if w:
            uv[:, k, :w] += sigma_px * epoch_generator(seed_words, first_epoch + k).standard_normal((R.shape[0], w, 2))
    return FeatureTracks(t=np.asarray(t, float), ids=ids, uv=uv, sigma_px=float(sigma_px), K=camera.K, camera=mount)


def camera_attitudes(frame: LocalFrame, q_cam_to_ecef: ArrayLike) -> NDArray:
    """Camera → world rotations (B..., T, 3, 3) from the vision truth's attitudes (with dithering)."""
    return frame.R @ q_to_R(np.asarray(q_cam_to_ecef, float))


def scene_ids(truth: Truth, camera: PinholeCamera, mount: Mount, points_w: ArrayLike, settings, terrain=None
              ) -> NDArray:
    """The points (T, W) the tracker follows along ``truth`` by the scene's rules (``settings``:
    :class:`~.settings.FeatureSceneSettings`): the nominal camera, masked by ``terrain``."""
    c, R = nominal_camera(truth, mount)
    return features_in_view(c, R, camera, points_w, margin_px=settings.margin_px, max_range_m=settings.max_range_m,
                            max_tracks=settings.max_tracks, terrain=terrain,
                            frame=LocalFrame(*map(float, truth.frame_origin)))


def scene_tracks(ids: NDArray, vision_truth, points_w: ArrayLike, frame: LocalFrame, camera: PinholeCamera,
                 mount: Mount, settings, seed_words: NDArray, first_epoch: int = 0, n_trials: int = 1
                 ) -> FeatureTracks:
    """The tracker's report of ``ids`` (T, W) at the epochs of ``vision_truth`` (a
    :class:`~.detect.VisionTruth` at the same epochs: the camera's true position and attitude, per trial)."""
    cam_w = frame.ecef_to_enu(np.asarray(vision_truth.cam_pos_ecef, float))
    return observe(vision_truth.t, ids, points_w, cam_w, camera_attitudes(frame, vision_truth.q_cam_to_ecef), camera,
                   mount, settings.sigma_px, seed_words, first_epoch, n_trials)


def track_features(truth: Truth, camera: PinholeCamera, mount: Mount, points_w: ArrayLike, sigma_px: float,
                   rng: np.random.Generator, n_trials: int, *, margin_px: float = 5.0, max_range_m: float = 200.0
                   ) -> FeatureTracks:
    """The tracker's output for ``n_trials`` trials along the shared ``truth`` (at the vision epochs), the
    nominal camera, noise time-major from ``rng`` (one pass over a whole run)."""
    if sigma_px < 0 or n_trials < 1:
        raise ValueError(f"track_features: expected sigma_px ≥ 0 and n_trials ≥ 1, got {sigma_px}, {n_trials}")
    ids, uv = true_pixels(truth, camera, mount, points_w, margin_px=margin_px, max_range_m=max_range_m)
    noise = rng.standard_normal((ids.shape[0], n_trials) + ids.shape[1:] + (2,)) * sigma_px  # time-major
    uv = uv[:, None] + noise
    uv[np.broadcast_to((ids < 0)[:, None, :, None], uv.shape)] = np.nan
    return FeatureTracks(t=np.asarray(truth.t, float), ids=ids, uv=np.moveaxis(uv, 1, 0), sigma_px=float(sigma_px),
                         K=camera.K, camera=mount)


__all__ = ["FeatureTracks", "camera_attitudes", "corridor_features", "corridor_size", "features_in_view", "ground_features",
           "nominal_camera", "observe", "project", "scene_ids", "scene_tracks", "track_features", "true_pixels"]
