"""Routes of map matching (under ``/api/v1``): floor plans and their models, walk tracking,
live tracking sessions, and suggestions for pose runs. Thin: the rules are in ``service``."""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Depends, Query, Request, Response, status
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool

from posefix.deps import AnyUser, EditorUser, SessionDep, SettingsDep, form_text, require
from posefix.errors import AppError, BadRequest, LengthRequired, PayloadTooLarge, UnsupportedMediaType, responses
from posefix.maps import repository as repo
from posefix.maps import service, sessions, suggestions
from posefix.maps.schemas import (
    FloorPlanList, FloorPlanPublic, SessionCreate, SessionCreated, StepsIn, StepsOut, SuggestionRequest,
    SuggestionsJob, SuggestionsOut, WalkTrack,
)
from posefix.runs.access import get_visible_run
from posefix.users.models import Role
from posefix.users.service import Principal

router = APIRouter(tags=["maps"])

AdminUploader = Annotated[Principal, Depends(require(Role.admin, allow_multipart=True))]
AnyUploader = Annotated[Principal, Depends(require(*tuple(Role), allow_multipart=True))]

FLOOR_UPLOAD: dict[str, Any] = {
    "requestBody": {"required": True, "content": {"multipart/form-data": {"schema": {
        "type": "object", "required": ["file", "name"],
        "properties": {
            "file": {"type": "string", "format": "binary",
                     "description": "a .zip holding floor_info.json, geojson_map.json and floor_image.png (Indoor Location "
                                    "Competition 2.0 layout), or a .geojson of walkable polygons in floor metres "
                                    "(properties.walkable: false marks blocked areas)"},
            "name": {"type": "string", "minLength": 1, "maxLength": 200},
            "cell_m": {"type": "number", "minimum": 0.2, "maximum": 5.0, "default": 0.8, "description": "graph cell size, metres"},
        }}}}},
}
WALK_UPLOAD: dict[str, Any] = {
    "requestBody": {"required": True, "content": {"multipart/form-data": {"schema": {
        "type": "object", "required": ["file"],
        "properties": {
            "file": {"type": "string", "format": "binary", "description": "a walk in the competition's path-file format (.txt)"},
            "start": {"type": "string", "default": "first_waypoint",
                      "description": "first_waypoint (the walk's first TYPE_WAYPOINT as known start, excluded from the "
                                     "error), unknown (uniform over the floor), or 'x,y' in floor metres"},
            "fingerprints": {"type": "string", "format": "binary",
                             "description": "optional: the floor's WiFi site survey (.npz from `posefix mapmatch "
                                            "fingerprints`); the answer's walk.wifi says whether it was used and why not"},
        }}}}},
}


async def _form(request: Request, limit: int, what: str) -> Any:
    length = request.headers.get("content-length")
    if length is None:
        raise LengthRequired("uploads need a Content-Length header")
    if not length.isdigit():
        raise BadRequest("Content-Length is not a number", code="bad_request")
    if int(length) > limit + (1 << 20):
        raise PayloadTooLarge(f"{what}: upload of {length} bytes is larger than the limit of {limit} bytes",
                              code="payload_too_large", extra={"field": "file"})
    if not request.headers.get("content-type", "").startswith("multipart/form-data"):
        raise UnsupportedMediaType(f"upload {what} as multipart/form-data", code="multipart_required")
    try:
        return await request.form(max_files=2, max_fields=10)
    except AppError:
        raise
    except Exception as exc:
        raise BadRequest(f"malformed multipart body: {exc}", code="bad_form") from None


def _file(form: Any, key: str = "file") -> Any:
    f = form.get(key)
    if f is None or isinstance(f, str):
        raise BadRequest(f"form field {key!r} must be a file", code="file_required", extra={"field": key})
    return f


def _wake(request: Request) -> Any:
    worker = getattr(request.app.state, "worker", None)
    return worker.wake if worker is not None else None


@router.post("/floorplans", response_model=FloorPlanPublic, status_code=status.HTTP_202_ACCEPTED, openapi_extra=FLOOR_UPLOAD,
             responses=responses(400, 401, 403, 411, 413, 415, 422))
async def upload_floorplan(request: Request, principal: AdminUploader, session: SessionDep, settings: SettingsDep) -> FloorPlanPublic:
    """Upload a floor plan (admins). The files are checked now; the model is built by a job
    (``job_id``: follow it with ``GET /jobs/{id}`` or ``GET /events``)."""
    form = await _form(request, service.MAX_FLOOR_UPLOAD_BYTES, "a floor plan")
    name = (form_text(form, "name") or "").strip()
    if not name or len(name) > 200:
        raise BadRequest("form field 'name': give 1 to 200 characters", code="bad_form", extra={"field": "name"})
    raw_cell = form_text(form, "cell_m")
    try:
        cell_m = 0.8 if raw_cell in (None, "") else float(raw_cell)
        if not 0.2 <= cell_m <= 5.0:
            raise ValueError
    except ValueError:
        raise BadRequest(f"form field 'cell_m': a number of metres in 0.2..5 expected, got {raw_cell!r}", code="bad_form",
                         extra={"field": "cell_m"}) from None
    up = _file(form)
    # Checking the floor rasterises it (~0.2 s): off the event loop.
    fp = await run_in_threadpool(lambda: service.create_floorplan(
        session, settings, principal, name=name, filename=up.filename, fh=up.file, cell_m=cell_m, wake=_wake(request)))
    return FloorPlanPublic.model_validate(fp)


@router.get("/floorplans", response_model=FloorPlanList, responses=responses(401))
def list_floorplans(session: SessionDep, _user: AnyUser,
                    limit: Annotated[int, Query(ge=1, le=500)] = 100, offset: Annotated[int, Query(ge=0, le=10**9)] = 0) -> FloorPlanList:
    """Floor plans, newest first (every signed-in user may track on them)."""
    rows, total = repo.page(session, limit, offset)
    return FloorPlanList(items=[FloorPlanPublic.model_validate(r) for r in rows], total=total)


@router.get("/floorplans/{floorplan_id}", response_model=FloorPlanPublic, responses=responses(401, 404))
def get_floorplan(floorplan_id: int, session: SessionDep, _user: AnyUser) -> FloorPlanPublic:
    """One floor plan: status of its model, size of the download, extent and geo-reference."""
    return FloorPlanPublic.model_validate(service.get_floorplan(session, floorplan_id))


@router.delete("/floorplans/{floorplan_id}", status_code=status.HTTP_204_NO_CONTENT, responses=responses(401, 403, 404))
def delete_floorplan(floorplan_id: int, session: SessionDep, settings: SettingsDep, _admin: Annotated[Principal, Depends(require(Role.admin))]) -> Response:
    """Delete a floor plan, its files and model, and end its tracking sessions (admins)."""
    service.delete_floorplan(session, settings, service.get_floorplan(session, floorplan_id))
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.get(
    "/floorplans/{floorplan_id}/model", response_class=FileResponse,
    responses={200: {"content": {"application/octet-stream": {}},
                     "description": "The model for devices: a NumPy .npz (format in docs/mapmatch.md, 'Model file format'); "
                                    "Content-Length and X-Model-Bytes give its size"},
               **responses(401, 404, 409)},
)
def download_model(floorplan_id: int, session: SessionDep, settings: SettingsDep, _user: AnyUser) -> FileResponse:
    """Download the compact device model of a floor plan (409 until its job has built it)."""
    fp = service.get_floorplan(session, floorplan_id)
    path = service.model_file(settings, fp)
    return FileResponse(path, media_type="application/octet-stream", filename=f"floorplan-{fp.id}.npz",
                        headers={"X-Model-Bytes": str(path.stat().st_size), "Cache-Control": "private, no-cache"})


@router.get("/floorplans/{floorplan_id}/image", response_class=FileResponse,
            responses={200: {"content": {"image/png": {}}, "description": "floor_image.png; covers [0, width_m] x [0, height_m]"},
                       **responses(401, 404)})
def floor_image(floorplan_id: int, session: SessionDep, settings: SettingsDep, _user: AnyUser) -> FileResponse:
    """The floor image of a competition floor plan (its bottom-left corner is the floor origin)."""
    fp = service.get_floorplan(session, floorplan_id)
    return FileResponse(service.image_file(settings, fp), media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})


@router.post("/floorplans/{floorplan_id}/walks", response_model=WalkTrack, openapi_extra=WALK_UPLOAD,
             responses=responses(400, 401, 403, 404, 409, 411, 413, 415, 422))
async def track_walk(floorplan_id: int, request: Request, session: SessionDep, settings: SettingsDep, _user: AnyUploader) -> dict[str, Any]:
    """Track a walk file on the floor's model (inline: ~1 ms per step). Returns GeoJSON in floor
    metres: the matched and the dead-reckoning tracks, the waypoints with their error, and
    ``steps`` (position, dead reckoning and 1σ error ellipse per step, converged, modes) and
    ``errors`` (at the waypoints: the competition's straight-line convention between them).
    With a ``fingerprints`` file (the floor's WiFi survey) the walk's scans are used too, and
    ``walk.wifi`` says how many fixes, or why none (a survey too small to calibrate them)."""
    fp = service.get_floorplan(session, floorplan_id)
    await run_in_threadpool(service.MODELS.get, settings, fp)  # 409 before reading the upload when there is no model yet
    form = await _form(request, service.MAX_WALK_BYTES, "a walk")
    up = _file(form)
    start = form_text(form, "start")
    fpr = _file(form, "fingerprints") if form.get("fingerprints") is not None else None
    # CPU-bound (reading the file, ~1 ms per step): off the event loop.
    return await run_in_threadpool(service.track_walk_upload, settings, fp, up.file, up.filename, start,
                                   fpr.file if fpr else None, fpr.filename if fpr else None)


@router.post("/floorplans/{floorplan_id}/sessions", response_model=SessionCreated, status_code=status.HTTP_201_CREATED,
             responses=responses(401, 403, 404, 409, 415, 422, 429))
def create_session(floorplan_id: int, body: SessionCreate, principal: AnyUser, session: SessionDep, settings: SettingsDep) -> SessionCreated:
    """Start a live tracking session (state kept in this server process; see ``posefix.maps.sessions``)."""
    fp = service.get_floorplan(session, floorplan_id)
    model = service.MODELS.get(settings, fp)
    start = None if body.start_xy_m is None else (float(body.start_xy_m[0]), float(body.start_xy_m[1]))
    if start is not None and not (np.all(np.isfinite(start)) and 0 <= start[0] <= fp.width_m and 0 <= start[1] <= fp.height_m):
        raise BadRequest(f"start_xy_m {list(start)} is outside the floor (0..{fp.width_m} x 0..{fp.height_m} m)",
                         code="bad_start", extra={"field": "start_xy_m"})
    sess, pos = sessions.SESSIONS.create(principal.user_id, fp.id, model, start)
    return SessionCreated(session_id=sess.id, floorplan_id=fp.id, expires_in_s=sessions.TTL_S, position=pos)


def _own_session(session_id: str, principal: AnyUser) -> sessions.TrackingSession:
    # A dependency, so it answers 404 before the body is validated: a 422 would tell another
    # user's session exists.
    return sessions.SESSIONS.get(session_id, principal.user_id)


OwnSession = Annotated[sessions.TrackingSession, Depends(_own_session)]


@router.post("/sessions/{session_id}/steps", response_model=StepsOut, responses=responses(401, 403, 404, 409, 415, 422))
def add_steps(sess: OwnSession, body: StepsIn) -> StepsOut:
    """Feed steps (vectors, or heading + length) or raw sensor batches; one position with its
    1σ ellipse comes back per step, in order."""
    with sess.lock:
        if body.steps:
            t, vec = sessions.step_vectors(sess.model, body.steps)
        else:
            assert body.sensors is not None
            t, vec = sessions.steps_from_sensors(sess, body.sensors.acc, body.sensors.rotvec)
        positions = sessions.advance(sess, t, vec)
        n = sess.n_steps
    return StepsOut(session_id=sess.id, n_steps=n, positions=positions, expires_in_s=sessions.TTL_S)


@router.delete("/sessions/{session_id}", status_code=status.HTTP_204_NO_CONTENT, responses=responses(401, 403, 404))
def delete_session(session_id: str, principal: AnyUser) -> Response:
    """End a tracking session."""
    sessions.SESSIONS.delete(session_id, principal.user_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.post("/runs/{run_id}/suggestions", response_model=SuggestionsJob, status_code=status.HTTP_202_ACCEPTED,
             responses={**responses(401, 403, 404, 409, 415, 422), 200: {"model": SuggestionsOut, "description":
                        "(the job's result, at GET /jobs/{job_id}): per keyframe the suggested lon/lat, moved_m, off_road, sigma_m"}})
def run_suggestions(run_id: int, request: Request, principal: EditorUser, session: SessionDep, settings: SettingsDep,
                    body: SuggestionRequest | None = None) -> dict[str, Any]:
    """Queue map-matching suggestions for a run's keyframes against the OpenStreetMap road
    network, or its drivable-area grid (a job; its result is a ``SuggestionsOut``: per keyframe the matched lon/lat, how far
    it would move, whether it lies off the road, and the match's 1σ). Accepting one is a move
    of kind ``suggestion`` in ``POST /runs/{id}/edits``."""
    run = get_visible_run(session, principal, settings, run_id)
    req = body or SuggestionRequest()
    return suggestions.request_suggestions(session, settings, principal, run, req.revision, req.cell_m, wake=_wake(request),
                                           matcher=req.matcher)
