"""Pixel-domain vision integrity (seed 003, the patent; INTEGRITY_MATH.md §5).

Measurements are the pixel coordinates of surveyed landmarks, two rows per
detected landmark, stacked with the GPS pseudorange rows: ``H′ = [H; G]``.
The pixel model projects the line of sight from the *estimated* camera
position, oriented by the aircraft's attitude *reference* (never truth) and
the camera mount, through the pinhole intrinsics ``K``. ``K`` is used in place
of the patent's ``T_c^pix`` (the patent's matrix is ``K`` for a camera whose
pixel grid is described by its physical size H×W, M×N pixels and focal length
f; the two are the same map, ``K`` is what the vision front end publishes).

Measurement noise model (stated, as the task asks):

* detection noise: ``σ_px`` per landmark, independent in u and v;
* attitude-reference error: a small body-frame rotation δφ ~ N(0, diag(σ_att²))
  with σ_att = ``vision.attitude_sigma`` (roll, pitch, yaw treated as rotations
  about body x, y, z – exact to first order for small errors at small pitch).
  It moves every landmark's pixels coherently, ``δz = J_att δφ`` with
  ``J_att = ∂π/∂s · R_c→bᵀ [R_b→wᵀ (t − p)]×``, so the pixel covariance is the
  full ``Σ_pix = σ_px² I + J_att Σ_att J_attᵀ`` (2L × 2L, correlated across
  landmarks), evaluated once at the starting state.
* landmark survey error is not modelled here (the patent carries it as a
  state δt; the record has no survey sigma) – it appears as an unmodelled bias.

Protection levels (patent step 6), with slopes in weighted form
(slope² = ‖A_H b‖² / bᵀWSb, so ``s_bias = sqrt(λ_det)`` in normalised units):

* H1 fault-free: ``HPL₁ = K_ff σ_x``, σ_x the semi-major axis of the horizontal
  error ellipse (sqrt of the largest eigenvalue of J's E/N block),
  ``VPL₁ = K_ff sqrt(J₃₃)``, ``K_ff = Φ⁻¹(1 − P_ff/2)``;
* H2 one fault (a satellite, or one landmark's (u, v) pair at the worst angle θ,
  a 2×2 generalised eigenvalue problem): ``HPL₂ = max slope · sqrt(λ_det)``;
* H3 two faults (two satellites, two landmarks or one of each; generalised
  eigenvalue on the stacked 2–4 columns): ``HPL₃ = max slope₂ · sqrt(λ_det)``;
* ``HPL = sqrt(max(HPL₁, HPL₂)² + HPL₃²)``, VPL likewise.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

from testbed.frames import LocalFrame, R_ecef_to_enu, q_to_R
from testbed.integrity import lsq
from testbed.integrity.levels import availability, service_level
from testbed.integrity.raim import compact_rows, scatter_rows
from testbed.integrity.settings import IntegritySettings
from testbed.integrity.monitor import REFERENCE_POINT, MonitorContext, Observations
from testbed.records import (
    Diagnostics,
    GnssEpochs,
    MonitorOutput,
    Mount,
    VisionEpochs,
    epoch_array,
    one_landmark_survey,
)


def _skew(v: NDArray) -> NDArray:
    """Cross-product matrices ``[v]×`` ``(..., 3, 3)`` of ``v`` ``(..., 3)``."""
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def body_to_world(frame: LocalFrame, pos_enu: ArrayLike, q_body_to_enu: ArrayLike) -> NDArray:
    """Rotation body -> world-frame ENU ``(..., 3, 3)``.

    ``q_body_to_enu`` refers to the local ENU at the aircraft; the world frame
    is tangent at its own origin, ~0.01° apart per km, which at a 1000 px focal
    length is 0.16 px per km – so the local-to-world rotation is applied, at
    the given (estimated) position.
    """
    p = np.asarray(pos_enu, float)
    lat, lon, _ = frame.enu_to_geodetic(p)
    R_local_to_world = frame.R @ np.swapaxes(R_ecef_to_enu(lat, lon), -1, -2)
    return R_local_to_world @ q_to_R(q_body_to_enu)


def project_landmarks(pos_enu: ArrayLike, R_cam_to_world: ArrayLike, cam_offset_world: ArrayLike,
                      landmarks_enu: ArrayLike, K: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
    """Pinhole pixels of landmarks and their Jacobian w.r.t. the reference position.

    Parameters
    ----------
    pos_enu : (..., 3) m, aircraft reference position (world frame).
    R_cam_to_world : (..., 3, 3) camera axes (x right, y down, z forward) -> world ENU.
    cam_offset_world : (..., 3) m, camera centre minus ``pos_enu`` (world axes).
    landmarks_enu : (L, 3) or (..., L, 3) m, landmark positions (world frame).
    K : (3, 3) intrinsics.

    Returns
    -------
    uv : (..., L, 2) px, ``π(s) = (K s)[:2] / (K s)[2]``, s = R_c→wᵀ (t − c).
    H : (..., L, 2, 3) px/m, ``∂uv/∂pos = −∂π/∂s · R_c→wᵀ`` (patent step 3).
    s_cam : (..., L, 3) m, line of sight in camera axes (s_z ≤ 0: behind the camera).
    """
    p = np.asarray(pos_enu, float)
    R = np.asarray(R_cam_to_world, float)
    K = np.asarray(K, float)
    c = p + np.asarray(cam_offset_world, float)
    d = np.asarray(landmarks_enu, float) - c[..., None, :]
    s = np.einsum("...ji,...lj->...li", R, d)  # R_c→wᵀ d
    Ks = s @ K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = Ks[..., :2] / Ks[..., 2:3]
        Jpi = (K[:2, :] - uv[..., :, None] * K[2, :]) / Ks[..., 2:3, None]  # ∂π/∂s (..., L, 2, 3)
    H = -np.einsum("...lij,...kj->...lik", Jpi, R)  # −Jπ R_c→wᵀ
    return uv, H, s


def attitude_pixel_jacobian(pos_enu: ArrayLike, R_body_to_world: ArrayLike, camera: Mount,
                            landmarks_enu: ArrayLike, K: ArrayLike) -> NDArray:
    """∂uv/∂δφ ``(..., L, 2, 3)`` px/rad for a small body-frame attitude error δφ.

    With ``R_b→w,true = R_b→w,ref (I + [δφ]×)`` the body-frame line of sight
    from the camera changes by ``[R_b→wᵀ (t − p)]× δφ`` (lever arm included).
    """
    p = np.asarray(pos_enu, float)
    Rb = np.asarray(R_body_to_world, float)
    R_c2w = Rb @ camera.R_sensor_to_body
    off = np.einsum("...ij,j->...i", Rb, camera.lever_arm_body)
    uv, _, s = project_landmarks(p, R_c2w, off, landmarks_enu, K)
    K = np.asarray(K, float)
    Ks = s @ K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        Jpi = (K[:2, :] - uv[..., :, None] * K[2, :]) / Ks[..., 2:3, None]
    r_b = np.einsum("...ji,...lj->...li", Rb, np.asarray(landmarks_enu, float) - p[..., None, :])
    ds_dphi = np.einsum("ji,...ljk->...lik", camera.R_sensor_to_body, _skew(r_b))  # R_c→bᵀ [r_b]×
    return Jpi @ ds_dphi


def pixel_covariance(J_att: NDArray, sigma_px: ArrayLike, attitude_sigma: ArrayLike | None) -> NDArray:
    """Full pixel covariance ``(..., 2L, 2L)`` px²: ``σ_px² I + J_att Σ_att J_attᵀ``.

    J_att : (..., L, 2, 3); sigma_px : (..., L); attitude_sigma : (3,) rad or None.
    """
    L = J_att.shape[-3]
    sp = np.asarray(sigma_px, float)
    Sig = np.zeros(J_att.shape[:-3] + (2 * L, 2 * L))
    if attitude_sigma is not None:
        Ja = J_att.reshape(J_att.shape[:-3] + (2 * L, 3))
        Sig = np.einsum("...ik,k,...jk->...ij", Ja, np.asarray(attitude_sigma, float) ** 2, Ja)
    d = np.repeat(sp**2, 2, axis=-1)
    return Sig + d[..., :, None] * np.eye(2 * L)


def _inverse_on_mask(Sig: NDArray, mask: NDArray) -> NDArray:
    """Inverse of the used sub-block (unused rows/columns zero), batched, NaN-safe."""
    mm = mask[..., :, None] & mask[..., None, :]
    eye = np.eye(Sig.shape[-1])
    S0 = np.where(mm & np.isfinite(Sig), Sig, 0.0) + eye * ~mask[..., None, :]
    W = np.linalg.inv(S0)
    return np.where(mm, W, 0.0)


def fault_units(n_sat: int, n_landmark: int, two_faults: bool = True) -> tuple[NDArray, NDArray, list[str]]:
    """Row index sets of the fault hypotheses (rows: satellites first, then u, v per landmark).

    Returns cols1 (n_sat + L, 2) single faults, cols2 (P, 4) pairs (empty if not
    ``two_faults``), and unit labels ("sat k" / "lm l").
    """
    units = [[i, -1] for i in range(n_sat)] + [[n_sat + 2 * l, n_sat + 2 * l + 1] for l in range(n_landmark)]
    labels = [f"sat {i}" for i in range(n_sat)] + [f"lm {l}" for l in range(n_landmark)]
    cols1 = np.array(units, int).reshape(-1, 2)
    if two_faults and len(units) > 1:
        pairs = [[c for c in units[a] + units[b] if c >= 0] for a, b in combinations(range(len(units)), 2)]
        cols2 = np.full((len(pairs), 4), -1, int)
        for k, pr in enumerate(pairs):
            cols2[k, :len(pr)] = pr
    else:
        cols2 = np.zeros((0, 4), int)
    return cols1, cols2, labels


def _ffill_epochs(x: NDArray, carry: NDArray | None = None) -> NDArray:
    """Forward-fill NaN rows along the epoch axis (-2) of ``x`` (..., T, k).

    ``carry`` (..., k) is the value in force before the first epoch (e.g. the
    last fix of the previous block of a live run); None leaves leading gaps NaN.
    """
    ok = np.isfinite(x).all(-1)
    T = x.shape[-2]
    idx = np.where(ok, np.arange(T), 0)
    idx = np.maximum.accumulate(idx, axis=-1)
    out = np.take_along_axis(x, idx[..., None], -2)
    seen = np.maximum.accumulate(ok, axis=-1)
    if carry is not None:
        return np.where(seen[..., None], out, np.asarray(carry, float)[..., None, :])
    return np.where(seen[..., None], out, np.nan)


#: the pixel monitor's reason texts: the least-squares ones, then its own
PIXEL_REASONS: tuple[str, ...] = lsq.REASONS + ("unavailable: no landmark in view (the pixel monitor needs vision)",)
NO_LANDMARK = len(lsq.REASONS)


@dataclass(frozen=True)
class PixelDiagnostics(Diagnostics):
    """The pixel-domain monitor's diagnostics (B..., T[, ...]).

    x_start : the iteration's start state per epoch (GPS fix carried forward).
    hpl1/2/3, vpl1/2/3 : the three hypotheses' levels (m); ``sigma_x`` the error-ellipse
    semi-major axis; slopes per satellite slot (NaN unused), per landmark pixel row, and
    the worst pair; residuals in m (pseudoranges) and px (landmarks).
    """

    x_start: NDArray = epoch_array(1)
    hpl1: NDArray = epoch_array()
    hpl2: NDArray = epoch_array()
    hpl3: NDArray = epoch_array()
    vpl1: NDArray = epoch_array()
    vpl2: NDArray = epoch_array()
    vpl3: NDArray = epoch_array()
    sigma_x: NDArray = epoch_array()
    lam_det: NDArray = epoch_array()
    hslope_sat: NDArray = epoch_array(1)
    vslope_sat: NDArray = epoch_array(1)
    hslope_lm: NDArray = epoch_array(1)
    vslope_lm: NDArray = epoch_array(1)
    hslope_pair_max: NDArray = epoch_array()
    vslope_pair_max: NDArray = epoch_array()
    residual_pr: NDArray = epoch_array(1)
    residual_px: NDArray = epoch_array(2)
    n_landmarks: NDArray = epoch_array()
    n_sat: NDArray = epoch_array()
    converged: NDArray = epoch_array()
    n_iter: NDArray = epoch_array()
    k_ff: float = 0.0


def pixel_monitor(gnss: GnssEpochs, vision: VisionEpochs, frame: LocalFrame,
                  settings: IntegritySettings | None = None, x0: ArrayLike | None = None,
                  name: str = "pixel", x_carry: ArrayLike | None = None) -> MonitorOutput:
    """The patent's pixel-domain integrity monitor, GPS + landmark pixels, batched.

    Parameters
    ----------
    gnss : GnssEpochs (B..., T, S); ``visible`` rows are used.
    vision : VisionEpochs (B..., T, L) at the same epochs; ``detected`` landmarks
        give two rows each (u, v).
    frame : world frame of the state [E, N, U, clock] (clock dropped when an
        epoch has no pseudorange row).
    settings : IntegritySettings (``p_fa``, ``p_md``, ``p_ff``, ``pixel_two_faults``,
        ``pixel_attitude_noise``, solver tolerances, service levels).
    x0 : (B..., T, 4) start of the iteration (e.g. the navigation prediction).
        Default: the GPS-only fix, forward-filled over epochs without one.
    x_carry : (B..., 4) the start state in force before the first epoch (a live
        run passes the previous block's last ``diagnostics.x_start`` (:class:`PixelState`)
        so that block-by-block equals one call over the whole flight).
        Default: the GPS-only WLS fix, carried forward over epochs without one.

    Returns
    -------
    MonitorOutput; diagnostics: ``hpl1, hpl2, hpl3, vpl1, vpl2, vpl3`` (m),
    ``sigma_x`` (m, error-ellipse semi-major axis), ``lam_det``,
    ``hslope_sat, vslope_sat`` (B..., T, S), ``hslope_lm, vslope_lm`` (B..., T, L),
    ``hslope_pair_max, vslope_pair_max``, ``residual_pr`` (B..., T, S) m,
    ``residual_px`` (B..., T, L, 2) px, ``n_landmarks``, ``converged``.
    """
    st = settings or IntegritySettings()
    if len(gnss.t) != len(vision.t) or not np.allclose(gnss.t, vision.t, atol=1e-6):
        raise ValueError(f"pixel_monitor: gnss and vision epochs must coincide; got {len(gnss.t)} GNSS and "
                         f"{len(vision.t)} vision epochs (resample one onto the other first)")
    pr = np.asarray(gnss.pseudorange, float)
    uv_meas = np.asarray(vision.pixel_uv, float)
    lead = np.broadcast_shapes(pr.shape[:-1], uv_meas.shape[:-2])
    S, L = pr.shape[-1], uv_meas.shape[-2]
    pr = np.broadcast_to(pr, lead + (S,))
    vis = np.broadcast_to(np.asarray(gnss.visible, bool), lead + (S,))
    sigma = np.broadcast_to(np.asarray(gnss.sigma, float), lead + (S,))
    sat_enu = frame.ecef_to_enu(np.broadcast_to(gnss.sat_pos_ecef, lead + (S, 3)))
    uv_meas = np.broadcast_to(uv_meas, lead + (L, 2))
    det = np.broadcast_to(np.asarray(vision.detected, bool), lead + (L,))
    sigma_px = np.broadcast_to(np.asarray(vision.sigma_px, float), lead + (L,))
    q_ref = np.broadcast_to(np.asarray(vision.q_body_to_enu_ref, float), lead + (4,))
    lm_enu = frame.ecef_to_enu(one_landmark_survey(vision, "pixel_monitor"))
    K = np.asarray(vision.K, float)

    # GNSS rows compacted (used first), as in gps_raim
    idx, mg, Ng = compact_rows(vis)
    take = lambda a: np.take_along_axis(a, idx, -1)  # noqa: E731
    z_g = take(pr)
    w_g = lsq.weights_from_sigma(take(sigma))
    anchor = np.take_along_axis(sat_enu, idx[..., None], -2)

    # starting state and the attitude-derived rotations/offsets at it
    if x0 is None:
        ant0 = np.einsum("...ij,j->...i", q_to_R(q_ref), gnss.antenna.lever_arm_body)
        gps = lsq.solve_ranges(anchor, z_g, w_g, mg, np.ones(Ng), offset_enu=ant0[..., None, :],
                               n_iter=st.max_iter, tol_m=st.tol_m, max_cond=st.max_cond)
        x_start = _ffill_epochs(gps.x, x_carry)
    else:
        x_start = np.broadcast_to(np.asarray(x0, float), lead + (4,))
    x_start = np.where(np.isfinite(x_start), x_start, 0.0)
    R_b2w = body_to_world(frame, x_start[..., :3], q_ref)

    # weights: blockdiag(W_G, W_pix), W_pix the inverse of the full pixel covariance
    att_sigma = np.asarray(vision.attitude_sigma, float) if st.pixel_attitude_noise else None
    J_att = attitude_pixel_jacobian(x_start[..., :3], R_b2w, vision.camera, lm_enu, K)
    Sig_pix = pixel_covariance(J_att, sigma_px, att_sigma)
    m_pix = np.repeat(det, 2, axis=-1)
    W_pix = _inverse_on_mask(Sig_pix, m_pix)
    N = Ng + 2 * L
    W = np.zeros(lead + (N, N))
    W[..., np.arange(Ng), np.arange(Ng)] = np.where(mg, w_g, 0.0)
    W[..., Ng:, Ng:] = W_pix
    mask = np.concatenate([mg, m_pix], axis=-1)
    z = np.concatenate([z_g, uv_meas.reshape(lead + (2 * L,))], axis=-1)

    def model(x: NDArray) -> tuple[NDArray, NDArray]:
        # the local-ENU -> world rotation follows the current estimate (its
        # 1.6e-7 rad/m dependence on x is left out of the Jacobian)
        Rb = body_to_world(frame, x[..., :3], q_ref)
        ant = np.einsum("...ij,j->...i", Rb, gnss.antenna.lever_arm_body)
        h_g, G_g = lsq.range_model(anchor, np.ones(Ng), ant[..., None, :])(x)
        cam = np.einsum("...ij,j->...i", Rb, vision.camera.lever_arm_body)
        uv, H, s = project_landmarks(x[..., :3], Rb @ vision.camera.R_sensor_to_body, cam, lm_enu, K)
        behind = s[..., 2] <= 0.0  # a landmark behind the camera has no pixel
        uv = np.where(behind[..., None], np.nan, uv)
        H = np.where(behind[..., None, None], np.nan, H)
        G_p = np.concatenate([H, np.zeros(H.shape[:-1] + (1,))], axis=-1).reshape(lead + (2 * L, 4))
        return np.concatenate([h_g, uv.reshape(lead + (2 * L,))], -1), np.concatenate([G_g, G_p], -2)

    sol = lsq.iterate_wls(model, z, W, mask, x_start, n_iter=st.max_iter, tol_m=st.tol_m, max_cond=st.max_cond)
    geom = sol.geometry
    WS = geom.ws_matrix()
    cols1, cols2, _ = fault_units(Ng, L, st.pixel_two_faults)
    with np.errstate(invalid="ignore", over="ignore"):
        hs1, vs1 = lsq.subspace_slopes(geom, cols1, WS)
        if len(cols2):
            hs2, vs2 = lsq.subspace_slopes(geom, cols2, WS)
        else:
            hs2 = vs2 = np.zeros(lead + (0,))
    nanmax = lambda a: np.max(np.where(np.isnan(a), -np.inf, a), axis=-1, initial=-np.inf)  # noqa: E731
    lam = lsq.lambda_det(geom.dof, st.p_fa, st.p_md)
    sb = np.sqrt(lam)
    k_ff = float(stats.norm.isf(st.p_ff / 2))
    J = geom.J
    with np.errstate(invalid="ignore"):
        sigma_x = np.sqrt(np.linalg.eigvalsh(np.where(np.isfinite(J[..., :2, :2]), J[..., :2, :2], 0.0))[..., -1])
        sigma_v = np.sqrt(J[..., 2, 2])
        hpl1, vpl1 = k_ff * sigma_x, k_ff * sigma_v
        hpl2, vpl2 = nanmax(hs1) * sb, nanmax(vs1) * sb
        if len(cols2):
            hpl3, vpl3 = nanmax(hs2) * sb, nanmax(vs2) * sb
        else:
            hpl3, vpl3 = np.zeros(lead), np.zeros(lead)
        hpl = np.sqrt(np.maximum(hpl1, hpl2) ** 2 + hpl3**2)
        vpl = np.sqrt(np.maximum(vpl1, vpl2) ** 2 + vpl3**2)
    reason = sol.reason.copy()
    undetectable = ~np.isfinite(hpl) | ~np.isfinite(vpl)
    reason = np.where((reason == lsq.Reason.OK) & undetectable & np.isfinite(sb),
                      lsq.Reason.UNDETECTABLE, reason).astype(np.int8)
    # without a landmark the solve is GPS RAIM's: the pixel monitor's integrity case does not apply
    reason = np.where((reason == lsq.Reason.OK) & ~det.any(-1), NO_LANDMARK, reason).astype(np.int8)
    ok = reason == lsq.Reason.OK
    T2 = lsq.chi2_threshold(geom.dof, st.p_fa)
    hpl, vpl = np.where(ok, hpl, np.nan), np.where(ok, vpl, np.nan)
    sse = np.where(ok, sol.sse, np.nan)
    T2 = np.where(ok, T2, np.nan)
    levels = tuple(service_level(s) for s in st.service_levels)

    r = sol.residual
    diag = PixelDiagnostics(
        x_start=x_start, hpl1=hpl1, hpl2=hpl2, hpl3=hpl3, vpl1=vpl1, vpl2=vpl2, vpl3=vpl3,
        sigma_x=sigma_x, lam_det=lam, k_ff=k_ff,
        hslope_sat=scatter_rows(hs1[..., :Ng], idx, mg, S), vslope_sat=scatter_rows(vs1[..., :Ng], idx, mg, S),
        hslope_lm=hs1[..., Ng:], vslope_lm=vs1[..., Ng:],
        hslope_pair_max=nanmax(hs2), vslope_pair_max=nanmax(vs2),
        residual_pr=scatter_rows(r[..., :Ng], idx, mg, S),
        residual_px=np.where(det[..., None], r[..., Ng:].reshape(lead + (L, 2)), np.nan),
        n_landmarks=det.sum(-1), n_sat=mg.sum(-1), converged=sol.converged, n_iter=sol.n_iter)
    return MonitorOutput(
        name=name, t=np.asarray(gnss.t), pos_enu=sol.x[..., :3], clock=sol.x[..., 3], hpl=hpl, vpl=vpl,
        test_stat=sse, threshold=T2, alert=ok & (sse > T2), available=availability(hpl, vpl, levels, ok),
        service_levels=tuple(st.service_levels), n_used=geom.n_used.astype(np.int16),
        excluded=np.full(reason.shape, -1, np.int16), reason=reason, reasons=PIXEL_REASONS, diagnostics=diag,
    )


@dataclass(frozen=True)
class PixelState:
    """The pixel monitor's start point in force before the next epoch, (B..., 4) or None."""

    x_start: NDArray | None = None


@dataclass(frozen=True)
class PixelMonitor:
    """The patent's pixel-domain monitor (seed 003) in the loop: state = :class:`PixelState`."""

    name: str
    context: MonitorContext
    inputs: ClassVar[frozenset[str]] = frozenset({"gnss", "vision"})
    reference: ClassVar[str] = REFERENCE_POINT

    def prepare(self) -> None:
        """Compile the kernels (numba caches them beside the package) before the first epoch."""
        from testbed.integrity.kernels import compile_all

        compile_all()

    def initial_state(self) -> PixelState:
        return PixelState()

    def step(self, obs: Observations, state: PixelState) -> tuple[MonitorOutput, PixelState]:
        out = pixel_monitor(obs.gnss, obs.vision, self.context.frame, self.context.integrity, name=self.name,
                            x_carry=state.x_start)
        x = out.diagnostics.x_start
        return out, PixelState(x[..., -1, :] if x.shape[-2] else state.x_start)


def build_monitor(context: MonitorContext, options) -> PixelMonitor:
    if options:
        raise ValueError(f"pixel takes no options (its settings are [integrity]); got {sorted(options)}")
    return PixelMonitor("pixel", context)
