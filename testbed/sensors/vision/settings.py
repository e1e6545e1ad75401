"""Settings models of the camera sensor (the ``[vision]`` and ``[landmarks]`` tables).

Every model is a :class:`~testbed.schema.StrictModel` (unknown keys are errors,
instances are frozen); defaults live here with their reasons. Angles in the
files are degrees (names end in ``_deg``); the code converts to radians.

Dithering / attitude-error axes are named ``roll, pitch, yaw`` and mean, for the
forward-looking camera: roll = about the optical axis (camera z), pitch = about
the camera x axis (image right), yaw = about the camera y axis (image down).
For the attitude *reference* (an aircraft quantity) they are the aircraft's
Euler angles.
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import Field, model_validator

from testbed.schema import LeverArm, StrictModel
from testbed.world import airport

from .camera import (APPROACH_HFOV_DEG, APPROACH_SIZE_PX, VA_RAIM_FOCAL_MM, VA_RAIM_SENSOR_MM,
                     PinholeCamera, approach_camera, va_raim_2015_camera)

NonNeg3 = tuple[Annotated[float, Field(ge=0.0)], Annotated[float, Field(ge=0.0)], Annotated[float, Field(ge=0.0)]]
AXES = ("roll", "pitch", "yaw")


# --------------------------------------------------------------------------- camera
class CameraSettings(StrictModel):
    """Intrinsics. ``preset`` picks a camera; ``custom`` takes exactly one of three forms:
    (a) width_px, height_px, hfov_deg; (b) width_px, height_px, focal_px;
    (c) dpi, focal_mm, sensor_width_mm, sensor_height_mm (pixel pitch = 25.4 mm / dpi).
    """

    preset: Literal["approach-1080p", "va-raim-2015", "custom"] = Field(
        "approach-1080p", description="approach-1080p: 1920x1080, 50 deg HFOV; va-raim-2015: the VA-RAIM paper's camera "
        "(needs dpi; 35 mm lens on a 36x24 mm sensor, assumed); custom: give the intrinsics")
    dpi: float | None = Field(None, gt=0, le=20_000, description="image resolution, dots per inch (va-raim-2015, custom form c)")
    width_px: int | None = Field(None, ge=16, le=1_000_000, description="image width, px (custom forms a, b)")
    height_px: int | None = Field(None, ge=16, le=1_000_000, description="image height, px (custom forms a, b)")
    hfov_deg: float | None = Field(None, ge=0.1, le=170, description="horizontal field of view, deg (custom form a)")
    focal_px: float | None = Field(None, ge=1, le=1e7, description="focal length, px (custom form b)")
    focal_mm: float | None = Field(None, gt=0, description=f"focal length, mm (custom form c; va-raim-2015 default {VA_RAIM_FOCAL_MM})")
    sensor_width_mm: float | None = Field(None, gt=0, description="sensor width, mm (form c)")
    sensor_height_mm: float | None = Field(None, gt=0, description="sensor height, mm (form c)")
    k1: float = Field(0.0, description="radial distortion k1 (Brown-Conrady, OpenCV)")
    k2: float = Field(0.0, description="radial distortion k2")
    p1: float = Field(0.0, description="tangential distortion p1")
    p2: float = Field(0.0, description="tangential distortion p2")

    @model_validator(mode="after")
    def _forms(self):
        given = {k for k in ("dpi", "width_px", "height_px", "hfov_deg", "focal_px", "focal_mm",
                             "sensor_width_mm", "sensor_height_mm") if getattr(self, k) is not None}
        if self.preset == "approach-1080p":
            extra = given - {"width_px", "height_px", "hfov_deg"}
            if extra:
                raise ValueError(f"preset approach-1080p takes only width_px/height_px/hfov_deg overrides, got {sorted(extra)}")
        elif self.preset == "va-raim-2015":
            if self.dpi is None:
                raise ValueError("preset va-raim-2015: expected dpi (the seed uses 120, 300, 480, 720), got none")
            extra = given - {"dpi", "focal_mm", "sensor_width_mm", "sensor_height_mm"}
            if extra:
                raise ValueError(f"preset va-raim-2015 takes dpi/focal_mm/sensor_*_mm, got also {sorted(extra)}")
        else:
            forms = [{"width_px", "height_px", "hfov_deg"}, {"width_px", "height_px", "focal_px"},
                     {"dpi", "focal_mm", "sensor_width_mm", "sensor_height_mm"}]
            if given not in forms:
                raise ValueError("custom camera: expected exactly one of {width_px, height_px, hfov_deg}, "
                                 "{width_px, height_px, focal_px}, {dpi, focal_mm, sensor_width_mm, "
                                 f"sensor_height_mm}}; got {sorted(given)}")
        return self

    def build(self) -> PinholeCamera:
        """The :class:`PinholeCamera` these settings describe."""
        dist = dict(k1=self.k1, k2=self.k2, p1=self.p1, p2=self.p2)
        if self.preset == "approach-1080p":
            cam = approach_camera(self.width_px or APPROACH_SIZE_PX[0], self.height_px or APPROACH_SIZE_PX[1],
                                  self.hfov_deg or APPROACH_HFOV_DEG)
        elif self.preset == "va-raim-2015":
            cam = va_raim_2015_camera(self.dpi, focal_mm=self.focal_mm or VA_RAIM_FOCAL_MM,
                                      sensor_mm=(self.sensor_width_mm or VA_RAIM_SENSOR_MM[0],
                                                 self.sensor_height_mm or VA_RAIM_SENSOR_MM[1]))
        elif self.hfov_deg is not None:
            cam = PinholeCamera.from_fov(self.width_px, self.height_px, self.hfov_deg)
        elif self.focal_px is not None:
            cam = PinholeCamera.from_focal_px(self.width_px, self.height_px, self.focal_px)
        else:
            cam = PinholeCamera.from_dpi(self.dpi, self.focal_mm, self.sensor_width_mm, self.sensor_height_mm)
        return cam.with_distortion(**dist)


# --------------------------------------------------------------------------- mount
class MountSettings(StrictModel):
    """Where the camera sits on the airframe and where it looks.

    Orientation: start from "looking along the body x axis, image top up"
    and apply yaw (right +), then pitch (up +), then roll (clockwise seen from
    behind +), all about body axes (aerospace 3-2-1). The default looks 9°
    below the body x axis: on a 3° path with the 737's ≈ 1–4° approach pitch
    attitude the touchdown zone sits 5–8° below the body axis, i.e. in the
    upper-middle of the image, with the horizon still in view.
    """

    lever_arm_body_m: LeverArm = Field((12.0, 0.0, 1.0), description="camera position from the CG, body FRD (m), "
                                       "at most 100 m long; default: a chin camera ~12 m ahead of a 737's CG, 1 m "
                                       "below it")
    roll_deg: float = Field(0.0, ge=-180, le=180, description="mount roll, deg")
    pitch_deg: float = Field(-9.0, ge=-90, le=90, description="mount pitch, deg (negative = looking down)")
    yaw_deg: float = Field(0.0, ge=-180, le=180, description="mount yaw, deg (positive = looking right)")


# --------------------------------------------------------------------------- dithering
class Tone(StrictModel):
    """A sinusoidal vibration of the camera: amplitude · sin(2π f t + phase) about one axis."""

    axis: Literal["roll", "pitch", "yaw"] = Field(..., description="rotation axis in camera axes: roll about the "
                                                                  "optical axis, pitch about image right, yaw "
                                                                  "about image down")
    freq_hz: float = Field(..., gt=0, description="tone frequency, Hz")
    amplitude_deg: float = Field(..., ge=0, description="tone amplitude (peak), deg")
    phase_deg: float | None = Field(None, description="phase, deg; None = drawn uniformly per flight from the rng")


class DitheringSettings(StrictModel):
    """Attitude dithering of the camera relative to its nominal mount (platform vibration).

    Angles are a small rotation vector in camera axes (roll about the optical axis, pitch about
    image right, yaw about image down). Band-limited noise: white Gaussian noise through a
    2nd-order Butterworth low-pass at ``noise_bandwidth_hz``, scaled so its
    stationary RMS is ``noise_rms_deg`` per axis.
    """

    tones: list[Tone] = Field(default_factory=lambda: [Tone(axis="pitch", freq_hz=12.0, amplitude_deg=0.02),
                                                       Tone(axis="yaw", freq_hz=12.0, amplitude_deg=0.01)],
                              description="vibration tones; default: a 12 Hz airframe mode, 0.02 deg pitch / 0.01 deg yaw")
    noise_rms_deg: NonNeg3 = Field((0.01, 0.02, 0.02), description="band-limited noise RMS (roll, pitch, yaw), deg")
    noise_bandwidth_hz: float = Field(5.0, gt=0, description="noise -3 dB bandwidth, Hz")
    enabled: bool = Field(True, description="False = the camera sits exactly on its nominal mount")


# --------------------------------------------------------------------------- attitude reference
class AttitudeRefSettings(StrictModel):
    """Error model of the navigation attitude reference (AHRS/IRS) the monitors use.

    Euler-angle errors per axis: a constant bias drawn once per flight
    N(0, bias_sigma²) plus white noise N(0, noise_sigma²) per epoch.
    Defaults: an AHRS-class unit (0.05° pitch/roll, 0.2° heading bias).
    """

    bias_sigma_deg: NonNeg3 = Field((0.05, 0.05, 0.2), description="per-flight bias 1-sigma (roll, pitch, heading), deg")
    noise_sigma_deg: NonNeg3 = Field((0.01, 0.01, 0.02), description="white noise 1-sigma (roll, pitch, heading), deg")


# --------------------------------------------------------------------------- detection
class DetectionSettings(StrictModel):
    """The landmark detector: visibility rules and its error model.

    Detected pixel = true + N(0, sigma_px²) per axis + motion blur of spread
    b = blur_factor · |ω| · exposure_s · f (|ω| the camera's angular rate,
    f the focal length in px): a point smeared uniformly over a streak of
    length L = |ω| t_exp f has a centroid spread of L/√12, the default factor.
    The blur comes from the camera's rotation during the exposure, so with
    ``blur_model = "rotation"`` (default) it is one rotation per frame that moves
    every landmark of the frame together, plus an own part of spread
    ``blur_independent`` · b per landmark; ``"independent"`` draws all of b apart
    for each landmark (the earlier model). The σ reported to the monitors is the
    per-landmark part. The blur's frame rotation is not published (it depends on
    the flown rates, ``VisionEpochs.dither_sigma`` is a static figure): VA-RAIM's
    cosines do not see it; the pixel monitor and the filter are told the
    dithering's rotation only: at ~1000 px and the default 4 ms exposure the
    blur's spread is 1.15 px per rad/s of camera rate, small beside a 1 px DE.
    """

    sigma_px: float = Field(1.0, ge=0, le=1000, description="detection error (DE) 1-sigma per axis, px (the VA-RAIM paper sweeps 1-4)")
    margin_px: float = Field(5.0, ge=0, description="detected only this far inside the image border, px")
    max_range_m: float = Field(20_000.0, gt=0, le=500_000, description="maximum detection range, m")
    min_size_px: float = Field(0.0, ge=0, description="minimum apparent landmark size, px (0 = rule off)")
    min_depth_m: float = Field(1.0, gt=0, description="closer than this along the optical axis counts as behind")
    exposure_s: float = Field(0.004, ge=0, description="exposure time, s (motion blur)")
    blur_factor: float = Field(0.2886751345948129, ge=0, description="blur std / streak length (1/sqrt(12))")
    blur_model: Literal["rotation", "independent"] = Field(
        "rotation", description="motion blur: 'rotation' (one camera rotation per frame, common to its landmarks, "
                                "plus blur_independent of it per landmark) or 'independent' (drawn per landmark)")
    blur_independent: float = Field(0.1, ge=0.0, le=1.0, description="blur_model 'rotation': the per-landmark part "
                                                                      "of the blur spread, as a fraction of it")
    sigma_told_px: float | None = Field(None, gt=0, description="sigma reported to the monitor, px; "
                                        "None = the model's own per-landmark sqrt(sigma_px² + blur²) "
                                        "(blur_model 'rotation': its per-landmark part)")


class FeatureSceneSettings(StrictModel):
    """Unsurveyed ground features for the GNSS/vision/INS filter (the ``ekf`` monitor; ``[vision.features]``):
    points on the terrain along the approach corridor that a tracker follows from frame to frame (:mod:`.features`).

    The scene is fixed by ``seed`` (the same ground for every flight and trial); the tracker reports the
    ``max_tracks`` nearest points in view, terrain-masked, with white pixel noise ``sigma_px`` and the
    camera's platform dithering, at the GNSS epochs (where the filter updates).
    """

    enabled: bool = Field(False, description="synthesise tracked ground features (read by the ekf monitor)")
    density_per_km2: float = Field(40.0, gt=0, le=10_000, description="points per km² of the corridor")
    half_width_m: float = Field(2_500.0, gt=0, le=20_000, description="the corridor's half width about the "
                                                                      "planned ground track, m")
    beyond_m: float = Field(4_000.0, ge=0, le=50_000, description="the corridor continues this far past the "
                                                                  "path's end (the camera looks ahead), m")
    max_range_m: float = Field(6_000.0, gt=0, le=100_000, description="the tracker's maximum range, m")
    max_tracks: int = Field(30, ge=1, le=500, description="the tracker follows at most this many points "
                                                         "(the nearest)")
    sigma_px: float = Field(1.0, ge=0, le=100, description="tracking error 1σ per axis, px")
    margin_px: float = Field(5.0, ge=0, description="tracked only this far inside the image border, px")
    seed: int = Field(0, ge=0, description="the scene's layout (not a trial's noise)")


class VisionSettings(StrictModel):
    """The camera sensor: rate, camera, mount, dithering, attitude reference, detector, ground features."""

    rate_hz: float = Field(10.0, gt=0, le=120, description="vision epoch rate, Hz (the truth is decimated to it; "
                           "at most the JSBSim rate)")
    camera: CameraSettings = Field(default_factory=CameraSettings, description="camera intrinsics and distortion")
    mount: MountSettings = Field(default_factory=MountSettings,
                                 description="where the camera sits and looks; without this table the aircraft "
                                             "file's camera_lever_arm_m, camera_pitch_down_deg and camera_yaw_deg "
                                             "set it (the defaults below are for keys a table leaves out)")
    dithering: DitheringSettings = Field(default_factory=DitheringSettings,
                                         description="vibration of the camera about its mount")
    attitude_ref: AttitudeRefSettings = Field(default_factory=AttitudeRefSettings,
                                              description="error model of the attitude reference the monitors use")
    detection: DetectionSettings = Field(default_factory=DetectionSettings,
                                         description="landmark detector: visibility rules and error model")
    features: FeatureSceneSettings = Field(default_factory=FeatureSceneSettings,
                                           description="unsurveyed ground features tracked for the ekf monitor")


# --------------------------------------------------------------------------- landmarks
class TriangleSet(StrictModel):
    """Landmarks on a circle (the VA-RAIM paper's: 3 points, radius 100 m, azimuths 0/120/240)."""

    kind: Literal["triangle"] = Field(..., description="landmark-set kind")
    prefix: str = Field("T", min_length=1, description="ids are prefix + 1, 2, ...")
    centre_lat_deg: float = Field(airport.VA_RAIM_CENTRE[0], ge=-90, le=90,
                                  description="latitude of the circle's centre, WGS84")
    centre_lon_deg: float = Field(airport.VA_RAIM_CENTRE[1], ge=-180, le=180,
                                  description="longitude of the circle's centre, WGS84")
    centre_h: float = Field(airport.VA_RAIM_CENTRE[2], description="centre height, m (WGS84)")
    radius_m: float = Field(100.0, gt=0, description="circle radius")
    azimuths_deg: list[float] = Field([0.0, 120.0, 240.0], min_length=1, description="from north, clockwise")
    height_m: float | None = Field(None, description="landmark height, m (WGS84); None = centre_h")
    size_m: float = Field(2.0, gt=0, description="physical size for the apparent-size rule, m")


class MarkerSet(StrictModel):
    """An "H" or "I" ground marker (the vision-integrity patent's); its outline corners are the landmarks.

    The letter lies flat at (lat, lon, h); ``heading_deg`` is the direction
    (from north, clockwise) its top points to. H: two uprights of
    ``stroke_m`` joined by a centre bar; I: a stem with top and bottom serifs.
    Both have 12 corners, listed counter-clockwise seen from above.
    """

    kind: Literal["marker"] = Field(..., description="landmark-set kind")
    letter: Literal["H", "I"] = Field(..., description="the letter's shape")
    prefix: str | None = Field(None, description="ids are prefix + 01..12; None = the letter")
    lat_deg: float = Field(..., ge=-90, le=90, description="latitude of the letter's centre, WGS84")
    lon_deg: float = Field(..., ge=-180, le=180, description="longitude of the letter's centre, WGS84")
    h: float = Field(..., description="marker height, m (WGS84)")
    height_m: float = Field(30.0, gt=0, description="letter height (along heading), m")
    width_m: float = Field(20.0, gt=0, description="letter width, m")
    stroke_m: float = Field(5.0, gt=0, description="stroke width, m")
    heading_deg: float = Field(0.0, description="direction the letter's top points, deg from north")
    size_m: float | None = Field(None, gt=0, description="corner feature size, m; None = stroke_m")

    @model_validator(mode="after")
    def _shape(self):
        if 2 * self.stroke_m >= min(self.width_m, self.height_m):
            raise ValueError(f"marker: stroke_m ({self.stroke_m}) must be under half of width_m ({self.width_m}) "
                             f"and height_m ({self.height_m})")
        return self


class RunwaySet(StrictModel):
    """The ZUNZ runway 05/23 outline (testbed.world.airport): threshold corners and edge points."""

    kind: Literal["runway"] = Field(..., description="landmark-set kind")
    prefix: str = Field("RWY", min_length=1, description="ids are prefix + 05L, 05R, 23R, 23L (threshold "
                                                        "corners) and L0300, R0300 ... (edge points, by distance "
                                                        "from the 05 threshold)")
    edge_spacing_m: float | None = Field(300.0, ge=1, description="edge points every this many m (≥ 1: an id names "
                                                               "the whole metre); None = corners only")
    width_m: float = Field(airport.RUNWAY_WIDTH_M, gt=0, description="paved width, m")
    size_m: float = Field(5.0, gt=0, description="feature size for the apparent-size rule, m")


class NamedPoint(StrictModel):
    """One landmark."""

    id: str = Field(..., min_length=1, description="landmark id (faults and outputs name it)")
    lat_deg: float = Field(..., ge=-90, le=90, description="latitude, WGS84")
    lon_deg: float = Field(..., ge=-180, le=180, description="longitude, WGS84")
    h: float = Field(..., description="height, m (WGS84 ellipsoidal)")
    size_m: float = Field(2.0, gt=0, description="physical size for the apparent-size rule")


class PointsSet(StrictModel):
    """Landmarks listed one by one."""

    kind: Literal["points"] = Field(..., description="landmark-set kind")
    points: list[NamedPoint] = Field(..., min_length=1, description="the landmarks, one table each")


LandmarkSet = Annotated[Union[TriangleSet, MarkerSet, RunwaySet, PointsSet], Field(discriminator="kind")]


class LandmarkSettings(StrictModel):
    """The landmark scene of an approach and the survey error of its coordinates."""

    sets: list[LandmarkSet] = Field(default_factory=lambda: [TriangleSet(kind="triangle")],
                                    min_length=1, description="landmark groups; default: the VA-RAIM paper's triangle")
    lpe_sigma_m: float = Field(0.05, ge=0, le=100, description="landmark position (survey) error 1-sigma per axis, m "
                               "(the VA-RAIM paper: 0.01-0.1), drawn once per flight")
