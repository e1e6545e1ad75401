"""A synthetic DPE scene for tests: satellites at chosen elevations over a static antenna.

The GNSS observations and truth are built by hand (no flight); the correlograms come from
the sensor's own :func:`synthesize_correlators`, so a test exercises sensor and monitor.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from testbed.frames import LocalFrame
from testbed.integrity.monitor import MonitorContext, Observations
from testbed.integrity.settings import IntegritySettings
from testbed.records import GnssEpochs, GnssTruth, Mount
from testbed.sensors.gnss.correlators import synthesize_correlators
from testbed.sensors.gnss.settings import GnssSettings

FRAME = LocalFrame(29.2958478, 94.3224478, 2939.0)
#: the reference epoch of docs/design/dpe.md §4.3: 8 satellites at 75 ... 10 deg
ELEVATIONS = (75.0, 55.0, 40.0, 35.0, 25.0, 20.0, 15.0, 10.0)
TRUTH_ENU = np.array([120.0, -80.0, 450.0])
CLOCK_M = 5000.0


def scene(T: int = 3, *, elevations=ELEVATIONS, gnss: GnssSettings | None = None, bias_m: dict | None = None,
          pr_sigma_m: float = 3.0, seed: int = 0, first_epoch: int = 0, agl_m: float = 300.0):
    """(Observations, CorrelatorTruth, antenna ENU (T, 3)) of T static epochs.

    bias_m : {satellite index: code-phase bias (m)} on every epoch (in the pseudorange and the code).
    """
    gs = gnss or GnssSettings()
    el = np.radians(np.asarray(elevations, float))
    S = el.size
    az = np.radians(np.arange(S) * (360.0 / S) + 17.0)
    los = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)
    sat_enu = TRUTH_ENU + 2.2e7 * los
    sat = np.broadcast_to(FRAME.enu_to_ecef(sat_enu), (T, S, 3)).copy()
    ant = np.broadcast_to(FRAME.enu_to_ecef(TRUTH_ENU), (T, 3)).copy()
    rng_m = np.linalg.norm(sat - ant[:, None], axis=-1)
    fault = np.zeros((T, S))
    for k, b in (bias_m or {}).items():
        fault[:, k] = b
    rng = np.random.default_rng(seed)
    noise = pr_sigma_m * rng.standard_normal((T, S))
    pr = rng_m + CLOCK_M + noise + fault
    t = np.arange(T, dtype=float) + first_epoch
    vis = np.ones((T, S), bool)
    g = GnssEpochs(t=t, t_gps=1.4e9 + t, prn=np.arange(1, S + 1), sat_pos_ecef=sat, sat_vel_ecef=np.zeros((T, S, 3)),
                   pseudorange=pr, range_rate=np.zeros((T, S)), sigma=np.full((T, S), pr_sigma_m), visible=vis,
                   reason=np.zeros((T, S), np.int8), antenna=Mount(lever_arm_body=np.zeros(3)))
    gt = GnssTruth(antenna_pos_ecef=ant, geometric_range=rng_m, clock_bias=np.full(T, CLOCK_M), noise=noise,
                   fault_bias=fault, faulty=fault != 0, elevation=np.broadcast_to(el, (T, S)).copy(),
                   azimuth=np.broadcast_to(az, (T, S)).copy())
    truth = SimpleNamespace(agl=np.full(T, agl_m), vel_enu=np.zeros((T, 3)))
    words = np.random.SeedSequence(seed + 1000).generate_state(4)
    corr, ct = synthesize_correlators(g, gt, truth, gs, words, first_epoch=first_epoch)
    return Observations(g, correlators=corr), ct, np.broadcast_to(TRUTH_ENU, (T, 3))


def context(**integrity) -> MonitorContext:
    return MonitorContext(frame=FRAME, integrity=IntegritySettings(**integrity))
