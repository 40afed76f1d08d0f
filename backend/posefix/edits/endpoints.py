"""Routes: preview, edit batches, revisions (list, detail, diff, revert), edits."""

from __future__ import annotations

from typing import Annotated, Any

import anyio
import orjson
from fastapi import APIRouter, Header, Path, Query, Request, Response

from posefix.deps import AnyUser, EditorReader, EditorUser, ReadSessionDep, SessionDep, SettingsDep, solver_limiter
from posefix.edits import failures
from posefix.edits import repository as edits_repo
from posefix.edits import service
from posefix.edits.schemas import (
    DiffResponse, EditBatchAccepted, EditBatchIn, EditPublic, PreviewRequest, PreviewResponse, RevertRequest,
    RevisionDetail, RevisionList, RevisionPublic,
)
from posefix.errors import responses
from posefix.runs import repository as runs_repo
from posefix.runs.access import check_direct_write, get_visible_run
from posefix.runs.models import Revision
from posefix.runs.schemas import FailedEdit

router = APIRouter(tags=["edits"])


def _wake(request: Request) -> Any:
    worker = getattr(request.app.state, "worker", None)
    return worker.wake if worker is not None else None


def _rev_public(rev: Revision, detail: bool = False, notes: dict[str, Any] | None = None, author: str | None = None) -> RevisionPublic:
    data = dict(**(notes or {}), author=author,
        number=rev.number, kind=rev.kind, batch_id=rev.batch_id, created_by=rev.created_by, created_at=rev.created_at,
        solver=rev.solver, drift=rev.drift, max_correction_m=rev.max_correction_m,
        n_moves=len(rev.edit_set.get("moves", [])), n_deleted=len(rev.edit_set.get("deleted", [])),
    )
    return RevisionDetail(**data, edit_set=rev.edit_set) if detail else RevisionPublic(**data)


@router.post("/runs/{run_id}/preview", response_model=PreviewResponse, responses=responses(401, 403, 404, 409, 415, 422))
async def preview(
    run_id: int, body: PreviewRequest, request: Request, principal: EditorReader, session: ReadSessionDep,
    settings: SettingsDep,
) -> Response:
    """Re-optimise keyframes with proposed, uncommitted edits (refused moves are left out and listed).

    409 ``stale_revision`` (with ``current_revision``) when ``base_revision`` is not the run's
    latest, as ``/edits`` answers for the same batch."""
    # A preview writes nothing: its session is a reading one (on SQLite a POST's session
    # would hold the database's one write lock, queueing previews and every writer behind
    # each other), and it holds no connection while it waits for a solver lane.

    def work() -> bytes:
        run = get_visible_run(session, principal, settings, run_id)
        out = service.preview(session, settings, run, body.base_revision, body.moves, body.deleted)
        session.commit()  # give the connection back before serialising
        return orjson.dumps(out, option=orjson.OPT_SERIALIZE_NUMPY)

    # orjson writes the (k, 2) positions array directly: validating and encoding 7,200 floats
    # through the response model took as long as the local solve itself
    content = await anyio.to_thread.run_sync(work, limiter=solver_limiter(request.app))
    return Response(content, media_type="application/json")


@router.post("/runs/{run_id}/edits", response_model=EditBatchAccepted, status_code=202, responses=responses(400, 401, 403, 404, 409, 415, 422))
def submit_edits(
    run_id: int, body: EditBatchIn, request: Request, principal: EditorUser, session: SessionDep, settings: SettingsDep,
    if_match: Annotated[str | None, Header(alias="If-Match", description='"<revision>" the edits were made on')] = None,
) -> EditBatchAccepted:
    """Submit a batch made against a base revision; the worker writes the next revision.

    409 ``stale_revision`` (with ``current_revision``) when someone else's batch came first;
    422 ``edit_refused`` with a reason per refused edit. 403 ``review_required`` for an operator
    on a run that belongs to a task (work goes through the assignment), ``not_on_task`` for a
    ``task_id`` the caller holds no live assignment of on this run.
    """
    run = get_visible_run(session, principal, settings, run_id)
    check_direct_write(session, principal, run, body.task_id)
    base = service.parse_base(if_match, body.base_revision)
    batch, job_id, flags = service.submit(
        session, settings, principal, run, base=base, moves=body.moves, deleted=body.deleted, accept=body.accept,
        comment=body.comment, task_id=body.task_id, wake=_wake(request),
    )
    return EditBatchAccepted(batch_id=batch.id, job_id=job_id, revision=batch.revision, flags=flags)  # type: ignore[arg-type]


@router.get("/runs/{run_id}/revisions", response_model=RevisionList, responses=responses(401, 404))
def list_revisions(run_id: int, principal: AnyUser, session: SessionDep, settings: SettingsDep) -> RevisionList:
    run = get_visible_run(session, principal, settings, run_id)
    revs = runs_repo.revisions(session, run.id)
    notes = edits_repo.revision_notes(session, run.id)
    names = edits_repo.usernames(session, {r.created_by for r in revs if r.created_by is not None})
    items = [_rev_public(r, notes=notes.get(r.number), author=names.get(r.created_by or 0)) for r in revs]
    return RevisionList(items=items, head_revision=run.head_revision,
                        failed=[failures.failed_json(b) for b in edits_repo.failed_batches(session, run.id)])  # type: ignore[misc]


@router.get("/runs/{run_id}/revisions/{number}", response_model=RevisionDetail, responses=responses(401, 404, 409))
def get_revision(run_id: int, number: int, principal: AnyUser, session: SessionDep, settings: SettingsDep) -> RevisionPublic:
    run = get_visible_run(session, principal, settings, run_id)
    return _rev_public(service.ready(session, run, number), detail=True)


@router.get("/runs/{run_id}/diff", response_model=DiffResponse, responses=responses(401, 404, 409, 422))
def diff(
    run_id: int, principal: AnyUser, session: SessionDep, settings: SettingsDep,
    from_: Annotated[int, Query(alias="from", ge=0, le=10**9)], to: Annotated[int, Query(ge=0, le=10**9)],
) -> dict[str, Any]:
    """Per-keyframe horizontal displacement between two ready revisions."""
    run = get_visible_run(session, principal, settings, run_id)
    return service.diff(session, settings, run, from_, to)


@router.post("/runs/{run_id}/revert", response_model=EditBatchAccepted, status_code=202, responses=responses(400, 401, 403, 404, 409, 415, 422))
def revert(
    run_id: int, body: RevertRequest, request: Request, principal: EditorUser, session: SessionDep, settings: SettingsDep,
    if_match: Annotated[str | None, Header(alias="If-Match")] = None,
) -> EditBatchAccepted:
    """Make a new revision with the edits of ``to_revision`` (history is kept); operators may
    not revert a run that belongs to a task (403 ``review_required``)."""
    run = get_visible_run(session, principal, settings, run_id)
    check_direct_write(session, principal, run)
    base = run.head_revision if if_match is None and body.base_revision is None else service.parse_base(if_match, body.base_revision)
    batch, job_id = service.revert(session, settings, principal, run, to_revision=body.to_revision, base=base,
                                   comment=body.comment, wake=_wake(request))
    return EditBatchAccepted(batch_id=batch.id, job_id=job_id, revision=batch.revision, flags=[])


@router.get("/runs/{run_id}/edits", response_model=list[EditPublic], responses=responses(401, 404))
def list_edits(
    run_id: int, principal: AnyUser, session: SessionDep, settings: SettingsDep,
    batch_id: Annotated[int | None, Query(ge=1, le=2**62)] = None,
    limit: Annotated[int, Query(ge=1, le=10000)] = 1000, offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
) -> list[EditPublic]:
    """Every edit ever submitted on the run (author, time, task), oldest first."""
    run = get_visible_run(session, principal, settings, run_id)
    return [EditPublic.model_validate(e) for e in edits_repo.edits(session, run.id, batch_id, limit, offset)]


@router.post("/runs/{run_id}/batches/{batch_id}/retry", response_model=EditBatchAccepted, status_code=202,
             responses=responses(401, 403, 404, 409))
def retry_batch(run_id: int, batch_id: Annotated[int, Path(ge=1, le=2**62)], request: Request, principal: EditorUser,
                session: SessionDep, settings: SettingsDep) -> EditBatchAccepted:
    """Compute a failed batch's revision again (its author, a reviewer or an admin); 409
    ``stale_revision`` when the run has moved on since (edit again on the latest revision)."""
    run = get_visible_run(session, principal, settings, run_id)
    batch = failures.retry(session, settings, principal, run, batch_id, wake=_wake(request))
    return EditBatchAccepted(batch_id=batch.id, job_id=batch.job_id, revision=batch.revision, flags=[])  # type: ignore[arg-type]


@router.post("/runs/{run_id}/batches/{batch_id}/discard", response_model=FailedEdit, responses=responses(401, 403, 404, 409))
def discard_batch(run_id: int, batch_id: Annotated[int, Path(ge=1, le=2**62)], principal: EditorUser,
                  session: SessionDep, settings: SettingsDep) -> dict[str, Any]:
    """Close a failed batch (its author, a reviewer or an admin): the run no longer shows it."""
    run = get_visible_run(session, principal, settings, run_id)
    return failures.failed_json(failures.discard(session, principal, run, batch_id))
