"""Frames and rotations: WGS84 geodetic, ECEF, local ENU/NED, body, camera.

Conventions (used everywhere in the testbed):

* SI units inside: metres, seconds, radians unless a name ends in ``_deg``.
* Batch axes first, components last: positions ``(..., 3)``, quaternions
  ``(..., 4)`` scalar-last ``[x, y, z, w]`` (scipy's convention).
* Heights are WGS84 ellipsoidal (JSBSim has no geoid; neither do we).
* Body axes are JSBSim's: x forward, y right wing, z down (FRD).
* ``R_a_to_b`` maps a vector's components in frame *a* to frame *b*:
  ``v_b = R_a_to_b @ v_a``.

Geodetic conversions delegate to pymap3d (well tested, vectorised); the local
rotation matrices are written out because they are needed batched and as
matrices, which pymap3d does not expose.
"""

from __future__ import annotations

import numpy as np
import pymap3d
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

WGS84 = pymap3d.Ellipsoid.from_name("wgs84")
#: Earth rotation rate used by GPS (IS-GPS-200), rad/s.
OMEGA_EARTH = 7.2921151467e-5
#: Speed of light (IS-GPS-200), m/s.
C_LIGHT = 299_792_458.0

FT = 0.3048  # metres per foot (exact)
KT = 1852.0 / 3600.0  # metres per second per knot (exact)
DEG_PER_H = np.pi / 180.0 / 3600.0  # rad/s per degree per hour (a gyro's bias unit)

# NED <-> ENU component swap; it is its own inverse.
R_NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def _check_last(x: NDArray, n: int, name: str) -> None:
    if x.shape[-1:] != (n,):
        raise ValueError(f"{name}: expected shape (..., {n}), got {x.shape}")


def geodetic_to_ecef(lat_deg: ArrayLike, lon_deg: ArrayLike, h: ArrayLike) -> NDArray:
    """Geodetic (deg, deg, m ellipsoidal) to ECEF, shape ``(..., 3)`` in metres."""
    x, y, z = pymap3d.geodetic2ecef(np.asarray(lat_deg, float), np.asarray(lon_deg, float),
                                    np.asarray(h, float), ell=WGS84, deg=True)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(pos_ecef: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
    """ECEF ``(..., 3)`` to ``(lat_deg, lon_deg, h)`` each ``(...)``."""
    p = np.asarray(pos_ecef, float)
    _check_last(p, 3, "pos_ecef")
    lat, lon, h = pymap3d.ecef2geodetic(p[..., 0], p[..., 1], p[..., 2], ell=WGS84, deg=True)
    return np.asarray(lat), np.asarray(lon), np.asarray(h)


def R_ecef_to_enu(lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray:
    """Rotation matrices ECEF -> local ENU at geodetic (lat, lon); shape ``(..., 3, 3)``."""
    lat = np.radians(np.asarray(lat_deg, float))
    lon = np.radians(np.asarray(lon_deg, float))
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    z = np.zeros_like(sl + so)
    return np.stack(
        [
            np.stack([-so + z, co + z, z], axis=-1),
            np.stack([-sl * co, -sl * so, cl + z], axis=-1),
            np.stack([cl * co, cl * so, sl + z], axis=-1),
        ],
        axis=-2,
    )


class LocalFrame:
    """A local ENU tangent frame anchored at a geodetic origin.

    The testbed's world frame for an approach (Rerun's ``world/``, monitors'
    state vector) is one of these, anchored at the approach's reference point.
    """

    def __init__(self, lat_deg: float, lon_deg: float, h: float) -> None:
        self.lat_deg, self.lon_deg, self.h = float(lat_deg), float(lon_deg), float(h)
        self.origin_ecef = geodetic_to_ecef(lat_deg, lon_deg, h)
        self.R = R_ecef_to_enu(lat_deg, lon_deg)  # ECEF -> ENU

    def __repr__(self) -> str:
        return f"LocalFrame(lat_deg={self.lat_deg:.7f}, lon_deg={self.lon_deg:.7f}, h={self.h:.2f})"

    def ecef_to_enu(self, pos_ecef: ArrayLike) -> NDArray:
        """ECEF positions ``(..., 3)`` to local ENU ``(..., 3)``."""
        p = np.asarray(pos_ecef, float)
        _check_last(p, 3, "pos_ecef")
        return (p - self.origin_ecef) @ self.R.T

    def enu_to_ecef(self, pos_enu: ArrayLike) -> NDArray:
        """Local ENU positions ``(..., 3)`` to ECEF ``(..., 3)``."""
        p = np.asarray(pos_enu, float)
        _check_last(p, 3, "pos_enu")
        return p @ self.R + self.origin_ecef

    def vec_ecef_to_enu(self, v_ecef: ArrayLike) -> NDArray:
        """Rotate (not translate) vectors ``(..., 3)`` from ECEF to this ENU frame."""
        return np.asarray(v_ecef, float) @ self.R.T

    def vec_enu_to_ecef(self, v_enu: ArrayLike) -> NDArray:
        """Rotate (not translate) vectors ``(..., 3)`` from this ENU frame to ECEF."""
        return np.asarray(v_enu, float) @ self.R

    def geodetic_to_enu(self, lat_deg: ArrayLike, lon_deg: ArrayLike, h: ArrayLike) -> NDArray:
        return self.ecef_to_enu(geodetic_to_ecef(lat_deg, lon_deg, h))

    def enu_to_geodetic(self, pos_enu: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
        return ecef_to_geodetic(self.enu_to_ecef(pos_enu))


def euler_to_R_body_to_ned(phi: ArrayLike, theta: ArrayLike, psi: ArrayLike) -> NDArray:
    """Aerospace 3-2-1 Euler angles (roll, pitch, heading; rad) to body->NED ``(..., 3, 3)``."""
    angles = np.stack(np.broadcast_arrays(np.asarray(psi, float), np.asarray(theta, float),
                                          np.asarray(phi, float)), axis=-1)
    flat = Rotation.from_euler("ZYX", angles.reshape(-1, 3))
    return flat.as_matrix().reshape(angles.shape[:-1] + (3, 3))


def euler_to_q_body_to_enu(phi: ArrayLike, theta: ArrayLike, psi: ArrayLike) -> NDArray:
    """Euler angles (rad) to the body->ENU quaternion ``(..., 4)``, scalar last."""
    R = R_NED_TO_ENU @ euler_to_R_body_to_ned(phi, theta, psi)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat().reshape(R.shape[:-2] + (4,))


def q_to_R(q: ArrayLike) -> NDArray:
    """Quaternions ``(..., 4)`` (scalar last) to rotation matrices ``(..., 3, 3)``."""
    q = np.asarray(q, float)
    _check_last(q, 4, "q")
    return Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(q.shape[:-1] + (3, 3))


def R_to_q(R: ArrayLike) -> NDArray:
    """Rotation matrices ``(..., 3, 3)`` to quaternions ``(..., 4)`` (scalar last)."""
    R = np.asarray(R, float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat().reshape(R.shape[:-2] + (4,))


def enu_to_az_el(los_enu: ArrayLike) -> tuple[NDArray, NDArray]:
    """Azimuth (from north, clockwise) and elevation, rad, of ENU vectors ``(..., 3)``."""
    v = np.asarray(los_enu, float)
    _check_last(v, 3, "los_enu")
    az = np.mod(np.arctan2(v[..., 0], v[..., 1]), 2 * np.pi)
    el = np.arctan2(v[..., 2], np.hypot(v[..., 0], v[..., 1]))
    return az, el
