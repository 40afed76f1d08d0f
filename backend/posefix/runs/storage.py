"""The file store: full-rate samples (Parquet), per-revision keyframe arrays (.npz), images.

Layout under ``settings.files_dir``::

    runs/<run_id>/original<ext>            the uploaded file, as received
    runs/<run_id>/r<N>-<tag>.parquet       revision N, every sample (interchange columns)
    runs/<run_id>/r<N>-<tag>.npz           revision N, keyframe positions and the display line
    images/<run_id>/<image_id><ext>        image originals; <image_id>.thumb.jpg thumbnails
    staging/<uuid>/                        uploads being checked (removed whatever happens)

Every file is written to a temporary name in the same directory and renamed into place,
so a reader never sees half a file.
"""

from __future__ import annotations

import os
import shutil
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from posefix.core.run import PoseRun

BASE_COLUMNS = ("t", "lat", "lon", "alt", "qw", "qx", "qy", "qz")
GNSS_COLUMNS = ("gnss_lat", "gnss_lon", "gnss_alt")
IMAGE_COLUMN = "image"


class FileStore:
    def __init__(self, root: Path):
        self.root = Path(root)

    def path(self, rel: str) -> Path:
        p = (self.root / rel).resolve()
        if self.root.resolve() not in p.parents:
            raise ValueError(f"path {rel!r} escapes the file store")
        return p

    @contextmanager
    def staging(self) -> Iterator[Path]:
        """A private directory removed on exit, whatever happens."""
        d = self.root / "staging" / uuid.uuid4().hex
        d.mkdir(parents=True, exist_ok=False)
        try:
            yield d
        finally:
            shutil.rmtree(d, ignore_errors=True)

    def put_file(self, src: Path, rel: str) -> str:
        dst = self.path(rel)
        dst.parent.mkdir(parents=True, exist_ok=True)
        os.replace(src, dst) if src.stat().st_dev == _dev(dst.parent) else shutil.copyfile(src, dst)
        return rel

    def put_bytes(self, data: bytes, rel: str) -> str:
        dst = self.path(rel)
        dst.parent.mkdir(parents=True, exist_ok=True)
        tmp = dst.with_name(f".{dst.name}.{uuid.uuid4().hex}.tmp")
        tmp.write_bytes(data)
        os.replace(tmp, dst)
        return rel

    def remove(self, rel: str) -> None:
        try:
            self.path(rel).unlink()
        except FileNotFoundError:
            pass

    def remove_tree(self, rel: str) -> None:
        shutil.rmtree(self.path(rel), ignore_errors=True)


def _dev(p: Path) -> int:
    return p.stat().st_dev


# -- full-rate samples -----------------------------------------------------------------

def run_to_table(run: PoseRun) -> pa.Table:
    q = run.q_body_to_enu_wxyz
    arrays: dict[str, pa.Array] = {
        "t": pa.array(run.t_s, pa.float64()), "lat": pa.array(run.lat_deg, pa.float64()),
        "lon": pa.array(run.lon_deg, pa.float64()), "alt": pa.array(run.alt_m, pa.float64()),
        "qw": pa.array(q[:, 0]), "qx": pa.array(q[:, 1]), "qy": pa.array(q[:, 2]), "qz": pa.array(q[:, 3]),
    }
    if run.has_gnss:
        for name, a in zip(GNSS_COLUMNS, (run.gnss_lat_deg, run.gnss_lon_deg, run.gnss_alt_m)):
            arrays[name] = pa.array(np.asarray(a, float))
    if run.images is not None:
        arrays[IMAGE_COLUMN] = pa.array(run.images, pa.string())
    for name, a in run.extra.items():
        if name in arrays:
            continue
        arr = np.asarray(a)
        arrays[name] = pa.array(arr) if arr.dtype.kind in "fiub" else pa.array([str(v) for v in arr.tolist()], pa.string())
    return pa.table(arrays)


def table_to_run(table: pa.Table, *, orientation_derived: bool, source: str) -> PoseRun:
    cols = {name: table.column(name) for name in table.column_names}

    def f(name: str) -> np.ndarray:
        return cols[name].to_numpy().astype(float, copy=False)

    q = np.stack([f("qw"), f("qx"), f("qy"), f("qz")], axis=1)
    gnss = [f(n) for n in GNSS_COLUMNS] if all(n in cols for n in GNSS_COLUMNS) else [None, None, None]
    images = cols[IMAGE_COLUMN].to_pylist() if IMAGE_COLUMN in cols else None
    reserved = set(BASE_COLUMNS) | set(GNSS_COLUMNS) | {IMAGE_COLUMN}
    extra = {}
    for name, col in cols.items():
        if name in reserved:
            continue
        extra[name] = col.to_numpy(zero_copy_only=False)
    return PoseRun(
        t_s=f("t"), lat_deg=f("lat"), lon_deg=f("lon"), alt_m=f("alt"), q_body_to_enu_wxyz=q,
        gnss_lat_deg=gnss[0], gnss_lon_deg=gnss[1], gnss_alt_m=gnss[2],
        images=[x or "" for x in images] if images is not None else None, extra=extra,
        orientation_derived=orientation_derived, source=source,
    )


def write_samples(store: FileStore, rel: str, run: PoseRun) -> str:
    dst = store.path(rel)
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(f".{dst.name}.{uuid.uuid4().hex}.tmp")
    table = run_to_table(run)
    # Dictionary encoding only for text (image names repeat): float samples are all distinct,
    # so trying a dictionary first tripled the write time (360,001 samples: 210 -> 70 ms) and
    # doubled the read time; zstd level 1 compresses them as well as the default level here.
    text = [f.name for f in table.schema if pa.types.is_string(f.type)]
    pq.write_table(table, tmp, compression="zstd", compression_level=1, use_dictionary=text or False)
    os.replace(tmp, dst)
    return rel


def read_samples(store: FileStore, rel: str, *, orientation_derived: bool, source: str) -> PoseRun:
    return table_to_run(pq.read_table(store.path(rel)), orientation_derived=orientation_derived, source=source)


# -- per-revision keyframe arrays --------------------------------------------------------

@dataclass(frozen=True)
class KeyframeArrays:
    """One revision's keyframes: positions (k,) degrees/metres, heading (deg clockwise from
    north), and the decimated full-rate line for display."""

    lon_deg: np.ndarray
    lat_deg: np.ndarray
    alt_m: np.ndarray
    heading_deg: np.ndarray
    line_lon_deg: np.ndarray
    line_lat_deg: np.ndarray


def write_keyframes(store: FileStore, rel: str, kf: KeyframeArrays) -> str:
    dst = store.path(rel)
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(f".{dst.name}.{uuid.uuid4().hex}.tmp.npz")
    np.savez_compressed(
        tmp, lon_deg=kf.lon_deg, lat_deg=kf.lat_deg, alt_m=kf.alt_m, heading_deg=kf.heading_deg,
        line_lon_deg=kf.line_lon_deg, line_lat_deg=kf.line_lat_deg,
    )
    os.replace(tmp, dst)
    return rel


def read_keyframes(store: FileStore, rel: str) -> KeyframeArrays:
    with np.load(store.path(rel)) as z:
        return KeyframeArrays(**{k: z[k] for k in z.files})


def heading_deg(q_body_to_enu_wxyz: np.ndarray) -> np.ndarray:
    """(n,) heading of the body x axis, degrees clockwise from north in [0, 360)."""
    w, x, y, z = (q_body_to_enu_wxyz[:, i] for i in range(4))
    east = 1.0 - 2.0 * (y * y + z * z)
    north = 2.0 * (x * y + w * z)
    return np.degrees(np.arctan2(east, north)) % 360.0


def decimate_line(lon_deg: np.ndarray, lat_deg: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    n = len(lon_deg)
    step = max(1, int(np.ceil(n / max(max_points - 1, 1))))
    idx = np.arange(0, n, step)
    if idx[-1] != n - 1:
        idx = np.append(idx, n - 1)
    return lon_deg[idx], lat_deg[idx]


def keyframe_arrays(run: PoseRun, index: np.ndarray, max_line_points: int) -> KeyframeArrays:
    line_lon, line_lat = decimate_line(run.lon_deg, run.lat_deg, max_line_points)
    return KeyframeArrays(
        lon_deg=run.lon_deg[index], lat_deg=run.lat_deg[index], alt_m=run.alt_m[index],
        heading_deg=heading_deg(run.q_body_to_enu_wxyz[index]), line_lon_deg=line_lon, line_lat_deg=line_lat,
    )
