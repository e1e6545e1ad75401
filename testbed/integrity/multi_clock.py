"""Snapshot least squares over the satellites given, with one receiver clock per constellation.

Rows of K constellations: hᵢ(x) = ‖aᵢ − (p + o)‖ + c_{k(i)}, state x = [E, N, U, c_1 … c_K]
(docs/design/gnss.md §4): each constellation's time differs from the receiver's by an
unknown offset, so each has its own clock column (the one-hot G columns of ARAIM's
geometry matrix). A constellation with no used row at an epoch has no column there: its
clock is not estimated and it adds no state. With one constellation this is the 4-state
problem of :mod:`testbed.integrity.lsq`; the monitors keep the compiled 4-state kernels
for it (bit for bit) and use this numpy path only when more than one system is present.

Everything :class:`~testbed.integrity.lsq.WlsFit` holds is computed here for ``3 + K``
states (J, A, (WS)ᵢᵢ, residuals, SSE, slopes, reason), so protection levels, DOPs and
exclusion work on it unchanged; ``n_states`` counts the clocks estimated, so the
detection test has n − 3 − K_present degrees of freedom.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.integrity.lsq import MAX_COND, Reason, WlsFit


def system_codes(system: ArrayLike) -> tuple[NDArray, tuple[str, ...]]:
    """Codes (S,) of each slot's system (0 … K−1, in order of first appearance) and the K letters."""
    letters = tuple(dict.fromkeys(np.asarray(system).tolist()))
    lookup = {c: k for k, c in enumerate(letters)}
    return np.array([lookup[c] for c in np.asarray(system).tolist()], np.int64), letters


def _rows(x: NDArray, anchor: NDArray, off: NDArray, code: NDArray, K: int) -> tuple[NDArray, NDArray]:
    """Predictions h (P, N) and partials G (P, N, 3 + K) at states x (P, 3 + K)."""
    d = anchor - (x[:, None, :3] + off[:, None, :])
    rng = np.linalg.norm(d, axis=-1)
    h = rng + np.take_along_axis(x[:, 3:], code, axis=1)
    onehot = (code[..., None] == np.arange(K)).astype(float)
    return h, np.concatenate([-d / rng[..., None], onehot], axis=-1)


def _normal(G: NDArray, w: NDArray, mask: NDArray, K: int):
    """The masked normal matrix with a unit pivot on each absent clock, the clocks present (P, K)."""
    Gm = np.where(mask[..., None], G, 0.0)
    wm = np.where(mask, w, 0.0)
    M = np.einsum("pni,pn,pnj->pij", Gm, wm, Gm)
    present = (Gm[..., 3:] != 0).any(axis=1)
    k = np.arange(K)
    M[:, 3 + k, 3 + k] += np.where(present, 0.0, 1.0)
    return Gm, wm, M, present


def fit_multi_clock(anchor: ArrayLike, off: ArrayLike, z: ArrayLike, w: ArrayLike, mask: ArrayLike,
                    code: ArrayLike, K: int, x0: ArrayLike | None = None, n_iter: int = 10, tol_m: float = 1e-3,
                    max_cond: float = MAX_COND) -> tuple[NDArray, NDArray, NDArray, WlsFit]:
    """Iterated WLS with a clock per constellation, each epoch stopping on its own.

    Parameters
    ----------
    anchor : (P, N, 3) satellite positions in the world frame.  off : (P, 3) antenna offset.
    z, w : (P, N) pseudoranges and weights 1/σ².  mask : (P, N) rows used.
    code : (P, N) int system code of each row (0 … K−1).  x0 : (P, 3 + K) start (default 0).

    Returns
    -------
    x : (P, 3 + K) (absent clocks 0; NaN where no solution).  converged : (P,).  n_iter : (P,).
    fit : the :class:`WlsFit` at x (J (P, 3+K, 3+K), A (P, 3+K, N)).
    """
    anchor, off, z, w = (np.asarray(a, float) for a in (anchor, off, z, w))
    mask, code = np.asarray(mask, bool), np.asarray(code, np.int64)
    P, N = z.shape
    n_s = 3 + K
    x = np.zeros((P, n_s)) if x0 is None else np.array(x0, float)
    bad_input = (mask & ~(np.isfinite(z) & np.isfinite(w) & np.isfinite(anchor).all(-1))).any(-1)
    z0 = np.where(mask, z, 0.0)
    frozen, converged = bad_input.copy(), np.zeros(P, bool)
    iters = np.zeros(P, np.int64)
    for it in range(1, n_iter + 1):
        h, G = _rows(x, np.where(mask[..., None], anchor, 1.0), off, code, K)
        Gm, wm, M, present = _normal(G, w, mask, K)
        n_states = 3 + present.sum(-1)
        solvable = ~frozen & (mask.sum(-1) >= n_states) & np.isfinite(M).all((-2, -1))
        with np.errstate(all="ignore"):
            ok_det = np.abs(np.linalg.det(np.where(solvable[:, None, None], M, np.eye(n_s)))) > 0
        stepping = solvable & ok_det & ~converged
        frozen |= ~converged & ~(solvable & ok_det)
        if not stepping.any():
            break
        g = np.einsum("pni,pn,pn->pi", Gm, wm, np.where(mask, z0 - h, 0.0))
        dx = np.zeros((P, n_s))
        dx[stepping] = np.linalg.solve(M[stepping], g[stepping][..., None])[..., 0]
        x = x + dx
        iters = np.where(stepping, it, iters)
        converged |= stepping & (np.linalg.norm(dx[:, :3], axis=-1) < tol_m)
        if np.all(converged | frozen):
            break
    fit = _fit_at(x, anchor, off, z, w, mask, code, K, bad_input, max_cond)
    solved = (fit.reason == Reason.OK) | (fit.reason == Reason.NO_REDUNDANCY)
    x = np.where(solved[:, None], x, np.nan)
    return x, converged & solved, iters, fit


def _fit_at(x, anchor, off, z, w, mask, code, K, bad_input, max_cond) -> WlsFit:
    """Every field of :class:`WlsFit` at states x (P, 3 + K) (as the 4-state kernel defines them)."""
    P, N = z.shape
    n_s = 3 + K
    h, G = _rows(np.where(np.isfinite(x), x, 0.0), np.where(mask[..., None], anchor, 1.0), off, code, K)
    Gm, wm, M, present = _normal(G, w, mask, K)
    n_used = mask.sum(-1)
    n_states = 3 + present.sum(-1)
    reason = np.full(P, Reason.OK, np.int8)
    reason[n_used - n_states < 1] = Reason.NO_REDUNDANCY
    d = np.sqrt(np.diagonal(M, axis1=-2, axis2=-1))
    with np.errstate(all="ignore"):
        scaled = M / (d[:, :, None] * d[:, None, :])
        good = np.isfinite(scaled).all((-2, -1)) & (d > 0).all(-1)
        cond = np.full(P, np.inf)
        cond[good] = np.linalg.cond(scaled[good], 1)
    reason[~(cond <= max_cond)] = Reason.SINGULAR
    reason[n_used < n_states] = Reason.NO_POSITION
    reason[bad_input] = Reason.NAN_INPUT
    solved = (reason == Reason.OK) | (reason == Reason.NO_REDUNDANCY)
    J = np.full((P, n_s, n_s), np.nan)
    if solved.any():
        Jp = np.linalg.inv(M[solved])
        drop = ~present[solved]  # an absent clock: no state, zero row and column
        Jp[:, 3:, :] = np.where(drop[:, :, None], 0.0, Jp[:, 3:, :])
        Jp[:, :, 3:] = np.where(drop[:, None, :], 0.0, Jp[:, :, 3:])
        J[solved] = Jp
    A = np.einsum("pij,pnj,pn->pin", J, Gm, wm)
    with np.errstate(all="ignore"):
        ws = wm - wm**2 * np.einsum("pni,pij,pnj->pn", Gm, J, Gm)
        zero = ws <= 1e-12 * np.abs(wm)
        hs = np.where(zero, np.inf, np.hypot(A[:, 0], A[:, 1]) / np.sqrt(ws))
        vs = np.where(zero, np.inf, np.abs(A[:, 2]) / np.sqrt(ws))
    use = mask & solved[:, None]
    r = np.where(mask, z - h, 0.0)
    residual = np.where(solved[:, None], r, np.nan)
    sse = np.where(solved, np.einsum("pn,pn,pn->p", wm, r, r), np.nan)
    hs, vs, ws = (np.where(use, a, np.nan) for a in (hs, vs, ws))
    with np.errstate(all="ignore"):
        hmax = np.where(solved, np.max(np.where(use, hs, -np.inf), axis=-1, initial=-np.inf), np.nan)
        vmax = np.where(solved, np.max(np.where(use, vs, -np.inf), axis=-1, initial=-np.inf), np.nan)
    return WlsFit(mask=mask, n_used=n_used.astype(np.int64), n_states=n_states.astype(np.int64), J=J, A=A,
                  ws_diag=ws, cond=cond, reason=reason, residual=residual, sse=sse, hslope=hs, vslope=vs,
                  hmax=hmax, vmax=vmax)


def geometry_dops(los_enu: ArrayLike, mask: ArrayLike, code: ArrayLike, K: int) -> dict[str, NDArray]:
    """Unweighted DOPs of the satellites ``mask`` (..., S) with one clock per constellation present.

    los_enu : (..., S, 3) unit lines of sight (receiver to satellite, ENU); code : (S,) or (..., S) system
    codes. Returns ``hdop``, ``vdop``, ``pdop`` (...), NaN where the rows do not fix position and clocks.
    """
    u = np.asarray(los_enu, float)
    m = np.asarray(mask, bool)
    onehot = (np.broadcast_to(np.asarray(code), m.shape)[..., None] == np.arange(K)).astype(float)
    G = np.where(m[..., None], np.concatenate([-u, onehot], axis=-1), 0.0)
    G = np.where(np.isfinite(G), G, 0.0)
    M = np.einsum("...ni,...nj->...ij", G, G)
    present = (G[..., 3:] != 0).any(axis=-2)
    k = np.arange(K)
    M[..., 3 + k, 3 + k] += np.where(present, 0.0, 1.0)  # an absent clock: no state
    ok = m.sum(-1) >= 3 + present.sum(-1)
    with np.errstate(all="ignore"):
        d = np.full(M.shape[:-1], np.nan)
        good = ok & (np.abs(np.linalg.det(np.where(ok[..., None, None], M, np.eye(3 + K)))) > 1e-12)
        d[good] = np.diagonal(np.linalg.inv(M[good]), axis1=-2, axis2=-1)
    return {"hdop": np.sqrt(d[..., 0] + d[..., 1]), "vdop": np.sqrt(d[..., 2]), "pdop": np.sqrt(d[..., :3].sum(-1))}
