"""The `likelihood` DPE solution of one epoch: coarse-to-fine grids, posterior, vertical marginal (docs/design/dpe.md §3).

1. 9⁴ candidates at 30 m about the initialisation -> the best node (recentred while it is
   on a face, at most 3 times);
2. 9⁴ at 6 m about it -> the best node + a per-axis quadratic refine;
3. the whitened grid x = x̂ + L·z, L·Lᵀ = J_CRB (from the receiver's C/N0 estimates),
   z on 17⁴ nodes at 0.6875 (±5.5σ along every principal direction; a ±4.4σ grid at 0.55 left
   0.1-1 % of the posterior on its faces, cutting the tails the overbound reads): it follows the
   U-clock correlation the box grids would waste candidates on. Recentred on the best node
   while that is on a face (≤ 3 times). When the CRB is much finer than stage 2 resolves
   (high C/N0), whitened 9⁴ grids zoom in first, ×¼ a step (docs/design/dpe.md §3.3:
   without them the peak leaves the fine grid's face above ~50 dB-Hz).

The posterior is L = exp(Λ − max Λ) on the whitened grid (a uniform prior over it; the
grid cells have equal volume, so plain weighted sums are integrals). Its mean is the
solution; the vertical marginal p(e), e = Û − U, is deposited onto bins of 0.25·√J_UU.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from testbed.correlation import crb_delay_sigma
from testbed.integrity.dpe.manifold import EpochManifold
from testbed.integrity.kernels.dpe import (deposit_marginal, deposit_marginal_threads, manifold_box,
                                         manifold_box_threads, posterior_moments, posterior_moments_threads)


class Status(IntEnum):
    OK = 0
    FEW_SATELLITES = 1
    PEAK_AT_EDGE = 2


@dataclass(frozen=True)
class GridPlan:
    """The three stages' spacing and nodes per axis, the recentring budget and the marginal's bins."""

    coarse_m: float = 30.0
    coarse_n: int = 9
    mid_m: float = 6.0
    mid_n: int = 9
    fine_z: float = 0.6875
    fine_n: int = 17
    max_recentre: int = 3
    bins: int = 161
    bin_sigma: float = 0.25


@dataclass(frozen=True)
class EpochSolution:
    """One epoch's DPE (offsets from the initialisation; NaN when ``status`` is not OK).

    x_mean, x_ml : (4,) posterior mean / best node.  cov : (4, 4) posterior covariance.
    J : (4, 4) the CRB.  offsets, marginal : (bins,) the vertical error marginal (m, mass).
    recentred : recentrings used.  used : (S,) satellites kept.  face_mass : the posterior's share on
    the fine grid's boundary faces (large when the posterior is wider than the CRB the grid was cut for).
    """

    status: Status
    x_mean: NDArray
    x_ml: NDArray
    cov: NDArray
    J: NDArray
    offsets: NDArray
    marginal: NDArray
    recentred: int
    used: NDArray
    face_mass: float = float("nan")


def _best_node(lam: NDArray, n: int) -> tuple[NDArray, bool]:
    q = int(np.argmax(lam))
    idx = np.array(np.unravel_index(q, (n,) * 4))
    return idx - (n - 1) / 2.0, bool(np.any((idx == 0) | (idx == n - 1)))


def _box_search(mf: EpochManifold, centre: NDArray, axes: NDArray, spacing: float, n: int, budget: int, cubic: bool,
                threaded: bool = False):
    """The best node of an n⁴ box about ``centre`` (recentred while on a face): (centre, lam, node, faces, used)."""
    out = np.empty(n ** 4)
    kernel = manifold_box_threads if threaded else manifold_box
    for used in range(budget + 1):
        c, H = mf.index_units(centre, axes)
        kernel(c, H, mf.poly, mf.floor, spacing, n, cubic, out)
        node, on_face = _best_node(out, n)
        if not on_face:
            return centre, out, node, False, used
        if used < budget:
            centre = centre + axes @ (node * spacing)
    return centre, out, node, True, budget


def _quadratic_refine(lam: NDArray, node: NDArray, n: int) -> NDArray:
    """Per-axis parabola vertex through the best node and its neighbours (in node units, |·| ≤ ½)."""
    box = lam.reshape((n,) * 4)
    i = tuple(int(v) for v in node + (n - 1) / 2.0)
    step = np.zeros(4)
    for a in range(4):
        lo, hi = list(i), list(i)
        lo[a] -= 1
        hi[a] += 1
        fm, f0, fp = box[tuple(lo)], box[i], box[tuple(hi)]
        curv = fm - 2.0 * f0 + fp
        if curv < 0.0:
            step[a] = np.clip(0.5 * (fm - fp) / curv, -0.5, 0.5)
    return step


def _zoom(mf: EpochManifold, centre: NDArray, L: NDArray, plan: GridPlan, threaded: bool) -> tuple[NDArray, int]:
    """Whitened 9⁴ grids from the stage-2 resolution down to the fine grid's, ×¼ each (at high C/N0 the
    posterior is far narrower than what a 6 m box resolves, most of all along the U-clock ridge)."""
    reach = plan.mid_m  # what stage 2 leaves, in metres, along any direction
    half_fine = (plan.fine_n - 1) / 2.0 * plan.fine_z
    f = reach / (half_fine * np.linalg.svd(L, compute_uv=False)[-1])
    n = plan.mid_n
    used = 0
    while f > 1.0:
        spacing = f * half_fine / ((n - 1) / 2.0)
        centre, _, node, _, r = _box_search(mf, centre, L, spacing, n, plan.max_recentre, True, threaded)
        centre = centre + L @ (node * spacing)
        used += r
        f /= 4.0
    return centre, used


def crb(g: NDArray, amplitude_sq: NDArray, n_blocks: int, bandwidth_chips: float) -> NDArray:
    """J_CRB = (Gᵀ diag(σ_δ⁻²) G)⁻¹ of the satellites' delay CRBs (4, 4)."""
    s = crb_delay_sigma(amplitude_sq, n_blocks, bandwidth_chips)
    return np.linalg.inv(g.T @ (g / (s * s)[:, None]))


def solve_epoch(mf: EpochManifold, amplitude_sq: NDArray, n_blocks: int, bandwidth_chips: float,
                plan: GridPlan = GridPlan(), threaded: bool = False) -> EpochSolution:
    """The `likelihood` DPE of one epoch about its initialisation (offsets ξ = 0).

    threaded : the grids on numba's threads (same numbers; campaigns, which run blocks side by
    side, keep it off).
    """
    nan4 = np.full(4, np.nan)
    failed = dict(x_mean=nan4, x_ml=nan4, cov=np.full((4, 4), np.nan), J=np.full((4, 4), np.nan),
                  offsets=np.full(plan.bins, np.nan), marginal=np.full(plan.bins, np.nan))
    eye = np.eye(4)
    half = (plan.coarse_n - 1) / 2.0 * plan.coarse_m
    used = mf.reaches(np.zeros(4), eye, half)
    if used.sum() < 4:
        return EpochSolution(Status.FEW_SATELLITES, recentred=0, used=used, **failed)
    mf = EpochManifold(mf.delta0[used], mf.g[used], mf.table[used], mf.floor[used], mf.delay0_m, mf.step_m)
    a2 = np.asarray(amplitude_sq, float)[used]
    centre, _, node, edge, r1 = _box_search(mf, np.zeros(4), eye, plan.coarse_m, plan.coarse_n, plan.max_recentre, True,
                                            threaded)
    if edge:
        return EpochSolution(Status.PEAK_AT_EDGE, recentred=r1, used=used, **failed)
    centre = centre + node * plan.coarse_m
    centre, lam, node, edge, r2 = _box_search(mf, centre, eye, plan.mid_m, plan.mid_n, plan.max_recentre, True,
                                              threaded)
    if edge:
        return EpochSolution(Status.PEAK_AT_EDGE, recentred=r1 + r2, used=used, **failed)
    centre = centre + (node + _quadratic_refine(lam, node, plan.mid_n)) * plan.mid_m
    J = crb(mf.g, a2, n_blocks, bandwidth_chips)
    L = np.linalg.cholesky(J)
    centre, r3 = _zoom(mf, centre, L, plan, threaded)
    centre, lam, node, edge, r4 = _box_search(mf, centre, L, plan.fine_z, plan.fine_n, plan.max_recentre, True,
                                              threaded)
    recentred = r1 + r2 + r3 + r4
    if edge:
        return EpochSolution(Status.PEAK_AT_EDGE, recentred=recentred, used=used, **failed)
    weights = np.empty_like(lam)
    moments = posterior_moments_threads if threaded else posterior_moments
    _, zbar, zz = moments(lam, plan.fine_z, plan.fine_n, weights)
    x_mean = centre + L @ zbar
    cov = L @ (zz - np.outer(zbar, zbar)) @ L.T
    x_ml = centre + L @ (node * plan.fine_z)
    # e = Û − U = (x̄_U − centre_U) − (L z)_U
    shift = float(x_mean[2] - centre[2])
    reach = (plan.fine_n - 1) / 2.0 * plan.fine_z * np.abs(L[2]).sum() + abs(shift)  # the largest |e| on the grid
    width = max(plan.bin_sigma * np.sqrt(J[2, 2]), reach / ((plan.bins - 1) / 2.0 - 1.0))
    bins = np.empty(plan.bins)
    (deposit_marginal_threads if threaded else deposit_marginal)(weights, plan.fine_z, plan.fine_n, -L[2].copy(),
                                                                 -shift, width, bins)
    offsets = (np.arange(plan.bins) - (plan.bins - 1) / 2.0) * width
    w4 = weights.reshape((plan.fine_n,) * 4)
    face_mass = float(1.0 - w4[1:-1, 1:-1, 1:-1, 1:-1].sum() / w4.sum())
    return EpochSolution(Status.OK, x_mean=x_mean, x_ml=x_ml, cov=cov, J=J, offsets=offsets,
                         marginal=bins / bins.sum(), recentred=recentred, used=used, face_mass=face_mass)
