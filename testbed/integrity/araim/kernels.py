"""Compiled ARAIM kernels: every fault mode's subset statistics, and the half-interval PL search.

A mode that removes one or two rows and leaves every clock a row is a rank-one or rank-two downdate of
the all-in-view solution (no n × n inverse: O(n² + N) per mode); any other mode's normal matrix is the
all-in-view one with the removed rows' outer products subtracted (Gᵀ W_k G = Gᵀ W G − Σ_{i∈R_k} w_i g_i g_iᵀ,
eq. 9), inverted by Gauss–Jordan on the Jacobi-scaled matrix. Both paths apply the condition test of
:func:`testbed.integrity.araim.subsets.checked_inverse` to the mode's own matrix and inverse. The PL search is :func:`testbed.integrity.araim.protection.solve_protection_level`'s halving,
with the sum of a step stopped as soon as it exceeds the target (the terms are non-negative).
"""

from __future__ import annotations

import math
import sys

import numpy as np
from numba import njit

from testbed.kernel_cache import keep_in_step

SQRT_HALF = 0.7071067811865476


@njit(cache=True, nogil=True, error_model="numpy")
def _scaled_inverse(A, inv, max_cond) -> bool:
    """``inv`` = A⁻¹ for symmetric positive (n, n) ``A`` via the Jacobi-scaled matrix; False when that
    matrix is singular or its 1-norm condition number exceeds ``max_cond`` (``inv`` is then garbage)."""
    n = A.shape[0]
    d = np.empty(n)
    for j in range(n):
        if not A[j, j] > 0.0:
            return False
        d[j] = math.sqrt(A[j, j])
    M = np.empty((n, 2 * n))
    norm_a = 0.0
    for j in range(n):
        col = 0.0
        for i in range(n):
            M[i, j] = A[i, j] / (d[i] * d[j])
            col += abs(M[i, j])
        norm_a = max(norm_a, col)
        for i in range(n):
            M[i, n + j] = 1.0 if i == j else 0.0
    for j in range(n):  # Gauss-Jordan, partial pivoting
        piv = j
        big = abs(M[j, j])
        for i in range(j + 1, n):
            if abs(M[i, j]) > big:
                big = abs(M[i, j])
                piv = i
        if not big > 0.0:
            return False
        if piv != j:
            for c in range(2 * n):
                tmp = M[j, c]
                M[j, c] = M[piv, c]
                M[piv, c] = tmp
        p = M[j, j]
        for c in range(2 * n):
            M[j, c] /= p
        for i in range(n):
            if i != j:
                f = M[i, j]
                if f != 0.0:
                    for c in range(2 * n):
                        M[i, c] -= f * M[j, c]
    norm_i = 0.0
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(M[i, n + j])
        norm_i = max(norm_i, col)
    cond = norm_a * norm_i
    if not (math.isfinite(cond) and cond <= max_cond):
        return False
    for i in range(n):
        for j in range(n):
            inv[i, j] = M[i, n + j] / (d[i] * d[j])
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def _direct(A0, G_e, w, removed_k, empty_clock_k, inv, max_cond) -> bool:
    """(Gᵀ W_k G)⁻¹ into ``inv`` from the all-in-view matrix less the removed rows, a clock without rows pinned."""
    n = A0.shape[0]
    N = G_e.shape[0]
    A = A0.copy()
    for i in range(N):
        if removed_k[i]:
            for a in range(n):
                for b in range(n):
                    A[a, b] -= G_e[i, a] * G_e[i, b] * w[i]
    for c in range(n - 3):
        if empty_clock_k[c]:  # no row left: the clock is pinned, the others unchanged
            for a in range(n):
                A[3 + c, a] = 0.0
                A[a, 3 + c] = 0.0
            A[3 + c, 3 + c] = 1.0
    return _scaled_inverse(A, inv, max_cond)


@njit(cache=True, nogil=True, error_model="numpy")
def _downdate(A0, inv0, G_e, w, Sfull, Pm, rows, r, inv, S, max_cond) -> bool:
    """Mode removing ``r`` ≤ 2 rows ``rows`` without emptying a clock, from the all-in-view solution:
    S⁽ᵏ⁾ = S⁽⁰⁾ − S⁽⁰⁾_{:,R} P_RR⁻¹ P_{R,:} and (Gᵀ W_k G)⁻¹ = (Gᵀ W G)⁻¹ + S⁽⁰⁾_{:,R} P_RR⁻¹ S⁽⁰⁾_{:,R}ᵀ,
    P = W − W G S⁽⁰⁾ (the rank-r update of the inverse; O(n² + N) instead of O(n³ + nN)). The condition
    test is the direct path's, on the updated matrix and inverse."""
    n = A0.shape[0]
    N = G_e.shape[0]
    i0 = rows[0]
    i1 = rows[1] if r == 2 else rows[0]
    if r == 1:
        p00 = Pm[i0, i0]
        if not abs(p00) > 1e-12 * w[i0]:
            return False
        q00, q01, q11 = 1.0 / p00, 0.0, 0.0
    else:
        p00, p01, p11 = Pm[i0, i0], Pm[i0, i1], Pm[i1, i1]
        det = p00 * p11 - p01 * p01
        if not abs(det) > 1e-12 * w[i0] * w[i1]:
            return False
        q00, q01, q11 = p11 / det, -p01 / det, p00 / det
    A = A0.copy()
    for a in range(n):
        for b in range(n):
            A[a, b] -= G_e[i0, a] * G_e[i0, b] * w[i0]
            if r == 2:
                A[a, b] -= G_e[i1, a] * G_e[i1, b] * w[i1]
    for a in range(n):
        if not A[a, a] > 0.0:
            return False
    for a in range(n):
        for b in range(n):
            u0a, u1a = Sfull[a, i0], Sfull[a, i1]
            u0b, u1b = Sfull[b, i0], Sfull[b, i1]
            if r == 1:
                inv[a, b] = inv0[a, b] + u0a * q00 * u0b
            else:
                inv[a, b] = inv0[a, b] + u0a * (q00 * u0b + q01 * u1b) + u1a * (q01 * u0b + q11 * u1b)
    norm_a = 0.0
    norm_i = 0.0
    for b in range(n):
        ca = 0.0
        ci = 0.0
        for a in range(n):
            da = math.sqrt(A[a, a] * A[b, b])
            ca += abs(A[a, b]) / da
            ci += abs(inv[a, b]) * da
        norm_a = max(norm_a, ca)
        norm_i = max(norm_i, ci)
    cond = norm_a * norm_i
    if not (math.isfinite(cond) and cond <= max_cond):
        return False
    for q in range(3):
        c0 = Sfull[q, i0] * q00 + (Sfull[q, i1] * q01 if r == 2 else 0.0)
        c1 = Sfull[q, i0] * q01 + Sfull[q, i1] * q11 if r == 2 else 0.0
        for i in range(N):
            S[q, i] = Sfull[q, i] - c0 * Pm[i0, i] - (c1 * Pm[i1, i] if r == 2 else 0.0)
        S[q, i0] = 0.0
        if r == 2:
            S[q, i1] = 0.0
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def subset_stats_epochs(G, c_int, c_acc, b_nom, b_cont, residual, has_residual, removed, empty_clock,
                        structurally_ok, max_cond, observable, sigma, bias, sigma_ss, bias_ss, separation, s0):
    """Eq. 9-13 for every epoch (E) and mode (M); mode 0 removes nothing. Shapes as
    :func:`testbed.integrity.araim.subsets.subset_stats` (outputs filled in place). A mode of one or two rows
    that leaves every clock a row is a downdate of the all-in-view solution (:func:`_downdate`), any other
    a direct solve (:func:`_direct`)."""
    E, N, n = G.shape
    M = removed.shape[0]
    n_clock = n - 3
    A0 = np.empty((n, n))
    inv0 = np.empty((n, n))
    inv = np.empty((n, n))
    S = np.empty((3, N))
    S0 = np.empty((3, N))
    Sfull = np.empty((n, N))
    Pm = np.empty((N, N))
    w = np.empty(N)
    n_removed = np.zeros(M, np.int64)
    rows = np.zeros((M, 2), np.int64)
    fast = np.zeros(M, np.bool_)
    for k in range(M):
        for i in range(N):
            if removed[k, i]:
                if n_removed[k] < 2:
                    rows[k, n_removed[k]] = i
                n_removed[k] += 1
        fast[k] = 1 <= n_removed[k] <= 2 and structurally_ok[k]
        for c in range(n_clock):
            if empty_clock[k, c]:
                fast[k] = False
    for e in range(E):
        G_e = G[e]
        for i in range(N):
            w[i] = 1.0 / c_int[e, i]
        for a in range(n):
            for b in range(n):
                acc = 0.0
                for i in range(N):
                    acc += G_e[i, a] * G_e[i, b] * w[i]
                A0[a, b] = acc
        ok0 = structurally_ok[0] and _direct(A0, G_e, w, removed[0], empty_clock[0], inv0, max_cond)
        if ok0:
            for a in range(n):  # S⁽⁰⁾ (all states) and P = W − W G S⁽⁰⁾
                for i in range(N):
                    acc = 0.0
                    for b in range(n):
                        acc += inv0[a, b] * G_e[i, b]
                    Sfull[a, i] = acc * w[i]
            for i in range(N):
                for j in range(N):
                    acc = 0.0
                    for a in range(n):
                        acc += G_e[i, a] * Sfull[a, j]
                    Pm[i, j] = (w[i] if i == j else 0.0) - w[i] * acc
            for q in range(3):
                for i in range(N):
                    S0[q, i] = Sfull[q, i]
                    s0[e, q, i] = Sfull[q, i]
        for k in range(M):
            if k == 0:
                ok = ok0
                if ok:
                    for q in range(3):
                        for i in range(N):
                            S[q, i] = S0[q, i]
            elif ok0 and fast[k]:
                ok = _downdate(A0, inv0, G_e, w, Sfull, Pm, rows[k], n_removed[k], inv, S, max_cond)
            else:
                ok = structurally_ok[k] and _direct(A0, G_e, w, removed[k], empty_clock[k], inv, max_cond)
                if ok:
                    for q in range(3):  # S⁽ᵏ⁾ = (Gᵀ W_k G)⁻¹ Gᵀ W_k, position rows (eq. 9)
                        for i in range(N):
                            if removed[k, i]:
                                S[q, i] = 0.0
                            else:
                                acc = 0.0
                                for a in range(n):
                                    acc += inv[q, a] * G_e[i, a]
                                S[q, i] = acc * w[i]
            observable[e, k] = ok
            if not ok:
                for q in range(3):
                    sigma[e, k, q] = np.nan
                    bias[e, k, q] = np.nan
                    sigma_ss[e, k, q] = np.nan
                    bias_ss[e, k, q] = np.nan
                    separation[e, k, q] = np.nan
                    if k == 0:
                        for i in range(N):
                            s0[e, q, i] = np.nan
                continue
            for q in range(3):  # eq. 10-13 and the separation
                s2 = 0.0
                bb = 0.0
                ss2 = 0.0
                bss = 0.0
                sep = 0.0
                for i in range(N):
                    s = S[q, i]
                    s2 += s * s * c_int[e, i]
                    bb += abs(s) * b_nom[e, i]
                    if ok0:
                        ds = s - S0[q, i]
                        ss2 += ds * ds * c_acc[e, i]
                        bss += abs(ds) * b_cont[e, i]
                        sep += ds * residual[e, i]
                sigma[e, k, q] = math.sqrt(s2)
                bias[e, k, q] = bb
                sigma_ss[e, k, q] = math.sqrt(ss2) if ok0 else np.nan
                bias_ss[e, k, q] = bss if ok0 else np.nan
                separation[e, k, q] = sep if (ok0 and has_residual) else np.nan


@njit(cache=True, nogil=True, error_model="numpy")
def halve_protection_levels(offset, sigma, weight, cap, target, lo, hi, tol, iterations):
    """Halve each bracket [lo, hi] (P,) of eq. 16 (terms (P, K)) until it is at most ``tol`` wide; ``hi`` and
    ``iterations`` updated in place. A term with weight 0 is unused."""
    P, K = offset.shape
    for p in range(P):
        low = lo[p]
        high = hi[p]
        it = 0
        while high - low > tol:
            mid = 0.5 * (low + high)
            risk = 0.0
            for k in range(K):
                wk = weight[p, k]
                if wk > 0.0:
                    z = (mid - offset[p, k]) / sigma[p, k]
                    qz = 1.0 if z <= 0.0 else 0.5 * math.erfc(z * SQRT_HALF)
                    risk += wk * min(qz, cap[p, k])
                    if risk > target[p]:  # the terms are non-negative: the verdict is in
                        break
            if risk > target[p]:
                low = mid
            else:
                high = mid
            it += 1
        hi[p] = high
        iterations[p] = it


# numba compiles a kernel again when its own file changes, not when a helper's does
keep_in_step(sys.modules[__name__])
