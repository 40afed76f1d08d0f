"""Tasks and gold runs: creation (idempotent by client token), visibility, cancellation, and
the qualification-test task a test gold run brings."""

from __future__ import annotations

import datetime as dt
import hashlib
import json
from typing import Any

from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.errors import Conflict, Forbidden, NotFound, Unprocessable
from posefix.runs import repository as runs_repo
from posefix.runs.models import Run, RunStatus
from posefix.tasks import repository as repo
from posefix.tasks.models import GoldRun, Task, TaskRun, TaskRunStatus, TaskStatus
from posefix.tasks.schemas import TaskCreate, TaskPublic, TaskRunPublic
from posefix.tasks.states import ensure_maintenance, move_task, slot, withdraw
from posefix.users.models import Role
from posefix.users.service import Principal

TOKEN_TTL = dt.timedelta(hours=24)


def _request_hash(body: TaskCreate) -> str:
    data = body.model_dump(mode="json", exclude={"client_token"})
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()


def create_task(session: Session, settings: Settings, principal: Principal, body: TaskCreate, now: dt.datetime,
                *, visible: Any) -> tuple[Task, bool]:
    """Create a task (or return the one made earlier with the same client token). (task, created)."""
    digest = _request_hash(body)
    if body.client_token:
        existing = repo.task_by_token(session, principal.user_id, body.client_token)
        if existing is not None:
            if existing.created_at + TOKEN_TTL > now:
                if existing.request_hash != digest:
                    raise Conflict("this client_token was used for a different task in the last 24 h",
                                   code="client_token_reused", extra={"task_id": existing.id})
                return existing, False
            existing.client_token = None  # the token's 24 h are over: it may name a new task
            session.flush()
    runs = repo.runs_by_id(session, body.run_ids)
    visible_ids = set(session.scalars(visible.where(Run.id.in_(body.run_ids))))
    missing = [r for r in body.run_ids if r not in runs or r not in visible_ids or runs[r].status == RunStatus.deleted]
    if missing:
        raise Unprocessable(f"run(s) {', '.join(map(str, missing))} do not exist or are not yours",
                            code="unknown_runs", extra={"field": "run_ids", "run_ids": missing})
    gold = repo.gold_run_ids(session, body.run_ids)
    task = Task(
        title=body.title, instructions=body.instructions, reward_cents=body.reward_cents, currency=body.currency,
        assignments_per_run=body.assignments_per_run, lease_s=body.lease_s, lifetime_s=body.lifetime_s,
        auto_approval_delay_s=body.auto_approval_delay_s, priority=body.priority,
        max_active_leases=body.max_active_leases, rules=body.rules.model_dump() if body.rules else None,
        requirements=[r.model_dump() for r in body.requirements], conflict_distance_m=body.conflict_distance_m,
        conflict_keyframes=body.conflict_keyframes, conflict_edit_m=body.conflict_edit_m,
        conflict_policy=body.conflict_policy, max_extra_assignments=body.max_extra_assignments,
        status=TaskStatus.assignable, requester_id=principal.user_id, client_token=body.client_token,
        request_hash=digest, created_at=now, updated_at=now, expires_at=now + dt.timedelta(seconds=body.lifetime_s),
    )
    try:
        with session.begin_nested():
            session.add(task)
            session.flush()
    except IntegrityError:
        # another request with the same token won the race: answer with its task
        existing = repo.task_by_token(session, principal.user_id, body.client_token or "")
        if existing is None:
            raise
        return existing, False
    repo.record(session, task_id=task.id, entity="task", to_status=TaskStatus.assignable, actor_id=principal.user_id,
                at=now, reason="created")
    slots = []
    for run_id in body.run_ids:
        run = runs[run_id]
        tr = TaskRun(
            task_id=task.id, run_id=run_id, is_gold=run_id in gold, wanted=body.assignments_per_run,
            centre_lon=(run.min_lon + run.max_lon) / 2, centre_lat=(run.min_lat + run.max_lat) / 2,
            base_revision=run.revision, status=TaskRunStatus.open, updated_at=now,
        )
        session.add(tr)
        session.flush()
        slots += [slot(tr, now) for _ in range(body.assignments_per_run)]
        if task.rules is not None and dict(run.rules) != task.rules:
            runs_repo.record(session, run, principal.user_id, "rules_set", task_id=task.id,
                             detail={"from": dict(run.rules), "to": task.rules})
            run.rules = dict(task.rules)
    repo.add_open_slots(session, slots)
    ensure_maintenance(session)
    session.flush()
    return task, True


def get_task(session: Session, principal: Principal, task_id: int) -> Task:
    task = session.get(Task, task_id)
    if task is None or not can_see_task(principal, task):
        raise NotFound(f"task {task_id} not found", code="task_not_found")
    return task


def get_offered_task(session: Session, principal: Principal, task_id: int, now: dt.datetime) -> Task:
    """A task whose eligibility the caller may ask: one they may see, one the queue offers
    (its ineligible list names live tasks), or one they held an assignment on. Any other
    answers as absent, so the route tells nothing of tasks that are not offered."""
    task = session.get(Task, task_id)
    if task is None or task.is_test or not (
            can_see_task(principal, task) or repo.is_offered(task, now)
            or repo.has_assignment_on(session, principal.user_id, task.id)):
        raise NotFound(f"task {task_id} not found", code="task_not_found")
    return task


def can_see_task(principal: Principal, task: Task) -> bool:
    if principal.role in (Role.admin, Role.reviewer):
        return True
    return principal.role == Role.client and task.requester_id == principal.user_id


def task_public(session: Session, task: Task, *, with_runs: bool = True) -> TaskPublic:
    counts = repo.counts_by_status(session, [task.id])[task.id]
    runs: list[TaskRunPublic] = []
    if with_runs:
        per_run = repo.run_counts(session, task.id)
        runs = [TaskRunPublic(id=tr.id, run_id=tr.run_id, wanted=tr.wanted, status=TaskRunStatus(tr.status),
                              conflicts=tr.conflicts, merged_revision=tr.merged_revision, counts=per_run.get(tr.id, {}))
                for tr in repo.task_runs(session, task.id)]
    data = {f: getattr(task, f) for f in TaskPublic.model_fields if f not in ("counts", "runs")}
    return TaskPublic(**data, counts=counts, runs=runs)


def cancel_task(session: Session, principal: Principal, task: Task, now: dt.datetime) -> None:
    if principal.role != Role.admin and task.requester_id != principal.user_id:
        raise Forbidden("only the requester or an admin may cancel a task", code="not_requester")
    if not move_task(session, task, TaskStatus.cancelled, now, actor_id=principal.user_id, reason="cancelled"):
        raise Conflict(f"task {task.id} is {task.status}; only an assignable or in-progress task can be cancelled",
                       code="task_not_cancellable")
    withdraw(session, task, now, principal.user_id)


def add_gold_run(session: Session, settings: Settings, principal: Principal, run: Run, truth_rel: str, *, is_test: bool,
                 pass_error_m: float, now: dt.datetime) -> GoldRun:
    gold = session.get(GoldRun, run.id)
    if gold is None:
        gold = GoldRun(run_id=run.id)
        session.add(gold)
    gold.truth_file, gold.is_test, gold.pass_error_m = truth_rel, is_test, pass_error_m
    gold.created_by, gold.created_at = principal.user_id, now
    session.flush()
    if is_test:
        task = Task(
            title="Qualification test", instructions="Correct this run as carefully as you can: it is scored before your first work.",
            assignments_per_run=1, lease_s=3600, lifetime_s=10 * 365 * 86400, auto_approval_delay_s=0, priority=0,
            max_active_leases=1, rules=None, requirements=[], conflict_distance_m=5.0, conflict_keyframes=3,
            conflict_edit_m=5.0, conflict_policy="flag", max_extra_assignments=0, is_test=True,
            status=TaskStatus.in_progress, requester_id=principal.user_id, created_at=now, updated_at=now,
            expires_at=now + dt.timedelta(days=3650),
        )
        session.add(task)
        session.flush()
        session.add(TaskRun(task_id=task.id, run_id=run.id, is_gold=True, wanted=0, centre_lon=(run.min_lon + run.max_lon) / 2,
                            centre_lat=(run.min_lat + run.max_lat) / 2, base_revision=run.revision, updated_at=now))
        repo.record(session, task_id=task.id, entity="task", to_status=task.status, actor_id=principal.user_id, at=now,
                    reason="qualification test created")
        session.flush()
    return gold
