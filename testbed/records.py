"""The records that flow between the rooms: truth, observations, monitor outputs.

Each record is a frozen dataclass of numpy arrays with batch axes first and
components last. Observation records carry no truth: anything a monitor must
not see lives in the matching ``*Truth`` record, which only evaluation reads.

Shapes use: T epochs, S satellite slots, L landmarks, B leading batch (trial)
axes (zero or more). Missing measurements are NaN *and* masked out.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray


def _take_epochs(rec, idx):
    """Return a copy of ``rec`` with every epoch-indexed array sliced by ``idx``.

    Arrays whose axis ``epoch_axis`` matches ``len(rec.t)`` are sliced;
    per-record constants (prn, landmark ids, frames) are kept.
    """
    n = len(rec.t)
    out = {}
    for f in fields(rec):
        v = getattr(rec, f.name)
        if isinstance(v, np.ndarray) and v.ndim >= 1 and f.name in rec._epoch_fields():
            axis = rec._epoch_axis(v)
            out[f.name] = np.take(v, idx, axis=axis) if v.shape[axis] == n else v
        else:
            out[f.name] = v
    return replace(rec, **out)


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
    specific_force_body : (T, 3) m/s², accelerometer truth at the CG.
    agl : (T,) m, height above the terrain model.
    airspeed : (T,) m/s, true airspeed.
    frame_origin : (3,) lat_deg, lon_deg, h of the world frame's origin.
    """

    t: NDArray
    pos_ecef: NDArray
    lat_deg: NDArray
    lon_deg: NDArray
    h: NDArray
    pos_enu: NDArray
    vel_enu: NDArray
    q_body_to_enu: NDArray
    euler: NDArray
    omega_body: NDArray
    specific_force_body: NDArray
    agl: NDArray
    airspeed: NDArray
    frame_origin: NDArray

    @staticmethod
    def _epoch_fields() -> set[str]:
        return {f.name for f in fields(Truth)} - {"frame_origin"}

    @staticmethod
    def _epoch_axis(v: NDArray) -> int:
        return 0

    def at_indices(self, idx: NDArray) -> "Truth":
        """The record at the given epoch indices (e.g. decimated to a sensor rate)."""
        return _take_epochs(self, np.asarray(idx))

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
                                 ("specific_force_body", self.specific_force_body, "xyz")]:
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


@dataclass(frozen=True)
class Mount:
    """A sensor on the airframe: lever arm from the CG and orientation.

    lever_arm_body : (3,) m in body axes (x fwd, y right, z down).
    R_sensor_to_body : (3, 3) rotation from the sensor frame to body axes.
    """

    lever_arm_body: NDArray
    R_sensor_to_body: NDArray = field(default_factory=lambda: np.eye(3))


@dataclass(frozen=True)
class GnssEpochs:
    """GPS observations as the receiver reports them (no truth inside).

    Attributes
    ----------
    t : (T,) s since the approach start.  t_gps : (T,) s since the GPS epoch (1980-01-06).
    prn : (S,) int satellite numbers, one slot per satellite of the constellation.
    sat_pos_ecef : (B..., T, S, 3) m, satellite position at transmit time expressed in
        the ECEF frame of the *receive* time (Earth rotation during flight applied),
        i.e. what the monitor uses directly: rho = |sat_pos_ecef - r| + clock.
    sat_vel_ecef : (B..., T, S, 3) m/s, same frame.
    pseudorange : (B..., T, S) m, after satellite clock / modelled atmosphere removed;
        NaN where ``visible`` is False.
    range_rate : (B..., T, S) m/s, NaN where not visible.
    sigma : (B..., T, S) m, the 1-sigma the monitor is told (seed eq. 27).
    visible : (B..., T, S) bool.  reason : (B..., T, S) int8 :class:`NotVisible` codes.
    antenna : the GNSS antenna mount (lever arm from the CG).
    """

    t: NDArray
    t_gps: NDArray
    prn: NDArray
    sat_pos_ecef: NDArray
    sat_vel_ecef: NDArray
    pseudorange: NDArray
    range_rate: NDArray
    sigma: NDArray
    visible: NDArray
    reason: NDArray
    antenna: Mount


@dataclass(frozen=True)
class GnssTruth:
    """Truth side of the GNSS synthesis (evaluation only; monitors never see it).

    antenna_pos_ecef : (T, 3) true antenna position.  geometric_range : (T, S).
    clock_bias : (B..., T) m, receiver clock bias.  noise : (B..., T, S) m, the drawn
    nominal error.  fault_bias : (B..., T, S) m, injected fault.  faulty : (B..., T, S) bool.
    elevation, azimuth : (T, S) rad, true geometry.
    """

    antenna_pos_ecef: NDArray
    geometric_range: NDArray
    clock_bias: NDArray
    noise: NDArray
    fault_bias: NDArray
    faulty: NDArray
    elevation: NDArray
    azimuth: NDArray


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
    """

    t: NDArray
    landmark_id: NDArray
    landmark_pos_ecef: NDArray
    pixel_uv: NDArray
    detected: NDArray
    reason: NDArray
    sigma_px: NDArray
    K: NDArray
    camera: Mount
    q_body_to_enu_ref: NDArray
    attitude_sigma: NDArray


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
    diagnostics : extra arrays (slopes, residuals, DOP...) for plots and tests.
    """

    name: str
    t: NDArray
    pos_enu: NDArray
    clock: NDArray
    hpl: NDArray
    vpl: NDArray
    test_stat: NDArray
    threshold: NDArray
    alert: NDArray
    available: NDArray
    service_levels: tuple[str, ...]
    n_used: NDArray
    excluded: NDArray
    reason: NDArray
    reasons: tuple[str, ...]
    diagnostics: dict = field(default_factory=dict)
