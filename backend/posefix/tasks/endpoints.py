"""Routes of the tasks domain: tasks, the queue, assignments, review, operators, gold runs."""

from __future__ import annotations

import asyncio
import json
import tempfile
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Annotated, Any

import anyio
from fastapi import APIRouter, Depends, File, Form, Query, Request, Response, UploadFile
from sse_starlette.sse import EventSourceResponse

from posefix.db import Database
from posefix.deps import AnyUser, ReviewerUser, SessionDep, SettingsDep, require
from posefix.errors import NotFound, Unprocessable, responses
from posefix.io import RunFormatError, read_run
from posefix.runs import storage
from posefix.runs.access import get_visible_run, visible_run_ids
from posefix.tasks import clock, leases, lifecycle, operators as ops, review as reviews, submission
from posefix.tasks import repository as repo
from posefix.tasks.models import AssignmentStatus, Task
from posefix.tasks.schemas import (
    AssignmentPublic, GoldRunPublic, HomeAreaIn, NextResponse, OperatorStats, QualificationGrant, QualificationPublic,
    ReviewIn, ReviewQueueItem, ReviewView, SubmitIn, SubmitOut, TaskCreate, TaskList, TaskPublic,
    TransitionPublic,
)
from posefix.users.models import Role, User
from posefix.users.service import Principal
from posefix.filestore import file_store

router = APIRouter(tags=["tasks"])

# Anyone who edits may take work (reviewers and admins too: they just never review their own).
OperatorUser = Annotated[Principal, Depends(require(Role.operator, Role.reviewer, Role.admin))]
RequesterUser = Annotated[Principal, Depends(require(Role.admin, Role.client))]
AdminOnly = Annotated[Principal, Depends(require(Role.admin))]
AdminUpload = Annotated[Principal, Depends(require(Role.admin, allow_multipart=True))]


def _wake(request: Request) -> Any:
    worker = getattr(request.app.state, "worker", None)
    return worker.wake if worker is not None else None


# -- tasks ----------------------------------------------------------------------------------------

@router.post("/tasks", response_model=TaskPublic, status_code=201, responses=responses(401, 403, 409, 415, 422))
def create_task(body: TaskCreate, response: Response, principal: RequesterUser, session: SessionDep,
                settings: SettingsDep) -> TaskPublic:
    """Create a task over runs you may see. With ``client_token``, repeating the request within
    24 h returns the same task (200) instead of making another; the same token with other
    parameters is 409 ``client_token_reused``."""
    task, created = lifecycle.create_task(session, settings, principal, body, clock.now(),
                                        visible=visible_run_ids(principal, settings))
    if not created:
        response.status_code = 200
    return lifecycle.task_public(session, task)


@router.get("/tasks", response_model=TaskList, responses=responses(401, 403))
def list_tasks(
    principal: Annotated[Principal, Depends(require(Role.admin, Role.client, Role.reviewer))], session: SessionDep,
    status: Annotated[str | None, Query(max_length=16)] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50, offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
) -> TaskList:
    """Tasks: a requester sees their own; admins and reviewers see all."""
    requester = principal.user_id if principal.role == Role.client else None
    rows, total = repo.list_tasks(session, requester, status, limit, offset)
    return TaskList(items=[lifecycle.task_public(session, t, with_runs=False) for t in rows], total=total)


@router.get("/tasks/{task_id}", response_model=TaskPublic, responses=responses(401, 404))
def get_task(task_id: int, principal: AnyUser, session: SessionDep) -> TaskPublic:
    """Status, counts of assignments by status, and each run's progress and conflicts (poll this, or use events)."""
    return lifecycle.task_public(session, lifecycle.get_task(session, principal, task_id))


@router.post("/tasks/{task_id}/cancel", response_model=TaskPublic, responses=responses(401, 403, 404, 409, 415))
def cancel_task(task_id: int, principal: RequesterUser, session: SessionDep) -> TaskPublic:
    task = lifecycle.get_task(session, principal, task_id)
    lifecycle.cancel_task(session, principal, task, clock.now())
    return lifecycle.task_public(session, task)


@router.get("/tasks/{task_id}/history", response_model=list[TransitionPublic], responses=responses(401, 404))
def task_history(task_id: int, principal: AnyUser, session: SessionDep,
                 after_id: Annotated[int, Query(ge=0)] = 0) -> list[TransitionPublic]:
    """Every transition of the task, its runs and assignments, oldest first (append-only)."""
    lifecycle.get_task(session, principal, task_id)
    return [TransitionPublic.model_validate(e) for e in repo.history(session, task_id, after_id)]


@router.get("/tasks/{task_id}/events",
            responses={200: {"content": {"text/event-stream": {}}, "description": "Event stream"}, **responses(401, 404)})
async def task_events(
    task_id: int, request: Request, principal: AnyUser,
    max_s: Annotated[float, Query(gt=0, le=3600)] = 600,
) -> EventSourceResponse:
    """Server-sent events ``task.transition`` (each history row) until the task is finished or ``max_s``."""
    db: Database = request.app.state.db

    def check() -> None:
        with db.transaction(write=False) as s:
            lifecycle.get_task(s, principal, task_id)

    await anyio.to_thread.run_sync(check)

    def poll(after: int) -> tuple[list[dict[str, Any]], str]:
        with db.transaction(write=False) as s:
            rows = [TransitionPublic.model_validate(e).model_dump(mode="json") for e in repo.history(s, task_id, after, 200)]
            task = s.get(Task, task_id)
            return rows, task.status if task else "cancelled"

    async def stream() -> AsyncIterator[dict[str, str]]:
        after = 0
        deadline = asyncio.get_running_loop().time() + max_s
        while asyncio.get_running_loop().time() < deadline:
            if await request.is_disconnected():
                return
            rows, status = await anyio.to_thread.run_sync(poll, after)
            for r in rows:
                after = r["id"]
                yield {"event": "task.transition", "data": json.dumps(r), "id": str(r["id"])}
            if not rows and status in ("done", "expired", "cancelled"):
                return
            await asyncio.sleep(0.25)

    return EventSourceResponse(stream(), ping=15)


@router.get("/tasks/{task_id}/eligibility", responses=responses(401, 404))
def task_eligibility(task_id: int, principal: OperatorUser, session: SessionDep) -> dict[str, Any]:
    """Whether you qualify for this task, and if not, why (in words)."""
    task = lifecycle.get_offered_task(session, principal, task_id, clock.now())
    reasons = ops.eligibility(session, principal.user_id, task)
    return {"task_id": task_id, "eligible": not reasons, "reasons": reasons}


# -- the queue and assignments --------------------------------------------------------------------

@router.post("/tasks/next", response_model=NextResponse, responses=responses(401, 403, 415))
def next_task(principal: OperatorUser, session: SessionDep) -> dict[str, Any]:
    """Lease the highest-priority assignment you qualify for; ``assignment`` is null (with the
    reasons) when there is none."""
    return leases.next_assignment(session, principal, clock.now())


@router.get("/assignments/mine", response_model=list[AssignmentPublic], responses=responses(401, 403))
def my_assignments(principal: OperatorUser, session: SessionDep,
                   status: Annotated[list[AssignmentStatus] | None, Query()] = None,
                   limit: Annotated[int, Query(ge=1, le=500)] = 100) -> list[AssignmentPublic]:
    now = clock.now()
    rows = repo.my_assignments(session, principal.user_id, tuple(status) if status else None, limit)
    return [leases.assignment_public(session, a, now) for a in rows]


@router.get("/assignments/{assignment_id}", response_model=AssignmentPublic, responses=responses(401, 404))
def get_assignment(assignment_id: int, principal: AnyUser, session: SessionDep) -> AssignmentPublic:
    return leases.assignment_public(session, leases.visible_assignment(session, principal, assignment_id), clock.now())


@router.post("/assignments/{assignment_id}/extend", response_model=AssignmentPublic, responses=responses(401, 404, 409, 410, 415))
def extend(assignment_id: int, principal: OperatorUser, session: SessionDep) -> AssignmentPublic:
    """Extend the lease to now + the task's assignment duration (while you are still working)."""
    now = clock.now()
    return leases.assignment_public(session, leases.extend_lease(session, principal, assignment_id, now), now)


@router.post("/assignments/{assignment_id}/return", response_model=AssignmentPublic, responses=responses(401, 404, 409, 410, 415))
def return_(assignment_id: int, principal: OperatorUser, session: SessionDep) -> AssignmentPublic:
    """Give the assignment back to the pool (you will not get this run again)."""
    now = clock.now()
    return leases.assignment_public(session, leases.return_assignment(session, principal, assignment_id, now), now)


@router.post("/assignments/{assignment_id}/submit", response_model=SubmitOut, responses=responses(401, 404, 409, 410, 415, 422))
def submit(assignment_id: int, body: SubmitIn, request: Request, principal: OperatorUser, session: SessionDep,
           settings: SettingsDep) -> SubmitOut:
    """Submit your edits (same shape as an edit batch). 410 ``lease_expired`` after the
    deadline (not counted); 422 ``edit_refused`` with a reason per refused edit."""
    now = clock.now()
    a, flags = submission.submit(session, settings, principal, assignment_id, body, now, wake=_wake(request))
    return SubmitOut(assignment=leases.assignment_public(session, a, now), flags=flags)  # type: ignore[arg-type]


# -- review -----------------------------------------------------------------------------------------

@router.get("/review/queue", response_model=list[ReviewQueueItem], responses=responses(401, 403))
def review_queue(principal: ReviewerUser, session: SessionDep,
                 limit: Annotated[int, Query(ge=1, le=500)] = 100) -> list[ReviewQueueItem]:
    """Runs with submitted work waiting for review (not your own), conflicts first."""
    return [
        ReviewQueueItem(task_run_id=tr.id, task_id=t.id, task_title=t.title, run_id=tr.run_id, status=tr.status,
                        submitted=n, conflicts=len(tr.conflicts or []))
        for tr, t, n in repo.review_queue(session, principal.user_id, limit)
    ]


@router.get("/task-runs/{task_run_id}/review", response_model=ReviewView, responses=responses(401, 403, 404))
def review_view(task_run_id: int, principal: ReviewerUser, session: SessionDep) -> ReviewView:
    """Submissions side by side: each corrected track and its edits, the consensus and the
    per-keyframe disagreement."""
    return reviews.review_view(session, task_run_id)


@router.post("/task-runs/{task_run_id}/merge", response_model=ReviewView, responses=responses(401, 403, 404, 409, 415))
def merge_again(task_run_id: int, principal: ReviewerUser, session: SessionDep) -> ReviewView:
    """Merge a run whose merge failed (409 ``not_merge_failed`` otherwise) again from its
    approved work, on the run's latest revision."""
    reviews.merge_again(session, principal, task_run_id, clock.now())
    return reviews.review_view(session, task_run_id)


@router.post("/assignments/{assignment_id}/review", response_model=AssignmentPublic, responses=responses(401, 403, 404, 409, 415))
def review(assignment_id: int, body: ReviewIn, principal: ReviewerUser, session: SessionDep) -> AssignmentPublic:
    """Approve or reject submitted work with feedback (never your own). When every submission
    of a run is decided, the approved work is merged into a new revision by the worker."""
    now = clock.now()
    a = reviews.review(session, principal, assignment_id, body.decision, body.feedback, now)
    return leases.assignment_public(session, a, now)


# -- operators ----------------------------------------------------------------------------------------

@router.get("/operators", response_model=list[OperatorStats], responses=responses(401, 403))
def operators(principal: AdminOnly, session: SessionDep) -> list[dict[str, Any]]:
    """Every operator: accuracy on gold runs, agreement with consensus, throughput, qualifications."""
    return ops.operator_stats(session, repo.operators(session))


@router.get("/operators/me", response_model=OperatorStats, responses=responses(401, 403))
def my_stats(principal: OperatorUser, session: SessionDep) -> dict[str, Any]:
    return ops.operator_stats(session, repo.operators(session, [principal.user_id]))[0]


def _operator(session: Any, user_id: int) -> User:
    users = repo.operators(session, [user_id])
    if not users:
        raise NotFound(f"operator {user_id} not found", code="operator_not_found")
    return users[0]


@router.put("/operators/me/home-area", response_model=OperatorStats, responses=responses(401, 403, 415, 422))
def set_my_home(body: HomeAreaIn, principal: OperatorUser, session: SessionDep) -> dict[str, Any]:
    ops.set_home_area(session, principal.user_id, body, clock.now())
    return ops.operator_stats(session, [_operator(session, principal.user_id)])[0]


@router.put("/operators/{user_id}/home-area", response_model=OperatorStats, responses=responses(401, 403, 404, 415, 422))
def set_home(user_id: int, body: HomeAreaIn, principal: AdminOnly, session: SessionDep) -> dict[str, Any]:
    user = _operator(session, user_id)
    ops.set_home_area(session, user_id, body, clock.now())
    return ops.operator_stats(session, [user])[0]


@router.post("/operators/{user_id}/qualifications", response_model=QualificationPublic, status_code=201,
             responses=responses(401, 403, 404, 415, 422))
def grant(user_id: int, body: QualificationGrant, principal: AdminOnly, session: SessionDep) -> QualificationPublic:
    _operator(session, user_id)
    q = ops.set_qualification(session, user_id, body.name, body.value, principal.user_id, clock.now(),
                                  detail={"message": "granted by an admin"})
    return QualificationPublic.model_validate(q)


@router.delete("/operators/{user_id}/qualifications/{name}", status_code=204, responses=responses(401, 403, 404))
def revoke(user_id: int, name: str, principal: AdminOnly, session: SessionDep) -> Response:
    _operator(session, user_id)
    ops.revoke_qualification(session, user_id, name)
    return Response(status_code=204)


# -- gold runs ------------------------------------------------------------------------------------------

@router.post("/gold-runs", response_model=GoldRunPublic, status_code=201, responses=responses(401, 403, 404, 413, 422))
def add_gold_run(
    principal: AdminUpload, session: SessionDep, settings: SettingsDep,
    run_id: Annotated[int, Form(ge=1)], truth: Annotated[UploadFile, File(description="the true trajectory, any run format")],
    is_test: Annotated[bool, Form()] = False, pass_error_m: Annotated[float, Form(gt=0, le=1000)] = 3.0,
) -> GoldRunPublic:
    """Mark a run as gold with its true trajectory (kept hidden from operators). ``is_test``
    makes it the qualification test taken before first work."""
    run = get_visible_run(session, principal, settings, run_id)
    name = Path(truth.filename or "truth.csv").name
    fs = file_store(settings)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / name
        size = 0
        with path.open("wb") as out:
            while chunk := truth.file.read(1 << 20):
                size += len(chunk)
                if size > settings.max_run_bytes:
                    raise Unprocessable(f"{name}: truth file larger than {settings.max_run_bytes} bytes", code="too_large")
                out.write(chunk)
        try:
            pose = read_run(path)
            pose.validated()
        except (RunFormatError, ValueError) as exc:
            raise Unprocessable(f"{name}: {exc}", code="invalid_truth", extra={"file": name}) from None
    if pose.t_s[-1] < run.t_start_s or pose.t_s[0] > run.t_end_s:
        raise Unprocessable(f"{name}: the truth ({pose.t_s[0]:.1f}..{pose.t_s[-1]:.1f} s) does not overlap run {run.id}",
                            code="invalid_truth", extra={"file": name, "field": "t"})
    rel = storage.write_samples(fs, f"gold/{run.id}/truth.parquet", pose)
    gold = lifecycle.add_gold_run(session, settings, principal, run, rel, is_test=is_test, pass_error_m=pass_error_m, now=clock.now())
    return GoldRunPublic.model_validate(gold)


@router.get("/gold-runs", response_model=list[GoldRunPublic], responses=responses(401, 403))
def list_gold_runs(principal: AdminOnly, session: SessionDep) -> list[GoldRunPublic]:
    return [GoldRunPublic.model_validate(g) for g in repo.gold_runs(session)]

