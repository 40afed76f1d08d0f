"""Routes: GET /jobs/{id}; GET /events (server-sent events: job.progress, revision.ready)."""

from __future__ import annotations

import asyncio
import datetime as dt
import json
from collections.abc import AsyncIterator
from typing import Annotated, Any

import anyio
from fastapi import APIRouter, Query, Request
from sse_starlette.sse import EventSourceResponse

from posefix.db import Database, utcnow
from posefix.deps import AnyUser, SessionDep, SettingsDep
from posefix.errors import NotFound, responses
from posefix.jobs import repository as repo
from posefix.jobs.models import Job, JobStatus
from posefix.jobs.schemas import JobPublic
from posefix.runs import repository as runs_repo
from posefix.runs.access import is_visible, visible_run_ids
from posefix.runs.models import Run
from posefix.users.models import Role

router = APIRouter(tags=["jobs"])

TERMINAL = {JobStatus.succeeded, JobStatus.dead}


def _job_visible(session: Any, principal: Any, settings: Any, job: Job) -> bool:
    if principal.role == Role.admin or job.created_by == principal.user_id:
        return True
    if job.run_id is None:
        return False
    return is_visible(session, principal, settings, job.run_id)


@router.get("/jobs/{job_id}", response_model=JobPublic, responses=responses(401, 404))
def get_job(job_id: int, principal: AnyUser, session: SessionDep, settings: SettingsDep) -> JobPublic:
    job = repo.get(session, job_id)
    if job is None or not _job_visible(session, principal, settings, job):
        raise NotFound(f"job {job_id} not found", code="job_not_found")
    return JobPublic.model_validate(job)


def _poll(db: Database, principal: Any, settings: Any, since: dt.datetime, last_rev_id: int,
          job_ids: list[int] | None, run_id: int | None) -> tuple[list[dict[str, Any]], list[dict[str, Any]], int]:
    with db.transaction(write=False) as s:
        runs_q = visible_run_ids(principal, settings)
        if run_id is not None:
            runs_q = runs_q.where(Run.id == run_id)
        jobs = repo.changed_since(s, since, job_ids, runs_q if principal.role != Role.admin or run_id else None, principal.user_id)
        revs = runs_repo.revisions_after(s, last_rev_id, runs_q)
        job_events = [JobPublic.model_validate(j).model_dump(mode="json") for j in jobs]
        rev_events = [
            {"run_id": r.run_id, "revision": r.number, "kind": r.kind, "batch_id": r.batch_id,
             "created_at": r.created_at.isoformat()}
            for r in revs
        ]
        max_rev = max([r.id for r in revs], default=last_rev_id)
    return job_events, rev_events, max_rev


@router.get(
    "/events",
    responses={200: {"content": {"text/event-stream": {}}, "description": "Event stream"}, **responses(401)},
)
async def events(
    request: Request, principal: AnyUser, settings: SettingsDep,
    job_id: Annotated[list[int] | None, Query(description="only these jobs")] = None,
    run_id: Annotated[int | None, Query(description="only this run")] = None,
    until_done: Annotated[bool, Query(description="close once every named job is finished")] = False,
    max_s: Annotated[float, Query(gt=0, le=3600, description="close after this many seconds")] = 600,
) -> EventSourceResponse:
    """Server-sent events: ``job.progress`` (a job changed) and ``revision.ready``."""
    db: Database = request.app.state.db

    # Start slightly in the past when following named jobs, so a job (and its revision)
    # that finished just before the subscription is still reported.
    since = utcnow() - dt.timedelta(seconds=5) if job_id else utcnow()

    def start_rev_id() -> int:
        with db.transaction(write=False) as s:
            return runs_repo.last_revision_id_at(s, since)

    last_rev_id = await anyio.to_thread.run_sync(start_rev_id)

    async def stream() -> AsyncIterator[dict[str, str]]:
        nonlocal since, last_rev_id
        deadline = asyncio.get_running_loop().time() + max_s
        finished: set[int] = set()
        while asyncio.get_running_loop().time() < deadline:
            if await request.is_disconnected():
                return
            poll_start = utcnow()
            jobs, revs, last_rev_id = await anyio.to_thread.run_sync(
                _poll, db, principal, settings, since, last_rev_id, job_id, run_id
            )
            since = poll_start - dt.timedelta(milliseconds=1) if not jobs else max(
                dt.datetime.fromisoformat(j["updated_at"]) for j in jobs
            )
            for j in jobs:
                yield {"event": "job.progress", "data": json.dumps(j), "id": f"job-{j['id']}-{j['updated_at']}"}
                if j["status"] in TERMINAL:
                    finished.add(j["id"])
            for r in revs:
                yield {"event": "revision.ready", "data": json.dumps(r), "id": f"rev-{r['run_id']}-{r['revision']}"}
            if until_done and job_id and set(job_id) <= finished:
                return
            await asyncio.sleep(0.25)

    return EventSourceResponse(stream(), ping=15)
