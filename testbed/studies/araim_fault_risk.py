"""ARAIM's integrity risk per fault mode on a campaign's geometry: P(HMI | mode k faulty) at the worst bias, by
importance sampling, and its prior-weighted sum against the allocation (:mod:`testbed.campaign.fault_risk`,
docs/design/importance-sampling.md).

At each chosen epoch of the spec's first cell (its start time), for every monitored fault mode and axis
(E, N, U): the worst-case conditional rate P(|e_q| > PL_q, no alert | k, b) with its 95 % interval, the
modes grouped by class (one satellite, a constellation, several satellites), and per axis the sum
Σ_k P_k · max_b P(HMI_q | k, b) against the axis's share of the budget after the unmonitored prior
(P_HMI,V, or P_HMI,H / 2 per horizontal axis, times 1 − P_unmonitored/P_HMI, over N_ES,int), the PL
equation's right side. The protection levels are the core's on the same rows (the monitor's VPL beside it).

    python -m testbed.studies.araim_fault_risk [SPEC] [--epochs 0,75,149] [--trials 1000]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from testbed.campaign import fault_risk as fr
from testbed.campaign import sampling_araim as sa
from testbed.campaign.context import cell_context
from testbed.campaign.sampling import linear_model
from testbed.campaign.spec import expand_cells, load_spec
from testbed.integrity.araim.core import araim
from testbed.integrity.araim.monitor import SYSTEM_CODES
from testbed.markdown import table as markdown_table
from testbed.schema import ConfigError

AXES = ("E", "N", "U")
CLASSES = ("satellite", "constellation", "satellites")


def epoch_risk(tests: sa.SeparationTests, system: np.ndarray, settings, n: int, seed: int,
               classes: tuple[str, ...] = CLASSES) -> dict:
    """One epoch's per-mode risks of the mode classes ``classes`` (module doc): ``{"pl", "target", "risks",
    "classes"}``."""
    rows = sa.epoch_rows(tests.los_enu, system, settings)
    ep = araim(rows, settings)
    pl = np.asarray(ep.pl_enu, float)
    scale = 1.0 - float(ep.p_unmonitored) / (settings.p_hmi_vert + settings.p_hmi_hor)
    target = np.array([0.5 * settings.p_hmi_hor, 0.5 * settings.p_hmi_hor, settings.p_hmi_vert]) * scale \
        / settings.n_es_int
    of = {int(k): fr.mode_class(tests, int(k), system) for k in np.unique(tests.mode)}
    risks = [fr.mode_risk(tests, k, q, float(pl[q]), n=n, seed=seed) for k in of if of[k] in classes
             for q in range(3)]
    return {"pl": pl, "target": target, "risks": risks, "classes": of}


def summary(result: dict) -> list[list]:
    """Rows (axis, class, modes, worst conditional with its interval or why it has none, its mode, Σ P_k·rate
    with the sum of the upper ends, the modes whose rate settled or saw no event)."""
    out = []
    for q in range(3):
        for cls in CLASSES:
            rs = [r for r in result["risks"] if r.axis == q and result["classes"][r.mode] == cls]
            if not rs:
                continue
            worst = max(rs, key=lambda r: r.rate.estimate)
            total = sum(r.prior * r.rate.estimate for r in rs)
            total_hi = sum(r.prior * (r.rate.hi if np.isfinite(r.rate.hi) else 0.0) for r in rs)
            settled = sum(r.rate.settled or r.rate.events == 0 for r in rs)
            out.append([AXES[q], cls, len(rs), worst.rate.text(), f"{worst.removed} at {worst.bias_m:.2f} m",
                        f"{total:.3g} (≤ {total_hi:.3g})", f"{settled}/{len(rs)}"])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m testbed.studies.araim_fault_risk", description=__doc__.splitlines()[0])
    ap.add_argument("spec", nargs="?", default="araim-fa-fault-free", help="campaign spec (its first cell's geometry)")
    ap.add_argument("--epochs", default="0", help="comma-separated epoch indices (default: 0)")
    ap.add_argument("--trials", type=int, default=1000, help="trials per mode, axis and bias (default 1000)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--classes", default=",".join(CLASSES),
                    help=f"comma-separated mode classes to estimate (default: all of {', '.join(CLASSES)})")
    a = ap.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        epochs = [int(x) for x in a.epochs.split(",")]
        classes = tuple(a.classes.split(","))
        if not set(classes) <= set(CLASSES):
            raise ValueError(f"--classes {a.classes}: expected a comma-separated subset of {', '.join(CLASSES)}")
        loaded = load_spec(a.spec)
    except (ValueError, ConfigError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if "araim" not in loaded.spec.monitors or a.trials < 100:
        print(f"error: {a.spec}: expected a spec with the araim monitor and --trials ≥ 100", file=sys.stderr)
        return 2
    ctx = cell_context(expand_cells(loaded)[0], loaded.spec)
    if not all(0 <= t < ctx.t.size for t in epochs):
        print(f"error: --epochs {a.epochs}: expected indices in 0..{ctx.t.size - 1}", file=sys.stderr)
        return 2
    mon = next(m for m in ctx.setup.monitors if m.name == "araim")
    settings = mon.settings.allocation(tuple(mon.context.integrity.service_levels))
    model = linear_model(ctx, "araim", None)[0]
    letters = np.asarray(ctx.g_geom.system)
    tests = sa.model_tests(model, letters, ctx.setup.frame.R, settings, epochs)
    for t in epochs:
        if tests[t] is None:
            print(f"\n## epoch {t}: no solution (unavailable)")
            continue
        system = np.array([SYSTEM_CODES[str(c)] for c in letters[tests[t].slots]])
        res = epoch_risk(tests[t], system, settings, a.trials, a.seed, classes)
        print(f"\n## epoch {t} (t = {ctx.t[t]:.0f} s): {tests[t].slots.size} satellites, "
              f"{len(res['classes'])} monitored modes (estimated: {', '.join(classes)}); PL E/N/U {res['pl'][0]:.2f} / {res['pl'][1]:.2f} / "
              f"{res['pl'][2]:.2f} m (the monitor's VPL {model.vpl[t]:.2f} m)\n")
        print("\n".join(markdown_table(["axis", "class", "modes", "worst P(HMI | k, b) [95 %]", "its mode (slots), bias",
                                        "Σ P_k·P(HMI | k)", "settled"], summary(res))))
        for q in range(3):
            total = sum(r.prior * r.rate.estimate for r in res["risks"] if r.axis == q)
            hi = sum(r.prior * (r.rate.hi if np.isfinite(r.rate.hi) else 0.0) for r in res["risks"] if r.axis == q)
            print(f"\n{AXES[q]}: Σ_k P_k·max_b P(HMI | k, b) over those modes = {total:.3g} (upper 95 % ends summed: {hi:.3g}) against "
                  f"the axis's budget per epoch {res['target'][q]:.3g}: {'within' if hi <= res['target'][q] else 'ABOVE'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
