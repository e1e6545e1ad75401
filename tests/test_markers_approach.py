"""The shipped approach with the patent's H and I ground markers (approaches/zunz-rwy05-markers.toml).

The markers must lie on the terrain (a marker under the surface is occluded, as
the runway outline is on the seed's flat field), be seen from the final, and
serve the pixel monitor with exclusion on, as the approach promises.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from test_integrity_core_helpers import make_gnss
from test_vision_detect import runway_final

from testbed.api import load_approach
from testbed.frames import ecef_to_geodetic
from testbed.integrity.pixel import pixel_monitor
from testbed.integrity.settings import PixelOptions
from testbed.records import take_epochs
from testbed.sensors.vision import synthesize_vision
from testbed.sensors.vision.landmarks import build_landmarks
from testbed.sim.setup import load_terrain_for, vision_settings
from testbed.world.airport import runway_frame

FRAME = runway_frame()


def _approach():
    ap = load_approach("zunz-rwy05-markers")
    return ap, build_landmarks(ap.config.landmarks)


def test_markers_lie_on_the_terrain_beside_the_centreline():
    ap, lm = _approach()
    ids = [str(i) for i in lm.id]
    assert [i for i in ids if i[0] in "HI" and i[1:].isdigit()] == [f"H{k:02d}" for k in range(1, 13)] + \
        [f"I{k:02d}" for k in range(1, 13)]
    terrain = load_terrain_for(ap)
    marker = np.array([i[0] in "HI" and i[1:].isdigit() for i in ids])
    lat, lon, h = ecef_to_geodetic(lm.pos_ecef[marker])
    above = h - terrain.height(lat, lon)
    assert np.all((above > 0.0) & (above < 0.5)), above
    enu = FRAME.ecef_to_enu(lm.pos_ecef[marker])
    along = np.radians(54.65)
    dist = -(enu[:, 0] * np.sin(along) + enu[:, 1] * np.cos(along))
    assert np.all((dist > 550) & (dist < 1560))  # 600 m and 1500 m before the threshold (± half a letter)
    assert ap.config.integrity.fde and ap.config.monitors == ["gps_raim", "pixel"]


def test_markers_are_seen_from_the_final_and_a_biased_corner_is_excluded():
    """From 4 km to 2 km out every marker corner is detected (not occluded, in the image), and with
    exclusion on, a 30 px bias on corner H05 is excluded (its slot S + l) at every epoch."""
    ap, lm = _approach()
    tr = runway_final().decimate(1.0)
    to_go = tr.t[-1] - tr.t  # s at 72 m/s
    tr = take_epochs(tr, np.flatnonzero((to_go >= 28.0) & (to_go <= 55.0)))
    vs = vision_settings(ap)
    ep, _ = synthesize_vision(tr, vs.model_copy(update={"rate_hz": 1.0}), landmarks=ap.config.landmarks, terrain=load_terrain_for(ap),
                              rng=np.random.default_rng(5))
    ids = [str(i) for i in ep.landmark_id]
    marker = np.array([i[0] in "HI" and i[1:].isdigit() for i in ids])
    assert ep.detected[:, marker].all()
    l = ids.index("H05")
    uv = ep.pixel_uv.copy()
    uv[:, l, 0] += 30.0
    g, _, _ = make_gnss(FRAME, tr.pos_enu, 344063.0 + ep.t, np.random.default_rng(6))
    g = replace(g, t=ep.t)
    out = pixel_monitor(g, replace(ep, pixel_uv=uv), FRAME, ap.config.integrity, options=PixelOptions(max_landmarks=40))
    S = g.visible.shape[-1]
    assert (out.reason == 0).all()
    assert (out.excluded == S + l).all() and not out.alert.any()
