"""Every query on edit batches and edits."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from sqlalchemy import func, insert, select, update
from sqlalchemy.orm import Session

from posefix.db import utcnow
from posefix.edits.models import BatchStatus, Edit, EditBatch
from posefix.runs.models import RunEvent
from posefix.users.models import User

LIVE = (BatchStatus.pending, BatchStatus.ready)

# Called in the transaction that moves a task's batch (one with a task_id) to a new status, so
# the task's own record of its merge (posefix.tasks) never says merged while the batch failed.
BatchListener = Callable[[Session, EditBatch], None]
BATCH_LISTENERS: list[BatchListener] = []


def on_task_batch(listener: BatchListener) -> BatchListener:
    if listener not in BATCH_LISTENERS:
        BATCH_LISTENERS.append(listener)
    return listener


def notify(session: Session, batch_id: int) -> None:
    batch = session.get(EditBatch, batch_id)
    if batch is None:
        return
    session.refresh(batch)
    if batch.task_id is not None:
        for listener in BATCH_LISTENERS:
            listener(session, batch)


def add(session: Session, obj: object) -> None:
    session.add(obj)
    session.flush()


def batch(session: Session, batch_id: int) -> EditBatch | None:
    return session.get(EditBatch, batch_id)


def batch_for_revision(session: Session, run_id: int, revision: int) -> EditBatch | None:
    """The live (pending or ready) batch that claimed ``revision``."""
    return session.scalars(select(EditBatch).where(
        EditBatch.run_id == run_id, EditBatch.revision == revision, EditBatch.status.in_(LIVE))).one_or_none()


def failed_batch_for_revision(session: Session, run_id: int, revision: int) -> EditBatch | None:
    """The latest failed or discarded batch that had claimed ``revision``."""
    return session.scalars(select(EditBatch).where(
        EditBatch.run_id == run_id, EditBatch.revision == revision, EditBatch.status.not_in(LIVE))
        .order_by(EditBatch.id.desc()).limit(1)).one_or_none()


def failed_batches(session: Session, run_id: int) -> list[EditBatch]:
    return list(session.scalars(select(EditBatch).where(
        EditBatch.run_id == run_id, EditBatch.status.not_in(LIVE)).order_by(EditBatch.id)))


def last_failed(session: Session, run_ids: list[int]) -> dict[int, EditBatch]:
    """Per run, its latest batch when that batch failed (later batches make it moot)."""
    if not run_ids:
        return {}
    last = select(func.max(EditBatch.id)).where(EditBatch.run_id.in_(run_ids)).group_by(EditBatch.run_id)
    rows = session.scalars(select(EditBatch).where(EditBatch.id.in_(last), EditBatch.status == BatchStatus.failed))
    return {b.run_id: b for b in rows}


def mark_ready(session: Session, batch_id: int) -> bool:
    """pending -> ready, in the transaction that writes its revision; False when it is not pending."""
    res = session.execute(update(EditBatch).where(EditBatch.id == batch_id, EditBatch.status == BatchStatus.pending)
                          .values(status=BatchStatus.ready))
    if (res.rowcount or 0) != 1:
        return False
    notify(session, batch_id)
    return True


def mark_failed(session: Session, batch_id: int, error: str) -> bool:
    """pending -> failed; False when the batch is not pending (its revision was written)."""
    res = session.execute(update(EditBatch).where(EditBatch.id == batch_id, EditBatch.status == BatchStatus.pending)
                          .values(status=BatchStatus.failed, error=error[:4000], failed_at=utcnow()))
    if (res.rowcount or 0) != 1:
        return False
    notify(session, batch_id)
    return True


def pending_below(session: Session, run_id: int, revision: int) -> int | None:
    """The highest revision below ``revision`` a pending batch of the run claims."""
    return session.scalar(select(func.max(EditBatch.revision)).where(
        EditBatch.run_id == run_id, EditBatch.revision < revision, EditBatch.status == BatchStatus.pending))


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
