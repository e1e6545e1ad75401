"""Streaming the vision synthesis: geometry/noise split, block concatenation, prefix stability."""

from __future__ import annotations

import math
from dataclasses import fields, replace

import numpy as np
import pytest
from scipy import stats

from testbed.flight.kinematic import straight_truth
from testbed.frames import LocalFrame
from testbed.sensors.faults import GpsStep, LandmarkMoved, Misassociation, PixelBias
from testbed.sensors.vision import (DitheringSettings, FaultKind, VisionSettings, build_landmarks, concat_geometry,
                                    dithering_angles, sample_vision, seed_triangle_settings, slice_epochs,
                                    synthesize_vision, vision_geometry, zunz_runway_settings)
from testbed.sensors.vision.detect import _GEOMETRY_EPOCH_FIELDS
from testbed.world import airport

P_TAIL = 1e-4


def seed_truth(rate_hz=10.0):
    """The VA-RAIM paper §3.1 leg, with a varying body rate so the motion blur changes along the flight."""
    fr = LocalFrame(*airport.VA_RAIM_CENTRE)
    a = fr.geodetic_to_enu(29.3065, 94.2539, 3650.0)
    b = fr.geodetic_to_enu(29.3065, 94.3144, 3150.0)
    tr = straight_truth(fr, a, b, 60.0, rate_hz=rate_hz)
    w = 0.05 * np.stack([np.sin(0.3 * tr.t), np.cos(0.2 * tr.t), 0.5 * np.sin(0.7 * tr.t)], axis=-1)
    return replace(tr, omega_body=w)


def runway_truth():
    fr = airport.runway_frame()
    c = math.radians(airport.RWY05_COURSE_DEG)
    along = np.array([math.sin(c), math.cos(c), 0.0])
    start = -6000.0 * along + [0.0, 0.0, 15.0 + 6000.0 * math.tan(math.radians(3.0))]
    return straight_truth(fr, start, np.array([0.0, 0.0, 15.0]), 6000.0 / 72.0, rate_hz=10.0)


def two_ridges():
    return pytest.importorskip("testbed.world.terrain").TwoRidges()


SEED_CAM = {"preset": "va-raim-2015", "dpi": 720}
STRONG_DITHER = {"tones": [{"axis": "pitch", "freq_hz": 3.0, "amplitude_deg": 0.1},
                           {"axis": "yaw", "freq_hz": 1.3, "amplitude_deg": 0.05}],
                 "noise_rms_deg": (0.05, 0.1, 0.1), "noise_bandwidth_hz": 2.0}
NOISY = dict(camera=SEED_CAM, dithering=STRONG_DITHER, detection={"sigma_px": 1.5, "exposure_s": 0.01},
             attitude_ref={"bias_sigma_deg": (0.1, 0.1, 0.3), "noise_sigma_deg": (0.02, 0.02, 0.05)})
# first active epochs (10 Hz from t = 0): 211 (t = 21.1 s) and 334 (t = 33.4 s)
FAULTS = [PixelBias(kind="pixel_bias", magnitude_px=8.0, angle_deg=40.0, onset_s=21.05),
          LandmarkMoved(kind="landmark_moved", delta_enu_m=(40.0, -20.0, 3.0), onset_s=33.35, end_s=55.0),
          Misassociation(kind="misassociation", landmarks=("T1", "T3"), onset_s=5.0, end_s=15.0),
          GpsStep(kind="gps_step", bias_m=10.0)]  # not a vision fault: ignored
PB_ONSET, LM_ONSET = 211, 334

CASES = {
    "default": (VisionSettings(), seed_triangle_settings(), None, None),
    "noisy": (VisionSettings(**NOISY), seed_triangle_settings(), None, None),
    "faults+terrain": (VisionSettings(**NOISY), seed_triangle_settings(), "ridges", FAULTS),
    "distortion": (VisionSettings(**{**NOISY, "camera": {"preset": "approach-1080p", "k1": -0.2, "k2": 0.05}}),
                   seed_triangle_settings(), None, FAULTS[:1]),
}


def arrays_equal(a, b, skip=()):
    """Names of the array fields of records ``a`` and ``b`` that differ (bit for bit, NaN == NaN)."""
    bad = []
    for f in fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name in skip or not isinstance(x, np.ndarray):
            continue
        if x.shape != y.shape or not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
            bad.append(f.name)
    return bad


def setup(case):
    s, lms, terrain, faults = CASES[case]
    terrain = two_ridges() if terrain == "ridges" else None
    tr = seed_truth().decimate(s.rate_hz)
    g = vision_geometry(tr, s, landmarks=lms, terrain=terrain, faults=faults)
    return s, lms, terrain, faults, tr, g


# ------------------------------------------------------------------ geometry
@pytest.mark.parametrize("case", ["faults+terrain", "runway"])
def test_geometry_of_blocks_concatenates_to_the_whole(case):
    if case == "runway":
        s, lms, terrain, faults = VisionSettings(), zunz_runway_settings(), None, None
        tr = runway_truth().decimate(s.rate_hz)
    else:
        s, lms, terrain, faults, tr, _ = setup(case)
    whole = vision_geometry(tr, s, landmarks=lms, terrain=terrain, faults=faults)
    T = len(tr.t)
    cuts = [0, 1, 1, 10, 11, 211, 334, 400, T] if T > 400 else [0, 1, 10, 11, 200, T]  # incl. an empty block
    parts = [vision_geometry(tr.at_indices(np.arange(a, b)), s, landmarks=lms, terrain=terrain, faults=faults)
             for a, b in zip(cuts[:-1], cuts[1:])]
    for cat in (concat_geometry(parts), parts[0].concat(*parts[1:])):
        assert len(cat) == T
        for k in _GEOMETRY_EPOCH_FIELDS:
            assert np.array_equal(getattr(cat, k), getattr(whole, k)), k
        assert cat.same_constants(whole)
    # slicing a geometry = the geometry of the sliced truth
    sub = whole[100:250]
    ref = vision_geometry(tr.at_indices(np.arange(100, 250)), s, landmarks=lms, terrain=terrain, faults=faults)
    for k in _GEOMETRY_EPOCH_FIELDS:
        assert np.array_equal(getattr(sub, k), getattr(ref, k)), k


def test_geometry_is_truth_only_and_checked():
    s, lms, terrain, faults, tr, g = setup("faults+terrain")
    # the noise settings do not enter the geometry
    g2 = vision_geometry(tr, VisionSettings(camera=SEED_CAM), landmarks=lms, terrain=terrain, faults=faults)
    for k in _GEOMETRY_EPOCH_FIELDS:
        assert np.array_equal(getattr(g, k), getattr(g2, k)), k
    assert g.los_moved.shape == (len(tr.t), 1, 3) and g.moved_keys.shape == (1, 5)
    other = vision_geometry(tr, s, landmarks=lms, terrain=terrain)  # no LandmarkMoved fault
    with pytest.raises(ValueError, match="another scene"):
        concat_geometry([g[:10], other[10:20]])
    with pytest.raises(ValueError, match="not in the geometry"):
        sample_vision(other, s, landmarks=lms, faults=faults, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="landmarks"):
        sample_vision(g, s, landmarks=zunz_runway_settings(), rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="mount"):
        sample_vision(g, VisionSettings(**{**NOISY, "mount": {"pitch_deg": -5.0}}), landmarks=lms,
                      rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="at least one"):
        concat_geometry([])
    with pytest.raises(TypeError, match="slice"):
        g[3]


# ------------------------------------------------------------------ prefix stability
@pytest.mark.parametrize("case", list(CASES))
def test_prefix_stable(case):
    """sample_vision(geometry[:T1]) == first T1 epochs of sample_vision(geometry[:T2]), bit for bit."""
    s, lms, terrain, faults, tr, g = setup(case)
    T = len(g)
    seed = 17
    runs = {n: sample_vision(g[:n], s, landmarks=lms, faults=faults, rng=np.random.default_rng(seed))
            for n in (1, 2, 57, PB_ONSET - 1, PB_ONSET, PB_ONSET + 1, LM_ONSET - 1, LM_ONSET, 500, T - 1, T)}
    lengths = sorted(runs)
    for i, T1 in enumerate(lengths):
        for T2 in lengths[i + 1:]:
            ep1, vt1 = runs[T1]
            ep2, vt2 = slice_epochs(*runs[T2], 0, T1)
            assert arrays_equal(ep1, ep2) == [], (T1, T2)
            moved_known = faults is None or T1 > LM_ONSET or not any(isinstance(f, LandmarkMoved) for f in faults)
            assert arrays_equal(vt1, vt2, skip=() if moved_known else ("landmark_moved_ecef",)) == [], (T1, T2)
            if not moved_known:  # the target is drawn at the onset: not known before it
                np.testing.assert_array_equal(vt1.landmark_moved_ecef, vt1.landmark_true_ecef)
    # the case exercises what it claims
    ep, vt = runs[T]
    if case != "default":
        assert np.abs(vt.dither_cam).max() > np.radians(0.05)
        assert np.ptp(vt.blur_sigma_px) > 0.1 and np.abs(vt.noise_px).max() > 1.0
        assert np.abs(np.diff(vt.attitude_ref_error, axis=0)).max() > 0
    if faults:
        pb = vt.fault_kind == FaultKind.PIXEL_BIAS
        assert pb.any() and not pb[:PB_ONSET].any() and pb[PB_ONSET].any()
        if any(isinstance(f, LandmarkMoved) for f in faults):
            assert vt.landmark_moved.any() and not vt.landmark_moved[:LM_ONSET].any()
            assert vt.landmark_moved[LM_ONSET].any()
            assert (vt.fault_kind == FaultKind.MISASSOCIATION).any()


@pytest.mark.parametrize("seed", range(6))
def test_random_fault_targets_prefix_stable(seed):
    """The "random" targets (pixel bias and moved landmark) are drawn from the epochs up to the onset."""
    s, lms, terrain, faults, tr, g = setup("faults+terrain")
    full = sample_vision(g, s, landmarks=lms, faults=faults, rng=np.random.default_rng(seed))[1]
    for T1 in (PB_ONSET + 1, LM_ONSET + 1):
        part = sample_vision(g[:T1], s, landmarks=lms, faults=faults, rng=np.random.default_rng(seed))[1]
        np.testing.assert_array_equal(part.fault_pixel_bias, full.fault_pixel_bias[:T1])
        np.testing.assert_array_equal(part.landmark_moved, full.landmark_moved[:T1])
    np.testing.assert_array_equal(part.landmark_moved_ecef, full.landmark_moved_ecef)


def test_block_by_block_loop_equals_one_whole_flight_call():
    """The closed loop's use: geometry per 1 s block, accumulated; sample; keep the new epochs."""
    s, lms, _, faults = CASES["faults+terrain"]
    terrain = two_ridges()
    truth = seed_truth()
    whole_ep, whole_vt = synthesize_vision(truth, s, landmarks=lms, terrain=terrain, faults=faults,
                                           rng=np.random.default_rng(5))
    tr = truth.decimate(s.rate_hz)
    T = len(tr.t)
    geometry = None
    for a in range(0, T, 10):
        b = min(a + 10, T)
        block = vision_geometry(tr.at_indices(np.arange(a, b)), s, landmarks=lms, terrain=terrain, faults=faults)
        geometry = block if geometry is None else concat_geometry([geometry, block])
        ep, vt = slice_epochs(*sample_vision(geometry, s, landmarks=lms, faults=faults,
                                             rng=np.random.default_rng(5)), a, b)
        ref_ep, ref_vt = slice_epochs(whole_ep, whole_vt, a, b)
        assert arrays_equal(ep, ref_ep) == [], a
        skip = () if b > LM_ONSET else ("landmark_moved_ecef",)
        assert arrays_equal(vt, ref_vt, skip=skip) == [], a


# ------------------------------------------------------------------ batched, streams, slicing
def test_batched_is_deterministic_and_matches_synthesize():
    s, lms, terrain, faults, tr, g = setup("faults+terrain")
    a = sample_vision(g, s, landmarks=lms, faults=faults, rng=np.random.default_rng(8), n_trials=4)
    b = sample_vision(g, s, landmarks=lms, faults=faults, rng=np.random.default_rng(8), n_trials=4)
    c = synthesize_vision(seed_truth(), s, landmarks=lms, terrain=terrain, faults=faults,
                          rng=np.random.default_rng(8), n_trials=4)
    for x, y in ((a, b), (a, c)):
        assert arrays_equal(x[0], y[0]) == [] and arrays_equal(x[1], y[1]) == []
    ep, vt = a
    assert ep.pixel_uv.shape == (4, len(g), 3, 2) and vt.cam_pos_ecef.shape == (len(g), 3)
    assert not np.allclose(vt.noise_px[0], vt.noise_px[1]) and not np.allclose(vt.dither_cam[0], vt.dither_cam[1])


def test_components_draw_from_separate_streams():
    """Turning one random component off leaves the others' draws unchanged."""
    s, lms, terrain, faults, tr, g = setup("noisy")
    base = dict(landmarks=lms, rng=None)
    runs = {}
    for name, st in (("all", s), ("no_dither", s.model_copy(update={"dithering": DitheringSettings(enabled=False)})),
                     ("no_exposure", VisionSettings(**{**NOISY, "detection": {"sigma_px": 1.5, "exposure_s": 0.0}}))):
        runs[name] = sample_vision(g, st, **{**base, "rng": np.random.default_rng(1)})[1]
    a, nd, ne = runs["all"], runs["no_dither"], runs["no_exposure"]
    np.testing.assert_array_equal(a.landmark_survey_ecef, nd.landmark_survey_ecef)
    np.testing.assert_array_equal(a.attitude_ref_error, nd.attitude_ref_error)
    assert not nd.dither_cam.any()
    # same standard normal draws, scaled by each run's own sigma (the per-landmark blur model; the rotation
    # model draws the frame's blur from a stream of its own and leaves these draws as they are)
    np.testing.assert_array_equal(a.dither_cam, ne.dither_cam)
    ind = s.model_copy(update={"detection": s.detection.model_copy(update={"blur_model": "independent"})})
    a_i = sample_vision(g, ind, **{**base, "rng": np.random.default_rng(1)})[1]
    sig = lambda v, share=1.0: np.sqrt(1.5**2 + (share * v.blur_sigma_px)**2)[..., None, None]  # noqa: E731
    np.testing.assert_allclose(a_i.noise_px / sig(a_i), ne.noise_px / sig(ne), rtol=1e-12)
    common = a.noise_px - (a_i.noise_px / sig(a_i)) * sig(a, 0.1)  # the rotation model's frame part alone
    assert np.abs(common).max() > 0.1 and np.ptp(a.blur_sigma_px) > 0.1


def test_slice_epochs():
    s, lms, terrain, faults, tr, g = setup("faults+terrain")
    ep, vt = sample_vision(g, s, landmarks=lms, faults=faults, rng=np.random.default_rng(2), n_trials=3)
    e2, v2 = slice_epochs(ep, vt, 100, 130)
    np.testing.assert_array_equal(e2.t, ep.t[100:130])
    np.testing.assert_array_equal(e2.pixel_uv, ep.pixel_uv[:, 100:130])
    np.testing.assert_array_equal(e2.q_body_to_enu_ref, ep.q_body_to_enu_ref[:, 100:130])
    np.testing.assert_array_equal(e2.landmark_pos_ecef, ep.landmark_pos_ecef)  # per-flight constant
    np.testing.assert_array_equal(v2.blur_sigma_px, vt.blur_sigma_px[:, 100:130])
    np.testing.assert_array_equal(v2.cam_pos_ecef, vt.cam_pos_ecef[100:130])
    np.testing.assert_array_equal(v2.fault_kind, vt.fault_kind[:, 100:130])
    np.testing.assert_array_equal(v2.landmark_moved_ecef, vt.landmark_moved_ecef)
    for rec, ref in ((e2, ep), (v2, vt)):
        for f in fields(rec):
            x = getattr(rec, f.name)
            if isinstance(x, np.ndarray) and x.ndim and x.shape != getattr(ref, f.name).shape:
                assert 30 in x.shape, f.name
    e3, v3 = slice_epochs(ep, None, -5, None)
    assert v3 is None and e3.detected.shape == (3, 5, 3)
    e0, v0 = slice_epochs(*sample_vision(g, s, landmarks=lms, faults=faults, rng=np.random.default_rng(2)), 7, 7)
    assert e0.pixel_uv.shape == (0, 3, 2) and v0.noise_px.shape == (0, 3, 2)


def test_empty_and_single_epoch_geometry():
    s, lms, terrain, faults, tr, g = setup("faults+terrain")
    for n in (0, 1):
        ep, vt = sample_vision(g[:n], s, landmarks=lms, faults=faults, rng=np.random.default_rng(0))
        assert ep.pixel_uv.shape == (n, 3, 2) and vt.dither_cam.shape == (n, 3)
    g0 = vision_geometry(tr.at_indices(np.arange(0)), s, landmarks=lms, terrain=terrain, faults=faults)
    assert len(g0) == 0 and g0.diff_ecef.shape == (0, 3, 3)


# ------------------------------------------------------------------ dithering noise
def test_dithering_noise_prefix_stable_and_stationary_from_the_start():
    t = np.arange(0.0, 30.0, 0.1)
    s = DitheringSettings(noise_rms_deg=(0.03, 0.05, 0.08), noise_bandwidth_hz=2.0)
    d, r = dithering_angles(t, s, np.random.default_rng(4), sample_rate_hz=10.0)
    for k in (1, 2, 33, 299):
        dk, rk = dithering_angles(t[:k], s, np.random.default_rng(4), sample_rate_hz=10.0)
        np.testing.assert_array_equal(dk, d[:k])
        np.testing.assert_array_equal(rk, r[:k])
    # across trials the first sample is already N(0, rms²) (burn-in: stationary start) and stays so
    s = DitheringSettings(tones=[], noise_rms_deg=(0.03, 0.05, 0.08), noise_bandwidth_hz=2.0)
    d, _ = dithering_angles(t[:50], s, np.random.default_rng(6), n_trials=2000, sample_rate_hz=10.0)
    cam_rms = np.radians([0.05, 0.08, 0.03])
    for i in (0, 49):
        chi = np.sum((d[:, i, :] / cam_rms) ** 2)
        n = d[:, i, :].size
        assert stats.chi2.ppf(P_TAIL / 2, n) < chi < stats.chi2.ppf(1 - P_TAIL / 2, n), i


def test_synthesize_is_sample_of_geometry():
    """synthesize_vision = sample_vision(vision_geometry(decimated truth)) for one flight."""
    s, lms, terrain, faults = CASES["faults+terrain"]
    terrain = two_ridges()
    truth = seed_truth(rate_hz=50.0)
    a = synthesize_vision(truth, s, landmarks=lms, terrain=terrain, faults=faults, rng=np.random.default_rng(3))
    g = vision_geometry(truth.decimate(s.rate_hz), s, landmarks=build_landmarks(lms), terrain=terrain, faults=faults)
    b = sample_vision(g, s, landmarks=lms, faults=faults, rng=np.random.default_rng(3))
    assert arrays_equal(a[0], b[0]) == [] and arrays_equal(a[1], b[1]) == []
    np.testing.assert_allclose(np.diff(a[0].t), 0.1, atol=1e-9)
