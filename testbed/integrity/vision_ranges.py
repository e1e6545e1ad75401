"""Vision pseudoranges from angles between lines of sight (the VA-RAIM paper, eq. 1-10).

Landmarks with surveyed positions ``p_i`` are detected in an image. The angle
between two lines of sight does not depend on the camera attitude, so the
ranges ``m_i`` from the camera to the landmarks follow from the cosine rule
(docs/design/integrity.md §7)::

    f_ij(m) = m_i² + m_j² − 2 m_i m_j c_ij − d_ij² = 0,   c_ij = b_i · b_j,

with ``b_i = normalise(K⁻¹ [u_i, v_i, 1])`` the 3D unit bearing of detection i
(the paper's eq. 4 uses 2D image-plane vectors; that is not the angle between
lines of sight — the 3D bearing is exact) and ``d_ij`` the surveyed distance.

Linearisation (the differential of f divided by 2 m_i m_j)::

    A δm = δc + B δd²,  A[ij, i] = 1/m_j − c_ij/m_i,  A[ij, j] = 1/m_i − c_ij/m_j,
                         B = diag(1 / (2 m_i m_j)).

Equivalently ``A = ∂c_model/∂m`` with ``c_model(m) = (m_i² + m_j² − d_ij²)/(2 m_i m_j)``,
the cosine the ranges imply; the Gauss–Newton solve minimises the weighted
cosine residual ``c − c_model(m)``.

Rank of Σ_c (a departure from the paper, which only treats N_V = 3): the
cosines are invariant to a common rotation of all bearings, so ``∂c/∂pixel``
has rank ``2 N_V − 3``. For N_V = 3 that equals N_C = 3 and Σ_c is regular;
for N_V ≥ 4 (N_C = N_V(N_V−1)/2 > 2 N_V − 3) Σ_c is *singular*. The weight is
therefore the rank-``(2 N_V − 3)`` pseudo-inverse ``W = Σ_c⁺`` (the smallest
``N_C − (2N_V − 3)`` eigenvalues, zero up to rounding, are dropped by count,
not by a tolerance), and ``A⁺ = (AᵀWA)⁻¹AᵀW``, which is ``A⁻¹`` when N_V = 3.
Then ``Σ_V = A⁺ Σ_c A⁺ᵀ = (AᵀWA)⁻¹``.

Shapes: ``(..., T)`` leading batch axes, L landmark slots (fixed per run),
N_C = L(L−1)/2 pair slots in ``numpy.triu_indices(L, 1)`` order. Missing
landmarks are masked; a bad epoch gets NaN ranges and a reason code, never an
exception.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from enum import IntEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import Field
from scipy.stats import chi2

from testbed.integrity import kernels
from testbed.schema import StrictModel


class VisionReason(IntEnum):
    """Why an epoch has no vision ranges (0 = ok)."""

    OK = 0
    TOO_FEW_LANDMARKS = 1  # fewer than 3 valid detections
    NAN_PIXELS = 2  # detections reported with non-finite pixels left fewer than 3
    DEGENERATE_GEOMETRY = 3  # collinear / coincident landmarks or a singular A
    NOT_CONVERGED = 4  # Gauss-Newton did not converge (or ranges went non-positive)
    RESIDUAL = 5  # converged but the cosine residual is not ~0 (wrong/absent solution)
    BRANCH_JUMP = 6  # solution far from the prior prediction relative to its covariance
    NO_PRIOR = 7  # no prior position to start from / to gate against


VISION_REASONS: tuple[str, ...] = (
    "ok",
    "fewer than 3 landmarks",
    "non-finite pixels (fewer than 3 valid landmarks)",
    "degenerate landmark geometry",
    "cosine-rule solve did not converge",
    "cosine-rule residual not ~0",
    "solution jumped away from the predicted branch",
    "no prior position",
)


class VisionRangeSettings(StrictModel):
    """Settings of the cosine-rule range solve and its branch protection."""

    max_iter: int = Field(25, ge=1, le=200, description="Gauss-Newton iterations at most")
    tol_m: float = Field(1e-4, gt=0.0, description="convergence: every range step below this (m)")
    residual_sigma_max: float = Field(
        1e-3, gt=0.0,
        description="N_V = 3: the solution is exact; the cosine residual must be below this "
                    "fraction of its 1-sigma (else RESIDUAL)")
    residual_p: float = Field(
        1e-9, gt=0.0, lt=1.0,
        description="N_V > 3: flag RESIDUAL when the weighted cosine residual exceeds the "
                    "chi-square(N_V - 3) quantile at 1 - residual_p")
    gate_p: float = Field(
        1e-7, gt=0.0, lt=1.0,
        description="branch gate: flag BRANCH_JUMP when (m - m_pred)'(Sigma_V + Sigma_pred)^-1"
                    "(m - m_pred) exceeds the chi-square(N_V) quantile at 1 - gate_p")
    min_baseline_m: float = Field(1.0, gt=0.0, description="landmarks closer than this are 'coincident'")
    collinear_ratio: float = Field(
        1e-3, gt=0.0, lt=1.0,
        description="landmark set is 'collinear' when its second principal spread is below "
                    "this fraction of the first")
    cond_max: float = Field(1e9, gt=1.0, description="A (column-scaled) condition number above this is degenerate")


# ----------------------------------------------------------------------------- geometry


def pair_indices(n_landmarks: int) -> tuple[NDArray, NDArray]:
    """Landmark indices ``(i, j)`` of the pair slots, each ``(N_C,)``, i < j (triu order)."""
    if n_landmarks < 2:
        raise ValueError(f"n_landmarks: expected >= 2, got {n_landmarks}")
    return np.triu_indices(n_landmarks, 1)


def survey_covariance(landmark_pos: ArrayLike, sigma_g: float) -> NDArray:
    """Full covariance (N_C, N_C) of the squared landmark distances, m⁴.

    ``δd²_ij = 2 (p_i − p_j)ᵀ(δp_i − δp_j)`` with ``δp ~ N(0, σ_g² I)`` per landmark;
    its diagonal is the paper's ``8 d_ij² σ_g²``; pairs sharing a landmark correlate.
    """
    p = np.asarray(landmark_pos, float)
    if p.ndim != 2 or p.shape[-1] != 3:
        raise ValueError(f"landmark_pos: expected shape (L, 3), got {p.shape}")
    I, J = pair_indices(len(p))
    nc = len(I)
    Jd = np.zeros((nc, len(p), 3))
    dp = 2.0 * (p[I] - p[J])
    Jd[np.arange(nc), I] = dp
    Jd[np.arange(nc), J] = -dp
    return sigma_g**2 * np.einsum("pla,qla->pq", Jd, Jd)


# ----------------------------------------------------------------------------- linear algebra


def _masked_pinv_weight(Sigma_c: NDArray, pair_mask: NDArray, n_v: NDArray) -> NDArray:
    """Rank-aware pseudo-inverse ``W = Σ_c⁺`` on the valid pairs, zero elsewhere.

    The rank of Σ_c is ``2 N_V − 3`` (rotation invariance of the cosines); the
    ``N_C,valid − (2 N_V − 3)`` smallest eigenvalues are structural zeros and are
    dropped by count. Masked pairs are padded with a large diagonal so they sort
    last and are dropped too.
    """
    nc = Sigma_c.shape[-1]
    pm = pair_mask.astype(float)
    diag = np.einsum("...ii->...i", Sigma_c)
    scale = np.sum(np.where(pair_mask, diag, 0.0), axis=-1) / np.maximum(pm.sum(-1), 1.0)
    scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
    S = Sigma_c / scale[..., None, None]
    S = np.where(pair_mask[..., :, None] & pair_mask[..., None, :], S, 0.0)
    S = S + np.einsum("...i,ij->...ij", np.where(pair_mask, 0.0, 1e12), np.eye(nc))
    S = np.where(np.isfinite(S), S, 0.0)
    lam, V = np.linalg.eigh(S)
    nvalid = pm.sum(-1).astype(int)
    rank = np.clip(2 * np.asarray(n_v) - 3, 0, None)
    k_null = np.clip(nvalid - rank, 0, None)
    idx = np.arange(nc)
    keep = (idx >= k_null[..., None]) & (idx < (k_null + rank)[..., None]) & (lam > 0)
    w = np.where(keep, 1.0 / np.where(keep, lam, 1.0), 0.0)
    W = np.einsum("...ik,...k,...jk->...ij", V, w, V) / scale[..., None, None]
    return W * (pm[..., :, None] * pm[..., None, :])


# ----------------------------------------------------------------------------- the solve


@dataclass(frozen=True)
class VisionRanges:
    """Output of :func:`vision_pseudoranges` (batch shape ``(...)``, usually (B..., T)).

    Attributes
    ----------
    m : (..., L) m, vision pseudoranges (NaN where unused or the epoch is unavailable).
    Sigma_V : (..., L, L) m², ``A⁺ Σ_c A⁺ᵀ`` (zero rows/cols for unused slots; NaN if unavailable).
    A : (..., N_C, L) 1/m.  B : (..., N_C) 1/m², diagonal of B.
    A_pinv : (..., L, N_C) m.  Sigma_c : (..., N_C, N_C).  W_c : (..., N_C, N_C) Σ_c⁺.
    c : (..., N_C) measured cosines.  d2 : (N_C,) m², surveyed squared distances.
    used : (..., L) bool, landmarks in the solve.  pair_mask : (..., N_C) bool.
    n_v : (...) int, landmarks used.  ok : (...) bool.  reason : (...) int8 :class:`VisionReason`.
    iterations : (...) int, Gauss-Newton steps taken.  residual_stat : (...) the N_V=3
    normalised max residual or the N_V>3 weighted residual.  gate_stat : (...) the
    branch-gate Mahalanobis distance (NaN if no prior covariance).  m_pred : (..., L).
    """

    m: NDArray
    Sigma_V: NDArray
    A: NDArray
    B: NDArray
    A_pinv: NDArray
    Sigma_c: NDArray
    W_c: NDArray
    c: NDArray
    d2: NDArray
    used: NDArray
    pair_mask: NDArray
    n_v: NDArray
    ok: NDArray
    reason: NDArray
    iterations: NDArray
    residual_stat: NDArray
    gate_stat: NDArray
    m_pred: NDArray


def _chi2_isf(p: float, dof: NDArray) -> NDArray:
    """chi2.isf(p, dof) for integer dof ≥ 1, from a cached table."""
    dof = np.asarray(dof)
    n = 64 if dof.size == 0 else max(64, 1 << int(dof.max()).bit_length())
    return _chi2_isf_table(float(p), n)[np.clip(dof, 1, n) - 1]


@lru_cache(maxsize=32)
def _chi2_isf_table(p: float, n: int) -> NDArray:
    return chi2.isf(p, np.arange(1, n + 1))


def _geometry_degenerate(p: NDArray, used: NDArray, s: VisionRangeSettings) -> NDArray:
    """(...) bool: the used landmark set is collinear or has coincident members."""
    I, J = pair_indices(p.shape[0])
    d = np.linalg.norm(p[I] - p[J], axis=-1)  # (N_C,)
    pm = used[..., I] & used[..., J]
    coincident = np.any(pm & (d < s.min_baseline_m), axis=-1)
    # Principal spreads of the used set: eigenvalues of its scatter matrix.
    w = used.astype(float)
    nw = np.maximum(w.sum(-1), 1.0)
    mu = np.einsum("...l,lk->...k", w, p) / nw[..., None]
    C = np.einsum("...l,lk,lj->...kj", w, p, p) / nw[..., None, None] - mu[..., :, None] * mu[..., None, :]
    ev = np.linalg.eigvalsh(C)  # ascending
    sv = np.sqrt(np.clip(ev, 0.0, None))
    collinear = sv[..., 1] < s.collinear_ratio * sv[..., 2]
    return coincident | collinear


def vision_pseudoranges(pixel_uv: ArrayLike, detected: ArrayLike, K: ArrayLike, sigma_px: ArrayLike,
                        landmark_pos: ArrayLike, m_pred: ArrayLike,
                        Sigma_pred: ArrayLike | None = None,
                        settings: VisionRangeSettings | None = None) -> VisionRanges:
    """Vision pseudoranges for every epoch of a batch by the cosine rule.

    Parameters
    ----------
    pixel_uv : (..., L, 2) px, detections (anything where not detected).
    detected : (..., L) bool.  A detected landmark with non-finite pixels is dropped.
    K : (3, 3) camera intrinsics.  sigma_px : (..., L) px, 1-sigma per detection.
    landmark_pos : (L, 3) m, *surveyed* landmark positions (any Cartesian frame).
    m_pred : (..., L) m, ranges predicted from a prior position (GPS solution or
        previous estimate — never truth); NaN where there is no prior.
    Sigma_pred : (..., L, L) m², covariance of ``m_pred`` for the branch gate;
        None disables the gate (``gate_stat`` NaN).
    settings : :class:`VisionRangeSettings`.

    Returns
    -------
    :class:`VisionRanges`.
    """
    s = settings or VisionRangeSettings()
    p = np.asarray(landmark_pos, float)
    uv = np.asarray(pixel_uv, float)
    det = np.asarray(detected, bool)
    L = p.shape[0] if p.ndim == 2 else -1
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"landmark_pos: expected shape (L, 3), got {p.shape}")
    if uv.shape[-2:] != (L, 2):
        raise ValueError(f"pixel_uv: expected shape (..., {L}, 2), got {uv.shape}")
    if det.shape != uv.shape[:-1]:
        raise ValueError(f"detected: expected shape {uv.shape[:-1]}, got {det.shape}")
    if L < 3:
        raise ValueError(f"landmark_pos: need at least 3 landmark slots, got {L}")
    batch = det.shape[:-1]
    sig = np.broadcast_to(np.asarray(sigma_px, float), batch + (L,))
    mp = np.broadcast_to(np.asarray(m_pred, float), batch + (L,))
    I, J = pair_indices(L)
    nc = len(I)
    d2 = np.sum((p[I] - p[J]) ** 2, axis=-1)

    finite_px = np.isfinite(uv).all(-1) & np.isfinite(sig) & (sig > 0)
    used = det & finite_px
    n_det = det.sum(-1)
    n_v = used.sum(-1)
    reason = np.zeros(batch, np.int8)
    few = n_v < 3
    reason[few & (n_det >= 3)] = VisionReason.NAN_PIXELS
    reason[few & (n_det < 3)] = VisionReason.TOO_FEW_LANDMARKS
    # the landmark positions are fixed: test each distinct landmark set once
    code = np.sum(used.astype(np.int64) << np.arange(L, dtype=np.int64), axis=-1)
    ucode, inv = np.unique(code, return_inverse=True)
    uused = ((ucode[:, None] >> np.arange(L)) & 1).astype(bool)
    degenerate = ~few & _geometry_degenerate(p, uused, s)[inv.reshape(code.shape)]
    reason[degenerate] = VisionReason.DEGENERATE_GEOMETRY
    no_prior = (reason == 0) & ~np.all(np.isfinite(mp) | ~used, axis=-1)
    reason[no_prior] = VisionReason.NO_PRIOR

    active = reason == 0
    pair_mask = used[..., I] & used[..., J] & active[..., None]
    colm = used & active[..., None]

    # cosines and Σ_c per epoch, compiled (the numpy functions above, fused; unused slots
    # see harmless pixels (0, 0) and contribute nothing)
    P = int(np.prod(batch, dtype=np.int64))

    def flat(a: NDArray, tail: tuple, dt: type = np.float64) -> NDArray:
        return kernels.kernel_input(a, batch + tail, (P,) + tail, dt)

    c, Sigma_c = np.empty((P, nc)), np.empty((P, nc, nc))
    kernels.cosines_and_covariance(flat(uv, (L, 2)), flat(colm, (L,), np.bool_), flat(sig, (L,)),
                                   kernels.kernel_input(np.linalg.inv(np.asarray(K, float)), (3, 3)), c, Sigma_c)
    c, Sigma_c = c.reshape(batch + (nc,)), Sigma_c.reshape(batch + (nc, nc))
    Sigma_c = np.where(pair_mask[..., :, None] & pair_mask[..., None, :], Sigma_c, 0.0)
    # N_V = 3: A is square, A⁺ = A⁻¹ whatever the (regular) weight, so the identity on the valid
    # pairs serves; the rank-aware pseudo-inverse (an eigen-decomposition) only where N_V > 3.
    W = np.einsum("...i,ij->...ij", pair_mask.astype(float), np.eye(nc))
    big = active & (n_v > 3)
    if big.any():
        W[big] = _masked_pinv_weight(Sigma_c[big], pair_mask[big], n_v[big])

    # --- Gauss-Newton on the weighted cosine residual, each epoch on its own (compiled; epochs side by side)
    m_f, it_f = np.empty((P, L)), np.empty(P, np.int64)
    conv_f, good_f = np.empty(P, bool), np.empty(P, bool)
    kernels.cosine_gauss_newton_tiles(flat(c, (nc,)), flat(W, (nc, nc)), kernels.kernel_input(d2, d2.shape),
                                flat(np.where(colm, mp, 1.0), (L,)), flat(colm, (L,), np.bool_),
                                flat(pair_mask, (nc,), np.bool_), s.max_iter, s.tol_m, m_f, it_f, conv_f, good_f)
    m = m_f.reshape(batch + (L,))
    iters = it_f.reshape(batch)
    converged = conv_f.reshape(batch) | ~active
    step_ok = good_f.reshape(batch) | ~active
    pos = np.all((m > 0) | ~colm, axis=-1)
    notconv = active & (~converged | ~step_ok | ~pos)
    reason[notconv] = VisionReason.NOT_CONVERGED
    active = reason == 0

    # --- at the solution, compiled per epoch: the linearisation with the measured cosines
    # (the paper's eq. 2), A⁺, Σ_V, the cosine residuals and the branch gate
    gate = Sigma_pred is not None
    Sp = np.broadcast_to(np.asarray(Sigma_pred, float), batch + (L, L)) if gate else np.zeros((0, L, L))
    A, Bd, Ap = np.empty((P, nc, L)), np.empty((P, nc)), np.empty((P, L, nc))
    Sigma_V, good, cond = np.empty((P, L, L)), np.empty(P, bool), np.empty(P)
    r_norm, r_w, gate_stat, gok = np.empty(P), np.empty(P), np.full(P, np.nan), np.zeros(P, bool)
    kernels.cosine_rule_products_tiles(flat(m, (L,)), flat(c, (nc,)), kernels.kernel_input(d2, d2.shape),
                                       flat(colm, (L,), np.bool_), flat(pair_mask, (nc,), np.bool_), flat(W, (nc, nc)),
                                       flat(Sigma_c, (nc, nc)), flat(mp, (L,)),
                                       flat(Sp, (L, L)) if gate else kernels.kernel_input(Sp, Sp.shape),
                                       A, Bd, Ap, good, cond, Sigma_V, r_norm, r_w, gate_stat, gok)
    A, Bd, Ap = A.reshape(batch + (nc, L)), Bd.reshape(batch + (nc,)), Ap.reshape(batch + (L, nc))
    Sigma_V, good, cond = Sigma_V.reshape(batch + (L, L)), good.reshape(batch), cond.reshape(batch)
    r_norm, r_w, gate_stat, gok = (a.reshape(batch) for a in (r_norm, r_w, gate_stat, gok))

    # Degenerate A (e.g. the danger cylinder): the condition of the column-scaled A (ranges
    # as units), Frobenius estimate ‖A diag(m)‖_F ‖diag(1/m) A⁺‖_F, an upper bound of the
    # 2-norm one, cheap from A⁺.
    bad_A = active & (~good | (cond > s.cond_max))
    reason[bad_A] = VisionReason.DEGENERATE_GEOMETRY
    active = reason == 0

    # --- residual check
    dof = np.maximum(n_v - 3, 1)
    res_bad3 = (n_v == 3) & (r_norm > s.residual_sigma_max)
    res_badn = (n_v > 3) & (r_w > _chi2_isf(s.residual_p, dof))
    residual_stat = np.where(n_v == 3, r_norm, r_w)
    reason[active & (res_bad3 | res_badn)] = VisionReason.RESIDUAL
    active = reason == 0

    # --- branch gate against the prediction
    if gate:
        gate_bad = active & (~gok | (gate_stat > _chi2_isf(s.gate_p, np.maximum(n_v, 1))))
        reason[gate_bad] = VisionReason.BRANCH_JUMP
    ok = reason == 0

    nanify = ~ok
    m_out = np.where(colm & ok[..., None], m, np.nan)
    Sigma_V = np.where(nanify[..., None, None], np.nan, Sigma_V)
    return VisionRanges(m=m_out, Sigma_V=Sigma_V, A=A, B=Bd, A_pinv=Ap, Sigma_c=Sigma_c, W_c=W, c=c,
                        d2=d2, used=used, pair_mask=used[..., I] & used[..., J], n_v=n_v, ok=ok,
                        reason=reason, iterations=iters, residual_stat=residual_stat,
                        gate_stat=gate_stat, m_pred=mp)
