"""ARAIM's integrity risk per fault mode on a campaign's geometry: P(HMI | mode k faulty) at the worst bias, by
importance sampling, and its prior-weighted sum against the allocation (:mod:`testbed.campaign.fault_risk`,
docs/design/importance-sampling.md).

At each chosen epoch of the spec's first cell (its start time), for every monitored fault mode and axis
(E, N, U): the worst-case conditional rate P(|e_q| > PL_q, no alert | k, b) with its 95 % interval, the
modes grouped by class (one satellite, a constellation, several satellites), and per axis the sum
Σ_k P_k · max_b P(HMI_q | k, b) against the axis's share of the budget after the unmonitored prior
(P_HMI,V, or P_HMI,H / 2 per horizontal axis, times 1 − P_unmonitored/P_HMI, over N_ES,int), the PL
equation's right side. The protection levels are the core's on the same rows (the monitor's VPL beside it).

The verdict per axis (:func:`budget_verdict`) counts no mode without a rate as 0: a mode whose event no trial
reached, or whose weights have not settled, withholds it ("not shown", the modes listed). A mode of several
rows is searched over a few fault profiles (``--profiles``), not all: a line says its figure holds for those.

    python -m testbed.studies.araim_fault_risk [SPEC] [--epochs 0,75,149] [--trials 1000] [--profiles 4]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

import numpy as np

from testbed.campaign import fault_risk as fr
from testbed.campaign import sampling_araim as sa
from testbed.campaign.context import cell_context
from testbed.campaign.sampling import linear_model
from testbed.campaign.spec import expand_cells, load_spec
from testbed.integrity.araim.core import araim
from testbed.integrity.araim.monitor import SYSTEM_CODES
from testbed.markdown import table as markdown_table
from testbed.schema import ConfigError, arg_in_range

AXES = ("E", "N", "U")
CLASSES = ("satellite", "constellation", "satellites")
#: random fault profiles tried per mode of several rows (fault_risk.fault_profiles)
RANDOM_PROFILES = 4


def epoch_risk(tests: sa.SeparationTests, system: np.ndarray, settings, n: int, seed: int,
               classes: tuple[str, ...] = CLASSES, random_profiles: int = RANDOM_PROFILES) -> dict:
    """One epoch's per-mode risks of the mode classes ``classes`` (module doc): ``{"pl", "target", "risks",
    "classes"}``."""
    rows = sa.epoch_rows(tests.los_enu, system, settings)
    ep = araim(rows, settings)
    pl = np.asarray(ep.pl_enu, float)
    scale = 1.0 - float(ep.p_unmonitored) / (settings.p_hmi_vert + settings.p_hmi_hor)
    target = np.array([0.5 * settings.p_hmi_hor, 0.5 * settings.p_hmi_hor, settings.p_hmi_vert]) * scale \
        / settings.n_es_int
    of = {int(k): fr.mode_class(tests, int(k), system) for k in np.unique(tests.mode)}
    risks = [fr.mode_risk(tests, k, q, float(pl[q]), n=n, seed=seed,
                           random_profiles=random_profiles) for k in of if of[k] in classes
             for q in range(3)]
    return {"pl": pl, "target": target, "risks": risks, "classes": of}


@dataclass(frozen=True)
class BudgetVerdict:
    """One axis's prior-weighted sum against its budget (:func:`budget_verdict`): the sums over the settled
    modes, the modes with no rate (no event under the proposal, or weights not settled) and the verdict, or
    ``None`` where the modes with no rate leave it open."""

    total: float  # Σ P_k · rate over the settled modes
    total_lo: float  # ... of the lower 95 % ends
    total_hi: float  # ... of the upper 95 % ends
    target: float
    settled: int
    missing: tuple[fr.ModeRisk, ...]  # no rate: unmeasured (no event) or unsettled, the likeliest first
    verdict: str | None  # "within", "ABOVE", or None (not shown)


def budget_verdict(risks: list[fr.ModeRisk], target: float) -> BudgetVerdict:
    """Σ_k P_k · max_b P(HMI | k, b) against ``target``. "within" needs every mode's rate settled and the sum
    of the upper ends inside; "ABOVE" holds when the settled modes' lower ends alone exceed it (the others
    add ≥ 0); otherwise no verdict: a mode whose event no trial reached has no upper bound, an unsettled
    rate's interval is not trusted, and neither counts as 0."""
    ok = [r for r in risks if r.rate.settled]
    missing = sorted((r for r in risks if not r.rate.settled),
                     key=lambda r: -r.prior * (r.rate.estimate if np.isfinite(r.rate.estimate) else 0.0) - r.prior)
    total = sum(r.prior * r.rate.estimate for r in ok)
    lo = sum(r.prior * r.rate.lo for r in ok)
    hi = sum(r.prior * r.rate.hi for r in ok)
    verdict = "ABOVE" if lo > target else "within" if not missing and hi <= target else None
    return BudgetVerdict(total, lo, hi, target, len(ok), tuple(missing), verdict)


def verdict_text(axis: str, v: BudgetVerdict, worst: int = 3) -> str:
    """The study's line for one axis: the settled sum, the verdict or "not shown" with the modes that withhold
    it (their count and the ``worst`` likeliest, by prior times estimate)."""
    of = f"{v.settled + len(v.missing)} modes"
    head = (f"{axis}: Σ_k P_k·max_b P(HMI | k, b) over the {v.settled} settled of {of} = {v.total:.3g} (upper 95 % "
            f"ends summed: {v.total_hi:.3g})" if v.settled else f"{axis}: none of the {of} settled") + \
        f" against the axis's budget per epoch {v.target:.3g}: "
    if v.verdict == "ABOVE":
        head += "ABOVE (the settled modes' lower 95 % ends alone exceed it)"
    elif v.verdict == "within":
        head += "within"
    elif v.missing:
        head += f"not shown: {len(v.missing)} mode(s) with no rate (no event, or not settled), which may add anything"
    else:
        head += "not shown: the summed interval straddles the budget"
    if v.missing:
        head += "".join(f"\n  - mode {r.removed} (P_k {r.prior:.2g}): {r.rate.text()}" for r in v.missing[:worst])
        if len(v.missing) > worst:
            head += f"\n  - and {len(v.missing) - worst} more"
    return head


def summary(result: dict) -> list[list]:
    """Rows (axis, class, modes, worst conditional with its interval or why it has none, its mode, Σ P_k·rate
    over the settled modes with the sum of their upper ends, the modes whose rate settled / saw no event)."""
    out = []
    for q in range(3):
        for cls in CLASSES:
            rs = [r for r in result["risks"] if r.axis == q and result["classes"][r.mode] == cls]
            if not rs:
                continue
            worst = max(rs, key=lambda r: r.rate.estimate if r.rate.settled else -1.0)
            v = budget_verdict(rs, np.inf)
            no_event = sum(r.rate.events == 0 for r in rs)
            total = (f"{v.total:.3g} (≤ {v.total_hi:.3g})" if v.settled else "no mode settled") \
                + (f", {len(v.missing)} not shown" if v.missing else "")
            out.append([AXES[q], cls, len(rs), worst.rate.text(),
                        f"{worst.removed} at {worst.bias_m:.2f} m ({worst.profile})", total,
                        f"{v.settled}/{len(rs)}" + (f" ({no_event} no event)" if no_event else "")])
    return out


def profile_note(result: dict, random_profiles: int) -> str | None:
    """The line that says what the figure of a mode of several rows is (module doc of fault_risk)."""
    multi = {r.mode for r in result["risks"] if r.profiles > 1 or result["classes"][r.mode] != "satellite"}
    if not multi:
        return None
    tried = ("the least-norm profile only" if random_profiles == 0 and
             all(r.profiles == 1 for r in result["risks"] if r.mode in multi) else
             f"the worst of the least-norm profile of each axis and {random_profiles} random profile(s)")
    return (f"The {len(multi)} mode(s) of several rows (constellations, several satellites): the figure holds for "
            f"{tried} on the mode's rows, not for every profile: for them Σ P_k·max_b is an estimate on the "
            "profiles tried, not a bound.")


def epochs_arg(text: str) -> list[int]:
    """``--epochs``: comma-separated epoch indices ≥ 0 (the upper end is the geometry's, checked once built)."""
    try:
        out = [int(x) for x in text.split(",")]
    except ValueError:
        out = []
    if not out or min(out) < 0:
        raise argparse.ArgumentTypeError(f"expected comma-separated epoch indices ≥ 0, got {text!r}")
    return out


def classes_arg(text: str) -> tuple[str, ...]:
    """``--classes``: a comma-separated subset of :data:`CLASSES`."""
    out = tuple(text.split(","))
    if not set(out) <= set(CLASSES):
        raise argparse.ArgumentTypeError(f"expected a comma-separated subset of {', '.join(CLASSES)}, got {text!r}")
    return out


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m testbed.studies.araim_fault_risk", description=__doc__.splitlines()[0])
    ap.add_argument("spec", nargs="?", default="araim-fa-fault-free", help="campaign spec (its first cell's geometry)")
    ap.add_argument("--epochs", type=epochs_arg, default=[0], help="comma-separated epoch indices (default: 0)")
    ap.add_argument("--trials", type=arg_in_range(int, 100, 10**8), default=1000,
                    help="trials per mode, axis and bias, at least 100 (default 1000)")
    ap.add_argument("--seed", type=arg_in_range(int, 0, 2**32), default=0, help="seed ≥ 0 (default 0)")
    ap.add_argument("--profiles", type=arg_in_range(int, 0, 1001), default=RANDOM_PROFILES,
                    help="random fault profiles tried per mode of several rows, beside the least-norm profile of "
                         f"each axis (default {RANDOM_PROFILES}; 0 with the axes' profiles only)")
    ap.add_argument("--classes", type=classes_arg, default=CLASSES,
                    help=f"comma-separated mode classes to estimate (default: all of {', '.join(CLASSES)})")
    return ap


def main(argv: list[str] | None = None) -> int:
    a = parser().parse_args(sys.argv[1:] if argv is None else argv)  # bad values: argparse's exit 2
    epochs, classes = a.epochs, a.classes
    try:
        loaded = load_spec(a.spec)
    except (ValueError, ConfigError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if "araim" not in loaded.spec.monitors:
        print(f"error: {a.spec}: expected a spec with the araim monitor", file=sys.stderr)
        return 2
    ctx = cell_context(expand_cells(loaded)[0], loaded.spec)
    if not all(0 <= t < ctx.t.size for t in epochs):
        print(f"error: --epochs {','.join(map(str, epochs))}: expected indices in 0..{ctx.t.size - 1}", file=sys.stderr)
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
        res = epoch_risk(tests[t], system, settings, a.trials, a.seed, classes, a.profiles)
        print(f"\n## epoch {t} (t = {ctx.t[t]:.0f} s): {tests[t].slots.size} satellites, "
              f"{len(res['classes'])} monitored modes (estimated: {', '.join(classes)}); PL E/N/U {res['pl'][0]:.2f} / {res['pl'][1]:.2f} / "
              f"{res['pl'][2]:.2f} m (the monitor's VPL {model.vpl[t]:.2f} m)\n")
        print("\n".join(markdown_table(["axis", "class", "modes", "worst settled P(HMI | k, b) [95 %]",
                                        "its mode (slots), bias (profile)", "Σ P_k·P(HMI | k), settled modes",
                                        "settled"], summary(res))))
        note = profile_note(res, a.profiles)
        if note:
            print(f"\n{note}")
        for q in range(3):
            print("\n" + verdict_text(AXES[q], budget_verdict([r for r in res["risks"] if r.axis == q],
                                                                float(res["target"][q]))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
