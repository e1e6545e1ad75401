"""The records that flow between the rooms: truth, observations, monitor outputs.

Each record is a frozen dataclass of numpy arrays with batch axes first and
components last. Observation records carry no truth: anything a monitor must
not see lives in the matching ``*Truth`` record, which only evaluation reads.

Shapes use: T epochs, S satellite slots, L landmarks, B leading batch (trial)
axes (zero or more). Missing measurements are NaN *and* masked out.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from dataclasses import dataclass, field, fields, replace
from enum import IntEnum
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray


def epoch_array(tail: int = 0, *, ragged: bool = False, batched: bool = True):
    """A record field holding a per-epoch array: ``(B..., T, *tail axes)``.

    tail : how many component axes follow the epoch axis (0 for ``(B..., T)``).
    ragged : the last axis's width may differ between blocks (a stacked problem's
        rows): joining blocks pads it (NaN, -1 or False) instead of dropping it.
    batched : False for arrays that never carry trial axes (the epoch times ``t``).
    """
    return field(metadata={"tail": tail, "ragged": ragged, "batched": batched})


def max_p95_text(x: ArrayLike, unit: str = "m") -> str:
    """A summary cell: the largest finite value and the 95th percentile ("-" when there is none)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return f"{x.max():.2f} / {np.percentile(x, 95):.2f} {unit}" if x.size else "-"


def largest_text(x: ArrayLike) -> str:
    """A summary cell: the largest finite value, as a rate ("-" when there is none)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return f"{x.max():.2e}" if x.size else "-"


def span_text(x: ArrayLike) -> str:
    """A summary cell: the smallest and largest count."""
    x = np.asarray(x)
    return f"{x.min()}-{x.max()}" if x.size else "-"


@dataclass(frozen=True)
class Diagnostics:
    """Base of a monitor's typed diagnostics record (plot and test data, never state).

    Every array field is declared with :func:`epoch_array`, so slicing, joining and
    stacking handle any monitor's record without knowing it; other fields
    (reason texts, constants) are carried as they are.
    """

    #: :meth:`trial_columns` reads the vision truth (a campaign shares a monitor's tables between cells only when
    #: what they read is the same)
    reads_vision_truth: ClassVar[bool] = False

    def trial_columns(self, vision_truth) -> dict[str, NDArray]:
        """The monitor's own columns of a campaign's trials table, one value per trial (evaluation against the
        truth): none by default."""
        return {}

    def summary_rows(self) -> dict[str, str]:
        """The monitor's own rows of a run's summary table (label -> text, over the run's epochs): none by
        default."""
        return {}

    def epoch_columns(self) -> dict[str, NDArray]:
        """The monitor's own columns of a per-epoch table (``testbed monitor``'s ``epochs-<monitor>`` file, beside
        the contract's): column name (its unit in the name) -> values (T,), one per epoch. None by default."""
        return {}

    def plot_series(self) -> dict[str, tuple[NDArray, str]]:
        """The monitor's own curves in its recording tab: entity suffix under ``integrity/<monitor>/`` (a
        panel's path, e.g. ``"vertical/emt"``) -> (values (T,), legend name). None by default."""
        return {}


def _record_fields(rec):
    """(name, value, metadata) of a MonitorOutput or Diagnostics record's fields."""
    for name, meta in _field_plan(type(rec)):
        yield name, getattr(rec, name), meta


@functools.cache
def _field_plan(cls) -> tuple[tuple[str, object], ...]:
    """(name, metadata) of a record class's fields, looked up once per class (records are walked per
    block and per monitor: :func:`dataclasses.fields` each time was most of a walk's cost)."""
    return tuple((f.name, f.metadata) for f in fields(cls))


def _is_nested(v) -> bool:
    return isinstance(v, (MonitorOutput, Diagnostics))


def _is_epoch_array(rec, name: str, v, meta) -> bool:
    """Whether field ``name`` holds a per-epoch array (declared with :func:`epoch_array`).

    Observation records keep per-run constants (PRNs, surveyed landmarks, K) as
    undeclared arrays; a Diagnostics record must declare every array it has.
    """
    if not isinstance(v, np.ndarray):
        return False
    if "tail" in meta:
        return True
    if isinstance(rec, Diagnostics):
        raise TypeError(f"{type(rec).__name__}.{name}: an array field must be declared with epoch_array()")
    return False


def map_epoch_arrays(rec, fn):
    """``rec`` (an observation record, a MonitorOutput or a Diagnostics) with ``fn(array,
    metadata)`` applied to every per-epoch array, nested records included; constants kept."""
    return _map_records([rec], lambda vs, meta: fn(vs[0], meta))


def _map_records(recs: list, fn):
    """The first of ``recs`` (records of one layout) with ``fn([its array, the others' arrays...],
    metadata)`` in place of every per-epoch array, nested records included, in one walk."""
    first = recs[0]
    if any(type(r) is not type(first) for r in recs):
        raise ValueError(f"records of different types: {', '.join(type(r).__name__ for r in recs)}")
    kw = {}
    for name, meta in _field_plan(type(first)):
        v = getattr(first, name)
        if _is_nested(v):
            kw[name] = _map_records([getattr(r, name) for r in recs], fn)
        elif _is_epoch_array(first, name, v, meta):
            kw[name] = fn([v] + [getattr(r, name) for r in recs[1:]], meta)
    return replace(first, **kw)


def epoch_array_pairs(a, b):
    """``(array_a, array_b, metadata)`` of matching per-epoch arrays of two records of one layout."""
    if type(a) is not type(b):
        raise ValueError(f"records of different types: {type(a).__name__} vs {type(b).__name__}")
    for (name, va, meta), (_, vb, _) in zip(_record_fields(a), _record_fields(b)):
        if _is_nested(va):
            yield from epoch_array_pairs(va, vb)
        elif _is_epoch_array(a, name, va, meta):
            yield va, vb, meta


def epoch_axis(a: NDArray, meta) -> int:
    return a.ndim - 1 - meta["tail"]


def take_epochs(rec, idx):
    """``rec`` restricted to epochs ``idx`` (a slice or index array), whatever its trial axes."""
    def take(a, meta):
        ax = epoch_axis(a, meta)
        return a[(slice(None),) * ax + (idx,)]

    return map_epoch_arrays(rec, take)


def concat_epochs(recs: list):
    """Records of one layout joined along the epoch axis (constants from the first).

    Ragged fields are padded to the widest block (NaN for floats, -1 for integers,
    False for booleans), so no block's values are lost.
    """
    if len(recs) == 1:
        return recs[0]

    def join(parts: list, meta) -> NDArray:
        if meta["ragged"]:
            width = max(p.shape[-1] for p in parts)
            parts = [_pad_last(p, width) for p in parts]
        return np.concatenate(parts, axis=epoch_axis(parts[0], meta))

    return _map_records(recs, join)


def _pad_last(a: NDArray, width: int) -> NDArray:
    if a.shape[-1] == width:
        return a
    fill = False if a.dtype == bool else (-1 if np.issubdtype(a.dtype, np.integer) else np.nan)
    out = np.full(a.shape[:-1] + (width,), fill, a.dtype)
    out[..., : a.shape[-1]] = a
    return out


@dataclass(frozen=True)
class Truth:
    """True aircraft state over time (the flight's output).

    Attributes
    ----------
    t : (T,) s since the start of the approach.
    pos_ecef : (T, 3) m, the aircraft reference point (JSBSim CG) in ECEF.
    lat_deg, lon_deg, h : (T,) geodetic position, h WGS84 ellipsoidal (m).
    pos_enu : (T, 3) m, position in the approach's world frame (``frame``).
    vel_enu : (T, 3) m/s, velocity in the local ENU frame at the aircraft.
    q_body_to_enu : (T, 4) body (FRD) -> local ENU at the aircraft, scalar last.
    euler : (T, 3) rad, roll, pitch, true heading.
    omega_body : (T, 3) rad/s, inertial body rates p, q, r.
    specific_force_eye_body : (T, 3) m/s², specific force at the pilot's eye point (JSBSim's
        ``a-pilot``: the CG's plus ω̇ × r_eye + ω × (ω × r_eye), r_eye ≈ 14 m ahead on the 737).
    specific_force_cg_body : (T, 3) m/s², specific force at the CG (accelerometer truth there;
        JSBSim's load factors × standard gravity).
    omega_dot_body : (T, 3) rad/s², body angular acceleration.
    agl : (T,) m, height above the terrain model.
    airspeed : (T,) m/s, true airspeed.
    frame_origin : (3,) lat_deg, lon_deg, h of the world frame's origin.
    """

    t: NDArray = epoch_array(batched=False)
    pos_ecef: NDArray = epoch_array(1)
    lat_deg: NDArray = epoch_array()
    lon_deg: NDArray = epoch_array()
    h: NDArray = epoch_array()
    pos_enu: NDArray = epoch_array(1)
    vel_enu: NDArray = epoch_array(1)
    q_body_to_enu: NDArray = epoch_array(1)
    euler: NDArray = epoch_array(1)
    omega_body: NDArray = epoch_array(1)
    specific_force_eye_body: NDArray = epoch_array(1)
    agl: NDArray = epoch_array()
    airspeed: NDArray = epoch_array()
    specific_force_cg_body: NDArray = epoch_array(1)
    omega_dot_body: NDArray = epoch_array(1)
    frame_origin: NDArray = field()

    def at_indices(self, idx: NDArray) -> "Truth":
        """The record at the given epoch indices (e.g. decimated to a sensor rate)."""
        return take_epochs(self, np.asarray(idx))

    def decimate(self, rate_hz: float) -> "Truth":
        """The record sampled at ``rate_hz`` (nearest flight epochs, starting at t[0])."""
        if rate_hz <= 0:
            raise ValueError(f"rate_hz: expected > 0, got {rate_hz}")
        dt = np.median(np.diff(self.t)) if len(self.t) > 1 else 1.0
        step = max(1, int(round(1.0 / (rate_hz * dt))))
        return self.at_indices(np.arange(0, len(self.t), step))

    def as_columns(self) -> dict[str, NDArray]:
        """Flat named columns (for tables / CSV / Parquet)."""
        cols = {"t": self.t, "lat_deg": self.lat_deg, "lon_deg": self.lon_deg, "h": self.h,
                "agl": self.agl, "airspeed": self.airspeed}
        for name, arr, comps in [("pos_ecef", self.pos_ecef, "xyz"), ("pos_enu", self.pos_enu, "enu"),
                                 ("vel_enu", self.vel_enu, "enu"), ("q_body_to_enu", self.q_body_to_enu, "xyzw"),
                                 ("euler", self.euler, ("roll", "pitch", "heading")),
                                 ("omega_body", self.omega_body, "pqr"),
                                 ("specific_force_eye_body", self.specific_force_eye_body, "xyz"),
                                 ("specific_force_cg_body", self.specific_force_cg_body, "xyz"),
                                 ("omega_dot_body", self.omega_dot_body, "pqr")]:
            for k, c in enumerate(comps):
                cols[f"{name}_{c}"] = arr[:, k]
        return cols


class NotVisible(IntEnum):
    """Why a satellite/landmark slot has no measurement at an epoch (0 = visible)."""

    VISIBLE = 0
    BELOW_MASK = 1  # below the elevation mask angle
    TERRAIN = 2  # line of sight blocked by terrain
    AIRFRAME = 3  # below the antenna plane (aircraft banked) / behind the camera
    OUT_OF_IMAGE = 4
    TOO_FAR = 5
    TOO_SMALL = 6
    UNHEALTHY = 7
    EXCLUDED = 8  # above the mask and in view, but not tracked (a cap of the GNSS schedule)
    NOT_OBSERVED = 9  # no usable code measurement at this epoch (a recorded file's; a correlogram without a peak)
    NO_EPHEMERIS = 10  # no broadcast record within its validity (2 h of toe) in the navigation file
    NO_SECOND_FREQUENCY = 11  # iono-free ranges asked for, but only one frequency was observed


@dataclass(frozen=True)
class Mount:
    """A sensor on the airframe: lever arm from the CG and orientation.

    lever_arm_body : (3,) m in body axes (x fwd, y right, z down).
    R_sensor_to_body : (3, 3) rotation from the sensor frame to body axes.
    """

    lever_arm_body: NDArray
    R_sensor_to_body: NDArray = field(default_factory=lambda: np.eye(3))


def satellite_ids(system: ArrayLike, prn: ArrayLike) -> NDArray:
    """RINEX 3 satellite identifiers, e.g. ``"G05"``, ``"E12"``, ``"C59"``, of system letters and numbers."""
    return np.array([f"{x}{int(p):02d}" for x, p in zip(np.ravel(system), np.ravel(prn))], dtype="<U3").reshape(
        np.shape(prn))


@dataclass(frozen=True)
class GnssEpochs:
    """GPS observations as the receiver reports them (no truth inside).

    Attributes
    ----------
    t : (T,) s since the approach start.  t_gps : (T,) s since the GPS epoch (1980-01-06),
        or (B..., T) when the trials start at different times (a campaign's sorties).
    prn : (S,) int satellite numbers, one slot per satellite of the constellation.
    sat_pos_ecef : (B..., T, S, 3) m, satellite position at transmit time expressed in
        the ECEF frame of the *receive* time (Earth rotation during flight applied),
        i.e. what the monitor uses directly: rho = |sat_pos_ecef - r| + clock.
    sat_vel_ecef : (B..., T, S, 3) m/s, same frame.
    pseudorange : (B..., T, S) m, after satellite clock / modelled atmosphere removed;
        NaN where ``visible`` is False.
    range_rate : (B..., T, S) m/s, NaN where not visible.
    sigma : (B..., T, S) m, the 1-sigma the monitor is told (seed eq. 27, or the DFMC C_int).
    visible : (B..., T, S) bool.  reason : (B..., T, S) int8 :class:`NotVisible` codes.
    antenna : the GNSS antenna mount (lever arm from the CG).
    system : (S,) RINEX 3 system letter of each slot ('G', 'E', 'C'); omitted, every slot is GPS.
    """

    t: NDArray = epoch_array(batched=False)
    t_gps: NDArray = epoch_array()
    prn: NDArray = field()
    sat_pos_ecef: NDArray = epoch_array(2)
    sat_vel_ecef: NDArray = epoch_array(2)
    pseudorange: NDArray = epoch_array(1)
    range_rate: NDArray = epoch_array(1)
    sigma: NDArray = epoch_array(1)
    visible: NDArray = epoch_array(1)
    reason: NDArray = epoch_array(1)
    antenna: Mount = field()
    system: NDArray | None = None

    def __post_init__(self) -> None:
        if self.system is None:  # a GPS-only record (every reader written before other systems existed)
            object.__setattr__(self, "system", np.full(np.shape(self.prn), "G"))

    @property
    def sat_id(self) -> NDArray:
        """RINEX 3 satellite identifiers ``(S,)`` of the slots, e.g. ``"G05"``, ``"E12"``."""
        return satellite_ids(self.system, self.prn)


@dataclass(frozen=True)
class GnssTruth:
    """Truth side of the GNSS synthesis (evaluation only; monitors never see it).

    antenna_pos_ecef : (T, 3) true antenna position.  geometric_range : (T, S).
    clock_bias : (B..., T) m, receiver clock bias.  noise : (B..., T, S) m, the drawn
    nominal error.  fault_bias : (B..., T, S) m, injected fault.  faulty : (B..., T, S) bool.
    elevation, azimuth : (T, S) rad, true geometry ((B..., T, S) when the trials start at
    different times, as is geometric_range).
    system_offset : (B..., S) m, the constant inter-system clock offset in each slot's pseudorange
    (0 on the first constellation's); None with one constellation.
    """

    antenna_pos_ecef: NDArray = epoch_array(1)
    geometric_range: NDArray = epoch_array(1)
    clock_bias: NDArray = epoch_array()
    noise: NDArray = epoch_array(1)
    fault_bias: NDArray = epoch_array(1)
    faulty: NDArray = epoch_array(1)
    elevation: NDArray = epoch_array(1)
    azimuth: NDArray = epoch_array(1)
    system_offset: NDArray | None = None


@dataclass(frozen=True)
class CorrelatorEpochs:
    """Correlator outputs per satellite and epoch on a code-delay grid (no truth; docs/design/dpe.md §2, §8).

    Delays in metres. Satellite k's grid is ``rho_ref[..., k] + delay0_m + j·delay_step_m``,
    j < M, with rho_ref the channel's scalar pseudorange rounded to the grid (corrected like
    ``GnssEpochs.pseudorange``). ``stat`` holds Σ_b |y_b(δ_j)|² (``stat_kind`` "pow") or
    (1/N_b)·Σ_b |y_b(δ_j)| ("mag"), y normalised so the noise has variance R_B(0) and the
    direct signal peak is A·R_B(0), A² = (C/N0)·T.

    t : (T,) s.  prn : (S,).  sat_pos_ecef : (B..., T, S, 3) m (as GnssEpochs).
    rho_ref : (B..., T, S) m, NaN where not tracked.  stat : (B..., T, S, M) float32.
    cn0_est_dbhz : (B..., T, S) the receiver's C/N0 estimate from the correlogram peak.
    visible : (B..., T, S) bool.  delay0_m, delay_step_m, coherent_s, n_noncoherent,
    bandwidth_chips (one-sided, in chip rates), stat_kind : constants.  antenna : the mount.
    """

    t: NDArray = epoch_array(batched=False)
    prn: NDArray = field()
    sat_pos_ecef: NDArray = epoch_array(2)
    rho_ref: NDArray = epoch_array(1)
    stat: NDArray = epoch_array(2)
    cn0_est_dbhz: NDArray = epoch_array(1)
    visible: NDArray = epoch_array(1)
    delay0_m: float = field()
    delay_step_m: float = field()
    coherent_s: float = field()
    n_noncoherent: int = field()
    bandwidth_chips: float = field()
    stat_kind: str = field()
    antenna: Mount = field()


@dataclass(frozen=True)
class CorrelatorTruth:
    """Truth side of the correlators (evaluation and tests only; no monitor imports it).

    delay_m : (B..., T, S) true code delay of the direct signal minus rho_ref (m).
    sis_m : (B..., T, S) signal-in-space error inside it.  fault_m : (B..., T, S) fault bias.
    cn0_dbhz : (B..., T, S) true C/N0.  echo_delay_m, echo_amplitude : (B..., T, S) the ground
    echo's excess delay (m) and relative amplitude (0 without one).
    """

    delay_m: NDArray = epoch_array(1)
    sis_m: NDArray = epoch_array(1)
    fault_m: NDArray = epoch_array(1)
    cn0_dbhz: NDArray = epoch_array(1)
    echo_delay_m: NDArray = epoch_array(1)
    echo_amplitude: NDArray = epoch_array(1)


@dataclass(frozen=True)
class VisionEpochs:
    """Camera landmark detections as the vision front end reports them (no truth).

    Attributes
    ----------
    t : (T,) s.  landmark_id : (L,) str.
    landmark_pos_ecef : (B..., L, 3) m, *surveyed* landmark positions (with survey error,
        drawn per trial; a monitor call takes one set, i.e. (L, 3) broadcast over trials).
    pixel_uv : (B..., T, L, 2) px, detected pixel coordinates (NaN where not detected).
    detected : (B..., T, L) bool.  reason : (B..., T, L) int8 :class:`NotVisible` codes.
    sigma_px : (B..., T, L) px, detection sigma the monitor is told.
    K : (3, 3) camera intrinsic matrix (pinhole; distortion already removed).
    camera : the camera mount (lever arm, R_cam_to_body; camera axes x right, y down, z forward).
    q_body_to_enu_ref : (B..., T, 4) the navigation attitude reference (with its errors).
    attitude_sigma : (3,) rad, 1-sigma of the attitude reference per axis (roll, pitch, yaw).
    dither_sigma : (3,) rad, rms of the camera's dithering on its mount per camera axis
        (x: pitch, y: yaw, z: roll) — its published statistics, not its realisation.
    """

    t: NDArray = epoch_array(batched=False)
    landmark_id: NDArray = field()
    landmark_pos_ecef: NDArray = field()
    pixel_uv: NDArray = epoch_array(2)
    detected: NDArray = epoch_array(1)
    reason: NDArray = epoch_array(1)
    sigma_px: NDArray = epoch_array(1)
    K: NDArray = field()
    camera: Mount = field()
    q_body_to_enu_ref: NDArray = epoch_array(1)
    attitude_sigma: NDArray = field()
    dither_sigma: NDArray = field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True)
class FeatureTracks:
    """Tracked unsurveyed ground features at the vision epochs (:mod:`testbed.sensors.vision.features`).

    t : (T,) s.  ids : (T, W) int, the scene points in view (−1: padding), the same for every trial.
    uv : (B, T, W, 2) px, reported pixels (NaN on padding).  sigma_px : the pixel noise 1σ per axis.
    K : (3, 3) intrinsics.  camera : the mount (lever arm, R_cam_to_body).
    (W is a block's widest epoch: blocks of a flight may differ in it, so they are not joined.)
    """

    t: NDArray = epoch_array(batched=False)
    ids: NDArray = epoch_array(1, batched=False)
    uv: NDArray = epoch_array(2)
    sigma_px: float = field()
    K: NDArray = field()
    camera: Mount = field()


@dataclass(frozen=True)
class ImuSamples:
    """What the IMU reports (no truth): increments over each interval ending at ``t``.

    t : (K,) s, end of each interval.  dtheta : (B..., K, 3) rad, gyro angle increments
    (body axes).  dvel : (B..., K, 3) m/s, accelerometer velocity increments (body axes).
    dt : interval, s.  lever_arm_body : (3,) m, IMU position from the CG.
    earth_rotation : whether the increments include the Earth's rate (the mechanisation must match).
    """

    t: NDArray = epoch_array(batched=False)
    dtheta: NDArray = epoch_array(1)
    dvel: NDArray = epoch_array(1)
    dt: float = field()
    lever_arm_body: NDArray = field()
    earth_rotation: bool = field()
    figures: dict = field(default_factory=dict)  # the grade's published error figures (ImuSettings.figures)


@dataclass(frozen=True)
class NavInit:
    """The alignment pseudo-sensor (docs/design/nav-filter.md §4): an initial navigation state with its published 1σ.

    t : start time (s).  C : (B..., 3, 3) body → world.  v, p : (B..., 3) world frame, IMU point.
    clock_bias, clock_drift : (B...) m, m/s.  sigma : (17,) 1σ of position, velocity, attitude
    (roll/pitch/heading about the world axes), accelerometer and gyro biases, clock bias and drift.
    """

    t: float
    C: NDArray
    v: NDArray
    p: NDArray
    clock_bias: NDArray
    clock_drift: NDArray
    sigma: NDArray


@dataclass(frozen=True)
class ImuTruth:
    """The IMU's truth (evaluation only): error-free increments (K, 3), biases (B..., K, 3) in
    force over each interval, the increments the injected faults added (K, 3; zero without),
    scale-factor errors (B..., 3)."""

    t: NDArray = epoch_array(batched=False)
    dtheta: NDArray = epoch_array(1)
    dvel: NDArray = epoch_array(1)
    gyro_bias: NDArray = epoch_array(1)
    accel_bias: NDArray = epoch_array(1)
    fault_dtheta: NDArray = epoch_array(1)
    fault_dvel: NDArray = epoch_array(1)
    gyro_scale: NDArray = field()
    accel_scale: NDArray = field()


def one_landmark_survey(vision, monitor: str) -> NDArray:
    """``vision.landmark_pos_ecef`` as the one (L, 3) surveyed set a monitor call takes.

    ``sample_vision`` draws a survey per trial ((B, L, 3)); a monitor call works on one
    survey (campaigns draw one per block), so anything else is a clear error, not a
    broadcast failure deep inside the monitor.
    """
    p = np.asarray(vision.landmark_pos_ecef, float)
    if p.ndim != 2 or p.shape[-1] != 3:
        raise ValueError(f"{monitor}: vision.landmark_pos_ecef has shape {p.shape}; expected one surveyed set "
                         f"(L, 3) per call (a survey per trial: call the monitor per trial or per block of "
                         f"trials sharing a survey, as campaigns do)")
    return p


@dataclass(frozen=True)
class MonitorOutput:
    """What an integrity monitor returns per epoch (batched).

    Attributes
    ----------
    t : (T,) s.
    pos_enu : (B..., T, 3) m, estimated position in the approach world frame.
    clock : (B..., T) m, estimated receiver clock bias.
    hpl, vpl : (B..., T) m, protection levels (NaN when unavailable).
    test_stat, threshold : (B..., T) the detection statistic and its threshold
        (same units, e.g. SSE vs chi-square quantile).
    alert : (B..., T) bool, detection (test_stat > threshold).
    available : (B..., T, K) bool, per service level in ``service_levels`` order.
    service_levels : (K,) names.
    n_used : (B..., T) int, measurements used.
    excluded : (B..., T) int, index of an excluded measurement, -1 if none.
    reason : (B..., T) int8 code; 0 = ok, else an index into ``reasons``.
    reasons : tuple of the reason texts (index 0 is "ok").
    diagnostics : the monitor's typed :class:`Diagnostics` record (slopes, residuals,
        DOP...) for plots and tests; never state.
    fde : what fault exclusion did (:class:`testbed.integrity.fde.FdeRecord`), None when the
        monitor ran without FDE. With FDE, ``alert`` is an alert no exclusion cleared, and
        the position, test and PLs of an excluded epoch are the reduced solve's.
    dimensions : ("H", "V"), or ("V",) for a vertical-only monitor (HPL NaN by design).
    """

    name: str
    t: NDArray = epoch_array(batched=False)
    pos_enu: NDArray = epoch_array(1)
    clock: NDArray = epoch_array()
    hpl: NDArray = epoch_array()
    vpl: NDArray = epoch_array()
    test_stat: NDArray = epoch_array()
    threshold: NDArray = epoch_array()
    alert: NDArray = epoch_array()
    available: NDArray = epoch_array(1)
    service_levels: tuple[str, ...]
    n_used: NDArray = epoch_array()
    excluded: NDArray = epoch_array()
    reason: NDArray = epoch_array()
    reasons: tuple[str, ...]
    diagnostics: Diagnostics | None = None
    fde: Diagnostics | None = None
    #: the position dimensions the protection levels bound: ("H", "V"), or ("V",) for a
    #: vertical-only monitor (DPE), whose misleading information is counted on V alone
    dimensions: tuple[str, ...] = ("H", "V")

    @property
    def detected(self) -> NDArray:
        """(B..., T) bool: the fault test failed (an alert, or an alert FDE cleared by an exclusion)."""
        return self.alert if self.fde is None else self.fde.detected

    def own_epoch_columns(self, taken: Iterable[str] = ()) -> dict[str, NDArray]:
        """The monitor's own per-epoch columns (its diagnostics' :meth:`Diagnostics.epoch_columns`: ARAIM's EMT,
        σ_acc and fault modes, ...), (B..., T) each; ValueError if one would rename a column of ``taken`` (the
        table's own)."""
        own = {} if self.diagnostics is None else self.diagnostics.epoch_columns()
        clash = sorted(set(own) & set(taken))
        if clash:
            raise ValueError(f"monitor {self.name}: its own epoch columns {clash} clash with the table's")
        return {k: np.asarray(v) for k, v in own.items()}
