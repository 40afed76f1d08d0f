"""GeoJSON (RFC 7946): LineString or Point features with times.

Read:
- a FeatureCollection, a Feature or a bare geometry;
- ``LineString`` features with per-vertex times in ``properties.times`` (seconds) or
  ``properties.coordTimes`` (ISO 8601 strings, the togeojson convention);
- ``Point`` features with ``properties.t`` (seconds) or ``properties.time`` (ISO 8601);
- optional per-vertex ``q_body_to_enu_wxyz`` ([w, x, y, z]), ``gnss`` ([lon, lat, alt] or
  null), ``images`` (strings); Points carry the same names singular: ``q``, ``gnss``,
  ``image``. Coordinates are [lon, lat(, alt)]; altitude missing -> 0 m.

Write: one FeatureCollection with one LineString feature holding every sample and the
properties above (times in seconds, so any epoch survives), plus ``extra`` columns.
Errors name the file, the line of the feature involved and the JSON path.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from posefix.core.run import PoseRun
from posefix.io._build import build_run
from posefix.io._jsonpos import loads_with_lines
from posefix.io._timeconv import parse_iso_utc
from posefix.io.atomic import atomic_write
from posefix.io.errors import RunFormatError

__all__ = ["read_geojson", "write_geojson"]


class _Fail(Exception):
    def __init__(self, obj: Any, field: str, message: str, row: int | None = None):
        self.obj, self.field, self.message, self.row = obj, field, message, row


def _num(v: Any, obj: Any, field: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _Fail(obj, field, f"not a number: {v!r}")
    return float(v)


def _time(v: Any, obj: Any, field: str) -> float:
    if isinstance(v, str):
        try:
            return parse_iso_utc(v)
        except ValueError:
            raise _Fail(obj, field, f"not an ISO 8601 time: {v!r}") from None
    if v is None:
        raise _Fail(obj, field, "time is missing")
    return _num(v, obj, field)


def _features(doc: Any) -> list[tuple[str, dict]]:
    if not isinstance(doc, dict):
        raise _Fail(doc, "$", "top level must be a GeoJSON object")
    kind = doc.get("type")
    if kind == "FeatureCollection":
        feats = doc.get("features")
        if not isinstance(feats, list):
            raise _Fail(doc, "features", "must be a list")
        return [(f"features[{i}]", f) for i, f in enumerate(feats)]
    if kind == "Feature":
        return [("$", doc)]
    if kind in ("LineString", "Point"):
        return [("$", {"type": "Feature", "geometry": doc, "properties": {}})]
    raise _Fail(doc, "type", f"expected FeatureCollection, Feature, LineString or Point, got {kind!r}")


def _collect(doc: Any) -> tuple[list, list]:
    """Return per-sample tuples (t, lon, lat, alt, q|None, gnss|None, image|None) and their features."""
    rows: list[tuple] = []
    owners: list[Any] = []
    for path, feat in _features(doc):
        if not isinstance(feat, dict) or feat.get("type") != "Feature":
            raise _Fail(feat, f"{path}.type", "expected a Feature")
        geom = feat.get("geometry")
        props = feat.get("properties") or {}
        if not isinstance(geom, dict):
            raise _Fail(feat, f"{path}.geometry", "missing geometry")
        gtype = geom.get("type")
        coords = geom.get("coordinates")
        if gtype == "LineString":
            if not isinstance(coords, list):
                raise _Fail(feat, f"{path}.geometry.coordinates", "must be a list")
            if "times" in props:
                times, tname = props["times"], "times"
            elif "coordTimes" in props:
                times, tname = props["coordTimes"], "coordTimes"
            else:
                raise _Fail(feat, f"{path}.properties.times", "LineString needs per-vertex times ('times' seconds or 'coordTimes' ISO)")
            if not isinstance(times, list) or len(times) != len(coords):
                raise _Fail(feat, f"{path}.properties.{tname}", f"needs one time per coordinate ({len(coords)})")
            qs = props.get("q_body_to_enu_wxyz")
            gn = props.get("gnss")
            im = props.get("images")
            for name, arr in (("q_body_to_enu_wxyz", qs), ("gnss", gn), ("images", im)):
                if arr is not None and (not isinstance(arr, list) or len(arr) != len(coords)):
                    raise _Fail(feat, f"{path}.properties.{name}", f"needs one entry per coordinate ({len(coords)})")
            for i, c in enumerate(coords):
                rows.append(_row(feat, f"{path}.geometry.coordinates[{i}]", c,
                                 _time(times[i], feat, f"{path}.properties.{tname}[{i}]"),
                                 None if qs is None else qs[i], None if gn is None else gn[i],
                                 None if im is None else im[i], f"{path}.properties", i))
                owners.append(feat)
        elif gtype == "Point":
            if "t" in props:
                t = _time(props["t"], feat, f"{path}.properties.t")
            elif "time" in props:
                t = _time(props["time"], feat, f"{path}.properties.time")
            else:
                raise _Fail(feat, f"{path}.properties.t", "Point needs a time ('t' seconds or 'time' ISO)")
            rows.append(_row(feat, f"{path}.geometry.coordinates", coords, t, props.get("q"),
                             props.get("gnss"), props.get("image"), f"{path}.properties", None))
            owners.append(feat)
        else:
            raise _Fail(feat, f"{path}.geometry.type", f"expected LineString or Point, got {gtype!r}")
    return rows, owners


def _row(feat, cpath, c, t, q, g, image, ppath, i):
    sfx = "" if i is None else f"[{i}]"
    if not isinstance(c, list) or len(c) < 2:
        raise _Fail(feat, cpath, "a position needs [lon, lat(, alt)]")
    lon = _num(c[0], feat, cpath + "[0] (lon)")
    lat = _num(c[1], feat, cpath + "[1] (lat)")
    alt = _num(c[2], feat, cpath + "[2] (alt)") if len(c) > 2 else 0.0
    qv = None
    if q is not None:
        qname = f"{ppath}.q_body_to_enu_wxyz{sfx}" if i is not None else f"{ppath}.q"
        if not isinstance(q, list) or len(q) != 4:
            raise _Fail(feat, qname, "a quaternion needs [w, x, y, z]")
        qv = [_num(v, feat, qname) for v in q]
    gv = None
    if g is not None:
        gname = f"{ppath}.gnss{sfx}"
        if not isinstance(g, list) or len(g) < 2:
            raise _Fail(feat, gname, "a GNSS fix needs [lon, lat(, alt)] or null")
        gv = [_num(v, feat, gname) for v in g[:3]] + ([0.0] if len(g) == 2 else [])
    if image is not None and not isinstance(image, str):
        raise _Fail(feat, f"{ppath}.image{'s' + sfx if i is not None else ''}", "image names must be a string")
    return (t, lon, lat, alt, qv, gv, image)


def read_geojson(path: str | os.PathLike) -> PoseRun:
    """Read a GeoJSON file of timed LineString/Point features into a ``PoseRun``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise RunFormatError(path, None, None, f"cannot read file: {exc}") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RunFormatError(path, exc.lineno, None, f"not valid JSON: {exc.msg}") from None
    try:
        rows, owners = _collect(doc)
    except _Fail:
        # Re-parse keeping line numbers to say where.
        try:
            _collect(loads_with_lines(text))
        except _Fail as exc:
            raise RunFormatError(path, getattr(exc.obj, "line", None), exc.field, exc.message) from None
        raise  # pragma: no cover - the two parses agree
    if not rows:
        raise RunFormatError(path, None, "features", "the run is empty: no LineString or Point features")
    t, lon, lat, alt = (np.array([r[k] for r in rows], dtype=float) for k in range(4))
    has_q = all(r[4] is not None for r in rows)
    q = np.array([r[4] for r in rows], dtype=float) if has_q else None
    gnss = None
    if any(r[5] is not None for r in rows):
        g = np.array([r[5] if r[5] is not None else [np.nan] * 3 for r in rows], dtype=float)
        gnss = (g[:, 1], g[:, 0], g[:, 2])
    images = [r[6] or "" for r in rows] if any(r[6] is not None for r in rows) else None
    extra = _extra_columns(doc, len(rows))
    line_cache: dict[str, Any] = {}

    def line_of_row(i: int) -> int | None:
        if "doc" not in line_cache:
            line_cache["doc"] = loads_with_lines(text)
            line_cache["rows"] = _collect(line_cache["doc"])[1]
        owners_l = line_cache["rows"]
        return getattr(owners_l[i], "line", None) if i < len(owners_l) else None

    return build_run(
        path, t, lat, lon, alt, q, line_of_row=line_of_row, gnss=gnss, images=images, extra=extra,
        field_names={"t_s": "times", "lat_deg": "coordinates (lat)", "lon_deg": "coordinates (lon)",
                     "alt_m": "coordinates (alt)", "q_body_to_enu_wxyz": "q_body_to_enu_wxyz",
                     "gnss_lat_deg": "gnss (lat)", "gnss_lon_deg": "gnss (lon)", "gnss_alt_m": "gnss (alt)"},
    )


def _extra_columns(doc: Any, n: int) -> dict[str, np.ndarray]:
    """Per-sample ``properties.extra`` columns of a single-LineString file (as posefix writes)."""
    feats = [f for _, f in _features(doc)]
    if len(feats) != 1:
        return {}
    extra = (feats[0].get("properties") or {}).get("extra")
    if not isinstance(extra, dict):
        return {}
    out = {}
    for name, values in extra.items():
        if isinstance(values, list) and len(values) == n:
            if all(isinstance(v, (int, float)) and not isinstance(v, bool) or v is None for v in values):
                out[name] = np.array([np.nan if v is None else v for v in values], dtype=float)
            else:
                out[name] = np.array(["" if v is None else str(v) for v in values], dtype=object)
    return out


def _jsonable(a: np.ndarray) -> list:
    arr = np.asarray(a)
    if arr.dtype.kind == "f":
        return [None if v != v else v for v in arr.tolist()]
    if arr.dtype.kind in "iub":
        return arr.tolist()
    return ["" if v is None else str(v) for v in arr.tolist()]


def write_geojson(run: PoseRun, path: str | os.PathLike) -> None:
    """Write ``run`` as a FeatureCollection with one timed LineString, atomically."""
    coords = np.column_stack([run.lon_deg, run.lat_deg, run.alt_m]).tolist()
    props: dict[str, Any] = {
        "times": run.t_s.tolist(),
        "q_body_to_enu_wxyz": run.q_body_to_enu_wxyz.tolist(),
        "orientation_derived": bool(run.orientation_derived),
    }
    if run.has_gnss:
        g = np.column_stack([run.gnss_lon_deg, run.gnss_lat_deg, run.gnss_alt_m])
        ok = np.all(np.isfinite(g), axis=1)
        props["gnss"] = [row if good else None for row, good in zip(g.tolist(), ok.tolist())]
    if run.images is not None:
        props["images"] = list(run.images)
    if run.extra:
        props["extra"] = {k: _jsonable(v) for k, v in run.extra.items()}
    doc = {
        "type": "FeatureCollection",
        "features": [{"type": "Feature", "geometry": {"type": "LineString", "coordinates": coords},
                      "properties": props}],
    }
    with atomic_write(path, "w") as fh:
        json.dump(doc, fh, separators=(",", ":"), allow_nan=False)
