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
