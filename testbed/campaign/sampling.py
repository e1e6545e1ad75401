"""Importance sampling of a campaign's fault-free pseudorange errors, and the weighted estimates of its rates.

A rate of 10⁻⁷ per epoch is out of reach of plain Monte Carlo: with no event in ``n`` trials the 95 % upper bound
is about ``3/n``. Importance sampling draws the trials from a *proposal* ``q`` that reaches the failure event
often and weights each trial by the likelihood ratio ``w = p/q`` of the error model ``p``: ``E_q[w·X] = E_p[X]``
for every quantity ``X`` of the trial (Rubinstein & Kroese 2017, ch. 5). One weight per trial serves every
monitor, every rate and every epoch of it.

The proposal (``[sampling]`` of the spec, :class:`~testbed.campaign.spec.SamplingPlan`) is aimed from the
monitor's own linear model: its position error is linear in the pseudorange errors, ``e = e₀ + A·z`` with ``z``
the standard-normal draws (``noise = σ·z``: white errors), ``A`` measured by running the monitor on the error-free
observations and on one 0.1 m bias per satellite (:func:`linear_model`; exact for a snapshot least-squares
monitor). The nearest point of ``{|e_v| > L}`` to the origin (the *dominating point*, Sadowsky & Bucklew 1990)
is ``z* = (±L − e₀)·s/|s|²`` along ``s = A_v``; in the horizontal plane along the major axis of ``A_h A_hᵀ``. It
lies in the solution space of the least-squares fit, so its residual (the test statistic) is zero: it is the
nearest error that is *misleading without an alert*. ``L`` is the protection level (``event = "misleading"``)
or the alert limit at the epochs whose protection level is within it (``"hazardous"``).

A sortie has many epochs, and a shift at every one would multiply their likelihood ratios into a degenerate
weight. The proposal is a mixture instead: each trial shifts one epoch's errors, a component ``k`` (epoch,
dimension, sign) chosen uniformly, and a share ``α`` of the trials (``defensive``) is drawn from ``p`` itself
(Hesterberg 1995), so the weight ``w = 1 / (α + (1−α)/K · Σ_k q_k/p)`` is at most ``1/α`` and the mixture
covers every epoch's event (Owen & Zhou 2000). With ``mixture = "tail"`` component ``k`` is drawn with
probability ``π_k ∝ Q(|z*_k|)``, its own tail, and ``1/K`` becomes ``π_k``: the trials go where the rate is
(a flight whose epochs' rates span orders of magnitude is otherwise carried by the few trials at its worst
epochs). ``proposal = "scale"`` instead scales by ``c`` one epoch's
errors in the fit's residual (parity) space, where the test statistic lives: its tail is the false alarm. The component choice comes from the block's own stream
(``sampling``), so a trial is a pure function of (spec, cell, trial) as before.

Estimates (:func:`weighted_rate`): the mean of ``w·X`` (a ratio of two weighted means where the denominator
varies), its standard error from the sample variance, a normal interval, and three diagnostics that say when
the weights have not settled and the report must print no rate: the effective number of events (Kish 1965),
the largest trial's share of the estimate, and the relative variance of the variance (VOV, the check of
X-5 Monte Carlo Team 2003).
"""

from __future__ import annotations

import hashlib
import json
import threading
from dataclasses import dataclass, replace

import numpy as np
from scipy import special, stats

from testbed.campaign import sampling_araim
from testbed.campaign.context import CellContext
from testbed.campaign.sampling_vision import PROBE_Z, TiltRecorder, VisionColumns, probe_tilt
from testbed.integrity.monitor import Observations
from testbed.monitors import monitor_inputs, monitor_names
from testbed.schema import ConfigError
from testbed.sensors.vision.detect import sample_vision
from testbed.sim import pipeline
from testbed.sim.streams import StreamTree

#: the bias (m) put on one satellite at a time to measure the monitor's linear model (the fix converges to
#: ~1e-10 m, the range's curvature over it is ~1e-9 m, and no alert is raised by a bias this small)
PROBE_M = 0.1

#: the diagnostics' limits: fewer effective events, a larger share of the estimate carried by one trial, or a
#: larger relative variance of the variance, and the report prints no rate (module doc)
MIN_EFFECTIVE_EVENTS = 10.0
MAX_LARGEST_SHARE = 0.25
MAX_VOV = 0.1


#: the inputs a proposal moves: the pseudorange draws; every other sensor's errors (vision, IMU, correlators,
#: features) are drawn from the error model itself
MOVED_INPUTS = frozenset({"gnss"})

#: the rates each proposal aims at: the shift at the errors beyond the PL (misleading) or the alert limit
#: (hazardous) with no alert, the scale at the tests' tails (whatever the event)
AIMED_RATES = {("shift", "misleading"): ("P_MI",), ("shift", "hazardous"): ("P_HMI",),
               ("scale", "misleading"): ("P_FA",), ("scale", "hazardous"): ("P_FA",),
               ("separation", "misleading"): ("P_FA",), ("separation", "hazardous"): ("P_FA",)}


def coverage(monitor: str, rate: str, aimed_monitor: str, proposal: str, event: str = "misleading"
             ) -> tuple[str, str]:
    """Whether the proposal aims at ``rate`` of ``monitor``: ``(status, why)``, status one of "aimed" (the
    monitor it is aimed from, a rate it aims at), "moved" (another monitor reading the pseudoranges alone: every
    input moved, efficient where its failure region is near the aimed one's), "not aimed" (a rate the proposal
    does not aim at) and "not reached" (the monitor reads inputs the proposal leaves as drawn: events they drive
    come at their plain rate). Every weighted estimate is unbiased; only an aimed one is efficient."""
    try:
        moved = moved_inputs(aimed_monitor)
        unmoved = sorted(monitor_inputs(monitor) - moved)
    except (KeyError, ValueError):
        return "not reached", f"{monitor} is not a registered monitor here: what it reads is unknown"
    if unmoved:
        what = "the pseudoranges only" if moved == MOVED_INPUTS else " and ".join(sorted(moved))
        return "not reached", (f"the proposal moves {what}; {monitor} also reads "
                               f"{', '.join(unmoved)}, drawn from the error model, so the events those errors drive "
                               "come at their plain rate")
    aims = AIMED_RATES.get((proposal, event), ())
    if rate not in aims:
        what = f"proposal '{proposal}'" + (f", event '{event}'" if proposal == "shift" else "")
        return "not aimed", f"{what} aims at {' and '.join(aims)}, not {rate}"
    if monitor != aimed_monitor:
        return "moved", (f"aimed from {aimed_monitor}'s linear model; efficient for {monitor} where its failure "
                         "region is near that one's")
    return "aimed", f"aimed from {monitor}'s linear model"


def moved_inputs(aimed_monitor: str) -> frozenset:
    """The inputs a proposal aimed from ``aimed_monitor`` moves: the pseudoranges, and the camera's Gaussian draws
    when that monitor reads the camera (:mod:`.sampling_vision`; its dithering and survey stay as drawn)."""
    return MOVED_INPUTS | (monitor_inputs(aimed_monitor) & VISION_INPUTS)


#: the inputs besides the pseudoranges a proposal can move: the camera's (:mod:`.sampling_vision`)
VISION_INPUTS = frozenset({"vision"})


# ----------------------------------------------------------------------------- checks before any work

def sampling_monitor(spec) -> str | None:
    """The monitor whose linear model aims the proposal: ``[sampling] monitor``, else the first of the spec's
    monitors that reads the pseudoranges alone (None: none does)."""
    if spec.sampling.monitor is not None:
        return spec.sampling.monitor
    return next((m for m in spec.monitors if monitor_inputs(m) == frozenset({"gnss"})), None)


def check_sampling(loaded, cells) -> None:
    """An importance-sampling spec that cannot be run as asked: a ConfigError naming the key, before any work."""
    spec = loaded.spec
    if spec.sampling.method != "importance":
        return
    problems = []
    name = sampling_monitor(spec)
    alone = [m for m in monitor_names() if monitor_inputs(m) == frozenset({"gnss"})]
    if name is None:
        problems.append(f"[sampling] method = 'importance': no monitor of {list(spec.monitors)} reads the "
                        f"pseudoranges alone (monitors that do: {', '.join(alone)}); the proposal is aimed from such a monitor's "
                        "linear model, or from a camera monitor's named by [sampling] monitor (pixel, va_raim): add "
                        "one to monitors or name it, or set method = 'plain'")
    elif not (monitor_inputs(name) == MOVED_INPUTS or monitor_inputs(name) == MOVED_INPUTS | VISION_INPUTS):
        problems.append(f"[sampling.monitor] {name!r} reads {sorted(monitor_inputs(name))}: expected a monitor "
                        f"that reads the pseudoranges alone (monitors that do: {', '.join(alone)}), or the "
                        "pseudoranges and the camera, whose position error is linear in their draws")
    elif monitor_inputs(name) & VISION_INPUTS and spec.sampling.proposal != "shift":
        problems.append(f"[sampling.proposal] {spec.sampling.proposal!r} with monitor {name!r}, which reads the "
                        "camera: the scale proposal scales the pseudorange residual space only; expected "
                        "proposal = 'shift'")
    if spec.sampling.adapt != "none" and spec.sorties.start != "fixed":
        problems.append(f"[sampling.adapt] {spec.sampling.adapt!r} with [sorties] start = "
                        f"{spec.sorties.start!r}: the pilot refits the proposal of one sky; expected start = 'fixed' "
                        "(sweep start_time_utc for several skies), or adapt = 'none'")
    if spec.sampling.proposal == "separation" and name is not None and name != "araim":
        problems.append(f"[sampling] proposal = 'separation' aims at ARAIM's solution-separation tests: expected "
                        f"monitor = 'araim' (got {name!r})")
    if spec.sampling.proposal == "separation" and spec.sorties.start != "fixed":
        problems.append(f"[sorties] start = {spec.sorties.start!r} with [sampling] proposal = 'separation': expected "
                        "'fixed' (a sky window's components, one per test, take ~100 MB: sweep start_time_utc "
                        "instead)")
    for c in cells:
        moved_by_options = [m for m in spec.monitors if monitor_inputs(m, c.config.monitor) != monitor_inputs(m)]
        if moved_by_options:
            problems.append(f"cell {c.index} ({c.approach.name}): {', '.join(moved_by_options)} read "
                            + "; ".join(f"{sorted(monitor_inputs(m, c.config.monitor))} with their options"
                                        for m in moved_by_options)
                            + ": the proposal is aimed, and its coverage reported, from a monitor's registered "
                            "inputs; importance sampling with such options is not supported yet: expected "
                            "method = 'plain'")
        g = c.config.gnss
        coloured = [k for k in ("multipath_tau_s", "ura_tropo_tau_s") if getattr(g, k) is not None]
        if coloured:
            problems.append(f"cell {c.index} ({c.approach.name}): [gnss] {', '.join(coloured)} set: importance "
                            "sampling shifts white pseudorange errors (noise = σ·z); expected them unset (white)")
        if g.correlator_pseudoranges:
            problems.append(f"cell {c.index} ({c.approach.name}): the pseudoranges come from the correlators; "
                            "importance sampling shifts the modelled pseudorange errors: expected the default "
                            "pseudorange source")
    if problems:
        raise ConfigError(loaded.source, problems)


# ----------------------------------------------------------------------------- the proposal

@dataclass(frozen=True)
class LinearModel:
    """A monitor's position error as a linear function of the standard-normal pseudorange draws, per epoch.

    e0 : (T, 3) ENU error on the error-free observations.  A : (T, 3, S) the error per unit draw of each slot
    (the drawn σ times the error per metre).  design : (T, S, k) the directions of the draws the fit absorbs
    whole: the columns of the design matrix (three lines of sight, one clock per constellation) over the drawn
    σ; a draw along them moves the fix and leaves every residual at zero.  used : (T, S) the slots the fix uses.
    hpl, vpl : (T,) the protection levels on the error-free observations (NaN: no solution).  dimensions : the
    dimensions the monitor bounds.
    """

    e0: np.ndarray
    A: np.ndarray
    design: np.ndarray
    used: np.ndarray
    hpl: np.ndarray
    vpl: np.ndarray
    dimensions: tuple[str, ...]


@dataclass(frozen=True)
class Components:
    """The mixture's components: component k acts on epoch ``epoch[k]``, with mean ``shift[k]`` (S,) (standard
    units), or scaling the draws' part in the fit's residual space, the projector ``parity[k]`` (S, S) of rank
    ``dof[k]``, by the plan's factor; drawn with probability ``exp(log_share[k])`` (None: uniformly; a share
    below the float range is -inf: never drawn, and no part of the weight)."""

    epoch: np.ndarray  # (K,)
    shift: np.ndarray  # (K, S)
    parity: np.ndarray  # (K, S, S)
    dof: np.ndarray  # (K,)
    log_share: np.ndarray | None = None  # (K,) log-probabilities summing to 1
    #: a shift component's event, for the adaptive step (:func:`cross_entropy_shifts`): the error's ENU direction
    #: (K, 3) (the bounded dimension's, with the component's sign) and the limit (K,) it must exceed there
    direction: np.ndarray | None = None
    limit: np.ndarray | None = None

    @property
    def size(self) -> int:
        return int(self.epoch.size)


def linear_model(ctx: CellContext, monitor_name: str, windows: np.ndarray | None) -> list[LinearModel]:
    """The monitor's :class:`LinearModel` on the cell's geometry, one per sky window of ``windows`` (None: the
    fixed start's one): the monitor on the error-free observations and on a :data:`PROBE_M` bias per slot; for a
    monitor that reads the camera, also on :data:`~.sampling_vision.PROBE_Z` standard deviations per vision column
    (:mod:`.sampling_vision`), whose columns follow the slots' in ``A``."""
    mon = next(m for m in ctx.setup.monitors if m.name == monitor_name)
    S = ctx.g_geom.prn.size
    W = 1 if windows is None else windows.size
    cols = vision_columns(ctx, monitor_name)
    V = 0 if cols is None else cols.size
    P = S + V + 1
    geom = ctx.gnss_geometry_of(None if windows is None else np.repeat(windows, P))
    base = pipeline.gnss_errors(ctx.plan, geom, StreamTree(0), W * P)  # for its σ and shapes; the draws are replaced
    T = ctx.t.size
    noise = np.zeros((W, P, T, S))
    noise[:, np.arange(1, S + 1), :, np.arange(S)] = PROBE_M
    zero = np.zeros((W * P, T))
    errors = type(base)(batch=base.batch, sigma=base.sigma, noise=noise.reshape(W * P, T, S), clock_bias=zero,
                        clock_drift=zero, rr_noise=np.zeros_like(base.rr_noise), fault_seed=base.fault_seed,
                        fault_bit_generator=base.fault_bit_generator)
    gnss, _ = pipeline.gnss_observations(geom, errors, [])
    vision = None
    if cols is not None:  # the error-free scene, the landmarks where they stand, and one vision column probed
        vision, _ = sample_vision(ctx.v_geom, ctx.setup.vision, landmarks=ctx.landmarks, faults=[],
                                  rng=StreamTree(0).generator("vision"), n_trials=W * P,
                                  survey_ecef=ctx.landmarks.pos_ecef, tilt=probe_tilt(cols, S + 1, P))
    out, _ = mon.step(Observations(gnss, vision), mon.initial_state())
    ref = pipeline.reference_enu(mon, ctx.truth_ant_enu, ctx.truth_cg_enu)
    pos = np.asarray(out.pos_enu, float).reshape(W, P, T, 3)
    sigma = np.broadcast_to(np.asarray(base.drawn_sigma, float), (W * P, T, S)).reshape(W, P, T, S)[:, 0]
    design = design_columns(ctx.gnss_geometry_of(None if windows is None else windows), (W, T, S))
    visible = np.broadcast_to(np.asarray(gnss.visible, bool), (W * P, T, S)).reshape(W, P, T, S)[:, 0]
    ok = np.asarray(out.reason).reshape(W, P, T)[:, 0] == 0
    hpl = np.asarray(out.hpl, float).reshape(W, P, T)[:, 0]
    vpl = np.asarray(out.vpl, float).reshape(W, P, T)[:, 0]
    models = []
    for w in range(W):
        per_unit = np.moveaxis(pos[w, 1:] - pos[w, :1], 0, -1)  # (T, 3, S + V)
        per_unit = np.where(np.isfinite(per_unit) & ok[w][:, None, None], per_unit, 0.0)
        per_m = per_unit[..., :S] / PROBE_M
        used = visible[w] & ok[w][:, None] & (np.abs(per_m).sum(1) > 0)
        A = np.concatenate([per_m * np.where(used, sigma[w], 0.0)[:, None, :], per_unit[..., S:] / PROBE_Z], -1)
        with np.errstate(divide="ignore", invalid="ignore"):
            per_draw = np.where(used[..., None], design[w] / sigma[w][..., None], 0.0)
        models.append(LinearModel(e0=pos[w, 0] - ref, A=A, design=per_draw, used=used,
                                  hpl=np.where(ok[w], hpl[w], np.nan),
                                  vpl=np.where(ok[w], vpl[w], np.nan), dimensions=tuple(out.dimensions)))
    return models


def vision_columns(ctx: CellContext, monitor_name: str) -> VisionColumns | None:
    """The vision columns a proposal aimed from ``monitor_name`` moves (:mod:`.sampling_vision`): None when that
    monitor does not read the camera."""
    if not (monitor_inputs(monitor_name) & VISION_INPUTS) or ctx.v_geom is None:
        return None
    return VisionColumns(len(ctx.landmarks))


def design_columns(geom, shape: tuple[int, int, int]) -> np.ndarray:
    """(W, T, S, 3 + C) the design matrix of a fix with one clock per constellation on ``geom`` (windows W,
    epochs T, slots S; C constellations), in metres: the unit lines of sight (ECEF: the span is what matters)
    and one indicator per constellation. Built from the geometry, not the monitor: a pseudorange error in
    their span is absorbed whole by the position and the clocks (the inter-system offsets are such an error)."""
    W, T, S = shape
    los = np.broadcast_to(np.asarray(geom.sat_pos_ecef, float), (W, T, S, 3)) \
        - np.broadcast_to(np.asarray(geom.ant_pos_ecef, float), (W, T, 3))[:, :, None, :]
    los = los / np.linalg.norm(los, axis=-1, keepdims=True)
    system = np.asarray(geom.system)
    clocks = np.stack([system == c for c in dict.fromkeys(system.tolist())], -1).astype(float)  # (S, C)
    return np.concatenate([los, np.broadcast_to(clocks, (W, T) + clocks.shape)], -1)


def components(model: LinearModel, plan, hal: float, val: float) -> Components:
    """The mixture components of ``plan`` (``[sampling]``) on one :class:`LinearModel` (module doc): per epoch
    with a solution, per bounded dimension, the two dominating points ``±L`` (``proposal = "shift"``), or one
    scaled epoch (``"scale"``). Epochs whose event cannot happen (``"hazardous"`` where the PL exceeds the
    alert limit: unavailable) have none."""
    T, _, S = model.A.shape
    epochs, shifts, directions, limits = [], [], [], []
    for dim, pl, al in (("V", model.vpl, val), ("H", model.hpl, hal)):
        if dim not in model.dimensions:
            continue
        limit = pl if plan.event == "misleading" else np.where(pl <= al, al, np.nan)
        for t in np.flatnonzero(np.isfinite(limit)):
            A = model.A[t]
            if dim == "V":
                s, e0, axis = A[2], model.e0[t, 2], np.array([0.0, 0.0, 1.0])
            else:
                vals, vecs = np.linalg.eigh(A[:2] @ A[:2].T)
                u = vecs[:, -1]
                s, e0, axis = u @ A[:2], float(u @ model.e0[t, :2]), np.array([u[0], u[1], 0.0])
            norm2 = float(s @ s)
            if not norm2 > 0:
                continue
            for sign in (1.0, -1.0):
                epochs.append(t)
                shifts.append((sign * limit[t] - e0) * s / norm2)
                directions.append(sign * axis)
                limits.append(limit[t])
    if plan.proposal == "scale":
        return _parity_components(model)
    ep = np.array(epochs, np.int64)
    shifts = np.array(shifts, float).reshape(ep.size, S)
    log_share = None
    if plan.mixture == "tail" and ep.size:  # each component in proportion to its own tail Q(|z*|)
        log_tail = stats.norm.logsf(np.linalg.norm(shifts, axis=1))
        log_share = log_tail - special.logsumexp(log_tail)
    return Components(ep, shifts, np.zeros((ep.size, S, S)), np.zeros(ep.size, np.int64), log_share,
                      np.array(directions, float).reshape(ep.size, 3), np.array(limits, float))


def _parity_components(model: LinearModel) -> Components:
    """One component per epoch with a solution and redundancy: the projector onto the residual (parity) space
    of the fit, the orthogonal complement, among the used slots, of the directions it absorbs (the design's
    columns over the drawn σ, one clock per constellation). Every test statistic (the residuals' χ², a solution
    separation) is a function of the draws' part there; with the σ told equal to the σ drawn, the χ² is its
    squared norm."""
    T, _, S = model.A.shape
    epochs, proj, dof = [], [], []
    for t in range(T):
        u = np.flatnonzero(model.used[t])
        cols = model.design[t][u]
        cols = cols[:, np.abs(cols).sum(0) > 0]  # a constellation with no used slot has no clock
        if u.size <= cols.shape[1] or not np.isfinite(model.vpl[t]):
            continue
        q, sv, _ = np.linalg.svd(cols, full_matrices=False)
        rank = int((sv > 1e-9 * sv.max()).sum())
        P = np.zeros((S, S))
        P[np.ix_(u, u)] = np.eye(u.size) - q[:, :rank] @ q[:, :rank].T
        epochs.append(t), proj.append(P), dof.append(u.size - rank)
    ep = np.array(epochs, np.int64)
    return Components(ep, np.zeros((ep.size, S)), np.array(proj).reshape(ep.size, S, S), np.array(dof, np.int64))


def cell_components(ctx: CellContext, spec, windows: np.ndarray | None) -> list[Components]:
    """:func:`components` of the cell's monitor on each distinct sky window of ``windows`` (sorted; None: the
    fixed start), kept per process by what fixes them (the cell's configuration, the plan, the window)."""
    plan = spec.sampling
    name = sampling_monitor(spec)
    key_cell = hashlib.sha256(json.dumps([ctx.cell.config.model_dump(mode="json"), plan.model_dump(mode="json"),
                                          name, spec.duration_s, spec.segment, spec.base_seed, ctx.cell.index],
                                         sort_keys=True, default=str)
                              .encode()).hexdigest()
    want = [None] if windows is None else [int(w) for w in np.unique(windows)]
    with _LOCK:  # blocks on threads: each window's model measured once
        missing = [w for w in want if (key_cell, w) not in _COMPONENTS]
        if missing:
            models = linear_model(ctx, name, None if windows is None else np.array(missing))
            if len(_COMPONENTS) + len(missing) > _MAX_KEPT:
                _COMPONENTS.clear()
            for w, m in zip(missing, models):
                if plan.proposal == "separation":
                    c = separation_components(ctx, name, m, plan)
                else:
                    c = components(m, plan, ctx.hal, ctx.val)
                    c = adapted_components(ctx, spec, c) if plan.adapt == "cross_entropy" else c
                _COMPONENTS[key_cell, w] = c
        return [_COMPONENTS[key_cell, w] for w in want]


def separation_components(ctx: CellContext, monitor_name: str, model: LinearModel, plan) -> Components:
    """The ``separation`` proposal's components (:mod:`.sampling_araim`) on one window's linear model of the
    ARAIM monitor ``monitor_name``: a mean shift to each solution-separation test's threshold."""
    mon = next(m for m in ctx.setup.monitors if m.name == monitor_name)
    settings = mon.settings.allocation(tuple(mon.context.integrity.service_levels))
    tests = sampling_araim.model_tests(model, np.asarray(ctx.g_geom.system), ctx.setup.frame.R, settings)
    S = model.used.shape[1]
    ep, shift, log_share = sampling_araim.separation_components(tests, S, plan.mixture == "tail")
    return Components(ep, shift, np.broadcast_to(np.zeros((1, S, S)), (ep.size, S, S)), np.zeros(ep.size, np.int64),
                      log_share)


_COMPONENTS: dict = {}
_LOCK = threading.Lock()
_MAX_KEPT = 20_000  # windows' components kept (a cell has at most 1436 sky windows of 60 s)


@dataclass(frozen=True)
class ProposalDraw:
    """One block's proposal: per trial the component drawn (−1: the error model itself) and the tilt."""

    component: np.ndarray  # (n,) int
    shift: np.ndarray  # (n, T, S) standard units


def draw_proposal(comps: list[Components], which: np.ndarray, plan, z: np.ndarray,
                  rng: np.random.Generator) -> ProposalDraw:
    """Choose each trial's component (defensive share: none) from ``rng`` and the shift of its draws ``z``
    (n, T, S): the component's mean, or ``(c − 1)`` times the draws' part in its parity space (which scales that
    part by ``c``). ``which`` (n,): the index into ``comps`` of each trial's sky window (all 0 at a fixed start)."""
    n = z.shape[0]
    u = rng.random(n)
    pick = rng.random(n)  # one uniform per trial whatever K: the stream does not depend on the geometry
    K = np.array([c.size for c in comps])[which]
    comp = np.where((u < plan.defensive) | (K == 0), -1, np.minimum((pick * K).astype(np.int64), K - 1))
    for j, c in enumerate(comps):  # components drawn by their shares: the same uniform, inverted
        sel = np.flatnonzero((which == j) & (comp >= 0))
        if c.log_share is not None and sel.size:
            comp[sel] = np.minimum(np.searchsorted(np.cumsum(np.exp(c.log_share)), pick[sel], side="right"),
                                   c.size - 1)
    shift = np.zeros(z.shape)
    for i in np.flatnonzero(comp >= 0):
        c, k = comps[which[i]], comp[i]
        t = c.epoch[k]
        shift[i, t] = c.shift[k] if plan.proposal != "scale" else (plan.scale - 1.0) * (c.parity[k] @ z[i, t])
    return ProposalDraw(comp, shift)


def log_weights(comps: list[Components], which: np.ndarray, plan, z: np.ndarray) -> np.ndarray:
    """(n,) ``log p/q`` of each trial's tilted draws ``z`` (n, T, S) under the mixture (module doc)."""
    n = z.shape[0]
    out = np.zeros(n)
    alpha = float(plan.defensive)
    for j, c in enumerate(comps):
        sel = np.flatnonzero(which == j)
        if sel.size == 0 or c.size == 0:
            continue  # no component: the trials were drawn from p (weight 1)
        if plan.proposal == "separation":  # K ~ 10⁵ tests: one epoch at a time
            mix = sampling_araim.shift_mixture_log_density(z[sel], c.epoch, c.shift, c.log_share)
            out[sel] = -(np.logaddexp(np.log(alpha), np.log1p(-alpha) + mix) if alpha > 0 else mix)
            continue
        zk = z[sel][:, c.epoch, :]  # (m, K, S)
        if plan.proposal == "shift":
            ell = np.einsum("mks,ks->mk", zk, c.shift) - 0.5 * np.einsum("ks,ks->k", c.shift, c.shift)
        else:
            s = float(plan.scale)
            pz = np.einsum("kst,mkt->mks", c.parity, zk)  # the draws' part in each parity space
            ell = -c.dof * np.log(s) + 0.5 * (1.0 - 1.0 / s**2) * np.einsum("mks,mks->mk", pz, pz)
        mix = (special.logsumexp(ell, axis=1) - np.log(c.size) if c.log_share is None
               else special.logsumexp(ell + c.log_share, axis=1))
        log_q = np.logaddexp(np.log(alpha), np.log1p(-alpha) + mix) if alpha > 0 else mix
        out[sel] = -log_q
    return out


@dataclass
class TiltedDraws:
    """One block's draws from the proposal: the tilted pseudorange errors, each trial's component (−1: the error
    model), and, when the proposal moves the camera's draws too, the ``tilt`` to hand
    :func:`~testbed.sim.pipeline.draw_vision` (it keeps the moved draws). :meth:`log_weight` after the draws."""

    gnss: object
    component: np.ndarray
    vision_tilt: TiltRecorder | None
    comps: list
    which: np.ndarray
    plan: object
    z_gnss: np.ndarray

    def log_weight(self) -> np.ndarray:
        """(n,) ``log p/q`` of each trial's moved draws, the pseudoranges' and the camera's in one vector per epoch
        (the camera's drawn through :attr:`vision_tilt` first)."""
        z = self.z_gnss
        if self.vision_tilt is not None:
            if self.vision_tilt.z is None:
                raise RuntimeError("TiltedDraws.log_weight: the camera's draws were not made through vision_tilt")
            z = np.concatenate([z, self.vision_tilt.z], -1)
        return log_weights(self.comps, self.which, self.plan, z)


def tilted_draws(ctx: CellContext, spec, errors, windows: np.ndarray | None, tree: StreamTree,
                 comps: list[Components] | None = None) -> TiltedDraws:
    """The block's draws from the proposal (:class:`TiltedDraws`): each trial's component from the block's
    ``sampling`` stream, its shift split between the pseudorange slots and the vision columns
    (:mod:`.sampling_vision`) of the monitor it is aimed from. ``comps``: the components per sky window (None:
    the cell's, :func:`cell_components`)."""
    comps = cell_components(ctx, spec, windows) if comps is None else comps
    n = errors.noise.shape[0]
    which = np.zeros(n, np.int64) if windows is None else np.searchsorted(np.unique(windows), windows)
    _, z0 = pipeline.tilt_gnss_errors(errors)  # the draws as drawn
    S = z0.shape[-1]
    cols = vision_columns(ctx, sampling_monitor(spec))
    if cols is not None:  # the camera's columns are drawn later; a shift does not read them
        z0 = np.concatenate([z0, np.zeros(z0.shape[:2] + (cols.size,))], -1)
    draw = draw_proposal(comps, which, spec.sampling, z0, tree.generator("sampling"))
    tilted, z = pipeline.tilt_gnss_errors(errors, draw.shift[..., :S])
    recorder = None if cols is None else TiltRecorder(cols, draw.shift[..., S:])
    return TiltedDraws(tilted, draw.component, recorder, comps, which, spec.sampling, z)


# ----------------------------------------------------------------------------- the adaptive step

#: the pilot's draw block: no campaign block reaches it (at most 10⁷ trials), so its draws are its own
PILOT_BLOCK = 2**40
#: a component's mean is refitted from at least this many effective elite trials (Kish), else kept
MIN_ELITE = 5.0


def cross_entropy_shifts(comps: Components, z: np.ndarray, log_weight: np.ndarray, elite: np.ndarray
                         ) -> Components:
    """``comps`` with each shift refitted by the cross-entropy method (Rubinstein & Kroese 2017, ch. 8) from a
    pilot's draws ``z`` (n, T, D), their ``log_weight`` (log p/q) and ``elite`` (n, K) (the trial's draws are in
    component k's event): the mean of a Gaussian family that minimises the cross-entropy to the zero-variance
    density ``p·1{event}/P`` is the event's conditional mean under ``p``, ``Σ w_i z_i / Σ w_i`` over the elite
    trials, read at the component's epoch. A component with fewer than :data:`MIN_ELITE` effective elite trials
    of its own (a pilot spread over many components) takes the pooled fit of one factor on every shift,
    ``c = Σ w_i (z_i·m_k)/|m_k|² / Σ w_i`` over all components' elite (how far along its own direction the
    event's mean lies, relative to the dominating point); with too few of those too, it keeps its dominating
    point. The shares are kept (every epoch's event stays covered)."""
    shift = comps.shift.copy()
    hit_i, hit_k = np.nonzero(elite)
    if hit_i.size == 0:
        return comps
    lw = log_weight[hit_i] - log_weight[hit_i].max()  # one scale for every elite trial (they are compared)
    along = np.einsum("id,id->i", z[hit_i, comps.epoch[hit_k], :], comps.shift[hit_k]) \
        / np.maximum(np.einsum("kd,kd->k", comps.shift, comps.shift)[hit_k], 1e-300)
    w = np.exp(lw)
    pooled = float(w @ along / w.sum()) if w.sum() ** 2 / np.sum(w**2) >= MIN_ELITE else None
    for k in range(comps.size):
        own = hit_k == k
        wk = np.exp(lw[own] - lw[own].max()) if own.any() else np.zeros(0)
        if wk.size and wk.sum() ** 2 / np.sum(wk**2) >= MIN_ELITE:
            shift[k] = wk @ z[hit_i[own], comps.epoch[k], :] / wk.sum()
        elif pooled is not None:
            shift[k] = pooled * comps.shift[k]
    return replace(comps, shift=shift)


def component_events(comps: Components, err: np.ndarray, alert: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(n, K) each trial's event of each component: at its epoch, a solution, no alert, and the error (n, T, 3)
    beyond the component's limit along its direction."""
    t = comps.epoch
    along = np.einsum("nkc,kc->nk", err[:, t, :], comps.direction)
    return ok[:, t] & ~alert[:, t] & (along > comps.limit)


def adapted_components(ctx: CellContext, spec, comps: Components) -> Components:
    """``comps`` refitted from a pilot run (``[sampling] adapt = "cross_entropy"``): ``pilot_trials`` sorties
    drawn from ``comps`` out of the pilot's own block (:data:`PILOT_BLOCK`, its streams apart from every
    campaign block's), the aimed monitor run on them, its events per component (:func:`component_events`) the
    elite of :func:`cross_entropy_shifts`. The pilot's sorties are not part of the estimate."""
    plan = spec.sampling
    name = sampling_monitor(spec)
    mon = next(m for m in ctx.setup.monitors if m.name == name)
    n = int(plan.pilot_trials)
    tree = StreamTree.of_block(spec.base_seed, ctx.cell.index, PILOT_BLOCK, False)
    errors = pipeline.gnss_errors(ctx.plan, ctx.g_geom, tree, n)
    d = tilted_draws(ctx, spec, errors, None, tree, comps=[comps])
    gnss, _ = pipeline.gnss_observations(ctx.g_geom, d.gnss, [])
    vision = None
    if "vision" in mon.inputs:
        vision, _ = pipeline.draw_vision(ctx.plan, ctx.v_geom, tree, n, [], tilt=d.vision_tilt)
    out, _ = mon.step(Observations(gnss, vision), mon.initial_state())
    err = np.asarray(out.pos_enu, float) - pipeline.reference_enu(mon, ctx.truth_ant_enu, ctx.truth_cg_enu)
    z = d.z_gnss if d.vision_tilt is None else np.concatenate([d.z_gnss, d.vision_tilt.z], -1)
    elite = component_events(comps, err, np.asarray(out.alert, bool), np.asarray(out.reason) == 0)
    return cross_entropy_shifts(comps, z, d.log_weight(), elite)


# ----------------------------------------------------------------------------- the estimates

@dataclass(frozen=True)
class Rate:
    """A weighted estimate of a rate (:func:`weighted_rate`)."""

    estimate: float
    se: float
    lo: float
    hi: float
    trials: int
    events: int  # trials with a non-zero numerator
    ess_weights: float  # Kish's effective sample size of the weights
    ess_events: float  # ... of the numerator's terms: the effective number of events
    largest_share: float  # the largest single trial's share of the estimate
    vov: float  # relative variance of the variance of the numerator's terms
    problems: tuple[str, ...]  # why no rate is printed (empty: settled)

    @property
    def settled(self) -> bool:
        return not self.problems

    def text(self, fmt: str = "{:.3g}") -> str:
        """The estimate with its interval, or why there is none."""
        if self.problems:
            return "no rate: " + "; ".join(self.problems)
        return f"{fmt.format(self.estimate)} [{fmt.format(self.lo)}, {fmt.format(self.hi)}]"


def weighted_rate(num: np.ndarray, den: np.ndarray | float, log_weight: np.ndarray, confidence: float = 0.95
                  ) -> Rate:
    """``E_p[num] / E_p[den]`` from trials drawn with ``log_weight = log p/q`` (all 0: plain sampling).

    A denominator that is the same for every trial (an indicator's 1, a sortie's epochs) is exact; one that
    varies is estimated too (the ratio estimator, its variance by the delta method). The interval is the
    normal one at ``confidence``, its lower end at 0 at least. A rate whose diagnostics fail (module doc),
    or whose event no trial reached, carries its ``problems`` instead of being printed.
    """
    num = np.asarray(num, float)
    lw = np.asarray(log_weight, float)
    den = np.broadcast_to(np.asarray(den, float), num.shape)
    n = num.size
    hit = num != 0
    events = int(hit.sum())
    if n == 0 or not (den > 0).any():
        return Rate(np.nan, np.nan, np.nan, np.nan, n, events, np.nan, np.nan, np.nan, np.nan, ("no trials",))
    w_all = np.exp(lw - lw.max())
    ess_w = float(w_all.sum() ** 2 / np.sum(w_all**2))
    if events == 0:
        return Rate(0.0, 0.0, 0.0, np.nan, n, 0, ess_w, 0.0, np.nan, np.nan,
                    (f"no event in {n} trials{' under the proposal' if lw.any() else ''}",))
    z = stats.norm.ppf(0.5 + confidence / 2)
    if np.all(den == den.flat[0]):  # an exact denominator: the weights scaled by the largest event's
        c = float(lw[hit].max())  # (they reach 1e-300 and below; the event's terms keep their digits)
        f = np.exp(np.where(hit, lw - c, -np.inf)) * num / float(den.flat[0])  # a non-event's e^(lw-c) may overflow
        est = f.mean() * np.exp(c)
        se = (f.std(ddof=1) / np.sqrt(n) if n > 1 else np.inf) * np.exp(c)
    else:  # a ratio of two weighted means (free of the common factor)
        c, w = 0.0, w_all
        f, g = w * num, w * den
        est = f.sum() / g.sum()
        se = np.std(f - est * g, ddof=1) / np.sqrt(n) / g.mean() if n > 1 else np.inf
    ess_e = float(f.sum() ** 2 / np.sum(f**2))
    share = float(np.abs(f).max() / np.abs(f).sum())
    dev = f - f.mean()
    m2 = np.sum(dev**2)
    vov = float(np.sum(dev**4) / m2**2 - 1.0 / n) if m2 > 0 else 0.0
    problems = []
    if not est > 0 and f.sum() > 0:  # the scaled terms kept their digits, the scale did not: say its size
        log10 = (np.log(f.mean()) + c) / np.log(10.0)
        problems.append(f"the estimate, 10^{log10:.1f}, is below the floating-point range")
    if ess_e < MIN_EFFECTIVE_EVENTS:
        problems.append(f"{ess_e:.1f} effective events (< {MIN_EFFECTIVE_EVENTS:g})")
    if share > MAX_LARGEST_SHARE:
        problems.append(f"one trial carries {100 * share:.0f} % of the estimate (> {100 * MAX_LARGEST_SHARE:g} %)")
    if vov > MAX_VOV:
        problems.append(f"variance of the variance {vov:.2f} (> {MAX_VOV:g}): the variance has not settled")
    return Rate(float(est), float(se), float(max(est - z * se, 0.0)), float(est + z * se), n, events, ess_w, ess_e,
                share, vov, tuple(problems))
