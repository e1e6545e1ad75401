"""The seed-002 filter in the loop: the ekf monitor through testbed fly, live blocks = one flight,
its recording tab, and the campaign's clear refusal (it draws no IMU data yet)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from testbed.api import load_approach, run_approach
from testbed.viz import readback


def _short(monitors=("gps_raim", "ekf")):
    ap = load_approach("zunz-rwy05-final")
    cfg = ap.config.model_copy(update={"monitors": list(monitors),
                                       "flight": ap.config.flight.model_copy(update={"start_distance_m": 3000.0})})
    return dataclasses.replace(ap, config=cfg)


def test_block_by_block_equals_one_flight_and_the_filter_tracks(tmp_path):
    """The alignment, IMU errors and filter carried across blocks: 2 s and 7 s blocks give bit-identical
    ekf outputs; the filter's error stays inside its covariance PLs and its horizontal 95 % error is
    below GPS RAIM's; the recording has an ekf tab."""
    a = run_approach(_short(), seed=3, rrd_path=tmp_path / "a.rrd", block_s=2.0)
    b = run_approach(_short(), seed=3, rrd_path=None, block_s=7.0)
    oa, ob = a.outputs["ekf"], b.outputs["ekf"]
    for f in ("pos_enu", "hpl", "vpl", "test_stat", "clock"):
        np.testing.assert_array_equal(getattr(oa, f), getattr(ob, f), err_msg=f)
    s = a.summaries["ekf"]
    assert s.mi_epochs == 0 and s.hmi_epochs == 0
    assert s.hpe95 < a.summaries["gps_raim"].hpe95
    assert (oa.reason == 0).all() and np.isfinite(oa.hpl).all()
    t, v = readback.scalar_series(a.rrd_path, "integrity/ekf/horizontal/hpl")
    np.testing.assert_allclose(v, oa.hpl, rtol=1e-6)


def test_same_seed_same_filter_output():
    a = run_approach(_short(), seed=5, rrd_path=None)
    b = run_approach(_short(), seed=5, rrd_path=None)
    np.testing.assert_array_equal(a.outputs["ekf"].pos_enu, b.outputs["ekf"].pos_enu)


def test_a_campaign_with_the_filter_is_refused_with_a_reason(tmp_path):
    from testbed.campaign.spec import CampaignSpec

    with pytest.raises(ValueError, match=r"read IMU data, which campaigns do not draw yet"):
        CampaignSpec(name="x", approaches=["zunz-rwy05-final"], monitors=["gps_raim", "ekf"], trials=10)
