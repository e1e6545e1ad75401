"""What the camera view draws over the image: pure geometry, no Rerun.

Camera coordinates are RDF (x right, y down, z forward), pixels ``u`` right and ``v``
down from the image's top-left corner; ``R_c2w`` rotates camera axes into the world
(ENU) frame. Segments are clipped against the near plane before they are projected
(an edge of the runway behind the camera has no image) and against the image after.
"""

from __future__ import annotations

import numpy as np

#: the nearest depth drawn, m (a point closer than this is behind the camera for drawing)
NEAR_M = 1.0
#: the screen size of a label, as a fraction of the image's width and height: in the layout's
#: camera panel a 1920 x 1080 image is drawn ~640 px wide (an 1800 px window), where a 6-letter
#: label is ~70 x 20 px, ~210 x 60 image px
LABEL_BOX = (0.12, 0.06)


def to_camera(X_world: np.ndarray, cam_enu: np.ndarray, R_c2w: np.ndarray) -> np.ndarray:
    """World points ``(..., 3)`` in camera coordinates: ``R_c2wᵀ (X - c)``."""
    return (np.asarray(X_world, float) - cam_enu) @ R_c2w


def project(K: np.ndarray, Xc: np.ndarray) -> np.ndarray:
    """Pixels ``(..., 2)`` of camera-frame points ``(..., 3)`` (in front of the camera)."""
    x = Xc @ np.asarray(K, float).T
    return x[..., :2] / x[..., 2:3]


def clip_to_rect_batch(p0: np.ndarray, p1: np.ndarray, w: float, h: float) -> tuple[np.ndarray, np.ndarray]:
    """The parts of segments ``p0 p1`` (``(..., 2)`` px) inside ``[0, w] x [0, h]`` (Liang-Barsky):
    ``(ends (..., 2, 2), ok (...))``, ``ok`` False where nothing is inside."""
    d = p1 - p0
    P = np.stack([-d[..., 0], d[..., 0], -d[..., 1], d[..., 1]], -1)
    Q = np.stack([p0[..., 0], w - p0[..., 0], p0[..., 1], h - p0[..., 1]], -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = Q / P
    t0 = np.max(np.where(P < 0, r, 0.0), axis=-1)
    t1 = np.min(np.where(P > 0, r, 1.0), axis=-1)
    parallel_out = np.any((P == 0) & (Q < 0), axis=-1)
    ok = ~parallel_out & (t0 <= t1)
    ends = np.stack([p0 + t0[..., None] * d, p0 + t1[..., None] * d], -2)
    return ends, ok


def clip_to_rect(p0: np.ndarray, p1: np.ndarray, w: float, h: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The part of segment ``p0 p1`` (pixels) inside ``[0, w] x [0, h]``, or None."""
    ends, ok = clip_to_rect_batch(np.asarray(p0, float), np.asarray(p1, float), w, h)
    return (ends[0], ends[1]) if ok else None


def segments_in_image(K, w: float, h: float, edges_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The visible parts of camera-frame segments ``(..., 2, 3)``: cut to depth >= :data:`NEAR_M`,
    projected, cut to the image. ``(ends (..., 2, 2) px, ok (...))``."""
    A, B = edges_c[..., 0, :], edges_c[..., 1, :]
    za, zb = A[..., 2:3], B[..., 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        A2 = np.where(za < NEAR_M, A + (NEAR_M - za) / (zb - za) * (B - A), A)
        B2 = np.where(zb < NEAR_M, B + (NEAR_M - zb) / (za - zb) * (A - B), B)
        front = ~((za < NEAR_M) & (zb < NEAR_M))[..., 0]
        a, b = project(K, np.where(front[..., None], A2, 1.0)), project(K, np.where(front[..., None], B2, 1.0))
    ends, ok = clip_to_rect_batch(a, b, w, h)
    ok &= front & (np.linalg.norm(ends[..., 1, :] - ends[..., 0, :], axis=-1) > 0.0)
    return ends, ok


def image_segments(K, w: float, h: float, edges_c: np.ndarray) -> np.ndarray:
    """The visible parts ``(n, 2, 2)`` px of camera-frame segments ``(m, 2, 3)``: in front, then in the image."""
    ends, ok = segments_in_image(K, w, h, np.asarray(edges_c, float).reshape(-1, 2, 3))
    return ends[ok]


def level_line(K, w: float, h: float, R_c2w: np.ndarray, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """The level line in the image (a head-up display's horizon) for camera attitudes ``(..., 3, 3)``:
    the vanishing line of the level plane (directions ``d`` with ``d · up = 0``), clipped to the
    image; ``(ends (..., 2, 2) px, ok (...))``. A sea-level horizon would lie lower by the dip, ~1°
    at 1 km height (~36 px at f = 2060 px); in a valley the skyline is the terrain, higher."""
    n = np.einsum("...ji,j->...i", np.asarray(R_c2w, float), np.asarray(up, float))  # up in camera axes
    fwd = np.array([0.0, 0.0, 1.0]) - n[..., 2:3] * n  # the optical axis made level
    norm = np.linalg.norm(fwd, axis=-1, keepdims=True)
    seen = (norm[..., 0] > 1e-6) & (fwd[..., 2] > 1e-9)  # else looking straight up or down
    fwd = fwd / np.where(norm > 0, norm, 1.0)
    side = np.cross(n, fwd)  # level and across the optical axis: its depth is 0
    fwd = np.where(seen[..., None], fwd, [0.0, 0.0, 1.0])
    p0, p1 = project(K, fwd - side), project(K, fwd + side)  # two level directions in front
    d = p1 - p0
    span = 4.0 * (w + h) / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)  # across the image
    ends, ok = clip_to_rect_batch(p0 - span * d, p0 + span * d, w, h)
    return ends, ok & seen


def horizon(K, w: float, h: float, R_c2w: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """The level line of one camera attitude, ``(n, 2, 2)`` px with n = 0 or 1 (see :func:`level_line`)."""
    ends, ok = level_line(K, w, h, np.asarray(R_c2w, float)[None], up)
    return ends[ok]


def declutter(uv: np.ndarray, box: tuple[float, float], order=None) -> np.ndarray:
    """Which of the labels at pixels ``uv`` ``(n, 2)`` to draw so that no two overlap: greedy in
    ``order`` (default: as given), a label is kept when its ``box`` (w, h px, centred on its point)
    overlaps no kept one. Returns a boolean mask."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    keep = np.zeros(len(uv), bool)
    bw, bh = box
    for i in (range(len(uv)) if order is None else order):
        k = np.flatnonzero(keep)
        if not np.any((np.abs(uv[k, 0] - uv[i, 0]) < bw) & (np.abs(uv[k, 1] - uv[i, 1]) < bh)):
            keep[i] = True
    return keep
