"""Path following and autothrottle on top of JSBSim (the airliners have no autopilot).

Cascaded loops, all in SI units:
- lateral: cross-track error and rate (+ a slow integral) -> bank command, plus
  the steady bank of an RF turn (feed-forward) -> aileron with roll-rate damping;
  a washed-out yaw damper on the rudder;
- vertical: height error against the profile -> vertical-speed command (on top of
  the profile's own descent rate) -> pitch command (PI) -> elevator with pitch-rate
  damping;
- speed: PI autothrottle on calibrated airspeed around the trimmed throttle.
Signs follow JSBSim: positive elevator command pitches nose down, positive
aileron command rolls right, positive rudder yaws right.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from testbed.flight.path import ApproachPath, PathState
from testbed.flight.settings import Gains

G0 = 9.80665


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


@dataclass
class Commands:
    aileron: float
    elevator: float
    rudder: float
    throttle: float


class Autopilot:
    """Stateful controller: call :meth:`update` once per integration step."""

    def __init__(self, path: ApproachPath, gains: Gains, trim: dict[str, float], speed_target: float,
                 dt: float) -> None:
        self.path, self.g, self.trim, self.v_ref, self.dt = path, gains, trim, speed_target, dt
        self.leg = 0
        self._xtk_int = 0.0
        self._vs_int = 0.0
        self._spd_int = 0.0
        self._r_wash = 0.0
        self.last: PathState | None = None
        self.h_error = 0.0

    def update(self, s: dict, e: float, n: float) -> Commands:
        g, dt = self.g, self.dt
        ps = self.path.locate(e, n, self.leg)
        self.leg, self.last = ps.leg, ps
        vn, ve, vd = s["vel_ned"]
        gs = math.hypot(vn, ve)
        course = math.atan2(ve, vn)

        # lateral
        xtk_rate = gs * math.sin(course - ps.track)
        self._xtk_int = _clip(self._xtk_int + ps.cross_track * dt, -2000.0, 2000.0)
        phi_ff = ps.turn_sign * math.atan(gs * gs / (G0 * ps.radius)) if ps.turn_sign else 0.0
        max_bank = math.radians(g.max_bank_deg)
        phi_cmd = _clip(phi_ff - g.k_xtk * ps.cross_track - g.k_xtk_rate * xtk_rate
                        - g.k_xtk_int * self._xtk_int, -max_bank, max_bank)
        aileron = _clip(self.trim["aileron"] + g.k_bank * (phi_cmd - s["phi"]) - g.k_roll_rate * s["p"], -1, 1)
        # washout filter (tau 3 s) so the damper does not fight a steady turn
        self._r_wash += (s["r"] - self._r_wash) * dt / 3.0
        rudder = _clip(self.trim["rudder"] - g.k_yaw_damper * (s["r"] - self._r_wash), -1, 1)

        # vertical
        h_path = self.path.height(ps.distance_to_go)
        self.h_error = s["h"] - h_path
        vs_path = -gs * math.tan(self.path.path_angle(ps.distance_to_go))
        vs_cmd = vs_path + _clip(-g.k_h * self.h_error, -g.max_vs_correction, g.max_vs_correction)
        vs_err = vs_cmd - (-vd)
        self._vs_int = _clip(self._vs_int + vs_err * dt, -200.0, 200.0)
        theta_cmd = _clip(self.trim["theta"] + g.k_vs * vs_err + g.k_vs_int * self._vs_int,
                          math.radians(-10), math.radians(15))
        elevator = _clip(self.trim["elevator"] - g.k_pitch * (theta_cmd - s["theta"]) + g.k_pitch_rate * s["q"], -1, 1)

        # speed
        spd_err = self.v_ref - s["cas"]
        self._spd_int = _clip(self._spd_int + spd_err * dt, -100.0, 100.0)
        throttle = _clip(self.trim["throttle"] + g.k_speed * spd_err + g.k_speed_int * self._spd_int, 0.0, 1.0)
        return Commands(aileron, elevator, rudder, throttle)
