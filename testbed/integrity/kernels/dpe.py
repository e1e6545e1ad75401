"""Compiled DPE manifold: candidate delays -> correlogram lookups -> likelihood (docs/design/dpe.md §3).

Per satellite k the candidate ξ (4 offsets) has delay ``c_k + H_k·ξ`` on its correlogram
(``poly[k]``, index units); the manifold is Σ_k f_k(delay). The lookup is Keys' cubic
convolution (a = −0.5), read from per-interval polynomials; ``cubic`` False: linear.
A delay outside the table's safe range reads the satellite's noise floor ``floor[k]``
(no signal there, so it cannot favour a candidate). :func:`manifold_numpy` in :mod:`testbed.integrity.dpe.manifold` is the plain
reference these kernels equal to rounding.
"""

from __future__ import annotations

import sys

import numpy as np
from numba import njit, prange

from testbed.kernel_cache import keep_in_step


@njit(cache=True, inline="always")
def _lookup(f, pos, floor, cubic):
    """f: (M, 4) the interval polynomials of :func:`interval_polynomials` (Horner in t)."""
    M = f.shape[0]
    if not (pos >= 1.0 and pos < M - 3.0):
        return floor
    i = int(pos)
    t = pos - i
    if cubic:
        return ((f[i, 3] * t + f[i, 2]) * t + f[i, 1]) * t + f[i, 0]
    return f[i, 0] + t * (f[i + 1, 0] - f[i, 0])


def interval_polynomials(table: np.ndarray) -> np.ndarray:
    """(S, M, 4) Keys' cubic on each interval [j, j + 1] as c0 + c1·t + c2·t² + c3·t³ (one cache line
    a lookup; c0 = f[j], so the linear lookup reads the same array). Edge intervals copy the edge."""
    f = np.asarray(table, np.float64)
    fp = np.concatenate([f[:, :1], f, f[:, -1:], f[:, -1:]], axis=1)  # f[-1], f[0..M-1], f[M], f[M+1]
    fm, f0, f1, f2 = fp[:, :-3], fp[:, 1:-2], fp[:, 2:-1], fp[:, 3:]
    return np.ascontiguousarray(np.stack([f0, 0.5 * (f1 - fm), fm - 2.5 * f0 + 2.0 * f1 - 0.5 * f2,
                                          -0.5 * fm + 1.5 * f0 - 1.5 * f1 + 0.5 * f2], axis=-1))


@njit(cache=True, inline="always")
def _product_slab(c, H, poly, floor, x0, x1, x2, x3, cubic, out, i0):
    """The candidates of the product grid x0 × x1 × x2 × x3 with first index i0, satellite by
    satellite (its polynomials stay in the first-level cache)."""
    n1, n2, n3 = x1.shape[0], x2.shape[0], x3.shape[0]
    size = n1 * n2 * n3
    for q in range(i0 * size, (i0 + 1) * size):
        out[q] = 0.0
    for k in range(c.shape[0]):
        f = poly[k]
        fl = floor[k]
        p0 = c[k] + H[k, 0] * x0[i0]
        q = i0 * size
        for i1 in range(n1):
            p1 = p0 + H[k, 1] * x1[i1]
            for i2 in range(n2):
                p2 = p1 + H[k, 2] * x2[i2]
                for i3 in range(n3):
                    out[q] += _lookup(f, p2 + H[k, 3] * x3[i3], fl, cubic)
                    q += 1


@njit(cache=True, nogil=True)
def manifold_product(c, H, poly, floor, x0, x1, x2, x3, cubic, out):
    """The manifold on the product grid x0 × x1 × x2 × x3 (any nodes per axis; out C order)."""
    for i0 in range(x0.shape[0]):
        _product_slab(c, H, poly, floor, x0, x1, x2, x3, cubic, out, i0)


@njit(cache=True, nogil=True)
def _box_axis(spacing, n):
    return (np.arange(n) - (n - 1) / 2.0) * spacing


@njit(cache=True, nogil=True)
def manifold_box(c, H, poly, floor, spacing, n, cubic, out):
    """The manifold on the box ξ_a = (i_a − (n−1)/2)·spacing, i_a < n (out: n⁴, C order)."""
    a = _box_axis(spacing, n)
    manifold_product(c, H, poly, floor, a, a, a, a, cubic, out)


@njit(cache=True, parallel=True)
def manifold_box_threads(c, H, poly, floor, spacing, n, cubic, out):
    """:func:`manifold_box` with the first axis's slabs on numba's threads (identical numbers)."""
    a = _box_axis(spacing, n)
    for i0 in prange(n):
        _product_slab(c, H, poly, floor, a, a, a, a, cubic, out, i0)


@njit(cache=True, nogil=True)
def weighted_mean_product(values, x0, x1, x2, x3):
    """Σ v·ξ / Σ v over the product grid (the seed's solution: the manifold as weights)."""
    tot = 0.0
    m = np.zeros(4)
    q = 0
    for i0 in range(x0.shape[0]):
        for i1 in range(x1.shape[0]):
            for i2 in range(x2.shape[0]):
                for i3 in range(x3.shape[0]):
                    v = values[q]
                    tot += v
                    m[0] += v * x0[i0]
                    m[1] += v * x1[i1]
                    m[2] += v * x2[i2]
                    m[3] += v * x3[i3]
                    q += 1
    return m / tot


@njit(cache=True, nogil=True, inline="always")
def _moment_slab(lam, spacing, n, weights, top, i0, acc):
    """Slab i0 of the posterior's sums into ``acc``: Σw, Σw·z (4), the upper triangle of Σw·z zᵀ (4×4)."""
    half = (n - 1) / 2.0
    z0 = (i0 - half) * spacing
    q = i0 * n * n * n
    for i1 in range(n):
        z1 = (i1 - half) * spacing
        for i2 in range(n):
            z2 = (i2 - half) * spacing
            # the i3 axis summed first: per (i0, i1, i2) line, Σw, Σw·z3, Σw·z3²
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            for i3 in range(n):
                z3 = (i3 - half) * spacing
                w = np.exp(lam[q] - top)
                weights[q] = w
                s0 += w
                s1 += w * z3
                s2 += w * z3 * z3
                q += 1
            acc[0] += s0
            acc[1] += s0 * z0
            acc[2] += s0 * z1
            acc[3] += s0 * z2
            acc[4] += s1
            acc[5] += s0 * z0 * z0
            acc[6] += s0 * z0 * z1
            acc[7] += s0 * z0 * z2
            acc[8] += s1 * z0
            acc[10] += s0 * z1 * z1
            acc[11] += s0 * z1 * z2
            acc[12] += s1 * z1
            acc[15] += s0 * z2 * z2
            acc[16] += s1 * z2
            acc[20] += s2


@njit(cache=True, nogil=True, inline="always")
def _moments_from_slabs(part):
    """Slab sums added in index order: (Σw, mean (4), second moments (4, 4)), box units."""
    tot = 0.0
    mean = np.zeros(4)
    sec = np.zeros((4, 4))
    for i0 in range(part.shape[0]):
        tot += part[i0, 0]
        for a in range(4):
            mean[a] += part[i0, 1 + a]
            for b in range(a, 4):
                sec[a, b] += part[i0, 5 + 4 * a + b]
    for a in range(4):
        for b in range(a):
            sec[a, b] = sec[b, a]
    return tot, mean / tot, sec / tot


@njit(cache=True, nogil=True)
def posterior_moments(lam, spacing, n, weights):
    """Weights exp(Λ − max) on the n⁴ box (into ``weights``): (Σw, mean (4), second moments (4, 4)), box units.

    Summed slab by slab (first axis) and the slabs added in order, as :func:`posterior_moments_threads`
    does on threads: the two give the same numbers, bit for bit.
    """
    top = lam.max()
    part = np.zeros((n, 21))
    for i0 in range(n):
        _moment_slab(lam, spacing, n, weights, top, i0, part[i0])
    return _moments_from_slabs(part)


@njit(cache=True, parallel=True)
def posterior_moments_threads(lam, spacing, n, weights):
    """:func:`posterior_moments` with the slabs on numba's threads (the same numbers for any thread count)."""
    top = lam.max()
    part = np.zeros((n, 21))
    for i0 in prange(n):
        _moment_slab(lam, spacing, n, weights, top, i0, part[i0])
    return _moments_from_slabs(part)


@njit(cache=True, nogil=True, inline="always")
def _deposit_slab(weights, spacing, n, coef, origin, width, i0, row):
    """Slab i0's weights onto ``row`` (linear shares) along u = coef·z − origin."""
    half = (n - 1) / 2.0
    nb = row.shape[0]
    mid = (nb - 1) / 2.0
    step3 = coef[3] * spacing / width
    q = i0 * n * n * n
    for i1 in range(n):
        for i2 in range(n):
            u0 = ((coef[0] * (i0 - half) + coef[1] * (i1 - half) + coef[2] * (i2 - half) - coef[3] * half) * spacing
                  - origin) / width + mid
            for i3 in range(n):
                p = u0 + i3 * step3
                j = int(np.floor(p))
                f = p - j
                w = weights[q]
                if j >= 0 and j < nb:
                    row[j] += w * (1.0 - f)
                if j + 1 >= 0 and j + 1 < nb:
                    row[j + 1] += w * f
                q += 1


@njit(cache=True, nogil=True, inline="always")
def _bins_from_slabs(part, bins):
    for j in range(bins.shape[0]):
        s = 0.0
        for i0 in range(part.shape[0]):
            s += part[i0, j]
        bins[j] = s


@njit(cache=True, nogil=True)
def deposit_marginal(weights, spacing, n, coef, origin, width, bins):
    """Deposit the box's weights onto ``bins`` (linear shares) along u = coef·z − origin.

    Bin j covers the u values centred on (j − (nb − 1)/2)·width. Slab by slab, the slabs' bins added in
    order (as :func:`deposit_marginal_threads`: the same numbers, bit for bit).
    """
    part = np.zeros((n, bins.shape[0]))
    for i0 in range(n):
        _deposit_slab(weights, spacing, n, coef, origin, width, i0, part[i0])
    _bins_from_slabs(part, bins)


@njit(cache=True, parallel=True)
def deposit_marginal_threads(weights, spacing, n, coef, origin, width, bins):
    """:func:`deposit_marginal` with the slabs on numba's threads (the same numbers for any thread count)."""
    part = np.zeros((n, bins.shape[0]))
    for i0 in prange(n):
        _deposit_slab(weights, spacing, n, coef, origin, width, i0, part[i0])
    _bins_from_slabs(part, bins)


# numba compiles a kernel again when its own file changes, not when a helper's does
keep_in_step(sys.modules[__name__])
