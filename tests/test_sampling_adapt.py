"""The adaptive cross-entropy step of an importance-sampling proposal ([sampling] adapt = "cross_entropy"): on the
Gaussian tail's closed form it moves each component to the event's conditional mean and lowers the variance at
equal trials; on the campaign path its pilot is drawn apart and the campaign stays deterministic."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy import stats

from test_sampling import gaussian_model, loose_spec, weighted_draws

from testbed.campaign.runner import run_campaign
from testbed.campaign.sampling import MAX_VOV, component_events, components, cross_entropy_shifts, weighted_rate
from testbed.campaign.spec import SamplingPlan, load_spec
from testbed.campaign.store import tables_equal

PLAN = SamplingPlan(method="importance")


def tail_with_an_unmoved_part(model, L: float, sigma_d: float, comps, n: int, seed: int):
    """Trials of ``e_v = A_v·z + d``: ``z`` drawn from ``comps``' proposal, ``d ~ N(0, σ_d²)`` from the error model
    whatever the proposal (an error the proposal does not move, like the dithering's tones); returns the
    errors (n, 1, 3) (vertical only) and the log-weights."""
    z, lw = weighted_draws(model, PLAN, n, seed, comps)
    d = np.random.default_rng(seed + 1000).normal(0.0, sigma_d, size=(n, 1))
    err = np.zeros((n, 1, 3))
    err[..., 2] = np.einsum("ts,nts->nt", model.A[:, 2], z) + d
    return z, err, lw


@pytest.mark.parametrize("p", [1e-5, 1e-7])
def test_cross_entropy_corrects_a_proposal_that_misses_part_of_the_error(p):
    """``P(|s·z + d| > L) = 2 Q(L / sqrt(|s|² + σ_d²))`` with ``d`` an error the proposal leaves as drawn (σ_d =
    0.35 |s|, as the dithering's tones are left): the dominating point of the linear model in ``z`` (which does
    not see ``d``) overshoots; the refit from a 2000-trial pilot moves the shifts back towards the event's
    conditional mean (shorter shifts). At equal trials (20000 each) each estimate but one settles and holds the
    closed form in its 99 % interval; at 1e-5 the refit's variance is the lower (0.93 of the dominating
    point's); at 1e-7 the refit's does not settle, and the diagnostic says why (variance of the variance 0.21
    > 0.1): the step is no guaranteed gain (docs/design/importance-sampling.md)."""
    model = gaussian_model(1, 8, np.array([1.0]))
    s_norm = float(np.linalg.norm(model.A[0, 2]))
    sigma_d = 0.35 * s_norm
    L = stats.norm.isf(p / 2) * np.hypot(s_norm, sigma_d)
    model = type(model)(model.e0, model.A, model.design, model.used, model.hpl, np.array([L]), model.dimensions)
    base = components(model, PLAN, np.inf, np.inf)
    z, err, lw = tail_with_an_unmoved_part(model, L, sigma_d, base, 2000, seed=99)
    elite = component_events(base, err, np.zeros((2000, 1), bool), np.ones((2000, 1), bool))
    ce = cross_entropy_shifts(base, z, lw, elite)
    assert np.all(np.linalg.norm(ce.shift, axis=1) < 0.99 * np.linalg.norm(base.shift, axis=1))
    rates = {}
    for name, comps in (("dominating point", base), ("cross-entropy", ce)):
        _, err, lw = tail_with_an_unmoved_part(model, L, sigma_d, comps, 20000, seed=5)
        r = weighted_rate((np.abs(err[..., 2]) > L).sum(-1), 1, lw, 0.99)
        if (p, name) == (1e-7, "cross-entropy"):  # the documented diagnostic withholds it: VOV past 0.1
            assert not r.settled and r.vov > MAX_VOV, (name, r)
        else:
            assert r.settled and r.lo <= p <= r.hi, (name, r, p)
        rates[name] = r
    if p == 1e-5:  # both settled: the refit's variance the lower (0.93 of the dominating point's)
        assert rates["dominating point"].settled and rates["cross-entropy"].settled
        assert (rates["cross-entropy"].se / rates["dominating point"].se) ** 2 < 1.0


def test_on_a_gaussian_tail_the_refit_lands_on_the_conditional_mean():
    """With nothing left unmoved, ``|N(0, σ²)| > L``: the refit moves each shift along the dominating direction to
    the tail's conditional mean, ``φ(a)/Q(a)`` standard deviations (a = L/σ) instead of ``a`` (the variance at
    equal trials is then the dominating point's to 0.1 %: in the shift family the dominating point is already
    near the optimum of a half-space)."""
    a = stats.norm.isf(1e-7 / 2)
    model = gaussian_model(1, 8, np.array([a]))
    base = components(model, PLAN, np.inf, np.inf)
    z, lw = weighted_draws(model, PLAN, 2000, 99, base)
    err = model.e0 + np.einsum("tcs,nts->ntc", model.A, z)
    elite = component_events(base, err, np.zeros((2000, 1), bool), np.ones((2000, 1), bool))
    ce = cross_entropy_shifts(base, z, lw, elite)
    s = model.A[0, 2] / np.linalg.norm(model.A[0, 2])
    assert np.allclose(np.abs(ce.shift @ s), stats.norm.pdf(a) / stats.norm.sf(a), rtol=0.02)


def test_a_component_without_elite_keeps_its_dominating_point():
    """A component whose event no pilot trial reached (or too few: under five effective) is not refitted."""
    model = gaussian_model(1, 8, np.array([stats.norm.isf(1e-7 / 2)]))
    base = components(model, PLAN, np.inf, np.inf)
    z, lw = weighted_draws(model, PLAN, 200, 1, base)
    none = np.zeros((200, base.size), bool)
    assert np.array_equal(cross_entropy_shifts(base, z, lw, none).shift, base.shift)


def test_adapt_is_refused_where_it_cannot_run(tmp_path: Path):
    """``adapt`` with the scale proposal, or ``pilot_trials`` without ``adapt``: refused when the spec is read."""
    with pytest.raises(ValueError, match="adapt"):
        SamplingPlan(method="importance", proposal="scale", adapt="cross_entropy")
    with pytest.raises(ValueError, match="pilot_trials"):
        SamplingPlan(method="importance", pilot_trials=100)
    assert load_spec("raim-hmi-fault-free").spec.sampling.adapt == "none"


def test_adapted_campaign_is_deterministic_across_chunking(tmp_path: Path):
    """GPS RAIM on the runway-05 final with its PLs loosened (misleading epochs ~1e-3): with the cross-entropy step
    (its pilot drawn from its own block) the same weights and tables bit for bit with chunks of 200 and of 100
    trials, and other weights than without the step (the pilot refitted the shifts)."""
    samp = '[sampling]\nmethod = "importance"'
    adapt = samp + '\nadapt = "cross_entropy"\npilot_trials = 200'
    runs = [(("a", 200, adapt)), ("b", 100, adapt), ("c", 200, samp)]
    outs = [pq.read_table(run_campaign(loose_spec(tmp_path, name, 200, chunk, text, duration=10.0), tmp_path / name,
                                       progress=False).out_dir / "trials.parquet") for name, chunk, text in runs]
    assert tables_equal(outs[0], outs[1])
    lw_a, lw_c = (t.column("log_weight").to_numpy() for t in (outs[0], outs[2]))
    assert np.isfinite(lw_a).all() and not np.array_equal(lw_a, lw_c)
