"""The synthetic LinZhi valley: the embedded default terrain (SYNTHETIC, not a survey).

A parametric model of the valley at Nyingchi Mainling (ZUNZ), which runs south-west
to north-east along the runway: a floor corridor that follows the RNP approach's turn and the extended runway
centreline, Gaussian walls to a rough crest, and the two broad peaks of the
eastern Himalaya, rasterised on a regular grid (:class:`terrain.GridTerrain`).
Every constant below is part of the model's definition; the figures it is fitted
to (floor, crest, peaks, runway elevations) are in docs/design/physics-notes.md §the-synthetic-valley.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pymap3d.vincenty
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from testbed.world import airport
from testbed.world.terrain import AnchoredMap, GridTerrain

#: Runway course, true (deg), and the heading the valley axis turns to far south-west.
VALLEY_RUNWAY_COURSE_DEG = airport.RWY05_COURSE_DEG
VALLEY_FAR_COURSE_DEG = 75.0
#: The floor is the union of two corridors (along-track = metres from the RWY05
#: threshold along the runway course, negative to the south-west):
#: * the valley (B), whose centreline (:func:`valley_centreline`) is the runway's for
#:   along-track >= BEND_START_M and turns (smoothstep in heading) to
#:   VALLEY_FAR_COURSE_DEG by BEND_END_M: the path an RNP approach follows, turning
#:   onto the runway course 4-12 km out (84 % of the turn done 6 km out);
#: * the runway corridor (A) along the extended runway centreline out to
#:   RUNWAY_CORRIDOR_END_M (16 km), where a straight-in 3 deg final flies; it tapers shut beyond.
VALLEY_BEND_START_M = -4000.0
VALLEY_BEND_END_M = -12000.0
VALLEY_RUNWAY_CORRIDOR_END_M = -16000.0
#: Floor: 2939 m at THR05 rising 9 m over the 3 km runway, clipped to this band.
VALLEY_FLOOR_BAND_M = (2880.0, 3010.0)
#: Floor half-widths: valley at the runway, valley beyond the bend, valley north-east,
#: runway corridor at its south-west end.
VALLEY_FLOOR_HALF_WIDTH_M = {"runway": 1000.0, "bend": 1800.0, "north_east": 1300.0,
                             "corridor": 1300.0}
#: Wall shape: rise = (crest - floor) * (1 - exp(-x^2 / (2 L^2))), x beyond the floor edge.
VALLEY_WALL_L_M = 950.0
VALLEY_CREST_M = 5250.0
VALLEY_CREST_VAR_M = 300.0
VALLEY_ROUGH_M = 250.0
VALLEY_SEED = 20_061_003  # fixed: the roughness is part of the model's definition
#: Broad peaks: (name, height m, range m and bearing deg from the ARP, flank slope, cap radius m).
VALLEY_PEAKS = (("Namcha Barwa", 7782.0, 79e3, 62.0, 0.30, 2000.0),
                ("Gyala Peri", 7294.0, 84e3, 47.0, 0.30, 2000.0))


def _smoothstep(t: NDArray) -> NDArray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


class _ValleyGeometry:
    """The valley's coordinates on the equirectangular map about the RWY05 threshold."""

    def __init__(self) -> None:
        t05, t23 = airport.RWY05, airport.RWY23
        self.map = AnchoredMap(t05.lat_deg, t05.lon_deg)
        x23, y23 = self.map.xy(t23.lat_deg, t23.lon_deg)
        L = math.hypot(x23, y23)
        self.u = np.array([x23, y23]) / L  # along the runway (north-east)
        self.v = np.array([self.u[1], -self.u[0]])  # right of it (south-east)
        self.a23 = L
        self.floor_slope = (t23.h - t05.h) / L
        # Centreline offset g(a) from the straight extended axis: g' = tan(theta(a)).
        a = np.arange(-400e3, VALLEY_BEND_START_M + 1.0, 25.0)
        th = self.theta(a)
        tan = np.tan(th)
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (tan[1:] + tan[:-1]) * np.diff(a))])
        self._ga, self._gv = a, cum - cum[-1]

    @staticmethod
    def theta(a: NDArray) -> NDArray:
        t = (VALLEY_BEND_START_M - np.asarray(a, float)) / (VALLEY_BEND_START_M - VALLEY_BEND_END_M)
        return math.radians(VALLEY_FAR_COURSE_DEG - VALLEY_RUNWAY_COURSE_DEG) * _smoothstep(t)

    def g(self, a: NDArray) -> NDArray:
        return np.interp(a, self._ga, self._gv, right=0.0)

    def half_width(self, a: NDArray) -> NDArray:
        w = VALLEY_FLOOR_HALF_WIDTH_M
        sw = _smoothstep((-4000.0 - np.asarray(a)) / 10000.0)
        ne = _smoothstep((np.asarray(a) - 8000.0) / 8000.0)
        return w["runway"] + (w["bend"] - w["runway"]) * sw + (w["north_east"] - w["runway"]) * ne

    def floor(self, a: NDArray) -> NDArray:
        return np.clip(airport.RWY05.h + self.floor_slope * np.asarray(a), *VALLEY_FLOOR_BAND_M)

    def corridor_excess(self, a: NDArray, c: NDArray) -> NDArray:
        """Distance (m) beyond the runway corridor's floor edge (negative inside)."""
        w = VALLEY_FLOOR_HALF_WIDTH_M
        half = w["runway"] + (w["corridor"] - w["runway"]) * _smoothstep((-2000.0 - a) / 10000.0)
        # tapers shut over ~4 km beyond its end
        return np.abs(c) - half + 0.35 * np.maximum(VALLEY_RUNWAY_CORRIDOR_END_M - a, 0.0)

    def along_cross(self, x: NDArray, y: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """Along-axis coordinate (m from THR05), signed distance from the valley
        centreline and from the straight runway axis (m, positive south-east)."""
        a = x * self.u[0] + y * self.u[1]
        c = x * self.v[0] + y * self.v[1]
        return a, (c - self.g(a)) * np.cos(self.theta(a)), c


@functools.lru_cache(maxsize=None)
def _valley_geometry() -> _ValleyGeometry:
    return _ValleyGeometry()


def valley_centreline(along_m: ArrayLike) -> tuple[NDArray, NDArray]:
    """Points on the synthetic valley's floor centreline: ``(lat_deg, lon_deg)``.

    ``along_m`` is the distance along the runway course from the RWY05 threshold
    (negative to the south-west). For ``along_m >= VALLEY_BEND_START_M`` (-4 km) the
    centreline is the runway centreline; between -4 and -12 km its heading turns
    smoothly (smoothstep in angle, least radius ~15 km) from 054.65 deg to 075 deg, so
    far south-west the valley comes from the WSW (bearing 255 deg): an RNP path can
    follow it and be on the runway course 4-8 km out. A straight-in final stays on
    the floor of the separate runway corridor (to 16 km out, tapering shut by ~20 km). Exactly: centreline = straight axis point at ``along_m`` plus ``g(along_m)`` metres to the
    right (south-east) of the runway course on the local equirectangular map, with
    ``g' = tan(theta)``, ``theta`` the heading change.
    """
    geo = _valley_geometry()
    a = np.asarray(along_m, float)
    g = geo.g(a)
    x = a * geo.u[0] + g * geo.v[0]
    y = a * geo.u[1] + g * geo.v[1]
    return geo.map.latlon(x, y)


def valley_axis_heading_deg(along_m: ArrayLike) -> NDArray:
    """Heading (true, deg, pointing north-east) of the valley centreline at ``along_m``."""
    return VALLEY_RUNWAY_COURSE_DEG + np.degrees(_ValleyGeometry.theta(along_m))


def valley_floor_half_width_m(along_m: ArrayLike) -> NDArray:
    """Half-width of the flat valley floor (no roughness there) at ``along_m``, m.

    Outside along -20 .. +4 km spurs move the wall edge in or out by up to 400 m.
    """
    return _valley_geometry().half_width(along_m)


def _noise_field(rng: np.random.Generator, shape: tuple[int, int], sigma_cells: float) -> NDArray:
    f = ndimage.gaussian_filter(rng.standard_normal(shape), sigma_cells, mode="wrap")
    return f / f.std()


def valley_height_xy(x: NDArray, y: NDArray) -> NDArray:
    """The synthetic valley's defining height function on its map (x east, y north, m).

    Heights m. Floor (no roughness), walls rising to crests of
    ``VALLEY_CREST_M +- VALLEY_CREST_VAR_M`` with ``+-VALLEY_ROUGH_M`` spur roughness
    (fixed-seed smooth noise on a 500 m lattice), and the two broad peaks.
    """
    geo = _valley_geometry()
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    a, c, c_axis = geo.along_cross(x, y)
    floor = geo.floor(a)
    big, small, spur = _valley_noise(x, y)
    # Distance beyond the floor edge of the union of the valley and the runway corridor.
    xw = np.minimum(np.abs(c) - geo.half_width(a), geo.corridor_excess(a, c_axis))
    # Spurs: the wall edge moves in and out by up to 400 m, except along the approaches
    # and runway (along -20 .. +4 km) where the floor is kept as designed.
    keep = _smoothstep((-20000.0 - a) / 3000.0) + _smoothstep((a - 4000.0) / 3000.0)
    xw = np.maximum(xw + 400.0 * np.tanh(spur) * keep, 0.0)
    crest = VALLEY_CREST_M + VALLEY_CREST_VAR_M * np.tanh(big)
    rise = 1.0 - np.exp(-0.5 * (xw / VALLEY_WALL_L_M) ** 2)
    # Ridged noise (1 - 2|n|) has sharp crests along the noise's zero lines: spurs.
    rough = VALLEY_ROUGH_M * (1.0 - 2.0 * np.abs(np.tanh(small))) * \
        (1.0 - np.exp(-0.5 * (xw / 600.0) ** 2))
    h = floor + (crest - floor) * rise + rough
    for _, P, rng_m, brg, slope, r0 in VALLEY_PEAKS:
        px, py = _peak_xy(rng_m, brg)
        r = np.hypot(x - px, y - py)
        h = np.maximum(h, P - slope * (np.sqrt(r * r + r0 * r0) - r0))
    return h


@functools.lru_cache(maxsize=None)
def _peak_xy(range_m: float, bearing_deg: float) -> tuple[float, float]:
    lat, lon = pymap3d.vincenty.vreckon(airport.ARP_LAT_DEG, airport.ARP_LON_DEG, range_m, bearing_deg)
    x, y = _valley_geometry().map.xy(float(lat), float(lon))
    return float(x), float(y)


_NOISE_LATTICE_M = 500.0
_NOISE_HALF_M = 160e3


@functools.lru_cache(maxsize=None)
def _noise_lattice() -> tuple[NDArray, NDArray, NDArray]:
    rng = np.random.default_rng(VALLEY_SEED)
    n = int(2 * _NOISE_HALF_M / _NOISE_LATTICE_M) + 1
    return (_noise_field(rng, (n, n), 12.0), _noise_field(rng, (n, n), 2.5),
            _noise_field(rng, (n, n), 5.0))


def _valley_noise(x: NDArray, y: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    coords = np.stack([(y + _NOISE_HALF_M) / _NOISE_LATTICE_M, (x + _NOISE_HALF_M) / _NOISE_LATTICE_M])
    return tuple(ndimage.map_coordinates(f, coords, order=1, mode="nearest") for f in _noise_lattice())


#: Grid of the rasterised valley: spacing (arc-seconds) and half extents (deg) about THR05.
VALLEY_GRID_ARCSEC = 3.0
VALLEY_HALF_EXTENT_DEG = (0.9, 1.0)


@functools.lru_cache(maxsize=2)
def _valley_grid(spacing_arcsec: float, half_lat: float, half_lon: float
                 ) -> tuple[NDArray, NDArray, NDArray]:
    t05 = airport.RWY05
    d = spacing_arcsec / 3600.0
    nlat, nlon = int(round(half_lat / d)), int(round(half_lon / d))
    lat = t05.lat_deg + d * np.arange(-nlat, nlat + 1)
    lon = t05.lon_deg + d * np.arange(-nlon, nlon + 1)
    geo = _valley_geometry()
    x, y = geo.map.xy(lat[:, None], lon[None, :])
    rows = []
    for i0 in range(0, lat.size, 256):  # bound temporaries
        xx, yy = np.broadcast_arrays(x, y[i0:i0 + 256])
        rows.append(valley_height_xy(xx, yy).astype(np.float32))
    return lat, lon, np.concatenate(rows)


class LinZhiSyntheticValley(GridTerrain):
    """SYNTHETIC terrain around ZUNZ built from the published figures
    (docs/design/physics-notes.md §the-synthetic-valley).

    Not a survey: a valley along the runway course (054.65 deg true) through both
    thresholds, floor 2939 m at THR05 rising linearly to 2948 m at THR23 (then
    continuing at 3 m/km, clipped to 2880-3010 m), flat floor half-width 1.0 km at
    the runway (1.8 km in the south-western bend, 1.3 km north-east; plus a straight
    runway corridor to 16 km out for straight-in finals), walls rising
    as ``(crest - floor)(1 - exp(-x^2/2L^2))`` with L = 950 m beyond the floor edge,
    so the 4000 m contours are ~4 km apart at the runway; crests 4950-5550 m plus
    +-250 m fixed-seed roughness (5000-6000 m class); 4-12 km south-west of the
    threshold the valley turns to come from the WSW (see :func:`valley_centreline`); Namcha
    Barwa (7782 m, 79 km at 062 deg) and Gyala Peri (7294 m, 84 km at 047 deg) as
    broad cones (flanks 0.3, i.e. 17 deg). Rasterised on a 3" grid (~90 x 81 m)
    +-0.9 deg lat, +-1.0 deg lon about THR05 (about +-100 km); heights WGS84
    ellipsoidal. Built once per process (~1-2 s) and shared.
    """

    def __init__(self, max_range_m: float = 150e3) -> None:
        lat, lon, H = _valley_grid(VALLEY_GRID_ARCSEC, *VALLEY_HALF_EXTENT_DEG)
        super().__init__(lat, lon, H, name="LinZhi synthetic valley (SYNTHETIC)",
                         synthetic=True, fill_voids=False, max_range_m=max_range_m,
                         source="LinZhiSyntheticValley",
                         description=("SYNTHETIC terrain, not a survey: a valley along runway 05/23 "
                                      "at ZUNZ built from published figures (floor ~2940 m, 4000 m "
                                      "walls ~2 km either side, crests 5000-6000 m, Namcha Barwa and "
                                      "Gyala Peri as broad peaks)."))
