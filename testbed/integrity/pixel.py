"""Pixel-domain vision integrity (the vision-integrity patent; docs/design/integrity.md §10).

Measurements are the pixel coordinates of surveyed landmarks, two rows per
detected landmark, stacked with the GPS pseudorange rows: ``H′ = [H; G]``.
The pixel model (:mod:`.pixel_model`) projects the line of sight from the
*estimated* camera position, oriented by the aircraft's attitude *reference*
(never truth) and the camera mount, through the pinhole intrinsics ``K``. ``K``
is used in place of the patent's ``T_c^pix`` (the patent's matrix is ``K`` for a
camera whose pixel grid is described by its physical size H×W, M×N pixels and
focal length f; the two are the same map, ``K`` is what the vision front end
publishes).

Measurement noise model (stated, as the task asks):

* detection noise: ``σ_px`` per landmark, independent in u and v;
* attitude-reference error: a small body-frame rotation δφ ~ N(0, diag(σ_att²)),
  σ_att = ``vision.attitude_sigma`` (roll, pitch, yaw as rotations about body
  x, y, z – exact to first order for small errors at small pitch);
* camera dithering on its mount: a small camera-frame rotation with the rms the
  vision front end publishes (``vision.dither_sigma``; its statistics, never
  its realisation);

both rotations move every landmark's pixels coherently, so the pixel covariance
is the full ``Σ_pix = σ_px² I + J_att Σ_att J_attᵀ + J_d Σ_d J_dᵀ`` (2L × 2L,
correlated across landmarks), evaluated once at the starting state. Landmark
survey error is not modelled (5 cm at a kilometre is 0.05 px at f = 1000 px).

Start point (the patent's step 1): this epoch's GPS fix; else a vision-only
fix from the landmarks' bearings through the attitude reference
(:func:`.pixel_model.bearing_fix`); else the last start carried forward (across
blocks too); with none of them the epoch is unavailable with its own reason.

Protection levels (patent step 6), with slopes in weighted form
(slope² = ‖A_H b‖² / bᵀWSb, so ``s_bias = sqrt(λ_det)`` in normalised units;
A_H the horizontal rows of A):

* H1 fault-free: ``HPL₁ = K_H σ_x``, σ_x the semi-major axis of the horizontal
  error ellipse (sqrt of the largest eigenvalue of J's E/N block) and
  ``VPL₁ = K_ff sqrt(J₃₃)``, ``K_ff = Φ⁻¹(1 − P_ff/2)``. The patent's
  ``K_H = K_ff`` bounds one axis, not the radial error: for a circular error
  P(r > K_ff σ) = exp(−K_ff²/2), 6.9 P_ff at P_ff = 1e-7. The default
  (``[monitor.pixel] h1 = "radial"``) takes ``K_H = sqrt(−2 ln P_ff)``, for which
  P(r > K_H σ_x) ≤ P_ff for every ellipse; ``"patent"`` keeps the printed form;
* H2 one fault (a satellite, or one landmark's (u, v) pair at the worst angle θ,
  a 2×2 generalised eigenvalue problem): ``HPL₂ = max slope · sqrt(λ_det)``;
* H3 two faults (two satellites, two landmarks or one of each; generalised
  eigenvalue on the stacked 2–4 columns): ``HPL₃ = max slope₂ · sqrt(λ_det)``;
* ``HPL = sqrt(max(HPL₁, HPL₂)² + HPL₃²)``, VPL likewise.

Exclusion (the patent's "故障检测和排除") is :mod:`.fde`'s, with a satellite's
row and a landmark's pixel pair as the units; the reduced solve recomputes the
pixel weights from the covariance of the rows it keeps.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from itertools import combinations
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

from testbed.frames import LocalFrame, q_to_R
from testbed.integrity import lsq
from testbed.integrity.fde import Verdict, exclude
from testbed.inertial import body_to_world
from testbed.integrity.levels import availability, service_level
from testbed.integrity.gps_only import gps_satellites
from testbed.integrity.monitor import MonitorContext, MonitorCost, MonitorDefaults, Observations, REFERENCE_POINT
from testbed.integrity.pixel_model import attitude_pixel_jacobians, bearing_fix, pixel_covariance, project_landmarks
from testbed.integrity.raim import compact_rows, scatter_rows
from testbed.integrity.settings import IntegritySettings, PixelOptions
from testbed.records import Diagnostics, GnssEpochs, MonitorOutput, VisionEpochs, epoch_array

__all__ = ["PIXEL_REASONS", "NO_LANDMARK", "NO_START", "PixelDiagnostics", "PixelMonitor", "PixelState",
           "fault_units", "h1_factor", "pixel_monitor"]


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


def h1_factor(p_ff: float, form: str = "radial") -> float:
    """The H1 multiplier of the horizontal error ellipse's semi-major axis (module doc).

    ``"radial"``: sqrt(−2 ln P_ff), so P(r > K σ_max) ≤ P_ff for any 2-D Gaussian;
    ``"patent"``: Φ⁻¹(1 − P_ff/2), a one-axis bound.
    """
    if form == "radial":
        return float(np.sqrt(-2.0 * np.log(p_ff)))
    if form == "patent":
        return float(stats.norm.isf(p_ff / 2))
    raise ValueError(f"h1: expected 'radial' or 'patent', got {form!r}")


def _ffill_epochs(x: NDArray, carry: NDArray | None = None) -> NDArray:
    """Forward-fill NaN rows along the epoch axis (-2) of ``x`` (..., T, k).

    ``carry`` (..., k) is the value in force before the first epoch (e.g. the
    last start of the previous block of a live run); None leaves leading gaps NaN.
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
PIXEL_REASONS: tuple[str, ...] = lsq.REASONS + (
    "unavailable: no landmark in view (the pixel monitor needs vision)",
    "unavailable: no start point (no GNSS fix, fewer than two landmarks, no earlier fix)",
)
NO_LANDMARK = len(lsq.REASONS)
NO_START = NO_LANDMARK + 1


@dataclass(frozen=True)
class PixelDiagnostics(Diagnostics):
    """The pixel-domain monitor's diagnostics (B..., T[, ...]), of the full-set solve.

    x_start : the iteration's start state per epoch; start_kind : 0 GPS fix, 1 vision-only
    fix, 2 carried, 3 given (``x0``), -1 none.
    hpl1/2/3, vpl1/2/3 : the three hypotheses' levels (m); ``sigma_x`` the error-ellipse
    semi-major axis; slopes per satellite slot (NaN unused), per landmark slot (NaN unused),
    and the worst pair; residuals in m (pseudoranges) and px (landmarks). ``tracked`` : the
    landmarks used (detected and within ``max_landmarks``).
    """

    x_start: NDArray = epoch_array(1)
    start_kind: NDArray = epoch_array()
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
    tracked: NDArray = epoch_array(1)
    n_landmarks: NDArray = epoch_array()
    n_sat: NDArray = epoch_array()
    converged: NDArray = epoch_array()
    n_iter: NDArray = epoch_array()
    k_ff: float = 0.0
    k_h1: float = 0.0


START_GPS, START_VISION, START_CARRIED, START_GIVEN = range(4)


@dataclass(frozen=True)
class _Problem:
    """The stacked problem of P epochs (flat over the batch and epoch axes): Ng GPS rows
    (compacted), then 2·Lc pixel rows of the tracked landmarks (:func:`_spread_landmarks`)."""

    anchor: NDArray  # (P, Ng, 3) satellites, world ENU
    z_g: NDArray  # (P, Ng)
    w_g: NDArray  # (P, Ng)
    m_g: NDArray  # (P, Ng)
    uv: NDArray  # (P, Lc, 2)
    det: NDArray  # (P, Lc)
    lm: NDArray  # (P, Lc, 3) landmarks, world ENU
    Sig_pix: NDArray  # (P, 2Lc, 2Lc) at the start state
    q_ref: NDArray  # (P, 4)
    x_start: NDArray  # (P, 4), 0 where there is none
    has_start: NDArray  # (P,)
    lever_ant: NDArray
    camera: object
    K: NDArray
    frame: LocalFrame

    def take(self, sel: NDArray) -> _Problem:
        per = {f.name: getattr(self, f.name)[sel] for f in fields(self)
               if f.name not in ("lever_ant", "camera", "K", "frame")}
        return replace(self, **per)


@dataclass(frozen=True)
class _Fit:
    """One solve of a :class:`_Problem` with the three hypotheses' levels (P epochs)."""

    sol: lsq.WlsSolution
    m_g: NDArray
    det: NDArray
    hpl: NDArray
    vpl: NDArray
    T2: NDArray
    reason: NDArray
    levels: dict  # hpl1..3, vpl1..3, sigma_x, lam_det
    slopes: tuple  # hs1, vs1, hs2, vs2

    @property
    def ok(self) -> NDArray:
        return self.reason == lsq.Reason.OK

    def verdict(self) -> Verdict:
        g = self.sol.geometry
        return Verdict(x=self.sol.x, test_stat=self.sol.sse, threshold=self.T2, dof=g.dof, hpl=self.hpl,
                       vpl=self.vpl, ok=self.ok, n_used=g.n_used.astype(np.int16))


def _inverse_on_mask(Sig: NDArray, mask: NDArray) -> NDArray:
    """Inverse of the used sub-block (unused rows/columns zero), batched, NaN-safe."""
    mm = mask[..., :, None] & mask[..., None, :]
    eye = np.eye(Sig.shape[-1])
    S0 = np.where(mm & np.isfinite(Sig), Sig, 0.0) + eye * ~mask[..., None, :]
    return np.where(mm, np.linalg.inv(S0), 0.0)


def _nanmax(a: NDArray) -> NDArray:
    return np.max(np.where(np.isnan(a), -np.inf, a), axis=-1, initial=-np.inf)


def _solve(pb: _Problem, st: IntegritySettings, opt: PixelOptions, keep: NDArray | None = None) -> _Fit:
    """Iterated WLS of the stacked rows (``keep`` (P, N): rows left in, for exclusion) and the PLs."""
    P, Ng = pb.z_g.shape
    Lc = pb.det.shape[-1]
    m_g, det = pb.m_g, pb.det
    if keep is not None:
        m_g, det = m_g & keep[:, :Ng], det & keep[:, Ng::2]
    m_pix = np.repeat(det, 2, axis=-1)
    N = Ng + 2 * Lc
    W = np.zeros((P, N, N))
    W[:, np.arange(Ng), np.arange(Ng)] = np.where(m_g, pb.w_g, 0.0)
    W[:, Ng:, Ng:] = _inverse_on_mask(pb.Sig_pix, m_pix)  # of the kept rows' covariance
    mask = np.concatenate([m_g, m_pix], axis=-1)
    z = np.concatenate([pb.z_g, pb.uv.reshape(P, 2 * Lc)], axis=-1)
    camera, K, frame = pb.camera, pb.K, pb.frame

    def model(x: NDArray) -> tuple[NDArray, NDArray]:
        # the local-ENU -> world rotation follows the current estimate (its
        # 1.6e-7 rad/m dependence on x is left out of the Jacobian)
        Rb = body_to_world(frame, x[..., :3], pb.q_ref)
        ant = np.einsum("...ij,j->...i", Rb, pb.lever_ant)
        h_g, G_g = lsq.range_model(pb.anchor, np.ones(Ng), ant[..., None, :])(x)
        cam = np.einsum("...ij,j->...i", Rb, camera.lever_arm_body)
        uv, H, s = project_landmarks(x[..., :3], Rb @ camera.R_sensor_to_body, cam, pb.lm, K)
        behind = s[..., 2] <= 0.0  # a landmark behind the camera has no pixel
        uv = np.where(behind[..., None], np.nan, uv)
        H = np.where(behind[..., None, None], np.nan, H)
        G_p = np.concatenate([H, np.zeros(H.shape[:-1] + (1,))], axis=-1).reshape(P, 2 * Lc, 4)
        return np.concatenate([h_g, uv.reshape(P, 2 * Lc)], -1), np.concatenate([G_g, G_p], -2)

    sol = lsq.iterate_wls(model, z, W, mask, pb.x_start, n_iter=st.max_iter, tol_m=st.tol_m, max_cond=st.max_cond)
    geom = sol.geometry
    WS = geom.ws_matrix()
    cols1, cols2, _ = fault_units(Ng, Lc, opt.two_faults)
    with np.errstate(invalid="ignore", over="ignore"):
        hs1, vs1 = lsq.subspace_slopes(geom, cols1, WS)
        hs2, vs2 = lsq.subspace_slopes(geom, cols2, WS) if len(cols2) else (np.zeros((P, 0)),) * 2
    lam = lsq.lambda_det(geom.dof, st.p_fa, st.p_md)
    sb = np.sqrt(lam)
    k_ff, k_h = h1_factor(opt.p_ff, "patent"), h1_factor(opt.p_ff, opt.h1)
    J = geom.J
    with np.errstate(invalid="ignore"):
        Jh = np.where(np.isfinite(J[..., :2, :2]), J[..., :2, :2], 0.0)
        sigma_x = np.sqrt(np.linalg.eigvalsh(Jh)[..., -1])
        hpl1, vpl1 = k_h * sigma_x, k_ff * np.sqrt(J[..., 2, 2])
        hpl2, vpl2 = _nanmax(hs1) * sb, _nanmax(vs1) * sb
        hpl3, vpl3 = (_nanmax(hs2) * sb, _nanmax(vs2) * sb) if len(cols2) else (np.zeros(P),) * 2
        hpl = np.sqrt(np.maximum(hpl1, hpl2) ** 2 + hpl3**2)
        vpl = np.sqrt(np.maximum(vpl1, vpl2) ** 2 + vpl3**2)
    reason = sol.reason.copy()
    undetectable = ~np.isfinite(hpl) | ~np.isfinite(vpl)
    reason = np.where((reason == lsq.Reason.OK) & undetectable & np.isfinite(sb), lsq.Reason.UNDETECTABLE, reason)
    if opt.vision_rows:
        # without a landmark the solve is GPS RAIM's: the pixel monitor's integrity case does not apply
        reason = np.where((reason == lsq.Reason.OK) & ~det.any(-1), NO_LANDMARK, reason)
    # a solve started from nowhere (the frame origin) reports NO_START, unless too few rows explain it
    no_start = ~pb.has_start & (reason != lsq.Reason.NO_POSITION)
    reason = np.where(no_start, NO_START, reason).astype(np.int8)
    ok = reason == lsq.Reason.OK
    T2 = lsq.chi2_threshold(geom.dof, st.p_fa)
    levels = {"hpl1": hpl1, "hpl2": hpl2, "hpl3": hpl3, "vpl1": vpl1, "vpl2": vpl2, "vpl3": vpl3,
              "sigma_x": sigma_x, "lam_det": lam}
    return _Fit(sol=sol, m_g=m_g, det=det, hpl=np.where(ok, hpl, np.nan), vpl=np.where(ok, vpl, np.nan),
                T2=np.where(ok, T2, np.nan), reason=reason, levels=levels, slopes=(hs1, vs1, hs2, vs2))


@dataclass(frozen=True)
class _Layout:
    """How the flat compacted problem maps back to the records' (B..., T, S | L) slots."""

    lead: tuple
    S: int
    L: int
    sat_idx: NDArray  # (P, Ng) slot of each compacted GPS row
    lm_idx: NDArray  # (P, Lc) slot of each compacted landmark
    start_kind: NDArray  # (P,)


def _read_problem(gnss: GnssEpochs, vision: VisionEpochs, frame: LocalFrame, st: IntegritySettings, opt: PixelOptions,
                  x0: ArrayLike | None, x_carry: ArrayLike | None) -> tuple[_Problem, _Layout]:
    pr = np.asarray(gnss.pseudorange, float)
    uv_all = np.asarray(vision.pixel_uv, float)
    lead = np.broadcast_shapes(pr.shape[:-1], uv_all.shape[:-2])
    S, L = pr.shape[-1], uv_all.shape[-2]
    P = int(np.prod(lead, dtype=np.int64))
    flat = lambda a, tail: np.broadcast_to(np.asarray(a), lead + tail).reshape((P,) + tail)  # noqa: E731
    vis = flat(np.asarray(gnss.visible, bool), (S,))
    sat_enu = frame.ecef_to_enu(flat(gnss.sat_pos_ecef, (S, 3)))
    det_all = flat(np.asarray(vision.detected, bool), (L,))
    if not opt.vision_rows:
        det_all = np.zeros_like(det_all)
    uv_all = flat(uv_all, (L, 2))
    q_ref = flat(vision.q_body_to_enu_ref, (4,))
    lm_all = flat(_survey_per_epoch(vision, lead), (L, 3))
    lm_all = frame.ecef_to_enu(lm_all)
    K = np.asarray(vision.K, float)

    idx, m_g, Ng = compact_rows(vis)
    z_g = np.take_along_axis(flat(pr, (S,)), idx, -1)
    w_g = lsq.weights_from_sigma(np.take_along_axis(flat(gnss.sigma, (S,)), idx, -1))
    anchor = np.take_along_axis(sat_enu, idx[..., None], -2)

    x_start, kind = _start_points(frame, (anchor, z_g, w_g, m_g), (uv_all, det_all, lm_all), q_ref, K,
                                  gnss.antenna.lever_arm_body, vision.camera, st, lead, x0, x_carry)
    has_start = np.isfinite(x_start).all(-1)
    x_start = np.where(has_start[:, None], x_start, 0.0)

    # landmark rows: at most max_landmarks detected ones, spread over the image
    Lc = max(min(int(det_all.sum(-1).max(initial=0)), opt.max_landmarks), 1)
    lm_idx = _spread_landmarks(uv_all, det_all, np.linalg.norm(lm_all - x_start[:, None, :3], axis=-1), Lc)
    det = np.take_along_axis(det_all, lm_idx, -1)
    uv = np.take_along_axis(uv_all, lm_idx[..., None], -2)
    lm = np.take_along_axis(lm_all, lm_idx[..., None], -2)
    sigma_px = np.take_along_axis(flat(vision.sigma_px, (L,)), lm_idx, -1)

    # pixel covariance at the start state: detection noise, attitude reference, dithering
    Rb = body_to_world(frame, x_start[:, :3], q_ref)
    J_att, J_dith = attitude_pixel_jacobians(x_start[:, :3], Rb, vision.camera, lm, K)
    rotations = []
    if opt.attitude_noise:
        rotations.append((J_att, np.asarray(vision.attitude_sigma, float)))
    if opt.dither_noise:
        rotations.append((J_dith, np.asarray(vision.dither_sigma, float)))
    Sig_pix = pixel_covariance(sigma_px, rotations)
    pb = _Problem(anchor=anchor, z_g=z_g, w_g=w_g, m_g=m_g, uv=uv, det=det, lm=lm, Sig_pix=Sig_pix, q_ref=q_ref,
                  x_start=x_start, has_start=has_start, lever_ant=np.asarray(gnss.antenna.lever_arm_body, float),
                  camera=vision.camera, K=K, frame=frame)
    return pb, _Layout(lead=lead, S=S, L=L, sat_idx=idx, lm_idx=lm_idx, start_kind=kind)


def _spread_landmarks(uv: NDArray, det: NDArray, range_m: NDArray, n: int) -> NDArray:
    """(P, n) landmark slots to track: the nearest detected one, then greedily the detected one
    farthest in the image from those chosen (farthest-point sampling), detected slots first.

    Spread pixels make a good geometry from few rows; the nearest-n would take one marker's
    clustered corners. Epochs with fewer than n detections fill with undetected slots.
    """
    P, L = det.shape
    rows = np.arange(P)
    chosen = np.zeros((P, L), bool)
    out = np.zeros((P, n), np.int64)
    first = np.argmin(np.where(det, range_m, np.inf), axis=-1)
    gap = np.full((P, L), np.inf)
    pick = first
    for k in range(n):
        out[:, k] = pick
        chosen[rows, pick] = True
        d = np.linalg.norm(np.nan_to_num(uv) - np.nan_to_num(uv[rows, pick])[:, None, :], axis=-1)
        gap = np.minimum(gap, d)
        score = np.where(det & ~chosen, gap, np.where(~chosen, -1.0, -np.inf))
        pick = np.argmax(score, axis=-1)
    return out


def _survey_per_epoch(vision: VisionEpochs, lead: tuple) -> NDArray:
    """The surveyed landmarks (L, 3) or one survey per trial (B..., L, 3), broadcastable to (B..., T, L, 3)."""
    p = np.asarray(vision.landmark_pos_ecef, float)
    if p.ndim == 2:
        return p
    if p.ndim == len(lead) + 1 and p.shape[-1] == 3:  # (B..., L, 3): one survey per trial
        return p[..., None, :, :]
    trials = f"one survey per trial {lead[:-1] + (p.shape[-2], 3)}" if len(lead) > 1 else \
        "no survey per trial (the observations have no trial axis)"
    raise ValueError(f"pixel_monitor: vision.landmark_pos_ecef has shape {p.shape}; expected (L, 3), or {trials}")


def _start_points(frame, gps_rows, vision_rows, q_ref, K, lever_ant, camera, st, lead, x0, x_carry):
    """Start state (P, 4) of each epoch and its kind (module doc); NaN where there is none."""
    P = q_ref.shape[0]
    if x0 is not None:
        x = np.broadcast_to(np.asarray(x0, float), lead + (4,)).reshape(P, 4)
        return x, np.where(np.isfinite(x).all(-1), START_GIVEN, -1)
    anchor, z_g, w_g, m_g = gps_rows
    Ng = z_g.shape[-1]
    R0 = q_to_R(q_ref)
    ant0 = np.einsum("...ij,j->...i", R0, lever_ant)
    gps = lsq.solve_ranges(anchor, z_g, w_g, m_g, np.ones(Ng), offset_enu=ant0[..., None, :],
                           n_iter=st.max_iter, tol_m=st.tol_m, max_cond=st.max_cond)
    uv, det, lm = vision_rows
    centre = np.where(det[..., None], lm, 0.0).sum(-2) / np.maximum(det.sum(-1), 1)[..., None]
    Rb = body_to_world(frame, centre, q_ref)  # the local-to-world tilt at the landmarks: < 0.1 mrad off
    cam, ok_v = bearing_fix(uv, det, K, Rb @ camera.R_sensor_to_body, lm)
    p_v = cam - np.einsum("...ij,j->...i", Rb, camera.lever_arm_body)
    with np.errstate(invalid="ignore", divide="ignore"):  # the clock from this epoch's pseudoranges, if any
        rho = np.linalg.norm(anchor - (p_v + ant0)[..., None, :], axis=-1)
        clk = np.where(m_g, z_g - rho, 0.0).sum(-1) / m_g.sum(-1)
    x_v = np.concatenate([p_v, np.where(np.isfinite(clk), clk, 0.0)[..., None]], -1)
    has_g = np.isfinite(gps.x).all(-1)
    x = np.where(has_g[:, None], gps.x, np.where(ok_v[:, None], x_v, np.nan))
    kind = np.where(has_g, START_GPS, np.where(ok_v, START_VISION, -1))
    carried = _ffill_epochs(x.reshape(lead + (4,)), x_carry).reshape(P, 4)
    kind = np.where((kind < 0) & np.isfinite(carried).all(-1), START_CARRIED, kind)
    return carried, kind


def _scatter_landmarks(values: NDArray, lm_idx: NDArray, det: NDArray, L: int) -> NDArray:
    """Per tracked landmark values (P, Lc[, k]) back in landmark slots (P, L[, k]), NaN elsewhere."""
    tail = values.shape[2:]
    out = np.full((values.shape[0], L) + tail, np.nan)
    v = np.where(det.reshape(det.shape + (1,) * len(tail)), values, np.nan)
    np.put_along_axis(out, lm_idx.reshape(lm_idx.shape + (1,) * len(tail)), v, 1)
    return out


def _output(fit: _Fit, pb: _Problem, lay: _Layout, st: IntegritySettings, opt: PixelOptions, t: NDArray,
            name: str) -> MonitorOutput:
    lead, S, L = lay.lead, lay.S, lay.L
    Ng = pb.z_g.shape[-1]
    hs1, vs1, hs2, vs2 = fit.slopes
    sol, ok = fit.sol, fit.ok
    shape = lambda a: a.reshape(lead + a.shape[1:])  # noqa: E731
    r = sol.residual
    lv = fit.levels
    diag = PixelDiagnostics(
        x_start=shape(np.where(pb.has_start[:, None], pb.x_start, np.nan)), start_kind=shape(lay.start_kind),
        **{k: shape(v) for k, v in lv.items()}, k_ff=h1_factor(opt.p_ff, "patent"), k_h1=h1_factor(opt.p_ff, opt.h1),
        hslope_sat=shape(scatter_rows(hs1[:, :Ng], lay.sat_idx, fit.m_g, S)),
        vslope_sat=shape(scatter_rows(vs1[:, :Ng], lay.sat_idx, fit.m_g, S)),
        hslope_lm=shape(_scatter_landmarks(hs1[:, Ng:], lay.lm_idx, fit.det, L)),
        vslope_lm=shape(_scatter_landmarks(vs1[:, Ng:], lay.lm_idx, fit.det, L)),
        hslope_pair_max=shape(_nanmax(hs2)), vslope_pair_max=shape(_nanmax(vs2)),
        residual_pr=shape(scatter_rows(r[:, :Ng], lay.sat_idx, fit.m_g, S)),
        residual_px=shape(_scatter_landmarks(r[:, Ng:].reshape(r.shape[0], -1, 2), lay.lm_idx, fit.det, L)),
        tracked=shape(_scatter_landmarks(np.ones(fit.det.shape), lay.lm_idx, fit.det, L) == 1),
        n_landmarks=shape(fit.det.sum(-1)), n_sat=shape(fit.m_g.sum(-1)), converged=shape(sol.converged),
        n_iter=shape(sol.n_iter))
    levels = tuple(service_level(s) for s in st.service_levels)
    sse = np.where(ok, sol.sse, np.nan)
    hpl, vpl = shape(fit.hpl), shape(fit.vpl)
    return MonitorOutput(
        name=name, t=np.asarray(t), pos_enu=shape(sol.x[:, :3]), clock=shape(sol.x[:, 3]), hpl=hpl, vpl=vpl,
        test_stat=shape(sse), threshold=shape(fit.T2), alert=shape(ok & (sse > fit.T2)),
        available=availability(hpl, vpl, levels, shape(ok)), service_levels=tuple(st.service_levels),
        n_used=shape(sol.geometry.n_used.astype(np.int16)), excluded=np.full(lead, -1, np.int16),
        reason=shape(fit.reason), reasons=PIXEL_REASONS, diagnostics=diag)


def _exclusion(out: MonitorOutput, fit: _Fit, pb: _Problem, lay: _Layout, st: IntegritySettings,
               opt: PixelOptions) -> MonitorOutput:
    """FDE (:func:`testbed.integrity.fde.exclude`): units are satellites' rows and landmarks' pixel pairs."""
    Ng, Lc = pb.z_g.shape[-1], pb.det.shape[-1]
    unit_rows = np.zeros((Ng + Lc, Ng + 2 * Lc), bool)
    unit_rows[np.arange(Ng), np.arange(Ng)] = True
    for l in range(Lc):
        unit_rows[Ng + l, Ng + 2 * l: Ng + 2 * l + 2] = True
    label = np.concatenate([np.where(fit.m_g, lay.sat_idx, -1), np.where(fit.det, lay.S + lay.lm_idx, -1)], -1)
    start = replace(pb, x_start=np.where(np.isfinite(fit.sol.x), fit.sol.x, pb.x_start))

    def solve_without(sel: NDArray, keep: NDArray) -> Verdict:
        return _solve(start.take(sel), st, opt, keep).verdict()

    return exclude(out, unit_rows, label.reshape(lay.lead + label.shape[1:]), solve_without, st)


def pixel_monitor(gnss: GnssEpochs, vision: VisionEpochs, frame: LocalFrame,
                  settings: IntegritySettings | None = None, x0: ArrayLike | None = None,
                  name: str = "pixel", x_carry: ArrayLike | None = None,
                  options: PixelOptions | None = None) -> MonitorOutput:
    """The patent's pixel-domain integrity monitor, GPS + landmark pixels, batched.

    Parameters
    ----------
    gnss : GnssEpochs (B..., T, S); ``visible`` rows are used.
    vision : VisionEpochs (B..., T, L) at the same epochs; ``detected`` landmarks
        give two rows each (u, v), at most ``options.max_landmarks`` of them, spread over the image;
        ``landmark_pos_ecef`` one survey (L, 3) or one per trial (B..., L, 3).
    frame : world frame of the state [E, N, U, clock] (clock dropped when an
        epoch has no pseudorange row).
    settings : IntegritySettings (``p_fa``, ``p_md``, ``fde*``, solver tolerances, service levels).
    options : PixelOptions, the monitor's own (``p_ff``, the H1 form, H3, the landmark cap, the
        covariance terms, whether vision rows enter).
    x0 : (B..., T, 4) start of the iteration (e.g. the navigation prediction).
        Default: the module doc's start point.
    x_carry : (B..., 4) the start state in force before the first epoch (a live
        run passes the previous block's last start (:class:`PixelState`) so that
        block-by-block equals one call over the whole flight).

    Returns
    -------
    MonitorOutput (reasons :data:`PIXEL_REASONS`) with :class:`PixelDiagnostics`, and an
    FDE record when ``settings.fde``.
    """
    st = settings or IntegritySettings()
    opt = options or PixelOptions()
    if len(gnss.t) != len(vision.t) or not np.allclose(gnss.t, vision.t, atol=1e-6):
        raise ValueError(f"pixel_monitor: gnss and vision epochs must coincide; got {len(gnss.t)} GNSS and "
                         f"{len(vision.t)} vision epochs (resample one onto the other first)")
    pb, lay = _read_problem(gnss, vision, frame, st, opt, x0, x_carry)
    fit = _solve(pb, st, opt)
    out = _output(fit, pb, lay, st, opt, gnss.t, name)
    return _exclusion(out, fit, pb, lay, st, opt) if st.fde else out


@dataclass(frozen=True)
class PixelState:
    """The pixel monitor's start point in force before the next epoch, (B..., 4) or None."""

    x_start: NDArray | None = None


@dataclass(frozen=True)
class PixelMonitor(MonitorDefaults):
    """The vision-integrity patent's pixel-domain monitor in the loop: state = :class:`PixelState`."""

    name: str
    context: MonitorContext
    options: PixelOptions = PixelOptions()
    inputs: ClassVar[frozenset[str]] = frozenset({"gnss", "vision"})
    reference: ClassVar[str] = REFERENCE_POINT
    compiles_kernels: ClassVar[bool] = True

    def prepare(self) -> None:
        """Compile the kernels (numba caches them beside the package) before the first epoch."""
        from testbed.integrity.kernels import compile_all

        compile_all()

    def initial_state(self) -> PixelState:
        return PixelState()

    def step(self, obs: Observations, state: PixelState) -> tuple[MonitorOutput, PixelState]:
        obs = gps_satellites(obs)  # the pixel monitor stays GPS-only (docs/design/gnss.md §5)
        out = pixel_monitor(obs.gnss, obs.vision, self.context.frame, self.context.integrity, name=self.name,
                            x_carry=state.x_start, options=self.options)
        x = out.diagnostics.x_start
        if not x.shape[-2]:
            return out, state
        last = x[..., -1, :]
        if state.x_start is not None:  # a block without any start keeps the one in force
            last = np.where(np.isfinite(last), last, state.x_start)
        return out, PixelState(last)


def build_monitor(context: MonitorContext, options: PixelOptions) -> PixelMonitor:
    """The pixel monitor with the approach's ``[monitor.pixel]`` options."""
    return PixelMonitor("pixel", context, options)


def cost(options: PixelOptions) -> MonitorCost:
    """Per trial-epoch, measured alone on va-raim-2015 and zunz-rwy05-markers (3 and 12 of 30 landmarks), the
    draws subtracted: it weighs at most ``max_landmarks`` landmarks."""
    return MonitorCost((5e3, 14e3, 0.0), (16e-6, 41e-6, 0.0), landmark_cap=options.max_landmarks)
