"""Where the GNSS antenna is, and which satellites it can see.

The antenna sits at a lever arm from the aircraft reference point (Mount),
rotated by the *true* attitude. A satellite slot is visible when it passes,
in this order (the first failure is the recorded reason):

1. elevation above the local (geodetic) horizon ≥ mask → else BELOW_MASK;
2. terrain: ``terrain.sky_visible(antenna, line of sight)`` → else TERRAIN;
3. airframe: elevation above the antenna plane (body x–y plane; body z points
   down, so "above" is −z) ≥ ``airframe_mask_deg`` → else AIRFRAME
   (the fuselage/wing shadows satellites on the low side in a bank);
4. satellite health flag 0 → else UNHEALTHY.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from testbed.frames import R_ecef_to_enu, ecef_to_geodetic, q_to_R
from testbed.records import Mount, NotVisible, Truth


def antenna_state(truth: Truth, antenna: Mount) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """True antenna position/velocity and the frames at it.

    Returns
    -------
    pos_ecef : (T, 3) m.   vel_ecef : (T, 3) m/s (Earth-relative, incl. ω × lever arm).
    R_body_to_ecef : (T, 3, 3).   R_ecef_to_enu : (T, 3, 3) local ENU at the antenna.
    """
    lever = np.asarray(antenna.lever_arm_body, float)
    if lever.shape != (3,):
        raise ValueError(f"antenna.lever_arm_body: expected shape (3,), got {lever.shape}")
    R_e2n_cg = R_ecef_to_enu(truth.lat_deg, truth.lon_deg)  # (T,3,3)
    R_b2e = np.einsum("tji,tjk->tik", R_e2n_cg, q_to_R(truth.q_body_to_enu))  # R_e2nᵀ·R_b2n
    pos = truth.pos_ecef + R_b2e @ lever
    vel = (np.einsum("tji,tj->ti", R_e2n_cg, truth.vel_enu)
           + np.einsum("tij,tj->ti", R_b2e, np.cross(truth.omega_body, lever)))
    lat, lon, _ = ecef_to_geodetic(pos)
    return pos, vel, R_b2e, R_ecef_to_enu(lat, lon)


def classify(los_ecef: NDArray, ant_pos_ecef: NDArray, R_e2n: NDArray, R_b2e: NDArray, health: NDArray, *,
             elevation_mask_deg: float = 5.0, terrain: Any = None, airframe_masking: bool = True,
             airframe_mask_deg: float = 0.0) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Elevation, azimuth and the NotVisible reason of every (epoch, slot).

    Parameters
    ----------
    los_ecef : (T, S, 3) unit vectors antenna -> satellite (ECEF).
    ant_pos_ecef : (T, 3).  R_e2n : (T, 3, 3) ECEF -> local ENU.  R_b2e : (T, 3, 3) body -> ECEF.
    health : (S,) satellite health (0 = healthy).
    elevation_mask_deg : a mask for every slot, or one per slot (S,) (a mask per constellation).
    terrain : object with ``sky_visible(origin_ecef (N,3), direction_ecef (N,3)) -> (N,) bool``, or None.

    Returns
    -------
    elevation, azimuth : (T, S) rad (local horizon).  elevation_body : (T, S) rad above the antenna plane.
    reason : (T, S) int8 NotVisible codes (0 = visible).
    """
    u_enu = np.einsum("tij,tsj->tsi", R_e2n, los_ecef)
    el = np.arcsin(np.clip(u_enu[..., 2], -1.0, 1.0))
    az = np.mod(np.arctan2(u_enu[..., 0], u_enu[..., 1]), 2 * np.pi)
    u_body = np.einsum("tji,tsj->tsi", R_b2e, los_ecef)
    el_body = np.arcsin(np.clip(-u_body[..., 2], -1.0, 1.0))  # body z is down
    reason = np.zeros(el.shape, np.int8)
    below = ~(el >= np.radians(elevation_mask_deg))  # NaN geometry counts as below
    reason[below] = NotVisible.BELOW_MASK
    if terrain is not None:
        cand = reason == 0
        if cand.any():
            origin = np.broadcast_to(ant_pos_ecef[:, None, :], los_ecef.shape)[cand]
            ok = np.asarray(terrain.sky_visible(origin, los_ecef[cand]), bool)
            if ok.shape != (int(cand.sum()),):
                raise ValueError(f"terrain.sky_visible: expected a bool array of shape ({int(cand.sum())},), "
                                 f"got {ok.shape}")
            r = reason[cand]
            r[~ok] = NotVisible.TERRAIN
            reason[cand] = r
    if airframe_masking:
        reason[(reason == 0) & (el_body < np.radians(airframe_mask_deg))] = NotVisible.AIRFRAME
    reason[(reason == 0) & (np.asarray(health)[None, :] != 0)] = NotVisible.UNHEALTHY
    return el, az, el_body, reason


def apply_schedule(reason: NDArray, elevation: NDArray, t: NDArray, schedule) -> NDArray:
    """``reason`` (..., T, S) with the schedule's caps: at each epoch (flight time ``t`` (T,)) the
    visible satellites beyond the cap in force, lowest elevations first, become EXCLUDED."""
    if not schedule:
        return reason
    t = np.asarray(t, float)
    starts = np.array([c.from_s for c in schedule])
    caps = np.array([c.max_satellites for c in schedule])
    k = np.searchsorted(starts, t, side="right") - 1
    cap = np.where(k >= 0, caps[np.maximum(k, 0)], np.iinfo(np.int32).max)  # (T,)
    return exclude_beyond(reason, elevation, cap)


def apply_system_caps(reason: NDArray, elevation: NDArray, system: NDArray, caps: dict) -> NDArray:
    """``reason`` (..., T, S) with each system's cap ``caps[letter]`` (None: none): at every epoch the visible
    satellites of that system beyond its cap, lowest elevations first, become EXCLUDED."""
    out = reason
    for letter, cap in caps.items():
        cols = np.flatnonzero(np.asarray(system) == letter)
        if cap is None or cols.size == 0:
            continue
        out = out.copy() if out is reason else out
        out[..., cols] = exclude_beyond(out[..., cols], elevation[..., cols], np.full(reason.shape[-2], cap))
    return out


def exclude_beyond(reason: NDArray, elevation: NDArray, cap: NDArray) -> NDArray:
    """``reason`` (..., T, S) with the visible satellites beyond ``cap`` (T,) at each epoch, lowest elevations
    first, EXCLUDED."""
    vis = reason == 0
    rank = np.argsort(np.argsort(np.where(vis, -elevation, np.inf), axis=-1, kind="stable"), axis=-1, kind="stable")
    out = reason.copy()
    out[vis & (rank >= cap[:, None])] = NotVisible.EXCLUDED
    return out
