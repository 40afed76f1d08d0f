"""Time conversions shared by the formats that carry absolute times (GPX, GeoJSON, KITTI)."""

from __future__ import annotations

import datetime as _dt

import numpy as np


def datetime_to_s(value: _dt.datetime) -> float:
    """Seconds since the Unix epoch; a naive datetime is taken as UTC."""
    if value.tzinfo is None:
        value = value.replace(tzinfo=_dt.timezone.utc)
    delta = value - _dt.datetime(1970, 1, 1, tzinfo=_dt.timezone.utc)
    # exact integer microseconds, then to float seconds
    return (delta.days * 86400 + delta.seconds) + delta.microseconds * 1e-6


def s_to_iso_utc(t_s: np.ndarray) -> np.ndarray:
    """Unix seconds -> ISO 8601 UTC strings with microseconds (``...T..:..:..ssssssZ``)."""
    us = np.round(np.asarray(t_s, dtype=float) * 1e6).astype(np.int64)
    text = np.datetime_as_string(us.astype("datetime64[us]"), unit="us")
    return np.char.add(text.astype(str), "Z")


def parse_iso_utc(text: str) -> float:
    """ISO 8601 (``Z`` or offset, or naive = UTC) -> Unix seconds."""
    s = text.strip()
    if s.endswith("Z") or s.endswith("z"):
        s = s[:-1] + "+00:00"
    return datetime_to_s(_dt.datetime.fromisoformat(s))
