"""Monitor-ready GPS, Galileo and BeiDou observations from a RINEX observation file and its navigation file.

What a receiver's code measurement is and what is done to it (IS-GPS-200, the
RINEX definitions), for a tag t_r in the receiver's time scale:

    P = c·(t_r − t_sv),    t_sv the satellite clock's transmit time
    transmit time (GPS time)  t_t = t_r − P/c − Δt_sv(t_t)   (Δt_sv: af0..af2 + relativistic term)
    satellite position        s(t_t) rotated about z by Ω̇e·τ, τ = |s − r|/c  (Earth rotation
                              during the light time: positions in the ECEF frame of reception)
    corrected pseudorange     P + c·Δt_sv − c·T_GD − I − T  (T_GD for single-frequency L1 only;
                              I ionosphere, T troposphere; iono-free: (f1²P1 − f2²P2)/(f1² − f2²), no T_GD)

The receiver clock stays in the corrected pseudorange, as the monitors expect
(:class:`testbed.records.GnssEpochs`). The rotation, elevation, azimuth and the
atmosphere need the receiver position: a preliminary unweighted fix per epoch
(Gauss-Newton from the Earth's centre, light time re-solved each iteration)
serves them; the monitors then solve their own weighted fix from the result. A
10 m error in the preliminary fix moves the Sagnac rotation of a satellite by
< 0.1 mm and the elevations by < 1e-6 rad.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from testbed.frames import C_LIGHT, OMEGA_EARTH, R_ecef_to_enu, ecef_to_geodetic
from testbed.records import GnssEpochs, Mount, NotVisible
from testbed.rinex.atmosphere import klobuchar_delay, klobuchar_sigma, saastamoinen_delay
from testbed.rinex.obs import RinexObs
from testbed.rinex.settings import RinexSettings
from testbed.correlation import L1_WAVELENGTH_M
from testbed.sensors.gnss.errors import F_L1, IONO_FREE_FACTOR, sigma_multipath, sigma_noise, sigma_tropo
from testbed.sensors.gnss.navfile import MAX_AGE_S, NavData, nearest_records
from testbed.sensors.gnss.orbits import SYSTEM_NAMES, sat_states
from testbed.sensors.gnss.signals import FREQUENCY_HZ
from testbed.sensors.gnss.synth import rotate_z
from testbed.sensors.gnss.rinex_text import RinexError
from testbed.sensors.gnss.timebase import SECONDS_PER_WEEK, gps_seconds_to_calendar

#: REC # / TYPE of files `testbed export-rinex` writes: their ranges are iono-free-equivalent
TESTBED_RECEIVER = "TESTBED SYNTHETIC"
_FIX_ITERATIONS = 12
_FIX_TOL_M = 1e-4  # the fix's last step (m): far below what the corrections need
#: rounds of (delays at the fix, fix without the delays): a 20 m height error -> < 0.1 mm after 3
_ATMOSPHERE_ROUNDS = 3
#: RTKLIB 2.4.3 pntpos constants (rtklib.h / pntpos.c) for its single-point variance
_RTK_ERR, _RTK_ERATIO, _RTK_URA, _RTK_CBIAS = 0.003, 100.0, 2.4, 0.3
_RTK_ION_OFF, _RTK_TROP_OFF, _RTK_BRDCI, _RTK_SAAS = 5.0, 3.0, 0.5, 0.3


@dataclass(frozen=True)
class Formation:
    """How the observations were formed (printed in the summary, written beside the table)."""

    l1_code: str
    second_code: str | None
    ionosphere: str
    troposphere: str
    error_model: str
    counts: dict[str, int]  # measurement counts by reason (VISIBLE = used)
    notes: tuple[str, ...]
    fix_ecef: NDArray  # (E, 3) the preliminary fix per epoch (NaN where none)
    origin_lat_lon_h: tuple[float, float, float]
    systems: tuple[str, ...] = ("G",)  # the systems used, in G, E, C order
    skipped_systems: dict[str, str] = field(default_factory=dict)  # system letter -> why it was not used
    codes: dict[str, str] = field(default_factory=dict)  # system letter -> first-frequency code used
    second_codes: dict[str, str] = field(default_factory=dict)  # system letter -> second-frequency code used


def _first_present(obs: RinexObs, codes: tuple[str, ...], system: str = "G") -> str | None:
    cols = obs.system == system
    return next((c for c in codes if c in obs.values and np.isfinite(obs.values[c][:, cols]).any()), None)


def _codes_seen(obs: RinexObs, system: str = "G") -> str:
    """The codes that have values for ``system``'s satellites, and those declared that have none."""
    cols = obs.system == system
    declared = sorted(c for c in obs.values if c in obs.types.get(system, obs.values))
    seen = [c for c in declared if np.isfinite(obs.values[c][:, cols]).any()]
    empty = [c for c in declared if c not in seen]
    return f"with values: {', '.join(seen) or 'none'}" + (f"; declared, never given: {', '.join(empty)}" if empty
                                                           else "")


#: the settings naming each system's code preferences (first frequency, second frequency)
_CODE_SETTINGS = {"G": ("l1_codes", "second_codes"), "E": ("galileo_codes", "galileo_second_codes"),
                  "C": ("beidou_codes", "beidou_second_codes")}
_BAND_NAMES = {"G": "L1", "E": "E1", "C": "B1"}


def choose_systems(obs: RinexObs, nav: NavData, s: RinexSettings) -> tuple[tuple[str, ...], dict[str, str]]:
    """The systems to use and, for the others in the observation file, why not (see ``[rinex] systems``)."""
    present, in_nav = obs.systems, set(nav.systems)
    skipped: dict[str, str] = {}
    if s.systems == "auto":
        use = list(present)  # every system observed: the monitors solve one receiver clock per system
        for x in list(use):
            if x not in in_nav:
                skipped[x] = f"no {SYSTEM_NAMES[x]} records in {nav.path.name}"
                use.remove(x)
        if not use:
            raise RinexError(nav.path, f"no records of the observed systems ({', '.join(present)}; it holds "
                                       f"{', '.join(sorted(in_nav)) or 'none'}); expected a navigation file with "
                                       f"records of the systems observed in {obs.path.name}")
        return tuple(use), skipped
    for x in s.systems:
        if x not in present:
            raise RinexError(obs.path, f"[rinex] systems asks for {SYSTEM_NAMES[x]} ({x}), but the file has no "
                                       f"{x} satellite records (it has {', '.join(present)}); expected only "
                                       f"systems it observes")
        if x not in in_nav:
            raise RinexError(nav.path, f"[rinex] systems asks for {SYSTEM_NAMES[x]} ({x}), but the navigation file "
                                       f"has no {x} records (it has {', '.join(sorted(in_nav)) or 'none'}"
                                       f"{'; skipped: ' + ', '.join(nav.skipped) if nav.skipped else ''}); expected "
                                       f"a navigation file with {SYSTEM_NAMES[x]} records")
    for x in present:
        if x not in s.systems:
            skipped[x] = "not in [rinex] systems"
    return tuple(x for x in SYSTEM_NAMES if x in s.systems), skipped


def _only(obs: RinexObs, systems: tuple[str, ...]) -> RinexObs:
    """``obs`` with the satellites of ``systems`` only (itself when that is all of them)."""
    keep = np.isin(obs.system, list(systems))
    if keep.all():
        return obs
    return replace(obs, prn=obs.prn[keep], system=obs.system[keep], values={c: v[:, keep] for c, v in obs.values.items()},
                   types={x: t for x, t in obs.types.items() if x in systems})


def _resolve(obs: RinexObs, nav: NavData, s: RinexSettings
             ) -> tuple[dict[str, str], dict[str, str], str, str, list[str]]:
    notes = []
    l1, second = {}, {}
    for x in obs.systems:
        first_name, second_name = _CODE_SETTINGS[x]
        codes = getattr(s, first_name)
        code = _first_present(obs, codes, x)
        if code is None:
            what = f"{'L1' if x == 'G' else _BAND_NAMES[x]} pseudorange"
            raise RinexError(obs.path, f"no {what}: none of {list(codes)} has a value in a {SYSTEM_NAMES[x]} record "
                                       f"({_codes_seen(obs, x)}); expected {'an L1' if x == 'G' else 'a'} code "
                                       f"observation ([rinex] {first_name})")
        l1[x] = code
        sec = _first_present(obs, getattr(s, second_name), x)
        if sec is not None:
            second[x] = sec
    synthetic = obs.receiver_type == TESTBED_RECEIVER
    iono, tropo = s.ionosphere, s.troposphere
    if iono == "auto":
        iono = "off" if synthetic else ("iono_free" if len(second) == len(l1) else "klobuchar")
    if tropo == "auto":
        tropo = "off" if synthetic else "saastamoinen"
    if synthetic and (s.ionosphere == "auto" or s.troposphere == "auto"):
        notes.append("testbed export: ranges are iono-free-equivalent, atmosphere models off (docs/guide/rinex.md, the export)")
    if iono == "iono_free" and len(second) < len(l1):
        x = next(x for x in l1 if x not in second)
        codes = getattr(s, _CODE_SETTINGS[x][1])
        raise RinexError(obs.path, f"[rinex] ionosphere = 'iono_free' needs a second-frequency code, but none of "
                                   f"{list(codes)} has a value in a {SYSTEM_NAMES[x]} record ({_codes_seen(obs, x)}); "
                                   f"expected 'klobuchar' or 'off' for a single-frequency file")
    if iono == "klobuchar" and (nav.klobuchar_alpha is None or nav.klobuchar_beta is None):
        raise RinexError(nav.path, "no Klobuchar coefficients (ION ALPHA / ION BETA in RINEX 2, IONOSPHERIC CORR "
                                   "GPSA / GPSB in RINEX 3) in the header; the broadcast ionosphere needs them. "
                                   "Expected them, or [rinex] ionosphere = 'iono_free' or 'off'")
    if "C" in l1 and l1["C"][1] == "1" and iono != "iono_free":
        notes.append(f"BeiDou {l1['C']} (B1C): no group delay applied (a RINEX 3 BeiDou record carries TGD1 for B1I "
                     f"only)")
    return l1, (second if iono == "iono_free" else {}), iono, tropo, notes


def _span(t: NDArray) -> str:
    a, b = gps_seconds_to_calendar(float(np.min(t))), gps_seconds_to_calendar(float(np.max(t)))
    return f"{a:%Y-%m-%d %H:%M} .. {b:%Y-%m-%d %H:%M} GPST (GPS week {int(np.min(t) // SECONDS_PER_WEEK)})"


def one_clock_rows(use: NDArray, system: NDArray) -> NDArray:
    """The rows (E, S) a one-clock fix may use: the satellites of the system with the most usable ones, at the
    epochs where it has four (the other systems' ranges hold their own receiver clock offsets, which a one-clock
    fix would read as position); every usable row at the other epochs."""
    letters, counts = np.unique(system, return_counts=True) if np.size(system) else ((), ())
    if len(letters) < 2:
        return use
    main = max(letters, key=lambda x: use[:, system == x].sum())
    own = use & (system == main)
    return np.where((own.sum(1) >= 4)[:, None], own, use)


def preliminary_fix(sat: NDArray, z: NDArray, use: NDArray, r0: NDArray) -> tuple[NDArray, NDArray]:
    """Unweighted Gauss-Newton ECEF fix per epoch, light time and Earth rotation re-solved each iteration.

    sat : (E, S, 3) transmit-time positions in the transmit-time ECEF frame.  z : (E, S) corrected ranges.
    r0 : (3,) or (E, 3) start (the Earth's centre converges in ~6 iterations; a previous fix in 1-2).
    Returns (r (E, 3), clock (E,) m); NaN where fewer than 4 rows. Compiled (:mod:`testbed.rinex.kernels`).
    """
    from testbed.rinex.kernels import ecef_fix

    E = z.shape[0]
    r0 = np.ascontiguousarray(np.broadcast_to(np.nan_to_num(np.asarray(r0, float)), (E, 3)))
    r, b = np.empty((E, 3)), np.empty(E)
    ecef_fix(np.ascontiguousarray(np.nan_to_num(sat)), np.ascontiguousarray(np.nan_to_num(z)),
             np.ascontiguousarray(use), r0, _FIX_ITERATIONS, _FIX_TOL_M, r, b)
    return r, b


def preliminary_fix_numpy(sat: NDArray, z: NDArray, use: NDArray, r0: NDArray) -> tuple[NDArray, NDArray]:
    """The numpy reference of :func:`preliminary_fix` (all epochs iterate until the slowest converges)."""
    E = z.shape[0]
    r0 = np.broadcast_to(np.nan_to_num(np.asarray(r0, float)), (E, 3))
    r, b = r0.copy(), np.zeros(E)
    ok = use.sum(1) >= 4
    zz = np.where(use, z, 0.0)
    for _ in range(_FIX_ITERATIONS):
        tau = np.linalg.norm(sat - r[:, None], axis=-1) / C_LIGHT
        s_rx = rotate_z(sat, OMEGA_EARTH * tau)
        d = s_rx - r[:, None]
        rho = np.where(use, np.linalg.norm(d, axis=-1), 1.0)
        G = np.concatenate([-d / rho[..., None], np.ones(rho.shape + (1,))], -1) * use[..., None]
        res = np.where(use, zz - rho - b[:, None], 0.0)
        N = np.einsum("esi,esj->eij", G, G)
        N[~ok] = np.eye(4)
        dx = np.linalg.solve(N, np.einsum("esi,es->ei", G, res)[..., None])[..., 0]
        dx[~ok] = 0.0
        r += dx[:, :3]
        b += dx[:, 3]
        if np.max(np.abs(dx[:, :3]), initial=0.0) < _FIX_TOL_M:
            break
    r[~ok] = np.nan
    b[~ok] = np.nan
    return r, b


def hold_last_fix(r: NDArray) -> NDArray:
    """Epochs without a fix take the nearest earlier one (else the first later one)."""
    ok = np.isfinite(r).all(1)
    idx = np.where(ok, np.arange(r.shape[0]), -1)
    idx = np.maximum.accumulate(idx)
    first = int(np.argmax(ok))
    idx[idx < 0] = first
    return r[idx]


def _sigma(s: RinexSettings, el: NDArray, iono: str, iono_m: NDArray, iono_sig: NDArray, tropo: str,
           dual_factor: float) -> NDArray:
    sin_el = np.sin(np.clip(el, 1e-3, None))
    if s.error_model == "user":
        return np.sqrt(s.sigma_a_m**2 + (s.sigma_b_m / sin_el) ** 2)
    if s.error_model == "rtklib":  # pntpos.c varerr() + rescode(): code, URA, code bias, iono, tropo terms
        var = _RTK_ERATIO**2 * (_RTK_ERR**2 + _RTK_ERR**2 / sin_el) * (9.0 if iono == "iono_free" else 1.0)
        var = var + _RTK_URA**2 + _RTK_CBIAS**2
        var = var + {"off": _RTK_ION_OFF**2, "iono_free": 0.0}.get(iono, 0.0) + (
            (_RTK_BRDCI * iono_m) ** 2 if iono == "klobuchar" else 0.0)
        var = var + (_RTK_TROP_OFF**2 if tropo == "off" else (_RTK_SAAS / (sin_el + 0.1)) ** 2)
        return np.sqrt(var)
    air = dual_factor * np.hypot(sigma_multipath(el), sigma_noise(el))
    return np.sqrt(s.sigma_ura_m**2 + sigma_tropo(el, s.sigma_tropo_zenith_m) ** 2 + air**2 + iono_sig**2)


def _look_and_delays(sat: NDArray, r: NDArray, t_tag: NDArray, iono: str, tropo: str, nav: NavData,
                     carrier_hz: NDArray | float = F_L1):
    """Elevation, azimuth (rad) and the modelled ionosphere (delay, residual 1σ) and troposphere (m) at fix ``r``.
    The broadcast ionosphere (an L1 delay) is scaled by (f_L1/f)² to each satellite's carrier (B1I)."""
    E, S = sat.shape[:2]
    lat, lon, h = ecef_to_geodetic(r)
    tau = np.linalg.norm(sat - r[:, None], axis=-1) / C_LIGHT
    los = np.einsum("eij,esj->esi", R_ecef_to_enu(lat, lon), rotate_z(sat, OMEGA_EARTH * tau) - r[:, None])
    el = np.arctan2(los[..., 2], np.hypot(los[..., 0], los[..., 1]))
    az = np.arctan2(los[..., 0], los[..., 1])
    latr, lonr = np.radians(lat)[:, None], np.radians(lon)[:, None]
    iono_m, iono_sig = np.zeros((E, S)), np.zeros((E, S))
    if iono == "klobuchar":
        tow = np.mod(t_tag, SECONDS_PER_WEEK)[:, None]
        iono_m = klobuchar_delay(nav.klobuchar_alpha, nav.klobuchar_beta, latr, lonr, np.clip(el, 0, None), az, tow)
        iono_sig = klobuchar_sigma(latr, lonr, np.clip(el, 0, None), az, iono_m)
        if np.any(np.asarray(carrier_hz) != F_L1):
            scale = (F_L1 / np.asarray(carrier_hz)) ** 2
            iono_m, iono_sig = iono_m * scale, iono_sig * scale
    tropo_m = saastamoinen_delay(latr, h[:, None], el) if tropo == "saastamoinen" else np.zeros((E, S))
    return el, az, iono_m, iono_sig, tropo_m


def form_epochs(obs: RinexObs, nav: NavData, settings: RinexSettings) -> tuple[GnssEpochs, Formation]:
    """GnssEpochs (the monitors' input; ``t`` from the first tag) and how they were formed.

    Satellites of the systems :func:`choose_systems` keeps, in the observation file's order (G, E, C);
    ``prn`` repeats across systems (G05 and E05 are two slots): the formation's ``systems`` and the
    summary name them."""
    s = settings
    systems, skipped_systems = choose_systems(obs, nav, s)
    obs = _only(obs, systems)
    l1s, seconds, iono, tropo, notes = _resolve(obs, nav, s)
    E, S = obs.t_tag.size, obs.prn.size
    p1, f1 = _per_system(obs, l1s)
    reason = np.full((E, S), NotVisible.NOT_OBSERVED, np.int8)
    have = np.isfinite(p1) & (p1 > 1e6)  # a code range is > 1000 km; zeros and junk are not measurements
    if seconds:
        p2, f2 = _per_system(obs, seconds)
        reason[have & ~np.isfinite(p2)] = NotVisible.NO_SECOND_FREQUENCY
        have &= np.isfinite(p2)
    rec = nearest_records(nav.eph, obs.prn, obs.t_tag, system=obs.system)
    reason[have & (rec < 0)] = NotVisible.NO_EPHEMERIS
    use = have & (rec >= 0)
    if not use.any():
        toe = nav.eph.toe_gps
        raise RinexError(nav.path, f"no broadcast record within {MAX_AGE_S / 3600:.0f} h of any observation: the "
                                   f"observation file {obs.path.name} spans {_span(obs.t_tag)}, the navigation "
                                   f"file's records {_span(toe)}; expected a navigation file for the same day")
    flat = np.flatnonzero(use)
    eph = nav.eph.take(rec.ravel()[flat])
    e_idx = flat // S
    tx = obs.t_tag[e_idx] - p1.ravel()[flat] / C_LIGHT
    # Δt_sv at tx instead of at tx − Δt_sv: they differ by Δt_sv times the clock's rate (< 1e-3 s × 1e-9 s/s)
    clk = sat_states(eph, tx, per_slot=True)[2]
    pos, vel, clk, clk_rate = sat_states(eph, tx - clk, per_slot=True)
    sat = np.full((E, S, 3), np.nan)
    sat_v = np.full((E, S, 3), np.nan)
    dts, dts_rate, tgd = np.zeros((E, S)), np.zeros((E, S)), np.zeros((E, S))
    health = np.zeros((E, S), np.int64)
    sat.reshape(-1, 3)[flat], sat_v.reshape(-1, 3)[flat] = pos, vel
    dts.ravel()[flat], dts_rate.ravel()[flat], tgd.ravel()[flat] = clk, clk_rate, eph.tgd
    if "C" in l1s and l1s["C"][1] != "2":  # TGD1 is B1I's; a B1C range gets none (see _resolve)
        tgd[:, obs.system == "C"] = 0.0
    health.ravel()[flat] = eph.health
    reason[use & (health != 0)] = NotVisible.UNHEALTHY
    use &= health == 0
    if seconds:
        code = (f1**2 * p1 - f2**2 * p2) / (f1**2 - f2**2)
        dual_factor = np.sqrt(f1**4 + f2**4) / (f1**2 - f2**2)
    else:
        code = p1 - C_LIGHT * tgd
        dual_factor = IONO_FREE_FACTOR if iono == "off" and obs.receiver_type == TESTBED_RECEIVER else 1.0
    z_geo = code + C_LIGHT * dts  # geometric range + receiver clock + atmosphere + errors
    sat0 = np.where(use[..., None], sat, 0.0)
    r_fix, _ = preliminary_fix(sat0, z_geo, one_clock_rows(use, obs.system), obs.approx_pos_ecef)
    if not np.isfinite(r_fix).any():
        if not np.any(obs.approx_pos_ecef):
            raise RinexError(obs.path, "no epoch has 4 satellites with ephemerides, and the header has no APPROX "
                                       "POSITION XYZ: expected at least one epoch with 4 usable satellites")
        r_fix = np.broadcast_to(obs.approx_pos_ecef, (E, 3)).astype(float)
    r_ref = hold_last_fix(r_fix)
    sat_use = use.copy()
    for _ in range(_ATMOSPHERE_ROUNDS):  # the delays at the fix, the fix with the delays removed
        el, az, iono_m, iono_sig, tropo_m = _look_and_delays(sat0, r_ref, obs.t_tag, iono, tropo, nav, f1)
        sat_use = use & (el >= np.radians(s.elevation_mask_deg))
        z = z_geo - iono_m - tropo_m
        r2, _ = preliminary_fix(np.where(sat_use[..., None], sat, 0.0), z, one_clock_rows(sat_use, obs.system),
                                r_ref)
        r_ref = hold_last_fix(np.where(np.isfinite(r2), r2, r_ref))
    reason[use & ~sat_use] = NotVisible.BELOW_MASK
    use = sat_use
    reason[use] = NotVisible.VISIBLE
    tau = np.linalg.norm(np.where(use[..., None], sat, 0.0) - r_ref[:, None], axis=-1) / C_LIGHT
    s_rx = rotate_z(sat, OMEGA_EARTH * tau)
    v_rx = rotate_z(sat_v, OMEGA_EARTH * tau)
    rr = _range_rate_from_doppler(obs, l1s) + C_LIGHT * dts_rate
    sigma = _sigma(s, el, iono, iono_m, iono_sig, tropo, dual_factor)
    first = r2[np.isfinite(r2).all(1)][0] if np.isfinite(r2).any() else r_ref[0]  # noqa: F821 (set in the loop)
    origin = (tuple(float(x) for x in s.origin) if s.origin != "first_fix"
              else tuple(float(np.asarray(x)) for x in ecef_to_geodetic(first)))
    epochs = GnssEpochs(t=obs.t_tag - obs.t_tag[0], t_gps=obs.t_tag.copy(), prn=obs.prn.copy(), system=obs.system.copy(),
                        sat_pos_ecef=np.where(use[..., None], s_rx, np.nan),
                        sat_vel_ecef=np.where(use[..., None], v_rx, np.nan),
                        pseudorange=np.where(use, z, np.nan), range_rate=np.where(use, rr, np.nan),
                        sigma=np.where(use, sigma, np.nan), visible=use, reason=reason,
                        antenna=Mount(np.zeros(3)))
    observed = reason[np.isfinite(p1)]
    counts = {NotVisible(k).name: int((observed == k).sum()) for k in np.unique(observed)}
    main = "G" if "G" in l1s else systems[0]
    return epochs, Formation(l1_code=l1s[main], second_code=seconds.get(main), ionosphere=iono, troposphere=tropo,
                             error_model=s.error_model, counts=counts, notes=tuple(notes), fix_ecef=r2,
                             origin_lat_lon_h=origin, systems=systems, skipped_systems=skipped_systems,
                             codes=l1s, second_codes=seconds)


def _per_system(obs: RinexObs, codes: dict[str, str]) -> tuple[NDArray, NDArray]:
    """(E, S) values of each system's code in its satellites' columns, and (S,) the carrier of each."""
    if set(codes) == {"G"} and (obs.system == "G").all():  # one system: the column as it is
        return obs.values[codes["G"]], np.full(obs.prn.shape, FREQUENCY_HZ["G"][codes["G"][1]])
    v = np.full((obs.t_tag.size, obs.prn.size), np.nan)
    f = np.full(obs.prn.shape, np.nan)
    for x, c in codes.items():
        cols = obs.system == x
        v[:, cols] = obs.values[c][:, cols]
        f[cols] = FREQUENCY_HZ[x][c[1]]
    return v, f


#: Doppler codes of each system's first band, in order of preference after the code's own
_DOPPLERS = {"G": ("D1C", "D1W", "D1X", "D1P"), "E": ("D1C", "D1X", "D1B"), "C": ("D1P", "D1X", "D1D", "D2I", "D2X")}


def _range_rate_from_doppler(obs: RinexObs, codes: dict[str, str]) -> NDArray:
    """(E, S) −Doppler·λ (m/s) on each system's code band (NaN where none): the Doppler of the code's own
    signal when given, else another on the same band."""
    E, S = obs.t_tag.size, obs.prn.size
    if set(codes) == {"G"} and (obs.system == "G").all():  # GPS as it always was: L1 Dopplers, λ_L1
        dop = next((obs.values[c] for c in _DOPPLERS["G"] if c in obs.values), np.full((E, S), np.nan))
        return -dop * L1_WAVELENGTH_M
    rr = np.full((E, S), np.nan)
    for x, c in codes.items():
        cols = obs.system == x
        own = "D" + c[1:]
        cands = [own] + [d for d in _DOPPLERS[x] if d[1] == c[1] and d != own]
        d = next((d for d in cands if d in obs.values and np.isfinite(obs.values[d][:, cols]).any()), None)
        if d is not None:
            rr[:, cols] = -obs.values[d][:, cols] * (C_LIGHT / FREQUENCY_HZ[x][c[1]])
    return rr
