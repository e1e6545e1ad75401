"""Everything a run will load, loaded and checked before any work starts.

The models check each value on its own (types, finiteness, ranges); this checks
what only the loaded run can say: the terrain and the almanac or navigation file
load and cover the approach, every fault names a satellite of the constellation
and a landmark of the scene and starts before the flight can end (an IMU fault
needs a monitor that reads the IMU, a vision fault one that reads vision), the start
point is above the terrain, and the aircraft trims at the start. ``testbed
check`` runs it, and so does the first step of every command that flies.
Every problem is one line naming the file, the key path, the value and what
was expected; the run is refused with all of them at once.
"""

from __future__ import annotations

import math

import numpy as np

from testbed.config import Approach
from testbed.monitors import monitor_inputs, monitor_names
from testbed.outputs import check_output
from testbed.schema import ConfigError
from testbed.sensors.faults import IMU_KINDS

KT = 1852.0 / 3600.0


def preflight(approach: Approach, *, trim: bool = True):
    """Load and check everything ``approach`` names; returns the run set-up (terrain loaded).

    Raises a ConfigError listing every problem found (the aircraft file for aircraft problems).
    """
    from testbed.flight.fly import check_start_clearance
    from testbed.sim.setup import build_setup, load_terrain_for

    terrain = load_terrain_for(approach)
    check_start_clearance(approach.flight_plan, terrain)
    setup = build_setup(approach, terrain)
    problems = []
    eph = _constellation(approach, problems)
    if eph is not None:
        problems += _gnss_fault_problems(approach, eph)
    problems += _vision_fault_problems(approach, setup)
    problems += _imu_fault_problems(approach)
    problems += _vision_weight_problems(setup)
    problems += _timing_problems(approach, setup)
    problems += _terrain_problems(approach, setup)
    if problems:
        raise ConfigError(approach.source, problems)
    if trim:
        check_trim(approach, terrain)
    return setup


def _constellation(approach: Approach, problems: list[str]):
    """Every tracked constellation loaded from its orbit source, each file's records of that system present and
    current at the start and at the latest end of the flight; the tracked set (None after a problem)."""
    from testbed.sensors.gnss.almanac import OrbitFileProblem
    from testbed.sensors.gnss.constellations import constellation_orbits, tracked_constellations
    from testbed.sensors.gnss.timebase import utc_to_gps_seconds

    g = approach.config.gnss
    t0 = utc_to_gps_seconds(approach.config.start_time_utc)
    t_end = t0 + flight_duration_bound(approach)
    ok = True
    for name in g.constellations:
        source, path, key = g.orbit_source_of(name)
        where = f"{key} = {str(path)!r}" if path is not None else f"gnss.{name}.orbit_source"
        for t in (t0, t_end) if source == "rinex_nav" else (t0,):
            try:
                eph = constellation_orbits(name, source, path, t, g.almanac_week)
            except OrbitFileProblem as exc:  # it reads, but holds no current record of the system
                problems.append(f"{where}: {exc}")
                ok = False
                break
            except Exception as exc:  # any reader failure on a user's file is a message, not a traceback
                problems.append(f"{where}: could not be read as a {source} file ({type(exc).__name__}: {exc})")
                ok = False
                break
            n = len(np.unique(eph.prn))
            if n < 4 and len(g.constellations) == 1:
                problems.append(f"{where}: {n} {name} satellite(s) in the file: expected at least 4")
                ok = False
                break
    if not ok:
        return None
    try:
        return tracked_constellations(g, t0)
    except ValueError as exc:  # an excluded PRN the constellation does not have
        problems.append(str(exc))
        return None


def _gnss_fault_problems(approach: Approach, eph) -> list[str]:
    from testbed.sensors.faults import GNSS_KINDS, SYSTEM_KINDS, named_targets

    out = []
    for k, f in enumerate(approach.config.faults):
        if f.kind not in GNSS_KINDS or (f.kind not in SYSTEM_KINDS and f.targets == "random"):
            continue
        try:
            named_targets(f, eph.prn, eph.system)
        except ValueError as exc:
            tracked = approach.config.gnss.constellations
            if f.kind in SYSTEM_KINDS:
                out.append(f"faults.{k}.system = {f.system!r}: not tracked (expected one of constellations = "
                           f"{tracked})")
                continue
            key = "sat" if f.sat is not None else "prn"
            out.append(f"faults.{k}.{key} = {getattr(f, key)!r}: {str(exc).split(': ', 1)[1]} "
                       f"(tracked: constellations = {tracked})")
    return out


def _vision_fault_problems(approach: Approach, setup) -> list[str]:
    from testbed.sensors.faults import VISION_KINDS

    ids = [str(i) for i in setup.landmarks.id]
    out = []
    for k, f in enumerate(approach.config.faults):
        if f.kind not in VISION_KINDS:
            continue
        if not setup.uses_vision:
            out.append(f"faults.{k}.kind = {f.kind!r}: a vision fault, but no configured monitor reads vision "
                       f"(monitors = {list(setup.monitor_names)})")
        names = list(f.landmarks) if f.kind == "misassociation" else [f.landmark]
        bad = [n for n in names if n != "random" and n not in ids]
        if bad:
            key = "landmarks" if f.kind == "misassociation" else "landmark"
            out.append(f"faults.{k}.{key} = {bad[0]!r}: not a landmark of the scene (expected one of "
                       f"{ids[:12]}{' ...' if len(ids) > 12 else ''})")
    return out


def _imu_fault_problems(approach: Approach) -> list[str]:
    """An IMU fault needs a monitor that reads the IMU (the run synthesises the IMU only for one)."""
    cfg = approach.config
    if cfg.reads("imu"):
        return []
    readers = [n for n in monitor_names() if "imu" in monitor_inputs(n, cfg.monitor)]
    return [f"faults.{k}.kind = {f.kind!r}: an IMU fault, but no configured monitor reads the IMU (monitors = "
            f"{list(cfg.monitors)}; expected one of {readers})" for k, f in enumerate(cfg.faults) if f.kind in IMU_KINDS]


def _vision_weight_problems(setup) -> list[str]:
    """The vision monitors weight pixels by 1/σ²: the σ they are told must not be zero."""
    d = setup.vision.detection
    told = d.sigma_told_px if d.sigma_told_px is not None else d.sigma_px
    if setup.uses_vision and told <= 0:
        return [f"vision.detection.sigma_px = {d.sigma_px:g}: the vision monitors weight pixels by 1/sigma^2, so "
                f"the sigma they are told must be > 0 (a noise-free camera: set sigma_told_px > 0)"]
    return []


def flight_duration_bound(approach: Approach, path=None) -> float:
    """An upper bound on the flight's duration (s): the path at the approach speed less the wind.

    True airspeed is at least the calibrated airspeed above sea level, so the ground
    speed is at least CAS − wind; gusts aside, the flight cannot last longer.
    path : the approach's planned path, when at hand (else made from the flight plan).
    """
    from testbed.flight.fly import approach_geometry

    plan = approach.flight_plan
    fl, ac = plan.flight, plan.aircraft
    cas = (fl.speed_kt if fl.speed_kt is not None else ac.approach.speed_kt) * KT
    wind = plan.wind.speed_kt * KT
    d0 = fl.start_distance_m or (path if path is not None else approach_geometry(plan)[1]).total_length
    gs = cas - wind
    return min(fl.max_duration_s, d0 / gs if gs > 0 else math.inf)


def _timing_problems(approach: Approach, setup) -> list[str]:
    bound = flight_duration_bound(approach, setup.path)
    out = []
    for k, f in enumerate(approach.config.faults):
        if f.onset_s >= bound:
            out.append(f"faults.{k}.onset_s = {f.onset_s:g}: after the flight ends (it lasts at most "
                       f"{bound:.0f} s): expected an onset before {bound:.0f} s")
    return out


def _terrain_problems(approach: Approach, setup) -> list[str]:
    """The terrain model must give a height all along the planned path (a DEM of another area does not)."""
    if setup.terrain is None:
        return []
    lat, lon, _ = (np.ravel(v) for v in setup.frame.enu_to_geodetic(setup.path.sample_enu(200.0)))
    with np.errstate(invalid="ignore"):
        h = np.asarray(setup.terrain.height(lat, lon), float)  # the terrain models take arrays
    bad = ~np.isfinite(h)
    if bad.any():
        i = int(np.argmax(bad))
        return [f"terrain: no height under the planned path (first at {float(lat[i]):.4f} N, "
                f"{float(lon[i]):.4f} E; {int(bad.sum())} of {bad.size} path points): expected a "
                f"terrain model covering the approach (a DEM tile of another area?)"]
    return []


def check_trim(approach: Approach, terrain) -> None:
    """Trim the aircraft at the start condition (as the flight will); a ConfigError naming the file that set it."""
    from testbed.flight.fly import start_condition
    from testbed.flight.jsbsim_fdm import JSBSimAircraft, TrimError

    plan = approach.flight_plan
    ic, flaps, gear, brake = start_condition(plan, terrain)
    try:
        ac = JSBSimAircraft(plan.aircraft.jsbsim_model, plan.aircraft.engines, plan.flight.dt_s)
    except ValueError as exc:
        raise ConfigError(approach.aircraft_source, [f"jsbsim_model = {plan.aircraft.jsbsim_model!r}: {exc}; "
                                                     "expected a JSBSim aircraft with the properties we drive"]) from None
    try:
        with ac:
            ac.trim(ic, flaps, gear, brake)
    except TrimError as exc:
        fl = plan.flight
        src, key = ((approach.source, "flight.speed_kt") if fl.speed_kt is not None
                    else (approach.aircraft_source, "approach.speed_kt"))
        v = plan.vertical
        path = (f"vertical.constraints: a {-ic.flight_path_deg:.1f}° descent" if v.constraints
                else f"vertical.glide_path_deg = {v.glide_path_deg:g}")
        raise ConfigError(src, [f"{key} = {ic.calibrated_airspeed_kt:g}: the aircraft does not trim at the start "
                                f"({ic.h:.0f} m, flaps {flaps:g}, {path}): {exc}; expected a speed it can fly "
                                f"on that path, or a shallower path"]) from None


def check_output_file(path, option: str, suffixes: tuple[str, ...]) -> None:
    """An output file we can create (or replace), tried before any work: not a folder, a known suffix, a
    folder that takes a new file (:func:`testbed.outputs.output_problem`)."""
    check_output(path, option, folder=False, suffixes=suffixes)


def check_output_folder(path, option: str) -> None:
    """An output folder we can create or write into, tried before any work."""
    check_output(path, option, folder=True)
