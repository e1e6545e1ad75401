"""Settings of the flight room: aircraft, guidance gains, path, wind and gusts.

All lengths in metres, angles in degrees (suffix ``_deg``), speeds in knots
only where the name says ``_kt`` (what pilots and approach charts use).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, Union

from pydantic import Field, field_validator, model_validator

from testbed.schema import LeverArm, StrictModel


class ApproachConfiguration(StrictModel):
    """How the aircraft is configured and trimmed for the approach."""

    speed_kt: float = Field(..., gt=30, lt=250, description="target calibrated airspeed on the approach")
    flaps: float = Field(..., ge=0, le=1, description="flap command, normalised 0..1")
    gear_down: bool = Field(True, description="landing gear extended on the approach")
    speed_brake: float = Field(0.0, ge=0, le=1, description="speed-brake command, normalised 0..1")


class Gains(StrictModel):
    """Guidance and control gains (SI: m, s, rad). Tuned per aircraft."""

    # lateral: cross-track (m) and its rate (m/s) -> bank command (rad)
    k_xtk: float = Field(0.004, ge=0, description="bank per metre of cross-track error (rad/m)")
    k_xtk_rate: float = Field(0.045, ge=0, description="bank per m/s of cross-track rate (rad s/m)")
    k_xtk_int: float = Field(0.00005, ge=0, description="bank per metre-second of integrated cross-track (rad/(m s))")
    max_bank_deg: float = Field(25.0, gt=0, le=35, description="bank-angle limit of the lateral guidance")
    k_bank: float = Field(2.0, ge=0, description="aileron per rad of bank error")
    k_roll_rate: float = Field(0.6, ge=0, description="aileron per rad/s of roll rate")
    k_yaw_damper: float = Field(1.0, ge=0, description="rudder per rad/s of washed-out yaw rate")
    # vertical: height error (m) -> vertical speed command (m/s) -> pitch -> elevator
    k_h: float = Field(0.12, ge=0, description="vertical-speed command per metre of path error (1/s)")
    max_vs_correction: float = Field(4.0, gt=0, description="limit on the vertical-speed correction (m/s)")
    k_vs: float = Field(0.02, ge=0, description="pitch per m/s of vertical-speed error (rad s/m)")
    k_vs_int: float = Field(0.006, ge=0, description="pitch per metre of integrated vertical-speed error (rad/m)")
    k_pitch: float = Field(3.0, ge=0, description="elevator per rad of pitch error")
    k_pitch_rate: float = Field(1.5, ge=0, description="elevator per rad/s of pitch rate")
    # autothrottle
    k_speed: float = Field(0.08, ge=0, description="throttle per m/s of airspeed error")
    k_speed_int: float = Field(0.01, ge=0, description="throttle per metre of integrated airspeed error")


class AircraftSettings(StrictModel):
    """An aircraft folder's ``aircraft.toml``."""

    name: str = Field(..., description="aircraft name (shown in the flight summary)")
    description: str = Field("", description="free text about the aircraft")
    jsbsim_model: str = Field(..., description="JSBSim model name (stock, or in this folder's jsbsim/ dir)")
    engines: int = Field(..., ge=1, le=8, description="number of engines of the JSBSim model (each gets the "
                                                      "throttle command)")
    approach: ApproachConfiguration = Field(..., description="approach configuration: speed, flaps, gear, "
                                                             "speed brake")
    gains: Gains = Field(Gains(), description="guidance and control gains")
    antenna_lever_arm_m: LeverArm = Field((0.0, 0.0, -2.0), description="GNSS antenna from the CG, body FRD (m); "
                                                                     "at most 100 m long")
    camera_lever_arm_m: LeverArm = Field((5.0, 0.0, 1.0), description="camera from the CG, body FRD (m); at most "
                                                                     "100 m long")
    camera_pitch_down_deg: float = Field(9.0, ge=-30, le=90, description="camera boresight below the body x axis")
    camera_yaw_deg: float = Field(0.0, ge=-180, le=180, description="camera boresight right of the body x axis")


class Wind(StrictModel):
    """Steady wind, meteorological convention (the direction it blows FROM)."""

    from_deg: float = Field(0.0, ge=0, le=360, description="direction the wind blows from, deg true")
    speed_kt: float = Field(0.0, ge=0, le=80, description="wind speed")


class Gusts(StrictModel):
    """Our own gust model (JSBSim's turbulence is ~0 at this elevation:
    docs/design/physics-notes.md §jsbsim-turbulence-at-high-elevation).

    First-order Markov gusts with MIL-F-8785C low-altitude length scales and
    intensities from the wind speed at 20 ft (``w20_kt``: light 15, moderate 30,
    severe 45). Seeded: the same seed gives the same gusts.
    """

    intensity: Literal["none", "light", "moderate", "severe"] = Field(
        "none", description="gust intensity: sets the wind speed at 20 ft (light 15 kt, moderate 30 kt, "
                            "severe 45 kt); none = no gusts")
    w20_kt: float | None = Field(None, ge=0, le=90, description="overrides the intensity's W20")
    seed: int = Field(0, ge=0, description="random seed of the gust draws (`--gust-seed` overrides it)")

    def w20(self) -> float:
        if self.w20_kt is not None:
            return self.w20_kt
        return {"none": 0.0, "light": 15.0, "moderate": 30.0, "severe": 45.0}[self.intensity]


class StraightLeg(StrictModel):
    """A straight leg."""

    type: Literal["straight"] = Field(..., description="leg type")
    length_m: float = Field(..., gt=0, le=200_000, description="leg length over the ground")


class RfLeg(StrictModel):
    """A constant-radius turn (ARINC 424 RF leg); turn_deg > 0 turns right."""

    type: Literal["rf"] = Field(..., description="leg type")
    radius_m: float = Field(..., gt=200, le=50_000, description="turn radius")
    turn_deg: float = Field(..., ge=-270, le=270, description="turn angle: > 0 turns right, < 0 left; "
                                                             "|turn_deg| >= 1")

    @field_validator("turn_deg")
    @classmethod
    def _nonzero(cls, v: float) -> float:
        if abs(v) < 1.0:
            raise ValueError(f"a turn of {v} deg is no turn: expected |turn_deg| >= 1")
        return v


Leg = Annotated[Union[StraightLeg, RfLeg], Field(discriminator="type")]


class PathSettings(StrictModel):
    """Lateral path: legs in flying order, ending at ``end`` on ``final_course_deg``.

    The geometry is built backwards from the end point, so consecutive legs are
    always tangent (no gaps, no kinks).
    """

    end_lat_deg: float = Field(..., ge=-90, le=90, description="latitude of the path's end point (threshold), WGS84")
    end_lon_deg: float = Field(..., ge=-180, le=180, description="longitude of the path's end point, WGS84")
    end_h: float = Field(..., ge=-500, le=9000, description="ellipsoidal height of the path end point (threshold), m")
    final_course_deg: float = Field(..., ge=0, lt=360, description="true course of the last leg")
    legs: list[Leg] = Field(..., min_length=1, description="legs in flying order (straight legs and RF turns, "
                                                           "tagged by type)")


class VerticalSettings(StrictModel):
    """Vertical profile: a glide path to a crossing height, or altitude constraints."""

    glide_path_deg: float | None = Field(3.0, description="flight path angle to the end point, 1 to 8 deg")
    crossing_height_m: float = Field(15.0, ge=0, le=100, description="height above the end point at the end (TCH)")
    constraints: list[tuple[float, float]] | None = Field(
        None, description="[(distance_to_go_m, height_m)] pairs; piecewise-linear profile (overrides the glide path)")

    @field_validator("glide_path_deg")
    @classmethod
    def _gpa(cls, v):
        if v is not None and not (1.0 <= v <= 8.0):
            raise ValueError(f"glide path angle must be between 1 and 8 degrees, got {v}")
        return v

    @model_validator(mode="after")
    def _one_profile(self):
        if self.glide_path_deg is None and not self.constraints:
            raise ValueError("give glide_path_deg or constraints")
        if self.constraints:
            d = [c[0] for c in self.constraints]
            if len(d) < 2 or any(b <= a for a, b in zip(d, d[1:])):
                raise ValueError("constraints: expected >= 2 pairs with strictly increasing distance_to_go_m")
        return self


class FrameSettings(StrictModel):
    """Origin of the approach's world frame (local ENU)."""

    lat_deg: float = Field(..., ge=-90, le=90, description="latitude of the origin, WGS84")
    lon_deg: float = Field(..., ge=-180, le=180, description="longitude of the origin, WGS84")
    h: float = Field(..., ge=-500, le=9000, description="WGS84 ellipsoidal height, m")


class FlightSettings(StrictModel):
    """How the approach is flown: JSBSim step, start, rates, limits, and overrides of the aircraft's
    approach configuration."""

    dt_s: float = Field(1.0 / 120.0, gt=0, le=0.05, description="JSBSim integration step")
    start_distance_m: float | None = Field(None, gt=0, description="distance to go at the start (default: whole path)")
    max_duration_s: float = Field(1800.0, gt=0, le=7200, description="the flight stops after this much "
                                                                    "simulated time if it has not reached the "
                                                                    "end")
    truth_rate_hz: float = Field(10.0, gt=0, le=120, description="rate of the decimated truth for sensors")
    terrain_update_hz: float = Field(10.0, gt=0, le=120, description="how often JSBSim's terrain height is refreshed")
    speed_kt: float | None = Field(None, gt=30, lt=300, description="overrides the aircraft's approach speed (CAS)")
    flaps: float | None = Field(None, ge=0, le=1, description="overrides the aircraft's approach flaps")
    speed_brake: float | None = Field(None, ge=0, le=1, description="overrides the aircraft's speed brake")


@dataclass(frozen=True)
class FlightPlan:
    """What flying an approach needs: its frame, path, profile, flight settings, air and aircraft.

    Built by :attr:`testbed.config.Approach.flight_plan`; ``source`` is the file that
    errors are reported against.
    """

    name: str
    source: Path
    frame: FrameSettings
    path: PathSettings
    vertical: VerticalSettings
    flight: FlightSettings
    wind: Wind
    gusts: Gusts
    aircraft: AircraftSettings
