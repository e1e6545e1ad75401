"""Evaluation: monitor outputs against truth (outside the monitors, which never see it).

Stanford-diagram regions for one dimension (horizontal or vertical), with
position error ``e``, protection level ``PL`` and alert limit ``AL``:

- ``normal``: PL <= AL and e <= PL
- ``unavailable``: PL > AL and e <= PL (the system says "don't use me")
- ``misleading``: e > PL and e <= AL (the bound failed, no hazard yet)
- ``hazardous``: e > AL and PL <= AL (hazardously misleading information)
- ``unavailable_misleading``: PL > AL and e > PL and e > AL
- ``alerted``: the monitor raised an alert (the position is flagged, not used);
  when alerts are given, such epochs are counted here and in no other region,
  so a detected fault is never counted as misleading information
- ``no_solution``: no position or PL (fewer than 5 measurements, singular...)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from testbed.integrity.levels import strictest_limits
from testbed.records import MonitorOutput

REGIONS = ("normal", "unavailable", "misleading", "hazardous", "unavailable_misleading", "alerted", "no_solution")


def stanford_regions(err: NDArray, pl: NDArray, al: float, alert: NDArray | None = None) -> dict[str, NDArray]:
    """Boolean masks of the Stanford regions (any shape); exactly one is True per epoch.

    ``alert`` (same shape, optional): alerted epochs with a solution go to ``alerted``.
    """
    err, pl = np.asarray(err, float), np.asarray(pl, float)
    ok = np.isfinite(err) & np.isfinite(pl)
    alerted = ok & np.asarray(alert, bool) if alert is not None else np.zeros(ok.shape, bool)
    ok = ok & ~alerted
    e = np.where(ok, err, 0.0)
    p = np.where(ok, pl, 0.0)
    bounded = e <= p
    avail = p <= al
    return {
        "normal": ok & bounded & avail,
        "unavailable": ok & bounded & ~avail,
        "misleading": ok & ~bounded & (e <= al),
        "hazardous": ok & ~bounded & (e > al) & avail,
        "unavailable_misleading": ok & ~bounded & (e > al) & ~avail,
        "alerted": alerted,
        "no_solution": ~ok & ~alerted,
    }


def misleading(he: NDArray, ve: NDArray, hpl: NDArray, vpl: NDArray, alert: NDArray,
               dimensions: tuple[str, ...] = ("H", "V")) -> NDArray:
    """Misleading information: an error above its PL, no alert, on the dimensions the monitor bounds.

    A vertical-only monitor (``dimensions`` ("V",), HPL NaN by design) is judged on V alone;
    one that bounds both needs both PLs finite.
    """
    pairs = [(e, p) for d, e, p in (("H", he, hpl), ("V", ve, vpl)) if d in dimensions]
    with np.errstate(invalid="ignore"):
        over = np.logical_or.reduce([np.asarray(e) > np.asarray(p) for e, p in pairs])
    bounded = np.logical_and.reduce([np.isfinite(p) for _, p in pairs])
    return over & bounded & ~np.asarray(alert, bool)


@dataclass(frozen=True)
class MonitorSummary:
    name: str
    epochs: int
    reference: str
    availability: dict[str, float]  # per service level, fraction of epochs
    hpl_max: float
    hpl_p95: float
    vpl_max: float
    vpl_p95: float
    hpe95: float
    vpe95: float
    alert_epochs: int
    excluded_epochs: int  # epochs whose alert FDE cleared by an exclusion
    first_alert_s: float  # nan if none
    time_to_alert_s: float  # from the first fault onset; nan if no fault or never alerted
    mi_epochs: int  # error > PL (H or V) with no alert
    hmi_epochs: int  # error > AL while PL <= AL (H or V) with no alert, for the most demanding level
    regions_h: dict[str, int] = field(default_factory=dict)
    regions_v: dict[str, int] = field(default_factory=dict)


def _pct(x: NDArray, q: float) -> float:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.percentile(x, q)) if x.size else float("nan")


def position_errors(out: MonitorOutput, true_pos_enu: NDArray) -> tuple[NDArray, NDArray]:
    """Horizontal and vertical position error magnitudes (m) of a monitor's estimate."""
    d = np.asarray(out.pos_enu, float) - np.asarray(true_pos_enu, float)
    return np.hypot(d[..., 0], d[..., 1]), np.abs(d[..., 2])


def summarise_monitor(out: MonitorOutput, true_pos_enu: NDArray, *, reference: str,
                      fault_onset_s: float | None = None) -> MonitorSummary:
    """Figures an integrity engineer reads for one monitor over one run (unbatched)."""
    he, ve = position_errors(out, true_pos_enu)
    alert = np.asarray(out.alert, bool)
    hpl, vpl = np.asarray(out.hpl, float), np.asarray(out.vpl, float)
    avail = np.asarray(out.available, bool)
    hal, val = strictest_limits(out.service_levels)
    rh, rv = stanford_regions(he, hpl, hal, alert), stanford_regions(ve, vpl, val, alert)
    mi = misleading(he, ve, hpl, vpl, alert, out.dimensions)
    hmi = rh["hazardous"] | rv["hazardous"]
    t = np.asarray(out.t, float)
    first_alert = float(t[alert][0]) if alert.any() else float("nan")
    tta = float("nan")
    if fault_onset_s is not None:
        after = np.asarray(out.detected, bool) & (t >= fault_onset_s - 1e-9)  # an alert or an exclusion
        if after.any():
            tta = float(t[after][0] - fault_onset_s)
    sol = np.isfinite(he)
    return MonitorSummary(
        name=out.name, epochs=int(t.size), reference=reference,
        availability={name: float(avail[..., k].mean()) for k, name in enumerate(out.service_levels)},
        hpl_max=float(np.nanmax(hpl)) if np.isfinite(hpl).any() else float("nan"), hpl_p95=_pct(hpl, 95),
        vpl_max=float(np.nanmax(vpl)) if np.isfinite(vpl).any() else float("nan"), vpl_p95=_pct(vpl, 95),
        hpe95=_pct(he[sol], 95), vpe95=_pct(ve[sol], 95), alert_epochs=int(alert.sum()),
        excluded_epochs=int((np.asarray(out.excluded) >= 0).sum()),
        first_alert_s=first_alert, time_to_alert_s=tta, mi_epochs=int(mi.sum()), hmi_epochs=int(hmi.sum()),
        regions_h={k: int(v.sum()) for k, v in rh.items()}, regions_v={k: int(v.sum()) for k, v in rv.items()})


def unavailable_reason(out: MonitorOutput) -> str | None:
    """Why a monitor gave no available epoch at any service level (its most frequent reason code),
    or None when some epoch was available."""
    avail = np.asarray(out.available, bool)
    if avail.size and avail.any():
        return None
    codes = np.asarray(out.reason, int).ravel()
    codes = codes[codes > 0]
    if codes.size == 0:
        return "protection levels above every alert limit"
    top = int(np.bincount(codes).argmax())
    text = out.reasons[top].removeprefix("unavailable: ")
    return f"{text} ({int((codes == top).sum())} of {np.asarray(out.reason).size} epochs)"


def describe_faults(faults, prn: NDArray, faulty: NDArray, visible: NDArray, t: NDArray,
                    system: NDArray | None = None) -> list[str]:
    """One line per injected fault (kind, size, target, onset) and, for the GNSS faults, which satellites
    the observations carried it on and at how many epochs (``faulty``/``visible``: (T, S), ``prn``: (S,)).
    A GNSS fault that no tracked satellite carried is said to be "not exercised". ``system`` (S,): the slots'
    system letters (None: GPS alone, named by PRN)."""
    from testbed.sensors.faults import GNSS_KINDS, IMU_KINDS, SYSTEM_KINDS, satellite_ids

    gps_alone = system is None or bool(np.all(np.asarray(system) == "G"))

    lines = []
    for f in faults:
        size = next((f"{getattr(f, k):+g} {u}" for k, u in (("bias_m", "m"), ("rate_m_s", "m/s"),
                                                          ("drift_m_s", "m/s"), ("magnitude_px", "px"))
                     if hasattr(f, k)), "")
        target = getattr(f, "prn", None) or getattr(f, "landmark", None) or getattr(f, "landmarks", None)
        if f.kind == "constellation_orbit":
            xyz = lambda v: ", ".join(f"{c:g}" for c in v)  # noqa: E731
            size = f"translation [{xyz(f.translation_m)}] m, rotation [{xyz(f.rotation_mas)}] mas (ECEF X, Y, Z)"
        if f.kind in IMU_KINDS:
            size, target = f.size_text, f"the IMU's {'accelerometers' if f.sensor == 'accel' else 'gyros'}"
        elif f.kind in SYSTEM_KINDS:
            target = f"every {f.system} satellite"
        elif getattr(f, "sat", None) is not None:
            target = ", ".join(f.targets)
        elif target == "random":
            target = "a random visible satellite" if f.kind in GNSS_KINDS else "a random detected landmark"
        elif f.kind in GNSS_KINDS:
            target = f"PRN {target}"
        end = f" to {f.end_s:g} s" if f.end_s is not None else ""
        lines.append(f"fault: {f.kind} {size} on {target} from {f.onset_s:g} s{end} (time to alert counts from "
                     f"the first onset)".replace("  ", " "))
    if any(f.kind in GNSS_KINDS for f in faults):
        seen = np.asarray(faulty, bool) & np.asarray(visible, bool)
        if not seen.any():
            lines.append("  in the observations: at no epoch (no tracked satellite carried it): not exercised")
        else:
            hit = seen.any(axis=0)
            sats = ("PRN " + ", ".join(str(int(p)) for p in np.asarray(prn)[hit]) if gps_alone
                    else ", ".join(satellite_ids(prn, system)[hit].tolist()))
            epochs = seen.any(axis=1)
            tt = np.asarray(t, float)[epochs]
            lines.append(f"  in the observations: {sats} at {int(epochs.sum())} of "
                         f"{epochs.size} epochs ({tt[0]:g}-{tt[-1]:g} s)")
    return lines
