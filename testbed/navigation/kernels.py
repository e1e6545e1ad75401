"""The EKF predict as one compiled loop over trials (numba): the same equations as :func:`.ekf.predict`.

:func:`.ekf.predict` is the readable numpy form (and the reference the tests hold
this to, to round-off); this kernel is what the filter runs: at a batch of one (a
live flight) numpy spends ~0.6 ms of dispatch per IMU step, the kernel ~15 µs.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# WGS84 (testbed.inertial): normal gravity and Bowring's latitude
_GE, _K, _E2 = 9.7803253359, 0.00193185265241, 6.69437999014e-3
_A, _F, _M = 6378137.0, 1.0 / 298.257223563, 0.00344978650684
_R_EARTH = 6_371_000.0


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
    e = np.empty(3)
    for i in range(3):
        e[i] = origin[i] + R[0, i] * p[0] + R[1, i] * p[1] + R[2, i] * p[2]
    b = _A * (1.0 - _F)
    ep2 = (_A * _A - b * b) / (b * b)
    r = np.hypot(e[0], e[1])
    u = np.arctan2(e[2] * _A, r * b)
    lat = np.arctan2(e[2] + ep2 * b * np.sin(u) ** 3, r - _E2 * _A * np.cos(u) ** 3)
    lon = np.arctan2(e[1], e[0])
    sl, cl = np.sin(lat), np.cos(lat)
    n = _A / np.sqrt(1.0 - _E2 * sl * sl)
    h = r * cl + e[2] * sl - n * (1.0 - _E2 * sl * sl)
    s2 = sl * sl
    g0 = _GE * (1.0 + _K * s2) / np.sqrt(1.0 - _E2 * s2)
    g = g0 * (1.0 - 2.0 / _A * (1.0 + _F + _M - 2.0 * _F * s2) * h + 3.0 / (_A * _A) * h * h)
    up = np.array([cl * np.cos(lon), cl * np.sin(lon), sl])
    for i in range(3):
        out[i] = -g * (R[i, 0] * up[0] + R[i, 1] * up[1] + R[i, 2] * up[2])
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
    Ed = np.empty((3, 3))
    C1 = np.empty((3, 3))
    Cm = np.empty((3, 3))
    g = np.empty(3)
    dth = np.empty(3)
    dv = np.empty(3)
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
        f = np.empty(3)
        cor = np.empty(3)
        cor[0] = w_ie[1] * v[b, 2] - w_ie[2] * v[b, 1]
        cor[1] = w_ie[2] * v[b, 0] - w_ie[0] * v[b, 2]
        cor[2] = w_ie[0] * v[b, 1] - w_ie[1] * v[b, 0]
        v1 = np.empty(3)
        for i in range(3):
            f[i] = (Cm[i, 0] * dv[0] + Cm[i, 1] * dv[1] + Cm[i, 2] * dv[2]) / dt
            v1[i] = v[b, i] + f[i] * dt + (g[i] - 2.0 * cor[i]) * dt
        # transition (testbed.navigation.ekf.transition)
        Phi[:, :] = 0.0
        for i in range(n):
            Phi[i, i] = 1.0
        Fx = np.array([[0.0, -f[2], f[1]], [f[2], 0.0, -f[0]], [-f[1], f[0], 0.0]])
        W = np.array([[0.0, -w_ie[2], w_ie[1]], [w_ie[2], 0.0, -w_ie[0]], [-w_ie[1], w_ie[0], 0.0]])
        FxC = Fx @ Cm
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
        CCt = np.zeros((3, 3))
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
        # Q = ½(Φ Qc Φᵀ + Qc) dt, the clock's exactly; P = Φ P Φᵀ + Q
        G[:, :] = Phi @ Qc
        tmp[:, :] = G @ Phi.T
        Pb = P[b]
        PP = Phi @ Pb @ Phi.T
        for i in range(n):
            for j in range(n):
                q = 0.5 * (tmp[i, j] + Qc[i, j]) * dt
                if i >= 15 or j >= 15:
                    q = 0.0
                PP[i, j] += q
        PP[15, 15] += clk_sf * dt + clk_sg * dt ** 3 / 3.0
        PP[15, 16] += clk_sg * dt * dt / 2.0
        PP[16, 15] += clk_sg * dt * dt / 2.0
        PP[16, 16] += clk_sg * dt
        for i in range(n):
            for j in range(n):
                P[b, i, j] = 0.5 * (PP[i, j] + PP[j, i])
        if accumulate:
            Phi_acc[b] = Phi @ Phi_acc[b]
        for i in range(3):
            p[b, i] = p[b, i] + 0.5 * (v[b, i] + v1[i]) * dt
            v[b, i] = v1[i]
            ba[b, i] = a_a * ba[b, i]
            bg[b, i] = a_g * bg[b, i]
            for j in range(3):
                C[b, i, j] = C1[i, j]
        cb[b] = cb[b] + cd[b] * dt
