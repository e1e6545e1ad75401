"""The weighted-LS geometry of every epoch: GᵀWG, its condition, J, A, (WS)ᵢᵢ, and the solution-side fit."""

from __future__ import annotations

import numpy as np
from numba import njit

from testbed.integrity.kernels.small import _cond4, _matmul


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
    _matmul(G0.T, WG, M)
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
    _matmul(J, WG.T, A)
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
