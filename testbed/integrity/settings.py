"""Settings of the integrity monitors (GPS-only RAIM, pixel-domain monitor).

Composed by ``testbed/config.py`` into the run configuration (section
``[integrity]``). Defaults are INTEGRITY_MATH.md's; the seeds do not state
P_FA / P_MD, so the values here are the testbed's recorded choice.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from testbed.integrity.levels import DEFAULT_P_FA, DEFAULT_P_MD, SERVICE_LEVELS
from testbed.schema import StrictModel


class IntegritySettings(StrictModel):
    """Integrity risk allocation, PL variant, service levels and solver tolerances."""

    p_fa: float = Field(DEFAULT_P_FA, gt=0.0, lt=1.0,
                         description="Probability of false alarm per epoch; sets the chi-square threshold "
                                     "T² = χ²⁻¹(1 − P_FA; n − 4).")
    p_md: float = Field(DEFAULT_P_MD, gt=0.0, lt=1.0,
                        description="Probability of missed detection; sets k_md = Φ⁻¹(1 − P_MD/2) (seed PL) and "
                                    "λ_det with P(χ²_nc(n − 4, λ_det) < T²) = P_MD (pbias PL and the pixel monitor).")
    pl_variant: Literal["seed", "pbias"] = Field(
        "seed", description="GPS/VA-RAIM protection level: 'seed' = max slope·T + k_md·σ (seed 000 eq. 22-23); "
                            "'pbias' = max slope·sqrt(λ_det).")
    service_levels: tuple[str, ...] = Field(
        ("APV-I", "LPV-200", "APV-II"),
        description="Service levels whose availability (HPL ≤ HAL and VPL ≤ VAL) is reported, in this order.")
    p_ff: float = Field(1e-7, gt=0.0, lt=1.0,
                        description="Pixel monitor H1 (fault-free) risk: K_ff = Φ⁻¹(1 − P_ff/2) multiplies the "
                                    "horizontal error-ellipse semi-major axis (and the vertical sigma).")
    pixel_two_faults: bool = Field(True, description="Pixel monitor: include hypothesis H3 (two simultaneous "
                                                     "faults) in the protection level, as the patent does.")
    pixel_attitude_noise: bool = Field(True, description="Pixel monitor: add the attitude-reference error, "
                                                         "propagated into pixels, to each landmark's 2×2 pixel "
                                                         "covariance.")
    max_iter: int = Field(8, ge=1, le=50, description="Maximum Gauss-Newton iterations of the WLS solve.")
    tol_m: float = Field(1e-3, gt=0.0, description="WLS convergence: position step below this (m).")
    max_cond: float = Field(1e10, gt=1.0, description="Largest accepted (1-norm) condition number of the "
                                                      "Jacobi-scaled normal matrix GᵀWG; above it the epoch is "
                                                      "'singular geometry'.")

    @field_validator("service_levels")
    @classmethod
    def _known_levels(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [s for s in v if s not in SERVICE_LEVELS]
        if unknown:
            raise ValueError(f"unknown service level(s) {unknown}; expected some of {list(SERVICE_LEVELS)}")
        if len(set(v)) != len(v):
            raise ValueError(f"service levels repeated: {list(v)}")
        return v
