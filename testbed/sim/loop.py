"""The closed loop: flight -> sensors -> monitors -> sinks, block by block while flying.

JSBSim flies at its own rate; an observer collects the truth at the sensor
epochs and, every ``block_s`` of simulated time, synthesises the observations
for the epochs just flown, runs every configured monitor on them and hands a
:class:`LoopBlock` to the sinks (Rerun, tables...). Nothing is post-processed.

Why the result does not depend on the block size: sensor geometry is computed
per epoch (no cross-epoch state) and accumulated; sensor noise is drawn
prefix-stably (one child generator per random component, causal filters), so
sampling the first T epochs again after every block reproduces the earlier
epochs bit for bit and adds the new ones; every monitor carries its own typed
state from block to block (:mod:`testbed.integrity.monitor`), and the loop
keeps no history for any of them. ``tests/test_loop.py`` checks that a
live run equals the batch functions applied to the whole flight.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from testbed.flight.fly import FlightResult, fly, truth_from_rows
from testbed.frames import q_to_R
from testbed.inertial import body_to_world, local_to_world
from testbed.integrity.monitor import Observations
from testbed.records import GnssEpochs, GnssTruth, MonitorOutput, Truth, concat_epochs, take_epochs
from testbed.sensors.faults import GNSS_KINDS
from testbed.sensors.gnss.code_tracking import correlator_pseudoranges
from testbed.sensors.gnss.correlators import synthesize_correlators
from testbed.sensors.gnss.synth import gnss_geometry
from testbed.sensors.imu import true_increments
from testbed.sensors.vision import detect as vdetect
from testbed.sim import pipeline, slicing
from testbed.sim.events import EventTracker
from testbed.sim.setup import RunSetup
from testbed.sim.streams import StreamTree



@dataclass
class LoopBlock:
    """What the sinks receive for one block of sensor epochs (world frame = the approach's ENU)."""

    t: np.ndarray  # (T,) GNSS (monitor) epochs
    truth: Truth  # at the GNSS epochs
    gnss: GnssEpochs | None
    gnss_truth: GnssTruth | None
    los_enu: np.ndarray | None  # (T, S, 3) unit lines of sight, world frame
    antenna_enu: np.ndarray | None  # (T, 3)
    vision: object | None  # VisionEpochs at the vision rate
    vision_truth: object | None
    camera_enu: np.ndarray | None  # (Tv, 3) true camera positions
    R_cam_to_world: np.ndarray | None  # (Tv, 3, 3)
    outputs: dict[str, MonitorOutput]
    events: list[tuple[float, str, str]]
    alert_limits: tuple[float, float]
    #: true position of each monitor's reference point (antenna or CG), (T, 3) world frame
    reference_enu: dict[str, np.ndarray] = field(default_factory=dict)
    #: the correlograms at the GNSS epochs and their truth (when a monitor reads correlators)
    correlators: object | None = None
    correlator_truth: object | None = None
    #: (t, monitor name or "" for all, kind) of the events plots mark: "fault onset", "alert",
    #: "alert cleared", "excluded", "unavailable", "available"
    marks: list[tuple[float, str, str]] = field(default_factory=list)
    #: the tracked ground features at the GNSS epochs (FeatureTracks, one trial), when the scene has them
    features: object | None = None


class Sink(Protocol):
    def start(self, scene) -> None: ...
    def log_block(self, block: LoopBlock) -> None: ...
    def close(self) -> None: ...


@dataclass
class Timings:
    flight: float = 0.0
    sensors: float = 0.0
    monitors: float = 0.0
    logging: float = 0.0
    per_monitor: dict[str, float] = field(default_factory=dict)  # wall time of each monitor's steps

    def as_dict(self) -> dict[str, float]:
        return {"flight": self.flight, "sensors": self.sensors, "monitors": self.monitors, "logging": self.logging}


@dataclass
class LoopResult:
    flight: FlightResult
    gnss: GnssEpochs
    gnss_truth: GnssTruth
    vision: object | None
    vision_truth: object | None
    outputs: dict[str, MonitorOutput]
    truth_at_gnss: Truth
    timings: Timings
    events: list[tuple[float, str, str]] = field(default_factory=list)


class _Runner:
    """The observer that turns flight steps into blocks of observations and monitor outputs."""

    def __init__(self, setup: RunSetup, streams: StreamTree, sinks: list, block_s: float) -> None:
        cfg = setup.approach.config
        self.setup, self.sinks, self.streams = setup, sinks, streams
        self.plan = plan = pipeline.sensor_plan(setup)
        dt = cfg.flight.dt_s
        self.g_step = max(1, int(round(1.0 / (setup.gnss.rate_hz * dt))))
        self.v_step = max(1, int(round(1.0 / (setup.vision.rate_hz * dt)))) if setup.uses_vision else self.g_step
        if self.g_step % self.v_step:
            self.v_step = self.g_step  # vision epochs must include the GNSS epochs
        self.uses_imu = plan.uses_imu
        # truth rows are kept at the fastest sensor rate (the IMU's when a monitor reads it)
        self.r_step = self.v_step
        if self.uses_imu:  # build_setup checked that the IMU rate divides the flight's and the vision's
            self.r_step = max(1, int(round(1.0 / (setup.imu.rate_hz * dt))))
        self.imu_stream = None
        self.imu_prev: Truth | None = None  # the last IMU-rate truth sample of the previous block
        self.block_steps = max(self.g_step, int(round(block_s / dt / self.g_step)) * self.g_step)
        self.start_utc = cfg.start_time_utc
        self.t0: float | None = None
        self.pending: list[tuple] = []  # rows at the vision (sensor) rate not yet processed
        self.pending_k: list[int] = []
        self.g_geom = None
        self.v_geom = None
        self.n_g = 0  # GNSS epochs processed
        self.n_v = 0
        self.parts: dict[str, list] = {"gnss": [], "gnss_truth": [], "vision": [], "vision_truth": [], "truth": []}
        names = setup.monitor_names
        self.outputs: dict[str, list[MonitorOutput]] = {m: [] for m in names}
        self.states = {m.name: m.initial_state() for m in setup.monitors}  # each monitor's typed state
        self.tracker = EventTracker(names, sorted({(f.onset_s, f.kind) for f in setup.faults}))
        self.events: list[tuple[float, str, str]] = []
        self.timings = Timings()

    # -- observer --------------------------------------------------------------
    def on_step(self, k: int, row: tuple) -> None:
        if self.t0 is None:
            self.t0 = row[0]
        if k % self.r_step == 0:
            self.pending.append(row)
            self.pending_k.append(k)
        if k > 0 and k % self.block_steps == self.block_steps - 1:
            self.flush()

    def flush(self) -> None:
        if not self.pending:
            return
        t_a = time.perf_counter()
        rows, ks = self.pending, np.asarray(self.pending_k)
        self.pending, self.pending_k = [], []
        s = self.setup
        truth_r = truth_from_rows(rows, s.frame, t0=self.t0)
        v_rows = np.flatnonzero(ks % self.v_step == 0)
        truth_v = truth_r.at_indices(v_rows)
        ks = ks[v_rows]
        g_sel = np.flatnonzero(ks % self.g_step == 0)
        truth_g = truth_v.at_indices(g_sel)
        block = LoopBlock(t=truth_g.t, truth=truth_g, gnss=None, gnss_truth=None, los_enu=None, antenna_enu=None,
                          vision=None, vision_truth=None, camera_enu=None, R_cam_to_world=None, outputs={},
                          events=[], alert_limits=s.alert_limits)
        self.parts["truth"].append(truth_g)
        # GNSS: geometry of the new epochs, noise re-drawn prefix-stably over all epochs so far
        g0 = self.n_g
        if g_sel.size:
            geom_new = gnss_geometry(truth_g, s.antenna, s.gnss, start_utc=self.start_utc, terrain=s.terrain,
                                     constellation=self.plan.constellation)
            self.g_geom = slicing.geometry_concat(self.g_geom, geom_new)
            g_all, gt_all = pipeline.draw_gnss(self.plan, self.g_geom, self.streams)
            new = slice(self.n_g, self.n_g + g_sel.size)
            block.gnss, block.gnss_truth = take_epochs(g_all, new), take_epochs(gt_all, new)
            self.n_g += g_sel.size
            ant_enu = s.frame.ecef_to_enu(block.gnss_truth.antenna_pos_ecef)
            sat_enu = s.frame.ecef_to_enu(block.gnss.sat_pos_ecef)
            los = sat_enu - ant_enu[:, None, :]
            block.los_enu = los / np.linalg.norm(los, axis=-1, keepdims=True)
            block.antenna_enu = ant_enu
            if self.plan.uses_correlators:  # per-epoch generators: only the new epochs are drawn
                block.correlators, block.correlator_truth = synthesize_correlators(
                    block.gnss, block.gnss_truth, truth_g, s.gnss, pipeline.correlator_words(self.streams),
                    first_epoch=new.start)
                if s.gnss.correlator_pseudoranges:  # every monitor reads the correlograms' code delays
                    block.gnss, block.gnss_truth = correlator_pseudoranges(block.gnss, block.gnss_truth,
                                                                           block.correlators, s.gnss)
            self.parts["gnss"].append(block.gnss)
            self.parts["gnss_truth"].append(block.gnss_truth)
        # vision at its own rate (GNSS epochs are a subset)
        v_at_g = None
        if s.uses_vision:
            geom_new = vdetect.vision_geometry(truth_v, s.vision, landmarks=s.landmarks, terrain=s.terrain,
                                               faults=list(s.faults))
            self.v_geom = geom_new if self.v_geom is None else vdetect.concat_geometry([self.v_geom, geom_new])
            v_all, vt_all = pipeline.draw_vision(self.plan, self.v_geom, self.streams)
            new = slice(self.n_v, self.n_v + len(truth_v.t))
            block.vision, block.vision_truth = take_epochs(v_all, new), take_epochs(vt_all, new)
            self.n_v += len(truth_v.t)
            block.camera_enu = s.frame.ecef_to_enu(block.vision_truth.cam_pos_ecef)
            block.R_cam_to_world = s.frame.R @ q_to_R(block.vision_truth.q_cam_to_ecef)
            self.parts["vision"].append(block.vision)
            self.parts["vision_truth"].append(block.vision_truth)
            v_at_g = take_epochs(block.vision, g_sel)
        tracks = None
        if self.plan.uses_features and g_sel.size:  # per-epoch geometry and draws: block-size free
            ids = pipeline.feature_ids(self.plan, truth_g, s.terrain)
            tracks = pipeline.draw_features(self.plan, ids, take_epochs(block.vision_truth, g_sel), self.streams,
                                            first_epoch=g0)
            block.features = tracks
        imu, init = self._imu(truth_r, block) if self.uses_imu else (None, None)
        t_b = time.perf_counter()
        self.timings.sensors += t_b - t_a
        if block.gnss is not None:
            self._monitors(block, v_at_g, imu, init, tracks)
        t_c = time.perf_counter()
        self.timings.monitors += t_c - t_b
        self._events(block)
        for sink in self.sinks:
            sink.log_block(block)
        self.timings.logging += time.perf_counter() - t_c

    # -- monitors --------------------------------------------------------------
    def _imu(self, truth_r: Truth, block: LoopBlock):
        """The block's IMU intervals (continuing the last block's) and, with the first block, the alignment."""
        s = self.setup
        init = None
        joined = truth_r if self.imu_prev is None else concat_epochs([self.imu_prev, truth_r])
        if self.imu_stream is None:
            self.imu_stream = pipeline.imu_errors(self.plan, self.streams)
            first = truth_r.at_indices(np.array([0]))
            p0 = first.pos_enu[0]
            start = (float(first.t[0]), body_to_world(s.frame, p0, first.q_body_to_enu[0]),
                     local_to_world(s.frame, p0, first.vel_enu[0]), p0)
            cb = float(np.asarray(block.gnss_truth.clock_bias).reshape(-1)[0]) if block.gnss_truth is not None else 0.0
            init = pipeline.alignment(self.plan, start, cb, self.streams)
        imu = pipeline.imu_samples(self.plan, true_increments(joined, s.imu), self.imu_stream)
        self.imu_prev = truth_r.at_indices(np.array([len(truth_r.t) - 1]))
        return imu, init

    def _monitors(self, block: LoopBlock, v_at_g, imu=None, init=None, features=None) -> None:
        obs = Observations(block.gnss, v_at_g, imu, init, block.correlators, features)
        cg_enu = self.setup.frame.ecef_to_enu(block.truth.pos_ecef)
        pm = self.timings.per_monitor
        outs, self.states = pipeline.step_monitors(self.setup.monitors, obs, self.states,
                                                   clock=lambda name, s: pm.__setitem__(name, pm.get(name, 0.0) + s))
        for mon in self.setup.monitors:
            block.outputs[mon.name] = outs[mon.name]
            block.reference_enu[mon.name] = pipeline.reference_enu(mon, block.antenna_enu, cg_enu)
            self.outputs[mon.name].append(outs[mon.name])

    # -- events ----------------------------------------------------------------
    def _events(self, block: LoopBlock) -> None:
        self.events.extend(self.tracker.add(block))


def run_loop(setup: RunSetup, *, seed: int = 0, sinks: list[Sink] | None = None, block_s: float = 5.0,
             gust_seed: int | None = None, streams: StreamTree | None = None) -> LoopResult:
    """Fly ``setup``'s approach with sensors and monitors in the loop.

    Parameters
    ----------
    setup : :func:`testbed.sim.setup.build_setup`.
    seed : roots every sensor random draw (:meth:`StreamTree.of_run`).
    sinks : observers with ``log_block`` (e.g. :class:`testbed.viz.rerun_sink.RerunSink`).
    block_s : simulated seconds per block (the live update period).
    streams : the stream tree to draw from instead of ``seed``'s (e.g. a campaign block's, to fly one of its
        trials again).
    """
    sinks = list(sinks or [])
    runner = _Runner(setup, StreamTree.of_run(seed) if streams is None else streams, sinks, block_s)
    wall0 = time.perf_counter()
    flight = fly(setup.approach.flight_plan, setup.terrain, gust_seed=gust_seed, on_step=runner.on_step)
    runner.flush()
    total = time.perf_counter() - wall0
    tm = runner.timings
    tm.flight = total - tm.sensors - tm.monitors - tm.logging
    p = runner.parts
    return LoopResult(
        flight=flight, gnss=concat_epochs(p["gnss"]), gnss_truth=concat_epochs(p["gnss_truth"]),
        vision=concat_epochs(p["vision"]) if p["vision"] else None,
        vision_truth=concat_epochs(p["vision_truth"]) if p["vision_truth"] else None,
        outputs={m: concat_epochs(v) for m, v in runner.outputs.items() if v},
        truth_at_gnss=concat_epochs(p["truth"]), timings=tm, events=runner.events)


def gnss_fault_onset(setup: RunSetup) -> float | None:
    """Onset of the first GNSS fault in the schedule (for time-to-alert), or None."""
    on = [f.onset_s for f in setup.faults if f.kind in GNSS_KINDS]
    return min(on) if on else None
