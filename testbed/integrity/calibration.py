"""GPS-based calibration of vision pseudoranges (the VA-RAIM paper, eq. 12-18; docs/design/integrity.md §8).

At a calibration epoch k = 0 (GPS-only RAIM available, its PLs within the alert
limits, no alert, vision ranges available) the GPS fix ``x̃(0)`` with
covariance ``Δ_G(0)`` and the vision quantities ``z_V(0), A(0), B(0), Σ_c(0)``
are stored. For a later epoch k with the *same landmark set*::

    β(0) = z_V(0) − r(x̃(0))                      (r: ranges from the camera at x̃(0))
    β(k) = M A(0) β(0),      M = A⁺(k) B(k) B(0)⁻¹
    ẑ_V(k) = z_V(k) − β(k)

The landmark-survey error δd² cancels (to first order), leaving the errors of
the current detections, of the calibration-epoch detections and of the GPS fix::

    ẑ_V(k) − r(x(k)) = A⁺(k) δc(k) − M P₀ δc(0) + M A(0) H_V(0) (x̃(0) − x(0))
                       + (A⁺(k) B(k) − M P₀ B(0)) δd²,       P₀ = A(0) A⁺(0)

    Σ̂_V(k) = Σ_V(k) + M P₀ Σ_c(0) P₀ᵀ Mᵀ + M A(0) H_V(0) Δ_G(0) H_V(0)ᵀ A(0)ᵀ Mᵀ
             + L_d Σ_d L_dᵀ,   L_d = A⁺(k) B(k) − M P₀ B(0).

For N_V = 3 (the paper's case) A(0) is square, ``P₀ = I``, ``L_d = 0`` and this
is exactly the paper's Σ̂_V (eq. 17). For N_V > 3 the paper's cancellation is
incomplete — ``A(0)A⁺(0)`` is a projector, not the identity, so ``δc(0)`` enters
through ``P₀`` and a residual survey term ``L_d δd²`` remains; both are carried
here (a deliberate extension: the paper only derives N_V = 3). ``Δ_G`` is the
position block of the GPS ``J`` (``H_V`` has no clock column).

Calibration is a sequential choice in time, implemented without an epoch
loop: for each distinct landmark set (a handful per flight) the first valid
epoch per trial is an ``argmax`` over the epoch axis. An epoch uses the
calibration made at the first valid epoch *with the same landmark set* at or
before it; a new set is recalibrated as soon as GPS allows, and returning to
an earlier set reuses its calibration (the survey bias is time-invariant).
Epochs with no calibration yet are "uncalibrated": the monitor excludes them
or inflates their covariance by the survey term ``A⁺ B Σ_d B A⁺ᵀ``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.integrity import kernels
from testbed.integrity.vision_ranges import (
    VisionRanges,
    survey_covariance,
)


def landmark_set_key(used: NDArray, ok: NDArray) -> NDArray:
    """Integer code (..., T) of the landmark set used at each epoch; -1 where vision is unavailable.

    used : (..., T, L) bool (L ≤ 62).  ok : (..., T) bool.
    """
    L = used.shape[-1]
    if L > 62:
        raise ValueError(f"landmark slots: expected at most 62 for the set code, got {L}")
    key = np.sum(used.astype(np.int64) << np.arange(L, dtype=np.int64), axis=-1)
    return np.where(ok, key, -1)


def calibration_epochs(candidate: ArrayLike, set_key: ArrayLike) -> NDArray:
    """Index of the calibration epoch used at each epoch, or -1 (uncalibrated).

    Parameters
    ----------
    candidate : (..., T) bool, epochs where a calibration may be made.
    set_key : (..., T) int, landmark set code (-1: no vision).

    Returns
    -------
    cal_idx : (..., T) int, for epoch k the first epoch k0 ≤ k with
        ``candidate[k0]`` and ``set_key[k0] == set_key[k]``; -1 if none.

    Vectorised over trials and epochs: one ``argmax`` per distinct landmark set.
    """
    cand = np.asarray(candidate, bool)
    key = np.asarray(set_key)
    if cand.shape != key.shape:
        raise ValueError(f"candidate and set_key: expected equal shapes, got {cand.shape} and {key.shape}")
    T = key.shape[-1]
    t = np.arange(T)
    out = np.full(key.shape, -1, np.int64)
    for kappa in np.unique(key[(key >= 0) & cand]):
        valid = cand & (key == kappa)
        has = valid.any(-1)
        first = np.argmax(valid, axis=-1)  # first True (0 where none: masked by `has`)
        use = (key == kappa) & has[..., None] & (t >= first[..., None])
        out = np.where(use, first[..., None], out)
    return out


@dataclass(frozen=True)
class CalibratedRanges:
    """Calibrated vision ranges for a batch (shape ``(..., T)``).

    z_hat : (..., T, L) m, ẑ_V (NaN where not calibrated or unavailable).
    Sigma_hat : (..., T, L, L) m², Σ̂_V (zero on unused slots; NaN where not calibrated).
    beta : (..., T, L) m, the carried bias β(k).  beta0 : (..., T, L) m, β(0) of the calibration used.
    calibrated : (..., T) bool.  cal_idx : (..., T) int, calibration epoch (-1 none).
    Sigma_uncal : (..., T, L, L) m², Σ_V plus the survey term (for 'inflate').
    """

    z_hat: NDArray
    Sigma_hat: NDArray
    beta: NDArray
    beta0: NDArray
    calibrated: NDArray
    cal_idx: NDArray
    Sigma_uncal: NDArray


def calibrate(vr: VisionRanges, cal_idx: ArrayLike, x_gps_enu: ArrayLike, P_gps: ArrayLike,
              cam_offset_enu: ArrayLike, landmark_enu: ArrayLike, survey_sigma_m: float) -> CalibratedRanges:
    """Apply the GPS calibration (the VA-RAIM paper, eq. 16-17, generalised to N_V ≥ 3;
    docs/design/integrity.md §8).

    Parameters
    ----------
    vr : :class:`VisionRanges` for every epoch (batch shape (..., T)).
    cal_idx : (..., T) int from :func:`calibration_epochs` (-1: uncalibrated).
    x_gps_enu : (..., T, 3) m, GPS-only position fix of the reference point (read at the
        calibration epochs only).
    P_gps : (..., T, 3, 3) m², its covariance (position block of J_G).
    cam_offset_enu : (..., T, 3) m, camera position minus reference point (lever arm
        rotated by the attitude *reference*).
    landmark_enu : (L, 3) m, surveyed landmark positions in the world frame.
    survey_sigma_m : landmark survey 1-sigma per axis σ_g (m), for the residual
        survey term (N_V > 3) and the uncalibrated covariance.
    """
    idx = np.asarray(cal_idx)
    has = idx >= 0
    i0 = np.where(has, idx, 0)
    p = np.asarray(landmark_enu, float)
    L = p.shape[0]
    Sd = survey_covariance(p, survey_sigma_m)

    # per epoch k, with the quantities of its calibration epoch (compiled; the products are
    # written out in the kernel's docstring)
    bt = idx.shape
    T = bt[-1]
    Bt = int(np.prod(bt[:-1], dtype=np.int64))
    nc = vr.B.shape[-1]

    def flat(a: ArrayLike, tail: tuple, dt: type = float) -> NDArray:
        return kernels.kernel_input(a, bt + tail, (Bt, T) + tail, dt)

    beta, beta0 = np.empty((Bt, T, L)), np.empty((Bt, T, L))
    Sigma_hat, Sigma_uncal = np.empty((Bt, T, L, L)), np.empty((Bt, T, L, L))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        kernels.calibrate_tiles(flat(i0, (), np.int64), flat(vr.m, (L,)), flat(vr.A, (nc, L)), flat(vr.B, (nc,)),
                                flat(vr.A_pinv, (L, nc)), flat(vr.Sigma_c, (nc, nc)), flat(vr.Sigma_V, (L, L)),
                                flat(vr.used, (L,), bool), flat(x_gps_enu, (3,)), flat(P_gps, (3, 3)),
                                flat(cam_offset_enu, (3,)), kernels.kernel_input(p, p.shape),
                                kernels.kernel_input(Sd, Sd.shape),
                                beta, beta0, Sigma_hat, Sigma_uncal)
    beta, beta0 = beta.reshape(bt + (L,)), beta0.reshape(bt + (L,))
    Sigma_hat, Sigma_uncal = Sigma_hat.reshape(bt + (L, L)), Sigma_uncal.reshape(bt + (L, L))

    calibrated = has & vr.ok
    z_hat = np.where(calibrated[..., None] & vr.used, vr.m - beta, np.nan)
    Sigma_hat = np.where(calibrated[..., None, None], Sigma_hat, np.nan)
    return CalibratedRanges(z_hat=z_hat, Sigma_hat=Sigma_hat, beta=np.where(calibrated[..., None], beta, np.nan),
                            beta0=np.where(calibrated[..., None], beta0, np.nan), calibrated=calibrated,
                            cal_idx=np.where(calibrated, idx, -1), Sigma_uncal=Sigma_uncal)
