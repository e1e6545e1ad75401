"""Fault schedules: what goes wrong, when, on which satellite or landmark.

A schedule is a list of fault models (a tagged union on ``kind``), read from
the ``[[faults]]`` tables of an approach file or built in code. Faults are
applied *after* nominal noise, and the truth side of every sensor output
records them, so evaluation can tell faulty measurements apart.

GNSS faults are turned into a bias array here (:func:`gnss_fault_bias`);
vision faults are applied by the vision sensor, which owns the geometry they
perturb, using :func:`active` for the time window; IMU faults into the angle and
velocity increments they add over each IMU interval (:func:`imu_fault_increments`),
which the IMU synthesis adds to its measured increments.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, ClassVar, Literal, Union

import numpy as np
from numpy.typing import NDArray
from pydantic import AfterValidator, BeforeValidator, Field, model_validator

from testbed.frames import DEG_PER_H
from testbed.schema import StrictModel

def _some_satellite(v):
    if isinstance(v, list) and not v:
        raise ValueError("expected a PRN, a list of at least 1 PRN, or 'random' (got an empty list)")
    return v


SatSelector = Annotated[Union[int, list[int], Literal["random"]], AfterValidator(_some_satellite)]

#: A satellite in the RINEX 3 spelling: system letter and two-digit PRN.
SAT_ID = re.compile(r"^[GEC]\d{2}$")
#: ``constellation_bias`` system names and their RINEX 3 letters (the names of ``[gnss] constellations``).
SYSTEM_LETTERS = {"gps": "G", "galileo": "E", "beidou": "C"}


def _sat_ids(v):
    ids = [v] if isinstance(v, str) else list(v)
    if not ids:
        raise ValueError("expected a satellite such as 'E11' or a list of at least 1 (got an empty list)")
    bad = [i for i in ids if not SAT_ID.match(i) or int(i[1:]) == 0]
    if bad:
        raise ValueError(f"expected satellites spelt as in RINEX 3, a system letter G, E or C and a two-digit PRN "
                         f"(e.g. 'G05', 'E11', 'C59'), got {bad[0]!r}")
    return v


SatIds = Annotated[Union[str, list[str]], AfterValidator(_sat_ids)]


class _Timed(StrictModel):
    onset_s: float = Field(0.0, ge=0.0, le=7200.0, description="fault starts at this time since approach start (s)")
    end_s: float | None = Field(None, le=7200.0, description="fault ends (exclusive); None = to the end")

    @model_validator(mode="after")
    def _window(self):
        if self.end_s is not None and self.end_s <= self.onset_s:
            raise ValueError(f"end_s ({self.end_s}) must be after onset_s ({self.onset_s})")
        return self


class _OnSatellites(_Timed):
    """A fault on chosen satellites: ``prn`` (GPS PRNs, or 'random': any visible satellite) or ``sat`` (RINEX 3
    identifiers of any constellation, e.g. 'E11')."""

    prn: SatSelector = Field("random", description="GPS PRN, list of GPS PRNs, or 'random' (a visible satellite "
                                                   "of any tracked constellation at onset)")
    sat: SatIds | None = Field(None, description="satellite(s) of any constellation in the RINEX 3 spelling "
                                                 "('G05', 'E11', 'C59'), instead of prn")

    @model_validator(mode="after")
    def _one_selector(self):
        if self.sat is not None and "prn" in self.model_fields_set:
            raise ValueError(f"give prn or sat, not both (prn = {self.prn!r}, sat = {self.sat!r})")
        return self

    @property
    def targets(self) -> list[str] | Literal["random"]:
        """The satellites named, in the RINEX 3 spelling, or 'random'."""
        if self.sat is not None:
            return [self.sat] if isinstance(self.sat, str) else list(self.sat)
        if self.prn == "random":
            return "random"
        return [f"G{p:02d}" for p in ([self.prn] if isinstance(self.prn, int) else self.prn)]

    @property
    def target_text(self) -> str:
        """How the approach file names the target (for messages)."""
        return f"sat = {self.sat!r}" if self.sat is not None else f"prn = {self.prn!r}"


class GpsStep(_OnSatellites):
    """A constant pseudorange bias on the selected satellite(s) (of any constellation)."""

    kind: Literal["gps_step"] = Field(..., description="fault kind")
    bias_m: float = Field(..., ge=-1e6, le=1e6, description="pseudorange bias (beyond 1000 km a receiver rejects "
                                                               "the range)")


class GpsRamp(_OnSatellites):
    """A pseudorange error growing linearly from the onset (on satellites of any constellation)."""

    kind: Literal["gps_ramp"] = Field(..., description="fault kind")
    rate_m_s: float = Field(..., ge=-1e4, le=1e4, description="growth rate of the pseudorange error")


class GpsClockRunoff(_OnSatellites):
    """A satellite clock run-off: error = drift·τ + ½·accel·τ², τ = t − onset (any constellation)."""

    kind: Literal["gps_clock"] = Field(..., description="fault kind")
    drift_m_s: float = Field(0.0, ge=-1e4, le=1e4, description="clock error rate at the onset")
    accel_m_s2: float = Field(0.05, ge=-1e3, le=1e3, description="clock error acceleration")


class _OnSystem(_Timed):
    """A fault on every satellite of one constellation."""

    system: Literal["gps", "galileo", "beidou"] = Field(..., description="the constellation hit")

    @property
    def target_text(self) -> str:
        return f"system = {self.system!r}"


class ConstellationBias(_OnSystem):
    """A constellation-wide fault: the same error on every satellite of one system, bias + rate·τ, τ = t − onset
    (a wrong broadcast system time offset or a ground-segment fault)."""

    kind: Literal["constellation_bias"] = Field(..., description="fault kind")
    bias_m: float = Field(0.0, ge=-1e6, le=1e6, description="error common to its satellites at the onset (m)")
    rate_m_s: float = Field(0.0, ge=-1e4, le=1e4, description="growth rate of the common error (m/s)")

    @model_validator(mode="after")
    def _something(self):
        if self.bias_m == 0.0 and self.rate_m_s == 0.0:
            raise ValueError("expected a non-zero bias_m or rate_m_s (a fault that adds nothing)")
        return self


#: one milliarcsecond in radians (a frame rotation's unit: 1 mas turns a GPS orbit's 26 560 km by 0.13 m)
MAS_RAD = np.pi / (180.0 * 3600.0 * 1000.0)
_Translation = Annotated[float, Field(ge=-1e5, le=1e5)]
_RotationMas = Annotated[float, Field(ge=-1e6, le=1e6)]


class ConstellationOrbit(_OnSystem):
    """A constellation-wide orbit (frame) error: every satellite of one system stands at R·s + d, not at the
    broadcast position s — a common ECEF translation d (``translation_m``) and a small rotation R of the
    constellation's frame about the Earth's centre (``rotation_mas``, the rotation vector). Its range error,
    |R·s + d − x| − |s − x| at the antenna x (≈ u·(d + θ × s) along each line of sight u), differs from satellite
    to satellite: the system's clock absorbs only its common part. For a user, a rotation θ looks like the
    translation θ × x (u·(θ × (s − x)) = 0)."""

    kind: Literal["constellation_orbit"] = Field(..., description="fault kind")
    translation_m: tuple[_Translation, _Translation, _Translation] = Field(
        (0.0, 0.0, 0.0), description="common displacement of the system's satellites, ECEF X, Y, Z (m)")
    rotation_mas: tuple[_RotationMas, _RotationMas, _RotationMas] = Field(
        (0.0, 0.0, 0.0), description="rotation of the system's frame about ECEF X, Y, Z (milliarcseconds; 1 mas "
                                     "moves a satellite 26 560 km from the Earth's centre by 0.13 m)")

    @model_validator(mode="after")
    def _something(self):
        if not any(self.translation_m) and not any(self.rotation_mas):
            raise ValueError("expected a non-zero translation_m or rotation_mas (a fault that moves nothing)")
        return self


def rotation_matrix(rotation_vector: NDArray) -> NDArray:
    """(3, 3) rotation by |v| radians about v/|v| (Rodrigues), the identity for v = 0."""
    v = np.asarray(rotation_vector, float)
    a = float(np.linalg.norm(v))
    if a == 0.0:
        return np.eye(3)
    k = v / a
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(a) * K + (1.0 - np.cos(a)) * (K @ K)


def orbit_range_error(fault: ConstellationOrbit, sat_pos_ecef: NDArray, ant_pos_ecef: NDArray) -> NDArray:
    """Range error (m, (..., T, S)) of satellites at ``sat_pos_ecef`` (..., T, S, 3) seen from ``ant_pos_ecef``
    (T, 3) when they really stand at R·s + d: the exact difference of the two distances (0 where a position is
    not finite)."""
    s = np.asarray(sat_pos_ecef, float)
    x = np.asarray(ant_pos_ecef, float)[..., None, :]
    moved = s @ rotation_matrix(np.asarray(fault.rotation_mas) * MAS_RAD).T + np.asarray(fault.translation_m)
    err = np.linalg.norm(moved - x, axis=-1) - np.linalg.norm(s - x, axis=-1)
    return np.where(np.isfinite(err), err, 0.0)


class PixelBias(_Timed):
    """A bias on one landmark's detected pixel (polar: magnitude, direction in the image)."""

    kind: Literal["pixel_bias"] = Field(..., description="fault kind")
    landmark: str | Literal["random"] = Field("random", description="landmark id, or 'random' (one detected "
                                                                     "at onset, drawn per trial)")
    magnitude_px: float = Field(..., ge=0.0, le=1e4, description="bias magnitude")
    angle_deg: float = Field(0.0, ge=-360.0, le=360.0, description="bias direction in the image, from the u "
                                                                   "axis (right) towards v (down)")


class LandmarkMoved(_Timed):
    """The real landmark stands at surveyed + delta (the survey says otherwise)."""

    kind: Literal["landmark_moved"] = Field(..., description="fault kind")
    landmark: str | Literal["random"] = Field("random", description="landmark id, or 'random' (one detected "
                                                                     "at onset, drawn per trial)")
    delta_enu_m: tuple[Annotated[float, Field(ge=-1e4, le=1e4)], Annotated[float, Field(ge=-1e4, le=1e4)],
                       Annotated[float, Field(ge=-1e4, le=1e4)]] = Field(
        ..., description="where the real landmark stands relative to its surveyed position, ENU")


class Misassociation(_Timed):
    """Two landmarks' detections are swapped by the matcher."""

    kind: Literal["misassociation"] = Field(..., description="fault kind")
    landmarks: tuple[str, str] = Field(..., description="ids of the two landmarks whose detections the matcher "
                                                         "swaps")

    @model_validator(mode="after")
    def _two(self):
        if self.landmarks[0] == self.landmarks[1]:
            raise ValueError(f"landmarks: expected two different landmarks, got {list(self.landmarks)}")
        return self


#: the IMU's body axes (FRD: x forward, y right, z down), as an IMU fault's ``axis`` names them
BODY_AXES = ("x", "y", "z")


def _body_vector(limit: float, unit: str):
    """A BeforeValidator: a number (along ``axis``) or a 3-vector of numbers (body FRD), each within ±``limit``."""

    def check(v):
        def number(x) -> bool:
            return isinstance(x, (int, float)) and not isinstance(x, bool)

        if number(v):
            parts = [v]
        elif isinstance(v, (list, tuple)) and len(v) == 3 and all(number(x) for x in v):
            parts = list(v)
        else:
            raise ValueError(f"expected a number (along axis = 'x', 'y' or 'z') or a 3-vector [x, y, z] of numbers "
                             f"(body axes: x forward, y right, z down), in {unit}")
        if any(not math.isfinite(x) or abs(x) > limit for x in parts):
            raise ValueError(f"expected finite values within ±{limit:g} {unit} per axis")
        return float(v) if number(v) else tuple(float(x) for x in v)

    return BeforeValidator(check)


def _body_field(limit: float, unit: str, default, description: str):
    """A field taking a number or a 3-vector (docs show the per-axis bound)."""
    one = Annotated[float, Field(ge=-limit, le=limit)]
    return Annotated[Union[one, tuple[one, one, one]], _body_vector(limit, unit)], Field(default,
                                                                                         description=description)


_ACCEL_BIAS, _ACCEL_BIAS_FIELD = _body_field(
    200.0, "m/s²", 0.0, "accelerometer bias from the onset, m/s²: a number along `axis`, or a 3-vector [x, y, z] in "
                        "body axes (FRD) without `axis`; within ±200 m/s² (20 g: beyond an aircraft accelerometer's "
                        "range) per axis")
_ACCEL_RATE, _ACCEL_RATE_FIELD = _body_field(
    20.0, "m/s³", 0.0, "growth of the accelerometer bias after the onset, m/s³ (bias + rate·τ, τ = t − onset): a "
                       "number along `axis`, or a 3-vector without it; within ±20 m/s³ per axis")
_GYRO_BIAS, _GYRO_BIAS_FIELD = _body_field(
    3.6e6, "deg/h", 0.0, "gyro bias from the onset, deg/h (1 deg/h = 4.85e-6 rad/s; a tactical gyro's own bias is "
                         "about 1 deg/h): a number along `axis`, or a 3-vector [x, y, z] in body axes (FRD) without "
                         "`axis`; within ±3.6e6 deg/h (1000 deg/s) per axis")
_GYRO_RATE, _GYRO_RATE_FIELD = _body_field(
    3.6e4, "deg/h/s", 0.0, "growth of the gyro bias after the onset, deg/h per second (bias + rate·τ, τ = t − onset): "
                           "a number along `axis`, or a 3-vector without it; within ±36000 deg/h/s (10 deg/s²) per "
                           "axis")


class _ImuBias(_Timed):
    """A bias on one IMU sensor triad from the onset: bias + rate·τ (τ = t − onset), on one body axis or as a
    3-vector; the increments of each interval carry its integral over the part of the interval inside the fault's
    window (:func:`imu_fault_increments`)."""

    #: the sensor hit ("gyro": the angle increments, "accel": the velocity increments), the names of the bias and
    #: rate keys and their units as the file gives them, and the SI value (rad or m) of one of the file's units
    sensor: ClassVar[str]
    bias_key: ClassVar[str]
    rate_key: ClassVar[str]
    bias_unit: ClassVar[str]
    rate_unit: ClassVar[str]
    to_si: ClassVar[float] = 1.0

    axis: Literal["x", "y", "z"] | None = Field(
        None, description="body axis (FRD: x forward, y right, z down) the bias and rate act along when they are "
                          "numbers; unset with 3-vectors")

    @model_validator(mode="after")
    def _shape(self):
        values = {k: getattr(self, k) for k in (self.bias_key, self.rate_key)}
        vectors = [k for k, v in values.items() if isinstance(v, tuple)]
        scalars = [k for k, v in values.items() if not isinstance(v, tuple) and v != 0.0]
        if self.axis is not None and vectors:
            k = vectors[0]
            raise ValueError(f"[{k}] a 3-vector takes no axis (axis = {self.axis!r}): give a number along the axis, "
                             f"or remove axis (got {list(values[k])})")
        if self.axis is None and scalars:
            k = scalars[0]
            raise ValueError(f"[{k}] a number needs axis = 'x', 'y' or 'z' (body FRD: x forward, y right, z down), "
                             f"or give a 3-vector [x, y, z] (got {values[k]!r})")
        if not any(np.any(np.asarray(v) != 0.0) for v in values.values()):
            raise ValueError(f"[{self.bias_key}] expected a non-zero {self.bias_key} or {self.rate_key} (a fault that "
                             f"adds nothing) (got {values[self.bias_key]!r})")
        return self

    def _si(self, key: str) -> NDArray:
        v = getattr(self, key)
        out = np.zeros(3)
        if isinstance(v, tuple):
            out[:] = v
        elif self.axis is not None:
            out[BODY_AXES.index(self.axis)] = v
        return out * self.to_si

    @property
    def bias_si(self) -> NDArray:
        """(3,) the bias from the onset, body axes, SI (rad/s or m/s²)."""
        return self._si(self.bias_key)

    @property
    def rate_si(self) -> NDArray:
        """(3,) the bias's growth per second after the onset, body axes, SI (rad/s² or m/s³)."""
        return self._si(self.rate_key)

    @property
    def size_text(self) -> str:
        """The bias and rate as the file gives them (for messages)."""
        def text(key: str, unit: str) -> str:
            v = getattr(self, key)
            return (f"[{', '.join(f'{c:g}' for c in v)}] {unit}" if isinstance(v, tuple)
                    else f"{v:+g} {unit} along {self.axis}")

        parts = [text(self.bias_key, self.bias_unit)]
        if np.any(np.asarray(getattr(self, self.rate_key)) != 0.0):
            parts.append("growing by " + text(self.rate_key, self.rate_unit))
        return ", ".join(parts) + " (body FRD)"


class ImuAccelBias(_ImuBias):
    """An accelerometer fault: a bias step (``bias_m_s2``) and ramp (``rate_m_s3``) from the onset, on one body
    axis or as a 3-vector; each velocity increment carries the bias integrated over the part of its interval inside
    the fault's window."""

    sensor: ClassVar[str] = "accel"
    bias_key: ClassVar[str] = "bias_m_s2"
    rate_key: ClassVar[str] = "rate_m_s3"
    bias_unit: ClassVar[str] = "m/s²"
    rate_unit: ClassVar[str] = "m/s³"

    kind: Literal["imu_accel_bias"] = Field(..., description="fault kind")
    bias_m_s2: _ACCEL_BIAS = _ACCEL_BIAS_FIELD
    rate_m_s3: _ACCEL_RATE = _ACCEL_RATE_FIELD


class ImuGyroBias(_ImuBias):
    """A gyro fault: a bias step (``bias_deg_h``) and ramp (``rate_deg_h_s``) from the onset, in degrees per hour,
    on one body axis or as a 3-vector; each angle increment carries the bias integrated over the part of its
    interval inside the fault's window."""

    sensor: ClassVar[str] = "gyro"
    bias_key: ClassVar[str] = "bias_deg_h"
    rate_key: ClassVar[str] = "rate_deg_h_s"
    bias_unit: ClassVar[str] = "deg/h"
    rate_unit: ClassVar[str] = "deg/h/s"
    to_si: ClassVar[float] = DEG_PER_H

    kind: Literal["imu_gyro_bias"] = Field(..., description="fault kind")
    bias_deg_h: _GYRO_BIAS = _GYRO_BIAS_FIELD
    rate_deg_h_s: _GYRO_RATE = _GYRO_RATE_FIELD


Fault = Annotated[Union[GpsStep, GpsRamp, GpsClockRunoff, ConstellationBias, ConstellationOrbit, PixelBias,
                        LandmarkMoved, Misassociation, ImuAccelBias, ImuGyroBias], Field(discriminator="kind")]
GNSS_KINDS = ("gps_step", "gps_ramp", "gps_clock", "constellation_bias", "constellation_orbit")
#: the GNSS kinds that hit every satellite of one system (``system``), not chosen satellites
SYSTEM_KINDS = ("constellation_bias", "constellation_orbit")
VISION_KINDS = ("pixel_bias", "landmark_moved", "misassociation")
IMU_KINDS = ("imu_accel_bias", "imu_gyro_bias")


def active(fault: _Timed, t: NDArray) -> NDArray:
    """Boolean mask ``(T,)``: where the fault is active at times ``t``."""
    t = np.asarray(t, float)
    on = t >= fault.onset_s
    if fault.end_s is not None:
        on &= t < fault.end_s
    return on


def fault_profile(fault: GpsStep | GpsRamp | GpsClockRunoff | ConstellationBias, t: NDArray) -> NDArray:
    """Error added to the faulty pseudorange at times ``t`` ``(T,)``, m (0 when inactive)."""
    tau = np.asarray(t, float) - fault.onset_s
    if isinstance(fault, GpsStep):
        e = np.full_like(tau, fault.bias_m)
    elif isinstance(fault, GpsRamp):
        e = fault.rate_m_s * tau
    elif isinstance(fault, ConstellationBias):
        e = fault.bias_m + fault.rate_m_s * tau
    else:
        e = fault.drift_m_s * tau + 0.5 * fault.accel_m_s2 * tau**2
    return np.where(active(fault, t), e, 0.0)


def satellite_ids(prn: NDArray, system: NDArray | None = None) -> NDArray:
    """RINEX 3 identifiers ``(S,)`` of slots ``prn`` of systems ``system`` (None: all GPS)."""
    prn = np.asarray(prn)
    system = np.full(prn.shape, "G") if system is None else np.asarray(system)
    return np.array([f"{c}{int(p):02d}" for c, p in zip(system, prn)], dtype="<U3")


def named_targets(fault, prn: NDArray, system: NDArray | None = None) -> NDArray:
    """Slot mask ``(S,)`` of the satellites a GNSS fault names (not 'random'); ValueError naming the missing
    ones when a named satellite or system is not tracked."""
    prn = np.asarray(prn)
    system = np.full(prn.shape, "G") if system is None else np.asarray(system)
    if isinstance(fault, _OnSystem):
        hit = system == SYSTEM_LETTERS[fault.system]
        if not hit.any():
            raise ValueError(f"fault {fault.kind}: system {fault.system!r} is not tracked (the constellation has "
                             f"{sorted(set(system.tolist()))})")
        return hit
    ids = satellite_ids(prn, system)
    wanted = fault.targets
    missing = [w for w in wanted if w not in set(ids.tolist())]
    if missing:
        shown = missing if fault.sat is not None else [int(m[1:]) for m in missing]
        raise ValueError(f"fault {fault.kind}: {'satellite' if fault.sat is not None else 'PRN'}(s) {shown} not in "
                         f"the constellation {sorted(set(ids.tolist())) if fault.sat is not None else sorted(prn[system == 'G'].tolist())}")
    return np.isin(ids, wanted)


def select_satellites(fault, t: NDArray, prn: NDArray, visible: NDArray,
                      rng: np.random.Generator, system: NDArray | None = None) -> NDArray:
    """Slot mask ``(S,)`` of the satellites a GNSS fault hits.

    ``visible`` is ``(T, S)``; ``system`` (S,) the slots' system letters (None: all GPS).
    "random" draws one satellite visible at the first active epoch (uniformly, from ``rng``,
    whatever its constellation); if none is visible, none is hit. A constellation fault hits
    every slot of its system.
    """
    prn = np.asarray(prn)
    if getattr(fault, "prn", None) == "random" and getattr(fault, "sat", None) is None:
        on = np.flatnonzero(active(fault, t))
        hit = np.zeros(prn.shape, bool)
        if on.size == 0:
            return hit
        cands = np.flatnonzero(visible[on[0]])
        if cands.size:
            hit[rng.choice(cands)] = True
        return hit
    return named_targets(fault, prn, system)


def gnss_fault_bias(faults: list, t: NDArray, prn: NDArray, visible: NDArray,
                    rng: np.random.Generator, system: NDArray | None = None, sat_pos_ecef: NDArray | None = None,
                    ant_pos_ecef: NDArray | None = None) -> NDArray:
    """Total injected pseudorange error ``(T, S)`` from the GNSS faults of a schedule.

    Non-GNSS faults are ignored. ``rng`` is used only for "random" selections;
    each fault gets its own child generator (spawned in schedule order), so a
    fault's choice does not depend on whether another fault's onset is inside
    ``t`` yet: the result is stable when ``t`` grows (the closed loop relies on it).
    ``system`` (S,): the slots' system letters (None: all GPS). ``sat_pos_ecef`` (T, S, 3) and
    ``ant_pos_ecef`` (T, 3): the geometry an orbit fault (:class:`ConstellationOrbit`) projects on.
    """
    t = np.asarray(t, float)
    bias = np.zeros((t.size, len(prn)))
    for f, g in zip(faults, rng.spawn(len(faults))):
        if f.kind not in GNSS_KINDS:
            continue
        hit = select_satellites(f, t, prn, np.asarray(visible, bool), g, system)
        if isinstance(f, ConstellationOrbit):
            if sat_pos_ecef is None or ant_pos_ecef is None:
                raise ValueError(f"fault {f.kind}: needs the satellites' and the antenna's positions")
            err = orbit_range_error(f, np.asarray(sat_pos_ecef)[:, hit], ant_pos_ecef)
            bias[:, hit] += np.where(active(f, t)[:, None], err, 0.0)
        else:
            bias[:, hit] += fault_profile(f, t)[:, None]
    return bias


def imu_fault_overlap(fault: _ImuBias, t: NDArray, dt: float) -> tuple[NDArray, NDArray]:
    """Where the fault's window [onset, end) meets each IMU interval (t − dt, t]: the times since the onset
    (τ₁, τ₂) (K,) of the shared part's ends, τ₁ = τ₂ where they do not meet."""
    t = np.asarray(t, float)
    lo = np.maximum(t - dt, fault.onset_s)
    hi = t if fault.end_s is None else np.minimum(t, fault.end_s)
    hi = np.maximum(hi, lo)
    return lo - fault.onset_s, hi - fault.onset_s


def imu_fault_increments(faults: list, t: NDArray, dt: float) -> tuple[NDArray, NDArray]:
    """The (Δθ, Δv) (K, 3) the IMU faults of a schedule add to the increments of the intervals (t − dt, t]
    ending at ``t`` (K,): each fault's bias b + r·τ integrated over the part of the interval inside its window,
    b·(τ₂ − τ₁) + ½·r·(τ₂² − τ₁²) (:func:`imu_fault_overlap`), so a partial interval at the onset or the end is
    counted exactly. Other kinds are ignored; no randomness (every trial's IMU carries the same fault)."""
    t = np.asarray(t, float)
    out = {"gyro": np.zeros((t.size, 3)), "accel": np.zeros((t.size, 3))}
    for f in faults:
        if f.kind not in IMU_KINDS:
            continue
        t1, t2 = imu_fault_overlap(f, t, dt)
        span = t2 - t1
        ramp = 0.5 * span * (t2 + t1)  # ½(τ₂² − τ₁²) without subtracting two large squares
        out[f.sensor] += span[:, None] * f.bias_si + ramp[:, None] * f.rate_si
    return out["gyro"], out["accel"]


def imu_fault_epochs(faults: list, t: NDArray, t_imu: NDArray, dt: float) -> NDArray:
    """Mask (T,) of the epochs ``t`` whose IMU increments since the previous epoch carry an IMU fault of the
    schedule: an interval (t_imu − dt, t_imu] (``t_imu`` (K,)) the fault's window meets for a positive time
    ends after the previous epoch and at or before this one."""
    t, t_imu = np.asarray(t, float), np.asarray(t_imu, float)
    hit = np.zeros(t_imu.size, bool)
    for f in faults:
        if f.kind in IMU_KINDS:
            t1, t2 = imu_fault_overlap(f, t_imu, dt)
            hit |= t2 > t1
    at = np.searchsorted(t, t_imu[hit] - 1e-6 * dt, side="left")  # the first epoch at or after each end
    out = np.zeros(t.size, bool)
    out[at[at < t.size]] = True
    return out
