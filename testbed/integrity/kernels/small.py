"""Small dense linear algebra for the kernels: LU solve, products, the certified 4×4 condition number."""

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
def cond4_batch(S, out):
    """:func:`_cond4` of every symmetric 4×4 matrix S[p] (NaN: not certified, use LAPACK)."""
    scratch = np.empty((4, 4))
    for p in range(S.shape[0]):
        out[p] = _cond4(S[p], scratch)
