"""Verdict rules of the ``reproduce`` commands: a claim judged on measured counts with its confidence.

Every rule takes numbers (counts, rates, statistics) and returns a :class:`Judgement`: whether the
figures support the claim (``True``), refute it (``False``) or cannot tell at this sample size
(``None``), with the words that say so and the bound behind them. The reproductions build their
claims tables from these, never from fixed strings, so a verdict changes when the numbers do.

Rates are binomial: Clopper–Pearson bounds (exact, conservative), two-sided 95 % unless stated.
A rate "meets" a requirement only when its one-sided upper bound is at or below it; it "exceeds"
it when the lower bound is above it; between the two the sample cannot tell, and the rule says
how many event-free trials would (:func:`trials_to_bound`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from scipy import stats

CONFIDENCE = 0.95


@dataclass(frozen=True)
class Judgement:
    """A rule's outcome: ``holds`` True / False / None (not shown at this sample size) and its words."""

    holds: bool | None
    text: str

    @property
    def word(self) -> str:
        return {True: "holds", False: "does not hold", None: "not shown at this sample size"}[self.holds]


def cp_interval(k: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Two-sided Clopper–Pearson interval of k events in n trials ((0, 1) when n = 0)."""
    if n <= 0:
        return 0.0, 1.0
    a = 1.0 - confidence
    lo = 0.0 if k <= 0 else float(stats.beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k >= n else float(stats.beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def cp_upper(k: int, n: int, confidence: float = CONFIDENCE) -> float:
    """One-sided Clopper–Pearson upper bound of the rate of k events in n trials (1 when n = 0)."""
    if n <= 0 or k >= n:
        return 1.0
    return float(stats.beta.ppf(confidence, k + 1, n - k))


def cp_lower(k: int, n: int, confidence: float = CONFIDENCE) -> float:
    """One-sided Clopper–Pearson lower bound of the rate of k events in n trials (0 when k = 0)."""
    if n <= 0 or k <= 0:
        return 0.0
    return float(stats.beta.ppf(1.0 - confidence, k, n - k + 1))


def trials_to_bound(p: float, confidence: float = CONFIDENCE) -> int:
    """Event-free trials needed for the one-sided upper bound to reach ``p``: (1 − p)^n ≤ 1 − confidence."""
    return int(math.ceil(math.log(1.0 - confidence) / math.log1p(-p)))


def rate_text(k: int, n: int) -> str:
    lo, hi = cp_interval(k, n)
    return f"{k} in {n} ({k / n if n else float('nan'):.2e}, 95 % CP [{lo:.2e}, {hi:.2e}])"


def rate_vs_requirement(k: int, n: int, requirement: float, what: str = "rate") -> Judgement:
    """The rate of k events in n trials against a requirement (at most ``requirement`` per trial).

    Meets it when the one-sided 95 % upper bound is at or below it, exceeds it when the lower bound is
    above it; otherwise the sample cannot tell, and the words say the rate it bounds and the
    event-free sample the requirement needs."""
    up, low = cp_upper(k, n), cp_lower(k, n)
    if n and up <= requirement:
        return Judgement(True, f"{what} {k} in {n}: ≤ {up:.1e} at 95 %, within {requirement:g}")
    if low > requirement:
        return Judgement(False, f"{what} {k} in {n}: ≥ {low:.1e} at 95 %, above {requirement:g}")
    return Judgement(None, f"{what} {k} in {n} bounds the rate to ≤ {up:.1e} at 95 % only; {requirement:g} "
                           f"needs {trials_to_bound(requirement):.1e} event-free epochs")


def compare_rates(k1: int, n1: int, k2: int, n2: int) -> int:
    """+1 if rate 1's 95 % CP band lies wholly above rate 2's, −1 wholly below, 0 if they overlap."""
    lo1, hi1 = cp_interval(k1, n1)
    lo2, hi2 = cp_interval(k2, n2)
    return 1 if lo1 > hi2 else -1 if hi1 < lo2 else 0


def sigma_interval(rms: float, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Two-sided confidence interval of a zero-mean Gaussian's σ from the RMS of n draws (chi-square)."""
    if n <= 0 or not math.isfinite(rms):
        return float("nan"), float("nan")
    a = 1.0 - confidence
    ss = n * rms * rms
    return math.sqrt(ss / stats.chi2.ppf(1 - a / 2, n)), math.sqrt(ss / stats.chi2.ppf(a / 2, n))


def paired_shrink(before, after) -> tuple[float, int]:
    """One-sided Wilcoxon signed-rank test that |after| < |before| over paired units (surveys): (p-value,
    pairs). NaN p with fewer than 6 pairs (the test cannot reach 5 % below that)."""
    import numpy as np

    b, a = np.abs(np.asarray(before, float)), np.abs(np.asarray(after, float))
    ok = np.isfinite(b) & np.isfinite(a)
    d = (b - a)[ok]
    if d.size < 6 or not np.any(d):
        return float("nan"), int(d.size)
    return float(stats.wilcoxon(d, alternative="greater").pvalue), int(d.size)
