"""Compiled DPE manifold: candidate delays -> correlogram lookups -> likelihood (DPE.md §2-§3).

Per satellite k the candidate ξ (4 offsets) has delay ``c_k + H_k·ξ`` on its correlogram
(``table[k]``, index units); the manifold is Σ_k f_k(delay). The lookup is Keys' cubic
convolution (a = −0.5; ``cubic`` False: linear). A delay outside the table's safe range
reads the satellite's noise floor ``floor[k]`` (no signal there, so it cannot favour a
candidate). :func:`manifold_numpy` in :mod:`testbed.integrity.dpe.manifold` is the plain
reference these kernels equal to rounding.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, inline="always")
def _keys(f, i, t):
    t2 = t * t
    t3 = t2 * t
    wm = -0.5 * t3 + t2 - 0.5 * t
    w0 = 1.5 * t3 - 2.5 * t2 + 1.0
    w1 = -1.5 * t3 + 2.0 * t2 + 0.5 * t
    w2 = 0.5 * t3 - 0.5 * t2
    return wm * f[i - 1] + w0 * f[i] + w1 * f[i + 1] + w2 * f[i + 2]


@njit(cache=True, inline="always")
def _lookup(f, pos, floor, cubic):
    M = f.shape[0]
    if not (pos >= 1.0 and pos < M - 3.0):
        return floor
    i = int(pos)
    t = pos - i
    if cubic:
        return _keys(f, i, t)
    return (1.0 - t) * f[i] + t * f[i + 1]


@njit(cache=True)
def manifold_points(c, H, table, floor, X, cubic, out):
    """out[n] = Σ_k f_k(c_k + H_k·X[n]) for candidates X (N, 4); c, H in index units."""
    S = c.shape[0]
    for n in range(X.shape[0]):
        s = 0.0
        x0, x1, x2, x3 = X[n, 0], X[n, 1], X[n, 2], X[n, 3]
        for k in range(S):
            pos = c[k] + H[k, 0] * x0 + H[k, 1] * x1 + H[k, 2] * x2 + H[k, 3] * x3
            s += _lookup(table[k], pos, floor[k], cubic)
        out[n] = s


@njit(cache=True)
def manifold_box(c, H, table, floor, spacing, n, cubic, out):
    """The manifold on the product grid ξ_a = (i_a − (n−1)/2)·spacing, i_a < n (out: n⁴, C order).

    The per-axis delay increments are summed incrementally (the lookups dominate).
    """
    S = c.shape[0]
    half = (n - 1) / 2.0
    q = 0
    for i0 in range(n):
        for i1 in range(n):
            for i2 in range(n):
                for i3 in range(n):
                    z0, z1, z2, z3 = (i0 - half) * spacing, (i1 - half) * spacing, (i2 - half) * spacing, (i3 - half) * spacing
                    s = 0.0
                    for k in range(S):
                        pos = c[k] + H[k, 0] * z0 + H[k, 1] * z1 + H[k, 2] * z2 + H[k, 3] * z3
                        s += _lookup(table[k], pos, floor[k], cubic)
                    out[q] = s
                    q += 1


@njit(cache=True, parallel=True)
def manifold_boxes(c, H, table, floor, spacing, n, cubic, out):
    """:func:`manifold_box` for a batch of epochs (E, ...) -> out (E, n⁴), one thread per epoch."""
    for e in prange(c.shape[0]):
        manifold_box(c[e], H[e], table[e], floor[e], spacing, n, cubic, out[e])


@njit(cache=True)
def posterior_moments(lam, spacing, n):
    """Weights exp(Λ − max) on the n⁴ box: (Σw, mean (4), second moments (4, 4)) in box units."""
    half = (n - 1) / 2.0
    top = lam.max()
    tot = 0.0
    mean = np.zeros(4)
    sec = np.zeros((4, 4))
    z = np.zeros(4)
    q = 0
    for i0 in range(n):
        for i1 in range(n):
            for i2 in range(n):
                for i3 in range(n):
                    w = np.exp(lam[q] - top)
                    z[0], z[1], z[2], z[3] = (i0 - half) * spacing, (i1 - half) * spacing, (i2 - half) * spacing, (i3 - half) * spacing
                    tot += w
                    for a in range(4):
                        mean[a] += w * z[a]
                        for b in range(4):
                            sec[a, b] += w * z[a] * z[b]
                    q += 1
    return tot, mean / tot, sec / tot


@njit(cache=True)
def deposit_marginal(lam, spacing, n, coef, origin, width, bins):
    """Deposit exp(Λ − max) of the n⁴ box onto ``bins`` (linear shares) along u = coef·z − origin.

    Bin j covers the u values centred on (j − (nb − 1)/2)·width.
    """
    half = (n - 1) / 2.0
    top = lam.max()
    nb = bins.shape[0]
    mid = (nb - 1) / 2.0
    for j in range(nb):
        bins[j] = 0.0
    q = 0
    for i0 in range(n):
        for i1 in range(n):
            for i2 in range(n):
                for i3 in range(n):
                    u = (coef[0] * (i0 - half) + coef[1] * (i1 - half) + coef[2] * (i2 - half)
                         + coef[3] * (i3 - half)) * spacing - origin
                    p = u / width + mid
                    j = int(np.floor(p))
                    f = p - j
                    w = np.exp(lam[q] - top)
                    if j >= 0 and j < nb:
                        bins[j] += w * (1.0 - f)
                    if j + 1 >= 0 and j + 1 < nb:
                        bins[j + 1] += w * f
                    q += 1
