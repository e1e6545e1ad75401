"""Epoch-axis slicing and concatenation of the sensor *geometry* records (epoch axis first).

The records that flow between the rooms slice and join themselves
(:func:`testbed.records.take_epochs`, :func:`testbed.records.concat_epochs`, from the
epoch axes each declares); the geometry records are cut by their per-epoch arrays here.
"""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np


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
