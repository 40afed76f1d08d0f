"""One person's work for the admin's audit view: the edit batches they submitted and the
reviews they made (of task assignments and of runs), newest first."""

from __future__ import annotations

import datetime as dt
from typing import Any

from pydantic import BaseModel, Field
from sqlalchemy import select
from sqlalchemy.orm import Session

from posefix.edits.models import EditBatch
from posefix.runs.models import Run, RunEvent
from posefix.tasks.models import Assignment, AssignmentStatus


class EditActivity(BaseModel):
    run_id: int
    run_name: str
    revision: int
    kind: str = Field(description="edit | revert")
    created_at: dt.datetime
    comment: str | None
    task_id: int | None
    n_moves: int
    n_deleted: int
    accept: bool


class ReviewActivity(BaseModel):
    target: str = Field(description="assignment (a task submission) | run (a run's revision)")
    run_id: int
    run_name: str
    decision: str = Field(description="approved | rejected (assignments), accepted | rejected (runs)")
    at: dt.datetime | None
    comment: str | None
    assignment_id: int | None = None
    task_id: int | None = None
    revision: int | None = None


class UserActivity(BaseModel):
    user_id: int
    username: str
    edits: list[EditActivity]
    reviews: list[ReviewActivity]


def _edits(session: Session, user_id: int, limit: int) -> list[EditActivity]:
    rows = session.execute(
        select(EditBatch, Run.name).join(Run, Run.id == EditBatch.run_id)
        .where(EditBatch.author_id == user_id).order_by(EditBatch.id.desc()).limit(limit)
    )
    out = []
    for b, name in rows:
        es: dict[str, Any] = b.edit_set or {}
        out.append(EditActivity(run_id=b.run_id, run_name=name, revision=b.revision, kind=b.kind, created_at=b.created_at,
                                comment=b.comment, task_id=b.task_id, n_moves=len(es.get("moves", [])),
                                n_deleted=len(es.get("deleted", [])), accept=b.accept))
    return out


def _reviews(session: Session, user_id: int, limit: int) -> list[ReviewActivity]:
    done = (AssignmentStatus.approved, AssignmentStatus.rejected)
    assignments = session.execute(
        select(Assignment, Run.name).join(Run, Run.id == Assignment.run_id)
        .where(Assignment.reviewed_by == user_id, Assignment.status.in_(done))
        .order_by(Assignment.reviewed_at.desc()).limit(limit)
    )
    out = [ReviewActivity(target="assignment", run_id=a.run_id, run_name=name, decision=a.status, at=a.reviewed_at,
                          comment=a.feedback, assignment_id=a.id, task_id=a.task_id) for a, name in assignments]
    runs = session.execute(
        select(RunEvent, Run.name).join(Run, Run.id == RunEvent.run_id)
        .where(RunEvent.actor_id == user_id, RunEvent.action.in_(("accepted", "rejected")))
        .order_by(RunEvent.id.desc()).limit(limit)
    )
    out += [ReviewActivity(target="run", run_id=e.run_id, run_name=name, decision=e.action, at=e.at, comment=e.comment,
                           revision=e.revision, task_id=e.task_id) for e, name in runs]
    out.sort(key=lambda r: r.at or dt.datetime.min.replace(tzinfo=dt.UTC), reverse=True)
    return out[:limit]


def user_activity(session: Session, user_id: int, username: str, limit: int) -> UserActivity:
    return UserActivity(user_id=user_id, username=username, edits=_edits(session, user_id, limit),
                        reviews=_reviews(session, user_id, limit))
