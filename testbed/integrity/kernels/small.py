"""Small dense linear algebra for the kernels: LU solve (one system, or many side by side), the Jacobi-scaled
LDLᵀ inverse of a symmetric positive matrix with its 1-norm condition number, and products."""

from __future__ import annotations

import sys

import numpy as np
from numba import njit

from testbed.kernel_cache import keep_in_step


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _offset_range(a0, a1, a2, p0, p1, p2):
    """(d0, d1, d2, |d|): the vector from p to a and its length, in the one order of operations every range
    row uses (the per-epoch kernels and their side-by-side versions give the same bits)."""
    d0 = a0 - p0
    d1 = a1 - p1
    d2 = a2 - p2
    return d0, d1, d2, np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _condition_1(S, Si) -> float:
    """‖S‖₁‖S⁻¹‖₁ (largest column sums of absolute values)."""
    K = S.shape[0]
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
    return n_s * n_si


@njit(cache=True, nogil=True, error_model="numpy")
def _scaled_ldl_inverse(M, d, S, L, Si, piv, y) -> float:
    """The inverse of symmetric positive (K, K) ``M`` through its Jacobi-scaled matrix, and that matrix's
    1-norm condition number.

    d (K) = diag(M)^½; S = D⁻¹ M D⁻¹ (symmetrised), factorised LDLᵀ (L (K, K), pivots ``piv`` (K)); Si = S⁻¹
    (so M⁻¹ = D⁻¹ Si D⁻¹); y (K) scratch. Returns ‖S‖₁‖S⁻¹‖₁ (independent of state units and weight scale),
    or inf when a diagonal or a pivot is not positive (S numerically singular; S, L, Si are then partial). For
    SPD S the factorisation is backward stable, so the inverse is as accurate as LAPACK's at any accepted
    condition.
    """
    K = M.shape[0]
    singular = False
    for i in range(K):
        d[i] = np.sqrt(M[i, i]) if M[i, i] > 0.0 else 0.0
        if not d[i] > 0.0:
            singular = True
    if singular:
        return np.inf
    for i in range(K):
        for c in range(K):
            S[i, c] = 0.5 * (M[i, c] + M[c, i]) / (d[i] * d[c])
    L[:, :] = 0.0
    for c in range(K):
        s = S[c, c]
        for q in range(c):
            s -= L[c, q] * L[c, q] * piv[q]
        if not (s > 0.0 and np.isfinite(s)):
            return np.inf
        piv[c] = s
        for i in range(c + 1, K):
            s = S[i, c]
            for q in range(c):
                s -= L[i, q] * L[c, q] * piv[q]
            L[i, c] = s / piv[c]
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
    kappa = _condition_1(S, Si)
    return kappa if np.isfinite(kappa) else np.inf


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


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _sandwich(X, C, out, tmp, accumulate):
    """out = X C Xᵀ, or out += X C Xᵀ with ``accumulate`` (X (L, n), C (n, n); tmp (L, n) scratch)."""
    L, n = X.shape
    _matmul(X, C, tmp)
    for l in range(L):
        for j in range(L):
            s = 0.0
            for q in range(n):
                s += tmp[l, q] * X[j, q]
            out[l, j] = out[l, j] + s if accumulate else s


@njit(cache=True, nogil=True, error_model="numpy")
def _tile_lu_solve(n, A, B, ok):
    """:func:`~testbed.integrity.kernels.small._lu_solve` of ``n`` systems side by side (A (K, K, T), one
    right-hand side B (K, T)), its operations and pivots per system, as selects: ``ok`` says which it solves."""
    K = A.shape[0]
    big, piv = np.empty(n), np.empty(n, np.int64)
    for q in range(n):
        ok[q] = True
    for j in range(K):
        for q in range(n):
            big[q] = abs(A[j, j, q])
            piv[q] = j
        for i in range(j + 1, K):
            for q in range(n):
                a = abs(A[i, j, q])
                up = a > big[q]
                big[q] = a if up else big[q]
                piv[q] = i if up else piv[q]
        for q in range(n):
            ok[q] = ok[q] and big[q] > 0.0  # also catches NaN
        for q in range(n):
            i = piv[q]
            if i != j:
                for c in range(K):
                    A[j, c, q], A[i, c, q] = A[i, c, q], A[j, c, q]
                B[j, q], B[i, q] = B[i, q], B[j, q]
        for i in range(j + 1, K):
            for q in range(n):
                f = A[i, j, q] / A[j, j, q]
                for c in range(j + 1, K):
                    A[i, c, q] = A[i, c, q] - f * A[j, c, q] if f != 0.0 else A[i, c, q]
                B[i, q] = B[i, q] - f * B[j, q] if f != 0.0 else B[i, q]
    for i in range(K - 1, -1, -1):
        for q in range(n):
            s = B[i, q]
            for c in range(i + 1, K):
                s -= A[i, c, q] * B[c, q]
            s = s / A[i, i, q]
            ok[q] = ok[q] and np.isfinite(s)
            B[i, q] = s


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _tile_matmul(n, X, Y, out, acc, xt):
    """out = X Y (or Xᵀ Y with ``xt``) for ``n`` products side by side (last axis), each sum in
    :func:`_matmul`'s order. X (I, K, T) (or (K, I, T)), Y (K, J, T), out (I, J, T); acc (T) scratch."""
    I, J = out.shape[0], out.shape[1]
    K = Y.shape[0]
    for i in range(I):
        for j in range(J):
            for q in range(n):
                acc[q] = 0.0
            for k in range(K):
                for q in range(n):
                    acc[q] += (X[k, i, q] if xt else X[i, k, q]) * Y[k, j, q]
            for q in range(n):
                out[i, j, q] = acc[q]


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _end_failed_lanes(n, active, solved, flag):
    """After :func:`_tile_lu_solve`: an active system it could not solve stops iterating (``flag`` False)."""
    for q in range(n):
        if active[q] and not solved[q]:
            flag[q] = False
            active[q] = False


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _tile_sandwich(n, X, C, out, tmp, acc, accumulate):
    """out = X C Xᵀ (or out += with ``accumulate``) for ``n`` systems side by side, in :func:`_sandwich`'s
    order (tmp: X C)."""
    _tile_matmul(n, X, C, tmp, acc, False)
    for l in range(out.shape[0]):
        for j in range(out.shape[1]):
            for q in range(n):
                acc[q] = 0.0
            for k in range(X.shape[1]):
                for q in range(n):
                    acc[q] += tmp[l, k, q] * X[j, k, q]
            for q in range(n):
                out[l, j, q] = out[l, j, q] + acc[q] if accumulate else acc[q]


# numba compiles a kernel again when its own file changes, not when a helper's does
keep_in_step(sys.modules[__name__])
