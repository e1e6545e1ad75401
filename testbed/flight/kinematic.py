"""Kinematic trajectories: a Truth record without flight dynamics.

For tests, for the seed paper's stylised straight sortie, and for campaigns
that want geometry without flying. Constant-velocity straight segment in the
world frame with a steady attitude (wings level, flight-path pitch plus an
optional angle of attack). The specific force is that of unaccelerated flight
(gravity opposed, in body axes).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from testbed.frames import LocalFrame, R_ecef_to_enu, R_to_q, euler_to_R_body_to_ned, R_NED_TO_ENU
from testbed.records import Truth

G0 = 9.80665


def straight_truth(frame: LocalFrame, start_enu: ArrayLike, end_enu: ArrayLike, duration_s: float,
                   rate_hz: float = 10.0, alpha_deg: float = 3.0) -> Truth:
    """A straight, constant-speed segment from ``start_enu`` to ``end_enu`` (world frame).

    Parameters
    ----------
    frame : the world frame the ENU points are given in.
    start_enu, end_enu : (3,) m.
    duration_s : flight time, s; epochs at ``rate_hz`` including both ends.
    alpha_deg : body pitch above the flight path (angle of attack), deg.
    """
    if duration_s <= 0 or rate_hz <= 0:
        raise ValueError(f"duration_s and rate_hz must be > 0, got {duration_s}, {rate_hz}")
    a, b = np.asarray(start_enu, float), np.asarray(end_enu, float)
    n = int(round(duration_s * rate_hz)) + 1
    t = np.linspace(0.0, duration_s, n)
    pos_enu = a + (b - a) * (t / duration_s)[:, None]
    pos_ecef = frame.enu_to_ecef(pos_enu)
    lat, lon, h = frame.enu_to_geodetic(pos_enu)
    v_world = (b - a) / duration_s
    # Velocity and attitude in the local ENU frame at each point (they differ
    # from the world frame by the Earth's curvature: ~0.1 mrad per km).
    R_loc = R_ecef_to_enu(lat, lon)  # (T,3,3) ECEF -> local ENU
    vel_enu = np.einsum("tij,j->ti", R_loc, frame.vec_enu_to_ecef(v_world))
    psi = np.arctan2(vel_enu[:, 0], vel_enu[:, 1])
    gamma = np.arctan2(vel_enu[:, 2], np.hypot(vel_enu[:, 0], vel_enu[:, 1]))
    theta = gamma + np.radians(alpha_deg)
    phi = np.zeros(n)
    R_b2n = euler_to_R_body_to_ned(phi, theta, psi)
    q = R_to_q(R_NED_TO_ENU @ R_b2n)
    g_ned = np.array([0.0, 0.0, -G0])  # specific force opposes gravity
    f_body = np.einsum("tji,j->ti", R_b2n, g_ned)
    speed = np.linalg.norm(vel_enu, axis=1)
    return Truth(t=t, pos_ecef=pos_ecef, lat_deg=lat, lon_deg=lon, h=h, pos_enu=pos_enu,
                 vel_enu=vel_enu, q_body_to_enu=q, euler=np.stack([phi, theta, psi], 1),
                 omega_body=np.zeros((n, 3)), specific_force_eye_body=f_body, specific_force_cg_body=f_body,
                 omega_dot_body=np.zeros((n, 3)), agl=np.full(n, np.nan), airspeed=speed,
                 frame_origin=np.array([frame.lat_deg, frame.lon_deg, frame.h]))
