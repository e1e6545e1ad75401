"""The GNSS/vision/INS filter in the loop: the ekf monitor through testbed fly, live blocks = one flight,
its recording tab, and in campaigns (each trial its own IMU and alignment)."""

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
    # its tests, each over its threshold, on one panel of its tab
    t, v = readback.scalar_series(a.rrd_path, "integrity/ekf/tests/separation")
    np.testing.assert_allclose(v, oa.diagnostics.ss_ratio, rtol=1e-6)
    views = {(w["class"], w["origin"]) for w in readback.views(a.rrd_path)}
    assert ("TimeSeries", "/integrity/ekf/tests") in views and ("TimeSeries", "/integrity/gps_raim/detection") in views


def test_same_seed_same_filter_output():
    a = run_approach(_short(), seed=5, rrd_path=None)
    b = run_approach(_short(), seed=5, rrd_path=None)
    np.testing.assert_array_equal(a.outputs["ekf"].pos_enu, b.outputs["ekf"].pos_enu)


EKF_SPEC = """
name = "ekf-tiny"
approaches = ["zunz-rwy05-ekf"]
monitors = ["gps_raim", "ekf"]
trials = 6
block_trials = 3
chunk_trials = {chunk}
base_seed = 12
per_epoch_trials = 3
duration_s = 40.0

[[faults]]
kind = "gps_step"
magnitudes = [0.0, 30.0]
onset_s = 20.0
prn = "random"
"""


def test_a_campaign_runs_the_filter_with_its_imus_and_alignments(tmp_path):
    """Campaign trials draw their own IMU and alignment (children of the block seed): chunking does not change
    a bit; fault-free the filter raises no alert and is not misled; a 30 m step on a random satellite from
    20 s (8 satellites, then 3 from 30 s) is detected in every sortie and never misleads it."""
    import pyarrow.parquet as pq

    from testbed.campaign.runner import run_campaign

    outs = []
    for chunk in (3, 6):
        spec = tmp_path / f"s{chunk}.toml"
        spec.write_text(EKF_SPEC.format(chunk=chunk))
        run_campaign(spec, tmp_path / f"out{chunk}", progress=False)
        outs.append(pq.read_table(tmp_path / f"out{chunk}" / "trials.parquet").to_pandas())
    a, b = outs
    assert a.equals(b)
    ekf = a[a.monitor == "ekf"]
    ff, step = ekf[ekf.cell == 0], ekf[ekf.cell == 1]
    assert not ff.detected.any() and (ff.mi_epochs == 0).all() and (ff["avail_APV-I"] == 1.0).all()
    assert step.detected.all() and (step.mi_epochs == 0).all() and (step.hmi_epochs == 0).all()
    assert ekf.max_hpl.nunique() > 1  # each trial its own IMU and alignment


def test_with_one_to_three_satellites_the_filter_navigates_where_snapshot_raim_cannot():
    """zunz-rwy05-ekf: 8 satellites for 30 s, then 3, 2, 1. GPS RAIM and VA-RAIM are available only
    before the caps (≤ 21 % of the final); the filter with its default solution-separation PLs (a sub-filter
    without each satellite and each landmark) is available at APV-I on ≥ 95 % of the epochs with its error
    inside its PLs throughout and no false alert (measured: 100 %, HPL ≤ 28.6 m, VPL ≤ 14.2 m after the
    first minute, HPE95 5.5 m)."""
    run = run_approach("zunz-rwy05-ekf", seed=0, rrd_path=None)
    s = run.summaries
    for m in ("gps_raim", "va_raim"):
        assert s[m].availability["APV-I"] <= 0.21
    assert s["ekf"].availability["APV-I"] >= 0.95
    assert s["ekf"].mi_epochs == 0 and s["ekf"].hmi_epochs == 0
    assert s["ekf"].hpe95 < 10.0
    o = run.outputs["ekf"]
    assert not o.alert.any() and (o.diagnostics.n_modes >= 5).all()
    n_sat = np.asarray(run.loop.gnss.visible).sum(-1)
    t = run.loop.gnss.t
    assert n_sat[t >= 100].max() == 1 and n_sat[(t >= 30) & (t < 70)].max() == 3


def test_the_schedule_keeps_the_highest_satellites_and_rejects_disorder():
    from testbed.records import NotVisible
    from testbed.sensors.gnss.settings import GnssSettings, SatelliteCap
    from testbed.sensors.gnss.visibility import apply_schedule

    rng = np.random.default_rng(0)
    el = rng.uniform(0, 1.5, (5, 9))
    reason = np.where(rng.random((5, 9)) < 0.3, NotVisible.TERRAIN, 0).astype(np.int8)
    sched = [SatelliteCap(from_s=0.0, max_satellites=4), SatelliteCap(from_s=2.0, max_satellites=2)]
    out = apply_schedule(reason, el, np.arange(5.0), sched)
    for k in range(5):
        cap = 4 if k < 2 else 2
        vis = np.flatnonzero(reason[k] == 0)
        want = set(vis[np.argsort(-el[k, vis])][:cap])
        assert set(np.flatnonzero(out[k] == 0)) == want
        assert set(np.flatnonzero(out[k] == NotVisible.EXCLUDED)) == set(vis) - want
    with pytest.raises(ValueError, match="strictly increasing from_s"):
        GnssSettings(schedule=[{"from_s": 5.0, "max_satellites": 2}, {"from_s": 1.0, "max_satellites": 3}])


def test_the_satellites_in_view_axis_caps_the_tracked_satellites(tmp_path):
    """[sweep] max_satellites replaces the approach's schedule per cell: the cells table records the cap, the
    epochs table's satellites used by GPS RAIM never exceed it, and the filter's PLs grow as satellites go."""
    import pyarrow.parquet as pq

    from testbed.campaign.runner import run_campaign

    spec = tmp_path / "s.toml"
    spec.write_text(EKF_SPEC.format(chunk=3).replace("trials = 6", "trials = 3").replace("40.0", "20.0")
                    .replace("magnitudes = [0.0, 30.0]", "magnitudes = [0.0]") + "\n[sweep]\nmax_satellites = [1, 5]\n")
    run_campaign(spec, tmp_path / "out", progress=False)
    cells = pq.read_table(tmp_path / "out" / "cells.parquet").to_pandas()
    assert cells.max_satellites.tolist() == [1, 5]
    t = pq.read_table(tmp_path / "out" / "trials.parquet").to_pandas()
    ekf = t[t.monitor == "ekf"].groupby("cell").max_hpl.median()
    assert ekf[0] > ekf[1]
    raim = t[t.monitor == "gps_raim"]
    assert (raim[raim.cell == 0]["avail_APV-I"] == 0).all()  # one satellite: no snapshot fix


@pytest.mark.parametrize("segment", ["first", "last"])
def test_the_imu_segment_starts_at_the_cells_first_gnss_epoch(segment):
    """The filter's IMU increments and first pose start where the cell's GNSS epochs start, for both segments
    (a duration that is not a whole number of GNSS intervals: the full-rate and 1 Hz records end apart)."""
    from testbed.campaign.context import cell_context
    from testbed.campaign.spec import CampaignSpec, expand_cells, resolve_spec
    from testbed.resources import campaigns_dir

    spec = CampaignSpec.model_validate({"name": "seg", "approaches": ["zunz-rwy05-ekf"], "monitors": ["ekf"],
                                        "trials": 1, "base_seed": 1, "per_epoch_trials": 0, "duration_s": 20.37,
                                        "segment": segment, "faults": [{"kind": "none"}]})
    loaded = resolve_spec(spec, campaigns_dir() / "seg.toml")
    ctx = cell_context(expand_cells(loaded)[0], loaded.spec)
    t_imu = ctx.imu_increments[0]
    assert ctx.t[0] == 0.0 and ctx.imu_start[0] == 0.0
    assert t_imu[0] >= 0.0 and t_imu[-1] >= ctx.t[-1] - 1e-9
    np.testing.assert_allclose(ctx.imu_start[3], ctx.truth_cg_enu[0], atol=1e-6)


def test_the_araim_variant_in_the_loop_detects_an_imu_fault_and_is_block_independent():
    """``pl_variant = "araim"`` (IMU prior 1e-8, so it may go unmonitored with fewer than four satellites) on 3 km of
    the final with the camera. Fault-free in 2 s blocks: every epoch protected (finite PLs and EMT, reason 0), its
    error inside them, no alert. With a 0.5 m/s² accelerometer bias on body z from 20 s, in 7 s blocks: up to the
    onset bit-identical to the fault-free run (the bank, snapshot and landmarks seen carried across blocks; the fault
    draws nothing); after it the separation test alerts, and no epoch's error leaves the PLs unalerted."""
    from testbed.config import fault_from_option
    from testbed.sim.evaluate import position_errors

    ap = _short(("ekf",))
    cfg = ap.config.model_copy(update={"monitor": {"ekf": {"pl_variant": "araim",
                                                           "araim": {"inertia": {"p": 1e-8}}}}})
    ap = dataclasses.replace(ap, config=cfg)
    free = run_approach(ap, seed=3, rrd_path=None, block_s=2.0)
    hit = run_approach(ap, seed=3, rrd_path=None, block_s=7.0,
                       faults=[fault_from_option("imu_accel_bias:axis=z,bias_m_s2=0.5,onset_s=20")])
    of, oh = free.outputs["ekf"], hit.outputs["ekf"]
    before = free.loop.gnss.t < 20.0
    for f in ("hpl", "vpl", "alert", "reason"):
        np.testing.assert_array_equal(getattr(of, f)[before], getattr(oh, f)[before], err_msg=f)
    np.testing.assert_array_equal(of.diagnostics.emt[before], oh.diagnostics.emt[before])
    assert (of.reason == 0).all() and np.isfinite(of.vpl).all() and np.isfinite(of.diagnostics.emt).all()
    assert not of.alert.any() and free.summaries["ekf"].mi_epochs == 0
    assert (of.diagnostics.n_modes >= 6).all()
    rows = of.diagnostics.summary_rows()
    assert rows["EMT max / p95"].endswith(" m") and set(of.diagnostics.epoch_columns()) >= {"emt_m", "risk_inertia_v"}
    risk = of.diagnostics.risk_aid_enu[..., 2]  # vision and IMU modes' vertical risk: within the vertical budget
    assert np.all(risk >= 0.0) and np.all(risk.sum(-1) <= 9.8e-8 * (1 + 1e-9))
    assert oh.alert[~before].any()
    he, ve = position_errors(oh, hit.loop.truth_at_gnss.pos_enu)
    assert not np.any(((ve > oh.vpl) | (he > oh.hpl)) & ~oh.alert)
