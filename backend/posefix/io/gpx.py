"""GPX 1.1 tracks (read with gpxpy after a defused XML check; written directly).

Reading takes every track point of every track segment in document order (or, with no
tracks, the route points). Times are required (UTC, to Unix seconds). Elevation missing
-> 0 m. Orientation comes from a posefix extension on each point if present::

    <extensions><pf:pose qw=".." qx=".." qy=".." qz=".." [gnss_lat gnss_lon gnss_alt]/></extensions>

otherwise the heading is derived from the track (roll, pitch zero) with a warning.
Documents with a DTD (entity expansion, external entities) are refused before gpxpy sees
them. gpxpy parses about 30,000 points per second: fine for GPS logs (1 Hz), slow for a
100 Hz run exported as GPX (interchange CSV is the fast format).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from posefix.core.run import PoseRun
from posefix.io._build import build_run
from posefix.io._timeconv import datetime_to_s, s_to_iso_utc_bytes
from posefix.io.atomic import atomic_write
from posefix.io.errors import RunFormatError

__all__ = ["read_gpx", "write_gpx", "POSEFIX_GPX_NS"]

POSEFIX_GPX_NS = "https://posefix.org/xmlns/gpx-pose/1"
_POINT_RE = {"trkpt": re.compile(rb"<(?:[\w.-]+:)?trkpt[\s>/]"), "rtept": re.compile(rb"<(?:[\w.-]+:)?rtept[\s>/]")}


class _Refused(Exception):
    pass


def _check_safe_xml(path: Path, data: bytes) -> None:
    """Refuse a document type declaration (entity bombs, external entities) before parsing.

    A C expat pass with only DTD handlers set is quick; any ``<!DOCTYPE`` or entity
    declaration stops it. Well-formedness errors are reported with their line. This is the
    check defusedxml makes (forbid_dtd), without building a tree.
    """
    import xml.parsers.expat

    parser = xml.parsers.expat.ParserCreate()

    def refuse(*_args):
        raise _Refused()

    parser.StartDoctypeDeclHandler = refuse
    parser.EntityDeclHandler = refuse
    parser.ExternalEntityRefHandler = refuse
    try:
        parser.Parse(data, True)
    except _Refused:
        raise RunFormatError(path, parser.CurrentLineNumber, "DOCTYPE",
                             "refused: XML with a DTD or entities is not accepted") from None
    except xml.parsers.expat.ExpatError as exc:
        raise RunFormatError(path, exc.lineno, None, f"not well-formed XML: {xml.parsers.expat.ErrorString(exc.code)}") from None


def _point_lines(data: bytes, kind: str) -> np.ndarray:
    starts = [m.start() for m in _POINT_RE[kind].finditer(data)]
    if not starts:
        return np.zeros(0, dtype=int)
    nl = np.flatnonzero(np.frombuffer(data, dtype=np.uint8) == 10)
    return np.searchsorted(nl, np.asarray(starts)) + 1


def _locate_bad_value(data: bytes) -> tuple[int, str, str] | None:
    """Find the first point with an unreadable lat/lon/ele/time: (line, field, message).

    Runs only after gpxpy refused the document (its errors carry no line numbers). The
    document has already passed the defused check, so expat sees no DTD.
    """
    import xml.parsers.expat

    from posefix.io._timeconv import parse_iso_utc

    found: list[tuple[int, str, str]] = []
    stack: list[str] = []
    text: list[str] = []
    parser = xml.parsers.expat.ParserCreate()

    def local(name: str) -> str:
        return name.rsplit(":", 1)[-1]

    def start(name, attrs):
        tag = local(name)
        stack.append(tag)
        text.clear()
        if found or tag not in ("trkpt", "rtept", "wpt"):
            return
        for key in ("lat", "lon"):
            value = attrs.get(key)
            try:
                float(value)
            except (TypeError, ValueError):
                found.append((parser.CurrentLineNumber, key, f"not a number: {value!r}"))
                return

    def chars(data_):
        text.append(data_)

    def end(name):
        tag = stack.pop() if stack else ""
        parent = stack[-1] if stack else ""
        if found or parent not in ("trkpt", "rtept", "wpt"):
            return
        value = "".join(text).strip()
        if tag == "ele":
            try:
                float(value)
            except ValueError:
                found.append((parser.CurrentLineNumber, "ele", f"not a number: {value!r}"))
        elif tag == "time":
            try:
                parse_iso_utc(value)
            except ValueError:
                found.append((parser.CurrentLineNumber, "time", f"not an ISO 8601 time: {value!r}"))

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError:
        return None
    return found[0] if found else None


def _pose_extension(point) -> dict[str, str] | None:
    for ext in getattr(point, "extensions", None) or []:
        if ext.tag.split("}")[-1] == "pose" and "qw" in ext.attrib:
            return dict(ext.attrib)
    return None


def read_gpx(path: str | os.PathLike) -> PoseRun:
    """Read a GPX 1.1 file's track (or route) points into a ``PoseRun``."""
    import gpxpy
    import gpxpy.gpx

    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RunFormatError(path, None, None, f"cannot read file: {exc.strerror or exc}") from None
    _check_safe_xml(path, data)
    try:
        doc = gpxpy.parse(data.decode("utf-8-sig"))
    except (gpxpy.gpx.GPXException, UnicodeDecodeError, ValueError) as exc:
        located = _locate_bad_value(data)
        if located is not None:
            raise RunFormatError(path, *located) from None
        raise RunFormatError(path, None, None, f"not a valid GPX document: {exc}") from None
    points = [p for trk in doc.tracks for seg in trk.segments for p in seg.points]
    kind = "trkpt"
    if not points:
        points = [p for rte in doc.routes for p in rte.points]
        kind = "rtept"
    if not points:
        raise RunFormatError(path, None, "trkpt", "the run is empty: no track or route points")
    lines = _point_lines(data, kind)

    def line_of_row(i: int) -> int | None:
        return int(lines[i]) if i < len(lines) else None

    n = len(points)
    t = np.empty(n)
    lat = np.empty(n)
    lon = np.empty(n)
    alt = np.zeros(n)
    exts = [_pose_extension(p) for p in points]
    has_q = all(e is not None for e in exts)
    q = np.empty((n, 4)) if has_q else None
    has_gnss = has_q and all("gnss_lat" in e for e in exts)
    gnss = np.full((3, n), np.nan) if has_gnss else None
    for i, p in enumerate(points):
        if p.time is None:
            raise RunFormatError(path, line_of_row(i), "time", "track point has no (valid) <time>")
        t[i] = datetime_to_s(p.time)
        lat[i], lon[i] = p.latitude, p.longitude
        if p.elevation is not None:
            alt[i] = p.elevation
        if has_q:
            e = exts[i]
            try:
                q[i] = [float(e[k]) for k in ("qw", "qx", "qy", "qz")]
                if has_gnss:
                    gnss[:, i] = [float(e[k]) if e[k] != "" else np.nan for k in ("gnss_lat", "gnss_lon", "gnss_alt")]
            except (KeyError, ValueError) as exc:
                raise RunFormatError(path, line_of_row(i), "pose", f"bad pose extension: {exc}") from None
    return build_run(
        path, t, lat, lon, alt, q, line_of_row=line_of_row,
        field_names={"t_s": "time", "alt_m": "ele", "q_body_to_enu_wxyz": "pose"},
        gnss=None if gnss is None else (gnss[0], gnss[1], gnss[2]),
    )


def write_gpx(run: PoseRun, path: str | os.PathLike, name: str | None = None) -> None:
    """Write ``run`` as one GPX 1.1 track, atomically.

    Times are ``t_s`` read as Unix seconds (UTC, microseconds). The orientation (and raw
    GNSS, if any) go in a ``pf:pose`` extension so posefix reads them back; other tools
    ignore it. Per-sample images and extra columns are not carried by GPX. Rows are
    rendered column-wise in threads (``_text.render_row_parts``) and written without joining.
    """
    from xml.sax.saxutils import escape

    from posefix.io._text import render_row_parts

    q = run.q_body_to_enu_wxyz
    pieces: list = [
        '<trkpt lat="', run.lat_deg, '" lon="', run.lon_deg, '"><ele>', run.alt_m, "</ele><time>",
        s_to_iso_utc_bytes(run.t_s), '</time><extensions><pf:pose qw="', q[:, 0], '" qx="', q[:, 1],
        '" qy="', q[:, 2], '" qz="', q[:, 3],
    ]
    if run.has_gnss:
        pieces += ['" gnss_lat="', run.gnss_lat_deg, '" gnss_lon="', run.gnss_lon_deg, '" gnss_alt="', run.gnss_alt_m]
    pieces.append('"/></extensions></trkpt>\n')
    body = render_row_parts(pieces, nan_text="")
    track_name = escape(name if name is not None else Path(run.source).stem or "posefix run")
    head = (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<gpx version="1.1" creator="posefix" xmlns="http://www.topografix.com/GPX/1/1" '
        f'xmlns:pf="{POSEFIX_GPX_NS}">\n'
        f"<trk><name>{track_name}</name><trkseg>\n"
    )
    with atomic_write(path, "wb") as fh:
        fh.write(head.encode("utf-8"))
        for part in body:
            fh.write(part)
        fh.write(b"</trkseg></trk>\n</gpx>\n")
