"""Range rows: the used-row gather and the iterated WLS of stacked GPS and vision range rows."""

from __future__ import annotations

import numpy as np
from numba import njit

from testbed.integrity.kernels.small import _lu_solve


@njit(cache=True, nogil=True, error_model="numpy")
def gather_used_rows(vis, pr, sigma, sat_ecef, R, origin, idx_out, mask_out, z_out, w_out, anchor_out):
    """The used rows of every epoch first, as ``raim.compact_rows``, with their data.

    vis, pr, sigma (P, S), sat_ecef (P, S, 3). Row order: the slots with ``vis`` in
    ascending order, then the others in ascending order (a stable sort of ``~vis``), the
    first N = idx_out.shape[1]. Writes the slot index, the row mask, the pseudorange, the
    weight 1/σ² (0 on unused rows) and the satellite position in the world frame,
    ``R (sat − origin)`` (R (3, 3) ECEF→ENU, origin (3,) ECEF; only rows that are written).
    """
    P, S = vis.shape
    N = idx_out.shape[1]
    for p in range(P):
        n = 0
        for s in range(S):
            if vis[p, s] and n < N:
                idx_out[p, n] = s
                n += 1
        for s in range(S):
            if not vis[p, s] and n < N:
                idx_out[p, n] = s
                n += 1
        for n in range(N):
            s = idx_out[p, n]
            used = vis[p, s]
            mask_out[p, n] = used
            z_out[p, n] = pr[p, s]
            w_out[p, n] = 1.0 / (sigma[p, s] * sigma[p, s]) if used else 0.0
            d0 = sat_ecef[p, s, 0] - origin[0]
            d1 = sat_ecef[p, s, 1] - origin[1]
            d2 = sat_ecef[p, s, 2] - origin[2]
            for c in range(3):
                anchor_out[p, n, c] = R[c, 0] * d0 + R[c, 1] * d1 + R[c, 2] * d2


@njit(cache=True, nogil=True, error_model="numpy")
def scatter_used_rows(values, idx, mask, out):
    """The inverse of :func:`gather_used_rows` for a per-row quantity, in one pass.

    values (P, N + E): N compacted rows, then E rows that are not satellites (copied as
    they are); idx, mask (P, N); out (P, S + E): the N rows put back in their slots
    ``idx``, NaN on every slot no used row fills, then the E rows.
    """
    P, N = idx.shape
    S = out.shape[1] - (values.shape[1] - N)
    E = values.shape[1] - N
    for p in range(P):
        for s in range(S):
            out[p, s] = np.nan
        for n in range(N):
            if mask[p, n]:
                out[p, idx[p, n]] = values[p, n]
        for e in range(E):
            out[p, S + e] = values[p, N + e]


@njit(cache=True, nogil=True, error_model="numpy")
def _range_rows(p, x, anchor_g, off_g, mask_g, anchor_v, off_v, Tm, mask_v, hv, Gv, h, G):
    """Stacked predictions h (NG + R,) and partials G (NG + R, 4) of epoch p at state x.

    Raw values (NaN inputs give NaN); masked rows are zero. hv (L,), Gv (L, 4): scratch.
    """
    NG = mask_g.shape[1]
    R = mask_v.shape[1]
    L = anchor_v.shape[0]
    for n in range(NG):
        if not mask_g[p, n]:
            h[n] = 0.0
            G[n, :] = 0.0
            continue
        d0 = anchor_g[p, n, 0] - (x[0] + off_g[p, 0])
        d1 = anchor_g[p, n, 1] - (x[1] + off_g[p, 1])
        d2 = anchor_g[p, n, 2] - (x[2] + off_g[p, 2])
        rng = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        h[n] = rng + x[3]
        G[n, 0] = -d0 / rng
        G[n, 1] = -d1 / rng
        G[n, 2] = -d2 / rng
        G[n, 3] = 1.0
    if R == 0:
        return
    for l in range(L):
        d0 = anchor_v[l, 0] - (x[0] + off_v[p, 0])
        d1 = anchor_v[l, 1] - (x[1] + off_v[p, 1])
        d2 = anchor_v[l, 2] - (x[2] + off_v[p, 2])
        rng = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        hv[l] = rng
        Gv[l, 0] = -d0 / rng
        Gv[l, 1] = -d1 / rng
        Gv[l, 2] = -d2 / rng
    for r in range(R):
        q = NG + r
        h[q] = 0.0
        G[q, :] = 0.0
        if not mask_v[p, r]:
            continue
        for l in range(L):
            t = Tm[p, r, l]
            if t != 0.0:
                h[q] += t * hv[l]
                for c in range(3):
                    G[q, c] += t * Gv[l, c]


@njit(cache=True, nogil=True, error_model="numpy")
def range_gauss_newton(anchor_g, off_g, z_g, w_g, mask_g, anchor_v, off_v, Tm, z_v, W_v, mask_v,
                       x0, n_iter, tol_m, x_out, conv_out, iter_out, h_out, G_out):
    """Iterated WLS of stacked range rows, one epoch at a time.

    State ``x = [E, N, U, clock]``. Row blocks (P = flattened batch):

    * GPS rows (P, NG): range from ``x + off_g`` to ``anchor_g`` plus the clock,
      diagonal weights ``w_g``;
    * vision rows (P, R): ``Tm @ ranges`` from ``x + off_v`` to the landmarks
      ``anchor_v`` (L, 3), no clock term, full weight block ``W_v`` (R, R).
      R = 0 for GPS-only solves.

    Masked rows are left out; non-finite predictions or partials count as zero,
    as in the numpy iteration. An epoch stops when its position step is below
    ``tol_m`` (converged) or its normal matrix is singular (not converged).
    Writes ``x_out`` (P, 4), ``conv_out`` (P,), ``iter_out`` (P,) steps taken, and the
    rows at the final state: ``h_out`` (P, NG + R), ``G_out`` (P, NG + R, 4) (raw, as
    :func:`_range_rows`).
    """
    P, NG = z_g.shape
    R = z_v.shape[1]
    L = anchor_v.shape[0]
    Nr = NG + R
    Nm = np.empty((4, 4))
    g = np.empty((4, 1))
    hv = np.empty(L)
    Gv = np.zeros((L, 4))
    h = np.empty(Nr)
    G = np.empty((Nr, 4))
    dz = np.empty(Nr)
    x = np.empty(4)
    for p in range(P):
        x[:] = x0[p]
        conv = False
        steps = 0
        while steps < n_iter:
            _range_rows(p, x, anchor_g, off_g, mask_g, anchor_v, off_v, Tm, mask_v, hv, Gv, h, G)
            for n in range(Nr):
                used = mask_g[p, n] if n < NG else mask_v[p, n - NG]
                zn = z_g[p, n] if n < NG else z_v[p, n - NG]
                dz[n] = zn - h[n] if used else 0.0
                if not np.isfinite(dz[n]):
                    dz[n] = 0.0
                for c in range(4):
                    if not np.isfinite(G[n, c]):
                        G[n, c] = 0.0
            Nm[:] = 0.0
            g[:] = 0.0
            for n in range(NG):
                w = w_g[p, n]
                if not mask_g[p, n] or w == 0.0:
                    continue
                for i in range(4):
                    wgi = w * G[n, i]
                    g[i, 0] += wgi * dz[n]
                    for j in range(i, 4):
                        Nm[i, j] += wgi * G[n, j]
            for r in range(R):
                if not mask_v[p, r]:
                    continue
                for s in range(R):
                    w = W_v[p, r, s]
                    if not mask_v[p, s] or w == 0.0 or not np.isfinite(w):
                        continue
                    for i in range(4):
                        wgi = w * G[NG + r, i]
                        g[i, 0] += wgi * dz[NG + s]
                        for j in range(i, 4):
                            Nm[i, j] += wgi * G[NG + s, j]
            for i in range(4):
                for j in range(i):
                    Nm[i, j] = Nm[j, i]
            if not _lu_solve(Nm, g):
                conv = False
                break
            steps += 1
            for i in range(4):
                x[i] += g[i, 0]
            conv = np.sqrt(g[0, 0] ** 2 + g[1, 0] ** 2 + g[2, 0] ** 2) < tol_m
            if conv:
                break
        x_out[p] = x
        conv_out[p] = conv
        iter_out[p] = steps
        _range_rows(p, x, anchor_g, off_g, mask_g, anchor_v, off_v, Tm, mask_v, hv, Gv, h_out[p], G_out[p])
