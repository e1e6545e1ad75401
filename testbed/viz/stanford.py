"""The Stanford diagram: a monitor's position errors against its protection levels, binned on a log grid, with the
regions (normal operation, misleading, hazardously misleading, unavailable) counted. The binning is the campaign
tables' and the replay's; the figure is the campaign report's and ``testbed monitor --out``'s.

matplotlib is imported inside the drawing functions: the binning alone (a campaign worker) never loads it.
"""

from __future__ import annotations

import numpy as np

#: Stanford histogram bins: log10 of error and PL in metres, 0.01 m .. 10 km, 0.05 dex
HIST_LOG10_MIN, HIST_LOG10_MAX, HIST_BINS = -2.0, 4.0, 120


def hist_edges() -> np.ndarray:
    """(HIST_BINS + 1,) bin edges in metres of the Stanford histograms."""
    return 10.0 ** np.linspace(HIST_LOG10_MIN, HIST_LOG10_MAX, HIST_BINS + 1)


def stanford_figure(monitor: str, panels: list[tuple[str, np.ndarray, dict[str, int], int, float]],
                    edges: np.ndarray, suptitle: str | None = None):
    """A monitor's Stanford diagrams side by side, one per ``(dim, H, counts, total, alert limit)`` of
    ``panels``. A dimension in which the monitor gives no PL at any epoch (the DPE bounds the vertical
    only) gets no panel: the others' titles say so. With no PL in any dimension every panel is drawn,
    each saying it is empty."""
    from matplotlib.figure import Figure

    empty = [_no_solution(p[2], p[3]) for p in panels]
    if all(empty):
        empty = [False] * len(panels)
    shown = [p for p, e in zip(panels, empty) if not e]
    absent = [p[0] for p, e in zip(panels, empty) if e]
    fig = Figure(figsize=(5.5 * len(shown), 4.8 + 0.25 * bool(absent)))
    axs = np.atleast_1d(fig.subplots(1, len(shown)))
    for ax, (dim, H, counts, total, al) in zip(axs, shown):
        stanford_panel(fig, ax, H, edges, counts, total, monitor, dim, al)
        if absent:
            ax.set_title(ax.get_title() + "\n" + f"({monitor} gives no {', '.join(d + 'PL' for d in absent)}: "
                         f"no {', '.join(absent)} diagram)", fontsize=10)
    if suptitle:
        fig.suptitle(suptitle)
    return fig


def stanford_panel(fig, ax, H: np.ndarray, edges: np.ndarray, counts: dict[str, int], total: int, monitor: str,
                   dim: str, al: float) -> None:
    """One Stanford diagram: the (error, PL) histogram ``H`` [error bin, PL bin] on log axes, the alert
    limit, the y = x line and the region counts."""
    from matplotlib.colors import LogNorm
    from matplotlib.ticker import LogFormatter

    if H.sum() > 0:
        # H is indexed [error bin, PL bin]; pcolormesh wants rows = y (PL)
        pcm = ax.pcolormesh(edges, edges, H.T, norm=LogNorm(vmin=1, vmax=max(H.max(), 2)), cmap="viridis",
                            shading="flat")
        cb = fig.colorbar(pcm, ax=ax, label="epochs")
        plain = LogFormatter(labelOnlyBase=False, minor_thresholds=(1.5, 0.5))  # 2, 3, 10, 100 rather than 2x10^0
        cb.ax.yaxis.set_major_formatter(plain)
        cb.ax.yaxis.set_minor_formatter(plain)
    empty = _no_solution(counts, total)  # e.g. the DPE's H panel: HPL NaN by design
    if not empty:  # the limit lines and y = x only where there is something to read against them
        lim = (edges[0], edges[-1])
        ax.plot(lim, lim, "k-", lw=0.8)
        ax.axhline(al, color="r", lw=0.8)
        ax.axvline(al, color="r", lw=0.8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(1e-2, 1e3)
    ax.set_ylim(1e-1, 1e4)
    ax.set_xlabel(f"{dim} position error (m)")
    ax.set_ylabel(f"{dim}PL (m)")
    txt = (f"normal {counts['normal']}\nunavailable {counts['unavailable']}\n"
           f"misleading {counts['misleading']}\nhazardous (HMI) {counts['hazardous']}\n"
           f"unavail.+misleading {counts['unavailable_misleading']}\n"
           f"alerted (not plotted) {counts['alerted']}\nno solution {counts['no_solution']}\n"
           f"total {total} epochs")
    ax.text(0.02, 0.98, txt, transform=ax.transAxes, va="top", fontsize=7,
            bbox={"facecolor": "white", "alpha": 0.8, "lw": 0})
    ax.set_title(f"{monitor}: {dim} Stanford diagram ({dim}AL {al:g} m)")
    if empty:
        ax.text(0.5, 0.5, f"{monitor} gives no {dim}PL", ha="center", va="center", transform=ax.transAxes,
                fontsize=10)


def _no_solution(counts: dict[str, int], total: int) -> bool:
    """Every epoch of the panel without a solution: the monitor gives no PL in that dimension."""
    return bool(total) and counts["no_solution"] == total
