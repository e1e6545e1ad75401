"""What the patent's monitor buys: its protection-level rule with and without vision rows and H3, beside GPS RAIM.

The vision-integrity patent claims that adding landmark pixels to the GNSS rows improves integrity
availability. Its monitor bundles two things: the *rows* (pixels next to the
pseudoranges) and the *rule* (three hypotheses, H3 = two simultaneous faults,
combined as sqrt(max(H1, H2)² + H3²)). To see what each costs and buys, the same
observations (a campaign cell's draw blocks: one flown trajectory, sorties over
the sky's repeat, the sensors' noise) go through

* GPS RAIM (slope PLs, the baseline);
* the patent's rule on the GNSS rows alone, with and without H3;
* the patent's rule on GNSS + landmark pixels, with and without H3 (with H3: the
  shipped pixel monitor).

:func:`benefit_table` gives, per variant: per-epoch availability per service
level, median and 95th percentile HPL/VPL over solved epochs, 95 % horizontal and
vertical accuracy, the per-epoch alert rate. :func:`draw_benefit` draws it.
``benchmarks/bench_pixel_benefit.py`` runs it on the runway-05 final.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from testbed.campaign.blocks import draw_block
from testbed.campaign.context import cell_context
from testbed.campaign.spec import LoadedSpec, expand_cells
from testbed.integrity.pixel import pixel_monitor
from testbed.integrity.raim import gps_raim
from testbed.integrity.settings import PixelOptions
from testbed.markdown import table as md_table
from testbed.sim.evaluate import position_errors


@dataclass(frozen=True)
class Variant:
    name: str
    vision_rows: bool | None  # None: GPS RAIM
    two_faults: bool = True


VARIANTS = (
    Variant("GPS RAIM", None),
    Variant("patent rule, GNSS rows", False, True),
    Variant("patent rule, GNSS rows, no H3", False, False),
    Variant("patent rule, GNSS + vision", True, True),
    Variant("patent rule, GNSS + vision, no H3", True, False),
)


def _run(variant: Variant, obs, setup):
    st = setup.integrity
    if variant.vision_rows is None:
        return gps_raim(obs.gnss, setup.frame, st), "antenna"
    options = PixelOptions(vision_rows=variant.vision_rows, two_faults=variant.two_faults)
    return pixel_monitor(obs.gnss, obs.vision, setup.frame, st, options=options), "cg"


def benefit_table(loaded: LoadedSpec, cell_index: int = 0, blocks: int | None = None) -> list[dict]:
    """One row per :data:`VARIANTS` entry over the cell's trials (all blocks, or the first ``blocks``)."""
    cell = expand_cells(loaded)[cell_index]
    spec = loaded.spec
    ctx = cell_context(cell, spec)
    n_blocks = -(-spec.trials // spec.block_trials) if blocks is None else blocks
    acc = {v.name: {"avail": [], "hpl": [], "vpl": [], "he": [], "ve": [], "alert": [], "solved": []} for v in VARIANTS}
    for b in range(n_blocks):
        d = draw_block(ctx, spec, b)
        for v in VARIANTS:
            out, ref = _run(v, d.obs, ctx.setup)
            he, ve = position_errors(out, ctx.truth_ant_enu if ref == "antenna" else ctx.truth_cg_enu)
            a = acc[v.name]
            solved = np.asarray(out.reason) == 0
            a["solved"].append(solved.ravel())
            a["avail"].append(np.asarray(out.available).reshape(-1, len(ctx.levels)))
            for k, x in (("hpl", out.hpl), ("vpl", out.vpl), ("he", he), ("ve", ve)):
                a[k].append(np.asarray(x, float).ravel())
            a["alert"].append(np.asarray(out.alert, bool).ravel())
    rows = []
    for v in VARIANTS:
        a = {k: np.concatenate(x) for k, x in acc[v.name].items()}
        ok = a["solved"]
        row = {"variant": v.name, "epochs": int(ok.size), "solved": float(ok.mean())}
        for k, lv in enumerate(ctx.levels):
            row[f"avail_{lv}"] = float(a["avail"][:, k].mean())
        for k in ("hpl", "vpl"):
            x = a[k][ok]
            row[f"{k}_median"] = float(np.median(x)) if x.size else float("nan")
            row[f"{k}_p95"] = float(np.percentile(x, 95)) if x.size else float("nan")
        for k in ("he", "ve"):
            x = a[k][ok & np.isfinite(a[k])]
            row[f"{k}95"] = float(np.percentile(x, 95)) if x.size else float("nan")
        row["alert_rate"] = float(a["alert"][ok].mean()) if ok.any() else float("nan")
        rows.append(row)
    return rows


def format_table(rows: list[dict], levels: tuple[str, ...]) -> str:
    """The table as Markdown."""
    head = ["variant", *(f"avail {lv}" for lv in levels), "HPL median / p95", "VPL median / p95",
            "HPE95 / VPE95", "alerts / epoch"]
    return "\n".join(md_table(head, [[r["variant"], *(f"{100 * r[f'avail_{lv}']:.1f} %" for lv in levels),
                                      f"{r['hpl_median']:.1f} / {r['hpl_p95']:.1f} m",
                                      f"{r['vpl_median']:.1f} / {r['vpl_p95']:.1f} m",
                                      f"{r['he95']:.1f} / {r['ve95']:.1f} m", f"{r['alert_rate']:.1e}"] for r in rows]))


def draw_benefit(rows: list[dict], level: str, path: str | Path, scene: str = "") -> Path:
    """Bars: availability at ``level`` and median HPL/VPL per variant (``scene``: what was flown, for the title)."""
    from testbed.integrity.levels import service_level

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [r["variant"] for r in rows]
    y = np.arange(len(rows))
    fig, axs = plt.subplots(1, 2, figsize=(11, 3.6), sharey=True, constrained_layout=True)
    axs[0].barh(y, [100 * r[f"avail_{level}"] for r in rows], color="#4477aa")
    axs[0].set_xlabel(f"{level} availability per epoch (%)")
    axs[0].set_xlim(0, 100)
    axs[0].set_yticks(y, names)
    axs[0].invert_yaxis()
    w = 0.38
    axs[1].barh(y - w / 2, [r["hpl_median"] for r in rows], w, color="#228833", label="median HPL")
    axs[1].barh(y + w / 2, [r["vpl_median"] for r in rows], w, color="#ee6677", label="median VPL")
    lv = service_level(level)
    axs[1].axvline(lv.hal, color="#228833", ls=":", lw=1)
    axs[1].axvline(lv.val, color="#ee6677", ls=":", lw=1)
    axs[1].set_xlabel(f"median PL (m); dotted: {level} HAL {lv.hal:g}, VAL {lv.val:g} m")
    axs[1].legend(loc="lower right", frameon=False)
    title = "What the patent's monitor buys: its PL rule with and without vision rows and H3, beside GPS RAIM"
    fig.suptitle(title + (f"\n{scene}" if scene else ""), fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
