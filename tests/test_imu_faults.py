"""Inertial sensor faults (``imu_accel_bias``, ``imu_gyro_bias``; testbed.sensors.faults): what they add to the IMU
increments, against the closed-form integral of the bias (and scipy's quadrature of it); that they draw nothing;
their checks through the command line; their campaign axis; and the ekf's reaction in the loop.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from pydantic import TypeAdapter, ValidationError
from scipy.integrate import quad

from testbed.api import load_approach, run_approach
from testbed.config import fault_from_option
from testbed.flight.kinematic import straight_truth
from testbed.sensors.faults import Fault, ImuAccelBias, ImuGyroBias, imu_fault_epochs
from testbed.sensors.imu import ImuSettings, sample_imu
from testbed.sim.evaluate import position_errors
from testbed.world.airport import runway_frame

FRAME = runway_frame()
IMU = ImuSettings(grade="hg1700", scale_factor_ppm=300.0)  # noise, biases and scale factors: the fault rides on them
TRUTH = straight_truth(FRAME, [-3000.0, -2000.0, 300.0], [0.0, 0.0, 15.0], 10.0, rate_hz=120.0)
DT = 1.0 / 120.0


def _pair(faults, seed=11, n=3):
    """(fault-free, faulted) IMU samples of one seed, and the faulted truth record."""
    free, _ = sample_imu(TRUTH, IMU, np.random.default_rng(seed), n_trials=n)
    hit, truth = sample_imu(TRUTH, IMU, np.random.default_rng(seed), n_trials=n, faults=faults)
    return free, hit, truth


def _integral(f, a: float, b: float, onset: float, end: float) -> float:
    """∫ f(τ = s − onset) ds over (a, b] ∩ [onset, end), by adaptive quadrature (no formula of ours)."""
    lo, hi = max(a, onset), min(b, end)
    if hi <= lo:
        return 0.0
    return quad(lambda s: f(s - onset), lo, hi, epsabs=1e-15, epsrel=1e-13)[0]


def test_an_accelerometer_step_and_ramp_add_their_exact_integral_to_each_velocity_increment():
    """A 0.5 m/s² + 0.02 m/s³·τ bias on body z from an onset 0.3 of the way into an interval to an end 0.6 into
    another: faulted − fault-free Δv equals ∫ (b + r·τ) over the part of each interval inside the window (scipy's
    quad) to 1e-12 m/s, in every trial alike; zero (bit for bit) before the onset, after the end and on x, y; the
    angle increments untouched; the whole window adds b·T + ½·r·T² (T = end − onset); the truth record says so."""
    t = TRUTH.t[1:]
    onset, end = float(t[360] + 0.3 * DT), float(t[840] + 0.6 * DT)
    b, r = 0.5, 0.02
    fault = ImuAccelBias(kind="imu_accel_bias", axis="z", bias_m_s2=b, rate_m_s3=r, onset_s=onset, end_s=end)
    free, hit, truth = _pair([fault])
    d = hit.dvel - free.dvel  # (3, K, 3)
    want = np.array([_integral(lambda tau: b + r * tau, ti - DT, ti, onset, end) for ti in hit.t])
    for k in range(3):
        np.testing.assert_allclose(d[k, :, 2], want, rtol=0, atol=1e-12)
    assert want[361] == pytest.approx(b * 0.7 * DT + 0.5 * r * (0.7 * DT) ** 2, abs=1e-15)  # the partial interval
    assert np.array_equal(hit.dvel[:, :361], free.dvel[:, :361])  # intervals ending before the onset
    assert np.array_equal(hit.dvel[:, 842:], free.dvel[:, 842:])  # after the end
    assert np.array_equal(hit.dvel[..., :2], free.dvel[..., :2]) and np.array_equal(hit.dtheta, free.dtheta)
    T = end - onset
    assert d[0, :, 2].sum() == pytest.approx(b * T + 0.5 * r * T**2, abs=1e-12)
    np.testing.assert_allclose(truth.fault_dvel[:, 2], d[0, :, 2], rtol=0, atol=1e-15)
    assert not truth.fault_dtheta.any()


def test_a_gyro_bias_turns_each_angle_increment_by_exactly_bias_times_dt():
    """A [3600, −7200, 36] deg/h bias (body FRD) from mid-interval: every later Δθ is turned by the bias in rad/s
    (deg → rad by numpy, not by the testbed's constant) times Δt, the onset interval by the part after the onset;
    nothing before it; Δv untouched."""
    t = TRUTH.t[1:]
    onset = float(t[100] + 0.25 * DT)
    deg_h = np.array([3600.0, -7200.0, 36.0])
    fault = ImuGyroBias(kind="imu_gyro_bias", bias_deg_h=list(deg_h), onset_s=onset)
    free, hit, _ = _pair([fault])
    d = hit.dtheta - free.dtheta
    rad_s = np.deg2rad(deg_h) / 3600.0
    np.testing.assert_allclose(d[:, 102:], np.broadcast_to(rad_s * DT, d[:, 102:].shape), rtol=0, atol=1e-12)
    np.testing.assert_allclose(d[:, 101], np.broadcast_to(rad_s * 0.75 * DT, d[:, 101].shape), rtol=0, atol=1e-12)
    assert np.array_equal(hit.dtheta[:, :101], free.dtheta[:, :101])
    assert np.array_equal(hit.dvel, free.dvel)


def test_faults_draw_nothing_the_same_seed_gives_the_same_bytes_and_faults_add_up():
    """Same seed, same faults: the same bytes. An accelerometer and a gyro fault together: each adds its own
    increments (the other sensor's as alone), so no fault consumes a random draw or touches another's."""
    acc = ImuAccelBias(kind="imu_accel_bias", bias_m_s2=[0.1, -0.2, 0.3], rate_m_s3=[0.0, 0.0, 0.01], onset_s=2.0)
    gyr = ImuGyroBias(kind="imu_gyro_bias", axis="y", bias_deg_h=-500.0, rate_deg_h_s=20.0, onset_s=4.5, end_s=9.0)
    a, _ = sample_imu(TRUTH, IMU, np.random.default_rng(3), n_trials=2, faults=[acc, gyr])
    b, _ = sample_imu(TRUTH, IMU, np.random.default_rng(3), n_trials=2, faults=[acc, gyr])
    assert a.dvel.tobytes() == b.dvel.tobytes() and a.dtheta.tobytes() == b.dtheta.tobytes()
    only_acc, _ = sample_imu(TRUTH, IMU, np.random.default_rng(3), n_trials=2, faults=[acc])
    only_gyr, _ = sample_imu(TRUTH, IMU, np.random.default_rng(3), n_trials=2, faults=[gyr])
    assert np.array_equal(a.dvel, only_acc.dvel) and np.array_equal(a.dtheta, only_gyr.dtheta)


def test_the_epochs_carrying_an_imu_fault_are_those_after_an_interval_it_reached():
    """1 Hz epochs over 120 Hz intervals: a fault from 3.4 s to 3.6 s reaches only the epoch at 4 s; one from
    an onset exactly on the 5 s epoch reaches 6 s on (the interval ending at 5 s holds none of it)."""
    t = np.arange(0.0, 10.0 + 1e-9, 1.0)
    t_imu = TRUTH.t[1:]
    short = ImuAccelBias(kind="imu_accel_bias", axis="x", bias_m_s2=1.0, onset_s=3.4, end_s=3.6)
    late = ImuGyroBias(kind="imu_gyro_bias", axis="z", bias_deg_h=10.0, onset_s=5.0)
    assert np.flatnonzero(imu_fault_epochs([short], t, t_imu, DT)).tolist() == [4]
    assert np.flatnonzero(imu_fault_epochs([late], t, t_imu, DT)).tolist() == [6, 7, 8, 9, 10]


@pytest.mark.parametrize("table, key, said", [
    ({"axis": "w", "bias_m_s2": 0.5}, "axis", "Input should be 'x', 'y' or 'z' (got 'w')"),
    ({"bias_m_s2": 0.5}, "bias_m_s2", "a number needs axis = 'x', 'y' or 'z'"),
    ({"axis": "z", "bias_m_s2": [1.0, 2.0, 3.0]}, "bias_m_s2", "a 3-vector takes no axis (axis = 'z')"),
    ({"bias_m_s2": [1.0, 2.0]}, "bias_m_s2", "or a 3-vector [x, y, z] of numbers"),
    ({"axis": "z", "bias_m_s2": 250.0}, "bias_m_s2", "within ±200 m/s² per axis (got 250.0)"),
    ({"axis": "z"}, "bias_m_s2", "a fault that adds nothing"),
])
def test_bad_fault_tables_name_the_key_and_value(table, key, said):
    with pytest.raises(ValidationError) as ei:
        TypeAdapter(Fault).validate_python({"kind": "imu_accel_bias", **table})
    from testbed.schema import format_validation_error

    lines = format_validation_error(ei.value, {"kind": "imu_accel_bias", **table})
    assert len(lines) == 1 and lines[0].startswith(f"{key}: ") and said in lines[0], lines


def test_a_bad_imu_fault_on_the_command_line_is_exit_2_naming_key_and_value(capsys):
    """`testbed fly --fault imu_accel_bias:...` with a wrong axis, a 2-vector, or on an approach whose monitors do
    not read the IMU: exit 2, the option, key and value in the message, no traceback, nothing written."""
    from testbed.cli import main

    def fly(approach, fault):
        rc = main(["fly", approach, "--no-record", "--fault", fault])
        return rc, capsys.readouterr().err

    rc, err = fly("zunz-rwy05-ekf", "imu_accel_bias:axis=up,bias_m_s2=0.5")
    assert rc == 2 and "Traceback" not in err
    assert "--fault 'imu_accel_bias:axis=up,bias_m_s2=0.5': axis: Input should be 'x', 'y' or 'z' (got 'up')" in err
    rc, err = fly("zunz-rwy05-ekf", "imu_gyro_bias:bias_deg_h=[1,2]")
    assert rc == 2 and "bias_deg_h: expected a number" in err and "(got [1, 2])" in err
    rc, err = fly("zunz-rwy05-final", "imu_accel_bias:axis=z,bias_m_s2=0.5")
    assert rc == 2 and "Traceback" not in err
    assert "faults.0.kind = 'imu_accel_bias': an IMU fault, but no configured monitor reads the IMU" in err


def _ekf_short():
    ap = load_approach("zunz-rwy05-ekf")
    cfg = ap.config.model_copy(update={"monitors": ["ekf"],
                                       "flight": ap.config.flight.model_copy(update={"start_distance_m": 3000.0})})
    return dataclasses.replace(ap, config=cfg)


@pytest.mark.slow  # the araim variant's loop test flies the same fault in the default set
def test_the_ekf_reacts_to_a_vertical_accelerometer_bias_in_the_loop():
    """zunz-rwy05-ekf (35 s of it, 8 satellites then 3), seed 4: 0.5 m/s² on body z from 20 s. Up to the onset
    the filter's outputs are bit-identical to the fault-free run's (the fault draws nothing); after it the
    vertical error grows to more than 5 times the fault-free run's over the same epochs (measured: 3.4 m against
    0.35 m) and the filter alerts (13 epochs from 22 s) where it did not."""
    onset = 20.0
    free = run_approach(_ekf_short(), seed=4, rrd_path=None)
    hit = run_approach(_ekf_short(), seed=4, rrd_path=None,
                       faults=[fault_from_option(f"imu_accel_bias:axis=z,bias_m_s2=0.5,onset_s={onset}")])
    t = free.loop.gnss.t
    before, after = t < onset, t >= onset
    assert before.sum() >= 15 and after.sum() >= 10
    of, oh = free.outputs["ekf"], hit.outputs["ekf"]
    assert np.array_equal(of.pos_enu[before], oh.pos_enu[before]) and np.array_equal(of.alert[before], oh.alert[before])
    ref_enu = hit.loop.truth_at_gnss.pos_enu  # the filter's reference point, the CG (the same flight in both)
    assert np.array_equal(ref_enu, free.loop.truth_at_gnss.pos_enu)
    _, ve_free = position_errors(of, ref_enu)
    _, ve_hit = position_errors(oh, ref_enu)
    assert ve_hit[after].max() > 5.0 * ve_free[after].max()
    assert not of.alert.any() and oh.alert[after].any()
    assert hit.summaries["ekf"].alert_epochs > free.summaries["ekf"].alert_epochs


IMU_SPEC = """
name = "imu-tiny"
approaches = ["zunz-rwy05-ekf"]
monitors = ["ekf"]
trials = 4
block_trials = 2
chunk_trials = 2
base_seed = 12
per_epoch_trials = 2
common_random_numbers = true
duration_s = 35.0

[[faults]]
kind = "imu_accel_bias"
axis = "z"
magnitudes = [0.0, 0.5]
onset_s = {onset}
"""


@pytest.mark.slow  # moved out of the default set: its run time (the default set stays within 8 min)
def test_an_imu_fault_sweeps_in_a_campaign_and_counts_as_exercised(tmp_path):
    """A campaign sweeps imu_accel_bias on body z (0, 0.5 m/s² from 20 s; common random numbers): the faulty cell's
    trials carry the fault on the IMU (fault_target 0) at every epoch after the onset, all exercised, and up to
    the onset its per-epoch errors are the fault-free cell's to the bit (the fault draws nothing); the ekf
    detects it in every sortie (measured: 4 of 4), and raises no alert fault-free."""
    import pyarrow.parquet as pq

    from testbed.campaign.detection import detection_table
    from testbed.campaign.runner import run_campaign
    from testbed.campaign.spec import MAGNITUDE_UNITS

    spec = tmp_path / "imu.toml"
    spec.write_text(IMU_SPEC.format(onset=20.0))
    run_campaign(spec, tmp_path / "out", progress=False)
    trials = pq.read_table(tmp_path / "out" / "trials.parquet").to_pandas()
    cells = pq.read_table(tmp_path / "out" / "cells.parquet").to_pylist()
    free, hit = trials[trials.cell == 0], trials[trials.cell == 1]
    assert (free.fault_target == -1).all() and (hit.fault_target == 0).all()
    assert [c["fault_unit"] for c in cells] == [MAGNITUDE_UNITS["imu_accel_bias"]] * 2 == ["m/s²"] * 2
    # 21 s to 35 s, every one with a solution: the epoch at the onset holds no increment of the fault
    assert hit.onset_epochs.tolist() == [15] * 4
    assert not free.detected.any() and hit.detected.all()
    rows = {r["cell"]: r for r in detection_table(cells, pq.read_table(tmp_path / "out" / "trials.parquet"))}
    assert rows[1]["not_exercised"] == 0 and rows[1]["k"] == 4
    ep = pq.read_table(tmp_path / "out" / "epochs.parquet").to_pandas()
    a = ep[(ep.cell == 0) & (ep.t < 20.0)].sort_values(["trial", "t"])
    b = ep[(ep.cell == 1) & (ep.t < 20.0)].sort_values(["trial", "t"])
    assert len(a) == 2 * 20 and np.array_equal(a.ve.to_numpy(), b.ve.to_numpy())
    assert not ep[(ep.cell == 1) & (ep.t <= 20.0)].fault_present.any()
    assert ep[(ep.cell == 1) & (ep.t > 20.0)].fault_present.all()


def test_an_imu_fault_after_the_last_epoch_is_refused_as_never_exercised(tmp_path, capsys):
    """Onset at the sortie's last epoch (35 s): no IMU interval of the sortie holds any of it, so no trial could
    exercise it: exit 2 naming the table, before any work; and FaultSweep's own checks of the axis."""
    from testbed.campaign.spec import FaultSweep
    from testbed.campaign_cli import main

    spec = tmp_path / "late.toml"
    spec.write_text(IMU_SPEC.format(onset=35.0))
    assert main(["campaign", str(spec), "--out", str(tmp_path / "o"), "--quiet", "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert "faults.0 (imu_accel_bias, axis = 'z'): in every cell that carries it (cell 1), no epoch of the sortie " \
           "(0-35 s) follows an IMU interval from the onset (35 s)" in err
    assert not (tmp_path / "o").exists()
    with pytest.raises(ValidationError, match="kind 'imu_gyro_bias': expected axis = 'x', 'y' or 'z'"):
        FaultSweep(kind="imu_gyro_bias", magnitudes=[0.0, 100.0])
    with pytest.raises(ValidationError, match="axis = 'z' is read by kinds 'imu_accel_bias', 'imu_gyro_bias' only"):
        FaultSweep(kind="gps_step", magnitudes=[0.0, 10.0], axis="z")
    table = FaultSweep(kind="imu_gyro_bias", magnitudes=[0.0, -100.0], axis="y", onset_s=5.0).fault(-100.0)
    f = TypeAdapter(Fault).validate_python(table)
    np.testing.assert_allclose(f.bias_si, [0.0, np.deg2rad(-100.0) / 3600.0, 0.0], rtol=1e-15)
