"""Fly an approach: JSBSim + our guidance, from the start point to the path's end.

:func:`fly` returns a :class:`FlightResult` with the full-rate :class:`Truth`,
the planned path, and a :class:`FlightSummary`. Observers (sensors, monitors,
Rerun) can follow the flight epoch by epoch through ``on_step``; the physics
does not know they exist.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Callable, Protocol

import numpy as np

from testbed.flight.guidance import Autopilot
from testbed.flight.jsbsim_fdm import InitialCondition, JSBSimAircraft
from testbed.flight.path import ApproachPath
from testbed.flight.settings import FlightPlan
from testbed.flight.wind import GustGenerator, wind_ned
from testbed.frames import LocalFrame, euler_to_q_body_to_enu
from testbed.records import Truth
from testbed.schema import ConfigError

CAPTURE_S = 30.0  # tracking statistics exclude the first 30 s (initial transient)
MIN_START_CLEARANCE_M = 50.0


class TerrainLike(Protocol):
    def height(self, lat_deg, lon_deg): ...


@dataclass(frozen=True)
class FlightSummary:
    approach: str
    aircraft: str
    duration_s: float
    steps: int
    reached_end: bool
    xtk_rms_m: float  # cross-track, after capture
    xtk_max_m: float
    vert_rms_m: float  # height minus path height, after capture
    vert_max_m: float
    end_height_above_m: float  # height above the path end point (threshold) when crossing it
    end_lateral_m: float
    end_cas_kt: float
    end_sink_rate_ms: float
    max_bank_deg: float
    pitch_range_deg: tuple[float, float]
    min_agl_m: float
    wall_s: float

    @property
    def realtime_factor(self) -> float:
        return self.duration_s / self.wall_s if self.wall_s > 0 else math.inf

    def as_dict(self) -> dict:
        d = asdict(self)
        d["realtime_factor"] = self.realtime_factor
        return d


@dataclass(frozen=True)
class FlightResult:
    truth: Truth
    path: ApproachPath
    frame: LocalFrame
    summary: FlightSummary
    xtk: np.ndarray  # (T,) cross-track error, m
    vert: np.ndarray  # (T,) vertical path error, m
    distance_to_go: np.ndarray  # (T,)


def approach_geometry(plan: FlightPlan) -> tuple[LocalFrame, ApproachPath]:
    """The world frame and planned path of an approach (no flying)."""
    frame = LocalFrame(plan.frame.lat_deg, plan.frame.lon_deg, plan.frame.h)
    return frame, ApproachPath(plan.path, plan.vertical, frame)


def check_start_clearance(plan: FlightPlan, terrain: TerrainLike | None) -> float:
    """Height of the start point above the terrain (m); a ConfigError if inside it."""
    frame, path = approach_geometry(plan)
    d0 = plan.flight.start_distance_m or path.total_length
    try:
        e, n, _ = path.start_point(d0)
    except ValueError as exc:
        raise ConfigError(plan.source, [f"flight.start_distance_m: {exc}"]) from None
    lat, lon, _ = frame.enu_to_geodetic(np.array([e, n, 0.0]))
    ground = float(terrain.height(lat, lon)) if terrain is not None else frame.h
    clearance = path.height(d0) - ground
    if clearance < MIN_START_CLEARANCE_M:
        raise ConfigError(plan.source, [
            f"flight.start_distance_m / path: the start point ({float(lat):.5f} N, {float(lon):.5f} E, "
            f"{path.height(d0):.0f} m) is {clearance:.0f} m above the terrain ({ground:.0f} m): "
            f"expected at least {MIN_START_CLEARANCE_M:.0f} m (start inside the terrain)"])
    return clearance


def start_condition(plan: FlightPlan, terrain: TerrainLike | None) -> tuple[InitialCondition, float, bool, float]:
    """The trim condition at the start point: (initial condition, flaps, gear down, speed brake)."""
    frame, path = approach_geometry(plan)
    fl, ac = plan.flight, plan.aircraft
    d0 = fl.start_distance_m or path.total_length
    e0, n0, track0 = path.start_point(d0)
    lat0, lon0, _ = frame.enu_to_geodetic(np.array([e0, n0, 0.0]))
    ground = float(terrain.height(float(lat0), float(lon0))) if terrain is not None else frame.h
    speed_kt = fl.speed_kt if fl.speed_kt is not None else ac.approach.speed_kt
    flaps = fl.flaps if fl.flaps is not None else ac.approach.flaps
    brake = fl.speed_brake if fl.speed_brake is not None else ac.approach.speed_brake
    ic = InitialCondition(float(lat0), float(lon0), path.height(d0), math.degrees(track0), speed_kt,
                          -math.degrees(path.path_angle(d0)), ground)
    return ic, flaps, ac.approach.gear_down, brake


ROW_FIELDS = 31  # columns of a flight row (see truth_from_rows)


def truth_from_rows(rows, frame: LocalFrame, t0: float = 0.0) -> Truth:
    """Build a Truth record from flight rows (``fly``'s per-step tuples); ``t0`` is the start time."""
    a = np.asarray(rows, float).reshape(-1, ROW_FIELDS)
    euler = a[:, 13:16]
    return Truth(
        t=a[:, 0] - t0, pos_ecef=a[:, 1:4], lat_deg=a[:, 4], lon_deg=a[:, 5], h=a[:, 6],
        pos_enu=a[:, 7:10], vel_enu=a[:, 10:13],
        q_body_to_enu=euler_to_q_body_to_enu(euler[:, 0], euler[:, 1], euler[:, 2]),
        euler=euler, omega_body=a[:, 16:19], specific_force_eye_body=a[:, 19:22], agl=a[:, 22],
        airspeed=a[:, 23], specific_force_cg_body=a[:, 25:28], omega_dot_body=a[:, 28:31],
        frame_origin=np.array([frame.lat_deg, frame.lon_deg, frame.h]))


def fly(plan: FlightPlan, terrain: TerrainLike | None = None, *, gust_seed: int | None = None,
        on_step: Callable[[int, tuple], None] | None = None) -> FlightResult:
    """Fly ``plan`` in JSBSim with our guidance until the end of the path.

    Parameters
    ----------
    plan : what the flight needs of an approach (``load_approach(...).flight_plan``).
    terrain : terrain model feeding JSBSim's ground height (None: flat at the frame origin).
    gust_seed : overrides the approach's gust seed (campaigns vary it per trajectory).
    on_step : observer called at each integration step with (step index, flight row);
        :func:`truth_from_rows` turns rows into a Truth record. The row at step 0 is
        the trimmed initial state.
    """
    cfg, ac_cfg = plan, plan.aircraft
    frame, path = approach_geometry(plan)
    check_start_clearance(plan, terrain)
    ground = (lambda la, lo: float(terrain.height(la, lo))) if terrain is not None else (lambda la, lo: frame.h)
    dt = cfg.flight.dt_s
    gusts_cfg = cfg.gusts if gust_seed is None else cfg.gusts.model_copy(update={"seed": gust_seed})
    max_steps = int(cfg.flight.max_duration_s / dt) + 1
    ic, flaps, gear_down, brake = start_condition(plan, terrain)
    speed_kt = ic.calibrated_airspeed_kt

    wall0 = time.perf_counter()
    with JSBSimAircraft(ac_cfg.jsbsim_model, ac_cfg.engines, dt) as ac:
        trim = ac.trim(ic, flaps, gear_down, brake)
        ac.set_wind_ned(wind_ned(cfg.wind))
        gust = GustGenerator(gusts_cfg, max_steps)
        pilot = Autopilot(path, ac_cfg.gains, trim, speed_kt * 1852 / 3600, dt)
        terrain_every = max(1, int(round(1.0 / (cfg.flight.terrain_update_hz * dt))))
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = frame.R.tolist()
        o0, o1, o2 = frame.origin_ecef.tolist()
        rows, xtk, vert, dtg = [], [], [], []
        reached = False
        for k in range(max_steps):
            s = ac.read()
            x, y, z = s["ecef"]
            dx, dy, dz = x - o0, y - o1, z - o2
            enu = (r00 * dx + r01 * dy + r02 * dz, r10 * dx + r11 * dy + r12 * dz, r20 * dx + r21 * dy + r22 * dz)
            cmd = pilot.update(s, enu[0], enu[1])
            ps = pilot.last
            row = (round(k * dt, 9), x, y, z, s["lat_deg"], s["lon_deg"], s["h"], *enu, s["vel_ned"][1],
                   s["vel_ned"][0], -s["vel_ned"][2], s["phi"], s["theta"], s["psi"], s["p"], s["q"],
                   s["r"], *s["f_eye_body"], s["agl"], s["tas"], s["cas"], *s["f_cg_body"], *s["omega_dot"])
            rows.append(row)
            xtk.append(ps.cross_track)
            vert.append(pilot.h_error)
            dtg.append(ps.distance_to_go)
            if on_step is not None:
                on_step(k, row)
            if ps.distance_to_go <= 0.0:
                reached = True
                break
            if s["on_ground"] or s["agl"] < 0.0:
                break
            if k % terrain_every == 0:
                ac.set_terrain(ground(s["lat_deg"], s["lon_deg"]))
            ac.set_gust_ned(gust.step(dt, s["tas"], s["agl"], s["psi"]))
            ac.command(cmd.aileron, cmd.elevator, cmd.rudder, cmd.throttle)
            ac.step()
    wall = time.perf_counter() - wall0

    a = np.asarray(rows)
    truth = truth_from_rows(a, frame, t0=a[0, 0])
    xtk_a, vert_a, dtg_a = np.asarray(xtk), np.asarray(vert), np.asarray(dtg)
    summary = _summarise(plan, truth, a[:, 24], xtk_a, vert_a, dtg_a, path, reached, wall)
    return FlightResult(truth, path, frame, summary, xtk_a, vert_a, dtg_a)


def _summarise(plan: FlightPlan, truth: Truth, cas: np.ndarray, xtk: np.ndarray, vert: np.ndarray,
               dtg: np.ndarray, path: ApproachPath, reached: bool, wall: float) -> FlightSummary:
    after = truth.t >= min(CAPTURE_S, truth.t[-1] / 2)

    def rms(x):
        return float(np.sqrt(np.mean(x[after] ** 2)))

    if reached and len(dtg) > 1:
        # interpolate the crossing of the path end between the last two epochs
        w = dtg[-2] / (dtg[-2] - dtg[-1])
        lerp = lambda v: float(v[-2] + w * (v[-1] - v[-2]))  # noqa: E731
        end_h = lerp(truth.h) - path.end_h
        end_lat = lerp(xtk)
        end_cas = lerp(cas) * 3600 / 1852
        end_sink = -lerp(truth.vel_enu[:, 2])
    else:
        end_h = end_lat = end_cas = end_sink = math.nan
    pitch = np.degrees(truth.euler[:, 1])
    return FlightSummary(
        approach=plan.name, aircraft=plan.aircraft.name, duration_s=float(truth.t[-1]),
        steps=len(truth.t), reached_end=reached, xtk_rms_m=rms(xtk), xtk_max_m=float(np.abs(xtk[after]).max()),
        vert_rms_m=rms(vert), vert_max_m=float(np.abs(vert[after]).max()), end_height_above_m=end_h,
        end_lateral_m=end_lat, end_cas_kt=end_cas, end_sink_rate_ms=end_sink,
        max_bank_deg=float(np.degrees(np.abs(truth.euler[:, 0])).max()),
        pitch_range_deg=(float(pitch.min()), float(pitch.max())), min_agl_m=float(np.nanmin(truth.agl)),
        wall_s=wall)
