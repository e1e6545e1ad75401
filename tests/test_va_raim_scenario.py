"""The VA-RAIM paper's scenario for tests and the benchmark (not a test module).

The VA-RAIM paper §3.1 with the longitude typo corrected
(docs/design/physics-notes.md §va-raim-scenario-longitudes): landmark centre
29.3065 N, 94.3359 E, 2950 m; three landmarks on a 100 m circle at azimuths
0/120/240°; a straight path due east from 94.2539 E / 3650 m to
94.3144 E / 3150 m in 60 s. Pixels are synthesised here by projecting the
*true* landmarks through a pinhole camera (the vision sensor is written in
parallel); the monitor gets the *surveyed* positions (true + survey error).

Camera assumption (the seed gives none usable): 2448 × 2048 px, f = 3400 px
(the public runway-detection dataset of docs/design/physics-notes.md §camera-references), looking forward and 5° down
from the body x axis, 4 m ahead of and 1 m below the reference point. GPS:
the DO-229 almanac helpers of ``test_integrity_core_helpers.py`` with an
elevation mask standing in for the valley walls.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from test_integrity_core_helpers import make_gnss  # noqa: E402

from testbed.flight.kinematic import straight_truth  # noqa: E402
from testbed.frames import LocalFrame, R_ecef_to_enu, q_to_R  # noqa: E402
from testbed.records import GnssEpochs, Mount, NotVisible, VisionEpochs  # noqa: E402
from testbed.world.airport import VA_RAIM_CENTRE  # noqa: E402

F_PX = 3400.0
K_CAM = np.array([[F_PX, 0.0, 1223.5], [0.0, F_PX, 1023.5], [0.0, 0.0, 1.0]])
CAM_DOWN_DEG = 5.0
# camera axes (x right, y down, z fwd) -> body FRD, pitched down about body y
_c = np.radians(CAM_DOWN_DEG)
_R_pitch = np.array([[np.cos(_c), 0.0, -np.sin(_c)], [0.0, 1.0, 0.0], [np.sin(_c), 0.0, np.cos(_c)]])
R_CAM_TO_BODY = _R_pitch @ np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
CAMERA = Mount(lever_arm_body=np.array([4.0, 0.0, 1.0]), R_sensor_to_body=R_CAM_TO_BODY)
ANTENNA = Mount(lever_arm_body=np.array([0.0, 0.0, -2.0]))
T_WEEK0 = 345600.0  # GPS time of week of the sortie start (s)


def seed_frame() -> LocalFrame:
    return LocalFrame(*VA_RAIM_CENTRE)


def seed_landmarks_enu(n: int = 3, radius: float = 100.0) -> np.ndarray:
    """(n, 3) landmarks on the circle at azimuths 0, 360/n, ... (n = 3: the seed's 0/120/240°)."""
    az = np.radians(np.arange(n) * 360.0 / n)
    return np.stack([radius * np.sin(az), radius * np.cos(az), np.zeros(n)], axis=1)


def seed_truth(frame: LocalFrame, rate_hz: float = 1.0, t0: float = 0.0, t1: float = 60.0):
    """The seed's straight sortie (optionally only the part between t0 and t1 s)."""
    a = frame.geodetic_to_enu(29.3065, 94.2539, 3650.0)
    b = frame.geodetic_to_enu(29.3065, 94.3144, 3150.0)
    full = straight_truth(frame, a, b, 60.0, rate_hz)
    keep = np.nonzero((full.t >= t0 - 1e-9) & (full.t <= t1 + 1e-9))[0]
    return full.at_indices(keep)


def _local_to_world(frame: LocalFrame, truth) -> np.ndarray:
    return frame.R @ np.swapaxes(R_ecef_to_enu(truth.lat_deg, truth.lon_deg), -1, -2)


def sensor_positions(frame: LocalFrame, truth) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True camera and antenna positions (T, 3) world ENU and R_cam_to_world (T, 3, 3)."""
    Rlw = _local_to_world(frame, truth)
    Rb = Rlw @ q_to_R(truth.q_body_to_enu)
    cam = truth.pos_enu + Rb @ CAMERA.lever_arm_body
    ant = truth.pos_enu + Rb @ ANTENNA.lever_arm_body
    return cam, ant, Rb @ CAMERA.R_sensor_to_body


def project(p_enu: np.ndarray, cam_enu: np.ndarray, R_cam_to_world: np.ndarray, K: np.ndarray = K_CAM) -> np.ndarray:
    """Ideal pixels (..., L, 2) of points p (L, 3) from cameras (..., 3) with attitude (..., 3, 3)."""
    v = np.einsum("...ji,...lj->...li", R_cam_to_world, p_enu - cam_enu[..., None, :])
    return (v[..., :2] / v[..., 2:]) @ K[:2, :2].T + K[:2, 2]


@dataclass
class Scenario:
    frame: LocalFrame
    truth: object
    gnss: GnssEpochs
    vision: VisionEpochs
    p_true: np.ndarray
    p_surv: np.ndarray
    m_true: np.ndarray  # (T, L) true camera-landmark ranges
    cam_enu: np.ndarray  # (T, 3)


def make_scenario(rng: np.random.Generator, batch: tuple[int, ...] = (), n_landmarks: int = 3,
                  sigma_px: float = 1.0, survey_sigma_m: float = 0.05, rate_hz: float = 1.0,
                  t0: float = 0.0, t1: float = 60.0, mask_deg: float = 5.0, gps_bias: np.ndarray | None = None,
                  survey_error: np.ndarray | None = None, attitude_noise_rad: float = 0.0,
                  gps_noise: bool = True) -> Scenario:
    frame = seed_frame()
    truth = seed_truth(frame, rate_hz, t0, t1)
    T = len(truth.t)
    p_true = seed_landmarks_enu(n_landmarks)
    dp = survey_error if survey_error is not None else rng.normal(0.0, survey_sigma_m, p_true.shape)
    p_surv = p_true + dp
    cam, ant, Rc = sensor_positions(frame, truth)
    uv0 = project(p_true, cam, Rc)  # (T, L, 2)
    shape = batch + (T, n_landmarks)
    uv = uv0 + sigma_px * rng.standard_normal(shape + (2,))
    det = np.ones(shape, bool)
    q = np.broadcast_to(truth.q_body_to_enu, batch + (T, 4)).copy()
    if attitude_noise_rad > 0:
        from scipy.spatial.transform import Rotation
        rv = rng.normal(0.0, attitude_noise_rad, batch + (T, 3)).reshape(-1, 3)
        q = (Rotation.from_rotvec(rv) * Rotation.from_quat(q.reshape(-1, 4))).as_quat().reshape(q.shape)
    vision = VisionEpochs(
        t=truth.t, landmark_id=np.array([f"L{i}" for i in range(n_landmarks)]),
        landmark_pos_ecef=frame.enu_to_ecef(p_surv), pixel_uv=uv, detected=det,
        reason=np.zeros(shape, np.int8) + NotVisible.VISIBLE, sigma_px=np.full(shape, sigma_px), K=K_CAM,
        camera=CAMERA, q_body_to_enu_ref=q, attitude_sigma=np.full(3, attitude_noise_rad))
    gnss, _, _ = make_gnss(frame, ant, T_WEEK0 + truth.t, rng if gps_noise else None, batch=batch,
                           mask_deg=mask_deg, bias=gps_bias)
    gnss = GnssEpochs(**{**gnss.__dict__, "t": truth.t, "antenna": ANTENNA})
    m_true = np.linalg.norm(p_true - cam[:, None, :], axis=-1)
    return Scenario(frame, truth, gnss, vision, p_true, p_surv, m_true, cam)
