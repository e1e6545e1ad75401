"""GNSS pseudorange and range-rate synthesis: fly once, sample many.

:func:`gnss_geometry` computes everything that depends only on the trajectory
(orbits, light time, Earth rotation, visibility) once; :func:`sample_gnss`
draws errors, receiver clock and faults for one or ``n_trials`` trials on top;
:func:`synthesize_gnss` does both.

Signal model (consistent with the monitors' model, docs/design/integrity.md §1):
the receive time t_r is the true GPS time of the epoch and the antenna is at
r(t_r). The transmit time t_t = t_r − τ solves τ = |R₃(Ω̇e τ)·s(t_t) − r(t_r)|/c
(3 fixed-point iterations, converged to < 1 ps). ``sat_pos_ecef`` is
s(t_t) rotated into the ECEF frame of t_r (the Sagnac / Earth-rotation
effect is therefore inside the geometry), so

    pseudorange = |sat_pos_ecef − antenna| + c·δt_rx + ε + fault,
    range_rate  = u·(sat_vel_ecef − antenna_vel) + c·δṫ_rx + ε_ṙ,

u the unit line of sight. The satellite clock and modelled atmosphere are
taken as removed by the receiver (ε is the residual of the VA-RAIM paper's eq. 27,
or of the DFMC model, ``settings.error_model``).

Several constellations (``settings.constellations``) share the satellite axis S in
the order listed; ``system`` (S,) holds each slot's RINEX 3 letter beside ``prn``.
One oscillator drives the receiver: the pseudoranges of every constellation but
the first listed carry a constant offset (the inter-system bias, drawn once per
trial, :attr:`GnssErrors.system_offset`), which a monitor estimates as one clock
state per constellation (docs/design/gnss.md §4).

Truth decimation: ``synthesize_gnss`` decimates the truth to
``settings.rate_hz`` itself (``Truth.decimate``: nearest flight epochs from
t[0]); a truth already at or below that rate passes unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from datetime import datetime
from typing import Any, ClassVar, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from testbed.frames import C_LIGHT, OMEGA_EARTH
from testbed.records import GnssEpochs, GnssTruth, Mount, Truth
from testbed.sensors.faults import GNSS_KINDS, gnss_fault_bias
from testbed.sensors.gnss.constellations import tracked_constellations
from testbed.sensors.gnss.errors import (IONO_FREE_FACTOR, range_sigmas, receiver_clock, sigma_multipath, sigma_noise,
                                         sigma_tropo, unit_gauss_markov, user_error_components)
from testbed.sensors.gnss.orbits import Ephemeris, sat_states
from testbed.sensors.gnss.settings import GnssSettings
from testbed.sensors.gnss.timebase import utc_to_gps_seconds
from testbed.sensors.gnss.visibility import antenna_state, apply_schedule, apply_system_caps, classify

_LIGHT_TIME_ITERATIONS = 3


@dataclass(frozen=True)
class GnssGeometry:
    """Trajectory-only GNSS quantities (no randomness), computed once per flight.

    Shapes: T epochs, S satellite slots. Frames: ECEF of the receive time.

    t, t_gps : (T,) s since approach start / since the GPS epoch (receive time, true).
    prn : (S,).  system : (S,) RINEX 3 system letter of each slot ('G', 'E', 'C').
    eph : the constellation(s) used.  antenna : the antenna mount.
    ant_pos_ecef, ant_vel_ecef : (T, 3) true antenna position (m) / velocity (m/s).
    sat_pos_ecef, sat_vel_ecef : (T, S, 3) transmit-time satellite state in the receive-time frame.
    sat_clock_s, sat_clock_rate : (T, S) satellite clock offset (s) / rate at transmit time.
    geometric_range : (T, S) m.  geometric_range_rate : (T, S) m/s.
    elevation, azimuth, elevation_body : (T, S) rad.  reason : (T, S) int8.  visible : (T, S) bool.

    A *stacked* geometry (:func:`gnss_geometry` with ``offsets_s``, or :meth:`windows`) has
    a leading axis on ``t_gps`` (W, T) and on every (T, S, ...) array: one per start time.
    The trajectory arrays (``t``, ``ant_pos_ecef``, ``ant_vel_ecef``) are shared.
    """

    t: NDArray
    t_gps: NDArray
    prn: NDArray
    system: NDArray
    eph: Ephemeris
    antenna: Mount
    ant_pos_ecef: NDArray
    ant_vel_ecef: NDArray
    sat_pos_ecef: NDArray
    sat_vel_ecef: NDArray
    sat_clock_s: NDArray
    sat_clock_rate: NDArray
    geometric_range: NDArray
    geometric_range_rate: NDArray
    elevation: NDArray
    azimuth: NDArray
    elevation_body: NDArray
    reason: NDArray
    visible: NDArray

    #: the fields with the epoch axis first (not stacked): what epoch slicing cuts (``prn``, ``system`` are per
    #: satellite, whatever their length)
    PER_EPOCH: ClassVar[tuple[str, ...]] = ("t", "ant_pos_ecef", "ant_vel_ecef", "t_gps", "sat_pos_ecef",
                                             "sat_vel_ecef", "sat_clock_s", "sat_clock_rate", "geometric_range",
                                             "geometric_range_rate", "elevation", "azimuth", "elevation_body",
                                             "reason", "visible")

    @property
    def stacked(self) -> bool:
        """True when the time-dependent arrays have a leading start-time axis."""
        return self.visible.ndim == 3

    def windows(self, which: ArrayLike) -> "GnssGeometry":
        """The stacked geometry of start-time windows ``which`` (n,) (one per trial, repeats allowed)."""
        if not self.stacked:
            raise ValueError("windows(): expected a stacked geometry (gnss_geometry with offsets_s)")
        idx = np.asarray(which, np.intp)
        return replace(self, **{f: getattr(self, f)[idx] for f in _PER_START})


def concat_windows(geoms: Sequence[GnssGeometry]) -> GnssGeometry:
    """One stacked geometry from stacked geometries of the same trajectory (windows in order)."""
    return replace(geoms[0], **{f: np.concatenate([getattr(g, f) for g in geoms]) for f in _PER_START})


#: GnssGeometry fields that depend on the start time (stacked: a leading window axis).
_PER_START = ("t_gps", "sat_pos_ecef", "sat_vel_ecef", "sat_clock_s", "sat_clock_rate", "geometric_range",
              "geometric_range_rate", "elevation", "azimuth", "elevation_body", "reason", "visible")


def rotate_z(v: NDArray, theta: NDArray) -> NDArray:
    """Components in the frame rotated by +θ about z (the Earth-fixed frame θ/Ω̇e later)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1], v[..., 2]], -1)


def signal_geometry(eph: Ephemeris, t_gps: NDArray, ant_pos_ecef: NDArray, ant_vel_ecef: NDArray):
    """Light-time-corrected satellite states in the receive-time ECEF frame.

    Parameters
    ----------
    t_gps : (T,) receive times.  ant_pos_ecef, ant_vel_ecef : (T, 3).

    Returns
    -------
    sat_pos, sat_vel : (T, S, 3).  clock_s, clock_rate : (T, S).  rng_m, rng_rate : (T, S).
    """
    t_gps = np.asarray(t_gps, float)
    tau = np.full((t_gps.size, len(eph)), 0.075)  # ~ 20 000 km / c
    for _ in range(_LIGHT_TIME_ITERATIONS):
        pos = sat_states(eph, t_gps[:, None] - tau, per_slot=True, position_only=True)[0]
        pos_r = rotate_z(pos, OMEGA_EARTH * tau)
        tau = np.linalg.norm(pos_r - ant_pos_ecef[:, None, :], axis=-1) / C_LIGHT
    pos, vel, clk, clk_rate = sat_states(eph, t_gps[:, None] - tau, per_slot=True)
    sat_pos = rotate_z(pos, OMEGA_EARTH * tau)
    sat_vel = rotate_z(vel, OMEGA_EARTH * tau)
    d = sat_pos - ant_pos_ecef[:, None, :]
    rng_m = np.linalg.norm(d, axis=-1)
    rate = np.einsum("tsi,tsi->ts", d / rng_m[..., None], sat_vel - ant_vel_ecef[:, None, :])
    return sat_pos, sat_vel, clk, clk_rate, rng_m, rate


def gnss_geometry(truth: Truth, antenna: Mount, settings: GnssSettings, *, start_utc: datetime | str,
                  terrain: Any = None, constellation: Ephemeris | None = None,
                  offsets_s: ArrayLike | None = None) -> GnssGeometry:
    """Satellite geometry and visibility along a trajectory (no noise; see module doc).

    ``truth`` is used at its own epochs (decimate it first, or use
    :func:`synthesize_gnss`). ``start_utc`` is the UTC time of ``truth.t == 0``.
    ``terrain`` is any object with ``sky_visible`` (ignored when
    ``settings.terrain_masking`` is False). ``constellation`` overrides the
    one named in ``settings``.

    ``offsets_s`` (W,): the same trajectory flown at W start times ``start_utc + offset``
    (sorties spread over a span, flown once): one batched pass, and a *stacked*
    geometry whose time-dependent arrays carry a leading window axis (W, T, ...)
    (:meth:`GnssGeometry.windows` picks per-trial windows from it).
    """
    t = np.asarray(truth.t, float)
    off = np.zeros(1) if offsets_s is None else np.asarray(offsets_s, float).reshape(-1)
    W, T = off.size, t.size
    t_gps = utc_to_gps_seconds(start_utc) + off[:, None] + t[None, :]  # (W, T)
    eph = constellation if constellation is not None else tracked_constellations(settings, float(t_gps[0, T // 2]))
    ant_pos, ant_vel, R_b2e, R_e2n = antenna_state(truth, antenna)

    def tiled(a: NDArray) -> NDArray:  # (T, ...) -> (W·T, ...), window-major
        return np.broadcast_to(a, (W,) + a.shape).reshape((W * T,) + a.shape[1:])

    sat_pos, sat_vel, clk, clk_rate, rng_m, rate = signal_geometry(eph, t_gps.reshape(-1), tiled(ant_pos),
                                                                   tiled(ant_vel))
    los = (sat_pos - tiled(ant_pos)[:, None, :]) / rng_m[..., None]
    el, az, el_body, reason = classify(
        los, tiled(ant_pos), tiled(R_e2n), tiled(R_b2e), eph.health, elevation_mask_deg=slot_masks(eph, settings),
        terrain=terrain if settings.terrain_masking else None, airframe_masking=settings.airframe_masking,
        airframe_mask_deg=settings.airframe_mask_deg)
    lead = (T,) if offsets_s is None else (W, T)

    def shaped(a: NDArray) -> NDArray:
        return a.reshape(lead + a.shape[1:])

    caps = {letter: settings.constellation(letter).max_satellites for letter in settings.systems}
    capped = apply_system_caps(shaped(reason), shaped(el), eph.system, caps)
    reason = apply_schedule(capped, shaped(el), t, settings.schedule).reshape(reason.shape)

    return GnssGeometry(t=t, t_gps=t_gps.reshape(lead), prn=np.asarray(eph.prn), system=np.asarray(eph.system),
                        eph=eph, antenna=antenna,
                        ant_pos_ecef=ant_pos, ant_vel_ecef=ant_vel, sat_pos_ecef=shaped(sat_pos),
                        sat_vel_ecef=shaped(sat_vel), sat_clock_s=shaped(clk), sat_clock_rate=shaped(clk_rate),
                        geometric_range=shaped(rng_m), geometric_range_rate=shaped(rate), elevation=shaped(el),
                        azimuth=shaped(az), elevation_body=shaped(el_body), reason=shaped(reason),
                        visible=shaped(reason == 0))


def slot_masks(eph: Ephemeris, settings: GnssSettings) -> float | NDArray:
    """The elevation mask (deg) of every slot: ``settings.elevation_mask_deg`` unless a constellation sets its
    own (then one per slot, (S,))."""
    own = {c: settings.constellation(c).elevation_mask_deg for c in settings.systems}
    if all(m is None for m in own.values()):
        return settings.elevation_mask_deg
    unknown = sorted(set(np.asarray(eph.system).tolist()) - set(own))
    if unknown:
        raise ValueError(f"constellation: slots of system(s) {unknown} are not in constellations = "
                         f"{settings.constellations}")
    return np.array([settings.elevation_mask_deg if own[c] is None else own[c] for c in eph.system], float)


def _fault_bias(faults: Sequence, geom: GnssGeometry, rng: np.random.Generator,
                batch: tuple[int, ...]) -> NDArray:
    gnss = [f for f in faults if f.kind in GNSS_KINDS]
    T, S = geom.visible.shape[-2:]
    if not gnss:
        return np.zeros(batch + (T, S))
    if batch and (geom.stacked or any(getattr(f, "targets", None) == "random" for f in gnss)):
        # per trial (drawn in trial order from rng): a fresh random satellite, visible in the trial's sky
        vis = geom.visible if geom.stacked else np.broadcast_to(geom.visible, batch + (T, S))
        sat = geom.sat_pos_ecef if geom.stacked else np.broadcast_to(geom.sat_pos_ecef, batch + (T, S, 3))
        return np.stack([gnss_fault_bias(gnss, geom.t, geom.prn, vis[i], rng, geom.system, sat[i], geom.ant_pos_ecef)
                         for i in range(batch[0])])
    return np.broadcast_to(gnss_fault_bias(gnss, geom.t, geom.prn, geom.visible, rng, geom.system, geom.sat_pos_ecef,
                                           geom.ant_pos_ecef), batch + (T, S))


@dataclass(frozen=True)
class GnssErrors:
    """The fault-free random part of a draw (:func:`draw_gnss_errors`): what a GNSS-fault sweep's cells share
    under common random numbers. ``fault_seed``: (entropy, spawn key, pool size, children spawned) of the
    faults' own child generator, rebuilt fresh for each application (a fault draw may spawn from it), so
    every fault schedule draws from the same stream."""

    batch: tuple[int, ...]
    sigma: NDArray  # (T, S) or stacked (n, T, S)
    noise: NDArray  # (batch, T, S)
    clock_bias: NDArray  # (batch, T)
    clock_drift: NDArray  # (batch, T)
    rr_noise: NDArray  # (batch, T, S)
    fault_seed: tuple
    fault_bit_generator: type  # the caller's kind of generator (PCG64 from default_rng)
    system_offset: NDArray | None = None  # (batch, S) inter-system clock offset per slot (m); None: one system
    #: the 1σ of the white error drawn, where it is not the 1σ the monitors are told (the 'dfmc' model draws
    #: σ_URE and tells σ_URA); None: ``sigma``
    sigma_drawn: NDArray | None = None

    @property
    def drawn_sigma(self) -> NDArray:
        """The 1σ of the white error drawn (``sigma_drawn``, else the ``sigma`` told)."""
        return self.sigma if self.sigma_drawn is None else self.sigma_drawn


def sample_gnss(geom: GnssGeometry, settings: GnssSettings, *, faults: Sequence = (), rng: np.random.Generator,
                n_trials: int | None = None) -> tuple[GnssEpochs, GnssTruth]:
    """Draw errors, receiver clock and faults on a fixed geometry.

    Returns observations with a leading trial axis ``(n_trials, T, S)`` when
    ``n_trials`` is given, else ``(T, S)``. Geometry-only arrays
    (satellite states, visibility, sigma) are broadcast views, not copies.
    Faults (``testbed.sensors.faults``) are added after the noise; the
    truth records them in ``fault_bias`` and ``faulty = fault_bias != 0``.
    A stacked geometry (:meth:`GnssGeometry.windows`, one start time per trial) needs
    ``n_trials`` equal to its number of windows; its arrays are used as they are.
    The same as :func:`apply_gnss_errors` on :func:`draw_gnss_errors`.
    """
    return apply_gnss_errors(geom, draw_gnss_errors(geom, settings, rng=rng, n_trials=n_trials), faults)


def draw_gnss_errors(geom: GnssGeometry, settings: GnssSettings, *, rng: np.random.Generator,
                     n_trials: int | None = None) -> GnssErrors:
    """The noise, receiver clock and range-rate noise of :func:`sample_gnss`, without the faults."""
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
    if n_trials is not None and (int(n_trials) != n_trials or n_trials < 1):
        raise ValueError(f"n_trials: expected a positive integer or None, got {n_trials!r}")
    batch = () if n_trials is None else (int(n_trials),)
    T, S = geom.visible.shape[-2:]
    if geom.stacked and batch != geom.visible.shape[:1]:
        raise ValueError(f"n_trials: a stacked geometry of {geom.visible.shape[0]} start times needs "
                         f"n_trials = {geom.visible.shape[0]}, got {n_trials!r}")
    shape = batch + (T, S)
    el = geom.elevation
    dt = float(np.median(np.diff(geom.t))) if T > 1 else 1.0
    # One child generator per random component: each time-dependent array is the
    # only draw from its generator, so for n_trials=None the first T1 epochs do
    # not depend on T (prefix-stable): the closed loop can synthesise block by
    # block and get exactly the whole-flight result.
    g_ut, g_mp, g_white, g_clock, g_rr, g_fault = rng.spawn(6)
    sigma, drawn, _ = range_sigmas(el, geom.system, settings)  # told to the monitors / of the error drawn
    if settings.multipath_tau_s is None and settings.ura_tropo_tau_s is None:
        noise = drawn * g_white.standard_normal(shape)
    else:
        if settings.error_model == "seed":
            sis = settings.sigma_ura_m
            mp, white = IONO_FREE_FACTOR * sigma_multipath(el), IONO_FREE_FACTOR * sigma_noise(el)
        else:
            sis = np.array([settings.constellation(str(c)).sigma_ure_m for c in geom.system])
            mp, white = user_error_components(el, settings.user_error)
        s_ut = np.hypot(sis, sigma_tropo(el, settings.sigma_tropo_zenith_m))
        noise = (s_ut * unit_gauss_markov(g_ut, shape, dt, settings.ura_tropo_tau_s)
                 + mp * unit_gauss_markov(g_mp, shape, dt, settings.multipath_tau_s)
                 + white * g_white.standard_normal(shape))
    if settings.clock_model:
        bias, drift = receiver_clock(g_clock, geom.t, batch, bias0_sigma_m=settings.clock_bias0_sigma_m,
                                     drift0_sigma_m_s=settings.clock_drift0_sigma_m_s,
                                     sf_m2_s=settings.clock_sf_m2_s, sg_m2_s3=settings.clock_sg_m2_s3)
    else:
        bias, drift = np.zeros(batch + (T,)), np.zeros(batch + (T,))
    rr_noise = settings.range_rate_sigma_m_s * g_rr.standard_normal(shape)
    ss = g_fault.bit_generator.seed_seq
    return GnssErrors(batch=batch, sigma=sigma, noise=noise, clock_bias=bias, clock_drift=drift, rr_noise=rr_noise,
                      fault_seed=(ss.entropy, ss.spawn_key, ss.pool_size, ss.n_children_spawned),
                      fault_bit_generator=type(g_fault.bit_generator),
                      system_offset=inter_system_offsets(geom.system, settings, rng, batch),
                      sigma_drawn=None if drawn is sigma else drawn)


def inter_system_offsets(system: NDArray, settings: GnssSettings, rng: np.random.Generator,
                         batch: tuple[int, ...]) -> NDArray | None:
    """Per slot (*batch, S), the constant offset (m) of its constellation's time from the first slot's
    (the receiver clock's reference): 0 on that system, σ = ``settings.inter_system_bias_sigma_m`` drawn once
    per trial for each other one, from a generator spawned after the six of :func:`draw_gnss_errors` (so a
    single constellation's draws are today's). None when every slot is of one system."""
    system = np.asarray(system)
    others = [c for c in dict.fromkeys(system.tolist()) if c != system[0]]
    if not others:
        return None
    z = settings.inter_system_bias_sigma_m * rng.spawn(1)[0].standard_normal(batch + (len(others),))
    per_system = np.concatenate([np.zeros(batch + (1,)), z], axis=-1)
    return per_system[..., [0 if c == system[0] else 1 + others.index(c) for c in system]]


def apply_gnss_errors(geom: GnssGeometry, errors: GnssErrors, faults: Sequence = ()) -> tuple[GnssEpochs, GnssTruth]:
    """The observations of ``geom`` with ``errors`` and the faults (drawn from the errors' fault stream)."""
    batch, sigma, noise, bias, drift = errors.batch, errors.sigma, errors.noise, errors.clock_bias, errors.clock_drift
    entropy, spawn_key, pool_size, spawned = errors.fault_seed
    g_fault = np.random.Generator(errors.fault_bit_generator(np.random.SeedSequence(
        entropy, spawn_key=spawn_key, pool_size=pool_size, n_children_spawned=spawned)))
    fault = _fault_bias(faults, geom, g_fault, batch)
    vis = geom.visible
    offset = errors.system_offset
    clock = bias[..., None] if offset is None else bias[..., None] + offset[..., None, :]
    pr = np.where(vis, geom.geometric_range + clock + noise + fault, np.nan)
    rr = np.where(vis, geom.geometric_range_rate + drift[..., None] + errors.rr_noise, np.nan)

    def b(x):  # geometry per trial: stacked already, or one geometry broadcast over the trials
        return x if geom.stacked else np.broadcast_to(x, batch + x.shape)

    epochs = GnssEpochs(t=geom.t, t_gps=geom.t_gps, prn=geom.prn, sat_pos_ecef=b(geom.sat_pos_ecef),
                        sat_vel_ecef=b(geom.sat_vel_ecef), pseudorange=pr, range_rate=rr,
                        sigma=b(np.where(vis, sigma, np.nan)), visible=b(vis), reason=b(geom.reason),
                        antenna=geom.antenna, system=geom.system)
    truth = GnssTruth(antenna_pos_ecef=geom.ant_pos_ecef, geometric_range=geom.geometric_range, clock_bias=bias,
                      noise=noise, fault_bias=fault, faulty=fault != 0, elevation=geom.elevation,
                      azimuth=geom.azimuth, system_offset=offset)
    return epochs, truth


def synthesize_gnss(truth: Truth, antenna: Mount, settings: GnssSettings, *, start_utc: datetime | str,
                    terrain: Any = None, faults: Sequence = (), rng: np.random.Generator,
                    n_trials: int | None = None, constellation: Ephemeris | None = None
                    ) -> tuple[GnssEpochs, GnssTruth]:
    """GPS observations for a flight (decimated to ``settings.rate_hz``) and their truth.

    Geometry (orbits, light time, visibility) is computed once; noise, clock
    and faults are drawn with a leading trial axis ``(n_trials, T, S)`` when
    ``n_trials`` is given. See :func:`gnss_geometry` and :func:`sample_gnss`.
    The range-rate noise 1σ the monitor should assume is ``settings.range_rate_sigma_m_s``.
    """
    geom = gnss_geometry(truth.decimate(settings.rate_hz), antenna, settings, start_utc=start_utc,
                         terrain=terrain, constellation=constellation)
    return sample_gnss(geom, settings, faults=faults, rng=rng, n_trials=n_trials)
