"""Compiled per-epoch Gauss–Newton loops (numba).

The monitors are batched numpy code, except for the two iterative solves: run
as whole-batch numpy they cost one stacked LAPACK call and a dozen temporaries
per iteration, and every epoch iterates until the slowest one has converged.
Here each epoch iterates on its own, in registers, until *its* step is below
the tolerance — so an epoch's answer no longer depends on what else is in the
batch (the per-epoch reference implementations stop the same way).

The kernels release the GIL, so callers may run chunks of a batch on threads.
They use numpy's floating-point error model: a division by zero gives inf/NaN
(and then an "unavailable" reason downstream), never an exception.
Compiled code is cached beside this file (numba's ``cache=True``); the first
call after an install compiles it (a few seconds).
"""

from __future__ import annotations

import numpy as np
from numba import njit


def kernel_input(a, shape: tuple, out_shape: tuple | None = None, dtype=np.float64) -> np.ndarray:
    """``a`` broadcast to ``shape`` (then reshaped to ``out_shape``), C-contiguous and read-only.

    numba compiles one specialisation per argument layout *and* writability, so every
    kernel input goes through here: one compiled version per kernel, whatever the caller's
    arrays are (fresh, broadcast views, read-only slices). Copies only when it must.
    """
    x = np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype), shape))
    if out_shape is not None:
        x = x.reshape(out_shape)
    v = x.view()
    v.flags.writeable = False
    return v


@njit(cache=True, nogil=True, error_model="numpy")
def _lu_solve(A, B) -> bool:
    """Solve ``A X = B`` in place (A (n, n) and B (n, k) overwritten, X left in B).

    LU with partial pivoting. Returns False for an exactly zero (or NaN) pivot or a
    non-finite answer: where LAPACK's solve would raise or return inf/NaN.
    """
    n = A.shape[0]
    k = B.shape[1]
    for j in range(n):
        piv = j
        big = abs(A[j, j])
        for i in range(j + 1, n):
            if abs(A[i, j]) > big:
                big = abs(A[i, j])
                piv = i
        if not big > 0.0:  # also catches NaN
            return False
        if piv != j:
            for q in range(n):
                A[j, q], A[piv, q] = A[piv, q], A[j, q]
            for c in range(k):
                B[j, c], B[piv, c] = B[piv, c], B[j, c]
        for i in range(j + 1, n):
            f = A[i, j] / A[j, j]
            if f != 0.0:
                for q in range(j + 1, n):
                    A[i, q] -= f * A[j, q]
                for c in range(k):
                    B[i, c] -= f * B[j, c]
    for c in range(k):
        for i in range(n - 1, -1, -1):
            s = B[i, c]
            for q in range(i + 1, n):
                s -= A[i, q] * B[q, c]
            s = s / A[i, i]
            if not np.isfinite(s):
                return False
            B[i, c] = s
    return True


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
        m[:] = m0[p]
        any_used = False
        for l in range(L):
            if colm[p, l]:
                any_used = True
            else:
                m[l] = 1.0
        conv = not any_used
        good = True
        it = 0
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
                for l in range(L):
                    s = 0.0
                    for k2 in range(nc):
                        s += W[p, k, k2] * A[k2, l]
                    WA[k, l] = s
            for a in range(L):
                s = 0.0
                for k in range(nc):
                    s += A[k, a] * Wr[k]
                g[a, 0] = s
                for b in range(L):
                    s = 0.0
                    for k in range(nc):
                        s += A[k, a] * WA[k, b]
                    N[a, b] = s
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
        m_out[p] = m
        iter_out[p] = it
        conv_out[p] = conv
        good_out[p] = good


@njit(cache=True, nogil=True, error_model="numpy")
def _laguerre4(lam, k1, k2, k3, det):
    """A root of ``λ⁴ − k1λ³ + k2λ² − k3λ + det`` by Laguerre's method from ``lam``
    (real-rooted: converges monotonically to the nearest root outside the root interval).
    Returns (root, converged)."""
    for _ in range(10):
        p = (((lam - k1) * lam + k2) * lam - k3) * lam + det
        if p == 0.0:
            return lam, True
        dp = ((4.0 * lam - 3.0 * k1) * lam + 2.0 * k2) * lam - k3
        d2p = (12.0 * lam - 6.0 * k1) * lam + 2.0 * k2
        G = dp / p
        H = G * G - d2p / p
        sq = np.sqrt(max(3.0 * (4.0 * H - G * G), 0.0))
        den = G - sq if G < 0 else G + sq
        step = 4.0 / den
        lam = lam - step
        if not abs(step) > 1e-13 * abs(lam):
            return lam, np.isfinite(lam)
    return lam, False


@njit(cache=True, nogil=True, error_model="numpy")
def _pos_def_shifted(S, sign, shift, b):
    """All LDLᵀ pivots of ``sign·(S − shift·I)`` (4×4) positive (b: 4×4 scratch)."""
    for i in range(4):
        for j in range(4):
            b[i, j] = sign * (S[i, j] - shift) if i == j else sign * S[i, j]
    for j in range(4):
        s = b[j, j]
        for q in range(j):
            s -= b[j, q] * b[j, q] * b[q, q]
        if not s > 0.0:
            return False
        b[j, j] = s
        for i in range(j + 1, 4):
            t = b[i, j]
            for q in range(j):
                t -= b[i, q] * b[j, q] * b[q, q]
            b[i, j] = t / s
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def _cond4(S, scratch):
    """``λ_max/λ_min`` of a symmetric 4×4 matrix, or NaN where not certified.

    The extreme roots of the characteristic polynomial (coefficients from the principal
    minors) by Laguerre from 0 and from the trace, accepted only when shifted LDLᵀ
    factorisations prove no eigenvalue lies outside them and the matrix is positive
    definite (same method as ``lsq._scaled_cond``); the caller recomputes NaN elements
    with LAPACK.
    """
    a00, a01, a02, a03 = S[0, 0], S[0, 1], S[0, 2], S[0, 3]
    a11, a12, a13 = S[1, 1], S[1, 2], S[1, 3]
    a22, a23, a33 = S[2, 2], S[2, 3], S[3, 3]
    s0 = a00 * a11 - a01 * a01
    s1 = a00 * a12 - a02 * a01
    s2 = a00 * a13 - a03 * a01
    s3 = a01 * a12 - a02 * a11
    s4 = a01 * a13 - a03 * a11
    s5 = a02 * a13 - a03 * a12
    c5 = a22 * a33 - a23 * a23
    c4 = a12 * a33 - a13 * a23
    c3 = a12 * a23 - a13 * a22
    c2 = a02 * a33 - a03 * a23
    c1 = a02 * a23 - a03 * a22
    c0 = a02 * a13 - a03 * a12
    det = s0 * c5 - s1 * c4 + s2 * c3 + s3 * c2 - s4 * c1 + s5 * c0
    k1 = a00 + a11 + a22 + a33
    k2 = (s0 + a00 * a22 - a02 * a02 + a00 * a33 - a03 * a03 + a11 * a22 - a12 * a12
          + a11 * a33 - a13 * a13 + c5)
    k3 = (_m3(a00, a01, a02, a11, a12, a22) + _m3(a00, a01, a03, a11, a13, a33)
          + _m3(a00, a02, a03, a22, a23, a33) + _m3(a11, a12, a13, a22, a23, a33))
    lo, ok_lo = _laguerre4(0.0, k1, k2, k3, det)
    hi, ok_hi = _laguerre4(k1, k1, k2, k3, det)
    if not (ok_lo and ok_hi and lo > 0.0 and det > 0.0):
        return np.nan
    if not (_pos_def_shifted(S, 1.0, lo * (1.0 - 1e-6), scratch)
            and _pos_def_shifted(S, -1.0, hi * (1.0 + 1e-6), scratch)):
        return np.nan
    return hi / lo


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _m3(p, q, r, s_, t, u):
    """det of [[p, q, r], [q, s_, t], [r, t, u]]."""
    return p * (s_ * u - t * t) - q * (q * u - t * r) + r * (q * t - s_ * r)


@njit(cache=True, nogil=True, error_model="numpy")
def normal_geometry(G0, WG, Wd, pivot_rtol, M_out, cond_out, J_out, A_out, ws_out, ok_out):
    """The weighted-LS matrices of every epoch (n states, all estimated).

    G0, WG (P, N, n) masked observation matrix and ``W G``; Wd (P, N) the diagonal of W.
    Writes ``M = GᵀWG``, the condition number of the Jacobi-scaled M (``λ_max/λ_min``,
    :func:`_cond4`; inf if a diagonal is zero, NaN where the caller must use LAPACK),
    ``J = M⁻¹`` by LDLᵀ, ``A = J (WG)ᵀ`` and ``(WS)_ii = W_ii − Σ_k (WG)_ik A_ki``.
    ``ok_out`` is False where a pivot ``d_j ≤ pivot_rtol·M_jj`` (J not trusted there).
    """
    P, N, n = G0.shape
    S = np.empty((n, n))
    scratch = np.empty((4, 4))
    Lm = np.zeros((n, n))
    d = np.empty(n)
    y = np.empty(n)
    for p in range(P):
        cond_out[p], ok_out[p] = _normal_element(G0[p], WG[p], Wd[p], pivot_rtol, M_out[p], S, scratch, Lm, d, y,
                                                 J_out[p], A_out[p], ws_out[p])


@njit(cache=True, nogil=True, error_model="numpy")
def _normal_element(G0, WG, Wd, pivot_rtol, M, S, scratch, Lm, d, y, J, A, ws):
    """:func:`normal_geometry` of one epoch: G0, WG (N, n), Wd (N,) in; M, J (n, n), A (n, N),
    ws (N,) out (J, A, ws NaN where J is not trusted); S, scratch, Lm (n, n), d, y (n,) scratch.
    Returns (cond, J trusted)."""
    N, n = G0.shape
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(N):
                s += G0[k, i] * WG[k, j]
            M[i, j] = s
    # condition of the Jacobi-scaled (symmetrised) matrix
    zero_diag = False
    for i in range(n):
        d[i] = np.sqrt(abs(M[i, i]))
        if not d[i] > 0.0:
            zero_diag = True
    if zero_diag:
        cond = np.inf
    else:
        for i in range(n):
            for j in range(n):
                v = 0.5 * (M[i, j] + M[j, i]) / (d[i] * d[j])
                S[i, j] = v if np.isfinite(v) else 0.0
        cond = _cond4(S, scratch) if n == 4 else np.nan
    # J = M⁻¹ by LDLᵀ (M symmetric positive definite when well posed)
    for j in range(n):
        s = M[j, j]
        for q in range(j):
            s -= Lm[j, q] * Lm[j, q] * d[q]
        if not (s > pivot_rtol * M[j, j] and np.isfinite(s)):
            J[:] = np.nan
            A[:] = np.nan
            ws[:] = np.nan
            return cond, False
        d[j] = s
        for i in range(j + 1, n):
            s = M[i, j]
            for q in range(j):
                s -= Lm[i, q] * Lm[j, q] * d[q]
            Lm[i, j] = s / d[j]
    for c in range(n):  # column c of J: L D Lᵀ x = e_c
        for i in range(n):
            s = 1.0 if i == c else 0.0
            for q in range(i):
                s -= Lm[i, q] * y[q]
            y[i] = s
        for i in range(n - 1, -1, -1):
            s = y[i] / d[i]
            for q in range(i + 1, n):
                s -= Lm[q, i] * J[q, c]
            J[i, c] = s
    for i in range(n):
        for k in range(N):
            s = 0.0
            for j in range(n):
                s += J[i, j] * WG[k, j]
            A[i, k] = s
    for k in range(N):
        s = 0.0
        for i in range(n):
            s += WG[k, i] * A[i, k]
        ws[k] = Wd[k] - s
    return cond, True


@njit(cache=True, nogil=True, error_model="numpy")
def fit_at_solution(G, h, z, wd, Wb, mask, pivot_rtol, fast_cond, ws_rtol,
                    J_out, ws_out, cond_out, r_out, sse_out, hs_out, vs_out, hmax_out, vmax_out,
                    n_used_out, fast_out):
    """Geometry, residuals, SSE and slopes at the solution of an iterated solve, every epoch.

    Rows (P, N): G (P, N, 4) partials, h predictions, z measurements, mask rows used. The
    weight is block-diagonal, ``W = blockdiag(diag(wd), Wb)``: the first n1 = wd.shape[1]
    rows uncorrelated, the last R = N − n1 rows with the dense block Wb (P, R, R).

    For a *clean* epoch — every used row finite, a clock row, J trusted (pivots as
    :func:`normal_geometry`), the condition number certified and ≤ ``fast_cond``, and
    ``(WS)_ii > ws_rtol·W_ii`` on every used row — writes J (4, 4), (WS)_ii (NaN on unused
    rows), cond, residuals ``z − h`` (0 on unused rows), ``SSE = rᵀWr``, slopes
    ``hypot(A₁ᵢ, A₂ᵢ)/sqrt((WS)ᵢᵢ)`` and ``|A₃ᵢ|/sqrt((WS)ᵢᵢ)`` (NaN on unused rows) with their
    maxima, and sets ``fast_out``. Every other epoch gets ``fast_out`` False and unspecified
    outputs (except ``n_used_out``): the caller takes it through the numpy path, which
    decides its reason.
    """
    P, N, n = G.shape
    n1 = wd.shape[1]
    R = N - n1
    G0 = np.empty((N, n))
    WG = np.empty((N, n))
    Wd = np.empty(N)
    M = np.empty((n, n))
    S = np.empty((n, n))
    scratch = np.empty((4, 4))
    Lm = np.zeros((n, n))
    d = np.empty(n)
    y = np.empty(n)
    A = np.empty((n, N))
    for p in range(P):
        clean = True
        clock = False
        nu = 0
        for k in range(N):
            if mask[p, k]:
                nu += 1
                rk = z[p, k] - h[p, k]
                clean = clean and np.isfinite(rk)
                r_out[p, k] = rk
                for c in range(n):
                    G0[k, c] = G[p, k, c]
                    clean = clean and np.isfinite(G0[k, c])
                clock = clock or G0[k, 3] != 0.0
            else:
                r_out[p, k] = 0.0
                G0[k, :] = 0.0
        n_used_out[p] = nu
        for k in range(n1):
            w = wd[p, k] if mask[p, k] else 0.0
            clean = clean and np.isfinite(w)
            Wd[k] = w
            for c in range(n):
                WG[k, c] = w * G0[k, c]
        for r in range(R):
            k = n1 + r
            Wd[k] = 0.0
            WG[k, :] = 0.0
            if not mask[p, k]:
                continue
            for s in range(R):
                if not mask[p, n1 + s]:
                    continue
                w = Wb[p, r, s]
                clean = clean and np.isfinite(w)
                if s == r:
                    Wd[k] = w
                for c in range(n):
                    WG[k, c] += w * G0[n1 + s, c]
        fast_out[p] = False
        if not (clean and clock):
            continue
        cond, ok = _normal_element(G0, WG, Wd, pivot_rtol, M, S, scratch, Lm, d, y, J_out[p], A, ws_out[p])
        cond_out[p] = cond
        if not (ok and cond <= fast_cond):
            continue
        fast = True
        for k in range(N):
            if mask[p, k]:
                fast = fast and ws_out[p, k] > ws_rtol * abs(Wd[k])
            else:
                ws_out[p, k] = np.nan
        if not fast:
            continue
        fast_out[p] = True
        sse = 0.0
        for k in range(n1):
            sse += Wd[k] * r_out[p, k] * r_out[p, k]
        sv = 0.0
        for r in range(R):
            if not mask[p, n1 + r]:
                continue
            t = 0.0
            for s in range(R):
                if mask[p, n1 + s]:
                    t += Wb[p, r, s] * r_out[p, n1 + s]
            sv += t * r_out[p, n1 + r]
        sse_out[p] = sse + sv
        hmax = -np.inf
        vmax = -np.inf
        for k in range(N):
            if not mask[p, k]:
                hs_out[p, k] = np.nan
                vs_out[p, k] = np.nan
                continue
            den = np.sqrt(ws_out[p, k])
            hs = np.hypot(A[0, k], A[1, k]) / den
            vs = abs(A[2, k]) / den
            hs_out[p, k] = hs
            vs_out[p, k] = vs
            hmax = max(hmax, hs)
            vmax = max(vmax, vs)
        hmax_out[p] = hmax
        vmax_out[p] = vmax


@njit(cache=True, nogil=True, error_model="numpy")
def cosines_and_covariance(uv, used, sigma_px, Kinv, c_out, Sc_out):
    """Pair cosines of the lines of sight and their full covariance from pixel noise.

    uv (P, L, 2) px; used (P, L) landmarks in the solve (others give zero rows);
    sigma_px (P, L); Kinv (3, 3). Writes ``c_out`` (P, N_C), ``c_ij = b_i·b_j`` with
    ``b = normalise(K⁻¹[u, v, 1])``, and ``Sc_out`` (P, N_C, N_C) = ``Jc diag(σ²) Jcᵀ``
    with ``Jc = ∂c/∂pixel`` (pairs in ``triu_indices(L, 1)`` order). The same numbers as
    ``vision_ranges.bearings_from_pixels`` → ``cosines`` → ``cosine_covariance``.
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


@njit(cache=True, nogil=True, error_model="numpy")
def cosine_rule_products(m, c, d2, colm, pair_mask, W, Sc, m_pred, S_pred,
                         A_out, B_out, Ap_out, good_out, cond_out, SigV_out, r_norm_out, r_w_out, gate_out,
                         gok_out):
    """What follows the cosine-rule solve, every epoch (INTEGRITY_MATH.md §2).

    m (P, L) solved ranges, c (P, N_C) measured cosines, d2 (N_C,) surveyed squared
    distances, colm (P, L) landmarks in the solve, pair_mask (P, N_C) pairs in it,
    W (P, N_C, N_C) the cosine weight, Sc (P, N_C, N_C) Σ_c, m_pred (P, L) prior ranges,
    S_pred (P, L, L) their covariance (P = 0 rows: no branch gate). Writes, with
    ``m̄ = m`` on used landmarks and 1 elsewhere:

    * A (N_C, L) of :func:`vision_ranges.cosine_rule_jacobians` at m̄ (zero outside the
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
        for l in range(L):
            for k in range(nc):
                s = 0.0
                for q in range(nc):
                    s += A[q, l] * W[p, q, k]
                AtW[l, k] = s
        finite = True
        for l in range(L):
            for j in range(L):
                s = 0.0
                for k in range(nc):
                    s += AtW[l, k] * A[k, j]
                if l == j and not colm[p, l]:
                    s += 1.0
                Nm[l, j] = s
                finite = finite and np.isfinite(s)
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
        _matmul(Ap_out[p], Sc[p], tmp)
        for l in range(L):
            for j in range(L):
                s = 0.0
                for k in range(nc):
                    s += tmp[l, k] * Ap_out[p, j, k]
                SigV_out[p, l, j] = s
        # cosine residuals at the solution
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
        r_norm_out[p] = rn
        rw = 0.0
        for k in range(nc):
            s = 0.0
            for q in range(nc):
                s += W[p, k, q] * r[q]
            rw += r[k] * s
        r_w_out[p] = rw
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
        _matmul(Tm, S0, tmp)
        finite = True
        for k in range(nc):
            for q in range(nc):
                s = 0.0
                for l in range(L):
                    s += tmp[k, l] * Tm[q, l]
                Sp[k, q] = s if mask[k] and mask[q] else (1.0 if k == q and not mask[k] else 0.0)
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
                d0 = p[l, 0] - (x0 + off[b, k, 0])
                d1 = p[l, 1] - (x1 + off[b, k, 1])
                d2 = p[l, 2] - (x2 + off[b, k, 2])
                rng = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                m_out[b, k, l] = rng if last >= 0 else np.nan
                H[l, 0] = -d0 / rng
                H[l, 1] = -d1 / rng
                H[l, 2] = -d2 / rng
            _matmul(H, Pp, HP)
            for l in range(L):
                for j in range(L):
                    S_out[b, k, l, j] = HP[l, 0] * H[j, 0] + HP[l, 1] * H[j, 1] + HP[l, 2] * H[j, 2]


@njit(cache=True, nogil=True, error_model="numpy")
def calibrate_epochs(i0, m, A, B, Ap, Sc, SigV, used, x, Pg, off, p, Sd,
                     beta_out, beta0_out, Sh_out, Su_out):
    """GPS calibration of the vision ranges (INTEGRITY_MATH.md §3), every epoch of every trial.

    Shapes (trial, epoch, ...): i0 (Bt, T) calibration epoch of each epoch (any valid index
    where uncalibrated; the caller masks); vision solve m (L), A (N_C, L), B (N_C), A⁺ (L, N_C),
    Σ_c (N_C, N_C), Σ_V (L, L), used (L); GPS fix x (3), its covariance Pg (3, 3), camera
    offset off (3); p (L, 3) surveyed landmarks; Sd (N_C, N_C) survey covariance of d².

    Writes β(k) = M A0 β(0) with M = A⁺(k) B(k) B(0)⁻¹, β(0) = m(0) − r(x̃(0)),
    Σ̂_V = Σ_V + M P0 Σc0 P0ᵀMᵀ + (M A0 H0) P_G (M A0 H0)ᵀ + Ld Sd Ldᵀ (P0 = A0 A0⁺,
    Ld = A⁺B − M P0 B0), and the uncalibrated Σ_V + A⁺B Sd BA⁺ᵀ — the products of
    ``calibration.calibrate`` per epoch.
    """
    Bt, T, L = m.shape
    nc = B.shape[2]
    r0 = np.empty(L)
    H0 = np.empty((L, 3))
    ratio = np.empty(nc)
    M = np.empty((L, nc))
    MA0 = np.empty((L, L))
    P0 = np.empty((nc, nc))
    MP0 = np.empty((L, nc))
    MAH = np.empty((L, 3))
    Ld = np.empty((L, nc))
    AB = np.empty((L, nc))
    tmp = np.empty((L, nc))
    tmp3 = np.empty((L, 3))
    for b in range(Bt):
        for t in range(T):
            k = i0[b, t]
            for l in range(L):
                d0 = p[l, 0] - (x[b, k, 0] + off[b, k, 0])
                d1 = p[l, 1] - (x[b, k, 1] + off[b, k, 1])
                d2 = p[l, 2] - (x[b, k, 2] + off[b, k, 2])
                r0[l] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                u = 1.0 if used[b, k, l] else 0.0
                H0[l, 0] = -d0 / r0[l] * u
                H0[l, 1] = -d1 / r0[l] * u
                H0[l, 2] = -d2 / r0[l] * u
                be = m[b, k, l] - r0[l] if used[b, k, l] else 0.0
                beta0_out[b, t, l] = be if np.isfinite(be) else 0.0
            for q in range(nc):
                v = B[b, t, q] / B[b, k, q] if B[b, k, q] != 0.0 else 0.0
                ratio[q] = v if np.isfinite(v) else 0.0
            for l in range(L):
                for q in range(nc):
                    M[l, q] = Ap[b, t, l, q] * ratio[q]
                    AB[l, q] = Ap[b, t, l, q] * B[b, t, q]
            _matmul(M, A[b, k], MA0)
            for l in range(L):
                s = 0.0
                for j in range(L):
                    s += MA0[l, j] * beta0_out[b, t, j]
                beta_out[b, t, l] = s
            _matmul(A[b, k], Ap[b, k], P0)
            _matmul(M, P0, MP0)
            _matmul(MA0, H0, MAH)
            for l in range(L):
                for q in range(nc):
                    Ld[l, q] = AB[l, q] - MP0[l, q] * B[b, k, q]
            # Σ̂_V = Σ_V + MP0 Σc0 MP0ᵀ + MAH Pg MAHᵀ + Ld Sd Ldᵀ;  Σ_unc = Σ_V + AB Sd ABᵀ
            for l in range(L):
                for j in range(L):
                    Sh_out[b, t, l, j] = SigV[b, t, l, j]
                    Su_out[b, t, l, j] = SigV[b, t, l, j]
            _add_sandwich(MP0, Sc[b, k], Sh_out[b, t], tmp)
            _add_sandwich(Ld, Sd, Sh_out[b, t], tmp)
            _add_sandwich(AB, Sd, Su_out[b, t], tmp)
            _add_sandwich(MAH, Pg[b, k], Sh_out[b, t], tmp3)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _add_sandwich(X, C, out, tmp):
    """out += X C Xᵀ (X (L, n), C (n, n); tmp (L, n) scratch)."""
    L, n = X.shape
    _matmul(X, C, tmp)
    for l in range(L):
        for j in range(L):
            s = 0.0
            for q in range(n):
                s += tmp[l, q] * X[j, q]
            out[l, j] += s


@njit(cache=True, nogil=True, error_model="numpy")
def cond4_batch(S, out):
    """:func:`_cond4` of every symmetric 4×4 matrix S[p] (NaN: not certified, use LAPACK)."""
    scratch = np.empty((4, 4))
    for p in range(S.shape[0]):
        out[p] = _cond4(S[p], scratch)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _matmul(X, Y, out):
    """out = X @ Y for small matrices (no allocation)."""
    n, k = X.shape
    m = Y.shape[1]
    for i in range(n):
        for j in range(m):
            s = 0.0
            for q in range(k):
                s += X[i, q] * Y[q, j]
            out[i, j] = s


def compile_all() -> None:
    """Compile (or load from numba's cache) every kernel for the argument types the monitors use.

    Call it during set-up so the first epochs of a run are not charged with compilation
    (~15 s after an install, well under a second once cached). Inputs are read-only
    (:func:`kernel_input`), outputs fresh arrays, as in the monitors.
    """
    f, b, i = np.float64, np.bool_, np.int64

    def r(*shape, dt=f):  # an input
        return kernel_input(np.zeros(shape, dt), shape, dtype=dt)

    def w(*shape, dt=f):  # an output
        return np.zeros(shape, dt)

    eye = kernel_input(np.eye(4), (1, 4, 4))
    gather_used_rows(r(1, 4, dt=b), r(1, 4), r(1, 4), r(1, 4, 3), r(3, 3), r(3), w(1, 3, dt=i), w(1, 3, dt=b), w(1, 3), w(1, 3),
                     w(1, 3, 3))
    range_gauss_newton(r(1, 4, 3), r(1, 3), r(1, 4), r(1, 4), r(1, 4, dt=b), r(1, 3), r(1, 3), r(1, 0, 1),
                       r(1, 0), r(1, 0, 0), r(1, 0, dt=b), r(1, 4), 1, 1e-3, w(1, 4), w(1, dt=b), w(1, dt=i),
                       w(1, 4), w(1, 4, 4))
    cosine_gauss_newton(r(1, 3), r(1, 3, 3), r(3), r(1, 3), r(1, 3, dt=b), r(1, 3, dt=b), 1, 1e-4, w(1, 3),
                        w(1, dt=i), w(1, dt=b), w(1, dt=b))
    normal_geometry(r(1, 5, 4), r(1, 5, 4), r(1, 5), 1e-5, w(1, 4, 4), w(1), w(1, 4, 4), w(1, 4, 5), w(1, 5),
                    w(1, dt=b))
    fit_at_solution(r(1, 5, 4), r(1, 5), r(1, 5), r(1, 2), r(1, 3, 3), r(1, 5, dt=b), 1e-5, 1e3, 1e-3, w(1, 4, 4),
                    w(1, 5), w(1), w(1, 5), w(1), w(1, 5), w(1, 5), w(1), w(1), w(1, dt=i), w(1, dt=b))
    cosine_rule_products(r(1, 3), r(1, 3), r(3), r(1, 3, dt=b), r(1, 3, dt=b), r(1, 3, 3), r(1, 3, 3), r(1, 3),
                         r(1, 3, 3), w(1, 3, 3), w(1, 3), w(1, 3, 3), w(1, dt=b), w(1), w(1, 3, 3), w(1), w(1), w(1),
                         w(1, dt=b))
    vision_rows(r(1, 3, 3), r(1, 3), r(1, 3, 3), r(1, 3, dt=b), r(1, 3, dt=b), r(1, dt=b), w(1, 3, 3), w(1, 3),
                w(1, 3, 3), w(1, 3, dt=b))
    vision_prior(r(1, 1, 4), r(1, 1, 3, 3), r(1, 1, dt=b), r(1), r(3, 3), r(1, 1, 3), 1.0, 1.0, w(1, 1, dt=i),
                 w(1, 1, 3), w(1, 1, 3, 3))
    cosines_and_covariance(r(1, 3, 2), r(1, 3, dt=b), r(1, 3), kernel_input(np.eye(3), (3, 3)), w(1, 3),
                           w(1, 3, 3))
    calibrate_epochs(r(1, 1, dt=i), r(1, 1, 3), r(1, 1, 3, 3), r(1, 1, 3), r(1, 1, 3, 3), r(1, 1, 3, 3),
                     r(1, 1, 3, 3), r(1, 1, 3, dt=b), r(1, 1, 3), r(1, 1, 3, 3), r(1, 1, 3), r(3, 3), r(3, 3),
                     w(1, 1, 3), w(1, 1, 3), w(1, 1, 3, 3), w(1, 1, 3, 3))
    cond4_batch(eye, w(1))
