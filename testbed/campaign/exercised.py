"""Can a campaign's faults happen at all? Decided before any trial is drawn, from the noise-free geometry
the trials fly: the runner's cell contexts (the flight, the satellites in view over each cell's sky
windows, the camera's nominal view of the landmarks).

A fault no trial can exercise would fill its cells with sorties that say nothing about detection (the
report counts them "not exercised", never missed). When that is certain for every cell of a fault table,
the spec is refused before any work starts (:func:`check_faults_exercised`, exit code 2), naming the
table, its satellite or landmark and what was in view instead. Cells where only some trials can exercise
it (a satellite that sets during the span of the sorties) run, and the report counts the others apart.

Decided here, where the trials' geometry fixes it: a GPS fault on a named PRN (in view, after the
elevation, terrain and airframe masks and the tracking schedule, at an epoch of the fault's window in
any sky window of the sorties); a vision fault on a named landmark, and a moved landmark (named or drawn
at the onset) after its move: in the nominal image (the camera's attitude widened by its dithering),
within range and in line of sight at an epoch of the window. An IMU fault reaches every trial's increments
alike, so it happens when a monitor of the cell reads the IMU and an epoch of the sortie follows an IMU
interval its window meets. A fault on a random satellite or detected landmark is drawn among those in view at its onset, so it
is left to the report.
"""

from __future__ import annotations

import math

import numpy as np

from testbed.campaign.context import cell_context
from testbed.campaign.spec import Cell, LoadedSpec, expand_cells
from testbed.schema import ConfigError
from testbed.sensors.faults import (GNSS_KINDS, IMU_KINDS, SYSTEM_KINDS, LandmarkMoved, active, imu_fault_epochs,
                                   named_targets, satellite_ids)


def check_faults_exercised(loaded: LoadedSpec, cells: list[Cell] | None = None) -> None:
    """Refuse (ConfigError naming each fault table) a spec with a fault table none of whose cells any trial
    can exercise; the cheap checks of the spec come first (:func:`~testbed.campaign.spec.load_spec`)."""
    cells = expand_cells(loaded) if cells is None else cells
    found: dict[int, list[tuple[Cell, str]]] = {}
    for cell in cells:
        fam = cell.params["fault_family"]
        if cell.params["fault_kind"] == "none" or not _decidable(cell.config.faults[0]):
            found.setdefault(fam, []).append((cell, ""))
            continue
        found.setdefault(fam, []).append((cell, fault_never_happens(cell, loaded.spec)))
    problems = []
    for fam, rows in sorted(found.items()):
        faulty = [(c, why) for c, why in rows if c.params["fault_kind"] != "none"]
        if faulty and all(why for _, why in faulty):
            f = loaded.spec.faults[fam]
            target = (f"system = {f.system!r}" if f.kind in SYSTEM_KINDS else f"prn = {f.prn}"
                      if f.kind in GNSS_KINDS else f"axis = {f.axis!r}" if f.kind in IMU_KINDS
                      else f"landmark = {f.landmark!r}")  # a spec's table
            ids = [c.index for c, _ in faulty]
            expected = ("a PRN in view then, or prn = \"random\" (one in view at the onset, per sortie)"
                        if f.kind in GNSS_KINDS else "an onset inside the sortie and a monitor that reads the IMU"
                        if f.kind in IMU_KINDS else "a landmark in the image then, or a smaller move")
            problems.append(f"faults.{fam} ({f.kind}, {target}): in every cell that carries it ({_span(ids)}), "
                            f"{faulty[0][1]}: no trial could exercise the fault, so none could detect it; expected "
                            f"{expected}")
    if problems:
        raise ConfigError(loaded.source, problems)


def _decidable(fault) -> bool:
    """Faults whose target the geometry fixes (not drawn among those in view at the onset)."""
    if fault.kind in SYSTEM_KINDS or fault.kind in IMU_KINDS:
        return True
    if fault.kind in GNSS_KINDS:
        return fault.targets != "random"
    return fault.landmark != "random" or isinstance(fault, LandmarkMoved)


def fault_never_happens(cell: Cell, spec) -> str:
    """Why no trial of ``cell`` can exercise its fault (a sentence), or "" when some trial can."""
    ctx = cell_context(cell, spec)
    fault = cell.config.faults[0]
    on = active(fault, ctx.t)
    end = "the end of the sortie" if fault.end_s is None else f"{fault.end_s:g} s"
    window = f"from the onset ({fault.onset_s:g} s) to {end}"
    if fault.kind in IMU_KINDS:
        return _imu_never(ctx, fault, window)
    if not on.any():
        return f"the sortie has no epoch {window}"
    if fault.kind in GNSS_KINDS:
        return _gnss_never(ctx, fault, on, window)
    return _vision_never(ctx, fault, on, window)


def _imu_never(ctx, fault, window: str) -> str:
    """An IMU fault reaches the increments of every trial alike: it happens when the cell reads the IMU and an
    IMU interval of the sortie meets its window."""
    if ctx.imu_increments is None:
        return "no monitor of the cell reads the IMU"
    t_imu, _, _, dt = ctx.imu_increments
    if imu_fault_epochs([fault], ctx.t, t_imu, dt).any():
        return ""
    return (f"no epoch of the sortie ({float(ctx.t[0]):g}-{float(ctx.t[-1]):g} s) follows an IMU interval "
            f"{window}")


def _gnss_never(ctx, fault, on: np.ndarray, window: str) -> str:
    g = ctx.g_geom
    prn = np.asarray(g.prn)
    vis = np.asarray(g.visible, bool)[..., on, :]  # ([W,] T_on, S)
    seen = vis.reshape(-1, vis.shape[-1]).any(0)  # (S,) in view at some epoch of the window, in some sky window
    if seen[named_targets(fault, prn, g.system)].any():
        return ""
    windows = 1 if vis.ndim == 2 else vis.shape[0]
    where = (f"(above the elevation mask, clear of the terrain and the airframe, tracked) {window} in any of the "
             f"{windows} sky window(s) of the sorties")
    if fault.kind in SYSTEM_KINDS:
        return f"no satellite of {fault.system} is ever in view {where}"
    if fault.sat is None and np.all(np.asarray(g.system) == "G"):  # GPS alone: PRNs, as the file names them
        wanted = [fault.prn] if isinstance(fault.prn, int) else list(fault.prn)
        return (f"PRN {', '.join(map(str, wanted))} is never in view {where} (in view then: PRN "
                f"{', '.join(str(int(p)) for p in prn[seen]) or 'none'})")
    ids = satellite_ids(prn, g.system)
    return (f"{', '.join(fault.targets)} never in view {where} (in view then: "
            f"{', '.join(ids[seen].tolist()) or 'none'})")


def _vision_never(ctx, fault, on: np.ndarray, window: str) -> str:
    from testbed.sensors.vision import detect as vdetect

    vg, lm, vision = ctx.v_geom, ctx.landmarks, ctx.setup.vision
    if vg is None:
        return "no monitor of the cell reads vision"
    on = active(fault, vg.t)  # the vision epochs (the GNSS ones in a campaign)
    cam = vision.camera.build()
    slack = _dither_bound_rad(vision.dithering)  # the camera's attitude wanders this far from the nominal one
    det = vision.detection.model_copy(update={"margin_px": vision.detection.margin_px - cam.fx * math.tan(slack)})
    moved = isinstance(fault, LandmarkMoved)
    L = len(lm)

    def in_view(epochs: np.ndarray, pos: np.ndarray, los: np.ndarray) -> np.ndarray:
        """(T_e, L) nominally in the image, within range, in line of sight, at ``pos`` (L, 3)."""
        diff = pos[None] - vg.cam_pos_ecef[epochs][:, None]
        p_cam = np.einsum("tji,tlj->tli", vg.R_cam_to_ecef[epochs], diff)
        return vdetect.visibility(cam, det, p_cam, np.linalg.norm(diff, axis=-1), lm.size_m, los)[1]

    first = np.flatnonzero(on)[:1]
    if fault.landmark != "random":
        targets = np.arange(L) == lm.index(fault.landmark)
    else:  # drawn among the landmarks detected at the onset, where they stand before the move
        targets = in_view(first, lm.pos_ecef, vg.los[first])[0]
        if not targets.any():
            return f"no landmark is in the camera's image at the onset ({fault.onset_s:g} s) to be drawn"
    pos, los = lm.pos_ecef, vg.los[on]
    if moved:
        pos = lm.pos_ecef + vdetect._moved_offset_ecef(lm, fault.delta_enu_m)  # the sensor's own move
        if vg.has_terrain:
            k = np.flatnonzero((vg.moved_keys == vdetect._moved_key(fault)).all(axis=1))[0]  # its line of sight
            los = vg.los_moved[on, k, :]
    if in_view(np.flatnonzero(on), pos, los)[:, targets].any():
        return ""
    what = ("landmark " + repr(fault.landmark) if fault.landmark != "random" else "every landmark in view at the onset")
    move = f", moved by {tuple(round(float(d), 3) for d in fault.delta_enu_m)} m ENU," if moved else ""
    return (f"{what}{move} is never in the camera's image (within {det.max_range_m:g} m, in line of sight, the "
            f"attitude's dithering allowed for) {window}")


def _dither_bound_rad(dithering) -> float:
    """How far the dithered camera can point from its nominal attitude, rad: the tones' amplitudes and
    six times the band-limited noise's RMS, on every axis at once (zero when dithering is off)."""
    if not dithering.enabled:
        return 0.0
    deg = sum(abs(t.amplitude_deg) for t in dithering.tones) + 6.0 * math.hypot(*dithering.noise_rms_deg)
    return math.radians(deg)


def _span(ids: list[int]) -> str:
    """Cell indices as ranges: ``cells 1-4, 7``."""
    out, start = [], None
    for k, i in enumerate(ids):
        if start is None:
            start = i
        if k + 1 == len(ids) or ids[k + 1] != i + 1:
            out.append(f"{start}" if start == i else f"{start}-{i}")
            start = None
    return ("cell " if len(ids) == 1 else "cells ") + ", ".join(out)
