"""KITTI raw OXTS folders: ``oxts/timestamps.txt`` and ``oxts/data/NNNNNNNNNN.txt``.

Each data file holds one line of 30 values; posefix uses the first six: lat, lon (deg),
alt (m), roll, pitch, yaw (rad). The OXTS body frame is x forward, y left, z up, and
yaw is measured from east, counter-clockwise, so body -> ENU is ``Rz(yaw) Ry(pitch)
Rx(roll)``. Velocities and accelerations are kept as extra columns (vf, vl, vu, af, al,
au, wf, wl, wu). Timestamps (``YYYY-MM-DD HH:MM:SS.fffffffff``, UTC) become Unix seconds.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from posefix.core.run import PoseRun
from posefix.io._build import build_run
from posefix.io._quat import matrix_to_quat, quat_to_matrix, rpy_to_matrix
from posefix.io.atomic import atomic_write
from posefix.io.errors import RunFormatError

__all__ = ["read_kitti_oxts", "write_kitti_oxts", "find_oxts_dir", "OXTS_FIELDS"]

OXTS_FIELDS = (
    "lat", "lon", "alt", "roll", "pitch", "yaw", "vn", "ve", "vf", "vl", "vu", "ax", "ay", "az",
    "af", "al", "au", "wx", "wy", "wz", "wf", "wl", "wu", "pos_accuracy", "vel_accuracy",
    "navstat", "numsats", "posmode", "velmode", "orimode",
)
KEPT_EXTRA = ("vf", "vl", "vu", "af", "al", "au", "wf", "wl", "wu")


def find_oxts_dir(path: Path) -> Path | None:
    """The ``oxts`` folder for a drive folder or the oxts folder itself, else None."""
    for cand in (path, path / "oxts"):
        if (cand / "timestamps.txt").is_file() and (cand / "data").is_dir():
            return cand
    return None


def _parse_timestamp(path: Path, lineno: int, text: str) -> np.datetime64:
    s = text.strip().replace(" ", "T")
    try:
        return np.datetime64(s, "ns")
    except ValueError:
        raise RunFormatError(path, lineno, "timestamp", f"not a time YYYY-MM-DD HH:MM:SS.f: {text.strip()!r}") from None


def read_kitti_oxts(path: str | os.PathLike) -> PoseRun:
    """Read a KITTI raw drive's OXTS packets into a ``PoseRun``."""
    path = Path(path)
    oxts = find_oxts_dir(path)
    if oxts is None:
        raise RunFormatError(path, None, None, "not a KITTI oxts folder (needs timestamps.txt and data/)")
    ts_path = oxts / "timestamps.txt"
    stamps = []
    for lineno, raw in enumerate(ts_path.read_text(encoding="utf-8").splitlines(), start=1):
        if raw.strip():
            stamps.append(_parse_timestamp(ts_path, lineno, raw))
    files = sorted((oxts / "data").glob("*.txt"))
    if not stamps or not files:
        raise RunFormatError(oxts, None, None, "the run is empty (no OXTS packets)")
    if len(files) != len(stamps):
        raise RunFormatError(ts_path, None, "timestamp", f"{len(stamps)} timestamps but {len(files)} data files")
    vals = np.empty((len(files), len(OXTS_FIELDS)))
    for i, f in enumerate(files):
        parts = f.read_text(encoding="utf-8").split()
        if len(parts) != len(OXTS_FIELDS):
            raise RunFormatError(f, 1, None, f"expected {len(OXTS_FIELDS)} values, found {len(parts)}")
        for k, (name, p) in enumerate(zip(OXTS_FIELDS, parts)):
            try:
                vals[i, k] = float(p)
            except ValueError:
                raise RunFormatError(f, 1, name, f"not a number: {p!r}") from None
            if vals[i, k] != vals[i, k]:
                raise RunFormatError(f, 1, name, "value is NaN")
    t_ns = np.array(stamps, dtype="datetime64[ns]").astype(np.int64)
    t_s = (t_ns // 1_000_000_000).astype(float) + (t_ns % 1_000_000_000) * 1e-9
    r = rpy_to_matrix(vals[:, 3], vals[:, 4], vals[:, 5])
    q = matrix_to_quat(r)
    extra = {name: vals[:, OXTS_FIELDS.index(name)].copy() for name in KEPT_EXTRA}
    idx = {name: k for k, name in enumerate(OXTS_FIELDS)}
    # An invariant break in a packet's values names that packet's data file; one in the
    # times names the line of timestamps.txt. ``build_run`` asks for the row's line.
    failing_row: list[int] = []

    def line_of_row(i: int) -> int:
        failing_row.append(i)
        return i + 1

    try:
        return build_run(
            ts_path, t_s, vals[:, idx["lat"]], vals[:, idx["lon"]], vals[:, idx["alt"]], q,
            line_of_row=line_of_row, extra=extra,
            field_names={"t_s": "timestamp", "q_body_to_enu_wxyz": "roll,pitch,yaw"},
        )
    except RunFormatError as exc:
        if exc.field in ("lat", "lon", "alt", "roll,pitch,yaw") and failing_row:
            raise RunFormatError(files[failing_row[-1]], 1, exc.field, exc.message) from None
        raise


def write_kitti_oxts(run: PoseRun, folder: str | os.PathLike) -> None:
    """Write ``run`` as a KITTI ``oxts`` folder (unknown OXTS values written as 0).

    Each file is written atomically; used to build fixtures and to hand runs to KITTI tools.
    """
    folder = Path(folder)
    data = folder / "data"
    data.mkdir(parents=True, exist_ok=True)
    r = quat_to_matrix(run.q_body_to_enu_wxyz)
    # inverse of Rz(yaw) Ry(pitch) Rx(roll)
    pitch = -np.arcsin(np.clip(r[:, 2, 0], -1.0, 1.0))
    roll = np.arctan2(r[:, 2, 1], r[:, 2, 2])
    yaw = np.arctan2(r[:, 1, 0], r[:, 0, 0])
    t_ns = np.round(run.t_s * 1e9).astype(np.int64).astype("datetime64[ns]")
    stamps = [s.replace("T", " ") for s in np.datetime_as_string(t_ns, unit="ns").tolist()]
    with atomic_write(folder / "timestamps.txt", "w") as fh:
        fh.write("\n".join(stamps) + "\n")
    for i in range(run.n):
        vals = np.zeros(len(OXTS_FIELDS))
        vals[:6] = (run.lat_deg[i], run.lon_deg[i], run.alt_m[i], roll[i], pitch[i], yaw[i])
        for name in KEPT_EXTRA:
            if name in run.extra:
                vals[OXTS_FIELDS.index(name)] = float(run.extra[name][i])
        with atomic_write(data / f"{i:010d}.txt", "w") as fh:
            fh.write(" ".join(repr(float(v)) for v in vals) + "\n")
