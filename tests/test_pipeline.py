"""One pipeline: a flight flown in the loop with a campaign block's stream tree draws what that one-trial campaign
draws, sensor by sensor, and its monitors give the same outputs.

The loop draws block by block as it flies (the flight so far again after every block, prefix-stably) and steps
its monitors with their state; the campaign draws its segment at once and runs the monitors on it from their
initial state. Both go through :mod:`testbed.sim.pipeline` with the same :class:`~testbed.sim.streams.StreamTree`.
"""

import re
import shutil
from dataclasses import fields, is_dataclass, replace

import numpy as np
import pytest

from testbed.campaign.blocks import block_streams, correlator_monitor, draw_block, monitor_block
from testbed.campaign.context import cell_context
from testbed.campaign.spec import CampaignSpec, expand_cells, resolve_spec
from record_checks import assert_records_equal

from testbed.records import concat_epochs, take_epochs
from testbed.resources import approaches_dir
from testbed.sim.loop import run_loop
from testbed.sim.streams import STREAMS, StreamTree

SEED = 11
DURATION_S = 24.0


def short_approach(tmp_path, name: str, legs_m: float, extra: str = "") -> str:
    """A shipped approach flown from ``legs_m`` out (a short flight), with ``extra`` TOML inserted before its
    first table."""
    text = (approaches_dir() / f"{name}.toml").read_text()
    text = re.sub(r"legs = \[\{ type = \"straight\", length_m = [0-9.]+ \}\]",
                  f'legs = [{{ type = "straight", length_m = {legs_m} }}]', text)
    assert f"length_m = {legs_m}" in text
    if extra:
        head, table, tail = text.partition("\n[")
        text = head + "\n" + extra + "\n" + table + tail
    path = tmp_path / f"{name}-short.toml"
    path.write_text(text)
    return str(path)


def one_trial(approach: str, monitors: list[str], faults: list[dict], tmp_path):
    spec = CampaignSpec.model_validate({"name": "one", "approaches": [approach], "monitors": monitors, "trials": 1,
                                        "block_trials": 1, "chunk_trials": 1, "base_seed": SEED,
                                        "per_epoch_trials": 0, "duration_s": DURATION_S, "faults": faults})
    loaded = resolve_spec(spec, tmp_path / "one.toml")
    cell = expand_cells(loaded)[0]
    return loaded.spec, cell


def first_epochs(rec, T: int):
    """The loop's record cut to the campaign's T epochs."""
    return take_epochs(rec, slice(0, T))


def trial0(rec, like):
    """The campaign's only trial of ``rec``, shaped as the loop's record ``like`` (a flight has no trial axis)."""
    kw = {}
    for f in fields(rec):
        v, w = getattr(rec, f.name), getattr(like, f.name)
        if is_dataclass(v) and not isinstance(v, type):
            kw[f.name] = trial0(v, w)
        elif isinstance(v, np.ndarray) and isinstance(w, np.ndarray) and v.ndim == w.ndim + 1 and v.shape[0] == 1:
            kw[f.name] = v[0]
    return replace(rec, **kw)


def same(loop_rec, camp_rec, T: int, what: str, **tol) -> int:
    live = first_epochs(loop_rec, T)
    return assert_records_equal(live, trial0(camp_rec, live), what + ".", **tol)


def test_stream_tree_names_its_children_stably():
    """Child ``name`` is the spawn key's next index in :data:`STREAMS` (what ``spawn`` gives, so a campaign block's
    draws are those of its former positional children), and fresh on every call."""
    tree = StreamTree.of_block(5, cell=2, block=3, common=False)
    kids = np.random.SeedSequence(5, spawn_key=(2, 3)).spawn(len(STREAMS))
    for i, name in enumerate(STREAMS):
        np.testing.assert_array_equal(tree.seed(name).generate_state(4), kids[i].generate_state(4))
    a, b = tree.generator("gnss"), tree.generator("gnss")
    a.spawn(3)
    assert tree.generator("gnss").standard_normal() == b.standard_normal()
    assert StreamTree.of_block(5, 2, 3, common=True).key == (3,)
    assert len(set(STREAMS)) == len(STREAMS)


@pytest.fixture(scope="module")
def slam_case(tmp_path_factory):
    """The filter's approach (GNSS, camera landmarks with their survey, IMU, alignment, ground features) with
    the camera at the GNSS rate and a random-satellite step, flown in the loop and as a one-trial campaign."""
    tmp = tmp_path_factory.mktemp("slam")
    ap = short_approach(tmp, "zunz-rwy05-slam", 4000.0, "")
    text = open(ap).read().replace("[vision.features]", "[vision]\nrate_hz = 1.0\n\n[vision.features]")
    open(ap, "w").write(text)
    spec, cell = one_trial(ap, ["gps_raim", "va_raim", "pixel", "ekf"],
                           [{"kind": "gps_step", "prn": "random", "magnitudes": [40.0], "onset_s": 10.0}], tmp)
    return spec, cell


def test_a_loop_flight_draws_what_its_campaign_trial_draws(slam_case):
    spec, cell = slam_case
    ctx = cell_context(cell, spec)
    d = draw_block(ctx, spec, 0)
    outs = monitor_block(ctx.setup.monitors, d.obs, lambda mon: correlator_monitor(mon, ctx, d))
    live = run_loop(ctx.setup, streams=block_streams(spec, cell.index, 0), block_s=3.0)
    T = len(ctx.t)
    assert T >= 20 and np.array_equal(live.gnss.t[:T], ctx.t)
    assert d.gnss_truth.faulty.any(), "the step was not exercised"
    n = same(live.gnss, d.obs.gnss, T, "gnss") + same(live.gnss_truth, d.gnss_truth, T, "gnss_truth")
    n += same(live.vision, d.obs.vision, T, "vision") + same(live.vision_truth, d.vision_truth, T, "vision_truth")
    for name, out in outs.items():
        n += same(live.outputs[name], out, T, name, rtol=1e-9, atol=1e-7)
    assert n >= 60


class Capture:
    """A sink keeping what the loop hands its sinks."""

    def __init__(self):
        self.blocks = []

    def start(self, scene):
        pass

    def log_block(self, block):
        self.blocks.append(block)

    def close(self):
        pass


def test_the_filters_own_inputs_are_the_same_draws(slam_case):
    """The inputs only the filter reads: its IMU increments and initial error (a flight's IMU drawn at once equals
    the campaign trial's), and the tracked ground features the loop hands its sinks."""
    from testbed.sim import pipeline

    spec, cell = slam_case
    ctx = cell_context(cell, spec)
    d = draw_block(ctx, spec, 0)
    tree = block_streams(spec, cell.index, 0)
    one = pipeline.imu_samples(ctx.plan, ctx.imu_increments, pipeline.imu_errors(ctx.plan, tree))
    for f in ("dtheta", "dvel"):
        camp = getattr(d.obs.imu, f)
        assert camp.shape[:-1] in ((1,) + one.dtheta.shape[:-1], one.dtheta.shape[:-1] + (1,)), camp.shape
        np.testing.assert_array_equal(getattr(one, f), camp.reshape(getattr(one, f).shape), err_msg=f)
    start_cb = np.asarray(d.gnss_truth.clock_bias).reshape(-1)[0]
    init = pipeline.alignment(ctx.plan, ctx.imu_start, start_cb, tree)
    assert assert_records_equal(init, trial0(d.obs.init, init)) >= 2
    sink = Capture()
    run_loop(ctx.setup, streams=tree, block_s=5.0, sinks=[sink])
    T = len(ctx.t)
    live = concat_epochs([b.features for b in sink.blocks if b.features is not None])
    assert same(live, d.obs.features, T, "features") >= 2


def test_correlator_draws_and_dpe_are_the_same_in_the_loop_and_the_campaign(tmp_path):
    """The correlograms (per-epoch generators under each trial's own words) and what is built on them: the
    pseudoranges read from their peaks, and direct position estimation."""
    ap = short_approach(tmp_path, "zunz-rwy05-dpe", 3000.0)
    shutil.copytree(approaches_dir() / "calibration", tmp_path / "calibration")  # its K record
    spec, cell = one_trial(ap, ["gps_raim", "dpe"], [{"kind": "none"}], tmp_path)
    ctx = cell_context(cell, spec)
    assert ctx.plan.uses_correlators and ctx.setup.gnss.correlator_pseudoranges
    d = draw_block(ctx, spec, 0)
    outs = monitor_block(ctx.setup.monitors, d.obs, lambda mon: correlator_monitor(mon, ctx, d))
    live = run_loop(ctx.setup, streams=block_streams(spec, cell.index, 0), block_s=4.0)
    T = len(ctx.t)
    n = same(live.gnss, d.obs.gnss, T, "gnss") + same(live.gnss_truth, d.gnss_truth, T, "gnss_truth")
    for name, out in outs.items():
        n += same(live.outputs[name], out, T, name, rtol=1e-9, atol=1e-7)
    assert np.isfinite(live.outputs["dpe"].vpl[:T]).any()
    assert n >= 30
