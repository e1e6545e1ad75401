"""What a monitor reports at the solution of an iterated solve, in one compiled pass.

After :func:`lsq.gauss_newton_ranges` a snapshot monitor needs, per epoch: the reason
code, J, (WS)ᵢᵢ, the condition number, the residuals and SSE, and the slopes with their
maxima (for both PL variants). As numpy these are a few dozen passes over
``(…, N, 4)`` temporaries, more time than the solve itself. :func:`wls_fit` computes
them with :func:`kernels.fit_at_solution` for every *clean* epoch (finite, clock
estimated, well conditioned, every used row redundant) and takes the others — NaN
input, a dropped clock, ill-conditioned or zero-redundancy geometry — through the
numpy geometry of :mod:`.lsq`, which decides their reasons. Each epoch's path is
decided on its own, so a chunk of a batch gives bit-identical numbers to the whole.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.integrity import kernels, lsq
from testbed.integrity.lsq import Reason


@dataclass(frozen=True)
class WlsFit(lsq.SolvedEpochs):
    """Per-epoch results at the solution (batch shape ``(...)``, N rows).

    mask : (..., N) rows used.  n_used, n_states : (...) rows used and states estimated.
    J : (..., 4, 4) ``(GᵀWG)⁻¹`` (NaN where there is no solution).
    ws_diag : (..., N) ``(WS)ᵢᵢ``, NaN on unused rows.  cond : (...) Jacobi-scaled condition.
    reason : (...) int8 geometry reason, NAN_INPUT also where a used residual is not finite.
    residual : (..., N) ``z − h`` (0 on unused rows), sse : (...) ``rᵀWr``; both NaN where
        there is no solution.
    hslope, vslope : (..., N) slopes (:func:`lsq.slopes`), hmax, vmax : (...) their maxima.
    """

    mask: NDArray
    n_used: NDArray
    n_states: NDArray
    J: NDArray
    ws_diag: NDArray
    cond: NDArray
    reason: NDArray
    residual: NDArray
    sse: NDArray
    hslope: NDArray
    vslope: NDArray
    hmax: NDArray
    vmax: NDArray

    def protection_levels(self, p_fa: float, p_md: float, variant: lsq.PlVariant = "pbias") -> lsq.ProtectionLevels:
        """:func:`lsq.protection_levels` of this solution."""
        return lsq.slope_protection_levels(self.hslope, self.vslope, self.hmax, self.vmax, self.J, self.dof,
                                           self.reason, p_fa, p_md, variant)


def wls_fit(h: ArrayLike, G: ArrayLike, z: ArrayLike, w_diag: ArrayLike, W_block: ArrayLike | None,
            mask: ArrayLike, max_cond: float = lsq.MAX_COND) -> WlsFit:
    """The monitor's quantities at a solution with predictions h (..., N), partials G (..., N, 4).

    z : (..., N) measurements; mask : (..., N) rows used (unused rows may hold NaN).
    Weights ``W = blockdiag(diag(w_diag), W_block)``: w_diag (..., n1) for the first,
    uncorrelated rows; W_block (..., N − n1, N − n1) for the rest, or None when
    ``n1 = N`` (diagonal W). Same numbers, to rounding, and the same reasons as
    :func:`lsq.wls_geometry` (or :func:`lsq.wls_geometry_blocks`), :func:`lsq.weighted_sse`
    and :func:`lsq.slopes` (see :func:`numpy_fit`).
    """
    G = np.asarray(G, float)
    batch, (N, n) = G.shape[:-2], G.shape[-2:]
    wd = np.asarray(w_diag, float)
    n1 = wd.shape[-1]
    if n != lsq.N_STATES or G.size == 0:
        return numpy_fit(h, G, z, w_diag, W_block, mask, max_cond)
    P = int(np.prod(batch, dtype=np.int64))

    def flat(a: ArrayLike, tail: tuple, dtype=np.float64) -> NDArray:
        return kernels.kernel_input(a, batch + tail, (P,) + tail, dtype)

    Wb = np.zeros((0, 0)) if W_block is None else W_block
    ins = (flat(G, (N, n)), flat(h, (N,)), flat(z, (N,)), flat(wd, (n1,)), flat(Wb, (N - n1, N - n1)),
           flat(mask, (N,), np.bool_))
    J, ws, cond = np.empty((P, n, n)), np.empty((P, N)), np.empty(P)
    r, sse, hs, vs = np.empty((P, N)), np.empty(P), np.empty((P, N)), np.empty((P, N))
    hmax, vmax, n_used, fast = np.empty(P), np.empty(P), np.empty(P, np.int64), np.empty(P, bool)
    kernels.fit_at_solution(*ins, lsq.SPD_PIVOT_RTOL, min(lsq.FAST_INV_COND, max_cond), lsq.FAST_WS_RTOL,
                            J, ws, cond, r, sse, hs, vs, hmax, vmax, n_used, fast)
    n_states = np.full(P, n, np.int64)
    reason = np.where(n_used - n_states < 1, Reason.NO_REDUNDANCY, Reason.OK).astype(np.int8)
    fields = {"J": J, "ws_diag": ws, "cond": cond, "residual": r, "sse": sse, "hslope": hs, "vslope": vs,
              "hmax": hmax, "vmax": vmax, "n_states": n_states, "reason": reason}
    slow = ~fast
    if slow.any():  # the numpy path decides these elements, reasons included
        Gf, hf, zf, wdf, Wbf, mf = (a[slow] for a in ins)
        sub = numpy_fit(hf, Gf, zf, wdf, None if W_block is None else Wbf, mf, max_cond)
        for k, a in fields.items():
            a[slow] = getattr(sub, k)
    out = {k: a.reshape(batch + a.shape[1:]) for k, a in fields.items()}
    return WlsFit(mask=ins[5].reshape(batch + (N,)), n_used=n_used.reshape(batch), **out)


def numpy_fit(h: ArrayLike, G: ArrayLike, z: ArrayLike, w_diag: ArrayLike, W_block: ArrayLike | None,
              mask: ArrayLike, max_cond: float = lsq.MAX_COND) -> WlsFit:
    """:func:`wls_fit` by the numpy geometry of :mod:`.lsq` (every element; the reference)."""
    h, z = np.asarray(h, float), np.asarray(z, float)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        if W_block is None:
            geom = lsq.wls_geometry(G, w_diag, mask, max_cond)
        else:
            geom = lsq.wls_geometry_blocks(G, w_diag, W_block, mask, max_cond)
        r = np.where(geom.mask, z - h, 0.0)
        nan_z = (geom.mask & ~np.isfinite(r)).any(-1)
        r = np.where(np.isfinite(r), r, 0.0)
        if W_block is None:
            sse = lsq.weighted_sse(r, geom.W, geom.mask)
        else:  # rᵀWr by blocks (geom.W is the masked diagonal)
            n1 = np.shape(w_diag)[-1]
            Wb = np.asarray(W_block, float)
            mv = geom.mask[..., n1:]
            Wb0 = np.where(mv[..., :, None] & mv[..., None, :] & np.isfinite(Wb), Wb, 0.0)
            rg, rv = r[..., :n1], r[..., n1:]
            sse = np.sum(geom.W[..., :n1] * rg * rg, axis=-1) + np.sum((Wb0 @ rv[..., None])[..., 0] * rv, axis=-1)
        hs, vs = lsq.slopes(geom)
    reason = np.where(nan_z, Reason.NAN_INPUT, geom.reason).astype(np.int8)
    bad = ~((reason == Reason.OK) | (reason == Reason.NO_REDUNDANCY))
    return WlsFit(mask=geom.mask, n_used=geom.n_used, n_states=geom.n_states, J=geom.J, ws_diag=geom.ws_diag,
                  cond=geom.cond, reason=reason, residual=np.where(bad[..., None], np.nan, r),
                  sse=np.where(bad, np.nan, sse), hslope=hs, vslope=vs, hmax=lsq.max_over_rows(hs),
                  vmax=lsq.max_over_rows(vs))
