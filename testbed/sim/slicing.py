"""Epoch-axis slicing and concatenation of the records (unbatched: epoch axis first).

Which fields carry the epoch axis is declared per record type (observations and
monitor outputs declare theirs on the record, :func:`testbed.records.epoch_array`),
so a scene whose landmark count happens to equal the epoch count cannot confuse it.
"""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np

from testbed.records import GnssEpochs, GnssTruth, MonitorOutput, VisionEpochs, concat_epochs, take_epochs

_EPOCH_FIELDS = {  # truth-side records: epoch axis first (they carry no trial axis in the loop)
    GnssTruth: ("antenna_pos_ecef", "geometric_range", "clock_bias", "noise", "fault_bias", "faulty",
                "elevation", "azimuth"),
}
_DECLARED = (GnssEpochs, VisionEpochs, MonitorOutput)  # epoch arrays declared on the record (records.epoch_array)


def epoch_fields(rec) -> tuple[str, ...]:
    for cls, names in _EPOCH_FIELDS.items():
        if isinstance(rec, cls):
            return names
    from testbed.sensors.vision.detect import VisionTruth

    if isinstance(rec, VisionTruth):
        return ("t", "cam_pos_ecef", "q_cam_to_ecef", "dither_cam", "attitude_ref_error", "landmark_moved",
                "pixel_true", "range_m", "visible", "noise_px", "blur_sigma_px", "fault_pixel_bias", "faulty",
                "fault_kind")
    raise TypeError(f"no epoch fields known for {type(rec).__name__}")


def take(rec, idx):
    """``rec`` restricted to epochs ``idx`` (a slice or index array), its diagnostics too."""
    if isinstance(rec, _DECLARED):
        return take_epochs(rec, idx)
    kw = {name: np.asarray(getattr(rec, name))[idx] for name in epoch_fields(rec)}
    return replace(rec, **kw)


def concat(recs: list):
    """Concatenate records of one type along the epoch axis (constants from the first)."""
    first = recs[0]
    if isinstance(first, _DECLARED):
        return concat_epochs(recs)
    if len(recs) == 1:
        return first
    kw = {name: np.concatenate([np.asarray(getattr(r, name)) for r in recs], axis=0) for name in epoch_fields(first)}
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
