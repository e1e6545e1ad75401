"""Campaign specs: what to sweep, how many trials, which monitors (``approaches/campaigns/*.toml``).

A spec is validated by :class:`CampaignSpec` (a :class:`~testbed.schema.StrictModel`:
unknown keys are errors naming the file and key path). :func:`expand_cells`
turns it into the list of :class:`Cell` s, the Cartesian product of

- the approaches,
- the start times (``sweep.start_time_utc``),
- every fault family and magnitude (``[[faults]]``; magnitude 0 or ``kind = "none"``
  gives fault-free trials, the false-alarm cells),
- the camera resolutions (``sweep.camera_dpi``), detection errors
  (``sweep.detection_sigma_px``), landmark position errors (``sweep.lpe_sigma_m``),
  landmark sets (``sweep.landmark_sets``) and VA-RAIM calibration modes
  (``sweep.calibration``).

Each cell becomes a concrete, validated :class:`~testbed.config.ApproachConfig`
(overrides applied to the approach file), so a bad combination (a dpi on a
camera preset that has no dpi, say) is reported before any work starts.

Randomness: trial ``i`` of cell ``c`` belongs to *draw block* ``b = i // block_trials``;
a block's generators come from ``SeedSequence(base_seed, spawn_key=(c, b))``
(``(b,)`` with ``common_random_numbers``), so a trial is a pure function of
(spec, cell, trial index) whatever the chunk size or number of workers.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import itertools
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from testbed.config import Approach, ApproachConfig, load_approach, read_toml, validate
from testbed.integrity.levels import strictest_limits
from testbed.monitors import MonitorName, monitor_options, reads
from testbed.sim.preflight import preflight
from testbed.schema import ConfigError, FileName, StrictModel
from testbed.sensors.faults import IMU_KINDS, SYSTEM_KINDS, VISION_KINDS
from testbed.sensors.gnss.constellations import constellation_orbits
from testbed.sensors.gnss.navfile import MAX_AGE_S
from testbed.sensors.gnss.settings import checked_constellation_set
from testbed.sensors.gnss.timebase import utc_to_gps_seconds
from testbed.sensors.vision.settings import LandmarkSet

FaultKindName = Literal["none", "gps_step", "gps_ramp", "constellation_bias", "constellation_orbit", "pixel_bias",
                        "landmark_moved", "imu_accel_bias", "imu_gyro_bias"]

#: what the magnitude of each fault family means (units go into tables and figure labels)
MAGNITUDE_UNITS = {"none": "", "gps_step": "m", "gps_ramp": "m/s", "constellation_bias": "m",
                   "constellation_orbit": "m", "pixel_bias": "px",
                   "landmark_moved": "m", "imu_accel_bias": "m/s²", "imu_gyro_bias": "deg/h"}
#: the fault table key each IMU family's magnitude sets
IMU_MAGNITUDE_KEYS = {"imu_accel_bias": "bias_m_s2", "imu_gyro_bias": "bias_deg_h"}


class FaultSweep(StrictModel):
    """One fault family swept over magnitudes (``[[faults]]`` in a spec)."""

    kind: FaultKindName = Field(..., description="none | gps_step (bias_m) | gps_ramp (rate_m_s) | "
                                                 "constellation_bias (bias_m on every satellite of `system`) | "
                                                 "constellation_orbit (every satellite of `system` moved this far "
                                                 "along `direction_ecef`) | "
                                                 "pixel_bias (magnitude_px) | landmark_moved (metres along direction_enu) | "
                                                 "imu_accel_bias (bias_m_s2 along `axis`) | imu_gyro_bias (bias_deg_h "
                                                 "along `axis`)")
    magnitudes: list[float] = Field([0.0], min_length=1, description="fault sizes; 0 = a fault-free cell")
    onset_s: float = Field(20.0, ge=0, description="fault onset, s after the approach start")
    end_s: float | None = Field(None, description="fault end (exclusive), s; None = to the end")
    prn: int | Literal["random"] = Field("random", description="GPS faults: PRN or 'random' (a visible one per trial)")
    system: Literal["gps", "galileo", "beidou"] | None = Field(
        None, description="constellation_bias, constellation_orbit: the constellation hit (required there, refused "
                          "with another kind)")
    direction_ecef: tuple[float, float, float] | None = Field(
        None, description="constellation_orbit: direction (ECEF X, Y, Z; normalised) of the common displacement of "
                          "the system's satellites (required there, refused with another kind)")
    landmark: str = Field("random", description="vision faults: landmark id or 'random' (per trial)")
    angle_deg: float = Field(0.0, description="pixel_bias: direction in the image, deg")
    direction_enu: tuple[float, float, float] = Field((1.0, 0.0, 0.0),
                                                      description="landmark_moved: unit direction (ENU) of the move")
    axis: Literal["x", "y", "z"] | None = Field(
        None, description="imu_accel_bias, imu_gyro_bias: the body axis (FRD: x forward, y right, z down) the bias "
                          "acts along, a signed magnitude (required there, refused with another kind)")

    @model_validator(mode="after")
    def _check(self):
        if self.end_s is not None and self.end_s <= self.onset_s:
            raise ValueError(f"end_s ({self.end_s}) must be after onset_s ({self.onset_s})")
        if self.kind in ("pixel_bias",) and any(m < 0 for m in self.magnitudes):
            raise ValueError(f"pixel_bias magnitudes must be >= 0, got {self.magnitudes}")
        if self.kind == "none" and any(m != 0 for m in self.magnitudes):
            raise ValueError(f"kind 'none' takes no magnitudes other than 0, got {self.magnitudes}")
        if self.kind == "landmark_moved":
            if math.hypot(*self.direction_enu) == 0:
                raise ValueError("direction_enu: expected a non-zero vector")
        if self.kind in SYSTEM_KINDS and self.system is None:
            raise ValueError(f"kind {self.kind!r}: expected system = 'gps', 'galileo' or 'beidou' (the "
                             "constellation whose satellites all carry the fault)")
        if self.kind not in SYSTEM_KINDS and self.system is not None:
            raise ValueError(f"system = {self.system!r} is read by kinds {', '.join(map(repr, SYSTEM_KINDS))} only, "
                             f"not by kind {self.kind!r}: remove it")
        if self.kind == "constellation_orbit":
            if self.direction_ecef is None:
                raise ValueError("kind 'constellation_orbit': expected direction_ecef = [x, y, z] (the ECEF direction "
                                 "the system's satellites are moved along)")
            if not all(math.isfinite(c) for c in self.direction_ecef) or math.hypot(*self.direction_ecef) == 0:
                raise ValueError(f"direction_ecef = {list(self.direction_ecef)}: expected a finite non-zero vector")
        elif self.direction_ecef is not None:
            raise ValueError(f"direction_ecef = {list(self.direction_ecef)} is read by kind 'constellation_orbit' "
                             f"only, not by kind {self.kind!r}: remove it")
        if self.kind in IMU_KINDS and self.axis is None:
            raise ValueError(f"kind {self.kind!r}: expected axis = 'x', 'y' or 'z' (the body axis, FRD, the bias "
                             "acts along)")
        if self.kind not in IMU_KINDS and self.axis is not None:
            raise ValueError(f"axis = {self.axis!r} is read by kinds {', '.join(map(repr, IMU_KINDS))} only, not by "
                             f"kind {self.kind!r}: remove it")
        return self

    def _move(self, magnitude: float) -> tuple[float, float, float]:
        """The landmark_moved displacement (ENU, m): ``magnitude`` along the unit ``direction_enu``, its norm by
        hypot, which neither overflows nor underflows where the sum of squares would (a direction of 1e200
        made every move 0 m, a fault that never happened; one of 1e-170 was refused as zero). The largest
        unit component is at least 1/√3, so a non-zero magnitude always moves the landmark."""
        n = math.hypot(*self.direction_enu)
        return tuple(magnitude * (c / n) for c in self.direction_enu)

    def fault(self, magnitude: float) -> dict | None:
        """The fault table (testbed.sensors.faults) for one magnitude; None = no fault."""
        if self.kind == "none" or magnitude == 0:
            return None
        win = {"onset_s": self.onset_s, **({"end_s": self.end_s} if self.end_s is not None else {})}
        if self.kind == "gps_step":
            return {"kind": "gps_step", "prn": self.prn, "bias_m": magnitude, **win}
        if self.kind == "gps_ramp":
            return {"kind": "gps_ramp", "prn": self.prn, "rate_m_s": magnitude, **win}
        if self.kind == "constellation_bias":
            return {"kind": "constellation_bias", "system": self.system, "bias_m": magnitude, **win}
        if self.kind == "constellation_orbit":
            n = math.hypot(*self.direction_ecef)
            return {"kind": "constellation_orbit", "system": self.system,
                    "translation_m": tuple(magnitude * (c / n) for c in self.direction_ecef), **win}
        if self.kind in IMU_KINDS:
            return {"kind": self.kind, "axis": self.axis, IMU_MAGNITUDE_KEYS[self.kind]: magnitude, **win}
        if self.kind == "pixel_bias":
            return {"kind": "pixel_bias", "landmark": self.landmark, "magnitude_px": magnitude,
                    "angle_deg": self.angle_deg, **win}
        return {"kind": "landmark_moved", "landmark": self.landmark, "delta_enu_m": self._move(magnitude), **win}


class Sweep(StrictModel):
    """Sensor and scenario axes; an empty list / missing key = the approach file's value."""

    start_time_utc: list[dt.datetime] = Field(default_factory=list, description="start times across the day (UTC)")
    camera_dpi: list[float] = Field(default_factory=list, description="camera resolution, dpi (va-raim-2015 / custom dpi cameras)")
    camera_focal_px: list[float] = Field(default_factory=list,
                                         description="camera focal length, px, at the approach camera's field of view "
                                                     "(the pixel count scales with it): the angular precision sweep")
    detection_sigma_px: list[float] = Field(default_factory=list, description="detection error 1-sigma, px")
    lpe_sigma_m: list[float] = Field(default_factory=list, description="landmark position (survey) error 1-sigma, m")
    landmark_sets: list[list[LandmarkSet]] = Field(default_factory=list, description="each entry: a full landmark set list")
    calibration: list[Literal["gps", "none"]] = Field(default_factory=list, description="VA-RAIM calibration modes")
    va_raim_variant: list[Literal["gated", "seed"]] = Field(default_factory=list,
                                                            description="VA-RAIM variants (testbed default 'gated')")
    dpe_variant: list[Literal["likelihood", "seed"]] = Field(
        default_factory=list, description="DPE variants (testbed default 'likelihood'); a 'seed' cell's receiver "
                                          "reports the DPE paper's magnitude statistic (exact synthesis) and its VPL "
                                          "factor is the Gaussian K = Q⁻¹(P/2) at P = 1e-7 (5.33)")
    multipath_echo_db: list[float | Literal["off"]] = Field(
        default_factory=list, description="the correlators' ground multipath: 'off', or the specular echo's amplitude "
                                          "relative to the direct signal (dB, ≤ 0): the multipath strength axis")
    max_satellites: list[int] = Field(
        default_factory=list, description="satellites tracked at most, for the whole sortie (replaces the approach's "
                                          "[gnss] schedule; which ones: its [gnss] keep): the satellites-in-view axis")
    ground_features: list[bool] = Field(
        default_factory=list, description="the tracked unsurveyed ground features off / on ([vision.features] "
                                          "enabled; the ekf monitor reads them): the SLAM axis")
    constellations: list[list[Literal["gps", "galileo", "beidou"]]] = Field(
        default_factory=list, description="each entry: the constellations tracked ([gnss] constellations; the "
                                          "approach's tables of the others are dropped): the constellation axis")
    terrain_masking: list[bool] = Field(
        default_factory=list, description="satellites masked by the terrain or not ([gnss] terrain_masking): "
                                          "the valley against open sky")

    @field_validator("start_time_utc")
    @classmethod
    def _utc(cls, v):
        for t in v:
            if t.tzinfo is None:
                raise ValueError("expected UTC times with an offset, e.g. 2026-03-01T04:00:00Z")
        return [t.astimezone(dt.timezone.utc) for t in v]

    @field_validator("constellations")
    @classmethod
    def _constellation_sets(cls, v):
        return [checked_constellation_set(x) for x in v]

    @field_validator("multipath_echo_db")
    @classmethod
    def _echo(cls, v):
        bad = [x for x in v if x != "off" and not (isinstance(x, (int, float)) and x <= 0.0 and x == x)]
        if bad:
            raise ValueError(f"expected 'off' or echo amplitudes ≤ 0 dB, got {bad}")
        return v

    @field_validator("camera_dpi", "detection_sigma_px", "lpe_sigma_m", "max_satellites")
    @classmethod
    def _nonneg(cls, v):
        bad = [x for x in v if x < 0]
        if bad:
            raise ValueError(f"expected values >= 0, got {bad}")
        return v

    @field_validator("camera_focal_px")
    @classmethod
    def _positive(cls, v):
        bad = [x for x in v if not x > 0]
        if bad:
            raise ValueError(f"expected focal lengths > 0 px, got {bad}")
        return v

    @model_validator(mode="after")
    def _one_camera_axis(self):
        if self.camera_dpi and self.camera_focal_px:
            raise ValueError("camera_dpi and camera_focal_px: expected at most one camera axis (both set the camera)")
        return self


#: Period after which the GPS sky over a place repeats, s: two orbits, about 10 s less than a
#: sidereal day (Choi, Bilich, Larson & Axelrad 2004, "Modified sidereal filtering": 86154 s on
#: average). Measured here on the DO-229 almanac: the best repeat over sidereal day ± 600 s is
#: 86154.1 s, elevations then agree to 0.044° a day later (0.10° at one sidereal day).
SKY_REPEAT_S = 86154.0


#: the [sorties] keys each start mode reads (one not read by the spec's mode is refused, not ignored)
READ_BY = {"sortie_s": ("consecutive", "uniform"), "span_s": ("uniform",), "window_s": ("consecutive", "uniform")}


class SortieStarts(StrictModel):
    """When each sortie of a cell is flown (``[sorties]`` in a spec).

    The trajectory is flown once; only the start time (the satellites' sky) changes.
    Sortie k starts ``offset_k`` after the approach's ``start_time_utc``:

    * ``fixed``: offset 0 for every sortie (one geometry per cell);
    * ``consecutive``: ``offset_k = k · sortie_s`` (the VA-RAIM paper's "1e5 sorties of
      60 s": about 69 days for 1e5 sorties);
    * ``uniform``: offsets drawn uniformly over ``[0, span_s − sortie_s]`` (seeded by the
      spec's base seed and the draw block; the same in every cell).

    The sky repeats after a period of the constellation set (GPS alone: :data:`SKY_REPEAT_S`, about a
    sidereal day; with Galileo or BeiDou, 7 to 70 sidereal days:
    :func:`testbed.campaign.sorties.sky_repeat_s`), so an offset is reduced modulo that period and
    rounded to a grid of ``window_s``: every sortie in one window flies under one computed sky, the
    first period's (GPS alone: at most ``round(86154 / window_s)`` windows, 1436 for 60 s). Two approximations, both measured
    (``tests/test_sorties.py``): the start phase is off by at most ``window_s / 2`` (30 s:
    ≤ 0.22° of satellite elevation over ZUNZ), and the constellation does not repeat exactly:
    a sortie d periods into the span flies a sky whose elevations differ from its true
    date's by up to 0.044° per period (3° by the 69th day of 1e5 consecutive 60 s sorties).
    Sky *coverage* (every phase of the repeat, each as often) is what the statistics need
    and is exact; a sortie's calendar date is not.
    """

    start: Literal["fixed", "consecutive", "uniform"] = Field("fixed", description="fixed | consecutive | uniform")
    sortie_s: float | None = Field(None, gt=0, description="sortie spacing (consecutive) and length (uniform), s; "
                                                           "default: the spec's duration_s")
    span_s: float | None = Field(None, gt=0, description="uniform: the span the starts are drawn over, s")
    window_s: float = Field(60.0, gt=0, le=3600, description="start times within one window of the sky's repeat "
                                                              "period share one geometry, s")

    @model_validator(mode="after")
    def _check(self):
        if self.start == "uniform" and self.span_s is None:
            raise ValueError("start = 'uniform' needs span_s (the span the start times are drawn over, s)")
        # one rule for every key: refused, never silently ignored, when the mode does not read it (its default
        # passes: a spec written back whole, as the workers and the manifest get it, holds every key)
        for key, modes in READ_BY.items():
            value, default = getattr(self, key), type(self).model_fields[key].default
            if self.start not in modes and value != default:
                raise ValueError(f"[{key}] read only with start = {' or '.join(map(repr, modes))}, not with "
                                 f"start = {self.start!r}: remove it, or choose a start that reads it "
                                 f"(got {value!r})")
        if self.span_s is not None and self.sortie_s is not None and self.span_s < self.sortie_s:
            raise ValueError(f"span_s = {self.span_s:g} s is shorter than one sortie (sortie_s = {self.sortie_s:g} s)")
        return self


class ReportSettings(StrictModel):
    """The statistics of the campaign report (``[report]`` in a spec)."""

    power: float = Field(0.99, gt=0, lt=1, description="detection power for the minimal detectable bias")
    confidence: float = Field(0.95, gt=0, lt=1, description="confidence of the binomial bands")
    interval: Literal["clopper-pearson", "wilson"] = Field(
        "clopper-pearson", description="binomial confidence interval of the rates: Clopper-Pearson (exact) or "
                                       "Wilson")


#: the [sampling] keys read only with method = "importance" (refused, not ignored, with "plain")
IMPORTANCE_KEYS = ("monitor", "event", "proposal", "scale", "defensive", "mixture", "adapt", "pilot_trials")

#: [sampling] keys added after specs were first stored: left out of the hash at these values
LATER_SAMPLING_DEFAULTS = {"mixture": "uniform", "adapt": "none", "pilot_trials": 400}


class SamplingPlan(StrictModel):
    """How a campaign draws its trials (``[sampling]`` in a spec; :mod:`testbed.campaign.sampling`).

    ``plain``: every trial from the error model itself (every table as without the table).
    ``importance``: the fault-free pseudorange errors drawn from a proposal aimed at a monitor's failure
    event, each trial carrying its log-likelihood ratio (``log_weight``); the report weights every rate.
    """

    method: Literal["plain", "importance"] = Field("plain", description="plain | importance")
    monitor: str | None = Field(None, description="importance: the monitor whose linear model aims the proposal "
                                                  "(one of the spec's monitors reading the pseudoranges, or the "
                                                  "pseudoranges and the camera, whose draws are then moved too; "
                                                  "default: the first reading the pseudoranges alone)")
    event: Literal["misleading", "hazardous"] = Field(
        "misleading", description="importance: the failure event aimed at: misleading (an error beyond the "
                                  "protection level, no alert) or hazardous (beyond the alert limit, the "
                                  "protection level within it, no alert)")
    proposal: Literal["shift", "scale", "separation"] = Field(
        "shift", description="importance: shift the mean of one epoch's errors to the event's nearest point "
                             "(misleading information), or scale one epoch's errors in the fit's residual space by "
                             "`scale` (the test statistic's tail: false alarms; `event` is not read), or (ARAIM) "
                             "shift them to one solution-separation test's threshold, a component per test "
                             "(ARAIM's false alerts; `event` is not read)")
    scale: float = Field(2.0, gt=1.0, le=100.0, description="importance, proposal = 'scale': the factor on the "
                                                            "residual-space errors' standard deviation")
    defensive: float = Field(0.1, ge=0.0, lt=1.0, description="importance: share of the trials drawn from the error "
                                                              "model itself (bounds every weight by 1/defensive)")
    mixture: Literal["uniform", "tail"] = Field(
        "uniform", description="importance, proposal = 'shift' or 'separation': how often each component (epoch, "
                               "dimension or test, sign) is drawn: uniformly, or in proportion to its own Gaussian "
                               "tail Q(|z*|), so that the "
                               "epochs whose event is likeliest get the trials (a flight whose epochs' rates span "
                               "orders of magnitude)")
    adapt: Literal["none", "cross_entropy"] = Field(
        "none", description="importance, proposal = 'shift': refit each component's mean from a pilot run before "
                            "the trials: the weighted mean of the pilot's draws that reached the component's event "
                            "(the cross-entropy method)")
    pilot_trials: int = Field(400, ge=50, le=100_000, description="adapt = 'cross_entropy': the pilot's sorties "
                                                                  "(drawn apart from the campaign's, not in its "
                                                                  "estimate)")

    @model_validator(mode="after")
    def _check(self):
        if self.method == "plain":
            for key in IMPORTANCE_KEYS:
                value, default = getattr(self, key), type(self).model_fields[key].default
                if value != default:
                    raise ValueError(f"[{key}] read only with method = 'importance', not with method = 'plain': "
                                     f"remove it, or set method = 'importance' (got {value!r})")
        if self.proposal != "scale" and self.scale != type(self).model_fields["scale"].default:
            raise ValueError(f"[scale] read only with proposal = 'scale', not with proposal = '{self.proposal}' "
                             f"(got {self.scale!r})")
        if self.proposal == "scale" and self.mixture != "uniform":
            raise ValueError(f"[mixture] read only with proposal = 'shift' (a scaled epoch has no tail of its own to "
                             f"draw it by), got {self.mixture!r}")
        if self.adapt == "none" and self.pilot_trials != type(self).model_fields["pilot_trials"].default:
            raise ValueError(f"[pilot_trials] read only with adapt = 'cross_entropy' (got {self.pilot_trials!r})")
        if self.proposal != "shift" and self.adapt != "none":
            raise ValueError(f"[adapt] read only with proposal = 'shift' (the cross-entropy step refits a shift's "
                             f"mean), got {self.adapt!r}")
        if self.proposal != "shift" and self.event != type(self).model_fields["event"].default:
            raise ValueError(f"[event] read only with proposal = 'shift' (proposal = '{self.proposal}' aims at the "
                             f"tests' tails), got {self.event!r}")
        return self


class CampaignSpec(StrictModel):
    """A fault-injection Monte Carlo campaign (``approaches/campaigns/<name>.toml``)."""

    name: FileName = Field(..., min_length=1, description="campaign name; it names the default output folder "
                                                          "(`campaigns/<name>`)")
    description: str = Field("", description="shown by `testbed approaches` (its first line)")
    approaches: list[str] = Field(..., min_length=1, description="approach names or paths (relative to the spec)")
    monitors: list[MonitorName] = Field(..., min_length=1, description="monitor names: gps_raim, va_raim, pixel, "
                                                                       "ekf, dpe, or one registered with "
                                                                       "testbed.monitors.register")
    trials: int = Field(..., ge=1, le=10_000_000, description="trials (sorties) per cell")
    base_seed: int = Field(0, ge=0, description="random seed of the campaign: every trial's draws derive from it, "
                                                "the cell and the draw block")
    block_trials: int = Field(100, ge=1, le=100_000, description="trials per draw block (share a landmark survey)")
    chunk_trials: int = Field(1000, ge=1, description="trials per stored chunk/task (a multiple of block_trials)")
    common_random_numbers: bool = Field(False, description="same noise draws in every cell (smoother sweeps)")
    per_epoch_trials: int = Field(20, ge=0, description="store per-epoch records for the first N trials of each cell")
    duration_s: float | None = Field(None, gt=0, description="use only duration_s of each flight (see segment)")
    segment: Literal["first", "last"] = Field(
        "first", description="which duration_s of each flight the sorties fly: the first (from the approach's start) "
                             "or the last (down to the threshold: where a ground echo reaches the correlators); a "
                             "segment's time starts at 0 (fault onsets count from it)")
    faults: list[FaultSweep] = Field(default_factory=lambda: [FaultSweep(kind="none")], min_length=1,
                                     description="fault families; [{kind = \"none\"}] for fault-free trials only")
    sweep: Sweep = Field(default_factory=Sweep, description="sensor and scenario axes")
    sorties: SortieStarts = Field(default_factory=SortieStarts, description="when each sortie is flown")
    report: ReportSettings = Field(default_factory=ReportSettings, description="statistics of the report")
    sampling: SamplingPlan = Field(default_factory=SamplingPlan, description="how the trials are drawn: plain, or "
                                                                             "importance sampling")

    @model_validator(mode="after")
    def _chunks(self):
        if self.segment == "last" and self.duration_s is None:
            raise ValueError("segment = 'last': expected duration_s (the length of the last segment)")
        so = self.sorties
        if so.start != "fixed" and so.sortie_s is None and self.duration_s is None:
            raise ValueError(f"sorties.sortie_s: expected the sortie length in s (or duration_s) with "
                             f"start = {so.start!r}")
        length = so.sortie_s if so.sortie_s is not None else self.duration_s
        if so.span_s is not None and length is not None and so.span_s < length:
            raise ValueError(f"sorties.span_s = {so.span_s:g} s is shorter than one sortie ({length:g} s)")
        if self.duration_s is not None:  # onsets count from the segment's start; its last epoch is at duration_s
            late = [k for k, f in enumerate(self.faults)
                    if f.kind != "none" and any(m != 0 for m in f.magnitudes) and f.onset_s > self.duration_s]
            if late:
                k = late[0]
                raise ValueError(f"[faults.{k}.onset_s] after the end of the sortie (duration_s = "
                                 f"{self.duration_s:g}), so no epoch would be faulty: expected an onset at or "
                                 f"before {self.duration_s:g} s (got {self.faults[k].onset_s:g})")
        if self.chunk_trials % self.block_trials:
            raise ValueError(f"chunk_trials ({self.chunk_trials}) must be a multiple of block_trials "
                             f"({self.block_trials})")
        if self.sampling.monitor is not None and self.sampling.monitor not in self.monitors:
            raise ValueError(f"[sampling.monitor] {self.sampling.monitor!r}: expected one of the spec's monitors "
                             f"{list(self.monitors)}")
        return self


@dataclass(frozen=True)
class Cell:
    """One point of the sweep: a concrete approach config and the fault it carries."""

    index: int
    approach: Approach
    params: dict  # flat, table-friendly: approach, start_time_utc, fault_kind, fault_size, dpi, ...

    @property
    def config(self) -> ApproachConfig:
        return self.approach.config


@dataclass(frozen=True)
class LoadedSpec:
    spec: CampaignSpec
    source: Path
    approaches: tuple[Approach, ...]

    @property
    def hash(self) -> str:
        return spec_hash(self.spec)


#: spec keys that change no result (the spec hash leaves them out): a resume may change them
NOT_HASHED = ("report", "description")


def spec_hash(spec: CampaignSpec) -> str:
    """A short hash of everything that changes results (the report settings excluded)."""
    d = _later_defaults_unset(spec.model_dump(mode="json", exclude=set(NOT_HASHED)))
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


#: sweep axes added after specs were first stored: left out of the hash while empty
LATER_AXES = ("constellations", "terrain_masking")


#: fault-family keys added after specs were first stored: left out of the hash while unset (None)
LATER_FAULT_KEYS = ("system", "direction_ecef", "axis")


def _later_defaults_unset(d: dict) -> dict:
    """A spec dump without what later versions added at its default: the ``[sampling]`` table when plain (its
    ``mixture`` when uniform), the later sweep axes when empty and the later fault keys when unset. A spec that
    uses none of them hashes, and compares on resume, as before."""
    if d.get("sampling") == SamplingPlan().model_dump(mode="json"):
        d = {k: v for k, v in d.items() if k != "sampling"}
    elif isinstance(d.get("sampling"), dict):  # keys added later, at their defaults
        d = {**d, "sampling": {k: v for k, v in d["sampling"].items()
                               if not (k in LATER_SAMPLING_DEFAULTS and v == LATER_SAMPLING_DEFAULTS[k])}}
    faults = d.get("faults")
    if isinstance(faults, list):
        d = {**d, "faults": [{k: v for k, v in f.items() if not (k in LATER_FAULT_KEYS and v is None)}
                             if isinstance(f, dict) else f for f in faults]}
    sweep = d.get("sweep")
    if isinstance(sweep, dict) and any(k in sweep and not sweep[k] for k in LATER_AXES):
        d = {**d, "sweep": {k: v for k, v in sweep.items() if not (k in LATER_AXES and not v)}}
    return d


def input_fingerprint(cells: list[Cell]) -> dict:
    """What the results depend on beyond the spec: every cell's resolved configuration (its
    approach and aircraft after the sweep) and the content of every file the cells read."""
    from importlib.metadata import PackageNotFoundError, version

    files: dict[str, str] = {}
    for c in cells:
        cfg = c.config
        for p in (c.approach.source, c.approach.aircraft_source, *cfg.gnss.orbit_files, *cfg.terrain.dem_paths):
            if p is not None and str(p) not in files and Path(p).is_file():
                files[str(p)] = hashlib.sha256(Path(p).read_bytes()).hexdigest()[:16]
    resolved = [[c.config.model_dump(mode="json"), c.approach.aircraft.model_dump(mode="json")] for c in cells]
    try:
        code = version("testbed")
    except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        code = "unknown"
    return {"cells": hashlib.sha256(json.dumps(resolved, sort_keys=True, default=str).encode()).hexdigest()[:16],
            "files": files, "testbed": code}


def fingerprint_changes(old: dict, new: dict) -> list[str]:
    """What differs between two :func:`input_fingerprint` s, one line each."""
    out = []
    of, nf = old.get("files", {}), new.get("files", {})
    out += [f"{p}: changed since the stored run" for p in sorted(set(of) & set(nf)) if of[p] != nf[p]]
    out += [f"{p}: read now, not by the stored run" for p in sorted(set(nf) - set(of))]
    out += [f"{p}: read by the stored run, not now" for p in sorted(set(of) - set(nf))]
    if not out and old.get("cells") != new.get("cells"):
        out.append("the resolved cell configurations differ (approach or aircraft settings)")
    if old.get("testbed") != new.get("testbed"):
        out.append(f"testbed version {old.get('testbed')} stored, {new.get('testbed')} now")
    return out


def spec_changes(stored: dict, now: dict) -> list[str]:
    """What differs between a stored spec and this one (both as ``model_dump(mode="json")`` gives them),
    one ``key.path: stored → now`` line per value, the keys of :data:`NOT_HASHED` left out."""
    old, new = _flat(_later_defaults_unset(stored)), _flat(_later_defaults_unset(now))
    show = lambda d, k: json.dumps(d[k], ensure_ascii=False) if k in d else "(not set)"  # noqa: E731
    keys = [k for k in {**old, **new} if k.split(".")[0] not in NOT_HASHED]
    return [f"{k}: {show(old, k)} → {show(new, k)}" for k in keys if old.get(k, ...) != new.get(k, ...)]


def _flat(d: dict, prefix: str = "") -> dict:
    """Nested tables (and lists of tables) as ``a.b.0.c`` keys."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            out |= _flat(v, key + ".")
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            out |= _flat({str(j): x for j, x in enumerate(v)}, key + ".")
        else:
            out[key] = v
    return out


def resolve_spec_path(name_or_path: str | Path) -> Path:
    """A shipped campaign name (``gps-step-sweep``) or a path to a spec file."""
    from testbed.resources import campaigns_dir, shipped_or_path

    return shipped_or_path(name_or_path, campaigns_dir(), "campaign spec")


def load_spec(path: str | Path, *, trials: int | None = None) -> LoadedSpec:
    """Read and validate a spec and every approach it names; errors name file and key path.

    path : a spec file or a shipped campaign name.  trials : override the spec's trials per
    cell (a quick look; the block and chunk sizes shrink to fit).
    """
    src = resolve_spec_path(path)
    data = read_toml(src)
    if trials is not None:
        data = {**data, "trials": trials}
        block, chunk = data.get("block_trials", 100), data.get("chunk_trials", 1000)
        if isinstance(block, int) and isinstance(chunk, int) and trials >= 1 and block >= 1:
            block = min(block, trials)
            data["block_trials"], data["chunk_trials"] = block, min(chunk, -(-trials // block) * block)
    spec = validate(CampaignSpec, data, src)
    return resolve_spec(spec, src)


def resolve_spec(spec: CampaignSpec, source: Path) -> LoadedSpec:
    """Load the spec's approaches and expand its cells once (so every problem shows up now)."""
    aps = []
    problems = []
    for k, name in enumerate(spec.approaches):
        p = Path(name)
        if (p.suffix == ".toml" or "/" in name) and not p.is_absolute():
            cand = source.parent / p
            name = str(cand) if cand.exists() else name
        try:
            aps.append(load_approach(name))
        except ConfigError as exc:
            problems.append(f"approaches.{k}: {name!r}: " + "; ".join(exc.problems))
    if problems:
        raise ConfigError(source, problems)
    loaded = LoadedSpec(spec, source, tuple(aps))
    expand_cells(loaded)  # validates every combination
    return loaded


def _set(d: dict, dotted: str, value: Any) -> None:
    keys = dotted.split(".")
    for k in keys[:-1]:
        d = d.setdefault(k, {})
    d[keys[-1]] = value


def expand_cells(loaded: LoadedSpec) -> list[Cell]:
    """Every cell of the sweep, in a fixed order (the cell index is part of each trial's seed)."""
    spec, sw = loaded.spec, loaded.spec.sweep
    axes = [
        ("start_time_utc", sw.start_time_utc or [None]),
        ("fault", [(k, f, m) for k, f in enumerate(spec.faults) for m in f.magnitudes]),
        ("dpi", sw.camera_dpi or [None]),
        ("focal_px", sw.camera_focal_px or [None]),
        ("sigma_px", sw.detection_sigma_px or [None]),
        ("lpe_sigma_m", sw.lpe_sigma_m or [None]),
        ("landmark_set", list(enumerate(sw.landmark_sets)) or [None]),
        ("calibration", sw.calibration or [None]),
        ("va_raim_variant", sw.va_raim_variant or [None]),
        ("dpe_variant", sw.dpe_variant or [None]),
        ("multipath_echo_db", sw.multipath_echo_db or [None]),
        ("max_satellites", sw.max_satellites or [None]),
        ("ground_features", sw.ground_features or [None]),
        ("constellations", [tuple(x) for x in sw.constellations] or [None]),
        ("terrain_masking", sw.terrain_masking or [None]),
    ]
    names = [a for a, _ in axes]
    cells: list[Cell] = []
    problems: list[str] = []
    for ap in loaded.approaches:
        base = ap.config.model_dump(mode="json", exclude_unset=True)
        for combo in itertools.product(*[v for _, v in axes]):
            c = dict(zip(names, combo))
            d = json.loads(json.dumps(base))
            d["monitors"] = list(spec.monitors)
            d["faults"] = []
            fk, fam, mag = c["fault"]
            fault = fam.fault(mag)
            if fault is not None:
                d["faults"] = [fault]
            if c["start_time_utc"] is not None:
                d["start_time_utc"] = c["start_time_utc"].isoformat()
            if c["dpi"] is not None:
                _set(d, "vision.camera.dpi", c["dpi"])
            if c["focal_px"] is not None:
                _set(d, "vision.camera", _camera_at_focal(ap.config.vision.camera, c["focal_px"]))
            if c["sigma_px"] is not None:
                _set(d, "vision.detection.sigma_px", c["sigma_px"])
            if c["lpe_sigma_m"] is not None:
                _set(d, "landmarks.lpe_sigma_m", c["lpe_sigma_m"])
                # the monitor is told the survey error it faces (seed: sigma_g known)
                _monitor_table(d, "va_raim")["landmark_survey_sigma_m"] = c["lpe_sigma_m"]
            if c["landmark_set"] is not None:
                _set(d, "landmarks.sets", [s.model_dump(mode="json") for s in sw.landmark_sets[c["landmark_set"][0]]])
            if c["calibration"] is not None:
                _monitor_table(d, "va_raim")["calibration"] = c["calibration"]
            if c["va_raim_variant"] is not None:
                _monitor_table(d, "va_raim")["variant"] = c["va_raim_variant"]
            if c["dpe_variant"] is not None:
                _dpe_variant(d, c["dpe_variant"])
            if c["multipath_echo_db"] is not None:
                corr = d.setdefault("gnss", {}).setdefault("correlators", {})
                corr["multipath"] = "off" if c["multipath_echo_db"] == "off" else "ground"
                if c["multipath_echo_db"] != "off":
                    corr["ground_echo_db"] = float(c["multipath_echo_db"])
            if c["max_satellites"] is not None:
                d.setdefault("gnss", {})["schedule"] = [{"from_s": 0.0, "max_satellites": int(c["max_satellites"])}]
            if c["ground_features"] is not None:
                _set(d, "vision.features.enabled", bool(c["ground_features"]))
            if c["constellations"] is not None:
                gnss = d.setdefault("gnss", {})
                for name in ("gps", "galileo", "beidou"):  # a table of an untracked constellation is refused
                    if name not in c["constellations"]:
                        gnss.pop(name, None)
                gnss["constellations"] = list(c["constellations"])
            if c["terrain_masking"] is not None:
                _set(d, "gnss.terrain_masking", bool(c["terrain_masking"]))
            if _reads_vision(spec.monitors, d.get("monitor")):
                # the vision monitors combine both sensors at the GNSS epochs
                _set(d, "vision.rate_hz", d.get("gnss", {}).get("rate_hz", ap.config.gnss.rate_hz))
            idx = len(cells)
            try:
                cfg = validate(ApproachConfig, d, ap.source)
                if fam.kind in VISION_KINDS and not cfg.reads("vision"):
                    raise ConfigError(ap.source, [f"a {fam.kind} fault needs a monitor that reads vision, with its "
                                                  f"options; none of {list(spec.monitors)} does"])
                preflight(replace(ap, config=cfg), trim=False)  # what the run loads (the trim: once, when flying)
                file_problems = _broadcast_sortie_problems(cfg, spec)
                if file_problems:
                    raise ConfigError(ap.source, file_problems)
            except ConfigError as exc:
                problems.append(f"cell {idx} ({_describe(ap.name, c)}): " + "; ".join(exc.problems))
                continue
            vis = cfg.vision
            params = {
                "cell": idx, "approach": ap.name, "start_time_utc": cfg.start_time_utc.isoformat(),
                "fault_family": fk, "fault_kind": "none" if fault is None else fam.kind,
                "fault_sweep_kind": fam.kind, "fault_size": float(mag), "fault_unit": MAGNITUDE_UNITS[fam.kind],
                "onset_s": float(fam.onset_s) if fault is not None else float("nan"),
                "dpi": float(vis.camera.dpi) if vis.camera.dpi is not None else float("nan"),
                "focal_px": float(c["focal_px"]) if c["focal_px"] is not None else float("nan"),
                "sigma_px": float(vis.detection.sigma_px), "lpe_sigma_m": float(cfg.landmarks.lpe_sigma_m),
                "landmark_set": -1 if c["landmark_set"] is None else int(c["landmark_set"][0]),
                "calibration": str(monitor_options("va_raim", cfg.monitor).calibration),
                "va_raim_variant": str(monitor_options("va_raim", cfg.monitor).variant),
                "dpe_variant": str(monitor_options("dpe", cfg.monitor).variant),
                "multipath_echo_db": (float(cfg.gnss.correlators.ground_echo_db)
                                      if cfg.gnss.correlators.multipath == "ground" else float("nan")),
                "max_satellites": -1 if c["max_satellites"] is None else int(c["max_satellites"]),
                "ground_features": int(cfg.vision.features.enabled),
                "constellations": "+".join(cfg.gnss.constellations),
                "terrain_masking": int(cfg.gnss.terrain_masking),
                **dict(zip(("hal", "val"), strictest_limits(cfg.integrity.service_levels))),
            }
            cells.append(Cell(idx, replace(ap, config=cfg), params))
    if problems:
        raise ConfigError(loaded.source, problems)
    return cells


def _reads_vision(monitors, tables: dict | None) -> bool:
    """Whether the monitors read vision with their options as given (not yet validated: an invalid table reads as
    its defaults here, and the cell's validation names the problem)."""
    try:
        return reads("vision", monitors, tables)
    except ValueError:  # pydantic's ValidationError included
        return reads("vision", monitors)


def _broadcast_sortie_problems(cfg: ApproachConfig, spec: CampaignSpec) -> list[str]:
    """Every sky window is computed from one broadcast record per satellite, the one nearest the approach's start:
    a constellation flown from a navigation file needs every sortie within that record's validity (2 h)."""
    so = spec.sorties
    length = so.sortie_s if so.sortie_s is not None else spec.duration_s
    if so.start == "fixed" or length is None:
        return []
    last_end = spec.trials * length if so.start == "consecutive" else float(so.span_s)
    t0 = utc_to_gps_seconds(cfg.start_time_utc)
    out = []
    for name in cfg.gnss.constellations:
        source, path, key = cfg.gnss.orbit_source_of(name)
        if source != "rinex_nav":
            continue
        toe = constellation_orbits(name, source, path, t0).toe_gps
        worst = float(np.max(np.maximum(np.abs(toe - t0), np.abs(toe - t0 - last_end))))
        if worst > MAX_AGE_S:
            out.append(f"{key} = {str(path)!r}: the sorties ([sorties] start = {so.start!r}) end "
                       f"{last_end / 3600:.1f} h after the start and every one flies the broadcast records nearest "
                       f"the start (up to {worst / 3600:.1f} h from their time of ephemeris): expected sorties "
                       f"within {MAX_AGE_S / 3600:.0f} h of them (a shorter span or fewer trials), or "
                       f"orbit_source = 'nominal'")
    return out


def _monitor_table(d: dict, name: str) -> dict:
    """The ``[monitor.<name>]`` table of approach data ``d`` (made empty when absent)."""
    tables = d.setdefault("monitor", {})
    table = tables.get(name)
    tables[name] = table = dict(table) if table is not None else {}
    return table


def _dpe_variant(d: dict, variant: str) -> None:
    """Set a cell's DPE variant. The seed's receiver reports (1/N_b)Σ|y_b| (``statistic = "mag"``,
    exact synthesis: GPS RAIM reads its peaks too when the approach derives pseudoranges from the
    correlators); its K is the Gaussian one its "factoring the overbound" implies, Q⁻¹(P/2) at the
    calibration's P = 1e-7 (the seed's own empirical K needs N·P ≥ 10, 1e8 epochs: docs/design/dpe.md §6.3)."""
    from testbed.integrity.dpe.calibration import DEFAULT_P_HMI, gaussian_k

    dpe = _monitor_table(d, "dpe")
    dpe["variant"] = variant
    if variant == "seed":
        corr = d.setdefault("gnss", {}).setdefault("correlators", {})
        corr.update(statistic="mag", synthesis="exact")
        dpe["k_factor"] = gaussian_k(DEFAULT_P_HMI)


def _camera_at_focal(camera, focal_px: float) -> dict:
    """A custom camera with the field of view (and distortion) of ``camera`` and focal length
    ``focal_px``: the pixel count scales with the focal length, so only the angular precision
    σ_px / f changes and the landmarks stay in view as with the approach's own camera."""
    import math

    cam = camera.build()
    hfov = 2 * math.atan(cam.width_px / (2 * cam.fx))
    vfov = 2 * math.atan(cam.height_px / (2 * cam.fy))
    return {"preset": "custom", "focal_px": float(focal_px),
            "width_px": max(16, int(round(2 * focal_px * math.tan(hfov / 2)))),
            "height_px": max(16, int(round(2 * focal_px * math.tan(vfov / 2)))),
            "k1": camera.k1, "k2": camera.k2, "p1": camera.p1, "p2": camera.p2}


def _describe(name: str, c: dict) -> str:
    parts = [name]
    fk, fam, mag = c["fault"]
    parts.append(f"faults.{fk} {fam.kind} {mag:g}")
    for k in ("start_time_utc", "dpi", "focal_px", "sigma_px", "lpe_sigma_m", "calibration", "va_raim_variant",
              "dpe_variant", "multipath_echo_db", "max_satellites", "ground_features", "constellations",
              "terrain_masking"):
        if c[k] is not None:
            parts.append(f"{k}={c[k]}")
    if c["landmark_set"] is not None:
        parts.append(f"landmark_sets.{c['landmark_set'][0]}")
    return ", ".join(parts)
