"""The vision stage of VA-RAIM, per epoch: cosines and Σ_c, the cosine-rule solve and its products,
the vision prior and the integrated solve's vision block."""

from __future__ import annotations

import sys

import numpy as np
from numba import njit

from testbed.integrity.kernels.small import (_end_failed_lanes, _lu_solve, _matmul, _offset_range, _sandwich, _tile_lu_solve,
                                            _tile_matmul, _tile_sandwich)
from testbed.kernel_cache import keep_in_step


@njit(cache=True, nogil=True, error_model="numpy")
def _pair_indices(L):
    """Landmark indices (I, J) of the N_C = L(L−1)/2 pair slots, ``numpy.triu_indices(L, 1)`` order."""
    nc = L * (L - 1) // 2
    I = np.empty(nc, np.int64)
    J = np.empty(nc, np.int64)
    q = 0
    for i in range(L):
        for j in range(i + 1, L):
            I[q] = i
            J[q] = j
            q += 1
    return I, J


@njit(cache=True, nogil=True, error_model="numpy")
def cosine_gauss_newton(c, W, d2, m0, colm, pair_mask, n_iter, tol_m, m_out, iter_out, conv_out, good_out):
    """Gauss–Newton on the weighted cosine residual ``c − c_model(m)``, one epoch at a time.

    c (P, N_C) measured cosines; W (P, N_C, N_C) weight (Σ_c⁺ or identity on the valid
    pairs); d2 (N_C,) surveyed squared distances; m0 (P, L) start ranges; colm (P, L) landmarks
    in the solve; pair_mask (P, N_C) valid pairs (pair slots in ``triu_indices(L, 1)`` order).
    Unused landmarks get an identity pad in the normal matrix and a zero step.

    Writes ``m_out`` (P, L), ``iter_out`` steps taken, ``conv_out`` every step below
    ``tol_m`` and ``good_out`` every normal matrix regular. Epochs with no used landmark
    are left at m0, converged.
    """
    P, nc = c.shape
    L = m0.shape[1]
    I, J = _pair_indices(L)
    A = np.zeros((nc, L))
    r = np.empty(nc)
    Wr = np.empty(nc)
    WA = np.empty((nc, L))
    N = np.empty((L, L))
    g = np.empty((L, 1))
    m = np.empty(L)
    for p in range(P):
        conv = _cosine_start(p, m0, colm, m)
        conv, good, it = _cosine_steps(p, m, conv, 0, n_iter, tol_m, c, W, d2, colm, pair_mask, I, J, A, r, Wr, WA,
                                       N, g)
        m_out[p] = m
        iter_out[p] = it
        conv_out[p] = conv
        good_out[p] = good


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _cosine_start(p, m0, colm, m) -> bool:
    """Epoch ``p``'s start ranges into ``m`` (1 on unused landmarks); True when it has no used landmark."""
    any_used = False
    for l in range(m.shape[0]):
        m[l] = m0[p, l]
        if colm[p, l]:
            any_used = True
        else:
            m[l] = 1.0
    return not any_used


@njit(cache=True, nogil=True, error_model="numpy")
def _cosine_steps(p, m, conv, it, n_iter, tol_m, c, W, d2, colm, pair_mask, I, J, A, r, Wr, WA, N, g):
    """Gauss–Newton steps of epoch ``p`` from ``m`` (updated in place), ``it`` already taken, until every
    step is below ``tol_m``, the normal matrix is singular or ``n_iter`` are taken: (converged, good, steps)."""
    nc = r.shape[0]
    L = m.shape[0]
    good = True
    while not conv and it < n_iter:
        A[:] = 0.0
        for k in range(nc):
            i = I[k]
            j = J[k]
            mi = m[i]
            mj = m[j]
            cm = (mi * mi + mj * mj - d2[k]) / (2.0 * mi * mj)
            A[k, i] = 1.0 / mj - cm / mi
            A[k, j] = 1.0 / mi - cm / mj
            r[k] = c[p, k] - cm if pair_mask[p, k] else 0.0
            if not colm[p, i]:
                A[k, i] = 0.0
            if not colm[p, j]:
                A[k, j] = 0.0
        for k in range(nc):
            s = 0.0
            for k2 in range(nc):
                s += W[p, k, k2] * r[k2]
            Wr[k] = s
        _matmul(W[p], A, WA)
        _matmul(A.T, WA, N)  # AᵀWA
        for a in range(L):
            s = 0.0
            for k in range(nc):
                s += A[k, a] * Wr[k]
            g[a, 0] = s
            if not colm[p, a]:
                N[a, a] += 1.0
        if not _lu_solve(N, g):
            good = False
            break
        it += 1
        small = True
        for l in range(L):
            if colm[p, l]:
                m[l] += g[l, 0]
                if not abs(g[l, 0]) < tol_m:
                    small = False
            if not np.isfinite(m[l]):
                m[l] = 1.0
        conv = small
    return conv, good, it


#: epochs iterated side by side by :func:`cosine_gauss_newton_tiles`
TILE = 64


@njit(cache=True, nogil=True, error_model="numpy")
def cosine_gauss_newton_tiles(c, W, d2, m0, colm, pair_mask, n_iter, tol_m, m_out, iter_out, conv_out, good_out):
    """:func:`cosine_gauss_newton`, epochs ``TILE`` at a time side by side: the same numbers bit for bit.

    Each epoch keeps its own iteration (it stops, as there, when every step is below ``tol_m`` or its
    normal matrix is singular); when an eighth or fewer of a tile still iterate they finish alone
    (:func:`_cosine_steps`).
    """
    P, nc = c.shape
    L = m0.shape[1]
    I, J = _pair_indices(L)
    A1, r1, Wr1, WA1, N1, g1, m1 = (np.zeros((nc, L)), np.empty(nc), np.empty(nc), np.empty((nc, L)),
                                    np.empty((L, L)), np.empty((L, 1)), np.empty(L))
    m, A, r, Wr = np.empty((L, TILE)), np.empty((nc, L, TILE)), np.empty((nc, TILE)), np.empty((nc, TILE))
    Wt, WA, N, g = np.empty((nc, nc, TILE)), np.empty((nc, L, TILE)), np.empty((L, L, TILE)), np.empty((L, TILE))
    ct, cm_, pm, cl = np.empty((nc, TILE)), np.empty(TILE), np.empty((nc, TILE), np.bool_), np.empty((L, TILE), np.bool_)
    conv, good, active, solved = (np.empty(TILE, np.bool_), np.empty(TILE, np.bool_), np.empty(TILE, np.bool_),
                                  np.empty(TILE, np.bool_))
    steps = np.empty(TILE, np.int64)
    for p0 in range(0, P, TILE):
        n = min(TILE, P - p0)
        for q in range(n):  # -- gather
            p = p0 + q
            conv[q] = _cosine_start(p, m0, colm, m1)
            good[q] = True
            active[q] = not conv[q]
            steps[q] = 0
            m[:, q] = m1
            cl[:, q] = colm[p]
            ct[:, q] = c[p]
            pm[:, q] = pair_mask[p]
            Wt[:, :, q] = W[p]
        for it in range(n_iter):
            more = 0
            for q in range(n):
                more += active[q]
            if more == 0:
                break
            if 8 * more <= n:  # a few epochs left: each finishes on its own (the same steps)
                for q in range(n):
                    if active[q]:
                        m1[:] = m[:, q]
                        conv[q], good[q], steps[q] = _cosine_steps(p0 + q, m1, False, steps[q], n_iter, tol_m, c, W, d2,
                                                                   colm, pair_mask, I, J, A1, r1, Wr1, WA1, N1, g1)
                        m[:, q] = m1
                        active[q] = False
                break
            A[:, :, :n] = 0.0
            for k in range(nc):
                i = I[k]
                j = J[k]
                for q in range(n):
                    mi = m[i, q]
                    mj = m[j, q]
                    cm = (mi * mi + mj * mj - d2[k]) / (2.0 * mi * mj)
                    A[k, i, q] = (1.0 / mj - cm / mi) if cl[i, q] else 0.0
                    A[k, j, q] = (1.0 / mi - cm / mj) if cl[j, q] else 0.0
                    r[k, q] = ct[k, q] - cm if pm[k, q] else 0.0
            _tile_matmul(n, Wt, r.reshape((nc, 1, TILE)), Wr.reshape((nc, 1, TILE)), cm_, False)  # _matmul's orders
            _tile_matmul(n, Wt, A, WA, cm_, False)
            _tile_matmul(n, A, WA, N, cm_, True)  # AᵀWA
            _tile_matmul(n, A, Wr.reshape((nc, 1, TILE)), g.reshape((L, 1, TILE)), cm_, True)
            for a in range(L):
                for q in range(n):
                    N[a, a, q] += 0.0 if cl[a, q] else 1.0
            _tile_lu_solve(n, N, g, solved)
            _end_failed_lanes(n, active, solved, good)
            for q in range(n):
                if not active[q]:
                    continue
                steps[q] += 1
                small = True
                for l in range(L):
                    if cl[l, q]:
                        m[l, q] += g[l, q]
                        if not abs(g[l, q]) < tol_m:
                            small = False
                    if not np.isfinite(m[l, q]):
                        m[l, q] = 1.0
                conv[q] = small
                active[q] = not small
        for q in range(n):  # -- scatter
            p = p0 + q
            for l in range(L):
                m_out[p, l] = m[l, q]
            iter_out[p] = steps[q]
            conv_out[p] = conv[q]
            good_out[p] = good[q]


@njit(cache=True, nogil=True, error_model="numpy")
def cosines_and_covariance(uv, used, sigma_px, Kinv, c_out, Sc_out):
    """Pair cosines of the lines of sight and their full covariance from pixel noise.

    uv (P, L, 2) px; used (P, L) landmarks in the solve (others give zero rows);
    sigma_px (P, L); Kinv (3, 3). Writes ``c_out`` (P, N_C), ``c_ij = b_i·b_j`` with
    ``b = normalise(K⁻¹[u, v, 1])``, and ``Sc_out`` (P, N_C, N_C) = ``Jc diag(σ²) Jcᵀ``
    with ``Jc = ∂c/∂pixel`` (pairs in ``triu_indices(L, 1)`` order). The same numbers as
    the numpy oracle in ``tests/vision_oracle.py``: bearings → ``cosines`` → ``cosine_covariance``.
    """
    P, L, _ = uv.shape
    nc = L * (L - 1) // 2
    b = np.empty((L, 3))
    db = np.empty((L, 3, 2))  # ∂b/∂(u, v) = (I − b bᵀ)/‖n‖ K⁻¹[:, :2]
    dci = np.empty((nc, 2))
    dcj = np.empty((nc, 2))
    I, J = _pair_indices(L)
    for p in range(P):
        for l in range(L):
            u = uv[p, l, 0] if used[p, l] else 0.0
            v = uv[p, l, 1] if used[p, l] else 0.0
            n0 = Kinv[0, 0] * u + Kinv[0, 1] * v + Kinv[0, 2]
            n1 = Kinv[1, 0] * u + Kinv[1, 1] * v + Kinv[1, 2]
            n2 = Kinv[2, 0] * u + Kinv[2, 1] * v + Kinv[2, 2]
            nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            b[l, 0] = n0 / nn
            b[l, 1] = n1 / nn
            b[l, 2] = n2 / nn
            for r in range(3):
                for a in range(2):
                    s = 0.0
                    for k in range(3):
                        proj = (1.0 if r == k else 0.0) - b[l, r] * b[l, k]
                        s += proj / nn * Kinv[k, a]
                    db[l, r, a] = s
        for k in range(nc):
            i = I[k]
            j = J[k]
            c_out[p, k] = b[i, 0] * b[j, 0] + b[i, 1] * b[j, 1] + b[i, 2] * b[j, 2]
            for a in range(2):
                dci[k, a] = b[j, 0] * db[i, 0, a] + b[j, 1] * db[i, 1, a] + b[j, 2] * db[i, 2, a]
                dcj[k, a] = b[i, 0] * db[j, 0, a] + b[i, 1] * db[j, 1, a] + b[i, 2] * db[j, 2, a]
        for k in range(nc):
            for k2 in range(nc):
                s = 0.0
                # pixels shared by pairs k and k2 (a landmark in both)
                for x_is_i in range(2):
                    lx = I[k] if x_is_i == 0 else J[k]
                    for y_is_i in range(2):
                        ly = I[k2] if y_is_i == 0 else J[k2]
                        if lx != ly or not used[p, lx]:
                            continue
                        s2 = sigma_px[p, lx] * sigma_px[p, lx]
                        for a in range(2):
                            gx = dci[k, a] if x_is_i == 0 else dcj[k, a]
                            gy = dci[k2, a] if y_is_i == 0 else dcj[k2, a]
                            s += gx * s2 * gy
                Sc_out[p, k, k2] = s


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _cosine_residuals(p, c, d2, pair_mask, Sc, W, I, J, ms, r):
    """Epoch p's cosine residuals at the ranges ``ms`` (written to r (N_C,)): (max |r|/σ_c over the used
    pairs, rᵀWr)."""
    nc = r.shape[0]
    rn = 0.0
    for k in range(nc):
        i, j = I[k], J[k]
        cm = (ms[i] * ms[i] + ms[j] * ms[j] - d2[k]) / (2.0 * ms[i] * ms[j])
        r[k] = c[p, k] - cm if pair_mask[p, k] else 0.0
        if pair_mask[p, k]:
            sc = np.sqrt(Sc[p, k, k])
            v = abs(r[k]) / (sc if sc > 0.0 else 1.0)
            if np.isnan(v) or v > rn:  # NaN propagates, as numpy's max
                rn = v
    rw = 0.0
    for k in range(nc):
        s = 0.0
        for q in range(nc):
            s += W[p, k, q] * r[q]
        rw += r[k] * s
    return rn, rw


@njit(cache=True, nogil=True, error_model="numpy")
def cosine_rule_products(m, c, d2, colm, pair_mask, W, Sc, m_pred, S_pred,
                         A_out, B_out, Ap_out, good_out, cond_out, SigV_out, r_norm_out, r_w_out, gate_out,
                         gok_out):
    """What follows the cosine-rule solve, every epoch (docs/design/integrity.md §7).

    m (P, L) solved ranges, c (P, N_C) measured cosines, d2 (N_C,) surveyed squared
    distances, colm (P, L) landmarks in the solve, pair_mask (P, N_C) pairs in it,
    W (P, N_C, N_C) the cosine weight, Sc (P, N_C, N_C) Σ_c, m_pred (P, L) prior ranges,
    S_pred (P, L, L) their covariance (P = 0 rows: no branch gate). Writes, with
    ``m̄ = m`` on used landmarks and 1 elsewhere:

    * A (N_C, L) of the VA-RAIM paper's eq. 2 at m̄ (oracle: ``tests/vision_oracle.py``; zero outside the
      used pairs × landmarks) and the diagonal B (N_C) (zero on unused pairs);
    * ``A⁺ = (AᵀWA + pad)⁻¹AᵀW`` (L, N_C) with ``good`` False where that matrix is
      non-finite or singular; the condition ``‖A diag(m̄)‖_F ‖diag(m̄)⁻¹A⁺‖_F`` (inf if not finite);
    * ``Σ_V = A⁺ Σ_c A⁺ᵀ``;
    * the cosine residual statistics: max |r|/σ_c over the used pairs and ``rᵀWr``;
    * the branch gate ``dmᵀ(Σ_V + S_pred)⁻¹dm`` over the used landmarks (``gok`` False
      where that matrix is non-finite or singular).
    """
    P, L = m.shape
    nc = c.shape[1]
    gate = S_pred.shape[0] > 0
    I, J = _pair_indices(L)
    ms = np.empty(L)
    AtW = np.empty((L, nc))
    Nm = np.empty((L, L))
    X = np.empty((L, nc))
    tmp = np.empty((L, nc))
    r = np.empty(nc)
    C = np.empty((L, L))
    dm = np.empty((L, 1))
    dmv = np.empty(L)
    for p in range(P):
        for l in range(L):
            ms[l] = m[p, l] if colm[p, l] else 1.0
        A = A_out[p]
        A[:] = 0.0
        for k in range(nc):
            i, j = I[k], J[k]
            pm = 1.0 if pair_mask[p, k] else 0.0
            A[k, i] = (1.0 / ms[j] - c[p, k] / ms[i]) * pm * (1.0 if colm[p, i] else 0.0)
            A[k, j] = (1.0 / ms[i] - c[p, k] / ms[j]) * pm * (1.0 if colm[p, j] else 0.0)
            B_out[p, k] = 1.0 / (2.0 * ms[i] * ms[j]) if pair_mask[p, k] else 0.0
        # A⁺ by the normal equations, an identity pad on unused landmarks
        _matmul(A.T, W[p], AtW)
        _matmul(AtW, A, Nm)
        finite = True
        for l in range(L):
            if not colm[p, l]:
                Nm[l, l] += 1.0
            for j in range(L):
                finite = finite and np.isfinite(Nm[l, j])
        X[:] = AtW
        ok = finite and _lu_solve(Nm, X)
        good_out[p] = ok
        for l in range(L):
            for k in range(nc):
                Ap_out[p, l, k] = X[l, k] if ok else np.nan
        sa = 0.0
        sp = 0.0
        for k in range(nc):
            for l in range(L):
                sa += (A[k, l] * ms[l]) ** 2
                sp += (Ap_out[p, l, k] / ms[l]) ** 2
        cond = np.sqrt(sa) * np.sqrt(sp)
        cond_out[p] = cond if np.isfinite(cond) else np.inf
        _sandwich(Ap_out[p], Sc[p], SigV_out[p], tmp, False)
        r_norm_out[p], r_w_out[p] = _cosine_residuals(p, c, d2, pair_mask, Sc, W, I, J, ms, r)
        if not gate:
            continue
        finite = True
        for l in range(L):
            dmv[l] = m[p, l] - m_pred[p, l] if colm[p, l] else 0.0
            dm[l, 0] = dmv[l]
            for j in range(L):
                v = SigV_out[p, l, j] + S_pred[p, l, j] if colm[p, l] and colm[p, j] else 0.0
                C[l, j] = v + (1.0 if l == j and not colm[p, l] else 0.0)
                finite = finite and np.isfinite(C[l, j])
        ok = finite and _lu_solve(C, dm)
        gok_out[p] = ok
        g = 0.0
        for l in range(L):
            g += dmv[l] * dm[l, 0]
        gate_out[p] = g if ok else np.nan


@njit(cache=True, nogil=True, error_model="numpy")
def cosine_rule_products_tiles(m, c, d2, colm, pair_mask, W, Sc, m_pred, S_pred,
                               A_out, B_out, Ap_out, good_out, cond_out, SigV_out, r_norm_out, r_w_out, gate_out,
                               gok_out):
    """:func:`cosine_rule_products`, epochs ``TILE`` at a time side by side: the same numbers bit for bit
    (each epoch's operations in that kernel's order, its LU solves by :func:`_tile_lu_solve`)."""
    P, L = m.shape
    nc = c.shape[1]
    gate = S_pred.shape[0] > 0
    I, J = _pair_indices(L)
    ms, A, Wt = np.empty((L, TILE)), np.empty((nc, L, TILE)), np.empty((nc, nc, TILE))
    AtW, Nm, X = np.empty((L, nc, TILE)), np.empty((L, L, TILE)), np.empty((L, nc, TILE))
    Sct, SV, tmp = np.empty((nc, nc, TILE)), np.empty((L, L, TILE)), np.empty((L, nc, TILE))
    r, Cg, dm = np.empty((nc, TILE)), np.empty((L, L, TILE)), np.empty((L, TILE))
    dmv, acc, Nw, xk = np.empty((L, TILE)), np.empty(TILE), np.empty((L, L, TILE)), np.empty((L, TILE))
    okk = np.empty(TILE, np.bool_)
    finite, solved, sa, sp = np.empty(TILE, np.bool_), np.empty(TILE, np.bool_), np.empty(TILE), np.empty(TILE)
    for p0 in range(0, P, TILE):
        n = min(TILE, P - p0)
        for l in range(L):
            for q in range(n):
                ms[l, q] = m[p0 + q, l] if colm[p0 + q, l] else 1.0
        for k in range(nc):
            i, j = I[k], J[k]
            for l in range(L):
                for q in range(n):
                    A[k, l, q] = 0.0
            for q in range(n):
                p = p0 + q
                pm = 1.0 if pair_mask[p, k] else 0.0
                A[k, i, q] = (1.0 / ms[j, q] - c[p, k] / ms[i, q]) * pm * (1.0 if colm[p, i] else 0.0)
                A[k, j, q] = (1.0 / ms[i, q] - c[p, k] / ms[j, q]) * pm * (1.0 if colm[p, j] else 0.0)
                B_out[p, k] = 1.0 / (2.0 * ms[i, q] * ms[j, q]) if pair_mask[p, k] else 0.0
            for k2 in range(nc):
                for q in range(n):
                    Wt[k, k2, q] = W[p0 + q, k, k2]
                    Sct[k, k2, q] = Sc[p0 + q, k, k2]
        for k in range(nc):
            for l in range(L):
                for q in range(n):
                    A_out[p0 + q, k, l] = A[k, l, q]
        # A⁺ by the normal equations, an identity pad on unused landmarks
        _tile_matmul(n, A, Wt, AtW, acc, True)
        _tile_matmul(n, AtW, A, Nm, acc, False)
        for q in range(n):
            finite[q] = True
        for l in range(L):
            for q in range(n):
                if not colm[p0 + q, l]:
                    Nm[l, l, q] += 1.0
            for j in range(L):
                for q in range(n):
                    finite[q] = finite[q] and np.isfinite(Nm[l, j, q])
        # column by column on a fresh copy of the normal matrix: each column gets _lu_solve's operations
        for q in range(n):
            solved[q] = finite[q]
        for k in range(nc):
            Nw[:] = Nm
            for l in range(L):
                for q in range(n):
                    xk[l, q] = AtW[l, k, q]
            _tile_lu_solve(n, Nw, xk, okk)
            for l in range(L):
                for q in range(n):
                    X[l, k, q] = xk[l, q]
            for q in range(n):
                solved[q] = solved[q] and okk[q]
        for q in range(n):
            good_out[p0 + q] = solved[q]
            sa[q] = 0.0
            sp[q] = 0.0
        for l in range(L):
            for k in range(nc):
                for q in range(n):
                    X[l, k, q] = X[l, k, q] if solved[q] else np.nan
                    Ap_out[p0 + q, l, k] = X[l, k, q]
        for k in range(nc):
            for l in range(L):
                for q in range(n):
                    sa[q] += (A[k, l, q] * ms[l, q]) ** 2
                    sp[q] += (X[l, k, q] / ms[l, q]) ** 2
        for q in range(n):
            cond = np.sqrt(sa[q]) * np.sqrt(sp[q])
            cond_out[p0 + q] = cond if np.isfinite(cond) else np.inf
        _tile_sandwich(n, X, Sct, SV, tmp, acc, False)
        for l in range(L):
            for j in range(L):
                for q in range(n):
                    SigV_out[p0 + q, l, j] = SV[l, j, q]
        for q in range(n):
            r_norm_out[p0 + q], r_w_out[p0 + q] = _cosine_residuals(p0 + q, c, d2, pair_mask, Sc, W, I, J, ms[:, q],
                                                                    r[:, q])
        if not gate:
            continue
        for q in range(n):
            finite[q] = True
        for l in range(L):
            for q in range(n):
                p = p0 + q
                dmv[l, q] = m[p, l] - m_pred[p, l] if colm[p, l] else 0.0
                dm[l, q] = dmv[l, q]
            for j in range(L):
                for q in range(n):
                    p = p0 + q
                    v = SV[l, j, q] + S_pred[p, l, j] if colm[p, l] and colm[p, j] else 0.0
                    Cg[l, j, q] = v + (1.0 if l == j and not colm[p, l] else 0.0)
                    finite[q] = finite[q] and np.isfinite(Cg[l, j, q])
        _tile_lu_solve(n, Cg, dm, solved)
        for q in range(n):
            ok = finite[q] and solved[q]
            gok_out[p0 + q] = ok
            g = 0.0
            for l in range(L):
                g += dmv[l, q] * dm[l, q]
            gate_out[p0 + q] = g if ok else np.nan


@njit(cache=True, nogil=True, error_model="numpy")
def vision_rows(A, z, Sigma, used, pair_mask, modified, Tm_out, zr_out, W_out, mask_out):
    """The vision block of the integrated solve, every epoch (va_raim module doc).

    A (P, N_C, L) cosine-rule matrix, z (P, L) vision ranges with covariance Sigma (P, L, L),
    used (P, L) landmarks whose ranges enter, pair_mask (P, N_C) pairs of used landmarks,
    modified (P,) epochs that take the modified single-fault equation (rows ``A z``, one per
    pair) instead of the ranges themselves (rows ``z``, the first L of the N_C slots).
    Non-finite ranges/covariances of unused landmarks count as zero. Writes the transform
    Tm (N_C, L), the rows ``Tm z``, their weight ``(Tm Σ Tmᵀ)⁻¹`` on the used rows (zero
    elsewhere) and the row mask (all False where that covariance is non-finite or singular).
    """
    P, nc, L = A.shape
    z0 = np.empty(L)
    S0 = np.empty((L, L))
    tmp = np.empty((nc, L))
    Sp = np.empty((nc, nc))
    X = np.empty((nc, nc))
    for p in range(P):
        Tm = Tm_out[p]
        mask = mask_out[p]
        for k in range(nc):
            for l in range(L):
                Tm[k, l] = A[p, k, l] if modified[p] else (1.0 if k == l else 0.0)
            if modified[p]:
                mask[k] = pair_mask[p, k]
            else:
                mask[k] = k < L and used[p, k]
        for l in range(L):
            v = z[p, l] if used[p, l] else 0.0
            z0[l] = v if np.isfinite(v) else 0.0
            for j in range(L):
                v = Sigma[p, l, j] if used[p, l] and used[p, j] else 0.0
                S0[l, j] = v if np.isfinite(v) else 0.0
        for k in range(nc):
            s = 0.0
            for l in range(L):
                s += Tm[k, l] * z0[l]
            zr_out[p, k] = s
        _sandwich(Tm, S0, Sp, tmp, False)
        finite = True
        for k in range(nc):
            for q in range(nc):
                Sp[k, q] = Sp[k, q] if mask[k] and mask[q] else (1.0 if k == q and not mask[k] else 0.0)
                finite = finite and np.isfinite(Sp[k, q])
                X[k, q] = 1.0 if k == q else 0.0
        good = finite and _lu_solve(Sp, X)
        for k in range(nc):
            mask[k] = mask[k] and good
            for q in range(nc):
                W_out[p, k, q] = X[k, q] if good and mask[k] and mask[q] else 0.0
            if not mask[k]:
                zr_out[p, k] = np.nan


@njit(cache=True, nogil=True, error_model="numpy")
def vision_prior(x_g, P_g, fix, t, p, off, speed, floor, li_out, m_out, S_out):
    """The prior of the vision solve: this epoch's GPS fix, else the latest one carried forward.

    Per trial (Bt, T): x_g (.., 4) GPS solution, P_g (.., 3, 3) its position covariance,
    fix (..) both finite; t (T,) s; p (L, 3) landmarks; off (.., 3) this epoch's camera
    offset. Writes
    the epoch the prior comes from (``li``, −1 if none yet), the predicted ranges m_pred
    (L) from it (NaN without a prior) and their covariance ``H (P_g + q I) Hᵀ`` with the
    growth ``q = (speed·Δt)² + floor²`` for the prior's age Δt.
    """
    Bt, T = fix.shape
    L = p.shape[0]
    H = np.empty((L, 3))
    HP = np.empty((L, 3))
    Pp = np.empty((3, 3))
    for b in range(Bt):
        last = -1
        for k in range(T):
            if fix[b, k]:
                last = k
            li_out[b, k] = last
            i = last if last >= 0 else 0
            q = (speed * (t[k] - t[i])) ** 2 + floor * floor
            for r in range(3):
                for c in range(3):
                    Pp[r, c] = (P_g[b, i, r, c] if last >= 0 else 0.0) + (q if r == c else 0.0)
            for l in range(L):
                x0 = x_g[b, i, 0] if last >= 0 else 0.0
                x1 = x_g[b, i, 1] if last >= 0 else 0.0
                x2 = x_g[b, i, 2] if last >= 0 else 0.0
                d0, d1, d2, rng = _offset_range(p[l, 0], p[l, 1], p[l, 2], x0 + off[b, k, 0], x1 + off[b, k, 1],
                                                x2 + off[b, k, 2])
                m_out[b, k, l] = rng if last >= 0 else np.nan
                H[l, 0] = -d0 / rng
                H[l, 1] = -d1 / rng
                H[l, 2] = -d2 / rng
            _sandwich(H, Pp, S_out[b, k], HP, False)


# numba compiles a kernel again when its own file changes, not when a helper's does
keep_in_step(sys.modules[__name__])
