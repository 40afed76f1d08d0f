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

import contextlib
import gc
import json
import os
import re
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import orjson

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


@contextlib.contextmanager
def _no_gc():
    """Pause the cyclic garbage collector while millions of lists are built.

    They hold only numbers and strings, so no cycles form; without the pause each
    allocation burst triggers full collections that cost more than the parse itself.
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def read_geojson(path: str | os.PathLike) -> PoseRun:
    """Read a GeoJSON file of timed LineString/Point features into a ``PoseRun``."""
    with _no_gc():
        # the parsed document is freed when _read returns, before collection resumes
        return _read(path)


def _read(path: str | os.PathLike) -> PoseRun:
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RunFormatError(path, None, None, f"cannot read file: {exc}") from None
    if data.startswith(_BOM):
        data = data[len(_BOM):]
    # The scan for booleans (below) runs in numpy, which releases the GIL, beside the parse.
    pool = ThreadPoolExecutor(1)
    bools = pool.submit(_stray_booleans, data)
    pool.shutdown(wait=False)
    try:
        # orjson (C) parses in a third of the stdlib's time; it refuses what json accepts
        # beyond RFC 8259 (NaN, huge integers, lone surrogates), so on any refusal the
        # stdlib decides, and its error names the line.
        doc = orjson.loads(data)
    except orjson.JSONDecodeError:
        doc = None
    text_cache: list[str] = []

    def text() -> str:
        if not text_cache:
            try:
                text_cache.append(data.decode("utf-8"))
            except UnicodeDecodeError as exc:
                raise RunFormatError(path, None, None, f"cannot read file: {exc}") from None
        return text_cache[0]

    if doc is None:
        try:
            doc = json.loads(text())
        except json.JSONDecodeError as exc:
            raise RunFormatError(path, exc.lineno, None, f"not valid JSON: {exc.msg}") from None
    # JSON booleans would pass numpy's float conversion as 0/1; with any besides the one
    # posefix writes, take the careful path.
    fast = _fast_linestring(doc) if bools.result() == 0 else None
    if fast is not None:

        def line_of_feature(_row: int) -> int | None:
            return getattr(_features(loads_with_lines(text()))[0][1], "line", None)

        return build_run(path, *fast[:5], line_of_row=line_of_feature, gnss=fast[5], images=fast[6],
                         extra=_extra_columns(doc, len(fast[0])), field_names=_FIELD_NAMES)
    try:
        rows, owners = _collect(doc)
    except _Fail:
        # Re-parse keeping line numbers to say where.
        try:
            _collect(loads_with_lines(text()))
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
            line_cache["doc"] = loads_with_lines(text())
            line_cache["rows"] = _collect(line_cache["doc"])[1]
        owners_l = line_cache["rows"]
        return getattr(owners_l[i], "line", None) if i < len(owners_l) else None

    return build_run(
        path, t, lat, lon, alt, q, line_of_row=line_of_row, gnss=gnss, images=images, extra=extra,
        field_names=_FIELD_NAMES,
    )


_BOM = "\ufeff".encode()
_FLAG_BEFORE = re.compile(rb'"orientation_derived"\s*:\s*$')


def _stray_booleans(data: bytes) -> int:
    """How many ``true``/``false`` the document holds besides ``orientation_derived``'s value.

    Only letters ``t`` and ``f`` can start one, and numbers hold neither, so numpy finds
    the few candidates without a Python-level pass over the bytes.
    """
    arr = np.frombuffer(data, dtype=np.uint8)
    count = 0
    for word in (b"true", b"false"):
        pos = np.flatnonzero(arr == word[0])
        pos = pos[pos + len(word) <= arr.size]
        ok = np.ones(pos.size, dtype=bool)
        for k in range(1, len(word)):
            ok &= arr[pos + k] == word[k]
        for p in pos[ok].tolist():
            # whitespace of over 64 bytes before the flag's value only costs the careful path
            if not _FLAG_BEFORE.search(data, max(0, p - 64 - len(b'"orientation_derived":')), p):
                count += 1
    return count
_FIELD_NAMES = {"t_s": "times", "lat_deg": "coordinates (lat)", "lon_deg": "coordinates (lon)",
                "alt_m": "coordinates (alt)", "q_body_to_enu_wxyz": "q_body_to_enu_wxyz",
                "gnss_lat_deg": "gnss (lat)", "gnss_lon_deg": "gnss (lon)", "gnss_alt_m": "gnss (alt)"}


def _numeric_array(values: Any, shape_tail: tuple[int, ...]) -> np.ndarray | None:
    """``values`` as a float array of shape (n, *shape_tail), or None if it is anything else."""
    if not isinstance(values, list):
        return None
    try:
        arr = np.array(values)  # no dtype: strings give a str array, nulls an object array
    except (TypeError, ValueError):
        return None
    if arr.dtype.kind not in "fi" or arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        return None
    return arr.astype(float, copy=False)


def _fast_linestring(doc: Any):
    """A single timed LineString read with numpy in one go (no per-vertex Python), or None.

    Anything unusual (several features, ISO times, 2-D coordinates mixed with 3-D, nulls,
    strings) returns None and the careful per-vertex path handles it -- and names the
    line and field of any error.
    """
    try:
        feats = _features(doc)
    except _Fail:
        return None
    if len(feats) != 1:
        return None
    feat = feats[0][1]
    if not isinstance(feat, dict) or feat.get("type") != "Feature":
        return None
    geom = feat.get("geometry") or {}
    props = feat.get("properties") or {}
    if not isinstance(geom, dict) or geom.get("type") != "LineString" or not isinstance(props, dict):
        return None
    coords = _numeric_array(geom.get("coordinates"), (3,))
    times = _numeric_array(props.get("times"), ())
    if coords is None or times is None or len(times) != len(coords) or len(coords) == 0:
        return None
    q = None
    if "q_body_to_enu_wxyz" in props:
        q = _numeric_array(props["q_body_to_enu_wxyz"], (4,))
        if q is None or len(q) != len(coords):
            return None
    gnss = None
    if "gnss" in props:
        g = props["gnss"]
        if not isinstance(g, list) or len(g) != len(coords):
            return None
        g = [[np.nan] * 3 if v is None else v for v in g]
        garr = _numeric_array(g, (3,))
        if garr is None:
            return None
        gnss = (garr[:, 1], garr[:, 0], garr[:, 2])
    images = None
    if "images" in props:
        im = props["images"]
        if not isinstance(im, list) or len(im) != len(coords) or not all(isinstance(v, str) for v in im):
            return None
        images = im
    return times, coords[:, 1], coords[:, 0], coords[:, 2], q, gnss, images


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


def _json_array_of_rows(pieces: list, n: int) -> bytes:
    """``[row0,row1,...]`` where each row is rendered from ``pieces`` (see ``render_rows``)."""
    from posefix.io._text import render_rows

    if n == 0:
        return b"[]"
    body = render_rows(pieces + [","], nan_text="null")
    return b"[" + body[:-1] + b"]"


def write_geojson(run: PoseRun, path: str | os.PathLike) -> None:
    """Write ``run`` as a FeatureCollection with one timed LineString, atomically.

    The large arrays are rendered column-wise in C++ (shortest round-trip floats), so an
    hour at 100 Hz writes in well under a second; the rest goes through ``json``.
    """
    n = run.n
    q = run.q_body_to_enu_wxyz
    coords = _json_array_of_rows(["[", run.lon_deg, ",", run.lat_deg, ",", run.alt_m, "]"], n)
    times = _json_array_of_rows([run.t_s], n)
    quats = _json_array_of_rows(["[", q[:, 0], ",", q[:, 1], ",", q[:, 2], ",", q[:, 3], "]"], n)
    parts = [
        b'{"type":"FeatureCollection","features":[{"type":"Feature","geometry":{"type":"LineString","coordinates":',
        coords, b'},"properties":{"times":', times, b',"q_body_to_enu_wxyz":', quats,
        b',"orientation_derived":', json.dumps(bool(run.orientation_derived)).encode(),
    ]
    if run.has_gnss:
        g = np.column_stack([run.gnss_lon_deg, run.gnss_lat_deg, run.gnss_alt_m])
        ok = np.all(np.isfinite(g), axis=1)
        rows = _json_array_of_rows(["[", g[:, 0], ",", g[:, 1], ",", g[:, 2], "]"], n)
        if not ok.all():
            # a sample without a fix is null, not [null,null,null]
            rows = rows.replace(b"[null,null,null]", b"null")
        parts += [b',"gnss":', rows]
    if run.images is not None:
        parts += [b',"images":', json.dumps(list(run.images)).encode()]
    if run.extra:
        parts += [b',"extra":', json.dumps({k: _jsonable(v) for k, v in run.extra.items()}, allow_nan=False).encode()]
    parts.append(b"}}]}")
    with atomic_write(path, "wb") as fh:
        for part in parts:
            fh.write(part)
