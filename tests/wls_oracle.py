"""The test oracle for the weighted-LS kernel (:func:`testbed.integrity.kernels.wls_epochs`).

Textbook numpy/LAPACK, one epoch at a time, written from docs/design/integrity.md §2-§4
and the VA-RAIM paper's eq. 20-26 without looking at the kernel: the used rows are selected (not
zero-weighted), W is formed in full, J by ``np.linalg.inv``, S = I − G A, the
condition numbers by ``np.linalg.cond`` (1-norm for the SINGULAR rule, 2-norm to
check the kernel's bound κ₂ ≤ κ₁ ≤ 4κ₂). Slow and obvious on purpose.
"""

from __future__ import annotations

import numpy as np

from testbed.integrity.lsq import MAX_COND, Reason


def oracle_fit(h, G, z, w_diag, W_block, mask, max_cond: float = MAX_COND) -> dict[str, np.ndarray]:
    """Per-epoch fields of :class:`testbed.integrity.lsq.WlsFit` for a batch (P, N), plus ``cond2``."""
    G = np.asarray(G, float)
    P, N, _ = G.shape
    n1 = np.shape(w_diag)[-1]
    out = {k: np.full((P, N), np.nan) for k in ("ws_diag", "residual", "hslope", "vslope")}
    out |= {k: np.full(P, np.nan) for k in ("cond", "cond2", "sse")}
    out |= {"J": np.full((P, 4, 4), np.nan), "A": np.full((P, 4, N), np.nan), "hmax": np.full(P, -np.inf),
            "vmax": np.full(P, -np.inf), "n_used": np.zeros(P, int), "n_states": np.zeros(P, int),
            "reason": np.zeros(P, int)}
    for p in range(P):
        W = np.zeros((N, N))
        W[np.arange(n1), np.arange(n1)] = w_diag[p]
        if W_block is not None:
            W[n1:, n1:] = W_block[p]
        m = np.asarray(mask[p], bool)
        Gm, Wm, r = G[p][m], W[np.ix_(m, m)], (z[p] - h[p])[m]
        clock = bool(np.any(Gm[:, 3][np.isfinite(Gm[:, 3])] != 0))
        n_states = 4 if clock else 3
        out["n_used"][p], out["n_states"][p] = m.sum(), n_states
        if not (np.isfinite(Gm).all() and np.isfinite(Wm).all() and np.isfinite(r).all()):
            out["reason"][p] = Reason.NAN_INPUT
            continue
        if m.sum() < n_states:
            out["reason"][p] = Reason.NO_POSITION
            continue
        Gs = Gm[:, :n_states]  # the estimated states only
        M = Gs.T @ Wm @ Gs
        d = np.sqrt(np.diag(M))
        if not (d > 0).all():
            out["reason"][p], out["cond"][p] = Reason.SINGULAR, np.inf
            continue
        Ms = M / np.outer(d, d)
        if n_states == 3:  # the dropped clock's unit pivot, as the kernel defines cond
            Ms = np.block([[Ms, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]])
        with np.errstate(all="ignore"):
            cond = np.linalg.cond(Ms, 1)
        out["cond"][p], out["cond2"][p] = cond, np.linalg.cond(Ms, 2)
        if not cond <= max_cond:
            out["reason"][p] = Reason.SINGULAR
            continue
        out["reason"][p] = Reason.NO_REDUNDANCY if m.sum() - n_states < 1 else Reason.OK
        J = np.zeros((4, 4))
        J[:n_states, :n_states] = np.linalg.inv(M)
        A = J @ Gm.T @ Wm
        ws = np.diag(Wm @ (np.eye(m.sum()) - Gm @ A))
        zero = ws <= 1e-12 * np.abs(np.diag(Wm))
        with np.errstate(divide="ignore", invalid="ignore"):
            hs = np.where(zero, np.inf, np.hypot(A[0], A[1]) / np.sqrt(ws))
            vs = np.where(zero, np.inf, np.abs(A[2]) / np.sqrt(ws))
        out["J"][p], out["A"][p] = J, 0.0
        out["A"][p][:, m] = A
        out["ws_diag"][p][m], out["hslope"][p][m], out["vslope"][p][m] = ws, hs, vs
        out["hmax"][p], out["vmax"][p] = hs.max(initial=-np.inf), vs.max(initial=-np.inf)
        out["residual"][p] = 0.0
        out["residual"][p][m] = r
        out["sse"][p] = r @ Wm @ r
    return out
