"""Tasks (HITs), their runs, assignments (leases), the append-only transition history,
operator profiles, admin-granted qualifications and gold runs.

An assignment row is one unit of work on one run of a task. Rows start ``open`` (in the
pool, no operator); leasing one is a single conditional UPDATE that sets the operator. A
returned or expired lease keeps its row (history) and puts a fresh ``open`` row back in the
pool, so "exactly N leases" is a count of rows, never a counter updated in Python.
"""

from __future__ import annotations

import datetime as dt
import enum
from typing import Any

from sqlalchemy import JSON, Boolean, Float, ForeignKey, Index, Integer, String, Text, UniqueConstraint
from sqlalchemy.orm import Mapped, mapped_column

from posefix.db import Base, UTCDateTime, utcnow


class TaskStatus(enum.StrEnum):
    assignable = "assignable"
    in_progress = "in_progress"
    reviewable = "reviewable"
    done = "done"
    expired = "expired"
    cancelled = "cancelled"


class AssignmentStatus(enum.StrEnum):
    open = "open"            # in the pool, nobody holds it
    accepted = "accepted"    # leased by an operator until lease_expires_at
    submitted = "submitted"
    approved = "approved"
    rejected = "rejected"
    returned = "returned"
    expired = "expired"
    withdrawn = "withdrawn"  # an open slot closed because its task ended


class TaskRunStatus(enum.StrEnum):
    open = "open"            # waiting for submissions
    agreed = "agreed"        # all submitted, no conflict
    conflict = "conflict"    # flagged for adjudication
    merging = "merging"      # merge job enqueued
    merged = "merged"        # a revision was made from the approved work
    merge_failed = "merge_failed"  # the merge or its revision failed: a reviewer may merge again
    unmerged = "unmerged"    # every submission was rejected


class ConflictPolicy(enum.StrEnum):
    flag = "flag"            # a reviewer adjudicates
    extend = "extend"        # one more assignment is requested automatically (then flag)


class Task(Base):
    __tablename__ = "tasks"
    __table_args__ = (
        UniqueConstraint("requester_id", "client_token"),
        Index("ix_tasks_status_priority", "status", "priority"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    title: Mapped[str] = mapped_column(String(200))
    instructions: Mapped[str] = mapped_column(Text, default="")
    reward_cents: Mapped[int] = mapped_column(Integer, default=0)
    currency: Mapped[str] = mapped_column(String(3), default="EUR")
    assignments_per_run: Mapped[int] = mapped_column(Integer, default=1)
    lease_s: Mapped[int] = mapped_column(Integer)
    lifetime_s: Mapped[int] = mapped_column(Integer)
    auto_approval_delay_s: Mapped[int] = mapped_column(Integer)
    priority: Mapped[int] = mapped_column(Integer, default=0)
    max_active_leases: Mapped[int] = mapped_column(Integer, default=1)
    rules: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    requirements: Mapped[list[dict[str, Any]]] = mapped_column(JSON, default=list)
    conflict_distance_m: Mapped[float] = mapped_column(Float)
    conflict_keyframes: Mapped[int] = mapped_column(Integer)
    conflict_edit_m: Mapped[float] = mapped_column(Float)
    conflict_policy: Mapped[str] = mapped_column(String(16), default=ConflictPolicy.flag)
    max_extra_assignments: Mapped[int] = mapped_column(Integer, default=1)
    is_test: Mapped[bool] = mapped_column(Boolean, default=False)
    status: Mapped[str] = mapped_column(String(16), default=TaskStatus.assignable)
    requester_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), nullable=True, index=True)
    client_token: Mapped[str | None] = mapped_column(String(64), nullable=True)
    request_hash: Mapped[str | None] = mapped_column(String(64), nullable=True)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    expires_at: Mapped[dt.datetime] = mapped_column(UTCDateTime)
    updated_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)


class TaskRun(Base):
    """One run of a task, with the consensus of its submissions."""

    __tablename__ = "task_runs"
    __table_args__ = (UniqueConstraint("task_id", "run_id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    task_id: Mapped[int] = mapped_column(ForeignKey("tasks.id", ondelete="CASCADE"), index=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    is_gold: Mapped[bool] = mapped_column(Boolean, default=False)
    centre_lon: Mapped[float] = mapped_column(Float)
    centre_lat: Mapped[float] = mapped_column(Float)
    wanted: Mapped[int] = mapped_column(Integer)
    extra_added: Mapped[int] = mapped_column(Integer, default=0)
    base_revision: Mapped[int] = mapped_column(Integer, default=0)
    status: Mapped[str] = mapped_column(String(16), default=TaskRunStatus.open)
    consensus: Mapped[list[list[float]] | None] = mapped_column(JSON, nullable=True)
    disagreement_m: Mapped[list[float] | None] = mapped_column(JSON, nullable=True)
    conflicts: Mapped[list[dict[str, Any]] | None] = mapped_column(JSON, nullable=True)
    merge_batch_id: Mapped[int | None] = mapped_column(Integer, nullable=True)
    merged_revision: Mapped[int | None] = mapped_column(Integer, nullable=True)
    merge_detail: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    updated_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)


class Assignment(Base):
    __tablename__ = "assignments"
    __table_args__ = (
        # Never the same run twice for one operator (NULL operators, the open pool, repeat freely).
        UniqueConstraint("operator_id", "run_id"),
        Index("ix_assignments_pool", "status", "task_id"),
        Index("ix_assignments_operator_status", "operator_id", "status"),
        Index("ix_assignments_lease", "status", "lease_expires_at"),
        Index("ix_assignments_auto_approve", "status", "auto_approve_at"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    task_id: Mapped[int] = mapped_column(ForeignKey("tasks.id", ondelete="CASCADE"))
    task_run_id: Mapped[int] = mapped_column(ForeignKey("task_runs.id", ondelete="CASCADE"), index=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    operator_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), nullable=True)
    status: Mapped[str] = mapped_column(String(16), default=AssignmentStatus.open)
    base_revision: Mapped[int | None] = mapped_column(Integer, nullable=True)
    leased_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime, nullable=True)
    lease_expires_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime, nullable=True)
    submitted_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime, nullable=True)
    edit_set: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    comment: Mapped[str | None] = mapped_column(Text, nullable=True)
    corrected: Mapped[list[list[float]] | None] = mapped_column(JSON, nullable=True)
    evaluated_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime, nullable=True)
    gold_error_m: Mapped[float | None] = mapped_column(Float, nullable=True)
    consensus_error_m: Mapped[float | None] = mapped_column(Float, nullable=True)
    auto_approve_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime, nullable=True)
    reviewed_by: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), nullable=True)
    reviewed_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime, nullable=True)
    feedback: Mapped[str | None] = mapped_column(Text, nullable=True)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    updated_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)


class TaskEvent(Base):
    """Append-only history of every task and assignment transition (audit and provenance)."""

    __tablename__ = "task_events"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    task_id: Mapped[int] = mapped_column(ForeignKey("tasks.id", ondelete="CASCADE"), index=True)
    assignment_id: Mapped[int | None] = mapped_column(Integer, nullable=True, index=True)
    task_run_id: Mapped[int | None] = mapped_column(Integer, nullable=True)
    entity: Mapped[str] = mapped_column(String(16))  # task | assignment | task_run
    from_status: Mapped[str | None] = mapped_column(String(16), nullable=True)
    to_status: Mapped[str] = mapped_column(String(16))
    actor_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), nullable=True)
    at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    reason: Mapped[str | None] = mapped_column(String(64), nullable=True)
    detail: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)


class OperatorProfile(Base):
    """Home area (point + radius, or polygon). The row is also each operator's queue lock."""

    __tablename__ = "operator_profiles"

    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), primary_key=True)
    home_lon: Mapped[float | None] = mapped_column(Float, nullable=True)
    home_lat: Mapped[float | None] = mapped_column(Float, nullable=True)
    home_radius_m: Mapped[float | None] = mapped_column(Float, nullable=True)
    home_polygon: Mapped[list[list[float]] | None] = mapped_column(JSON, nullable=True)
    last_request_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime, nullable=True)
    updated_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)


class OperatorQualification(Base):
    """A named qualification value held by an operator (admin-granted, or the test result)."""

    __tablename__ = "operator_qualifications"

    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), primary_key=True)
    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    value: Mapped[float] = mapped_column(Float, default=1.0)
    granted_by: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), nullable=True)
    granted_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    detail: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)


class GoldRun(Base):
    """A run with a known true trajectory (full-rate truth in the file store)."""

    __tablename__ = "gold_runs"

    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), primary_key=True)
    truth_file: Mapped[str] = mapped_column(String(255))
    is_test: Mapped[bool] = mapped_column(Boolean, default=False)
    pass_error_m: Mapped[float] = mapped_column(Float, default=3.0)
    created_by: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), nullable=True)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
