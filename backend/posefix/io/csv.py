"""Interchange CSV: the format every part of posefix speaks.

Header row, then one sample per line. Columns (any order):

=================  ========================================================
``t``              time, seconds (float, strictly increasing)
``lat``, ``lon``   WGS84 degrees
``alt``            metres above the ellipsoid
``qw,qx,qy,qz``    unit quaternion body (x fwd, y left, z up) -> local ENU;
                   optional as a group (missing: heading derived from track)
``gnss_lat,gnss_lon,gnss_alt``  optional raw GNSS fix (empty/NaN: no fix)
``image``          optional, image names separated by ``;``
anything else      kept verbatim as text and written back
=================  ========================================================

Parsing is columnar (pyarrow) so a one-hour 100 Hz run parses in a fraction of a second.
When it fails, a slower pass finds the exact line and field to name in the error. Lines
are counted as physical lines; fields containing quoted newlines are not supported.
Files under ``SMALL_FILE_BYTES`` (a few thousand rows) are read and written by the standard
library instead, to the same arrays, errors and bytes: importing pyarrow costs about 40 ms of
CPU, more than the whole parse of such a file.
"""

from __future__ import annotations

import csv as _stdcsv
import io as _io
import math
import os
import sys
from pathlib import Path

import numpy as np

from posefix.core.run import PoseRun
from posefix.io._build import build_run
from posefix.io.atomic import atomic_write
from posefix.io.errors import RunFormatError

__all__ = ["read_csv", "write_csv", "POSE_COLUMNS", "QUAT_COLUMNS", "GNSS_COLUMNS"]

POSE_COLUMNS = ("t", "lat", "lon", "alt")
QUAT_COLUMNS = ("qw", "qx", "qy", "qz")
GNSS_COLUMNS = ("gnss_lat", "gnss_lon", "gnss_alt")
IMAGE_COLUMN = "image"
NUMERIC = POSE_COLUMNS + QUAT_COLUMNS + GNSS_COLUMNS
# Values that mean "missing" (null): only honoured in the optional GNSS columns.
NULL_VALUES = ["", "nan", "NaN", "NAN", "NA", "null", "NULL"]


def _header(path: Path, data: bytes) -> list[str]:
    end = data.find(b"\n")
    first = (data if end < 0 else data[:end]).rstrip(b"\r")
    if not first.strip():
        raise RunFormatError(path, 1, None, "empty file or blank header line; expected a header row "
                             f"with at least {', '.join(POSE_COLUMNS)}")
    try:
        text = first.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise RunFormatError(path, 1, None, f"header is not UTF-8 text ({exc.reason})") from None
    names = [c.strip() for c in next(_stdcsv.reader([text]))]
    check_columns(path, names, 1)
    return names


def check_columns(path: Path, names: list[str], line: int | None, where: str = "header") -> None:
    """The interchange columns' rules: named once each, the pose present, groups complete."""
    seen: set[str] = set()
    for name in names:
        if not name:
            raise RunFormatError(path, line, None, f"empty column name in {where}")
        if name in seen:
            raise RunFormatError(path, line, name, f"column appears twice in {where}")
        seen.add(name)
    missing = [c for c in POSE_COLUMNS if c not in seen]
    if missing:
        raise RunFormatError(path, line, ",".join(missing), f"missing required column(s); {where} has: {', '.join(names)}")
    q_present = [c for c in QUAT_COLUMNS if c in seen]
    if q_present and len(q_present) != 4:
        miss = [c for c in QUAT_COLUMNS if c not in seen]
        raise RunFormatError(path, line, ",".join(miss), "orientation needs all of qw,qx,qy,qz")
    g_present = [c for c in GNSS_COLUMNS if c in seen]
    if g_present and len(g_present) != 3:
        miss = [c for c in GNSS_COLUMNS if c not in seen]
        raise RunFormatError(path, line, ",".join(miss), "raw GNSS needs all of gnss_lat,gnss_lon,gnss_alt")


def _read_head(path: Path, chunk: int = 1 << 16) -> bytes:
    """The file's first line (or all of it if shorter), read without loading the rest."""
    with open(path, "rb") as fh:
        head = fh.read(chunk)
        while b"\n" not in head:
            more = fh.read(chunk)
            if not more:
                break
            head += more
    return head


def _data_line_numbers(data: bytes) -> np.ndarray:
    """1-based physical line numbers of the non-blank lines after the header."""
    buf = np.frombuffer(data, dtype=np.uint8)
    nl = np.flatnonzero(buf == 10)
    starts = np.concatenate(([0], nl + 1))
    ends = np.concatenate((nl, [len(buf)]))
    # a line is blank when it holds nothing but optional '\r'
    length = ends - starts
    blank = (length == 0) | ((length == 1) & (buf[np.minimum(starts, len(buf) - 1)] == 13))
    lines = np.flatnonzero(~blank) + 1
    return lines[1:]  # drop the header


def _locate_failure(path: Path, data: bytes, names: list[str]) -> RunFormatError:
    """Slow pass after the fast parser failed: find the first bad line and field."""
    text = data.decode("utf-8-sig", errors="replace")
    reader = _stdcsv.reader(_io.StringIO(text, newline=""))
    next(reader, None)
    for row in reader:
        line = reader.line_num
        if not row or (len(row) == 1 and not row[0].strip()):
            continue
        if len(row) != len(names):
            return RunFormatError(path, line, None, f"expected {len(names)} fields, found {len(row)}")
        for name, value in zip(names, row):
            if name not in NUMERIC:
                continue
            v = value.strip()
            try:
                if "_" in v:  # float() reads 1_000, which Arrow refuses
                    raise ValueError(v)
                x = float(v)
            except ValueError:
                if name in GNSS_COLUMNS and v in NULL_VALUES:
                    continue
                return RunFormatError(path, line, name, f"not a number: {value!r}")
            if math.isnan(x) and name not in GNSS_COLUMNS:
                return RunFormatError(path, line, name, "value is NaN")
    return RunFormatError(path, None, None, "the file could not be parsed as CSV")


def _parse(pacsv, pa, source, names: list[str], column_types: dict):
    return pacsv.read_csv(
        source,
        # our own parse of the header (stripped names, BOM removed) names the columns
        read_options=pacsv.ReadOptions(use_threads=True, block_size=1 << 24, column_names=names, skip_rows=1),
        parse_options=pacsv.ParseOptions(newlines_in_values=False),
        convert_options=pacsv.ConvertOptions(
            column_types=column_types, null_values=NULL_VALUES, strings_can_be_null=False,
            quoted_strings_can_be_null=False,
        ),
    )


# Below this size a file is parsed in Python (``_read_small``): quicker than importing pyarrow.
SMALL_FILE_BYTES = 1 << 20


def _read_small(path: Path, data: bytes, names: list[str]) -> PoseRun:
    """``read_csv`` of a small file by the standard library: the same arrays and errors as the
    Arrow path (empty and null-like fields are missing, NaN only in the GNSS columns)."""
    text = data.decode("utf-8-sig", errors="strict")
    reader = _stdcsv.reader(_io.StringIO(text, newline=""))
    next(reader, None)
    rows, lines = [], []
    width = len(names)
    for row in reader:
        if not row or (len(row) == 1 and not row[0].strip()):
            continue
        if len(row) != width:
            raise RunFormatError(path, reader.line_num, None, f"expected {width} fields, found {len(row)}")
        rows.append(row)
        lines.append(reader.line_num)
    if not rows:
        raise RunFormatError(path, 2, None, "the run is empty (header but no samples)")
    cols = list(zip(*rows))
    nulls = set(NULL_VALUES)

    def numeric(name: str) -> np.ndarray:
        """The column as floats, null-like fields NaN; a field that is not a number is named
        by ``_locate_failure``, the first bad line in the file, as on the Arrow path."""
        values = cols[names.index(name)]
        if "_" not in "".join(values):  # float() reads 1_000, which Arrow refuses
            try:
                return np.array([float(v) for v in values])
            except ValueError:
                pass  # a null-like field, or a bad one: one by one below
        out = np.empty(len(values))
        for i, value in enumerate(values):
            v = value.strip()
            if v in nulls:
                out[i] = np.nan  # where the column may not miss, checked() names it
                continue
            try:
                if "_" in v:
                    raise ValueError(v)
                out[i] = float(v)
            except ValueError:
                raise _locate_failure(path, data, names) from None
        return out

    def checked(name: str) -> np.ndarray:
        arr = numeric(name)
        bad = np.isnan(arr)
        if bad.any():
            raise RunFormatError(path, lines[int(np.flatnonzero(bad)[0])], name, "value is missing or NaN")
        return arr

    t = checked("t")
    lat, lon, alt = (checked(c) for c in ("lat", "lon", "alt"))
    q = np.column_stack([checked(c) for c in QUAT_COLUMNS]) if "qw" in names else None
    gnss = tuple(numeric(c) for c in GNSS_COLUMNS) if "gnss_lat" in names else None
    images = list(cols[names.index(IMAGE_COLUMN)]) if IMAGE_COLUMN in names else None
    known = set(NUMERIC) | {IMAGE_COLUMN}
    extra = {}
    for c in names:
        if c not in known:
            a = np.empty(len(rows), dtype=object)
            a[:] = cols[names.index(c)]
            extra[c] = a
    return build_run(path, t, lat, lon, alt, q, line_of_row=lambda i: lines[i] if i < len(lines) else i + 2,
                     gnss=gnss, images=images, extra=extra)


def read_csv(path: str | os.PathLike) -> PoseRun:
    """Read an interchange CSV file into a ``PoseRun`` (small files: ``_read_small``).

    Raises
    ------
    RunFormatError
        naming the file, 1-based line and column for: a missing/unreadable file, missing
        columns, a non-numeric or NaN value, latitude/longitude out of range, timestamps
        not strictly increasing, a zero or non-unit quaternion, an empty run.
    """
    path = Path(path)
    try:
        head = _read_head(path)
    except OSError as exc:
        raise RunFormatError(path, None, None, f"cannot read file: {exc.strerror or exc}") from None
    names = _header(path, head)
    if len(head) < SMALL_FILE_BYTES:
        try:
            size = path.stat().st_size
        except OSError as exc:
            raise RunFormatError(path, None, None, f"cannot read file: {exc.strerror or exc}") from None
        if size < SMALL_FILE_BYTES:
            try:
                data = path.read_bytes()
            except OSError as exc:
                raise RunFormatError(path, None, None, f"cannot read file: {exc.strerror or exc}") from None
            try:
                return _read_small(path, data, names)
            except UnicodeDecodeError:
                pass  # Arrow's reading of such a file decides
            except _stdcsv.Error:
                raise _locate_failure(path, data, names) from None
    import pyarrow as pa
    import pyarrow.csv as pacsv

    column_types = {c: (pa.float64() if c in NUMERIC else pa.string()) for c in names}
    cache: dict[str, bytes] = {}

    def data() -> bytes:
        # the whole file, only needed to name the line of an error
        if "data" not in cache:
            cache["data"] = path.read_bytes()
        return cache["data"]

    try:
        with pa.memory_map(str(path)) as source:
            table = _parse(pacsv, pa, source, names, column_types)
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        raise _locate_failure(path, data(), names) from None
    except OSError as exc:
        raise RunFormatError(path, None, None, f"cannot read file: {exc.strerror or exc}") from None

    n = table.num_rows
    if n == 0:
        raise RunFormatError(path, 2, None, "the run is empty (header but no samples)")
    lines = None

    def line_of_row(i: int) -> int:
        nonlocal lines
        if lines is None:
            lines = _data_line_numbers(data())
        return int(lines[i]) if i < len(lines) else i + 2

    def numeric(name: str, nullable: bool) -> np.ndarray:
        col = table.column(name)
        arr = col.to_numpy(zero_copy_only=False).astype(float, copy=False)
        if not nullable and col.null_count:
            row = int(np.flatnonzero(np.isnan(arr))[0]) if np.isnan(arr).any() else 0
            raise RunFormatError(path, line_of_row(row), name, "value is missing or NaN")
        return arr

    t = numeric("t", False)
    lat, lon, alt = (numeric(c, False) for c in ("lat", "lon", "alt"))
    q = None
    if "qw" in names:
        q = np.column_stack([numeric(c, False) for c in QUAT_COLUMNS])
    gnss = None
    if "gnss_lat" in names:
        gnss = tuple(numeric(c, True) for c in GNSS_COLUMNS)
    images = None
    if IMAGE_COLUMN in names:
        images = table.column(IMAGE_COLUMN).to_pylist()
    known = set(NUMERIC) | {IMAGE_COLUMN}
    extra = {c: table.column(c).to_numpy(zero_copy_only=False) for c in names if c not in known}
    return build_run(path, t, lat, lon, alt, q, line_of_row=line_of_row, gnss=gnss,
                     images=images, extra=extra)


def _column_for_csv(a: np.ndarray):
    import pyarrow as pa

    arr = np.asarray(a)
    if arr.dtype.kind in "fiub":
        return pa.array(arr)
    return pa.array([("" if v is None else str(v)) for v in arr.tolist()], type=pa.string())


# Decimal places written: far below any physical meaning (1e-10 deg is 11 µm on the
# ground), and shorter numbers make a one-hour 100 Hz file ~25 % smaller and faster to
# write. Times are written exactly (shortest round-trip form): edits name samples by them.
DECIMALS = {"lat": 10, "lon": 10, "alt": 6, "q": 12, "gnss_lat": 10, "gnss_lon": 10, "gnss_alt": 6}


def run_to_table(run: PoseRun, exact: bool = False):
    """The run as a pyarrow Table in interchange column order (``exact``: no rounding)."""
    import pyarrow as pa

    def col(name: str, a: np.ndarray):
        a = np.ascontiguousarray(a, dtype=float)
        places = DECIMALS.get("q" if name in QUAT_COLUMNS else name)
        if places is not None and not exact:
            a = np.round(a, places) + 0.0  # + 0.0 turns -0.0 into 0.0 ("-0" in the file)
        return pa.array(a, from_pandas=True)  # NaN -> empty field

    qarr = run.q_body_to_enu_wxyz
    arrays = {"t": pa.array(np.ascontiguousarray(run.t_s, dtype=float))}
    for name, a in (("lat", run.lat_deg), ("lon", run.lon_deg), ("alt", run.alt_m),
                    ("qw", qarr[:, 0]), ("qx", qarr[:, 1]), ("qy", qarr[:, 2]), ("qz", qarr[:, 3])):
        arrays[name] = col(name, a)
    if run.has_gnss:
        for k, v in zip(GNSS_COLUMNS, (run.gnss_lat_deg, run.gnss_lon_deg, run.gnss_alt_m)):
            arrays[k] = col(k, v)
    if run.images is not None:
        arrays[IMAGE_COLUMN] = pa.array(run.images, type=pa.string())
    for k, v in run.extra.items():
        if k in arrays:
            continue
        arrays[k] = _column_for_csv(v)
    return pa.table(arrays)


# Rows per slice written by one thread: below this a thread costs more than it saves.
WRITE_SLICE_ROWS = 50_000


def write_csv(run: PoseRun, path: str | os.PathLike, exact: bool = False) -> None:
    """Write ``run`` as interchange CSV, atomically (temp file renamed at the end).

    Floats are written in shortest round-trip form after rounding to ``DECIMALS`` (unless
    ``exact``), so times read back bit for bit and positions to 1e-10 degrees. Long runs are
    formatted in slices on several threads (Arrow's writer releases the GIL), then written
    in order: the bytes are those of one writer.
    """
    small = _csv_small(run, exact) if run.n <= SMALL_WRITE_ROWS and "pyarrow" not in sys.modules else None
    if small is not None:
        with atomic_write(path, "wb") as fh:
            fh.write(small)
        return
    table = run_to_table(run, exact=exact)
    with atomic_write(path, "wb") as fh:
        for chunk in _csv_chunks(table):
            fh.write(chunk)


# Runs up to this many rows are written by ``_csv_small`` when pyarrow is not loaded yet:
# formatting them in Python costs less than importing it.
SMALL_WRITE_ROWS = 5_000


def _arrow_float(x: float) -> str:
    """A double as Arrow's CSV writer prints it: the shortest round-trip digits, in fixed
    notation for decimal exponents -6..9, else d.ddde+XX; NaN as an empty field."""
    if x != x:
        return ""
    if x in (math.inf, -math.inf):
        return "inf" if x > 0 else "-inf"
    r = repr(x)
    sign = "-" if r[0] == "-" else ""
    r = r.lstrip("-")
    if "e" in r:
        mant, e = r.split("e")
        exp = int(e)
        digits = mant.replace(".", "")
    else:
        whole, _, frac = r.partition(".")
        frac = frac.rstrip("0")
        if whole != "0":
            exp = len(whole) - 1
            digits = (whole + frac)
        else:
            stripped = frac.lstrip("0")
            exp = -(len(frac) - len(stripped)) - 1
            digits = stripped or "0"
        digits = digits.rstrip("0") or "0"
    digits = digits.lstrip("0") or "0"
    digits = digits.rstrip("0") or "0"
    if -6 <= exp < 10:
        if exp < 0:
            return f"{sign}0.{'0' * (-exp - 1)}{digits}"
        if len(digits) <= exp + 1:
            return sign + digits + "0" * (exp + 1 - len(digits))
        return f"{sign}{digits[:exp + 1]}.{digits[exp + 1:]}"
    mant = digits[0] + ("." + digits[1:] if len(digits) > 1 else "")
    return f"{sign}{mant}e{'+' if exp >= 0 else '-'}{abs(exp)}"


def _float_strings(a: np.ndarray) -> list[str]:
    """``_arrow_float`` of every value; the usual magnitudes straight from repr."""
    mag = np.abs(a)
    usual = ((mag >= 1e-4) & (mag < 1e10)) | (a == 0)  # repr prints these in fixed notation too
    out = [v[:-2] if v.endswith(".0") else v for v in map(repr, a.tolist())]
    for i in np.flatnonzero(~usual).tolist():
        out[i] = _arrow_float(float(a[i]))
    return out


def _csv_small(run: PoseRun, exact: bool) -> bytes | None:
    """The bytes Arrow's writer makes of ``run_to_table(run, exact)``, formatted in Python
    (None for a column kind it does not cover: then Arrow writes)."""
    cols: dict[str, list[str]] = {"t": _float_strings(np.ascontiguousarray(run.t_s, dtype=float))}
    qarr = run.q_body_to_enu_wxyz
    floats = [("lat", run.lat_deg), ("lon", run.lon_deg), ("alt", run.alt_m),
              ("qw", qarr[:, 0]), ("qx", qarr[:, 1]), ("qy", qarr[:, 2]), ("qz", qarr[:, 3])]
    if run.has_gnss:
        floats += list(zip(GNSS_COLUMNS, (run.gnss_lat_deg, run.gnss_lon_deg, run.gnss_alt_m)))
    for name, a in floats:
        a = np.ascontiguousarray(a, dtype=float)
        places = DECIMALS.get("q" if name in QUAT_COLUMNS else name)
        if places is not None and not exact:
            a = np.round(a, places) + 0.0
        cols[name] = _float_strings(a)
        if np.isnan(a).any():  # from_pandas: NaN is a null, an empty field
            cols[name] = ["" if v == "nan" else v for v in cols[name]]

    def quoted(values) -> list[str]:
        # Arrow's "needed" quoting quotes every string (a null is an empty field)
        return ["" if v is None else '"' + str(v).replace('"', '""') + '"' for v in values]

    if run.images is not None:
        cols[IMAGE_COLUMN] = quoted(run.images)
    for k, v in run.extra.items():
        if k in cols:
            continue
        arr = np.asarray(v)
        if arr.dtype.kind in "fiub":
            return None
        cols[k] = ['"' + ("" if x is None else str(x)).replace('"', '""') + '"' for x in arr.tolist()]
    lines = [",".join(cols)]
    lines += map(",".join, zip(*cols.values()))
    return ("\n".join(lines) + "\n").encode()


def _csv_chunks(table) -> list:
    import pyarrow as pa
    import pyarrow.csv as pacsv

    def fmt(i: int, part):
        sink = pa.BufferOutputStream()
        opts = pacsv.WriteOptions(quoting_style="needed", quoting_header="none", include_header=i == 0)
        pacsv.write_csv(part, sink, write_options=opts)
        return sink.getvalue()

    k = max(1, min(os.cpu_count() or 1, table.num_rows // WRITE_SLICE_ROWS))
    if k == 1:
        return [fmt(0, table)]
    from concurrent.futures import ThreadPoolExecutor

    step = -(-table.num_rows // k)
    with ThreadPoolExecutor(k) as pool:
        return list(pool.map(fmt, range(k), [table.slice(i * step, step) for i in range(k)]))
