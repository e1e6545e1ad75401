"""The default Rerun layout stored in every recording.

Left: the 3D world (terrain, runway, landmarks, planned path, flown trail, the
aircraft with a marker that reads at valley scale, satellite lines of sight,
each monitor's estimate with its protection volume coloured by Stanford
region) as a fixed view, one that follows the aircraft from behind and above,
and the map, above the camera image (its frame, the horizon, the runway and
the detections). Right: one tab per monitor with its horizontal and vertical
plots (PL, alert limit, error vs truth) and its test over its threshold; below,
satellites/landmarks in use and the alert log.

Every series carries its name (``SeriesLines``/``SeriesPoints`` in the sink) and every
plot shows its legend, so no curve goes unnamed; titles stay short.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import rerun.blueprint as rrb

if TYPE_CHECKING:  # pragma: no cover
    from testbed.sim.setup import Scene

#: the follow view's frame: at the aircraft, x along its ground track, z up (level: the
#: horizon stays level whatever the aircraft's attitude); logged by the sink every epoch
FOLLOW_FRAME = "/world/follow"
#: the follow view's eye in that frame, m: behind and above the aircraft, looking at it (the
#: orbit centre: dragging turns the view about the aircraft). At 320 m the 36 m airframe spans
#: ~10 % of the view's width and the terrain below and the approach ahead stay in view.
FOLLOW_EYE_M = (-320.0, 0.0, 110.0)
FOLLOW_TARGET_M = (0.0, 0.0, 0.0)
#: the aircraft's marker (a disc of constant screen size, labelled): drawn in the fixed view only
AIRCRAFT_MARKER = "/world/aircraft/marker"


def monitor_label(m: str) -> str:
    """Monitor ``m``'s label above the protection volumes, stacked with the others' (in the follow view
    only: at valley scale the volumes are a few pixels and their labels would pile on the aircraft's)."""
    return f"/world/integrity/{m}/name"


#: the test panels plot each statistic over its threshold (an alert above 1) on 0..TEST_RATIO_MAX:
#: Rerun 0.41 has no log axis, and a linear ratio keeps the margin below the threshold readable
#: (fault-free ratios are ~0.1-0.8) where a raw statistic of ~1000 after a fault flattened it;
#: a ratio above the range leaves the top of the plot (the alert mark and the log say when)
TEST_RATIO_MAX = 2.0
#: PL plots span 0..PL_RANGE_OVER_LIMIT x the alert limit (rounded up, see :func:`y_range`)
PL_RANGE_OVER_LIMIT = 1.5


def approach_eye(planned_enu) -> rrb.EyeControls3D:
    """A 3D eye behind, right of and above the start of the approach, looking at its end."""
    start, end = np.asarray(planned_enu[0], float), np.asarray(planned_enu[-1], float)
    back = start - end
    L = float(np.linalg.norm(back[:2])) or 1000.0
    right = np.array([back[1], -back[0], 0.0]) / L  # right of the inbound track
    pos = start + 0.15 * back + 0.45 * L * right + np.array([0.0, 0.0, 0.55 * L])
    return rrb.EyeControls3D(position=pos, look_target=0.5 * (start + end), eye_up=[0.0, 0.0, 1.0])


def follow_eye() -> rrb.EyeControls3D:
    """The follow view's eye in :data:`FOLLOW_FRAME`: behind and above the aircraft, orbiting it."""
    return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=FOLLOW_EYE_M, look_target=FOLLOW_TARGET_M,
                             eye_up=[0.0, 0.0, 1.0])


def y_range(limit: float, over: float = PL_RANGE_OVER_LIMIT) -> tuple[float, float] | None:
    """0 .. ``over`` x ``limit`` rounded up to a whole number of the limit's decade steps (40 m -> 60,
    20 m -> 30, 556 m -> 900): the viewer labels the y axis at decade steps, and on a short plot it
    drops them all but 0 when they come closer than 20 px (a range of 76 m on 110 px did). None
    (fit the data) without a finite limit."""
    if not (math.isfinite(limit) and limit > 0):
        return None
    step = 10.0 ** math.floor(math.log10(limit))
    return 0.0, math.ceil(over * limit / step - 1e-9) * step


#: series views show the whole flight, not the last seconds before the cursor
WHOLE_FLIGHT = rrb.VisibleTimeRange("sim_time", start=rrb.TimeRangeBoundary.infinite(),
                                    end=rrb.TimeRangeBoundary.infinite())
#: ... and their x axis spans it too (the viewer's default is a window around the cursor)
WHOLE_AXIS = rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                   end=rrb.TimeRangeBoundary.infinite()))
#: the legend at the top left: over the start of the flight above the limit line, where a curve
#: runs only while the PL exceeds its limit (its background is translucent)
LEGEND = rrb.PlotLegend(corner=rrb.Corner2D.LeftTop, visible=True)


def _series(name: str, origin: str, y: tuple[float, float] | None = None, contents=None,
            legend: rrb.PlotLegend = LEGEND) -> rrb.TimeSeriesView:
    """A time-series view over the whole flight with its legend (each series names itself)."""
    return rrb.TimeSeriesView(name=name, origin=origin, contents=contents or "$origin/**", time_ranges=[WHOLE_FLIGHT],
                              axis_x=WHOLE_AXIS, axis_y=rrb.ScalarAxis(range=y) if y is not None else None,
                              plot_legend=legend)


def _monitor_tab(m: str, hal: float, val: float, vertical_only: bool, several_tests: bool = False) -> rrb.Vertical:
    vertical = _series(f"{m}: vertical, m", f"/integrity/{m}/vertical", y_range(val))
    if vertical_only:  # DPE: no HPL and no test; its σ_ob and the density it bounds instead
        return rrb.Vertical(
            vertical,
            _series(f"{m}: overbound of the vertical error, m", f"/integrity/{m}/overbound"),
            rrb.BarChartView(name=f"{m}: vertical error density at the cursor (m; what σ_ob bounds)",
                             origin=f"/integrity/{m}/vertical_error_density",
                             plot_legend=rrb.PlotLegend(visible=False)),
            name=m,
        )
    tests = (_series(f"{m}: tests / threshold", f"/integrity/{m}/tests", (0.0, TEST_RATIO_MAX))
             if several_tests else
             _series(f"{m}: test / threshold", f"/integrity/{m}/detection", (0.0, TEST_RATIO_MAX),
                     contents=["$origin/ratio", "$origin/limit", "$origin/marks/**"]))
    return rrb.Vertical(_series(f"{m}: horizontal, m", f"/integrity/{m}/horizontal", y_range(hal)), vertical, tests,
                        name=m)


def default_blueprint(monitors: list[str], eye: rrb.EyeControls3D | None = None,
                      alert_limits: tuple[float, float] = (float("nan"), float("nan")),
                      play_state: str | None = None, vertical_only: tuple[str, ...] = (),
                      active_monitor: str | None = None, several_tests: tuple[str, ...] = (),
                      camera_resolution: tuple[int, int] | None = None, map_view: bool = True,
                      follow_open: bool = False) -> rrb.Blueprint:
    """The layout; ``play_state`` ("following": the cursor at the newest data) for the time panel;
    ``vertical_only`` monitors (DPE) get a VPL, overbound and error-density tab; ``active_monitor``
    the tab shown first (default: the first monitor's); ``several_tests`` monitors (the Won et al. filter) a
    panel of their tests, each over its threshold, instead of the single test's. ``camera_resolution``
    (w, h px; None: a flight without a camera) frames the camera view on the image, ``map_view=False``
    leaves out the map (its tiles come from the internet: the documentation's screenshots are taken
    without it); ``follow_open`` opens the follow view's tab instead of the fixed view's."""
    hal, val = alert_limits
    monitor_tabs = [_monitor_tab(m, hal, val, m in vertical_only, m in several_tests) for m in monitors]
    # the flown trail is one point per epoch: show all of them up to the cursor
    trail = {"world/path/flown": rrb.VisibleTimeRanges(rrb.VisibleTimeRange(
        "sim_time", start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.cursor_relative()))}
    world = ["/world/**", "- /world/camera/detections/**", "- /world/camera/scene/**", "- /world/camera/features/**",
             "- /world/camera/labels/**"]
    views_3d = [
        rrb.Spatial3DView(name="world", origin="/world", eye_controls=eye, overrides=trail,
                          contents=world + [f"- {monitor_label(m)}/**" for m in monitors]),
        # a level frame at the aircraft as the view's origin, the eye behind and above it: the
        # view rides with the aircraft down the approach
        rrb.Spatial3DView(name="follow the aircraft", origin=FOLLOW_FRAME, eye_controls=follow_eye(),
                          contents=world + [f"- {AIRCRAFT_MARKER}/**"], overrides=trail,
                          line_grid=rrb.LineGrid3D(visible=False)),  # its plane would run through the aircraft
    ]
    if map_view:
        views_3d.append(rrb.MapView(name="map", origin="/map"))
    left = [rrb.Tabs(*views_3d, active_tab=1 if follow_open else None)]
    if camera_resolution is not None:
        w, h = camera_resolution
        pad = 0.02 * w  # the frame's outline inside the view
        left.append(rrb.Spatial2DView(
            name="camera: image frame, horizon (blue), runway (grey), detections (cyan; red: faulty)",
            origin="/world/camera", background=[22, 26, 34],  # dark: the overlay reads in either theme
            visual_bounds=rrb.VisualBounds2D(x_range=[-pad, w + pad], y_range=[-pad, h + pad])))
    right = rrb.Vertical(
        rrb.Tabs(*monitor_tabs, active_tab=None if active_monitor is None else list(monitors).index(active_monitor))
        if monitor_tabs
        else rrb.TextLogView(name="alerts", origin="/alerts"),
        rrb.Horizontal(
            _series("satellites, landmarks and features in view / in use", "/sensors"),
            rrb.TextLogView(name="alerts", origin="/alerts"),
            column_shares=[3, 2],
        ),
        row_shares=[3, 1.4],
    )
    # the time panel on the simulation's timeline (a viewer would otherwise pick the first one it sees)
    left_column = rrb.Vertical(*left, row_shares=[3, 2][:len(left)])
    return rrb.Blueprint(rrb.Horizontal(left_column, right, column_shares=[3, 2]),
                         rrb.TimePanel(timeline="sim_time", state="collapsed", play_state=play_state),
                         collapse_panels=True)


def scene_blueprint(scene: "Scene", **options) -> rrb.Blueprint:
    """The layout of ``scene``'s recording (``options``: those of :func:`default_blueprint` after
    ``camera_resolution``, and ``play_state``, ``active_monitor``)."""
    return default_blueprint(list(scene.monitors), approach_eye(scene.planned_enu), tuple(scene.alert_limits),
                             vertical_only=tuple(scene.vertical_only), several_tests=tuple(scene.several_tests),
                             camera_resolution=tuple(scene.camera_resolution) if scene.camera_K is not None else None,
                             **options)
