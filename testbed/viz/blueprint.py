"""The default Rerun layout stored in every recording.

Left: the 3D world (terrain, runway, landmarks, planned path, flown trail,
aircraft, satellite lines of sight, each monitor's estimate with its HPL circle
and VPL bar coloured by Stanford region), as a fixed view and one that follows
the aircraft, above the camera view with its detections. Right: one tab per monitor with HPL/VPL against HAL/VAL and the
test statistic against its threshold; below, satellites/landmarks in use, the
alert log and the map track.
"""

from __future__ import annotations

import rerun.blueprint as rrb


def approach_eye(planned_enu) -> rrb.EyeControls3D:
    """A 3D eye behind, right of and above the start of the approach, looking at its end."""
    import numpy as np

    start, end = np.asarray(planned_enu[0], float), np.asarray(planned_enu[-1], float)
    back = start - end
    L = float(np.linalg.norm(back[:2])) or 1000.0
    right = np.array([back[1], -back[0], 0.0]) / L  # right of the inbound track
    pos = start + 0.15 * back + 0.45 * L * right + np.array([0.0, 0.0, 0.55 * L])
    return rrb.EyeControls3D(position=pos, look_target=0.5 * (start + end), eye_up=[0.0, 0.0, 1.0])


#: what the event markers on the integrity plots mean (viz.rerun_sink.MARKS)
MARK_KEY = "Marks: ◆ fault onset, ✕ alert, + cleared, ✱ excluded, ▼ unavailable, ▲ available"

#: series views show the whole flight, not the last seconds before the cursor
WHOLE_FLIGHT = rrb.VisibleTimeRange("sim_time", start=rrb.TimeRangeBoundary.infinite(),
                                    end=rrb.TimeRangeBoundary.infinite())
#: ... and their x axis spans it too (the viewer's default is a window around the cursor)
WHOLE_AXIS = rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                   end=rrb.TimeRangeBoundary.infinite()))


def _series(name: str, origin: str) -> rrb.TimeSeriesView:
    """A time-series view over the whole flight. No legend box (any corner hides some data): the
    title names each curve's colour."""
    return rrb.TimeSeriesView(name=name, origin=origin, time_ranges=[WHOLE_FLIGHT], axis_x=WHOLE_AXIS,
                              plot_legend=rrb.PlotLegend(visible=False))


def _monitor_tab(m: str, hal: float, val: float, vertical_only: bool, several_tests: bool = False) -> rrb.Vertical:
    if vertical_only:  # DPE: no HPL and no test; its σ_ob and the density it bounds instead
        return rrb.Vertical(
            _series(f"{m}: VPL (blue) vs VAL {val:g} m (red), m. VPE (yellow). {MARK_KEY}", f"/integrity/{m}/vertical"),
            _series(f"{m}: overbound σ_ob (blue) and median (red) of the vertical error, m", f"/integrity/{m}/overbound"),
            rrb.BarChartView(name=f"{m}: vertical error density at the cursor epoch (m; it is what σ_ob bounds)",
                             origin=f"/integrity/{m}/vertical_error_density"),
            name=m,
        )
    tests = (_series(f"{m}: each test over its threshold: innovation NIS (blue), windowed NIS (green), solution "
                     f"separation max |Δ|/T (orange); an alert above 1 (red)", f"/integrity/{m}/tests")
             if several_tests else
             _series(f"{m}: test statistic SSE (blue) vs threshold (red). {MARK_KEY}", f"/integrity/{m}/detection"))
    return rrb.Vertical(
        _series(f"{m}: HPL (blue) vs HAL {hal:g} m (red), m. HPE (yellow). {MARK_KEY}", f"/integrity/{m}/horizontal"),
        _series(f"{m}: VPL (blue) vs VAL {val:g} m (red), m. VPE (yellow). {MARK_KEY}", f"/integrity/{m}/vertical"),
        tests,
        name=m,
    )


def default_blueprint(monitors: list[str], eye: rrb.EyeControls3D | None = None,
                      alert_limits: tuple[float, float] = (float("nan"), float("nan")),
                      play_state: str | None = None, vertical_only: tuple[str, ...] = (),
                      active_monitor: str | None = None, several_tests: tuple[str, ...] = (),
                      camera_view: bool = True, map_view: bool = True) -> rrb.Blueprint:
    """The layout; ``play_state`` ("following": the cursor at the newest data) for the time panel;
    ``vertical_only`` monitors (DPE) get a VPL, overbound and error-density tab; ``active_monitor``
    the tab shown first (default: the first monitor's); ``several_tests`` monitors (the Won et al. filter) a
    panel of their tests, each over its threshold, instead of the single test's. ``camera_view=False``
    (a flight without a camera) leaves out the camera view, ``map_view=False`` the map (its tiles come
    from the internet: the documentation's screenshots are taken without it)."""
    hal, val = alert_limits
    monitor_tabs = [_monitor_tab(m, hal, val, m in vertical_only, m in several_tests) for m in monitors]
    # the flown trail is one point per epoch: show all of them up to the cursor
    trail = {"world/path/flown": rrb.VisibleTimeRanges(rrb.VisibleTimeRange(
        "sim_time", start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.cursor_relative()))}
    world = ["/world/**", "- /world/camera/detections/**", "- /world/camera/scene/**", "- /world/camera/features/**"]
    views_3d = rrb.Tabs(
        rrb.Spatial3DView(name="world", origin="/world", eye_controls=eye, contents=world, overrides=trail),
        # the aircraft's frame as the view's origin: the eye rides with it down the approach
        rrb.Spatial3DView(name="follow the aircraft", origin="/world/aircraft", contents=world, overrides=trail),
    )
    camera = rrb.Spatial2DView(name="camera: detections (cyan; red: faulty), landmarks and runway where they are "
                                    "(white), tracked ground features (amber)",
                               origin="/world/camera")
    left = rrb.Vertical(views_3d, camera, row_shares=[3, 2]) if camera_view else rrb.Vertical(views_3d)
    right = rrb.Vertical(
        rrb.Tabs(*monitor_tabs, active_tab=None if active_monitor is None else list(monitors).index(active_monitor))
        if monitor_tabs
        else rrb.TextLogView(name="alerts", origin="/alerts"),
        rrb.Horizontal(
            rrb.TimeSeriesView(name="satellites and landmarks in view / in use; ground features tracked / in the "
                                    "filter's state", origin="/sensors",
                               time_ranges=[WHOLE_FLIGHT], axis_x=WHOLE_AXIS,
                               plot_legend=rrb.PlotLegend(corner=rrb.Corner2D.LeftTop)),
            rrb.TextLogView(name="alerts", origin="/alerts"),
        ),
        *([rrb.MapView(name="map", origin="/map")] if map_view else []),
        row_shares=[3, 2, 2] if map_view else [3, 2],
    )
    # the time panel on the simulation's timeline (a viewer would otherwise pick the first one it sees)
    return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[3, 2]),
                         rrb.TimePanel(timeline="sim_time", state="collapsed", play_state=play_state),
                         collapse_panels=True)
