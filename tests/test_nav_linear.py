"""T-LIN (docs/design/nav-filter.md §12): the filter's measurement update reduced to a linear problem equals filterpy's
``KalmanFilter`` run per trial and the batch information solution, to 1e-9.

The reduction: rows that do not touch the attitude error (so the injected correction stays additive), a
static state between updates (Φ = I, Q = 0), innovations formed from the accumulated estimate. Each trial
has its own geometry, noise and mask (masked rows are inert), a batch of 6 trials over 5 updates; the prior
is a full random covariance except that the attitude error is uncorrelated with the rest (else the gain
would correct the attitude, which the nominal state takes multiplicatively).
"""

from __future__ import annotations

import numpy as np
import pytest

from testbed.navigation.ekf import BA, BG, CB, CD, N, P_, PSI, V_, NavState, update

filterpy = pytest.importorskip("filterpy.kalman")

ADDITIVE = np.r_[np.arange(N)[P_], np.arange(N)[V_], np.arange(N)[BA], np.arange(N)[BG], CB, CD]


def _estimate(s: NavState) -> np.ndarray:
    """The error-state estimate the nominal state has absorbed (attitude untouched, so its part is 0)."""
    x = np.zeros((s.p.shape[0], N))
    x[:, P_], x[:, V_], x[:, BA], x[:, BG], x[:, CB], x[:, CD] = s.p, s.v, s.ba, s.bg, s.cb, s.cd
    return x


def test_update_equals_filterpy_and_the_information_solution():
    rng = np.random.default_rng(19)
    B, K, M = 6, 5, 7
    A = rng.normal(size=(B, N, N))
    P0 = np.einsum("bij,bkj->bik", A, A) / N + np.eye(N) * 0.5
    other = np.setdiff1d(np.arange(N), np.arange(N)[PSI])
    P0[:, PSI.start:PSI.stop, other] = 0.0  # the attitude error uncorrelated with the rest: its gain stays 0
    P0[:, other[:, None], np.arange(PSI.start, PSI.stop)] = 0.0
    x_true = rng.normal(size=(B, N)) * 3.0
    x_true[:, PSI] = 0.0
    s = NavState(C=np.broadcast_to(np.eye(3), (B, 3, 3)).copy(), v=np.zeros((B, 3)), p=np.zeros((B, 3)),
                 ba=np.zeros((B, 3)), bg=np.zeros((B, 3)), cb=np.zeros(B), cd=np.zeros(B), P=P0.copy())
    kfs = []
    for b in range(B):
        kf = filterpy.KalmanFilter(dim_x=N, dim_z=M)
        kf.x, kf.P = np.zeros((N, 1)), P0[b].copy()
        kfs.append(kf)
    info = np.linalg.inv(P0)
    info_vec = np.zeros((B, N))  # prior mean 0
    for _ in range(K):
        H = rng.normal(size=(B, M, N))
        H[..., PSI] = 0.0  # no attitude rows: the injection stays additive
        L = rng.normal(size=(B, M, M)) * 0.3
        R = np.einsum("bij,bkj->bik", L, L) + np.eye(M)
        z = np.einsum("bmn,bn->bm", H, x_true) + np.einsum("bij,bj->bi", np.linalg.cholesky(R),
                                                            rng.normal(size=(B, M)))
        mask = rng.random((B, M)) < 0.75
        nu = z - np.einsum("bmn,bn->bm", H, _estimate(s))
        s, nis, dof = update(s, nu, H, R, mask)
        for b in range(B):
            k = np.flatnonzero(mask[b])
            kfs[b].update(z[b, k][:, None], R=R[b][np.ix_(k, k)], H=H[b, k])
            Rinv = np.linalg.inv(R[b][np.ix_(k, k)])
            info[b] += H[b, k].T @ Rinv @ H[b, k]
            info_vec[b] += H[b, k].T @ Rinv @ z[b, k]
        assert np.array_equal(dof, mask.sum(-1))
    x_kf = np.stack([kf.x[:, 0] for kf in kfs])
    P_kf = np.stack([kf.P for kf in kfs])
    P_info = np.linalg.inv(info)
    x_info = np.einsum("bij,bj->bi", P_info, info_vec)
    x_ours = _estimate(s)
    scale = np.abs(x_info).max()
    np.testing.assert_allclose(x_ours[:, ADDITIVE], x_kf[:, ADDITIVE], rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(x_ours[:, ADDITIVE], x_info[:, ADDITIVE], rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(s.P, P_kf, rtol=0, atol=1e-9 * np.abs(P_kf).max())
    np.testing.assert_allclose(s.P, P_info, rtol=0, atol=1e-9 * np.abs(P_info).max())
    np.testing.assert_array_equal(s.C, np.broadcast_to(np.eye(3), (B, 3, 3)))
