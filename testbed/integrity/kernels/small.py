"""Small dense linear algebra for the kernels: LU solve and products."""

from __future__ import annotations

import numpy as np
from numba import njit


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
