"""Pose run formats and the edits file (no web or database code).

>>> from posefix.io import read_run, write_run, read_edits, RunFormatError
>>> run = read_run("drive.csv")             # format from the extension, or fmt=...
>>> write_run(run, "drive.gpx")

Formats: ``csv`` (interchange), ``parquet`` and ``arrow`` (Arrow IPC / Feather v2: the
interchange columns, units in the schema), ``gpx``, ``geojson``, ``tum`` (needs ``origin``),
``kitti`` (raw ``oxts`` folder), ``comma2k19`` (segment folder). Write: csv, parquet, arrow,
gpx, geojson (and tum). Every reader raises ``RunFormatError(file, line, field, message)`` on bad input;
every writer writes a temporary file and renames it at the end.
"""

from __future__ import annotations

import os
from pathlib import Path

from posefix.io.edits import EditSet, MatchedEdits, Move, match_edits, read_edits, write_edits
from posefix.io.errors import EditMatchError, EditsFormatError, OrientationDerivedWarning, RunFormatError

__all__ = [
    "read_run", "write_run", "detect_format", "READ_FORMATS", "WRITE_FORMATS", "FILE_EXTENSIONS",
    "read_edits", "write_edits", "match_edits", "EditSet", "Move", "MatchedEdits",
    "RunFormatError", "EditsFormatError", "EditMatchError", "OrientationDerivedWarning",
]

READ_FORMATS = ("csv", "parquet", "arrow", "gpx", "geojson", "tum", "kitti", "comma2k19")
WRITE_FORMATS = ("csv", "parquet", "arrow", "gpx", "geojson", "tum")
_EXTENSIONS = {
    ".csv": "csv", ".parquet": "parquet", ".arrow": "arrow", ".feather": "arrow", ".ipc": "arrow",
    ".gpx": "gpx", ".geojson": "geojson", ".json": "geojson", ".tum": "tum", ".txt": "tum",
}

FILE_EXTENSIONS = tuple(sorted(_EXTENSIONS))  # the run files read by extension (folders aside)


def detect_format(path: str | os.PathLike, *, for_writing: bool = False) -> str:
    """Format name from the path: a known extension, or for a folder its layout."""
    p = Path(path)
    if not for_writing and p.is_dir():
        from posefix.io.comma2k19 import find_comma2k19_segment
        from posefix.io.kitti import find_oxts_dir

        if find_comma2k19_segment(p) is not None:
            return "comma2k19"
        if find_oxts_dir(p) is not None:
            return "kitti"
        raise RunFormatError(p, None, None, "folder is neither a comma2k19 segment nor a KITTI oxts folder")
    fmt = _EXTENSIONS.get(p.suffix.lower())
    if fmt is None:
        known = ", ".join(sorted(_EXTENSIONS))
        raise RunFormatError(p, None, None, f"unknown file extension {p.suffix!r} (known: {known}; or name the format)")
    return fmt


def read_run(path: str | os.PathLike, fmt: str | None = None, origin=None):
    """Read a pose run; ``fmt`` overrides detection; ``origin`` (lat, lon, alt) for TUM."""
    p = Path(path)
    fmt = fmt or detect_format(p)
    if fmt not in READ_FORMATS:
        raise RunFormatError(p, None, None, f"unknown format {fmt!r} (known: {', '.join(READ_FORMATS)})")
    if not p.exists():
        raise RunFormatError(p, None, None, "no such file or folder")
    if fmt == "csv":
        from posefix.io.csv import read_csv
        return read_csv(p)
    if fmt == "parquet":
        from posefix.io.columnar import read_parquet
        return read_parquet(p)
    if fmt == "arrow":
        from posefix.io.columnar import read_arrow
        return read_arrow(p)
    if fmt == "gpx":
        from posefix.io.gpx import read_gpx
        return read_gpx(p)
    if fmt == "geojson":
        from posefix.io.geojson import read_geojson
        return read_geojson(p)
    if fmt == "tum":
        from posefix.io.tum import read_tum
        return read_tum(p, origin)
    if fmt == "kitti":
        from posefix.io.kitti import read_kitti_oxts
        return read_kitti_oxts(p)
    from posefix.io.comma2k19 import read_comma2k19
    return read_comma2k19(p)


def write_run(run, path: str | os.PathLike, fmt: str | None = None, origin=None) -> None:
    """Write a pose run atomically; format from the extension unless ``fmt`` is given."""
    p = Path(path)
    fmt = fmt or detect_format(p, for_writing=True)
    if fmt not in WRITE_FORMATS:
        raise RunFormatError(p, None, None, f"cannot write format {fmt!r} (writable: {', '.join(WRITE_FORMATS)})")
    if not p.parent.is_dir():
        raise RunFormatError(p, None, None, f"output folder {str(p.parent)!r} does not exist")
    if fmt == "csv":
        from posefix.io.csv import write_csv
        write_csv(run, p)
    elif fmt == "parquet":
        from posefix.io.columnar import write_parquet
        write_parquet(run, p)
    elif fmt == "arrow":
        from posefix.io.columnar import write_arrow
        write_arrow(run, p)
    elif fmt == "gpx":
        from posefix.io.gpx import write_gpx
        write_gpx(run, p)
    elif fmt == "geojson":
        from posefix.io.geojson import write_geojson
        write_geojson(run, p)
    else:
        from posefix.io.tum import write_tum
        write_tum(run, p, origin)
