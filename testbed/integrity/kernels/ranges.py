"""Range rows: the used-row gather and the iterated WLS of stacked GPS and vision range rows."""

from __future__ import annotations

import sys

import numpy as np
from numba import njit

from testbed.integrity.kernels.small import _end_failed_lanes, _lu_solve, _offset_range, _tile_lu_solve
from testbed.kernel_cache import keep_in_step


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
        d0, d1, d2, rng = _offset_range(anchor_g[p, n, 0], anchor_g[p, n, 1], anchor_g[p, n, 2],
                                        x[0] + off_g[p, 0], x[1] + off_g[p, 1], x[2] + off_g[p, 2])
        h[n] = rng + x[3]
        G[n, 0] = -d0 / rng
        G[n, 1] = -d1 / rng
        G[n, 2] = -d2 / rng
        G[n, 3] = 1.0
    if R == 0:
        return
    for l in range(L):
        d0, d1, d2, rng = _offset_range(anchor_v[l, 0], anchor_v[l, 1], anchor_v[l, 2],
                                        x[0] + off_v[p, 0], x[1] + off_v[p, 1], x[2] + off_v[p, 2])
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
def _gn_steps(p, x, steps, n_iter, tol_m, anchor_g, off_g, z_g, w_g, mask_g, anchor_v, off_v, Tm, z_v, W_v, mask_v,
              Nm, g, hv, Gv, h, G, dz):
    """Gauss–Newton steps of epoch ``p`` from ``x`` (updated in place), ``steps`` already taken, until its
    step is below ``tol_m``, its normal matrix is singular or it has taken ``n_iter``: (converged, steps)."""
    NG = z_g.shape[1]
    R = z_v.shape[1]
    Nr = NG + R
    conv = False
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
    return conv, steps


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
        conv, steps = _gn_steps(p, x, 0, n_iter, tol_m, anchor_g, off_g, z_g, w_g, mask_g, anchor_v, off_v, Tm, z_v, W_v,
                                mask_v, Nm, g, hv, Gv, h, G, dz)
        x_out[p] = x
        conv_out[p] = conv
        iter_out[p] = steps
        _range_rows(p, x, anchor_g, off_g, mask_g, anchor_v, off_v, Tm, mask_v, hv, Gv, h_out[p], G_out[p])


#: epochs iterated side by side by :func:`range_gauss_newton_tiles`
TILE = 64


@njit(cache=True, nogil=True, error_model="numpy")
def _tile_rows(n, x, ag, og, mg, av, ov, Tm, mv, hv, Gv, h, G):
    """:func:`_range_rows` for ``n`` gathered epochs side by side (last axis), the same arithmetic.

    ag (NG, 3, T), og (3, T), mg (NG, T); av (L, 3); ov (3, T), Tm (R, L, T), mv (R, T);
    x (4, T). Writes h (NG + R, T) and G (NG + R, 4, T); hv (L, T), Gv (L, 3, T) scratch.
    """
    NG = ag.shape[0]
    R = Tm.shape[0]
    L = av.shape[0]
    for k in range(NG):
        for q in range(n):
            d0, d1, d2, rng = _offset_range(ag[k, 0, q], ag[k, 1, q], ag[k, 2, q],
                                            x[0, q] + og[0, q], x[1, q] + og[1, q], x[2, q] + og[2, q])
            u = mg[k, q]
            h[k, q] = rng + x[3, q] if u else 0.0
            G[k, 0, q] = -d0 / rng if u else 0.0
            G[k, 1, q] = -d1 / rng if u else 0.0
            G[k, 2, q] = -d2 / rng if u else 0.0
            G[k, 3, q] = 1.0 if u else 0.0
    if R == 0:
        return
    for l in range(L):
        for q in range(n):
            d0, d1, d2, rng = _offset_range(av[l, 0], av[l, 1], av[l, 2],
                                            x[0, q] + ov[0, q], x[1, q] + ov[1, q], x[2, q] + ov[2, q])
            hv[l, q] = rng
            Gv[l, 0, q] = -d0 / rng
            Gv[l, 1, q] = -d1 / rng
            Gv[l, 2, q] = -d2 / rng
    for r in range(R):
        k = NG + r
        for q in range(n):
            h[k, q] = 0.0
            G[k, 0, q] = 0.0
            G[k, 1, q] = 0.0
            G[k, 2, q] = 0.0
            G[k, 3, q] = 0.0
        for l in range(L):
            for q in range(n):
                t = Tm[r, l, q]
                if mv[r, q] and t != 0.0:
                    h[k, q] += t * hv[l, q]
                    G[k, 0, q] += t * Gv[l, 0, q]
                    G[k, 1, q] += t * Gv[l, 1, q]
                    G[k, 2, q] += t * Gv[l, 2, q]


@njit(cache=True, nogil=True, error_model="numpy")
def _tile_normal(n, h, G, zg, wg, zv, Wv, dz, Nm, g):
    """The normal equations of ``n`` epochs side by side at the rows h, G (:func:`range_gauss_newton`'s
    arithmetic: non-finite residuals and partials count as zero; weights of unused rows are zero)."""
    NG = zg.shape[0]
    R = zv.shape[0]
    Nr = NG + R
    for k in range(Nr):
        for q in range(n):
            zk = zg[k, q] if k < NG else zv[k - NG, q]
            e = zk - h[k, q]
            dz[k, q] = e if np.isfinite(e) else 0.0
        for c in range(4):
            for q in range(n):
                gc = G[k, c, q]
                G[k, c, q] = gc if np.isfinite(gc) else 0.0
    Nm[:, :, :n] = 0.0
    g[:, :n] = 0.0
    for k in range(NG):  # each sum in the per-epoch kernel's order (the epochs innermost)
        for i in range(4):
            for q in range(n):
                g[i, q] += (wg[k, q] * G[k, i, q]) * dz[k, q]
            for j in range(i, 4):
                for q in range(n):
                    Nm[i, j, q] += (wg[k, q] * G[k, i, q]) * G[k, j, q]
    for r in range(R):
        for s in range(R):
            for i in range(4):
                for q in range(n):
                    g[i, q] += (Wv[r, s, q] * G[NG + r, i, q]) * dz[NG + s, q]
                for j in range(i, 4):
                    for q in range(n):
                        Nm[i, j, q] += (Wv[r, s, q] * G[NG + r, i, q]) * G[NG + s, j, q]


@njit(cache=True, nogil=True, error_model="numpy")
def range_gauss_newton_tiles(anchor_g, off_g, z_g, w_g, mask_g, anchor_v, off_v, Tm, z_v, W_v, mask_v,
                             x0, epochs, n_iter, tol_m, x_out, conv_out, iter_out, h_out, G_out):
    """:func:`range_gauss_newton`, epochs ``TILE`` at a time side by side: the same numbers bit for bit.

    Only the epochs listed in ``epochs`` (int64 indices into the batch) are solved and written.

    Each epoch keeps its own iteration: it stops, as there, when its step is below ``tol_m`` or its
    normal matrix is singular, and later passes leave it alone. An unused row or pair of rows
    enters with a zero weight, and adding an exact zero to a sum that starts at +0 changes no bit.
    """
    P = epochs.shape[0]
    NG = z_g.shape[1]
    R = z_v.shape[1]
    L = anchor_v.shape[0]
    Nr = NG + R
    ag, og, zg, wg, mg = (np.empty((NG, 3, TILE)), np.empty((3, TILE)), np.empty((NG, TILE)), np.empty((NG, TILE)),
                          np.empty((NG, TILE), np.bool_))
    ov, Tt, zv, Wt, mv = (np.empty((3, TILE)), np.empty((R, L, TILE)), np.empty((R, TILE)), np.empty((R, R, TILE)),
                          np.empty((R, TILE), np.bool_))
    x, h, G, dz = np.empty((4, TILE)), np.empty((Nr, TILE)), np.empty((Nr, 4, TILE)), np.empty((Nr, TILE))
    hv, Gv = np.empty((L, TILE)), np.empty((L, 3, TILE))
    Nm, g = np.empty((4, 4, TILE)), np.empty((4, TILE))
    active, solved = np.empty(TILE, np.bool_), np.empty(TILE, np.bool_)
    x1, Nm1, g1, hv1, Gv1 = np.empty(4), np.empty((4, 4)), np.empty((4, 1)), np.empty(L), np.zeros((L, 4))
    h1, G1, dz1 = np.empty(Nr), np.empty((Nr, 4)), np.empty(Nr)
    conv = np.empty(TILE, np.bool_)
    steps = np.empty(TILE, np.int64)
    for p0 in range(0, P, TILE):
        n = min(TILE, P - p0)
        for q in range(n):  # -- gather; a skipped row or pair gets weight 0
            p = epochs[p0 + q]
            mg[:, q] = mask_g[p]
            zg[:, q] = z_g[p]
            ag[:, :, q] = anchor_g[p]
            og[:, q] = off_g[p]
            ov[:, q] = off_v[p]
            mv[:, q] = mask_v[p]
            zv[:, q] = z_v[p]
            Tt[:, :, q] = Tm[p]
            for k in range(NG):
                wg[k, q] = w_g[p, k] if mask_g[p, k] else 0.0
            for r in range(R):
                for s in range(R):
                    w = W_v[p, r, s]
                    use = mask_v[p, r] and mask_v[p, s] and w != 0.0 and np.isfinite(w)
                    Wt[r, s, q] = w if use else 0.0
            for c in range(4):
                x[c, q] = x0[p, c]
            active[q] = True
            conv[q] = False
            steps[q] = 0
        for it in range(n_iter):
            _tile_rows(n, x, ag, og, mg, anchor_v, ov, Tt, mv, hv, Gv, h, G)
            _tile_normal(n, h, G, zg, wg, zv, Wt, dz, Nm, g)
            for i in range(4):
                for j in range(i):
                    for q in range(n):
                        Nm[i, j, q] = Nm[j, i, q]
            _tile_lu_solve(n, Nm, g, solved)
            _end_failed_lanes(n, active, solved, conv)
            more = 0
            for q in range(n):
                if not active[q]:
                    continue
                steps[q] += 1
                for i in range(4):
                    x[i, q] += g[i, q]
                conv[q] = np.sqrt(g[0, q] ** 2 + g[1, q] ** 2 + g[2, q] ** 2) < tol_m
                active[q] = not conv[q]
                more += active[q]
            if more == 0:
                break
            if 8 * more <= n:  # a few epochs left: each finishes on its own (the same steps)
                for q in range(n):
                    if active[q]:
                        x1[:] = x[:, q]
                        conv[q], steps[q] = _gn_steps(epochs[p0 + q], x1, steps[q], n_iter, tol_m, anchor_g, off_g, z_g, w_g,
                                                      mask_g, anchor_v, off_v, Tm, z_v, W_v, mask_v, Nm1, g1, hv1, Gv1,
                                                      h1, G1, dz1)
                        x[:, q] = x1
                break
        _tile_rows(n, x, ag, og, mg, anchor_v, ov, Tt, mv, hv, Gv, h, G)
        for q in range(n):  # -- scatter
            p = epochs[p0 + q]
            for c in range(4):
                x_out[p, c] = x[c, q]
            conv_out[p] = conv[q]
            iter_out[p] = steps[q]
            for k in range(Nr):
                h_out[p, k] = h[k, q]
                for c in range(4):
                    G_out[p, k, c] = G[k, c, q]


# numba compiles a kernel again when its own file changes, not when a helper's does
keep_in_step(sys.modules[__name__])
