"""The file store: full-rate samples (Parquet), per-revision keyframe arrays (.npz), images.

Layout in the file store (``<data_dir>/files``, or ``POSEFIX_FILES_URL``)::

    runs/<run_id>/original<ext>            the uploaded file, as received
    runs/<run_id>/r<N>-<tag>.parquet       revision N, every sample (interchange columns)
    runs/<run_id>/r<N>-<tag>.npz           revision N, keyframe positions and the display line
    runs/<run_id>/r<N>-<tag>.solution.npz  revision N, the solved keyframe state (a cache: warm
                                           start of previews in every API process; optional)
    images/<run_id>/<image_id><ext>        image originals; <image_id>.thumb.jpg thumbnails
    staging/<uuid>/                        uploads being checked (removed whatever happens)

The store is local disk or object storage (``posefix.filestore``); on disk every file is
written to a temporary name and renamed into place, so a reader never sees half a file.
A revision's files exist for good only once its row is
committed: files of a revision written by a job that died (or lost the race to another run
of the same job) are removed by ``sweep_revision_files``.
"""

from __future__ import annotations

import dataclasses
import io
import json
from dataclasses import dataclass
from functools import cache
from pathlib import PurePosixPath
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from posefix.core.run import PoseRun
from posefix.filestore import FileStore
from posefix.io.columnar import run_to_arrow, write_parquet_table

BASE_COLUMNS = ("t", "lat", "lon", "alt", "qw", "qx", "qy", "qz")
GNSS_COLUMNS = ("gnss_lat", "gnss_lon", "gnss_alt")
IMAGE_COLUMN = "image"


# -- full-rate samples -----------------------------------------------------------------

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
    with store.writing(rel) as tmp:
        write_parquet_table(run_to_arrow(run), tmp)  # the columnar run file: exact values, units in the schema
    return rel


def read_samples(store: FileStore, rel: str, *, orientation_derived: bool, source: str) -> PoseRun:
    source_file = store.path(rel) if store.is_local else pa.BufferReader(store.read_bytes(rel))
    return table_to_run(pq.read_table(source_file), orientation_derived=orientation_derived, source=source)


# -- per-revision keyframe arrays --------------------------------------------------------

@dataclass(frozen=True)
class KeyframeArrays:
    """One revision's keyframes: positions (k,) degrees/metres, heading (deg clockwise from
    north), the decimated full-rate line for display, and the horizontal 1-sigma of each
    keyframe's correction the run's held-out edits predict (None: fewer than three edits)."""

    lon_deg: np.ndarray
    lat_deg: np.ndarray
    alt_m: np.ndarray
    heading_deg: np.ndarray
    line_lon_deg: np.ndarray
    line_lat_deg: np.ndarray
    sigma_m: np.ndarray | None = None


def write_keyframes(store: FileStore, rel: str, kf: KeyframeArrays) -> str:
    buffer = io.BytesIO()
    extra = {} if kf.sigma_m is None else {"sigma_m": kf.sigma_m}
    np.savez_compressed(
        buffer, lon_deg=kf.lon_deg, lat_deg=kf.lat_deg, alt_m=kf.alt_m, heading_deg=kf.heading_deg,
        line_lon_deg=kf.line_lon_deg, line_lat_deg=kf.line_lat_deg, **extra,
    )
    return store.put_bytes(buffer.getvalue(), rel)


def read_keyframes(store: FileStore, rel: str) -> KeyframeArrays:
    with np.load(io.BytesIO(store.read_bytes(rel)), allow_pickle=False) as z:
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


# -- solved keyframe state of a revision (a cache shared by every process) ----------------

SOLUTION_FORMAT = 2  # 2: the engine's classes moved (engine.results, core.drift.base)
# The engine's result types a solution file may hold (nothing else is ever instantiated).
@cache
def _solution_classes() -> dict[str, type]:
    """The dataclasses a solution file may hold, by the name written for them (an allow-list:
    a file names classes, and only these are ever built from one)."""
    from posefix.core.drift.base import DriftEstimate
    from posefix.core.keyframes import KeyframeSet
    from posefix.core.rules import Refusal
    from posefix.core.solver import Linearisation, SolverResult
    from posefix.core.terms import Terms
    from posefix.engine.calibrate import Calibration, ProcessFit
    from posefix.engine.results import Solution

    classes = (Solution, KeyframeSet, SolverResult, DriftEstimate, Terms, Refusal, Linearisation, Calibration, ProcessFit)
    return {f"{c.__module__}:{c.__qualname__}": c for c in classes}


def solution_rel(keyframes_rel: str) -> str:
    """The solution file beside a revision's keyframes file (``r<N>-<tag>.npz``)."""
    stem = keyframes_rel[:-4] if keyframes_rel.endswith(".npz") else keyframes_rel
    return f"{stem}.solution.npz"


def _encode(value: Any, arrays: dict[str, np.ndarray]) -> Any:
    """A JSON tree of ``value`` with its arrays moved to ``arrays`` (stored without pickle)."""
    if isinstance(value, np.ndarray):
        for key, stored in arrays.items():  # one copy of an array referenced twice
            if stored is value:
                return {"__array__": key}
        key = f"a{len(arrays)}"
        arrays[key] = value
        return {"__array__": key}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        name = f"{type(value).__module__}:{type(value).__qualname__}"
        if name not in _solution_classes():
            raise TypeError(f"{name} is not stored in solution files")
        return {"__dataclass__": name,
                "fields": {f.name: _encode(getattr(value, f.name), arrays) for f in dataclasses.fields(value)}}
    if isinstance(value, tuple):
        return {"__tuple__": [_encode(v, arrays) for v in value]}
    if isinstance(value, list):
        return [_encode(v, arrays) for v in value]
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise TypeError("only text keys are stored in solution files")
        out = {}
        for k, v in value.items():
            try:
                out[k] = _encode(v, arrays)
            except TypeError:  # a diagnostic of a kind files do not hold: left out
                continue
        return {"__dict__": out}
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"cannot store a {type(value).__name__} in a solution file")


def _decode(node: Any, arrays: Any) -> Any:
    if isinstance(node, list):
        return [_decode(v, arrays) for v in node]
    if not isinstance(node, dict):
        return node
    if "__array__" in node:
        return arrays[node["__array__"]]
    if "__tuple__" in node:
        return tuple(_decode(v, arrays) for v in node["__tuple__"])
    if "__dict__" in node:
        return {k: _decode(v, arrays) for k, v in node["__dict__"].items()}
    name = node["__dataclass__"]
    cls = _solution_classes().get(name)
    if cls is None:
        raise TypeError(f"{name} is not stored in solution files")
    # TypeError when the engine's classes changed since the file was written: a cache miss
    return cls(**{k: _decode(v, arrays) for k, v in node["fields"].items()})


def write_solution(store: FileStore, rel: str, solution: Any, fingerprint: str) -> str:
    """Store an engine ``Solution`` (arrays in an .npz, the rest as JSON; no pickle), atomically."""
    arrays: dict[str, np.ndarray] = {}
    tree = _encode(solution, arrays)
    meta = json.dumps({"format": SOLUTION_FORMAT, "fingerprint": fingerprint, "solution": tree}).encode()
    buffer = io.BytesIO()
    np.savez(buffer, __meta__=np.frombuffer(meta, dtype=np.uint8), **arrays)
    return store.put_bytes(buffer.getvalue(), rel)


def read_solution(store: FileStore, rel: str, fingerprint: str) -> Any | None:
    """The ``Solution`` stored at ``rel``; None when there is none, or it was written by
    another engine configuration (``fingerprint``) or version of the engine's classes."""
    try:
        with np.load(io.BytesIO(store.read_bytes(rel)), allow_pickle=False) as z:
            meta = json.loads(z["__meta__"].tobytes())
            if meta.get("format") != SOLUTION_FORMAT or meta.get("fingerprint") != fingerprint:
                return None
            arrays = {k: z[k] for k in z.files if k != "__meta__"}
        return _decode(meta["solution"], arrays)
    except (OSError, ValueError, KeyError, TypeError, AttributeError, ImportError):
        return None


# -- files of revisions that were never committed ----------------------------------------

def revision_files(store: FileStore, run_id: int, number: int) -> list[str]:
    """Names of every file of revision ``number`` of a run, temporaries of interrupted writes included."""
    prefixes = (f"r{number}-", f".r{number}-")
    return [name for name in store.names(f"runs/{run_id}") if name.startswith(prefixes)]


def sweep_revision_files(store: FileStore, run_id: int, number: int, keep: set[str]) -> list[str]:
    """Remove the files of revision ``number`` other than ``keep`` (file-store paths of its
    committed row, whose solution files are kept too); returns the names removed.

    Call it only once the revision's row is committed (or can never be: its job is dead):
    then every other file of that revision is left over from a run of the job that died or
    lost the race, and no later run of the job will use it.
    """
    kept = {PurePosixPath(rel).name for rel in keep} | {PurePosixPath(solution_rel(rel)).name for rel in keep if rel.endswith(".npz")}
    removed = []
    for name in revision_files(store, run_id, number):
        if name not in kept:
            store.remove(f"runs/{run_id}/{name}")
            removed.append(name)
    return removed
