"""Routes: /runs (upload, search, metadata, soft delete, keyframes, export, history, review), /images."""

from __future__ import annotations

import datetime as dt
from typing import Annotated, Any

from fastapi import APIRouter, BackgroundTasks, Query, Request, Response
from fastapi.responses import StreamingResponse
from starlette.datastructures import UploadFile

import anyio

from posefix.filestore import file_response
from posefix.deps import AnyUser, OwnerUser, ReviewerUser, SessionDep, SettingsDep, UploaderUser, form_text, solver_limiter
from posefix.errors import AppError, BadRequest, LengthRequired, PayloadTooLarge, UnsupportedMediaType, responses
from posefix.runs import solutions
from posefix.runs import images as image_service
from posefix.runs import repository as repo
from posefix.runs import service
from posefix.runs.access import get_visible_run, visible_clause
from posefix.runs.models import RunStatus
from posefix.runs.warm import prewarm
from posefix.users.models import Role
from posefix.runs.schemas import (
    ImageList, ImagePublic, ReviewRequest, RunEventPublic, RunHistory, RunList, RunPublic, UploadFormats,
)
from posefix.runs.uploads import IMAGE_TYPES, RUN_EXTENSIONS

router = APIRouter(tags=["runs"])

UPLOAD_SCHEMA: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "required": ["file", "name"],
                    "properties": {
                        "file": {"type": "string", "format": "binary", "description": "the run: csv, parquet, arrow, gpx, geojson, tum, or a zipped KITTI/comma2k19 folder"},
                        "name": {"type": "string", "minLength": 1, "maxLength": 200},
                        "format": {"type": "string", "enum": ["csv", "parquet", "arrow", "gpx", "geojson", "tum", "kitti", "comma2k19"]},
                        "origin": {"type": "string", "description": "lat,lon,alt of a TUM run's local frame"},
                        "images": {"type": "array", "items": {"type": "string", "format": "binary"},
                                   "description": "a zip of images, or several image files"},
                    },
                }
            }
        },
    }
}


@router.post("/runs", response_model=RunPublic, status_code=201, openapi_extra=UPLOAD_SCHEMA,
             responses=responses(400, 401, 403, 411, 413, 415, 422))
async def upload_run(request: Request, principal: UploaderUser, session: SessionDep, settings: SettingsDep) -> RunPublic:
    """Upload a run (multipart ``file`` and ``name``; optional ``images``: a zip or several files)."""
    limit = settings.max_run_bytes + settings.max_images_bytes + (1 << 20)
    length = request.headers.get("content-length")
    if length is None:
        raise LengthRequired("uploads need a Content-Length header")
    if not length.isdigit():
        raise BadRequest("Content-Length is not a number", code="bad_request")
    if int(length) > limit:
        raise PayloadTooLarge(f"upload of {length} bytes is larger than the limit of {limit} bytes", code="payload_too_large")
    ctype = request.headers.get("content-type", "")
    if not ctype.startswith("multipart/form-data"):
        raise UnsupportedMediaType("upload a run as multipart/form-data", code="multipart_required")
    try:
        form = await request.form(max_files=settings.max_image_count + 1, max_fields=20)
    except AppError:
        raise
    except Exception as exc:
        raise BadRequest(f"malformed multipart body: {exc}", code="bad_form") from None
    try:
        name = (form_text(form, "name") or "").strip()
        file = form.get("file")
        if not isinstance(file, UploadFile):
            raise BadRequest("multipart field 'file' (the run) is missing", code="bad_form", extra={"field": "file"})
        if not name:
            raise BadRequest("multipart field 'name' is missing or empty", code="bad_form", extra={"field": "name"})
        if len(name) > 200:
            raise BadRequest("name is longer than 200 characters", code="bad_form", extra={"field": "name"})
        fmt = form_text(form, "format") or None
        origin = None
        origin_s = form_text(form, "origin")
        if origin_s:
            try:
                lat, lon, alt = (float(x) for x in origin_s.split(","))
                origin = (lat, lon, alt)
            except ValueError:
                raise BadRequest("origin must be 'lat,lon,alt'", code="bad_form", extra={"field": "origin"}) from None
        image_files = []
        for item in form.getlist("images"):
            if not isinstance(item, UploadFile):
                raise BadRequest("multipart field 'images' must hold files", code="bad_form", extra={"field": "images"})
            image_files.append((item.filename or "", item.file))

        run = await anyio.to_thread.run_sync(
            lambda: service.import_run(
                session, settings, principal, name=name, file_name=file.filename or "", file=file.file,
                images=image_files, fmt=fmt, origin=origin,
            )
        )
        n_images = len(image_files) and repo.image_counts(session, [run.id]).get(run.id, 0)
        return service.run_public(run, n_images)
    finally:
        await form.close()


@router.get("/upload-formats", response_model=UploadFormats, responses=responses(401))
def upload_formats(principal: AnyUser) -> UploadFormats:
    """The file extensions ``POST /runs`` accepts: the upload form offers exactly these."""
    return UploadFormats(run=sorted(RUN_EXTENSIONS), images=sorted(IMAGE_TYPES))


@router.get("/runs", response_model=RunList, responses=responses(400, 401))
def list_runs(
    principal: AnyUser, session: SessionDep, settings: SettingsDep,
    name: Annotated[str | None, Query(max_length=200, description="substring of the name")] = None,
    status: RunStatus | None = None,
    bbox: Annotated[str | None, Query(description="minlon,minlat,maxlon,maxlat")] = None,
    since: dt.datetime | None = None, until: dt.datetime | None = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50, offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
) -> RunList:
    """Search runs visible to the caller (deleted ones only with ``status=deleted``)."""
    box = None
    if bbox:
        try:
            box = tuple(float(v) for v in bbox.split(","))
        except ValueError:
            box = None
        if box is None or len(box) != 4 or not all(abs(v) <= 180 for v in box) or box[0] > box[2] or box[1] > box[3]:
            raise BadRequest("bbox must be minlon,minlat,maxlon,maxlat with min <= max", code="bad_bbox", extra={"field": "bbox"})
    since = since.replace(tzinfo=dt.UTC) if since is not None and since.tzinfo is None else since
    until = until.replace(tzinfo=dt.UTC) if until is not None and until.tzinfo is None else until
    rows, total = repo.search(
        session, visible_clause(principal, settings), name=name, status=status, bbox=box,  # type: ignore[arg-type]
        since=since, until=until, limit=limit, offset=offset,
    )
    counts = repo.image_counts(session, [r.id for r in rows])
    failed = _failed_edits(session, [r.id for r in rows])
    return RunList(items=[service.run_public(r, counts.get(r.id, 0), failed.get(r.id)) for r in rows],
                   total=total, limit=limit, offset=offset)


def _failed_edits(session: Any, run_ids: list[int]) -> dict[int, dict[str, Any]]:
    """Runs whose latest edit batch failed (answered by the edits domain, registered by the app factory)."""
    out: dict[int, dict[str, Any]] = {}
    for provider in FAILED_EDITS:
        out.update(provider(session, run_ids))
    return out


FAILED_EDITS: list[Any] = []


def register_failed_edits(provider: Any) -> None:
    if provider not in FAILED_EDITS:
        FAILED_EDITS.append(provider)


@router.get("/runs/{run_id}", response_model=RunPublic, responses=responses(401, 404))
def get_run(run_id: int, principal: AnyUser, session: SessionDep, settings: SettingsDep) -> RunPublic:
    run = get_visible_run(session, principal, settings, run_id)
    return service.run_public(run, repo.image_counts(session, [run.id]).get(run.id, 0), _failed_edits(session, [run.id]).get(run.id))


@router.delete("/runs/{run_id}", status_code=204, responses=responses(401, 403, 404))
def delete_run(run_id: int, principal: OwnerUser, session: SessionDep, settings: SettingsDep) -> Response:
    """Soft delete: the run leaves lists and its data stays for the audit trail."""
    run = get_visible_run(session, principal, settings, run_id)
    service.soft_delete(session, principal, run)
    return Response(status_code=204)


def accepts_gzip(accept_encoding: str | None) -> bool:
    """``Accept-Encoding`` allows gzip (named, or ``*``, with a q-value above 0)."""
    for part in (accept_encoding or "").lower().split(","):
        coding, *params = (p.strip() for p in part.split(";"))
        if coding not in ("gzip", "*"):
            continue
        q = 1.0
        for param in params:
            if param.startswith("q="):
                try:
                    q = float(param[2:])
                except ValueError:
                    q = 0.0
        return q > 0.0
    return False


@router.get("/runs/{run_id}/keyframes", responses={200: {"content": {"application/geo+json": {}}}, 304: {"description": "Not Modified (If-None-Match)"}, **responses(401, 404, 409)})
def get_keyframes(
    run_id: int, principal: AnyUser, session: SessionDep, settings: SettingsDep, request: Request,
    background: BackgroundTasks, revision: Annotated[int | None, Query(ge=0, le=10**9)] = None,
) -> Response:
    """Keyframes of a revision (default: the latest ready) as a GeoJSON FeatureCollection.

    Rendered once per revision; a strong ``ETag`` answers ``If-None-Match`` with 304 (what a
    browser sends when it reloads), and gzip is sent to clients that accept it.
    """
    run = get_visible_run(session, principal, settings, run_id)
    rendered = service.keyframes_geojson(session, settings, run, revision)
    if principal.role in (Role.admin, Role.reviewer, Role.operator) and run.head_revision == (revision if revision is not None else run.revision) \
            and solutions.PROBLEMS.solution(run.id, run.rules, run.head_revision) is None:
        # An editor is about to drag: solve (or load) this revision now, after the response is sent.
        async def presolve(app: Any = request.app, run_id: int = run.id, number: int = run.head_revision) -> None:
            await anyio.to_thread.run_sync(prewarm, app.state.db, settings, run_id, number, limiter=solver_limiter(app))

        background.add_task(presolve)
    # private: the run is access-checked; no-cache: revalidate each time (the ETag makes that cheap)
    headers = {"Cache-Control": "private, no-cache", "Vary": "Accept-Encoding"}
    gzipped = accepts_gzip(request.headers.get("accept-encoding"))
    headers["ETag"] = rendered.gzip_etag if gzipped else rendered.etag
    if rendered.matches(request.headers.get("if-none-match")):
        return Response(status_code=304, headers=headers, background=background)
    if gzipped:
        headers["Content-Encoding"] = "gzip"
        return Response(rendered.gzip_body, media_type="application/geo+json", headers=headers, background=background)
    return Response(rendered.body, media_type="application/geo+json", headers=headers, background=background)


@router.get("/runs/{run_id}/export", responses={200: {"content": {media: {} for media, _ext in service.EXPORT_FORMATS.values()}}, **responses(401, 404, 409, 422)})
def export_run(
    run_id: int, principal: AnyUser, session: SessionDep, settings: SettingsDep,
    format: Annotated[str, Query(pattern="^(csv|parquet|arrow|gpx|geojson)$")] = "csv",
    revision: Annotated[int | None, Query(ge=0, le=10**9)] = None,
) -> StreamingResponse:
    """The full-rate corrected run of a revision, streamed: CSV, Parquet or Arrow IPC (the
    interchange columns, units in the schema), GPX or GeoJSON."""
    run = get_visible_run(session, principal, settings, run_id)
    stream, media, filename = service.export_stream(session, settings, run, revision, format)
    return StreamingResponse(stream, media_type=media, headers={"Content-Disposition": f'attachment; filename="{filename}"'})


@router.get("/runs/{run_id}/history", response_model=RunHistory, responses=responses(401, 404))
def run_history(run_id: int, principal: AnyUser, session: SessionDep, settings: SettingsDep) -> RunHistory:
    """Every action on the run, oldest first (append-only)."""
    run = get_visible_run(session, principal, settings, run_id, include_deleted=True)
    return RunHistory(items=[RunEventPublic.model_validate(e) for e in repo.history(session, run.id)])


@router.post("/runs/{run_id}/review", response_model=RunPublic, responses=responses(401, 403, 404, 409, 415, 422))
def review_run(run_id: int, body: ReviewRequest, principal: ReviewerUser, session: SessionDep, settings: SettingsDep) -> RunPublic:
    """Accept (status accepted, verified) or reject (back to in_review) the latest revision."""
    run = get_visible_run(session, principal, settings, run_id)
    service.review(session, principal, run, body.decision, body.comment)
    return service.run_public(run)


@router.get("/runs/{run_id}/images", response_model=ImageList, tags=["images"], responses=responses(401, 404))
def list_images(run_id: int, principal: AnyUser, session: SessionDep, settings: SettingsDep) -> ImageList:
    run = get_visible_run(session, principal, settings, run_id)
    return ImageList(items=[ImagePublic.model_validate(i) for i in repo.images(session, run.id)])


@router.get("/images/{image_id}", tags=["images"], responses={200: {"content": {"image/jpeg": {}, "image/png": {}}}, **responses(401, 404)})
def get_image(image_id: int, principal: AnyUser, session: SessionDep, settings: SettingsDep) -> Response:
    img = image_service.visible_image(session, principal, settings, image_id)
    return file_response(*image_service.original(settings, img), media_type=img.content_type,
                         headers={"Cache-Control": "private, max-age=86400"})


@router.get("/images/{image_id}/thumbnail", tags=["images"], responses={200: {"content": {"image/jpeg": {}}}, **responses(401, 404)})
def get_thumbnail(image_id: int, principal: AnyUser, session: SessionDep, settings: SettingsDep) -> Response:
    img = image_service.visible_image(session, principal, settings, image_id)
    return file_response(*image_service.thumbnail(settings, img), media_type="image/jpeg",
                         headers={"Cache-Control": "private, max-age=86400"})
