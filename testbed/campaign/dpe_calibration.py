"""``testbed calibrate-dpe``: K of the DPE's VPL from fault-free sorties, validated on held-out ones (DPE.md §6).

Fly the approach once; for each sortie, the same trajectory at another start time (spread over
24 h), with its own GNSS and correlator draws, a C/N0 offset and a multipath setting from the
strata (cycled); run the dpe monitor; collect z = (e − m)/σ on every epoch with a solution.
The calibration set C and the validation set V use disjoint seed spawn keys and start times
shifted by half a spacing. K is fitted on C (:func:`~testbed.integrity.dpe.calibration.fit_k_tail`),
raised to the worst stratum's if one needs more, and checked on V; the file records K with
its provenance, and the monitor reads it (``[dpe] k_factor = "path.json"``).

Epochs count as independent (N_eff = N): the SIS error and the correlator noise are white from
epoch to epoch in this model (stated in the file). DPE.md §6 sizes C at 3.6e6 epochs; a short
run extrapolates from shallower tails, and the file says how deep its levels went.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
from pathlib import Path
from typing import Any, Callable

import numpy as np

from testbed.integrity.dpe.calibration import KFit, fit_k_tail, settings_fingerprint, validate

#: strata cycled over the sorties (DPE.md §6's set C)
CN0_OFFSETS_DB = (0.0, -3.0, -6.0)
MULTIPATH = ("off", "ground")
ASSUMPTION = ("the normalised errors' tails beyond the deepest measured level are no heavier than the Gaussian "
              "fitted to the measured ones; epochs independent (white SIS and correlator noise per epoch)")

def _sortie_errors(ap, setup, truth_g, mon, offset_s: float, cn0_db: float, multipath: str, key: tuple[int, int],
                   seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One sortie: (z, e, σ, m) on its epochs with a solution."""
    from testbed.integrity.monitor import Observations
    from testbed.sensors.gnss.correlators import synthesize_correlators
    from testbed.sensors.gnss.synth import gnss_geometry, sample_gnss

    cs = setup.gnss.correlators.model_copy(update={"cn0_offset_db": setup.gnss.correlators.cn0_offset_db + cn0_db,
                                                   "multipath": multipath})
    gs = setup.gnss.model_copy(update={"correlators": cs})
    start = ap.config.start_time_utc + dt.timedelta(seconds=offset_s)
    geom = gnss_geometry(truth_g, setup.antenna, gs, start_utc=start, terrain=setup.terrain)
    ss = np.random.SeedSequence(seed, spawn_key=key)
    g_gnss, g_corr = ss.spawn(2)
    g, gt = sample_gnss(geom, gs, rng=np.random.default_rng(g_gnss))
    corr, _ = synthesize_correlators(g, gt, truth_g, gs, g_corr.generate_state(4))
    out, _ = mon.step(Observations(g, correlators=corr), mon.initial_state())
    d = out.diagnostics
    ok = out.reason == 0
    true_u = setup.frame.ecef_to_enu(gt.antenna_pos_ecef)[:, 2]
    e = out.pos_enu[:, 2] - true_u
    sigma = np.hypot(d.sigma_ob, d.sigma_sis_u) if mon.settings.sis == "add" else d.sigma_ob
    return ((e - d.median_m) / sigma)[ok], e[ok], sigma[ok], d.median_m[ok]


def calibrate_dpe(approach: str | Path = "zunz-rwy05-dpe", *, sorties: int = 60, p_hmi: float = 1e-7, seed: int = 0,
                  progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Fit K on ``sorties`` fault-free sorties and validate it on as many held-out ones (module doc).

    Returns the calibration record (what ``testbed calibrate-dpe`` writes).
    """
    from testbed.config import load_approach
    from testbed.flight.fly import fly
    from testbed.integrity.dpe.monitor import DpeMonitor, DpeSettings
    from testbed.integrity.monitor import MonitorContext
    from testbed.sim.preflight import preflight

    if sorties < 6:
        raise ValueError(f"sorties: expected at least 6 (one per stratum), got {sorties}")
    if not 0 < p_hmi < 0.01:
        raise ValueError(f"p_hmi: expected a probability below 0.01, got {p_hmi}")
    say = progress or (lambda _: None)
    ap = load_approach(approach)
    # the K being fitted replaces the approach's (whose record may be for the settings before a change)
    ap = dataclasses.replace(ap, config=ap.config.model_copy(update={"dpe": {**ap.config.dpe, "k_factor": 1.0}}))
    setup = preflight(ap)
    settings = DpeSettings.model_validate({**ap.config.dpe, "k_factor": 1.0})
    fingerprint, cover = settings_fingerprint(settings, setup.gnss.correlators)
    mon = DpeMonitor("dpe", MonitorContext(frame=setup.frame, integrity=setup.integrity), settings)
    mon.prepare()
    truth_g = fly(ap.flight_plan, setup.terrain).truth.decimate(setup.gnss.rate_hz)
    spacing = 86400.0 / sorties
    sets: dict[str, dict[str, list]] = {}
    for name, set_key, shift in (("calibration", 0, 0.0), ("validation", 1, 0.5 * spacing)):
        acc = {"z": [], "e": [], "sigma": [], "m": [], "stratum": []}
        for j in range(sorties):
            cn0, mp = CN0_OFFSETS_DB[j % 3], MULTIPATH[(j // 3) % 2]
            z, e, s, m = _sortie_errors(ap, setup, truth_g, mon, j * spacing + shift, cn0, mp, (set_key, j), seed)
            for k, v in (("z", z), ("e", e), ("sigma", s), ("m", m)):
                acc[k].append(v)
            acc["stratum"].append(np.full(z.size, (j % 3) + 3 * ((j // 3) % 2)))
            if (j + 1) % 10 == 0 or j + 1 == sorties:
                say(f"{name}: {j + 1}/{sorties} sorties, {sum(a.size for a in acc['z'])} epochs")
        sets[name] = {k: np.concatenate(v) for k, v in acc.items()}
    c, v = sets["calibration"], sets["validation"]
    overall = fit_k_tail(c["z"], p_hmi)
    strata = {}
    for s in range(6):
        zs = c["z"][c["stratum"] == s]
        if zs.size > 1000:
            strata[f"cn0 {CN0_OFFSETS_DB[s % 3]:+g} dB, multipath {MULTIPATH[s // 3]}"] = fit_k_tail(zs, p_hmi)
    worst_name, worst = max(strata.items(), key=lambda kv: kv[1].k, default=("", overall))
    chosen: KFit = worst if worst.k > overall.k else overall
    check = validate(chosen, v["z"], np.abs(v["e"]) > chosen.k * v["sigma"] + np.abs(v["m"]))
    return {
        "what": "K of the dpe monitor's VPL = K*sigma + |median| (testbed calibrate-dpe)",
        "k": chosen.k, "sigma_z": chosen.sigma_z, "b_z": chosen.b_z, "p_hmi": p_hmi,
        "estimator": chosen.estimator, "binding": {"side": chosen.binding_side, "tail_level": chosen.binding_level},
        "k_from": f"stratum '{worst_name}'" if chosen is worst and worst is not overall else "all strata",
        "overall": {"k": overall.k, "sigma_z": overall.sigma_z, "b_z": overall.b_z},
        "strata": {n: {"k": f.k, "sigma_z": f.sigma_z, "n": f.n} for n, f in strata.items()},
        "n": chosen.n, "n_eff": chosen.n_eff, "n_calibration": int(c["z"].size), "deepest_level": 100.0 / overall.n_eff,
        "validation": {"passed": check.passed, "tails_hold": check.tails_hold, "worst_ratio": check.worst_ratio,
                       "levels_checked": check.levels_checked, "exceedances": check.exceedances,
                       "allowed": check.allowed, "epochs": check.epochs},
        "approach": ap.name, "sorties_per_set": sorties, "seed": seed,
        "seed_keys": {"calibration": "SeedSequence(seed, spawn_key=(0, sortie))",
                      "validation": "SeedSequence(seed, spawn_key=(1, sortie))"},
        "start_offsets_s": {"calibration": f"sortie * {spacing:g}", "validation": f"sortie * {spacing:g} + {spacing / 2:g}"},
        "strata_cycle": {"cn0_offset_db": list(CN0_OFFSETS_DB), "multipath": list(MULTIPATH)},
        "fingerprint": fingerprint, "settings": cover, "assumption": ASSUMPTION,
        "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
    }


def write_record(record: dict, path: Path) -> None:
    """Write beside the target, then rename (an interrupted write never replaces an earlier file)."""
    path = Path(path)
    part = path.with_name(path.name + ".part")
    part.write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")
    part.replace(path)
