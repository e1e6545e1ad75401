"""The DPE paper's method as a loop monitor (``dpe``): direct position estimation and its vertical protection level.

Per epoch (docs/design/dpe.md §1, the ``likelihood`` variant, the default):

1. **Initialisation**: the same-epoch GPS-only WLS fix from the scalar pseudoranges, else the
   previous DPE solution (held: the monitor has no velocity), else ``NO_INIT``. Never truth.
2. **Manifold and solution** (:mod:`.manifold`, :mod:`.solve`): Λ(ξ) on coarse-to-fine grids,
   the posterior mean as the solution, the vertical marginal of its error.
3. **Overbound** (:mod:`.overbound`): the tightest median-centred zero-mean Gaussian CDF
   overbound σ_ob of the marginal, and its median m.
4. **VPL = K·σ + |m|**, σ² = σ_ob² + σ²_SIS,U with ``sis = "add"`` (the signal-in-space error
   is outside the manifold: docs/design/dpe.md F6), σ = σ_ob with ``sis = "none"``. K is ``k_factor``; without
   one the VPL is NaN and the epoch ``NOT_CALIBRATED``.

A vertical-only monitor: HPL is NaN, availability is VPL ≤ VAL alone, and ``dimensions`` is
("V",) so evaluation counts misleading information on the vertical only. DPE has no fault
detection (alert is always False): it bounds what the manifold sees.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from testbed.correlation import amplitude_sq, crb_delay_sigma
from testbed.integrity.dpe.manifold import epoch_manifold
from testbed.integrity.dpe.overbound import gaussian_overbound
from testbed.integrity.dpe.seed_variant import SPREAD_STEPS, solve_epoch_seed
from testbed.integrity.dpe.solve import GridPlan, Status, crb, solve_epoch
from testbed.integrity.levels import service_level
from testbed.integrity.gps_only import gps_satellites
from testbed.integrity.monitor import ANTENNA, MonitorContext, MonitorCost, MonitorDefaults, Observations
from testbed.integrity.raim import gps_raim
from testbed.records import Diagnostics, MonitorOutput, epoch_array
from testbed.schema import StrictModel
from testbed.sensors.gnss.errors import sigma_tropo

DPE_REASONS: tuple[str, ...] = (
    "ok",
    "unavailable: fewer than 4 satellites with correlograms inside their delay windows",
    "unavailable: no initialisation (no GPS fix and no previous DPE fix)",
    "unavailable: the likelihood peak is on the grid's edge after the recentrings",
    "unavailable: K not calibrated (dpe.k_factor unset)",
    "unavailable: NaN correlator outputs",
    "unavailable: no Gaussian overbounds the vertical error distribution",
)
FEW, NO_INIT, PEAK_AT_EDGE, NOT_CALIBRATED, NAN_INPUT, INFEASIBLE = 1, 2, 3, 4, 5, 6
_STATUS_REASON = {Status.FEW_SATELLITES: FEW, Status.PEAK_AT_EDGE: PEAK_AT_EDGE}


class DpeSettings(StrictModel):
    """Options of the ``dpe`` monitor (``[dpe]`` in an approach file)."""

    variant: Literal["likelihood", "seed"] = Field(
        "likelihood", description="'likelihood': GLRT power manifold, posterior mean, marginal; 'seed': "
                                  "the paper as written (spread grid, magnitude sum, weighted mean, conditional "
                                  "slice), for reproduction; it needs gnss.correlators.statistic = 'mag'")
    seed_passes: int = Field(50, ge=1, le=200, description="'seed': mean-shift passes of the weighted mean")
    seed_power: float = Field(1.0, gt=0.0, le=8.0, description="'seed': f = (mean |y|)^p")
    seed_mass: Literal["sum", "density"] = Field(
        "sum", description="'seed': the slice read as masses ('sum', the DPE paper's literal reading) or densities")
    k_factor: Annotated[float, Field(gt=0.0, le=100.0)] | str | None = Field(
        None, description="VPL = K·σ + |m|; a number, or in an approach file the path of a "
                                            "`testbed calibrate-dpe` record; None: VPL NaN, every epoch NOT_CALIBRATED")
    sis: Literal["add", "none"] = Field(
        "add", description="'add': σ² = σ_ob² + σ²_SIS,U (the SIS error is outside the manifold); 'none': σ_ob")
    sigma_ura_m: float = Field(0.75, ge=0.0, description="σ_URA the monitor assumes for the SIS term (m)")
    sigma_tropo_zenith_m: float = Field(0.12, ge=0.0, description="residual troposphere at zenith it assumes (m)")
    coarse_spacing_m: float = Field(30.0, gt=0.0, le=300.0, description="stage-1 grid spacing (m; 9 nodes/axis)")
    mid_spacing_m: float = Field(6.0, gt=0.0, le=60.0, description="stage-2 grid spacing (m; 9 nodes/axis)")
    fine_spacing: float = Field(0.6875, gt=0.0, le=2.0,
                                description="whitened-grid spacing (CRB sigmas; 17 nodes/axis: ±5.5σ)")
    max_recentre: int = Field(3, ge=0, le=10, description="recentrings per stage before PEAK_AT_EDGE")

    def plan(self) -> GridPlan:
        return GridPlan(coarse_m=self.coarse_spacing_m, mid_m=self.mid_spacing_m, fine_z=self.fine_spacing,
                        max_recentre=self.max_recentre)


@dataclass(frozen=True)
class DpeDiagnostics(Diagnostics):
    """The DPE per epoch (B..., T[, ...]); the marginal is what the VPL's σ_ob bounds."""

    sigma_ob: NDArray = epoch_array()
    median_m: NDArray = epoch_array()
    sigma_sis_u: NDArray = epoch_array()
    posterior_sd_u: NDArray = epoch_array()
    crb_sd_u: NDArray = epoch_array()
    x_ml: NDArray = epoch_array(1)
    init_kind: NDArray = epoch_array()  # 0 none, 1 GPS fix, 2 previous DPE fix
    recentred: NDArray = epoch_array()
    posterior_face_mass: NDArray = epoch_array()  # the posterior's share on the fine grid's faces (truncation)
    marginal_offsets: NDArray = epoch_array(1)
    marginal: NDArray = epoch_array(1)
    k_factor: float = float("nan")


@dataclass(frozen=True)
class DpeState:
    """The last DPE fix per trial ((B..., 4) ENU + clock; NaN before the first)."""

    last_fix: NDArray | None = None


def _sis_sigma(el: NDArray, st: DpeSettings) -> NDArray:
    """σ_URA ⊕ the residual troposphere at elevations (rad): the SIS terms
    (docs/design/integrity.md §1, eq. 1.2-1.3)."""
    return np.hypot(st.sigma_ura_m, sigma_tropo(el, st.sigma_tropo_zenith_m))


@dataclass(frozen=True)
class DpeMonitor(MonitorDefaults):
    name: str
    context: MonitorContext
    settings: DpeSettings
    inputs: ClassVar[frozenset[str]] = frozenset({"gnss", "correlators"})
    reference: ClassVar[str] = ANTENNA
    compiles_kernels: ClassVar[bool] = True
    dimensions: ClassVar[tuple[str, ...]] = ("V",)  # its PL bounds the vertical only

    @property
    def seed(self) -> bool:
        return self.settings.variant == "seed"

    def prepare(self) -> None:
        """Compile the kernels before the first epoch (numba caches them): GPS RAIM's (the
        initialisation) and the manifold's, on arrays of the types an epoch uses."""
        from testbed.integrity.kernels import compile_all
        from testbed.integrity.kernels.dpe import (deposit_marginal, deposit_marginal_threads, manifold_box,
                                                 manifold_box_threads, posterior_moments, posterior_moments_threads)

        compile_all()
        lam = np.zeros(1)
        for kernel in (manifold_box, manifold_box_threads):
            kernel(np.zeros(1), np.zeros((1, 4)), np.zeros((1, 8, 4)), np.zeros(1), 1.0, 1, True, lam)
        posterior_moments(lam, 1.0, 1, np.zeros(1))
        deposit_marginal(lam, 1.0, 1, np.zeros(4), 0.0, 1.0, np.zeros(3))
        posterior_moments_threads(lam, 1.0, 1, np.zeros(1))
        deposit_marginal_threads(lam, 1.0, 1, np.zeros(4), 0.0, 1.0, np.zeros(3))

    def initial_state(self) -> DpeState:
        return DpeState()

    def step(self, obs: Observations, state: DpeState) -> tuple[MonitorOutput, DpeState]:
        obs = gps_satellites(obs)  # DPE stays GPS-only (docs/design/gnss.md §5)
        corr = obs.correlators
        if corr is None:
            raise ValueError("dpe: the observations carry no correlators (the run did not synthesise them)")
        g = obs.gnss
        lead = np.shape(g.pseudorange)[:-2]
        T, S = np.shape(g.pseudorange)[-2:]
        c = self.context
        state = state if state is not None else DpeState()
        fix = gps_raim(g, c.frame, c.integrity, name="dpe-init", threads=c.threads)
        init = np.concatenate([fix.pos_enu, fix.clock[..., None]], -1).reshape((-1, T, 4))
        B = init.shape[0]
        last = np.full((B, 4), np.nan) if state.last_fix is None else np.asarray(state.last_fix).reshape(B, 4)
        sat = np.broadcast_to(np.asarray(corr.sat_pos_ecef), lead + (T, S, 3)).reshape(B, T, S, 3)
        rho = np.broadcast_to(np.asarray(corr.rho_ref), lead + (T, S)).reshape(B, T, S)
        stat = np.broadcast_to(np.asarray(corr.stat), lead + (T, S) + corr.stat.shape[-1:]).reshape(B, T, S, -1)
        vis = np.broadcast_to(np.asarray(corr.visible, bool), lead + (T, S)).reshape(B, T, S)
        cn0 = np.broadcast_to(np.asarray(corr.cn0_est_dbhz), lead + (T, S)).reshape(B, T, S)
        res = _Results(B, T, SPREAD_STEPS.size if self.seed else self.settings.plan().bins)
        for b in range(B):
            for i in range(T):
                x0, kind = init[b, i], 1
                if not np.all(np.isfinite(x0)):
                    x0, kind = last[b], 2
                if not np.all(np.isfinite(x0)):
                    res.reason[b, i] = NO_INIT
                    continue
                res.init_kind[b, i] = kind
                k = np.flatnonzero(vis[b, i] & np.isfinite(rho[b, i]))
                if not np.all(np.isfinite(stat[b, i, k])) or not np.all(np.isfinite(cn0[b, i, k])):
                    res.reason[b, i] = NAN_INPUT
                    continue
                self._solve(res, b, i, x0, sat[b, i, k], rho[b, i, k], stat[b, i, k], cn0[b, i, k], corr)
                if res.reason[b, i] == 0:
                    last[b] = res.x[b, i]
        out = self._output(res, np.asarray(g.t), lead)
        return out, DpeState(last.reshape(lead + (4,)) if lead else last[0])

    def _solve(self, res: "_Results", b: int, i: int, x0: NDArray, sat: NDArray, rho: NDArray, stat: NDArray,
               cn0: NDArray, corr) -> None:
        fr = self.context.frame
        want = "mag" if self.seed else "pow"
        if corr.stat_kind != want:
            raise ValueError(f"dpe: variant {self.settings.variant!r} reads the {want!r} statistic, the correlators "
                             f"report {corr.stat_kind!r} (gnss.correlators.statistic)")
        mf = epoch_manifold(fr, sat, rho, stat, x0[:3], float(x0[3]), stat_kind=corr.stat_kind,
                            n_blocks=corr.n_noncoherent, bandwidth_chips=corr.bandwidth_chips,
                            delay0_m=corr.delay0_m, step_m=corr.delay_step_m)
        if self.seed:
            ss = solve_epoch_seed(mf, self.settings.seed_passes, self.settings.seed_power)
            res.x[b, i] = x0 + ss.x_mean
            res.x_ml[b, i] = res.x[b, i]
            res.offsets[b, i] = -ss.slice_u[::-1]  # error coordinates e = Û − U, ascending
            res.marginal[b, i] = ss.slice_values[::-1]
            res.n_used[b, i] = int(ss.used.sum())
            self._sis(res, b, i, mf.g, ss.used, cn0, corr)
            return
        sol = solve_epoch(mf, amplitude_sq(cn0, corr.coherent_s), corr.n_noncoherent, corr.bandwidth_chips,
                          self.settings.plan(), threaded=self.context.threads != 1)
        res.recentred[b, i] = sol.recentred
        if sol.status != Status.OK:
            res.reason[b, i] = _STATUS_REASON[sol.status]
            return
        res.x[b, i] = x0 + sol.x_mean
        res.x_ml[b, i] = x0 + sol.x_ml
        res.post_sd_u[b, i] = np.sqrt(sol.cov[2, 2])
        res.face_mass[b, i] = sol.face_mass
        res.crb_sd_u[b, i] = np.sqrt(sol.J[2, 2])
        res.offsets[b, i] = sol.offsets
        res.marginal[b, i] = sol.marginal
        res.n_used[b, i] = int(sol.used.sum())
        self._sis(res, b, i, mf.g, sol.used, cn0, corr)

    def _sis(self, res: "_Results", b: int, i: int, g: NDArray, used: NDArray, cn0: NDArray, corr) -> None:
        """σ_SIS,U: the SIS errors through the DPE's own weighting, A_w = J Gᵀ W with the CRB weights."""
        g_used = g[used]
        el = np.arcsin(np.clip(-g_used[:, 2], -1.0, 1.0))
        a2 = amplitude_sq(cn0[used], corr.coherent_s)
        w = 1.0 / crb_delay_sigma(a2, corr.n_noncoherent, corr.bandwidth_chips) ** 2
        A_u = (crb(g_used, a2, corr.n_noncoherent, corr.bandwidth_chips) @ (g_used * w[:, None]).T)[2]
        res.sis_u[b, i] = float(np.sqrt(np.sum((A_u * _sis_sigma(el, self.settings)) ** 2)))

    def _output(self, res: "_Results", t: NDArray, lead: tuple) -> MonitorOutput:
        st, ds = self.context.integrity, self.settings
        ok = res.reason == 0
        ob = gaussian_overbound(np.where(ok[..., None], res.offsets, np.arange(res.offsets.shape[-1])),
                                np.where(ok[..., None], res.marginal, 1.0),
                                mass=self.settings.seed_mass if self.seed else "density")
        infeasible = ok & ~np.isfinite(ob.sigma)
        ok = ok & ~infeasible
        sigma_ob = np.where(ok, ob.sigma, np.nan)
        med = np.where(ok, ob.median, np.nan)
        sigma = np.hypot(sigma_ob, res.sis_u) if ds.sis == "add" else sigma_ob
        k = np.nan if ds.k_factor is None else ds.k_factor
        reason = res.reason.copy()
        reason[infeasible] = INFEASIBLE
        if ds.k_factor is None:
            reason[ok] = NOT_CALIBRATED
        vpl = np.where(reason == 0, k * sigma + np.abs(med), np.nan)
        levels = tuple(service_level(s) for s in st.service_levels)
        val = np.array([lv.val for lv in levels])
        available = (vpl[..., None] <= val) & (reason == 0)[..., None]
        shape = lambda a: a.reshape(lead + a.shape[2:]) if lead else a[0]  # noqa: E731
        diag = DpeDiagnostics(sigma_ob=shape(sigma_ob), median_m=shape(med), sigma_sis_u=shape(res.sis_u),
                              posterior_sd_u=shape(res.post_sd_u), crb_sd_u=shape(res.crb_sd_u), x_ml=shape(res.x_ml),
                              init_kind=shape(res.init_kind), recentred=shape(res.recentred),
                              posterior_face_mass=shape(res.face_mass),
                              marginal_offsets=shape(res.offsets), marginal=shape(res.marginal), k_factor=float(k))
        x = np.where(ok[..., None], res.x, np.nan)
        nan = np.full(res.reason.shape, np.nan)
        return MonitorOutput(
            name=self.name, t=t, pos_enu=shape(x[..., :3]), clock=shape(x[..., 3]), hpl=shape(nan), vpl=shape(vpl),
            test_stat=shape(sigma_ob), threshold=shape(nan), alert=shape(np.zeros(res.reason.shape, bool)),
            available=shape(available), service_levels=tuple(st.service_levels), n_used=shape(res.n_used),
            excluded=shape(np.full(res.reason.shape, -1, np.int16)), reason=shape(reason.astype(np.int8)),
            reasons=DPE_REASONS, diagnostics=diag, dimensions=("V",))


class _Results:
    """Per (trial, epoch) arrays the epoch loop fills."""

    def __init__(self, B: int, T: int, bins: int) -> None:
        self.reason = np.zeros((B, T), np.int8)
        self.init_kind = np.zeros((B, T), np.int8)
        self.recentred = np.zeros((B, T), np.int16)
        self.n_used = np.zeros((B, T), np.int16)
        self.x = np.full((B, T, 4), np.nan)
        self.x_ml = np.full((B, T, 4), np.nan)
        self.post_sd_u = np.full((B, T), np.nan)
        self.crb_sd_u = np.full((B, T), np.nan)
        self.sis_u = np.full((B, T), np.nan)
        self.face_mass = np.full((B, T), np.nan)
        self.offsets = np.full((B, T, bins), np.nan)
        self.marginal = np.full((B, T, bins), np.nan)


def build_monitor(context: MonitorContext, options: DpeSettings) -> DpeMonitor:
    """DPE with the approach's ``[monitor.dpe]`` options (a K file already read into ``k_factor``)."""
    if isinstance(options.k_factor, str):
        raise ValueError(f"k_factor = {options.k_factor!r}: a K record is read by the run's set-up "
                         "(testbed.sim.setup.build_monitors); a monitor built directly takes a number")
    return DpeMonitor("dpe", context, options)


def cost(options: DpeSettings) -> MonitorCost:
    """Per trial-epoch, measured alone on zunz-rwy05-dpe less its correlograms (``python
    benchmarks/bench_budget.py --fit``: 11.4 ms a trial-epoch with its two correlogram passes of 2.2 ms); the DPE
    paper's variant makes 50 mean-shift passes over 390 625 candidates, ~0.29 s an epoch (dpe-variants.toml)."""
    return MonitorCost((2e3, 0.0, 0.0), (0.29 if options.variant == "seed" else 7.0e-3, 0.0, 0.0))


__all__ = ["DPE_REASONS", "DpeDiagnostics", "DpeMonitor", "DpeSettings", "DpeState", "build_monitor"]
