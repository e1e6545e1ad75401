"""The weighted-LS geometry and fit of an epoch (docs/design/integrity.md §2-§4).

One implementation for every monitor and every epoch, clean or not (:func:`wls_one`): the
used rows, NaN checks, a dropped clock, GᵀWG, its Jacobi-scaled condition, J, A, (WS)ᵢᵢ,
the residuals, SSE and the slopes, with the epoch's :class:`~testbed.integrity.lsq.Reason`.
:func:`wls_epochs` runs it over a batch, the common epochs side by side in vector lanes
(1.8x faster, the same numbers bit for bit; ``tests/test_integrity_kernels.py``).
"""

from __future__ import annotations

import sys

import numpy as np
from numba import njit

from testbed.integrity.kernels.small import _condition_1, _scaled_ldl_inverse
from testbed.kernel_cache import keep_in_step

# lsq.Reason codes (kernels cannot import lsq: lsq imports the kernels)
_OK, _NAN_INPUT, _NO_POSITION, _NO_REDUNDANCY, _SINGULAR = 0, 1, 2, 3, 4

#: A used row whose (WS)ᵢᵢ is at or below this fraction of Wᵢᵢ has zero redundancy: the
#: value is rounding noise, and a fault on the row moves the position unseen (slope inf).
ZERO_REDUNDANCY_RTOL = 1e-12

@njit(cache=True, nogil=True, error_model="numpy")
def wls_one(G, h, z, wd, Wb, mask, max_cond,
            J, A, ws, cond, r, sse, hslope, vslope, hmax, vmax, n_used, n_states, reason, work, vec, wg):
    """Weighted LS of one epoch at the linearisation point (prediction ``h``, partials ``G``).

    Inputs: G (N, 4) rows ∂h/∂[E, N, U, clock]; h, z (N) prediction and measurement;
    ``W = blockdiag(diag(wd), Wb)``, wd (n1) for the first, uncorrelated rows, Wb (R, R)
    with R = N − n1 for the rest; mask (N) rows used (unused rows may hold anything);
    max_cond the largest accepted condition number; work (4, 4, 4), vec (3, 4), wg (4):
    scratch.

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
        # -- M = GᵀWG, the normal matrix of A = (GᵀWG)⁻¹GᵀW (the VA-RAIM paper's eq. 20-21); WG in A's columns for now
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
        # -- Jacobi scaling, LDLᵀ, the inverse and its 1-norm condition (inf: a pivot not positive) --
        d, piv, y = vec[0], vec[1], vec[2]
        cond[0] = _scaled_ldl_inverse(M, d, S, L, Si, piv, y)
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
    # -- per row: A = J (WG)ᵀ, (WS)ᵢᵢ = Wᵢᵢ − (WG)ᵢ Aᵢ, slopes (docs/design/integrity.md §4, eq. 4.1-4.2) --
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
            hslope[k] = np.sqrt(A[0, k] * A[0, k] + A[1, k] * A[1, k]) / den
            vslope[k] = abs(A[2, k]) / den
        hmax[0] = max(hmax[0], hslope[k])
        vmax[0] = max(vmax[0], vslope[k])
    # -- SSE = rᵀWr at the solution (the VA-RAIM paper's eq. 25-26) ----------------------------
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


#: epochs solved side by side by :func:`wls_epochs` (their quantities in registers' lanes)
TILE = 64


@njit(cache=True, nogil=True, error_model="numpy")
def _tile_solve(n, n1, max_cond, Gt, WG, wdt, Wbt, wkk, rt, M, S, Lf, Si, Jt, At, d, piv, y, bad, kap, wst, hst, vst,
                sset):
    """:func:`wls_one`'s arithmetic for ``n`` gathered epochs side by side (the last axis), in its order:
    M = GᵀWG, the scaled LDLᵀ, J, the condition, A, (WS)ᵢᵢ, the slopes and the SSE. ``bad``: epochs
    :func:`wls_one` must decide itself (a non-positive pivot, a rejected condition)."""
    N, K = Gt.shape[0], Gt.shape[1]
    R = N - n1
    # -- WG (A's columns for now) and M = GᵀWG ------------------------------------------
    for k in range(n1):
        for c in range(K):
            for q in range(n):
                WG[k, c, q] = wdt[k, q] * Gt[k, c, q]
    for k in range(n1, N):
        WG[k, :, :n] = 0.0
        for j in range(R):
            for c in range(K):
                for q in range(n):
                    WG[k, c, q] += Wbt[k - n1, j, q] * Gt[n1 + j, c, q]
    M[:, :, :n] = 0.0
    for k in range(N):
        for i in range(K):
            for c in range(K):
                for q in range(n):
                    M[i, c, q] += Gt[k, i, q] * WG[k, c, q]
    # -- Jacobi scaling, LDLᵀ, the inverse and its 1-norm condition ----------------------
    for q in range(n):
        bad[q] = False
    for i in range(K):
        for q in range(n):
            m = M[i, i, q]
            d[i, q] = np.sqrt(m) if m > 0.0 else 0.0
            bad[q] = bad[q] or not d[i, q] > 0.0
    for i in range(K):
        for c in range(K):
            for q in range(n):
                S[i, c, q] = 0.5 * (M[i, c, q] + M[c, i, q]) / (d[i, q] * d[c, q])
    for c in range(K):
        for q in range(n):
            s = S[c, c, q]
            for t in range(c):
                s -= Lf[c, t, q] * Lf[c, t, q] * piv[t, q]
            bad[q] = bad[q] or not (s > 0.0 and np.isfinite(s))
            piv[c, q] = s
        for i in range(c + 1, K):
            for q in range(n):
                s = S[i, c, q]
                for t in range(c):
                    s -= Lf[i, t, q] * Lf[c, t, q] * piv[t, q]
                Lf[i, c, q] = s / piv[c, q]
    for c in range(K):
        for i in range(K):
            for q in range(n):
                s = 1.0 if i == c else 0.0
                for t in range(i):
                    s -= Lf[i, t, q] * y[t, q]
                y[i, q] = s
        for i in range(K - 1, -1, -1):
            for q in range(n):
                s = y[i, q] / piv[i, q]
                for t in range(i + 1, K):
                    s -= Lf[t, i, q] * Si[t, c, q]
                Si[i, c, q] = s
    for q in range(n):
        kappa = _condition_1(S[:, :, q], Si[:, :, q])
        kappa = kappa if np.isfinite(kappa) else np.inf
        bad[q] = bad[q] or not kappa <= max_cond
        kap[q] = kappa
    for i in range(K):
        for c in range(K):
            for q in range(n):
                Jt[i, c, q] = Si[i, c, q] / (d[i, q] * d[c, q])
    # -- per row: A = J (WG)ᵀ, (WS)ᵢᵢ, slopes; SSE ---------------------------------------
    for k in range(N):
        for q in range(n):
            s = 0.0
            for i in range(K):
                a = 0.0
                for c in range(K):
                    a += Jt[i, c, q] * WG[k, c, q]
                At[i, k, q] = a
                s += WG[k, i, q] * a
            w_kk = wkk[k, q]
            wsk = w_kk - s
            den = np.sqrt(wsk)
            zero = wsk <= ZERO_REDUNDANCY_RTOL * abs(w_kk)
            wst[k, q] = wsk
            hst[k, q] = np.inf if zero else np.sqrt(At[0, k, q] * At[0, k, q] + At[1, k, q] * At[1, k, q]) / den
            vst[k, q] = np.inf if zero else abs(At[2, k, q]) / den
    for q in range(n):
        s = 0.0
        for k in range(n1):
            s += wdt[k, q] * rt[k, q] * rt[k, q]
        sset[q] = s
    for i in range(R):
        for q in range(n):
            t = 0.0
            for j in range(R):
                t += Wbt[i, j, q] * rt[n1 + j, q]
            sset[q] += t * rt[n1 + i, q]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _wls_at(p, G, h, z, wd, Wb, mask, max_cond, J, A, ws, cond, r, sse, hslope, vslope, hmax, vmax, n_used, n_states,
            reason, work, vec, wg):
    """:func:`wls_one` on epoch ``p`` of a flat batch, in place."""
    wls_one(G[p], h[p], z[p], wd[p], Wb[p], mask[p], max_cond, J[p], A[p], ws[p], cond[p:p + 1], r[p], sse[p:p + 1],
            hslope[p], vslope[p], hmax[p:p + 1], vmax[p:p + 1], n_used[p:p + 1], n_states[p:p + 1],
            reason[p:p + 1], work, vec, wg)


@njit(cache=True, nogil=True, error_model="numpy")
def wls_epochs(G, h, z, wd, Wb, mask, max_cond, epochs,
               J, A, ws, cond, r, sse, hslope, vslope, hmax, vmax, n_used, n_states, reason):
    """:func:`wls_one` for the epochs ``epochs`` (int64 indices) of a flat batch (P, ...), the same numbers
    bit for bit, faster; the other epochs' outputs are not written.

    Epochs are solved ``TILE`` at a time with the epoch as the innermost (vectorised) axis: the
    arithmetic of each epoch is :func:`wls_one`'s, operation for operation and in its order. An
    unused row enters as zeros, and adding an exact zero to a sum that starts at +0 changes no
    bit. An epoch off the common path (a non-finite used input, no clock term, no redundancy, a
    singular or rejected normal matrix) is solved again by :func:`wls_one` itself.
    """
    N, K = G.shape[1:]
    P = epochs.shape[0]
    n1 = wd.shape[1]
    R = N - n1
    work, vec, wg = np.empty((4, K, K)), np.empty((3, K)), np.empty(K)
    lanes = np.empty(TILE, np.int64)
    Gt, WG, At = np.empty((N, K, TILE)), np.empty((N, K, TILE)), np.empty((K, N, TILE))
    wdt, rt, wkk = np.empty((n1, TILE)), np.empty((N, TILE)), np.empty((N, TILE))
    Wbt = np.empty((R, R, TILE))
    M, S, Lf, Si, Jt = (np.empty((K, K, TILE)), np.empty((K, K, TILE)), np.empty((K, K, TILE)),
                        np.empty((K, K, TILE)), np.empty((K, K, TILE)))
    d, piv, y = np.empty((K, TILE)), np.empty((K, TILE)), np.empty((K, TILE))
    wst, hst, vst, sset, kap = (np.empty((N, TILE)), np.empty((N, TILE)), np.empty((N, TILE)), np.empty(TILE),
                                np.empty(TILE))
    bad = np.empty(TILE, np.bool_)
    used = np.empty((N, TILE), np.bool_)
    e0 = 0
    while e0 < P:
        # -- the tile's common-path epochs, gathered with unused rows as zeros ------------
        n = 0
        e = e0
        while e < P and n < TILE:
            p = epochs[e]
            nu = 0
            chk = 0.0  # stays 0 while every used input is finite (x·0 is NaN for inf and NaN)
            clock = False
            for k in range(N):
                if mask[p, k]:
                    nu += 1
                    chk += (z[p, k] - h[p, k]) * 0.0 + G[p, k, 0] * 0.0 + G[p, k, 1] * 0.0 + G[p, k, 2] * 0.0
                    chk += G[p, k, 3] * 0.0
                    clock = clock or G[p, k, 3] != 0.0
                    if k < n1:
                        chk += wd[p, k] * 0.0
                    else:
                        for j in range(R):
                            if mask[p, n1 + j]:
                                chk += Wb[p, k - n1, j] * 0.0
            if chk == 0.0 and clock and nu - K >= 1:
                lanes[n] = p
                n_used[p] = nu
                for k in range(N):
                    u = mask[p, k]
                    used[k, n] = u
                    rt[k, n] = z[p, k] - h[p, k] if u else 0.0
                    for c in range(K):
                        Gt[k, c, n] = G[p, k, c] if u else 0.0
                    wkk[k, n] = (wd[p, k] if k < n1 else Wb[p, k - n1, k - n1]) if u else 0.0
                for k in range(n1):
                    wdt[k, n] = wd[p, k] if mask[p, k] else 0.0
                for i in range(R):
                    for j in range(R):
                        Wbt[i, j, n] = Wb[p, i, j] if (mask[p, n1 + i] and mask[p, n1 + j]) else 0.0
                n += 1
            else:
                _wls_at(p, G, h, z, wd, Wb, mask, max_cond, J, A, ws, cond, r, sse, hslope, vslope, hmax, vmax, n_used,
                        n_states, reason, work, vec, wg)
            e += 1
        e0 = e
        if n == 0:
            continue
        _tile_solve(n, n1, max_cond, Gt, WG, wdt, Wbt, wkk, rt, M, S, Lf, Si, Jt, At, d, piv, y, bad, kap, wst, hst, vst,
                    sset)
        for q in range(n):
            cond[lanes[q]] = kap[q]
        for q in range(n):
            p = lanes[q]
            if bad[q]:
                _wls_at(p, G, h, z, wd, Wb, mask, max_cond, J, A, ws, cond, r, sse, hslope, vslope, hmax, vmax, n_used,
                        n_states, reason, work, vec, wg)
                continue
            n_states[p] = K
            reason[p] = _OK
            sse[p] = sset[q]
            for i in range(K):
                for c in range(K):
                    J[p, i, c] = Jt[i, c, q]
            hm = -np.inf
            vm = -np.inf
            for k in range(N):
                r[p, k] = rt[k, q]
                u = used[k, q]
                for i in range(K):
                    A[p, i, k] = At[i, k, q] if u else 0.0
                ws[p, k] = wst[k, q] if u else np.nan
                hslope[p, k] = hst[k, q] if u else np.nan
                vslope[p, k] = vst[k, q] if u else np.nan
                if u:
                    hm = max(hm, hst[k, q])
                    vm = max(vm, vst[k, q])
            hmax[p] = hm
            vmax[p] = vm


# numba compiles a kernel again when its own file changes, not when a helper's does
keep_in_step(sys.modules[__name__])
