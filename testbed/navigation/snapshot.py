"""The filter's solution without its IMU: the epoch's pseudoranges alone, solved by weighted least squares about the
filter's predicted state (docs/design/nav-filter.md §8.4).

This is the subset solution of the inertial fault mode. Its estimate is ``x̂_s = x̂⁻ + Sν`` with ν the prefit
residuals of the pseudorange rows and ``S`` the position rows of ``(GᵀWG)⁻¹GᵀW`` over the position and clock columns
``G`` of their Jacobian (W = R⁻¹, the filter's own row variances). Its error is ``(E − SH)δx⁻ − Sε``: with the
antenna at the IMU point ``SH = E`` and the prior drops out; with a lever arm the attitude's share stays, through the
antenna's offset (millimetres for a metre's lever and milliradians). So its covariance is
``Σ_s = (E − SH)P⁻(E − SH)ᵀ + SRSᵀ``.

The filter's estimate uses everything the snapshot uses, and more, optimally under its model: so the two errors'
difference is uncorrelated with the filter's, and ``cov(x̂_s − x̂) = Σ_s − P`` (the nested-estimator identity the
sub-filter bank relies on too, tested against the distribution of the separations).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from testbed.integrity.araim.subsets import checked_inverse
from testbed.navigation.ekf import CB, P_

#: least squares needs the position and the clock: four rows
MIN_ROWS = 4
#: the largest condition number (1-norm, Jacobi-scaled) of the normal matrix solved: the ARAIM core's default
MAX_COND = 1e10


def gnss_snapshot(p_prior: NDArray, P_prior: NDArray, nu: NDArray, H: NDArray, R: NDArray, mask: NDArray
                  ) -> tuple[NDArray, NDArray]:
    """The IMU-free position (B, 3) and its covariance (B, 3, 3) from one update's GNSS rows — prefit residuals ν
    (B, M), Jacobian H (B, M, n), covariance R (B, M, M) (diagonal over the pseudoranges), mask (B, M) — at the
    filter's prior position ``p_prior`` (B, 3) and covariance ``P_prior`` (B, n, n). Pseudorange rows are those with
    a clock-bias column; range-rate rows are left out. NaN for a trial with fewer than :data:`MIN_ROWS` of them, or
    whose geometry is singular or conditioned worse than :data:`MAX_COND`."""
    pr = mask & (H[..., CB] != 0.0)
    enough = pr.sum(-1) >= MIN_ROWS
    var = np.diagonal(R, axis1=-2, axis2=-1)
    w = np.where(pr, 1.0 / np.where(pr, var, 1.0), 0.0)
    cols = np.r_[np.arange(P_.start, P_.stop), CB]
    G = H[..., cols]
    normal = np.einsum("bmi,bm,bmj->bij", G, w, G) + np.eye(cols.size) * ~enough[:, None, None]
    inv, conditioned = checked_inverse(normal, MAX_COND)
    ok = enough & conditioned
    S = np.where(ok[:, None, None], np.nan_to_num(inv) @ (np.swapaxes(G, -1, -2) * w[:, None, :]), 0.0)[:, :3]
    E = np.zeros((3, H.shape[-1]))
    E[:, P_] = np.eye(3)
    A = E - S @ np.where(pr[..., None], H, 0.0)
    R_pr = np.where(pr[..., :, None] & pr[..., None, :], R, 0.0)
    cov = A @ P_prior @ np.swapaxes(A, -1, -2) + S @ R_pr @ np.swapaxes(S, -1, -2)
    p = p_prior + np.einsum("bim,bm->bi", S, np.where(pr, nu, 0.0))
    nan = ~ok[:, None]
    return np.where(nan, np.nan, p), np.where(nan[..., None], np.nan, 0.5 * (cov + np.swapaxes(cov, -1, -2)))


__all__ = ["MAX_COND", "MIN_ROWS", "gnss_snapshot"]
