"""Every query on edit batches and edits."""

from __future__ import annotations

from typing import Any

from sqlalchemy import insert, select
from sqlalchemy.orm import Session

from posefix.edits.models import Edit, EditBatch
from posefix.runs.models import RunEvent
from posefix.users.models import User


def add(session: Session, obj: object) -> None:
    session.add(obj)
    session.flush()


def batch(session: Session, batch_id: int) -> EditBatch | None:
    return session.get(EditBatch, batch_id)


def batch_for_revision(session: Session, run_id: int, revision: int) -> EditBatch | None:
    return session.scalars(select(EditBatch).where(EditBatch.run_id == run_id, EditBatch.revision == revision)).one_or_none()


def insert_edits(session: Session, rows: list[dict[str, Any]]) -> None:
    if rows:
        session.execute(insert(Edit), rows)


def edits(session: Session, run_id: int, batch_id: int | None, limit: int, offset: int) -> list[Edit]:
    stmt = select(Edit).where(Edit.run_id == run_id)
    if batch_id is not None:
        stmt = stmt.where(Edit.batch_id == batch_id)
    return list(session.scalars(stmt.order_by(Edit.id).limit(limit).offset(offset)))


def revision_notes(session: Session, run_id: int) -> dict[int, dict[str, Any]]:
    """Per revision number: the batch's comment and task, and the last review decision on it."""
    notes: dict[int, dict[str, Any]] = {}
    for rev, comment, task_id in session.execute(
        select(EditBatch.revision, EditBatch.comment, EditBatch.task_id).where(EditBatch.run_id == run_id)
    ):
        notes[rev] = {"comment": comment, "task_id": task_id}
    reviews = session.execute(
        select(RunEvent.revision, RunEvent.action, RunEvent.comment, User.username)
        .outerjoin(User, User.id == RunEvent.actor_id)
        .where(RunEvent.run_id == run_id, RunEvent.action.in_(("accepted", "rejected")))
        .order_by(RunEvent.id)
    )
    for rev, action, comment, who in reviews:
        if rev is not None:
            notes.setdefault(rev, {}).update(review=action, review_comment=comment, reviewer=who)
    return notes


def usernames(session: Session, ids: set[int]) -> dict[int, str]:
    if not ids:
        return {}
    return {i: n for i, n in session.execute(select(User.id, User.username).where(User.id.in_(ids)))}
