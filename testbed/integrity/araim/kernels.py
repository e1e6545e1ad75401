"""Compiled ARAIM kernels: every fault mode's subset statistics, and the half-interval PL search.

The subset normal matrix of mode k is the all-in-view one with the removed rows' outer products
subtracted (Gᵀ W_k G = Gᵀ W G − Σ_{i∈R_k} w_i g_i g_iᵀ, eq. 9): |R_k|·n² work instead of N·n², the
factor a mode shares with the fault-free solution reused. The n × n inverse (n ≤ 7) is Gauss–Jordan
on the Jacobi-scaled matrix, the condition test the one :func:`testbed.integrity.araim.subsets.checked_inverse`
applies. The PL search is :func:`testbed.integrity.araim.protection.solve_protection_level`'s halving,
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
def subset_stats_epochs(G, c_int, c_acc, b_nom, b_cont, residual, has_residual, removed, empty_clock,
                        structurally_ok, max_cond, observable, sigma, bias, sigma_ss, bias_ss, separation, s0):
    """Eq. 9-13 for every epoch (E) and mode (M); mode 0 removes nothing. Shapes as
    :func:`testbed.integrity.araim.subsets.subset_stats` (outputs filled in place)."""
    E, N, n = G.shape
    M = removed.shape[0]
    n_clock = n - 3
    A0 = np.empty((n, n))
    A = np.empty((n, n))
    inv = np.empty((n, n))
    S = np.empty((3, N))
    S0 = np.empty((3, N))
    w = np.empty(N)
    for e in range(E):
        for i in range(N):
            w[i] = 1.0 / c_int[e, i]
        for a in range(n):
            for b in range(n):
                acc = 0.0
                for i in range(N):
                    acc += G[e, i, a] * G[e, i, b] * w[i]
                A0[a, b] = acc
        ok0 = False
        for k in range(M):
            for a in range(n):
                for b in range(n):
                    A[a, b] = A0[a, b]
            for i in range(N):
                if removed[k, i]:
                    for a in range(n):
                        for b in range(n):
                            A[a, b] -= G[e, i, a] * G[e, i, b] * w[i]
            for c in range(n_clock):
                if empty_clock[k, c]:  # no row left: the clock is pinned, the others unchanged
                    for a in range(n):
                        A[3 + c, a] = 0.0
                        A[a, 3 + c] = 0.0
                    A[3 + c, 3 + c] = 1.0
            ok = structurally_ok[k] and _scaled_inverse(A, inv, max_cond)
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
            for q in range(3):  # S⁽ᵏ⁾ = (Gᵀ W_k G)⁻¹ Gᵀ W_k, position rows (eq. 9)
                for i in range(N):
                    if removed[k, i]:
                        S[q, i] = 0.0
                    else:
                        acc = 0.0
                        for a in range(n):
                            acc += inv[q, a] * G[e, i, a]
                        S[q, i] = acc * w[i]
            if k == 0:
                ok0 = True
                for q in range(3):
                    for i in range(N):
                        S0[q, i] = S[q, i]
                        s0[e, q, i] = S[q, i]
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
