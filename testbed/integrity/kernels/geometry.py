"""The weighted-LS geometry and fit of one epoch (INTEGRITY_MATH.md §4), as a gufunc.

One implementation for every monitor and every epoch, clean or not: the used rows,
NaN checks, a dropped clock, GᵀWG, its Jacobi-scaled condition, J, A, (WS)ᵢᵢ, the
residuals, SSE and the slopes, with the epoch's :class:`~testbed.integrity.lsq.Reason`.
numpy's gufunc machinery broadcasts it over any batch axes and releases the GIL.
"""

from __future__ import annotations

import numpy as np
from numba import guvectorize

# lsq.Reason codes (kernels cannot import lsq: lsq imports the kernels)
_OK, _NAN_INPUT, _NO_POSITION, _NO_REDUNDANCY, _SINGULAR = 0, 1, 2, 3, 4

#: A used row whose (WS)ᵢᵢ is at or below this fraction of Wᵢᵢ has zero redundancy: the
#: value is rounding noise, and a fault on the row moves the position unseen (slope inf).
ZERO_REDUNDANCY_RTOL = 1e-12

SIGNATURE = "(n,k),(n),(n),(a),(b,b),(n),()->(k,k),(k,n),(n),(),(n),(),(n),(n),(),(),(),(),()"
#: the one type signature: a static gufunc is a plain numpy ufunc (a few µs a call), where
#: a dynamic one (layout only) costs ~0.8 ms of Python dispatch a call
TYPES = ("void(f8[:,:], f8[:], f8[:], f8[:], f8[:,:], b1[:], f8, f8[:,:], f8[:,:], f8[:], f8[:], f8[:], f8[:], "
         "f8[:], f8[:], f8[:], f8[:], i8[:], i8[:], i1[:])")


@guvectorize([TYPES], SIGNATURE, nopython=True, cache=True)
def wls_epoch(G, h, z, wd, Wb, mask, max_cond,
              J, A, ws, cond, r, sse, hslope, vslope, hmax, vmax, n_used, n_states, reason):
    """Weighted LS of one epoch at the linearisation point (prediction ``h``, partials ``G``).

    Inputs: G (N, 4) rows ∂h/∂[E, N, U, clock]; h, z (N) prediction and measurement;
    ``W = blockdiag(diag(wd), Wb)``, wd (n1) for the first, uncorrelated rows, Wb (R, R)
    with R = N − n1 for the rest; mask (N) rows used (unused rows may hold anything);
    max_cond the largest accepted condition number.

    Outputs (NaN where the epoch has no solution): J (4, 4) = (GᵀWG)⁻¹, A (4, N) = J GᵀW
    (zero columns on unused rows), ws (N) = (WS)ᵢᵢ (NaN on unused rows), cond, r (N) = z − h
    (0 on unused rows), sse = rᵀWr, hslope/vslope (N) with their maxima hmax/vmax (−inf
    with no used row), n_used, n_states (3 when no used row has a clock term: the clock
    is then not estimated, its J/A rows are zero and the test gains a degree of freedom),
    reason (NAN_INPUT, NO_POSITION, SINGULAR, NO_REDUNDANCY or OK).

    cond is the 1-norm condition number ‖S‖₁‖S⁻¹‖₁ of the Jacobi-scaled normal matrix
    S = D⁻¹(GᵀWG)D⁻¹, D = diag(GᵀWG)^½ (independent of state units and weight scale;
    κ₂ ≤ κ₁ ≤ 4κ₂ for 4 states). S is factorised LDLᵀ; a pivot that is not positive
    means S is numerically singular (cond = inf). For SPD S the factorisation is
    backward stable, so J is as accurate as LAPACK's inverse at any accepted condition.
    """
    N, K = G.shape
    n1 = wd.shape[0]
    R = N - n1
    # -- rows used, finite inputs, residuals -------------------------------------
    nu = 0
    finite = True
    clock = False
    for k in range(N):
        r[k] = 0.0
        if mask[k]:
            nu += 1
            rk = z[k] - h[k]
            finite = finite and np.isfinite(rk)
            r[k] = rk
            for c in range(K):
                finite = finite and np.isfinite(G[k, c])
            clock = clock or (np.isfinite(G[k, 3]) and G[k, 3] != 0.0)
    for k in range(n1):
        if mask[k]:
            finite = finite and np.isfinite(wd[k])
    for i in range(R):
        if mask[n1 + i]:
            for j in range(R):
                if mask[n1 + j]:
                    finite = finite and np.isfinite(Wb[i, j])
    ns = K if clock else K - 1
    n_used[0] = nu
    n_states[0] = ns
    hmax[0] = -np.inf
    vmax[0] = -np.inf
    cond[0] = np.nan
    code = _OK
    if not finite:
        code = _NAN_INPUT
    elif nu < ns:
        code = _NO_POSITION
    if code == _OK:
        # -- M = GᵀWG, the normal matrix of A = (GᵀWG)⁻¹GᵀW (seed eq. 20-21); WG in A's columns for now --
        work = np.empty((4, K, K))  # one allocation for M, S, its LDLᵀ factor L, S⁻¹
        M, S, L, Si = work[0], work[1], work[2], work[3]
        M[:, :] = 0.0
        for k in range(N):
            for c in range(K):
                A[c, k] = 0.0
            if not mask[k]:
                continue
            if k < n1:
                for c in range(K):
                    A[c, k] = wd[k] * G[k, c]
            else:
                for j in range(R):
                    if mask[n1 + j]:
                        for c in range(K):
                            A[c, k] += Wb[k - n1, j] * G[n1 + j, c]
            for i in range(K):
                for c in range(K):
                    M[i, c] += G[k, i] * A[c, k]
        if not clock:  # the clock is not estimated: its row and column out, a unit pivot in
            for i in range(K):
                M[i, K - 1] = 0.0
                M[K - 1, i] = 0.0
            M[K - 1, K - 1] = 1.0
        # -- Jacobi scaling, LDLᵀ, the inverse and its 1-norm condition -----------
        vec = np.empty((3, K))  # d, the LDLᵀ pivots, a forward-substitution column
        d, piv, y = vec[0], vec[1], vec[2]
        for i in range(K):
            d[i] = np.sqrt(M[i, i]) if M[i, i] > 0.0 else 0.0
            if not d[i] > 0.0:
                code = _SINGULAR
        if code == _OK:
            for i in range(K):
                for c in range(K):
                    S[i, c] = 0.5 * (M[i, c] + M[c, i]) / (d[i] * d[c])
            L[:, :] = 0.0
            for c in range(K):
                s = S[c, c]
                for q in range(c):
                    s -= L[c, q] * L[c, q] * piv[q]
                if not (s > 0.0 and np.isfinite(s)):
                    code = _SINGULAR
                    break
                piv[c] = s
                for i in range(c + 1, K):
                    s = S[i, c]
                    for q in range(c):
                        s -= L[i, q] * L[c, q] * piv[q]
                    L[i, c] = s / piv[c]
        if code == _OK:
            for c in range(K):  # column c of S⁻¹: L D Lᵀ x = e_c
                for i in range(K):
                    s = 1.0 if i == c else 0.0
                    for q in range(i):
                        s -= L[i, q] * y[q]
                    y[i] = s
                for i in range(K - 1, -1, -1):
                    s = y[i] / piv[i]
                    for q in range(i + 1, K):
                        s -= L[q, i] * Si[q, c]
                    Si[i, c] = s
            n_s = 0.0
            n_si = 0.0
            for c in range(K):
                a = 0.0
                b = 0.0
                for i in range(K):
                    a += abs(S[i, c])
                    b += abs(Si[i, c])
                n_s = max(n_s, a)
                n_si = max(n_si, b)
            kappa = n_s * n_si
            cond[0] = kappa if np.isfinite(kappa) else np.inf
            if not cond[0] <= max_cond:
                code = _SINGULAR
            else:
                for i in range(K):  # J = D⁻¹ S⁻¹ D⁻¹; a dropped clock is not estimated
                    for c in range(K):
                        J[i, c] = Si[i, c] / (d[i] * d[c])
                if not clock:
                    for i in range(K):
                        J[i, K - 1] = 0.0
                        J[K - 1, i] = 0.0
        else:
            cond[0] = np.inf
        if code == _OK and nu - ns < 1:
            code = _NO_REDUNDANCY
    reason[0] = code
    if not (code == _OK or code == _NO_REDUNDANCY):
        J[:, :] = np.nan
        A[:, :] = np.nan
        sse[0] = np.nan
        for k in range(N):
            r[k] = np.nan
            ws[k] = np.nan
            hslope[k] = np.nan
            vslope[k] = np.nan
        return
    # -- per row: A = J (WG)ᵀ, (WS)ᵢᵢ = Wᵢᵢ − (WG)ᵢ Aᵢ, slopes (seed eq. 20-21 with (WS)ᵢᵢ, §4) --
    wg = np.empty(K)
    for k in range(N):
        if not mask[k]:
            ws[k] = np.nan
            hslope[k] = np.nan
            vslope[k] = np.nan
            continue
        for c in range(K):
            wg[c] = A[c, k]
        s = 0.0
        for i in range(K):
            a = 0.0
            for c in range(K):
                a += J[i, c] * wg[c]
            A[i, k] = a
            s += wg[i] * a
        w_kk = wd[k] if k < n1 else Wb[k - n1, k - n1]
        ws[k] = w_kk - s
        if ws[k] <= ZERO_REDUNDANCY_RTOL * abs(w_kk):
            hslope[k] = np.inf
            vslope[k] = np.inf
        else:
            den = np.sqrt(ws[k])
            hslope[k] = np.hypot(A[0, k], A[1, k]) / den
            vslope[k] = abs(A[2, k]) / den
        hmax[0] = max(hmax[0], hslope[k])
        vmax[0] = max(vmax[0], vslope[k])
    # -- SSE = rᵀWr at the solution (seed eq. 25-26) --------------------------------
    s = 0.0
    for k in range(n1):
        if mask[k]:
            s += wd[k] * r[k] * r[k]
    for i in range(R):
        if mask[n1 + i]:
            t = 0.0
            for j in range(R):
                if mask[n1 + j]:
                    t += Wb[i, j] * r[n1 + j]
            s += t * r[n1 + i]
    sse[0] = s
