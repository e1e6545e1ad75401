"""Compiled ARAIM kernels: every fault mode's subset statistics, and the protection levels.

Subset statistics (:func:`subset_stats_epochs`). A mode that removes one or two rows and leaves every clock a
row is a rank-one or rank-two downdate of the all-in-view solution (no n × n inverse: O(n² + N) per mode);
any other mode's normal matrix is the all-in-view one with the removed rows' outer products subtracted
(Gᵀ W_k G = Gᵀ W G − Σ_{i∈R_k} w_i g_i g_iᵀ, eq. 9), inverted by the shared Jacobi-scaled LDLᵀ of
:mod:`testbed.integrity.kernels.small`. Both paths apply the same condition test (the 1-norm condition
number of the Jacobi-scaled matrix, :func:`~testbed.integrity.kernels.small._condition_1`) to the mode's
own matrix and inverse.

Protection levels (:func:`protection_levels_epochs`): the thresholds, eq. 16's terms, the bracket and the
ADD's half-interval search of :func:`testbed.integrity.araim.protection.solve_protection_level`, step for step
(the same midpoints, the same verdicts, the same result), with the terms that cannot matter set aside:
at the bracket's low end a term k is bounded for every later midpoint by p_k·Q(z_k) ≤ p_k·½·exp(−z_k²/2)
(z grows with the PL), so a term whose bound is at most ε = 10⁻³·target/K is not evaluated and the K_dead
such terms count ε each. A midpoint whose evaluated sum alone exceeds the target, or whose sum plus the
dead terms' K_dead·ε stays below it (each with a 10⁻¹² relative margin for rounding), has the verdict the
full sum would give; any other is summed in full, in the full sum's order. Near the root most of the
hundreds of modes of three constellations are dead (their priors are 10⁻¹⁰-10⁻⁹ and their thresholds
far below the PL).

The epochs of a batch are independent: each is computed alone on one thread (``prange``; a small batch on
one thread, :func:`testbed.integrity.araim.subsets.run_kernel`), so the results do not depend on the
number of threads or on what else is in the batch.
"""

from __future__ import annotations

import math
import sys

import numpy as np
from numba import njit, prange

from testbed.integrity.kernels.small import _condition_1, _scaled_ldl_inverse
from testbed.kernel_cache import keep_in_step

SQRT_HALF = 0.7071067811865476
#: relative margin of a verdict taken without the dead terms (the sums' rounding is ~K·10⁻¹⁶)
VERDICT_MARGIN = 1e-12


@njit(cache=True, nogil=True, error_model="numpy")
def _direct(A0, G_e, w, removed_k, empty_clock_k, inv, max_cond, work, vec) -> bool:
    """(Gᵀ W_k G)⁻¹ into ``inv`` from the all-in-view matrix less the removed rows, a clock without rows pinned;
    False when singular or worse conditioned than ``max_cond``. work (4, n, n), vec (3, n): scratch."""
    n = A0.shape[0]
    N = G_e.shape[0]
    A = work[0]
    A[:, :] = A0
    for i in range(N):
        if removed_k[i]:
            for a in range(n):
                for b in range(n):
                    A[a, b] -= G_e[i, a] * G_e[i, b] * w[i]
    for c in range(n - 3):
        if empty_clock_k[c]:  # no row left: the clock is pinned, the others unchanged
            for a in range(n):
                A[3 + c, a] = 0.0
                A[a, 3 + c] = 0.0
            A[3 + c, 3 + c] = 1.0
    d = vec[0]
    cond = _scaled_ldl_inverse(A, d, work[1], work[2], work[3], vec[1], vec[2])
    if not cond <= max_cond:
        return False
    Si = work[3]
    for a in range(n):
        for b in range(n):
            inv[a, b] = Si[a, b] / (d[a] * d[b])
    return True


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _downdate_condition_ok(A0, inv0, G_e, w, Sfull, i0, i1, r, q00, q01, q11, max_cond, work, vec) -> bool:
    """The direct path's condition test on the downdated matrix A_k = A0 − Σ w g gᵀ and its inverse
    (Gᵀ W_k G)⁻¹ = inv0 + S⁽⁰⁾_{:,R} P_RR⁻¹ S⁽⁰⁾_{:,R}ᵀ, both Jacobi-scaled by diag(A_k)^½.

    First a bound that needs the diagonals only: the scaled matrix S has a unit diagonal and, positive
    definite, off-diagonal entries of at most 1, so ‖S‖₁ ≤ n; its inverse, positive definite too, has no entry
    above its largest diagonal entry, so ‖S⁻¹‖₁ ≤ n·max_a (S⁻¹)_aa. When n²·max_a (S⁻¹)_aa is within
    ``max_cond`` so is the condition number; otherwise (or with a diagonal that is not positive) the full
    1-norm test decides."""
    n = A0.shape[0]
    sd = vec[0]
    bound_ok = True
    worst = 0.0
    for a in range(n):
        aa = A0[a, a] - G_e[i0, a] * G_e[i0, a] * w[i0]
        if r == 2:
            aa -= G_e[i1, a] * G_e[i1, a] * w[i1]
        if not aa > 0.0:
            return False
        sd[a] = math.sqrt(aa)
        u0, u1 = Sfull[a, i0], Sfull[a, i1]
        if r == 1:
            iv = inv0[a, a] + u0 * q00 * u0
        else:
            iv = inv0[a, a] + u0 * (q00 * u0 + q01 * u1) + u1 * (q01 * u0 + q11 * u1)
        bound_ok = bound_ok and iv > 0.0
        worst = max(worst, iv * aa)
    if bound_ok and n * n * worst <= max_cond:
        return True
    S = work[0]
    Si = work[1]
    for a in range(n):
        u0a, u1a = Sfull[a, i0], Sfull[a, i1]
        for b in range(n):
            ab = A0[a, b] - G_e[i0, a] * G_e[i0, b] * w[i0]
            u0b, u1b = Sfull[b, i0], Sfull[b, i1]
            if r == 1:
                iv = inv0[a, b] + u0a * q00 * u0b
            else:
                ab -= G_e[i1, a] * G_e[i1, b] * w[i1]
                iv = inv0[a, b] + u0a * (q00 * u0b + q01 * u1b) + u1a * (q01 * u0b + q11 * u1b)
            S[a, b] = ab / (sd[a] * sd[b])
            Si[a, b] = iv * (sd[a] * sd[b])
    cond = _condition_1(S, Si)
    return math.isfinite(cond) and cond <= max_cond


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _downdate_biases(Sfull, q, Pm, ca, cb, i0, i1, b_nom, b_cont):
    """Eq. 11 and 13 of axis ``q`` of a downdated mode, S_q⁽ᵏ⁾ − S_q⁽⁰⁾ = −(ca·P_{i0,:} + cb·P_{i1,:}) and 0 − S_q⁽⁰⁾
    on the removed rows: (Σ|s|b_nom, Σ|ds|b_cont). (Whole arrays and indices, not row views: a view per mode
    costs more than the sums.)"""
    bb = 0.0
    bss = 0.0
    for i in range(b_nom.shape[0]):  # every row as if kept (no branch: the loop vectorises) ...
        ds = -(ca * Pm[i0, i] + cb * Pm[i1, i])
        bb += abs(Sfull[q, i] + ds) * b_nom[i]
        bss += abs(ds) * b_cont[i]
    for j in range(2 if i1 != i0 else 1):  # ... then the removed rows corrected to S⁽ᵏ⁾ = 0 there
        i = i0 if j == 0 else i1
        ds = -(ca * Pm[i0, i] + cb * Pm[i1, i])
        bb -= abs(Sfull[q, i] + ds) * b_nom[i]
        bss += (abs(Sfull[q, i]) - abs(ds)) * b_cont[i]
    return max(bb, 0.0), max(bss, 0.0)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _weighted_gram(Pm, c, X, PC):
    """X = P diag(c) P (P symmetric (N, N)); PC (N, N) scratch."""
    N = Pm.shape[0]
    for j in range(N):
        for i in range(N):
            PC[j, i] = Pm[j, i] * c[i]
    for i in range(N):
        for j in range(i + 1):
            acc = 0.0
            for t in range(N):
                acc += Pm[i, t] * PC[j, t]
            X[i, j] = acc
            X[j, i] = acc


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _row_sums(S, Sfull, q, c_int, c_acc, b_nom, b_cont, residual):
    """Eq. 10-13 and the separation of one axis from the mode's rows S⁽ᵏ⁾ and the all-in-view S⁽⁰⁾."""
    s2 = 0.0
    bb = 0.0
    ss2 = 0.0
    bss = 0.0
    sep = 0.0
    for i in range(c_int.shape[0]):
        s = S[q, i]
        ds = s - Sfull[q, i]
        s2 += s * s * c_int[i]
        bb += abs(s) * b_nom[i]
        ss2 += ds * ds * c_acc[i]
        bss += abs(ds) * b_cont[i]
        sep += ds * residual[i]
    return s2, bb, ss2, bss, sep


@njit(cache=True, nogil=True, error_model="numpy", fastmath={"reassoc", "nsz"})
def _epoch_stats(e, G, c_int, c_acc, b_nom, b_cont, residual, has_residual, removed, empty_clock,
                 structurally_ok, max_cond, rows, n_removed, fast, observable, sigma, bias, sigma_ss, bias_ss,
                 separation, s0):
    """:func:`subset_stats_epochs` for epoch ``e`` (its own scratch: epochs run on any thread). Its helpers are
    inlined (a call per mode and axis cost as much as the sums) and its sums may be reassociated, so that they
    vectorise: the order of a sum is fixed by the compiled code, the same for every epoch and thread."""
    N, n = G.shape[1], G.shape[2]
    M = removed.shape[0]
    G_e = G[e]
    A0 = np.empty((n, n))
    inv0 = np.empty((n, n))
    inv = np.empty((n, n))
    S = np.empty((3, N))
    Sfull = np.empty((n, N))
    Pm = np.empty((N, N))
    X = np.empty((N, N))
    PC = np.empty((N, N))
    pres = np.empty(N)
    var0 = np.empty(3)
    w = np.empty(N)
    work = np.empty((4, n, n))
    vec = np.empty((3, n))
    for i in range(N):
        w[i] = 1.0 / c_int[e, i]
    for a in range(n):
        for b in range(n):
            acc = 0.0
            for i in range(N):
                acc += G_e[i, a] * G_e[i, b] * w[i]
            A0[a, b] = acc
    ok0 = structurally_ok[0] and _direct(A0, G_e, w, removed[0], empty_clock[0], inv0, max_cond, work, vec)
    if ok0:
        for a in range(n):  # S⁽⁰⁾ (all states) and P = W − W G S⁽⁰⁾
            for i in range(N):
                acc = 0.0
                for b in range(n):
                    acc += inv0[a, b] * G_e[i, b]
                Sfull[a, i] = acc * w[i]
        for i in range(N):
            for j in range(N):
                acc = 0.0
                for a in range(n):
                    acc += G_e[i, a] * Sfull[a, j]
                Pm[i, j] = (w[i] if i == j else 0.0) - w[i] * acc
        for q in range(3):
            for i in range(N):
                s0[e, q, i] = Sfull[q, i]
        # closed forms of a downdate (c = P_RR⁻¹ S⁽⁰⁾_{q,R}ᵀ, ds = −c P_{R,:}): with W = C_int⁻¹, S⁽⁰⁾ C_int P = 0 and
        # P C_int P = P, so σ⁽ᵏ⁾² = σ⁽⁰⁾² + c·S⁽⁰⁾_{q,R}; σ_ss² = cᵀ (P C_acc P)_RR c; separation −c·(P Δy)_R
        _weighted_gram(Pm, c_acc[e], X, PC)
        for i in range(N):
            acc = 0.0
            for j in range(N):
                acc += Pm[i, j] * residual[e, j]
            pres[i] = acc
        for q in range(3):
            acc = 0.0
            for i in range(N):
                acc += Sfull[q, i] * Sfull[q, i] * c_int[e, i]
            var0[q] = acc
    else:
        Sfull[:, :] = 0.0  # the separations of an epoch without an all-in-view solution are NaN (below)
    res, ci, ca_, bn, bc = residual[e], c_int[e], c_acc[e], b_nom[e], b_cont[e]  # views made once an epoch
    for k in range(M):
        r = n_removed[k]
        i0 = rows[k, 0]
        i1 = rows[k, 1] if r == 2 else i0
        down = ok0 and fast[k]
        q00, q01, q11 = 0.0, 0.0, 0.0
        if k == 0:
            ok = ok0
        elif down:  # S⁽ᵏ⁾ = S⁽⁰⁾ − S⁽⁰⁾_{:,R} P_RR⁻¹ P_{R,:} (eq. 9a), P_RR⁻¹ in closed form
            if r == 1:
                p00 = Pm[i0, i0]
                ok = abs(p00) > 1e-12 * w[i0]
                if ok:
                    q00 = 1.0 / p00
            else:
                p00, p01, p11 = Pm[i0, i0], Pm[i0, i1], Pm[i1, i1]
                det = p00 * p11 - p01 * p01
                ok = abs(det) > 1e-12 * w[i0] * w[i1]
                if ok:
                    q00, q01, q11 = p11 / det, -p01 / det, p00 / det
            ok = ok and _downdate_condition_ok(A0, inv0, G_e, w, Sfull, i0, i1, r, q00, q01, q11, max_cond,
                                               work, vec)
        else:
            ok = structurally_ok[k] and _direct(A0, G_e, w, removed[k], empty_clock[k], inv, max_cond, work, vec)
            if ok:
                for q in range(3):  # S⁽ᵏ⁾ = (Gᵀ W_k G)⁻¹ Gᵀ W_k, position rows (eq. 9)
                    for i in range(N):
                        if removed[k, i]:
                            S[q, i] = 0.0
                        else:
                            acc = 0.0
                            for a in range(n):
                                acc += inv[q, a] * G_e[i, a]
                            S[q, i] = acc * w[i]
        observable[e, k] = ok
        if not ok:
            for q in range(3):
                sigma[e, k, q] = np.nan
                bias[e, k, q] = np.nan
                sigma_ss[e, k, q] = np.nan
                bias_ss[e, k, q] = np.nan
                separation[e, k, q] = np.nan
                if k == 0:
                    for i in range(N):
                        s0[e, q, i] = np.nan
            continue
        for q in range(3):  # eq. 10-13 and the separation
            if k == 0:
                s2, bb, ss2, bss, sep = _row_sums(Sfull, Sfull, q, ci, ca_, bn, bc, res)
            elif down:
                ca = Sfull[q, i0] * q00 + Sfull[q, i1] * q01
                cb = Sfull[q, i0] * q01 + Sfull[q, i1] * q11
                bb, bss = _downdate_biases(Sfull, q, Pm, ca, cb, i0, i1, bn, bc)
                s2 = var0[q] + ca * Sfull[q, i0] + cb * Sfull[q, i1]
                ss2 = max(ca * ca * X[i0, i0] + 2.0 * ca * cb * X[i0, i1] + cb * cb * X[i1, i1], 0.0)
                sep = -(ca * pres[i0] + cb * pres[i1])
            else:
                s2, bb, ss2, bss, sep = _row_sums(S, Sfull, q, ci, ca_, bn, bc, res)
            sigma[e, k, q] = math.sqrt(s2)
            bias[e, k, q] = bb
            sigma_ss[e, k, q] = math.sqrt(ss2) if ok0 else np.nan
            bias_ss[e, k, q] = bss if ok0 else np.nan
            separation[e, k, q] = sep if (ok0 and has_residual) else np.nan


@njit(cache=True, nogil=True, error_model="numpy")
def _mode_rows(removed, empty_clock, structurally_ok, n_clock):
    """Per mode: its removed rows (the first two), how many, and whether it is a downdate (one or two rows,
    every clock left a row)."""
    M, N = removed.shape
    n_removed = np.zeros(M, np.int64)
    rows = np.zeros((M, 2), np.int64)
    fast = np.zeros(M, np.bool_)
    for k in range(M):
        for i in range(N):
            if removed[k, i]:
                if n_removed[k] < 2:
                    rows[k, n_removed[k]] = i
                n_removed[k] += 1
        fast[k] = 1 <= n_removed[k] <= 2 and structurally_ok[k]
        for c in range(n_clock):
            if empty_clock[k, c]:
                fast[k] = False
    return rows, n_removed, fast


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def subset_stats_epochs(G, c_int, c_acc, b_nom, b_cont, residual, has_residual, removed, empty_clock,
                        structurally_ok, max_cond, observable, sigma, bias, sigma_ss, bias_ss, separation, s0):
    """Eq. 9-13 for every epoch (E) and mode (M); mode 0 removes nothing. Shapes as
    :func:`testbed.integrity.araim.subsets.subset_stats` (outputs filled in place): G (E, N, n) rows,
    removed (M, N) bool, empty_clock (M, n − 3) bool clocks a mode leaves without a row, structurally_ok (M)
    bool. A mode of one or two rows that leaves every clock a row is a downdate of the all-in-view solution,
    any other a direct solve (:func:`_direct`). Epochs run in parallel, each alone."""
    rows, n_removed, fast = _mode_rows(removed, empty_clock, structurally_ok, G.shape[2] - 3)
    for e in prange(G.shape[0]):
        _epoch_stats(e, G, c_int, c_acc, b_nom, b_cont, residual, has_residual, removed, empty_clock,
                     structurally_ok, max_cond, rows, n_removed, fast, observable, sigma, bias, sigma_ss, bias_ss,
                     separation, s0)


@njit(cache=True, nogil=True, error_model="numpy")
def _risk_exceeds(mid, offset, sig, wt, cap, K, target) -> bool:
    """Eq. 16's left side at ``mid`` over terms 0 … K−1 (a term of weight 0 unused), in order, stopped as soon as
    it exceeds ``target`` (the terms are non-negative: the verdict is in): above the target?"""
    risk = 0.0
    for t in range(K):
        if wt[t] > 0.0:
            z = (mid - offset[t]) / sig[t]
            qz = 1.0 if z <= 0.0 else 0.5 * math.erfc(z * SQRT_HALF)
            risk += wt[t] * min(qz, cap[t])
            if risk > target:
                return True
    return False


@njit(cache=True, nogil=True, error_model="numpy")
def _epoch_protection(e, sigma, bias, sigma_ss, bias_ss, separation, observable, k_fa, p, alpha, prior_class,
                      z_lo, z_hi, z_dead, eps, target, protectable, has_residual, p_emt, tol, threshold, pl,
                      iterations, emt, ratio):
    """:func:`protection_levels_epochs` for epoch ``e``."""
    M = sigma.shape[1]
    offset = np.empty(M)
    sig = np.empty(M)
    wt = np.empty(M)
    cap = np.empty(M)
    cls = np.empty(M, np.int64)
    live = np.empty(M, np.int64)
    e_mt = 0.0
    worst = -np.inf
    undefined = False  # a monitored mode's ratio is NaN (as numpy's max, the result is then NaN)
    for q in range(3):
        threshold[e, 0, q] = 0.0
        for k in range(1, M):
            threshold[e, k, q] = k_fa[e, q] * sigma_ss[e, k, q] + bias_ss[e, k, q]  # T_k,q (eq. 15)
            if observable[e, k]:
                if q == 2 and p[k] >= p_emt:
                    e_mt = max(e_mt, threshold[e, k, q])  # eq. 17
                x = abs(separation[e, k, q]) / threshold[e, k, q]
                if math.isnan(x):
                    undefined = True
                else:
                    worst = max(worst, x)
    emt[e] = e_mt
    ratio[e] = np.nan if (undefined or not has_residual) else max(worst, 0.0)
    for q in range(3):
        if not protectable[e]:
            pl[e, q] = np.inf
            iterations[e, q] = 0
            continue
        tg = target[e, q]
        K = 0  # eq. 16's terms, in mode order: the fault-free one, then every monitored mode
        for k in range(M):
            if k == 0 or (observable[e, k] and p[k] > 0.0):  # a term of weight 0 is unused
                offset[K] = bias[e, k, q] if k == 0 else threshold[e, k, q] + bias[e, k, q]
                sig[K] = sigma[e, k, q]
                wt[K] = 2.0 if k == 0 else p[k]
                cap[K] = alpha[k]
                cls[K] = prior_class[k]
                K += 1
        # bracket: low end, the largest solution of a term that alone reaches the target; high end, the
        # largest PL at which every term is at most target/K
        low = -np.inf
        high = -np.inf
        for t in range(K):
            if wt[t] * cap[t] >= tg:
                low = max(low, offset[t] + z_lo[e, q, cls[t]] * sig[t])
            high = max(high, offset[t] + z_hi[e, q, cls[t]] * sig[t])
        low = low if math.isfinite(low) else 0.0
        # the terms that can matter above the low end; every other is at most eps[e, q]
        n_live = 0
        n_dead = 0
        for t in range(K):
            if wt[t] * cap[t] <= eps[e, q] or (low - offset[t]) / sig[t] >= z_dead[e, q, cls[t]]:
                n_dead += 1
            else:
                live[n_live] = t
                n_live += 1
        slack = n_dead * eps[e, q]
        it = 0
        while high - low > tol:
            mid = 0.5 * (low + high)
            part = 0.0
            for j in range(n_live):
                t = live[j]
                z = (mid - offset[t]) / sig[t]
                qz = 1.0 if z <= 0.0 else 0.5 * math.erfc(z * SQRT_HALF)
                part += wt[t] * min(qz, cap[t])
                if part > tg * (1.0 + VERDICT_MARGIN):
                    break
            if part > tg * (1.0 + VERDICT_MARGIN):
                above = True
            elif (part + slack) * (1.0 + VERDICT_MARGIN) <= tg:
                above = False
            else:  # too close to call without the dead terms: the full sum
                above = _risk_exceeds(mid, offset, sig, wt, cap, K, tg)
            if above:
                low = mid
            else:
                high = mid
            it += 1
        pl[e, q] = high
        iterations[e, q] = it


@njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def protection_levels_epochs(sigma, bias, sigma_ss, bias_ss, separation, observable, k_fa, p, alpha, prior_class,
                             z_lo, z_hi, z_dead, eps, target, protectable, has_residual, p_emt, tol, threshold, pl,
                             iterations, emt, ratio):
    """Thresholds (eq. 15), the protection levels (eq. 16), EMT (eq. 17) and the test ratio of every epoch.

    Inputs (E epochs, M modes, mode 0 fault-free; a mode is monitored where ``observable`` and k ≥ 1):
    sigma, bias, sigma_ss, bias_ss, separation (E, M, 3) from :func:`subset_stats_epochs`; k_fa (E, 3);
    p, alpha (M) priors and missed-detection caps (alpha[0] = 1); prior_class (M) index of each mode's weight
    (2 for mode 0, p_k else) into the per-weight tables z_lo, z_hi, z_dead (E, 3, U): Q⁻¹(min(target/w, 1)),
    max(Q⁻¹(min(target/(K·w), 1)), 10⁻⁶) and √(2 ln(w/(2ε))) (0 when w ≤ 2ε); eps, target (E, 3);
    protectable (E) bool; has_residual; p_emt; tol (m).
    Outputs: threshold (E, M, 3) (0 for mode 0), pl (E, 3) (∞ where not protectable), iterations (E, 3),
    emt (E), ratio (E) max |separation|/T over monitored modes and axes (−∞ with none, NaN without residuals).
    """
    for e in prange(sigma.shape[0]):
        _epoch_protection(e, sigma, bias, sigma_ss, bias_ss, separation, observable, k_fa, p, alpha, prior_class,
                          z_lo, z_hi, z_dead, eps, target, protectable, has_residual, p_emt, tol, threshold, pl,
                          iterations, emt, ratio)


@njit(cache=True, nogil=True, error_model="numpy")
def halve_protection_levels(offset, sigma, weight, cap, target, lo, hi, tol, iterations):
    """Halve each bracket [lo, hi] (P,) of eq. 16 (terms (P, K)) until it is at most ``tol`` wide; ``hi`` and
    ``iterations`` updated in place. A term with weight 0 is unused."""
    P, K = offset.shape
    for p in range(P):
        low = lo[p]
        high = hi[p]
        it = 0
        while high - low > tol:
            mid = 0.5 * (low + high)
            if _risk_exceeds(mid, offset[p], sigma[p], weight[p], cap[p], K, target[p]):
                low = mid
            else:
                high = mid
            it += 1
        hi[p] = high
        iterations[p] = it


# numba compiles a kernel again when its own file changes, not when a helper's does
keep_in_step(sys.modules[__name__])
