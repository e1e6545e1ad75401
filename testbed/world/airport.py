"""Facts about Nyingchi Mainling airport (LinZhi, ZUNZ) used across the testbed.

Sources (see docs/design/physics-notes.md §airport-and-runway): airport databases for the
reference point and elevation; flight-simulator scenery data for the
threshold coordinates. Heights are used as given and treated as WGS84
ellipsoidal (the testbed has no geoid model; see docs/design/physics-notes.md §heights).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.frames import LocalFrame


@dataclass(frozen=True)
class Threshold:
    name: str
    lat_deg: float
    lon_deg: float
    h: float  # m


ICAO = "ZUNZ"
NAME = "Nyingchi Mainling (LinZhi)"
ARP_LAT_DEG, ARP_LON_DEG = 29.3033, 94.3353  # aerodrome reference point
ELEVATION_M = 2949.0
RWY05 = Threshold("05", 29.2958478, 94.3224478, 2939.0)
RWY23 = Threshold("23", 29.3115028, 94.3476320, 2948.0)
RUNWAY_LENGTH_M = 3000.0
RUNWAY_WIDTH_M = 45.0
RWY05_COURSE_DEG = 54.65  # true

# The VA-RAIM paper's scenario centre (its §3.1) with its longitude typo
# (90.xx E) corrected to 94.xx E: 0.36 km from the ARP, same elevation.
VA_RAIM_CENTRE = (29.3065, 94.3359, 2950.0)


def runway_frame() -> LocalFrame:
    """The world frame of the ZUNZ approaches: ENU at the runway-05 threshold."""
    return LocalFrame(RWY05.lat_deg, RWY05.lon_deg, RWY05.h)


def runway_corners_enu(frame: LocalFrame) -> np.ndarray:
    """Runway 05/23 paved outline ``(4, 3)`` in ``frame`` (05 left, 05 right, 23 right, 23 left)."""
    a = frame.geodetic_to_enu(RWY05.lat_deg, RWY05.lon_deg, RWY05.h)
    b = frame.geodetic_to_enu(RWY23.lat_deg, RWY23.lon_deg, RWY23.h)
    along = (b - a) / np.linalg.norm(b - a)
    right = np.array([along[1], -along[0], 0.0])
    right /= np.linalg.norm(right)
    w = RUNWAY_WIDTH_M / 2
    return np.stack([a - w * right, a + w * right, b + w * right, b - w * right])
