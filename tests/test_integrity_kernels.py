"""The compiled per-epoch kernels against numpy/LAPACK oracles (``wls_oracle.py``, ``vision_oracle.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from vision_oracle import bearings_from_pixels, cosine_covariance, cosine_model, cosine_rule_jacobians, cosines

from testbed.integrity import kernels, lsq


def test_lu_solve_matches_lapack_and_flags_singular_and_nan():
    rng = np.random.default_rng(1)
    M = rng.normal(size=(50, 5, 5))
    R = rng.normal(size=(50, 5, 3))
    M[3] = 0.0  # singular
    M[7, 1] = M[7, 2]  # singular (equal rows)
    M[9, 0, 0] = np.nan
    X = R.copy()
    good = np.array([kernels._lu_solve(M[p].copy(), X[p]) for p in range(50)])
    bad = [3, 7, 9]
    assert not good[bad].any() and good[np.setdiff1d(np.arange(50), bad)].all()
    ok = good
    np.testing.assert_allclose(X[ok], np.linalg.solve(M[ok], R[ok]), rtol=1e-10, atol=1e-12)


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
    names = ("gather_used_rows", "range_gauss_newton_tiles", "cosine_gauss_newton_tiles", "wls_epochs",
             "cosine_rule_products", "vision_rows", "cosines_and_covariance", "calibrate_tiles")

    def compiled(n):
        k = getattr(kernels, n)
        return len(k.types) if hasattr(k, "types") else len(k.signatures)  # a gufunc, or a jit function

    before = {n: compiled(n) for n in names}
    sc = make_scenario(np.random.default_rng(4), (2,), t0=40.0, t1=60.0)
    uv = sc.vision.pixel_uv.copy()
    uv[0, 3, 0] = np.nan
    va_raim(sc.gnss, replace(sc.vision, pixel_uv=uv), sc.frame)
    gps_raim(sc.gnss, sc.frame)
    assert {n: compiled(n) for n in names} == before


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


# ----------------------------------------------------------------------------- fused solution-side kernels


def _solve_or_nan(M, rhs):
    """numpy.linalg.solve per element; NaN and False where M is non-finite or singular."""
    X = np.full(np.broadcast_shapes(M.shape[:-2], rhs.shape[:-2]) + rhs.shape[-2:], np.nan)
    good = np.zeros(X.shape[:-2], bool)
    for p in range(len(X)):
        if np.isfinite(M[p]).all():
            try:
                X[p] = np.linalg.solve(M[p], rhs[p])
                good[p] = np.isfinite(X[p]).all()
            except np.linalg.LinAlgError:
                pass
    return np.where(good[:, None, None], X, np.nan), good


def _noisy_cosine_scene(rng, P: int, L: int):
    """Landmarks within 300 m, cameras a few km off: squared pair distances, true and noisy ranges, cosines."""
    I, J = np.triu_indices(L, 1)
    p_lm = rng.uniform(-300, 300, (L, 3))
    d2 = np.sum((p_lm[I] - p_lm[J]) ** 2, -1)
    cam = rng.uniform(-3000, 3000, (P, 3)) + [0, 0, 2000]
    m_true = np.linalg.norm(p_lm - cam[:, None], axis=-1)
    m = m_true * (1 + 1e-4 * rng.normal(size=(P, L)))
    return d2, m_true, m, cosine_model(m_true, d2) + 1e-6 * rng.normal(size=(P, len(I)))


def test_cosine_rule_products_match_the_numpy_formulas():
    """A, B (seed eq. 2), A⁺ = (AᵀWA)⁻¹AᵀW, Σ_V, the residual statistics and the branch gate."""
    rng = np.random.default_rng(7)
    P, L = 300, 4
    I, J = np.triu_indices(L, 1)
    nc = len(I)
    d2, m_true, m, c = _noisy_cosine_scene(rng, P, L)
    colm = np.ones((P, L), bool)  # N_V = 3 or 4, as the monitor passes them (fewer is unavailable before)
    colm[np.arange(P), rng.integers(0, L, P)] = rng.random(P) > 0.5
    pair_mask = colm[:, I] & colm[:, J]
    X = rng.normal(size=(P, nc, nc))
    Sc = 1e-12 * X @ np.swapaxes(X, -1, -2) * (pair_mask[:, :, None] & pair_mask[:, None, :])
    W = np.einsum("pi,ij->pij", pair_mask.astype(float), np.eye(nc))
    m_pred = m_true + rng.normal(size=(P, L))
    Y = rng.normal(size=(P, L, L))
    S_pred = Y @ np.swapaxes(Y, -1, -2)
    m[5, 0] = np.nan  # a non-finite solve: A⁺ not good
    outs = (np.empty((P, nc, L)), np.empty((P, nc)), np.empty((P, L, nc)), np.empty(P, bool), np.empty(P),
            np.empty((P, L, L)), np.empty(P), np.empty(P), np.empty(P), np.empty(P, bool))
    kernels.cosine_rule_products(m, c, d2, colm, pair_mask, W, Sc, m_pred, S_pred, *outs)
    A, B, Ap, good, cond, SigV, r_norm, r_w, gate, gok = outs

    ms = np.where(colm, m, 1.0)
    A_ref, B_ref = cosine_rule_jacobians(ms, c)
    A_ref = A_ref * pair_mask[..., :, None] * colm[..., None, :]
    np.testing.assert_allclose(A, A_ref, rtol=1e-14)
    np.testing.assert_allclose(B, np.where(pair_mask, B_ref, 0.0), rtol=1e-14)
    AtW = np.swapaxes(A_ref, -1, -2) @ W
    Nm = AtW @ A_ref + np.einsum("pi,ij->pij", (~colm).astype(float), np.eye(L))
    Ap_ref, good_ref = _solve_or_nan(Nm, AtW)
    assert np.array_equal(good, good_ref) and not good[5] and good.sum() > 250
    np.testing.assert_allclose(Ap[good], Ap_ref[good], rtol=1e-9, atol=1e-9 * np.abs(Ap_ref[good]).max())
    cond_ref = (np.sqrt(np.sum((A_ref * ms[:, None, :]) ** 2, axis=(-2, -1)))
                * np.sqrt(np.sum((Ap_ref / ms[:, :, None]) ** 2, axis=(-2, -1))))
    np.testing.assert_allclose(cond, np.where(np.isfinite(cond_ref), cond_ref, np.inf), rtol=1e-9)
    SigV_ref = Ap_ref @ Sc @ np.swapaxes(Ap_ref, -1, -2)
    np.testing.assert_allclose(SigV[good], SigV_ref[good], rtol=1e-8, atol=1e-8 * np.abs(SigV_ref[good]).max())
    r = np.where(pair_mask, c - cosine_model(ms, d2), 0.0)
    sc = np.sqrt(np.einsum("pii->pi", Sc))
    np.testing.assert_allclose(r_norm, np.max(np.where(pair_mask, np.abs(r) / np.where(sc > 0, sc, 1.0), 0.0), -1),
                               rtol=1e-8)
    np.testing.assert_allclose(r_w, np.einsum("pi,pij,pj->p", r, W, r), rtol=1e-8, atol=1e-30)
    dm = np.where(colm, m - m_pred, 0.0)
    C = np.where(colm[:, :, None] & colm[:, None, :], SigV_ref + S_pred, 0.0)
    C = C + np.einsum("pi,ij->pij", (~colm).astype(float), np.eye(L))
    x, gok_ref = _solve_or_nan(C, dm[..., None])
    assert np.array_equal(gok, gok_ref)
    np.testing.assert_allclose(gate[gok], np.einsum("pi,pi->p", dm, x[..., 0])[gok], rtol=1e-8)
    assert np.isnan(gate[~gok]).all()


def test_vision_rows_match_the_numpy_formulas():
    """Plain rows (the ranges) or the modified equation's rows (A z), and their weight (T Σ Tᵀ)⁻¹."""
    rng = np.random.default_rng(8)
    P, L = 200, 3
    I, J = np.triu_indices(L, 1)
    nc = len(I)
    A = rng.normal(size=(P, nc, L))
    z = rng.uniform(2000, 8000, (P, L))
    X = rng.normal(size=(P, L, L))
    Sigma = X @ np.swapaxes(X, -1, -2) + 0.1 * np.eye(L)
    used = rng.random((P, L)) > 0.2
    z[used & (rng.random((P, L)) > 0.9)] = np.nan  # a NaN range in a used row: that epoch's rows go
    z[~used] = np.nan
    pair_mask = used[:, I] & used[:, J]
    modified = rng.random(P) > 0.5
    Tm, zr, W, mask = np.empty((P, nc, L)), np.empty((P, nc)), np.empty((P, nc, nc)), np.empty((P, nc), bool)
    kernels.vision_rows(A, z, Sigma, used, pair_mask, modified, Tm, zr, W, mask)

    Tm_ref = np.where(modified[:, None, None], A, np.eye(nc, L))
    mask_ref = np.where(modified[:, None], pair_mask, np.concatenate([used, np.zeros((P, nc - L), bool)], -1))
    z0 = np.where(used & np.isfinite(z), z, 0.0)
    zr_ref = np.einsum("prl,pl->pr", Tm_ref, z0)
    S0 = np.where(used[:, :, None] & used[:, None, :], Sigma, 0.0)
    mm = mask_ref[:, :, None] & mask_ref[:, None, :]
    Sp = np.where(mm, Tm_ref @ S0 @ np.swapaxes(Tm_ref, -1, -2), 0.0) + np.einsum(
        "pi,ij->pij", (~mask_ref).astype(float), np.eye(nc))
    W_ref, good = _solve_or_nan(Sp, np.broadcast_to(np.eye(nc), Sp.shape))
    mask_ref = mask_ref & good[:, None]
    W_ref = np.where(mm & good[:, None, None], W_ref, 0.0)
    np.testing.assert_array_equal(Tm, Tm_ref)
    np.testing.assert_array_equal(mask, mask_ref)
    assert mask.any(-1).mean() > 0.5
    np.testing.assert_allclose(zr, np.where(mask_ref, zr_ref, np.nan), rtol=1e-14, atol=1e-9)
    np.testing.assert_allclose(W, W_ref, rtol=1e-8, atol=1e-10 * np.abs(W_ref).max())


def _fit_batch(rng, P=400, n1=8, R=3):
    """Stacked GPS-like (diagonal) and vision-like (dense block) rows with every degenerate case."""
    N = n1 + R
    G = rng.normal(size=(P, N, 4))
    G[:, :, :3] /= np.linalg.norm(G[:, :, :3], axis=-1, keepdims=True)
    G[:, :n1, 3] = 1.0
    G[:, n1:, 3] = 0.0
    h = rng.uniform(2e7, 2.6e7, (P, N))
    z = h + rng.normal(size=(P, N))
    wd = rng.uniform(0.2, 1.0, (P, n1))
    X = rng.normal(size=(P, R, R))
    Wb = np.linalg.inv(X @ np.swapaxes(X, -1, -2) + 0.5 * np.eye(R))
    mask = rng.random((P, N)) > 0.1
    mask[:20] = True
    G[0, 2, 1] = np.nan  # NaN partial in a used row
    z[1, 3] = np.nan  # NaN measurement in a used row
    mask[2, :n1] = False  # vision rows only: the clock is dropped
    G[3, :, 2] = 0.5 * G[3, :, 3] + 1e-5 * rng.normal(size=N)  # nearly the clock column: ill-conditioned
    mask[4] = False
    mask[4, :4] = True  # exactly determined: no redundancy
    mask[5] = False
    mask[5, :3] = True  # not enough rows
    mask[6] = False  # no rows
    Wb[7, 0, 1] = Wb[7, 1, 0] = np.nan  # NaN weight between used rows
    G[8, 10] = np.nan  # NaN on an unused row: harmless
    mask[8, 10] = False
    G[9, :, 2] = G[9, :, 3]  # the up column equals the clock column: exactly singular
    return h, G, z, wd, Wb, mask


def test_wls_fit_matches_the_oracle_on_every_reason_code():
    """The compiled fit against the textbook numpy/LAPACK oracle, epoch by epoch, for both weight
    forms, on a batch with every reason code; a chunk gives the whole batch's numbers bit for bit."""
    from wls_oracle import oracle_fit

    h, G, z, wd, Wb, mask = _fit_batch(np.random.default_rng(9))
    for W_block in (Wb, None):
        wdiag = wd if W_block is not None else np.concatenate([wd, np.full(Wb.shape[:-1], 2.0)], -1)
        got = lsq.wls_fit(h, G, z, wdiag, W_block, mask)
        ref = oracle_fit(h, G, z, wdiag, W_block, mask)
        np.testing.assert_array_equal(got.reason, ref["reason"])
        assert (ref["reason"] == 0).sum() > 350
        R = lsq.Reason
        assert {int(r) for r in ref["reason"][:10]} >= {R.NAN_INPUT, R.NO_REDUNDANCY, R.NO_POSITION, R.SINGULAR}
        for f in ("n_used", "n_states"):
            np.testing.assert_array_equal(getattr(got, f), ref[f], err_msg=f)
        # well-conditioned epochs to 1e-9; the marginal one (cond ~ 1e8) to cond·ε
        good = got.cond < 1e4
        for f in ("J", "A", "ws_diag", "residual", "sse", "hslope", "vslope", "hmax", "vmax", "cond"):
            a, b = getattr(got, f), ref[f]
            np.testing.assert_allclose(a[good], b[good], rtol=1e-9, atol=1e-12, err_msg=f)
            np.testing.assert_allclose(a[~good], b[~good], rtol=1e-5, atol=1e-9, err_msg=f)
        k2, k1 = ref["cond2"], got.cond
        fin = k2 < 1e15  # not numerically singular (there the kernel says inf)
        assert (k1[fin] >= k2[fin] * (1 - 1e-9)).all() and (k1[fin] <= 4 * k2[fin]).all()  # κ₂ ≤ κ₁ ≤ 4κ₂
        for v in ("seed", "pbias"):
            pl = got.protection_levels(1e-2, 1e-3, v)
            assert np.isfinite(pl.hpl[ref["reason"] == 0]).all() and np.isnan(pl.hpl[ref["reason"] != 0]).all()
        part = lsq.wls_fit(h[:11], G[:11], z[:11], wdiag[:11], None if W_block is None else Wb[:11], mask[:11])
        for f in ("J", "A", "cond", "sse", "hslope", "reason"):
            np.testing.assert_array_equal(getattr(part, f), getattr(got, f)[:11], err_msg=f)


def _fit_outputs(P, N):
    """wls kernels' outputs, pre-filled with a value neither writes (so an unwritten one shows)."""
    f = lambda *s: np.full((P,) + s, 7.0)  # noqa: E731
    i = lambda dt: np.full(P, 7, dt)  # noqa: E731
    return [f(4, 4), f(4, N), f(N), f(), f(N), f(), f(N), f(N), f(), f(), i(np.int64), i(np.int64), i(np.int8)]


def _listed(rng, P: int, subset: bool) -> np.ndarray:
    """The epochs a tiled kernel is asked for: all, or the first 8 (the batches' special cases) and a random
    two thirds of the rest (sorted, as lsq lists them)."""
    return np.flatnonzero((rng.random(P) < 2 / 3) | (np.arange(P) < 8)) if subset else np.arange(P)


@pytest.mark.parametrize("subset", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_side_by_side_fit_gives_the_one_epoch_fit_bit_for_bit(seed, subset):
    """wls_epochs (epochs in vector lanes) against wls_one called on each epoch alone, byte for byte (the
    sign of a zero included), on a batch with every reason code, both weight forms, and more epochs than a tile;
    asked for a subset of the epochs, it writes those, the same bytes, and leaves the others alone."""
    from testbed.integrity.kernels.geometry import TILE

    h, G, z, wd, Wb, mask = _fit_batch(np.random.default_rng(seed), P=3 * TILE + 17)
    N = G.shape[1]
    listed = _listed(np.random.default_rng(seed + 100), len(G), subset)
    others = np.setdiff1d(np.arange(len(G)), listed)
    for wdiag, W_block in ((wd, Wb), (np.concatenate([wd, np.full(Wb.shape[:-1], 2.0)], -1), np.zeros((len(G), 0, 0)))):
        got = _fit_outputs(len(G), N)
        kernels.wls_epochs(G, h, z, wdiag, W_block, mask, 1e10, listed, *got)
        ref = _fit_outputs(len(G), N)
        scratch = (np.empty((4, 4, 4)), np.empty((3, 4)), np.empty(4))
        for p in listed:
            kernels.wls_one(G[p], h[p], z[p], wdiag[p], W_block[p], mask[p], 1e10,
                            *(o[p] if o.ndim > 1 else o[p:p + 1] for o in ref), *scratch)
        for k, (a, b) in enumerate(zip(got, ref)):
            assert a.tobytes() == b.tobytes(), k
            assert (a[others] == 7).all(), k  # not written
        codes = got[-1][listed]
        assert (codes == 0).sum() > (1 if subset else 2) * TILE and len(set(codes.tolist())) == 5  # every reason


def _range_problem(rng, P, NG=8, L=3):
    """Stacked GPS and vision range rows around random truths, with every way an epoch can go wrong."""
    x_true = rng.normal(scale=500.0, size=(P, 4))
    u = rng.normal(size=(P, NG, 3))
    sats = 2.2e7 * u / np.linalg.norm(u, axis=-1, keepdims=True)
    sats[..., 2] = np.abs(sats[..., 2])
    off_g = rng.normal(scale=2.0, size=(P, 3))
    z_g = np.linalg.norm(sats - (x_true[:, None, :3] + off_g[:, None]), axis=-1) + x_true[:, None, 3]
    z_g += rng.normal(size=z_g.shape)
    w_g = rng.uniform(0.2, 1.0, (P, NG))
    mask_g = rng.random((P, NG)) > 0.15
    lm = np.array([[6000.0, 0.0, -3000.0], [6100.0, 80.0, -3000.0], [6050.0, -90.0, -3010.0]])[:L]
    off_v = rng.normal(scale=3.0, size=(P, 3))
    m_true = np.linalg.norm(lm - (x_true[:, None, :3] + off_v[:, None]), axis=-1)
    Tm = np.broadcast_to(np.eye(L) + 0.1 * rng.normal(size=(L, L)), (P, L, L)).copy()
    z_v = np.einsum("prl,pl->pr", Tm, m_true + rng.normal(scale=5.0, size=(P, L)))
    X = rng.normal(size=(P, L, L))
    W_v = np.linalg.inv(X @ np.swapaxes(X, -1, -2) + 0.5 * np.eye(L)) / 25.0
    mask_v = rng.random((P, L)) > 0.15
    x0 = x_true + rng.normal(scale=30.0, size=(P, 4))
    x0[0] = np.nan  # no start
    mask_g[1] = False  # vision rows only: the clock is unobservable (singular)
    w_g[2, :3] = 0.0  # zero weights
    W_v[3, 0, 1] = W_v[3, 1, 0] = np.nan  # a NaN weight between used rows
    z_g[4, 0] = np.nan  # a NaN pseudorange on a used row
    mask_v[5] = False
    x0[6] = [1e9, 1e9, 1e9, 0.0]  # far off: many steps
    return (sats, off_g, z_g, w_g, mask_g, lm, off_v, Tm, z_v, W_v, mask_v, x0)


@pytest.mark.parametrize("subset", [False, True])
@pytest.mark.parametrize("vision", [True, False])
def test_the_side_by_side_gauss_newton_gives_the_per_epoch_one_bit_for_bit(vision, subset):
    """range_gauss_newton_tiles (epochs in vector lanes, stragglers finished alone) against the per-epoch kernel,
    byte for byte, on epochs that converge in 2, 3 or more steps, fail or never start, over several tiles; asked
    for a subset of the epochs, it writes those, the same bytes, and leaves the others alone."""
    from testbed.integrity.kernels.ranges import TILE

    P = 3 * TILE + 5
    args = list(_range_problem(np.random.default_rng(21), P))
    if not vision:
        args[5:11] = [np.zeros((1, 3)), np.zeros((P, 3)), np.zeros((P, 0, 1)), np.zeros((P, 0)), np.zeros((P, 0, 0)),
                      np.zeros((P, 0), bool)]
    Nr = args[2].shape[1] + args[8].shape[1]

    def outs():
        return [np.full((P, 4), 7.0), np.zeros(P, bool), np.full(P, 7), np.full((P, Nr), 7.0), np.full((P, Nr, 4), 7.0)]

    ref, got = outs(), outs()
    listed = _listed(np.random.default_rng(5), P, subset)
    others = np.setdiff1d(np.arange(P), listed)
    kernels.range_gauss_newton(*args, 8, 1e-3, *ref)
    kernels.range_gauss_newton_tiles(*args, listed, 8, 1e-3, *got)
    for k, (a, b) in enumerate(zip(got, ref)):
        assert a[listed].tobytes() == b[listed].tobytes(), k
        assert (a[others] == outs()[k][others]).all(), k  # not written
    steps = ref[2]
    assert ref[1].mean() > 0.9 and not ref[1][:2].any() and steps.max() >= 4 and {0, 2, 3} <= set(steps.tolist())


@pytest.mark.parametrize("L", [3, 4])
def test_the_side_by_side_cosine_solve_gives_the_per_epoch_one_bit_for_bit(L):
    """cosine_gauss_newton_tiles against the per-epoch kernel, byte for byte: landmarks and pairs left out,
    far and NaN starts, NaN cosines, epochs with no landmark, over several tiles."""
    from testbed.integrity.kernels.vision import TILE

    rng = np.random.default_rng(31 + L)
    P = 3 * TILE + 9
    lm = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [50.0, 86.6, 0.0], [40.0, 30.0, 25.0]])[:L]
    I, J = np.triu_indices(L, 1)
    cam = np.column_stack([rng.uniform(-6000, -3000, P), rng.uniform(-500, 500, P), rng.uniform(300, 800, P)])
    m = np.linalg.norm(lm[None] - cam[:, None], axis=-1)
    d2 = np.sum((lm[I] - lm[J]) ** 2, axis=-1)
    c = (m[:, I] ** 2 + m[:, J] ** 2 - d2) / (2 * m[:, I] * m[:, J]) + 1e-7 * rng.normal(size=(P, len(I)))
    W = np.broadcast_to(np.eye(len(I)), (P, len(I), len(I))).copy()
    m0 = m * (1 + 0.01 * rng.normal(size=m.shape))
    colm = rng.random((P, L)) > 0.05
    pair = colm[:, I] & colm[:, J]
    m0[:10] *= 3.0  # far starts: many steps
    m0[10:13] = np.nan
    c[13:16] = np.nan
    colm[16:18] = False
    ref = [np.full((P, L), 7.0), np.full(P, 7), np.zeros(P, bool), np.zeros(P, bool)]
    got = [a.copy() for a in ref]
    kernels.cosine_gauss_newton(c, W, d2, m0, colm, pair, 25, 1e-4, *ref)
    kernels.cosine_gauss_newton_tiles(c, W, d2, m0, colm, pair, 25, 1e-4, *got)
    for k, (a, b) in enumerate(zip(got, ref)):
        assert a.tobytes() == b.tobytes(), k
    steps = ref[1]
    assert ref[2].mean() > 0.8 and steps.max() >= 5 and 0 in set(steps.tolist()) and not ref[3][10:13].all()


@pytest.mark.parametrize("L, gate", [(3, True), (4, True), (3, False)])
def test_the_side_by_side_cosine_products_give_the_per_epoch_ones_bit_for_bit(L, gate):
    """cosine_rule_products_tiles against the per-epoch kernel, byte for byte: landmarks and pairs left out
    (identity pad), NaN ranges and cosines, singular and NaN covariances, with and without the branch gate,
    over several tiles."""
    from testbed.integrity.kernels.vision import TILE

    rng = np.random.default_rng(53 + L)
    P = 3 * TILE + 5
    I, J = np.triu_indices(L, 1)
    nc = len(I)
    d2, m_true, m, c = _noisy_cosine_scene(rng, P, L)
    colm = rng.random((P, L)) > 0.1
    colm[[5, 7, 11]] = True
    colm[9] = False
    pair_mask = colm[:, I] & colm[:, J]
    X = rng.normal(size=(P, nc, nc))
    Sc = 1e-12 * X @ np.swapaxes(X, -1, -2) * (pair_mask[:, :, None] & pair_mask[:, None, :])
    W = np.einsum("pi,ij->pij", pair_mask.astype(float), np.eye(nc)) * rng.uniform(0.5, 2.0, (P, 1, 1))
    m_pred = m_true + rng.normal(size=(P, L))
    Y = rng.normal(size=(P, L, L))
    S_pred = Y @ np.swapaxes(Y, -1, -2) if gate else np.zeros((0, L, L))
    m[5, 0] = np.nan
    c[7] = np.nan
    W[11] = 0.0  # singular normal equations
    if gate:
        S_pred[13] = np.nan
        S_pred[14] = 0.0
    shapes = ((nc, L), (nc,), (L, nc), (), (), (L, L), (), (), (), ())
    kinds = (float, float, float, bool, float, float, float, float, float, bool)
    ref = [np.full((P,) + s, 7, k) for s, k in zip(shapes, kinds)]
    got = [a.copy() for a in ref]
    kernels.cosine_rule_products(m, c, d2, colm, pair_mask, W, Sc, m_pred, S_pred, *ref)
    kernels.cosine_rule_products_tiles(m, c, d2, colm, pair_mask, W, Sc, m_pred, S_pred, *got)
    for k, (a, b) in enumerate(zip(got, ref)):
        assert a.tobytes() == b.tobytes(), k
    good, gok = ref[3], ref[9]
    assert good.mean() > 0.7 and not good[[5, 7, 11]].any()
    assert not gate or (gok.mean() > 0.7 and not gok[13])


@pytest.mark.slow  # moved out of the default set: its run time (the default set stays within 8 min)
def test_the_side_by_side_calibration_gives_the_per_epoch_one_bit_for_bit():
    """calibrate_tiles against calibrate_epochs, byte for byte, on random products with zero B entries, NaN
    ranges, unused landmarks and calibration epochs anywhere in the trial, over several tiles."""
    from testbed.integrity.kernels.calibration import TILE

    rng = np.random.default_rng(41)
    Bt, T, L, nc = 3, TILE + 11, 3, 3
    f = lambda *s: rng.normal(size=(Bt, T) + s)  # noqa: E731
    sym = lambda a: a @ np.swapaxes(a, -1, -2)  # noqa: E731
    m = 6000.0 + 100.0 * f(L)
    m[rng.random(m.shape) < 0.05] = np.nan
    B = f(nc) * 1e-8
    B[rng.random(B.shape) < 0.05] = 0.0
    args = (rng.integers(0, T, (Bt, T)), m, f(nc, L) * 1e-4, B, f(L, nc) * 1e4, sym(f(nc, nc)) * 1e-12,
            sym(f(L, L)), rng.random((Bt, T, L)) > 0.1, f(3) * 100.0, sym(f(3, 3)), f(3), rng.normal(size=(L, 3)) * 50.0,
            sym(rng.normal(size=(nc, nc))))
    outs = lambda: [np.full((Bt, T, L), 7.0), np.full((Bt, T, L), 7.0), np.full((Bt, T, L, L), 7.0),  # noqa: E731
                    np.full((Bt, T, L, L), 7.0)]
    ref, got = outs(), outs()
    kernels.calibrate_epochs(*args, *ref)
    kernels.calibrate_tiles(*args, *got)
    for k, (a, b) in enumerate(zip(got, ref)):
        assert a.tobytes() == b.tobytes(), k
    assert np.isfinite(ref[2]).mean() > 0.5


def test_wls_fit_broadcasts_over_batch_axes_and_checks_its_weights():
    """One (N, 4) geometry against a (2, 3) batch of measurements: the gufunc broadcasts."""
    import pytest

    rng = np.random.default_rng(11)
    G = rng.normal(size=(7, 4))
    G[:, 3] = 1.0
    w = rng.uniform(0.5, 2.0, 7)
    z = rng.normal(size=(2, 3, 7))
    many = lsq.wls_fit(np.zeros(7), G, z, w, None, None)
    one = lsq.wls_fit(np.zeros(7), G, z[1, 2], w, None, None)
    assert many.J.shape == (2, 3, 4, 4) and many.sse.shape == (2, 3)
    np.testing.assert_array_equal(many.sse[1, 2], one.sse)
    with pytest.raises(ValueError, match="W_block"):
        lsq.wls_fit(np.zeros(7), G, z, w[:5], np.eye(3), None)


def test_exactly_singular_and_marginal_geometry():
    """Two identical satellites and no spread: SINGULAR with cond inf or above the limit; a
    geometry at cond ~ 1e8 (under the 1e10 limit) is solved, J to cond·ε of LAPACK's inverse."""
    rng = np.random.default_rng(12)
    G = rng.normal(size=(2, 8, 4))
    G[..., 3] = 1.0
    G[0, :, 2] = 1.0  # the up column equals the clock column: exactly singular
    G[1, :, 2] = 1.0 + 1e-4 * rng.normal(size=8)  # nearly: cond ~ 1e8
    w = np.ones(8)
    ft = lsq.wls_fit(np.zeros(8), G, np.zeros(8), w, None, None)
    assert ft.reason[0] == lsq.Reason.SINGULAR and not ft.cond[0] <= lsq.MAX_COND
    assert np.isnan(ft.J[0]).all() and np.isnan(ft.hslope[0]).all()
    assert ft.reason[1] == lsq.Reason.OK and 1e6 < ft.cond[1] < 1e10
    J = np.linalg.inv(G[1].T @ G[1])
    np.testing.assert_allclose(ft.J[1], J, rtol=ft.cond[1] * 1e-14, atol=0)


def test_used_gps_rows_match_compact_rows_and_take():
    from testbed.frames import LocalFrame
    from testbed.integrity.raim import compact_rows, used_gps_rows

    rng = np.random.default_rng(10)
    P, S = 300, 12
    vis = rng.random((P, S)) > 0.4
    pr = rng.uniform(2e7, 2.6e7, (P, S))
    sigma = rng.uniform(1, 5, (P, S))
    sigma[~vis & (rng.random((P, S)) > 0.5)] = np.nan  # unused slots may hold anything
    sat = np.broadcast_to(rng.normal(size=(S, 3)) * 2e7, (P, S, 3))  # a broadcast view, as the monitors pass
    frame = LocalFrame(29.3, 94.3, 2950.0)
    width = int(vis.sum(-1).max())
    idx, m, z, w, anchor = used_gps_rows(vis, pr, sigma, sat, frame, width)
    idx_ref, m_ref, _ = compact_rows(vis, width)
    np.testing.assert_array_equal(idx, idx_ref)
    np.testing.assert_array_equal(m, m_ref)
    np.testing.assert_array_equal(z, np.take_along_axis(pr, idx_ref, -1))
    np.testing.assert_array_equal(w, np.where(m_ref, 1.0 / np.take_along_axis(sigma, idx_ref, -1) ** 2, 0.0))
    np.testing.assert_allclose(anchor, frame.ecef_to_enu(np.take_along_axis(sat, idx_ref[..., None], -2)),
                               rtol=0, atol=1e-7)


def test_scatter_rows_is_the_inverse_of_compact_rows_with_trailing_rows_kept():
    from testbed.integrity.raim import compact_rows, scatter_rows

    rng = np.random.default_rng(11)
    B, T, S, E = 7, 9, 12, 3
    vis = rng.random((B, T, S)) > 0.4
    idx, m, N = compact_rows(vis)
    vals = rng.normal(size=(B, T, N + E))
    got = scatter_rows(vals, idx, m, S)
    ref = np.full((B, T, S), np.nan)  # the numpy formula the kernel replaced
    np.put_along_axis(ref, idx, np.where(m, vals[..., :N], np.nan), -1)
    np.testing.assert_array_equal(got, np.concatenate([ref, vals[..., N:]], -1))
    np.testing.assert_array_equal(np.isfinite(got[..., :S]), vis)  # NaN exactly on the unused slots
    np.testing.assert_array_equal(scatter_rows(vals[..., :N], idx, m, S), ref)  # no trailing rows


def test_every_serial_kernel_releases_the_gil_so_campaign_blocks_run_side_by_side():
    """A campaign runs its draw blocks on threads with the monitors on one thread each; a compiled entry point
    that holds the GIL serialises them (the DPE's manifold did: one core busy of two on a DPE campaign).
    Inlined helpers run inside their caller; numba's parallel ones run on its own threads."""
    import importlib
    import pkgutil

    from numba.core.registry import CPUDispatcher

    import testbed.integrity.kernels as pkg

    mods = [importlib.import_module(f"testbed.integrity.kernels.{m.name}") for m in pkgutil.iter_modules(pkg.__path__)]
    mods.append(importlib.import_module("testbed.navigation.kernels"))
    holding, checked = [], 0
    for mod in mods:
        for name, f in vars(mod).items():
            if isinstance(f, CPUDispatcher) and f.__module__ == mod.__name__:
                opts = f.targetoptions
                if opts.get("inline") == "always" or opts.get("parallel"):
                    continue
                checked += 1
                if not opts.get("nogil"):
                    holding.append(f"{mod.__name__}.{name}")
    assert checked >= 15 and not holding, holding


def test_fit_and_solve_where_leave_the_other_epochs_unfitted():
    """lsq.wls_fit / gauss_newton_ranges with ``where``: the listed epochs as the whole batch gives them, bit for
    bit; the others not fitted (NaN, counts 0, reason NO_POSITION) and not solved (NaN, not converged, 0 steps)."""
    from testbed.integrity.kernels.geometry import TILE

    P = 2 * TILE + 9
    h, G, z, wd, Wb, mask = _fit_batch(np.random.default_rng(3), P=P)
    where = np.random.default_rng(4).random(P) < 0.5
    full = lsq.wls_fit(h, G, z, wd, Wb, mask)
    part = lsq.wls_fit(h, G, z, wd, Wb, mask, where=where)
    for f in ("J", "A", "ws_diag", "cond", "residual", "sse", "hslope", "vslope", "hmax", "vmax", "n_used",
              "n_states", "reason"):
        a, b = getattr(part, f), getattr(full, f)
        assert a[where].tobytes() == b[where].tobytes(), f
        if f == "reason":
            assert (a[~where] == lsq.Reason.NO_POSITION).all()
        elif f in ("n_used", "n_states"):
            assert (a[~where] == 0).all()
        else:
            assert np.isnan(a[~where]).all(), f

    sats, off_g, z_g, w_g, mask_g, lm, off_v, Tm, z_v, W_v, mask_v, x0 = _range_problem(np.random.default_rng(6), P)
    gps, vision = (sats, off_g, z_g, w_g, mask_g), (lm, off_v, Tm, z_v, W_v, mask_v)
    full = lsq.gauss_newton_ranges(x0, 8, 1e-3, gps, vision)
    part = lsq.gauss_newton_ranges(x0, 8, 1e-3, gps, vision, where=where)
    for k, (a, b) in enumerate(zip(part, full)):
        assert a[where].tobytes() == b[where].tobytes(), k
    x, conv, steps, hh, GG = part
    assert np.isnan(x[~where]).all() and not conv[~where].any() and (steps[~where] == 0).all()
    assert np.isnan(hh[~where]).all() and np.isnan(GG[~where]).all()
