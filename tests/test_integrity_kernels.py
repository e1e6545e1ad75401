"""The compiled per-epoch kernels against numpy/LAPACK and the numpy formulas they replace."""

from __future__ import annotations

import numpy as np

from testbed.integrity import kernels, lsq
from testbed.integrity.vision_ranges import bearings_from_pixels, cosine_covariance, cosines


def test_solve_batch_matches_lapack_and_flags_singular_and_nan():
    rng = np.random.default_rng(1)
    M = rng.normal(size=(50, 5, 5))
    R = rng.normal(size=(50, 5, 3))
    M[3] = 0.0  # singular
    M[7, 1] = M[7, 2]  # singular (equal rows)
    M[9, 0, 0] = np.nan
    X = np.empty_like(R)
    good = np.empty(50, bool)
    kernels.solve_batch(M, R, X, good)
    bad = [3, 7, 9]
    assert not good[bad].any() and good[np.setdiff1d(np.arange(50), bad)].all()
    assert np.isnan(X[bad]).all()
    ok = good
    np.testing.assert_allclose(X[ok], np.linalg.solve(M[ok], R[ok]), rtol=1e-10, atol=1e-12)


def test_normal_geometry_matches_lapack():
    rng = np.random.default_rng(2)
    P, N = 400, 9
    G = rng.normal(size=(P, N, 4))
    G[:, :, 3] = 1.0
    G[:20, :, 2] *= 1e-3  # poorly conditioned (still certified or handed back as NaN)
    w = rng.uniform(0.5, 2.0, (P, N))
    WG = w[..., None] * G
    M, cond, J, A, ws = (np.empty((P, 4, 4)), np.empty(P), np.empty((P, 4, 4)), np.empty((P, 4, N)),
                         np.empty((P, N)))
    ok = np.empty(P, bool)
    kernels.normal_geometry(G, WG, w, lsq.SPD_PIVOT_RTOL, M, cond, J, A, ws, ok)
    M_ref = np.swapaxes(G, -1, -2) @ WG
    np.testing.assert_allclose(M, M_ref, rtol=1e-13, atol=1e-13 * np.abs(M_ref).max())
    d = np.sqrt(np.diagonal(M_ref, axis1=-2, axis2=-1))
    ev = np.linalg.eigvalsh(M_ref / (d[:, :, None] * d[:, None, :]))
    certified = np.isfinite(cond)
    assert certified.mean() > 0.95
    np.testing.assert_allclose(cond[certified], (ev[:, -1] / ev[:, 0])[certified], rtol=1e-9)
    assert ok.all()
    J_ref = np.linalg.inv(M_ref)
    np.testing.assert_allclose(J, J_ref, rtol=1e-9, atol=1e-12 * np.abs(J_ref).max())
    A_ref = J_ref @ np.swapaxes(WG, -1, -2)
    np.testing.assert_allclose(A, A_ref, rtol=1e-9, atol=1e-12)
    ws_ref = w - np.einsum("pni,pij,pnj->pn", WG, J_ref, WG)
    np.testing.assert_allclose(ws, ws_ref, rtol=1e-8, atol=1e-12)


def test_cond4_refuses_indefinite_and_singular():
    S = np.diag([1.0, 2.0, 3.0, -1e-3])
    assert np.isnan(kernels._cond4(S, np.empty((4, 4))))
    S = np.diag([1.0, 2.0, 3.0, 0.0])
    assert np.isnan(kernels._cond4(S, np.empty((4, 4))))
    S = np.diag([1.0, 2.0, 3.0, 4.0])
    assert abs(kernels._cond4(S, np.empty((4, 4))) - 4.0) < 1e-13


def test_fused_cosines_and_covariance_match_the_numpy_formulas():
    rng = np.random.default_rng(3)
    P, L = 200, 5
    K = np.array([[1200.0, 0.0, 640.0], [0.0, 1200.0, 360.0], [0.0, 0.0, 1.0]])
    uv = rng.uniform([0, 0], [1280, 720], (P, L, 2))
    used = rng.random((P, L)) > 0.2
    sig = rng.uniform(0.5, 2.0, (P, L))
    nc = L * (L - 1) // 2
    c, Sc = np.empty((P, nc)), np.empty((P, nc, nc))
    kernels.cosines_and_covariance(uv, used, sig, np.linalg.inv(K), c, Sc)
    uv0 = np.where(used[..., None], uv, 0.0)
    b, db = bearings_from_pixels(uv0, K)
    c_ref, dci, dcj = cosines(b, db)
    Sc_ref = cosine_covariance(dci, dcj, np.where(used, sig, 0.0), L)
    np.testing.assert_allclose(c, c_ref, rtol=0, atol=1e-15)
    np.testing.assert_allclose(Sc, Sc_ref, rtol=1e-12, atol=1e-24)


def test_compile_all_covers_the_monitors_so_nothing_compiles_mid_flight():
    """After the set-up's compile_all, running the monitors adds no numba specialisation."""
    import sys
    from dataclasses import replace
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).parent))
    from test_va_raim_scenario import make_scenario

    from testbed.integrity.raim import gps_raim
    from testbed.integrity.va_raim import va_raim

    kernels.compile_all()
    names = ("solve_batch", "range_gauss_newton", "cosine_gauss_newton", "normal_geometry",
             "cosines_and_covariance", "calibrate_epochs", "cond4_batch")
    before = {n: len(getattr(kernels, n).signatures) for n in names}
    sc = make_scenario(np.random.default_rng(4), (2,), t0=40.0, t1=60.0)
    uv = sc.vision.pixel_uv.copy()
    uv[0, 3, 0] = np.nan
    va_raim(sc.gnss, replace(sc.vision, pixel_uv=uv), sc.frame)
    gps_raim(sc.gnss, sc.frame)
    assert {n: len(getattr(kernels, n).signatures) for n in names} == before


def test_division_by_zero_gives_nan_not_an_exception():
    """numpy's error model: a zero range (degenerate geometry) propagates inf/NaN."""
    c = np.zeros((1, 3))
    m = np.zeros((1, 3))  # zero start ranges
    out_m, it, conv, good = np.empty((1, 3)), np.empty(1, np.int64), np.empty(1, bool), np.empty(1, bool)
    kernels.cosine_gauss_newton(c, np.broadcast_to(np.eye(3), (1, 3, 3)).copy(), np.ones(3), m,
                                np.ones((1, 3), bool), np.ones((1, 3), bool), 5, 1e-4, out_m, it, conv, good)
    assert not (conv[0] and good[0])


def test_geometry_of_an_element_does_not_depend_on_the_batch():
    """A dropped-clock element (vision-only rows) in the batch leaves the others' numbers unchanged,
    bit for bit: every path decision in wls_geometry is per element."""
    rng = np.random.default_rng(6)
    G = rng.normal(size=(3, 7, 4))
    G[..., 3] = 1.0
    G[1, :, 3] = 0.0  # no clock term in any row: the clock is dropped for element 1
    G[2, :, 2] *= 1e-4  # ill-conditioned: the LAPACK path
    w = rng.uniform(0.5, 2.0, (3, 7))
    whole = lsq.wls_geometry(G, w)
    assert whole.n_states[1] == 3
    for k in (0, 2):
        alone = lsq.wls_geometry(G[k:k + 1], w[k:k + 1])
        for f in ("J", "A", "ws_diag", "cond", "reason"):
            np.testing.assert_array_equal(getattr(whole, f)[k], getattr(alone, f)[0], err_msg=f)
