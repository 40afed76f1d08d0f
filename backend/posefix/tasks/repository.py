"""Every query of the tasks domain. The lease is one conditional UPDATE ... RETURNING.

PostgreSQL: the UPDATE picks its row with a sub-select ``FOR UPDATE OF assignments SKIP
LOCKED`` (concurrent operators skip each other's rows instead of queueing on them). SQLite:
the same statement inside ``BEGIN IMMEDIATE`` (one writer at a time). Zero rows back means
nothing is available; nobody checks first and updates later.
"""

from __future__ import annotations

import datetime as dt
from typing import Any

from sqlalchemy import case, func, insert, or_, select, update
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.orm import Session, aliased

from posefix.runs.models import Run
from posefix.tasks.models import (
    Assignment, AssignmentStatus, GoldRun, OperatorProfile, OperatorQualification, Task, TaskEvent, TaskRun,
    TaskRunStatus, TaskStatus,
)
from posefix.users.models import Role, User

ACTIVE_TASK = (TaskStatus.assignable, TaskStatus.in_progress)
HELD = (AssignmentStatus.accepted,)
SUBMITTED_OR_BETTER = (AssignmentStatus.submitted, AssignmentStatus.approved)


def is_pg(session: Session) -> bool:
    return session.get_bind().dialect.name == "postgresql"


# -- history ---------------------------------------------------------------------------

def record(
    session: Session, *, task_id: int, entity: str, to_status: str, from_status: str | None = None,
    assignment_id: int | None = None, task_run_id: int | None = None, actor_id: int | None = None,
    at: dt.datetime, reason: str | None = None, detail: dict[str, Any] | None = None,
) -> None:
    session.add(TaskEvent(
        task_id=task_id, entity=entity, from_status=from_status, to_status=to_status, assignment_id=assignment_id,
        task_run_id=task_run_id, actor_id=actor_id, at=at, reason=reason, detail=detail,
    ))


def history(session: Session, task_id: int, after_id: int = 0, limit: int = 1000) -> list[TaskEvent]:
    stmt = select(TaskEvent).where(TaskEvent.task_id == task_id, TaskEvent.id > after_id).order_by(TaskEvent.id).limit(limit)
    return list(session.scalars(stmt))


# -- tasks -----------------------------------------------------------------------------

def task_by_token(session: Session, requester_id: int, token: str) -> Task | None:
    return session.scalars(select(Task).where(Task.requester_id == requester_id, Task.client_token == token)).one_or_none()


def forget_tokens(session: Session, older_than: dt.datetime) -> int:
    res = session.execute(
        update(Task).where(Task.client_token.is_not(None), Task.created_at < older_than).values(client_token=None)
    )
    return res.rowcount or 0


def runs_by_id(session: Session, run_ids: list[int]) -> dict[int, Run]:
    return {r.id: r for r in session.scalars(select(Run).where(Run.id.in_(run_ids)))}


def gold_run_ids(session: Session, run_ids: list[int]) -> set[int]:
    return set(session.scalars(select(GoldRun.run_id).where(GoldRun.run_id.in_(run_ids))))


def add_open_slots(session: Session, rows: list[dict[str, Any]]) -> None:
    if rows:
        session.execute(insert(Assignment), rows)


def list_tasks(session: Session, requester_id: int | None, status: str | None, limit: int, offset: int) -> tuple[list[Task], int]:
    stmt = select(Task).where(Task.is_test.is_(False))
    if requester_id is not None:
        stmt = stmt.where(Task.requester_id == requester_id)
    if status:
        stmt = stmt.where(Task.status == status)
    total = session.scalar(select(func.count()).select_from(stmt.subquery())) or 0
    rows = session.scalars(stmt.order_by(Task.id.desc()).limit(limit).offset(offset))
    return list(rows), int(total)


def counts_by_status(session: Session, task_ids: list[int]) -> dict[int, dict[str, int]]:
    out: dict[int, dict[str, int]] = {t: {} for t in task_ids}
    if not task_ids:
        return out
    stmt = select(Assignment.task_id, Assignment.status, func.count()).where(Assignment.task_id.in_(task_ids)).group_by(
        Assignment.task_id, Assignment.status)
    for tid, status, n in session.execute(stmt):
        out[int(tid)][str(status)] = int(n)
    return out


def run_counts(session: Session, task_id: int) -> dict[int, dict[str, int]]:
    out: dict[int, dict[str, int]] = {}
    stmt = select(Assignment.task_run_id, Assignment.status, func.count()).where(Assignment.task_id == task_id).group_by(
        Assignment.task_run_id, Assignment.status)
    for trid, status, n in session.execute(stmt):
        out.setdefault(int(trid), {})[str(status)] = int(n)
    return out


def task_runs(session: Session, task_id: int) -> list[TaskRun]:
    return list(session.scalars(select(TaskRun).where(TaskRun.task_id == task_id).order_by(TaskRun.id)))


def task_run_of_batch(session: Session, batch_id: int) -> TaskRun | None:
    return session.scalars(select(TaskRun).where(TaskRun.merge_batch_id == batch_id).limit(1)).first()


def merging_runs(session: Session) -> list[TaskRun]:
    return list(session.scalars(select(TaskRun).where(TaskRun.status == TaskRunStatus.merging).order_by(TaskRun.id)))


def set_task_status(session: Session, task: Task, to: TaskStatus, *, allowed_from: tuple[str, ...], at: dt.datetime,
                    actor_id: int | None = None, reason: str | None = None, skip_locked: bool = False) -> bool:
    """Conditional transition: only from the given states; recorded when it happens.

    ``skip_locked``: on PostgreSQL, give up at once when another transaction holds the row
    (the first lease of a task: fifty operators must not queue on one row lock).
    """
    before = task.status
    target = Task.id == task.id
    if skip_locked and is_pg(session):
        target = Task.id == select(Task.id).where(Task.id == task.id).with_for_update(skip_locked=True).scalar_subquery()
    res = session.execute(
        update(Task).where(target, Task.status.in_(allowed_from)).values(status=to, updated_at=at),
        execution_options={"synchronize_session": False},
    )
    if (res.rowcount or 0) != 1:
        return False
    record(session, task_id=task.id, entity="task", from_status=before, to_status=to, actor_id=actor_id, at=at, reason=reason)
    session.refresh(task)
    return True


# -- queue -----------------------------------------------------------------------------

def lock_operator(session: Session, user_id: int, at: dt.datetime) -> None:
    """Serialise one operator's queue requests: their profile row is the lock. One upsert
    creates the row or updates it, and on PostgreSQL ``ON CONFLICT DO UPDATE`` holds the
    row lock to the end of the transaction (SQLite: ``BEGIN IMMEDIATE`` serialises anyway)."""
    table = OperatorProfile.__table__
    stmt = (pg_insert(table) if is_pg(session) else sqlite_insert(table)).values(
        user_id=user_id, updated_at=at, last_request_at=at,
    )
    session.execute(stmt.on_conflict_do_update(index_elements=["user_id"], set_={"last_request_at": at}))


def active_leases(session: Session, user_id: int) -> int:
    return int(session.scalar(
        select(func.count()).select_from(Assignment).where(Assignment.operator_id == user_id, Assignment.status == AssignmentStatus.accepted)
    ) or 0)


def is_offered(task: Task, at: dt.datetime) -> bool:
    """The task is live: the queue may name it to any operator."""
    return task.status in ACTIVE_TASK and not task.is_test and task.expires_at > at


def has_assignment_on(session: Session, user_id: int, task_id: int) -> bool:
    stmt = select(Assignment.id).where(Assignment.task_id == task_id, Assignment.operator_id == user_id).limit(1)
    return session.scalar(stmt) is not None


def candidate_tasks(session: Session, user_id: int, at: dt.datetime) -> list[Task]:
    """Live tasks with an open slot on a run this operator has never had."""
    mine = aliased(Assignment)
    open_slot = (
        select(Assignment.id).where(
            Assignment.task_id == Task.id, Assignment.status == AssignmentStatus.open,
            Assignment.run_id.not_in(select(mine.run_id).where(mine.operator_id == user_id)),
        ).exists()
    )
    stmt = select(Task).where(
        Task.status.in_(ACTIVE_TASK), Task.expires_at > at, Task.is_test.is_(False), open_slot,
    ).order_by(Task.priority.desc(), Task.id).limit(500)
    return list(session.scalars(stmt))


def task_run_centres(session: Session, task_ids: list[int]) -> list[tuple[int, int, float, float]]:
    stmt = select(TaskRun.id, TaskRun.task_id, TaskRun.centre_lon, TaskRun.centre_lat).where(
        TaskRun.task_id.in_(task_ids), TaskRun.status == TaskRunStatus.open)
    return [(int(a), int(b), float(c), float(d)) for a, b, c, d in session.execute(stmt)]


def lease_one(
    session: Session, user_id: int, at: dt.datetime, *, task_ids: list[int], task_run_ids: list[int],
    deadlines: dict[int, dt.datetime], active: int,
) -> tuple[int, int] | None:
    """Take the highest-priority open slot the operator may have, in one UPDATE ... RETURNING.

    ``task_ids``: tasks whose every run the operator may take; ``task_run_ids``: single runs
    (tasks with a home-area requirement). Returns (assignment id, task id) or None.
    """
    if not task_ids and not task_run_ids:
        return None
    mine = aliased(Assignment)
    where = [
        Assignment.status == AssignmentStatus.open,
        Task.status.in_(ACTIVE_TASK),
        Task.expires_at > at,
        Task.max_active_leases > active,
        Assignment.run_id.not_in(select(mine.run_id).where(mine.operator_id == user_id)),
    ]
    scope = []
    if task_ids:
        scope.append(Assignment.task_id.in_(task_ids))
    if task_run_ids:
        scope.append(Assignment.task_run_id.in_(task_run_ids))
    pick = (
        select(Assignment.id).join(Task, Task.id == Assignment.task_id).where(*where, or_(*scope))
        .order_by(Task.priority.desc(), Task.id, Assignment.id).limit(1)
    )
    if is_pg(session):
        pick = pick.with_for_update(of=Assignment, skip_locked=True)
    base = select(Run.revision).where(Run.id == Assignment.run_id).scalar_subquery()
    stmt = (
        update(Assignment)
        .where(Assignment.id == pick.scalar_subquery(), Assignment.status == AssignmentStatus.open)
        .values(
            status=AssignmentStatus.accepted, operator_id=user_id, leased_at=at, updated_at=at, base_revision=base,
            lease_expires_at=case(deadlines, value=Assignment.task_id),
        )
        .returning(Assignment.id, Assignment.task_id)
    )
    row = session.execute(stmt, execution_options={"synchronize_session": False}).first()
    return None if row is None else (int(row[0]), int(row[1]))


def get_assignment(session: Session, assignment_id: int, *, for_update: bool = False) -> Assignment | None:
    stmt = select(Assignment).where(Assignment.id == assignment_id)
    if for_update and is_pg(session):
        stmt = stmt.with_for_update()
    return session.scalars(stmt).one_or_none()


def transition_assignment(
    session: Session, assignment_id: int, *, from_status: tuple[str, ...], values: dict[str, Any],
    extra_where: list[Any] | None = None,
) -> bool:
    """Conditional UPDATE of one assignment; False when it was not in an allowed state."""
    res = session.execute(
        update(Assignment).where(Assignment.id == assignment_id, Assignment.status.in_(from_status), *(extra_where or []))
        .values(**values), execution_options={"synchronize_session": False},
    )
    return (res.rowcount or 0) == 1


def my_assignments(session: Session, user_id: int, statuses: tuple[str, ...] | None, limit: int) -> list[Assignment]:
    stmt = select(Assignment).where(Assignment.operator_id == user_id)
    if statuses:
        stmt = stmt.where(Assignment.status.in_(statuses))
    return list(session.scalars(stmt.order_by(Assignment.id.desc()).limit(limit)))


def expired_leases(session: Session, at: dt.datetime, limit: int = 500) -> list[Assignment]:
    stmt = select(Assignment).where(Assignment.status == AssignmentStatus.accepted, Assignment.lease_expires_at <= at)
    return list(session.scalars(stmt.order_by(Assignment.id).limit(limit)))


def due_for_auto_approval(session: Session, at: dt.datetime, limit: int = 500) -> list[Assignment]:
    """Due work on runs whose consensus is in and agreed (work held for review has no due time)."""
    stmt = (
        select(Assignment).join(TaskRun, TaskRun.id == Assignment.task_run_id)
        .where(Assignment.status == AssignmentStatus.submitted, Assignment.auto_approve_at <= at,
               Assignment.evaluated_at.is_not(None), TaskRun.status == TaskRunStatus.agreed)
        .order_by(Assignment.id).limit(limit)
    )
    return list(session.scalars(stmt))


def overdue_tasks(session: Session, at: dt.datetime) -> list[Task]:
    return list(session.scalars(select(Task).where(Task.status.in_(ACTIVE_TASK), Task.expires_at <= at)))


def run_assignments(session: Session, task_run_id: int) -> list[Assignment]:
    return list(session.scalars(select(Assignment).where(Assignment.task_run_id == task_run_id).order_by(Assignment.id)))


# -- operators ---------------------------------------------------------------------------

def usernames(session: Session, user_ids: list[int]) -> dict[int, str]:
    return {u.id: u.username for u in session.scalars(select(User).where(User.id.in_(user_ids)))}


def operators(session: Session, user_ids: list[int] | None = None) -> list[User]:
    """Every operator by name; with ``user_ids``, those users whatever their role (anyone may take work)."""
    stmt = select(User).where(User.role == Role.operator) if user_ids is None else select(User).where(User.id.in_(user_ids))
    return list(session.scalars(stmt.order_by(User.username)))


def gold_runs(session: Session) -> list[GoldRun]:
    return list(session.scalars(select(GoldRun).order_by(GoldRun.run_id)))


def profile(session: Session, user_id: int) -> OperatorProfile | None:
    return session.get(OperatorProfile, user_id)


def qualifications(session: Session, user_id: int) -> list[OperatorQualification]:
    return list(session.scalars(select(OperatorQualification).where(OperatorQualification.user_id == user_id)
                                .order_by(OperatorQualification.name)))


def operator_numbers(session: Session, user_ids: list[int] | None = None) -> dict[int, dict[str, Any]]:
    """Per operator: counts by status, mean gold error, mean distance to consensus, lease time."""
    work_s = func.sum(
        case((Assignment.submitted_at.is_not(None), func.coalesce(
            _seconds_between(session, Assignment.leased_at, Assignment.submitted_at), 0.0)), else_=0.0)
    )
    stmt = (
        select(
            Assignment.operator_id,
            func.count().filter(Assignment.status.in_((AssignmentStatus.submitted, AssignmentStatus.approved, AssignmentStatus.rejected))),
            func.count().filter(Assignment.status == AssignmentStatus.approved),
            func.count().filter(Assignment.status == AssignmentStatus.rejected),
            func.count().filter(Assignment.status == AssignmentStatus.returned),
            func.count().filter(Assignment.status == AssignmentStatus.expired),
            func.avg(Assignment.gold_error_m),
            func.count(Assignment.gold_error_m),
            func.avg(Assignment.consensus_error_m),
            work_s,
        )
        .where(Assignment.operator_id.is_not(None))
        .group_by(Assignment.operator_id)
    )
    if user_ids is not None:
        stmt = stmt.where(Assignment.operator_id.in_(user_ids))
    out = {}
    for uid, sub, appr, rej, ret, exp, acc, n_gold, agree, work in session.execute(stmt):
        out[int(uid)] = {
            "submitted": int(sub), "approved": int(appr), "rejected": int(rej), "returned": int(ret), "expired": int(exp),
            "accuracy_m": None if acc is None else float(acc), "gold_scored": int(n_gold),
            "agreement_m": None if agree is None else float(agree), "work_s": float(work or 0.0),
        }
    return out


def _seconds_between(session: Session, a: Any, b: Any) -> Any:
    if is_pg(session):
        return func.extract("epoch", b - a)
    return (func.julianday(b) - func.julianday(a)) * 86400.0


def approved_count(session: Session, user_id: int) -> int:
    return int(session.scalar(select(func.count()).select_from(Assignment).where(
        Assignment.operator_id == user_id, Assignment.status == AssignmentStatus.approved, Assignment.task_id.in_(
            select(Task.id).where(Task.is_test.is_(False))))) or 0)


def gold_accuracy(session: Session, user_id: int) -> tuple[float | None, int]:
    row = session.execute(select(func.avg(Assignment.gold_error_m), func.count(Assignment.gold_error_m)).where(
        Assignment.operator_id == user_id)).one()
    return (None if row[0] is None else float(row[0])), int(row[1])


def gold_accuracies(session: Session, user_ids: list[int]) -> dict[int, tuple[float, int]]:
    """Per operator with any gold score: (mean gold error in metres, gold runs scored)."""
    stmt = (select(Assignment.operator_id, func.avg(Assignment.gold_error_m), func.count(Assignment.gold_error_m))
            .where(Assignment.operator_id.in_(user_ids), Assignment.gold_error_m.is_not(None))
            .group_by(Assignment.operator_id))
    return {int(u): (float(a), int(n)) for u, a, n in session.execute(stmt)}


def evaluated_by_run(session: Session, task_id: int, max_runs: int) -> dict[int, list[Assignment]]:
    """The evaluated submissions (submitted, approved or rejected) of the task's most recent
    ``max_runs`` runs that have at least two, by task run."""
    done = (AssignmentStatus.submitted, AssignmentStatus.approved, AssignmentStatus.rejected)
    shared = (select(Assignment.task_run_id).where(Assignment.task_id == task_id, Assignment.status.in_(done),
                                                   Assignment.evaluated_at.is_not(None))
              .group_by(Assignment.task_run_id).having(func.count() >= 2)
              .order_by(Assignment.task_run_id.desc()).limit(max_runs))
    trids = list(session.scalars(shared))
    out: dict[int, list[Assignment]] = {t: [] for t in sorted(trids)}
    if trids:
        stmt = select(Assignment).where(Assignment.task_run_id.in_(trids), Assignment.status.in_(done),
                                        Assignment.evaluated_at.is_not(None)).order_by(Assignment.id)
        for a in session.scalars(stmt):
            out[a.task_run_id].append(a)
    return out


def open_gold_task_runs(session: Session, task_ids: list[int]) -> list[int]:
    stmt = select(TaskRun.id).where(TaskRun.task_id.in_(task_ids), TaskRun.is_gold.is_(True), TaskRun.status == TaskRunStatus.open)
    return list(session.scalars(stmt))


def gold_pending(session: Session, user_id: int) -> bool:
    """Does the operator hold, or wait for the score of, work on a gold run?"""
    stmt = (select(Assignment.id).join(TaskRun, TaskRun.id == Assignment.task_run_id)
            .where(Assignment.operator_id == user_id, TaskRun.is_gold.is_(True), Assignment.gold_error_m.is_(None),
                   Assignment.status.in_((AssignmentStatus.accepted, AssignmentStatus.submitted, AssignmentStatus.approved)))
            .limit(1))
    return session.scalar(stmt) is not None


def test_assignments(session: Session, user_id: int) -> list[Assignment]:
    stmt = select(Assignment).join(Task, Task.id == Assignment.task_id).where(
        Task.is_test.is_(True), Assignment.operator_id == user_id).order_by(Assignment.id)
    return list(session.scalars(stmt))


def test_task_slot(session: Session, user_id: int) -> tuple[Task, TaskRun] | None:
    """A live qualification-test task whose gold run this operator has never had."""
    mine = aliased(Assignment)
    stmt = (
        select(Task, TaskRun).join(TaskRun, TaskRun.task_id == Task.id)
        .where(Task.is_test.is_(True), Task.status.in_(ACTIVE_TASK),
               TaskRun.run_id.not_in(select(mine.run_id).where(mine.operator_id == user_id)))
        .order_by(Task.id, TaskRun.id).limit(1)
    )
    row = session.execute(stmt).first()
    return None if row is None else (row[0], row[1])


def review_queue(session: Session, reviewer_id: int, limit: int) -> list[tuple[TaskRun, Task, int]]:
    """Task runs with submitted work the reviewer did not do, conflicts first."""
    sub = (
        select(Assignment.task_run_id, func.count().label("n"))
        .where(Assignment.status == AssignmentStatus.submitted, Assignment.evaluated_at.is_not(None))
        .group_by(Assignment.task_run_id).subquery()
    )
    own = select(Assignment.task_run_id).where(Assignment.operator_id == reviewer_id)
    stmt = (
        select(TaskRun, Task, sub.c.n).join(sub, sub.c.task_run_id == TaskRun.id).join(Task, Task.id == TaskRun.task_id)
        .where(TaskRun.id.not_in(own), Task.is_test.is_(False), TaskRun.status.in_(
            (TaskRunStatus.open, TaskRunStatus.agreed, TaskRunStatus.conflict)))
        .order_by(case((TaskRun.status == TaskRunStatus.conflict, 0), else_=1), Task.priority.desc(), TaskRun.id)
        .limit(limit)
    )
    return [(tr, t, int(n)) for tr, t, n in session.execute(stmt)]


def statuses_of_run(session: Session, task_run_id: int) -> dict[str, int]:
    stmt = select(Assignment.status, func.count()).where(Assignment.task_run_id == task_run_id).group_by(Assignment.status)
    return {str(s): int(n) for s, n in session.execute(stmt)}


def remaining_open_runs(session: Session, task_id: int, statuses: tuple[str, ...]) -> int:
    return int(session.scalar(select(func.count()).select_from(TaskRun).where(
        TaskRun.task_id == task_id, TaskRun.status.in_(statuses))) or 0)


def withdraw_open(session: Session, task_id: int, at: dt.datetime) -> list[int]:
    ids = list(session.scalars(select(Assignment.id).where(Assignment.task_id == task_id, Assignment.status == AssignmentStatus.open)))
    if ids:
        session.execute(update(Assignment).where(Assignment.id.in_(ids), Assignment.status == AssignmentStatus.open)
                        .values(status=AssignmentStatus.withdrawn, updated_at=at), execution_options={"synchronize_session": False})
    return ids


def anything_timed(session: Session) -> bool:
    live = select(Task.id).where(Task.status.in_(ACTIVE_TASK), Task.is_test.is_(False)).limit(1)
    held = select(Assignment.id).where(Assignment.status.in_((AssignmentStatus.accepted, AssignmentStatus.submitted))).limit(1)
    return session.scalar(live) is not None or session.scalar(held) is not None


def pending_job(session: Session, kind: str, run_id: int | None = None) -> bool:
    """Is a job of ``kind`` (for ``run_id``, when given) queued or running?"""
    from posefix.jobs.models import Job, JobStatus

    stmt = select(Job.id).where(Job.kind == kind, Job.status.in_((JobStatus.queued, JobStatus.running)))
    if run_id is not None:
        stmt = stmt.where(Job.run_id == run_id)
    return session.scalar(stmt.limit(1)) is not None

