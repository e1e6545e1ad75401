"""ARAIM thresholds, protection levels, EMT and availability (docs/design/araim.md §5-§7).

The protection level of axis q solves the integrity-risk equation (eq. 16)

    2·Q̃((PL − b_q⁽⁰⁾)/σ_q⁽⁰⁾) + Σ_{k≥1} p_k·min(Q̃((PL − T_k,q − b_q⁽ᵏ⁾)/σ_q⁽ᵏ⁾), α_k) = P_q / N_ES,int

with Q̃(x) = 1 for x ≤ 0, else Q(x) = 1 − Φ(x), by the ADD's half-interval search: from a bracket that
holds the root, halve until it is at most TOL_PL wide and return its upper end (within TOL_PL above the
root, never below it); the halving runs compiled (:mod:`testbed.integrity.araim.kernels`), with the terms
that cannot change a verdict set aside (:func:`protection_levels`). All arrays are batched: epochs first,
modes next, axes last.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr, ndtri

from testbed.integrity.araim.kernels import halve_protection_levels, protection_levels_epochs
from testbed.integrity.araim.subsets import SubsetStats, run_kernel
from testbed.integrity.kernels import kernel_input
from testbed.integrity.levels import service_level

#: LPV-200 limits on EMT and σ_acc,v (m) beside the HAL/VAL of the service level (eq. 19)
EMT_LIMITS = {"LPV-200": 15.0}
SIGMA_ACC_V_LIMITS = {"LPV-200": 1.87}


def q_function(x: NDArray) -> NDArray:
    """Q(x) = 1 − Φ(x), accurate in the far tail."""
    return ndtr(-x)


def q_inverse(p: NDArray) -> NDArray:
    """Q⁻¹(p): the x with Q(x) = p."""
    return -ndtri(p)


def q_tilde(x: NDArray) -> NDArray:
    """Q̃(x): 1 for x ≤ 0 (a mode's error may sit anywhere up to its threshold), else Q(x)."""
    return np.where(x <= 0.0, 1.0, q_function(x))


def fa_multipliers(n_modes: NDArray, p_fa_hor: float, p_fa_vert: float, n_es_cont: int) -> NDArray:
    """K_fa per axis (eq. 14): Q⁻¹(P_FA,H/(4·N_ES·N_modes)) for E and N, Q⁻¹(P_FA,V/(2·N_ES·N_modes)) for U.

    n_modes : (...) monitored fault modes.  Returns (..., 3).
    """
    n = np.maximum(np.asarray(n_modes, float), 1.0)
    kh = q_inverse(p_fa_hor / (4.0 * n_es_cont * n))
    kv = q_inverse(p_fa_vert / (2.0 * n_es_cont * n))
    return np.stack([kh, kh, kv], axis=-1)


def integrity_risk(pl: NDArray, offset: NDArray, sigma: NDArray, weight: NDArray, cap: NDArray) -> NDArray:
    """The left side of eq. 16 at ``pl`` (...), terms along the last axis of ``offset``, ``sigma``, ``weight``,
    ``cap`` (..., K): Σ weight·min(Q̃((pl − offset)/sigma), cap). Unused terms carry weight 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (pl[..., None] - offset) / sigma
        term = weight * np.minimum(q_tilde(z), cap)
    return np.sum(np.where(weight > 0.0, term, 0.0), axis=-1)


def solve_protection_level(offset: NDArray, sigma: NDArray, weight: NDArray, cap: NDArray, target: NDArray,
                           tol: float) -> tuple[NDArray, NDArray]:
    """Half-interval search of eq. 16: the upper end of a bracket ≤ ``tol`` wide holding the root.

    Parameters
    ----------
    offset, sigma, weight, cap : (..., K) per term: T + b (m), σ (m), the prior (2 for the fault-free term),
        the cap α on the missed detection (1 for the fault-free term). A term with weight 0 is unused.
    target : (...) the right side, P_q/N_ES,int (> 0).

    Returns
    -------
    pl : (...) m.  iterations : (...) halvings taken.
    """
    used = weight > 0.0
    # low end: a term that alone reaches the target puts the root above its own solution
    alone = used & (weight * cap >= target[..., None])
    with np.errstate(divide="ignore", invalid="ignore"):
        lo_k = offset + q_inverse(np.minimum(target[..., None] / weight, 1.0)) * sigma
        n_terms = used.sum(-1, keepdims=True)
        # high end: every term at most target/K makes the sum at most the target (a term whose share
        # exceeds Q(0) is met just above its offset, where Q̃ < 1/2; a share above 1 likewise, not Q⁻¹'s NaN)
        share = np.minimum(target[..., None] / (n_terms * weight), 1.0)
        hi_k = offset + np.maximum(q_inverse(share), 1e-6) * sigma
    lo = np.max(np.where(alone, lo_k, -np.inf), axis=-1)
    lo = np.where(np.isfinite(lo), lo, 0.0)
    hi = np.max(np.where(used, hi_k, -np.inf), axis=-1)
    batch, K = lo.shape, offset.shape[-1]
    P = int(np.prod(batch, dtype=np.int64))
    flat = lambda a: kernel_input(a, batch + (K,), (P, K))  # noqa: E731
    hi = np.ascontiguousarray(hi, float).reshape(P).copy()
    iterations = np.zeros(P, np.int64)
    halve_protection_levels(flat(offset), flat(np.where(used, sigma, 1.0)), flat(weight), flat(cap),
                            kernel_input(target, batch, (P,)), kernel_input(lo, batch, (P,)), hi, float(tol),
                            iterations)
    return hi.reshape(batch), iterations.reshape(batch)


#: a term whose bound stays below this fraction of target/K above the bracket's low end is not evaluated
DEAD_TERM_FRACTION = 1e-3


def protection_levels(st: SubsetStats, p: NDArray, alpha: NDArray, k_fa: NDArray, target: NDArray,
                      protectable: NDArray, has_residual: bool, p_emt: float,
                      tol: float) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Thresholds (eq. 15), protection levels (eq. 16, :func:`solve_protection_level`'s bracket and halving,
    step for step), EMT (eq. 17) and the test ratio of E epochs of one mode set.

    Parameters
    ----------
    st : the subset statistics (E epochs, M modes).  p, alpha : (M,) priors and caps (alpha[0] = 1).
    k_fa : (E, 3).  target : (E, 3) eq. 16's right side.
    protectable : (E,) bool.  has_residual : separations are defined.  p_emt, tol : settings.

    Returns
    -------
    pl (E, 3) m (∞ where not protectable), iterations (E, 3), threshold (E, M, 3) m, emt (E,) m,
    ratio (E,) (NaN without residuals).
    """
    E, M = st.observable.shape
    weight = np.asarray(p, float).copy()
    weight[0] = 2.0  # the fault-free term's weight
    classes, prior_class = np.unique(weight, return_inverse=True)  # the few distinct weights: Q⁻¹ once each
    n_terms = np.where(protectable, 1 + (st.observable[:, 1:] & (weight[1:] > 0.0)).sum(-1), 1)[:, None, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        z_lo = q_inverse(np.minimum(target[..., None] / classes, 1.0))
        z_hi = np.maximum(q_inverse(np.minimum(target[..., None] / (n_terms * classes), 1.0)), 1e-6)
        eps = DEAD_TERM_FRACTION * target / n_terms[..., 0]
        # Q(z) ≤ ½·exp(−z²/2) for z ≥ 0: w·Q(z) ≤ eps from z = √(2 ln(w/(2 eps))) on (0 when w ≤ 2 eps)
        ln = np.log(classes / (2.0 * eps[..., None]))
        z_dead = np.where(ln > 0.0, np.sqrt(np.maximum(2.0 * ln, 0.0)) * (1.0 + 1e-12), 0.0)
    pl, iterations = np.empty((E, 3)), np.empty((E, 3), np.int64)
    threshold, emt, ratio = np.empty((E, M, 3)), np.empty(E), np.empty(E)
    ro = lambda a, dt=np.float64: kernel_input(a, np.shape(a), dtype=dt)  # noqa: E731
    run_kernel(protection_levels_epochs, E * M, ro(st.sigma), ro(st.bias), ro(st.sigma_ss),
               ro(st.bias_ss), ro(st.separation), ro(st.observable, np.bool_), ro(k_fa), ro(p), ro(alpha),
               ro(prior_class, np.int64), ro(z_lo), ro(z_hi), ro(z_dead), ro(eps), ro(target),
               ro(protectable, np.bool_), bool(has_residual), float(p_emt), float(tol), threshold, pl, iterations, emt,
               ratio)
    return pl, iterations, threshold, emt, ratio


def araim_availability(hpl: NDArray, vpl: NDArray, emt: NDArray, sigma_acc_v: NDArray,
                       levels: tuple[str, ...]) -> NDArray:
    """Per service level (eq. 19): HPL ≤ HAL ∧ VPL ≤ VAL, and for LPV-200 also EMT ≤ 15 m ∧ σ_acc,v ≤ 1.87 m.

    All (...) m, NaN or ∞ where unavailable. Returns (..., K) bool.
    """
    out = []
    for name in levels:
        lv = service_level(name)
        ok = (hpl <= lv.hal) & (vpl <= lv.val)
        if name in EMT_LIMITS:
            ok &= emt <= EMT_LIMITS[name]
        if name in SIGMA_ACC_V_LIMITS:
            ok &= sigma_acc_v <= SIGMA_ACC_V_LIMITS[name]
        out.append(ok)
    return np.stack(out, axis=-1)
