"""The DPE monitor in the loop: testbed fly with correlators, live blocks = one flight, its recording tab,
and the campaign's clear refusal (campaigns draw no correlators yet)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from testbed.api import load_approach, run_approach
from testbed.resources import approaches_dir
from testbed.viz import readback


def _short():
    ap = load_approach("zunz-rwy05-dpe")
    cfg = ap.config.model_copy(update={"flight": ap.config.flight.model_copy(update={"start_distance_m": 3000.0})})
    return dataclasses.replace(ap, config=cfg)


def test_block_by_block_equals_one_flight_and_the_recording_has_the_dpe_tab(tmp_path):
    """Correlators drawn per epoch and the DPE's carried fix: 2 s and 7 s blocks give bit-identical
    outputs; every epoch is available with its vertical error inside the VPL; the recording holds
    the VPL, the overbound and the error density the VPL bounds."""
    a = run_approach(_short(), seed=3, rrd_path=tmp_path / "a.rrd", block_s=2.0)
    b = run_approach(_short(), seed=3, rrd_path=None, block_s=7.0)
    oa, ob = a.outputs["dpe"], b.outputs["dpe"]
    for f in ("pos_enu", "vpl", "test_stat", "clock"):
        np.testing.assert_array_equal(getattr(oa, f), getattr(ob, f), err_msg=f)
    np.testing.assert_array_equal(oa.diagnostics.marginal, ob.diagnostics.marginal)
    shipped = json.loads((approaches_dir() / "calibration" / "dpe-k.json").read_text())
    assert oa.diagnostics.k_factor == shipped["k"] and shipped["validation"]["passed"]  # the calibrated K, read
    s = a.summaries["dpe"]
    assert (oa.reason == 0).all() and s.mi_epochs == 0 and s.hmi_epochs == 0
    assert np.all(np.isnan(oa.hpl)) and np.isnan(s.hpl_max)
    t, v = readback.scalar_series(a.rrd_path, "integrity/dpe/vertical/vpl")
    np.testing.assert_allclose(v, oa.vpl, rtol=1e-6)
    t, v = readback.scalar_series(a.rrd_path, "integrity/dpe/overbound/sigma_ob")
    np.testing.assert_allclose(v, oa.diagnostics.sigma_ob, rtol=1e-6)
    assert "/integrity/dpe/vertical_error_density" in readback.entity_paths(a.rrd_path)


def test_a_campaign_with_the_dpe_is_refused_with_a_reason():
    from testbed.campaign.spec import CampaignSpec

    with pytest.raises(ValueError, match=r"read correlator outputs, which campaigns do not synthesise yet"):
        CampaignSpec(name="x", approaches=["zunz-rwy05-final"], monitors=["gps_raim", "dpe"], trials=10)
