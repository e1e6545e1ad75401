"""Landmark detections: from the true aircraft pose to what the vision front end reports.

The synthesis is split in two so the closed loop can run it block by block:

* :func:`vision_geometry` (truth only, no randomness, no cross-epoch state):
  per vision epoch the nominal camera pose (truth attitude × mount, camera
  position = CG + R_body_to_ecef · lever arm), the camera-to-landmark vectors
  and ranges, the terrain line of sight (and the line of sight to where a
  :class:`~testbed.sensors.faults.LandmarkMoved` fault puts a landmark). It takes
  the truth *already at the vision epochs*; geometries of consecutive truth
  blocks concatenate (:func:`concat_geometry`) to the geometry of the whole.
* :func:`sample_vision` (every random draw and the rest), per epoch:

  1. true camera attitude = nominal × dithering (:mod:`.dithering`);
  2. ideal pixel of each landmark's *actual* position (true, or surveyed + Δ
     while a LandmarkMoved fault is active), then the lens distortion (the
     detector works in the raw image);
  3. visibility, first failing rule gives the reason (:class:`~testbed.records.NotVisible`):
     behind the camera (AIRFRAME), outside the image less a margin (OUT_OF_IMAGE),
     beyond the maximum range (TOO_FAR), terrain between camera and landmark
     (TERRAIN), apparent size f·size/range below ``min_size_px`` (TOO_SMALL);
  4. detected pixel = raw pixel + detection error + motion blur, b = blur_factor ·
     |ω_cam| · t_exp · f the blur's spread (ω_cam the camera's angular rate: body
     rate + dithering rate). ``blur_model = "rotation"`` (default): the blur of a
     frame is one rotation of the camera during the exposure, ε = u · blur_factor ·
     t_exp · ω_cam with u ~ N(0, 1) per frame, which moves every landmark of the
     frame together (re-projected exactly), plus N(0, σ_DE² + (blur_independent·b)²)
     per landmark and axis; ``"independent"``: N(0, σ_DE² + b²) per landmark and
     axis (the blur drawn apart for each landmark). Then a pixel-bias fault; then undistorted back to the ideal pinhole image the
     monitors use (``VisionEpochs.K``); a misassociation swaps two slots last.

* :func:`synthesize_vision` = decimate the truth to ``settings.rate_hz``, then
  ``sample_vision(vision_geometry(...))``.

Random streams: ``rng`` spawns one child generator per component
(:data:`RNG_STREAMS`: survey error, dithering, attitude reference, detection
noise, fault targets; the last spawns one per fault), each drawing its
time-dependent array once, time-major, after its fixed-size draws. Without
``n_trials`` the output is therefore *prefix stable*: sampling the first T1
epochs of a geometry gives, bit for bit, the first T1 epochs of sampling any
longer prefix with an identically seeded ``rng``. A random fault target
depends only on the epochs up to its onset.

With ``n_trials`` every random quantity gets a leading trial axis (then not
prefix stable, but deterministic); the geometry, including the terrain
line of sight, is computed once per trajectory.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from testbed.frames import R_ecef_to_enu, R_to_q, ecef_to_geodetic
from testbed.records import Mount, NotVisible, Truth, VisionEpochs, epoch_array
from testbed.sensors.faults import LandmarkMoved, Misassociation, PixelBias, VISION_KINDS, active

from .attitude_ref import attitude_draws, attitude_reference_from_draws, q_to_euler
from .camera import PinholeCamera
from .dithering import camera_pose, dither_rms_cam, dithering_parts, mount_from_settings
from .landmarks import Landmarks, build_landmarks, survey
from .settings import DetectionSettings, LandmarkSettings, VisionSettings

#: Child generators spawned from ``rng`` by :func:`sample_vision`, in this order.
RNG_STREAMS = ("survey", "dithering", "attitude_ref", "noise", "faults")


@dataclass(frozen=True)
class VisionDraws:
    """The Gaussian draws of one :func:`sample_vision` call that an importance-sampling proposal may move
    (``tilt``), in standard units: ``detection`` (B..., T, L, 2) the detection error over its σ (DE and the per-landmark
    blur), ``blur`` (B..., T) the frame's blur rotation over its spread (``blur_model = "rotation"``; zeros with
    ``"independent"``, which draws none), ``attitude_bias`` (B..., 1, 3) and ``attitude_noise`` (B..., T, 3) the
    attitude reference's errors over their σ (roll, pitch, heading), ``dither_noise`` (B..., T, 3) the dithering's
    band-limited noise at the epochs over its σ (camera axes; a move is made through the noise's white grid,
    :func:`~.dithering.dithering_parts`, so the noise stays the filter's). ``dither_tone_angle`` and
    ``dither_tone_rate`` (B..., T, 3) rad, rad/s are the dithering's tones, of random phase (not Gaussian: a
    proposal leaves them; the probe of a monitor's linear model zeroes them for the error-free scene)."""

    detection: NDArray
    blur: NDArray
    attitude_bias: NDArray
    attitude_noise: NDArray
    dither_noise: NDArray
    dither_tone_angle: NDArray
    dither_tone_rate: NDArray


class FaultKind:
    """Codes of ``VisionTruth.fault_kind`` (0 = none)."""

    NONE, PIXEL_BIAS, LANDMARK_MOVED, MISASSOCIATION = 0, 1, 2, 3


@dataclass(frozen=True)
class VisionTruth:
    """Truth side of the vision synthesis (evaluation only; monitors never see it).

    Attributes
    ----------
    t : (T,) s, vision epochs.
    cam_pos_ecef : (T, 3) m, true camera position.
    q_cam_to_ecef : (B..., T, 4) true camera attitude (with dithering), scalar last.
    dither_cam : (B..., T, 3) rad, dithering rotation vector in camera axes (x pitch, y yaw, z roll).
    attitude_ref_error : (B..., T, 3) rad, (roll, pitch, heading) error of the attitude reference.
    landmark_true_ecef : (L, 3) m, true landmark positions.
    landmark_survey_ecef : (B..., L, 3) m, surveyed positions (what the monitor gets).
    landmark_moved_ecef : (B..., L, 3) m, where a moved landmark stands during its fault
        (= true position for landmarks no fault moves, and for all while no LandmarkMoved
        onset lies within ``t``: a random target is drawn at the onset). The one field
        that is not prefix stable before the onset (the per-epoch ``landmark_moved`` is).
    landmark_moved : (B..., T, L) bool, landmark displaced by a LandmarkMoved fault at that epoch.
    pixel_true : (B..., T, L, 2) px, ideal pinhole pixel of the actual landmark under the true
        camera pose (before noise and faults; NaN behind the camera).
    range_m : (B..., T, L) m, true camera-to-landmark distance.
    visible : (B..., T, L) bool, nominal visibility of each slot (before a misassociation swap).
    noise_px : (B..., T, L, 2) px, drawn nominal detection error (DE + blur), in the raw image.
    blur_sigma_px : (B..., T) px, motion-blur std.
    fault_pixel_bias : (B..., T, L, 2) px, injected pixel bias.
    faulty : (B..., T, L) bool, the reported measurement in this slot is faulty.
    fault_kind : (B..., T, L) int8 :class:`FaultKind` code.
    """

    t: NDArray = epoch_array(batched=False)
    cam_pos_ecef: NDArray = epoch_array(1)
    q_cam_to_ecef: NDArray = epoch_array(1)
    dither_cam: NDArray = epoch_array(1)
    attitude_ref_error: NDArray = epoch_array(1)
    landmark_true_ecef: NDArray = field()
    landmark_survey_ecef: NDArray = field()
    landmark_moved_ecef: NDArray = field()
    landmark_moved: NDArray = epoch_array(1)
    pixel_true: NDArray = epoch_array(2)
    range_m: NDArray = epoch_array(1)
    visible: NDArray = epoch_array(1)
    noise_px: NDArray = epoch_array(2)
    blur_sigma_px: NDArray = epoch_array()
    fault_pixel_bias: NDArray = epoch_array(2)
    faulty: NDArray = epoch_array(1)
    fault_kind: NDArray = epoch_array(1)


def visibility(camera: PinholeCamera, det: DetectionSettings, p_cam: NDArray, range_m: NDArray,
               size_m: NDArray, los: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Apply the visibility rules to points in camera axes.

    Parameters
    ----------
    p_cam : (..., L, 3) m, landmark in camera axes.  range_m : (..., L) m.
    size_m : (L,) m.  los : (..., L) bool, terrain line of sight clear.

    Returns
    -------
    uv_raw : (..., L, 2) px, pixel in the raw (distorted) image (NaN behind the camera).
    visible : (..., L) bool.  reason : (..., L) int8 :class:`NotVisible` code (first failing rule).
    """
    return _visibility(camera, det, p_cam, range_m, size_m, los)[1:]


def _visibility(camera, det, p_cam, range_m, size_m, los):
    """:func:`visibility` also returning, first, the ideal pinhole pixel ``(..., L, 2)``."""
    uv_ideal, in_front = camera.project(p_cam, min_depth=det.min_depth_m)
    uv_raw = camera.distort(uv_ideal)
    in_img = camera.in_image(uv_raw, det.margin_px)
    too_far = range_m > det.max_range_m
    size_px = camera.fx * size_m / np.maximum(range_m, 1e-9)
    too_small = (det.min_size_px > 0) & (size_px < det.min_size_px)
    reason = np.select([~in_front, ~in_img, too_far, ~los, too_small],
                       [NotVisible.AIRFRAME, NotVisible.OUT_OF_IMAGE, NotVisible.TOO_FAR, NotVisible.TERRAIN,
                        NotVisible.TOO_SMALL], NotVisible.VISIBLE).astype(np.int8)
    return uv_ideal, uv_raw, reason == NotVisible.VISIBLE, reason


def rotation_shift(camera, det: DetectionSettings, p_cam: NDArray, rotvec: NDArray, uv_raw: NDArray) -> NDArray:
    """Raw-image shift (B..., T, L, 2) px of every landmark (camera-axes points ``p_cam`` (B..., T, L, 3)) when
    the camera turns by the small rotation ``rotvec`` (B..., T, 3) rad in its own axes (attitude × exp([ε]×),
    as the dithering turns it): the exact re-projection, lens distortion included; NaN where not projectable."""
    R = Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_matrix().reshape(rotvec.shape[:-1] + (3, 3))
    p = np.einsum("...ji,...lj->...li", R, p_cam)  # Rᵀ p: the points seen from the turned camera
    uv, _ = camera.project(p, min_depth=det.min_depth_m)
    return camera.distort(uv) - uv_raw


def _line_of_sight(terrain, cam_pos: NDArray, lm_pos: NDArray, candidates: NDArray) -> NDArray:
    """Terrain LOS ``(T, L)`` for camera ``(T, 3)`` and landmarks ``(L, 3)`` or ``(T, L, 3)``.

    Only ``candidates`` (T, L) pairs are asked (others count as clear: another rule
    already hides them); ``terrain`` None = no terrain.
    """
    T, L = candidates.shape
    los = np.ones((T, L), bool)
    if terrain is None or not candidates.any():
        return los
    ti, li = np.nonzero(candidates)
    tgt = lm_pos[li] if lm_pos.ndim == 2 else lm_pos[ti, li]
    res = np.asarray(terrain.line_of_sight(cam_pos[ti], tgt), bool)
    if res.shape != ti.shape:
        raise ValueError(f"terrain.line_of_sight: expected a result of shape {ti.shape}, got {res.shape}")
    los[ti, li] = res
    return los


def _select(fault, name: str, lm: Landmarks, det_at_onset: NDArray, rng: np.random.Generator) -> NDArray:
    """Slot index per trial ``(B...,)`` a fault targets; -1 = none (random and nothing detected)."""
    batch = det_at_onset.shape[:-1]
    if name != "random":
        return np.full(batch, lm.index(name), int)
    score = rng.random(det_at_onset.shape)
    score = np.where(det_at_onset, score, -1.0)
    k = np.argmax(score, axis=-1)
    return np.where(np.take_along_axis(score, k[..., None], -1)[..., 0] >= 0, k, -1)


def _as_landmarks(landmarks: Landmarks | LandmarkSettings) -> Landmarks:
    return build_landmarks(landmarks) if isinstance(landmarks, LandmarkSettings) else landmarks


def _vision_faults(faults: list | None) -> list:
    return [f for f in (faults or []) if getattr(f, "kind", None) in VISION_KINDS]


def geometry_faults(faults: list | None) -> list:
    """The faults :func:`vision_geometry` reads (LandmarkMoved); the rest are :func:`sample_vision`'s."""
    return [f for f in _vision_faults(faults) if isinstance(f, LandmarkMoved)]


def _moved_key(f: LandmarkMoved) -> NDArray:
    """(5,) the LandmarkMoved parameters its terrain line of sight depends on: delta ENU, onset, end."""
    return np.array([*map(float, f.delta_enu_m), f.onset_s, np.inf if f.end_s is None else f.end_s])


def _moved_offset_ecef(lm: Landmarks, delta_enu_m) -> NDArray:
    """(L, 3) m, the ECEF offset of ``delta_enu_m`` (ENU at each landmark)."""
    lat, lon, _ = ecef_to_geodetic(lm.pos_ecef)
    return np.einsum("lji,j->li", R_ecef_to_enu(lat, lon), np.asarray(delta_enu_m, float))


# Fields of VisionGeometry indexed by epoch (axis 0); the others are per-flight constants.
_GEOMETRY_EPOCH_FIELDS = ("t", "cam_pos_ecef", "R_cam_to_ecef", "omega_cam", "euler", "diff_ecef", "range_m",
                          "los", "los_moved")


@dataclass(frozen=True, eq=False)
class VisionGeometry:
    """Truth-only part of the vision synthesis, per vision epoch (no randomness, no dithering).

    Every epoch-indexed array has the epoch on axis 0 and depends only on that
    epoch's truth, so geometries of consecutive truth blocks concatenate
    (:func:`concat_geometry`) to the geometry of the whole flight, bit for bit;
    ``geometry[a:b]`` slices epochs.

    Attributes
    ----------
    t : (T,) s, vision epochs.
    cam_pos_ecef : (T, 3) m, camera position (CG + lever arm rotated by the true attitude).
    R_cam_to_ecef : (T, 3, 3) nominal camera attitude (truth × mount, before dithering).
    omega_cam : (T, 3) rad/s, true body rate in nominal camera axes.
    euler : (T, 3) rad, true (roll, pitch, heading) (``q_to_euler`` of the truth quaternion).
    diff_ecef : (T, L, 3) m, true landmark position minus camera position.
    range_m : (T, L) m, its norm.
    los : (T, L) bool, terrain line of sight clear (asked only within ``max_range_m``;
        True beyond it, where TOO_FAR hides the landmark first).
    los_moved : (T, F, L) bool, terrain line of sight to each landmark displaced by the
        F-th LandmarkMoved fault of ``moved_keys`` (asked only while that fault is active).
    moved_keys : (F, 5) (delta E, N, U m, onset s, end s or inf) of those faults.
    landmark_id : (L,) ids of the scene the geometry was built for.
    has_terrain : a terrain was given (else every line of sight is clear and F = 0).
    mount : the camera mount used.  max_range_m : the detector's maximum range used.
    """

    t: NDArray
    cam_pos_ecef: NDArray
    R_cam_to_ecef: NDArray
    omega_cam: NDArray
    euler: NDArray
    diff_ecef: NDArray
    range_m: NDArray
    los: NDArray
    los_moved: NDArray
    moved_keys: NDArray
    landmark_id: NDArray
    has_terrain: bool
    mount: Mount
    max_range_m: float

    def __len__(self) -> int:
        return int(self.t.size)

    def __getitem__(self, idx) -> "VisionGeometry":
        """Epochs ``idx`` (a slice or an index array) of the geometry."""
        if isinstance(idx, (int, np.integer)):
            raise TypeError("VisionGeometry: index with a slice or an index array (epochs), not a scalar")
        return replace(self, **{k: getattr(self, k)[idx] for k in _GEOMETRY_EPOCH_FIELDS})

    def concat(self, *others: "VisionGeometry") -> "VisionGeometry":
        """This geometry followed by ``others`` (see :func:`concat_geometry`)."""
        return concat_geometry([self, *others])

    def same_constants(self, other: "VisionGeometry") -> bool:
        """True if both were built for the same scene, mount, range limit, terrain use and moved faults."""
        return (np.array_equal(self.landmark_id, other.landmark_id) and self.has_terrain == other.has_terrain
                and np.array_equal(self.moved_keys, other.moved_keys) and self.max_range_m == other.max_range_m
                and np.array_equal(self.mount.lever_arm_body, other.mount.lever_arm_body)
                and np.array_equal(self.mount.R_sensor_to_body, other.mount.R_sensor_to_body))


def concat_geometry(parts: list[VisionGeometry]) -> VisionGeometry:
    """Concatenate the geometries of consecutive truth blocks along the epoch axis.

    Parameters
    ----------
    parts : geometries built with the same settings, landmarks, terrain use and faults
        (ValueError otherwise), in time order (not checked: blocks are the caller's).

    Returns
    -------
    The geometry of all their epochs; equal, bit for bit, to :func:`vision_geometry`
    of the concatenated truth.
    """
    parts = list(parts)
    if not parts:
        raise ValueError("concat_geometry: expected at least one geometry, got none")
    first = parts[0]
    for k, g in enumerate(parts[1:], 1):
        if not first.same_constants(g):
            raise ValueError(f"concat_geometry: part {k} was built for another scene, mount, range limit, "
                             "terrain use or LandmarkMoved fault set than part 0")
    return replace(first, **{k: np.concatenate([getattr(g, k) for g in parts], axis=0)
                             for k in _GEOMETRY_EPOCH_FIELDS})


def vision_geometry(truth: Truth, settings: VisionSettings, *, landmarks: Landmarks | LandmarkSettings,
                    terrain=None, faults: list | None = None) -> VisionGeometry:
    """The truth-only part of the vision synthesis at the epochs of ``truth``.

    Parameters
    ----------
    truth : the flight *at the vision epochs* (no decimation here: :func:`synthesize_vision`
        decimates to ``settings.rate_hz``; the closed loop hands blocks already at that rate).
    settings : uses the mount and ``detection.max_range_m`` (the rest is :func:`sample_vision`'s).
    landmarks : the scene (built :class:`Landmarks` or its settings).
    terrain : an object with ``line_of_sight(origin_ecef (..., 3), target_ecef (..., 3)) -> bool (...)``,
        or None (no terrain masking).
    faults : the fault schedule; only the LandmarkMoved faults are used (the terrain line of sight
        to where they put the landmarks). Pass the same schedule to :func:`sample_vision`.

    Returns
    -------
    :class:`VisionGeometry` with T = ``len(truth.t)``; computed epoch by epoch, so the
    geometries of consecutive blocks concatenate (:func:`concat_geometry`) to the whole's.
    """
    lm = _as_landmarks(landmarks)
    mount = mount_from_settings(settings.mount)
    max_range = float(settings.detection.max_range_m)
    t = np.asarray(truth.t, float)
    T, L = t.size, len(lm)
    cam_pos, R_c2e0 = camera_pose(truth.pos_ecef, truth.q_body_to_enu, mount)  # (T, 3), (T, 3, 3)
    diff0 = lm.pos_ecef[None, :, :] - cam_pos[:, None, :]  # (T, L, 3)
    range0 = np.linalg.norm(diff0, axis=-1)
    los0 = _line_of_sight(terrain, cam_pos, lm.pos_ecef, range0 <= max_range)
    moved = geometry_faults(faults) if terrain is not None else []
    keys = np.array([_moved_key(f) for f in moved]).reshape(-1, 5)
    los_moved = np.ones((T, len(moved), L), bool)
    for k, f in enumerate(moved):
        # once per trajectory, at the true position + delta (cm survey errors do not matter to terrain)
        on = active(f, t)
        los_moved[:, k, :] = _line_of_sight(terrain, cam_pos, lm.pos_ecef + _moved_offset_ecef(lm, f.delta_enu_m),
                                            np.broadcast_to(on[:, None], (T, L)))
    return VisionGeometry(t=t, cam_pos_ecef=cam_pos, R_cam_to_ecef=R_c2e0,
                          omega_cam=np.asarray(truth.omega_body, float) @ mount.R_sensor_to_body,
                          euler=q_to_euler(truth.q_body_to_enu), diff_ecef=diff0, range_m=range0, los=los0,
                          los_moved=los_moved, moved_keys=keys, landmark_id=lm.id.copy(),
                          has_terrain=terrain is not None, mount=mount, max_range_m=max_range)


def _spawn(rng: np.random.Generator, n: int) -> list[np.random.Generator]:
    """``n`` independent child generators, deterministic in ``rng``'s seed."""
    try:
        return rng.spawn(n)
    except TypeError:  # a bit generator without a SeedSequence: seed one from the stream
        return np.random.default_rng(rng.integers(0, 2**63, size=4)).spawn(n)


def _check_geometry(g: VisionGeometry, settings: VisionSettings, lm: Landmarks) -> None:
    if not np.array_equal(g.landmark_id, lm.id):
        raise ValueError(f"sample_vision: the geometry was built for landmarks {list(g.landmark_id)}, "
                         f"got {list(lm.id)}")
    mount = mount_from_settings(settings.mount)
    if not (np.array_equal(g.mount.lever_arm_body, mount.lever_arm_body)
            and np.array_equal(g.mount.R_sensor_to_body, mount.R_sensor_to_body)
            and g.max_range_m == settings.detection.max_range_m):
        raise ValueError("sample_vision: the geometry was built with another mount or max_range_m than `settings`")


def _given_survey(survey_ecef: NDArray, lm: Landmarks) -> NDArray:
    s = np.asarray(survey_ecef, float)
    if s.shape[-2:] != lm.pos_ecef.shape:
        raise ValueError(f"survey_ecef: expected (..., {len(lm)}, 3) surveyed positions, got shape {s.shape}")
    return s


def _check_rng_trials(rng, n_trials) -> None:
    """Fail early, before any geometry is computed, on a bad generator or trial count."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: expected numpy.random.Generator, got {type(rng).__name__}")
    if n_trials is not None and int(n_trials) < 1:
        raise ValueError(f"n_trials: expected >= 1 or None, got {n_trials}")


def sample_vision(geometry: VisionGeometry, settings: VisionSettings, *, landmarks: Landmarks | LandmarkSettings,
                  faults: list | None = None, rng: np.random.Generator,
                  n_trials: int | None = None, survey_ecef: NDArray | None = None,
                  share: Callable[..., Any] | None = None,
                  tilt: Callable[[VisionDraws], VisionDraws] | None = None) -> tuple[VisionEpochs, VisionTruth]:
    """Random part of the vision synthesis: detections from a :class:`VisionGeometry`.

    Parameters
    ----------
    geometry : from :func:`vision_geometry` (or :func:`concat_geometry` of blocks), built with
        the same ``settings`` mount and max range, ``landmarks`` and LandmarkMoved faults.
    settings : camera, dithering, attitude reference, detector (``rate_hz`` sets the
        dithering noise grid, not a decimation).
    landmarks : the scene (built :class:`Landmarks` or its settings).
    faults : a fault schedule; only the vision kinds (pixel_bias, landmark_moved,
        misassociation) are used.
    rng : the only source of randomness; it spawns one child per entry of
        :data:`RNG_STREAMS` (survey error, dithering, attitude reference, detection
        noise, fault targets with one grandchild per vision fault). Without
        ``n_trials`` the result is prefix stable: with an identically seeded ``rng``
        (e.g. ``np.random.default_rng(seed)`` made afresh for each call),
        ``sample_vision(geometry[:T1])`` equals the first T1 epochs of
        ``sample_vision(geometry[:T2])`` for T1 < T2, bit for bit.
    n_trials : when given, a leading trial axis B = (n_trials,) on every random output.
    survey_ecef : the surveyed landmark positions the monitors are given, ``(L, 3)`` (one survey for
        every trial) or ``(B..., L, 3)``; None draws one survey per trial from the survey child of
        ``rng`` (the run pipeline passes its own: one survey per flight or campaign block).
    share : ``share(key, make)`` returns ``make()`` or what an earlier call with the same key made: the
        caller's sharing of the dithering between runs drawing it alike (a campaign's cells of one camera
        sweep); None computes it.
    tilt : ``tilt(draws)`` returns the :class:`VisionDraws` to use in place of those drawn (same shapes): an
        importance-sampling proposal's shift (:mod:`testbed.campaign.sampling`); None: as drawn. The streams
        are read as without it.

    Returns
    -------
    (VisionEpochs, VisionTruth); shapes as documented there, with B = () when
    ``n_trials`` is None. ``VisionEpochs.landmark_pos_ecef`` is ``(B..., L, 3)``
    (the survey drawn per trial), or ``survey_ecef`` as given.
    """
    _check_rng_trials(rng, n_trials)
    lm = _as_landmarks(landmarks)
    g = geometry
    _check_geometry(g, settings, lm)
    faults = _vision_faults(faults)
    batch = () if n_trials is None else (int(n_trials),)
    det = settings.detection
    cam = settings.camera.build()
    mount = g.mount
    t = g.t
    T, L = t.size, len(lm)

    # Random draws: one child generator per component, each time-dependent array drawn once, time-major.
    g_survey, g_dith, g_att, g_noise, g_faults = _spawn(rng, len(RNG_STREAMS))
    fault_rngs = _spawn(g_faults, len(faults))
    lm_survey = survey(lm, g_survey, n_trials) if survey_ecef is None else _given_survey(survey_ecef, lm)
    ss = g_dith.bit_generator.seed_seq

    def dither(noise_shift=None, gen=g_dith):  # (B..., T, 3) angles and rates, tones and noise apart
        return dithering_parts(t, settings.dithering, gen, n_trials, sample_rate_hz=settings.rate_hz,
                               noise_shift=noise_shift)

    if share is None:
        parts = dither()
    else:  # the same seed, times and settings dither every camera of a sweep alike: keyed on all the draw reads
        parts = share(("dithering", t.tobytes(), settings.dithering.model_dump_json(), settings.rate_hz,
                       ss.entropy, ss.spawn_key, ss.pool_size, ss.n_children_spawned, n_trials), dither)
    delta, delta_rate = parts.angle, parts.rate
    z_bias, z_att = attitude_draws(g_att, batch, (T,))
    noise_std = g_noise.standard_normal(batch + (T, L, 2))
    rotation_blur = det.blur_model == "rotation"
    # the frame's blur rotation: its own stream, so the DE draws stay as they were
    u = _spawn(g_noise, 1)[0].standard_normal(batch + (T,)) if rotation_blur else np.zeros(batch + (T,))
    if tilt is not None:
        d = tilt(VisionDraws(noise_std, u, z_bias, z_att, parts.noise_z, parts.tone_angle, parts.tone_rate))
        noise_std, u, z_bias, z_att = d.detection, d.blur, d.attitude_bias, d.attitude_noise
        noise_angle, noise_rate = parts.noise_angle, parts.noise_rate
        if not np.array_equal(d.dither_noise, parts.noise_z):  # moved through the noise's own white grid, drawn again
            moved = dither(d.dither_noise - parts.noise_z, np.random.Generator(type(g_dith.bit_generator)(ss)))
            noise_angle, noise_rate = moved.noise_angle, moved.noise_rate
        delta, delta_rate = d.dither_tone_angle + noise_angle, d.dither_tone_rate + noise_rate
    q_ref, att_err, att_sigma = attitude_reference_from_draws(g.euler, settings.attitude_ref, z_bias, z_att)

    # True camera attitude: nominal × dithering (the position is not dithered).
    if settings.dithering.enabled:
        R_d = Rotation.from_rotvec(np.array(delta.reshape(-1, 3))).as_matrix().reshape(delta.shape[:-1] + (3, 3))
    else:
        R_d = np.broadcast_to(np.eye(3), delta.shape[:-1] + (3, 3))
    R_c2e = g.R_cam_to_ecef @ R_d  # (B..., T, 3, 3)

    # Nominal scene (true landmark positions).
    p_cam0 = np.einsum("...tji,tlj->...tli", R_c2e, g.diff_ecef)
    range_b = np.broadcast_to(g.range_m, batch + (T, L))
    uv_true, uv_raw, vis, reason = _visibility(cam, det, p_cam0, range_b, lm.size_m, g.los)
    p_scene = p_cam0  # the landmarks where they stand (camera axes), moved ones included below
    moved = np.zeros(batch + (T, L), bool)
    moved_pos = np.broadcast_to(lm.pos_ecef, batch + (L, 3)).copy()
    range_m = range_b

    # LandmarkMoved: the landmark stands at surveyed + delta while active.
    moved_faults = [(f, r) for f, r in zip(faults, fault_rngs) if isinstance(f, LandmarkMoved)]
    if moved_faults:
        vis0 = vis
        los = np.broadcast_to(g.los, batch + (T, L)).copy()
        for f, frng in moved_faults:
            on = active(f, t)
            if not on.any():
                continue
            k = _select(f, f.landmark, lm, vis0[..., np.argmax(on), :], frng)  # (B...,)
            hit = (np.arange(L) == k[..., None])  # (B..., L)
            moved_pos = np.where(hit[..., None], lm_survey + _moved_offset_ecef(lm, f.delta_enu_m), moved_pos)
            moved |= on[:, None] & hit[..., None, :]
            if g.has_terrain:
                j = np.flatnonzero((g.moved_keys == _moved_key(f)).all(axis=1))
                if j.size == 0:
                    raise ValueError(f"sample_vision: fault {f!r} is not in the geometry; pass the same faults "
                                     "to vision_geometry (it computes their terrain line of sight)")
                los = np.where(on[:, None] & hit[..., None, :], g.los_moved[:, j[0], :], los)
        if moved.any():
            actual = np.where(moved[..., None], moved_pos[..., None, :, :], lm.pos_ecef)  # (B..., T, L, 3)
            diff = actual - g.cam_pos_ecef[:, None, :]
            range_m = np.linalg.norm(diff, axis=-1)
            p_scene = np.einsum("...tji,...tlj->...tli", R_c2e, diff)
            uv_true, uv_raw, vis, reason = _visibility(cam, det, p_scene, range_m, lm.size_m, los)
    range_m = np.array(range_m)  # own copy (T, L) or (B..., T, L)

    # Detection noise with motion blur: camera rate = mount-rotated body rate + dithering rate.
    omega_cam = np.einsum("...tji,tj->...ti", R_d, g.omega_cam) + delta_rate
    blur = det.blur_factor * np.linalg.norm(omega_cam, axis=-1) * det.exposure_s * cam.fx  # (B..., T)
    if rotation_blur:  # the frame's blur is one rotation: common to its landmarks (+ a small own part)
        blur_rot = (det.blur_factor * det.exposure_s * u)[..., None] * omega_cam  # (B..., T, 3) rad, camera axes
        common = rotation_shift(cam, det, p_scene, blur_rot, uv_raw)
        sigma = np.sqrt(det.sigma_px**2 + (det.blur_independent * blur)**2)  # (B..., T)
        noise = noise_std * sigma[..., None, None] + np.where(np.isfinite(common), common, 0.0)
    else:  # per landmark, independent (the VA-RAIM paper's white DE with the blur folded in)
        sigma = np.sqrt(det.sigma_px**2 + blur**2)  # (B..., T)
        noise = noise_std * sigma[..., None, None]
    uv_meas = uv_raw + noise

    # Pixel-bias faults (in the raw image, on detected slots).
    bias = np.zeros(batch + (T, L, 2))
    kind = np.where(moved & vis, FaultKind.LANDMARK_MOVED, FaultKind.NONE).astype(np.int8)
    for f, frng in zip(faults, fault_rngs):
        if not isinstance(f, PixelBias):
            continue
        on = active(f, t)
        if not on.any():
            continue
        k = _select(f, f.landmark, lm, vis[..., np.argmax(on), :], frng)
        hit = on[:, None] & (np.arange(L) == k[..., None])[..., None, :] & vis  # (B..., T, L)
        a = np.radians(f.angle_deg)
        bias += np.where(hit[..., None], f.magnitude_px * np.array([np.cos(a), np.sin(a)]), 0.0)
        kind = np.where(hit, FaultKind.PIXEL_BIAS, kind).astype(np.int8)
    uv_meas = cam.undistort(uv_meas + bias)

    sigma_told = np.broadcast_to((sigma if det.sigma_told_px is None else np.full_like(sigma, det.sigma_told_px))
                                 [..., None], batch + (T, L)).copy()
    detected = vis.copy()
    rep_reason = reason.copy()
    for f in faults:  # misassociation last: the matcher swaps two slots' reports
        if not isinstance(f, Misassociation):
            continue
        i, j = lm.index(f.landmarks[0]), lm.index(f.landmarks[1])
        on = active(f, t)
        perm = np.arange(L)
        perm[[i, j]] = [j, i]
        uv_meas = np.where(on[:, None, None], uv_meas[..., perm, :], uv_meas)
        detected = np.where(on[:, None], detected[..., perm], detected)
        rep_reason = np.where(on[:, None], rep_reason[..., perm], rep_reason)
        sigma_told = np.where(on[:, None], sigma_told[..., perm], sigma_told)
        swapped = np.zeros((T, L), bool)
        swapped[on, i] = swapped[on, j] = True
        kind = np.where(swapped & detected, FaultKind.MISASSOCIATION, kind).astype(np.int8)

    uv_meas = np.where(detected[..., None], uv_meas, np.nan)
    faulty = (kind != FaultKind.NONE) & detected
    kind = np.where(detected, kind, FaultKind.NONE).astype(np.int8)

    epochs = VisionEpochs(t=t.copy(), landmark_id=lm.id.copy(), landmark_pos_ecef=lm_survey, pixel_uv=uv_meas,
                          detected=detected, reason=rep_reason, sigma_px=sigma_told, K=cam.K, camera=mount,
                          q_body_to_enu_ref=q_ref, attitude_sigma=att_sigma,
                          dither_sigma=dither_rms_cam(settings.dithering))
    vtruth = VisionTruth(t=t.copy(), cam_pos_ecef=g.cam_pos_ecef.copy(), q_cam_to_ecef=R_to_q(R_c2e),
                         dither_cam=delta, attitude_ref_error=att_err, landmark_true_ecef=lm.pos_ecef.copy(),
                         landmark_survey_ecef=lm_survey, landmark_moved_ecef=moved_pos, landmark_moved=moved,
                         pixel_true=uv_true, range_m=range_m, visible=vis, noise_px=noise, blur_sigma_px=blur,
                         fault_pixel_bias=bias, faulty=faulty, fault_kind=kind)
    return epochs, vtruth


def synthesize_vision(truth: Truth, settings: VisionSettings, *, landmarks: Landmarks | LandmarkSettings,
                      terrain=None, faults: list | None = None, rng: np.random.Generator,
                      n_trials: int | None = None, survey_ecef: NDArray | None = None
                      ) -> tuple[VisionEpochs, VisionTruth]:
    """Synthesize camera landmark detections along a flight.

    ``sample_vision(vision_geometry(truth.decimate(settings.rate_hz), ...), ...)``.

    Parameters
    ----------
    truth : the flight (any rate; decimated to ``settings.rate_hz``).
    settings : camera, mount, dithering, attitude reference, detector.
    landmarks : the scene (built :class:`Landmarks` or its settings).
    terrain : an object with ``line_of_sight(origin_ecef (..., 3), target_ecef (..., 3)) -> bool (...)``,
        or None (no terrain masking).
    faults : a fault schedule; only the vision kinds (pixel_bias, landmark_moved,
        misassociation) are used.
    rng : the only source of randomness (child streams as in :func:`sample_vision`).
    n_trials, survey_ecef : as in :func:`sample_vision`.

    Returns
    -------
    (VisionEpochs, VisionTruth) as :func:`sample_vision`.
    """
    _check_rng_trials(rng, n_trials)
    lm = _as_landmarks(landmarks)
    geometry = vision_geometry(truth.decimate(settings.rate_hz), settings, landmarks=lm, terrain=terrain,
                               faults=faults)
    return sample_vision(geometry, settings, landmarks=lm, faults=faults, rng=rng, n_trials=n_trials,
                         survey_ecef=survey_ecef)


# Trailing axes after the epoch axis of the epoch-indexed fields (batch axes lead).
_EPOCHS_TRAILING = {"t": 0, "pixel_uv": 2, "detected": 1, "reason": 1, "sigma_px": 1, "q_body_to_enu_ref": 1}
_TRUTH_TRAILING = {"t": 0, "cam_pos_ecef": 1, "q_cam_to_ecef": 1, "dither_cam": 1, "attitude_ref_error": 1,
                   "landmark_moved": 1, "pixel_true": 2, "range_m": 1, "visible": 1, "noise_px": 2,
                   "blur_sigma_px": 0, "fault_pixel_bias": 2, "faulty": 1, "fault_kind": 1}


def _slice_record(rec, trailing: dict[str, int], sl: slice):
    out = {}
    for name, n_after in trailing.items():
        v = getattr(rec, name)
        ax = v.ndim - 1 - n_after
        out[name] = v[(slice(None),) * ax + (sl,)].copy()
    return replace(rec, **out)


def slice_epochs(vision_epochs: VisionEpochs, vision_truth: VisionTruth | None, start: int | None,
                 stop: int | None) -> tuple[VisionEpochs, VisionTruth | None]:
    """The records restricted to epochs ``[start, stop)`` (Python slice semantics, copies).

    Parameters
    ----------
    vision_epochs : (B..., T, ...) detections.  vision_truth : its truth side, or None.
    start, stop : epoch indices (None = open end).

    Returns
    -------
    (VisionEpochs, VisionTruth or None) with T' = len(range(T)[start:stop]) epochs; per-flight
    constants (landmark ids and positions, K, mount, attitude sigma) are kept.
    """
    sl = slice(start, stop)
    ep = _slice_record(vision_epochs, _EPOCHS_TRAILING, sl)
    vt = None if vision_truth is None else _slice_record(vision_truth, _TRUTH_TRAILING, sl)
    return ep, vt
