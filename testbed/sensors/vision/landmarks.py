"""Landmark scenes: the seed triangle, "H"/"I" ground markers, the runway outline.

:func:`build_landmarks` turns :class:`~.settings.LandmarkSettings` (the
``[landmarks]`` table of an approach file) into a :class:`Landmarks` record of
*true* positions. The survey the monitors get differs from the truth by the
landmark position error (LPE), drawn once per flight by :func:`survey`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from testbed.frames import LocalFrame, geodetic_to_ecef
from testbed.world import airport

from .settings import LandmarkSettings, MarkerSet, PointsSet, RunwaySet, TriangleSet


@dataclass(frozen=True)
class Landmarks:
    """True landmark positions.

    Attributes
    ----------
    id : (L,) str.  pos_ecef : (L, 3) m, true positions.  size_m : (L,) m, physical size
    (for the apparent-size rule).  lpe_sigma_m : survey error 1-sigma per axis, m.
    """

    id: NDArray
    pos_ecef: NDArray
    size_m: NDArray
    lpe_sigma_m: float = 0.0

    def __post_init__(self) -> None:
        ids = list(np.asarray(self.id).tolist())
        seen: set = set()
        dup = sorted({i for i in ids if i in seen or seen.add(i)})  # one pass (a count per id was quadratic: 100 s
        # for the 80 000 edge points of a 0.1 m runway spacing, in every check)
        if dup:
            more = f" and {len(dup) - 5} more" if len(dup) > 5 else ""
            raise ValueError(f"landmarks: ids must be unique, got duplicates {dup[:5]}{more}")
        if np.shape(self.pos_ecef) != (len(ids), 3) or np.shape(self.size_m) != (len(ids),):
            raise ValueError(f"landmarks: expected pos_ecef ({len(ids)}, 3) and size_m ({len(ids)},), got "
                             f"{np.shape(self.pos_ecef)} and {np.shape(self.size_m)}")

    def __len__(self) -> int:
        return len(self.id)

    def index(self, name: str) -> int:
        """Slot of landmark ``name`` (ValueError naming the known ids if absent)."""
        hits = np.flatnonzero(self.id == name)
        if hits.size == 0:
            raise ValueError(f"landmark {name!r}: not in the scene; known ids {list(self.id)}")
        return int(hits[0])


def marker_outline(letter: str, height_m: float, width_m: float, stroke_m: float) -> NDArray:
    """The 12 corners ``(12, 2)`` of an "H" or "I" (x right, y towards the letter's top), m, centred.

    Counter-clockwise from the bottom-left corner.
    """
    h2, w2, s = height_m / 2, width_m / 2, stroke_m
    if letter == "H":
        pts = [(-w2, -h2), (-w2 + s, -h2), (-w2 + s, -s / 2), (w2 - s, -s / 2), (w2 - s, -h2), (w2, -h2),
               (w2, h2), (w2 - s, h2), (w2 - s, s / 2), (-w2 + s, s / 2), (-w2 + s, h2), (-w2, h2)]
    elif letter == "I":
        pts = [(-w2, -h2), (w2, -h2), (w2, -h2 + s), (s / 2, -h2 + s), (s / 2, h2 - s), (w2, h2 - s),
               (w2, h2), (-w2, h2), (-w2, h2 - s), (-s / 2, h2 - s), (-s / 2, -h2 + s), (-w2, -h2 + s)]
    else:
        raise ValueError(f"marker letter: expected 'H' or 'I', got {letter!r}")
    return np.array(pts, float)


def _triangle(s: TriangleSet):
    frame = LocalFrame(s.centre_lat_deg, s.centre_lon_deg, s.centre_h)
    az = np.radians(np.asarray(s.azimuths_deg, float))
    enu = np.stack([s.radius_m * np.sin(az), s.radius_m * np.cos(az), np.zeros_like(az)], axis=-1)
    lat, lon, _ = frame.enu_to_geodetic(enu)
    h = s.centre_h if s.height_m is None else s.height_m
    ids = [f"{s.prefix}{k + 1}" for k in range(az.size)]
    return ids, geodetic_to_ecef(lat, lon, np.full(az.size, h)), np.full(az.size, s.size_m)


def _marker(s: MarkerSet):
    xy = marker_outline(s.letter, s.height_m, s.width_m, s.stroke_m)
    psi = np.radians(s.heading_deg)
    up = np.array([np.sin(psi), np.cos(psi), 0.0])
    right = np.array([np.cos(psi), -np.sin(psi), 0.0])
    enu = xy[:, :1] * right + xy[:, 1:] * up
    frame = LocalFrame(s.lat_deg, s.lon_deg, s.h)
    lat, lon, _ = frame.enu_to_geodetic(enu)
    prefix = s.letter if s.prefix is None else s.prefix
    ids = [f"{prefix}{k + 1:02d}" for k in range(len(xy))]
    size = s.stroke_m if s.size_m is None else s.size_m
    return ids, geodetic_to_ecef(lat, lon, np.full(len(xy), s.h)), np.full(len(xy), size)


def runway_points_enu(frame: LocalFrame, width_m: float = airport.RUNWAY_WIDTH_M,
                      edge_spacing_m: float | None = 300.0) -> tuple[list[str], NDArray]:
    """ZUNZ runway 05/23 outline points in ``frame``: ids and ``(P, 3)`` ENU, m.

    The four threshold corners (``05L, 05R, 23R, 23L``; left/right as seen
    landing on 05) and, every ``edge_spacing_m`` from the 05 threshold, points
    on both edges (``L0300``, ``R0300`` ...), none closer than half a spacing
    to the 23 threshold. Heights vary linearly between the
    two threshold elevations.
    """
    a = frame.geodetic_to_enu(airport.RWY05.lat_deg, airport.RWY05.lon_deg, airport.RWY05.h)
    b = frame.geodetic_to_enu(airport.RWY23.lat_deg, airport.RWY23.lon_deg, airport.RWY23.h)
    length = np.linalg.norm(b - a)
    along = (b - a) / length
    right = np.array([along[1], -along[0], 0.0])
    right /= np.linalg.norm(right)
    w = width_m / 2
    ids = ["05L", "05R", "23R", "23L"]
    pts = [a - w * right, a + w * right, b + w * right, b - w * right]
    if edge_spacing_m is not None:
        # no edge point within half a spacing of the far threshold (its corners are there)
        for d in np.arange(edge_spacing_m, length - 0.5 * edge_spacing_m, edge_spacing_m):
            c = a + along * d
            ids += [f"L{d:04.0f}", f"R{d:04.0f}"]
            pts += [c - w * right, c + w * right]
    return ids, np.array(pts)


def _runway(s: RunwaySet):
    frame = airport.runway_frame()
    ids, enu = runway_points_enu(frame, s.width_m, s.edge_spacing_m)
    return [s.prefix + i for i in ids], frame.enu_to_ecef(enu), np.full(len(ids), s.size_m)


def _points(s: PointsSet):
    ids = [p.id for p in s.points]
    pos = geodetic_to_ecef([p.lat_deg for p in s.points], [p.lon_deg for p in s.points], [p.h for p in s.points])
    return ids, pos, np.array([p.size_m for p in s.points])


_BUILDERS = {"triangle": _triangle, "marker": _marker, "runway": _runway, "points": _points}


def build_landmarks(settings: LandmarkSettings) -> Landmarks:
    """True landmark positions of the scene ``settings`` (sets in order, ids as documented per set)."""
    ids, pos, size = [], [], []
    for s in settings.sets:
        i, p, z = _BUILDERS[s.kind](s)
        ids += list(i)
        pos.append(np.atleast_2d(p))
        size.append(np.atleast_1d(z))
    return Landmarks(id=np.array(ids), pos_ecef=np.concatenate(pos), size_m=np.concatenate(size),
                     lpe_sigma_m=settings.lpe_sigma_m)


def survey(landmarks: Landmarks, rng: np.random.Generator, n_trials: int | None = None) -> NDArray:
    """Surveyed positions = true + N(0, lpe_sigma² I) per axis, drawn once per flight.

    Returns ``(B..., L, 3)`` m ECEF (isotropic, so the axes it is drawn in do not matter).
    """
    batch = () if n_trials is None else (int(n_trials),)
    err = rng.standard_normal(batch + landmarks.pos_ecef.shape) * landmarks.lpe_sigma_m
    return landmarks.pos_ecef + err


def seed_triangle_settings(lpe_sigma_m: float = 0.05) -> LandmarkSettings:
    """The VA-RAIM paper's scene (its §3.1.2, longitude typo corrected to 94.3359 E)."""
    return LandmarkSettings(sets=[TriangleSet(kind="triangle")], lpe_sigma_m=lpe_sigma_m)


def zunz_runway_settings(edge_spacing_m: float | None = 300.0, lpe_sigma_m: float = 0.05) -> LandmarkSettings:
    """The ZUNZ runway 05/23 outline as landmarks."""
    return LandmarkSettings(sets=[RunwaySet(kind="runway", edge_spacing_m=edge_spacing_m)], lpe_sigma_m=lpe_sigma_m)
