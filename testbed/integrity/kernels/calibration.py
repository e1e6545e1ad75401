"""The GPS calibration of the vision ranges (docs/design/integrity.md §8), every epoch."""

from __future__ import annotations

import sys

import numpy as np
from numba import njit

from testbed.integrity.kernels.small import _matmul, _offset_range, _sandwich, _tile_matmul, _tile_sandwich
from testbed.kernel_cache import keep_in_step


@njit(cache=True, nogil=True, error_model="numpy")
def calibrate_epochs(i0, m, A, B, Ap, Sc, SigV, used, x, Pg, off, p, Sd,
                     beta_out, beta0_out, Sh_out, Su_out):
    """GPS calibration of the vision ranges (docs/design/integrity.md §8), every epoch of every trial.

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
                d0, d1, d2, r0[l] = _offset_range(p[l, 0], p[l, 1], p[l, 2], x[b, k, 0] + off[b, k, 0],
                                                  x[b, k, 1] + off[b, k, 1], x[b, k, 2] + off[b, k, 2])
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
            _sandwich(MP0, Sc[b, k], Sh_out[b, t], tmp, True)
            _sandwich(Ld, Sd, Sh_out[b, t], tmp, True)
            _sandwich(AB, Sd, Su_out[b, t], tmp, True)
            _sandwich(MAH, Pg[b, k], Sh_out[b, t], tmp3, True)


#: epochs calibrated side by side by :func:`calibrate_tiles`
TILE = 64


@njit(cache=True, nogil=True, error_model="numpy")
def calibrate_tiles(i0, m, A, B, Ap, Sc, SigV, used, x, Pg, off, p, Sd, beta_out, beta0_out, Sh_out, Su_out):
    """:func:`calibrate_epochs`, epochs ``TILE`` at a time side by side: the same numbers bit for bit."""
    Bt, T, L = m.shape
    nc = B.shape[2]
    P = Bt * T
    xk, ok_, mk, uk = np.empty((3, TILE)), np.empty((3, TILE)), np.empty((L, TILE)), np.empty((L, TILE))
    Bt_, Bk, ratio = np.empty((nc, TILE)), np.empty((nc, TILE)), np.empty((nc, TILE))
    Apt, Apk, Ak = np.empty((L, nc, TILE)), np.empty((L, nc, TILE)), np.empty((nc, L, TILE))
    Sck, Sdt, P0 = np.empty((nc, nc, TILE)), np.empty((nc, nc, TILE)), np.empty((nc, nc, TILE))
    Pgk, H0, MAH, tmp3 = np.empty((3, 3, TILE)), np.empty((L, 3, TILE)), np.empty((L, 3, TILE)), np.empty((L, 3, TILE))
    SVt, MA0, Sh, Su = np.empty((L, L, TILE)), np.empty((L, L, TILE)), np.empty((L, L, TILE)), np.empty((L, L, TILE))
    M, AB, MP0 = np.empty((L, nc, TILE)), np.empty((L, nc, TILE)), np.empty((L, nc, TILE))
    Ld, tmp = np.empty((L, nc, TILE)), np.empty((L, nc, TILE))
    b0, bet, acc = np.empty((L, 1, TILE)), np.empty((L, 1, TILE)), np.empty(TILE)
    for q in range(TILE):
        Sdt[:, :, q] = Sd
    for p0 in range(0, P, TILE):
        n = min(TILE, P - p0)
        for q in range(n):  # -- gather: the epoch's own rows and its calibration epoch's
            b, t = divmod(p0 + q, T)
            k = i0[b, t]
            xk[:, q] = x[b, k]
            ok_[:, q] = off[b, k]
            mk[:, q] = m[b, k]
            for l in range(L):
                uk[l, q] = 1.0 if used[b, k, l] else 0.0
            Bt_[:, q] = B[b, t]
            Bk[:, q] = B[b, k]
            Apt[:, :, q] = Ap[b, t]
            Apk[:, :, q] = Ap[b, k]
            Ak[:, :, q] = A[b, k]
            Sck[:, :, q] = Sc[b, k]
            Pgk[:, :, q] = Pg[b, k]
            SVt[:, :, q] = SigV[b, t]
        for l in range(L):
            for q in range(n):
                d0, d1, d2, r0 = _offset_range(p[l, 0], p[l, 1], p[l, 2], xk[0, q] + ok_[0, q],
                                               xk[1, q] + ok_[1, q], xk[2, q] + ok_[2, q])
                u = uk[l, q]
                H0[l, 0, q] = -d0 / r0 * u
                H0[l, 1, q] = -d1 / r0 * u
                H0[l, 2, q] = -d2 / r0 * u
                be = mk[l, q] - r0 if u != 0.0 else 0.0
                b0[l, 0, q] = be if np.isfinite(be) else 0.0
        for c in range(nc):
            for q in range(n):
                v = Bt_[c, q] / Bk[c, q] if Bk[c, q] != 0.0 else 0.0
                ratio[c, q] = v if np.isfinite(v) else 0.0
        for l in range(L):
            for c in range(nc):
                for q in range(n):
                    M[l, c, q] = Apt[l, c, q] * ratio[c, q]
                    AB[l, c, q] = Apt[l, c, q] * Bt_[c, q]
        _tile_matmul(n, M, Ak, MA0, acc, False)
        _tile_matmul(n, MA0, b0, bet, acc, False)
        _tile_matmul(n, Ak, Apk, P0, acc, False)
        _tile_matmul(n, M, P0, MP0, acc, False)
        _tile_matmul(n, MA0, H0, MAH, acc, False)
        for l in range(L):
            for c in range(nc):
                for q in range(n):
                    Ld[l, c, q] = AB[l, c, q] - MP0[l, c, q] * Bk[c, q]
        Sh[:, :, :n] = SVt[:, :, :n]
        Su[:, :, :n] = SVt[:, :, :n]
        _tile_sandwich(n, MP0, Sck, Sh, tmp, acc, True)
        _tile_sandwich(n, Ld, Sdt, Sh, tmp, acc, True)
        _tile_sandwich(n, AB, Sdt, Su, tmp, acc, True)
        _tile_sandwich(n, MAH, Pgk, Sh, tmp3, acc, True)
        for q in range(n):  # -- scatter
            b, t = divmod(p0 + q, T)
            beta_out[b, t] = bet[:, 0, q]
            beta0_out[b, t] = b0[:, 0, q]
            Sh_out[b, t] = Sh[:, :, q]
            Su_out[b, t] = Su[:, :, q]


# numba compiles a kernel again when its own file changes, not when a helper's does
keep_in_step(sys.modules[__name__])
