"""ARAIM fault modes: events, their priors, the fault order to monitor, the modes (docs/design/araim.md §3).

A *fault event* is one satellite (prior P_sat) or one constellation (P_const), and with vision rows one
landmark (its two pixel rows) or the whole camera (every pixel row and the camera's rotation prior rows,
a group like a constellation, §11); events are independent.
A *fault mode* is the set of rows a combination of events removes; its prior is the product of its events'
priors (eq. 5), as the ADD writes it: at least those events faulted, an upper bound on exactly those by the
factor 1/Π(1 − p) ≈ 1.0003, so a single-satellite mode's prior is P_sat itself. The modes of one row structure (how many rows of which system,
with which priors) do not depend on the geometry, so they are built once per structure and reused for every
epoch that has it.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from testbed.integrity.araim.settings import SYSTEMS, AraimSettings, AidFaultPrior

#: modes with an exposure prior above this are always monitored (MAAST-2's must-monitor floor)
P_MUST_MONITOR = 1e-7
#: kinds of a non-GNSS (aid) row: one landmark's pixel row, a prior row of the camera's rotation states, a row of
#: an inertial (coasted) position prediction
AID_LANDMARK, AID_CAMERA, AID_INERTIA = 0, 1, 2
#: the aid groups whose modes are reported apart, and the row kinds of each
AID_GROUPS: dict[str, tuple[int, ...]] = {"vision": (AID_LANDMARK, AID_CAMERA), "inertia": (AID_INERTIA,)}
#: the group code of the camera event (after the GNSS systems' codes): consolidated like a constellation
CAMERA_GROUP = len(SYSTEMS)


@dataclass(frozen=True)
class FaultEvents:
    """The independent fault events of one row structure.

    rows : per event, the row indices it removes.  p : (E,) instantaneous priors.
    p_exp : (E,) priors over the exposure, p·(1 + T_EXP/MFD) (eq. 5).  system : (E,) the system code of a
    constellation event, :data:`CAMERA_GROUP` for the camera, -1 for a satellite or landmark event.
    """

    rows: tuple[frozenset[int], ...]
    p: NDArray
    p_exp: NDArray
    system: NDArray


@dataclass(frozen=True)
class ModeSet:
    """The monitored fault modes of one row structure (mode 0 is fault-free: nothing removed).

    removed : (M, N) bool, rows each mode removes.  p, p_exp : (M,) instantaneous and exposure priors
    (p[0] = p_exp[0] = the fault-free probability).  p_unmonitored : the exposure prior not monitored
    (events beyond the enumerated order and modes left out).  fault_order : N_fault,max.
    order_exceeded : the ADD rule asks for more than ``max_fault_order``.
    """

    removed: NDArray
    p: NDArray
    p_exp: NDArray
    p_unmonitored: float
    fault_order: int
    order_exceeded: bool


def fault_events(system: NDArray, settings: AraimSettings, aid: tuple[tuple[int, int], ...] = ()) -> FaultEvents:
    """The satellite events (one per row), the constellation events (one per system present), then with aid
    rows one event per landmark and one for the camera.

    system : (N,) int system code of each GNSS row.  aid : per aid row (rows N, N+1, …), its (kind, unit):
    (:data:`AID_LANDMARK`, landmark number) or (:data:`AID_CAMERA`, state number).
    """
    system = np.asarray(system)
    rows, p, factor, sys = [], [], [], []

    def add(members, prior: AidFaultPrior, code: int) -> None:
        rows.append(frozenset(members))
        p.append(prior.p)
        factor.append(settings.exposure_factor(prior.mfd_h))
        sys.append(code)

    for i, s in enumerate(system):
        ism = settings.system_ism(int(s))
        rows.append(frozenset({i}))
        p.append(ism.p_sat)
        factor.append(settings.exposure_factor(ism.mfd_sat_h))
        sys.append(-1)
    for s in dict.fromkeys(int(c) for c in system):  # systems in order of first appearance
        ism = settings.system_ism(s)
        rows.append(frozenset(np.flatnonzero(system == s).tolist()))
        p.append(ism.p_const)
        factor.append(settings.exposure_factor(ism.mfd_const_h))
        sys.append(s)
    N = system.size
    landmarks: dict[int, list[int]] = {}
    for a, (kind, unit) in enumerate(aid):
        if kind == AID_LANDMARK:
            landmarks.setdefault(unit, []).append(N + a)
    for members in landmarks.values():
        add(members, settings.landmark, -1)
    camera = [N + a for a, (kind, _) in enumerate(aid) if kind in (AID_LANDMARK, AID_CAMERA)]
    if camera:
        add(camera, settings.camera, CAMERA_GROUP)
    inertia = [N + a for a, (kind, _) in enumerate(aid) if kind == AID_INERTIA]
    if inertia:
        add(inertia, settings.inertia, -1)
    p = np.array(p, float)
    return FaultEvents(tuple(rows), p, p * np.array(factor), np.array(sys, int))


def elementary_symmetric(q: NDArray, kmax: int) -> NDArray:
    """e_0 … e_kmax of ``q``: e_k = Σ over k-subsets of the product (a recursion, no cancellation)."""
    e = np.zeros(kmax + 1)
    e[0] = 1.0
    for x in q:
        e[1:] = e[1:] + x * e[:-1]
    return e


def prob_at_least(p: NDArray, r: int) -> float:
    """P(at least r of the independent events with priors ``p`` occur) (eq. 6).

    Exact for r ≤ 3 (Π(1−p)·Σ_{k≥r} e_k(q), q = p/(1−p), summed without cancellation); the ADD's bound
    (Σp)^r / r! for r ≥ 4.
    """
    p = np.asarray(p, float)
    if r <= 0:
        return 1.0
    if r >= 4:
        return float(p.sum() ** r / math.factorial(r))
    e = elementary_symmetric(p / (1.0 - p), p.size)
    return float(np.prod(1.0 - p) * e[r:].sum())


def fault_order(p_exp: NDArray, settings: AraimSettings) -> tuple[int, bool]:
    """N_fault,max: the smallest r ≥ ``min_fault_order`` with P(≥ r+1 events) ≤ P_THRES (eq. 7), capped at
    ``max_fault_order``; and whether the cap cut it short."""
    r = settings.min_fault_order
    while prob_at_least(p_exp, r + 1) > settings.p_thres:
        if r == settings.max_fault_order:
            return r, True
        r += 1
    return r, False


def fault_modes(system: NDArray, settings: AraimSettings, aid: tuple[tuple[int, int], ...] = ()) -> ModeSet:
    """The monitored modes of rows of systems ``system`` (N,) and aid rows ``aid`` (:func:`fault_events`):
    enumerate, consolidate, select (eq. 5-8).

    1. every combination of at most N_fault,max events; identical removed sets are one mode (priors summed);
    2. consolidation (``fc_thres`` > 0): a mode inside one constellation (or the camera) whose prior is below
       fc_thres × that constellation's is folded into the constellation mode;
    3. selection: every mode whose p_exp exceeds :data:`P_MUST_MONITOR`, then the others by number of rows
       removed (then prior, largest first) until the unmonitored prior is at most P_THRES. The unmonitored
       prior is P(≥ N_fault,max + 1 events) (eq. 6) plus the modes left out.
    """
    system = np.asarray(system)
    N = system.size + len(aid)
    ev = fault_events(system, settings, aid)
    order, exceeded = fault_order(ev.p_exp, settings)
    log_none = float(np.sum(np.log1p(-ev.p)))
    log_none_exp = float(np.sum(np.log1p(-ev.p_exp)))
    modes: dict[frozenset[int], list[float]] = {}
    p_event, p_exp_event = ev.p.tolist(), ev.p_exp.tolist()  # Python floats: a numpy call per combination cost ~10 µs
    for r in range(1, order + 1):
        for combo in itertools.combinations(range(len(ev.rows)), r):
            rows = frozenset().union(*(ev.rows[e] for e in combo))
            pr = [math.prod(p_event[e] for e in combo), math.prod(p_exp_event[e] for e in combo)]
            acc = modes.setdefault(rows, [0.0, 0.0])
            acc[0] += pr[0]
            acc[1] += pr[1]
    if settings.fc_thres > 0.0:
        for e in np.flatnonzero(ev.system >= 0):
            const_rows = ev.rows[e]
            if const_rows not in modes:
                continue
            p_const_mode = modes[const_rows][0]
            for rows in [m for m in modes if m < const_rows and modes[m][0] < settings.fc_thres * p_const_mode]:
                folded = modes.pop(rows)
                modes[const_rows][0] += folded[0]
                modes[const_rows][1] += folded[1]
    p_ff_exp = math.exp(log_none_exp)
    ranked = sorted(modes.items(), key=lambda kv: (len(kv[0]), -kv[1][1], sorted(kv[0])))
    must = [kv for kv in ranked if kv[1][1] > P_MUST_MONITOR]
    optional = [kv for kv in ranked if kv[1][1] <= P_MUST_MONITOR]
    p_unmonitored = prob_at_least(ev.p_exp, order + 1) + sum(v[1] for _, v in optional)
    chosen = list(must)
    for rows, pr in optional:
        if p_unmonitored <= settings.p_thres:
            break
        chosen.append((rows, pr))
        p_unmonitored -= pr[1]
    chosen.sort(key=lambda kv: (len(kv[0]), -kv[1][1], sorted(kv[0])))
    removed = np.zeros((len(chosen) + 1, N), bool)
    for k, (rows, _) in enumerate(chosen, start=1):
        removed[k, sorted(rows)] = True
    p = np.array([math.exp(log_none)] + [pr[0] for _, pr in chosen])
    p_exp = np.array([p_ff_exp] + [pr[1] for _, pr in chosen])
    return ModeSet(removed, p, p_exp, max(p_unmonitored, 0.0), order, exceeded)
