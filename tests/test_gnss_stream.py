"""GNSS synthesis is prefix-stable: block-by-block synthesis equals the whole flight, bit for bit."""

import numpy as np
import pytest

from testbed.flight.kinematic import straight_truth
from testbed.records import Mount
from testbed.sensors.faults import GpsRamp, GpsStep
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.gnss.synth import gnss_geometry, sample_gnss
from testbed.sim.slicing import geometry_prefix
from testbed.world.airport import runway_frame


@pytest.mark.parametrize("settings", [GnssSettings(), GnssSettings(multipath_tau_s=30.0, ura_tropo_tau_s=300.0)],
                         ids=["white", "gauss-markov"])
def test_prefix_stable(settings):
    f = runway_frame()
    truth = straight_truth(f, [-10000, -7000, 700], [0, 0, 15], 120.0, rate_hz=1.0)
    geom = gnss_geometry(truth, Mount(np.zeros(3)), settings, start_utc="2026-03-01T04:00:00Z")
    faults = [GpsRamp(kind="gps_ramp", prn="random", rate_m_s=2.0, onset_s=80.0),
              GpsStep(kind="gps_step", prn="random", bias_m=50.0, onset_s=30.0)]
    whole, whole_t = sample_gnss(geom, settings, faults=faults, rng=np.random.default_rng(5))
    assert whole_t.faulty[:, :].any(axis=1)[31] and whole_t.faulty.any(axis=1)[81]
    for T1 in (1, 17, 31, 60, 81, 100):
        part_geom = geometry_prefix(geom, T1)
        part, part_t = sample_gnss(part_geom, settings, faults=faults, rng=np.random.default_rng(5))
        np.testing.assert_array_equal(part.pseudorange, whole.pseudorange[:T1])
        np.testing.assert_array_equal(part.range_rate, whole.range_rate[:T1])
        np.testing.assert_array_equal(part_t.fault_bias, whole_t.fault_bias[:T1])
        np.testing.assert_array_equal(part_t.clock_bias, whole_t.clock_bias[:T1])

