"""Pinhole camera with optional Brown–Conrady distortion, and the camera presets.

Camera axes are OpenCV's: x right, y down, z forward (along the optical axis).
Pixel coordinates ``(u, v)``: u along image columns (right), v along rows
(down), pixel *centres* at integers, 0-based, so a ``W × H`` image spans
``[-0.5, W - 0.5] × [-0.5, H - 0.5]`` and its centre is ``((W-1)/2, (H-1)/2)``.

Intrinsics::

    K = [[fx, 0, cx],
         [0, fy, cy],
         [0,  0,  1]]        [u, v, 1]ᵀ ∝ K · p_cam   (ideal pinhole)

Distortion (optional, Brown–Conrady, OpenCV's k1, k2, p1, p2) maps ideal
normalised image coordinates ``(x, y) = (X/Z, Y/Z)`` to the distorted ones the
sensor records::

    r² = x² + y²
    x_d = x (1 + k1 r² + k2 r⁴) + 2 p1 x y + p2 (r² + 2 x²)
    y_d = y (1 + k1 r² + k2 r⁴) + p1 (r² + 2 y²) + 2 p2 x y

The vision-integrity patent writes the pixel → camera map as ``T_pix^c`` with a
camera frame x up, y right, z forward and 1-based pixel indices;
:func:`patent_T_pix_to_c` gives that matrix for a camera here, and the tests
show it is the same map as ``K⁻¹`` up to the axis relabelling. The testbed uses
``K`` (OpenCV axes) throughout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

MM_PER_INCH = 25.4

#: Assumptions of the ``va-raim-2015`` preset (the VA-RAIM paper §3.1.2 gives only the dpi).
VA_RAIM_FOCAL_MM = 35.0
VA_RAIM_SENSOR_MM = (36.0, 24.0)  # width, height: a "full-frame" 3:2 sensor
VA_RAIM_DPI = (120, 300, 480, 720)

#: Default approach camera: 1920 × 1080, 50° horizontal field of view.
APPROACH_SIZE_PX = (1920, 1080)
APPROACH_HFOV_DEG = 50.0


def _check_last(x: NDArray, n: int, name: str) -> None:
    if x.shape[-1:] != (n,):
        raise ValueError(f"{name}: expected shape (..., {n}), got {x.shape}")


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera: image size, intrinsics and Brown–Conrady distortion.

    Attributes
    ----------
    width_px, height_px : image size in pixels (columns, rows).
    fx, fy : focal lengths in pixels.  cx, cy : principal point, px (0-based).
    k1, k2 : radial distortion coefficients.  p1, p2 : tangential coefficients.
    name : a label (preset name) for logs and plots.
    """

    width_px: int
    height_px: int
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    name: str = "custom"

    def __post_init__(self) -> None:
        if int(self.width_px) < 1 or int(self.height_px) < 1:
            raise ValueError(f"camera size: expected width_px, height_px >= 1, got "
                             f"{self.width_px} x {self.height_px}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"camera focal length: expected fx, fy > 0 px, got {self.fx}, {self.fy}")

    # -- constructors -----------------------------------------------------
    @classmethod
    def from_fov(cls, width_px: int, height_px: int, hfov_deg: float, **kw) -> "PinholeCamera":
        """Square pixels, principal point at the image centre, given horizontal FOV (deg)."""
        if not 0.0 < hfov_deg < 180.0:
            raise ValueError(f"hfov_deg: expected in (0, 180), got {hfov_deg}")
        f = (width_px / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
        return cls.from_focal_px(width_px, height_px, f, **kw)

    @classmethod
    def from_focal_px(cls, width_px: int, height_px: int, focal_px: float, **kw) -> "PinholeCamera":
        """Square pixels, principal point at the image centre, focal length in pixels."""
        return cls(int(width_px), int(height_px), float(focal_px), float(focal_px),
                   (width_px - 1) / 2.0, (height_px - 1) / 2.0, **kw)

    @classmethod
    def from_dpi(cls, dpi: float, focal_mm: float, sensor_width_mm: float, sensor_height_mm: float,
                 **kw) -> "PinholeCamera":
        """The VA-RAIM paper's form: resolution in dots per inch on a sensor of stated size.

        Pixel pitch = 25.4 mm / dpi; pixel counts = sensor size / pitch
        (rounded); focal length in px = focal_mm / pitch.
        """
        for nm, val in (("dpi", dpi), ("focal_mm", focal_mm), ("sensor_width_mm", sensor_width_mm),
                        ("sensor_height_mm", sensor_height_mm)):
            if not val > 0:
                raise ValueError(f"{nm}: expected > 0, got {val}")
        pitch_mm = MM_PER_INCH / dpi
        w = int(round(sensor_width_mm / pitch_mm))
        h = int(round(sensor_height_mm / pitch_mm))
        return cls.from_focal_px(w, h, focal_mm / pitch_mm, **kw)

    # -- derived quantities -----------------------------------------------
    @property
    def K(self) -> NDArray:
        """Intrinsic matrix ``(3, 3)``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view (deg) of the undistorted image, centred principal point."""
        return float(np.degrees(np.arctan((self.cx + 0.5) / self.fx) + np.arctan((self.width_px - 0.5 - self.cx) / self.fx)))

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view (deg)."""
        return float(np.degrees(np.arctan((self.cy + 0.5) / self.fy) + np.arctan((self.height_px - 0.5 - self.cy) / self.fy)))

    @property
    def has_distortion(self) -> bool:
        return any(c != 0.0 for c in (self.k1, self.k2, self.p1, self.p2))

    def with_distortion(self, k1: float = 0.0, k2: float = 0.0, p1: float = 0.0, p2: float = 0.0) -> "PinholeCamera":
        """A copy with the given distortion coefficients."""
        return PinholeCamera(self.width_px, self.height_px, self.fx, self.fy, self.cx, self.cy,
                             k1, k2, p1, p2, self.name)

    # -- pinhole maps -----------------------------------------------------
    def project(self, p_cam: ArrayLike, *, min_depth: float = 1e-6) -> tuple[NDArray, NDArray]:
        """Ideal (undistorted) pixel of points in the camera frame.

        Parameters
        ----------
        p_cam : (..., 3) m, points in camera axes (x right, y down, z forward).
        min_depth : points with z ≤ this are "behind" the camera.

        Returns
        -------
        uv : (..., 2) px, NaN for points behind the camera.
        in_front : (...,) bool.
        """
        p = np.asarray(p_cam, float)
        _check_last(p, 3, "p_cam")
        z = p[..., 2]
        in_front = z > min_depth
        zs = np.where(in_front, z, np.nan)
        u = self.fx * p[..., 0] / zs + self.cx
        v = self.fy * p[..., 1] / zs + self.cy
        return np.stack([u, v], axis=-1), in_front

    def unproject(self, uv: ArrayLike) -> NDArray:
        """Unit bearing vectors ``(..., 3)`` (camera axes) of ideal pixels ``(..., 2)``: normalise(K⁻¹[u, v, 1])."""
        uv = np.asarray(uv, float)
        _check_last(uv, 2, "uv")
        x = (uv[..., 0] - self.cx) / self.fx
        y = (uv[..., 1] - self.cy) / self.fy
        b = np.stack([x, y, np.ones_like(x)], axis=-1)
        return b / np.linalg.norm(b, axis=-1, keepdims=True)

    # -- distortion -------------------------------------------------------
    def _distort_norm(self, x: NDArray, y: NDArray) -> tuple[NDArray, NDArray]:
        r2 = x * x + y * y
        radial = 1.0 + self.k1 * r2 + self.k2 * r2 * r2
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return xd, yd

    def distort(self, uv_ideal: ArrayLike) -> NDArray:
        """Ideal pinhole pixels ``(..., 2)`` → distorted pixels the sensor records ``(..., 2)``."""
        uv = np.asarray(uv_ideal, float)
        _check_last(uv, 2, "uv_ideal")
        if not self.has_distortion:
            return uv.copy()
        x = (uv[..., 0] - self.cx) / self.fx
        y = (uv[..., 1] - self.cy) / self.fy
        xd, yd = self._distort_norm(x, y)
        return np.stack([self.fx * xd + self.cx, self.fy * yd + self.cy], axis=-1)

    def undistort(self, uv_distorted: ArrayLike, *, iterations: int = 30, tol_px: float = 1e-9) -> NDArray:
        """Distorted pixels ``(..., 2)`` → ideal pinhole pixels ``(..., 2)``.

        Batched Newton iteration on the normalised coordinates with the analytic
        2×2 Jacobian of the distortion map; elements that do not converge
        (outside the map's invertible region) come back NaN.
        """
        uv = np.asarray(uv_distorted, float)
        _check_last(uv, 2, "uv_distorted")
        if not self.has_distortion:
            return uv.copy()
        xd = (uv[..., 0] - self.cx) / self.fx
        yd = (uv[..., 1] - self.cy) / self.fy
        x, y = xd.copy(), yd.copy()
        k1, k2, p1, p2 = self.k1, self.k2, self.p1, self.p2
        for _ in range(iterations):
            fx_, fy_ = self._distort_norm(x, y)
            ex, ey = fx_ - xd, fy_ - yd
            r2 = x * x + y * y
            radial = 1.0 + k1 * r2 + k2 * r2 * r2
            drad = 2.0 * k1 + 4.0 * k2 * r2  # d(radial)/d(r2) * 2
            # Jacobian of (x_d, y_d) with respect to (x, y)
            a = radial + x * drad * x + 2.0 * p1 * y + 6.0 * p2 * x
            b = x * drad * y + 2.0 * p1 * x + 2.0 * p2 * y
            c = y * drad * x + 2.0 * p1 * x + 2.0 * p2 * y
            d = radial + y * drad * y + 6.0 * p1 * y + 2.0 * p2 * x
            det = a * d - b * c
            x = x - (d * ex - b * ey) / det
            y = y - (-c * ex + a * ey) / det
        fx_, fy_ = self._distort_norm(x, y)
        bad = np.hypot(fx_ - xd, fy_ - yd) * max(self.fx, self.fy) > 1e3 * tol_px + 1e-6
        bad |= ~np.isfinite(x) | ~np.isfinite(y)
        out = np.stack([self.fx * x + self.cx, self.fy * y + self.cy], axis=-1)
        out[bad] = np.nan
        return out

    # -- image bounds -----------------------------------------------------
    def in_image(self, uv: ArrayLike, margin_px: float = 0.0) -> NDArray:
        """True where pixels ``(..., 2)`` lie at least ``margin_px`` inside the image border."""
        uv = np.asarray(uv, float)
        _check_last(uv, 2, "uv")
        u, v = uv[..., 0], uv[..., 1]
        with np.errstate(invalid="ignore"):
            return ((u >= -0.5 + margin_px) & (u <= self.width_px - 0.5 - margin_px)
                    & (v >= -0.5 + margin_px) & (v <= self.height_px - 0.5 - margin_px))


def patent_T_pix_to_c(camera: PinholeCamera) -> NDArray:
    """The vision-integrity patent's ``T_pix^c`` ``(3, 3)`` for ``camera`` (patent eq. before the linearisation).

    The patent writes, for an ``M × N`` pixel grid (M rows, N columns) of
    physical height H and width W and focal length f::

        T_pix^c = [[-H/(fM), 0,      H(M+1)/(2fM)],
                   [0,       W/(fN), -W(N+1)/(2fN)],
                   [0,       0,      1]]

    acting on ``[m, n, 1]`` with 1-based row m and column n, giving a camera
    frame x up, y right, z forward (normalised to z = 1). Pixel pitch over
    focal length H/(fM) is 1/fy in pixels here. The patent assumes the
    principal point at the image centre; so does this function's output,
    whatever ``cx, cy`` are (the two agree for the presets).
    """
    M, N = camera.height_px, camera.width_px
    return np.array([[-1.0 / camera.fy, 0.0, (M + 1) / (2.0 * camera.fy)],
                     [0.0, 1.0 / camera.fx, -(N + 1) / (2.0 * camera.fx)],
                     [0.0, 0.0, 1.0]])


def va_raim_2015_camera(dpi: float, *, focal_mm: float = VA_RAIM_FOCAL_MM,
                        sensor_mm: tuple[float, float] = VA_RAIM_SENSOR_MM) -> PinholeCamera:
    """The camera of the VA-RAIM paper (its §3.1.2), at ``dpi`` dots per inch.

    The paper states only the resolutions (120, 300, 480, 720 dpi). Assumed
    here (a testbed choice): a 35 mm lens on a 36 × 24 mm sensor, so
    pixel pitch = 25.4 mm / dpi and (HFOV 54.4°, VFOV 37.8° at every dpi):

    ====  ==========  ===========  ============
    dpi   pitch (µm)  pixels       focal (px)
    ====  ==========  ===========  ============
    120   211.7       170 × 113    165.4
    300   84.7        425 × 283    413.4
    480   52.9        680 × 454    661.4
    720   35.3        1020 × 680   992.1
    ====  ==========  ===========  ============

    One pixel then subtends 6.05, 2.42, 1.51 and 1.01 mrad at the centre.
    """
    cam = PinholeCamera.from_dpi(dpi, focal_mm, sensor_mm[0], sensor_mm[1])
    return PinholeCamera(cam.width_px, cam.height_px, cam.fx, cam.fy, cam.cx, cam.cy,
                         name=f"va-raim-2015@{dpi:g}dpi")


def approach_camera(width_px: int = APPROACH_SIZE_PX[0], height_px: int = APPROACH_SIZE_PX[1],
                    hfov_deg: float = APPROACH_HFOV_DEG) -> PinholeCamera:
    """The default approach camera: 1920 × 1080 px, 50° HFOV (f ≈ 2058.8 px, VFOV ≈ 29.4°).

    Sized like common cockpit footage (docs/design/physics-notes.md §camera-references).
    """
    cam = PinholeCamera.from_fov(width_px, height_px, hfov_deg)
    return PinholeCamera(cam.width_px, cam.height_px, cam.fx, cam.fy, cam.cx, cam.cy, name="approach-1080p")
