"""The public Python API: everything the ``testbed`` command does, as plain calls.

>>> from testbed.api import fly_approach
>>> result = fly_approach("zunz-rwy05-final")
>>> result.summary.xtk_rms_m
"""

from __future__ import annotations

from pathlib import Path

from testbed.config import Approach, list_approaches, load_approach, read_toml
from testbed.flight.fly import FlightResult, check_start_clearance, fly
from testbed.schema import ConfigError
from testbed.sim.truth_io import write_truth

__all__ = ["Approach", "FlightResult", "check_file", "fly_approach", "list_approaches", "load_approach",
           "load_terrain_for", "print_flight_summary"]


def load_terrain_for(approach: Approach):
    """The terrain model an approach names (its ``[terrain]`` table)."""
    from testbed.world.settings import load_terrain

    try:
        return load_terrain(approach.config.terrain, approach.source.parent)
    except (ValueError, OSError) as exc:
        raise ConfigError(approach.source, [f"terrain: {exc}"]) from None


def fly_approach(approach: str | Path | Approach, *, gust_seed: int | None = None,
                 truth_path: str | Path | None = None) -> FlightResult:
    """Load (if needed) and fly an approach; optionally write its truth trajectory."""
    ap = approach if isinstance(approach, Approach) else load_approach(approach)
    result = fly(ap, load_terrain_for(ap), gust_seed=gust_seed)
    if truth_path is not None:
        write_truth(result.truth, truth_path)
    return result


def check_file(path: str | Path) -> list[str]:
    """Every problem with an approach file (empty list when it is valid)."""
    try:
        ap = load_approach(path)
        check_start_clearance(ap, load_terrain_for(ap))
    except ConfigError as exc:
        return exc.problems
    return []


def print_flight_summary(result: FlightResult) -> None:
    from rich.console import Console
    from rich.table import Table

    s = result.summary
    t = Table(title=f"{s.approach} ({s.aircraft})", show_header=False)
    rows = [
        ("duration", f"{s.duration_s:.1f} s ({s.steps} steps, {s.realtime_factor:.0f}x real time)"),
        ("reached threshold", "yes" if s.reached_end else "NO"),
        ("cross-track after capture", f"RMS {s.xtk_rms_m:.2f} m, max {s.xtk_max_m:.2f} m"),
        ("vertical path after capture", f"RMS {s.vert_rms_m:.2f} m, max {s.vert_max_m:.2f} m"),
        ("at threshold", f"{s.end_height_above_m:.1f} m above, {s.end_lateral_m:+.1f} m lateral, "
                         f"{s.end_cas_kt:.0f} kt CAS, sink {s.end_sink_rate_ms:.1f} m/s"),
        ("attitude", f"max bank {s.max_bank_deg:.1f} deg, pitch {s.pitch_range_deg[0]:.1f}..{s.pitch_range_deg[1]:.1f} deg"),
        ("min height above terrain", f"{s.min_agl_m:.0f} m"),
    ]
    for k, v in rows:
        t.add_row(k, v)
    Console().print(t)
