"""A straightforward per-epoch VA-RAIM: the reference the batched monitor must equal.

What one would write first: a Python loop over trials and epochs, small numpy
matrices per epoch, the calibration as a running state, textbook formulas
(the VA-RAIM paper's eq. 12-23) with no masking machinery. Used by
``tests/test_va_raim.py`` (a sample of trials) and ``benchmarks/bench_va_raim.py``
(speed side by side). Nominal data only: every epoch well posed.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from testbed.frames import q_to_R
from testbed.integrity import lsq
from testbed.integrity.levels import service_level
from testbed.integrity.va_raim import VaRaimSettings
from testbed.integrity.vision_ranges import survey_covariance


def _wls(anchor, clock_col, off, z, W, x0, n_iter, tol):
    """Plain Gauss-Newton for one epoch: returns x, G at x, J, A."""
    x = x0.copy()
    for _ in range(n_iter):
        d = anchor - (x[:3] + off)
        rng = np.linalg.norm(d, axis=1)
        G = np.column_stack([-d / rng[:, None], clock_col])
        h = rng + clock_col * x[3]
        J = np.linalg.inv(G.T @ W @ G)
        dx = J @ G.T @ W @ (z - h)
        x = x + dx
        if np.linalg.norm(dx[:3]) < tol:
            break
    d = anchor - (x[:3] + off)
    rng = np.linalg.norm(d, axis=1)
    G = np.column_stack([-d / rng[:, None], clock_col])
    h = rng + clock_col * x[3]
    J = np.linalg.inv(G.T @ W @ G)
    return x, z - h, G, J, J @ G.T @ W


def _pls(G, W, J, A, r, p_fa, p_md):
    n = len(r)
    S = np.eye(n) - G @ A
    WS = W @ S
    sse = float(r @ W @ r)
    dof = n - 4
    T2 = float(stats.chi2.isf(p_fa, dof))
    hs = np.hypot(A[0], A[1]) / np.sqrt(np.diag(WS))
    vs = np.abs(A[2]) / np.sqrt(np.diag(WS))
    kmd = stats.norm.isf(p_md / 2)
    hpl_seed = hs.max() * np.sqrt(T2) + kmd * np.sqrt(J[0, 0] + J[1, 1])
    vpl_seed = vs.max() * np.sqrt(T2) + kmd * np.sqrt(J[2, 2])
    lam = float(lsq.lambda_det(np.array(dof), p_fa, p_md))
    return sse, T2, hpl_seed, vpl_seed, hs.max() * np.sqrt(lam), vs.max() * np.sqrt(lam)


def _vision_one(uv, sig, K, p, m0, n_iter, tol):
    """Cosine-rule ranges for one epoch (all landmarks used)."""
    L = len(p)
    I, Jx = np.triu_indices(L, 1)
    Kinv = np.linalg.inv(K)
    nvec = (Kinv @ np.column_stack([uv, np.ones(L)]).T).T
    nn = np.linalg.norm(nvec, axis=1)
    b = nvec / nn[:, None]
    c = np.sum(b[I] * b[Jx], axis=1)
    Jc = np.zeros((len(I), 2 * L))
    for q, (i, j) in enumerate(zip(I, Jx)):
        dbi = (np.eye(3) - np.outer(b[i], b[i])) / nn[i] @ Kinv[:, :2]
        dbj = (np.eye(3) - np.outer(b[j], b[j])) / nn[j] @ Kinv[:, :2]
        Jc[q, 2 * i:2 * i + 2] = b[j] @ dbi
        Jc[q, 2 * j:2 * j + 2] = b[i] @ dbj
    Sc = Jc @ np.diag(np.repeat(sig**2, 2)) @ Jc.T
    lam, V = np.linalg.eigh(Sc)
    rank = 2 * L - 3
    w = np.zeros_like(lam)
    w[len(lam) - rank:] = 1 / lam[len(lam) - rank:]
    Wc = V @ np.diag(w) @ V.T
    d2 = np.sum((p[I] - p[Jx]) ** 2, axis=1)

    def jac(m, cc):
        A = np.zeros((len(I), L))
        A[np.arange(len(I)), I] = 1 / m[Jx] - cc / m[I]
        A[np.arange(len(I)), Jx] = 1 / m[I] - cc / m[Jx]
        return A

    m = m0.copy()
    for _ in range(n_iter):
        cm = (m[I] ** 2 + m[Jx] ** 2 - d2) / (2 * m[I] * m[Jx])
        A = jac(m, cm)
        dm = np.linalg.solve(A.T @ Wc @ A, A.T @ Wc @ (c - cm))
        m = m + dm
        if np.all(np.abs(dm) < tol):
            break
    A = jac(m, c)
    B = 1 / (2 * m[I] * m[Jx])
    Ap = np.linalg.solve(A.T @ Wc @ A, A.T @ Wc)
    return m, A, B, Ap, Sc, Ap @ Sc @ Ap.T


def va_raim_reference(gnss, vision, frame, st: VaRaimSettings, trials) -> dict[str, np.ndarray]:
    """Per-epoch VA-RAIM for the given trial indices (nominal data: every epoch well posed)."""
    ist, vst = st.integrity, st.vision
    lvl = service_level(st.calibration_level)
    p = frame.ecef_to_enu(vision.landmark_pos_ecef)
    L = len(p)
    Sd = survey_covariance(p, st.landmark_survey_sigma_m)
    T = len(gnss.t)
    keys = ("x", "sse", "T2", "hpl", "vpl", "alert", "m", "z_hat")
    out = {k: [] for k in keys}
    for b in trials:
        cal = None
        res = {k: [] for k in keys}
        for k in range(T):
            R = q_to_R(vision.q_body_to_enu_ref[b, k])
            off_a = R @ gnss.antenna.lever_arm_body
            off_c = R @ vision.camera.lever_arm_body
            vis = gnss.visible[b, k]
            sat = frame.ecef_to_enu(gnss.sat_pos_ecef[b, k, vis])
            zg = gnss.pseudorange[b, k, vis]
            Wg = np.diag(1 / gnss.sigma[b, k, vis] ** 2)
            ones = np.ones(vis.sum())
            xg, rg, Gg, Jg, Ag = _wls(sat, ones, off_a, zg, Wg, np.zeros(4), ist.max_iter, ist.tol_m)
            sse_g, T2g, hs_g, vs_g, hp_g, vp_g = _pls(Gg, Wg, Jg, Ag, rg, ist.p_fa, ist.p_md)
            hpl_g, vpl_g = (hs_g, vs_g) if ist.pl_variant == "seed" else (hp_g, vp_g)
            # vision from the GPS fix
            cam = xg[:3] + off_c
            dv = p - cam
            m_pred = np.linalg.norm(dv, axis=1)
            m, A, B, Ap, Sc, SV = _vision_one(vision.pixel_uv[b, k], vision.sigma_px[b, k], vision.K, p, m_pred,
                                              vst.max_iter, vst.tol_m)
            cand = hpl_g <= lvl.hal and vpl_g <= lvl.val and sse_g <= T2g
            at_cal = False
            if cal is None and cand:
                r0 = np.linalg.norm(p - (xg[:3] + off_c), axis=1)
                H0 = -(p - (xg[:3] + off_c)) / r0[:, None]
                cal = dict(beta0=m - r0, A0=A, B0=B, Ap0=Ap, Sc0=Sc, P=Jg[:3, :3], H0=H0)
                at_cal = True
            zv = None
            if cal is not None and not at_cal:
                M = Ap @ np.diag(B / cal["B0"])
                P0 = cal["A0"] @ cal["Ap0"]
                MAH = M @ cal["A0"] @ cal["H0"]
                Ld = Ap @ np.diag(B) - M @ P0 @ np.diag(cal["B0"])
                beta = M @ cal["A0"] @ cal["beta0"]
                zv = m - beta
                Sv = SV + M @ P0 @ cal["Sc0"] @ P0.T @ M.T + MAH @ cal["P"] @ MAH.T + Ld @ Sd @ Ld.T
            # integrated
            if zv is not None:
                Tm = A if (L == 3 and st.modified_equation) else np.eye(L)
                Wv = np.linalg.inv(Tm @ Sv @ Tm.T)
                anchor = np.vstack([sat, p])
                n_g = len(zg)
                Wi = np.zeros((n_g + len(Wv),) * 2)
                Wi[:n_g, :n_g] = Wg
                Wi[n_g:, n_g:] = Wv

                def linearise(x):
                    """Integrated rows (GPS + modified vision) at x: G, residual, J, A."""
                    d = anchor - np.vstack([np.tile(x[:3] + off_a, (n_g, 1)), np.tile(x[:3] + off_c, (L, 1))])
                    rng = np.linalg.norm(d, axis=1)
                    Graw = np.column_stack([-d / rng[:, None], np.r_[ones, np.zeros(L)]])
                    h = rng + np.r_[ones, np.zeros(L)] * x[3]
                    G = np.vstack([Graw[:n_g], Tm @ Graw[n_g:]])
                    resid = np.r_[zg - h[:n_g], Tm @ (zv - h[n_g:])]
                    J = np.linalg.inv(G.T @ Wi @ G)
                    Ai = J @ G.T @ Wi
                    return G, resid, J, Ai

                x = xg.copy()
                for _ in range(ist.max_iter):
                    G, resid, J, Ai = linearise(x)
                    dx = Ai @ resid
                    x = x + dx
                    if np.linalg.norm(dx[:3]) < ist.tol_m:
                        break
                G, resid, J, Ai = linearise(x)
                sse, T2, hs, vs, hp, vp = _pls(G, Wi, J, Ai, resid, ist.p_fa, ist.p_md)
                hpl, vpl = (hs, vs) if ist.pl_variant == "seed" else (hp, vp)
            else:
                x, sse, T2, hpl, vpl = xg, sse_g, T2g, hpl_g, vpl_g
            res["x"].append(x)
            res["sse"].append(sse)
            res["T2"].append(T2)
            res["hpl"].append(hpl)
            res["vpl"].append(vpl)
            res["alert"].append(sse > T2)
            res["m"].append(m)
            res["z_hat"].append(zv if zv is not None else np.full(L, np.nan))
        for kk in keys:
            out[kk].append(np.array(res[kk]))
    return {kk: np.array(v) for kk, v in out.items()}


def check_same_numbers(sc, out, st, trials) -> None:
    ref = va_raim_reference(sc.gnss, sc.vision, sc.frame, st, trials)
    x = np.concatenate([out.pos_enu, out.clock[..., None]], -1)[trials]
    d = out.diagnostics
    np.testing.assert_allclose(ref["x"], x, atol=1e-3, err_msg="position/clock")
    np.testing.assert_allclose(ref["m"], d.vision_m[trials], rtol=1e-9, atol=1e-4, err_msg="vision ranges")
    used = np.isfinite(ref["z_hat"])  # the reference leaves the calibration epoch itself unused
    assert np.array_equal(used.all(-1), d.vision_rows_used[trials]), "epochs with vision rows"
    np.testing.assert_allclose(ref["z_hat"][used], d.z_hat[trials][used], rtol=1e-9, atol=1e-4,
                               err_msg="calibrated")
    np.testing.assert_allclose(ref["sse"], out.test_stat[trials], rtol=1e-5, atol=1e-6, err_msg="SSE")
    np.testing.assert_allclose(ref["T2"], out.threshold[trials], rtol=1e-9, err_msg="threshold")
    np.testing.assert_allclose(ref["hpl"], out.hpl[trials], rtol=1e-6, err_msg="HPL")
    np.testing.assert_allclose(ref["vpl"], out.vpl[trials], rtol=1e-6, err_msg="VPL")
    np.testing.assert_array_equal(ref["alert"], out.alert[trials], err_msg="alerts")
