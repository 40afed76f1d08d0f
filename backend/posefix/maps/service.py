"""Floor plans, models, walk tracking and suggestions: the rules of the maps domain.

Uploads are staged in a private folder of the file store and checked there (names, sizes,
zip bombs, JSON and image content) before a row exists; the checked files move to
``floorplans/<id>/`` only when the row is flushed, and are removed again if the request's
transaction rolls back, so a refused or failed upload leaves nothing behind. The model is
built by the worker (job ``floorplan.build``). Services never commit.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import threading
import time
import uuid
from collections import OrderedDict
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.db import on_commit, on_rollback
from posefix.errors import BadRequest, Conflict, NotFound, PayloadTooLarge, Unprocessable
from posefix.filestore import file_store
from posefix.jobs import repository as jobs
from posefix.mapmatch import api as mapmatch
from posefix.maps import repository as repo
from posefix.maps.models import FloorPlan, FloorPlanSource, FloorPlanStatus
from posefix.runs import uploads
from posefix.users.service import Principal

BUILD_JOB = "floorplan.build"
FLOOR_FILES = ("floor_info.json", "geojson_map.json", "floor_image.png")
MODEL_FILE = "model.npz"
GEOJSON_FILE = "walkable.geojson"
# Upload limits (bytes). The shared floor is 0.3 MB; a walk file 0.1-1.5 MB.
MAX_FLOOR_UPLOAD_BYTES = 64 * 1024 * 1024
MAX_FLOOR_MEMBER_BYTES = 32 * 1024 * 1024
MAX_WALK_BYTES = 64 * 1024 * 1024
# A floor larger than this (m, either side) is refused: the 0.1 m raster would not fit in memory.
MAX_FLOOR_SIDE_M = 2000.0


# ---- file store -----------------------------------------------------------------------

def floor_dir(settings: Settings, fp: FloorPlan) -> Path:
    """A local folder with the floor plan's files (the store's own on local disk, else a cached copy)."""
    return file_store(settings).local_copy(fp.folder)


def staging_dir(settings: Settings) -> Path:
    root = file_store(settings).staging_root
    root.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix="floor-", dir=root))


# ---- checking uploads -----------------------------------------------------------------

def _floor_error(upload_name: str, exc: Exception) -> Unprocessable:
    """A FloorFormatError re-worded with the uploaded file's name instead of the staging path."""
    file = Path(getattr(exc, "file", "") or "").name or upload_name
    field = getattr(exc, "field", None)
    text = str(exc)
    if field and f"field {field}: " in text:
        text = text.split(f"field {field}: ", 1)[1]
    where = f"{upload_name}: {file}" if file != upload_name else upload_name
    return Unprocessable(f"{where}: field {field}: {text}" if field else f"{where}: {text}", code="invalid_floor",
                         extra={"file": file, "field": field})


def _extract_competition_zip(zpath: Path, name: str, dest: Path, settings: Settings) -> None:
    """The three floor files out of a zip (anywhere in it, once each); other members are ignored."""
    zf = uploads.open_zip(zpath, name)
    with zf:
        members = uploads.check_zip(zf, name, settings, max_total=MAX_FLOOR_UPLOAD_BYTES * 4, max_files=10_000)
        found: dict[str, Any] = {}
        for m in members:
            base = uploads.safe_member_name(m.filename, name)
            if base in FLOOR_FILES and "__MACOSX" not in m.filename:
                if base in found:
                    raise BadRequest(f"{name}: {base} appears twice ({found[base].filename}, {m.filename})",
                                     code="duplicate_member", extra={"file": name, "member": m.filename})
                found[base] = m
        missing = [f for f in FLOOR_FILES if f not in found]
        if missing:
            raise Unprocessable(f"{name}: missing {', '.join(missing)} (a competition floor zip holds {', '.join(FLOOR_FILES)})",
                                code="invalid_floor", extra={"file": name, "member": missing[0]})
        for base, m in found.items():
            if m.file_size > MAX_FLOOR_MEMBER_BYTES:
                raise PayloadTooLarge(f"{name}: {base} is larger than {MAX_FLOOR_MEMBER_BYTES} bytes",
                                      code="file_too_large", extra={"file": name, "member": m.filename})
            uploads.extract_member(zf, m, dest / base, name)


def _check_competition(dest: Path, name: str) -> dict[str, Any]:
    """Parse the floor (walkable raster + geo-reference) to refuse bad content now, not in the job."""
    uploads.check_image(dest / "floor_image.png", "floor_image.png")
    try:
        info = json.loads((dest / "floor_info.json").read_text())
        w, h = float(info["map_info"]["width"]), float(info["map_info"]["height"])
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError) as exc:
        raise Unprocessable(f"{name}: floor_info.json: field map_info.width/height: unreadable ({exc})",
                            code="invalid_floor", extra={"file": "floor_info.json", "field": "map_info"}) from None
    if not (0 < w <= MAX_FLOOR_SIDE_M and 0 < h <= MAX_FLOOR_SIDE_M):
        raise Unprocessable(f"{name}: floor_info.json: field map_info: {w} x {h} m is outside 0..{MAX_FLOOR_SIDE_M:.0f} m",
                            code="invalid_floor", extra={"file": "floor_info.json", "field": "map_info"})
    try:
        raster = mapmatch.load_ilc_floor(dest)
    except mapmatch.FloorFormatError as exc:
        raise _floor_error(name, exc) from None
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise Unprocessable(f"{name}: geojson_map.json: field features: unusable geometry ({exc})",
                            code="invalid_floor", extra={"file": "geojson_map.json", "field": "features"}) from None
    if not raster.walkable.any():
        raise Unprocessable(f"{name}: geojson_map.json: field features: no walkable area", code="invalid_floor",
                            extra={"file": "geojson_map.json", "field": "features"})
    g = raster.georef
    return {"width_m": w, "height_m": h, "georef": None if g is None else [float(v) for v in g.as_array()], "has_image": True}


def parse_walkable_geojson(path: Path, name: str) -> tuple[float, float, list, list]:
    """GeoJSON of polygons in floor metres -> (width_m, height_m, walkable, blocked).

    Every Polygon/MultiPolygon feature is walkable unless ``properties.walkable`` is false
    (then it blocks, e.g. a shop or a pillar). Coordinates must be ≥ 0 (the floor frame's
    origin is its south-west corner)."""
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise Unprocessable(f"{name}: line {getattr(exc, 'lineno', 0)}: not JSON ({exc})", code="invalid_floor",
                            extra={"file": name, "field": None}) from None
    feats = doc.get("features") if isinstance(doc, dict) else None
    if not isinstance(feats, list) or not feats:
        raise Unprocessable(f"{name}: field features: expected a FeatureCollection with polygon features",
                            code="invalid_floor", extra={"file": name, "field": "features"})
    walk, block = [], []
    hi = np.zeros(2)
    for i, f in enumerate(feats):
        field = f"features[{i}].geometry"
        geom = (f or {}).get("geometry") if isinstance(f, dict) else None
        if not isinstance(geom, dict) or geom.get("type") not in ("Polygon", "MultiPolygon"):
            raise Unprocessable(f"{name}: field {field}: expected a Polygon or MultiPolygon", code="invalid_floor",
                                extra={"file": name, "field": field})
        polys = [geom.get("coordinates")] if geom["type"] == "Polygon" else geom.get("coordinates")
        try:
            rings = [[np.asarray(r, dtype=float)[:, :2] for r in poly] for poly in polys]
        except (TypeError, ValueError, IndexError) as exc:
            raise Unprocessable(f"{name}: field {field}.coordinates: not rings of [x, y] metres ({exc})",
                                code="invalid_floor", extra={"file": name, "field": field}) from None
        for poly in rings:
            for r in poly:
                if r.ndim != 2 or r.shape[0] < 3 or not np.all(np.isfinite(r)):
                    raise Unprocessable(f"{name}: field {field}.coordinates: a ring needs 3 or more finite [x, y] points",
                                        code="invalid_floor", extra={"file": name, "field": field})
                if r.min() < 0 or r.max() > MAX_FLOOR_SIDE_M:
                    raise Unprocessable(
                        f"{name}: field {field}.coordinates: metres in 0..{MAX_FLOOR_SIDE_M:.0f} expected "
                        f"(got {r.min():.1f}..{r.max():.1f}; lon/lat is not accepted here)",
                        code="invalid_floor", extra={"file": name, "field": field})
                hi = np.maximum(hi, r.max(axis=0))
        walkable = ((f.get("properties") or {}).get("walkable", True)) is not False
        (walk if walkable else block).extend(rings)
    if not walk:
        raise Unprocessable(f"{name}: field features: no walkable polygon (all have walkable: false)",
                            code="invalid_floor", extra={"file": name, "field": "features"})
    return float(hi[0]), float(hi[1]), walk, block


def create_floorplan(
    session: Session, settings: Settings, principal: Principal, *, name: str, filename: str | None, fh: BinaryIO,
    cell_m: float, wake: Any = None, build_now: bool = False,
) -> FloorPlan:
    """Check an upload, store it, and queue its model build (or build it here: ``build_now``)."""
    fname = uploads.safe_name(filename, "file")
    ext = Path(fname).suffix.lower()
    if ext not in (".zip", ".geojson", ".json"):
        raise Unprocessable(f"{fname}: expected a .zip of a competition floor or a .geojson of walkable polygons",
                            code="invalid_floor", extra={"file": fname, "field": "file"})
    stage = staging_dir(settings)
    try:
        raw = stage / f"upload{ext}"
        uploads.copy_limited(fh, raw, MAX_FLOOR_UPLOAD_BYTES, fname)
        files = stage / "files"
        files.mkdir()
        if ext == ".zip":
            _extract_competition_zip(raw, fname, files, settings)
            meta = _check_competition(files, fname)
            source = FloorPlanSource.competition
        else:
            w, h, walk, _block = parse_walkable_geojson(raw, fname)
            shutil.move(str(raw), files / GEOJSON_FILE)
            meta = {"width_m": w, "height_m": h, "georef": None, "has_image": False}
            source = FloorPlanSource.geojson
            # A graph needs cells: refuse a floor too small for one.
            if min(w, h) < cell_m:
                raise Unprocessable(f"{fname}: field features: the floor ({w:.1f} x {h:.1f} m) is smaller than one {cell_m} m cell",
                                    code="invalid_floor", extra={"file": fname, "field": "features"})
        fp = FloorPlan(
            name=name, source=source, status=FloorPlanStatus.queued, cell_m=cell_m, folder=f"tmp/{stage.name}",
            created_by_id=principal.user_id, extra={"upload": fname}, **meta,
        )
        repo.add(session, fp)
        fp.folder = f"floorplans/{fp.id}-{uuid.uuid4().hex[:8]}"
        store = file_store(settings)
        folder = fp.folder
        on_rollback(session, lambda: store.remove_tree(folder))
        store.put_tree(files, folder)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    if build_now:
        out = build_model(settings, fp, lambda _f, _m=None: None)
        fp.status, fp.n_vertices, fp.model_bytes, fp.build_s = FloorPlanStatus.ready, out["n_vertices"], out["model_bytes"], out["build_s"]
        session.flush()
        return fp
    job = jobs.enqueue(session, BUILD_JOB, {"floorplan_id": fp.id}, created_by=principal.user_id,
                       max_attempts=settings.job_max_attempts)
    fp.job_id = job.id
    if wake is not None:
        on_commit(session, wake)
    session.flush()
    return fp


def get_floorplan(session: Session, floorplan_id: int) -> FloorPlan:
    fp = repo.get(session, floorplan_id)
    if fp is None:
        raise NotFound(f"floor plan {floorplan_id} not found", code="floorplan_not_found")
    return fp


def delete_floorplan(session: Session, settings: Settings, fp: FloorPlan) -> None:
    folder, store = fp.folder, file_store(settings)
    fid = fp.id
    repo.delete(session, fp)

    def remove() -> None:
        store.remove_tree(folder)
        MODELS.forget(fid)
        from posefix.maps.sessions import SESSIONS

        SESSIONS.drop_floorplan(fid)

    on_commit(session, remove)


# ---- models ---------------------------------------------------------------------------

def build_model(settings: Settings, fp: FloorPlan, progress: Any) -> dict[str, Any]:
    """Build the floor plan's model on a local copy of its files and store ``model.npz``."""
    folder = floor_dir(settings, fp)
    out = build_model_files(folder, fp.source, fp.cell_m, progress)
    file_store(settings).put_file(folder / MODEL_FILE, f"{fp.folder}/{MODEL_FILE}")
    return out


def build_model_files(folder: Path, source: str, cell_m: float, progress: Any) -> dict[str, Any]:
    """Build and write ``model.npz`` in ``folder``; returns vertices, size and build time."""
    t0 = time.perf_counter()
    progress(0.1, "reading the floor plan")
    if source == FloorPlanSource.competition:
        model = mapmatch.build_model(folder, cell_m=cell_m)
    else:
        w, h, walk, block = parse_walkable_geojson(folder / GEOJSON_FILE, GEOJSON_FILE)
        progress(0.4, "building the graph")
        model = mapmatch.build_polygon_model(w, h, walk, block, cell_m=cell_m)
    if model.graph.n_vertices == 0:
        raise ValueError("no walkable cell survived (floor smaller than the minimum reachable area?)")
    progress(0.8, "writing the model")
    tmp = folder / f".{MODEL_FILE}.{uuid.uuid4().hex}.tmp"
    size = mapmatch.save_model(model, tmp)
    tmp.replace(folder / MODEL_FILE)
    return {"n_vertices": int(model.graph.n_vertices), "model_bytes": int(size), "build_s": round(time.perf_counter() - t0, 3)}


class ModelCache:
    """Loaded models by floor plan (a handful; a model of the shared floor is ~5 MB in memory)."""

    def __init__(self, size: int = 4):
        self.size = size
        self._items: OrderedDict[tuple[int, str], mapmatch.Model] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, settings: Settings, fp: FloorPlan) -> mapmatch.Model:
        if fp.status != FloorPlanStatus.ready:
            raise Conflict(f"floor plan {fp.id} has no model yet (status {fp.status})", code="model_not_ready",
                           extra={"status": fp.status, "job_id": fp.job_id})
        key = (fp.id, fp.folder)
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        model = mapmatch.load_model(floor_dir(settings, fp) / MODEL_FILE)
        with self._lock:
            self._items[key] = model
            while len(self._items) > self.size:
                self._items.popitem(last=False)
        return model

    def forget(self, floorplan_id: int) -> None:
        with self._lock:
            for k in [k for k in self._items if k[0] == floorplan_id]:
                del self._items[k]


MODELS = ModelCache()


def model_file(settings: Settings, fp: FloorPlan) -> Path:
    if fp.status != FloorPlanStatus.ready:
        raise Conflict(f"floor plan {fp.id} has no model yet (status {fp.status})", code="model_not_ready",
                       extra={"status": fp.status, "job_id": fp.job_id})
    path = floor_dir(settings, fp) / MODEL_FILE
    if not path.is_file():
        raise NotFound(f"floor plan {fp.id}: the model file is missing; upload the floor again", code="model_missing")
    return path


def image_file(settings: Settings, fp: FloorPlan) -> Path:
    path = floor_dir(settings, fp) / "floor_image.png"
    if not fp.has_image or not path.is_file():
        raise NotFound(f"floor plan {fp.id} has no floor image", code="image_not_found")
    return path


# ---- walks ----------------------------------------------------------------------------

def parse_start(value: str | None) -> tuple[str, tuple[float, float] | None]:
    """``first_waypoint`` (default), ``unknown``, or ``x,y`` in floor metres."""
    v = (value or "first_waypoint").strip()
    if v in ("first_waypoint", "unknown"):
        return v, None
    parts = v.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        xy = (float(parts[0]), float(parts[1]))
        if not all(np.isfinite(xy)):
            raise ValueError
    except ValueError:
        raise BadRequest(f"start: expected first_waypoint, unknown or 'x,y' in metres, got {v[:40]!r}", code="bad_start",
                         extra={"field": "start"}) from None
    return "xy", xy


def track_walk_upload(settings: Settings, fp: FloorPlan, fh: BinaryIO, filename: str | None, start: str | None,
                      fingerprints_fh: BinaryIO | None = None, fingerprints_name: str | None = None) -> dict[str, Any]:
    """Track an uploaded walk file: matched and dead-reckoning tracks, ellipses, waypoint errors;
    with ``fingerprints_fh`` (a fingerprint .npz, the floor's WiFi survey) its scans too."""
    fname = uploads.safe_name(filename, "file")
    mode, xy = parse_start(start)
    model = MODELS.get(settings, fp)
    stage = staging_dir(settings)
    fpm, fp_name = None, None
    try:
        path = stage / "walk.txt"
        uploads.copy_limited(fh, path, MAX_WALK_BYTES, fname)
        try:
            walk = mapmatch.read_walk(path)
        except mapmatch.WalkFormatError as exc:
            msg = str(exc).split(f"field {exc.field}: ", 1)[-1]
            raise Unprocessable(f"{fname}:{exc.line}: field {exc.field}: {msg}", code="invalid_walk",
                                extra={"file": fname, "line": exc.line, "field": exc.field}) from None
        if fingerprints_fh is not None:
            fp_name = uploads.safe_name(fingerprints_name, "fingerprints")
            fpath = stage / "fingerprints.npz"
            uploads.copy_limited(fingerprints_fh, fpath, MAX_WALK_BYTES, fp_name)
            try:
                fpm = mapmatch.load_fingerprints(fpath)
            except ValueError as exc:  # "{path}:0: field F: message"
                field, _, msg = str(exc).partition("field ")[2].partition(": ")
                raise Unprocessable(f"{fp_name}:0: field {field}: {msg}", code="invalid_fingerprints",
                                    extra={"file": fp_name, "field": field}) from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    if mode == "first_waypoint":
        if walk.waypoints.shape[0] == 0:
            raise Unprocessable(f"{fname}: field TYPE_WAYPOINT: no waypoint to start from; give start=x,y or start=unknown",
                                code="invalid_walk", extra={"file": fname, "field": "TYPE_WAYPOINT"})
        xy = (float(walk.waypoints[0, 1]), float(walk.waypoints[0, 2]))
    t0 = time.perf_counter()
    res = mapmatch.track_walk(model, walk, start_xy_m=xy, fingerprints=fpm)
    track_s = time.perf_counter() - t0
    out = walk_geojson(fp, model, walk, res, start_mode=mode, track_s=track_s, filename=fname)
    out["walk"]["wifi"] = wifi_use(model, walk, fpm, fp_name)
    return out


def wifi_use(model: mapmatch.Model, walk: mapmatch.Walk, fpm, name: str | None) -> dict[str, Any]:
    """What the walk's WiFi contributed: ``fingerprints`` (the file's name, None without one),
    ``fixes`` (scans placed by the survey), ``used``, ``note`` (why not, when the survey could not
    calibrate f3), ``walk_corr`` (its walk-long error correlation ρ: a walk's WiFi counts at
    most 1/ρ fixes) and ``robust`` (f3's heavy-tailed form)."""
    if fpm is None:
        return {"fingerprints": None, "fixes": 0, "used": False, "note": "no fingerprint file given", "walk_corr": None,
                "robust": None}
    fixes = len(fpm.predict_walk(walk, model.graph.p_xy_m))
    note = fpm.f3_note if not fpm.f3_calibrated else ("" if fixes else "no scan of this walk matched the survey")
    return {"fingerprints": name, "fixes": fixes, "used": bool(fixes), "note": note, "walk_corr": _r(fpm.walk_corr),
            "robust": bool(fpm.robust)}


def _r(v: float, nd: int = 3) -> float:
    return round(float(v), nd)


def walk_geojson(fp: FloorPlan, model: mapmatch.Model, walk: mapmatch.Walk, res: mapmatch.TrackResult, *,
                 start_mode: str, track_s: float, filename: str) -> dict[str, Any]:
    geo = model.graph.georef
    ll = geo.to_lonlat(res.p_xy_m) if geo is not None else None
    steps = []
    for i in range(res.t_ms.size):
        row = {
            "i": i, "t_ms": int(res.t_ms[i]), "x_m": _r(res.p_xy_m[i, 0]), "y_m": _r(res.p_xy_m[i, 1]),
            "dr_x_m": _r(res.dr_xy_m[i, 0]), "dr_y_m": _r(res.dr_xy_m[i, 1]),
            "sigma_major_m": _r(res.sigma_major_m[i]), "sigma_minor_m": _r(res.sigma_minor_m[i]),
            "angle_deg": _r(res.angle_deg[i], 1),
            "converged": bool(res.modes[i].converged), "n_modes": int(res.modes[i].n),
            "mode_spread_m": _r(res.modes[i].spread_m),
        }
        if ll is not None:
            row["lon"], row["lat"] = round(float(ll[i, 0]), 8), round(float(ll[i, 1]), 8)
        steps.append(row)
    features: list[dict[str, Any]] = [
        {"type": "Feature", "id": "matched", "properties": {"kind": "matched"},
         "geometry": {"type": "LineString", "coordinates": [[_r(x), _r(y)] for x, y in res.p_xy_m]}},
        {"type": "Feature", "id": "dead_reckoning", "properties": {"kind": "dead_reckoning"},
         "geometry": {"type": "LineString", "coordinates": [[_r(x), _r(y)] for x, y in res.dr_xy_m]}},
    ]
    errors: dict[str, Any] = {"n": 0, "mean_m": None, "median_m": None, "p95_m": None, "max_m": None,
                              "skip_first": start_mode == "first_waypoint", "waypoints": []}
    wp = walk.waypoints
    if wp.shape[0]:
        ev = mapmatch.evaluate_track(wp, res.t_ms, res.p_xy_m)
        ev_dr = mapmatch.evaluate_track(wp, res.t_ms, res.dr_xy_m)
        scored = ev.err_wp_m[1:] if errors["skip_first"] else ev.err_wp_m
        for j in range(wp.shape[0]):
            given = errors["skip_first"] and j == 0
            errors["waypoints"].append({"t_ms": int(wp[j, 0]), "x_m": _r(wp[j, 1]), "y_m": _r(wp[j, 2]),
                                        "error_m": _r(ev.err_wp_m[j]), "dr_error_m": _r(ev_dr.err_wp_m[j]), "given_start": given})
            features.append({"type": "Feature", "id": f"waypoint-{j}",
                             "properties": {"kind": "waypoint", "t_ms": int(wp[j, 0]), "error_m": _r(ev.err_wp_m[j]),
                                            "given_start": given},
                             "geometry": {"type": "Point", "coordinates": [_r(wp[j, 1]), _r(wp[j, 2])]}})
        if scored.size:
            dr_scored = ev_dr.err_wp_m[1:] if errors["skip_first"] else ev_dr.err_wp_m
            errors.update(n=int(scored.size), mean_m=_r(scored.mean()), median_m=_r(np.median(scored)),
                          p95_m=_r(np.percentile(scored, 95)), max_m=_r(scored.max()), dr_mean_m=_r(dr_scored.mean()))
    return {
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "posefix:floor-metres", "floorplan_id": fp.id,
                                                "note": "x east, y north, metres from the floor's south-west corner"}},
        "features": features,
        "steps": steps,
        "errors": errors,
        "walk": {"file": filename, "n_steps": int(res.t_ms.size - 1), "start": start_mode,
                 "track_ms": _r(track_s * 1000, 1), "ms_per_step": _r(res.time_per_step_s * 1000, 3),
                 "converged_share": _r(float(np.mean(res.converged))), "converged_at_end": bool(res.converged[-1])},
    }
