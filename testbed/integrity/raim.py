"""Snapshot RAIM over the satellites given: WLS fix, chi-square detection, slope protection levels.

The baseline every VA-RAIM figure is compared with (docs/design/integrity.md §2-§5
with satellite rows only). Batched over any leading (trial) axes and the epoch axis; a
bad epoch gets NaN and a reason code, never an exception. With satellites of several
constellations the state has one clock per constellation (:mod:`testbed.integrity.multi_clock`,
docs/design/gnss.md §4); with one constellation it is today's 4-state solve, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.frames import LocalFrame
from testbed.integrity import kernels, lsq, multi_clock
from testbed.integrity.fde import Verdict, exclude, flat_take
from testbed.integrity.batching import map_trial_chunks
from testbed.integrity.levels import availability, service_level
from testbed.integrity.settings import IntegritySettings
from testbed.integrity.monitor import ANTENNA, MonitorContext, MonitorCost, MonitorDefaults, NoOptions, Observations
from testbed.records import Diagnostics, GnssEpochs, MonitorOutput, epoch_array


def compact_rows(mask: NDArray, width: int | None = None) -> tuple[NDArray, NDArray, int]:
    """Order the used rows first so the stacked problem is only as wide as needed.

    Parameters
    ----------
    mask : (..., S) bool.
    width : N to use (at least the most used rows of any element; chunks of one batch
        pass the whole batch's width so their outputs stack). Default: that maximum.

    Returns
    -------
    idx : (..., N) int, slot index of each compacted row (stable order).
    mask_c : (..., N) bool, compacted mask.
    N : width = max number of used rows over the batch (at least 1).
    """
    m = np.asarray(mask, bool)
    N = max(int(m.sum(-1).max(initial=0)), 1) if width is None else int(width)
    idx = np.argsort(~m, axis=-1, kind="stable")[..., :N]
    return idx, np.take_along_axis(m, idx, -1), N


def used_gps_rows(vis: NDArray, pr: NDArray, sigma: NDArray, sat_ecef: NDArray, frame: LocalFrame, width: int
                  ) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """:func:`compact_rows` of ``vis`` (..., S) and the compacted rows' data, in one compiled pass.

    Returns idx, mask (..., N), the pseudoranges ``pr`` (..., N), the weights ``1/sigma²``
    (0 on unused rows) and the satellite positions ``sat_ecef`` in ``frame`` (..., N, 3);
    N = width.
    """
    batch, S = vis.shape[:-1], vis.shape[-1]
    P = int(np.prod(batch, dtype=np.int64))

    def flat(a: NDArray, tail: tuple, dt: type = np.float64) -> NDArray:
        return kernels.kernel_input(a, batch + tail, (P,) + tail, dt)

    idx, m = np.empty((P, width), np.int64), np.empty((P, width), bool)
    z, w, anchor = np.empty((P, width)), np.empty((P, width)), np.empty((P, width, 3))
    kernels.gather_used_rows(flat(vis, (S,), np.bool_), flat(pr, (S,)), flat(sigma, (S,)), flat(sat_ecef, (S, 3)),
                             kernels.kernel_input(frame.R, (3, 3)), kernels.kernel_input(frame.origin_ecef, (3,)),
                             idx, m, z, w, anchor)
    return (idx.reshape(batch + (width,)), m.reshape(batch + (width,)), z.reshape(batch + (width,)),
            w.reshape(batch + (width,)), anchor.reshape(batch + (width, 3)))


def scatter_rows(values: NDArray, idx: NDArray, mask_c: NDArray, S: int) -> NDArray:
    """Inverse of :func:`compact_rows` for a per-row quantity ``(..., N + E)`` -> ``(..., S + E)``.

    The N compacted rows go back to their satellite slots (NaN on every other slot); E
    trailing rows that are not satellites (VA-RAIM's vision block) follow unchanged.
    Unused compacted rows are skipped, so a used slot is written exactly once.
    """
    batch, (N, E) = idx.shape[:-1], (idx.shape[-1], values.shape[-1] - idx.shape[-1])
    P = int(np.prod(batch, dtype=np.int64))
    out = np.empty((P, S + E))
    kernels.scatter_used_rows(kernels.kernel_input(values, batch + (N + E,), (P, N + E)),
                              kernels.kernel_input(idx, batch + (N,), (P, N), np.int64),
                              kernels.kernel_input(mask_c, batch + (N,), (P, N), np.bool_), out)
    return out.reshape(batch + (S + E,))


def gps_raim(gnss: GnssEpochs, frame: LocalFrame, settings: IntegritySettings | None = None,
             antenna_offset_enu: ArrayLike | None = None, x0: ArrayLike | None = None,
             name: str = "gps_raim", threads: int | None = None) -> MonitorOutput:
    """Snapshot RAIM over every satellite of ``gnss`` for every epoch (and trial), one clock per
    constellation present (``gnss.system``); the name says where it started: GPS alone.

    Parameters
    ----------
    gnss : GnssEpochs, pseudorange (B..., T, S), sat_pos_ecef (B..., T, S, 3),
        sigma (B..., T, S), visible (B..., T, S). Rows used = ``visible``; a
        visible row with a NaN pseudorange/sigma makes its epoch unavailable.
    frame : world frame; the state is [E, N, U, clock] in it.
    settings : IntegritySettings (default: all defaults).
    antenna_offset_enu : (B..., T, 3) or (3,) m, antenna position minus the
        reported reference point, in ENU (from the attitude reference and the
        antenna lever arm). None: the reported position is the antenna's.
    x0 : (B..., T, 4) start of the iteration; default the frame origin (the
        satellites are 2e7 m away, so 3-4 iterations reach 1e-3 m).
    name : the MonitorOutput name.
    threads : chunks of trials on this many threads (None: one per core; see
        :func:`testbed.integrity.batching.map_trial_chunks`; bit-identical whatever the count).

    Returns
    -------
    MonitorOutput with ``pos_enu (B..., T, 3)``, ``hpl``/``vpl`` of
    ``settings.pl_variant``, ``test_stat`` = SSE and ``threshold`` = T², and
    diagnostics: ``hslope``, ``vslope``, ``residual`` (B..., T, S; NaN on
    unused slots), ``hpl_seed``, ``vpl_seed``, ``hpl_pbias``, ``vpl_pbias``,
    ``lam_det``, ``gdop``/``pdop``/``hdop``/``vdop``/``tdop`` (unweighted-
    equivalent, i.e. from J with the used sigmas), ``cond``, ``converged``.
    """
    st = settings or IntegritySettings()
    pr = np.asarray(gnss.pseudorange, float)
    bt = pr.shape[:-1]
    vis = np.broadcast_to(np.asarray(gnss.visible, bool), pr.shape)
    sat = np.broadcast_to(np.asarray(gnss.sat_pos_ecef, float), pr.shape + (3,))
    sigma = np.broadcast_to(np.asarray(gnss.sigma, float), pr.shape)
    off = None if antenna_offset_enu is None else np.broadcast_to(np.asarray(antenna_offset_enu, float), bt + (3,))
    x0b = None if x0 is None else np.broadcast_to(np.asarray(x0, float), bt + (4,))
    width = max(int(vis.sum(-1).max(initial=0)), 1)  # one row width for every chunk
    code, letters = multi_clock.system_codes(gnss.system)
    clocks = (code, len(letters)) if len(letters) > 1 else None

    def chunk(sl: slice) -> MonitorOutput:
        return _gps_raim_chunk(pr[sl], vis[sl], sat[sl], sigma[sl], None if off is None else off[sl],
                               None if x0b is None else x0b[sl], np.asarray(gnss.t), frame, st, name, width,
                               clocks)

    return map_trial_chunks(chunk, bt, threads)


def fix_at_solution(h: NDArray, G: NDArray, z: NDArray, W: tuple, mask: NDArray, x: NDArray, conv: NDArray,
            ist: IntegritySettings):
    """Geometry, residuals, SSE, both PL variants and the reason code at the solution x of an
    iterated solve (GPS RAIM and its exclusion solves; VA-RAIM's exclusion solves; VA-RAIM's
    integrated solve runs its two halves, :func:`lsq.wls_fit` and :func:`solution_verdict`).

    h (..., N), G (..., N, 4): the predictions and partials at x. W = ``(w_diag, W_block)``:
    the block-diagonal weight of :func:`lsq.wls_fit` (GPS rows first, then the vision block;
    W_block None for GPS rows only).
    """
    return solution_verdict(lsq.wls_fit(h, G, z, W[0], W[1], mask, ist.max_cond), x, conv, ist)


def solution_verdict(ft: lsq.WlsFit, x: NDArray, conv: NDArray, ist: IntegritySettings):
    """:func:`fix_at_solution` from the fit at the solution: (fit, PLs, reason, ok, x)."""
    with np.errstate(invalid="ignore", over="ignore"):
        pls = {v: ft.protection_levels(ist.p_fa, ist.p_md, v) for v in ("seed", "pbias")}
    reason = np.where((ft.reason == lsq.Reason.OK) & ~conv, lsq.Reason.NOT_CONVERGED, ft.reason)
    pl = pls[ist.pl_variant]
    reason = np.where(reason != lsq.Reason.OK, reason, pl.reason).astype(np.int8)
    ok = reason == lsq.Reason.OK
    x = np.where(ft.solvable[..., None], x, np.nan)
    return ft, pls, reason, ok, x


@dataclass(frozen=True)
class GpsRaimDiagnostics(Diagnostics):
    """GPS RAIM's diagnostics (B..., T[, S]): per-satellite slot quantities are NaN on unused slots."""

    hslope: NDArray = epoch_array(1)
    vslope: NDArray = epoch_array(1)
    residual: NDArray = epoch_array(1)
    lam_det: NDArray = epoch_array()
    cond: NDArray = epoch_array()
    converged: NDArray = epoch_array()
    n_iter: NDArray = epoch_array()
    hpl_seed: NDArray = epoch_array()
    vpl_seed: NDArray = epoch_array()
    hpl_pbias: NDArray = epoch_array()
    vpl_pbias: NDArray = epoch_array()
    gdop: NDArray = epoch_array()
    pdop: NDArray = epoch_array()
    hdop: NDArray = epoch_array()
    vdop: NDArray = epoch_array()
    tdop: NDArray = epoch_array()


@dataclass(frozen=True)
class GpsFix:
    """GPS RAIM at one chunk's solution, before it becomes a MonitorOutput (VA-RAIM's step 1 reads it).

    idx, mask, z, w, anchor : the compacted used rows (:func:`used_gps_rows`); x : (..., 4)
    the fix (NaN where unsolvable); fit, pls, reason, ok, converged, n_iter: as
    :func:`fix_at_solution` returns them.
    """

    idx: NDArray
    mask: NDArray
    z: NDArray
    w: NDArray
    anchor: NDArray
    x: NDArray
    fit: object
    pls: dict
    reason: NDArray
    ok: NDArray
    converged: NDArray
    n_iter: NDArray


def gps_fix(pr: NDArray, vis: NDArray, sat_ecef: NDArray, sigma: NDArray, off: NDArray | None,
            x0: NDArray | None, frame: LocalFrame, st: IntegritySettings, width: int,
            clocks: tuple[NDArray, int] | None = None) -> GpsFix:
    """The iterated WLS fix over the satellites given and its fit (arrays broadcast to one batch).

    ``clocks``: (system code per slot (S,), K) when the slots hold K > 1 constellations (one clock
    each, :mod:`testbed.integrity.multi_clock`); None: one clock (the compiled 4-state solve)."""
    idx, m, z, w, anchor = used_gps_rows(vis, pr, sigma, sat_ecef, frame, width)
    bt = pr.shape[:-1]
    off = np.zeros(bt + (3,)) if off is None else off
    if clocks is not None:
        x_it, conv, iters, ft = _multi_clock_solve(idx, m, z, w, anchor, off, x0, clocks, st)
        ft, pls, reason, ok, x = solution_verdict(ft, x_it, conv, st)
        return GpsFix(idx, m, z, w, anchor, x, ft, pls, reason, ok, conv, iters)
    x0 = np.zeros(bt + (4,)) if x0 is None else x0
    x_it, conv, iters, h, G = lsq.gauss_newton_ranges(x0, st.max_iter, st.tol_m, (anchor, off, z, w, m))
    ft, pls, reason, ok, x = fix_at_solution(h, G, z, (w, None), m, x_it, conv, st)
    return GpsFix(idx, m, z, w, anchor, x, ft, pls, reason, ok, conv, iters)


def _multi_clock_solve(idx: NDArray, m: NDArray, z: NDArray, w: NDArray, anchor: NDArray, off: NDArray,
                       x0: NDArray | None, clocks: tuple[NDArray, int], st: IntegritySettings):
    """:func:`multi_clock.fit_multi_clock` on compacted rows of any batch shape: (x, converged, n_iter, fit)."""
    code, K = clocks
    bt, N = m.shape[:-1], m.shape[-1]
    P = int(np.prod(bt, dtype=np.int64))
    start = None
    if x0 is not None:  # the 4-state start: its clock for every constellation
        x0f = np.broadcast_to(x0, bt + (4,)).reshape(P, 4)
        start = np.concatenate([x0f, np.repeat(x0f[:, 3:], K - 1, axis=1)], axis=1)
    x, conv, iters, ft = multi_clock.fit_multi_clock(
        anchor.reshape(P, N, 3), np.broadcast_to(off, bt + (3,)).reshape(P, 3), z.reshape(P, N), w.reshape(P, N),
        m.reshape(P, N), np.asarray(code)[idx].reshape(P, N), K, start, st.max_iter, st.tol_m, st.max_cond)
    ft = _shaped_fit(ft, bt)
    return x.reshape(bt + (3 + K,)), conv.reshape(bt), iters.reshape(bt), ft


def _shaped_fit(ft: lsq.WlsFit, bt: tuple) -> lsq.WlsFit:
    """A flat (P, ...) :class:`lsq.WlsFit` with the batch shape ``bt`` instead of P."""
    return replace(ft, **{f.name: getattr(ft, f.name).reshape(bt + getattr(ft, f.name).shape[1:])
                          for f in fields(ft)})


def snapshot_output(name: str, t: NDArray, x: NDArray, ft, pls: dict, reason: NDArray, ok: NDArray,
                    st: IntegritySettings, make_diagnostics) -> MonitorOutput:
    """The MonitorOutput of a slope-PL snapshot monitor at its solution (GPS RAIM, VA-RAIM).

    PLs of ``st.pl_variant``, SSE against T², alerts and availability per service level on the
    epochs with a solution (``ok``; NaN elsewhere). ``make_diagnostics(pl, per_variant)`` builds
    the monitor's record from the selected PLs and every variant's ``hpl_*``/``vpl_*``.
    """
    pl = pls[st.pl_variant]
    hpl = np.where(ok, pl.hpl, np.nan)
    vpl = np.where(ok, pl.vpl, np.nan)
    sse = np.where(ok, ft.sse, np.nan)
    T2 = np.where(ok, pl.T2, np.nan)
    with np.errstate(invalid="ignore"):
        alert = ok & (sse > T2)
    levels = tuple(service_level(s) for s in st.service_levels)
    per_variant = {f"{d}pl_{v}": np.where(ok, getattr(p, f"{d}pl"), np.nan) for v, p in pls.items() for d in "hv"}
    return MonitorOutput(
        name=name, t=t, pos_enu=x[..., :3], clock=x[..., 3], hpl=hpl, vpl=vpl, test_stat=sse, threshold=T2,
        alert=alert, available=availability(hpl, vpl, levels, ok), service_levels=tuple(st.service_levels),
        n_used=ft.n_used.astype(np.int16), excluded=np.full(reason.shape, -1, np.int16), reason=reason,
        reasons=lsq.REASONS, diagnostics=make_diagnostics(pl, per_variant))


def gps_output(fix: GpsFix, t: NDArray, S: int, st: IntegritySettings, name: str) -> MonitorOutput:
    """GPS RAIM's MonitorOutput at a fix (one function for the module and VA-RAIM's step 1)."""
    ft, ok, idx, m = fix.fit, fix.ok, fix.idx, fix.mask

    def diagnostics(pl, per_variant) -> GpsRaimDiagnostics:
        with np.errstate(invalid="ignore"):
            dop = lsq.dops(ft)
        return GpsRaimDiagnostics(
            hslope=scatter_rows(pl.hslope, idx, m, S), vslope=scatter_rows(pl.vslope, idx, m, S),
            residual=scatter_rows(ft.residual, idx, m, S), lam_det=np.where(ok, pl.lam_det, np.nan), cond=ft.cond,
            converged=fix.converged & ft.solvable, n_iter=fix.n_iter, **per_variant, **dop)

    return snapshot_output(name, t, fix.x, ft, fix.pls, fix.reason, ok, st, diagnostics)


def _gps_raim_chunk(pr: NDArray, vis: NDArray, sat_ecef: NDArray, sigma: NDArray, off: NDArray | None,
                    x0: NDArray | None, t: NDArray, frame: LocalFrame, st: IntegritySettings, name: str,
                    width: int, clocks: tuple[NDArray, int] | None = None) -> MonitorOutput:
    """:func:`gps_raim` on one chunk of trials (arrays broadcast to the chunk's batch)."""
    fix = gps_fix(pr, vis, sat_ecef, sigma, off, x0, frame, st, width, clocks)
    out = gps_output(fix, t, pr.shape[-1], st, name)
    return gps_exclusion(fix, out, off, st, clocks) if st.fde else out


def snapshot_verdict(ft: lsq.WlsFit, pls: dict, ok: NDArray, x: NDArray, st: IntegritySettings) -> Verdict:
    """A slope-PL solve (:func:`fix_at_solution`'s results) as FDE judges it."""
    pl = pls[st.pl_variant]
    return Verdict(x=x, test_stat=ft.sse, threshold=pl.T2, dof=ft.dof, hpl=pl.hpl, vpl=pl.vpl, ok=ok,
                   n_used=ft.n_used.astype(np.int16))


def gps_exclusion(fix: GpsFix, out: MonitorOutput, off: NDArray | None, st: IntegritySettings,
                  clocks: tuple[NDArray, int] | None = None) -> MonitorOutput:
    """GPS RAIM's output after FDE (:func:`testbed.integrity.fde.exclude`): a unit is a satellite's row."""
    nb = fix.mask.ndim - 1
    x_start = np.where(np.isfinite(fix.x), fix.x, 0.0)  # the full-set fix: a few metres from the reduced one

    def solve_without(sel: NDArray, keep: NDArray) -> Verdict:
        take = lambda a: flat_take(a, nb, sel)  # noqa: E731
        m = take(fix.mask) & keep
        o = np.zeros((sel.size, 3)) if off is None else flat_take(np.broadcast_to(off, fix.x.shape[:-1] + (3,)), nb, sel)
        z, w, anchor = take(fix.z), take(fix.w), take(fix.anchor)
        if clocks is not None:
            x_it, conv, _, ft = multi_clock.fit_multi_clock(
                anchor, o, z, w, m, np.asarray(clocks[0])[take(fix.idx)], clocks[1], take(x_start), st.max_iter,
                st.tol_m, st.max_cond)
            ft, pls, _, ok, x = solution_verdict(ft, x_it, conv, st)
            return snapshot_verdict(ft, pls, ok, x, st)
        x_it, conv, _, h, G = lsq.gauss_newton_ranges(take(x_start), st.max_iter, st.tol_m, (anchor, o, z, w, m))
        ft, pls, _, ok, x = fix_at_solution(h, G, z, (w, None), m, x_it, conv, st)
        return snapshot_verdict(ft, pls, ok, x, st)

    N = fix.mask.shape[-1]
    return exclude(out, np.eye(N, dtype=bool), np.where(fix.mask, fix.idx, -1), solve_without, st)


@dataclass(frozen=True)
class GpsRaimMonitor(MonitorDefaults):
    """GPS-only snapshot RAIM as a loop monitor: the receiver's own estimator, at the antenna.

    No state: every epoch stands alone.
    """

    name: str
    context: MonitorContext
    inputs: ClassVar[frozenset[str]] = frozenset({"gnss"})
    reference: ClassVar[str] = ANTENNA
    compiles_kernels: ClassVar[bool] = True

    def prepare(self) -> None:
        """Compile the kernels (numba caches them beside the package) before the first epoch."""
        from testbed.integrity.kernels import compile_all

        compile_all()

    def initial_state(self) -> None:
        return None

    def step(self, obs: Observations, state: None) -> tuple[MonitorOutput, None]:
        c = self.context
        return gps_raim(obs.gnss, c.frame, c.integrity, name=self.name, threads=c.threads), None


def build_monitor(context: MonitorContext, options: NoOptions) -> GpsRaimMonitor:
    """GPS RAIM: its settings are the shared ``[integrity]`` ones (it takes no options of its own)."""
    return GpsRaimMonitor("gps_raim", context)


def cost(options: NoOptions) -> MonitorCost:
    """Per trial-epoch, measured alone on va-raim-2015 (24 satellites), the GNSS draw subtracted."""
    return MonitorCost((1400.0, 0.0, 0.0), (6.5e-6, 0.0, 0.0))
