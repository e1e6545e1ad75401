"""Camera sensor: pinhole camera, mount, dithering, attitude reference, landmarks, detections."""

from .attitude_ref import attitude_reference
from .camera import PinholeCamera, approach_camera, patent_T_pix_to_c, va_raim_2015_camera
from .detect import (FaultKind, VisionGeometry, VisionTruth, concat_geometry, sample_vision, slice_epochs,
                     synthesize_vision, vision_geometry)
from .dithering import camera_pose, dithering_angles, mount_from_settings
from .landmarks import Landmarks, build_landmarks, seed_triangle_settings, survey, zunz_runway_settings
from .settings import (AttitudeRefSettings, CameraSettings, DetectionSettings, DitheringSettings,
                       LandmarkSettings, MountSettings, VisionSettings)

__all__ = ["PinholeCamera", "approach_camera", "va_raim_2015_camera", "patent_T_pix_to_c",
           "synthesize_vision", "vision_geometry", "sample_vision", "concat_geometry",
           "slice_epochs", "VisionGeometry", "VisionTruth", "FaultKind", "attitude_reference", "dithering_angles",
           "camera_pose", "mount_from_settings", "Landmarks", "build_landmarks", "survey",
           "seed_triangle_settings", "zunz_runway_settings", "VisionSettings", "CameraSettings",
           "MountSettings", "DitheringSettings", "AttitudeRefSettings", "DetectionSettings",
           "LandmarkSettings"]
