"""Vision pseudoranges by the cosine rule: Jacobians, exact solves, covariances, degenerate inputs.

References no one here wrote: central finite differences, exact geometry
(ranges of a known camera), Monte Carlo sample covariances.
"""

from __future__ import annotations

import numpy as np
import pytest

from testbed.integrity.vision_ranges import (VisionRangeSettings, VisionReason, pair_indices, survey_covariance,
                                             vision_pseudoranges)
from vision_oracle import bearings_from_pixels, cosine_covariance, cosine_model, cosine_rule_jacobians, cosines

F = 3400.0
K = np.array([[F, 0.0, 1223.5], [0.0, F, 1023.5], [0.0, 0.0, 1.0]])
N_MC = 20_000
# Relative standard error of a sample variance from n Gaussian draws is sqrt(2/n)
# (1.0% for 20k); 5 of them plus ~1% of linearisation error at these ranges.
MC_REL_TOL = 5 * np.sqrt(2 / N_MC) + 0.01


def look_at(cam: np.ndarray, target: np.ndarray) -> np.ndarray:
    """R_cam_to_world for a camera (x right, y down, z forward) looking at ``target``."""
    z = target - cam
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def landmarks(n: int, radius: float = 100.0) -> np.ndarray:
    az = np.radians(np.arange(n) * 360.0 / n + 7.0)
    return np.stack([radius * np.sin(az), radius * np.cos(az), 2.0 * np.arange(n)], axis=1)


def pixels(P: np.ndarray, cam: np.ndarray, Rc: np.ndarray) -> np.ndarray:
    v = (P - cam) @ Rc
    return (v[:, :2] / v[:, 2:]) @ K[:2, :2].T + K[:2, 2]


CAM = np.array([-2000.0, 150.0, 400.0])


def _fd(f, x, h):
    x = np.asarray(x, float)
    cols = []
    for k in range(x.size):
        e = np.zeros_like(x)
        e.flat[k] = h
        cols.append((f(x + e) - f(x - e)) / (2 * h))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("n", [3, 4, 6])
def test_A_and_B_match_finite_differences(n):
    P = landmarks(n)
    m = np.linalg.norm(P - CAM, axis=1)
    I, J = pair_indices(n)
    d2 = np.sum((P[I] - P[J]) ** 2, -1)
    A, B = cosine_rule_jacobians(m, cosine_model(m, d2))
    A_fd = _fd(lambda mm: cosine_model(mm, d2), m, 1e-3)
    np.testing.assert_allclose(A, A_fd, rtol=1e-6, atol=1e-12)
    # A δm = δc + B δd²  <=>  ∂c_model/∂(d²) = −B
    B_fd = np.diagonal(_fd(lambda dd: cosine_model(m, dd), d2, 1e-2))
    np.testing.assert_allclose(B, -B_fd, rtol=1e-6)
    # the seed's 3x3 A for pairs (12, 13, 23) in triu order
    if n == 3:
        c = cosine_model(m, d2)
        assert np.isclose(A[0, 0], 1 / m[1] - c[0] / m[0]) and A[0, 2] == 0.0
        assert np.isclose(A[2, 2], 1 / m[1] - c[2] / m[2])


def test_cosine_pixel_jacobian_matches_finite_differences():
    P = landmarks(4)
    uv = pixels(P, CAM, look_at(CAM, np.zeros(3))) + np.array([3.0, -2.0])
    b, db = bearings_from_pixels(uv, K)
    np.testing.assert_allclose(np.linalg.norm(b, axis=-1), 1.0, rtol=1e-14)
    _, dci, dcj = cosines(b, db)
    fd = _fd(lambda x: cosines(bearings_from_pixels(x.reshape(4, 2), K)[0])[0], uv.ravel(), 1e-3)
    fd = fd.reshape(6, 4, 2)
    I, J = pair_indices(4)
    rows = np.arange(6)
    np.testing.assert_allclose(dci, fd[rows, I], rtol=1e-5, atol=1e-14)
    np.testing.assert_allclose(dcj, fd[rows, J], rtol=1e-5, atol=1e-14)
    # and nothing else: c_ij does not depend on other landmarks' pixels
    other = fd.copy()
    other[rows, I] = 0
    other[rows, J] = 0
    assert np.abs(other).max() < 1e-15


@pytest.mark.parametrize("n", [3, 4, 6])
def test_noise_free_pixels_give_exact_ranges(n):
    P = landmarks(n)
    uv = pixels(P, CAM, look_at(CAM, np.zeros(3)))
    m_true = np.linalg.norm(P - CAM, axis=1)
    m_pred = m_true + np.linspace(-30, 25, n)  # a prior tens of metres off
    out = vision_pseudoranges(uv, np.ones(n, bool), K, np.ones(n), P, m_pred)
    assert out.reason == VisionReason.OK and out.ok
    one_mm = 1e-3
    np.testing.assert_allclose(out.m, m_true, atol=one_mm)
    assert out.residual_stat < 1e-6


def test_survey_covariance_diagonal_is_seed_value_and_matches_monte_carlo():
    P = landmarks(4)
    sg = 0.05
    Sd = survey_covariance(P, sg)
    I, J = pair_indices(4)
    d2 = np.sum((P[I] - P[J]) ** 2, -1)
    np.testing.assert_allclose(np.diag(Sd), 8 * d2 * sg**2, rtol=1e-12)  # seed: 8 d² σ_g²
    rng = np.random.default_rng(11)
    dp = rng.normal(0, sg, (N_MC, 4, 3))
    Pn = P + dp
    dd2 = np.sum((Pn[:, I] - Pn[:, J]) ** 2, -1) - d2
    C = np.cov(dd2.T)
    # element-wise, relative to the scale sqrt(Σ_ii Σ_jj) of each entry
    scale = np.sqrt(np.outer(np.diag(Sd), np.diag(Sd)))
    assert np.all(np.abs(C - Sd) < MC_REL_TOL * scale)


def _var_ratios(samples: np.ndarray, Sigma: np.ndarray) -> np.ndarray:
    """Sample variance / predicted variance along the eigenvectors of Sigma with nonzero eigenvalue."""
    lam, V = np.linalg.eigh(Sigma)
    keep = lam > lam.max() * 1e-9
    proj = (samples - samples.mean(0)) @ V[:, keep]
    return proj.var(0, ddof=1) / lam[keep]


@pytest.mark.parametrize("n", [3, 4, 6])
def test_sigma_c_and_sigma_v_match_monte_carlo(n):
    rng = np.random.default_rng(100 + n)
    P = landmarks(n)
    Rc = look_at(CAM, np.zeros(3))
    uv0 = pixels(P, CAM, Rc)
    sig = np.linspace(0.8, 1.5, n)  # per-detection sigmas differ
    uv = uv0 + sig[:, None] * rng.standard_normal((N_MC, n, 2))
    m_true = np.linalg.norm(P - CAM, axis=1)
    out = vision_pseudoranges(uv, np.ones((N_MC, n), bool), K, sig, P, np.broadcast_to(m_true, (N_MC, n)))
    assert out.ok.all()
    # Σ_c: the analytic one at the noise-free pixels
    b, db = bearings_from_pixels(uv0, K)
    c0, dci, dcj = cosines(b, db)
    Sc = cosine_covariance(dci, dcj, sig, n)
    rank = np.linalg.matrix_rank(Sc, tol=np.abs(Sc).max() * 1e-9)
    assert rank == 2 * n - 3  # rotation invariance of the cosines
    r = _var_ratios(out.c, Sc)
    assert np.all(np.abs(r - 1) < MC_REL_TOL), r
    # Σ_V against the spread of the solved ranges
    r = _var_ratios(out.m, out.Sigma_V.mean(0))
    assert np.all(np.abs(r - 1) < MC_REL_TOL), r
    # full-matrix check in the whitened space of Σ_V: sample covariance ≈ I
    lam, V = np.linalg.eigh(out.Sigma_V.mean(0))
    wht = (out.m - out.m.mean(0)) @ V / np.sqrt(lam)
    Cw = np.cov(wht.T)
    assert np.abs(Cw - np.eye(n)).max() < MC_REL_TOL + 5 / np.sqrt(N_MC)


def test_degenerate_inputs_are_unavailable_with_reasons_and_do_not_spoil_the_batch():
    n = 4
    P = landmarks(n)
    Rc = look_at(CAM, np.zeros(3))
    uv_good = pixels(P, CAM, Rc)
    m_true = np.linalg.norm(P - CAM, axis=1)
    uv = np.broadcast_to(uv_good, (7, n, 2)).copy()
    det = np.ones((7, n), bool)
    # 0: good.  1: only 2 detections.  2: NaN pixels on 2 of 4 detections.
    det[1, 2:] = False
    uv[2, :2] = np.nan
    # 3: non-existent geometry (all four detections at one pixel): no positive solution
    uv[3] = uv_good[0]
    # 4: prior far off (another branch / no convergence in few iterations is acceptable either way)
    # 5: one NaN pixel of four: still 3 valid -> ok
    uv[5, 3] = np.nan
    # 6: two landmarks missing and the image otherwise good -> too few
    det[6, :2] = False
    m_pred = np.broadcast_to(m_true, (7, n)).copy()
    m_pred[4] = m_true * 0.2
    Sp = np.broadcast_to(25.0 * np.eye(n), (7, n, n))
    out = vision_pseudoranges(uv, det, K, np.ones((7, n)), P, m_pred, Sp)
    R = VisionReason
    assert out.reason[0] == R.OK and out.reason[5] == R.OK
    assert out.reason[1] == R.TOO_FEW_LANDMARKS and out.reason[6] == R.TOO_FEW_LANDMARKS
    assert out.reason[2] == R.NAN_PIXELS
    assert out.reason[3] in (R.NOT_CONVERGED, R.RESIDUAL)
    assert out.reason[4] in (R.NOT_CONVERGED, R.RESIDUAL, R.BRANCH_JUMP)
    np.testing.assert_allclose(out.m[0], m_true, atol=1e-3)
    np.testing.assert_allclose(out.m[5, :3], m_true[:3], atol=1e-3)
    assert np.isnan(out.m[5, 3]) and out.n_v[5] == 3
    assert np.all(np.isnan(out.m[[1, 2, 3, 4, 6]]))
    # the same good epoch alone gives the same numbers (batch independence)
    alone = vision_pseudoranges(uv[:1], det[:1], K, np.ones((1, n)), P, m_pred[:1], Sp[:1])
    np.testing.assert_array_equal(alone.m[0], out.m[0])


def test_non_converging_solve_is_reported():
    P = landmarks(3)
    uv = pixels(P, CAM, look_at(CAM, np.zeros(3)))
    m_true = np.linalg.norm(P - CAM, axis=1)
    out = vision_pseudoranges(uv, np.ones(3, bool), K, np.ones(3), P, m_true * 3.0,
                              settings=VisionRangeSettings(max_iter=2))
    assert out.reason == VisionReason.NOT_CONVERGED and np.isnan(out.m).all()


def test_p3p_branch_jump_is_flagged():
    """Starts far from the truth can converge on the other P3P branch; the gate flags a solution far
    from its prediction (relative to Σ_V + Σ_pred), while a good prediction passes."""
    P = landmarks(3)
    uv = pixels(P, CAM, look_at(CAM, np.zeros(3)))
    m_true = np.linalg.norm(P - CAM, axis=1)
    rng = np.random.default_rng(5)
    n = 400
    starts = m_true * rng.uniform(0.05, 3.0, (n, 3))
    det = np.ones((n, 3), bool)
    sol = vision_pseudoranges(np.broadcast_to(uv, (n, 3, 2)), det, K, np.ones(3), P, starts)
    other = sol.ok & (np.abs(sol.m - m_true).max(-1) > 1.0)
    assert other.any(), "this geometry has a second P3P branch"
    k = int(np.argmax(other))
    # both branches fit the cosines exactly: the residual cannot tell them apart
    assert sol.residual_stat[k] < 1e-3
    Sp = np.eye(3) * 10.0**2
    both = vision_pseudoranges(np.broadcast_to(uv, (2, 3, 2)), det[:2], K, np.ones(3), P,
                               np.stack([starts[k], m_true + 5.0]), np.stack([Sp, Sp]))
    assert both.reason[0] == VisionReason.BRANCH_JUMP and np.isnan(both.m[0]).all()
    assert both.reason[1] == VisionReason.OK
    np.testing.assert_allclose(both.m[1], m_true, atol=1e-3)
    assert both.gate_stat[0] > 1e3 and both.gate_stat[1] < 30.0


@pytest.mark.parametrize("layout", ["collinear", "coincident"])
def test_collinear_or_coincident_landmarks_are_degenerate(layout):
    if layout == "collinear":
        P = np.array([[-100.0, 0.0, 0.0], [0.0, 0.0, 0.0], [120.0, 0.0, 0.0]])
    else:
        P = np.array([[0.0, 100.0, 0.0], [0.0, 100.3, 0.0], [87.0, -50.0, 0.0]])
    uv = pixels(P, CAM, look_at(CAM, np.zeros(3)))
    m_true = np.linalg.norm(P - CAM, axis=1)
    out = vision_pseudoranges(uv, np.ones(3, bool), K, np.ones(3), P, m_true)
    assert out.reason == VisionReason.DEGENERATE_GEOMETRY and not out.ok


def test_bad_shapes_raise_value_errors_naming_the_input():
    P = landmarks(3)
    with pytest.raises(ValueError, match="pixel_uv"):
        vision_pseudoranges(np.zeros((3, 3)), np.ones(3, bool), K, np.ones(3), P, np.ones(3))
    with pytest.raises(ValueError, match="landmark_pos"):
        vision_pseudoranges(np.zeros((3, 2)), np.ones(3, bool), K, np.ones(3), P[:, :2], np.ones(3))
