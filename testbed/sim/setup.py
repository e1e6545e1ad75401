"""Everything a run needs, built once from an approach: terrain, sensors, scene, monitors.

Nothing here flies or draws random numbers; :mod:`testbed.sim.loop` does.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
from pydantic import ValidationError

from testbed.config import Approach
from testbed.flight.fly import approach_geometry
from testbed.flight.path import ApproachPath
from testbed.frames import R_NED_TO_ENU, LocalFrame, R_ecef_to_enu, euler_to_R_body_to_ned
from testbed.integrity.dpe.calibration import read_k_file, settings_fingerprint
from testbed.integrity.levels import strictest_limits
from testbed.integrity.monitor import Monitor, MonitorContext, compute
from testbed.integrity.settings import IntegritySettings
from testbed.kernel_cache import compiled_before, mark_compiled
from testbed.monitors import build_monitor, monitor_options
from testbed.records import Mount
from testbed.schema import ConfigError, format_validation_error
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.vision.features import corridor_features
from testbed.sensors.vision.landmarks import Landmarks, build_landmarks
from testbed.sensors.vision.settings import MountSettings, VisionSettings
from testbed.world import airport
from testbed.world.settings import load_terrain


@dataclass(frozen=True)
class RunSetup:
    approach: Approach
    frame: LocalFrame
    path: ApproachPath
    terrain: object
    gnss: GnssSettings
    antenna: Mount
    vision: VisionSettings
    landmarks: Landmarks
    integrity: IntegritySettings
    monitors: tuple[Monitor, ...]
    faults: tuple
    imu: object = None  # ImuSettings (read when a monitor reads "imu")

    @functools.cached_property
    def features(self) -> np.ndarray | None:
        """The unsurveyed ground features' scene (n, 3), world frame, when ``[vision.features]`` is enabled and a
        monitor reads features (the ekf); None otherwise. Made when first read, so a check (which never reads it)
        does not build a scene of millions of points: `testbed check` of a dense corridor (10 000 per km², 40 km
        wide, 50 km beyond) peaked at 5.7 GB resident for 48 s when the set-up built it."""
        scene = self.vision.features
        if not (scene.enabled and self.approach.config.reads("features")):
            return None
        return corridor_features(self.path.sample(200.0)[0], scene, self.frame, self.terrain)

    @property
    def monitor_names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.monitors)

    def monitor(self, name: str) -> Monitor:
        return next(m for m in self.monitors if m.name == name)

    @property
    def uses_vision(self) -> bool:
        return any("vision" in m.inputs for m in self.monitors)

    @property
    def alert_limits(self) -> tuple[float, float]:
        """(HAL, VAL) of the most demanding configured service level (for plots)."""
        return strictest_limits(self.integrity.service_levels)


def load_terrain_for(approach: Approach):
    """The terrain model an approach names (its ``[terrain]`` table)."""

    try:
        return load_terrain(approach.config.terrain, approach.source.parent)
    except (ValueError, OSError) as exc:
        raise ConfigError(approach.source, [f"terrain: {exc}"]) from None


def antenna_mount(approach: Approach) -> Mount:
    return Mount(lever_arm_body=np.asarray(approach.aircraft.antenna_lever_arm_m, float))


def vision_settings(approach: Approach) -> VisionSettings:
    """The approach's camera settings; the mount comes from the aircraft unless the file sets one."""
    v = approach.config.vision
    if "mount" in v.model_fields_set:
        return v
    ac = approach.aircraft
    mount = MountSettings(lever_arm_body_m=ac.camera_lever_arm_m, pitch_deg=-ac.camera_pitch_down_deg,
                          yaw_deg=ac.camera_yaw_deg)
    return v.model_copy(update={"mount": mount})


def build_setup(approach: Approach, terrain, monitor_threads: int | None = None,
                share: Callable[..., Any] = compute) -> RunSetup:
    """The run's frame, path, sensor settings and monitors (built, not compiled: see prepare_monitors).

    monitor_threads : threads each monitor may use on a batch (None: one per core; campaigns,
    which run draw blocks side by side, pass 1).
    share : what the monitors may share with other runs (:class:`~testbed.integrity.monitor.MonitorContext`;
    a campaign passes :func:`testbed.memo.shared`); nothing by default.
    """
    c = approach.config
    frame, path = approach_geometry(approach.flight_plan)
    vision = vision_settings(approach)
    gnss = c.gnss
    ratio = vision.rate_hz / gnss.rate_hz
    if c.reads("vision") and abs(ratio - round(ratio)) > 1e-9:
        raise ConfigError(approach.source, [
            f"vision.rate_hz ({vision.rate_hz}) must be an integer multiple of gnss.rate_hz ({gnss.rate_hz}): "
            "the vision monitors combine both at the GNSS epochs"])
    if c.reads("imu"):
        steps = 1.0 / (c.imu.rate_hz * c.flight.dt_s)  # flight steps per IMU interval
        per_vision = vision.rate_hz / c.imu.rate_hz if c.reads("vision") else gnss.rate_hz / c.imu.rate_hz
        if abs(steps - round(steps)) > 1e-6 * steps or round(steps) < 1 or abs(1 / per_vision - round(1 / per_vision)) > 1e-6:
            raise ConfigError(approach.source, [
                f"imu.rate_hz = {c.imu.rate_hz:g}: expected a divisor of the flight rate {1.0 / c.flight.dt_s:g} Hz "
                f"and a multiple of the {'vision' if c.reads('vision') else 'GNSS'} rate"])
    if c.reads("correlators") or gnss.correlator_pseudoranges:
        cs = gnss.correlators
        if cs.coherent_s * cs.n_noncoherent > 1.0 / gnss.rate_hz * (1 + 1e-9):
            raise ConfigError(approach.source, [
                f"gnss.correlators: {cs.n_noncoherent} blocks of {cs.coherent_s:g} s (n_noncoherent x coherent_s) "
                f"do not fit in one epoch of {1.0 / gnss.rate_hz:g} s (gnss.rate_hz = {gnss.rate_hz:g})"])
        if gnss.ura_tropo_tau_s is not None:
            raise ConfigError(approach.source, [
                f"gnss.ura_tropo_tau_s = {gnss.ura_tropo_tau_s:g}: the correlators draw the SIS error white per "
                f"epoch (a correlated SIS for the monitors reading correlators is not implemented); remove it"])
        variant = monitor_options("dpe", c.monitor).variant if "dpe" in c.monitors else None
        want = {"seed": "mag", "likelihood": "pow"}.get(variant)
        if want is not None and cs.statistic != want:
            raise ConfigError(approach.source, [
                f"gnss.correlators.statistic = {cs.statistic!r}: monitor.dpe.variant = {variant!r} reads {want!r}"
                + (" (and needs synthesis = 'exact')" if want == "mag" else "")])
    monitors = build_monitors(approach, frame, monitor_threads, share)
    try:
        landmarks = build_landmarks(c.landmarks)
    except ValueError as exc:  # ids repeated across sets
        raise ConfigError(approach.source, [f"landmarks.sets: {exc}"]) from None
    return RunSetup(approach=approach, frame=frame, path=path, terrain=terrain, gnss=gnss,
                    antenna=antenna_mount(approach), vision=vision, landmarks=landmarks,
                    integrity=c.integrity, monitors=monitors, faults=tuple(c.faults), imu=c.imu)


def _dpe_k_from_file(approach: Approach, dpe) -> float:
    """``[monitor.dpe] k_factor = "file.json"``: K from a `testbed calibrate-dpe` record (relative to the
    approach file), if it was calibrated for these settings; otherwise a ConfigError naming the key and the file."""

    c = approach.config
    path = Path(dpe.k_factor)
    path = path if path.is_absolute() else approach.source.parent / path
    try:
        return read_k_file(path, settings_fingerprint(dpe.model_copy(update={"k_factor": 1.0}), c.gnss.correlators)[1])
    except ValueError as exc:
        raise ConfigError(approach.source, [f"monitor.dpe.k_factor = {dpe.k_factor!r}: {exc}"]) from None


def build_monitors(approach: Approach, frame: LocalFrame, threads: int | None = None,
                   share: Callable[..., Any] = compute) -> tuple[Monitor, ...]:
    """The approach's monitors, from the registry (their option tables were validated with the approach);
    what only building finds (a K file that does not fit) is a ConfigError naming its key."""
    c = approach.config
    names = tuple(dict.fromkeys(c.monitors))
    options = {n: t for n, t in c.monitor.items() if n in names}
    dpe = options.get("dpe")
    if dpe is not None and isinstance(dpe.k_factor, str):
        options["dpe"] = dpe.model_copy(update={"k_factor": _dpe_k_from_file(approach, dpe)})
    ctx = MonitorContext(frame=frame, integrity=c.integrity, options=options, threads=threads, share=share)
    return tuple(_built(name, ctx, approach) for name in names)


def _built(name: str, ctx: MonitorContext, approach: Approach) -> Monitor:
    """The monitor from the registry; a bad option table is a ConfigError naming its key."""
    try:
        return build_monitor(name, ctx)
    except ValidationError as exc:
        raise ConfigError(approach.source, [f"monitor.{name}." + p for p in format_validation_error(exc)]) from None
    except ValueError as exc:
        raise ConfigError(approach.source, [f"monitor.{name}: {exc}"]) from None


def prepare_monitors(setup: RunSetup, announce: Callable[[str], None] | None = None) -> tuple[str, ...]:
    """Compile what the monitors compile (numba kernels) before the flight, not in its first epochs.

    announce : called once with a notice before compiling when some monitor's kernels were not
        compiled from these sources by an earlier run (the first run after an install or an edit).
    Returns the names of the monitors whose kernels were compiled for the first time.
    """
    first = tuple(m.name for m in setup.monitors if m.compiles_kernels and not compiled_before(m.name))
    if first and announce is not None:
        announce(f"compiling the integrity kernels of {', '.join(first)} once for this installation "
                 "(about a minute on 2 cores; cached for later runs)...")
    for m in setup.monitors:
        m.prepare()
        if m.compiles_kernels:
            mark_compiled(m.name)
    return first


@dataclass(frozen=True)
class Scene:
    """Static content for the sinks (drawn once)."""

    title: str
    monitors: tuple[str, ...]
    planned_enu: np.ndarray
    terrain_mesh: tuple[np.ndarray, np.ndarray] | None
    runway_enu: np.ndarray | None
    landmarks_enu: np.ndarray | None
    landmark_ids: tuple[str, ...]
    camera_K: np.ndarray | None
    camera_resolution: tuple[int, int]
    alert_limits: tuple[float, float] = (float("nan"), float("nan"))  # HAL, VAL of the most demanding level
    vertical_only: tuple[str, ...] = ()  # monitors that bound the vertical only (no HPL): DPE
    several_tests: tuple[str, ...] = ()  # monitors whose alert is several tests (the Won et al. filter)
    features_enu: np.ndarray | None = None  # the unsurveyed ground features' scene (n, 3), when synthesised


def build_scene(setup: RunSetup, camera=None, mesh_half_size_m: float = 9_000.0,
                mesh_spacing_m: float = 150.0) -> Scene:
    """The static scene in the world frame: terrain mesh around the path, runway, landmarks, path."""
    planned = setup.path.sample_enu(50.0)
    centre = planned[len(planned) // 2]
    mesh = None
    if setup.terrain is not None and hasattr(setup.terrain, "mesh"):
        # a frame at the middle of the path so the mesh covers the whole approach
        lat, lon, _ = setup.frame.enu_to_geodetic(np.array([centre[0], centre[1], 0.0]))
        mid = LocalFrame(float(lat), float(lon), setup.frame.h)
        half = max(mesh_half_size_m, 0.6 * float(np.ptp(planned[:, :2], axis=0).max()))
        v_mid, f = setup.terrain.mesh(mid, half, mesh_spacing_m)
        mesh = (setup.frame.ecef_to_enu(mid.enu_to_ecef(v_mid)), f)
    runway = airport.runway_corners_enu(setup.frame)
    if np.linalg.norm(runway[0]) > 100e3:
        runway = None
    lm_enu = setup.frame.ecef_to_enu(setup.landmarks.pos_ecef) if setup.uses_vision else None
    K, res = None, (0, 0)
    if camera is not None and setup.uses_vision:
        K, res = camera.K, (camera.width_px, camera.height_px)
    ap = setup.approach
    return Scene(title=f"{ap.name} ({ap.aircraft.name})", monitors=setup.monitor_names, planned_enu=planned,
                 terrain_mesh=mesh, runway_enu=runway, landmarks_enu=lm_enu,
                 landmark_ids=tuple(str(i) for i in setup.landmarks.id), camera_K=K, camera_resolution=res,
                 alert_limits=tuple(setup.alert_limits),
                 vertical_only=tuple(m.name for m in setup.monitors if m.dimensions == ("V",)),
                 several_tests=tuple(m.name for m in setup.monitors if m.several_tests),
                 features_enu=setup.features)


def R_body_to_world(frame: LocalFrame, euler: np.ndarray, lat_deg: np.ndarray, lon_deg: np.ndarray) -> np.ndarray:
    """Body -> world-ENU rotations ``(T, 3, 3)`` from Euler angles at the aircraft's position."""

    R_b2n = euler_to_R_body_to_ned(euler[:, 0], euler[:, 1], euler[:, 2])
    R_loc = R_ecef_to_enu(lat_deg, lon_deg)  # ECEF -> local ENU
    return frame.R @ np.swapaxes(R_loc, -1, -2) @ R_NED_TO_ENU @ R_b2n
