"""The batched least-squares core (testbed.integrity.lsq) against independent computations.

Finite differences for the range Jacobian, brute-force fault injection for the
slopes and λ = bᵀWSb, plain per-epoch numpy for the batched matrices, closed
forms for DOP, and the degenerate cases (each element must fail alone).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from test_integrity_core_helpers import make_gnss, sat_pos_ecef
from testbed.integrity import lsq
from testbed.world.airport import runway_frame

FRAME = runway_frame()
RX_ENU = np.array([-4000.0, -2800.0, 350.0])  # on the RWY05 approach, 350 m above the threshold
TOW0 = 344063.0

ONE_MM = 1e-3
REL_SLOPE = 1e-6  # nonlinearity of a 10 m bias over 2e7 m ranges: ~1e-6 relative


def geometry_at(tow: float, mask_deg: float = 5.0):
    """Satellite ENU positions (S, 3), visibility (S,), sigma (S,), true ranges at RX_ENU."""
    g, rho0, sig = make_gnss(FRAME, RX_ENU[None], np.array([tow]), None, mask_deg=mask_deg, clock_m=0.0)
    sat_enu = FRAME.ecef_to_enu(g.sat_pos_ecef[0])
    return sat_enu, g.visible[0], sig[0], rho0[0]


def random_spd(rng, n, cond_boost=1.0):
    X = rng.standard_normal((n, n))
    return X @ X.T + n * cond_boost * np.eye(n)


# ---------------------------------------------------------------------------


def test_range_jacobian_matches_finite_differences():
    sat, vis, _, _ = geometry_at(TOW0)
    rng = np.random.default_rng(1)
    offset = np.array([[0.3, -1.2, 0.8]])
    clock_col = (rng.random(len(sat)) < 0.7).astype(float)  # mix of pseudorange and range rows
    model = lsq.range_model(sat, clock_col, offset)
    x = np.array([RX_ENU[0], RX_ENU[1], RX_ENU[2], 37.0])
    _, G = model(x)
    # ranges are 2e7 m: round-off in h is ~4e-9 m, so a 1 m step (truncation
    # error ~ step²/range² ≈ 3e-15) keeps the difference quotient good to ~4e-9
    step = 1.0
    G_fd = np.stack([(model(x + step * e)[0] - model(x - step * e)[0]) / (2 * step) for e in np.eye(4)], -1)
    np.testing.assert_allclose(G, G_fd, atol=2e-8)


def test_batched_matrices_equal_plain_numpy_per_epoch():
    """J, A, (WS)_ii, S from the stacked code equal textbook formulas per epoch (full and diagonal W)."""
    rng = np.random.default_rng(2)
    B, N = 6, 9
    G = rng.standard_normal((B, N, 4))
    Wfull = np.stack([np.linalg.inv(random_spd(rng, N)) for _ in range(B)])
    wdiag = rng.uniform(0.2, 3.0, (B, N))
    mask = rng.random((B, N)) < 0.85
    mask[:, :6] = True
    for W in (Wfull, wdiag):
        geom = lsq.wls_geometry(G, W, mask)
        for b in range(B):
            m = mask[b]
            Gb = G[b][m]
            Wb = W[b][np.ix_(m, m)] if W.ndim == 3 else np.diag(W[b][m])
            J = np.linalg.inv(Gb.T @ Wb @ Gb)
            A = J @ Gb.T @ Wb
            S = np.eye(m.sum()) - Gb @ A
            np.testing.assert_allclose(geom.J[b], J, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(geom.A[b][:, m], A, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(geom.A[b][:, ~m], 0.0)
            np.testing.assert_allclose(geom.ws_diag[b][m], np.diag(Wb @ S), rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(geom.residual_projector()[b][np.ix_(m, m)], S, atol=1e-10)
            assert np.isnan(geom.ws_diag[b][~m]).all()


@pytest.mark.parametrize("weights", ["diagonal", "full_correlated"])
def test_slopes_and_lambda_match_brute_force_injection(weights):
    """Bias on row i in a noise-free nonlinear solve: error/sqrt(λ) = slope, λ = bᵀWSb = SSE."""
    sat, vis, sig, rho0 = geometry_at(TOW0 + 3600.0)
    idx = np.flatnonzero(vis)
    sat, sig, rho0 = sat[idx], sig[idx], rho0[idx]
    n = len(idx)
    assert n >= 6
    if weights == "diagonal":
        W = 1.0 / sig**2
    else:
        # correlated errors: a common-mode term plus per-row noise
        rng = np.random.default_rng(3)
        C = np.diag(sig**2) + 0.3 * np.outer(sig, sig) + 0.05 * random_spd(rng, n) / n
        W = np.linalg.inv(C)
    clock = 55.0
    z0 = rho0 + clock
    clean = lsq.solve_ranges(sat, z0, W, None, np.ones(n), n_iter=10, tol_m=1e-9)
    np.testing.assert_allclose(clean.x, [*RX_ENU, clock], atol=ONE_MM)
    geom = clean.geometry
    hs, vs = geom.hslope, geom.vslope
    WS = geom.ws_matrix()
    bias = 10.0  # m
    for i in range(n):
        b = np.zeros(n)
        b[i] = bias
        f = lsq.solve_ranges(sat, z0 + b, W, None, np.ones(n), n_iter=10, tol_m=1e-9)
        err = f.x[:3] - RX_ENU
        lam = b @ WS @ b
        np.testing.assert_allclose(f.sse, lam, rtol=1e-5)
        np.testing.assert_allclose(np.hypot(err[0], err[1]) / np.sqrt(lam), hs[i], rtol=REL_SLOPE * 10, atol=1e-9)
        np.testing.assert_allclose(abs(err[2]) / np.sqrt(lam), vs[i], rtol=REL_SLOPE * 10, atol=1e-9)


def test_chi2_threshold_and_lambda_det_definitions():
    dof = np.array([0, 1, 2, 5, 12, 200])
    T2 = lsq.chi2_threshold(dof, 1e-5)
    lam = lsq.lambda_det(dof, 1e-5, 1e-3)
    assert np.isnan(T2[0]) and np.isnan(lam[0])
    np.testing.assert_allclose(stats.chi2.sf(T2[1:], dof[1:]), 1e-5, rtol=1e-8)
    np.testing.assert_allclose(stats.ncx2.cdf(T2[1:], dof[1:], lam[1:]), 1e-3, rtol=1e-6)
    # published anchor: for one dof the test is |z| > 4.4172 (Φ⁻¹(1 − 0.5e-5)), and
    # λ_det = (4.4172 + 3.0902)² ≈ 56.36 up to the far tail (P(z < −T − sqrt λ) ≈ 0)
    assert abs(np.sqrt(T2[1]) - 4.41717) < 1e-4
    assert abs(lam[1] - (4.41717 + 3.09023) ** 2) < 1e-2


def test_pl_variants_closed_form():
    rng = np.random.default_rng(4)
    G = rng.standard_normal((3, 8, 4))
    w = rng.uniform(0.5, 2.0, (3, 8))
    geom = lsq.wls_geometry(G, w)
    hs, vs = geom.hslope, geom.vslope
    seed = lsq.protection_levels(geom, 1e-5, 1e-3, "seed")
    pb = lsq.protection_levels(geom, 1e-5, 1e-3, "pbias")
    T = np.sqrt(stats.chi2.isf(1e-5, 4))
    k = stats.norm.isf(0.5e-3)
    J = geom.J
    np.testing.assert_allclose(seed.hpl, hs.max(-1) * T + k * np.sqrt(J[:, 0, 0] + J[:, 1, 1]), rtol=1e-12)
    np.testing.assert_allclose(seed.vpl, vs.max(-1) * T + k * np.sqrt(J[:, 2, 2]), rtol=1e-12)
    lam = lsq.lambda_det(4, 1e-5, 1e-3)
    np.testing.assert_allclose(pb.hpl, hs.max(-1) * np.sqrt(lam), rtol=1e-12)
    with pytest.raises(ValueError, match="variant"):
        lsq.protection_levels(geom, 1e-5, 1e-3, "ARAIM")
    with pytest.raises(ValueError, match="p_fa"):
        lsq.protection_levels(geom, 0.0, 1e-3, "seed")


def test_dops_equal_classic_formula_for_equal_weights():
    sat, vis, _, rho0 = geometry_at(TOW0)
    sat, rho0 = sat[vis], rho0[vis]
    sol = lsq.solve_ranges(sat, rho0, np.ones(len(rho0)), None, np.ones(len(rho0)))
    G = sol.geometry.G
    Q = np.linalg.inv(G.T @ G)
    d = lsq.dops(sol.geometry)
    np.testing.assert_allclose(d["gdop"], np.sqrt(np.trace(Q)), rtol=1e-12)
    np.testing.assert_allclose(d["hdop"], np.sqrt(Q[0, 0] + Q[1, 1]), rtol=1e-12)
    assert 0.5 < d["hdop"] < 3.0 and d["vdop"] > 0.5  # a 24-satellite constellation


def test_degenerate_epochs_fail_alone():
    """n < 5, n < 4, NaN in a used row, singular geometry: NaN + reason; the others untouched."""
    sat, vis, sig, rho0 = geometry_at(TOW0)
    idx = np.flatnonzero(vis)
    assert len(idx) >= 6
    sat, sig, z = sat[idx], sig[idx], rho0[idx] + 12.0
    n = len(idx)
    B = 6
    satb = np.broadcast_to(sat, (B, n, 3)).copy()
    zb = np.broadcast_to(z, (B, n)).copy()
    mask = np.ones((B, n), bool)
    mask[1, 4:] = False  # 4 rows: position but no redundancy
    mask[2, 3:] = False  # 3 rows: no position
    zb[3, 2] = np.nan  # NaN in a used row
    satb[4, :] = satb[4, 0]  # all rows from one satellite: singular
    zb[4] = zb[4, 0]
    zb[5, n - 1] = np.nan  # NaN in an *unused* row: fine
    mask[5, n - 1] = False
    w = 1.0 / sig**2
    sol = lsq.solve_ranges(satb, zb, w, mask, np.ones(n))
    pl = lsq.protection_levels(sol.geometry, 1e-5, 1e-3)
    R = lsq.Reason
    assert list(sol.reason) == [R.OK, R.NO_REDUNDANCY, R.NO_POSITION, R.NAN_INPUT, R.SINGULAR, R.OK]
    assert list(pl.reason[[0, 5]]) == [R.OK, R.OK]
    assert np.isnan(pl.hpl[1:5]).all() and np.isfinite(pl.hpl[[0, 5]]).all()
    assert np.isnan(sol.x[[2, 3, 4]]).all() and np.isfinite(sol.x[[0, 1, 5]]).all()
    # the good elements equal their own solve
    alone = lsq.solve_ranges(sat, z, w, None, np.ones(n))
    np.testing.assert_allclose(sol.x[0], alone.x, atol=1e-9)
    np.testing.assert_allclose(pl.hpl[0], lsq.protection_levels(alone.geometry, 1e-5, 1e-3).hpl, rtol=1e-12)
    alone7 = lsq.solve_ranges(sat[:-1], z[:-1], w[:-1], None, np.ones(n - 1))
    np.testing.assert_allclose(sol.x[5], alone7.x, atol=1e-9)


def test_clock_dropped_when_no_clock_rows():
    """Range rows without a clock term: the solve equals a 3-state solve with one more dof."""
    rng = np.random.default_rng(5)
    G3 = rng.standard_normal((7, 3))
    w = rng.uniform(0.5, 2.0, 7)
    G4 = np.concatenate([G3, np.zeros((7, 1))], -1)
    g4 = lsq.wls_geometry(G4, w)
    J3 = np.linalg.inv(G3.T @ (w[:, None] * G3))
    np.testing.assert_allclose(g4.J[:3, :3], J3, rtol=1e-12)
    assert g4.n_states == 3 and g4.dof == 4 and g4.reason == lsq.Reason.OK
    np.testing.assert_allclose(g4.A[3], 0.0)


def test_scalar_and_batched_inputs_agree():
    sat, vis, sig, rho0 = geometry_at(TOW0)
    sat, sig, z = sat[vis], sig[vis], rho0[vis] + 3.0
    w = 1.0 / sig**2
    one = lsq.solve_ranges(sat, z, w, None, np.ones(len(z)))
    many = lsq.solve_ranges(np.broadcast_to(sat, (2, 3) + sat.shape), np.broadcast_to(z, (2, 3) + z.shape),
                            np.broadcast_to(w, (2, 3) + w.shape), None, np.ones(len(z)))
    np.testing.assert_allclose(many.x, np.broadcast_to(one.x, (2, 3, 4)), atol=1e-9)
    assert one.x.shape == (4,) and one.sse.shape == ()


def test_bad_weight_shape_names_the_problem():
    with pytest.raises(ValueError, match=r"W: expected"):
        lsq.wls_geometry(np.zeros((5, 4)), np.ones((3, 3)))


def test_almanac_geometry_sanity():
    """At ZUNZ with a 5° mask the 24-satellite almanac gives 6-12 satellites."""
    pos = sat_pos_ecef(TOW0 + np.arange(0, 86400, 1800.0))
    g, _, _ = make_gnss(FRAME, np.broadcast_to(RX_ENU, (len(pos), 3)), TOW0 + np.arange(0, 86400, 1800.0), None)
    n = g.visible.sum(-1)
    assert n.min() >= 5 and n.max() <= 12
