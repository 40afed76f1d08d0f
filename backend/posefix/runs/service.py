"""Run rules: import (checked before anything is stored), keyframes GeoJSON, export, status."""

from __future__ import annotations

import datetime as dt
import gzip
import hashlib
import json
import threading
import uuid
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import orjson
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.core.rules import EditRules, adjustable_mask, locked_mask
from posefix.core.run import PoseRun, RunValidationError
from posefix.db import on_rollback
from posefix.errors import Conflict, Forbidden, NotFound, Unprocessable
from posefix.io import RunFormatError, read_run, write_run
from posefix.core.geodesy import horizontal_distance_m
from posefix.engine import Edits, prepare
from posefix.runs import solutions, storage, uploads
from posefix.runs.engine_config import default_rules, engine_config
from posefix.runs import repository as repo
from posefix.runs.models import Revision, Run, RunImage, RunStatus
from posefix.runs.schemas import RunPublic
from posefix.users.models import Role
from posefix.users.service import Principal
from posefix.filestore import file_store

EXPORT_FORMATS = {
    "csv": ("text/csv", ".csv"), "parquet": ("application/vnd.apache.parquet", ".parquet"),
    "arrow": ("application/vnd.apache.arrow.file", ".arrow"), "gpx": ("application/gpx+xml", ".gpx"),
    "geojson": ("application/geo+json", ".geojson"),
}
# Unix times after 2000-01-01 are read as wall-clock times for the recorded time span.
EPOCH_2000_S = 946684800.0


def store(settings: Settings) -> storage.FileStore:
    return file_store(settings)


def run_public(run: Run, n_images: int = 0, failed: dict[str, Any] | None = None) -> RunPublic:
    data = {c: getattr(run, c) for c in RunPublic.model_fields if hasattr(run, c) and c != "bbox"}
    return RunPublic(**data, bbox=[run.min_lon, run.min_lat, run.max_lon, run.max_lat], n_images=n_images,
                     failed_edit=failed)


# -- import --------------------------------------------------------------------------------

def _read(path: Path, name: str, fmt: str | None, origin: tuple[float, float, float] | None) -> PoseRun:
    try:
        run = read_run(path, fmt=fmt, origin=origin)
        run.validated()
    except RunFormatError as exc:
        line = exc.line
        raise Unprocessable(
            f"{name}{f':{line}' if line else ''}: field {exc.field or '(whole file)'}: {exc.message}",
            code="invalid_run", extra={"file": name, "line": line, "field": exc.field},
        ) from None
    except RunValidationError as exc:
        raise Unprocessable(
            f"{name}: field {exc.field}{f' at sample {exc.row}' if exc.row is not None else ''}: {exc.message}",
            code="invalid_run", extra={"file": name, "line": None, "field": exc.field},
        ) from None
    return run


def _recorded(t_s: float) -> dt.datetime | None:
    return dt.datetime.fromtimestamp(t_s, dt.UTC) if t_s >= EPOCH_2000_S and t_s < 4102444800.0 else None


def _match_images(run: PoseRun, index: np.ndarray, staged: list[uploads.StagedImage]) -> list[tuple[int | None, int | None]]:
    """(sample row, keyframe) for each image: by the run's image column, else nearest keyframe to its EXIF GPS."""
    by_name: dict[str, int] = {}
    if run.images is not None:
        for row, names in enumerate(run.images):
            for nm in names.split(";") if names else ():
                by_name.setdefault(Path(nm.strip()).name, row)
    kf_lon, kf_lat = run.lon_deg[index], run.lat_deg[index]
    coslat = np.cos(np.radians(kf_lat.mean()))
    out: list[tuple[int | None, int | None]] = []
    for img in staged:
        row = by_name.get(img.filename)
        if row is not None:
            k = int(np.clip(np.searchsorted(index, row, side="right") - 1, 0, len(index) - 1))
            out.append((row, k))
        elif img.exif_lon is not None and img.exif_lat is not None:
            d2 = ((kf_lon - img.exif_lon) * coslat) ** 2 + (kf_lat - img.exif_lat) ** 2
            k = int(np.argmin(d2))
            out.append((int(index[k]), k))
        else:
            out.append((None, None))
    return out


def import_run(
    session: Session, settings: Settings, principal: Principal, *, name: str, file_name: str, file: BinaryIO,
    images: list[tuple[str, BinaryIO]], fmt: str | None = None, origin: tuple[float, float, float] | None = None,
) -> Run:
    """Check everything in a staging folder, then store rows and files in one go."""
    fs = store(settings)
    with fs.staging() as staging:
        path, original = uploads.stage_run_file(file, file_name, staging, settings)
        run = _read(path, original, fmt, origin)
        staged = uploads.stage_images(images, staging, settings)
        rules = default_rules(settings)
        cfg = engine_config(settings, rules)
        problem = prepare(run, cfg)
        index = problem.keyframe_index
        matches = _match_images(run, index, staged)

        row = Run(
            name=name, status=RunStatus.imported, verified=False, adjusted=False, owner_id=principal.user_id,
            source_format=(fmt or ("folder" if path.is_dir() else path.suffix.lstrip(".").lower())),
            original_filename=original, n_samples=run.n, n_keyframes=len(index),
            t_start_s=float(run.t_s[0]), t_end_s=float(run.t_s[-1]),
            recorded_start=_recorded(float(run.t_s[0])), recorded_end=_recorded(float(run.t_s[-1])),
            min_lon=float(run.lon_deg.min()), min_lat=float(run.lat_deg.min()),
            max_lon=float(run.lon_deg.max()), max_lat=float(run.lat_deg.max()),
            length_m=float(problem.along_m[-1]), orientation_derived=bool(run.orientation_derived),
            revision=0, head_revision=0, rules=rules,
        )
        repo.add(session, row)
        run_dir = f"runs/{row.id}"
        on_rollback(session, lambda: fs.remove_tree(run_dir))
        on_rollback(session, lambda: fs.remove_tree(f"images/{row.id}"))

        heading = storage.heading_deg(run.q_body_to_enu_wxyz[index])
        columns = zip(index.tolist(), run.t_s[index].tolist(), run.lon_deg[index].tolist(), run.lat_deg[index].tolist(),
                      run.alt_m[index].tolist(), heading.tolist())  # whole columns to Python at once
        repo.insert_keyframes(session, [
            {"run_id": row.id, "k": k, "sample_index": r, "t_s": t, "lon": lon, "lat": lat, "alt": alt, "heading_deg": h}
            for k, (r, t, lon, lat, alt, h) in enumerate(columns)
        ])
        tag = uuid.uuid4().hex[:8]
        if path.is_file():
            fs.put_file(path, f"{run_dir}/original{path.suffix.lower()}")
        samples_rel = storage.write_samples(fs, f"{run_dir}/r0-{tag}.parquet", run)
        kf_rel = storage.write_keyframes(fs, f"{run_dir}/r0-{tag}.npz", storage.keyframe_arrays(run, index, settings.line_max_points))
        repo.add(session, Revision(
            run_id=row.id, number=0, kind="import", created_by=principal.user_id, edit_set=Edits().to_json(),
            solver=None, drift=None, samples_file=samples_rel, keyframes_file=kf_rel, max_correction_m=0.0,
        ))
        for img, (sample, k) in zip(staged, matches):
            im = RunImage(
                run_id=row.id, filename=img.filename, content_type=img.content_type, size_bytes=img.size_bytes,
                width=img.width, height=img.height, sample_index=sample, keyframe=k, exif_lon=img.exif_lon,
                exif_lat=img.exif_lat, exif_time=img.exif_time, storage_path="",
            )
            repo.add(session, im)
            im.storage_path = fs.put_file(img.path, f"images/{row.id}/{im.id}{Path(img.filename).suffix.lower()}")
        repo.record(session, row, principal.user_id, "imported", to_status=RunStatus.imported, revision=0,
                    detail={"file": original, "samples": run.n, "keyframes": len(index), "images": len(staged)})
        session.flush()
    solutions.PROBLEMS.put(row.id, rules, problem)
    return row


# -- reading -----------------------------------------------------------------------------

def ready_revision(session: Session, run: Run, number: int | None) -> Revision:
    n = run.revision if number is None else number
    rev = repo.revision(session, run.id, n)
    if rev is None:
        if 0 <= n <= run.head_revision:
            raise Conflict(f"revision {n} of run {run.id} is still being computed", code="revision_pending",
                           extra={"revision": run.revision, "head_revision": run.head_revision})
        raise NotFound(f"run {run.id} has no revision {n}", code="revision_not_found")
    return rev


@dataclass(frozen=True)
class RenderedGeoJson:
    """A keyframes GeoJSON rendered once: the bytes, gzip-compressed bytes and a strong ETag
    (a hash of the bytes; the gzip representation's tag has a ``-gz`` suffix)."""

    body: bytes
    gzip_body: bytes
    etag: str

    @property
    def gzip_etag(self) -> str:
        return self.etag[:-1] + '-gz"'

    def matches(self, if_none_match: str | None) -> bool:
        """``If-None-Match`` names this content (either representation; weak comparison)."""
        if not if_none_match:
            return False
        tags = {t.strip().removeprefix("W/") for t in if_none_match.split(",")}
        return "*" in tags or self.etag in tags or self.gzip_etag in tags


class _GeoJsonCache:
    """Rendered keyframes GeoJSON per (file store, run, revision, head, rules): revisions never
    change. One thread renders a key; others asking for it meanwhile wait for that render
    (50 operators opening a run at once would otherwise render it 50 times)."""

    def __init__(self, size: int = 16):
        self.size = size
        self._data: OrderedDict[tuple[Any, ...], RenderedGeoJson] = OrderedDict()
        self._lock = threading.Lock()
        self._rendering: dict[tuple[Any, ...], threading.Lock] = {}

    def get(self, key: tuple[Any, ...]) -> RenderedGeoJson | None:
        with self._lock:
            v = self._data.get(key)
            if v is not None:
                self._data.move_to_end(key)
            return v

    def clear(self) -> None:
        with self._lock:
            self._data.clear()

    def put(self, key: tuple[Any, ...], value: RenderedGeoJson) -> None:
        with self._lock:
            self._data[key] = value
            self._data.move_to_end(key)
            while len(self._data) > self.size:
                self._data.popitem(last=False)

    def get_or_render(self, key: tuple[Any, ...], render: Callable[[], bytes]) -> RenderedGeoJson:
        cached = self.get(key)
        if cached is not None:
            return cached
        with self._lock:
            gate = self._rendering.setdefault(key, threading.Lock())
        try:
            with gate:
                cached = self.get(key)
                if cached is not None:
                    return cached
                body = render()
                rendered = RenderedGeoJson(
                    body, gzip.compress(body, compresslevel=6, mtime=0),
                    '"' + hashlib.blake2b(body, digest_size=12).hexdigest() + '"',
                )
                self.put(key, rendered)
                return rendered
        finally:
            with self._lock:
                if self._rendering.get(key) is gate:
                    del self._rendering[key]


GEOJSON_CACHE = _GeoJsonCache()


def _rounded(a: np.ndarray, nd: int) -> list[float]:
    return np.round(np.asarray(a, dtype=float), nd).tolist()


def keyframes_geojson(session: Session, settings: Settings, run: Run, revision: int | None) -> RenderedGeoJson:
    """The keyframes of a revision (default: the latest ready) as GeoJSON, rendered once per
    (revision, head revision, rules): the same for every user allowed to see the run."""
    number = run.revision if revision is None else revision
    key = (run.id, number, settings.files_dir.as_posix(), json.dumps(run.rules, sort_keys=True), run.head_revision)
    cached = GEOJSON_CACHE.get(key)
    if cached is not None:
        return cached
    rev = ready_revision(session, run, revision)
    return GEOJSON_CACHE.get_or_render(key, lambda: _render_geojson(session, settings, run, rev))


def _render_geojson(session: Session, settings: Settings, run: Run, rev: Revision) -> bytes:
    kfs = repo.keyframe_columns(session, run.id)
    arrays = storage.read_keyframes(store(settings), rev.keyframes_file)
    k = len(kfs)
    rules = EditRules.from_json(run.rules)
    edit_set = rev.edit_set or Edits().to_json()
    edited_idx = [int(m[0]) for m in edit_set.get("moves", [])]
    deleted = set(int(d) for d in edit_set.get("deleted", []))
    flagged = {int(f["index"]): f for f in edit_set.get("flags", [])}
    adjustable = adjustable_mask(k, rules).tolist()
    locked = locked_mask(k, edited_idx, rules).tolist()
    edited = set(edited_idx)
    images_by_k: dict[int, list[int]] = {}
    for im in repo.images(session, run.id):
        if im.keyframe is not None:
            images_by_k.setdefault(im.keyframe, []).append(im.id)
    rep_lon = np.array([r[3] for r in kfs])
    rep_lat = np.array([r[4] for r in kfs])
    corr_m = _rounded(horizontal_distance_m(rep_lon, rep_lat, arrays.lon_deg, arrays.lat_deg), 3)
    lon, lat = _rounded(arrays.lon_deg, 7), _rounded(arrays.lat_deg, 7)
    rlon, rlat = _rounded(rep_lon, 7), _rounded(rep_lat, 7)
    heading = _rounded(arrays.heading_deg, 2)
    sigma = [None] * len(kfs) if arrays.sigma_m is None else _rounded(arrays.sigma_m, 3)
    features = []
    for i, (kk, sample, t, _lon, _lat, _alt) in enumerate(kfs):
        imgs = images_by_k.get(kk, [])
        features.append({
            "type": "Feature", "id": kk,
            "geometry": {"type": "Point", "coordinates": [lon[i], lat[i]]},
            "properties": {
                "index": kk, "sample": sample, "t": t, "heading_deg": heading[i],
                "adjustable": adjustable[i] and kk not in deleted, "locked": locked[i],
                "edited": kk in edited, "deleted": kk in deleted, "flagged": kk in flagged,
                "flag_reason": flagged[kk]["reason"] if kk in flagged else None,
                "has_images": bool(imgs), "images": imgs, "reported": [rlon[i], rlat[i]],
                "correction_m": corr_m[i], "sigma_m": sigma[i],
            },
        })
    body = {
        "type": "FeatureCollection", "run_id": run.id, "revision": rev.number, "head_revision": run.head_revision,
        "rules": run.rules, "drift": rev.drift, "solver": rev.solver,
        "line": {"type": "LineString", "coordinates": np.stack(
            [np.round(arrays.line_lon_deg, 7), np.round(arrays.line_lat_deg, 7)], axis=1).tolist()},
        "features": features,
    }
    return orjson.dumps(body)


def export_stream(session: Session, settings: Settings, run: Run, revision: int | None, fmt: str) -> tuple[Iterator[bytes], str, str]:
    """A generator of the exported file's bytes (written to staging, streamed, then removed)."""
    if fmt not in EXPORT_FORMATS:
        raise Unprocessable(f"format must be one of {', '.join(EXPORT_FORMATS)}", code="bad_format")
    rev = ready_revision(session, run, revision)
    fs = store(settings)
    pose_run = storage.read_samples(fs, rev.samples_file, orientation_derived=run.orientation_derived, source=run.name)
    media, ext = EXPORT_FORMATS[fmt]
    cm = fs.staging()
    staging = cm.__enter__()
    try:
        out = staging / f"export{ext}"
        write_run(pose_run, out, fmt=fmt)
    except BaseException:
        cm.__exit__(None, None, None)
        raise

    def gen() -> Iterator[bytes]:
        try:
            with open(out, "rb") as fh:
                while chunk := fh.read(1 << 16):
                    yield chunk
        finally:
            cm.__exit__(None, None, None)

    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in run.name)[:80] or f"run-{run.id}"
    return gen(), media, f"{safe}-r{rev.number}{ext}"


# -- changes -----------------------------------------------------------------------------

def soft_delete(session: Session, principal: Principal, run: Run) -> None:
    if principal.role != Role.admin and run.owner_id != principal.user_id:
        raise Forbidden("only an admin or the run's owner may delete it", code="not_owner")
    repo.record(session, run, principal.user_id, "deleted", to_status=RunStatus.deleted)
    run.status = RunStatus.deleted
    run.deleted_at = dt.datetime.now(dt.UTC)
    solutions.PROBLEMS.forget(run.id)


def review(session: Session, principal: Principal, run: Run, decision: str, comment: str | None) -> Run:
    """A reviewer accepts a run (verified) or sends it back to review; nobody reviews a
    revision that holds their own edits (the task review's ``own_work`` rule)."""
    if repo.authored_up_to(session, run.id, principal.user_id, run.head_revision):
        raise Forbidden("you edited this run, so someone else reviews it", code="own_work")
    if run.head_revision != run.revision:
        raise Conflict("a revision is still being computed; review it when it is ready", code="revision_pending",
                       extra={"revision": run.revision, "head_revision": run.head_revision})
    if decision == "accept":
        if run.status == RunStatus.accepted:
            raise Conflict("the run is already accepted", code="invalid_transition")
        repo.record(session, run, principal.user_id, "accepted", to_status=RunStatus.accepted, revision=run.revision, comment=comment)
        run.status = RunStatus.accepted
        run.verified = True
    else:
        if run.status not in (RunStatus.corrected, RunStatus.accepted):
            raise Conflict(f"only a corrected or accepted run can be rejected (it is {run.status})", code="invalid_transition")
        repo.record(session, run, principal.user_id, "rejected", to_status=RunStatus.in_review, revision=run.revision, comment=comment)
        run.status = RunStatus.in_review
        run.verified = False
    return run
