"""Vision-aided RAIM (VA-RAIM: the VA-RAIM paper §2.3; docs/design/integrity.md §7-§9).

Per epoch (batched over trials and epochs, no epoch loop):

1. GPS-only RAIM (:func:`testbed.integrity.raim.gps_raim`) gives the GPS fix,
   its covariance ``J_G`` and the calibration criteria.
2. Vision pseudoranges by the cosine rule (:mod:`.vision_ranges`), started
   from ranges predicted from the GPS fix (or the last one, forward-filled
   with a growing covariance) — never from truth; non-convergence and branch
   jumps make vision unavailable for that epoch.
3. GPS calibration (:mod:`.calibration`) removes the landmark-survey bias.
4. Integrated iterated WLS on the stacked rows (:mod:`.lsq`):
   * N_V = 3: the modified, single-fault-preserving equation (the VA-RAIM paper, eq. 18;
     docs/design/integrity.md §9, eq. 9.2)
     ``z′ = A ẑ_V``, ``H′ = A H_V``, ``Σ′ = A Σ̂_V Aᵀ``;
   * N_V > 3: ``ẑ_V`` with its full covariance Σ̂_V (``A Σ̂_V Aᵀ`` would be
     N_C × N_C of rank N_V: singular);
   then the SSE test, slopes, both PL variants and availability per level.

The state is the aircraft reference point ``[E, N, U, clock]`` in the world
frame: GPS rows see the antenna at ``x + R·l_ant`` and vision rows the camera
at ``ĉ = x + R·l_cam``, with R from the navigation attitude *reference*
(``VisionEpochs.q_body_to_enu_ref``), never truth. Vision rows have no clock
term, so an epoch with no GPS rows is singular (the clock is unobservable).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, field_validator
from scipy import optimize, stats

from testbed.frames import LocalFrame, q_to_R
from testbed.integrity import kernels, lsq
from testbed.integrity.batching import map_trial_chunks
from testbed.integrity.calibration import (
    CalibratedRanges,
    calibrate,
    calibration_epochs,
    landmark_set_key,
)
from testbed.integrity.levels import SERVICE_LEVELS, service_level
from testbed.integrity.gps_only import gps_satellites
from testbed.integrity.monitor import MonitorContext, MonitorCost, MonitorDefaults, Observations, REFERENCE_POINT, compute
from testbed.integrity.fde import Verdict, exclude, flat_take
from testbed.integrity.raim import (
    GpsFix,
    GpsRaimMonitor,
    fix_at_solution,
    gps_exclusion,
    gps_fix,
    gps_output,
    scatter_rows,
    snapshot_output,
    snapshot_verdict,
    solution_verdict,
)
from testbed.integrity.settings import IntegritySettings
from testbed.integrity.vision_ranges import (
    VISION_REASONS,
    VisionRanges,
    VisionReason,
    VisionRangeSettings,
    vision_pseudoranges,
)
from testbed.records import (
    Diagnostics,
    GnssEpochs,
    MonitorOutput,
    VisionEpochs,
    concat_epochs,
    epoch_array,
    one_landmark_survey,
    take_epochs,
)
from testbed.schema import StrictModel


class VaRaimOptions(StrictModel):
    """VA-RAIM's own options (``[monitor.va_raim]``)."""

    variant: Literal["gated", "seed"] = Field(
        "gated", description="'gated' (default): vision rows only where the linearised vision-range error is "
                             "small enough next to the range for the paper's Gaussian model to hold at the test's "
                             "threshold (linear_range_limit); 'seed': the paper's method as written (every "
                             "converged vision solve), which exceeds its false-alarm budget when sigma_V/m is large.")
    linearity_inflation: float = Field(
        0.1, gt=0.0, le=1.0, description="'gated': the relative excess of a vision row's two-sided tail probability "
                                         "at the detection threshold that is tolerated (0.1 = 10 %).")
    vision: VisionRangeSettings = Field(default_factory=VisionRangeSettings,
                                        description="Cosine-rule solve and branch protection.")
    calibration: Literal["gps", "none"] = Field(
        "gps", description="'gps': calibrate vision ranges with GPS (the VA-RAIM paper's eq. 12-18); 'none': use raw ranges "
                           "with the survey error in their covariance (for comparison).")
    calibration_level: str = Field(
        "APV-I", description="Service level whose alert limits the GPS-only PLs must meet at a calibration epoch.")
    uncalibrated: Literal["exclude", "inflate"] = Field(
        "exclude", description="Vision rows at epochs without a valid calibration for the current landmark set: "
                               "'exclude' them, or 'inflate' = use raw ranges with covariance "
                               "Σ_V + A⁺BΣ_dBA⁺ᵀ (survey error included).")
    landmark_survey_sigma_m: float = Field(
        0.05, ge=0.0, description="Landmark survey error σ_g per axis (m) the monitor assumes (LPE).")
    modified_equation: bool = Field(
        True, description="N_V = 3: use the single-fault-preserving rows z′ = A ẑ_V (the VA-RAIM paper's eq. 18). False: use ẑ_V "
                          "with Σ̂_V (same fix and SSE, different slopes).")
    prior_floor_m: float = Field(
        30.0, ge=0.0, description="1-sigma (m per axis) added to the GPS-fix covariance when it predicts the vision "
                                  "ranges for the branch gate: covers undetected GPS errors, so a GPS fault does not "
                                  "masquerade as a P3P branch jump.")
    prior_speed_m_s: float = Field(
        150.0, gt=0.0, description="When an epoch has no GPS fix the last one is carried forward with sigma growing "
                                   "by this speed (m/s) times the elapsed time.")

    @field_validator("calibration_level")
    @classmethod
    def _known(cls, v: str) -> str:
        if v not in SERVICE_LEVELS:
            raise ValueError(f"unknown service level {v!r}; expected one of {list(SERVICE_LEVELS)}")
        return v


class VaRaimSettings(VaRaimOptions):
    """Settings of the VA-RAIM monitor: its options and the shared integrity settings."""

    integrity: IntegritySettings = Field(default_factory=IntegritySettings,
                                         description="P_FA, P_MD, PL variant, service levels, WLS tolerances "
                                                     "(shared with GPS-only RAIM).")


@functools.lru_cache(maxsize=64)
def linear_range_limit(p_fa: float, inflation: float = 0.1) -> float:
    """Largest relative vision-range error σ_V/m at which the paper's linear model keeps its tail.

    A range from the angle between lines of sight to landmarks a baseline b apart is
    m ≈ b/θ: with θ Gaussian the range is reciprocal-normal, not normal. At the k-sigma
    point of the test (k = Φ⁻¹(1 − P_FA/2), the threshold of a single dominating row)
    its two tails hold Φ(−k/(1 + kε)) + Φ(−k/(1 − kε)) instead of 2Φ(−k), ε = σ_V/m.
    The limit is the ε at which that sum is ``(1 + inflation)·P_FA``; for P_FA = 1e-5
    and 10 % it is 0.53 % (1e-2: 3.0 %). Rows beyond it are heavy-tailed at the test's
    threshold and are left out (variant "gated").
    """
    k = float(stats.norm.isf(p_fa / 2))

    def excess(e: float) -> float:
        return float(stats.norm.cdf(-k / (1 + k * e)) + stats.norm.cdf(-k / (1 - k * e))) - (1 + inflation) * p_fa

    return float(optimize.brentq(excess, 1e-12, 0.999 / k))


def _linear_enough(vr: VisionRanges, limit: float) -> tuple[NDArray, NDArray]:
    """(..., ) the largest σ_V,i/m_i over the used landmarks (NaN without vision) and whether it is ≤ limit."""
    with np.errstate(invalid="ignore", divide="ignore"):
        sig = np.sqrt(np.maximum(np.diagonal(vr.Sigma_V, axis1=-2, axis2=-1), 0.0))
        rel = np.where(vr.used, sig / np.abs(vr.m), -np.inf).max(-1, initial=-np.inf)
    rel = np.where(vr.ok & np.isfinite(rel), rel, np.nan)
    return rel, vr.ok & (rel <= limit)


def _vision_prior(x_g: NDArray, P_g: NDArray, fix: NDArray, t: NDArray, p_enu: NDArray, off_cam: NDArray,
                  st: VaRaimSettings) -> tuple[NDArray, NDArray, NDArray]:
    """(..., T) epoch the prior comes from (-1: none yet), predicted ranges (..., T, L) and their
    covariance (..., T, L, L) (:func:`kernels.vision_prior`)."""
    bt, L = fix.shape, p_enu.shape[0]
    T = bt[-1]
    Bt = int(np.prod(bt[:-1], dtype=np.int64))

    def flat(a: NDArray, tail: tuple, dt: type = np.float64) -> NDArray:
        return kernels.kernel_input(a, bt + tail, (Bt, T) + tail, dt)

    last, m, S = np.empty((Bt, T), np.int64), np.empty((Bt, T, L)), np.empty((Bt, T, L, L))
    kernels.vision_prior(flat(x_g, (4,)), flat(P_g, (3, 3)), flat(fix, (), np.bool_), kernels.kernel_input(t, (T,)),
                         kernels.kernel_input(p_enu, (L, 3)), flat(off_cam, (3,)), st.prior_speed_m_s,
                         st.prior_floor_m, last, m, S)
    return last.reshape(bt), m.reshape(bt + (L,)), S.reshape(bt + (L, L))


def _take_t(a: NDArray, idx: NDArray) -> NDArray:
    ii = idx.reshape(idx.shape + (1,) * (a.ndim - idx.ndim))
    return np.take_along_axis(a, ii, axis=idx.ndim - 1)


@dataclass(frozen=True)
class VaRaimDiagnostics(Diagnostics):
    """VA-RAIM's diagnostics, (B..., T[, ...]).

    Stacked-row quantities (``hslope``, ``vslope``, ``residual``, ``ws_diag``) are
    (B..., T, S + N_C): one column per satellite slot (NaN where unused), then the vision
    block's N_C rows, so their layout does not depend on the batch.
    ``gps`` is GPS RAIM's own output (step 1, at the antenna). ``cal_t`` : time of the
    calibration epoch in use (NaN: uncalibrated).
    """

    hslope: NDArray = epoch_array(1)
    vslope: NDArray = epoch_array(1)
    residual: NDArray = epoch_array(1)
    ws_diag: NDArray = epoch_array(1)
    lam_det: NDArray = epoch_array()
    cond: NDArray = epoch_array()
    hpl_seed: NDArray = epoch_array()
    vpl_seed: NDArray = epoch_array()
    hpl_pbias: NDArray = epoch_array()
    vpl_pbias: NDArray = epoch_array()
    converged: NDArray = epoch_array()
    gps: MonitorOutput = field()
    gps_P: NDArray = epoch_array(2)
    vision_m: NDArray = epoch_array(1)
    vision_Sigma_V: NDArray = epoch_array(2)
    vision_reason: NDArray = epoch_array()
    vision_n_v: NDArray = epoch_array()
    vision_iterations: NDArray = epoch_array()
    vision_residual_stat: NDArray = epoch_array()
    vision_gate_stat: NDArray = epoch_array()
    vision_m_pred: NDArray = epoch_array(1)
    z_hat: NDArray = epoch_array(1)
    Sigma_hat: NDArray = epoch_array(2)
    beta: NDArray = epoch_array(1)
    calibrated: NDArray = epoch_array()
    at_calibration_epoch: NDArray = epoch_array()
    cal_t: NDArray = epoch_array()
    vision_rows_used: NDArray = epoch_array()
    vision_rel_sigma: NDArray = epoch_array()
    vision_linear: NDArray = epoch_array()
    modified: NDArray = epoch_array()
    n_gps: NDArray = epoch_array()
    n_vision_rows: NDArray = epoch_array()
    vision_reasons: tuple[str, ...] = VISION_REASONS
    reads_vision_truth: ClassVar[bool] = True

    def trial_columns(self, vision_truth) -> dict[str, NDArray]:
        """Per-trial sums of the raw and calibrated vision-range errors against the true ranges
        (evaluation, for the campaign tables: count, sum and sum of squares over epochs and landmarks)."""
        m_true = np.asarray(vision_truth.range_m, float)
        col = {}
        for tag, est, ok in (("raw", self.vision_m, None), ("cal", self.z_hat, self.calibrated)):
            err = np.asarray(est, float) - m_true
            good = np.isfinite(err)
            if ok is not None:
                good &= np.asarray(ok, bool)[..., None]
            e0 = np.where(good, err, 0.0)
            col[f"vre_{tag}_n"] = good.sum((-1, -2)).astype(np.int64)
            col[f"vre_{tag}_sum"] = e0.sum((-1, -2))
            col[f"vre_{tag}_sumsq"] = (e0**2).sum((-1, -2))
        # what happens to vision at the epochs a vision fault reaches (the reproduction's "why"): how many,
        # at how many the branch gate drops the vision ranges, at how many vision rows still enter the fit
        hit = np.asarray(vision_truth.faulty, bool).any(-1)
        col["vf_epochs"] = hit.sum(-1).astype(np.int64)
        col["vf_gate_dropped"] = (hit & (np.asarray(self.vision_reason) == VisionReason.BRANCH_JUMP)).sum(-1).astype(np.int64)
        col["vf_rows_used"] = (hit & np.asarray(self.vision_rows_used, bool)).sum(-1).astype(np.int64)
        return col


def _monitor_output(name, t, x, ft: lsq.WlsFit, pls, reason, ok, ist, extra: dict, gps_rows: tuple) -> MonitorOutput:
    """gps_rows : (idx, mask, S) of the compacted GPS rows, to put the stacked rows back in satellite slots."""
    idx, mg, S = gps_rows

    def slots(v: NDArray) -> NDArray:  # (..., Ng + N_C) -> (..., S + N_C)
        return scatter_rows(v, idx, mg, S)

    def diagnostics(pl, per_variant) -> VaRaimDiagnostics:
        return VaRaimDiagnostics(hslope=slots(pl.hslope), vslope=slots(pl.vslope), residual=slots(ft.residual),
                                 lam_det=np.where(ok, pl.lam_det, np.nan), cond=ft.cond, ws_diag=slots(ft.ws_diag),
                                 **per_variant, **extra)

    return snapshot_output(name, t, x, ft, pls, reason, ok, ist, diagnostics)


@dataclass(frozen=True)
class _VisionRows:
    z: NDArray  # (..., R)
    Tm: NDArray  # (..., R, L)
    W: NDArray  # (..., R, R)
    mask: NDArray  # (..., R)
    modified: NDArray  # (...) bool


def _vision_rows(vr: VisionRanges, z: NDArray, Sigma: NDArray, use: NDArray, modified_ok: bool) -> _VisionRows:
    """Rows, transform and weights of the vision block (R = N_C rows; see module doc)."""
    batch, (nc, L) = vr.A.shape[:-2], vr.A.shape[-2:]
    P = int(np.prod(batch, dtype=np.int64))
    modified = use & (vr.n_v == 3) & modified_ok

    def flat(a: NDArray, tail: tuple, dt: type = np.float64) -> NDArray:
        return kernels.kernel_input(a, batch + tail, (P,) + tail, dt)

    Tm, zr, W, mask = np.empty((P, nc, L)), np.empty((P, nc)), np.empty((P, nc, nc)), np.empty((P, nc), bool)
    kernels.vision_rows(flat(vr.A, (nc, L)), flat(z, (L,)), flat(Sigma, (L, L)),
                        flat(vr.used & use[..., None], (L,), np.bool_),
                        flat(vr.pair_mask & use[..., None], (nc,), np.bool_), flat(modified, (), np.bool_),
                        Tm, zr, W, mask)
    return _VisionRows(z=zr.reshape(batch + (nc,)), Tm=Tm.reshape(batch + (nc, L)), W=W.reshape(batch + (nc, nc)),
                       mask=mask.reshape(batch + (nc,)), modified=modified)


@dataclass(frozen=True)
class _Inputs:
    """What VA-RAIM reads from the records: arrays broadcast to the batch ``bt = (B..., T)``."""

    t: NDArray  # (T,)
    pr: NDArray  # (bt, S)
    vis: NDArray  # (bt, S) bool
    sat_ecef: NDArray  # (bt, S, 3)
    sigma: NDArray  # (bt, S)
    q: NDArray  # (bt, 4) attitude reference
    uv: NDArray  # (bt, L, 2)
    det: NDArray  # (bt, L) bool
    sig: NDArray  # (bt, L)
    p_enu: NDArray  # (L, 3) surveyed landmarks in the world frame
    K: NDArray  # (3, 3)
    lever_ant: NDArray  # (3,) body
    lever_cam: NDArray  # (3,) body
    n_gps_rows: int  # compacted GPS row width over the whole batch
    frame: LocalFrame

    def trials(self, sl: slice) -> _Inputs:
        """The same inputs for trials ``sl`` of the first batch axis (views)."""
        per = {k: getattr(self, k)[sl] for k in ("pr", "vis", "sat_ecef", "sigma", "q", "uv", "det", "sig")}
        return dataclasses.replace(self, **per)


def _read_inputs(gnss: GnssEpochs, vision: VisionEpochs, frame: LocalFrame) -> _Inputs:
    pr = np.asarray(gnss.pseudorange, float)
    bt = pr.shape[:-1]  # (B..., T)
    T = bt[-1]
    t = np.asarray(gnss.t, float)
    uv = np.asarray(vision.pixel_uv, float)
    if uv.shape[:-2] != bt:
        raise ValueError(f"vision.pixel_uv: expected batch/epoch shape {bt} (from gnss.pseudorange), "
                         f"got {uv.shape[:-2]}")
    if len(vision.t) != T or not np.allclose(np.asarray(vision.t, float), t):
        raise ValueError("vision.t: expected the same epochs as gnss.t (resample one of them first)")
    p_enu = frame.ecef_to_enu(one_landmark_survey(vision, "va_raim"))  # (L, 3)
    L = p_enu.shape[0]
    vis = np.broadcast_to(np.asarray(gnss.visible, bool), pr.shape)
    return _Inputs(
        t=t, pr=pr, vis=vis, sat_ecef=np.broadcast_to(np.asarray(gnss.sat_pos_ecef, float), pr.shape + (3,)),
        sigma=np.broadcast_to(np.asarray(gnss.sigma, float), pr.shape),
        q=np.broadcast_to(np.asarray(vision.q_body_to_enu_ref, float), bt + (4,)), uv=uv,
        det=np.broadcast_to(np.asarray(vision.detected, bool), bt + (L,)),
        sig=np.broadcast_to(np.asarray(vision.sigma_px, float), bt + (L,)), p_enu=p_enu,
        K=np.asarray(vision.K, float), lever_ant=np.asarray(gnss.antenna.lever_arm_body, float),
        lever_cam=np.asarray(vision.camera.lever_arm_body, float),
        n_gps_rows=max(int(vis.sum(-1).max(initial=0)), 1), frame=frame)


def va_raim(gnss: GnssEpochs, vision: VisionEpochs, frame: LocalFrame,
            settings: VaRaimSettings | None = None, name: str = "va_raim",
            threads: int | None = None, share: Callable[..., Any] = compute) -> MonitorOutput:
    """The vision-aided RAIM monitor for every epoch (and trial) of a run.

    Parameters
    ----------
    gnss : GnssEpochs, pseudoranges (B..., T, S).
    vision : VisionEpochs, pixel_uv (B..., T, L, 2), detected / sigma_px (B..., T, L),
        q_body_to_enu_ref (B..., T, 4), surveyed landmark_pos_ecef (L, 3), K, camera mount.
    frame : the world frame; the state is [E, N, U, clock] of the reference point in it.
    settings : :class:`VaRaimSettings`.
    threads : run chunks of trials on this many threads (None: one per available core;
        1: in the calling thread). Every epoch is computed on its own, so the result is
        bit-identical whatever the number of threads or chunks.

    Returns
    -------
    MonitorOutput (reasons: :data:`testbed.integrity.lsq.REASONS`) with diagnostics:
    ``gps`` (the GPS-only RAIM MonitorOutput), ``vision_m`` (B..., T, L) raw vision ranges,
    ``vision_Sigma_V`` (B..., T, L, L), ``vision_reason`` (B..., T) with texts
    ``vision_reasons``, ``vision_iterations``, ``vision_residual_stat``, ``vision_gate_stat``
    (branch flags), ``z_hat`` / ``Sigma_hat`` / ``beta`` / ``calibrated`` / ``cal_idx``
    (calibration), ``vision_rows_used`` (B..., T) bool, ``modified`` (B..., T) bool,
    ``n_gps``, ``n_vision_rows``, ``hslope``/``vslope`` (B..., T, N) over the stacked rows
    (GPS rows compacted first, then the vision block), ``hpl_seed``/``vpl_seed``/
    ``hpl_pbias``/``vpl_pbias``, ``lam_det``, ``cond``, ``converged``.
    """
    st = settings or VaRaimSettings()
    inp = _read_inputs(gnss, vision, frame)
    # step 1 reads the GNSS record only: the cells of a camera sweep that share it share step 1; step 2 reads
    # both records and step 1: the cells that differ only after it (variant, calibration) share it (``share``:
    # what the caller shares, keyed on the records' identity and on everything else each step reads)
    gps_key = ("va_raim_gps", id(gnss), st.integrity.model_dump_json(), np.asarray(frame.origin_ecef, float).tobytes(),
               np.asarray(frame.R, float).tobytes())
    vision_key = gps_key + ("va_raim_vision", id(vision), st.vision.model_dump_json(), st.prior_speed_m_s,
                            st.prior_floor_m)
    return map_trial_chunks(lambda sl: _va_raim_chunk(inp.trials(sl), st, name, (gps_key + (sl.start, sl.stop), gnss),
                                                      (vision_key + (sl.start, sl.stop), (gnss, vision)), share),
                            inp.pr.shape[:-1], threads)


def _gps_step(inp: _Inputs, ist: IntegritySettings) -> tuple[GpsFix, MonitorOutput]:
    """Step 1: the GPS RAIM monitor itself on the chunk's pseudoranges."""
    fix_g = gps_fix(inp.pr, inp.vis, inp.sat_ecef, inp.sigma, None, None, inp.frame, ist, inp.n_gps_rows)
    return fix_g, gps_output(fix_g, inp.t, inp.pr.shape[-1], ist, "gps_raim")


def _va_raim_chunk(inp: _Inputs, st: VaRaimSettings, name: str, shared_gps: tuple, shared_vision: tuple,
                   share: Callable[..., Any]) -> MonitorOutput:
    """:func:`va_raim` on one chunk of trials."""
    ist = st.integrity
    pr, t, p_enu, uv = inp.pr, inp.t, inp.p_enu, inp.uv
    bt = pr.shape[:-1]  # (B..., T)
    T = bt[-1]

    # --- lever arms through the attitude reference (local ENU at the aircraft ≈ world ENU:
    # the frames differ by ~0.16 mrad per km from the origin, < 5 mm on a 5 m lever arm at 6 km)
    R = q_to_R(inp.q)
    off_ant = R @ inp.lever_ant
    off_cam = R @ inp.lever_cam

    # --- 1. GPS-only RAIM: the GPS RAIM monitor itself (at the antenna, as a receiver solves),
    # then moved to the reference point through the lever arm (the pseudoranges see x + R·l_ant
    # only, so this is the fix a solve for the reference point reaches, to rounding)
    key, guard = shared_gps
    fix_g, gps = share(key, lambda: _gps_step(inp, ist), guard=guard)
    idx, mg, zg, wg, anchor_g, fit_g = fix_g.idx, fix_g.mask, fix_g.z, fix_g.w, fix_g.anchor, fix_g.fit
    x_g = fix_g.x - np.concatenate([off_ant, np.zeros(bt + (1,))], axis=-1)
    has_fix = np.isfinite(x_g).all(-1)
    x_g0 = np.where(has_fix[..., None], x_g, 0.0)
    P_g = np.where(has_fix[..., None, None], fit_g.J[..., :3, :3], np.nan)

    # --- 2. the vision ranges, solved from the prior of this epoch's fix (else the last one carried forward)
    def vision_step() -> tuple[NDArray, VisionRanges]:
        last, m_pred, Sigma_pred = _vision_prior(x_g, P_g, has_fix & np.isfinite(P_g).all((-1, -2)), t, p_enu,
                                                 off_cam, st)
        return last, vision_pseudoranges(uv, inp.det, inp.K, inp.sig, p_enu, m_pred, Sigma_pred, st.vision)

    last, vr = share(shared_vision[0], vision_step, guard=shared_vision[1])
    li = np.maximum(last, 0)
    # the paper's Gaussian vision model holds only while σ_V/m is small (linear_range_limit;
    # docs/design/integrity.md §9, eq. 9.5)
    rel_sigma, linear = _linear_enough(vr, linear_range_limit(ist.p_fa, st.linearity_inflation))
    vision_ok = linear if st.variant == "gated" else vr.ok

    # --- 3. calibration
    lvl = service_level(st.calibration_level)
    with np.errstate(invalid="ignore"):
        cand = ((gps.reason == 0) & (gps.hpl <= lvl.hal) & (gps.vpl <= lvl.val) & ~gps.alert & vision_ok)
    cal_idx = calibration_epochs(cand, landmark_set_key(vr.used, vr.ok))
    if st.calibration == "none":
        cal_idx = np.full(bt, -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cr: CalibratedRanges = calibrate(vr, cal_idx, x_g0[..., :3], np.where(np.isfinite(P_g), P_g, 0.0),
                                         off_cam, p_enu, st.landmark_survey_sigma_m)
    # At its own calibration epoch ẑ_V(0) = r(x̃(0)) exactly: the vision rows are a function of
    # that epoch's GPS rows (no new information, and correlated with them), so they are not used.
    at_cal = cr.calibrated & (cr.cal_idx == np.arange(T))
    use_cal = cr.calibrated & ~at_cal & vision_ok
    use_raw = vision_ok & ~use_cal & ((st.uncalibrated == "inflate") | (st.calibration == "none"))
    z_v = np.where(use_cal[..., None], cr.z_hat, vr.m)
    S_v = np.where(use_cal[..., None, None], cr.Sigma_hat, cr.Sigma_uncal)
    use_v = use_cal | use_raw
    rows = _vision_rows(vr, z_v, S_v, use_v, st.modified_equation)
    use_v = use_v & rows.mask.any(-1)

    # --- 4. integrated iterated WLS
    x0 = _take_t(x_g0, li)
    gps_rows = (anchor_g, off_ant, zg, wg, mg)
    vision_rows = (p_enu, off_cam, rows.Tm, rows.z, rows.W, rows.mask)
    ft, pls, reason, ok, x, conv = _integrated_fix(use_v, fix_g, x_g, x0, gps_rows, vision_rows, ist)
    extra = {
        "gps": gps_exclusion(fix_g, gps, None, ist) if ist.fde else gps,
        "vision_m": vr.m, "vision_Sigma_V": vr.Sigma_V, "vision_reason": vr.reason,
        "vision_n_v": vr.n_v, "vision_iterations": vr.iterations,
        "vision_residual_stat": vr.residual_stat, "vision_gate_stat": vr.gate_stat, "vision_m_pred": vr.m_pred,
        "z_hat": cr.z_hat, "Sigma_hat": cr.Sigma_hat, "beta": cr.beta, "calibrated": cr.calibrated,
        "at_calibration_epoch": at_cal, "cal_t": np.where(cr.cal_idx >= 0, t[np.maximum(cr.cal_idx, 0)], np.nan),
        "vision_rows_used": use_v, "vision_rel_sigma": rel_sigma, "vision_linear": linear,
        "modified": rows.modified, "n_gps": mg.sum(-1),
        "n_vision_rows": rows.mask.sum(-1), "converged": conv, "gps_P": P_g,
    }
    out = _monitor_output(name, t, x, ft, pls, reason, ok, ist, extra, (idx, mg, pr.shape[-1]))
    if not ist.fde:
        return out
    return _exclusion(out, gps_rows, vision_rows, idx, np.where(ok[..., None], x, x0), ist)


#: What an unused row holds in the fit's per-row fields on a solvable epoch (``kernels.wls_one``;
#: every row is NaN on an unsolvable one)
_UNUSED_ROW = {"A": 0.0, "residual": 0.0, "ws_diag": np.nan, "hslope": np.nan, "vslope": np.nan}


def _flat_epochs(a: NDArray, nb: int) -> NDArray:
    """``a`` (B..., T, ...) as (B·T, ...), a view (it raises rather than copy)."""
    v = a.view()
    v.shape = (-1,) + a.shape[nb:]
    return v


def _put_gps_fit(ft: lsq.WlsFit, gps: lsq.WlsFit, epochs: NDArray, nb: int) -> None:
    """Write step 1's fit into ``ft`` at the flat ``epochs``, in place: its rows, then the vision
    block's rows unused."""
    ng = gps.residual.shape[-1]
    solvable = lsq.solvable(flat_take(gps.reason, nb, epochs))  # at those epochs only
    for f in dataclasses.fields(ft):
        if f.name == "mask":  # the stacked mask, given: step 1's rows and no vision row there
            continue
        dst, src = _flat_epochs(getattr(ft, f.name), nb), flat_take(getattr(gps, f.name), nb, epochs)
        if f.name not in _UNUSED_ROW:
            dst[epochs] = src
            continue
        fill = np.where(solvable, _UNUSED_ROW[f.name], np.nan)
        dst[epochs, ..., :ng] = src
        dst[epochs, ..., ng:] = fill.reshape(fill.shape + (1,) * (src.ndim - 1))


def _integrated_fix(need: NDArray, fix_g: GpsFix, x_g: NDArray, x0: NDArray, gps_rows: tuple,
                    vision_rows: tuple, ist: IntegritySettings):
    """Step 4, the integrated solve and its fit, on the epochs with a vision row (``need``).

    Elsewhere the rows are step 1's, and so are the solve and its fit: GPS RAIM's fix moved to
    the reference point (``x_g``) and its fit, the vision block's rows unused. (The integrated
    solve of those rows, started at that fix, stops within its tolerance of it: the same answer
    to 1e-6 m and 1e-6 relative, tested; the gated default leaves whole cells of a camera sweep
    without a vision row.) An epoch's path depends on its own rows only, so chunks and workers
    give the same numbers bit for bit.

    Returns :func:`solution_verdict`'s (fit, PLs, reason, ok, x) and the converged flags.
    """
    where = None if need.all() else need
    zg, wg, mg = gps_rows[2:]
    zv, Wv, mv = vision_rows[3:]
    x, conv, _, h, G = lsq.gauss_newton_ranges(x0, ist.max_iter, ist.tol_m, gps_rows, vision_rows, where=where)
    ft = lsq.wls_fit(h, G, np.concatenate([zg, zv], -1), wg, Wv, np.concatenate([mg, mv], -1), ist.max_cond,
                     where=where)
    if where is not None:
        nb = need.ndim
        rest = np.flatnonzero(~need)
        _put_gps_fit(ft, fix_g.fit, rest, nb)
        _flat_epochs(x, nb)[rest] = flat_take(x_g, nb, rest)
        _flat_epochs(conv, nb)[rest] = flat_take(fix_g.converged, nb, rest)
    return solution_verdict(ft, x, conv, ist) + (conv,)


def _exclusion(out: MonitorOutput, gps_rows: tuple, vision_rows: tuple, idx: NDArray, x_start: NDArray,
               ist: IntegritySettings) -> MonitorOutput:
    """VA-RAIM after FDE (:func:`testbed.integrity.fde.exclude`).

    Units: each satellite's row, and the vision block as one unit, index S + L (its rows are
    correlated and one detection fault enters several of them; excluding it leaves GPS RAIM's
    rows).
    """
    mg, mv = gps_rows[-1], vision_rows[-1]
    Ng, Nv = mg.shape[-1], mv.shape[-1]
    nb = mg.ndim - 1
    S, L = out.diagnostics.hslope.shape[-1] - Nv, vision_rows[0].shape[0]
    label = np.concatenate([np.where(mg, idx, -1), np.where(mv.any(-1), S + L, -1)[..., None]], -1)
    unit_rows = np.zeros((Ng + 1, Ng + Nv), bool)
    unit_rows[np.arange(Ng), np.arange(Ng)] = True
    unit_rows[Ng, Ng:] = True
    x_start = np.where(np.isfinite(x_start), x_start, 0.0)

    def solve_without(sel: NDArray, keep: NDArray) -> Verdict:
        take = lambda a: flat_take(np.broadcast_to(a, mg.shape[:-1] + np.shape(a)[nb:]), nb, sel)  # noqa: E731
        anchor, off_a, zg, wg, m = (take(a) for a in gps_rows)
        m = m & keep[:, :Ng]
        p_enu = vision_rows[0]
        off_c, Tm, zv, Wv, mvs = (take(a) for a in vision_rows[1:])
        mvs = mvs & keep[:, Ng:]
        x_it, conv, _, h, G = lsq.gauss_newton_ranges(take(x_start), ist.max_iter, ist.tol_m,
                                                      (anchor, off_a, zg, wg, m), (p_enu, off_c, Tm, zv, Wv, mvs))
        ft, pls, _, ok, x = fix_at_solution(h, G, np.concatenate([zg, zv], -1), (wg, Wv),
                                            np.concatenate([m, mvs], -1), x_it, conv, ist)
        return snapshot_verdict(ft, pls, ok, x, ist)

    return exclude(out, unit_rows, label, solve_without, ist)


@dataclass(frozen=True)
class VaRaimState:
    """What VA-RAIM needs of the past: the observations at the epochs later epochs depend on.

    Those are the calibration epoch of each landmark set in use (the calibration is
    re-derived from them) and the last epoch with a GPS fix (the prior of the vision
    solve), for every trial: at most a few epochs, however long the flight.
    context : Observations at those epochs (None before the first epoch).
    """

    context: Observations | None = None


@dataclass(frozen=True)
class VaRaimMonitor(MonitorDefaults):
    """VA-RAIM as a loop monitor (the VA-RAIM paper): state = :class:`VaRaimState`."""

    name: str
    context: MonitorContext
    settings: VaRaimSettings
    inputs: ClassVar[frozenset[str]] = frozenset({"gnss", "vision"})
    reference: ClassVar[str] = REFERENCE_POINT
    compiles_kernels: ClassVar[bool] = True
    provides_others: ClassVar[bool] = True  # GPS RAIM: its step 1

    def prepare(self) -> None:
        """Compile the kernels (numba caches them beside the package) before the first epoch."""
        from testbed.integrity.kernels import compile_all

        compile_all()

    def initial_state(self) -> VaRaimState:
        return VaRaimState()

    def step(self, obs: Observations, state: VaRaimState) -> tuple[MonitorOutput, VaRaimState]:
        obs = gps_satellites(obs)  # VA-RAIM stays GPS-only (docs/design/gnss.md §5)
        ctx = state.context
        full_obs = obs if ctx is None else Observations(concat_epochs([ctx.gnss, obs.gnss]),
                                                         concat_epochs([ctx.vision, obs.vision]))
        n_ctx = 0 if ctx is None else len(ctx.t)
        full = va_raim(full_obs.gnss, full_obs.vision, self.context.frame, self.settings, name=self.name,
                       threads=self.context.threads, share=self.context.share)
        keep = _context_epochs(full)
        new_ctx = Observations(take_epochs(full_obs.gnss, keep), take_epochs(full_obs.vision, keep))
        # (the first step's output as it is: its step-1 arrays stay the shared ones, and so do the tables)
        return (take_epochs(full, slice(n_ctx, None)) if n_ctx else full), VaRaimState(new_ctx)

    def provides(self, other, out: MonitorOutput) -> MonitorOutput | None:
        """GPS RAIM's output: step 1 is that monitor (same rows, weights, settings and solve)."""
        if isinstance(other, GpsRaimMonitor) and other.context.integrity == self.settings.integrity:
            return dataclasses.replace(out.diagnostics.gps, name=other.name)
        return None


def _context_epochs(out: MonitorOutput) -> NDArray:
    """Epoch indices of ``out`` that later epochs depend on, over all trials (sorted)."""
    d: VaRaimDiagnostics = out.diagnostics
    t = np.asarray(out.t)
    cal = np.isin(t, np.asarray(d.cal_t)[np.isfinite(d.cal_t)])
    fix = np.isfinite(d.gps.pos_enu).all(-1)  # (B..., T)
    last = np.zeros(t.shape, bool)
    has = fix.any(-1)
    last_idx = t.size - 1 - np.argmax(fix[..., ::-1], axis=-1)
    last[np.unique(last_idx[has])] = True
    return np.flatnonzero(cal | last)


def build_monitor(context: MonitorContext, options: VaRaimOptions) -> VaRaimMonitor:
    """VA-RAIM from the approach's ``[monitor.va_raim]`` table (the shared ``[integrity]`` added)."""
    settings = VaRaimSettings.model_validate({**dict(options), "integrity": context.integrity})
    return VaRaimMonitor("va_raim", context, settings)


def cost(options: VaRaimOptions) -> MonitorCost:
    """Per trial-epoch, measured alone on va-raim-2015 (24 satellites, 3 landmarks), the draws subtracted; its
    first step is GPS RAIM, so GPS RAIM beside it costs no time."""
    return MonitorCost((2800.0, 0.0, 0.0), (24e-6, 0.0, 3e-6), provides=("gps_raim",))
