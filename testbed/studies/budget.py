"""The resource estimates of the studies: a paper's reproduction (a sequence of campaigns) and the DPE's K
calibration, built on the campaign estimate (:mod:`testbed.campaign.budget`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from testbed.campaign.budget import campaign_estimate, sequence_estimate
from testbed.campaign.spec import load_spec
from testbed.config import load_approach
from testbed.sim.budget import (BASE_BYTES, FLIGHT_SECONDS_PER_S, Estimate, correlator_seconds, correlator_trial_bytes,
                                sortie_shape)
from testbed.studies.reproduce import FULL_TRIALS, QUICK_TRIALS, loaded_experiments
from testbed.studies.reproduce_dpe import CAMPAIGNS as DPE_CAMPAIGNS, QUICK_TRIALS as DPE_QUICK_TRIALS

def reproduction_estimate(paper: str, full: bool, *, workers: int | str = "auto", out_dir=None,
                          resume: bool = False) -> Estimate | None:
    """``testbed reproduce``: va-raim-2015's experiments one after the other, dpe-vertical's campaign (its
    per-epoch cases are seconds); None for won-2013, whose two sizes are fixed (19 min with --full)."""

    if paper == "va-raim-2015":
        out = Path(out_dir) if out_dir is not None else None
        parts = [campaign_estimate(loaded, workers=workers, out_dir=None if out is None else out / name,
                                   resume=True)  # a stored experiment resumes (reproduce_va_raim_2015)
                 for name, loaded in loaded_experiments(FULL_TRIALS if full else QUICK_TRIALS).items()]
        return sequence_estimate(f"reproduce va-raim-2015{' --full' if full else ''}", parts)
    if paper == "dpe-vertical":
        trials = 2000 if full else DPE_QUICK_TRIALS
        parts = [campaign_estimate(load_spec(name, trials=trials), workers=1, resume=True,
                                   out_dir=None if out_dir is None else Path(out_dir) / name) for name in DPE_CAMPAIGNS]
        est = sequence_estimate(f"reproduce dpe-vertical{' --full' if full else ''}", parts)
        return Estimate(est.what, est.memory, est.time, (f"without --full: {DPE_QUICK_TRIALS} sorties per cell",),
                        cores=est.cores)
    return None


#: the DPE solves per epoch of a ground-echo stratum in ``calibrate-dpe --method importance``: the epoch's copies
#: (2.25 on average at 480 sorties a set, docs/design/dpe.md §6.8) and the pilot on its expected correlograms
IMPORTANCE_ECHO_SOLVES = 2.25 + 1.0


def calibration_estimate(approach: str, sorties: int, trajectories: tuple[str, ...] = (), method: str = "tail",
                         workers: int = 1) -> Estimate:
    """``testbed calibrate-dpe``: 2 x ``sorties`` sorties of the dpe monitor (calibration and held-out), each a
    whole flight of one of the trajectories (the approach's own by default) with the approach's correlator
    settings, one trial at a time. ``method = "importance"``: the ground-echo strata solve each epoch
    :data:`IMPORTANCE_ECHO_SOLVES` times, on ``workers`` processes."""
    from testbed.integrity.batching import available_cores
    from testbed.studies.dpe_calibration import MULTIPATH

    ap = load_approach(approach)
    shapes = []
    for t in trajectories or (approach,):
        other = load_approach(t)
        corr = ap.config.gnss.correlators.model_copy(update={"pseudorange_source": "model"})  # one synthesis
        cfg = other.config.model_copy(update={"gnss": other.config.gnss.model_copy(update={"correlators": corr}),
                                              "monitors": ["dpe"], "monitor": ap.config.monitor})
        shapes.append(sortie_shape(replace(other, config=cfg)))
    epochs = sum(s.epochs for s in shapes) / len(shapes)
    per_epoch = sum(s.monitor_cost("dpe")[1] + correlator_seconds(s) for s in shapes) / len(shapes)
    kept = 2 * sorties * epochs * 6 * 8.0  # z, e, sigma, m, satellites, VDOP per epoch with a solution
    processes, cores, solves = 1, 1, 1.0
    if method == "importance":
        echo = sum(m != "off" for m in MULTIPATH) / len(MULTIPATH)
        solves = 1.0 - echo + echo * IMPORTANCE_ECHO_SOLVES
        processes = workers
        cores = max(1, min(workers, available_cores()))
    memory = {"process and kernels": BASE_BYTES * processes,
              "one sortie's correlograms": max(correlator_trial_bytes(s) for s in shapes) * processes,
              "the sorties' errors kept for the fit": kept * solves}
    time = {f"{2 * sorties} sorties x ~{epochs:.0f} epochs" + (f" x {solves:.2f} solves" if solves != 1.0 else ""):
            2 * sorties * epochs * per_epoch * solves / cores,
            "flights": sum(s.flight_s for s in shapes) * FLIGHT_SECONDS_PER_S}
    return Estimate(f"calibrate-dpe {approach}", memory, time,
                    (f"fewer sorties (--sorties; now {sorties})", "--work DIR keeps every chunk, so a long run can "
                     "be stopped and resumed (--resume)" if method == "tail" else "more --workers"), cores=cores)
