"""The Won et al. paper's GNSS/vision/INS error-state EKF: the core, batched over trials
(docs/design/nav-filter.md §2–§6).

State (per trial): the nominal IMU-point pose and biases — ``C = C_b^w``, v, p in the
approach's world frame, accelerometer and gyro biases, receiver clock bias and
drift — and the covariance P of the 17 error states ``[δp, δv, δψ, δb_a, δb_g,
δc_b, δc_d]`` with ``C = Exp(δψ) Ĉ``. A live flight is a batch of one.

* **Predict** at the IMU rate: the strapdown step of :mod:`testbed.inertial` on
  bias-corrected increments, and ``P ← ΦPΦᵀ + Q`` with the piecewise-constant
  transition of docs/design/nav-filter.md §5 (Earth rate, Coriolis and the vertical gravity gradient
  kept) and Q from the IMU's random walks, its Gauss–Markov biases and the
  clock's two-state model (trapezoidal discretisation: second order in Δt).
* **Update** at the aiding epochs: pseudorange rows
  ``−eᵢᵀδp + eᵢᵀ[(Ĉl_a)×]δψ + δc_b`` for however many satellites are in view
  (0, 1, 2, 3 or more — the filter never needs four) and two pixel rows per
  surveyed landmark (``∂m^c/∂δp = −C_c^bᵀĈᵀ``, ``∂m^c/∂δψ = C_c^bᵀĈᵀ[(m − p)×]``),
  with the pixel noise and the landmark survey error in R, and the camera's published
  dithering as what it is: one small rotation of the camera per frame, common to every
  pixel of the frame (:class:`CameraNoise`, dense in R); Joseph-form covariance update, masked rows inert; the normalised
  innovation squared (NIS) and its dof per epoch are kept for the integrity test.

Range-rate rows are here too; the integrity layer is :mod:`.separation` and
:mod:`.monitor`; unsurveyed features (SLAM states with delayed initialisation) are
:mod:`.slam`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from testbed.frames import LocalFrame
from testbed.inertial import earth_rate_world, gravity_world, mechanise_step, skew, so3_exp
from testbed.integrity.pixel_model import project_landmarks

N = 17
P_, V_, PSI, BA, BG = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12), slice(12, 15)
CB, CD = 15, 16
R_EARTH = 6_371_000.0


@dataclass(frozen=True)
class ImuNoise:
    """What the filter knows of its IMU: random walks (per √s), bias Gauss–Markov σ and τ."""

    arw: float
    vrw: float
    gyro_inrun: float
    accel_inrun: float
    tau_gyro: float
    tau_accel: float

    @classmethod
    def from_figures(cls, f: dict) -> ImuNoise:
        return cls(f["arw"], f["vrw"], f["gyro_inrun"], f["accel_inrun"], f["tau_gyro"], f["tau_accel"])


@dataclass(frozen=True)
class ClockNoise:
    sf: float = 9.0e-3  # m²/s, white FM
    sg: float = 3.55e-2  # m²/s³, random-walk FM


@dataclass(frozen=True)
class CameraNoise:
    """What the filter knows of its camera beyond each point's detector or tracker noise.

    ``white_px``: extra independent pixel noise 1σ per row. ``rotation_rad``: the rms (3,) per camera axis of
    the camera's dithering on its mount, a small rotation δ of the camera per frame that moves every pixel of
    the frame together. It enters a frame's R as ``G Q Gᵀ`` (G = ∂uv/∂ψ of every row, Q its world-frame
    covariance), dense across all the frame's points, surveyed or not. Spread over the rows as per-pixel
    noise instead (it once was) the mean NIS stays about right but the energy of the 2–3 common directions is
    under-stated by the number of points: a frame's NIS then passes its 0.999 quantile 20 times too often
    (``tests/test_ekf.py``).
    """

    white_px: float = 0.0
    rotation_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def rotation_cov(self, C: NDArray, R_cam_to_body: NDArray) -> NDArray:
        """Q (B, 3, 3): the world-frame covariance of the rotation ψ = C R_cb δ on attitudes C (B, 3, 3)."""
        M = C @ np.asarray(R_cam_to_body, float)
        return (M * np.asarray(self.rotation_rad, float) ** 2) @ np.swapaxes(M, -1, -2)

    def covariance(self, G: NDArray, C: NDArray, R_cam_to_body: NDArray) -> NDArray:
        """Its share (B, M, M) of the R of one frame's pixel rows with rotation Jacobians G (B, M, 3)."""
        Q = self.rotation_cov(C, R_cam_to_body)
        return self.white_px**2 * np.eye(G.shape[-2]) + G @ Q @ np.swapaxes(G, -1, -2)


def rotation_rows(Hm: NDArray, points_w: NDArray, cam_w: NDArray) -> NDArray:
    """∂uv/∂ψ (B, 2L, 3) of the pixels of points (B, L, 3) seen from camera positions (B, 3) when the camera
    alone turns by a world-frame ψ: ``Hm [(m − c)×]`` with Hm = ∂uv/∂m (B, L, 2, 3)."""
    G = Hm @ skew(points_w - cam_w[:, None, :])
    return G.reshape(G.shape[0], -1, 3)


@dataclass(frozen=True)
class NavState:
    """Batched filter state (B trials)."""

    C: NDArray  # (B, 3, 3)
    v: NDArray  # (B, 3)
    p: NDArray  # (B, 3)
    ba: NDArray  # (B, 3)
    bg: NDArray  # (B, 3)
    cb: NDArray  # (B,)
    cd: NDArray  # (B,)
    P: NDArray  # (B, 17, 17)


def transition(C: NDArray, f_w: NDArray, dt: float, w_ie: NDArray, tau_g: float, tau_a: float,
               g0: NDArray | float) -> NDArray:
    """Φ (B, 17, 17) of one step with the specific force f_w (B, 3) and attitude C constant over it.

    w_ie = 0, τ = inf and g0 = 0 drop the Earth rate, the bias decay and the gravity gradient.
    """
    B = C.shape[0]
    Phi = np.broadcast_to(np.eye(N), (B, N, N)).copy()
    Fx = skew(f_w)
    W = skew(np.broadcast_to(w_ie, (B, 3)))
    # vertical gravity gradient 2g/R (the horizontal −g/R terms kept too)
    Gam = np.zeros((B, 3, 3))
    g0 = np.broadcast_to(np.asarray(g0, float), (B,))
    Gam[:, 0, 0] = Gam[:, 1, 1] = -g0 / R_EARTH
    Gam[:, 2, 2] = 2 * g0 / R_EARTH
    Phi[:, P_, V_] = dt * np.eye(3)
    Phi[:, P_, PSI] = -0.5 * dt**2 * Fx
    Phi[:, P_, BA] = -0.5 * dt**2 * C
    Phi[:, P_, BG] = dt**3 / 6.0 * Fx @ C
    Phi[:, V_, P_] = dt * Gam
    Phi[:, V_, V_] = np.eye(3) - 2.0 * dt * W
    Phi[:, V_, PSI] = -dt * Fx
    Phi[:, V_, BA] = -dt * C
    Phi[:, V_, BG] = 0.5 * dt**2 * Fx @ C
    Phi[:, PSI, PSI] = np.eye(3) - dt * W
    Phi[:, PSI, BG] = -dt * C
    Phi[:, BA, BA] = np.exp(-dt / tau_a) * np.eye(3)
    Phi[:, BG, BG] = np.exp(-dt / tau_g) * np.eye(3)
    Phi[:, CB, CD] = dt
    return Phi


def process_noise(Phi: NDArray, C: NDArray, dt: float, imu: ImuNoise, clock: ClockNoise) -> NDArray:
    """Q (B, 17, 17): the continuous noise ``G Q_c Gᵀ`` discretised by the trapezoid ½(ΦGQ_cGᵀΦᵀ + GQ_cGᵀ)Δt,
    the clock's exactly."""
    B = C.shape[0]
    Qc = np.zeros((B, N, N))
    Qc[:, V_, V_] = imu.vrw**2 * C @ np.swapaxes(C, -1, -2)  # δv̇ = −Ĉ n_a
    Qc[:, PSI, PSI] = imu.arw**2 * C @ np.swapaxes(C, -1, -2)
    Qc[:, BA, BA] = 2 * imu.accel_inrun**2 / imu.tau_accel * np.eye(3)
    Qc[:, BG, BG] = 2 * imu.gyro_inrun**2 / imu.tau_gyro * np.eye(3)
    Q = 0.5 * (Phi @ Qc @ np.swapaxes(Phi, -1, -2) + Qc) * dt
    Q[:, CB:, :] = 0.0
    Q[:, :, CB:] = 0.0
    Q[:, CB, CB] = clock.sf * dt + clock.sg * dt**3 / 3.0
    Q[:, CB, CD] = Q[:, CD, CB] = clock.sg * dt**2 / 2.0
    Q[:, CD, CD] = clock.sg * dt
    return Q


def predict(s: NavState, dtheta: NDArray, dvel: NDArray, dt: float, frame: LocalFrame, imu: ImuNoise,
            clock: ClockNoise, earth_rotation: bool = True) -> NavState:
    """One IMU step for every trial: dtheta, dvel (B, 3) measured increments."""
    w_ie = earth_rate_world(frame, earth_rotation)
    s1, C_mid, f_w, g = nominal_step(s, dtheta, dvel, dt, frame, imu, earth_rotation)
    Phi = transition(C_mid, f_w, dt, w_ie, imu.tau_gyro, imu.tau_accel, np.linalg.norm(g, axis=-1))
    Q = process_noise(Phi, s.C, dt, imu, clock)
    P = Phi @ s.P @ np.swapaxes(Phi, -1, -2) + Q
    return replace(s1, P=0.5 * (P + np.swapaxes(P, -1, -2)))


def predict_compiled(s: NavState, dtheta: NDArray, dvel: NDArray, dt: float, frame: LocalFrame, imu: ImuNoise,
                     clock: ClockNoise, earth_rotation: bool = True, transition: NDArray | None = None
                     ) -> NavState:
    """:func:`predict` through K IMU steps by the compiled kernel (:mod:`.kernels`; equal to round-off, tested).

    dtheta, dvel : (B, 3) one step, or (B, K, 3) K steps in order.
    transition : (B, 17, 17), multiplied in place by the K steps' transitions (``Φ_K ⋯ Φ_1 · transition``).
    """
    from testbed.navigation.kernels import predict_batch

    w_ie = earth_rate_world(frame, earth_rotation)
    E = so3_exp(-w_ie * dt)
    out = NavState(**{k: np.array(getattr(s, k), float) for k in ("C", "v", "p", "ba", "bg", "cb", "cd", "P")})
    dth = np.ascontiguousarray(dtheta, float)
    dvl = np.ascontiguousarray(dvel, float)
    if dth.ndim == 2:
        dth, dvl = dth[:, None], dvl[:, None]
    R, o = np.ascontiguousarray(frame.R, float), np.ascontiguousarray(frame.origin_ecef, float)
    accumulate = transition is not None
    Phi = np.array(transition, float) if accumulate else np.zeros((1, N, N))
    for k in range(dth.shape[1]):
        predict_batch(out.C, out.v, out.p, out.ba, out.bg, out.cb, out.cd, out.P, dth[:, k], dvl[:, k], float(dt), R,
                      o, w_ie, E, imu.arw, imu.vrw, imu.gyro_inrun, imu.accel_inrun, imu.tau_gyro, imu.tau_accel,
                      clock.sf, clock.sg, Phi, accumulate)
    if accumulate:
        transition[...] = Phi
    return out


def nominal_step(s: NavState, dtheta: NDArray, dvel: NDArray, dt: float, frame: LocalFrame, imu: ImuNoise,
                 earth_rotation: bool = True) -> tuple[NavState, NDArray, NDArray, NDArray]:
    """The nominal state one IMU step on (P untouched), the step's mean attitude and specific force, and g."""
    w_ie = earth_rate_world(frame, earth_rotation)
    dth = dtheta - s.bg * dt
    dv = dvel - s.ba * dt
    g = gravity_world(frame, s.p)
    C1, v1, p1 = mechanise_step(s.C, s.v, s.p, dth, dv, dt, g, w_ie)
    C_mid = 0.5 * (s.C + C1)
    f_w = np.einsum("bij,bj->bi", C_mid, dv) / dt
    a_a, a_g = np.exp(-dt / imu.tau_accel), np.exp(-dt / imu.tau_gyro)
    s1 = NavState(C=C1, v=v1, p=p1, ba=a_a * s.ba, bg=a_g * s.bg, cb=s.cb + s.cd * dt, cd=s.cd, P=s.P)
    return s1, C_mid, f_w, g


def inject(s: NavState, dx: NDArray) -> NavState:
    """The nominal state ⊕ an error-state correction dx (B, 17)."""
    return replace(s, p=s.p + dx[:, P_], v=s.v + dx[:, V_], C=so3_exp(dx[:, PSI]) @ s.C, ba=s.ba + dx[:, BA],
                   bg=s.bg + dx[:, BG], cb=s.cb + dx[:, CB], cd=s.cd + dx[:, CD])


def pseudorange_rows(s: NavState, sat_w: NDArray, lever_ant: NDArray) -> tuple[NDArray, NDArray]:
    """Predicted pseudoranges h (B, S) and H (B, S, 17) at satellites ``sat_w`` (B, S, 3) in the world frame."""
    la = np.einsum("bij,j->bi", s.C, lever_ant)
    d = sat_w - (s.p + la)[:, None, :]
    r = np.linalg.norm(d, axis=-1)
    e = d / r[..., None]
    H = np.zeros(r.shape + (N,))
    H[..., P_] = -e
    H[..., PSI] = np.einsum("bsi,bij->bsj", e, skew(la))
    H[..., CB] = 1.0
    return r + s.cb[:, None], H


def range_rate_rows(s: NavState, sat_w: NDArray, sat_v_w: NDArray, lever_ant: NDArray, omega_b: NDArray
                    ) -> tuple[NDArray, NDArray]:
    """Predicted range rates h (B, S) and H (B, S, 17): satellites at ``sat_w`` moving at ``sat_v_w`` (B, S, 3),
    world frame (Earth-fixed, as the filter's velocity), the antenna at p + C·l moving at v + C(ω × l).

    h = e·(v_s − v_a) + ċ with e the unit line of sight. Columns: velocity −eᵀ; clock drift 1;
    position −(v_s − v_a)⊥ᵀ/r (the line of sight turning, ~4e-5 per m; ⊥: across e); attitude
    eᵀ[a×] + (v_s − v_a)⊥ᵀ[Ĉl×]/r with a = C(ω × l) (C = exp(ψ×)Ĉ: the antenna's velocity and, through its
    position, the line of sight); gyro bias −eᵀĈ[l×] (ω = ω_measured − b_g). ``omega_b`` (B, 3): the body rate.
    """
    la = np.einsum("bij,j->bi", s.C, lever_ant)
    a = np.einsum("bij,bj->bi", s.C, np.cross(omega_b, lever_ant))
    d = sat_w - (s.p + la)[:, None, :]
    r = np.linalg.norm(d, axis=-1)
    e = d / r[..., None]
    dv = sat_v_w - (s.v + a)[:, None, :]
    H = np.zeros(r.shape + (N,))
    H[..., V_] = -e
    H[..., CD] = 1.0
    turn = (dv - np.einsum("bsi,bsi->bs", dv, e)[..., None] * e) / r[..., None]  # ∂h/∂(antenna position)
    H[..., P_] = -turn
    H[..., PSI] = np.einsum("bsi,bij->bsj", e, skew(a)) + np.einsum("bsi,bij->bsj", turn, skew(la))
    H[..., BG] = -np.einsum("bsi,bij->bsj", e, s.C @ skew(np.broadcast_to(lever_ant, a.shape)))
    return np.einsum("bsi,bsi->bs", e, dv) + s.cd[:, None], H


def pixel_rows(s: NavState, landmarks_w: NDArray, K: NDArray, R_cam_to_body: NDArray, lever_cam: NDArray
               ) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Predicted pixels h (B, 2L), H (B, 2L, 17), ∂uv/∂m (B, 2L, 3L) blocks and the camera-frame rays (B, L, 3)."""
    B = s.C.shape[0]
    Rc2w = s.C @ R_cam_to_body
    cam_off = np.einsum("bij,j->bi", s.C, lever_cam)
    uv, Hp, ray = project_landmarks(s.p, Rc2w, cam_off, landmarks_w, K)  # Hp = ∂uv/∂p (B, L, 2, 3)
    L = uv.shape[-2]
    d = landmarks_w - s.p[:, None, :]
    H = np.zeros((B, L, 2, N))
    H[..., P_] = Hp
    H[..., PSI] = -np.einsum("blij,bljk->blik", Hp, skew(d))  # Jπ C_c^bᵀĈᵀ[(m − p)×] = −Hp [d×]
    Hm = -Hp  # ∂uv/∂m
    return uv.reshape(B, 2 * L), H.reshape(B, 2 * L, N), Hm, ray


def update(s: NavState, nu: NDArray, H: NDArray, R: NDArray, mask: NDArray) -> tuple[NavState, NDArray, NDArray]:
    """Masked batched EKF update (Joseph form): innovations nu (B, M), H (B, M, 17), R (B, M, M).

    Rows off the mask are inert (zero H, zero ν, unit R). Returns the state, the NIS and its dof (B,).
    """
    dx, P, nis, dof = gain_update(s.P, nu, H, R, mask)
    return inject(replace(s, P=P), dx), nis, dof


def gain_update(P: NDArray, nu: NDArray, H: NDArray, R: NDArray, mask: NDArray, joseph: bool = True
                ) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """The linear step of :func:`update`: the correction dx (B, n), P after, the NIS and its dof (B,) (any
    state size n: the core's 17, or with :mod:`.slam`'s static block). ``joseph``: the Joseph form (else
    ``P − KHP``, symmetrised)."""
    m = np.asarray(mask, bool)
    mm = m[..., :, None] & m[..., None, :]
    H = np.where(m[..., None], H, 0.0)
    nu = np.where(m, nu, 0.0)
    R = np.where(mm, R, 0.0) + np.eye(m.shape[-1]) * ~m[..., None, :]
    PHt = P @ np.swapaxes(H, -1, -2)
    S = H @ PHt + R
    Sinv_nu = np.linalg.solve(S, nu[..., None])[..., 0]
    nis = np.einsum("bm,bm->b", nu, Sinv_nu)
    Kt = np.linalg.solve(S, np.swapaxes(PHt, -1, -2))  # (B, M, 17) = Kᵀ
    K = np.swapaxes(Kt, -1, -2)
    dx = np.einsum("bnm,bm->bn", K, nu)
    if joseph:
        I_KH = np.eye(P.shape[-1]) - K @ H
        P = I_KH @ P @ np.swapaxes(I_KH, -1, -2) + K @ R @ Kt
    else:  # P − K H P: a third of the cost, for large states (docs/design/nav-filter.md §6 (6.9))
        P = P - K @ np.swapaxes(PHt, -1, -2)
    return dx, 0.5 * (P + np.swapaxes(P, -1, -2)), nis, m.sum(-1)

