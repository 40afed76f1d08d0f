"""Columnar run files: Parquet and Arrow IPC (Feather v2), the form a fleet stores hours of
100 Hz data in.

The columns are the interchange CSV's (``posefix.io.csv``): ``t`` (s), ``lat``/``lon``
(WGS84 degrees), ``alt`` (m above the ellipsoid), ``qw,qx,qy,qz`` (unit quaternion, body
x fwd/y left/z up -> local ENU), optional ``gnss_lat,gnss_lon,gnss_alt`` (null: no fix),
``image`` and any other column kept as is. Each field carries its unit in its metadata
(``unit``), and the schema a ``posefix`` entry naming the layout. Values are stored exactly
(no rounding, float64), so a round trip gives the run back bit for bit.

Errors name the file, the field and, for a bad value, the 1-based row in the ``line`` slot
(these files have no lines).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from posefix.core.run import PoseRun
from posefix.io._build import build_run
from posefix.io.atomic import atomic_write
from posefix.io.csv import GNSS_COLUMNS, IMAGE_COLUMN, NUMERIC, POSE_COLUMNS, QUAT_COLUMNS, check_columns, run_to_table
from posefix.io.errors import RunFormatError

__all__ = [
    "read_parquet", "write_parquet", "write_parquet_table", "read_arrow", "write_arrow", "UNITS", "run_to_arrow",
    "arrow_to_run",
]

UNITS = {
    "t": "s", "lat": "deg", "lon": "deg", "alt": "m", "qw": "1", "qx": "1", "qy": "1", "qz": "1",
    "gnss_lat": "deg", "gnss_lon": "deg", "gnss_alt": "m",
}
LAYOUT = {"layout": "posefix-run", "version": 1,
          "frames": "WGS84 lat/lon/ellipsoidal alt; q = body (x fwd, y left, z up) -> local ENU, Hamilton, w first"}


def run_to_arrow(run: PoseRun):
    """The run as an Arrow table: interchange columns, exact values, units in the metadata."""
    import pyarrow as pa

    table = run_to_table(run, exact=True)
    fields = [f.with_metadata({"unit": UNITS[f.name]}) if f.name in UNITS else f for f in table.schema]
    meta = dict(LAYOUT, orientation_derived=bool(run.orientation_derived))
    schema = pa.schema(fields, metadata={"posefix": json.dumps(meta)})
    return pa.Table.from_arrays(table.columns, schema=schema)


def arrow_to_run(path: str | os.PathLike, table) -> PoseRun:
    """Check and build a run from an Arrow table read from ``path`` (errors name it)."""
    import pyarrow as pa

    names = list(table.column_names)
    check_columns(Path(path), names, None, where="schema")
    if table.num_rows == 0:
        raise RunFormatError(path, None, None, "the run is empty (no rows)")
    for name in names:
        typ = table.schema.field(name).type
        if name in NUMERIC and not (pa.types.is_floating(typ) or pa.types.is_integer(typ)):
            raise RunFormatError(path, None, name, f"column type {typ} is not a number")

    def numeric(name: str, nullable: bool) -> np.ndarray:
        col = table.column(name)
        arr = col.to_numpy().astype(float, copy=False) if col.null_count == 0 else \
            col.cast(pa.float64()).fill_null(np.nan).to_numpy()
        if not nullable and col.null_count:
            row = int(np.flatnonzero(col.is_null().to_numpy(zero_copy_only=False))[0])
            raise RunFormatError(path, row + 1, name, "value is missing")
        return arr

    t, lat, lon, alt = (numeric(c, False) for c in POSE_COLUMNS)
    q = np.column_stack([numeric(c, False) for c in QUAT_COLUMNS]) if "qw" in names else None
    gnss = tuple(numeric(c, True) for c in GNSS_COLUMNS) if "gnss_lat" in names else None
    images = None
    if IMAGE_COLUMN in names:
        images = [v or "" for v in table.column(IMAGE_COLUMN).cast(pa.string()).to_pylist()]
    known = set(NUMERIC) | {IMAGE_COLUMN}
    extra = {c: table.column(c).to_numpy(zero_copy_only=False) for c in names if c not in known}
    run = build_run(path, t, lat, lon, alt, q, line_of_row=lambda i: i + 1, gnss=gnss, images=images, extra=extra)
    meta = (table.schema.metadata or {}).get(b"posefix")
    if q is not None and meta is not None and json.loads(meta).get("orientation_derived"):
        from dataclasses import replace

        run = replace(run, orientation_derived=True)
    return run


def _unreadable(path: Path, kind: str, exc: Exception) -> RunFormatError:
    return RunFormatError(path, None, None, f"not a readable {kind} file ({' '.join(str(exc).split())})")


def read_parquet(path: str | os.PathLike) -> PoseRun:
    import pyarrow as pa
    import pyarrow.parquet as pq

    p = Path(path)
    try:
        table = pq.read_table(p, use_threads=True)
    except (pa.ArrowException, OSError) as exc:
        raise _unreadable(p, "Parquet", exc) from None
    return arrow_to_run(p, table)


def write_parquet(run: PoseRun, path: str | os.PathLike) -> None:
    with atomic_write(path, "wb") as fh:
        write_parquet_table(run_to_arrow(run), fh)


def write_parquet_table(table, where) -> None:
    """Parquet as posefix writes it: float columns byte-stream-split (their bytes grouped by
    significance, which the codec then finds runs in: an hour at 100 Hz 32 -> 19 MB), LZ4
    (as small as zstd level 1 there, for less CPU on both write and read); dictionary
    encoding only for text (float samples are all distinct: a dictionary tried first triples
    the write time); min/max statistics only for ``t``, the column a reader filters on."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    text = [f.name for f in table.schema if pa.types.is_string(f.type)]
    floats = [f.name for f in table.schema if pa.types.is_floating(f.type)]
    stats = [name for name in ("t",) if name in table.column_names]
    pq.write_table(table, where, compression="lz4", use_dictionary=text or False,
                   use_byte_stream_split=floats or False, write_statistics=stats or False)


def read_arrow(path: str | os.PathLike) -> PoseRun:
    import pyarrow as pa
    import pyarrow.ipc as ipc

    p = Path(path)
    try:
        with pa.memory_map(str(p)) as source:
            table = ipc.open_file(source).read_all()
    except (pa.ArrowException, OSError) as exc:
        raise _unreadable(p, "Arrow IPC", exc) from None
    return arrow_to_run(p, table)


def write_arrow(run: PoseRun, path: str | os.PathLike) -> None:
    """Arrow IPC file format (Feather v2), uncompressed: memory-mapped on read."""
    import pyarrow.ipc as ipc

    table = run_to_arrow(run)
    with atomic_write(path, "wb") as fh:
        with ipc.new_file(fh, table.schema) as writer:
            writer.write_table(table)
