"""Epoch-axis slicing and concatenation of the sensor *geometry* records (epoch axis first).

The records that flow between the rooms slice and join themselves
(:func:`testbed.records.take_epochs`, :func:`testbed.records.concat_epochs`, from the
epoch axes each declares); the geometry records are cut by their per-epoch arrays here.
"""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np


def per_epoch_fields(geom) -> tuple[str, ...]:
    """The fields of ``geom`` with an epoch axis first: those its class declares (``PER_EPOCH``), else every
    array whose first axis has the epochs' length but ``prn`` (a per-satellite array of that length would be
    mistaken: declare them)."""
    declared = getattr(type(geom), "PER_EPOCH", None)
    if declared is not None:
        return tuple(declared)
    T = len(geom.t)
    return tuple(f.name for f in fields(geom) if f.name != "prn" and isinstance(getattr(geom, f.name), np.ndarray)
                 and getattr(geom, f.name).ndim >= 1 and getattr(geom, f.name).shape[0] == T)


def geometry_prefix(geom, T1: int):
    """A GNSS geometry restricted to its first ``T1`` epochs."""
    return replace(geom, **{name: getattr(geom, name)[:T1] for name in per_epoch_fields(geom)})


def geometry_concat(a, b):
    """Two consecutive GNSS geometries as one (per-epoch arrays concatenated)."""
    if a is None:
        return b
    return replace(a, **{name: np.concatenate([getattr(a, name), getattr(b, name)], axis=0)
                         for name in per_epoch_fields(a)})
