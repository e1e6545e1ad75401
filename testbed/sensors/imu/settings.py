"""IMU settings: grade presets and the error model (docs/design/nav-filter.md §4).

Each axis of each sensor: output increment = (1 + s)·true increment + b·Δt + N·√Δt·ξ,
with b = b₀ + β: a turn-on bias b₀ ~ N(0, σ_b0²) drawn once per flight and an
in-run first-order Gauss–Markov bias β (time constant τ, stationary σ_GM); N the
angle / velocity random walk; s a scale-factor error ~ N(0, σ_s²) per flight.

Presets (rad, s, m units inside; the table gives them as published):

=============  ===========  ============  ==============  ====================  ===========  ==========================
preset         gyro bias    ARW           accel bias      VRW                   GM τ         source
=============  ===========  ============  ==============  ====================  ===========  ==========================
hg1700         1 °/h        0.125 °/√h    1 mg            0.065 ft/s/√h         3600 s       the paper's simulation;
                                                                                             NavToolkit hg1700_model
adis16364      25 °/h       2.0 °/√h      0.1 mg          0.12 m/s/√h           100 s        the paper's experiment;
                                                                                             datasheet (recheck)
consumer_mems  1 °/s on,    0.3 °/√h      20 mg on,       0.24 m/s/√h           100 s        MPU-6000-class noise
               20 °/h run                 0.2 mg run                                         densities (0.005 °/s/√Hz,
                                                                                             400 µg/√Hz); biases
                                                                                             illustrative
navigation     0.01 °/h     0.002 °/√h    25 µg           0.005 m/s/√h          3600 s       "typical" IRS class
perfect        0            0             0               0                     –            tests
=============  ===========  ============  ==============  ====================  ===========  ==========================

In-run σ equals the turn-on σ unless a preset says otherwise (consumer_mems).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from testbed.frames import DEG_PER_H
from testbed.schema import LeverArm, StrictModel

DEG_PER_SQRT_H = np.pi / 180.0 / 60.0  # rad/√s
MG = 9.80665e-3  # m/s²
PER_SQRT_H = 1.0 / 60.0  # (unit)/√h -> (unit)/√s

#: preset -> (gyro turn-on σ, gyro in-run σ, ARW, accel turn-on σ, accel in-run σ, VRW, τ_gyro, τ_accel)
PRESETS: dict[str, tuple[float, ...]] = {
    "hg1700": (1.0 * DEG_PER_H, 1.0 * DEG_PER_H, 0.125 * DEG_PER_SQRT_H, 1.0 * MG, 1.0 * MG,
               0.065 * 0.3048 * PER_SQRT_H, 3600.0, 3600.0),
    "adis16364": (25.0 * DEG_PER_H, 25.0 * DEG_PER_H, 2.0 * DEG_PER_SQRT_H, 0.1 * MG, 0.1 * MG,
                  0.12 * PER_SQRT_H, 100.0, 100.0),
    "consumer_mems": (3600.0 * DEG_PER_H, 20.0 * DEG_PER_H, 0.3 * DEG_PER_SQRT_H, 20.0 * MG, 0.2 * MG,
                      0.24 * PER_SQRT_H, 100.0, 100.0),
    "navigation": (0.01 * DEG_PER_H, 0.01 * DEG_PER_H, 0.002 * DEG_PER_SQRT_H, 0.025 * MG, 0.025 * MG,
                   0.005 * PER_SQRT_H, 3600.0, 3600.0),
    "perfect": (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 3600.0, 3600.0),
}


class ImuSettings(StrictModel):
    """The IMU sensor: grade (preset, or every figure given), rate, placement, Earth rotation."""

    grade: Literal["hg1700", "adis16364", "consumer_mems", "navigation", "perfect", "custom"] = Field(
        "hg1700", description="error preset (its figures: the table in testbed/sensors/imu/settings.py); 'custom' "
                              "takes every bias, in-run and random-walk figure below")
    rate_hz: float = Field(120.0, gt=0.0, le=1000.0, description="increment rate, Hz; must divide the truth rate")
    gyro_bias_sigma_rad_s: float | None = Field(None, ge=0.0, description="turn-on gyro bias 1σ (custom)")
    gyro_inrun_sigma_rad_s: float | None = Field(None, ge=0.0, description="in-run Gauss-Markov σ (custom)")
    arw_rad_sqrt_s: float | None = Field(None, ge=0.0, description="angle random walk (custom)")
    accel_bias_sigma_m_s2: float | None = Field(None, ge=0.0, description="turn-on accelerometer bias 1σ (custom)")
    accel_inrun_sigma_m_s2: float | None = Field(None, ge=0.0, description="in-run Gauss-Markov σ (custom)")
    vrw_m_s_sqrt_s: float | None = Field(None, ge=0.0, description="velocity random walk (custom)")
    gm_tau_s: float | None = Field(None, gt=0.0, description="in-run bias time constant (custom; both sensors)")
    scale_factor_ppm: float = Field(0.0, ge=0.0, le=1e5, description="scale-factor error 1σ per axis, ppm")
    lever_arm_body_m: LeverArm = Field((0.0, 0.0, 0.0), description="IMU position from the CG, body FRD, m; at "
                                                                    "most 100 m long")
    earth_rotation: bool = Field(True, description="the Earth's rate in the synthesis (and the mechanisation)")

    @model_validator(mode="after")
    def _custom(self):
        keys = ("gyro_bias_sigma_rad_s", "gyro_inrun_sigma_rad_s", "arw_rad_sqrt_s", "accel_bias_sigma_m_s2",
                "accel_inrun_sigma_m_s2", "vrw_m_s_sqrt_s", "gm_tau_s")
        given = [k for k in keys if getattr(self, k) is not None]
        if self.grade == "custom" and len(given) != len(keys):
            raise ValueError(f"grade 'custom' needs every one of {list(keys)}; missing "
                             f"{[k for k in keys if k not in given]}")
        if self.grade != "custom" and given:
            raise ValueError(f"{given} are only read with grade = 'custom' (the preset {self.grade!r} sets them)")
        return self

    def figures(self) -> dict[str, float]:
        """The error figures in SI units (rad, s, m)."""
        if self.grade == "custom":
            g = (self.gyro_bias_sigma_rad_s, self.gyro_inrun_sigma_rad_s, self.arw_rad_sqrt_s,
                 self.accel_bias_sigma_m_s2, self.accel_inrun_sigma_m_s2, self.vrw_m_s_sqrt_s, self.gm_tau_s,
                 self.gm_tau_s)
        else:
            g = PRESETS[self.grade]
        names = ("gyro_bias", "gyro_inrun", "arw", "accel_bias", "accel_inrun", "vrw", "tau_gyro", "tau_accel")
        return dict(zip(names, map(float, g)))
