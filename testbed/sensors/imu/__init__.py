"""IMU sensor: grade presets, error-free increments by inverse strapdown of the truth, the error model."""

from .settings import PRESETS, ImuSettings
from .synth import ImuErrorStream, apply_errors, apply_faults, sample_imu, true_increments

__all__ = ["ImuSettings", "PRESETS", "ImuErrorStream", "apply_errors", "apply_faults", "sample_imu", "true_increments"]
