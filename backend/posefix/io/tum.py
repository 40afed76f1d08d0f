"""TUM RGB-D trajectory files: ``timestamp tx ty tz qx qy qz qw`` per line.

TUM positions are in a local frame, so reading needs an origin (lat, lon, alt): posefix
takes the frame as East-North-Up at that origin, and the quaternion as the rotation body
(x fwd, y left, z up) -> that frame. Orientations are re-expressed in the ENU frame at
each sample's own position (differs from the origin's by up to ~1 deg per 100 km).
Lines starting with ``#`` and blank lines are skipped.
"""

from __future__ import annotations

import io as _io
import os
from pathlib import Path

import numpy as np

from posefix.core.geodesy import OriginLike, as_origin, enu_to_geodetic, geodetic_to_enu, quat_local_enu_to_origin_enu
from posefix.core.rotations import quat_conjugate, quat_multiply
from posefix.core.run import PoseRun
from posefix.io._build import build_run
from posefix.io.atomic import atomic_write
from posefix.io.errors import RunFormatError

__all__ = ["read_tum", "write_tum"]

TUM_FIELDS = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")


def _parse_table(path: Path, fields: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Whitespace table -> (values (m, k) float, 1-based line numbers (m,)).

    numpy's C reader first; if it refuses anything (or finds NaN), a line-by-line pass
    names the line and field.
    """
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise RunFormatError(path, None, None, f"cannot read file: {exc}") from None
    if "," not in text:
        import warnings

        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # "no data": reported below
                vals = np.loadtxt(_io.StringIO(text), dtype=float, comments="#", ndmin=2)
        except ValueError:
            vals = None
        if vals is not None and vals.shape[0] > 0 and vals.shape[1] == len(fields) and not np.isnan(vals).any():
            lines = _data_lines(text)
            if len(lines) == vals.shape[0]:
                return vals, lines
    rows: list[list[float]] = []
    lines: list[int] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) != len(fields):
            raise RunFormatError(path, lineno, None, f"expected {len(fields)} values ({' '.join(fields)}), found {len(parts)}")
        vals = []
        for name, p in zip(fields, parts):
            try:
                v = float(p)
            except ValueError:
                raise RunFormatError(path, lineno, name, f"not a number: {p!r}") from None
            if v != v:
                raise RunFormatError(path, lineno, name, "value is NaN")
            vals.append(v)
        rows.append(vals)
        lines.append(lineno)
    if not rows:
        raise RunFormatError(path, None, None, "the run is empty (no data lines)")
    return np.asarray(rows, dtype=float), np.asarray(lines)


def _data_lines(text: str) -> np.ndarray:
    """1-based numbers of the lines that hold data (not blank, not a comment)."""
    out = [i for i, raw in enumerate(text.splitlines(), start=1) if raw.strip() and not raw.lstrip().startswith("#")]
    return np.asarray(out, dtype=int)


def read_tum(path: str | os.PathLike, origin: OriginLike | None) -> PoseRun:
    """Read a TUM trajectory; ``origin`` = (lat_deg, lon_deg, alt_m) of the local frame."""
    path = Path(path)
    if origin is None:
        raise RunFormatError(path, None, "origin", "TUM files are in a local frame: give its origin as lat,lon,alt (--origin)")
    try:
        o = as_origin(origin)
    except ValueError as exc:
        raise RunFormatError(path, None, "origin", str(exc)) from None
    vals, lines = _parse_table(path, TUM_FIELDS)
    lat, lon, alt = enu_to_geodetic(vals[:, 1:4], o)
    q_xyzw = vals[:, 4:8]
    q_origin = np.column_stack([q_xyzw[:, 3], q_xyzw[:, :3]])
    norm = np.linalg.norm(q_origin, axis=1)
    bad = np.flatnonzero(norm < 1e-12)
    if bad.size:
        raise RunFormatError(path, int(lines[bad[0]]), "qx,qy,qz,qw", "zero quaternion (no rotation defined)")
    # body -> origin ENU  ==>  body -> local ENU = (local <- origin) ⊗ (origin <- body);
    # the product keeps the file's norm, so the unit-norm check still sees it.
    q = quat_multiply(quat_conjugate(quat_local_enu_to_origin_enu(lat, lon, o)), q_origin)
    return build_run(
        path, vals[:, 0], lat, lon, alt, q, line_of_row=lambda i: int(lines[i]),
        field_names={"t_s": "timestamp", "lat_deg": "tx,ty,tz", "lon_deg": "tx,ty,tz", "alt_m": "tz",
                     "q_body_to_enu_wxyz": "qx,qy,qz,qw"},
    )


def write_tum(run: PoseRun, path: str | os.PathLike, origin: OriginLike | None = None) -> None:
    """Write ``run`` as TUM in ENU at ``origin`` (default: the first sample), atomically."""
    o = as_origin(origin) if origin is not None else as_origin((run.lat_deg[0], run.lon_deg[0], run.alt_m[0]))
    p = geodetic_to_enu(run.lat_deg, run.lon_deg, run.alt_m, o)
    q = quat_multiply(quat_local_enu_to_origin_enu(run.lat_deg, run.lon_deg, o), run.q_body_to_enu_wxyz)
    from posefix.io._text import render_rows

    body = render_rows([run.t_s, " ", p[:, 0], " ", p[:, 1], " ", p[:, 2], " ", q[:, 1], " ", q[:, 2], " ",
                        q[:, 3], " ", q[:, 0], "\n"])
    with atomic_write(path, "wb") as fh:
        fh.write(f"# posefix TUM export; frame: ENU at lat={o.lat_deg!r} lon={o.lon_deg!r} alt={o.alt_m!r}\n".encode())
        fh.write(b"# timestamp tx ty tz qx qy qz qw\n")
        fh.write(body)
