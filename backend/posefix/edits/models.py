"""Edit batches and the individual edits, appended and never overwritten.

A batch claims revision ``base_revision + 1`` of its run when it is submitted (a unique
index on ``(run_id, revision)`` over live batches makes the claim exclusive) and carries the
cumulative edit set that revision is solved from; the worker writes the revision later.

Status: ``pending`` until its revision is written (``ready``). A batch whose revision job
died is ``failed`` (``error`` says why): the run's head goes back, so the number is free
again; its author may retry it (pending again, if the run has not moved on) or discard it.
"""

from __future__ import annotations

import datetime as dt
import enum
from typing import Any

from sqlalchemy import JSON, Boolean, Float, ForeignKey, Index, Integer, String, Text, text
from sqlalchemy.orm import Mapped, mapped_column

from posefix.db import Base, UTCDateTime, utcnow


class BatchStatus(enum.StrEnum):
    pending = "pending"
    ready = "ready"
    failed = "failed"
    discarded = "discarded"


LIVE = "status IN ('pending', 'ready')"


class EditBatch(Base):
    __tablename__ = "edit_batches"
    __table_args__ = (
        Index("uq_edit_batches_live_revision", "run_id", "revision", unique=True,
              sqlite_where=text(LIVE), postgresql_where=text(LIVE)),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    kind: Mapped[str] = mapped_column(String(16))  # edit | revert
    base_revision: Mapped[int] = mapped_column(Integer)
    revision: Mapped[int] = mapped_column(Integer)
    author_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), nullable=True)
    task_id: Mapped[int | None] = mapped_column(Integer, nullable=True, index=True)
    accept: Mapped[bool] = mapped_column(Boolean, default=False)
    comment: Mapped[str | None] = mapped_column(Text, nullable=True)
    edit_set: Mapped[dict[str, Any]] = mapped_column(JSON)
    job_id: Mapped[int | None] = mapped_column(Integer, nullable=True)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    status: Mapped[str] = mapped_column(String(16), default=BatchStatus.pending)
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    failed_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime, nullable=True)


class Edit(Base):
    __tablename__ = "edits"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    batch_id: Mapped[int] = mapped_column(ForeignKey("edit_batches.id", ondelete="CASCADE"), index=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    k: Mapped[int] = mapped_column(Integer)
    kind: Mapped[str] = mapped_column(String(16))  # move | delete | suggestion (a move accepted from map matching)
    lon: Mapped[float | None] = mapped_column(Float, nullable=True)
    lat: Mapped[float | None] = mapped_column(Float, nullable=True)
    alt: Mapped[float | None] = mapped_column(Float, nullable=True)
    author_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), nullable=True)
    task_id: Mapped[int | None] = mapped_column(Integer, nullable=True)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
