"""Strapdown inertial equations in the approach's world frame (docs/design/nav-filter.md §3).

One set of equations for both sides of the IMU: the sensor synthesises
error-free increments by *inverse* strapdown of the true pose, and the
navigation filter integrates measured increments *forward* with the same
mechanisation, so an error-free IMU reproduces the truth it came from
(attitude and velocity to round-off; position to the trapezoid rule's error,
below). Base module: the sensors and the navigation room both import it.

World frame w: the ENU tangent frame of the approach (``LocalFrame``), fixed to
the Earth; b: body FRD; ``C = C_b^w``. Over an interval Δt (k−1 → k)::

    C_k = Exp(−ω_ie^w Δt) C_{k−1} Exp(Δθ_k)
    v_k = v_{k−1} + ½(C_{k−1} + C_k) Δv_k + (g^w(p_{k−1}) − 2 ω_ie^w × v_{k−1}) Δt
    p_k = p_{k−1} + ½(v_{k−1} + v_k) Δt

Δθ, Δv: the gyro's and accelerometer's increments over the interval (body axes;
the accelerometer's with the trapezoid ½(C_{k−1} + C_k) as the mean attitude);
g^w: WGS84 normal gravity (Somigliana, with the second-order free-air
correction) along the local down; ω_ie^w: the Earth's rate in w. With
``earth_rotation = False`` ω_ie = 0 on both sides (the Won et al. paper's model).

Position error of the trapezoid against a smooth truth: Δt²/12 · |v̈| per second
of flight (a jerk of 1 m/s³ at 120 Hz: 0.6 mm over 100 s).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.frames import OMEGA_EARTH, LocalFrame, R_ecef_to_enu, q_to_R

# WGS84 normal gravity (NIMA TR8350.2 §4): equatorial / polar gravity, Somigliana's constant
_GE, _K, _E2 = 9.7803253359, 0.00193185265241, 6.69437999014e-3
_A, _F, _M = 6378137.0, 1.0 / 298.257223563, 0.00344978650684


def skew(v: NDArray) -> NDArray:
    """``[v]×`` (..., 3, 3)."""
    z = np.zeros(np.shape(v)[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def so3_exp(phi: ArrayLike) -> NDArray:
    """Rotation matrices ``Exp([φ]×)`` (..., 3, 3) of rotation vectors φ (..., 3) (Rodrigues, series near 0)."""
    phi = np.asarray(phi, float)
    a2 = np.sum(phi * phi, -1)[..., None, None]
    a = np.sqrt(a2)
    small = a2 < 1e-12
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(small, 1.0 - a2 / 6.0, np.sin(a) / a)
        c = np.where(small, 0.5 - a2 / 24.0, (1.0 - np.cos(a)) / a2)
    K = skew(phi)
    return np.eye(3) + s * K + c * (K @ K)


def so3_log(R: ArrayLike) -> NDArray:
    """Rotation vectors (..., 3) of rotation matrices (..., 3, 3), angles below π."""
    R = np.asarray(R, float)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    a = np.arccos(cos)
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(a < 1e-6, 0.5 + a * a / 12.0, a / (2.0 * np.sin(a)))
    return k[..., None] * w


def normal_gravity(lat_deg: ArrayLike, h: ArrayLike) -> NDArray:
    """WGS84 normal gravity magnitude (m/s²) at geodetic latitude and ellipsoidal height."""
    s2 = np.sin(np.radians(np.asarray(lat_deg, float))) ** 2
    g0 = _GE * (1.0 + _K * s2) / np.sqrt(1.0 - _E2 * s2)
    h = np.asarray(h, float)
    return g0 * (1.0 - 2.0 / _A * (1.0 + _F + _M - 2.0 * _F * s2) * h + 3.0 / _A**2 * h * h)


def _geodetic_up(pos_ecef: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Geodetic latitude (deg), height (m) and the ellipsoid normal (..., 3) of ECEF points.

    Bowring's closed form (one step): < 1 mm in height and < 1e-11 rad in latitude up to
    10 km above the ellipsoid — cheap enough to call at every IMU step.
    """
    x, y, z = pos_ecef[..., 0], pos_ecef[..., 1], pos_ecef[..., 2]
    b = _A * (1.0 - _F)
    ep2 = (_A * _A - b * b) / (b * b)
    r = np.hypot(x, y)
    u = np.arctan2(z * _A, r * b)
    lat = np.arctan2(z + ep2 * b * np.sin(u) ** 3, r - _E2 * _A * np.cos(u) ** 3)
    lon = np.arctan2(y, x)
    sl, cl = np.sin(lat), np.cos(lat)
    n = _A / np.sqrt(1.0 - _E2 * sl * sl)
    h = r * cl + z * sl - n * (1.0 - _E2 * sl * sl)
    up = np.stack([cl * np.cos(lon), cl * np.sin(lon), sl], -1)
    return np.degrees(lat), h, up


def gravity_world(frame: LocalFrame, pos_w: ArrayLike) -> NDArray:
    """Normal gravity (..., 3) in the world frame at world positions (..., 3): −g along the ellipsoid normal."""
    p = np.asarray(pos_w, float)
    ecef = frame.origin_ecef + np.einsum("ji,...j->...i", frame.R, p)
    lat, h, up = _geodetic_up(ecef)
    return -normal_gravity(lat, h)[..., None] * np.einsum("ij,...j->...i", frame.R, up)


def earth_rate_world(frame: LocalFrame, earth_rotation: bool = True) -> NDArray:
    """ω_ie in the world frame (3,) rad/s (zero when ``earth_rotation`` is off)."""
    return frame.R @ np.array([0.0, 0.0, OMEGA_EARTH if earth_rotation else 0.0])


def body_to_world(frame: LocalFrame, pos_w: ArrayLike, q_body_to_local_enu: ArrayLike) -> NDArray:
    """``C_b^w`` (..., 3, 3) from an attitude given against the local ENU at ``pos_w``."""
    lat, lon, _ = frame.enu_to_geodetic(np.asarray(pos_w, float))
    R_local_to_world = frame.R @ np.swapaxes(R_ecef_to_enu(lat, lon), -1, -2)
    return R_local_to_world @ q_to_R(q_body_to_local_enu)


def local_to_world(frame: LocalFrame, pos_w: ArrayLike, vec_local: ArrayLike) -> NDArray:
    """A vector (..., 3) given in the local ENU at ``pos_w`` in world-frame components."""
    lat, lon, _ = frame.enu_to_geodetic(np.asarray(pos_w, float))
    R_local_to_world = frame.R @ np.swapaxes(R_ecef_to_enu(lat, lon), -1, -2)
    return np.einsum("...ij,...j->...i", R_local_to_world, np.asarray(vec_local, float))


def mechanise_step(C: NDArray, v: NDArray, p: NDArray, dtheta: NDArray, dvel: NDArray, dt: float,
                   g_w: NDArray, w_ie: NDArray, earth_turn: NDArray | None = None) -> tuple[NDArray, NDArray, NDArray]:
    """One strapdown step (module doc), batched: C (..., 3, 3), v, p, dtheta, dvel, g_w (..., 3).

    earth_turn : ``Exp(−ω_ie Δt)`` when the caller has it (it is the same at every step).
    """
    E = so3_exp(-w_ie * dt) if earth_turn is None else earth_turn
    C1 = E @ C @ so3_exp(dtheta)
    v1 = v + np.einsum("...ij,...j->...i", 0.5 * (C + C1), dvel) + (g_w - 2.0 * np.cross(w_ie, v)) * dt
    p1 = p + 0.5 * (v + v1) * dt
    return C1, v1, p1


def mechanise(frame: LocalFrame, C0: NDArray, v0: NDArray, p0: NDArray, dtheta: NDArray, dvel: NDArray,
              dt: float, earth_rotation: bool = True) -> tuple[NDArray, NDArray, NDArray]:
    """Integrate increments (..., K, 3) from (C0 (..., 3, 3), v0, p0 (..., 3)): C (..., K+1, 3, 3), v, p (..., K+1, 3)."""
    w_ie = earth_rate_world(frame, earth_rotation)
    E = so3_exp(-w_ie * dt)
    K = dtheta.shape[-2]
    C, v, p = [np.asarray(C0, float)], [np.asarray(v0, float)], [np.asarray(p0, float)]
    for k in range(K):
        c1, v1, p1 = mechanise_step(C[-1], v[-1], p[-1], dtheta[..., k, :], dvel[..., k, :], dt,
                                    gravity_world(frame, p[-1]), w_ie, E)
        C.append(c1), v.append(v1), p.append(p1)
    return np.stack(C, -3), np.stack(v, -2), np.stack(p, -2)


def inverse_strapdown(frame: LocalFrame, C: NDArray, v: NDArray, p: NDArray, dt: float,
                      earth_rotation: bool = True) -> tuple[NDArray, NDArray]:
    """The error-free increments (K, 3) that carry the pose samples C (K+1, 3, 3), v, p (K+1, 3) through
    :func:`mechanise_step` (attitude and velocity exactly)::

        Δθ_k = Log(C_{k−1}ᵀ Exp(ω_ie Δt) C_k)
        Δv_k = [½(C_{k−1} + C_k)]⁻¹ (v_k − v_{k−1} − (g^w(p_{k−1}) − 2 ω_ie × v_{k−1}) Δt)
    """
    w_ie = earth_rate_world(frame, earth_rotation)
    C0, C1 = C[:-1], C[1:]
    dtheta = so3_log(np.swapaxes(C0, -1, -2) @ so3_exp(w_ie * dt) @ C1)
    rhs = v[1:] - v[:-1] - (gravity_world(frame, p[:-1]) - 2.0 * np.cross(w_ie, v[:-1])) * dt
    dvel = np.linalg.solve(0.5 * (C0 + C1), rhs[..., None])[..., 0]
    return dtheta, dvel
