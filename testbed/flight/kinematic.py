"""Kinematic trajectories: a Truth record without flight dynamics.

For tests, for the VA-RAIM paper's stylised straight sortie, and for campaigns
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


def racetrack_truth(frame: LocalFrame, duration_s: float = 300.0, rate_hz: float = 120.0,
                    straight_m: float = 150.0, radius_m: float = 30.0, height_m: float = 10.0) -> Truth:
    """The Won et al. paper's simulated route: two straights (east, then west) joined by two left half circles,
    flown twice in ``duration_s`` at constant speed and height, wings level, nose along the track.

    The straights run from the world origin east for ``straight_m`` and back ``2·radius_m`` to the north;
    exact arcs, so the body rate is the path's turn rate (``speed/radius`` while turning, 0 on the
    straights). The IMU is derived from the sampled poses (inverse strapdown), so the rate steps at the
    arcs' ends cost nothing in consistency.
    """
    if duration_s <= 0 or rate_hz <= 0 or straight_m <= 0 or radius_m <= 0:
        raise ValueError(f"racetrack: duration_s, rate_hz, straight_m and radius_m must be > 0, got "
                         f"{duration_s}, {rate_hz}, {straight_m}, {radius_m}")
    lap = 2 * straight_m + 2 * np.pi * radius_m
    speed = 2 * lap / duration_s
    n = int(round(duration_s * rate_hz)) + 1
    t = np.linspace(0.0, duration_s, n)
    s = (speed * t) % lap
    a1, a2, a3 = straight_m, straight_m + np.pi * radius_m, 2 * straight_m + np.pi * radius_m
    pos = np.zeros((n, 3))
    track = np.zeros(n)  # the velocity's angle from east, counter-clockwise
    turn = np.zeros(n)  # its rate (rad/s)
    east = s < a1
    pos[east, 0] = s[east]
    arc1 = (s >= a1) & (s < a2)
    ang = (s[arc1] - a1) / radius_m
    pos[arc1, 0], pos[arc1, 1] = straight_m + radius_m * np.sin(ang), radius_m * (1 - np.cos(ang))
    track[arc1], turn[arc1] = ang, speed / radius_m
    west = (s >= a2) & (s < a3)
    pos[west, 0], pos[west, 1], track[west] = straight_m - (s[west] - a2), 2 * radius_m, np.pi
    arc2 = s >= a3
    ang = (s[arc2] - a3) / radius_m
    pos[arc2, 0], pos[arc2, 1] = -radius_m * np.sin(ang), radius_m * (1 + np.cos(ang))
    track[arc2], turn[arc2] = np.pi + ang, speed / radius_m
    pos[:, 2] = height_m
    vel = speed * np.stack([np.cos(track), np.sin(track), np.zeros(n)], -1)
    acc = speed * turn[:, None] * np.stack([-np.sin(track), np.cos(track), np.zeros(n)], -1)
    pos_ecef = frame.enu_to_ecef(pos)
    lat, lon, h = frame.enu_to_geodetic(pos)
    R_loc = R_ecef_to_enu(lat, lon)
    vel_enu = np.einsum("tij,tj->ti", R_loc, frame.vec_enu_to_ecef(vel))
    psi = np.arctan2(vel_enu[:, 0], vel_enu[:, 1])
    zero = np.zeros(n)
    R_b2n = euler_to_R_body_to_ned(zero, zero, psi)
    q = R_to_q(R_NED_TO_ENU @ R_b2n)
    f_ned = np.stack([acc[:, 1], acc[:, 0], np.full(n, -G0)], -1)  # a − g, NED
    f_body = np.einsum("tji,tj->ti", R_b2n, f_ned)
    omega = np.stack([zero, zero, -turn], -1)  # a left turn: negative yaw rate about body z (down)
    return Truth(t=t, pos_ecef=pos_ecef, lat_deg=lat, lon_deg=lon, h=h, pos_enu=pos, vel_enu=vel_enu,
                 q_body_to_enu=q, euler=np.stack([zero, zero, psi], 1), omega_body=omega,
                 specific_force_eye_body=f_body, specific_force_cg_body=f_body, omega_dot_body=np.zeros((n, 3)),
                 agl=np.full(n, height_m), airspeed=np.full(n, speed),
                 frame_origin=np.array([frame.lat_deg, frame.lon_deg, frame.h]))
