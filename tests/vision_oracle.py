"""Numpy oracles of the compiled vision stage (:mod:`testbed.integrity.kernels.vision`).

The VA-RAIM paper's eq. 1-10 (docs/design/integrity.md §7) written as plain batched numpy:
bearings and their pixel Jacobian, pair cosines, the cosines ranges imply, the
cosine-rule matrices A and B, and Σ_c from pixel noise. The kernels are tested against
these; these are tested against finite differences and Monte Carlo in
``test_vision_ranges.py``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.integrity.vision_ranges import pair_indices


def bearings_from_pixels(pixel_uv: ArrayLike, K: ArrayLike) -> tuple[NDArray, NDArray]:
    """3D unit bearings in the camera frame and their pixel Jacobian.

    Parameters
    ----------
    pixel_uv : (..., L, 2) px.
    K : (3, 3) pinhole intrinsics.

    Returns
    -------
    b : (..., L, 3) unit vectors ``normalise(K⁻¹ [u, v, 1])``.
    db_duv : (..., L, 3, 2) exact ``∂b/∂(u, v)`` = ``(I − b bᵀ)/‖n‖ · K⁻¹[:, :2]``.
    """
    uv = np.asarray(pixel_uv, float)
    if uv.shape[-1:] != (2,):
        raise ValueError(f"pixel_uv: expected shape (..., L, 2), got {uv.shape}")
    Kinv = np.linalg.inv(np.asarray(K, float))
    n = uv @ Kinv[:, :2].T + Kinv[:, 2]
    nn = np.linalg.norm(n, axis=-1, keepdims=True)
    b = n / nn
    P = np.eye(3) - b[..., :, None] * b[..., None, :]
    db_duv = (P / nn[..., None]) @ Kinv[:, :2]
    return b, db_duv


def cosines(b: NDArray, db_duv: NDArray | None = None) -> tuple[NDArray, NDArray | None, NDArray | None]:
    """Pair cosines ``c_ij = b_i·b_j`` and their pixel Jacobians.

    Returns ``c`` (..., N_C), ``dc_duv_i`` and ``dc_duv_j`` (..., N_C, 2): the
    derivatives with respect to the pixels of the pair's first and second landmark.
    """
    I, J = pair_indices(b.shape[-2])
    bi, bj = b[..., I, :], b[..., J, :]
    c = np.einsum("...k,...k->...", bi, bj)
    if db_duv is None:
        return c, None, None
    dci = np.einsum("...k,...ka->...a", bj, db_duv[..., I, :, :])
    dcj = np.einsum("...k,...ka->...a", bi, db_duv[..., J, :, :])
    return c, dci, dcj


def cosine_model(m: NDArray, d2: NDArray) -> NDArray:
    """Cosines implied by ranges: ``(m_i² + m_j² − d_ij²)/(2 m_i m_j)``, (..., N_C)."""
    I, J = pair_indices(m.shape[-1])
    mi, mj = m[..., I], m[..., J]
    return (mi * mi + mj * mj - d2) / (2.0 * mi * mj)


def cosine_rule_jacobians(m: NDArray, c: NDArray) -> tuple[NDArray, NDArray]:
    """Seed eq. 2 matrices for any N_V.

    Parameters
    ----------
    m : (..., L) ranges, m.  c : (..., N_C) pair cosines.

    Returns
    -------
    A : (..., N_C, L), row ij has ``1/m_j − c_ij/m_i`` at column i and
        ``1/m_i − c_ij/m_j`` at column j (1/m).
    B : (..., N_C), the diagonal of ``B = diag(1/(2 m_i m_j))`` (1/m²).
    """
    L = m.shape[-1]
    I, J = pair_indices(L)
    mi, mj = m[..., I], m[..., J]
    nc = len(I)
    A = np.zeros(m.shape[:-1] + (nc, L))
    rows = np.arange(nc)
    A[..., rows, I] = 1.0 / mj - c / mi
    A[..., rows, J] = 1.0 / mi - c / mj
    return A, 1.0 / (2.0 * mi * mj)


def cosine_covariance(dci: NDArray, dcj: NDArray, sigma_px: NDArray, n_landmarks: int) -> NDArray:
    """Full Σ_c (..., N_C, N_C) from isotropic pixel noise ``sigma_px`` (..., L).

    Pairs that share a landmark are correlated through that landmark's pixels.
    """
    I, J = pair_indices(n_landmarks)
    nc = len(I)
    # Dense Jacobian Jc (..., N_C, L, 2): pair p depends on the pixels of I[p] and J[p].
    Jc = np.zeros(dci.shape[:-2] + (nc, n_landmarks, 2))
    rows = np.arange(nc)
    Jc[..., rows, I, :] = dci
    Jc[..., rows, J, :] = dcj
    s2 = np.asarray(sigma_px, float) ** 2
    return np.einsum("...pla,...l,...qla->...pq", Jc, s2, Jc)
