"""GPS time: UTC -> GPS seconds, week / seconds-of-week, calendar GPST.

Times inside the GNSS layer are float seconds since the GPS epoch
(1980-01-06 00:00:00 GPST), called ``t_gps``. A float64 of ~1.4e9 s has a
resolution of 0.24 µs: a GPS satellite moves ~1 mm in that time, far below
every error the testbed models.

UTC -> GPST adds the leap seconds accumulated since 1980 (18 s since
2017-01-01; IERS Bulletin C has announced none since, as of 2025).
"""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import numpy as np
from numpy.typing import ArrayLike, NDArray

GPS_EPOCH = datetime(1980, 1, 6, tzinfo=timezone.utc)
SECONDS_PER_WEEK = 604_800.0

#: (UTC date from which it applies, GPS − UTC in s). IERS Bulletin C / IS-GPS-200 ΔtLS.
LEAP_SECONDS: tuple[tuple[datetime, int], ...] = tuple(
    (datetime(y, m, 1, tzinfo=timezone.utc), n)
    for (y, m, n) in [
        (1981, 7, 1), (1982, 7, 2), (1983, 7, 3), (1985, 7, 4), (1988, 1, 5), (1990, 1, 6),
        (1991, 1, 7), (1992, 7, 8), (1993, 7, 9), (1994, 7, 10), (1996, 1, 11), (1997, 7, 12),
        (1999, 1, 13), (2006, 1, 14), (2009, 1, 15), (2012, 7, 16), (2015, 7, 17), (2017, 1, 18),
    ]
)


def _as_utc(dt: datetime | str) -> datetime:
    if isinstance(dt, str):
        try:
            dt = datetime.fromisoformat(dt.replace("Z", "+00:00"))
        except ValueError as exc:
            raise ValueError(f"start_utc: expected an ISO 8601 time such as '2024-03-15T06:00:00Z', "
                             f"got {dt!r}") from exc
    if not isinstance(dt, datetime):
        raise ValueError(f"start_utc: expected a datetime or ISO string, got {type(dt).__name__}")
    if dt.tzinfo is None:  # naive times are taken as UTC (documented)
        dt = dt.replace(tzinfo=timezone.utc)
    return dt.astimezone(timezone.utc)


def leap_seconds(utc: datetime | str) -> int:
    """GPS − UTC (s) at a UTC instant (0 before 1981-07-01)."""
    u = _as_utc(utc)
    n = 0
    for since, k in LEAP_SECONDS:
        if u >= since:
            n = k
    return n


def utc_to_gps_seconds(utc: datetime | str) -> float:
    """Seconds since the GPS epoch (GPST) of a UTC instant (naive = UTC)."""
    u = _as_utc(utc)
    if u < GPS_EPOCH:
        raise ValueError(f"start_utc: expected a time after the GPS epoch 1980-01-06, got {u.isoformat()}")
    return (u - GPS_EPOCH).total_seconds() + leap_seconds(u)


def gps_seconds_to_week_sow(t_gps: ArrayLike) -> tuple[NDArray, NDArray]:
    """Full GPS week number and seconds of week of ``t_gps`` (any shape)."""
    t = np.asarray(t_gps, float)
    week = np.floor(t / SECONDS_PER_WEEK)
    return week.astype(np.int64), t - week * SECONDS_PER_WEEK


def gps_seconds_to_calendar(t_gps: float) -> datetime:
    """GPST calendar time (as a naive datetime, microsecond resolution) of ``t_gps``.

    This is the time scale RINEX writes with ``GPS`` time system: no leap seconds.
    """
    return (GPS_EPOCH + timedelta(seconds=float(t_gps))).replace(tzinfo=None)


def gps_seconds_to_utc(t_gps: float) -> datetime:
    """UTC (aware datetime) of a GPST instant (leap seconds from the table)."""
    guess = GPS_EPOCH + timedelta(seconds=float(t_gps))
    return guess - timedelta(seconds=leap_seconds(guess - timedelta(seconds=leap_seconds(guess))))


def gpst_calendar_to_gps_seconds(year: int, month: int, day: int, hour: int = 0, minute: int = 0,
                                 second: float = 0.0) -> float:
    """Seconds since the GPS epoch of a GPST calendar time (as RINEX writes it; no leap seconds)."""
    d = datetime(year, month, day, hour, minute, tzinfo=timezone.utc) - GPS_EPOCH
    return d.total_seconds() + float(second)
