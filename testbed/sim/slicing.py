"""Epoch-axis slicing and concatenation of the records (unbatched: epoch axis first).

Which fields carry the epoch axis is listed explicitly per record type, so a
scene whose landmark count happens to equal the epoch count cannot confuse it.
"""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np

from testbed.records import GnssEpochs, GnssTruth, MonitorOutput

_EPOCH_FIELDS = {
    GnssEpochs: ("t", "t_gps", "sat_pos_ecef", "sat_vel_ecef", "pseudorange", "range_rate", "sigma", "visible",
                 "reason"),
    GnssTruth: ("antenna_pos_ecef", "geometric_range", "clock_bias", "noise", "fault_bias", "faulty",
                "elevation", "azimuth"),
    MonitorOutput: ("t", "pos_enu", "clock", "hpl", "vpl", "test_stat", "threshold", "alert", "available",
                    "n_used", "excluded", "reason"),
}


def epoch_fields(rec) -> tuple[str, ...]:
    for cls, names in _EPOCH_FIELDS.items():
        if isinstance(rec, cls):
            return names
    try:  # the vision records are defined in their own room
        from testbed.records import VisionEpochs
        from testbed.sensors.vision.detect import VisionTruth
    except ImportError:  # pragma: no cover
        raise TypeError(f"no epoch fields known for {type(rec).__name__}") from None
    if isinstance(rec, VisionEpochs):
        return ("t", "pixel_uv", "detected", "reason", "sigma_px", "q_body_to_enu_ref")
    if isinstance(rec, VisionTruth):
        return ("t", "cam_pos_ecef", "q_cam_to_ecef", "dither_cam", "attitude_ref_error", "landmark_moved",
                "pixel_true", "range_m", "visible", "noise_px", "blur_sigma_px", "fault_pixel_bias", "faulty",
                "fault_kind")
    raise TypeError(f"no epoch fields known for {type(rec).__name__}")


def take(rec, idx):
    """``rec`` restricted to epochs ``idx`` (a slice or index array); diagnostics too."""
    n = len(rec.t) if hasattr(rec, "t") else None
    kw = {name: np.asarray(getattr(rec, name))[idx] for name in epoch_fields(rec)}
    if isinstance(rec, MonitorOutput):
        kw["diagnostics"] = {k: (v[idx] if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == n else v)
                             for k, v in rec.diagnostics.items()}
    return replace(rec, **kw)


def concat(recs: list):
    """Concatenate records of one type along the epoch axis (constants from the first)."""
    first = recs[0]
    if len(recs) == 1:
        return first
    kw = {name: np.concatenate([np.asarray(getattr(r, name)) for r in recs], axis=0) for name in epoch_fields(first)}
    if isinstance(first, MonitorOutput):
        diag = {}
        for k, v in first.diagnostics.items():
            parts = [r.diagnostics.get(k) for r in recs]
            if all(isinstance(p, np.ndarray) and p.ndim and p.shape[0] == len(r.t) for p, r in zip(parts, recs)):
                try:
                    diag[k] = np.concatenate(parts, axis=0)
                    continue
                except ValueError:  # ragged trailing shapes (e.g. stacked problem width)
                    pass
            diag[k] = v
        kw["diagnostics"] = diag
    return replace(first, **kw)


def geometry_prefix(geom, T1: int):
    """A GNSS geometry restricted to its first ``T1`` epochs."""
    T = len(geom.t)
    kw = {}
    for f in fields(geom):
        v = getattr(geom, f.name)
        if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == T and f.name != "prn":
            kw[f.name] = v[:T1]
    return replace(geom, **kw)


def geometry_concat(a, b):
    """Two consecutive GNSS geometries as one (per-epoch arrays concatenated)."""
    if a is None:
        return b
    T = len(a.t)
    kw = {}
    for f in fields(a):
        v = getattr(a, f.name)
        if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == T and f.name != "prn":
            kw[f.name] = np.concatenate([v, getattr(b, f.name)], axis=0)
    return replace(a, **kw)
