"""Terrain models, line of sight, sky visibility and horizon masks.

Every model is a :class:`Terrain`: a height field ``h(lat, lon)`` (WGS84
ellipsoidal metres; the testbed has no geoid) with vectorised queries:

* :meth:`Terrain.height` ``(lat_deg, lon_deg) -> h``, broadcasting; a scalar
  call on a grid model is a few microseconds (the flight loop's AGL);
* :meth:`Terrain.line_of_sight` ``(origin_ecef (...,3), target_ecef (...,3)) -> (...) bool``;
* :meth:`Terrain.sky_visible` ``(origin_ecef (...,3), direction_ecef (...,3)) -> (...) bool``;
* :meth:`Terrain.horizon` ``(lat, lon, h, azimuth_rad (K,)) -> elevation_rad (K,)``;
* :meth:`Terrain.mesh` ``(frame, half_size_m, spacing_m) -> (vertices_enu (V,3), triangles (F,3))``.

Models: :class:`Flat`, :class:`TwoRidges` (the VA-RAIM paper's terrain),
:class:`GridTerrain` (a regular lat/lon grid: SRTM ``.hgt`` or ``.npz``), and
:class:`~testbed.world.valley.LinZhiSyntheticValley` (the embedded default, SYNTHETIC, rasterised
on a grid).

How rays are tested (the Earth's curvature is exact, not approximated):
a ray is sampled at ``step_m`` (half the terrain resolution). Exact geodetic
coordinates are computed at *knots* every ``KNOT_SAMPLES`` samples (~1.3 km on
the valley grid); between knots latitude, longitude and height are linear in
range (error < K^2/(8R) ~ 0.05 m). Before sampling, each ray is clipped to the
part that lies below the model's maximum height (a conservative sphere bound),
and a knot-to-knot segment is only sampled when its lowest point is below an
upper bound of the terrain around it (for grids: block maxima); everything is
batched over rays. A ray is blocked when a sample has ray height < terrain
height. Sampling can miss a grazing contact between samples: a disagreement
with a dense brute-force march needs a clearance within (steepest slope x half a
step) of zero (<= 50 m on the valley; measured: 0 of 1000 landmark rays and 0 of
1000 sky rays at 0-30 deg elevation disagree with a 1-2 m brute-force march).
Rays leaving a grid model's extent see no terrain beyond it; the antimeridian
is not handled.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from testbed.frames import WGS84, LocalFrame
from testbed.world import airport
from testbed.world.dem import check_regular, fill_voids_nearest, read_hgt_mosaic, read_npz

_A = WGS84.semimajor_axis
_E2 = 1.0 - (WGS84.semiminor_axis / WGS84.semimajor_axis) ** 2
#: Sphere radius used to clip rays to "below the maximum terrain height". It is larger
#: than every radius of curvature of the WGS84 ellipsoid (max a^2/b = 6 399 594 m), so the
#: sphere under-estimates a ray's ellipsoidal height: the clip is conservative.
_R_CLIP = 6.41e6
#: Height slack of the clip and of the segment skip test, m (covers knot interpolation).
_CLIP_SLACK_M = 2.0
#: Rays whose samples exceed this count are processed in chunks (memory bound).
_CHUNK_SAMPLES = 600_000
#: Range windows (m) marched one after the other; blocked rays stop after their window.
_RANGE_WINDOWS_M = ((0.0, 8e3), (8e3, 30e3), (30e3, np.inf))


def radii_of_curvature(lat_deg: ArrayLike) -> tuple[NDArray, NDArray]:
    """Meridian ``M`` and prime-vertical ``N`` radii of curvature (m) of WGS84 at ``lat_deg``."""
    s2 = np.sin(np.radians(np.asarray(lat_deg, float))) ** 2
    w = np.sqrt(1.0 - _E2 * s2)
    return _A * (1 - _E2) / w**3, _A / w


_B = WGS84.semiminor_axis
_EP2 = _E2 / (1.0 - _E2)


def ecef_to_geodetic_fast(pos_ecef: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """ECEF ``(..., 3)`` to ``(lat_deg, lon_deg, h)`` by Bowring's closed form (one step).

    Sub-millimetre for heights below ~100 km (checked against pymap3d in the tests);
    a few times cheaper than the general conversion, and without its per-call
    overhead, which matters for single-ray queries.
    """
    x, y, z = pos_ecef[..., 0], pos_ecef[..., 1], pos_ecef[..., 2]
    p = np.hypot(x, y)
    th = np.arctan2(z * _A, p * _B)
    st, ct = np.sin(th), np.cos(th)
    lat = np.arctan2(z + _EP2 * _B * st**3, p - _E2 * _A * ct**3)
    sl, cl = np.sin(lat), np.cos(lat)
    h = p * cl + z * sl - _A * np.sqrt(1.0 - _E2 * sl * sl)
    return np.degrees(lat), np.degrees(np.arctan2(y, x)), h


def _up_ecef(lat_deg: NDArray, lon_deg: NDArray) -> NDArray:
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1)


def _as_vec3(x: ArrayLike, name: str) -> NDArray:
    a = np.asarray(x, float)
    if a.shape[-1:] != (3,):
        raise ValueError(f"{name}: expected shape (..., 3), got {a.shape}")
    return a


class Terrain:
    """A terrain height field with batched line-of-sight queries (base class).

    Subclasses provide :meth:`_height_ab` on internal coordinates ``(a, b)``
    given by :meth:`_param` (identity: latitude/longitude in degrees), the
    attributes below, and optionally :meth:`_bound_ab` (an upper bound of the
    terrain within one knot spacing of a point; default ``h_max``).

    Attributes
    ----------
    name, description : str.  synthetic : bool (True: invented terrain, say so on plots).
    h_max : float, m, an upper bound of the terrain height everywhere.
    step_m : float, m, sampling step along rays (about half the resolution).
    max_range_m : float, m, how far :meth:`sky_visible` and :meth:`horizon` look.
    """

    name: str = "terrain"
    description: str = ""
    synthetic: bool = True
    h_max: float = 0.0
    step_m: float = 50.0
    max_range_m: float = 150e3
    #: Samples between knots (exact geodetic conversion at knots, linear between).
    KNOT_SAMPLES: int = 32

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, synthetic={self.synthetic})"

    # -- subclass hooks --------------------------------------------------------------
    def _param(self, lat_deg: NDArray, lon_deg: NDArray) -> tuple[NDArray, NDArray]:
        return lat_deg, lon_deg

    def _height_ab(self, a: NDArray, b: NDArray) -> NDArray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _bound_ab(self, a: NDArray, b: NDArray) -> NDArray:
        return np.full(np.shape(a), self.h_max)

    # -- heights ---------------------------------------------------------------------
    def height(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray | float:
        """Terrain height (m, WGS84 ellipsoidal) at geodetic points; inputs broadcast.

        NaN outside the model's extent. A scalar call returns a float.
        """
        lat, lon = np.broadcast_arrays(np.asarray(lat_deg, float), np.asarray(lon_deg, float))
        h = self._height_ab(*self._param(lat, lon))
        return float(h) if h.ndim == 0 else h

    # -- rays ------------------------------------------------------------------------
    def ray_clearance(self, origin_ecef: ArrayLike, direction_ecef: ArrayLike,
                      s_min: ArrayLike, s_max: ArrayLike) -> NDArray:
        """Lowest sampled clearance (ray height minus terrain height, m) along rays.

        Parameters
        ----------
        origin_ecef : (..., 3) m.  direction_ecef : (..., 3) unit vectors (normalised here).
        s_min, s_max : (...) m, the range interval of each ray that is tested.

        Returns
        -------
        (...) m. Negative: the ray is blocked and this is a sampled penetration (the
        deepest within the nearest range window where one was found). Non-negative: the ray clears, by at least this much (segments far
        above the terrain are bounded, not sampled); ``+inf`` when the tested part never
        comes below the model's maximum height or lies outside the model. NaN for
        non-finite inputs.
        """
        o = _as_vec3(origin_ecef, "origin_ecef")
        d = _as_vec3(direction_ecef, "direction_ecef")
        o, d, s0, s1 = np.broadcast_arrays(o, d, np.asarray(s_min, float)[..., None],
                                           np.asarray(s_max, float)[..., None])
        shape = o.shape[:-1]
        o, d = o.reshape(-1, 3), d.reshape(-1, 3)
        s0, s1 = s0[..., 0].reshape(-1), s1[..., 0].reshape(-1)
        norm = np.linalg.norm(d, axis=-1)
        good = np.isfinite(o).all(-1) & np.isfinite(d).all(-1) & np.isfinite(s0) & \
            np.isfinite(s1) & (norm > 0)
        out = np.full(o.shape[0], np.nan)
        out[good] = self._clearance(o[good], d[good] / norm[good, None], s0[good], s1[good])
        return out.reshape(shape)

    def line_of_sight(self, origin_ecef: ArrayLike, target_ecef: ArrayLike,
                      margin_m: float = 1.0) -> NDArray:
        """True where the straight segment origin -> target clears the terrain.

        Parameters
        ----------
        origin_ecef, target_ecef : (..., 3) m, broadcast.
        margin_m : the last and first ``margin_m`` of each segment are not tested, so a
            point lying on the surface (a landmark) does not mask itself.

        Returns
        -------
        (...) bool. False for non-finite inputs; True for segments shorter than
        ``2 * margin_m``.
        """
        o = _as_vec3(origin_ecef, "origin_ecef")
        t = _as_vec3(target_ecef, "target_ecef")
        v = t - o
        L = np.linalg.norm(v, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            d = v / L[..., None]
        c = self.ray_clearance(o, d, np.minimum(margin_m, L / 2), np.maximum(L - margin_m, L / 2))
        c = np.where(L <= 2 * margin_m, np.inf, c)  # nothing left to test between the margins
        return np.asarray(np.nan_to_num(c, nan=-1.0) >= 0.0)

    def sky_visible(self, origin_ecef: ArrayLike, direction_ecef: ArrayLike,
                    margin_m: float = 1.0) -> NDArray:
        """True where the ray from ``origin_ecef`` along ``direction_ecef`` clears the terrain.

        For satellites (effectively at infinity). The ray is tested from ``margin_m`` to
        ``max_range_m`` (terrain beyond the model's extent is not modelled).

        Parameters
        ----------
        origin_ecef : (..., 3) m.  direction_ecef : (..., 3), normalised here; broadcast.

        Returns
        -------
        (...) bool. False for non-finite inputs.
        """
        o = _as_vec3(origin_ecef, "origin_ecef")
        c = self.ray_clearance(o, direction_ecef, margin_m, self.max_range_m)
        return np.asarray(np.nan_to_num(c, nan=-1.0) >= 0.0)

    def _clearance(self, o: NDArray, d: NDArray, s0: NDArray, s1: NDArray) -> NDArray:
        """Kernel of :meth:`ray_clearance` on flat arrays ``(n, 3)``, ``(n,)``."""
        n = o.shape[0]
        out = np.full(n, np.inf)
        if n == 0:
            return out
        # Clip each ray to where a sphere of radius _R_CLIP (tangent below the origin)
        # puts it under h_max: |o + s d - C| <= R + H  <=>  s^2 + 2 b s + c <= 0.
        lat0, lon0, h0 = ecef_to_geodetic_fast(o)
        sin_eps = np.einsum("ij,ij->i", d, _up_ecef(lat0, lon0))
        rho = _R_CLIP + h0
        b = rho * sin_eps
        c = rho**2 - (_R_CLIP + self.h_max + _CLIP_SLACK_M) ** 2
        disc = b * b - c
        root = np.sqrt(np.maximum(disc, 0.0))
        lo = np.maximum(s0, -b - root)
        hi = np.minimum(s1, -b + root)
        alive = (disc >= 0) & (hi >= lo)
        K = self.KNOT_SAMPLES * self.step_m
        # Range windows, nearest first: a ray found blocked is not marched further
        # (most low rays in a valley hit the nearest wall).
        for w0, w1 in _RANGE_WINDOWS_M:
            wlo = np.maximum(lo, w0)
            whi = np.minimum(hi, w1)
            active = np.flatnonzero(alive & (whi >= wlo) & ~(out < 0))
            if active.size:
                out[active] = np.minimum(out[active], self._march_chunks(
                    o[active], d[active], wlo[active], whi[active], K))
        return out

    def _march_chunks(self, o: NDArray, d: NDArray, lo: NDArray, hi: NDArray, K: float) -> NDArray:
        m = self.KNOT_SAMPLES
        nseg = np.maximum(np.ceil((hi - lo) / K).astype(np.int64), 1)
        # Chunk rays so that (knots x samples per segment) stays bounded.
        budget = max(1, _CHUNK_SAMPLES // (m + 1))
        csum = np.cumsum(nseg)
        out = np.empty(o.shape[0])
        start = 0
        while start < o.shape[0]:
            stop = int(np.searchsorted(csum, (csum[start - 1] if start else 0) + budget, "right"))
            stop = max(stop, start + 1)
            sl = slice(start, stop)
            out[sl] = self._march(o[sl], d[sl], lo[sl], hi[sl], nseg[sl], K)
            start = stop
        return out

    def _march(self, o: NDArray, d: NDArray, lo: NDArray, hi: NDArray, nseg: NDArray,
               K: float) -> NDArray:
        m = self.KNOT_SAMPLES
        nk = nseg + 1
        koff = np.concatenate([[0], np.cumsum(nk)[:-1]])
        ray_k = np.repeat(np.arange(o.shape[0]), nk)
        q = np.arange(nk.sum()) - np.repeat(koff, nk)
        sk = lo[ray_k] + q * K
        lat, lon, hk = ecef_to_geodetic_fast(o[ray_k] + sk[:, None] * d[ray_k])
        ak, bk = self._param(lat, lon)
        # Segments k -> k+1 (drop each ray's last knot as a segment start).
        seg = np.flatnonzero(q < np.repeat(nseg, nk))
        gap = np.minimum(hk[seg], hk[seg + 1]) - _CLIP_SLACK_M - self._bound_ab(ak[seg], bk[seg])
        out = np.full(o.shape[0], np.inf)
        skip = gap >= 0
        np.minimum.at(out, ray_k[seg[skip]], gap[skip])  # clears by at least this much
        suspect = seg[~skip]
        if suspect.size == 0:
            return out
        ray = ray_k[suspect]
        # (n, m+1) fractions within each segment; samples past the ray's end sit on
        # the end point, so the end itself is always tested.
        t = np.minimum(np.arange(m + 1) / m, ((hi[ray] - sk[suspect]) / K)[:, None])
        a = ak[suspect, None] + t * (ak[suspect + 1] - ak[suspect])[:, None]
        bb = bk[suspect, None] + t * (bk[suspect + 1] - bk[suspect])[:, None]
        hr = hk[suspect, None] + t * (hk[suspect + 1] - hk[suspect])[:, None]
        ht = self._height_ab(a, bb)
        valid = np.isfinite(ht)
        clr = np.where(valid, hr - np.where(valid, ht, 0.0), np.inf).min(axis=1)
        np.minimum.at(out, ray, clr)
        return out

    # -- horizon ---------------------------------------------------------------------
    def horizon(self, lat_deg: float, lon_deg: float, h: float, azimuth_rad: ArrayLike,
                max_range_m: float | None = None, step_m: float | None = None) -> NDArray:
        """Terrain elevation angle by azimuth seen from a point: the horizon mask.

        Parameters
        ----------
        lat_deg, lon_deg, h : the observer (deg, deg, m ellipsoidal).
        azimuth_rad : (K,) from north, clockwise.
        max_range_m : how far to look (default ``max_range_m``).  step_m : largest range
            step (default ``step_m``); nearer than ``100 * step_m`` the step is 1 % of the
            range (at least 1 m), so a near wall's angle is resolved to ~0.5 % of its slope.

        Returns
        -------
        (K,) rad: the largest elevation (in the observer's local ENU frame; geometric,
        Earth curvature included, no refraction) of any terrain point within range;
        NaN where no terrain is modelled along that azimuth.
        """
        az = np.atleast_1d(np.asarray(azimuth_rad, float))
        rmax = self.max_range_m if max_range_m is None else float(max_range_m)
        dr = self.step_m if step_m is None else float(step_m)
        frame = LocalFrame(lat_deg, lon_deg, h)
        r = _horizon_ranges(dr, rmax)
        out = np.full(az.shape, -np.inf)
        for chunk in np.array_split(np.arange(az.size), max(1, az.size * r.size // 400_000)):
            a = az[chunk, None]
            foot_enu = np.stack(np.broadcast_arrays(r * np.sin(a), r * np.cos(a), 0.0 * a), -1)
            flat, flon, _ = frame.enu_to_geodetic(foot_enu)
            ht = self.height(flat, flon)
            ok = np.isfinite(ht)
            p = frame.geodetic_to_enu(flat, flon, np.where(ok, ht, 0.0))
            el = np.arctan2(p[..., 2], np.hypot(p[..., 0], p[..., 1]))
            out[chunk] = np.where(ok, el, -np.inf).max(axis=1)
        return np.where(np.isfinite(out), out, np.nan)

    # -- visualisation ---------------------------------------------------------------
    def mesh(self, frame: LocalFrame, half_size_m: float, spacing_m: float
             ) -> tuple[NDArray, NDArray]:
        """A triangle mesh of the terrain around ``frame``'s origin, for Rerun's ``Mesh3D``.

        Parameters
        ----------
        frame : the world frame; vertices are in its ENU coordinates.
        half_size_m : the square covers east and north in ``[-half_size_m, half_size_m]``.
        spacing_m : vertex spacing in the frame's horizontal plane.

        Returns
        -------
        vertices_enu : (V, 3) float64 m.  triangles : (F, 3) uint32 vertex indices
        (counter-clockwise seen from above). Cells with no terrain are left out.
        """
        if not (half_size_m > 0 and spacing_m > 0):
            raise ValueError(f"mesh: half_size_m and spacing_m must be > 0, got "
                             f"{half_size_m}, {spacing_m}")
        n = int(math.ceil(2 * half_size_m / spacing_m)) + 1
        x = np.linspace(-half_size_m, half_size_m, n)
        E, N = np.meshgrid(x, x)  # rows north, columns east
        lat, lon, _ = frame.enu_to_geodetic(np.stack([E, N, np.zeros_like(E)], -1))
        ht = self.height(lat, lon)
        ok = np.isfinite(ht)
        verts = frame.geodetic_to_enu(lat, lon, np.where(ok, ht, 0.0)).reshape(-1, 3)
        idx = np.arange(n * n).reshape(n, n)
        v00, v01, v10, v11 = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
        tri = np.concatenate([np.stack([v00, v01, v11], -1).reshape(-1, 3),
                              np.stack([v00, v11, v10], -1).reshape(-1, 3)])
        okf = ok.reshape(-1)
        tri = tri[okf[tri].all(axis=1)]
        used = np.zeros(n * n, bool)
        used[tri.reshape(-1)] = True
        remap = np.cumsum(used) - 1
        return verts[used], remap[tri].astype(np.uint32)


# ------------------------------------------------------------------------------------
# Analytic models
# ------------------------------------------------------------------------------------
def _horizon_ranges(dr: float, rmax: float, rel: float = 0.01, r0: float = 1.0) -> NDArray:
    """Ranges 1 m .. rmax: steps of ``rel * r`` (>= 1 m) up to ``dr``, then ``dr``."""
    r_lin0 = dr / rel
    n_small = int(r_lin0 / r0)
    small = np.arange(1, min(n_small, 100) + 1) * r0  # 1 m steps to 100 m
    geo = np.geomspace(small[-1], max(r_lin0, small[-1]), max(2, int(np.log(max(r_lin0 / small[-1], 1.0))
                                                                      / np.log1p(rel)) + 1))[1:]
    lin = np.arange(geo[-1] + dr if geo.size else small[-1] + dr, rmax + 0.5 * dr, dr)
    r = np.concatenate([small, geo, lin])
    return r[r <= rmax + 0.5 * dr]


class AnchoredMap:
    """Equirectangular map about an anchor: x east, y north (m), linear in lon/lat.

    Used to *define* analytic terrains; it is not a geodetic conversion (its scale
    error grows with distance, which does not matter for a height field defined on it).
    """

    def __init__(self, lat_deg: float, lon_deg: float) -> None:
        self.lat0, self.lon0 = float(lat_deg), float(lon_deg)
        M, N = radii_of_curvature(self.lat0)
        self.ky = float(M) * math.pi / 180.0  # m per degree of latitude
        self.kx = float(N) * math.cos(math.radians(self.lat0)) * math.pi / 180.0

    def xy(self, lat_deg: NDArray, lon_deg: NDArray) -> tuple[NDArray, NDArray]:
        return (lon_deg - self.lon0) * self.kx, (lat_deg - self.lat0) * self.ky

    def latlon(self, x: NDArray, y: NDArray) -> tuple[NDArray, NDArray]:
        return self.lat0 + np.asarray(y) / self.ky, self.lon0 + np.asarray(x) / self.kx


class Flat(Terrain):
    """Constant height ``h`` (m ellipsoidal) everywhere; for tests."""

    synthetic = True

    def __init__(self, h: float = airport.ELEVATION_M, max_range_m: float = 150e3) -> None:
        self.h = float(h)
        self.h_max = self.h
        self.step_m = 100.0
        self.max_range_m = float(max_range_m)
        self.name = f"flat {self.h:.0f} m"
        self.description = f"SYNTHETIC flat terrain at {self.h:.1f} m (WGS84 ellipsoidal)."

    def _height_ab(self, a: NDArray, b: NDArray) -> NDArray:
        return np.full(np.shape(a), self.h)

    def height(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray | float:
        if isinstance(lat_deg, float) and isinstance(lon_deg, float):
            return self.h
        return super().height(lat_deg, lon_deg)


class TwoRidges(Terrain):
    """The VA-RAIM paper's terrain: two ridges parallel to the approach course.

    The VA-RAIM paper §3.1 says "two mountain chains of unified height 1000 m, 3000 m east
    and west of the centre"; taken literally the western chain stands in the
    approach path, so (docs/design/physics-notes.md §va-raim-scenario-terrain) we read them
    as two ridges *parallel to the approach course*, their crests ``offset_m``
    to either side of the centre.

    Cross-section (our assumption, the paper gives none): a flat floor at the
    centre's height ``h_field``; each ridge is a raised cosine
    ``h_field + height_m * cos^2(pi * u / base_width_m)`` for ``|u| < base_width_m / 2``,
    ``u`` being the cross-course distance from its crest; the ridges are uniform
    along the course and unbounded. Distances are on a local equirectangular map
    about the centre (so for course 090 the crests follow parallels of latitude).
    """

    synthetic = True

    def __init__(self, centre_lat_deg: float = airport.VA_RAIM_CENTRE[0],
                 centre_lon_deg: float = airport.VA_RAIM_CENTRE[1],
                 h_field: float = airport.VA_RAIM_CENTRE[2], offset_m: float = 3000.0,
                 height_m: float = 1000.0, course_deg: float = 90.0,
                 base_width_m: float = 2000.0, max_range_m: float = 150e3) -> None:
        if not (0 < base_width_m <= 2 * offset_m):
            raise ValueError(f"TwoRidges: base_width_m must be in (0, 2*offset_m], got {base_width_m}")
        self.map = AnchoredMap(centre_lat_deg, centre_lon_deg)
        self.h_field, self.offset_m, self.height_m = float(h_field), float(offset_m), float(height_m)
        self.course = math.radians(course_deg)
        self.base_width_m = float(base_width_m)
        self.h_max = self.h_field + max(self.height_m, 0.0)
        self.step_m = self.base_width_m / 40
        self.max_range_m = float(max_range_m)
        self.name = "two ridges (VA-RAIM paper)"
        self.description = (
            f"SYNTHETIC: two raised-cosine ridges {self.height_m:.0f} m above {self.h_field:.0f} m, "
            f"crests {self.offset_m:.0f} m either side of ({centre_lat_deg:.4f}, {centre_lon_deg:.4f}), "
            f"parallel to course {course_deg:.1f} deg, base width {self.base_width_m:.0f} m.")

    def _height_ab(self, a: NDArray, b: NDArray) -> NDArray:
        x, y = self.map.xy(a, b)
        c = x * math.cos(self.course) - y * math.sin(self.course)  # right of course
        u = np.abs(np.abs(c) - self.offset_m)
        bump = np.where(u < self.base_width_m / 2, np.cos(np.pi * u / self.base_width_m) ** 2, 0.0)
        return self.h_field + self.height_m * bump

    def height(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray | float:
        if isinstance(lat_deg, float) and isinstance(lon_deg, float):  # the flight loop's fast path
            x = (lon_deg - self.map.lon0) * self.map.kx
            y = (lat_deg - self.map.lat0) * self.map.ky
            u = abs(abs(x * math.cos(self.course) - y * math.sin(self.course)) - self.offset_m)
            if u >= self.base_width_m / 2:
                return self.h_field
            return self.h_field + self.height_m * math.cos(math.pi * u / self.base_width_m) ** 2
        return super().height(lat_deg, lon_deg)


# ------------------------------------------------------------------------------------
# Grids
# ------------------------------------------------------------------------------------
class GridTerrain(Terrain):
    """Heights on a regular latitude/longitude grid, bilinear in (lat, lon).

    Parameters
    ----------
    lat_deg : (M,) ascending, evenly spaced.  lon_deg : (N,) ascending, evenly spaced.
    height_m : (M, N) m, treated as WGS84 ellipsoidal (see :mod:`testbed.world.dem`).
        NaN voids are filled from the nearest valid sample when ``fill_voids``,
        otherwise they stay NaN (no terrain: never blocks a ray).
    Outside the grid the height is NaN and nothing blocks rays.
    """

    #: Block size (cells) of the max-pyramid used to skip ray segments well above ground.
    BLOCK = 16

    def __init__(self, lat_deg: ArrayLike, lon_deg: ArrayLike, height_m: ArrayLike, *,
                 name: str = "grid", description: str = "", synthetic: bool = False,
                 fill_voids: bool = True, max_range_m: float = 150e3, source: str = "grid") -> None:
        lat = np.array(lat_deg, float)
        lon = np.array(lon_deg, float)
        H = np.asarray(height_m)
        if not np.issubdtype(H.dtype, np.floating):
            H = H.astype(float)
        if lat.ndim != 1 or lon.ndim != 1 or H.shape != (lat.size, lon.size) or min(H.shape) < 2:
            raise ValueError(f"{source}: expected lat_deg (M,), lon_deg (N,), height_m (M, N) with "
                             f"M, N >= 2; got {lat.shape}, {lon.shape}, {H.shape}")
        check_regular(lat, f"{source}: lat_deg")
        check_regular(lon, f"{source}: lon_deg")
        self.n_void = int((~np.isfinite(H)).sum())
        if fill_voids:
            H = fill_voids_nearest(H)
        if not np.isfinite(H).any():
            raise ValueError(f"{source}: the grid has no valid heights")
        self.lat_deg, self.lon_deg = lat, lon
        self._H = np.array(H, dtype=np.float32, order="C")  # a copy: never alias the input
        self._H.setflags(write=False)
        self._Hflat = self._H.reshape(-1)
        self._M, self._N = H.shape
        self._lat0, self._lon0 = float(lat[0]), float(lon[0])
        self._dlat = (float(lat[-1]) - self._lat0) / (self._M - 1)
        self._dlon = (float(lon[-1]) - self._lon0) / (self._N - 1)
        self._ilat, self._ilon = 1.0 / self._dlat, 1.0 / self._dlon
        Mr, Nr = radii_of_curvature(lat.mean())
        cell_lat_m = float(Mr) * math.radians(self._dlat)
        cell_lon_m = float(Nr) * math.cos(math.radians(np.abs(lat).max())) * math.radians(self._dlon)
        self.resolution_m = min(cell_lat_m, cell_lon_m)
        self.step_m = 0.5 * self.resolution_m
        self.h_max = float(np.nanmax(self._H))
        self.max_range_m = float(max_range_m)
        self.name, self.description, self.synthetic = name, description, synthetic
        self._blockmax = self._block_max()

    @classmethod
    def from_hgt(cls, paths: list, **kw) -> "GridTerrain":
        """Load one or several SRTM ``.hgt`` tiles (one resolution; mosaicked)."""
        paths = list(paths)
        lat, lon, h, nvoid = read_hgt_mosaic(paths)
        names = ", ".join(str(p) for p in paths)
        kw.setdefault("name", f"SRTM {names}")
        kw.setdefault("description", f"SRTM DEM {names} ({nvoid} void samples); EGM96 heights "
                      "used as ellipsoidal (no geoid in the testbed).")
        return cls(lat, lon, h, source=names, **kw)

    @classmethod
    def from_npz(cls, path, **kw) -> "GridTerrain":
        """Load a plain ``.npz`` grid (``lat_deg``, ``lon_deg``, ``height_m``)."""
        lat, lon, h = read_npz(path)
        kw.setdefault("name", f"grid {path}")
        kw.setdefault("description", f"gridded terrain from {path}")
        return cls(lat, lon, h, source=str(path), **kw)

    @property
    def extent_deg(self) -> tuple[float, float, float, float]:
        """``(lat_min, lat_max, lon_min, lon_max)`` of the grid, deg."""
        return (self._lat0, float(self.lat_deg[-1]), self._lon0, float(self.lon_deg[-1]))

    def _block_max(self) -> NDArray:
        """Max over each BLOCK x BLOCK cells (including their corner nodes), dilated 3x3.

        A ray segment starting in block (i, j) and no longer than BLOCK cells in either
        axis only meets terrain bounded by this value (bilinear heights are convex
        combinations of the cell's nodes).
        """
        H = np.where(np.isfinite(self._H), self._H, -np.inf)
        cell = np.maximum(np.maximum(H[:-1, :-1], H[:-1, 1:]), np.maximum(H[1:, :-1], H[1:, 1:]))
        B = self.BLOCK
        mi, ni = -(-cell.shape[0] // B), -(-cell.shape[1] // B)
        pad = np.full((mi * B, ni * B), -np.inf)
        pad[: cell.shape[0], : cell.shape[1]] = cell
        blk = pad.reshape(mi, B, ni, B).max(axis=(1, 3))
        blk = ndimage.maximum_filter(blk, size=3, mode="nearest")
        return np.pad(blk, 1, mode="edge")  # one ring for knots just outside the grid

    def _param(self, lat_deg: NDArray, lon_deg: NDArray) -> tuple[NDArray, NDArray]:
        return (lat_deg - self._lat0) * self._ilat, (lon_deg - self._lon0) * self._ilon

    def _bound_ab(self, a: NDArray, b: NDArray) -> NDArray:
        B = self.BLOCK
        bm = self._blockmax
        inside = (a > -B) & (a < self._M - 1 + B) & (b > -B) & (b < self._N - 1 + B)
        i = np.floor(np.where(inside, a, 0.0) / B).astype(np.intp) + 1
        j = np.floor(np.where(inside, b, 0.0) / B).astype(np.intp) + 1
        i = np.clip(i, 0, bm.shape[0] - 1)
        j = np.clip(j, 0, bm.shape[1] - 1)
        return np.where(inside, bm[i, j], -np.inf)

    def _height_ab(self, a: NDArray, b: NDArray) -> NDArray:
        M, N = self._M, self._N
        inside = (a >= 0) & (a <= M - 1) & (b >= 0) & (b <= N - 1)
        a = np.where(inside, a, 0.0)
        b = np.where(inside, b, 0.0)
        i = np.minimum(a.astype(np.intp), M - 2)
        j = np.minimum(b.astype(np.intp), N - 2)
        fa, fb = a - i, b - j
        k = i * N + j
        H = self._Hflat
        h00, h01, h10, h11 = H[k], H[k + 1], H[k + N], H[k + N + 1]
        h0 = h00 + fb * (h01 - h00)
        h1 = h10 + fb * (h11 - h10)
        return np.where(inside, h0 + fa * (h1 - h0), np.nan)

    def height(self, lat_deg: ArrayLike, lon_deg: ArrayLike) -> NDArray | float:
        """Bilinear height (m); NaN outside the grid. Scalar floats take a fast path."""
        if isinstance(lat_deg, float) and isinstance(lon_deg, float):
            a = (lat_deg - self._lat0) * self._ilat
            b = (lon_deg - self._lon0) * self._ilon
            if not (0.0 <= a <= self._M - 1 and 0.0 <= b <= self._N - 1):
                return math.nan
            i = min(int(a), self._M - 2)
            j = min(int(b), self._N - 2)
            fa, fb = a - i, b - j
            k = i * self._N + j
            H = self._Hflat
            h00, h01 = float(H[k]), float(H[k + 1])
            h10, h11 = float(H[k + self._N]), float(H[k + self._N + 1])
            h0 = h00 + fb * (h01 - h00)
            return h0 + fa * (h10 + fb * (h11 - h10) - h0)
        return super().height(lat_deg, lon_deg)
