"""ARAIM's integrity risk per fault mode by importance sampling: P(HMI | mode k faulty, bias b) at the worst
bias found, and its prior-weighted sum against the allocation (docs/design/importance-sampling.md, "ARAIM").

The all-in-view error on axis ``q`` and every solution separation are linear in the standard-normal draws
``z`` and the fault's bias: ``e_q = s0_q·(z + β)``, ``Δ_j = d_j·(z + β)`` (:class:`~.sampling_araim.
SeparationTests`: the monitor's own rows, probed from the ARAIM core). The fault puts ``β = b·v`` on mode k's
rows, ``v`` a profile on them scaled to move ``e_q`` by one metre, so ``b`` is the fault's effect on the axis.
Hazardous misleading information is ``|e_q| > PL_q`` with no test alerting.

The conditional probability is estimated by importance sampling on ``z`` alone, the fault being given: a
mixture of two mean shifts, one per sign of the error, to the dominating point of the event (a least-norm
``z`` that puts ``e_q`` at ``±PL`` with every separation back inside its threshold, :func:`dominating_point`;
the faulty mode's own test sees the bias whole, ``Δ_kq = −S⁽⁰⁾_q b`` on the removed rows, so past its
threshold the event needs both the error's and the separations' tails), drawn by their tails, beside a
defensive share from ``p``.

The worst fault is searched, with the same draws throughout, on mode k's own test (the tightest; the full event
is a subset of it): over a grid of biases along each profile of :func:`fault_profiles`. A one-satellite mode
has one profile (its row); a mode of several rows (a constellation, several satellites) has a space of them:
the search tries the least-norm profile for each axis (:func:`fault_direction`) and ``random_profiles`` random
ones, not every profile. The best grid bias and its two neighbours are then compared with every test on the
search draws, and the rate is estimated once, with fresh draws, at the bias chosen: an unbiased estimate of
P(HMI_q | k, b) at that (profile, bias), not the maximum of several noisy estimates (the search itself may
stop short of the worst bias or profile, which leaves the figure low).

    P_HMI,q ≤ Σ_k P_k · max_{v,b} P(HMI_q | k, v, b)  against  P_HMI,q · (1 − P_unmonitored / P_HMI) / N_ES,int

For a one-satellite mode the searched figure estimates the maximum over the bias (to the grid's step). For a
mode of several rows it is the maximum over the profiles tried only: the worst profile of the mode's rows is
not searched in full, so the sum is an estimate of the bound's right side on the profiles tried, not a bound.
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
    profile: str = "least-norm"  # the fault profile on the mode's rows the worst bias was found on
    profiles: int = 1  # profiles tried (1: the mode has one row, or only the least-norm profile was tried)


def fault_direction(tests: SeparationTests, mode: int, axis: int) -> np.ndarray:
    """(N,) the fault profile, in the units of the draws, on mode ``mode``'s rows that moves the all-in-view
    position's axis ``axis`` by one metre at least norm (``s0_q · v = 1``, ``v`` zero off the mode's rows). A
    mode whose rows do not move that axis gets zeros."""
    rows = np.isin(tests.slots, tests.removed[mode])
    s = np.where(rows, tests.s0[axis], 0.0)
    n2 = float(s @ s)
    return s / n2 if n2 > 0 else np.zeros_like(s)


def fault_profiles(tests: SeparationTests, mode: int, axis: int, random_profiles: int, rng: np.random.Generator
                   ) -> list[tuple[str, np.ndarray]]:
    """``[(label, v (N,))]`` the fault profiles searched for mode ``mode`` on ``axis``, each on the mode's rows
    and scaled to ``s0_q · v = 1``: the least-norm one first (:func:`fault_direction`); for a mode of several
    rows also the least-norm profiles of the other axes and ``random_profiles`` uniform random directions on
    the rows (each sign-flipped to move the axis positively; one that barely moves it, |s0_q·u| below 1 % of
    its largest, is dropped: its bias would be out of the grid's reach)."""
    first = fault_direction(tests, mode, axis)
    rows = np.flatnonzero(np.isin(tests.slots, tests.removed[mode]))
    if rows.size < 2 or not first.any():
        return [("least-norm", first)]
    s = tests.s0[axis]
    out = [("least-norm", first)]
    candidates = [(f"least-norm {'ENU'[a]}", fault_direction(tests, mode, a)) for a in range(3) if a != axis]
    for i in range(random_profiles):
        u = np.zeros_like(s)
        u[rows] = rng.standard_normal(rows.size)
        candidates.append((f"random {i + 1}", u / np.linalg.norm(u)))
    reach = np.linalg.norm(s[rows])
    for label, u in candidates:
        g = float(s @ u)
        if abs(g) > 0.01 * reach * np.linalg.norm(u):
            out.append((label, u / g))
    return out


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
              grid: int = 41, seed: int = 0, defensive: float = 0.1, random_profiles: int = 0) -> ModeRisk:
    """Mode ``mode``'s worst-case conditional risk on ``axis`` against the protection level ``pl`` (module
    doc): the fault searched over ``grid`` biases from 0 to PL + T + 5σ along each profile of
    :func:`fault_profiles` (``n_search`` trials, own test), the best bias and its neighbours compared with
    every test on the same draws, then the rate estimated once at the bias chosen with ``n`` fresh trials."""
    own = own_tests(tests, mode)
    prior = float(own.prior[0])
    sigma = float(np.linalg.norm(tests.s0[axis]))
    t_own = float(own.threshold[own.axis == axis][0])
    biases = np.linspace(0.0, pl + t_own + 5.0 * sigma, grid)
    rng = np.random.default_rng([seed, mode, axis])
    profiles = fault_profiles(tests, mode, axis, random_profiles, np.random.default_rng([seed, mode, axis, 1]))

    def estimate(which: SeparationTests, bias: float, v: np.ndarray, z: np.ndarray, pick: np.ndarray) -> Rate:
        event, lw = hmi_draws(which, mode, axis, pl, float(bias), v, z, pick, defensive)
        return weighted_rate(event.astype(float), 1.0, lw)

    z, pick = rng.standard_normal((n_search, tests.s0.shape[1])), rng.random(n_search)
    found = [(estimate(own, b, v, z, pick).estimate, p, i) for p, (_, v) in enumerate(profiles)
             for i, b in enumerate(biases)]
    _, p, i = max(found, key=lambda f: f[0])
    label, v = profiles[p]
    near = biases[max(i - 1, 0): i + 2]
    bias = float(near[max(range(near.size), key=lambda j: estimate(tests, near[j], v, z, pick).estimate)])
    z, pick = rng.standard_normal((n, v.size)), rng.random(n)  # fresh: the chosen bias's own estimate
    rate = estimate(tests, bias, v, z, pick)
    return ModeRisk(mode, tests.removed[mode], prior, axis, bias, rate, label, len(profiles))


def mode_class(tests: SeparationTests, mode: int, system: np.ndarray) -> str:
    """"satellite", "constellation" (every used row of one system) or "satellites" (several, not a whole
    system) for mode ``mode``; ``system`` (N,) the rows' system codes."""
    removed = np.isin(tests.slots, tests.removed[mode])
    if removed.sum() == 1:
        return "satellite"
    if np.unique(system[removed]).size == 1 and removed.sum() == (system == system[removed][0]).sum():
        return "constellation"
    return "satellites"
