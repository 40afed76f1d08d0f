"""Every query on edit batches and edits."""

from __future__ import annotations

from typing import Any

from sqlalchemy import insert, select
from sqlalchemy.orm import Session

from posefix.edits.models import Edit, EditBatch


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
