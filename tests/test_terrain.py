"""Terrain models: ray queries against brute force and closed forms; the synthetic valley's figures."""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pymap3d.vincenty
import pytest

from testbed.frames import LocalFrame, R_ecef_to_enu, geodetic_to_ecef
from testbed.world import airport
from testbed.world.settings import TerrainSettings, load_terrain
from testbed.world.terrain import Flat, Terrain, TwoRidges, radii_of_curvature
from testbed.world.valley import (VALLEY_FAR_COURSE_DEG, LinZhiSyntheticValley, valley_axis_heading_deg,
                                  valley_centreline, valley_floor_half_width_m)

THRESHOLD_TOL_M = 1.0  # floor height at the thresholds vs published elevations
BRUTE_STEP_M = 2.0  # brute-force march step


@pytest.fixture(scope="module")
def valley() -> LinZhiSyntheticValley:
    return load_terrain(TerrainSettings())


@pytest.fixture(scope="module")
def valley30() -> LinZhiSyntheticValley:
    """The same valley looking only 30 km far (keeps brute force affordable)."""
    return LinZhiSyntheticValley(max_range_m=30e3)


def grazing_tolerance_m(t: LinZhiSyntheticValley) -> float:
    """How far a sampled march can be from the continuous answer: the steepest rise of
    the bilinear surface over half a sampling step (model and brute force)."""
    H = t._H.astype(float)
    gy, gx = np.gradient(H, t.resolution_m * 1.14, t.resolution_m)  # cells ~92 x ~81 m
    return float(np.hypot(gx, gy).max()) * (t.step_m + BRUTE_STEP_M) / 2


def brute_clearance(t: Terrain, o: np.ndarray, d: np.ndarray, s0: float | np.ndarray,
                    s1: float | np.ndarray, step: float = BRUTE_STEP_M) -> np.ndarray:
    """Dense march, one ray at a time, exact geodetic conversion at every sample."""
    s0 = np.broadcast_to(s0, o.shape[:1])
    s1 = np.broadcast_to(s1, o.shape[:1])
    out = np.empty(o.shape[0])
    for i in range(o.shape[0]):
        s = np.append(np.arange(s0[i], s1[i], step), s1[i])
        p = o[i] + s[:, None] * d[i]
        lat, lon, h = pymap3d.ecef2geodetic(p[:, 0], p[:, 1], p[:, 2])
        ht = t.height(lat, lon)
        ok = np.isfinite(ht)
        out[i] = np.min(h[ok] - ht[ok]) if ok.any() else np.inf
    return out


def points_over_valley(t: Terrain, rng: np.random.Generator, n: int, agl=(30.0, 1500.0)):
    """Random aircraft positions over the valley floor along the approach, ECEF (n, 3)."""
    a = rng.uniform(-14000, 5000, n)
    lat, lon = valley_centreline(a)
    side = rng.uniform(-1500, 1500, n)
    lat, lon = pymap3d.vincenty.vreckon(lat, lon, np.abs(side), np.where(side > 0, 144.65, 324.65))
    h = t.height(lat, lon) + rng.uniform(*agl, n)
    return geodetic_to_ecef(lat, lon, h), lat, lon


def enu_dirs_to_ecef(lat, lon, az, el):
    d_enu = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)
    return np.einsum("...ji,...j->...i", R_ecef_to_enu(lat, lon), d_enu)


# --------------------------------------------------------------------------------------
# Brute force agreement
# --------------------------------------------------------------------------------------
def test_line_of_sight_matches_brute_force(valley):
    rng = np.random.default_rng(1)
    n = 200
    o, lat, lon = points_over_valley(valley, rng, n)
    tlat, tlon = pymap3d.vincenty.vreckon(lat, lon, rng.uniform(500, 12000, n), rng.uniform(0, 360, n))
    tgt = geodetic_to_ecef(tlat, tlon, valley.height(tlat, tlon) + 2.0)  # a landmark on the ground
    los = valley.line_of_sight(o, tgt)
    v = tgt - o
    L = np.linalg.norm(v, axis=1)
    ref = brute_clearance(valley, o, v / L[:, None], 1.0, L - 1.0)
    tol = grazing_tolerance_m(valley)
    wrong = los != (ref >= 0)
    assert 0.2 < los.mean() < 0.8, "the ray set must exercise both outcomes"
    assert np.all(np.abs(ref[wrong]) < tol), (ref[wrong], tol)
    assert wrong.sum() <= 4, f"{wrong.sum()} grazing disagreements"
    # Blocked: the clearance is a sampled penetration (sparser samples see no lower
    # point than the dense march). Clear: a lower bound of the clearance.
    c = valley.ray_clearance(o, v / L[:, None], 1.0, L - 1.0)
    blocked = c < 0
    assert np.all(c[blocked] >= ref[blocked] - 0.1)
    assert np.all(c[~blocked] <= ref[~blocked] + tol)


def test_sky_visible_matches_brute_force(valley30):
    rng = np.random.default_rng(2)
    n = 200
    o, lat, lon = points_over_valley(valley30, rng, n)
    d = enu_dirs_to_ecef(lat, lon, rng.uniform(0, 2 * np.pi, n), np.radians(rng.uniform(0, 45, n)))
    vis = valley30.sky_visible(o, d)
    ref = brute_clearance(valley30, o, d, 1.0, 30e3, step=5.0)
    tol = grazing_tolerance_m(valley30) + 2.5 * 2.4
    wrong = vis != (ref >= 0)
    assert 0.2 < vis.mean() < 0.8
    assert np.all(np.abs(ref[wrong]) < tol), (ref[wrong], tol)
    assert wrong.sum() <= 4


def test_horizon_matches_brute_force_and_sky_visible(valley30):
    lat, lon = valley_centreline(-6000.0)
    lat, lon = float(lat), float(lon)
    h = valley30.height(lat, lon) + 100.0
    az = np.radians(np.arange(0, 360, 15.0))
    el = valley30.horizon(lat, lon, h, az)
    # Brute force: terrain points every 5 m (2 m near) along each azimuth.
    r = np.concatenate([np.arange(2.0, 2000, 2.0), np.arange(2000, 30e3, 5.0)])
    ref = np.empty_like(az)
    o = geodetic_to_ecef(lat, lon, h)
    R = R_ecef_to_enu(lat, lon)
    for k, a in enumerate(az):
        plat, plon = pymap3d.vincenty.vreckon(lat, lon, r, np.full_like(r, math.degrees(a)))
        p = (geodetic_to_ecef(plat, plon, valley30.height(plat, plon)) - o) @ R.T
        ref[k] = np.max(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    HORIZON_TOL_RAD = math.radians(0.3)
    assert np.all(np.abs(el - ref) < HORIZON_TOL_RAD), np.degrees(el - ref)
    assert np.degrees(el).max() > 10  # a valley floor sees walls
    # sky_visible agrees with the mask away from it
    rng = np.random.default_rng(3)
    el_t = el + np.radians(rng.choice([-1, 1], az.size) * rng.uniform(0.5, 5, az.size))
    vis = valley30.sky_visible(o, enu_dirs_to_ecef(lat, lon, az, el_t))
    np.testing.assert_array_equal(vis, el_t > el)


def test_two_ridges_line_of_sight_brute_force():
    t = TwoRidges()
    rng = np.random.default_rng(4)
    n = 100
    c = airport.VA_RAIM_CENTRE
    frame = LocalFrame(*c)
    o = frame.enu_to_ecef(np.c_[rng.uniform(-6000, 0, n), rng.uniform(-2000, 2000, n),
                                rng.uniform(50, 1200, n)])
    g = frame.enu_to_ecef(np.c_[rng.uniform(-8000, 8000, n), rng.uniform(-8000, 8000, n),
                                np.zeros(n)])
    glat, glon, _ = pymap3d.ecef2geodetic(g[:, 0], g[:, 1], g[:, 2])
    g = geodetic_to_ecef(glat, glon, t.height(glat, glon) + 1.0)
    los = t.line_of_sight(o, g)
    v = g - o
    L = np.linalg.norm(v, axis=1)
    ref = brute_clearance(t, o, v / L[:, None], 1.0, L - 1.0)
    tol = (math.pi * t.height_m / t.base_width_m) * (t.step_m + BRUTE_STEP_M) / 2  # max slope
    wrong = los != (ref >= 0)
    assert 0.2 < los.mean() < 0.9
    assert np.all(np.abs(ref[wrong]) < tol)


# --------------------------------------------------------------------------------------
# Closed forms
# --------------------------------------------------------------------------------------
class NorthWall(Terrain):
    """Flat at h0 with a plateau of dh from latitude lat_w northwards (an infinite wall)."""

    def __init__(self, h0: float, dh: float, lat_w: float):
        self.h0, self.dh, self.lat_w = h0, dh, lat_w
        self.h_max = h0 + dh
        self.step_m = 5.0
        self.max_range_m = 60e3
        self.name, self.description, self.synthetic = "north wall", "test wall", True

    def _height_ab(self, a, b):
        return np.where(a >= self.lat_w, self.h0 + self.dh, self.h0)


def wall_elevation_closed_form(lat, h_obs, h_top, d, az):
    """Elevation of the wall's near top edge at azimuth ``az`` (rad from north) for a wall
    ``d`` m north along the meridian, on the osculating circle of that azimuth (Euler)."""
    M, N = (float(x) for x in radii_of_curvature(lat))
    R = 1.0 / (math.cos(az) ** 2 / M + math.sin(az) ** 2 / N)
    theta = d / math.cos(az) / R
    return math.atan2((R + h_top) * math.cos(theta) - (R + h_obs), (R + h_top) * math.sin(theta))


@pytest.mark.parametrize("d", [3000.0, 10000.0, 25000.0])
@pytest.mark.parametrize("az_deg", [0.0, 30.0])
def test_wall_horizon_and_visibility_closed_form(d, az_deg):
    lat0, lon0, h0, dh, agl = 29.3, 94.3, 2950.0, 1000.0, 10.0
    M, _ = radii_of_curvature(lat0)
    lat_w = lat0 + math.degrees(d / float(M))
    t = NorthWall(h0, dh, lat_w)
    az = math.radians(az_deg)
    el_true = wall_elevation_closed_form(lat0, h0 + agl, h0 + dh, d, az)
    if d == 25000.0:  # curvature matters: 25 km drops the top by ~49 m (0.11 deg)
        assert math.degrees(math.atan((dh - agl) / (d / math.cos(az))) - el_true) > 0.08
    el = t.horizon(lat0, lon0, h0 + agl, [az])[0]
    # Horizon samples stop at most one range step past the edge: the angle is lower by
    # at most dh * step / r^2.
    r = d / math.cos(az)
    tol = dh * min(t.step_m, 0.01 * r) / r**2 + 2e-5
    assert el_true - tol <= el <= el_true + 2e-5
    o = geodetic_to_ecef(lat0, lon0, h0 + agl)
    dirs = enu_dirs_to_ecef(lat0, lon0, np.full(2, az), el_true + np.radians([-0.05, 0.05]))
    np.testing.assert_array_equal(t.sky_visible(o, dirs), [False, True])
    # A target well beyond the wall, just below / above the edge line.
    tgt = o + 2 * r * dirs
    np.testing.assert_array_equal(t.line_of_sight(o, tgt), [False, True])


def test_flat_masks_below_the_geometric_horizon():
    t = Flat(1000.0)
    lat, lon, agl = 29.3, 94.3, 500.0
    o = geodetic_to_ecef(lat, lon, 1000.0 + agl)
    M, N = (float(x) for x in radii_of_curvature(lat))
    R = 1 / (0.5 / M + 0.5 / N)  # azimuth 45 deg
    dip = -math.acos(R / (R + agl))  # tangent to the sphere: ~ -0.72 deg
    el = t.horizon(lat, lon, 1000.0 + agl, [math.radians(45)])[0]
    # the tangent point is ~80 km away, inside the 150 km range
    assert abs(el - dip) < math.radians(0.01)
    d = enu_dirs_to_ecef(lat, lon, np.full(2, math.radians(45)), dip + np.radians([-0.05, 0.05]))
    np.testing.assert_array_equal(t.sky_visible(o, d), [False, True])


# --------------------------------------------------------------------------------------
# The synthetic valley meets its parameters (docs/design/physics-notes.md §the-synthetic-valley)
# --------------------------------------------------------------------------------------
def test_valley_is_labelled_synthetic(valley):
    assert valley.synthetic
    assert "SYNTHETIC" in valley.name and "SYNTHETIC" in valley.description


def test_valley_floor_at_thresholds(valley):
    for thr in (airport.RWY05, airport.RWY23):
        assert abs(valley.height(thr.lat_deg, thr.lon_deg) - thr.h) < THRESHOLD_TOL_M


def _cross_section(valley, along, offsets):
    lat, lon = valley_centreline(along)
    hd = valley_axis_heading_deg(along)
    lat, lon = pymap3d.vincenty.vreckon(np.full(offsets.shape, float(lat)),
                                        np.full(offsets.shape, float(lon)),
                                        np.abs(offsets), np.where(offsets > 0, hd + 90, hd - 90))
    return valley.height(lat, lon)


@pytest.mark.parametrize("along,within", [(-14000.0, 6000.0), (-8000.0, 4000.0), (-3000.0, 3000.0),
                                          (0.0, 3000.0), (1500.0, 3000.0), (3000.0, 3000.0),
                                          (6000.0, 3000.0)])
def test_valley_walls_rise_above_4000_m_within_a_few_km(valley, along, within):
    """Walls above 4000 m within 3 km of the runway; the approach floor (valley plus
    the straight-in corridor) is wider."""
    c = np.arange(10.0, within + 500.0, 10.0)
    for side in (-1, 1):
        h = _cross_section(valley, along, side * c)
        first = c[np.argmax(h > 4000)] if (h > 4000).any() else np.inf
        assert first < within, f"along {along}: no 4000 m wall within {within} m on side {side}"
    if -20000.0 <= along <= 4000.0:  # no spurs here: the floor is smooth to its half width
        w = float(valley_floor_half_width_m(along))
        c = np.linspace(-0.95 * w, 0.95 * w, 21)
        hf = _cross_section(valley, along, c)
        resid = hf - np.polyval(np.polyfit(c, hf, 1), c)  # the floor's gradient is 3 m/km
        assert np.abs(resid).max() < 0.5 and 2880 <= hf.mean() <= 3010


def test_valley_narrowest_4000_m_gap_is_about_4_km(valley):
    gaps = []
    c = np.arange(10.0, 8000.0, 10.0)
    for along in np.arange(-14000.0, 3001.0, 500.0):
        left, right = _cross_section(valley, along, -c) > 4000, _cross_section(valley, along, c) > 4000
        assert left.any() and right.any()
        gaps.append(c[np.argmax(left)] + c[np.argmax(right)])
    assert 3500.0 < min(gaps) < 4500.0, min(gaps)


def test_valley_crests_in_the_5000_6000_class(valley):
    frame = airport.runway_frame()
    x = np.arange(-15e3, 15e3, 100.0)
    E, N = np.meshgrid(x, x)
    lat, lon, _ = frame.enu_to_geodetic(np.stack([E, N, 0 * E], -1))
    h = valley.height(lat, lon)
    assert 5000.0 <= h.max() <= 6000.0
    assert np.mean(h > 5000.0) > 0.1  # plenty of crests, not a single spike


@pytest.mark.parametrize("name,P,rng_m,brg", [("Namcha Barwa", 7782.0, 79e3, 62.0),
                                            ("Gyala Peri", 7294.0, 84e3, 47.0)])
def test_valley_big_peaks(valley, name, P, rng_m, brg):
    lat, lon = pymap3d.vincenty.vreckon(airport.ARP_LAT_DEG, airport.ARP_LON_DEG, rng_m, brg)
    assert abs(valley.height(float(lat), float(lon)) - P) < 5.0  # grid node spacing ~90 m
    # broad: still above 6000 m 4 km away
    lat2, lon2 = pymap3d.vincenty.vreckon(float(lat), float(lon), 4000.0, 200.0)
    assert valley.height(float(lat2), float(lon2)) > 6000.0


def test_valley_glide_path_clearance(valley):
    """3 deg final on the extended centreline from 14 km: >= 150 m above terrain
    (where the glide path is that high above the floor: beyond 2.5 km) and nothing
    but floor under it within +-300 m."""
    t05 = airport.RWY05
    d = np.arange(0.0, 14001.0, 50.0)
    gp = 2954.0 + d * math.tan(math.radians(3.0))
    worst = np.full(d.shape, -np.inf)
    for lateral in (-300.0, 0.0, 300.0):
        lat, lon = pymap3d.vincenty.vreckon(t05.lat_deg, t05.lon_deg, d, np.full(d.shape, 234.65))
        lat, lon = pymap3d.vincenty.vreckon(lat, lon, np.full(d.shape, abs(lateral) + 1e-6),
                                            np.full(d.shape, 144.65 if lateral > 0 else 324.65))
        worst = np.maximum(worst, valley.height(lat, lon))
    floor = t05.h + (airport.RWY23.h - t05.h) / 3000.0 * -d
    assert np.all(np.abs(worst - floor) < 1.0)
    assert np.all((gp - worst)[d >= 2500.0] >= 150.0)
    # and the path itself has line of sight to the threshold all the way
    o = geodetic_to_ecef(*pymap3d.vincenty.vreckon(t05.lat_deg, t05.lon_deg, d[1:], np.full(d.size - 1, 234.65)),
                         gp[1:])
    assert valley.line_of_sight(o, geodetic_to_ecef(t05.lat_deg, t05.lon_deg, t05.h + 15.0)).all()


def test_valley_bends_to_the_wsw_4_to_12_km_out():
    assert float(valley_axis_heading_deg(0.0)) == pytest.approx(airport.RWY05_COURSE_DEG)
    assert float(valley_axis_heading_deg(-3900.0)) == pytest.approx(airport.RWY05_COURSE_DEG)
    # an RNP path along the valley is within 5 deg of the runway course 6 km out
    assert float(valley_axis_heading_deg(-6000.0)) - airport.RWY05_COURSE_DEG < 5.0
    assert float(valley_axis_heading_deg(-30000.0)) == pytest.approx(VALLEY_FAR_COURSE_DEG)
    # far south-west the centreline lies north-west of the extended runway centreline
    lat, lon = valley_centreline(-30000.0)
    _, brg = pymap3d.vincenty.vdist(airport.RWY05.lat_deg, airport.RWY05.lon_deg, float(lat), float(lon))
    assert 234.65 + 3 < float(brg) < 255.0


def test_valley_centreline_is_on_the_floor(valley):
    a = np.linspace(-60e3, 20e3, 81)
    lat, lon = valley_centreline(a)
    h = valley.height(lat, lon)
    floor = np.clip(2939.0 + 9.0 / 2999.6 * a, 2880.0, 3010.0)
    assert np.all(np.abs(h - floor) < 2.0)


# --------------------------------------------------------------------------------------
# Shapes, scalar path, immutability, mesh
# --------------------------------------------------------------------------------------
def test_height_broadcasts_and_scalar_path_agrees(valley):
    lat = np.linspace(29.25, 29.35, 3)[:, None]
    lon = np.linspace(94.28, 94.38, 4)
    h = valley.height(lat, lon)
    assert h.shape == (3, 4)
    for i in range(3):
        for j in range(4):
            assert valley.height(float(lat[i, 0]), float(lon[j])) == pytest.approx(h[i, j], abs=1e-6)
    assert isinstance(valley.height(29.3, 94.33), float)
    assert math.isnan(valley.height(10.0, 10.0))


def test_ray_queries_keep_batch_shapes_and_inputs(valley):
    rng = np.random.default_rng(5)
    o, lat, lon = points_over_valley(valley, rng, 10)
    o = o.reshape(2, 5, 3)
    o_copy = o.copy()
    d = enu_dirs_to_ecef(lat, lon, rng.uniform(0, 6, 10), rng.uniform(0, 1, 10)).reshape(2, 5, 3)
    vis = valley.sky_visible(o, d)
    assert vis.shape == (2, 5) and vis.dtype == bool
    np.testing.assert_array_equal(vis.reshape(-1), valley.sky_visible(o.reshape(-1, 3), d.reshape(-1, 3)))
    for k in range(10):  # one ray at a time gives the same answer
        assert valley.sky_visible(o.reshape(-1, 3)[k], d.reshape(-1, 3)[k]) == vis.reshape(-1)[k]
    assert valley.line_of_sight(o, o + 1000 * d).shape == (2, 5)
    np.testing.assert_array_equal(o, o_copy)
    bad = o.reshape(-1, 3).copy()
    bad[0] = np.nan
    assert not valley.sky_visible(bad, d.reshape(-1, 3))[0]  # a bad element, not an exception
    with pytest.raises(ValueError, match=r"expected shape \(\.\.\., 3\), got \(4, 2\)"):
        valley.sky_visible(np.zeros((4, 2)), d)


def test_mesh_vertices_lie_on_the_terrain(valley):
    frame = airport.runway_frame()
    v, f = valley.mesh(frame, 2000.0, 250.0)
    n = 17
    assert v.shape == (n * n, 3) and f.shape == (2 * (n - 1) ** 2, 3) and f.max() < len(v)
    lat, lon, h = frame.enu_to_geodetic(v)
    np.testing.assert_allclose(h, valley.height(lat, lon), atol=1e-3)
    # counter-clockwise seen from above: positive z of the face normals (mostly flat)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    assert np.all(np.cross(b - a, c - a)[:, 2] > 0)


def test_two_ridges_cross_section():
    t = TwoRidges()
    c = airport.VA_RAIM_CENTRE
    north = np.array([0.0, 3000.0, 2500.0, 3500.0, 4000.0, -3000.0, -3500.0])  # geodesic, m
    lat, lon = pymap3d.vincenty.vreckon(np.full(north.shape, c[0]), np.full(north.shape, c[1]),
                                        np.abs(north), np.where(north < 0, 180.0, 0.0))
    # course 090: the ridges run east-west at +-3000 m north/south of the centre;
    # raised cosine: half height 500 m from the crest, zero at 1000 m
    np.testing.assert_allclose(t.height(lat, lon), [2950, 3950, 3450, 3450, 2950, 3950, 3450], atol=0.5)
    # uniform along the course (on the model's map a 090 course is a parallel)
    np.testing.assert_allclose(t.height(lat, lon + 0.2), t.height(lat, lon), atol=1e-9)


def test_fast_geodetic_conversion_matches_pymap3d():
    from testbed.world.terrain import ecef_to_geodetic_fast
    rng = np.random.default_rng(6)
    n = 20000
    lat, lon, h = rng.uniform(-89.9, 89.9, n), rng.uniform(-180, 180, n), rng.uniform(-500, 30e3, n)
    p = geodetic_to_ecef(lat, lon, h)
    la, lo, hh = ecef_to_geodetic_fast(p)
    ONE_MM = 1e-3
    assert np.abs(la - lat).max() * 111e3 < ONE_MM
    assert np.abs(lo - lon).max() * 111e3 < ONE_MM
    assert np.abs(hh - h).max() < ONE_MM


def test_valley_roughness_is_deterministic():
    from testbed.world import valley as tm
    rebuilt = tm._noise_lattice.__wrapped__()
    for a, b in zip(rebuilt, tm._noise_lattice()):
        np.testing.assert_array_equal(a, b)


def test_mesh_leaves_out_cells_without_terrain():
    lat = np.linspace(29.0, 29.1, 11)
    lon = np.linspace(94.0, 94.1, 11)
    from testbed.world.terrain import GridTerrain
    t = GridTerrain(lat, lon, np.full((11, 11), 500.0))
    frame = LocalFrame(29.0, 94.0, 500.0)  # the grid's south-west corner: 3/4 of the square is outside
    v, f = t.mesh(frame, 4000.0, 500.0)
    assert 0 < len(f) < 2 * 16 * 16 and f.max() < len(v)
    assert np.all(np.isfinite(v))
    lat_v, lon_v, h_v = frame.enu_to_geodetic(v)
    assert np.all(lat_v >= 29.0 - 1e-9) and np.all(lon_v >= 94.0 - 1e-9)


def test_short_and_coincident_segments_are_clear():
    t = Flat(0.0)
    p = geodetic_to_ecef(29.0, 94.0, 100.0)
    np.testing.assert_array_equal(t.line_of_sight(p, np.stack([p, p + 1.0])), [True, True])


def test_valley_centreline_path_stays_on_the_floor(valley):
    """An RNP path following the valley centreline from 60 km out: only floor within 500 m."""
    a = np.arange(-60000.0, 0.0, 50.0)
    lat, lon = valley_centreline(a)
    hd = valley_axis_heading_deg(a)
    floor = np.clip(2939.0 + 9.0 / 2999.6 * a, 2880.0, 3010.0)
    for off in (-500.0, 500.0):
        la, lo = pymap3d.vincenty.vreckon(lat, lon, np.full(a.shape, abs(off)), hd + np.sign(off) * 90)
        assert np.all(valley.height(la, lo) - floor < 2.0)


@pytest.mark.parametrize("model", [Flat(1234.0), TwoRidges(course_deg=54.65)])
def test_scalar_fast_paths_agree_with_vector_paths(model):
    rng = np.random.default_rng(7)
    lat = rng.uniform(29.25, 29.36, 200)
    lon = rng.uniform(94.28, 94.39, 200)
    vec = model.height(lat, lon)
    sca = np.array([model.height(float(a), float(b)) for a, b in zip(lat, lon)])
    np.testing.assert_allclose(sca, vec, atol=1e-9, rtol=0)
    if isinstance(model, TwoRidges):
        assert np.ptp(vec) > 500.0  # the sample crosses the ridges
