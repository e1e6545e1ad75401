"""ARAIM multiple-hypothesis solution separation, batched over epochs (docs/design/araim.md).

:func:`araim` takes the rows of any number of epochs (batch axes first, satellites next) and returns the
protection levels, EMT, σ_acc, the availability per service level and, given prefit residuals, the
solution-separation test. An epoch that cannot be protected gets ∞ protection levels and a reason code
(:class:`AraimReason`), never an exception. :func:`araim_modes` returns one epoch's full mode table.

Epochs are grouped by row structure (which systems their used rows belong to): the fault modes of a
structure are enumerated once and every epoch of the group is solved together.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.integrity.araim.error_model import row_variances
from testbed.integrity.araim.fault_modes import AID_GROUPS, ModeSet, fault_modes
from testbed.integrity.araim.protection import araim_availability, fa_multipliers, protection_levels, q_tilde
from testbed.integrity.araim.settings import SYSTEMS, AraimSettings
from testbed.integrity.araim.subsets import chunk_epochs, subset_stats


class AraimReason(IntEnum):
    """Why an epoch has no ARAIM protection. Index into :data:`ARAIM_REASONS`."""

    OK = 0
    NAN_INPUT = 1
    NO_POSITION = 2
    SINGULAR = 3
    FAULT_ORDER = 4
    UNMONITORED = 5


ARAIM_REASONS: tuple[str, ...] = (
    "ok",
    "unavailable: NaN or a non-positive variance in a used row",
    "unavailable: fewer used rows than states (3 + one clock per system)",
    "unavailable: singular all-in-view geometry",
    "unavailable: the fault modes to monitor need more simultaneous faults than max_fault_order",
    "unavailable: too few satellites for the fault modes (the unmonitored prior exhausts the integrity budget)",
)


@dataclass(frozen=True)
class AraimRows:
    """The ranging rows of a batch of epochs, batch axes first: (..., N) per row, (..., N, 3) per vector.

    los_enu : receiver→satellite unit vectors in the local east-north-up frame.
    system : (N,) or (..., N) int system codes (index into :data:`~testbed.integrity.araim.settings.SYSTEMS`).
    used : (..., N) bool rows in the solution.  c_int, c_acc : (..., N) m² integrity and accuracy variances.
    b_nom, b_cont : (..., N) m nominal biases.  residual : (..., N) m prefit residuals Δy at the linearisation
    point, or None (then no detection test and no position correction).

    Non-GNSS (aid) rows, all None without them (docs/design/araim.md §11): A rows in fixed slots, each a linear
    measurement of the position and of K nuisance states (the camera's rotations) with its own variance.
    aid_g : (..., A, 3 + K) ∂row/∂[E, N, U, nuisance states].  aid_state : (A, K) bool, the nuisance states a
    row observes (a state no kept row observes is pinned, like the clock of a removed constellation).
    aid_label : (A, 2) int (kind, unit) of :mod:`.fault_modes` (a landmark's pixel row, a camera prior row).
    aid_used : (..., A) bool.  aid_c : (..., A) variances (row units²; integrity and accuracy alike, no bias).
    aid_residual : (..., A) prefit residuals (None exactly when ``residual`` is).
    """

    los_enu: NDArray
    system: NDArray
    used: NDArray
    c_int: NDArray
    c_acc: NDArray
    b_nom: NDArray
    b_cont: NDArray
    residual: NDArray | None = None
    aid_g: NDArray | None = None
    aid_state: NDArray | None = None
    aid_label: NDArray | None = None
    aid_used: NDArray | None = None
    aid_c: NDArray | None = None
    aid_residual: NDArray | None = None

    @property
    def n_aid(self) -> int:
        return 0 if self.aid_g is None else int(np.shape(self.aid_g)[-2])

    @classmethod
    def from_elevation(cls, los_enu: ArrayLike, system: ArrayLike, used: ArrayLike, settings: AraimSettings,
                       residual: ArrayLike | None = None) -> "AraimRows":
        """Rows whose variances and biases come from the ISM and the airborne model (eq. 1); the elevation is
        that of ``los_enu``."""
        los = np.asarray(los_enu, float)
        elevation = np.arcsin(np.clip(los[..., 2], -1.0, 1.0))
        c_int, c_acc, b_nom, b_cont = row_variances(elevation, np.broadcast_to(system, elevation.shape), settings)
        return cls(los, np.asarray(system), np.asarray(used, bool), c_int, c_acc, b_nom, b_cont,
                   None if residual is None else np.asarray(residual, float))


@dataclass(frozen=True)
class AraimEpochs:
    """ARAIM outputs per epoch, shape (...) unless stated (∞ protection levels where unavailable).

    hpl, vpl : m.  pl_enu : (..., 3) m per-axis protection levels (HPL = √(PL_E² + PL_N²)).  emt : m.
    sigma_acc_enu : (..., 3) m accuracy sigmas of the all-in-view solution (σ_acc,v is [..., 2]).
    available : (..., K) bool per ``service_levels``.  reason : (...) int8 :class:`AraimReason`.
    n_modes : monitored, observable fault modes.  fault_order : N_fault,max.  p_unmonitored : the
    unmonitored prior including unobservable modes.  k_fa : (..., 3) threshold multipliers.
    dx_enu : (..., 3) m all-in-view position correction S⁽⁰⁾Δy (NaN without residuals).
    test_ratio : max over modes and axes of |x̂⁽ᵏ⁾ − x̂⁽⁰⁾| / T_k,q (NaN without residuals).
    alert : test_ratio > 1.  iterations : (..., 3) halvings of the PL search.
    n_modes_aid : (..., G) per aid group of :data:`~.fault_modes.AID_GROUPS` (vision, inertia), the monitored
    modes that remove rows of that group.  risk_aid_enu : (..., G, 3) the integrity risk those modes take in
    eq. 16 at the protection levels, per axis, over the exposure (× N_ES,INT; the horizontal budget is shared by
    E and N); 0 without such rows, NaN where unavailable.
    """

    hpl: NDArray
    vpl: NDArray
    pl_enu: NDArray
    emt: NDArray
    sigma_acc_enu: NDArray
    available: NDArray
    service_levels: tuple[str, ...]
    reason: NDArray
    n_modes: NDArray
    fault_order: NDArray
    p_unmonitored: NDArray
    k_fa: NDArray
    dx_enu: NDArray
    test_ratio: NDArray
    alert: NDArray
    iterations: NDArray
    n_modes_aid: NDArray
    risk_aid_enu: NDArray
    reasons: tuple[str, ...] = ARAIM_REASONS

    @property
    def sigma_acc_v(self) -> NDArray:
        return self.sigma_acc_enu[..., 2]


@dataclass(frozen=True)
class ModeTable:
    """One epoch's fault modes (row 0 is fault-free). removed : per mode, the input row indices it removes.
    p, p_exp, alpha : (M,) priors and missed-detection caps.  observable : (M,) bool.
    sigma, bias, sigma_ss, bias_ss, threshold, separation : (M, 3) m in E, N, U."""

    removed: tuple[tuple[int, ...], ...]
    p: NDArray
    p_exp: NDArray
    alpha: NDArray
    observable: NDArray
    sigma: NDArray
    bias: NDArray
    sigma_ss: NDArray
    bias_ss: NDArray
    threshold: NDArray
    separation: NDArray


@lru_cache(maxsize=256)
def _modes(systems: tuple[int, ...], settings_json: str, aid: tuple[tuple[int, int], ...] = ()) -> ModeSet:
    return fault_modes(np.array(systems, int), AraimSettings.model_validate_json(settings_json), aid)


def _check_rows(rows: AraimRows, settings: AraimSettings) -> tuple[tuple[int, ...], int]:
    """Batch shape and N of ``rows``, or a ValueError naming the array and its shape / the system codes."""
    los = np.asarray(rows.los_enu)
    if los.ndim < 2 or los.shape[-1] != 3:
        raise ValueError(f"ARAIM rows: los_enu expected (..., N, 3), got {los.shape}")
    batch, N = los.shape[:-2], los.shape[-2]
    for name in ("used", "c_int", "c_acc", "b_nom", "b_cont", "residual"):
        a = getattr(rows, name)
        if a is not None and np.shape(a) != batch + (N,):
            raise ValueError(f"ARAIM rows: {name} expected {batch + (N,)} (from los_enu {los.shape}), got "
                             f"{np.shape(a)}")
    system = np.asarray(rows.system)
    if system.shape not in ((N,), batch + (N,)) or system.dtype.kind not in "iu":
        raise ValueError(f"ARAIM rows: system expected integer codes of shape {(N,)} or {batch + (N,)}, got "
                         f"{system.dtype} {system.shape}")
    if rows.aid_g is not None:
        g = np.asarray(rows.aid_g)
        if g.ndim < 2 or g.shape[:-2] != batch or g.shape[-1] < 3:
            raise ValueError(f"ARAIM rows: aid_g expected {batch + ('A', '3 + K')}, got {g.shape}")
        A, K = g.shape[-2], g.shape[-1] - 3
        for name, shape in (("aid_used", batch + (A,)), ("aid_c", batch + (A,)), ("aid_state", (A, K)),
                            ("aid_label", (A, 2))):
            if np.shape(getattr(rows, name)) != shape:
                raise ValueError(f"ARAIM rows: {name} expected {shape} (from aid_g {g.shape}), got "
                                 f"{np.shape(getattr(rows, name))}")
        if (rows.aid_residual is None) != (rows.residual is None) or (
                rows.aid_residual is not None and np.shape(rows.aid_residual) != batch + (A,)):
            raise ValueError(f"ARAIM rows: aid_residual expected {batch + (A,)} exactly when residual is given, got "
                             f"{None if rows.aid_residual is None else np.shape(rows.aid_residual)}")
    for code in np.unique(system[np.broadcast_to(rows.used, batch + (N,))] if system.ndim > 1 else system):
        if not 0 <= code < len(SYSTEMS) or SYSTEMS[code] not in settings.ism:
            raise ValueError(f"ARAIM rows: system code {int(code)} has no ISM (expected a code of "
                             f"{[SYSTEMS.index(s) for s in settings.ism]} = {list(settings.ism)})")
    return batch, N


def _risk_terms(pl, bias, sigma, p, monitored, protectable, threshold, alpha) -> NDArray:
    """Chosen modes' terms of eq. 16 at the protection levels ``pl`` (E, 3), (E, M, 3) for the M modes given (their
    ``bias``, ``sigma``, ``threshold`` (E, M, 3), priors ``p`` and caps ``alpha`` (M,)): P_k·min(Q̃((PL − T − b)/σ),
    α) where monitored, 0 where not, NaN where the epoch is not protectable (what the aid groups' risks sum)."""
    weight = np.where(monitored & protectable[:, None], p, 0.0)[..., None]  # (E, M, 1)
    with np.errstate(invalid="ignore", over="ignore"):
        z = (pl[:, None, :] - np.where(weight > 0.0, threshold + bias, 0.0)) / np.where(weight > 0.0, sigma, 1.0)
        terms = weight * np.minimum(q_tilde(z), alpha[None, :, None])  # Q̃, as the PL search sums it
    return np.where(protectable[:, None, None], terms, np.nan)


def _solve_group(G, c_int, c_acc, b_nom, b_cont, residual, clock_of_row, modes: ModeSet,
                 settings: AraimSettings, budget_share: NDArray, risk_modes: NDArray | None = None
                 ) -> dict[str, NDArray]:
    """Every output of the epochs of one row structure (E epochs), plus the per-mode arrays."""
    E = G.shape[0]
    st = subset_stats(G, c_int, c_acc, b_nom, b_cont, modes.removed, clock_of_row, settings.max_cond, residual)
    monitored = st.observable.copy()
    monitored[:, 0] = False
    unobservable_p = np.where(st.observable[:, 1:], 0.0, modes.p_exp[1:]).sum(-1)
    p_nm = modes.p_unmonitored + unobservable_p
    n_modes = monitored.sum(-1)
    k_fa = fa_multipliers(n_modes, settings.p_fa_hor, settings.p_fa_vert, settings.n_es_cont)  # (E, 3)
    n_es = settings.n_es_int if settings.max_pmd else 1
    alpha = np.minimum(1.0, modes.p_exp / (modes.p * n_es))
    alpha[0] = 1.0
    scale = 1.0 - p_nm / (settings.p_hmi_vert + settings.p_hmi_hor)  # budget left (eq. 16)
    budget = budget_share[:, None] * np.stack([0.5 * settings.p_hmi_hor * scale] * 2 + [settings.p_hmi_vert * scale], -1)
    protectable = st.observable[:, 0] & (scale > 0.0)
    target = np.where(protectable[:, None], budget, 1.0) / settings.n_es_int
    pl, iterations, threshold, emt, ratio = protection_levels(st, modes.p, alpha, k_fa, target, protectable,
                                                              residual is not None, settings.p_emt, settings.tol_pl)
    terms = None  # the risk terms of the modes asked for (the aid groups'), over the exposure
    if risk_modes is not None and risk_modes.any():
        k = np.flatnonzero(risk_modes)
        terms = _risk_terms(pl, st.bias[:, k], st.sigma[:, k], modes.p[k], monitored[:, k], protectable,
                            threshold[:, k], alpha[k]) * settings.n_es_int
    sigma_acc = np.sqrt(np.einsum("eqi,ei->eq", st.s0 ** 2, c_acc))
    dx = (np.full((E, 3), np.nan) if residual is None else np.einsum("eqi,ei->eq", st.s0, residual))
    return dict(pl=pl, iterations=iterations, emt=emt, sigma_acc=sigma_acc, n_modes=n_modes, p_nm=p_nm, k_fa=k_fa,
                monitored=monitored, terms=terms, ratio=ratio, dx=dx,
                singular=~st.observable[:, 0], unmonitored=st.observable[:, 0] & (scale <= 0.0),
                table=dict(p=modes.p, p_exp=modes.p_exp, alpha=alpha, observable=st.observable, sigma=st.sigma,
                           bias=st.bias, sigma_ss=st.sigma_ss, bias_ss=st.bias_ss, threshold=threshold,
                           separation=st.separation))


def _run(rows: AraimRows, settings: AraimSettings, keep_table: bool = False, budget_share: ArrayLike = 1.0):
    batch, N = _check_rows(rows, settings)
    P = int(np.prod(batch, dtype=np.int64))
    share = np.broadcast_to(np.asarray(budget_share, float), batch).reshape(P)
    los = np.asarray(rows.los_enu, float).reshape(P, N, 3)
    system = np.broadcast_to(np.asarray(rows.system), batch + (N,)).reshape(P, N)
    used = np.asarray(rows.used, bool).reshape(P, N)
    flat = {k: np.asarray(getattr(rows, k), float).reshape(P, N) for k in ("c_int", "c_acc", "b_nom", "b_cont")}
    residual = None if rows.residual is None else np.asarray(rows.residual, float).reshape(P, N)
    finite = (np.isfinite(los).all(-1) & np.isfinite(flat["c_int"]) & np.isfinite(flat["c_acc"])
              & (flat["c_int"] > 0) & (flat["c_acc"] > 0) & np.isfinite(flat["b_nom"]) & np.isfinite(flat["b_cont"]))
    if residual is not None:
        finite &= np.isfinite(residual)
    bad = (used & ~finite).any(-1)
    aid = _aid_rows(rows, P)
    if aid is not None:
        bad |= (aid["used"] & ~aid["finite"]).any(-1)

    out = dict(pl=np.full((P, 3), np.inf), iterations=np.zeros((P, 3), int), emt=np.full(P, np.nan),
               sigma_acc=np.full((P, 3), np.nan), n_modes=np.zeros(P, int), p_nm=np.full(P, np.nan),
               k_fa=np.full((P, 3), np.nan), ratio=np.full(P, np.nan), dx=np.full((P, 3), np.nan),
               fault_order=np.zeros(P, int), reason=np.where(bad, AraimReason.NAN_INPUT, AraimReason.OK),
               n_modes_aid=np.zeros((P, len(AID_GROUPS)), int),
               risk_aid=np.zeros((P, len(AID_GROUPS), 3)))
    # used rows first, ordered by system (stable): epochs with the same key share their fault modes
    order = np.lexsort((system, ~used), axis=-1)
    sys_sorted = np.take_along_axis(system, order, -1)
    used_sorted = np.take_along_axis(used, order, -1)
    key = np.where(used_sorted & ~bad[:, None], sys_sorted, -1)
    if aid is not None:  # the aid rows keep their slots: which are used is part of the structure
        key = np.concatenate([key, np.where(aid["used"] & ~bad[:, None], 1, -1)], -1)
    keys, group = np.unique(key, axis=0, return_inverse=True)
    group = group.reshape(-1)
    settings_json = settings.model_dump_json()
    table = None
    for g, k in enumerate(keys):
        systems = tuple(int(c) for c in k[:N][k[:N] >= 0])
        epochs = np.flatnonzero((group == g) & ~bad)
        if epochs.size == 0:
            continue
        present = list(dict.fromkeys(systems))
        aid_idx = np.flatnonzero(k[N:] > 0)
        labels = () if aid is None else tuple((int(a), int(u)) for a, u in aid["label"][aid_idx])
        nuisance = (np.zeros(0, int) if aid is None else np.flatnonzero(aid["state"][aid_idx].any(0)))
        n_states = 3 + len(present) + nuisance.size
        n_gnss = len(systems)
        n_rows = n_gnss + aid_idx.size
        if n_rows < n_states:
            out["reason"][epochs] = AraimReason.NO_POSITION
            continue
        modes = _modes(systems, settings_json, labels)
        out["fault_order"][epochs] = modes.fault_order
        if modes.order_exceeded:
            out["reason"][epochs] = AraimReason.FAULT_ORDER
            continue
        clock_of_row = np.array([present.index(s) for s in systems], int)
        incidence = np.zeros((n_rows, len(present) + nuisance.size), bool)
        incidence[np.arange(n_gnss), clock_of_row] = True
        idx = order[epochs, :n_gnss]
        take = lambda a: np.take_along_axis(a[epochs], idx, -1)  # noqa: E731
        G = np.concatenate([-np.take_along_axis(los[epochs], idx[..., None], 1),
                            np.broadcast_to(np.eye(len(present))[clock_of_row], (epochs.size, n_gnss, len(present))),
                            np.zeros((epochs.size, n_gnss, nuisance.size))], -1)
        parts = [take(flat[k]) for k in ("c_int", "c_acc", "b_nom", "b_cont")]
        res = None if residual is None else take(residual)
        if aid_idx.size:
            incidence[n_gnss:, len(present):] = aid["state"][aid_idx][:, nuisance]
            g_aid = aid["g"][epochs][:, aid_idx]
            G = np.concatenate([G, np.concatenate([g_aid[..., :3], np.zeros(g_aid.shape[:-1] + (len(present),)),
                                                   g_aid[..., 3 + nuisance]], -1)], 1)
            c_aid = aid["c"][epochs][:, aid_idx]
            zero = np.zeros_like(c_aid)
            parts = [np.concatenate([x, y], -1) for x, y in zip(parts, (c_aid, c_aid, zero, zero))]
            res = None if res is None else np.concatenate([res, aid["residual"][epochs][:, aid_idx]], -1)
        kinds = np.array([a for a, _ in labels], int)
        aid_mode = np.stack([modes.removed[:, n_gnss:][:, np.isin(kinds, group)].any(-1)
                             for group in AID_GROUPS.values()], -1)  # (M, G)
        step = chunk_epochs(epochs.size, modes.removed.shape[0], n_rows, n_states)
        for a in range(0, epochs.size, step):
            sl = slice(a, a + step)
            e = epochs[sl]
            r = _solve_group(G[sl], *(x[sl] for x in parts), None if res is None else res[sl], incidence,
                             modes, settings, share[e], aid_mode.any(-1))
            for name in ("pl", "iterations", "emt", "sigma_acc", "n_modes", "p_nm", "k_fa", "ratio", "dx"):
                out[name][e] = r[name]
            out["n_modes_aid"][e] = (r["monitored"][..., None] & aid_mode).sum(1)
            if r["terms"] is not None:
                of_group = aid_mode[aid_mode.any(-1)].astype(float)  # (M_aid, G): the modes the terms are of
                out["risk_aid"][e] = np.einsum("mg,emq->egq", of_group, np.nan_to_num(r["terms"]))
            out["reason"][e[r["singular"]]] = AraimReason.SINGULAR
            out["reason"][e[r["unmonitored"]]] = AraimReason.UNMONITORED
            if keep_table:
                slot = np.concatenate([idx[sl][0], N + aid_idx])
                table = ModeTable(removed=tuple(tuple(sorted(int(slot[i]) for i in np.flatnonzero(m)))
                                                for m in modes.removed),
                                  **{name: v[0] if np.ndim(v) > 1 else v for name, v in r["table"].items()})
    return batch, out, table


def _aid_rows(rows: AraimRows, P: int) -> dict[str, NDArray] | None:
    """The aid rows of ``rows`` flattened to P epochs (None without them), and which are finite."""
    A = rows.n_aid
    if not A:
        return None
    g = np.asarray(rows.aid_g, float)
    g = g.reshape(P, A, g.shape[-1])
    c = np.asarray(rows.aid_c, float).reshape(P, A)
    res = None if rows.aid_residual is None else np.asarray(rows.aid_residual, float).reshape(P, A)
    finite = np.isfinite(g).all(-1) & np.isfinite(c) & (c > 0)
    if res is not None:
        finite &= np.isfinite(res)
    return dict(g=g, c=c, residual=res, finite=finite, used=np.asarray(rows.aid_used, bool).reshape(P, A),
                state=np.asarray(rows.aid_state, bool), label=np.asarray(rows.aid_label, int))


def araim(rows: AraimRows, settings: AraimSettings | None = None, budget_share: ArrayLike = 1.0) -> AraimEpochs:
    """ARAIM protection levels, EMT, σ_acc, availability and the detection test of every epoch of ``rows``.

    Parameters
    ----------
    rows : the epochs' ranging rows (:class:`AraimRows`), batch axes (...) first.
    settings : risk allocation and ISM; default :class:`AraimSettings()` (the ADD v4.2-style allocation).
    budget_share : scalar or (...): the fraction (0, 1] of the integrity budget these protection levels get
        (eq. 16's right side times it): below 1 after an exclusion, whose candidates share the budget (§10).

    Returns
    -------
    :class:`AraimEpochs`, arrays of shape (...) (and (..., 3) / (..., K) as documented there).
    """
    settings = AraimSettings() if settings is None else settings
    if not np.all((np.asarray(budget_share) > 0.0) & (np.asarray(budget_share) <= 1.0)):
        raise ValueError(f"araim: budget_share expected in (0, 1], got {budget_share}")
    batch, out, _ = _run(rows, settings, budget_share=budget_share)
    ok = out["reason"] == AraimReason.OK
    pl = np.where(ok[:, None], out["pl"], np.inf)
    hpl, vpl = np.hypot(pl[:, 0], pl[:, 1]), pl[:, 2]
    emt = np.where(ok, out["emt"], np.nan)
    sigma_acc = out["sigma_acc"]
    avail = araim_availability(hpl, vpl, emt, sigma_acc[:, 2], settings.service_levels) & ok[:, None]
    shape = lambda a: a.reshape(batch + a.shape[1:])  # noqa: E731
    ratio = out["ratio"]
    return AraimEpochs(hpl=shape(hpl), vpl=shape(vpl), pl_enu=shape(pl), emt=shape(emt),
                       sigma_acc_enu=shape(sigma_acc), available=shape(avail), service_levels=settings.service_levels,
                       reason=shape(out["reason"].astype(np.int8)), n_modes=shape(out["n_modes"]),
                       fault_order=shape(out["fault_order"]), p_unmonitored=shape(out["p_nm"]),
                       k_fa=shape(out["k_fa"]), dx_enu=shape(out["dx"]), test_ratio=shape(ratio),
                       alert=shape(ratio > 1.0), iterations=shape(out["iterations"]),
                       n_modes_aid=shape(out["n_modes_aid"]),
                       risk_aid_enu=shape(np.where(ok[:, None, None], out["risk_aid"], np.nan)))


def araim_modes(rows: AraimRows, settings: AraimSettings | None = None) -> ModeTable | None:
    """The fault-mode table of one epoch (``rows`` without batch axes: (N,), (N, 3)); None when the epoch has
    no modes (its :func:`araim` reason says why)."""
    settings = AraimSettings() if settings is None else settings
    if np.ndim(rows.los_enu) != 2:
        raise ValueError(f"araim_modes: one epoch expected, los_enu (N, 3), got {np.shape(rows.los_enu)}")
    return _run(rows, settings, keep_table=True)[2]
