"""The JSBSim border: the only module that speaks feet, knots and property names.

Safety rules (docs/design/physics-notes.md §jsbsim-pitfalls), enforced here:
- the global debug level is set to 0 before any FGFDMExec is built (no chatter);
- ``disable_input()`` before ``load_model`` (the stock 737 would listen on
  TCP 5137 / UDP 5139 on all interfaces);
- output goes to a private temporary directory that is removed on close
  (some stock aircraft write CSV files even with output disabled);
- every property name we touch is checked to exist (a misspelt write would
  silently create a new node).
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import jsbsim
import numpy as np

from testbed.frames import FT, KT

jsbsim.FGJSBBase().debug_lvl = 0

#: JSBSim's load factors N_x,y,z are the CG specific force over standard gravity (m/s²)
STANDARD_GRAVITY = 9.80665

READ = {
    "lat": "position/lat-geod-deg",
    "lon": "position/long-gc-deg",
    "h_ft": "position/geod-alt-ft",
    "agl_ft": "position/h-agl-ft",
    "ecef_x_ft": "position/ecef-x-ft",
    "ecef_y_ft": "position/ecef-y-ft",
    "ecef_z_ft": "position/ecef-z-ft",
    "phi": "attitude/phi-rad",
    "theta": "attitude/theta-rad",
    "psi": "attitude/psi-rad",
    "p": "velocities/pi-rad_sec",
    "q": "velocities/qi-rad_sec",
    "r": "velocities/ri-rad_sec",
    "vn_fps": "velocities/v-north-fps",
    "ve_fps": "velocities/v-east-fps",
    "vd_fps": "velocities/v-down-fps",
    "vc_kt": "velocities/vc-kts",
    "vt_fps": "velocities/vt-fps",
    "ax_fps2": "accelerations/a-pilot-x-ft_sec2",
    "ay_fps2": "accelerations/a-pilot-y-ft_sec2",
    "az_fps2": "accelerations/a-pilot-z-ft_sec2",
    "nx": "accelerations/Nx",  # CG specific force / standard gravity (Nz positive up)
    "ny": "accelerations/Ny",
    "nz": "accelerations/Nz",
    "pdot": "accelerations/pdot-rad_sec2",
    "qdot": "accelerations/qdot-rad_sec2",
    "rdot": "accelerations/rdot-rad_sec2",
    "wow": "gear/wow",
}
WRITE = {
    "aileron": "fcs/aileron-cmd-norm",
    "elevator": "fcs/elevator-cmd-norm",
    "rudder": "fcs/rudder-cmd-norm",
    "flaps": "fcs/flap-cmd-norm",
    "gear": "gear/gear-cmd-norm",
    "speedbrake": "fcs/speedbrake-cmd-norm",
    "gust_n": "atmosphere/gust-north-fps",
    "gust_e": "atmosphere/gust-east-fps",
    "gust_d": "atmosphere/gust-down-fps",
    "wind_n": "atmosphere/wind-north-fps",
    "wind_e": "atmosphere/wind-east-fps",
    "wind_d": "atmosphere/wind-down-fps",
    "terrain_ft": "position/terrain-elevation-asl-ft",
}


class TrimError(RuntimeError):
    """JSBSim could not trim the aircraft in the requested condition."""


@dataclass(frozen=True)
class InitialCondition:
    lat_deg: float
    lon_deg: float
    h: float  # m, ellipsoidal
    track_deg: float
    calibrated_airspeed_kt: float
    flight_path_deg: float
    terrain_h: float  # m


class JSBSimAircraft:
    """One JSBSim aircraft: build, trim at an initial condition, step, read state.

    Parameters
    ----------
    model : JSBSim model name (a stock aircraft, or one under ``aircraft_dir``).
    engines : number of engines (throttle commands go to each: docs/design/physics-notes.md §throttle-of-every-engine).
    dt : integration step, s (default 1/120).
    aircraft_dir : optional directory holding ``<model>/<model>.xml``.
    """

    def __init__(self, model: str, engines: int, dt: float = 1.0 / 120.0,
                 aircraft_dir: Path | None = None) -> None:
        self._tmp = tempfile.mkdtemp(prefix="testbed-jsbsim-")
        root = jsbsim.get_default_root_dir()
        fdm = jsbsim.FGFDMExec(root)
        fdm.set_debug_level(0)
        fdm.disable_input()
        fdm.set_output_path(self._tmp)
        if aircraft_dir is not None:
            fdm.set_aircraft_path(str(aircraft_dir))
        if not fdm.load_model(model):
            self.close()
            raise ValueError(f"JSBSim could not load aircraft model {model!r}")
        fdm.disable_output()
        fdm.set_dt(dt)
        self.fdm, self.model, self.engines, self.dt = fdm, model, engines, dt
        pm = fdm.get_property_manager()
        missing = [p for p in list(READ.values()) + list(WRITE.values()) if not pm.hasNode(p)]
        if missing:
            self.close()
            raise ValueError(f"JSBSim model {model!r} lacks properties {missing}")
        self._r = {k: pm.get_node(p, False) for k, p in READ.items()}
        self._w = {k: pm.get_node(p, False) for k, p in WRITE.items()}
        self._thr = [pm.get_node(f"fcs/throttle-cmd-norm[{k}]", False) for k in range(engines)]
        if any(n is None for n in self._thr):
            self.close()
            raise ValueError(f"JSBSim model {model!r} has fewer than {engines} engines")

    # -- lifecycle -------------------------------------------------------------
    def close(self) -> None:
        shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> "JSBSimAircraft":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # belt and braces: never leave temp dirs behind
        try:
            self.close()
        except Exception:
            pass

    # -- set-up ----------------------------------------------------------------
    def trim(self, ic: InitialCondition, flaps: float, gear_down: bool, speed_brake: float,
             throttle_guess: float = 0.5) -> dict[str, float]:
        """Initialise and trim (JSBSim mode 1) in still air; returns the trimmed controls."""
        f = self.fdm
        f["ic/lat-geod-deg"] = ic.lat_deg
        f["ic/long-gc-deg"] = ic.lon_deg
        f["ic/terrain-elevation-ft"] = ic.terrain_h / FT
        f["ic/h-sl-ft"] = ic.h / FT
        f["ic/psi-true-deg"] = ic.track_deg
        f["ic/vc-kts"] = ic.calibrated_airspeed_kt
        f["ic/gamma-deg"] = ic.flight_path_deg
        if not f.run_ic():
            raise TrimError("JSBSim rejected the initial condition")
        f["propulsion/set-running"] = -1
        for n in self._thr:
            n.set_double_value(throttle_guess)
        self._w["flaps"].set_double_value(flaps)
        self._w["gear"].set_double_value(1.0 if gear_down else 0.0)
        self._w["speedbrake"].set_double_value(speed_brake)
        try:
            f.do_trim(1)
        except Exception as exc:  # JSBSim raises a generic error type
            raise TrimError(f"{self.model}: trim failed at {ic.calibrated_airspeed_kt} kt, "
                            f"{ic.h:.0f} m, flaps {flaps}: {exc}") from None
        return {"elevator": f["fcs/elevator-cmd-norm"], "aileron": f["fcs/aileron-cmd-norm"],
                "rudder": f["fcs/rudder-cmd-norm"], "throttle": f["fcs/throttle-cmd-norm[0]"],
                "theta": f["attitude/theta-rad"], "alpha": f["aero/alpha-rad"]}

    def set_wind_ned(self, wind_ms: np.ndarray) -> None:
        """Steady wind (m/s NED, blowing to). Set after trim: trim resets the wind."""
        for k, key in enumerate(("wind_n", "wind_e", "wind_d")):
            self._w[key].set_double_value(float(wind_ms[k]) / FT)

    def set_gust_ned(self, gust_ms: np.ndarray) -> None:
        self._w["gust_n"].set_double_value(float(gust_ms[0]) / FT)
        self._w["gust_e"].set_double_value(float(gust_ms[1]) / FT)
        self._w["gust_d"].set_double_value(float(gust_ms[2]) / FT)

    def set_terrain(self, h: float) -> None:
        """Terrain height under the aircraft (m); JSBSim's AGL follows it."""
        self._w["terrain_ft"].set_double_value(h / FT)

    # -- loop ------------------------------------------------------------------
    def command(self, aileron: float, elevator: float, rudder: float, throttle: float) -> None:
        self._w["aileron"].set_double_value(aileron)
        self._w["elevator"].set_double_value(elevator)
        self._w["rudder"].set_double_value(rudder)
        for n in self._thr:
            n.set_double_value(throttle)

    def step(self) -> None:
        self.fdm.run()

    @property
    def time(self) -> float:
        return self.fdm.get_sim_time()

    def read(self) -> dict[str, float]:
        """The state in SI units (m, m/s, rad, rad/s, m/s²)."""
        v = {k: n.get_double_value() for k, n in self._r.items()}
        return {
            "lat_deg": v["lat"], "lon_deg": v["lon"], "h": v["h_ft"] * FT, "agl": v["agl_ft"] * FT,
            "ecef": (v["ecef_x_ft"] * FT, v["ecef_y_ft"] * FT, v["ecef_z_ft"] * FT),
            "phi": v["phi"], "theta": v["theta"], "psi": v["psi"],
            "p": v["p"], "q": v["q"], "r": v["r"],
            "vel_ned": (v["vn_fps"] * FT, v["ve_fps"] * FT, v["vd_fps"] * FT),
            "cas": v["vc_kt"] * KT, "tas": v["vt_fps"] * FT,
            "f_eye_body": (v["ax_fps2"] * FT, v["ay_fps2"] * FT, v["az_fps2"] * FT),
            "f_cg_body": (v["nx"] * STANDARD_GRAVITY, v["ny"] * STANDARD_GRAVITY, -v["nz"] * STANDARD_GRAVITY),
            "omega_dot": (v["pdot"], v["qdot"], v["rdot"]),
            "on_ground": v["wow"] > 0.5,
        }
