"""Fault detection and exclusion (FDE): one mechanism for every snapshot monitor.

A monitor that alerts at an epoch may try to exclude the faulty measurement
instead of losing the epoch (the vision-integrity patent's "故障检测和排除"; RAIM-FDE of every
receiver). The monitor describes its measurements as *units* — a satellite's
pseudorange row, a landmark's (u, v) pixel pair, VA-RAIM's vision block — and
gives a function that re-solves chosen epochs with some rows left out and
returns the reduced :class:`Verdict` (its position, test, threshold and
protection levels, computed by the monitor's own rules on the reduced
geometry). This module does the rest:

1. on alerted epochs only, re-solve once per unit present (one extra solve per
   candidate; fault-free epochs that pass cost nothing);
2. a candidate *passes* when its reduced solve has a solution with protection
   levels and its reduced test passes (SSE ≤ T² at the reduced dof);
3. the rule picks the exclusion:

   * ``"best"`` (default): of the passing candidates, the one whose reduced
     statistic is most consistent (largest χ² p-value at its own dof, so a
     landmark pair (2 rows) and a satellite (1 row) compare fairly);
   * ``"unique"``: only if exactly one candidate passes; several passing is
     *ambiguous* and the alert stands;

4. with ``fde_max_excluded = 2`` and no single exclusion passing, pairs of units
   are tried the same way;
5. the epoch's output becomes the reduced solve's: position, test, threshold,
   HPL/VPL *of the reduced geometry* (the reduced set is itself a monitored
   set: a fault left in it — a wrong exclusion — is protected by its PLs at
   P_MD, which is what "protect after exclusion" means), availability judged on
   those PLs, ``alert`` cleared and ``excluded`` set. An alert that no exclusion
   clears stays an alert and the epoch is unavailable.

What the reduced PLs do not carry is the selection: the set kept is the one
whose test passed, so after a *wrong* exclusion the fault left in it is more
hidden than an arbitrary one. For the single-fault hypothesis the PLs are built
on this is rare (a 60 m step: 99.8 % right exclusions, no PL exceeded in 4800
epochs; tests/test_fde.py); for two faults at 7 satellites (one dof left after
excluding a pair) 19 % of the pair exclusions are wrong and 6.7 % exceed the PL.

False-exclusion budget: an exclusion needs an alert first, so fault-free
P(exclusion) ≤ P_FA per epoch (tested against the binomial bound).

Measurement indices in ``excluded`` (:func:`measurement_label` names them): a satellite
slot ``0 ≤ k < S``; ``S + l`` for landmark l (pixel monitor); ``S + L`` for VA-RAIM's
vision block (L landmarks).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from itertools import combinations
from typing import Callable

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from testbed.integrity.levels import availability, service_level
from testbed.integrity.settings import IntegritySettings
from testbed.records import Diagnostics, MonitorOutput, epoch_array, satellite_ids

#: FDE outcome texts, indexed by :attr:`FdeRecord.outcome`
FDE_OUTCOMES: tuple[str, ...] = (
    "no alert",
    "excluded",
    "alert: no exclusion passes its test",
    "alert: several exclusions pass (rule 'unique')",
    "alert: too few measurements left to exclude any",
)
NO_ALERT, EXCLUDED, NONE_PASSES, AMBIGUOUS, TOO_FEW = range(len(FDE_OUTCOMES))


@dataclass(frozen=True)
class Verdict:
    """A reduced solve, as FDE judges it, at n epochs.

    x : (n, 4) state.  test_stat, threshold : (n,) SSE and T² at the reduced dof (n,).
    hpl, vpl : (n,) the monitor's PLs on the reduced geometry.  ok : (n,) a solution with PLs.
    n_used : (n,) measurement rows used.
    """

    x: NDArray
    test_stat: NDArray
    threshold: NDArray
    dof: NDArray
    hpl: NDArray
    vpl: NDArray
    ok: NDArray
    n_used: NDArray

    @property
    def passed(self) -> NDArray:
        with np.errstate(invalid="ignore"):
            return self.ok & (self.test_stat <= self.threshold)

    @property
    def p_value(self) -> NDArray:
        """χ² survival of the reduced statistic at its dof (-1 where it does not pass)."""
        p = stats.chi2.sf(np.where(self.passed, self.test_stat, 0.0), np.maximum(self.dof, 1))
        return np.where(self.passed, p, -1.0)

    def take(self, i: NDArray) -> Verdict:
        return Verdict(**{k: getattr(self, k)[i] for k in self.__dataclass_fields__})


@dataclass(frozen=True)
class FdeRecord(Diagnostics):
    """What FDE did at each epoch (B..., T): attached to a monitor's output as ``fde``.

    detected : the full-set test failed (the fault was detected, whether or not excluded).
    outcome : int8 index into ``outcomes``.  excluded : (B..., T, 2) measurement indices
    (-1: none), two when a pair was excluded.  test_stat_all, threshold_all, hpl_all,
    vpl_all : the full-set values the exclusion replaced.
    """

    detected: NDArray = epoch_array()
    outcome: NDArray = epoch_array()
    excluded: NDArray = epoch_array(1)
    test_stat_all: NDArray = epoch_array()
    threshold_all: NDArray = epoch_array()
    hpl_all: NDArray = epoch_array()
    vpl_all: NDArray = epoch_array()
    outcomes: tuple[str, ...] = FDE_OUTCOMES


def flat_take(a: NDArray, batch_ndim: int, sel: NDArray) -> NDArray:
    """Epochs ``sel`` (flat over the first ``batch_ndim`` axes, trial and epoch) of ``a``: (n, *tail)."""
    a = np.asarray(a)
    return a.reshape((-1,) + a.shape[batch_ndim:])[sel]


def measurement_label(index: int, prn, landmark_id=None, system=None) -> str:
    """What an ``excluded`` index names: "PRN 12" (GPS alone) or "satellite E11" (``system`` (S,) letters with
    another system), "landmark RWY3", "the vision block" (or "" for -1)."""
    S = len(prn)
    L = 0 if landmark_id is None else len(landmark_id)
    if index < 0:
        return ""
    if index < S:
        if system is None or all(c == "G" for c in system):
            return f"PRN {int(prn[index])}"
        return f"satellite {satellite_ids(system[index:index + 1], prn[index:index + 1])[0]}"
    if index < S + L:
        return f"landmark {landmark_id[index - S]}"
    return "the vision block"


#: re-solve epochs ``sel`` (n,) (flat over the output's batch and epoch axes) keeping rows ``keep`` (n, R)
SolveWithout = Callable[[NDArray, NDArray], Verdict]


@dataclass(frozen=True)
class _Choice:
    """The exclusion chosen at each alerted epoch (n,): its verdict and units, and the outcome."""

    verdict: Verdict | None
    units: NDArray  # (n, 2) unit indices, -1 none
    outcome: NDArray  # (n,) int8


def _try(sel: NDArray, units: list[tuple[int, ...]], unit_rows: NDArray, label: NDArray,
         solve_without: SolveWithout, rule: str) -> _Choice:
    """Every candidate (a tuple of units present at the epoch) at epochs ``sel``, one batched solve."""
    n = sel.size
    present = np.stack([(label[sel][:, list(u)] >= 0).all(-1) for u in units], -1)  # (n, C)
    e, c = np.nonzero(present)
    outcome = np.full(n, TOO_FEW, np.int8)
    chosen_units = np.full((n, 2), -1, np.int64)
    if e.size == 0:
        return _Choice(None, chosen_units, outcome)
    drop = np.stack([unit_rows[list(u)].any(0) for u in units])  # (C, R)
    v = solve_without(sel[e], ~drop[c])
    p = v.p_value
    passes = np.zeros(n, np.int64)
    np.add.at(passes, e, v.passed)
    any_ok = np.zeros(n, bool)
    np.logical_or.at(any_ok, e, v.ok)
    best_p = np.full(n, -1.0)
    np.maximum.at(best_p, e, p)
    # the first candidate (in unit order) reaching an epoch's best p-value wins ties
    is_best = v.passed & (p == best_p[e])
    first = np.full(n, -1, np.int64)
    k = np.flatnonzero(is_best)[::-1]
    first[e[k]] = k  # written in reverse: the lowest k stays
    outcome = np.where(any_ok, NONE_PASSES, TOO_FEW).astype(np.int8)
    take = passes > 0
    if rule == "unique":
        outcome = np.where(passes > 1, AMBIGUOUS, outcome).astype(np.int8)
        take = passes == 1
    outcome = np.where(take, EXCLUDED, outcome).astype(np.int8)
    cand = np.array([list(u) + [-1] * (2 - len(u)) for u in units], np.int64)
    chosen_units[take] = cand[c[first[take]]]
    return _Choice(v.take(np.where(take, first, 0)), chosen_units, outcome)


def exclude(out: MonitorOutput, unit_rows: NDArray, unit_label: NDArray, solve_without: SolveWithout,
            st: IntegritySettings) -> MonitorOutput:
    """``out`` after fault exclusion on its alerted epochs (the module doc's rule), with an :class:`FdeRecord`.

    unit_rows : (U, R) bool, the rows of the monitor's stacked problem each unit holds.
    unit_label : (B..., T, U) int, the measurement index a unit stands for at each epoch
        (-1: the unit is absent there).
    solve_without : the monitor's reduced solve (:data:`SolveWithout`).
    """
    bt = out.alert.shape
    alert = np.asarray(out.alert, bool).reshape(-1)
    sel = np.flatnonzero(alert)
    record = FdeRecord(detected=out.alert, outcome=np.zeros(bt, np.int8), excluded=np.full(bt + (2,), -1, np.int16),
                       test_stat_all=out.test_stat, threshold_all=out.threshold, hpl_all=out.hpl, vpl_all=out.vpl)
    if not sel.size:  # nothing to try: the output as it is (the common, fault-free case)
        return replace(out, fde=record)
    label = np.asarray(unit_label).reshape(alert.size, -1)
    U = label.shape[-1]
    ch = _try(sel, [(u,) for u in range(U)], unit_rows, label, solve_without, st.fde_rule)
    if st.fde_max_excluded >= 2 and U >= 2:
        retry = ch.outcome == NONE_PASSES
        if retry.any():
            ch2 = _try(sel[retry], list(combinations(range(U), 2)), unit_rows, label, solve_without, st.fde_rule)
            ch = _merge_choices(ch, retry, ch2)
    return _apply(out, record, sel, ch, label)


def _apply(out: MonitorOutput, record: FdeRecord, sel: NDArray, ch: _Choice, label: NDArray) -> MonitorOutput:
    """``out`` with the exclusions ``ch`` at its alerted epochs ``sel`` (flat) written in."""
    bt = out.alert.shape
    P = int(np.prod(bt, dtype=np.int64))
    fields = {k: np.array(getattr(out, k)).reshape((P,) + getattr(out, k).shape[len(bt):])
              for k in ("pos_enu", "clock", "hpl", "vpl", "test_stat", "threshold", "alert", "available", "n_used")}
    outcome = np.zeros(P, np.int8)
    excl = np.full((P, 2), -1, np.int64)
    outcome[sel] = ch.outcome
    done = ch.outcome == EXCLUDED
    at = sel[done]
    if at.size:
        v = ch.verdict.take(np.flatnonzero(done))
        fields["pos_enu"][at] = v.x[:, :3]
        fields["clock"][at] = v.x[:, 3]
        fields["hpl"][at], fields["vpl"][at] = v.hpl, v.vpl
        fields["test_stat"][at], fields["threshold"][at] = v.test_stat, v.threshold
        fields["alert"][at] = False
        fields["n_used"][at] = v.n_used
        u = ch.units[done]
        excl[at] = np.where(u >= 0, label[at[:, None], np.maximum(u, 0)], -1)
        levels = tuple(service_level(s) for s in out.service_levels)
        fields["available"][at] = availability(fields["hpl"][at], fields["vpl"][at], levels)
    fields["available"][sel[~done]] = False  # an alert no exclusion clears: no service
    shaped = {k: v.reshape(bt + v.shape[1:]) for k, v in fields.items()}
    record = replace(record, outcome=outcome.reshape(bt), excluded=excl.reshape(bt + (2,)).astype(np.int16))
    return replace(out, **shaped, excluded=excl[:, 0].reshape(bt).astype(np.int16), fde=record)


def _merge_choices(first: _Choice, retry: NDArray, second: _Choice) -> _Choice:
    """``first`` with the epochs ``retry`` replaced by ``second`` where the pair search excluded something.

    ``retry`` epochs had a solution (outcome NONE_PASSES), so ``first.verdict`` exists.
    """
    took = second.outcome == EXCLUDED
    at = np.flatnonzero(retry)[took]
    outcome, units = first.outcome.copy(), first.units.copy()
    outcome[at], units[at] = EXCLUDED, second.units[took]
    merged = {k: np.array(getattr(first.verdict, k)) for k in Verdict.__dataclass_fields__}
    if at.size:
        for k in merged:
            merged[k][at] = getattr(second.verdict, k)[took]
    return _Choice(Verdict(**merged), units, outcome)
