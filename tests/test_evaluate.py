"""Stanford regions: each constructed epoch lands in exactly the region its definition says."""

import numpy as np

from testbed.sim.evaluate import REGIONS, stanford_regions

AL = 40.0


def test_each_region_by_construction():
    #            normal unavail misl  hazard  unav+misl alerted(err>AL) no-solution
    err = np.array([5.0, 5.0, 30.0, 60.0, 80.0, 90.0, np.nan])
    pl = np.array([10.0, 50.0, 20.0, 30.0, 60.0, 30.0, 10.0])
    alert = np.array([False, False, False, False, False, True, False])
    r = stanford_regions(err, pl, AL, alert)
    expected = ["normal", "unavailable", "misleading", "hazardous", "unavailable_misleading", "alerted",
                "no_solution"]
    for i, name in enumerate(expected):
        hits = [k for k in REGIONS if r[k][i]]
        assert hits == [name], (i, hits)


def test_without_alerts_the_detected_epoch_is_hazardous():
    r = stanford_regions(np.array([90.0]), np.array([30.0]), AL)
    assert r["hazardous"][0] and not r["alerted"][0]


def test_regions_partition_random_epochs():
    rng = np.random.default_rng(0)
    err = 10 ** rng.uniform(-1, 3, 10_000)
    pl = 10 ** rng.uniform(-1, 3, 10_000)
    err[::97] = np.nan
    alert = rng.random(10_000) < 0.1
    r = stanford_regions(err, pl, AL, alert)
    assert np.array_equal(sum(r[k].astype(int) for k in REGIONS), np.ones(10_000, int))


def test_a_gnss_fault_no_tracked_satellite_carries_is_not_exercised():
    from testbed.sensors.faults import GpsStep
    from testbed.sim.evaluate import describe_faults

    f = [GpsStep(kind="gps_step", prn=7, bias_m=30.0, onset_s=10.0)]
    t, prn = np.arange(5.0), np.array([3, 7])
    faulty = np.zeros((5, 2), bool)
    faulty[2:, 1] = True
    hidden = np.array([[True, False]] * 5)  # PRN 7 never tracked
    lines = describe_faults(f, prn, faulty, hidden, t)
    assert lines[0].startswith("fault: gps_step +30 m on PRN 7 from 10 s")
    assert lines[1].endswith("not exercised")
    lines = describe_faults(f, prn, faulty, np.ones((5, 2), bool), t)
    assert lines[1].strip() == "in the observations: PRN 7 at 3 of 5 epochs (2-4 s)"


def test_the_unavailable_reason_is_the_most_frequent_code_and_none_when_ever_available():
    from types import SimpleNamespace

    from testbed.sim.evaluate import unavailable_reason

    out = SimpleNamespace(available=np.zeros((4, 2), bool), reason=np.array([1, 2, 2, 0]),
                          reasons=("ok", "unavailable: too few satellites", "geometry"))
    assert unavailable_reason(out) == "geometry (2 of 4 epochs)"
    assert unavailable_reason(SimpleNamespace(**{**vars(out), "available": np.eye(4, 2, dtype=bool)})) is None
