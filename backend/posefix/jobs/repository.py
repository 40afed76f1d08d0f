"""Every query on the job table: enqueue, claim (one atomic statement), lease, finish.

Claim: PostgreSQL picks a row with ``FOR UPDATE SKIP LOCKED`` inside the UPDATE; SQLite runs
the same conditional UPDATE inside ``BEGIN IMMEDIATE`` (one writer at a time). Either way a
job is handed to exactly one worker; a worker that finds zero rows simply has nothing to do.
A running job whose lease has expired (its worker died) is claimable again.
"""

from __future__ import annotations

import datetime as dt
from typing import Any

from sqlalchemy import and_, or_, select, text, update
from sqlalchemy.orm import Session

from posefix.db import utcnow
from posefix.jobs.models import Job, JobStatus


def enqueue(
    session: Session, kind: str, payload: dict[str, Any], *, run_id: int | None = None,
    created_by: int | None = None, max_attempts: int = 5, priority: int = 0,
) -> Job:
    """Add a job in the caller's transaction: it exists only if that transaction commits."""
    now = utcnow()
    job = Job(
        kind=kind, payload=payload, status=JobStatus.queued, priority=priority, attempts=0,
        max_attempts=max_attempts, run_after=now, run_id=run_id, created_by=created_by,
        created_at=now, updated_at=now, progress=0.0,
    )
    session.add(job)
    session.flush()
    return job


def get(session: Session, job_id: int) -> Job | None:
    return session.get(Job, job_id)


_CLAIM_PG = text(
    """
    UPDATE jobs SET status = 'running', attempts = attempts + 1, worker_id = :worker,
           lease_expires_at = :lease, updated_at = :now
    WHERE id = (
        SELECT id FROM jobs
        WHERE (status = 'queued' AND run_after <= :now)
           OR (status = 'running' AND lease_expires_at < :now AND attempts < max_attempts)
        ORDER BY priority DESC, id
        FOR UPDATE SKIP LOCKED
        LIMIT 1
    )
    RETURNING id
    """
)

_CLAIM_SQLITE = text(
    """
    UPDATE jobs SET status = 'running', attempts = attempts + 1, worker_id = :worker,
           lease_expires_at = :lease, updated_at = :now
    WHERE id = (
        SELECT id FROM jobs
        WHERE (status = 'queued' AND run_after <= :now)
           OR (status = 'running' AND lease_expires_at < :now AND attempts < max_attempts)
        ORDER BY priority DESC, id
        LIMIT 1
    )
    RETURNING id
    """
)


def live_for_run(session: Session, kind: str, run_id: int, limit: int = 20) -> list[Job]:
    """The newest jobs of ``kind`` for a run that are not dead, newest first."""
    stmt = (select(Job).where(Job.kind == kind, Job.run_id == run_id, Job.status != JobStatus.dead)
            .order_by(Job.id.desc()).limit(limit))
    return list(session.scalars(stmt))


def _ts(session: Session, value: dt.datetime) -> Any:
    # Raw SQL bypasses the UTCDateTime type: SQLite compares text, so bind the same
    # format SQLAlchemy stores ("YYYY-MM-DD HH:MM:SS.ffffff"); PostgreSQL takes datetimes.
    if session.get_bind().dialect.name == "sqlite":
        return value.astimezone(dt.UTC).replace(tzinfo=None).strftime("%Y-%m-%d %H:%M:%S.%f")
    return value


def claim(session: Session, worker_id: str, lease_s: float) -> int | None:
    now = utcnow()
    stmt = _CLAIM_SQLITE if session.get_bind().dialect.name == "sqlite" else _CLAIM_PG
    row = session.execute(
        stmt,
        {"worker": worker_id, "lease": _ts(session, now + dt.timedelta(seconds=lease_s)), "now": _ts(session, now)},
    ).first()
    return None if row is None else int(row[0])


def bury_expired(session: Session) -> int:
    """Running jobs whose lease expired after their last allowed attempt become dead."""
    now = utcnow()
    res = session.execute(
        update(Job)
        .where(Job.status == JobStatus.running, Job.lease_expires_at < now, Job.attempts >= Job.max_attempts)
        .values(status=JobStatus.dead, last_error="lease expired on the last attempt", updated_at=now, finished_at=now)
    )
    return res.rowcount or 0


def heartbeat(session: Session, job_id: int, worker_id: str, lease_s: float, progress: float | None, message: str | None) -> bool:
    """Extend the lease (and record progress); False when this worker no longer holds it."""
    now = utcnow()
    values: dict[str, Any] = {"lease_expires_at": now + dt.timedelta(seconds=lease_s), "updated_at": now}
    if progress is not None:
        values["progress"] = float(min(max(progress, 0.0), 1.0))
    if message is not None:
        values["message"] = message[:255]
    res = session.execute(
        update(Job)
        .where(Job.id == job_id, Job.worker_id == worker_id, Job.status == JobStatus.running)
        .values(**values)
    )
    return (res.rowcount or 0) == 1


def succeed(session: Session, job_id: int, worker_id: str, result: dict[str, Any]) -> bool:
    now = utcnow()
    res = session.execute(
        update(Job)
        .where(Job.id == job_id, Job.worker_id == worker_id, Job.status == JobStatus.running)
        .values(status=JobStatus.succeeded, result=result, progress=1.0, message="done",
                updated_at=now, finished_at=now, lease_expires_at=None)
    )
    return (res.rowcount or 0) == 1


def fail(session: Session, job: Job, worker_id: str, error: str, backoff_s: float, *, permanent: bool) -> str:
    """Retry later with backoff, or bury after the last attempt (or a permanent error)."""
    now = utcnow()
    dead = permanent or job.attempts >= job.max_attempts
    values: dict[str, Any] = {"last_error": error[:4000], "updated_at": now, "lease_expires_at": None}
    if dead:
        values.update(status=JobStatus.dead, finished_at=now)
    else:
        values.update(status=JobStatus.queued, run_after=now + dt.timedelta(seconds=backoff_s))
    session.execute(
        update(Job)
        .where(Job.id == job.id, Job.worker_id == worker_id, Job.status == JobStatus.running)
        .values(**values)
    )
    return JobStatus.dead if dead else JobStatus.queued


def changed_since(session: Session, since: dt.datetime, job_ids: list[int] | None, run_ids_query: Any | None, user_id: int | None) -> list[Job]:
    stmt = select(Job).where(Job.updated_at > since)
    if job_ids is not None:
        stmt = stmt.where(Job.id.in_(job_ids))
    if run_ids_query is not None:
        stmt = stmt.where(or_(Job.run_id.in_(run_ids_query), and_(Job.run_id.is_(None), Job.created_by == user_id)))
    return list(session.scalars(stmt.order_by(Job.updated_at, Job.id).limit(500)))
