"""Batched weighted least squares, detection test and slope-based protection levels.

The one numerical core every snapshot monitor (GPS-only RAIM, VA-RAIM, the
pixel-domain monitor) builds on. Notation follows docs/design/integrity.md §2-§4 and the
VA-RAIM paper's eq. 19-26:

* ``G`` ``(..., N, 4)`` linearised observation matrix, state ``x = [E, N, U, clock]``
  (clock in metres; a row without a clock term has a zero last column).
* ``W`` weights, either full ``(..., N, N)`` (correlated rows, W = Σ⁻¹) or
  diagonal given as a vector ``(..., N)`` (W = diag(1/σ²)).
* ``mask`` ``(..., N)`` bool, the rows used. Variable measurement counts are
  handled by zero weight on unused rows, never by ragged lists, so a batch of
  epochs is one stack of matrices.
* ``J = (GᵀWG)⁻¹``, ``A = J GᵀW``, ``S = I − G A``, ``SSE = rᵀ W r``.

One compiled pass per epoch (:func:`kernels.wls_epochs`, behind :func:`wls_fit` and
:func:`wls_geometry`) computes all of it, degenerate epochs included; it never forms
the N×N matrix ``S``: ``(WS)ᵢᵢ = Wᵢᵢ − (WG)ᵢ J (WG)ᵢᵀ`` needs only ``WG`` and ``J``.
The numpy/LAPACK formulas it replaces are the test oracle (``tests/wls_oracle.py``).

A bad batch element (fewer rows than unknowns, singular geometry, NaN in a used
row) never raises: it gets NaN outputs and a :class:`Reason` code, and the rest
of the batch is computed as usual.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from enum import IntEnum
from functools import lru_cache
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import optimize, stats

from testbed.integrity import kernels

N_STATES = 4  # E, N, U, clock


class Reason(IntEnum):
    """Why an epoch has no (full) integrity output. Index into :data:`REASONS`."""

    OK = 0
    NAN_INPUT = 1  # a row marked as used has NaN measurement, geometry or weight
    NO_POSITION = 2  # fewer used rows than unknowns: no solution at all
    NO_REDUNDANCY = 3  # solution exists but n - 4 < 1: no detection test, no PL
    SINGULAR = 4  # normal matrix singular / condition number too large
    NOT_CONVERGED = 5  # iterated WLS did not reach the tolerance
    UNDETECTABLE = 6  # a used row has (WS)_ii = 0: a fault on it is unobservable


#: Texts for :class:`Reason`, in code order (MonitorOutput.reasons).
REASONS: tuple[str, ...] = (
    "ok",
    "unavailable: NaN in a used measurement",
    "unavailable: fewer measurements than unknowns (no position)",
    "unavailable: fewer than 5 measurements (no redundancy)",
    "unavailable: singular geometry",
    "unavailable: least squares did not converge",
    "unavailable: a measurement with zero redundancy (fault undetectable)",
)

#: Default limit on the condition number of the Jacobi-scaled normal matrix.
MAX_COND = 1e10


# ---------------------------------------------------------------------------
# weights and masks
# ---------------------------------------------------------------------------


def _is_diag(W: NDArray, G: NDArray) -> bool:
    """True when W is given as a vector of diagonal weights ``(..., N)``.

    ``W.ndim == G.ndim − 1`` (or fewer dims, broadcast over the batch) means
    diagonal; ``W.ndim == G.ndim`` means full. To share one full W across a
    batch, broadcast it to ``G.shape[:-1] + (N,)`` first.
    """
    if W.ndim <= G.ndim - 1 and W.ndim >= 1 and W.shape[-1] == G.shape[-2]:
        return True
    if W.ndim == G.ndim and W.shape[-2:] == (G.shape[-2], G.shape[-2]):
        return False
    raise ValueError(
        f"W: expected (..., N) diagonal weights or (..., N, N) full weights with N = {G.shape[-2]} "
        f"(from G {G.shape}), got {W.shape}"
    )


def weights_from_sigma(sigma: ArrayLike) -> NDArray:
    """Diagonal weights ``1/σ²`` ``(..., N)`` from 1-sigma ``(..., N)`` (m or px)."""
    s = np.asarray(sigma, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return 1.0 / (s * s)


def apply_W(W: NDArray, X: NDArray, diag: bool) -> NDArray:
    """``W @ X`` for X ``(..., N, k)`` with W diagonal ``(..., N)`` or full ``(..., N, N)``."""
    if diag:
        return W[..., :, None] * X
    return W @ X


# ---------------------------------------------------------------------------
# the fit of an epoch: J, A, (WS)_ii, condition, residuals, SSE, slopes
# ---------------------------------------------------------------------------


class SolvedEpochs:
    """``dof`` and ``solvable`` of per-epoch results with ``n_used``, ``n_states`` and ``reason``."""

    n_used: NDArray
    n_states: NDArray
    reason: NDArray

    @property
    def dof(self) -> NDArray:
        """Degrees of freedom of the test, ``n_used − n_states`` (may be ≤ 0)."""
        return self.n_used - self.n_states

    @property
    def solvable(self) -> NDArray:
        """(...) bool: a position solution exists (reason OK or NO_REDUNDANCY)."""
        return solvable(self.reason)


def solvable(reason: NDArray) -> NDArray:
    """Whether reason codes leave a position solution (OK or NO_REDUNDANCY)."""
    return (reason == Reason.OK) | (reason == Reason.NO_REDUNDANCY)


@dataclass(frozen=True)
class WlsFit(SolvedEpochs):
    """The weighted LS of a batch of epochs at a linearisation point (:func:`wls_fit`).

    Batch shape ``(...)``, N rows, 4 states.

    mask : (..., N) rows used.  n_used, n_states : (...) rows used and states estimated
        (3 when no used row has a clock term: the clock is not estimated).
    J : (..., 4, 4) ``(GᵀWG)⁻¹``.  A : (..., 4, N) ``J GᵀW`` (zero columns on unused rows).
    ws_diag : (..., N) ``(WS)ᵢᵢ``, NaN on unused rows.
    cond : (...) 1-norm condition number of the Jacobi-scaled GᵀWG (inf: numerically singular).
    reason : (...) int8 :class:`Reason` (OK, NAN_INPUT, NO_POSITION, NO_REDUNDANCY, SINGULAR).
    residual : (..., N) ``z − h`` (0 on unused rows).  sse : (...) ``rᵀWr`` (the VA-RAIM paper's eq. 26).
    hslope, vslope : (..., N) slopes (docs/design/integrity.md §4, eq. 4.1-4.2), NaN on unused rows, inf where
        (WS)ᵢᵢ = 0 (a fault there is undetectable); hmax, vmax : (...) their maxima.
    J, A, residual, sse, slopes and ws_diag are NaN where the epoch has no solution.
    """

    mask: NDArray
    n_used: NDArray
    n_states: NDArray
    J: NDArray
    A: NDArray
    ws_diag: NDArray
    cond: NDArray
    reason: NDArray
    residual: NDArray
    sse: NDArray
    hslope: NDArray
    vslope: NDArray
    hmax: NDArray
    vmax: NDArray

    def protection_levels(self, p_fa: float, p_md: float, variant: PlVariant = "pbias") -> ProtectionLevels:
        """:func:`protection_levels` of this fit."""
        return protection_levels(self, p_fa, p_md, variant)


@dataclass(frozen=True)
class WlsGeometry(WlsFit):
    """A :class:`WlsFit` that also keeps its masked G (..., N, 4) and W, for the full matrices.

    ``W`` is in the form given: diagonal (..., N) when ``diag``, else (..., N, N).
    """

    G: NDArray
    W: NDArray
    diag: bool

    def ws_matrix(self) -> NDArray:
        """Full ``W S = W − W G A`` ``(..., N, N)`` (symmetric; for small problems and subspace slopes)."""
        W = self.W[..., :, None] * np.eye(self.W.shape[-1]) if self.diag else self.W
        return W - apply_W(self.W, self.G, self.diag) @ self.A

    def residual_projector(self) -> NDArray:
        """Full ``S = I − G A`` ``(..., N, N)`` (for tests and small problems)."""
        N = self.G.shape[-2]
        return np.eye(N) - self.G @ self.A


_FIT_FIELDS = ("J", "A", "ws_diag", "cond", "residual", "sse", "hslope", "vslope", "hmax", "vmax", "n_used",
               "n_states", "reason")


def wls_fit(h: ArrayLike, G: ArrayLike, z: ArrayLike, w_diag: ArrayLike, W_block: ArrayLike | None,
            mask: ArrayLike | None, max_cond: float = MAX_COND, where: ArrayLike | None = None) -> WlsFit:
    """The weighted LS of every epoch at predictions h (..., N) with partials G (..., N, 4).

    z : (..., N) measurements; mask : (..., N) rows used (None: all; unused rows may hold
    anything). Weights ``W = blockdiag(diag(w_diag), W_block)``: w_diag (..., n1) for the
    first, uncorrelated rows (e.g. pseudoranges), W_block (..., N − n1, N − n1) for the
    rest (e.g. a vision block), or None when ``n1 = N``. One compiled pass per epoch
    (:func:`kernels.wls_epochs`) decides every epoch it fits, degenerate ones included, on
    its own: a chunk of a batch gives the same numbers, bit for bit, as the whole.
    where : (...) bool, the epochs to fit (None: all); the others are not fitted: NaN, counts 0,
    reason NO_POSITION (their inputs are not read).
    """
    G = np.asarray(G, float)
    if G.ndim < 2 or G.shape[-1] != N_STATES:
        raise ValueError(f"G: expected (..., N, {N_STATES}) partials, got shape {G.shape}")
    N = G.shape[-2]
    wd = np.asarray(w_diag, float)
    n1 = wd.shape[-1] if wd.ndim else -1
    Wb = np.zeros((0, 0)) if W_block is None else np.asarray(W_block, float)
    if not (0 <= n1 <= N and Wb.ndim >= 2 and Wb.shape[-2:] == (N - n1, N - n1)):
        raise ValueError(f"weights: expected w_diag (..., n1) and W_block (..., N − n1, N − n1) with N = {N} "
                         f"(from G {G.shape}), got w_diag {wd.shape} and W_block {Wb.shape}")
    m = np.ones(G.shape[:-1], bool) if mask is None else np.asarray(mask, bool)
    h, z = np.asarray(h, float), np.asarray(z, float)
    batch = np.broadcast_shapes(G.shape[:-2], h.shape[:-1], z.shape[:-1], wd.shape[:-1], Wb.shape[:-2],
                                m.shape[:-1])
    P = int(np.prod(batch, dtype=np.int64))
    R = N - n1

    def flat(a: NDArray, tail: tuple, dt: type = np.float64) -> NDArray:
        return kernels.kernel_input(a, batch + tail, (P,) + tail, dt)

    out = {"J": (N_STATES, N_STATES), "A": (N_STATES, N), "ws_diag": (N,), "cond": (), "residual": (N,), "sse": (),
           "hslope": (N,), "vslope": (N,), "hmax": (), "vmax": (), "n_used": (), "n_states": (), "reason": ()}
    dtypes = {"n_used": np.int64, "n_states": np.int64, "reason": np.int8}
    out = {k: np.empty((P,) + tail, dtypes.get(k, np.float64)) for k, tail in out.items()}
    epochs, skipped = _listed_epochs(where, batch, P)
    for k, v in out.items():
        v[skipped] = Reason.NO_POSITION if k == "reason" else (0 if k in dtypes else np.nan)
    kernels.wls_epochs(flat(G, (N, N_STATES)), flat(h, (N,)), flat(z, (N,)), flat(wd, (n1,)), flat(Wb, (R, R)),
                       flat(m, (N,), np.bool_), float(max_cond), epochs, *(out[k] for k in _FIT_FIELDS))
    return WlsFit(mask=np.broadcast_to(m, batch + (N,)), **{k: v.reshape(batch + v.shape[1:]) for k, v in out.items()})


def _listed_epochs(where: ArrayLike | None, batch: tuple, P: int) -> tuple[NDArray, NDArray]:
    """The flat indices of the epochs ``where`` lists (all when None) and of the others."""
    if where is None:
        listed, others = np.arange(P, dtype=np.int64), np.zeros(0, np.int64)
    else:
        w = np.broadcast_to(np.asarray(where, bool), batch).reshape(-1)
        listed, others = np.flatnonzero(w), np.flatnonzero(~w)
    return kernels.kernel_input(listed, listed.shape, dtype=np.int64), others


def wls_fit_any(G: ArrayLike, W: ArrayLike, mask: ArrayLike | None = None, max_cond: float = MAX_COND,
                h: ArrayLike | None = None, z: ArrayLike | None = None) -> tuple[WlsFit, bool]:
    """:func:`wls_fit` with W diagonal (..., N) or full (..., N, N); also returns whether W is diagonal."""
    G = np.asarray(G, float)
    W = np.asarray(W, float)
    diag = _is_diag(W, G)
    zero = np.zeros(G.shape[-2])
    h = zero if h is None else h
    z = zero if z is None else z
    if diag:
        return wls_fit(h, G, z, W, None, mask, max_cond), True
    return wls_fit(h, G, z, W[..., 0, :0], W, mask, max_cond), False


def wls_geometry(G: ArrayLike, W: ArrayLike, mask: ArrayLike | None = None,
                 max_cond: float = MAX_COND, h: ArrayLike | None = None,
                 z: ArrayLike | None = None) -> WlsGeometry:
    """:func:`wls_fit` with W diagonal (..., N) or full (..., N, N), keeping masked G and W.

    Parameters
    ----------
    G : (..., N, 4) linearised observation matrix (rows ∂h/∂[E, N, U, clock]).
    W : (..., N) diagonal weights (1/m²) or (..., N, N) full weight matrix (Σ⁻¹).
    mask : (..., N) bool, rows to use (default all). Unused rows may hold NaN.
    max_cond : largest accepted condition number of the Jacobi-scaled GᵀWG.
    h, z : (..., N) predictions and measurements for the residuals and SSE (default 0).
    """
    G = np.asarray(G, float)
    W = np.asarray(W, float)
    ft, diag = wls_fit_any(G, W, mask, max_cond, h, z)
    m = ft.mask
    G0 = np.where(m[..., None] & np.isfinite(G), G, 0.0)
    if diag:
        W0 = np.where(m & np.isfinite(W), W, 0.0)
    else:
        mm = m[..., :, None] & m[..., None, :]
        W0 = np.where(mm & np.isfinite(W), W, 0.0)
    return WlsGeometry(**{f: getattr(ft, f) for f in ("mask",) + _FIT_FIELDS}, G=G0, W=W0, diag=diag)


# ---------------------------------------------------------------------------
# thresholds, λ_det, slopes, protection levels
# ---------------------------------------------------------------------------

DOF_TABLE_MAX = 128  # largest n − 4 the cached tables cover (more falls back to scipy)


@lru_cache(maxsize=64)
def _chi2_table(p_fa: float) -> NDArray:
    dof = np.arange(1, DOF_TABLE_MAX + 1)
    return np.concatenate([[np.nan], stats.chi2.isf(p_fa, dof)])


def _lambda_det_one(dof: int, p_fa: float, p_md: float) -> float:
    T2 = stats.chi2.isf(p_fa, dof)
    f = lambda lam: stats.ncx2.cdf(T2, dof, lam) - p_md  # noqa: E731 - decreasing in λ
    hi = 10.0
    while f(hi) > 0:
        hi *= 2.0
    return float(optimize.brentq(f, 1e-12, hi, xtol=1e-12, rtol=1e-12))


@lru_cache(maxsize=64)
def _lambda_table(p_fa: float, p_md: float) -> NDArray:
    return np.array([np.nan] + [_lambda_det_one(k, p_fa, p_md) for k in range(1, DOF_TABLE_MAX + 1)])


def _check_prob(p: float, name: str) -> float:
    p = float(p)
    if not 0.0 < p < 1.0:
        raise ValueError(f"{name}: expected a probability in (0, 1), got {p}")
    return p


def _lookup(table: NDArray, dof: ArrayLike, fallback: Callable[[int], float]) -> NDArray:
    dof = np.asarray(dof)
    idx = np.clip(dof, 0, DOF_TABLE_MAX).astype(int)
    out = table[idx]
    out = np.where(dof < 1, np.nan, out)
    big = np.unique(dof[dof > DOF_TABLE_MAX])
    for k in big:  # rare: only when more than 132 rows are stacked
        out = np.where(dof == k, fallback(int(k)), out)
    return out


def chi2_threshold(dof: ArrayLike, p_fa: float) -> NDArray:
    """Detection threshold ``T² = χ²⁻¹(1 − P_FA; dof)`` per epoch; NaN where dof < 1."""
    p_fa = _check_prob(p_fa, "p_fa")
    return _lookup(_chi2_table(p_fa), dof, lambda k: float(stats.chi2.isf(p_fa, k)))


def lambda_det(dof: ArrayLike, p_fa: float, p_md: float) -> NDArray:
    """Non-centrality ``λ_det`` with ``P(χ²_nc(dof, λ) < T²) = P_MD`` (cached per dof).

    NaN where dof < 1. Units: normalised (λ = bᵀWSb for a bias b).
    """
    p_fa = _check_prob(p_fa, "p_fa")
    p_md = _check_prob(p_md, "p_md")
    return _lookup(_lambda_table(p_fa, p_md), dof, lambda k: _lambda_det_one(k, p_fa, p_md))


@lru_cache(maxsize=64)
def k_md(p_md: float) -> float:
    """Two-sided missed-detection multiplier ``Φ⁻¹(1 − P_MD/2)`` (the VA-RAIM paper's eq. 22-23)."""
    return float(stats.norm.isf(_check_prob(p_md, "p_md") / 2))


def worst_direction_slopes(Ah: NDArray, Av: NDArray, Q: NDArray, rtol: float = 1e-9) -> tuple[NDArray, NDArray]:
    """``max_b ‖Ah b‖² / bᵀQb`` and ``max_b (Av b)² / bᵀQb`` for stacked c×c ``Q`` (one eigendecomposition).

    Ah : (..., 2, c), Av : (..., 1, c) the rows of A a fault b on c rows moves the position
    through; Q : (..., c, c) ⪰ 0 (possibly singular), the fault's WS block. With
    ``Q = V diag(q) Vᵀ`` the maxima are the largest eigenvalues of ``R V q⁻¹ Vᵀ Rᵀ``
    (2×2 for Ah: closed form; 1×1 for Av) over Q's range. A direction in Q's null space
    that moves the position gives ``inf`` (the fault moves it, not the test statistic);
    null directions that do not are ignored (padding columns). Returns two (...) arrays.
    """
    q, V = np.linalg.eigh(Q)
    qmax = np.maximum(q[..., -1:], 0.0)
    good = q > rtol * qmax
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(good, 1.0 / np.where(good, q, 1.0), 0.0)
    out = []
    for R in (Ah, Av):
        RV = R @ V  # (..., r, c)
        M = (RV * inv[..., None, :]) @ np.swapaxes(RV, -1, -2)  # (..., r, r)
        if M.shape[-1] == 1:
            mu = M[..., 0, 0]
        else:  # the larger eigenvalue of a symmetric 2×2
            a, b, d = M[..., 0, 0], M[..., 0, 1], M[..., 1, 1]
            mu = 0.5 * (a + d) + np.sqrt((0.5 * (a - d)) ** 2 + b * b)
        moved = (RV**2).sum(-2)  # (..., c) how far each eigen-direction moves the position
        scale = np.maximum(moved.sum(-1), np.finfo(float).tiny)
        leak = (~good & (moved > rtol * scale[..., None])).any(-1)
        out.append(np.where(leak, np.inf, np.maximum(mu, 0.0)))
    return out[0], out[1]


def subspace_slopes(geom: WlsGeometry, cols: ArrayLike, WS: NDArray | None = None) -> tuple[NDArray, NDArray]:
    """Worst-direction slopes for faults spanning several rows (patent H2/H3).

    For a fault b confined to the rows ``cols[m]`` the slope² is
    ``‖A_H b‖² / (bᵀ WS b)``; its maximum over the direction of b is a
    generalised eigenvalue problem of size ``len(cols[m])`` (exact, no sweep).
    ``Hslope`` uses A's rows E, N; ``Vslope`` the U row. One-row units reduce
    to :func:`slopes`.

    Parameters
    ----------
    geom : WlsGeometry.
    cols : (M, c) int row indices of each fault unit, padded with -1
        (e.g. a satellite ``[i, -1]``, a landmark's pixel pair ``[2l, 2l+1]``,
        a pair of landmarks ``[u1, v1, u2, v2]``).
    WS : (..., N, N) optional precomputed ``geom.ws_matrix()``.

    Returns
    -------
    hslope, vslope : (..., M); NaN where a unit has an unused row, inf where a
    fault direction is undetectable but moves the position.
    """
    cols = np.asarray(cols, int)
    if cols.ndim != 2:
        raise ValueError(f"cols: expected (M, c) row indices padded with -1, got shape {cols.shape}")
    WS = geom.ws_matrix() if WS is None else WS
    pad = cols < 0
    c0 = np.where(pad, 0, cols)
    A_sel = np.where(pad, 0.0, geom.A[..., :, c0])  # (..., 4, M, c)
    Q = WS[..., c0[:, :, None], c0[:, None, :]]  # (..., M, c, c)
    Q = np.where(pad[:, :, None] | pad[:, None, :], 0.0, Q)
    used = np.where(pad, True, geom.mask[..., c0]).all(-1)  # (..., M)
    ok = used & geom.solvable[..., None]
    Qs = np.where(ok[..., None, None], Q, np.eye(cols.shape[1]))
    A_m = np.moveaxis(np.where(ok[..., None, :, None], A_sel, 0.0), -3, -2)  # (..., 4, M, c) -> (..., M, 4, c)
    with np.errstate(invalid="ignore"):
        h2, v2 = worst_direction_slopes(A_m[..., :2, :], A_m[..., 2:3, :], Qs)
    return np.where(ok, np.sqrt(h2), np.nan), np.where(ok, np.sqrt(v2), np.nan)


PlVariant = Literal["seed", "pbias"]


@dataclass(frozen=True)
class ProtectionLevels:
    """Protection levels and the detection quantities behind them.

    hpl, vpl : (...) m (NaN where unavailable). T2 : (...) threshold on SSE.
    lam_det : (...) λ_det. hslope, vslope : (..., N). reason : (...) int8 codes.
    """

    hpl: NDArray
    vpl: NDArray
    T2: NDArray
    lam_det: NDArray
    hslope: NDArray
    vslope: NDArray
    reason: NDArray


def protection_levels(geom: WlsFit, p_fa: float, p_md: float,
                      variant: PlVariant = "pbias") -> ProtectionLevels:
    """HPL/VPL by the slope method (docs/design/integrity.md §4), two variants.

    * ``"seed"`` (the VA-RAIM paper, eq. 22-23): ``HPL = max Hslope·T + k_md·sqrt(J₁₁ + J₂₂)``,
      ``VPL = max Vslope·T + k_md·sqrt(J₃₃)``, T = sqrt(T²), k_md = Φ⁻¹(1 − P_MD/2).
    * ``"pbias"``: ``PL = max slope · sqrt(λ_det)``.

    Epochs with reason ≠ OK get NaN; an epoch whose worst slope is infinite
    gets reason UNDETECTABLE and NaN.
    """
    if variant not in ("seed", "pbias"):
        raise ValueError(f"variant: expected 'seed' or 'pbias', got {variant!r}")
    hs, vs, hmax, vmax, J, reason = geom.hslope, geom.vslope, geom.hmax, geom.vmax, geom.J, geom.reason
    T2 = chi2_threshold(geom.dof, p_fa)
    lam = lambda_det(geom.dof, p_fa, p_md)
    if variant == "seed":
        kmd = k_md(p_md)
        T = np.sqrt(T2)
        hpl = hmax * T + kmd * np.sqrt(J[..., 0, 0] + J[..., 1, 1])
        vpl = vmax * T + kmd * np.sqrt(J[..., 2, 2])
    else:
        hpl = hmax * np.sqrt(lam)
        vpl = vmax * np.sqrt(lam)
    reason = np.where((reason == Reason.OK) & (np.isinf(hmax) | np.isinf(vmax)),
                      Reason.UNDETECTABLE, reason).astype(np.int8)
    ok = reason == Reason.OK
    return ProtectionLevels(hpl=np.where(ok, hpl, np.nan), vpl=np.where(ok, vpl, np.nan),
                            T2=np.where(ok | (reason == Reason.UNDETECTABLE), T2, np.nan),
                            lam_det=lam, hslope=hs, vslope=vs, reason=reason)


# ---------------------------------------------------------------------------
# iterated WLS for nonlinear models
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class WlsSolution:
    """Result of an iterated WLS solve.

    x : (..., 4) state [E, N, U, clock] (m), NaN where no solution.
    residual : (..., N) post-fit residual ``z − h(x̂)`` (0 on unused rows).
    sse : (...) ``rᵀWr``.
    geometry : :class:`WlsGeometry` at the solution.
    converged : (...) bool, last position update below the tolerance.
    n_iter : (...) int, iterations run by each element (it stops at its own convergence).
    reason : (...) int8 (geometry reason, or NOT_CONVERGED).
    """

    x: NDArray
    residual: NDArray
    sse: NDArray
    geometry: WlsGeometry
    converged: NDArray
    n_iter: NDArray
    reason: NDArray


#: A measurement model: x (..., 4) -> (predicted (..., N), G (..., N, 4)).
Model = Callable[[NDArray], tuple[NDArray, NDArray]]


def iterate_wls(model: Model, z: ArrayLike, W: ArrayLike, mask: ArrayLike | None,
                x0: ArrayLike, n_iter: int = 8, tol_m: float = 1e-3,
                max_cond: float = MAX_COND) -> WlsSolution:
    """Gauss–Newton WLS for a generic model, vectorised over the batch.

    At most ``n_iter`` iterations over the batch; each element stops at the
    iteration whose position step is below ``tol_m`` (and is not stepped
    again), so its answer never depends on what else is in the batch. Elements
    that cannot be solved are frozen and get NaN and a reason.

    Parameters
    ----------
    model : callable, x (..., 4) -> (h(x) (..., N), ∂h/∂x (..., N, 4)).
    z : (..., N) measurements (NaN allowed on unused rows).
    W : (..., N) or (..., N, N) weights.  mask : (..., N) bool rows used.
    x0 : (..., 4) starting state (e.g. the previous epoch's solution; never truth).
    n_iter : maximum iterations.  tol_m : convergence tolerance on the position step (m).
    """
    z = np.asarray(z, float)
    x = np.array(np.broadcast_to(np.asarray(x0, float), z.shape[:-1] + (N_STATES,)))
    m = np.ones(z.shape, bool) if mask is None else np.broadcast_to(np.asarray(mask, bool), z.shape)
    nan_z = (m & ~np.isfinite(z)).any(-1)
    frozen = nan_z.copy()
    converged = np.zeros(z.shape[:-1], bool)
    iters = np.zeros(z.shape[:-1], np.int64)
    for it in range(1, n_iter + 1):
        h, G = model(x)
        geom, _ = wls_fit_any(G, W, mask, max_cond, h, z)  # the masked G and W only at the solution
        dz = np.where(np.isfinite(geom.residual), geom.residual, 0.0)
        dx = np.einsum("...ij,...j->...i", geom.A, dz)  # x̂ = x + A (z − h(x)) (the VA-RAIM paper's eq. 24)
        stepping = ~(frozen | converged)  # a converged element stops where it converged
        frozen = frozen | (stepping & ~geom.solvable)
        stepping &= geom.solvable
        dx = np.where(~stepping[..., None] | ~np.isfinite(dx), 0.0, dx)
        x = x + dx
        iters = np.where(stepping, it, iters)
        converged = converged | (stepping & (np.linalg.norm(dx[..., :3], axis=-1) < tol_m))
        if np.all(converged | frozen):
            break
    h, G = model(x)
    return _solution_at(x, wls_geometry(G, W, mask, max_cond, h, z), converged, frozen, iters)


def _solution_at(x: NDArray, geom: WlsGeometry, converged: NDArray, frozen: NDArray,
                 n_iter: ArrayLike) -> WlsSolution:
    """The solve's verdict at its final state: NaN where frozen, NOT_CONVERGED where it did not stop."""
    reason = np.where((geom.reason == Reason.OK) & ~converged, Reason.NOT_CONVERGED, geom.reason).astype(np.int8)
    bad = ~geom.solvable | frozen
    x = np.where(bad[..., None], np.nan, x)
    # the geometry carries the solve's verdict, so PLs computed from it are NaN too
    geom = replace(geom, reason=reason)
    return WlsSolution(x=x, residual=np.where(bad[..., None], np.nan, geom.residual),
                       sse=np.where(bad, np.nan, geom.sse), geometry=geom, converged=converged & ~bad,
                       n_iter=np.broadcast_to(np.asarray(n_iter, np.int64), reason.shape).copy(), reason=reason)


def gauss_newton_ranges(x0: NDArray, n_iter: int, tol_m: float, gps: tuple, vision: tuple | None = None,
                        where: NDArray | None = None) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Iterated WLS of stacked range rows, each epoch stopping on its own (compiled, :mod:`.kernels`; epochs
    side by side in vector lanes, the per-epoch kernel's numbers bit for bit).

    gps = ``(anchor (..., NG, 3), antenna offset (..., 3), z, w, mask (..., NG))``;
    vision = ``(landmarks (L, 3), camera offset (..., 3), Tm (..., R, L), z (..., R),
    W (..., R, R), mask (..., R))`` or None. The monitors then evaluate the geometry once,
    at the solution, for the reasons, SSE, slopes and PLs (:func:`wls_fit`).
    Returns the state (..., 4), a converged flag (...), the steps taken (...), and the
    stacked predictions h (..., N) and partials G (..., N, 4) at that state (N = NG + R;
    masked rows zero). where : (...) bool, the epochs to solve (None: all); the others are
    not solved (NaN, not converged, 0 steps) and their inputs not read.
    """
    batch = x0.shape[:-1]
    P = int(np.prod(batch, dtype=np.int64))

    def flat(a, tail, dtype=np.float64):
        return kernels.kernel_input(a, batch + tail, (P,) + tail, dtype)

    ag, og, zg, wg, mg = gps
    NG = zg.shape[-1]
    if vision is None:  # no vision block: empty rows
        vision = (np.zeros((1, 3)), np.zeros(3), np.zeros((0, 1)), np.zeros(0), np.zeros((0, 0)), np.zeros(0, bool))
    av, ov, Tm, zv, Wv, mv = vision
    R, L = Tm.shape[-2:]
    av = kernels.kernel_input(av, np.shape(av))
    ov, Tm, zv, Wv = flat(ov, (3,)), flat(Tm, (R, L)), flat(zv, (R,)), flat(Wv, (R, R))
    mv = flat(mv, (R,), np.bool_)
    Nr = NG + zv.shape[-1]
    x = np.empty((P, 4))
    conv = np.empty(P, bool)
    iters = np.empty(P, np.int64)
    h, G = np.empty((P, Nr)), np.empty((P, Nr, 4))
    epochs, skipped = _listed_epochs(where, batch, P)
    for a, v in ((x, np.nan), (conv, False), (iters, 0), (h, np.nan), (G, np.nan)):
        a[skipped] = v
    kernels.range_gauss_newton_tiles(flat(ag, (NG, 3)), flat(og, (3,)), flat(zg, (NG,)), flat(wg, (NG,)),
                                     flat(mg, (NG,), np.bool_), av, ov, Tm, zv, Wv, mv, flat(x0, (4,)), epochs,
                                     n_iter, tol_m, x, conv, iters, h, G)
    return (x.reshape(batch + (4,)), conv.reshape(batch), iters.reshape(batch), h.reshape(batch + (Nr,)),
            G.reshape(batch + (Nr, 4)))


def range_model(anchor_enu: ArrayLike, clock_col: ArrayLike,
                offset_enu: ArrayLike | None = None) -> Model:
    """Range-type measurement model ``hᵢ(x) = ‖aᵢ − (x_pos + oᵢ)‖ + cᵢ·clock``.

    Covers both row kinds of the integrated solution:
    * pseudorange rows: aᵢ = satellite position, cᵢ = 1, oᵢ = antenna lever arm (ENU);
    * vision range rows: aᵢ = landmark position, cᵢ = 0, oᵢ = camera lever arm (ENU),
      so the camera is at ĉ(x) = x + oᵢ (docs/design/integrity.md §2, eq. 2.1).

    Parameters
    ----------
    anchor_enu : (..., N, 3) m, satellite/landmark positions in the world frame.
    clock_col : (..., N) or (N,) 1 for rows with a receiver-clock term, else 0.
    offset_enu : (..., N, 3) or (..., 1, 3) m, sensor position relative to the state position.

    Returns
    -------
    callable x (..., 4) -> (h (..., N), G (..., N, 4)), G rows ``[−uᵢᵀ, cᵢ]``
    with uᵢ the unit vector from the sensor to the anchor.
    """
    a = np.asarray(anchor_enu, float)
    c = np.asarray(clock_col, float)
    o = None if offset_enu is None else np.asarray(offset_enu, float)

    # per-axis contiguous components (the same arithmetic as on (..., N, 3), without strided reads)
    ac = [np.ascontiguousarray(a[..., k]) for k in range(3)]
    oc = None if o is None else [np.ascontiguousarray(o[..., k]) for k in range(3)]

    def model(x: NDArray) -> tuple[NDArray, NDArray]:
        d = []
        for k in range(3):
            p = x[..., None, k]
            if oc is not None:
                p = p + oc[k]
            d.append(ac[k] - p)
        dx, dy, dz = d
        rng = dx * dx  # = norm(d, axis=-1): same operations and summation order, fewer temporaries
        rng += dy * dy
        rng += dz * dz
        np.sqrt(rng, out=rng)
        G = np.empty(rng.shape + (4,))
        nrng = -rng
        with np.errstate(divide="ignore", invalid="ignore"):
            for k in range(3):
                np.divide(d[k], nrng, out=G[..., k])  # −u
        h = rng + c * x[..., None, 3]
        G[..., 3] = c
        return h, G

    return model


def solve_ranges(anchor_enu: ArrayLike, z: ArrayLike, W: ArrayLike, mask: ArrayLike | None,
                 clock_col: ArrayLike, offset_enu: ArrayLike | None = None,
                 x0: ArrayLike | None = None, n_iter: int = 8, tol_m: float = 1e-3,
                 max_cond: float = MAX_COND) -> WlsSolution:
    """Iterated WLS position/clock fix from range-type rows (see :func:`range_model`).

    Parameters
    ----------
    anchor_enu : (..., N, 3) m.  z : (..., N) m measured (pseudo)ranges.
    W : (..., N) or (..., N, N) weights (1/m²).  mask : (..., N) bool.
    clock_col : (..., N) or (N,) 1 for pseudorange rows, 0 for vision ranges.
    offset_enu : optional sensor offsets (..., N, 3) m.
    x0 : (..., 4) start (default: frame origin, zero clock — fine for
        pseudoranges near the frame; vision-only solves should pass a prediction).
    """
    z = np.asarray(z, float)
    if x0 is None:
        x0 = np.zeros(z.shape[:-1] + (N_STATES,))
    Wa = np.asarray(W, float)
    c = np.asarray(clock_col, float)
    off = None if offset_enu is None else np.asarray(offset_enu, float)
    if Wa.ndim == z.ndim and np.all(c == 1.0) and (off is None or off.shape[-2] == 1):
        # pseudorange rows with diagonal weights: each epoch iterates on its own, compiled
        a = np.asarray(anchor_enu, float)
        batch = np.broadcast_shapes(z.shape[:-1], a.shape[:-2], Wa.shape[:-1], np.shape(x0)[:-1])
        N = z.shape[-1]
        m = np.ones(batch + (N,), bool) if mask is None else np.broadcast_to(np.asarray(mask, bool), batch + (N,))
        o = np.zeros(batch + (3,)) if off is None else np.broadcast_to(off[..., 0, :], batch + (3,))
        zb = np.broadcast_to(z, batch + (N,))
        x0b = np.broadcast_to(np.asarray(x0, float), batch + (N_STATES,))
        x, conv, iters, h, G = gauss_newton_ranges(
            x0b, n_iter, tol_m, (np.broadcast_to(a, batch + (N, 3)), o, zb, np.broadcast_to(Wa, batch + (N,)), m))
        geom = wls_geometry(G, np.broadcast_to(Wa, batch + (N,)), m, max_cond, h, zb)
        return _solution_at(x, geom, conv, ~geom.solvable, iters)
    return iterate_wls(range_model(anchor_enu, clock_col, offset_enu), z, W, mask, x0,
                       n_iter=n_iter, tol_m=tol_m, max_cond=max_cond)


def dops(geom, sigma_uere: float = 1.0) -> dict[str, NDArray]:
    """Weighted DOPs from ``geom.J`` (a WlsFit; equal to classic DOPs when
    W = I/σ²·sigma_uere²).

    Returns dict with ``gdop, pdop, hdop, vdop, tdop`` (...), computed as
    sqrt of the J diagonal divided by ``sigma_uere``.
    """
    Jd = np.diagonal(geom.J, axis1=-2, axis2=-1) / sigma_uere**2
    return {"gdop": np.sqrt(Jd.sum(-1)), "pdop": np.sqrt(Jd[..., :3].sum(-1)),
            "hdop": np.sqrt(Jd[..., :2].sum(-1)), "vdop": np.sqrt(Jd[..., 2]),
            "tdop": np.sqrt(Jd[..., 3])}
