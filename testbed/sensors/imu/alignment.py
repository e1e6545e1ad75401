"""The alignment pseudo-sensor (docs/design/nav-filter.md §4): an initial navigation state and its published 1σ.

Before the filter's first epoch a real system aligns (levelling from the
accelerometers, heading from a gyrocompass or the last known state, the clock
from a first fix); the testbed draws that result: the true start ⊕ ξ with
ξ ~ N(0, diag(σ²)), and publishes σ (the filter starts with P₀ = diag(σ²)).
IMU biases start at zero with the grade's bias σ; the clock drift at zero with
the receiver's drift σ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from testbed.inertial import so3_exp
from testbed.records import NavInit


@dataclass(frozen=True)
class AlignmentSigmas:
    """The alignment's published 1σ."""

    pos_m: float = 3.0
    vel_m_s: float = 0.1
    roll_pitch_rad: float = float(np.radians(0.05))
    heading_rad: float = float(np.radians(0.2))
    clock_bias_m: float = 100.0
    clock_drift_m_s: float = 1.0


def align(t0: float, C: NDArray, v: NDArray, p: NDArray, clock_bias: NDArray, clock_drift: NDArray,
          imu_figures: dict, rng: np.random.Generator, n_trials: int | None = None,
          sig: AlignmentSigmas = AlignmentSigmas()) -> NavInit:
    """The true start (C body→world (3, 3), v, p (3,), clock bias and drift (B,) or scalars) ⊕ ξ.

    The drawn error ξ (B, 17) is the filter's initial error: estimate = truth ⊖ ξ.
    """
    B = 1 if n_trials is None else int(n_trials)
    sd = np.zeros(17)
    sd[0:3], sd[3:6] = sig.pos_m, sig.vel_m_s
    sd[6:9] = [sig.roll_pitch_rad, sig.roll_pitch_rad, sig.heading_rad]
    sd[9:12] = np.hypot(imu_figures.get("accel_bias", 0.0), imu_figures.get("accel_inrun", 0.0))
    sd[12:15] = np.hypot(imu_figures.get("gyro_bias", 0.0), imu_figures.get("gyro_inrun", 0.0))
    sd[15], sd[16] = sig.clock_bias_m, sig.clock_drift_m_s
    xi = rng.standard_normal((B, 17)) * sd
    cb = np.broadcast_to(np.asarray(clock_bias, float), (B,))
    cd = np.broadcast_to(np.asarray(clock_drift, float), (B,))
    init = NavInit(t=float(t0), C=so3_exp(-xi[:, 6:9]) @ np.asarray(C, float), v=np.asarray(v, float) - xi[:, 3:6],
                   p=np.asarray(p, float) - xi[:, 0:3], clock_bias=cb - xi[:, 15], clock_drift=cd - xi[:, 16],
                   sigma=sd)
    if n_trials is None:
        init = NavInit(t=init.t, C=init.C[0], v=init.v[0], p=init.p[0], clock_bias=init.clock_bias[0],
                       clock_drift=init.clock_drift[0], sigma=sd)
    return init
