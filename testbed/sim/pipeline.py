"""One sensor-to-monitor pipeline: the draws every sensor makes, and the monitors' stepping, for the loop and the
campaigns alike.

The closed loop (:mod:`testbed.sim.loop`) draws one flight block by block; a campaign block
(:mod:`testbed.campaign.runner`) draws ``n`` trials of a flown trajectory at once. Both call the functions here,
with the same settings and the same :class:`~testbed.sim.streams.StreamTree`, so a flight flown with the tree of a
one-trial campaign's block sees exactly the observations of that trial, and its monitors give the same outputs
(``tests/test_pipeline.py``). What differs stays with the callers: the loop extends its geometry as it flies and
keeps each monitor's state between blocks; a campaign shares draws between the cells of a sweep
(:mod:`testbed.memo`), which it decides and passes in.

The rules every caller used to restate are here once: which true point a monitor is judged against
(:func:`reference_enu`), the alert limits of a run (:func:`strictest_limits` in
:mod:`testbed.integrity.levels`), the camera built from its settings (:class:`SensorPlan`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np

from testbed.integrity.monitor import ANTENNA, Monitor, Observations, compute
from testbed.records import ImuSamples, MonitorOutput
from testbed.sensors.gnss.constellations import tracked_constellations
from testbed.sensors.gnss.synth import GnssErrors, GnssGeometry, apply_gnss_errors, draw_gnss_errors
from testbed.sensors.gnss.timebase import utc_to_gps_seconds
from testbed.sensors.imu import ImuErrorStream, apply_errors, apply_faults
from testbed.sensors.imu.alignment import align
from testbed.sensors.vision import detect as vdetect
from testbed.sensors.vision.dithering import mount_from_settings
from testbed.sensors.vision.features import scene_ids, scene_tracks
from testbed.sensors.vision.landmarks import survey
from testbed.sim.setup import RunSetup
from testbed.sim.streams import StreamTree


@dataclass(frozen=True)
class SensorPlan:
    """What a run's sensors need besides the trajectory and the draws, built once per run set-up."""

    setup: RunSetup
    constellation: object  # the GNSS ephemerides (almanac) at the approach's start
    camera: object | None  # the vision camera (PinholeCamera), when a monitor reads vision or features
    mount: object | None  # its mount on the body
    uses_vision: bool
    uses_imu: bool
    uses_correlators: bool  # a monitor reads correlograms, or the pseudoranges come from them
    uses_features: bool

    @property
    def gnss(self):
        return self.setup.gnss


def sensor_plan(setup: RunSetup) -> SensorPlan:
    """The plan of ``setup``'s sensors: which ones its monitors read, and what they share."""
    g = setup.gnss
    eph = tracked_constellations(g, utc_to_gps_seconds(setup.approach.config.start_time_utc))
    inputs = {i for m in setup.monitors for i in m.inputs}
    looks = setup.uses_vision or setup.features is not None
    return SensorPlan(setup=setup, constellation=eph,
                      camera=setup.vision.camera.build() if looks else None,
                      mount=mount_from_settings(setup.vision.mount) if looks else None,
                      uses_vision=setup.uses_vision, uses_imu="imu" in inputs,
                      uses_correlators="correlators" in inputs or g.correlator_pseudoranges,
                      uses_features=setup.features is not None)


# ----------------------------------------------------------------------------- GNSS

def gnss_errors(plan: SensorPlan, geom: GnssGeometry, streams: StreamTree, n_trials: int | None = None):
    """The fault-free errors (noise, receiver clock) of ``geom``'s epochs, from the tree's GNSS stream
    (prefix-stable without ``n_trials``: the loop draws the flight so far again after every block)."""
    return draw_gnss_errors(geom, plan.gnss, rng=streams.generator("gnss"), n_trials=n_trials)


def gnss_observations(geom: GnssGeometry, errors, faults: Sequence = ()):
    """``(GnssEpochs, GnssTruth)`` of ``geom`` with ``errors`` and the GNSS faults (their targets drawn from the
    errors' own fault stream)."""
    return apply_gnss_errors(geom, errors, faults)


def draw_gnss(plan: SensorPlan, geom: GnssGeometry, streams: StreamTree, n_trials: int | None = None,
              faults: Sequence | None = None):
    """:func:`gnss_errors` then :func:`gnss_observations` with the set-up's faults (or ``faults``)."""
    faults = plan.setup.faults if faults is None else faults
    return gnss_observations(geom, gnss_errors(plan, geom, streams, n_trials), list(faults))


def tilt_gnss_errors(errors: GnssErrors, shift: np.ndarray | None = None) -> tuple[GnssErrors, np.ndarray]:
    """``errors`` with their standard-normal pseudorange draws ``z`` moved to ``z + shift`` (``shift`` (n, T, S)
    or broadcast to the noise; None: none): an importance-sampling proposal (:mod:`testbed.campaign.sampling`,
    whose shift may itself be a function of ``z``: a scaling). Only for white errors, ``noise = σ·z`` (no
    Gauss-Markov component: the caller checks). ``σ`` is the 1σ of the error *drawn* (``errors.drawn_sigma``:
    the 'dfmc' model draws σ_URE and tells the monitors σ_URA), so that ``z`` is standard normal under the error
    model. Returns the tilted errors and their draws ``z' = noise'/σ`` (0 where σ is 0), where the caller
    evaluates its likelihood ratio; the clock, inter-system offset, range-rate and fault streams are left as
    drawn (the offsets are constant per constellation and trial: the monitors' per-system clocks absorb them)."""
    sigma = np.broadcast_to(np.asarray(errors.drawn_sigma, float), np.shape(errors.noise))
    noise = np.asarray(errors.noise, float)
    if shift is not None:
        noise = noise + sigma * shift
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(sigma > 0, noise / np.where(sigma > 0, sigma, 1.0), 0.0)
    return replace(errors, noise=noise), z


def correlator_words(streams: StreamTree, trial: int = 0) -> np.ndarray:
    """Seed words of one trial's correlograms (per-epoch generators below them, :mod:`testbed.sensors.streams`):
    a flight is trial 0 of its tree."""
    return streams.words("correlators", trial)


# ----------------------------------------------------------------------------- vision

def landmark_survey(plan: SensorPlan, streams: StreamTree) -> np.ndarray:
    """(L, 3) the surveyed landmark positions the monitors are given: true + N(0, σ_lpe² I), one survey per
    tree (a flight, or a campaign block: a surveyed scene serves many sorties)."""
    return survey(plan.setup.landmarks, streams.generator("survey"))


def draw_vision(plan: SensorPlan, v_geom, streams: StreamTree, n_trials: int | None = None,
                faults: Sequence | None = None, share: Callable[..., Any] = compute,
                tilt: Callable[[vdetect.VisionDraws], vdetect.VisionDraws] | None = None):
    """``(VisionEpochs, VisionTruth)`` of the vision geometry ``v_geom``: dithering, attitude reference, detection
    noise and the vision faults from the tree's vision stream, the landmarks as :func:`landmark_survey` has them
    (``share``, ``tilt``: as :func:`~testbed.sensors.vision.detect.sample_vision` takes them; ``tilt`` is an
    importance-sampling proposal's move of the Gaussian draws, :mod:`testbed.campaign.sampling_vision`)."""
    s = plan.setup
    faults = s.faults if faults is None else faults
    return vdetect.sample_vision(v_geom, s.vision, landmarks=s.landmarks, faults=list(faults),
                                 rng=streams.generator("vision"), n_trials=n_trials,
                                 survey_ecef=landmark_survey(plan, streams), share=share, tilt=tilt)


def feature_ids(plan: SensorPlan, truth_g, terrain) -> np.ndarray:
    """(T, W) the ground features the tracker follows along ``truth_g`` (no randomness)."""
    s = plan.setup
    return scene_ids(truth_g, plan.camera, plan.mount, s.features, s.vision.features, terrain)


def draw_features(plan: SensorPlan, ids: np.ndarray, vision_truth_g, streams: StreamTree, n_trials: int = 1,
                  first_epoch: int = 0):
    """The tracker's report of ``ids`` under each trial's (dithered) camera; per-epoch draws from the tree's feature
    stream (``first_epoch``: the index of the first epoch in the flight)."""
    s = plan.setup
    return scene_tracks(ids, vision_truth_g, s.features, s.frame, plan.camera, plan.mount, s.vision.features,
                        streams.words("features"), first_epoch=first_epoch, n_trials=n_trials)


# ----------------------------------------------------------------------------- IMU

def imu_errors(plan: SensorPlan, streams: StreamTree, n_trials: int | None = None) -> ImuErrorStream:
    """The error processes of ``n_trials`` IMUs (one without), drawn interval by interval as the caller asks."""
    imu = plan.setup.imu
    return ImuErrorStream(imu, 1.0 / imu.rate_hz, streams.generator("imu"), n_trials)


def imu_samples(plan: SensorPlan, increments: tuple, stream: ImuErrorStream,
                faults: Sequence | None = None) -> ImuSamples:
    """The measured increments: the true ``(t, Δθ, Δv, Δt)`` with the stream's next errors and the IMU faults of
    the set-up (or ``faults``), which draw nothing."""
    imu = plan.setup.imu
    faults = plan.setup.faults if faults is None else faults
    t, dth, dvl, dt = increments
    d_th, d_v = apply_errors(dth, dvl, stream, stream.draw(np.size(t)))
    d_th, d_v = apply_faults(np.asarray(t, float), d_th, d_v, dt, faults)
    return ImuSamples(t=t, dtheta=d_th, dvel=d_v, dt=1.0 / imu.rate_hz,
                      lever_arm_body=np.asarray(imu.lever_arm_body_m, float), earth_rotation=imu.earth_rotation,
                      figures=imu.figures())


def alignment(plan: SensorPlan, start: tuple, clock_bias, streams: StreamTree, n_trials: int | None = None):
    """The inertial filter's initial state(s) at the first pose ``start = (t0, C_body_to_world, v, p)``, with the
    receiver clock bias of each trial then: the truth minus an error drawn from the tree's alignment stream."""
    t0, C, v, p = start
    return align(float(t0), C, v, p, clock_bias, 0.0, plan.setup.imu.figures(), streams.generator("alignment"),
                 n_trials)


# ----------------------------------------------------------------------------- monitors

def reference_enu(monitor: Monitor, antenna_enu: np.ndarray, cg_enu: np.ndarray) -> np.ndarray:
    """The true point a monitor's position is judged against: the antenna or the centre of gravity."""
    return antenna_enu if monitor.reference == ANTENNA else cg_enu


def step_monitors(monitors: Sequence[Monitor], obs: Observations, states: dict,
                  clock: Callable[[str, float], None] | None = None) -> tuple[dict[str, MonitorOutput], dict]:
    """Every monitor's step on ``obs`` from its state: ``(outputs, new states)``. ``clock(name, seconds)`` is told
    each step's wall time."""
    outs, new = {}, {}
    for mon in monitors:
        t0 = time.perf_counter()
        outs[mon.name], new[mon.name] = mon.step(obs, states[mon.name])
        if clock is not None:
            clock(mon.name, time.perf_counter() - t0)
    return outs, new
