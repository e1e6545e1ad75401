"""Approach path geometry: straight and constant-radius (RF) legs plus a vertical profile.

The lateral path lives in the east/north plane of the approach's world frame
(a local tangent plane; over 30 km its scale error is < 1e-5). Tracks are true
courses in radians, clockwise from north. Heights along the path are WGS84
ellipsoidal heights, not world-frame "up" (which drops below the ellipsoid by
d²/2R: 70 m at 30 km), so vertical guidance compares like with like.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from testbed.flight.settings import PathSettings, RfLeg, VerticalSettings
from testbed.frames import LocalFrame

TWO_PI = 2.0 * math.pi


def _wrap_pi(a: float) -> float:
    """Angle wrapped to (-pi, pi]."""
    return a - TWO_PI * math.floor((a + math.pi) / TWO_PI)


def _dir(track: float) -> tuple[float, float]:
    """Unit (east, north) vector of a track angle."""
    return math.sin(track), math.cos(track)


def _right(track: float) -> tuple[float, float]:
    """Unit (east, north) vector pointing to the right of a track."""
    return math.cos(track), -math.sin(track)


@dataclass(frozen=True)
class LegGeometry:
    """One leg in flying order. ``turn`` is 0 for straight legs, else the signed sweep (rad, + right)."""

    start: tuple[float, float]
    track0: float
    length: float
    turn: float = 0.0
    radius: float = math.inf
    centre: tuple[float, float] = (math.nan, math.nan)

    @property
    def sign(self) -> float:
        return math.copysign(1.0, self.turn) if self.turn else 0.0

    def project(self, e: float, n: float) -> tuple[float, float, float]:
        """(along-leg distance, cross-track right-positive, path track) for a point."""
        if not self.turn:
            de, dn = e - self.start[0], n - self.start[1]
            d, r = _dir(self.track0), _right(self.track0)
            return de * d[0] + dn * d[1], de * r[0] + dn * r[1], self.track0
        s = self.sign
        ve, vn = e - self.centre[0], n - self.centre[1]
        bearing = math.atan2(ve, vn)
        b_start = math.atan2(self.start[0] - self.centre[0], self.start[1] - self.centre[1])
        mid = b_start + s * abs(self.turn) / 2
        phi = s * _wrap_pi(bearing - mid)
        along = (phi + abs(self.turn) / 2) * self.radius
        xtk = s * (self.radius - math.hypot(ve, vn))
        return along, xtk, bearing + s * math.pi / 2

    def point(self, along: NDArray) -> NDArray:
        """(east, north) points ``(K, 2)`` at along-leg distances ``(K,)``."""
        along = np.asarray(along, float)
        if not self.turn:
            d = _dir(self.track0)
            return np.stack([self.start[0] + along * d[0], self.start[1] + along * d[1]], -1)
        s = self.sign
        b_start = math.atan2(self.start[0] - self.centre[0], self.start[1] - self.centre[1])
        b = b_start + s * along / self.radius
        return np.stack([self.centre[0] + self.radius * np.sin(b), self.centre[1] + self.radius * np.cos(b)], -1)


@dataclass(frozen=True)
class PathState:
    """Where the aircraft is relative to the path (one epoch)."""

    leg: int
    distance_to_go: float  # m along the path to its end (negative past it)
    cross_track: float  # m, right of the path positive
    track: float  # rad, the path's true course here
    turn_sign: float  # +1 right turn, -1 left, 0 straight
    radius: float  # m (inf on straight legs)


class ApproachPath:
    """Lateral legs plus a vertical profile; built from settings in a world frame."""

    def __init__(self, lateral: PathSettings, vertical: VerticalSettings, frame: LocalFrame) -> None:
        self.frame = frame
        self.vertical = vertical
        end = frame.geodetic_to_enu(lateral.end_lat_deg, lateral.end_lon_deg, lateral.end_h)
        self.end_h = lateral.end_h
        self.legs = self._build(lateral, (float(end[0]), float(end[1])))
        self.lengths = np.array([leg.length for leg in self.legs])
        # distance to go from the *end* of each leg
        self._after = np.concatenate([np.cumsum(self.lengths[::-1])[::-1][1:], [0.0]])
        self.total_length = float(self.lengths.sum())
        self._tan_gpa = math.tan(math.radians(vertical.glide_path_deg)) if vertical.glide_path_deg else math.nan

    @staticmethod
    def _build(lateral: PathSettings, end: tuple[float, float]) -> list[LegGeometry]:
        legs: list[LegGeometry] = []
        p, track = end, math.radians(lateral.final_course_deg)
        for leg in reversed(lateral.legs):
            if isinstance(leg, RfLeg):
                turn = math.radians(leg.turn_deg)
                s = math.copysign(1.0, turn)
                r_end = _right(track)
                centre = (p[0] + s * leg.radius_m * r_end[0], p[1] + s * leg.radius_m * r_end[1])
                track0 = track - turn
                r0 = _right(track0)
                start = (centre[0] - s * leg.radius_m * r0[0], centre[1] - s * leg.radius_m * r0[1])
                legs.append(LegGeometry(start, track0, leg.radius_m * abs(turn), turn, leg.radius_m, centre))
                p, track = start, track0
            else:
                d = _dir(track)
                start = (p[0] - leg.length_m * d[0], p[1] - leg.length_m * d[1])
                legs.append(LegGeometry(start, track, leg.length_m))
                p = start
        return legs[::-1]

    # -- lateral ---------------------------------------------------------------
    def locate(self, e: float, n: float, leg_hint: int = 0) -> PathState:
        """Project a point onto the path, searching forward from ``leg_hint`` (the active leg)."""
        i = max(0, min(leg_hint, len(self.legs) - 1))
        while True:
            leg = self.legs[i]
            along, xtk, track = leg.project(e, n)
            if along <= leg.length or i == len(self.legs) - 1:
                break
            i += 1
        return PathState(i, float(self._after[i] + leg.length - along), xtk, track, leg.sign, leg.radius)

    def start_point(self, distance_to_go: float) -> tuple[float, float, float]:
        """(east, north, track) of the point ``distance_to_go`` before the end."""
        if not (0 < distance_to_go <= self.total_length):
            raise ValueError(f"start distance {distance_to_go:.0f} m: expected within the path (0, {self.total_length:.0f}] m")
        i = int(np.argmax(self._after < distance_to_go))  # first leg ending closer than d (the last ends at 0)
        leg = self.legs[i]
        along = leg.length - (distance_to_go - self._after[i])
        e, n = leg.point(np.array([along]))[0]
        return float(e), float(n), leg.track0 + (leg.turn * along / leg.length if leg.turn else 0.0)

    # -- vertical --------------------------------------------------------------
    def height(self, distance_to_go: float | NDArray) -> float | NDArray:
        """Path height (WGS84 ellipsoidal, m) at a distance to go."""
        v = self.vertical
        if isinstance(distance_to_go, float) and not v.constraints:  # the flight loop's fast path
            return self.end_h + v.crossing_height_m + distance_to_go * self._tan_gpa
        d = np.asarray(distance_to_go, float)
        if v.constraints:
            dd, hh = np.array(v.constraints).T
            out = np.interp(d, dd, hh)
        else:
            out = self.end_h + v.crossing_height_m + d * self._tan_gpa
        return float(out) if np.ndim(out) == 0 else out

    def path_angle(self, distance_to_go: float) -> float:
        """Descent angle of the profile here (rad, positive descending)."""
        v = self.vertical
        if not v.constraints:
            return math.radians(v.glide_path_deg)
        dd, hh = np.array(v.constraints).T
        k = int(np.clip(np.searchsorted(dd, distance_to_go) - 1, 0, len(dd) - 2))
        return math.atan2(hh[k + 1] - hh[k], dd[k + 1] - dd[k])

    # -- drawing ---------------------------------------------------------------
    def sample(self, spacing_m: float = 50.0) -> tuple[NDArray, NDArray]:
        """Points along the path: ``(east_north (K, 2), distance_to_go (K,))``."""
        pts, dtg = [], []
        for i, leg in enumerate(self.legs):
            a = np.linspace(0.0, leg.length, max(2, int(leg.length / spacing_m) + 1))
            pts.append(leg.point(a))
            dtg.append(self._after[i] + leg.length - a)
        return np.concatenate(pts), np.concatenate(dtg)

    def sample_enu(self, spacing_m: float = 50.0) -> NDArray:
        """The 3D planned path ``(K, 3)`` in the world frame (for plots and Rerun)."""
        en, dtg = self.sample(spacing_m)
        lat, lon, _ = self.frame.enu_to_geodetic(np.column_stack([en, np.zeros(len(en))]))
        return self.frame.geodetic_to_enu(lat, lon, self.height(dtg))
