"""GNSS synthesis: light time (inertial brute force), batching, determinism, faults."""

import numpy as np
import pytest
from scipy.optimize import brentq

from testbed.flight.kinematic import straight_truth
from testbed.frames import C_LIGHT, OMEGA_EARTH
from testbed.records import Mount
from testbed.sensors.faults import GpsRamp, GpsStep
from testbed.sensors.gnss.orbits import sat_states
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.gnss.synth import gnss_geometry, sample_gnss, synthesize_gnss
from testbed.world.airport import runway_frame

START = "2024-03-15T06:00:00Z"
ONE_MM = 1e-3


@pytest.fixture(scope="module")
def truth():
    return straight_truth(runway_frame(), [-9000.0, -6400.0, 650.0], [-3000.0, -2100.0, 200.0], 60.0, rate_hz=10.0)


def _Rz(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_light_time_against_inertial_brute_force(truth):
    """Solve cτ = |r_sat^I(t_r − τ) − r_rx^I(t_r)| with brentq in the inertial frame aligned with ECEF at t_r.

    The unknown is τ itself (t_gps floats near 1.4e9 s resolve only 0.24 µs = 72 m of c·t).
    Also checked: the textbook first-order Sagnac form |s(t_t) − r| + Ω̇e(x_s y_r − y_s x_r)/c.
    """
    s = GnssSettings(terrain_masking=False)
    g = gnss_geometry(truth, Mount(np.zeros(3)), s, start_utc=START)
    for k in (0, 30, 60):
        rx = g.ant_pos_ecef[k]
        for j in np.flatnonzero(g.visible[k])[:4]:
            eph = g.eph.take([j])

            def f(tau):
                p, *_ = sat_states(eph, g.t_gps[k] - tau)
                return C_LIGHT * tau - np.linalg.norm(_Rz(-OMEGA_EARTH * tau) @ p[0] - rx)
            tau = brentq(f, 0.05, 0.1, xtol=1e-15)
            assert C_LIGHT * tau == pytest.approx(g.geometric_range[k, j], abs=ONE_MM)
            p, *_ = sat_states(eph, g.t_gps[k] - tau)
            sagnac = np.linalg.norm(p[0] - rx) + OMEGA_EARTH * (p[0, 0] * rx[1] - p[0, 1] * rx[0]) / C_LIGHT
            assert sagnac == pytest.approx(g.geometric_range[k, j], abs=0.01)  # second-order terms < 1 cm


def test_shapes_batch_and_decimation(truth):
    s = GnssSettings(terrain_masking=False)  # 1 Hz: the 10 Hz truth is decimated inside
    ep, tr = synthesize_gnss(truth, Mount(np.zeros(3)), s, start_utc=START, rng=np.random.default_rng(1), n_trials=7)
    T, S = 61, 24
    assert ep.t.shape == (T,) and np.allclose(np.diff(ep.t), 1.0)
    assert ep.pseudorange.shape == (7, T, S) and ep.sat_pos_ecef.shape == (7, T, S, 3)
    assert tr.noise.shape == (7, T, S) and tr.clock_bias.shape == (7, T)
    assert np.all(np.isnan(ep.pseudorange[~ep.visible])) and np.all(np.isfinite(ep.pseudorange[ep.visible]))
    assert np.all(np.isnan(ep.sigma[~ep.visible]))
    # trials differ; geometry is shared
    assert np.abs(ep.pseudorange[0] - ep.pseudorange[1])[ep.visible[0]].max() > 1.0
    ep1, _ = synthesize_gnss(truth, Mount(np.zeros(3)), s, start_utc=START, rng=np.random.default_rng(1))
    assert ep1.pseudorange.shape == (T, S)
    # pseudorange = |sat − antenna| + clock + noise (the monitor's model, no hidden terms)
    pr_model = (np.linalg.norm(ep.sat_pos_ecef - tr.antenna_pos_ecef[:, None], axis=-1)
                + tr.clock_bias[..., None] + tr.noise)
    np.testing.assert_allclose(ep.pseudorange[ep.visible], pr_model[ep.visible], atol=1e-6)


def test_bit_identical_reruns(truth):
    s = GnssSettings(terrain_masking=False, multipath_tau_s=15.0)
    a, _ = synthesize_gnss(truth, Mount(np.zeros(3)), s, start_utc=START, rng=np.random.default_rng(42), n_trials=3)
    b, _ = synthesize_gnss(truth, Mount(np.zeros(3)), s, start_utc=START, rng=np.random.default_rng(42), n_trials=3)
    np.testing.assert_array_equal(a.pseudorange, b.pseudorange)
    np.testing.assert_array_equal(a.range_rate, b.range_rate)


def test_step_and_ramp_fault_on_chosen_prn(truth):
    s = GnssSettings(terrain_masking=False)
    g = gnss_geometry(truth.decimate(1.0), Mount(np.zeros(3)), s, start_utc=START)
    prn = int(g.prn[np.flatnonzero(g.visible[0])[0]])
    faults = [GpsStep(kind="gps_step", prn=prn, bias_m=50.0, onset_s=20.0, end_s=40.0),
              GpsRamp(kind="gps_ramp", prn=prn, rate_m_s=2.0, onset_s=45.0)]
    clean, _ = sample_gnss(g, s, rng=np.random.default_rng(3), n_trials=2)
    ep, tr = sample_gnss(g, s, faults=faults, rng=np.random.default_rng(3), n_trials=2)
    diff = np.nan_to_num(ep.pseudorange - clean.pseudorange)
    slot = np.flatnonzero(g.prn == prn)[0]
    expected = np.where((g.t >= 20) & (g.t < 40), 50.0, 0.0) + np.where(g.t >= 45, 2.0 * (g.t - 45.0), 0.0)
    vis = g.visible[:, slot]
    np.testing.assert_allclose(diff[:, :, slot], np.broadcast_to(np.where(vis, expected, 0.0), (2, g.t.size)),
                               atol=1e-6)
    others = np.delete(diff, slot, axis=-1)
    assert np.all(others == 0.0)
    np.testing.assert_array_equal(tr.faulty[..., slot], np.broadcast_to(expected != 0, (2, g.t.size)))
    assert not tr.faulty[..., np.arange(24) != slot].any()


def test_random_fault_differs_per_trial_and_bad_inputs(truth):
    s = GnssSettings(terrain_masking=False)
    g = gnss_geometry(truth.decimate(1.0), Mount(np.zeros(3)), s, start_utc=START)
    _, tr = sample_gnss(g, s, faults=[GpsStep(kind="gps_step", bias_m=30.0)], rng=np.random.default_rng(0),
                        n_trials=40)
    hit = tr.faulty.any(axis=1)  # (trials, S)
    assert np.all(hit.sum(1) == 1)
    assert len(np.unique(np.argmax(hit, 1))) > 1  # different satellites across trials
    assert np.all(g.visible[0][np.argmax(hit, 1)])  # always a satellite visible at onset
    with pytest.raises(ValueError, match="rng"):
        sample_gnss(g, s, rng=1)
    with pytest.raises(ValueError, match="n_trials"):
        sample_gnss(g, s, rng=np.random.default_rng(0), n_trials=0)
    with pytest.raises(ValueError, match="PRN"):
        sample_gnss(g, s, faults=[GpsStep(kind="gps_step", prn=31, bias_m=1.0)], rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="almanac_path"):
        GnssSettings(almanac_source="yuma")
