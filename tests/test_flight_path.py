"""Path geometry against closed forms: tangency, lengths, projections, the vertical profile."""

import math

import numpy as np
import pytest

from testbed.flight.path import ApproachPath
from testbed.flight.settings import PathSettings, VerticalSettings
from testbed.frames import LocalFrame

FRAME = LocalFrame(29.2958478, 94.3224478, 2939.0)
MM = 1e-3


def make_path(legs, course=54.65, vertical=None):
    lat = PathSettings(end_lat_deg=FRAME.lat_deg, end_lon_deg=FRAME.lon_deg, end_h=FRAME.h,
                       final_course_deg=course, legs=legs)
    return ApproachPath(lat, vertical or VerticalSettings(), FRAME)


def test_straight_final_geometry():
    p = make_path([{"type": "straight", "length_m": 10000.0}])
    e, n, trk = p.start_point(10000.0)
    # start is 10 km back along the reciprocal of the course
    c = math.radians(54.65)
    assert e == pytest.approx(-10000 * math.sin(c), abs=MM)
    assert n == pytest.approx(-10000 * math.cos(c), abs=MM)
    # a point 30 m to the right of the course, 4 km to go
    right = np.array([math.cos(c), -math.sin(c)])
    on = np.array([-4000 * math.sin(c), -4000 * math.cos(c)])
    st = p.locate(*(on + 30 * right))
    assert st.cross_track == pytest.approx(30.0, abs=MM)
    assert st.distance_to_go == pytest.approx(4000.0, abs=MM)


def test_rf_leg_is_tangent_and_has_arc_length():
    R, turn = 4000.0, -40.0
    p = make_path([{"type": "straight", "length_m": 5000.0}, {"type": "rf", "radius_m": R, "turn_deg": turn},
                   {"type": "straight", "length_m": 6000.0}])
    assert p.total_length == pytest.approx(11000 + R * math.radians(40), abs=MM)
    arc = p.legs[1]
    # leg joins: end of leg k == start of leg k+1, same track (tangent)
    for a, b in zip(p.legs, p.legs[1:]):
        end = a.point(np.array([a.length]))[0]
        assert np.allclose(end, b.start, atol=MM)
        assert math.isclose((a.track0 + a.turn) % (2 * math.pi), b.track0 % (2 * math.pi), abs_tol=1e-12)
    # every arc point is R from the centre; cross-track of a point 50 m outside a left turn is +50 (right)
    pts = arc.point(np.linspace(0, arc.length, 50))
    assert np.allclose(np.hypot(pts[:, 0] - arc.centre[0], pts[:, 1] - arc.centre[1]), R, atol=MM)
    mid = arc.point(np.array([arc.length / 2]))[0]
    out = mid + 50 * (mid - np.array(arc.centre)) / R
    st = p.locate(*out, leg_hint=1)
    assert st.leg == 1 and st.turn_sign == -1
    assert st.cross_track == pytest.approx(50.0, abs=MM)
    assert st.distance_to_go == pytest.approx(6000 + arc.length / 2, abs=0.01)


def test_glide_path_and_constraints():
    p = make_path([{"type": "straight", "length_m": 10000.0}], vertical=VerticalSettings(glide_path_deg=3.0))
    assert p.height(5000.0) == pytest.approx(FRAME.h + 15 + 5000 * math.tan(math.radians(3)), abs=MM)
    q = make_path([{"type": "straight", "length_m": 10000.0}],
                  vertical=VerticalSettings(glide_path_deg=None, constraints=[(0, 2954), (4000, 3200), (10000, 3700)]))
    assert q.height(2000.0) == pytest.approx(3077.0, abs=MM)
    assert q.path_angle(7000.0) == pytest.approx(math.atan2(500, 6000))


def test_planned_path_heights_are_ellipsoidal():
    p = make_path([{"type": "straight", "length_m": 20000.0}])
    pts = p.sample_enu(500.0)
    _, dtg = p.sample(500.0)
    lat, lon, h = FRAME.enu_to_geodetic(pts)
    assert np.allclose(h, p.height(dtg), atol=0.01)
    # world-frame "up" is below the ellipsoidal height by ~d^2/2R (31 m at 20 km)
    assert (h - FRAME.h - pts[:, 2])[0] == pytest.approx(20000**2 / (2 * 6.38e6), rel=0.02)
