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


def clip_to_rect(p0: np.ndarray, p1: np.ndarray, w: float, h: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The part of segment ``p0 p1`` (pixels) inside ``[0, w] x [0, h]`` (Liang-Barsky), or None."""
    d = p1 - p0
    t0, t1 = 0.0, 1.0
    for p, q in ((-d[0], p0[0]), (d[0], w - p0[0]), (-d[1], p0[1]), (d[1], h - p0[1])):
        if p == 0.0:
            if q < 0.0:
                return None
            continue
        r = q / p
        if p < 0.0:
            t0 = max(t0, r)
        else:
            t1 = min(t1, r)
        if t0 > t1:
            return None
    return p0 + t0 * d, p0 + t1 * d


def clip_to_front(A: np.ndarray, B: np.ndarray, near: float = NEAR_M) -> tuple[np.ndarray, np.ndarray] | None:
    """The part of camera-frame segment ``A B`` at depth >= ``near``, or None."""
    za, zb = A[2], B[2]
    if za < near and zb < near:
        return None
    if za < near:
        A = A + (near - za) / (zb - za) * (B - A)
    elif zb < near:
        B = B + (near - zb) / (za - zb) * (A - B)
    return A, B


def image_segments(K, w: float, h: float, edges_c: np.ndarray) -> np.ndarray:
    """The visible parts ``(n, 2, 2)`` px of camera-frame segments ``(m, 2, 3)``: in front, then in the image."""
    out = []
    for A, B in edges_c:
        front = clip_to_front(A, B)
        if front is None:
            continue
        seg = clip_to_rect(*project(K, np.stack(front)), w, h)
        if seg is not None and np.linalg.norm(seg[1] - seg[0]) > 0.0:
            out.append(seg)
    return np.array(out, float).reshape(-1, 2, 2)


def horizon(K, w: float, h: float, R_c2w: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """The level line in the image (a head-up display's horizon), ``(n, 2, 2)`` px with n = 0 or 1:
    the vanishing line of the level plane (directions ``d`` with ``d · up = 0``), clipped to the
    image. A sea-level horizon would lie lower by the dip, ~1° at 1 km height (~36 px at f = 2060
    px); in a valley the skyline is the terrain, higher."""
    n = np.asarray(R_c2w, float).T @ np.asarray(up, float)  # up in camera axes
    fwd = np.array([0.0, 0.0, 1.0]) - n[2] * n  # the optical axis made level
    if np.linalg.norm(fwd) < 1e-6 or fwd[2] <= 1e-9:  # looking straight up or down: no horizon in view
        return np.zeros((0, 2, 2))
    fwd /= np.linalg.norm(fwd)
    side = np.cross(n, fwd)  # level and across the optical axis: its depth is 0
    p0, p1 = project(K, np.stack([fwd - side, fwd + side]))  # two level directions in front
    d = p1 - p0
    span = 4.0 * (w + h) / max(np.linalg.norm(d), 1e-9)  # long enough to cross the whole image
    seg = clip_to_rect(p0 - span * d, p0 + span * d, w, h)
    return np.zeros((0, 2, 2)) if seg is None else np.array([seg])


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
