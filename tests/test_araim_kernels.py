"""The compiled ARAIM kernels against what they replace or rely on: the full half-interval search of eq. 16
(the terms set aside must not change a verdict), the direct condition test (the downdates' bound must not
accept what it rejects), the shared scaled LDLᵀ inverse against LAPACK, and the thread count."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from testbed.integrity.araim import AraimRows, AraimSettings, ConstellationIsm, araim, araim_modes
from testbed.integrity.araim.protection import solve_protection_level
from testbed.integrity.araim.subsets import PARALLEL_MIN_WORK, checked_inverse
from testbed.integrity.kernels.small import _scaled_ldl_inverse

GPS, GAL, BDS = 0, 1, 2


def random_sky(rng, counts):
    n = sum(counts)
    az = rng.uniform(0.0, 2 * np.pi, n)
    el = np.arcsin(rng.uniform(math.sin(math.radians(5.0)), 1.0, n))
    los = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)
    return los, np.repeat([GPS, GAL, BDS][:len(counts)], counts)


def one(rows: AraimRows, t: int) -> AraimRows:
    return AraimRows(*(a if a is None or np.ndim(a) == 1 else np.asarray(a)[t] for a in
                       (rows.los_enu, rows.system, rows.used, rows.c_int, rows.c_acc, rows.b_nom, rows.b_cont,
                        rows.residual)))


def batch_of_skies(rng, n_epochs, counts, settings, residual=True):
    skies = [random_sky(rng, counts) for _ in range(n_epochs)]
    los = np.stack([s[0] for s in skies])
    rows = AraimRows.from_elevation(los, skies[0][1], np.ones(los.shape[:2], bool), settings)
    res = rng.standard_normal(los.shape[:2]) * np.sqrt(rows.c_acc) if residual else None
    return AraimRows(rows.los_enu, rows.system, rows.used, rows.c_int, rows.c_acc, rows.b_nom, rows.b_cont, res)


CASES = {
    # three constellations: ~350 modes, pairs of priors 1e-10, most of them set aside near the root
    "3 x 10, default allocation": ((10, 10, 10), AraimSettings(), 1.0),
    "3 x 10, TOL_PL 1e-6": ((10, 10, 10), AraimSettings(tol_pl=1e-6), 1.0),
    "2 x 9, ADD v3.1, a fifth of the budget": ((9, 9), AraimSettings.add_v31(), 0.2),
    # a large budget against small priors: the terms' shares exceed 1 (the high end's special case)
    "2 x 8, P_HMI 1e-2": ((8, 8), AraimSettings.add_v31(p_hmi_vert=1e-2, p_hmi_hor=1e-2), 1.0),
}


@pytest.mark.parametrize("case", list(CASES))
def test_protection_levels_are_the_full_half_interval_search_bit_for_bit(case):
    """Each axis's PL and halvings equal :func:`solve_protection_level` (every term summed at every midpoint)
    on the epoch's own mode table, to the bit: the terms the kernel sets aside never change a verdict."""
    counts, settings, share = CASES[case]
    rng = np.random.default_rng(sum(counts) + int(1e6 * settings.tol_pl))
    rows = batch_of_skies(rng, 12, counts, settings)
    out = araim(rows, settings, budget_share=share)
    assert (out.reason == 0).all() and (out.n_modes > 0).all()
    for t in range(12):
        table = araim_modes(one(rows, t), settings)
        monitored = table.observable.copy()
        monitored[0] = False
        weight = np.where(monitored, table.p, 0.0)
        weight[0] = 2.0
        offset = np.where(monitored[:, None], table.threshold + table.bias, 0.0)
        offset[0] = table.bias[0]
        sigma = np.where(weight[:, None] > 0.0, table.sigma, 1.0)
        scale = 1.0 - out.p_unmonitored[t] / (settings.p_hmi_vert + settings.p_hmi_hor)
        budget = share * np.array([0.5 * settings.p_hmi_hor * scale] * 2 + [settings.p_hmi_vert * scale])
        target = budget / settings.n_es_int
        pl, halvings = solve_protection_level(offset.T, sigma.T, np.broadcast_to(weight, (3, len(weight))),
                                              np.broadcast_to(table.alpha, (3, len(weight))), target, settings.tol_pl)
        np.testing.assert_array_equal(out.pl_enu[t], pl)
        np.testing.assert_array_equal(out.iterations[t], halvings)


def test_a_downdated_mode_is_observable_exactly_when_its_direct_inverse_is_conditioned():
    """One- and two-satellite modes (downdates with a cheap bound before the full 1-norm test) against the
    condition test of their normal matrices solved directly, at a max_cond that rejects some of them."""
    rng = np.random.default_rng(5)
    ism = ConstellationIsm(p_sat=1e-3, p_const=1e-8)
    settings = AraimSettings.add_v31(ism={"GPS": ism, "Galileo": ism}, max_cond=60.0, min_fault_order=2)
    accepted = rejected = 0
    for _ in range(40):
        los, system = random_sky(rng, (4, 4))
        rows = AraimRows.from_elevation(los, system, np.ones(8, bool), settings)
        table = araim_modes(rows, settings)
        if table is None or not table.observable[0]:
            continue
        G = np.concatenate([-los, (system[:, None] == np.array([GPS, GAL])).astype(float)], -1)
        for k, removed in enumerate(table.removed[1:], 1):
            keep = np.ones(8, bool)
            keep[list(removed)] = False
            if len(removed) > 2 or not all(keep[system == s].any() for s in (GPS, GAL)):
                continue  # a direct solve in the kernel too
            A = (G[keep] / rows.c_int[keep, None]).T @ G[keep]
            _, ok = checked_inverse(A, settings.max_cond)
            assert table.observable[k] == ok, (removed, table.observable[k], ok)
            accepted += bool(ok)
            rejected += not ok
    assert accepted > 50 and rejected > 50, (accepted, rejected)


def test_scaled_ldl_inverse_matches_lapack_and_flags_singular_matrices():
    rng = np.random.default_rng(2)
    for n in (3, 4, 6, 7):
        for _ in range(20):
            B = rng.standard_normal((n + 3, n)) * rng.uniform(0.1, 10.0, n)
            M = B.T @ B
            d, piv, y = np.empty(n), np.empty(n), np.empty(n)
            S, L, Si = np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
            kappa = _scaled_ldl_inverse(M, d, S, L, Si, piv, y)
            Ms = M / np.sqrt(np.outer(np.diag(M), np.diag(M)))
            expected = np.abs(Ms).sum(0).max() * np.abs(np.linalg.inv(Ms)).sum(0).max()
            assert kappa == pytest.approx(expected, rel=1e-9)
            np.testing.assert_allclose(Si / np.outer(d, d), np.linalg.inv(M), rtol=1e-9 * kappa,
                                       atol=1e-12 * np.abs(np.linalg.inv(M)).max())
    M = np.ones((3, 3))  # rank one: a zero pivot
    w = [np.empty(3) for _ in range(3)] + [np.empty((3, 3)) for _ in range(3)]
    assert _scaled_ldl_inverse(M, w[0], w[3], w[4], w[5], w[1], w[2]) == np.inf
    M = np.diag([1.0, 0.0, 2.0])  # a zero diagonal
    assert _scaled_ldl_inverse(M, w[0], w[3], w[4], w[5], w[1], w[2]) == np.inf


def test_results_do_not_depend_on_the_number_of_threads_or_the_batch():
    """The kernels run the epochs of a large batch on numba's threads, each epoch alone, and a small batch on one:
    one thread or two, or eight epochs alone, the same bytes (three constellations: downdates, direct solves and
    the PL search)."""
    settings = AraimSettings()
    rows = batch_of_skies(np.random.default_rng(9), 64, (10, 10, 10), settings)
    assert 64 * (araim(one(rows, 0), settings).n_modes + 1) >= PARALLEL_MIN_WORK  # the parallel kernels run
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one_thread = araim(rows, settings)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two_threads = araim(rows, settings)
    finally:
        numba.set_num_threads(before)
    small = araim(AraimRows(*(a if a is None or np.ndim(a) == 1 else np.asarray(a)[:8] for a in
                              (rows.los_enu, rows.system, rows.used, rows.c_int, rows.c_acc, rows.b_nom, rows.b_cont,
                               rows.residual))), settings)
    for name in ("pl_enu", "emt", "sigma_acc_enu", "test_ratio", "iterations", "n_modes", "reason"):
        assert getattr(one_thread, name).tobytes() == getattr(two_threads, name).tobytes(), name
        assert getattr(small, name).tobytes() == getattr(two_threads, name)[:8].tobytes(), name

