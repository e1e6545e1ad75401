"""The break-even search against brute force (a dense sweep of a known ratio curve)."""

from __future__ import annotations

import numpy as np

from testbed.studies.vision_pays import break_even


def brute_break_even(f: np.ndarray, r: np.ndarray) -> float:
    """The smallest f of a dense sweep from which r stays below 1."""
    bad = np.flatnonzero(~(r < 1.0))
    return float(f[0]) if bad.size == 0 else float(f[bad[-1] + 1])


def test_break_even_matches_a_dense_brute_force_sweep():
    def ratio(f):  # worse than GPS for short lenses, better for long ones; crosses 1 at f = 6.96e4
        return 0.6 + 3.0 / (1.0 + (f / 2e4) ** 1.5)

    dense = np.geomspace(1e3, 1e5, 200_001)
    truth = brute_break_even(dense, ratio(dense))
    assert abs(truth / (2e4 * 6.5 ** (1 / 1.5)) - 1) < 1e-4  # the closed-form crossing
    for n in (6, 11, 101):
        coarse = np.geomspace(1e3, 1e5, n)
        got, text = break_even(coarse, ratio(coarse))
        i = np.searchsorted(coarse, truth)
        assert coarse[i - 1] < got <= coarse[i] and text == f"{got:.0f} px"  # inside the swept bracket
        assert abs(np.log(got / truth)) < 0.5 * np.log(coarse[1] / coarse[0])  # and within half a step
    got, _ = break_even(np.geomspace(1e3, 1e5, 1001), ratio(np.geomspace(1e3, 1e5, 1001)))
    assert abs(got / truth - 1) < 1e-3


def test_break_even_is_where_the_ratio_stays_below_one():
    f = np.array([1e3, 3e3, 1e4, 3e4, 1e5])
    r = np.array([1.2, 0.9, 1.05, 0.8, 0.7])  # a dip at 3e3 that does not last
    got, _ = break_even(f[::-1], r[::-1])  # any order
    assert 1e4 < got < 3e4 and got == break_even(f, r)[0]
    dense_f = np.geomspace(1e3, 1e5, 4001)
    dense_r = np.interp(np.log(dense_f), np.log(f), r)
    assert abs(got / brute_break_even(dense_f, dense_r) - 1) < 2e-3
    assert np.isnan(break_even(f, np.array([1.2, 0.9, 0.8, 0.7, 1.01]))[0])
    assert break_even(f, np.array([1.2, 0.9, 0.8, 0.7, 1.01]))[1] == "VA-RAIM never beats GPS RAIM below f = 100000 px"
    assert break_even(f, np.full(5, 0.5)) == (1e3, "≤ 1000 px (beats GPS RAIM at every swept focal length)")
    got, _ = break_even(f, np.array([1.2, np.nan, 0.9, 0.8, 0.7]))  # an unmeasurable ratio is not a win
    assert got == 1e4
