"""ARAIM's integrity risk per fault mode by importance sampling: P(HMI | mode k faulty, bias b) at the worst
bias, and its prior-weighted sum against the allocation (docs/design/importance-sampling.md, "ARAIM").

The all-in-view error on axis ``q`` and every solution separation are linear in the standard-normal draws
``z`` and the fault's bias: ``e_q = s0_q·(z + β)``, ``Δ_j = d_j·(z + β)`` (:class:`~.sampling_araim.
SeparationTests`: the monitor's own rows, probed from the ARAIM core). The fault puts ``β = b·v`` on mode k's
rows, ``v`` the least-norm profile on them that moves ``e_q`` by one metre (:func:`fault_direction`): one
satellite's bias, or a constellation's biases in proportion to their weight in the position. Hazardous
misleading information is ``|e_q| > PL_q`` with no test alerting.

The conditional probability is estimated by importance sampling on ``z`` alone, the fault being given: a
mixture of two mean shifts, one per sign of the error, to the dominating point of the event (a least-norm
``z`` that puts ``e_q`` at ``±PL`` with every separation back inside its threshold, :func:`dominating_point`;
the faulty mode's own test sees the bias whole, ``Δ_kq = −S⁽⁰⁾_q b`` on the removed rows, so past its
threshold the event needs both the error's and the separations' tails), drawn by their tails, beside a
defensive share from ``p``. The worst
bias is searched on a grid with the same draws at every bias, on mode k's own test (the tightest; the full
event is a subset of it), then the rate is estimated afresh with every test at the best grid bias and its
two neighbours (fresh draws: the maximum of noisy estimates is not its own estimate).

    P_HMI,q ≤ Σ_k P_k · max_b P(HMI_q | k, b)  against  P_HMI,q · (1 − P_unmonitored / P_HMI) / N_ES,int
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import special, stats

from testbed.campaign.sampling import Rate, weighted_rate
from testbed.campaign.sampling_araim import SeparationTests


@dataclass(frozen=True)
class ModeRisk:
    """One fault mode's worst-case conditional risk on one axis: the bias (m, its effect on the all-in-view
    position's axis ``axis``) whose estimated P(|e_q| > PL_q, no alert | mode faulty, bias) is largest, and that
    rate (every test of the epoch)."""

    mode: int
    removed: tuple[int, ...]
    prior: float
    axis: int
    bias_m: float
    rate: Rate


def fault_direction(tests: SeparationTests, mode: int, axis: int) -> np.ndarray:
    """(N,) the fault profile, in the units of the draws, on mode ``mode``'s rows that moves the all-in-view
    position's axis ``axis`` by one metre at least norm (``s0_q · v = 1``, ``v`` zero off the mode's rows). A
    mode whose rows do not move that axis gets zeros."""
    rows = np.isin(tests.slots, tests.removed[mode])
    s = np.where(rows, tests.s0[axis], 0.0)
    n2 = float(s @ s)
    return s / n2 if n2 > 0 else np.zeros_like(s)


def hmi_draws(tests: SeparationTests, mode: int, axis: int, pl: float, bias: float, v: np.ndarray, z: np.ndarray,
              pick: np.ndarray, defensive: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """``(event (n,), log_weight (n,))`` of the draws ``z`` (n, N) (standard normal under the fault-free model)
    moved by the mixture's component (``pick`` (n,) uniform: below ``defensive`` none, else one of the two
    dominating points by their tails): the event ``|e_q| > PL`` with no test of ``tests`` alerting, the fault's
    bias ``bias·v`` on its rows (module doc)."""
    s = tests.s0[axis]
    beta = bias * v
    shifts = np.stack([dominating_point(tests, mode, axis, sign * pl, beta) for sign in (1.0, -1.0)])
    log_pi = stats.norm.logsf(np.linalg.norm(shifts, axis=1))
    log_pi = log_pi - special.logsumexp(log_pi)
    first = defensive + (1.0 - defensive) * np.exp(log_pi[0])
    comp = np.where(pick < defensive, -1, np.where(pick < first, 0, 1))
    z = z + np.where(comp[:, None] >= 0, shifts[np.maximum(comp, 0)], 0.0)
    ell = z @ shifts.T - 0.5 * np.einsum("ks,ks->k", shifts, shifts)
    mix = special.logsumexp(ell + log_pi, axis=1)
    log_q = np.logaddexp(np.log(defensive), np.log1p(-defensive) + mix) if defensive > 0 else mix
    x = z + beta
    event = (np.abs(x @ s) > pl) & (np.abs(x @ tests.rows.T) <= tests.threshold).all(-1)
    return event, -log_q


def dominating_point(tests: SeparationTests, mode: int, axis: int, limit: float, beta: np.ndarray,
                     rounds: int = 20) -> np.ndarray:
    """(N,) a least-norm draw ``z*`` that puts the faulted error ``e_q = s0_q·(z + β)`` at ``limit`` with every
    separation ``d_j·(z + β)`` of ``tests`` inside its threshold: the nearest point of the event ``{e_q beyond
    the limit, no alert}``, by active sets (start from the faulty mode's own test on the axis, which sees the
    bias whole; add each test the current point alerts, held at its nearest edge ±T_j; ``rounds`` at most)."""
    s = tests.s0[axis]
    active = list(np.flatnonzero((tests.mode == mode) & (tests.axis == axis)))
    edge = {j: np.clip(tests.rows[j] @ beta, -tests.threshold[j], tests.threshold[j]) for j in active}
    for _ in range(rounds):
        M = np.stack([s] + [tests.rows[j] for j in active])
        goal = np.array([limit] + [edge[j] for j in active])
        z = M.T @ np.linalg.lstsq(M @ M.T, goal - M @ beta, rcond=None)[0]
        sep = tests.rows @ (z + beta)
        alerting = [j for j in np.flatnonzero(np.abs(sep) > tests.threshold * (1 + 1e-9)) if j not in edge]
        if not alerting:
            break
        for j in alerting:
            active.append(j)
            edge[j] = float(np.sign(sep[j]) * tests.threshold[j])
    return z


def own_tests(tests: SeparationTests, mode: int) -> SeparationTests:
    """``tests`` restricted to mode ``mode``'s own (one per axis)."""
    j = np.flatnonzero(tests.mode == mode)
    return replace(tests, rows=tests.rows[j], threshold=tests.threshold[j], mode=tests.mode[j],
                   axis=tests.axis[j], prior=tests.prior[j])


def mode_risk(tests: SeparationTests, mode: int, axis: int, pl: float, n_search: int = 400, n: int = 1000,
              grid: int = 41, seed: int = 0, defensive: float = 0.1) -> ModeRisk:
    """Mode ``mode``'s worst-case conditional risk on ``axis`` against the protection level ``pl`` (module
    doc): the bias searched over ``grid`` values from 0 to PL + T + 5σ (``n_search`` trials, own test), then
    estimated with ``n`` fresh trials and every test at the best bias and its neighbours."""
    own = own_tests(tests, mode)
    v = fault_direction(tests, mode, axis)
    prior = float(own.prior[0])
    sigma = float(np.linalg.norm(tests.s0[axis]))
    t_own = float(own.threshold[own.axis == axis][0])
    biases = np.linspace(0.0, pl + t_own + 5.0 * sigma, grid)
    rng = np.random.default_rng([seed, mode, axis])

    def estimate(which: SeparationTests, bias: float, z: np.ndarray, pick: np.ndarray) -> Rate:
        event, lw = hmi_draws(which, mode, axis, pl, float(bias), v, z, pick, defensive)
        return weighted_rate(event.astype(float), 1.0, lw)

    z, pick = rng.standard_normal((n_search, v.size)), rng.random(n_search)
    i = int(np.argmax([estimate(own, b, z, pick).estimate for b in biases]))
    z, pick = rng.standard_normal((n, v.size)), rng.random(n)
    near = [(float(b), estimate(tests, b, z, pick)) for b in biases[max(i - 1, 0): i + 2]]
    bias, rate = max(near, key=lambda br: br[1].estimate)
    return ModeRisk(mode, tests.removed[mode], prior, axis, bias, rate)


def mode_class(tests: SeparationTests, mode: int, system: np.ndarray) -> str:
    """"satellite", "constellation" (every used row of one system) or "satellites" (several, not a whole
    system) for mode ``mode``; ``system`` (N,) the rows' system codes."""
    removed = np.isin(tests.slots, tests.removed[mode])
    if removed.sum() == 1:
        return "satellite"
    if np.unique(system[removed]).size == 1 and removed.sum() == (system == system[removed][0]).sum():
        return "constellation"
    return "satellites"
