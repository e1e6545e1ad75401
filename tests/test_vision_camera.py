"""Pinhole camera, distortion, presets, settings, landmark scenes (testbed.sensors.vision)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from testbed.frames import LocalFrame, geodetic_to_ecef
from testbed.sensors.vision import (CameraSettings, LandmarkSettings, PinholeCamera, approach_camera,
                                    build_landmarks, patent_T_pix_to_c, va_raim_2015_camera)
from testbed.sensors.vision.landmarks import marker_outline
from testbed.world import airport

ROUNDTRIP_PX = 1e-9  # float round-off over a 1000-px image
UNDISTORT_PX = 1e-6
MM = 1e-3


@pytest.fixture
def cam() -> PinholeCamera:
    return approach_camera()


def test_projection_roundtrip_pixel_bearing_point(cam):
    rng = np.random.default_rng(3)
    uv = rng.uniform([-0.5, -0.5], [cam.width_px - 0.5, cam.height_px - 0.5], size=(4, 50, 2))
    b = cam.unproject(uv)  # (4, 50, 3)
    np.testing.assert_allclose(np.linalg.norm(b, axis=-1), 1.0, atol=1e-15)
    r = rng.uniform(10.0, 20_000.0, size=(4, 50, 1))
    p = b * r  # a point at a known range along the bearing
    uv2, front = cam.project(p)
    assert front.all()
    np.testing.assert_allclose(uv2, uv, atol=ROUNDTRIP_PX * 1e3)
    np.testing.assert_allclose(np.linalg.norm(p, axis=-1), r[..., 0], rtol=1e-12)


def test_projection_scalar_and_behind(cam):
    uv, front = cam.project([0.0, 0.0, 10.0])
    assert front and uv.shape == (2,)
    np.testing.assert_allclose(uv, [cam.cx, cam.cy])
    uv, front = cam.project([[1.0, 2.0, -5.0]])
    assert not front[0] and np.isnan(uv).all()
    with pytest.raises(ValueError, match=r"expected shape \(\.\.\., 3\)"):
        cam.project(np.zeros((4, 2)))


def test_hand_computed_pixel(cam):
    # 1920 x 1080, HFOV 50 deg: f = 960 / tan(25 deg) = 960 / 0.46630766 = 2058.7300 px
    f = 960.0 / math.tan(math.radians(25.0))
    assert f == pytest.approx(2058.7266, abs=1e-4)
    # point 100 m right, 41.104 m down, 1018.975 m ahead (camera axes)
    u = 2058.7266 * 100.0 / 1018.975 + 959.5  # = 202.0390 + 959.5
    v = 2058.7266 * 41.104 / 1018.975 + 539.5  # = 83.0461 + 539.5
    uv, _ = cam.project([100.0, 41.104, 1018.975])
    np.testing.assert_allclose(uv, [u, v], atol=1e-4)
    assert uv[0] == pytest.approx(1161.5390, abs=1e-4) and uv[1] == pytest.approx(622.5461, abs=1e-4)


def test_patent_T_pix_to_c_matches_Kinv(cam):
    """The vision-integrity patent's T_pix^c (x up, y right, z fwd; 1-based m row, n column) is K^-1 relabelled."""
    T = patent_T_pix_to_c(cam)
    rng = np.random.default_rng(1)
    uv = rng.uniform(0, 1000, size=(20, 2))
    mn1 = np.stack([uv[:, 1] + 1, uv[:, 0] + 1, np.ones(20)], -1)  # m = row + 1, n = column + 1
    s_patent = mn1 @ T.T
    s_cv = np.stack([uv[:, 0], uv[:, 1], np.ones(20)], -1) @ np.linalg.inv(cam.K).T
    np.testing.assert_allclose(s_patent, np.stack([-s_cv[:, 1], s_cv[:, 0], s_cv[:, 2]], -1), atol=1e-12)
    # and in the patent's own symbols: pitch H/M over focal f, centre (M+1)/2
    M, N = cam.height_px, cam.width_px
    H_over_fM = 1.0 / cam.fy
    assert T[0, 0] == -H_over_fM and T[0, 2] == pytest.approx(H_over_fM * (M + 1) / 2)
    assert T[1, 2] == pytest.approx(-(N + 1) / (2 * cam.fx))


def test_distortion_hand_value_and_inverse():
    cam = PinholeCamera.from_focal_px(1000, 800, 900.0).with_distortion(k1=-0.12, k2=0.02, p1=1e-3, p2=-5e-4)
    # one point by hand: x = (800 - 499.5)/900, y = (700 - 399.5)/900
    x, y = 300.5 / 900.0, 300.5 / 900.0
    r2 = x * x + y * y
    rad = 1 - 0.12 * r2 + 0.02 * r2 * r2
    xd = x * rad + 2 * 1e-3 * x * y + (-5e-4) * (r2 + 2 * x * x)
    yd = y * rad + 1e-3 * (r2 + 2 * y * y) + 2 * (-5e-4) * x * y
    np.testing.assert_allclose(cam.distort([800.0, 700.0]), [900 * xd + 499.5, 900 * yd + 399.5], atol=1e-9)
    rng = np.random.default_rng(2)
    uv = rng.uniform([0, 0], [999, 799], size=(3, 200, 2))
    np.testing.assert_allclose(cam.undistort(cam.distort(uv)), uv, atol=UNDISTORT_PX)
    # no distortion: identity, and a copy (inputs never mutated)
    plain = approach_camera()
    out = plain.distort(uv)
    assert out is not uv and np.array_equal(out, uv)


@pytest.mark.parametrize("dpi,w,h", [(120, 170, 113), (300, 425, 283), (480, 680, 454), (720, 1020, 680)])
def test_va_raim_preset(dpi, w, h):
    cam = va_raim_2015_camera(dpi)
    pitch_mm = 25.4 / dpi
    assert (cam.width_px, cam.height_px) == (round(36.0 / pitch_mm), round(24.0 / pitch_mm)) == (w, h)
    assert cam.fx == pytest.approx(35.0 / pitch_mm, rel=1e-12)
    # 36 mm sensor behind a 35 mm lens: HFOV = 2 atan(18/35) = 54.41 deg (pixel rounding < 0.2 deg)
    assert cam.hfov_deg == pytest.approx(math.degrees(2 * math.atan(18 / 35)), abs=0.2)


def test_approach_preset(cam):
    assert (cam.width_px, cam.height_px) == (1920, 1080)
    assert cam.hfov_deg == pytest.approx(50.0, abs=1e-9)
    assert cam.vfov_deg == pytest.approx(2 * math.degrees(math.atan(540 / cam.fx)), abs=1e-9)


def test_camera_settings_forms_and_errors():
    assert CameraSettings().build().fx == pytest.approx(approach_camera().fx)
    c = CameraSettings(preset="va-raim-2015", dpi=300).build()
    assert (c.width_px, c.height_px) == (425, 283)
    c = CameraSettings(preset="custom", width_px=2448, height_px=2048, focal_px=3400.0).build()
    assert c.vfov_deg == pytest.approx(2 * math.degrees(math.atan(1024 / 3400)), abs=1e-9)  # ~33.5 deg
    c = CameraSettings(preset="custom", dpi=254, focal_mm=10.0, sensor_width_mm=10.0, sensor_height_mm=5.0).build()
    assert (c.width_px, c.height_px, c.fx) == (100, 50, pytest.approx(100.0))
    with pytest.raises(ValidationError, match="expected dpi"):
        CameraSettings(preset="va-raim-2015")
    with pytest.raises(ValidationError, match="exactly one of"):
        CameraSettings(preset="custom", width_px=100, height_px=100, focal_px=50.0, hfov_deg=40.0)
    with pytest.raises(ValidationError, match="hfov_deg"):
        CameraSettings(preset="custom", width_px=100, height_px=100, hfov_deg=190.0)
    with pytest.raises(ValidationError, match="extra"):
        CameraSettings(focal=3.0)
    with pytest.raises(ValueError, match="focal length"):
        PinholeCamera(100, 100, -1.0, 1.0, 50, 50)


def test_seed_triangle_geometry():
    lm = build_landmarks(LandmarkSettings())
    assert list(lm.id) == ["T1", "T2", "T3"]
    c = geodetic_to_ecef(*airport.VA_RAIM_CENTRE)
    frame = LocalFrame(*airport.VA_RAIM_CENTRE)
    enu = frame.ecef_to_enu(lm.pos_ecef)
    np.testing.assert_allclose(np.hypot(enu[:, 0], enu[:, 1]), 100.0, atol=1 * MM)
    az = np.degrees(np.arctan2(enu[:, 0], enu[:, 1]))
    np.testing.assert_allclose((az - [0, 120, 240] + 180) % 360 - 180, 0.0, atol=1e-5)
    d = np.linalg.norm(lm.pos_ecef[:, None] - lm.pos_ecef[None], axis=-1)
    np.testing.assert_allclose(d[[0, 1, 2], [1, 2, 0]], 100 * math.sqrt(3), atol=1 * MM)  # equilateral
    _, _, h = frame.enu_to_geodetic(enu)
    np.testing.assert_allclose(h, 2950.0, atol=1 * MM)
    assert np.linalg.norm(lm.pos_ecef.mean(0) - c) < 1.0  # centroid at the centre (up to curvature)


@pytest.mark.parametrize("letter,area", [("H", 2 * 5 * 30 + (20 - 10) * 5), ("I", 2 * 20 * 5 + 5 * (30 - 10))])
def test_marker_outline_area_and_placement(letter, area):
    xy = marker_outline(letter, 30.0, 20.0, 5.0)
    shoelace = 0.5 * np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1])
    assert xy.shape == (12, 2) and shoelace == pytest.approx(area)  # positive = counter-clockwise
    s = LandmarkSettings(sets=[{"kind": "marker", "letter": letter, "lat_deg": 29.3, "lon_deg": 94.33,
                                "h": 2950.0, "heading_deg": 90.0}])
    lm = build_landmarks(s)
    enu = LocalFrame(29.3, 94.33, 2950.0).ecef_to_enu(lm.pos_ecef)
    # heading 090: the letter's top points east, so its 30 m height spans east-west
    assert np.ptp(enu[:, 0]) == pytest.approx(30.0, abs=1 * MM)
    assert np.ptp(enu[:, 1]) == pytest.approx(20.0, abs=1 * MM)
    assert lm.id[0] == f"{letter}01" and np.allclose(lm.size_m, 5.0)


def test_runway_outline_facts():
    s = LandmarkSettings(sets=[{"kind": "runway", "edge_spacing_m": 300.0}])
    lm = build_landmarks(s)
    frame = airport.runway_frame()
    enu = dict(zip(lm.id, frame.ecef_to_enu(lm.pos_ecef)))
    assert np.linalg.norm(enu["RWY05L"] - enu["RWY05R"]) == pytest.approx(45.0, abs=1 * MM)
    mid05 = (enu["RWY05L"] + enu["RWY05R"]) / 2
    mid23 = (enu["RWY23L"] + enu["RWY23R"]) / 2
    # docs/design/physics-notes.md §airport-and-runway: geodesic 2999.6 m on the ellipsoid;
    # at ~2943 m height lengths grow by (1 + h/R)
    assert np.linalg.norm(mid23 - mid05) == pytest.approx(2999.6 * (1 + 2943.0 / 6.371e6), abs=0.1)
    course = math.degrees(math.atan2(*(mid23 - mid05)[:2])) % 360
    assert course == pytest.approx(54.65, abs=0.05)
    # 05L is left of the centreline when landing on 05
    a, b = mid23[:2] - mid05[:2], enu["RWY05L"][:2] - mid05[:2]
    assert a[0] * b[1] - a[1] * b[0] > 0
    assert len(lm) == 4 + 2 * 9 and "RWY_L" not in lm.id and "RWYL2700" in lm.id


def test_landmark_settings_errors():
    with pytest.raises(ValidationError, match="stroke_m"):
        LandmarkSettings(sets=[{"kind": "marker", "letter": "H", "lat_deg": 0, "lon_deg": 0, "h": 0,
                                "stroke_m": 12.0}])
    with pytest.raises(ValidationError, match="lpe_sigma_m"):
        LandmarkSettings(lpe_sigma_m=-0.1)
    with pytest.raises(ValueError, match="unique"):
        build_landmarks(LandmarkSettings(sets=[{"kind": "triangle"}, {"kind": "triangle"}]))
