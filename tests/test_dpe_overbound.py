"""The DeCleene overbound against closed forms and brute force (docs/design/dpe.md §5, §10 O1-O9)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats
from scipy.special import ndtr

from testbed.integrity.dpe.overbound import gaussian_overbound, overbounds

U = np.arange(-30.0, 30.0 + 1e-9, 0.1)
WIDE = np.arange(-60.0, 60.0 + 1e-9, 0.05)


def test_a_gaussian_gives_its_sigma():
    ob = gaussian_overbound(U, stats.norm.pdf(U, 0, 2))
    assert abs(ob.sigma / 2 - 1) <= 1e-3  # O1 (piecewise-linear CDF of 0.1 m cells: 2.0004)
    coarse = np.arange(-30.0, 30.0 + 1e-9, 0.5)
    assert abs(gaussian_overbound(coarse, stats.norm.pdf(coarse, 0, 2)).sigma - 2.011) < 1e-3
    assert abs(ob.median) < 1e-12 and ob.about_solution


def test_a_uniform_gives_its_known_value():
    u = np.linspace(-10, 10, 2001)
    a = 10.0 + 0.005  # the outer cells reach half a step beyond the last values
    assert abs(gaussian_overbound(u, np.ones_like(u)).sigma / (2 * a / np.sqrt(2 * np.pi)) - 1) < 1e-5  # O2


def test_an_offset_gaussian_is_overbound_about_its_median_only():
    ob = gaussian_overbound(U, stats.norm.pdf(U, 0.7, 2))  # O3
    assert abs(ob.sigma / 2 - 1) <= 1e-3 and abs(ob.median - 0.7) < 1e-9
    assert not ob.about_solution  # Φ(0/σ) = ½ ≠ F(0) for every σ (docs/design/dpe.md F3)


def test_heavy_tails_need_the_notes_sigmas():
    mix = 0.95 * stats.norm.pdf(WIDE) + 0.05 * stats.norm.pdf(WIDE, 0, 4)
    assert abs(gaussian_overbound(WIDE, mix).sigma - 3.95) < 0.01  # O4
    assert abs(gaussian_overbound(WIDE, stats.t.pdf(WIDE, 3)).sigma - 11.9) < 0.05
    lap = gaussian_overbound(WIDE, stats.laplace.pdf(WIDE, scale=1.5)).sigma
    assert abs(lap - 6.80) < 0.01
    narrow = np.arange(-30.0, 30.0 + 1e-9, 0.05)
    assert gaussian_overbound(narrow, stats.laplace.pdf(narrow, scale=1.5)).sigma < lap  # grows with the extent


def _random_curves(rng, n):
    """Mixtures of 1-3 Gaussians and Laplacians on a common grid, any skew."""
    u = np.linspace(-40, 40, 801)
    out = []
    for _ in range(n):
        k = rng.integers(1, 4)
        w = rng.dirichlet(np.ones(k))
        c = np.zeros_like(u)
        for j in range(k):
            m, s = rng.normal(0, 3), rng.uniform(0.5, 6)
            c += w[j] * (stats.norm.pdf(u, m, s) if rng.random() < 0.6 else stats.laplace.pdf(u, m, s / 1.4))
        out.append(c)
    return u, np.array(out)


def _pl_tails(u, ell):
    """Independent piecewise-linear left and right tails of cells between midpoints (outer cells mirrored)."""
    mid = 0.5 * (u[1:] + u[:-1])
    edges = np.r_[u[0] - (mid[0] - u[0]), mid, u[-1] + (u[-1] - mid[-1])]
    mass = ell * np.diff(edges)
    mass = mass / mass.sum()
    return edges, np.r_[0.0, np.cumsum(mass)], np.r_[np.cumsum(mass[::-1])[::-1], 0.0]


def _brute_holds(sigma, u, ell, rel=1e-9):
    """Φ((x − m)/σ) ≥ L(x) left of the median and Q((x − m)/σ) ≥ R(x) right of it, at 200 001 points
    (relative to the tail, so the far tails count as much as the core)."""
    edges, L, R = _pl_tails(u, ell)
    med = np.interp(0.5, L, edges)
    x = np.linspace(edges[0], edges[-1], 200_001)
    left, right = x < med, x >= med
    tl, tr = np.interp(x[left], edges, L), np.interp(x[right], edges, R)
    ok_l = (ndtr((x[left] - med) / sigma) >= (1 - rel) * tl) | (tl < 1e-300)  # subnormal tails are rounding
    ok_r = (ndtr(-(x[right] - med) / sigma) >= (1 - rel) * tr) | (tr < 1e-300)
    return bool(ok_l.all() and ok_r.all())


def test_random_curves_hold_at_sigma_and_fail_just_below():
    """O5/O6: a dense 200 001-point check of 200 random curves: bounds at σ_ob, not at 0.999σ_ob."""
    u, curves = _random_curves(np.random.default_rng(11), 200)
    ob = gaussian_overbound(np.broadcast_to(u, curves.shape), curves)
    misses = [i for i in range(curves.shape[0]) if not _brute_holds(ob.sigma[i], u, curves[i])]
    assert not misses
    tight = [i for i in range(curves.shape[0]) if _brute_holds(0.999 * ob.sigma[i], u, curves[i])]
    assert not tight
    for i in range(0, 200, 40):
        assert not overbounds(0.995 * ob.sigma[i], u, curves[i])  # O6, the monitor's own check


def test_scaling_mirroring_and_value_scale_invariance():
    u, curves = _random_curves(np.random.default_rng(5), 6)
    base = gaussian_overbound(np.broadcast_to(u, curves.shape), curves)
    scaled = gaussian_overbound(np.broadcast_to(3 * u, curves.shape), curves)
    np.testing.assert_allclose(scaled.sigma, 3 * base.sigma, rtol=2e-7)  # O7
    mirrored = gaussian_overbound(np.broadcast_to(u, curves.shape), curves[:, ::-1])
    np.testing.assert_allclose(mirrored.sigma, base.sigma, rtol=2e-7)
    np.testing.assert_allclose(mirrored.median, -base.median, atol=1e-9)
    np.testing.assert_allclose(gaussian_overbound(np.broadcast_to(u, curves.shape), 7.5 * curves).sigma, base.sigma,
                               rtol=1e-12)


def test_batch_equals_one_by_one_and_an_empty_curve_is_nan():
    u, curves = _random_curves(np.random.default_rng(2), 4)
    batch = gaussian_overbound(np.broadcast_to(u, curves.shape), curves).sigma
    single = [float(gaussian_overbound(u, c).sigma) for c in curves]
    np.testing.assert_allclose(batch, single, rtol=2e-7)
    assert np.isnan(gaussian_overbound(u, np.zeros_like(u)).sigma)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(s1=st.floats(0.2, 20.0), s2=st.floats(0.2, 20.0), seed=st.integers(0, 50))
def test_feasibility_is_monotone_in_sigma(s1, s2, seed):
    """O9: a σ that overbounds keeps overbounding when it grows."""
    u, curves = _random_curves(np.random.default_rng(seed), 1)
    lo, hi = sorted((s1, s2))
    assert not (overbounds(lo, u, curves[0]) and not overbounds(hi, u, curves[0]))
