"""Unsurveyed ground features in the loop (the GNSS/vision/INS filter): the corridor scene, the tracker's selection against a
brute force, its noise and prefix stability, the ekf monitor on the SLAM filter through testbed fly (live
blocks = one flight, recording) and in campaigns (consistency, determinism)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats

from testbed.api import load_approach, run_approach
from testbed.frames import LocalFrame
from testbed.navigation.monitor import EkfSettings
from testbed.records import Mount
from testbed.sensors.vision.camera import approach_camera
from testbed.sensors.vision.features import features_in_view, observe, project
from testbed.sim.setup import build_setup, load_terrain_for
from testbed.viz import readback

FRAME = LocalFrame(29.2958478, 94.3224478, 2939.0)


def test_the_corridor_scene_is_uniform_on_the_terrain_inside_its_swath():
    """A straight 13 070 m track, 4 km beyond, ±2.5 km: round(40 · 17.07 · 5) = 3414 points, each on the
    terrain (its height the model's to 1 mm), within the swath, uniform along and across it (binomial 99.9 %)."""
    ap = load_approach("zunz-rwy05-slam")
    terrain = load_terrain_for(ap)
    setup = build_setup(ap, terrain)
    fs = setup.vision.features
    pts = setup.features
    assert pts.shape == (round(40.0 * (13070.0 + 4000.0) * 5000.0 / 1e6), 3)
    lat, lon, h = setup.frame.enu_to_geodetic(pts)
    np.testing.assert_allclose(h, terrain.height(lat, lon), atol=1e-3)
    en, _ = setup.path.sample(200.0)
    a, b = en[0], en[-1]
    u = (b - a) / np.linalg.norm(b - a)
    along = (pts[:, :2] - a) @ u
    across = (pts[:, :2] - a) @ np.array([-u[1], u[0]])
    # (a point stands on the terrain at its latitude and longitude: the tangent plane's vertical tilts by
    # 2.7 mrad at 17 km, so a point 1 km above or below the frame's height moves ~3 m across in it)
    assert np.abs(across).max() <= fs.half_width_m + 5.0
    assert along.min() >= -5.0 and along.max() <= 13070.0 + fs.beyond_m + 5.0
    n = len(pts)
    lo, hi = stats.binom.ppf([0.0005, 0.9995], n, 0.5)
    assert lo <= (along < 0.5 * (13070.0 + fs.beyond_m)).sum() <= hi
    assert lo <= (across < 0).sum() <= hi


class _Wall:
    """A stand-in terrain: a segment is masked where it crosses the plane north = 0 (for the brute force)."""

    def __init__(self, frame):
        self.frame = frame

    def line_of_sight(self, o_ecef, t_ecef, margin_m=1.0):
        o, t = self.frame.ecef_to_enu(o_ecef), self.frame.ecef_to_enu(t_ecef)
        return ~((o[..., 1] > 0) != (t[..., 1] > 0))


def test_the_tracker_keeps_the_nearest_unmasked_points_in_view_as_a_brute_force_does():
    rng = np.random.default_rng(4)
    cam = approach_camera()
    pts = np.column_stack([rng.uniform(-3000, 3000, 1500), rng.uniform(-3000, 3000, 1500), rng.uniform(-50, 50, 1500)])
    T = 12
    c = np.column_stack([rng.uniform(-500, 500, T), rng.uniform(-500, 500, T), rng.uniform(300, 800, T)])
    from scipy.spatial.transform import Rotation
    # camera z forward, tilted down ~20° about a random heading
    R0 = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # RDF camera -> ENU looking north
    R = np.stack([Rotation.from_euler("z", rng.uniform(0, 360), degrees=True).as_matrix() @ R0
                  @ Rotation.from_euler("x", -20, degrees=True).as_matrix() for _ in range(T)])
    for terrain, cap in ((None, None), (_Wall(FRAME), 25), (_Wall(FRAME), 3)):
        ids = features_in_view(c, R, cam, pts, margin_px=5.0, max_range_m=2500.0, max_tracks=cap, terrain=terrain,
                               frame=FRAME)
        for k in range(T):
            want = []
            for i in range(len(pts)):
                s = R[k].T @ (pts[i] - c[k])
                if s[2] <= 1.0 or np.linalg.norm(pts[i] - c[k]) > 2500.0:
                    continue
                u, v = (cam.K @ (s / s[2]))[:2]
                if not (5 <= u <= cam.width_px - 6 and 5 <= v <= cam.height_px - 6):
                    continue
                if terrain is not None and (c[k, 1] > 0) != (pts[i, 1] > 0):
                    continue
                want.append(i)
            want = sorted(want, key=lambda i: np.linalg.norm(pts[i] - c[k]))[:cap]
            got = ids[k][ids[k] >= 0]
            assert got.tolist() == want, (k, cap)
        assert (ids >= 0).sum() >= 2 * T  # the case is not empty


def test_tracking_noise_is_white_with_its_sigma_and_any_block_split_draws_the_same():
    """Pixels = the projection + N(0, σ²): the sample variance inside its χ² 99.9 % band, u and v and
    consecutive epochs uncorrelated (|r| < 4/√n); two blocks (the second from epoch 7) equal one pass."""
    rng = np.random.default_rng(5)
    cam = approach_camera()
    T, W, L, B = 20, 40, 200, 50
    pts = rng.uniform(-100, 100, (L, 3)) + [0, 0, 2000.0]
    ids = np.stack([rng.permutation(L)[:W] for _ in range(T)])
    ids[::3, 30:] = -1  # padded epochs
    c = np.zeros((T, 3))
    R = np.broadcast_to(np.eye(3), (T, 3, 3))
    words = np.random.SeedSequence(9).generate_state(4)
    mount = Mount(np.zeros(3))
    one = observe(np.arange(T, dtype=float), ids, pts, c, R, cam, mount, 1.5, words, n_trials=B)
    a = observe(np.arange(7.0), ids[:7], pts, c[:7], R[:7], cam, mount, 1.5, words, 0, B)
    b = observe(np.arange(7.0, T), ids[7:], pts, c[7:], R[7:], cam, mount, 1.5, words, 7, B)
    np.testing.assert_array_equal(one.uv, np.concatenate([a.uv, b.uv], 1))
    e = one.uv - project(pts, ids, c, np.broadcast_to(R, (B, T, 3, 3)), cam.K)
    x = e[np.broadcast_to((ids >= 0)[None], e.shape[:-1])]  # (n, 2)
    n = x.size
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], n) / n
    assert lo <= (x**2).mean() / 1.5**2 <= hi
    assert abs(np.corrcoef(x[:, 0], x[:, 1])[0, 1]) < 4 / np.sqrt(len(x))
    lag = e[:, 1:4, :30] * e[:, 2:5, :30]  # same slot, consecutive unpadded epochs (ids differ: independent draws)
    assert abs(lag.mean()) / 1.5**2 < 4 / np.sqrt(lag.size)
    assert np.isnan(one.uv[:, ::3, 30:]).all()


def _slam_short(monitors=("ekf",), start_distance_m=4000.0):
    ap = load_approach("zunz-rwy05-slam")
    cfg = ap.config.model_copy(update={"monitors": list(monitors),
                                       "flight": ap.config.flight.model_copy(update={"start_distance_m": start_distance_m})})
    return dataclasses.replace(ap, config=cfg)


def test_the_filter_with_features_block_by_block_equals_one_flight_and_records_them(tmp_path):
    """2 s and 7 s blocks give bit-identical ekf outputs with features; features enter the state; the
    recording carries the features tracked and in the state, and the scene."""
    a = run_approach(_slam_short(), seed=2, rrd_path=tmp_path / "a.rrd", block_s=2.0)
    b = run_approach(_slam_short(), seed=2, rrd_path=None, block_s=7.0)
    oa, ob = a.outputs["ekf"], b.outputs["ekf"]
    for f in ("pos_enu", "hpl", "vpl", "test_stat", "clock"):
        np.testing.assert_array_equal(getattr(oa, f), getattr(ob, f), err_msg=f)
    nf = np.asarray(oa.diagnostics.n_features)
    np.testing.assert_array_equal(nf, ob.diagnostics.n_features)
    assert nf.max() >= 3 and (oa.reason == 0).all() and np.isfinite(oa.hpl).all()
    assert a.summaries["ekf"].mi_epochs == 0
    t, v = readback.scalar_series(a.rrd_path, "sensors/features_in_state/ekf")
    np.testing.assert_array_equal(v, nf)
    t, v = readback.scalar_series(a.rrd_path, "sensors/features_tracked")
    assert v.size == oa.t.size and v.max() == 30


def test_same_seed_same_features_and_the_option_turns_them_off():
    """Bit-identical for one seed; another seed's tracking noise differs; ``[ekf] features = false``
    navigates without them (no feature states), as zunz-rwy05-ekf's filter."""
    a = run_approach(_slam_short(start_distance_m=2500.0), seed=5, rrd_path=None)
    b = run_approach(_slam_short(start_distance_m=2500.0), seed=5, rrd_path=None)
    c = run_approach(_slam_short(start_distance_m=2500.0), seed=6, rrd_path=None)
    np.testing.assert_array_equal(a.outputs["ekf"].pos_enu, b.outputs["ekf"].pos_enu)
    assert not np.array_equal(a.outputs["ekf"].pos_enu, c.outputs["ekf"].pos_enu)
    ap = _slam_short(start_distance_m=2500.0)
    off = dataclasses.replace(ap, config=ap.config.model_copy(update={"monitor": {"ekf": EkfSettings(features=False)}}))
    d = run_approach(off, seed=5, rrd_path=None)
    assert (np.asarray(d.outputs["ekf"].diagnostics.n_features) == 0).all()
    assert not np.array_equal(a.outputs["ekf"].pos_enu, d.outputs["ekf"].pos_enu)


@pytest.mark.slow
def test_campaign_with_features_is_consistent_and_paired_against_none():
    """40 fault-free sorties (one satellite, the walls as a cap; start times over a day): with features the
    position NEES averaged over the runs stays inside its χ²(3·40) 99 % band at ≥ 90 % of epochs (as the
    17-state filter's), features are in the state, and the sorties are paired: the same IMU, GNSS and
    alignment draws with and without (common random numbers), so only the features differ."""
    from testbed.campaign.blocks import draw_block, monitor_block
    from testbed.campaign.context import cell_context
    from testbed.campaign.spec import expand_cells, load_spec
    from testbed.resources import campaigns_dir

    loaded = load_spec(campaigns_dir() / "ekf-features.toml", trials=40)
    spec = loaded.spec.model_copy(update={"block_trials": 40})
    cells = [c for c in expand_cells(loaded) if c.params["fault_size"] == 0 and c.params["max_satellites"] == 1]
    assert [c.params["ground_features"] for c in cells] == [0, 1]
    res = {}
    for c in cells:
        ctx = cell_context(c, spec)
        d = draw_block(ctx, spec, 0)
        out = monitor_block(ctx.setup.monitors, d.obs)["ekf"]
        e = np.asarray(out.pos_enu) - ctx.truth_cg_enu
        P = np.asarray(out.diagnostics.cov_enu)
        res[c.params["ground_features"]] = (d, out, np.einsum("bti,btij,btj->bt", e, np.linalg.inv(P), e))
    (d0, o0, _), (d1, o1, nees) = res[0], res[1]
    np.testing.assert_array_equal(d0.obs.imu.dvel, d1.obs.imu.dvel)
    np.testing.assert_array_equal(d0.obs.gnss.pseudorange, d1.obs.gnss.pseudorange)
    assert d0.obs.features is None and d1.obs.features.uv.shape[0] == 40
    lo, hi = stats.chi2.ppf([0.005, 0.995], 3 * 40) / 40
    inside = (nees.mean(0) >= lo) & (nees.mean(0) <= hi)
    assert inside.mean() >= 0.9, inside.mean()
    assert np.asarray(o1.diagnostics.n_features).mean() >= 2.0
    assert (np.asarray(o0.diagnostics.n_features) == 0).all()
