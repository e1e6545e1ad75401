"""Settings every integrity monitor shares (``[integrity]``), and the pixel monitor's own (``[monitor.pixel]``).

Composed by ``testbed/config.py`` into the run configuration. Defaults are those of docs/design/integrity.md §3-§4 and §10; the sources do
not state P_FA / P_MD, so the values here are the testbed's recorded choice.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from testbed.integrity.levels import DEFAULT_P_FA, DEFAULT_P_MD, SERVICE_LEVELS
from testbed.schema import StrictModel


#: keys ``[integrity]`` had before the monitors got their own tables, and where they are now
MOVED_KEYS = {"p_ff": "[monitor.pixel] p_ff", "pixel_two_faults": "[monitor.pixel] two_faults",
              "pixel_attitude_noise": "[monitor.pixel] attitude_noise",
              "pixel_dither_noise": "[monitor.pixel] dither_noise", "pixel_h1": "[monitor.pixel] h1",
              "pixel_max_landmarks": "[monitor.pixel] max_landmarks",
              "pixel_vision_rows": "[monitor.pixel] vision_rows"}


class IntegritySettings(StrictModel):
    """What every monitor shares: the integrity risk allocation, PL variant, service levels, the FDE policy
    and solver tolerances."""

    @model_validator(mode="before")
    @classmethod
    def _moved(cls, data):
        moved = [f"{k} moved to {MOVED_KEYS[k]}" for k in (data if isinstance(data, dict) else ()) if k in MOVED_KEYS]
        if moved:
            raise ValueError("; ".join(moved))
        return data

    p_fa: float = Field(DEFAULT_P_FA, gt=0.0, lt=1.0,
                         description="Probability of false alarm per epoch; sets the chi-square threshold "
                                     "T² = χ²⁻¹(1 − P_FA; n − 4).")
    p_md: float = Field(DEFAULT_P_MD, gt=0.0, lt=1.0,
                        description="Probability of missed detection; sets k_md = Φ⁻¹(1 − P_MD/2) ('seed' PL) and "
                                    "λ_det with P(χ²_nc(n − 4, λ_det) < T²) = P_MD (pbias PL and the pixel monitor).")
    pl_variant: Literal["seed", "pbias"] = Field(
        "seed", description="GPS/VA-RAIM protection level: 'seed' = max slope·T + k_md·σ (the VA-RAIM paper's eq. "
                            "22-23); "
                            "'pbias' = max slope·sqrt(λ_det).")
    service_levels: tuple[str, ...] = Field(
        ("APV-I", "LPV-200", "APV-II"),
        description="Service levels whose availability (HPL ≤ HAL and VPL ≤ VAL) is reported, in this order.")
    fde: bool = Field(False, description="Fault exclusion after an alert (GPS RAIM, VA-RAIM, pixel monitor; "
                                         "testbed.integrity.fde): re-solve without each measurement unit, keep the "
                                         "exclusion whose reduced test passes, protect with the reduced geometry's PLs.")
    fde_rule: Literal["best", "unique"] = Field(
        "best", description="Which passing exclusion FDE takes: 'best' = the most consistent reduced test (largest "
                            "chi-square p-value); 'unique' = only when exactly one passes (else the alert stands).")
    fde_max_excluded: int = Field(1, ge=1, le=2, description="Measurement units FDE may exclude at one epoch (2: pairs "
                                                             "are tried when no single exclusion passes).")
    max_iter: int = Field(8, ge=1, le=50, description="Maximum Gauss-Newton iterations of the WLS solve.")
    tol_m: float = Field(1e-3, gt=0.0, description="WLS convergence: position step below this (m).")
    max_cond: float = Field(1e10, gt=1.0, description="Largest accepted (1-norm) condition number of the "
                                                      "Jacobi-scaled normal matrix GᵀWG; above it the epoch is "
                                                      "'singular geometry'.")

    @field_validator("service_levels")
    @classmethod
    def _known_levels(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        if not v:  # availability, the calibration criterion and the tables are per level
            raise ValueError(f"expected at least one service level, some of {list(SERVICE_LEVELS)}")
        unknown = [s for s in v if s not in SERVICE_LEVELS]
        if unknown:
            raise ValueError(f"unknown service level(s) {unknown}; expected some of {list(SERVICE_LEVELS)}")
        if len(set(v)) != len(v):
            raise ValueError(f"service levels repeated: {list(v)}")
        return v


class PixelOptions(StrictModel):
    """The pixel-domain monitor's own options (``[monitor.pixel]``)."""

    p_ff: float = Field(1e-7, gt=0.0, lt=1.0,
                        description="H1 (fault-free) risk: K_ff = Φ⁻¹(1 − P_ff/2) multiplies the "
                                    "horizontal error-ellipse semi-major axis (and the vertical sigma). The filter has its own, [monitor.ekf] p_ff.")
    two_faults: bool = Field(True, description="Include hypothesis H3 (two simultaneous "
                                                     "faults) in the protection level, as the patent does.")
    attitude_noise: bool = Field(True, description="Add the attitude-reference error, "
                                                         "propagated into pixels, to each landmark's 2×2 pixel "
                                                         "covariance.")
    dither_noise: bool = Field(True, description="Add the camera dithering the vision front end "
                                                       "publishes (its rms, VisionEpochs.dither_sigma), propagated "
                                                       "into pixels, to the pixel covariance.")
    h1: Literal["radial", "patent"] = Field(
        "radial", description="H1 multiplier of the horizontal error ellipse's semi-major axis: "
                              "'radial' = sqrt(-2 ln P_ff) (bounds the radial fault-free risk by P_ff); "
                              "'patent' = Φ⁻¹(1 − P_ff/2) as printed (a one-axis bound: up to 6.9 P_ff radially).")
    max_landmarks: int = Field(12, ge=1, le=1000, description="Landmarks used per epoch: the "
                                                                    "nearest detected one, then farthest-point picks "
                                                                    "in the image (the cost grows with the square of "
                                                                    "the rows and with the H3 pairs).")
    vision_rows: bool = Field(True, description="False = the patent's three-hypothesis rule on "
                                                      "the GNSS rows alone (what vision buys, for comparison).")
