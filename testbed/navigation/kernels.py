"""The EKF predict as one compiled loop over trials (numba): the same equations as :func:`.ekf.predict`.

:func:`.ekf.predict` is the readable numpy form (and the reference the tests hold
this to, to round-off); this kernel is what the filter runs: at a batch of one (a
live flight) numpy spends ~0.6 ms of dispatch per IMU step, the kernel ~15 µs.
"""

from __future__ import annotations

import sys

import numpy as np
from numba import njit

from testbed.kernel_cache import keep_in_step

# WGS84 (testbed.inertial): normal gravity and Bowring's latitude
_GE, _K, _E2 = 9.7803253359, 0.00193185265241, 6.69437999014e-3
_A, _F, _M = 6378137.0, 1.0 / 298.257223563, 0.00344978650684
_R_EARTH = 6_371_000.0


def _transition_pattern() -> tuple[np.ndarray, np.ndarray]:
    """Where Φ (:func:`.ekf.transition`) can be non-zero, as CSR row pointers and columns: 99 of 289
    entries, so the covariance sandwich costs a third of the dense one."""
    m = np.eye(17, dtype=bool)
    m[0:3, 3:6] |= np.eye(3, dtype=bool)  # p ← v dt
    m[0:3, 6:15] = True  # p ← ψ, b_a, b_g
    m[3:6, 0:3] |= np.eye(3, dtype=bool)  # v ← p (gravity gradient, diagonal)
    m[3:6, 3:15] = True  # v ← v (Coriolis), ψ, b_a, b_g
    m[6:9, 6:9] = True  # ψ ← ψ (Earth rate)
    m[6:9, 12:15] = True  # ψ ← b_g
    m[15, 16] = True  # clock bias ← drift
    rows, cols = np.nonzero(m)
    return np.searchsorted(rows, np.arange(18)).astype(np.int64), cols.astype(np.int64)


_PTR, _COLS = _transition_pattern()


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _phi_left(Phi, M, out):
    """out = Φ M over Φ's pattern."""
    n = M.shape[0]
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for q in range(_PTR[i], _PTR[i + 1]):
                c = _COLS[q]
                acc += Phi[i, c] * M[c, j]
            out[i, j] = acc


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _times_phi_t_symmetric(A, Phi, out):
    """out = A Φᵀ, known symmetric (A = Φ M with M symmetric): the upper triangle, mirrored."""
    n = A.shape[0]
    for i in range(n):
        for j in range(i, n):
            acc = 0.0
            for q in range(_PTR[j], _PTR[j + 1]):
                c = _COLS[q]
                acc += A[i, c] * Phi[j, c]
            out[i, j] = acc
            out[j, i] = acc


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _exp(phi, out):
    a2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    if a2 < 1e-12:
        s = 1.0 - a2 / 6.0
        c = 0.5 - a2 / 24.0
    else:
        a = np.sqrt(a2)
        s = np.sin(a) / a
        c = (1.0 - np.cos(a)) / a2
    x, y, z = phi[0], phi[1], phi[2]
    out[0, 0] = 1.0 - c * (y * y + z * z)
    out[1, 1] = 1.0 - c * (x * x + z * z)
    out[2, 2] = 1.0 - c * (x * x + y * y)
    out[0, 1] = -s * z + c * x * y
    out[1, 0] = s * z + c * x * y
    out[0, 2] = s * y + c * x * z
    out[2, 0] = -s * y + c * x * z
    out[1, 2] = -s * x + c * y * z
    out[2, 1] = s * x + c * y * z


@njit(cache=True, nogil=True, error_model="numpy")
def _gravity(p, R, origin, out):
    """Normal gravity in the world frame at world position p (testbed.inertial.gravity_world)."""
    e0 = origin[0] + R[0, 0] * p[0] + R[1, 0] * p[1] + R[2, 0] * p[2]
    e1 = origin[1] + R[0, 1] * p[0] + R[1, 1] * p[1] + R[2, 1] * p[2]
    e2 = origin[2] + R[0, 2] * p[0] + R[1, 2] * p[1] + R[2, 2] * p[2]
    b = _A * (1.0 - _F)
    ep2 = (_A * _A - b * b) / (b * b)
    r = np.hypot(e0, e1)
    u = np.arctan2(e2 * _A, r * b)
    lat = np.arctan2(e2 + ep2 * b * np.sin(u) ** 3, r - _E2 * _A * np.cos(u) ** 3)
    sl, cl = np.sin(lat), np.cos(lat)
    n = _A / np.sqrt(1.0 - _E2 * sl * sl)
    h = r * cl + e2 * sl - n * (1.0 - _E2 * sl * sl)
    s2 = sl * sl
    g0 = _GE * (1.0 + _K * s2) / np.sqrt(1.0 - _E2 * s2)
    g = g0 * (1.0 - 2.0 / _A * (1.0 + _F + _M - 2.0 * _F * s2) * h + 3.0 / (_A * _A) * h * h)
    u0, u1 = cl * e0 / r, cl * e1 / r  # cos φ (cos λ, sin λ)
    for i in range(3):
        out[i] = -g * (R[i, 0] * u0 + R[i, 1] * u1 + R[i, 2] * sl)
    return g


@njit(cache=True, nogil=True, error_model="numpy")
def predict_batch(C, v, p, ba, bg, cb, cd, P, dtheta, dvel, dt, R, origin, w_ie, E, arw, vrw, sg_in, sa_in,
                  tau_g, tau_a, clk_sf, clk_sg, Phi_acc, accumulate):
    """One IMU step of every trial, in place (arrays (B, ...) as :class:`.ekf.NavState`); with ``accumulate``,
    also ``Phi_acc[b] ← Φ Phi_acc[b]`` (the transition over several steps, for the sub-filter bank)."""
    B = C.shape[0]
    n = 17
    a_a, a_g = np.exp(-dt / tau_a), np.exp(-dt / tau_g)
    Phi = np.zeros((n, n))
    Qc = np.zeros((n, n))
    G = np.empty((n, n))
    tmp = np.empty((n, n))
    PP = np.empty((n, n))
    Ed = np.empty((3, 3))
    C1 = np.empty((3, 3))
    Cm = np.empty((3, 3))
    g = np.empty(3)
    dth = np.empty(3)
    dv = np.empty(3)
    f = np.empty(3)
    cor = np.empty(3)
    v1 = np.empty(3)
    Fx = np.zeros((3, 3))
    FxC = np.empty((3, 3))
    CCt = np.empty((3, 3))
    W = np.array([[0.0, -w_ie[2], w_ie[1]], [w_ie[2], 0.0, -w_ie[0]], [-w_ie[1], w_ie[0], 0.0]])
    for b in range(B):
        for i in range(3):
            dth[i] = dtheta[b, i] - bg[b, i] * dt
            dv[i] = dvel[b, i] - ba[b, i] * dt
        gm = _gravity(p[b], R, origin, g)
        _exp(dth, Ed)
        # C1 = E C Exp(dθ)
        for i in range(3):
            for j in range(3):
                acc = 0.0
                for k in range(3):
                    s = 0.0
                    for m in range(3):
                        s += E[i, m] * C[b, m, k]
                    acc += s * Ed[k, j]
                C1[i, j] = acc
        for i in range(3):
            for j in range(3):
                Cm[i, j] = 0.5 * (C[b, i, j] + C1[i, j])
        cor[0] = w_ie[1] * v[b, 2] - w_ie[2] * v[b, 1]
        cor[1] = w_ie[2] * v[b, 0] - w_ie[0] * v[b, 2]
        cor[2] = w_ie[0] * v[b, 1] - w_ie[1] * v[b, 0]
        for i in range(3):
            f[i] = (Cm[i, 0] * dv[0] + Cm[i, 1] * dv[1] + Cm[i, 2] * dv[2]) / dt
            v1[i] = v[b, i] + f[i] * dt + (g[i] - 2.0 * cor[i]) * dt
        # transition (testbed.navigation.ekf.transition)
        Phi[:, :] = 0.0
        for i in range(n):
            Phi[i, i] = 1.0
        Fx[0, 1], Fx[0, 2], Fx[1, 0], Fx[1, 2], Fx[2, 0], Fx[2, 1] = -f[2], f[1], f[2], -f[0], -f[1], f[0]
        for i in range(3):
            for j in range(3):
                FxC[i, j] = Fx[i, 0] * Cm[0, j] + Fx[i, 1] * Cm[1, j] + Fx[i, 2] * Cm[2, j]
        for i in range(3):
            Phi[i, 3 + i] = dt
            for j in range(3):
                Phi[i, 6 + j] = -0.5 * dt * dt * Fx[i, j]
                Phi[i, 9 + j] = -0.5 * dt * dt * Cm[i, j]
                Phi[i, 12 + j] = dt * dt * dt / 6.0 * FxC[i, j]
                Phi[3 + i, 3 + j] -= 2.0 * dt * W[i, j]
                Phi[3 + i, 6 + j] = -dt * Fx[i, j]
                Phi[3 + i, 9 + j] = -dt * Cm[i, j]
                Phi[3 + i, 12 + j] = 0.5 * dt * dt * FxC[i, j]
                Phi[6 + i, 6 + j] -= dt * W[i, j]
                Phi[6 + i, 12 + j] = -dt * Cm[i, j]
            Phi[9 + i, 9 + i] = a_a
            Phi[12 + i, 12 + i] = a_g
        Phi[3, 0] = -dt * gm / _R_EARTH
        Phi[4, 1] = -dt * gm / _R_EARTH
        Phi[5, 2] = 2.0 * dt * gm / _R_EARTH
        Phi[15, 16] = dt
        # continuous noise (G Q_c Gᵀ), with the step's start attitude
        Qc[:, :] = 0.0
        for i in range(3):
            for j in range(3):
                acc = 0.0
                for k in range(3):
                    acc += C[b, i, k] * C[b, j, k]
                CCt[i, j] = acc
        for i in range(3):
            for j in range(3):
                Qc[3 + i, 3 + j] = vrw * vrw * CCt[i, j]
                Qc[6 + i, 6 + j] = arw * arw * CCt[i, j]
            Qc[9 + i, 9 + i] = 2.0 * sa_in * sa_in / tau_a
            Qc[12 + i, 12 + i] = 2.0 * sg_in * sg_in / tau_g
        # Q = ½(Φ Qc Φᵀ + Qc) dt, the clock's exactly: P ← Φ(P + ½Qc dt)Φᵀ + ½Qc dt + Q_clock, one
        # sandwich over Φ's pattern (Qc has no clock rows, so neither has its part of Q)
        for i in range(n):
            for j in range(n):
                G[i, j] = P[b, i, j] + 0.5 * dt * Qc[i, j]
        _phi_left(Phi, G, tmp)
        _times_phi_t_symmetric(tmp, Phi, PP)
        for i in range(n):
            for j in range(n):
                P[b, i, j] = PP[i, j] + 0.5 * dt * Qc[i, j]
        P[b, 15, 15] += clk_sf * dt + clk_sg * dt ** 3 / 3.0
        P[b, 15, 16] += clk_sg * dt * dt / 2.0
        P[b, 16, 15] += clk_sg * dt * dt / 2.0
        P[b, 16, 16] += clk_sg * dt
        if accumulate:
            _phi_left(Phi, Phi_acc[b], tmp)
            Phi_acc[b] = tmp
        for i in range(3):
            p[b, i] = p[b, i] + 0.5 * (v[b, i] + v1[i]) * dt
            v[b, i] = v1[i]
            ba[b, i] = a_a * ba[b, i]
            bg[b, i] = a_g * bg[b, i]
            for j in range(3):
                C[b, i, j] = C1[i, j]
        cb[b] = cb[b] + cd[b] * dt


# numba compiles a kernel again when its own file changes, not when a helper's does
keep_in_step(sys.modules[__name__])
