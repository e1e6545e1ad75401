"""Test helpers for the integrity core: DO-229 almanac geometry and synthetic GNSS epochs.

Independent of ``testbed.sensors.gnss`` (written in parallel): circular-orbit
satellite positions straight from the RTCA DO-229 24-satellite almanac
(testbed/data/do229_gps_almanac_24sat.tsv; IS-GPS-200 Table 20-IV equations
with e = 0, ω = 0), the VA-RAIM paper's eq. 27 sigma model, and Gaussian noise.
The file also checks the helpers against published orbit facts.
"""

from __future__ import annotations

from importlib import resources

import numpy as np

from testbed.frames import OMEGA_EARTH, enu_to_az_el
from testbed.records import GnssEpochs, Mount, NotVisible

MU_GPS = 3.986005e14  # m³/s², IS-GPS-200 WGS84 value
F_L1, F_L5 = 1575.42e6, 1176.45e6


def load_almanac() -> dict[str, np.ndarray]:
    path = resources.files("testbed") / "data" / "do229_gps_almanac_24sat.tsv"
    rows = [ln.split("\t") for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    head, data = rows[0], rows[1:]
    cols = {h: np.array([float(r[k]) for r in data]) for k, h in enumerate(head)}
    cols["prn"] = cols["prn"].astype(int)
    return cols


def sat_pos_ecef(t_week_s: np.ndarray) -> np.ndarray:
    """ECEF positions (T, 24, 3) m of the almanac satellites at GPS time-of-week ``t_week_s`` (T,)."""
    alm = load_almanac()
    t = np.asarray(t_week_s, float)[:, None]
    a = alm["sqrt_a_m05"] ** 2
    n = np.sqrt(MU_GPS / a**3)
    tk = t - alm["toa_s"]
    u = alm["mean_anomaly_rad"] + n * tk + alm["arg_perigee_rad"]  # e = 0: true = mean anomaly
    Om = alm["raan_at_toa_rad"] + (alm["raan_rate_rad_s"] - OMEGA_EARTH) * tk - OMEGA_EARTH * alm["toa_s"]
    i = alm["inclination_rad"]
    xp, yp = a * np.cos(u), a * np.sin(u)
    return np.stack([xp * np.cos(Om) - yp * np.cos(i) * np.sin(Om),
                     xp * np.sin(Om) + yp * np.cos(i) * np.cos(Om),
                     yp * np.sin(i)], axis=-1)


def sigma_seed(el_rad: np.ndarray) -> np.ndarray:
    """The VA-RAIM paper's eq. 27 pseudorange sigma (m) at elevation ``el_rad``."""
    el_deg = np.degrees(el_rad)
    s_ura = 0.75
    s_tropo = 0.12 * 1.001 / np.sqrt(0.002001 + np.sin(el_rad) ** 2)
    s_mp = 0.13 + 0.53 * np.exp(-el_deg / 10.0)
    s_noise = 0.15 + 0.43 * np.exp(-el_deg / 6.9)
    s_user2 = (s_mp**2 + s_noise**2) * (F_L1**4 + F_L5**4) / (F_L1**2 - F_L5**2) ** 2
    return np.sqrt(s_ura**2 + s_tropo**2 + s_user2)


def make_gnss(frame, rx_enu: np.ndarray, t_week_s: np.ndarray, rng: np.random.Generator | None,
              batch: tuple[int, ...] = (), clock_m: float = 1234.5, mask_deg: float = 5.0,
              bias: np.ndarray | None = None) -> tuple[GnssEpochs, np.ndarray, np.ndarray]:
    """Synthetic GnssEpochs at a receiver ``rx_enu`` (T, 3) in ``frame``.

    Returns (gnss, geometric-only pseudorange without noise (T, S), sigma (T, S)).
    ``bias`` (B..., T, S) is added after the noise. ``rng=None`` gives noise-free data.
    """
    t_week_s = np.asarray(t_week_s, float)
    T = len(t_week_s)
    sat = sat_pos_ecef(t_week_s)  # (T, S, 3)
    rx_ecef = frame.enu_to_ecef(rx_enu)
    los_enu = frame.vec_ecef_to_enu(sat - rx_ecef[:, None, :])
    _, el = enu_to_az_el(los_enu)
    vis = el > np.radians(mask_deg)
    sig = sigma_seed(np.maximum(el, 0.0))
    rho0 = np.linalg.norm(sat - rx_ecef[:, None, :], axis=-1) + clock_m
    shape = batch + (T, sat.shape[1])
    noise = np.zeros(shape) if rng is None else rng.standard_normal(shape) * sig
    pr = rho0 + noise + (0.0 if bias is None else bias)
    vis_b = np.broadcast_to(vis, shape)
    pr = np.where(vis_b, pr, np.nan)
    gnss = GnssEpochs(
        t=t_week_s - t_week_s[0], t_gps=t_week_s, prn=load_almanac()["prn"],
        sat_pos_ecef=np.broadcast_to(sat, shape + (3,)), sat_vel_ecef=np.zeros(shape + (3,)),
        pseudorange=pr, range_rate=np.where(vis_b, 0.0, np.nan), sigma=np.broadcast_to(sig, shape).copy(),
        visible=vis_b.copy(), reason=np.where(vis_b, NotVisible.VISIBLE, NotVisible.BELOW_MASK).astype(np.int8),
        antenna=Mount(lever_arm_body=np.zeros(3)))
    return gnss, rho0, sig


def test_almanac_orbits_match_published_gps_facts():
    """Radius 26 559.7 km (sqrt(a) = 5153.62), ground track repeating each sidereal day, 55° inclination."""
    pos = sat_pos_ecef(np.array([0.0, 86164.1]))
    r = np.linalg.norm(pos, axis=-1)
    one_metre = 1.0
    np.testing.assert_allclose(r, 5153.620087**2, atol=one_metre)
    # two orbits (2 × 43 077.6 s) take 8.5 s less than a sidereal day: the
    # track repeats to 8.5 s × 3.87 km/s ≈ 33 km
    assert np.max(np.linalg.norm(pos[1] - pos[0], axis=-1)) < 2e5
    lat = np.degrees(np.arcsin(pos[..., 2] / r))
    assert 54.0 < lat.max() <= 55.0 + 1e-9


def test_sigma_seed_iono_free_factor():
    """docs/design/integrity.md §1 (eq. 1.4): the iono-free factor is about 2.59."""
    f = np.sqrt((F_L1**4 + F_L5**4) / (F_L1**2 - F_L5**2) ** 2)
    assert abs(f - 2.59) < 0.01
    s = sigma_seed(np.radians(np.array([5.0, 90.0])))
    assert s[0] > s[1] > 0.75
