"""GNSS visibility: elevation mask, terrain (closed-form wall, LinZhi valley), airframe masking."""

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from testbed.flight.kinematic import straight_truth
from testbed.frames import LocalFrame, R_NED_TO_ENU, euler_to_q_body_to_enu
from testbed.records import Mount, NotVisible
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.gnss.synth import gnss_geometry
from testbed.world import airport

START = "2024-03-15T00:00:00Z"
ANGLE_MARGIN = 1e-6  # rad: slots this close to a mask edge are not judged


class Wall:
    """Stub terrain: an infinite vertical wall, the plane east = D of ``frame``, top at up = H."""

    def __init__(self, frame: LocalFrame, D: float, H: float) -> None:
        self.frame, self.D, self.H = frame, D, H

    def sky_visible(self, origin_ecef, direction_ecef):
        o = self.frame.ecef_to_enu(origin_ecef)
        d = self.frame.vec_ecef_to_enu(direction_ecef)
        hits = (d[..., 0] > 0) & (o[..., 0] < self.D)
        s = np.where(hits, (self.D - o[..., 0]) / np.where(hits, d[..., 0], 1.0), 0.0)
        return ~(hits & (o[..., 2] + s * d[..., 2] < self.H))


def static_truth(frame, hours=24.0, step_s=300.0, h_above=0.0):
    return straight_truth(frame, [0.0, 0.0, h_above], [0.0, 0.0, h_above], hours * 3600.0, rate_hz=1.0 / step_s)


def test_elevation_mask_reason():
    frame = LocalFrame(airport.ARP_LAT_DEG, airport.ARP_LON_DEG, airport.ELEVATION_M)
    s = GnssSettings(rate_hz=1 / 300, terrain_masking=False, elevation_mask_deg=10.0)
    g = gnss_geometry(static_truth(frame, 6), Mount(np.zeros(3)), s, start_utc=START)
    el = np.degrees(g.elevation)
    assert np.all((g.reason == NotVisible.BELOW_MASK) == (el < 10.0))
    assert np.all(g.visible == (el >= 10.0))


def test_wall_masking_closed_form():
    """Blocked iff the satellite is east-going and tan(el) < H·sin(az)/D (observer at the wall frame origin)."""
    frame = LocalFrame(airport.ARP_LAT_DEG, airport.ARP_LON_DEG, airport.ELEVATION_M)
    D, H = 1000.0, 1000.0
    s = GnssSettings(rate_hz=1 / 300)
    g = gnss_geometry(static_truth(frame), Mount(np.zeros(3)), s, start_utc=START, terrain=Wall(frame, D, H))
    el, az = g.elevation, g.azimuth
    above = el >= np.radians(5.0)
    blocked = (np.sin(az) > 0) & (np.tan(el) < H * np.sin(az) / D)
    margin = np.abs(np.tan(el) - H * np.sin(az) / D) > ANGLE_MARGIN
    judged = above & margin
    assert np.all((g.reason[judged] == NotVisible.TERRAIN) == blocked[judged])
    assert (g.reason == NotVisible.TERRAIN).sum() > 200  # the wall really blocks something
    # with terrain masking switched off the same wall is ignored
    g2 = gnss_geometry(static_truth(frame), Mount(np.zeros(3)), s.model_copy(update={"terrain_masking": False}),
                       start_utc=START, terrain=Wall(frame, D, H))
    assert not np.any(g2.reason == NotVisible.TERRAIN)


def test_airframe_masking_in_a_bank():
    frame = airport.runway_frame()
    base = straight_truth(frame, [-8000.0, -5600.0, 600.0], [-7000.0, -4900.0, 550.0], 3600.0, rate_hz=1 / 60)
    n = base.t.size
    phi = np.full(n, np.radians(35.0))
    theta, psi = base.euler[:, 1], base.euler[:, 2]
    banked = replace(base, q_body_to_enu=euler_to_q_body_to_enu(phi, theta, psi),
                     euler=np.stack([phi, theta, psi], 1))
    s = GnssSettings(rate_hz=1 / 60, terrain_masking=False)
    g = gnss_geometry(banked, Mount(np.zeros(3)), s, start_utc=START)
    # independent: antenna-plane normal ("up" = −z body) from scipy's ZYX Euler body->NED, then NED->ENU
    R_b2ned = Rotation.from_euler("ZYX", np.stack([psi, theta, phi], 1)).as_matrix()
    up_enu = np.einsum("ij,tjk,k->ti", R_NED_TO_ENU, R_b2ned, np.array([0.0, 0.0, -1.0]))
    los_enu = np.stack([np.cos(g.elevation) * np.sin(g.azimuth), np.cos(g.elevation) * np.cos(g.azimuth),
                        np.sin(g.elevation)], -1)
    el_body = np.arcsin(np.einsum("tsi,ti->ts", los_enu, up_enu))
    judged = (g.elevation >= np.radians(5.0)) & (np.abs(el_body) > ANGLE_MARGIN)
    assert np.all((g.reason[judged] == NotVisible.AIRFRAME) == (el_body[judged] < 0))
    assert (g.reason == NotVisible.AIRFRAME).sum() > 20
    g_off = gnss_geometry(banked, Mount(np.zeros(3)), s.model_copy(update={"airframe_masking": False}),
                          start_utc=START)
    assert not np.any(g_off.reason == NotVisible.AIRFRAME)
    # wings level: nothing above the 5° mask is below the antenna plane at this small pitch
    g_lvl = gnss_geometry(base, Mount(np.zeros(3)), s, start_utc=START)
    assert not np.any(g_lvl.reason == NotVisible.AIRFRAME)


class ValleyStub:
    """Stub valley: two vertical walls parallel to the RWY05 course, ±W cross-track, top at H (frame up)."""

    def __init__(self, frame: LocalFrame, W: float = 2000.0, H: float = 1100.0) -> None:
        psi = np.radians(airport.RWY05_COURSE_DEG)
        self.frame, self.W, self.H = frame, W, H
        self.right = np.array([np.cos(psi), -np.sin(psi), 0.0])

    def height(self, lat_deg, lon_deg):
        return self.frame.h

    def sky_visible(self, origin_ecef, direction_ecef):
        o = self.frame.ecef_to_enu(origin_ecef)
        d = self.frame.vec_ecef_to_enu(direction_ecef)
        oc, dc = o @ self.right, d @ self.right
        wall = np.where(dc > 0, self.W, -self.W)
        s = (wall - oc) / np.where(dc == 0, 1.0, dc)
        return ~((dc != 0) & (o[..., 2] + s * d[..., 2] < self.H))


def _valley(frame):
    try:
        from testbed.world.valley import LinZhiSyntheticValley
    except ImportError:  # the terrain room not landed: closed-form stub valley
        return ValleyStub(frame), "stub valley (walls ±2 km, 1100 m)"
    return LinZhiSyntheticValley(), "LinZhiSyntheticValley"


def test_day_at_zunz_with_and_without_terrain():
    """Satellites in view at the ZUNZ reference point every 5 min over a day (DO-229, 5° mask)."""
    frame = LocalFrame(airport.ARP_LAT_DEG, airport.ARP_LON_DEG, airport.ELEVATION_M)
    terrain, name = _valley(frame)
    h_ground = float(terrain.height(airport.ARP_LAT_DEG, airport.ARP_LON_DEG))
    truth = static_truth(frame, h_above=h_ground - airport.ELEVATION_M + 2.0)  # antenna 2 m above ground
    s = GnssSettings(rate_hz=1 / 300)
    g = gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc=START, terrain=terrain)
    open_sky = (g.reason == 0) | (g.reason == NotVisible.TERRAIN)
    n_open, n_valley = open_sky.sum(1), g.visible.sum(1)
    print(f"\nZUNZ ARP, 24 h every 5 min, DO-229 24 sats, 5° mask: open sky min/median/max = "
          f"{n_open.min()}/{np.median(n_open):.0f}/{n_open.max()}; with {name}: "
          f"{n_valley.min()}/{np.median(n_valley):.0f}/{n_valley.max()}")
    # the 24-satellite DO-229 constellation gives 5-12 satellites above 5° anywhere
    assert 5 <= n_open.min() and n_open.max() <= 12
    assert np.all(n_valley <= n_open)
    assert n_valley.mean() < n_open.mean() - 1.0  # the valley walls really mask


def test_day_with_stub_valley():
    frame = LocalFrame(airport.ARP_LAT_DEG, airport.ARP_LON_DEG, airport.ELEVATION_M)
    g = gnss_geometry(static_truth(frame, h_above=2.0), Mount(np.zeros(3)), GnssSettings(rate_hz=1 / 300),
                      start_utc=START, terrain=ValleyStub(frame))
    n = g.visible.sum(1)
    print(f"\nstub valley (walls ±2 km, 1100 m): min/median/max = {n.min()}/{np.median(n):.0f}/{n.max()}")
    # closed form: a satellite across the valley is masked iff tan(el) < (H − 2)/ (W / |sin(az − course)|)
    rel = g.azimuth - np.radians(airport.RWY05_COURSE_DEG)
    blocked = np.tan(g.elevation) < 1098.0 * np.abs(np.sin(rel)) / 2000.0
    judged = (g.elevation >= np.radians(5.0)) & (np.abs(np.tan(g.elevation) - 1098.0 * np.abs(np.sin(rel)) / 2000.0)
                                                 > ANGLE_MARGIN)
    assert np.all((g.reason[judged] == NotVisible.TERRAIN) == blocked[judged])
