"""Maintenance (a periodic worker job): expired leases back to the pool, due work
auto-approved, overdue tasks expired, old client tokens forgotten."""

from __future__ import annotations

import datetime as dt

from sqlalchemy.orm import Session

from posefix.tasks import repository as repo
from posefix.tasks.agreement import update_consensus
from posefix.tasks.lifecycle import TOKEN_TTL
from posefix.tasks.merge import maybe_merge, sweep_dead_merges
from posefix.tasks.models import Assignment, AssignmentStatus, TaskRun, TaskStatus
from posefix.tasks.states import move_assignment, move_task, replace_slot, withdraw


def needs_maintenance(session: Session) -> bool:
    """Is there a live task, a held lease or submitted work (things that time out)?"""
    return repo.anything_timed(session)


def maintain(session: Session, now: dt.datetime) -> dict[str, int]:
    """Return expired leases to the pool, auto-approve due work, expire old tasks, forget old tokens."""
    expired = 0
    for a in repo.expired_leases(session, now):
        if move_assignment(session, a, AssignmentStatus.expired, now, actor_id=None, reason="lease expired",
                           extra_where=[Assignment.lease_expires_at <= now]):
            replace_slot(session, a, now)
            expired += 1
    approved = 0
    for a in repo.due_for_auto_approval(session, now):
        if move_assignment(session, a, AssignmentStatus.approved, now, actor_id=None, reason="auto-approved",
                           values={"reviewed_at": now, "feedback": "approved automatically after the review delay"}):
            approved += 1
            tr = session.get(TaskRun, a.task_run_id)
            assert tr is not None
            maybe_merge(session, tr, now, actor_id=None)
    ended = 0
    for task in repo.overdue_tasks(session, now):
        if move_task(session, task, TaskStatus.expired, now, reason="lifetime over"):
            withdraw(session, task, now, None)
            # work already submitted on runs that will get no more still goes to review
            for tr in repo.task_runs(session, task.id):
                update_consensus(session, tr.id, now)
            ended += 1
    forgotten = repo.forget_tokens(session, now - TOKEN_TTL)
    failed = sweep_dead_merges(session, now)
    return {"leases_expired": expired, "auto_approved": approved, "tasks_expired": ended, "tokens_forgotten": forgotten,
            "merges_failed": failed}
