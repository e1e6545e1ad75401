"""The DPE's K fitted where its tail is *measured* at P_HMI, by importance sampling (docs/design/dpe.md §6.8).

The tail estimator (:func:`~testbed.integrity.dpe.calibration.fit_k_tail`) measures the normalised error's
tails down to ~100/N and extrapolates to P = 10⁻⁷ under a Gaussian assumption; measuring 10⁻⁷ by brute force
takes ~10⁹ epochs. Here an epoch's draws are aimed at large vertical errors. Its vertical error moves with the
per-satellite signal-in-space draws ``ε = σ_SIS·u`` (``u ~ N(0, I)``, white from epoch to epoch) through the
DPE's CRB weighting ``A_U`` (``A = J Gᵀ W``, docs/design/dpe.md eq. 5.6), and with each satellite's thermal
noise along the one direction of its correlator draws that moves the correlogram as a later delay does
(:func:`delay_directions`, a delay error of CRB σ_δ). :func:`aim` gives the unit gradient ``h`` over both kinds
of whitened draw, and ``π = h·(u, x) ~ N(0, 1)`` is the draws' projection on it: the thousands of other
correlator draws stay plain, and the likelihood ratio is that of one Gaussian coordinate.

Each epoch draws one component of a mixture on π (shifts ``±ℓ`` for the levels of :data:`LEVELS`) or, with
probability ``defensive``, none (the error model itself). With a ground echo, ``z ≈ b + π``: the echo moves an
epoch's solution by a bias ``b`` (up to ~1 σ at low height) that the draws do not set and the median ``m`` does
not remove; it is the DPE's error on the epoch's expected correlograms (:func:`echo_bias`), and the components
sit at ``±ℓ − b``. An echo stratum's tail is carried by its few epochs of largest ``|b|``, so an epoch is drawn
:func:`copies` times, in proportion to its expected share of the tail, each copy with 1/copies of its weight.
Each draw's weight is its projection's likelihood ratio (the campaign sampler's
:func:`~testbed.campaign.sampling.log_weights`); an epoch's copies are summed into one term, and the rates are
:func:`~testbed.campaign.sampling.weighted_rate` over the epochs, with its diagnostics.

K is the smallest factor on a 0.005 grid at which the weighted estimate of P(|e| > K·σ + |m|) per epoch with a
solution is settled and the upper end of its interval is at most P, in every C/N0 × multipath stratum; K is
the largest of those. The held-out check estimates the same rate at that K on another set of sorties (other
seeds, other start times), per stratum and over all: it passes when every estimate is settled and at most P.

**Assumption**: an epoch's outcome depends on its own draws (the DPE starts from the same-epoch GPS fix; the
previous DPE fix, a function of earlier draws, is used only when that fails).
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import importlib.metadata
import subprocess
from pathlib import Path
from typing import Any, Callable

import numpy as np
from scipy import special
from scipy.special import ndtri

from testbed.campaign.sampling import Components, Rate, draw_proposal, log_weights, weighted_rate
from testbed.campaign.spec import SamplingPlan
from testbed.heap import keep_freed_memory
from testbed.integrity.dpe.calibration import DEFAULT_P_HMI, settings_fingerprint
from testbed.monitors import monitor_options
from testbed.pool import WorkerPool
from testbed.studies.dpe_calibration import (CN0_OFFSETS_DB, MULTIPATH, CalibrationRun, calibration_run, chunk_sorties,
                                             run_provenance, vdop)
from testbed.threads import sleep_idle_threads

#: the mixture's levels ℓ (in σ of the epoch's VPL): the tail is measured from ~4 σ to ~7 σ
LEVELS = (4.5, 5.5, 6.5)
DEFENSIVE = 0.1
#: the K grid the tail is read on, and the interval's confidence (two-sided normal: its upper end is 97.5 %)
K_STEP = 0.005
K_RANGE = (2.0, 20.0)
CONFIDENCE = 0.95
ASSUMPTION = ("the tail is measured, not extrapolated: importance sampling of each epoch's SIS draws and its "
              "correlator draws along the satellites' delay directions (the other correlator draws plain); an "
              "epoch's outcome depends on its own draws (white SIS and correlator noise; the previous DPE fix is "
              "used only when the same-epoch GPS fix fails)")


def plan(defensive: float = DEFENSIVE) -> SamplingPlan:
    """The mixture's plan in the campaign sampler's terms: mean shifts, a defensive share, uniform components
    (a defensive share near 1 draws every epoch from the error model: plain sampling, weights ~1)."""
    return SamplingPlan(method="importance", proposal="shift", defensive=defensive)


def vertical_response(los_enu: np.ndarray, cn0_dbhz: np.ndarray, visible: np.ndarray, coherent_s: float,
                      n_blocks: int, bandwidth_chips: float) -> tuple[np.ndarray, np.ndarray]:
    """Per epoch, the DPE's vertical error per metre of each satellite's delay ``A_U`` (T, S) and the delays'
    CRB σ_δ (T, S), from its CRB weighting at the true C/N0 (docs/design/dpe.md eq. 2.13-2.14, 5.6); zero
    where an epoch has fewer than four satellites in view."""
    from testbed.correlation import amplitude_sq, crb_delay_sigma

    T, S, _ = los_enu.shape
    a_u, sd = np.zeros((T, S)), np.zeros((T, S))
    for t in range(T):
        k = np.flatnonzero(visible[t])
        if k.size < 4:
            continue
        g = np.concatenate([-los_enu[t, k], np.ones((k.size, 1))], 1)
        sd[t, k] = crb_delay_sigma(amplitude_sq(cn0_dbhz[t, k], coherent_s), n_blocks, bandwidth_chips)
        w = 1.0 / sd[t, k] ** 2
        a_u[t, k] = (np.linalg.inv(g.T @ (g * w[:, None])) @ (g * w[:, None]).T)[2]
    return a_u, sd


def aim(a_u: np.ndarray, sigma_sis: np.ndarray, sigma_delay: np.ndarray, thermal: bool = True
        ) -> tuple[np.ndarray, np.ndarray]:
    """The unit direction of the vertical error's gradient in each epoch's whitened draws, split into its SIS
    part ``h_sis`` (T, S) (per standard SIS draw) and its thermal part ``h_noise`` (T, S) (per unit whitened
    shift along a satellite's delay direction); zero rows where the epoch has no response. ``thermal=False``:
    the SIS alone (the thermal noise drawn plainly)."""
    gs = a_u * sigma_sis
    gn = a_u * sigma_delay if thermal else np.zeros_like(a_u)
    norm = np.sqrt((gs * gs).sum(1) + (gn * gn).sum(1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norm[:, None] > 0, gs / norm[:, None], 0.0), np.where(norm[:, None] > 0, gn / norm[:, None], 0.0)


def epoch_components(has_response: np.ndarray, levels: tuple[float, ...] = LEVELS,
                     bias: np.ndarray | None = None) -> list[Components]:
    """One :class:`Components` per epoch on the one-dimensional projection π of its draws on the aimed direction
    (π ~ N(0, 1) under the error model): the shifts ±ℓ − b of :data:`LEVELS`, b the epoch's ``bias`` (T,) in σ
    (None: 0), so that the component meets the event ``|b + π| > ℓ`` on either side; none where the epoch has no
    response."""
    level = np.array([sg * lv for lv in levels for sg in (1.0, -1.0)])
    b = np.zeros(len(has_response)) if bias is None else np.asarray(bias, float)
    n = level.size
    empty = Components(np.zeros(0, np.int64), np.zeros((0, 1)), np.zeros((0, 1, 1)), np.zeros(0, np.int64))
    return [Components(np.zeros(n, np.int64), (level - bt)[:, None], np.zeros((n, 1, 1)), np.zeros(n, np.int64))
            if h else empty for h, bt in zip(has_response, b)]


def tilted_projection_shifts(comps: list[Components], which: np.ndarray, rng: np.random.Generator,
                             defensive: float = DEFENSIVE) -> tuple[np.ndarray, np.ndarray]:
    """Each epoch's component (−1: the error model) and the shift of its projection π (n,)."""
    draw = draw_proposal(comps, which, plan(defensive), np.zeros((which.size, 1, 1)), rng)
    return draw.component, draw.shift[:, 0, 0]


def epoch_log_weights(comps: list[Components], which: np.ndarray, pi: np.ndarray, defensive: float = DEFENSIVE
                      ) -> np.ndarray:
    """(n,) log p/q of each epoch's projection ``pi`` (n,), as tilted."""
    return log_weights(comps, which, plan(defensive), np.asarray(pi, float)[:, None, None])


def delay_directions(K: np.ndarray, spec, A: np.ndarray, delay: np.ndarray, grid, n_blocks: int,
                     bandwidth_chips: float, echo_delay: np.ndarray | None = None) -> np.ndarray:
    """(S, 2, L) unit (complex norm 1) directions of the standard draws of the processes U that move each
    satellite's correlogram as a later code delay does (docs/design/dpe.md §6.8). A delay ε moves the direct
    path and its echo together, so the signal term A²·RᵀHR (R = (R_B(δ − δ_k), R_B(δ − δ_k − Δ)), H the paths'
    Gram matrix) changes by −2εA²·RᵀHR′, which the cross term 2A·Re(RᵀV) reproduces with ΔV = −εA·H·R′;
    through V = K U this is ΔU = K⁺ΔV, uncoloured. Without an echo (H = diag(N_b, 0)) this is the direct path's
    ΔV₀ = −εA·N_b·R_B′ alone. ``echo_delay`` (S,): Δ of each satellite (None: no echo)."""
    from testbed.sensors.gnss.correlators import tabulated_correlation

    L = spec.amplitude.size
    j = np.arange(L)
    off = grid.delay0_m + grid.step_m * np.where(j < grid.size + (L - grid.size) // 2, j, j - L)  # periodic grid
    x = off[None, :] - delay[:, None]
    echo = np.zeros(delay.size) if echo_delay is None else np.asarray(echo_delay, float)
    h = 0.25
    d_r = np.stack([(tabulated_correlation(y + h, bandwidth_chips) - tabulated_correlation(y - h, bandwidth_chips))
                    / (2 * h) for y in (x, x - echo[:, None])], 1)  # (S, 2, L): R′ of the direct path, of the echo
    H = np.einsum("sij,skj->sik", K, np.conj(K))
    dv = -A[:, None, None] * np.einsum("sij,sjl->sil", H, d_r)
    du = np.einsum("sij,sjl->sil", np.linalg.pinv(K), dv)
    amp = spec.amplitude
    keep = amp > 1e-9 * amp.max()
    dz = np.where(keep, np.fft.ifft(du, axis=-1) / np.where(keep, amp, 1.0), 0.0)
    norm = np.sqrt((np.abs(dz) ** 2).sum((1, 2)))
    return dz / np.where(norm > 0, norm, 1.0)[:, None, None]


class _NoiseTilt:
    """The thermal part of one sortie's tilt (``synthesize_correlators``' ``noise_tilt``): per epoch, the shift
    ``c·h_noise,k/√2`` of satellite k's standard draws along its delay direction, and the draws' projection
    ``√2·Re⟨e_k, z_k⟩`` weighted by ``h_noise,k`` summed into ``pi_noise``."""

    def __init__(self, shift: np.ndarray, h_noise: np.ndarray, correlators) -> None:
        self.c, self.h, self.cs = shift, h_noise, correlators
        self.pi_noise = np.zeros(shift.size)

    def __call__(self, i: int, k: np.ndarray, A: np.ndarray, delay: np.ndarray, grid, echo_delay: np.ndarray):
        if not np.any(self.h[i, k]):
            return None
        h = self.h[i, k]
        outer = self

        class One:
            def shift(self, K, spec):
                self.e = delay_directions(K, spec, A, delay, grid, outer.cs.n_noncoherent, outer.cs.bandwidth_chips,
                                          echo_delay)
                return outer.c[i] * h[:, None, None] * self.e / np.sqrt(2.0)

            def seen(self, z):
                proj = np.sqrt(2.0) * np.real(np.sum(np.conj(self.e) * z, axis=(1, 2)))
                outer.pi_noise[i] = float(h @ proj)

        return One()


def sortie(ap, setup, truth_g, mon, offset_s: float, cn0_db: float, multipath: str, key: tuple[int, int],
           seed: int, thermal: bool = True, levels: tuple[float, ...] = LEVELS, defensive: float = DEFENSIVE
           ) -> dict[str, np.ndarray]:
    """One importance-sampled sortie: per trial with a solution z, e, σ, m, the log weight, the component, the
    projection π of its draws, its epoch's echo bias and its epoch; the unsolved trials' log weights. Every epoch
    is a trial; an epoch whose echo bias makes it weigh more is drawn :func:`copies` times, each copy with its
    own draws and 1/copies of its weight (module doc). ``defensive`` near 1: every epoch drawn from the error
    model (plain sampling)."""
    from testbed.sensors.gnss.correlators import cn0_at, sis_sigma

    # the first two: the plain run's; the fourth: the copies' (spawning four leaves the first three as they were)
    g_gnss, g_corr, g_sampling, g_copies = np.random.SeedSequence(seed, spawn_key=key).spawn(4)
    gs, g, gt = sortie_sky(ap, setup, truth_g, offset_s, cn0_db, multipath, g_gnss)
    cs = gs.correlators
    vis = np.asarray(g.visible, bool)
    el = np.asarray(gt.elevation, float)
    ant = np.asarray(gt.antenna_pos_ecef, float)
    los = np.asarray(g.sat_pos_ecef, float) - ant[:, None, :]
    los_enu = setup.frame.vec_ecef_to_enu(los / np.linalg.norm(los, axis=-1, keepdims=True))
    sig = sis_sigma(el, gs)
    a_u, sd = vertical_response(los_enu, cn0_at(el, cs), vis, cs.coherent_s, cs.n_noncoherent, cs.bandwidth_chips)
    h_sis, h_noise = aim(a_u, np.where(vis, sig, 0.0), sd, thermal and cs.synthesis == "fast")
    bias = echo_bias(mon, g, gt, truth_g, gs, setup.frame) if multipath != "off" else np.zeros(vis.shape[0])
    n = copies(bias)
    ep = _Epochs(g, gt, truth_g, gs, mon, setup.frame, sig, h_sis, h_noise, bias, n, levels, defensive,
                 vdop(setup.frame, np.asarray(g.sat_pos_ecef, float), vis, ant))
    parts = [_tilted_draws(ep, np.arange(vis.shape[0]), g_corr, g_sampling)]
    for r, stream in enumerate(g_copies.spawn(int(n.max()) - 1), start=1):
        g_c, g_s = stream.spawn(2)
        parts.append(_tilted_draws(ep, np.flatnonzero(n > r), g_c, g_s))
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def sortie_sky(ap, setup, truth_g, offset_s: float, cn0_db: float, multipath: str, g_gnss: np.random.SeedSequence):
    """A sortie's GNSS settings (its C/N0 offset and multipath), epochs and their truth, drawn from ``g_gnss``."""
    from testbed.sensors.gnss.synth import gnss_geometry, sample_gnss

    cs = setup.gnss.correlators.model_copy(update={"cn0_offset_db": setup.gnss.correlators.cn0_offset_db + cn0_db,
                                                   "multipath": multipath})
    gs = setup.gnss.model_copy(update={"correlators": cs})
    start = ap.config.start_time_utc + dt.timedelta(seconds=offset_s)
    geom = gnss_geometry(truth_g, setup.antenna, gs, start_utc=start, terrain=setup.terrain)
    g, gt = sample_gnss(geom, gs, rng=np.random.default_rng(g_gnss))
    return gs, g, gt


#: the copies of an epoch (:func:`copies`): its expected share of the tail at K ≈ :data:`COPY_K` (the measured K
#: without an echo) against an unbiased epoch's, one copy per :data:`SHARE_PER_COPY`, at most :data:`MAX_COPIES`
COPY_K = 5.3
SHARE_PER_COPY = 1.0
MAX_COPIES = 64


def copies(bias: np.ndarray) -> np.ndarray:
    """(T,) how many times each epoch is drawn: ⌈r⌉ in 1..64, r = (Q(K − |b|) + Q(K + |b|))/(2 Q(K)) at
    K = 5.3 the factor by which its echo bias b raises its tail. The tail of an echo stratum is an average over
    epochs of which the few of largest |b| carry most (|b| ~ 1: r ~ 70); one draw each leaves their estimate,
    and the stratum's, to a few events. Drawing an epoch m times with weights 1/m each keeps the estimate
    unbiased (Neyman's allocation: copies in proportion to the epoch's share)."""
    b = np.abs(np.asarray(bias, float))
    share = (special.ndtr(b - COPY_K) + special.ndtr(-b - COPY_K)) / (2.0 * special.ndtr(-COPY_K))
    return np.clip(np.ceil(share / SHARE_PER_COPY), 1, MAX_COPIES).astype(np.int64)


@dataclasses.dataclass(frozen=True)
class _Epochs:
    """What a sortie's draws are made and judged on, per epoch: its observations' records, the monitor, the SIS
    σ, the aimed directions, the echo bias, the copies, the mixture's levels and defensive share, and the VDOP."""

    gnss: Any
    gnss_truth: Any
    truth: Any
    settings: Any
    mon: Any
    frame: Any
    sigma_sis: np.ndarray
    h_sis: np.ndarray
    h_noise: np.ndarray
    bias: np.ndarray
    copies: np.ndarray
    levels: tuple[float, ...]
    defensive: float
    vdop: np.ndarray


def _tilted_draws(ep: _Epochs, idx: np.ndarray, g_corr: np.random.SeedSequence, g_sampling: np.random.SeedSequence
                  ) -> dict[str, np.ndarray]:
    """One tilted draw of epochs ``idx`` (every epoch, or those drawn again) from the streams given."""
    from testbed.integrity.monitor import Observations
    from testbed.records import take_epochs
    from testbed.sensors.gnss.correlators import synthesize_correlators

    every = idx.size == ep.bias.size
    g, gt, truth = ((ep.gnss, ep.gnss_truth, ep.truth) if every else
                    (take_epochs(ep.gnss, idx), take_epochs(ep.gnss_truth, idx), take_epochs(ep.truth, idx)))
    vis = np.asarray(g.visible, bool)
    h_sis, h_noise = ep.h_sis[idx], ep.h_noise[idx]
    has = (np.abs(h_sis).sum(1) + np.abs(h_noise).sum(1)) > 0
    comps = epoch_components(has, ep.levels, ep.bias[idx])
    which = np.arange(idx.size)
    comp, c = tilted_projection_shifts(comps, which, np.random.default_rng(g_sampling), ep.defensive)
    tilt = _NoiseTilt(c, h_noise, ep.settings.correlators)
    corr, ct = synthesize_correlators(g, gt, truth, ep.settings, g_corr.generate_state(4), sis_shift=c[:, None] * h_sis,
                                      noise_tilt=tilt if np.any(h_noise) else None)
    sig = ep.sigma_sis[idx]
    u = np.where(vis, np.nan_to_num(np.asarray(ct.sis_m, float)) / sig, 0.0)  # the standard SIS draws, as tilted
    pi = (h_sis * u).sum(1) + tilt.pi_noise
    lw = epoch_log_weights(comps, which, pi, ep.defensive) - np.log(ep.copies[idx])
    e, sigma, m, ok = vertical_solution(ep.mon, Observations(g, correlators=corr), ep.frame,
                                        np.asarray(gt.antenna_pos_ecef, float))
    return {"z": ((e - m) / sigma)[ok], "e": e[ok], "sigma": sigma[ok], "m": m[ok],
            "log_weight": lw[ok], "component": comp[ok].astype(np.int16), "pi": pi[ok], "bias": ep.bias[idx][ok],
            "epoch": idx[ok], "vdop": ep.vdop[idx][ok], "unsolved_log_weight": lw[~ok], "unsolved_epoch": idx[~ok]}


def vertical_solution(mon, obs, frame, ant_ecef: np.ndarray) -> tuple[np.ndarray, ...]:
    """The DPE on one sortie's observations: per epoch the vertical error e, the σ its VPL scales, the median
    offset m and whether it solved (T,) each."""
    out, _ = mon.step(obs, mon.initial_state())
    d = out.diagnostics
    e = out.pos_enu[:, 2] - frame.ecef_to_enu(ant_ecef)[:, 2]
    sigma = np.hypot(d.sigma_ob, d.sigma_sis_u) if mon.settings.sis == "add" else d.sigma_ob
    return e, sigma, d.median_m, out.reason == 0


def echo_bias(mon, g, gt, truth_g, gs, frame) -> np.ndarray:
    """(T,) the ground echo's bias of z per epoch, b = (e₀ − m₀)/σ₀ of the DPE on the epoch's *expected*
    correlograms (no SIS error, no thermal draw: the signal, its echo and the noise's power); 0 where that
    solution fails. The echo's amplitude, delay and phase follow from the truth, so b is fixed by the geometry
    and known before the draws: the proposal may centre on it (module doc)."""
    from testbed.integrity.monitor import Observations
    from testbed.sensors.gnss.correlators import synthesize_correlators

    corr, _ = synthesize_correlators(g, gt, truth_g, gs, np.zeros(4, np.uint32), expected=True)
    e, sigma, m, ok = vertical_solution(mon, Observations(g, correlators=corr), frame,
                                        np.asarray(gt.antenna_pos_ecef, float))
    return np.where(ok, (e - m) / np.where(ok, sigma, 1.0), 0.0)


#: the seed streams' set keys: the plain calibration's sets are 0 and 1, these are other streams
SET_KEYS = {"calibration": 2, "validation": 3}


def measured_chunk(run: CalibrationRun, set_key: int, chunk: int) -> dict[str, np.ndarray]:
    """One chunk of sorties of a set, in sortie order (a pure function of (run, set, chunk))."""
    parts = []
    sorties = chunk_sorties(run, set_key, chunk, set_key != SET_KEYS["calibration"], sortie)
    for i, (one, stratum, _) in enumerate(sorties):
        one["stratum"] = np.full(one["z"].size, stratum, np.int8)
        one["unsolved_stratum"] = np.full(one["unsolved_log_weight"].size, stratum, np.int8)
        for k in ("epoch", "unsolved_epoch"):  # unique in the set: the sortie's number, then its epoch
            one[k] = (chunk * run.chunk + i) * EPOCH_STRIDE + one[k]
        parts.append(one)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _chunk_job(run: CalibrationRun, set_key: int, chunk: int) -> dict[str, np.ndarray]:
    """A chunk on a worker process, which runs nothing but these (process settings as the command's)."""
    keep_freed_memory()
    sleep_idle_threads()
    return measured_chunk(run, set_key, chunk)


def run_sets(run: CalibrationRun, workers: int = 1, progress: Callable[[str], None] | None = None
             ) -> dict[str, dict[str, np.ndarray]]:
    """Both sets' per-epoch arrays; chunks on ``workers`` processes (the result does not depend on them)."""
    say = progress or (lambda _: None)
    jobs = [(run, SET_KEYS[name], c) for name in SET_KEYS for c in range(run.n_chunks)]
    got: list = [None] * len(jobs)
    if workers <= 1:
        for i, j in enumerate(jobs):
            got[i] = measured_chunk(*j)
            say(f"{i + 1}/{len(jobs)} chunks of {run.chunk} sorties")
    else:  # the chunks in the order they finish, each put in its place
        with WorkerPool(min(workers, len(jobs))) as pool:  # no more processes than chunks
            for i, (j, res) in enumerate(pool.unordered(_chunk_job, enumerate(jobs))):
                got[j] = res
                say(f"{i + 1}/{len(jobs)} chunks of {run.chunk} sorties")
    out = {}
    for n, name in enumerate(SET_KEYS):
        mine = got[n * run.n_chunks:(n + 1) * run.n_chunks]
        out[name] = {k: np.concatenate([p[k] for p in mine]) for k in mine[0]}
    return out


#: the epoch ids of a set: sortie number × this + the epoch's index in its sortie
EPOCH_STRIDE = 1_000_000


def epoch_units(epoch: np.ndarray, epoch_unsolved: np.ndarray) -> np.ndarray:
    """Each trial's epoch as 0..U−1 (the solved trials', then the unsolved ones'), from their ids."""
    return np.unique(np.concatenate([epoch, epoch_unsolved]), return_inverse=True)[1].ravel()


def hmi_rate(t: np.ndarray, lw: np.ndarray, lw_unsolved: np.ndarray, k: float, unit: np.ndarray | None = None
             ) -> Rate:
    """P(|e| > k·σ + |m|) per epoch with a solution: ``t = (|e| − |m|)/σ`` of the solved trials; the unsolved
    ones enter the ratio's denominator with zero (a ratio of two weighted means). ``unit``: each trial's epoch
    (:func:`epoch_units`) where epochs are drawn more than once (:func:`copies`): an epoch's copies are summed
    into one term, the unit the interval and the diagnostics count (None: each trial an epoch of its own)."""
    num = np.concatenate([(t > k).astype(float), np.zeros(lw_unsolved.size)])
    den = np.concatenate([np.ones(t.size), np.zeros(lw_unsolved.size)])
    lw_all = np.concatenate([lw, lw_unsolved])
    if unit is None:
        return weighted_rate(num, den, lw_all, CONFIDENCE)
    w = np.exp(lw_all - lw_all.max())  # the ratio is free of the common factor
    n = int(unit.max()) + 1 if unit.size else 0
    return weighted_rate(np.bincount(unit, w * num, n), np.bincount(unit, w * den, n), np.zeros(n), CONFIDENCE)


@dataclasses.dataclass(frozen=True)
class MeasuredK:
    """K at a measured tail: the smallest grid K whose rate is settled with its upper end ≤ P (None: no such K
    before the estimate stopped settling: the tail is not measured that deep), the rate there, and the deepest
    settled upper end reached."""

    k: float | None
    rate: Rate | None
    deepest_hi: float
    p_hmi: float


def fit_k_measured(t: np.ndarray, lw: np.ndarray, lw_unsolved: np.ndarray, p_hmi: float,
                   unit: np.ndarray | None = None) -> MeasuredK:
    """:class:`MeasuredK` of one set (module doc). The grid is walked upwards in steps of 20 grid steps, then the
    step that crossed one grid step at a time, to the first K whose rate's upper end is at most P; the tail is
    measured there only if that rate is settled (a K further up, where a few events happen to settle a far
    smaller rate, is not a measurement at P)."""
    deepest = np.inf

    def at(k: float) -> Rate:
        nonlocal deepest
        r = hmi_rate(t, lw, lw_unsolved, k, unit)
        if r.settled:
            deepest = min(deepest, r.hi)
        return r

    def below(r: Rate) -> bool:
        return r.events > 0 and r.hi <= p_hmi

    coarse = 20 * K_STEP
    lo = K_RANGE[0]
    while lo <= K_RANGE[1]:
        r = at(lo)
        if r.events == 0:
            break
        if below(r):
            k = max(K_RANGE[0], lo - coarse)
            while k < lo - K_STEP / 2:  # the first grid K in the step that crossed
                k = round(k + K_STEP, 9)
                r2 = at(k)
                if below(r2) or r2.events == 0:
                    r, lo = r2, k
                    break
            if r.settled and r.events > 0:
                return MeasuredK(float(round(lo, 6)), r, deepest, p_hmi)
            break
        lo = round(lo + coarse, 9)
    return MeasuredK(None, None, float(deepest), p_hmi)


def _tail(d: dict[str, np.ndarray], solved=slice(None), unsolved=slice(None)) -> dict[str, np.ndarray | None]:
    """:func:`hmi_rate`'s arrays of a set's trials ``solved`` and ``unsolved`` (masks): the threshold
    ``t = (|e| − |m|)/σ``, the log weights and each trial's epoch (None: a set without epoch ids)."""
    unit = epoch_units(d["epoch"][solved], d["unsolved_epoch"][unsolved]) if "epoch" in d else None
    return {"t": ((np.abs(d["e"]) - np.abs(d["m"])) / d["sigma"])[solved], "lw": d["log_weight"][solved],
            "lw_unsolved": d["unsolved_log_weight"][unsolved], "unit": unit}


def weighted_median(x: np.ndarray, lw: np.ndarray) -> float:
    """The median of ``x`` under the weights exp(lw) (the error model's median of z)."""
    o = np.argsort(x)
    w = np.exp(lw[o] - lw.max())
    c = np.cumsum(w)
    return float(x[o][np.searchsorted(c, 0.5 * c[-1])])


def _commit() -> str:
    """The source's commit, ``-dirty`` when the checkout has uncommitted changes (the record is then not
    reproducible from the commit alone); "unknown" outside a git checkout."""
    try:
        return subprocess.run(["git", "describe", "--always", "--dirty", "--abbrev=7"], cwd=Path(__file__).parent,
                              capture_output=True, text=True, timeout=10).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _version() -> str:
    try:
        return importlib.metadata.version("testbed")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _rate_record(r: Rate | None) -> dict:
    if r is None:
        return {"estimate": None}
    return {"estimate": r.estimate, "interval": [r.lo, r.hi], "settled": r.settled, "problems": list(r.problems),
            "effective_events": r.ess_events, "ess_weights": r.ess_weights, "trials": r.trials, "events": r.events}


def calibrate_dpe_measured(approach: str | Path = "zunz-rwy05-dpe", *, sorties: int = 600,
                           p_hmi: float = DEFAULT_P_HMI, seed: int = 0, trajectories: tuple[str | Path, ...] = (),
                           chunk: int = 25, workers: int = 1, progress: Callable[[str], None] | None = None,
                           sets: dict | None = None) -> dict[str, Any]:
    """Fit K at a measured tail on ``sorties`` importance-sampled sorties and check it on as many held-out ones
    (module doc). Returns the K record (the tail estimator's schema plus the provenance of the measurement).
    ``sets``: the two sets' arrays of this run measured before (:func:`run_sets`), to fit again without flying."""
    from testbed.config import load_approach

    run = calibration_run(approach, trajectories, sorties, seed, chunk, p_hmi)
    src = run.approach
    names = run.trajectories or (src,)
    ap = load_approach(src)
    fingerprint, cover = settings_fingerprint(
        monitor_options("dpe", ap.config.monitor).model_copy(update={"k_factor": 1.0}), ap.config.gnss.correlators)
    sets = run_sets(run, workers, progress) if sets is None else sets
    c, v = sets["calibration"], sets["validation"]

    def strata_of(d):
        return {f"cn0 {CN0_OFFSETS_DB[s % 3]:+g} dB, multipath {MULTIPATH[s // 3]}":
                (d["stratum"] == s, d["unsolved_stratum"] == s) for s in range(6)}

    overall = fit_k_measured(**_tail(c), p_hmi=p_hmi)
    fits = {n: fit_k_measured(**_tail(c, m, mu), p_hmi=p_hmi) for n, (m, mu) in strata_of(c).items()}
    unmeasured = [n for n, f in fits.items() if f.k is None] + (["all strata"] if overall.k is None else [])
    if unmeasured:
        k, k_from, chosen = None, "", None
    else:
        k_from, chosen = max(fits.items(), key=lambda kv: kv[1].k)
        k = max(chosen.k, overall.k)
        if overall.k >= chosen.k:
            k_from, chosen = "all strata", overall
        else:
            k_from = f"stratum '{k_from}'"
    checks = {}
    if k is not None:
        checks["all strata"] = hmi_rate(**_tail(v), k=k)
        for n, (m, mu) in strata_of(v).items():
            checks[n] = hmi_rate(**_tail(v, m, mu), k=k)
    passed = bool(checks) and all(r.settled and r.estimate <= p_hmi for r in checks.values())
    b_z = weighted_median(c["z"], c["log_weight"])
    q = float(-ndtri(p_hmi / 2.0))
    lw_all = np.concatenate([c["log_weight"], c["unsolved_log_weight"]])
    w = np.exp(lw_all - lw_all.max())
    spacing = 86400.0 / sorties
    ess = float(w.sum() ** 2 / np.sum(w * w))
    rec = {
        "what": "K of the dpe monitor's VPL = K*sigma + |median| (testbed calibrate-dpe --method importance)",
        "k": k, "sigma_z": None if k is None else (k - abs(b_z)) / q, "b_z": b_z, "p_hmi": p_hmi,
        "estimator": "importance",
        "binding": {"side": "both", "tail_level": None if chosen is None else chosen.rate.hi},
        "k_from": k_from,
        "overall": {"k": overall.k, "rate": _rate_record(overall.rate), "deepest_settled_upper": overall.deepest_hi},
        "strata": {n: {"k": f.k, "rate": _rate_record(f.rate), "deepest_settled_upper": f.deepest_hi,
                       "n": int(strata_of(c)[n][0].sum())} for n, f in fits.items()},
        "n": int(c["z"].size), "n_eff": ess, "n_calibration": int(c["z"].size),
        "deepest_level": None if chosen is None else chosen.rate.hi,
        "interval": None if chosen is None else [chosen.rate.lo, chosen.rate.hi],
        "trials": int(c["z"].size + c["unsolved_log_weight"].size),
        "method": "importance sampling of the SIS and thermal draws along the DPE's vertical response, per "
                  "epoch (docs/design/dpe.md §6.8)",
        "proposal": {"kind": "mean shift of the standard SIS and thermal draws along the DPE's vertical response, "
                             "per epoch", "levels": list(LEVELS),
                     "shift": "pi ~ N(+-level - b, 1), pi the draws' projection on the aimed direction", "centre": "-b, b = (e0 - m0)/sigma0 of the DPE on "
                     "the epoch's expected correlograms (ground-echo strata; 0 without an echo)",
                     "copies": f"ceil(r/{SHARE_PER_COPY:g}) in 1..{MAX_COPIES}, r = (Q({COPY_K:g} - |b|) + "
                               f"Q({COPY_K:g} + |b|))/(2 Q({COPY_K:g})); each copy weighted 1/copies, the copies of "
                               "an epoch summed into one term of the estimate",
                     "defensive": DEFENSIVE, "confidence": CONFIDENCE, "k_step": K_STEP},
        "validation": {"passed": passed, "epochs": int(v["z"].size),
                       "rates": {n: _rate_record(r) for n, r in checks.items()},
                       "rule": "every held-out estimate of P(|e| > K*sigma + |m|) settled and at most p_hmi"},
        **run_provenance(ap.name, [load_approach(t).name for t in names], sorties, seed, spacing,
                         {"calibration": "SeedSequence(seed, spawn_key=(2, sortie)): gnss, correlators, sampling, copies",
                          "validation": "SeedSequence(seed, spawn_key=(3, sortie)): gnss, correlators, sampling, copies"},
                         fingerprint, cover, ASSUMPTION),
        "version": _version(), "commit": _commit(),
    }
    return rec
