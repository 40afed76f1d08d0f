"""Business rules of tasks: creation (idempotent), the queue, leases, submission, review,
consensus and merge, operator qualification and statistics.

State machines (every transition is a conditional UPDATE and a ``TaskEvent`` row):

    task:        assignable -> in_progress -> reviewable -> done
                 assignable | in_progress -> expired | cancelled;  reviewable -> in_progress (extra slot)
    assignment:  open -> accepted -> submitted -> approved | rejected
                 accepted -> returned | expired (a fresh open slot replaces it);  open -> withdrawn

Services never commit: the request or the worker job does. ``now`` is passed in (the
domain's clock, ``posefix.tasks.clock``), so tests can move time.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
from collections.abc import Callable
from typing import Any

import numpy as np
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.core import geodesy
from posefix.edits.schemas import MoveIn
from posefix.errors import Conflict, Forbidden, Gone, NotFound, Unprocessable
from posefix.jobs import repository as jobs
from posefix.runs import correction
from posefix.runs import repository as runs_repo
from posefix.runs.models import Run, RunStatus
from posefix.tasks import consensus
from posefix.tasks import qualification as qual
from posefix.tasks import repository as repo
from posefix.tasks.models import (
    Assignment, AssignmentStatus, GoldRun, OperatorQualification, Task, TaskRun, TaskRunStatus, TaskStatus,
)
from posefix.tasks.schemas import (
    AssignmentPublic, HomeAreaIn, SubmitIn, TaskBrief, TaskCreate, TaskPublic, TaskRunPublic,
)
from posefix.users.models import Role, User
from posefix.users.service import Principal

EVALUATE_JOB = "tasks.evaluate"
MERGE_JOB = "tasks.merge"
MAINTAIN_JOB = "tasks.maintain"
TOKEN_TTL = dt.timedelta(hours=24)
TEST_QUALIFICATION = "qualification_test"
MAINTAIN_EVERY_S = 5.0

TASK_TRANSITIONS: dict[str, set[str]] = {
    TaskStatus.assignable: {TaskStatus.in_progress, TaskStatus.expired, TaskStatus.cancelled},
    TaskStatus.in_progress: {TaskStatus.reviewable, TaskStatus.expired, TaskStatus.cancelled},
    TaskStatus.reviewable: {TaskStatus.done, TaskStatus.in_progress},
    TaskStatus.done: set(), TaskStatus.expired: set(), TaskStatus.cancelled: set(),
}
ASSIGNMENT_TRANSITIONS: dict[str, set[str]] = {
    AssignmentStatus.open: {AssignmentStatus.accepted, AssignmentStatus.withdrawn},
    AssignmentStatus.accepted: {AssignmentStatus.submitted, AssignmentStatus.returned, AssignmentStatus.expired},
    AssignmentStatus.submitted: {AssignmentStatus.approved, AssignmentStatus.rejected},
    AssignmentStatus.approved: set(), AssignmentStatus.rejected: set(), AssignmentStatus.returned: set(),
    AssignmentStatus.expired: set(), AssignmentStatus.withdrawn: set(),
}


def _from_states(table: dict[str, set[str]], to: str) -> tuple[str, ...]:
    """Every state allowed to move to ``to`` (the machine, read backwards)."""
    return tuple(s for s, nxt in table.items() if to in nxt)


def move_task(session: Session, task: Task, to: TaskStatus, at: dt.datetime, *, actor_id: int | None = None,
              reason: str | None = None, skip_locked: bool = False) -> bool:
    return repo.set_task_status(session, task, to, allowed_from=_from_states(TASK_TRANSITIONS, to), at=at,
                                actor_id=actor_id, reason=reason, skip_locked=skip_locked)


def move_assignment(
    session: Session, a: Assignment, to: AssignmentStatus, at: dt.datetime, *, actor_id: int | None,
    reason: str | None = None, values: dict[str, Any] | None = None, extra_where: list[Any] | None = None,
    detail: dict[str, Any] | None = None,
) -> bool:
    allowed = _from_states(ASSIGNMENT_TRANSITIONS, to)
    before = a.status
    ok = repo.transition_assignment(session, a.id, from_status=allowed, extra_where=extra_where,
                                    values={"status": to, "updated_at": at, **(values or {})})
    if ok:
        repo.record(session, task_id=a.task_id, entity="assignment", assignment_id=a.id, task_run_id=a.task_run_id,
                    from_status=before, to_status=to, actor_id=actor_id, at=at, reason=reason, detail=detail)
        session.refresh(a)
    return ok


# -- tasks -------------------------------------------------------------------------------------

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
        slots += [_slot(tr, now) for _ in range(body.assignments_per_run)]
        if task.rules is not None and dict(run.rules) != task.rules:
            runs_repo.record(session, run, principal.user_id, "rules_set", task_id=task.id,
                             detail={"from": dict(run.rules), "to": task.rules})
            run.rules = dict(task.rules)
    repo.add_open_slots(session, slots)
    ensure_maintenance(session)
    session.flush()
    return task, True


def _slot(tr: TaskRun, now: dt.datetime) -> dict[str, Any]:
    return {"task_id": tr.task_id, "task_run_id": tr.id, "run_id": tr.run_id, "status": AssignmentStatus.open,
            "created_at": now, "updated_at": now}


def ensure_maintenance(session: Session) -> None:
    """Keep one periodic maintenance job queued (lease expiry, auto-approval, task expiry)."""
    if not repo.pending_job(session, MAINTAIN_JOB):
        jobs.enqueue(session, MAINTAIN_JOB, {}, max_attempts=1000)


def needs_maintenance(session: Session) -> bool:
    """Is there a live task, a held lease or submitted work (things that time out)?"""
    return repo.anything_timed(session)


def get_task(session: Session, principal: Principal, task_id: int) -> Task:
    task = session.get(Task, task_id)
    if task is None or not can_see_task(principal, task):
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
    _withdraw(session, task, now, principal.user_id)


def _withdraw(session: Session, task: Task, now: dt.datetime, actor_id: int | None) -> None:
    for aid in repo.withdraw_open(session, task.id, now):
        repo.record(session, task_id=task.id, entity="assignment", assignment_id=aid, from_status=AssignmentStatus.open,
                    to_status=AssignmentStatus.withdrawn, actor_id=actor_id, at=now, reason=f"task {task.status}")


# -- qualification -----------------------------------------------------------------------------

def operator_facts(session: Session, user_id: int) -> qual.OperatorFacts:
    prof = repo.profile(session, user_id)
    home = qual.HomeArea() if prof is None else qual.HomeArea(prof.home_lon, prof.home_lat, prof.home_radius_m, prof.home_polygon)
    granted = {q.name: q.value for q in repo.qualifications(session, user_id)}
    acc, n_gold = repo.gold_accuracy(session, user_id)
    tests = repo.test_assignments(session, user_id)
    status, detail = "not_taken", ""
    if TEST_QUALIFICATION in granted:
        status = "passed" if granted[TEST_QUALIFICATION] >= 1 else "failed"
        q = next(q for q in repo.qualifications(session, user_id) if q.name == TEST_QUALIFICATION)
        detail = (q.detail or {}).get("message", "")
    elif any(a.status in (AssignmentStatus.accepted, AssignmentStatus.submitted) for a in tests):
        status = "pending"
    return qual.OperatorFacts(approved_count=repo.approved_count(session, user_id), accuracy_m=acc, gold_scored=n_gold,
                              granted=granted, test_status=status, test_detail=detail, home=home)


def eligibility(session: Session, user_id: int, task: Task, facts: qual.OperatorFacts | None = None) -> list[str]:
    facts = facts or operator_facts(session, user_id)
    reasons = qual.check_requirements(task.requirements, facts)
    if not reasons and qual.needs_home_area(task.requirements):
        centres = repo.task_run_centres(session, [task.id])
        inside = qual.check_home_area(facts.home, np.array([c[2] for c in centres]), np.array([c[3] for c in centres]))
        if centres and not inside.any():
            reasons.append("none of this task's runs lies within your home area")
    return reasons


# -- the queue ---------------------------------------------------------------------------------

def next_assignment(session: Session, principal: Principal, now: dt.datetime) -> dict[str, Any]:
    """Lease the highest-priority assignment the operator qualifies for (or say why not)."""
    uid = principal.user_id
    repo.lock_operator(session, uid, now)
    active = repo.active_leases(session, uid)
    candidates = repo.candidate_tasks(session, uid, now)
    # the operator's facts cost several queries: only when some task asks for them
    facts = operator_facts(session, uid) if any(t.requirements for t in candidates) else qual.OperatorFacts()
    free: list[int] = []
    area_tasks: list[Task] = []
    ineligible: list[dict[str, Any]] = []
    wants_test = False
    for task in candidates:
        reasons = qual.check_requirements(task.requirements, facts)
        if reasons:
            if qual.needs_test(task.requirements) and facts.test_status == "not_taken":
                wants_test = True
            ineligible.append({"task_id": task.id, "title": task.title, "reasons": reasons})
            continue
        if active >= task.max_active_leases:
            ineligible.append({"task_id": task.id, "title": task.title, "reasons": [
                f"you already hold {active} lease(s); this task allows {task.max_active_leases} at a time"]})
            continue
        if qual.needs_home_area(task.requirements):
            area_tasks.append(task)
        else:
            free.append(task.id)
    area_runs: list[int] = []
    if area_tasks:
        centres = repo.task_run_centres(session, [t.id for t in area_tasks])
        if centres:
            inside = qual.check_home_area(facts.home, np.array([c[2] for c in centres]), np.array([c[3] for c in centres]))
            area_runs = [c[0] for c, ok in zip(centres, inside) if ok]
            near = {c[1] for c, ok in zip(centres, inside) if ok}
            for t in area_tasks:
                if t.id not in near:
                    ineligible.append({"task_id": t.id, "title": t.title,
                                       "reasons": ["none of this task's open runs lies within your home area"]})
    deadlines = {t.id: now + dt.timedelta(seconds=t.lease_s) for t in candidates}
    if wants_test and active == 0:
        test = _lease_test(session, uid, now)
        if test is not None:
            return {"assignment": test, "message": "first, the qualification test: correct this run as well as you can",
                    "ineligible": ineligible}
    got = repo.lease_one(session, uid, now, task_ids=free, task_run_ids=area_runs, deadlines=deadlines, active=active)
    if got is None:
        if active > 0 and not free and not area_runs:
            message = "finish or return the assignment you hold first"
        elif ineligible and not free and not area_runs:
            message = "no task you qualify for has work left; see the reasons per task"
        else:
            message = "no work is available right now"
        return {"assignment": None, "message": message, "ineligible": ineligible}
    aid, tid = got
    a = repo.get_assignment(session, aid)  # not loaded before the UPDATE: read fresh
    assert a is not None
    repo.record(session, task_id=tid, entity="assignment", assignment_id=aid, task_run_id=a.task_run_id,
                from_status=AssignmentStatus.open, to_status=AssignmentStatus.accepted, actor_id=uid, at=now, reason="leased",
                detail={"lease_expires_at": a.lease_expires_at.isoformat() if a.lease_expires_at else None})
    task = session.get(Task, tid)
    assert task is not None
    if task.status == TaskStatus.assignable:
        move_task(session, task, TaskStatus.in_progress, now, actor_id=uid, reason="first lease", skip_locked=True)
    return {"assignment": assignment_public(session, a, now), "message": "leased", "ineligible": ineligible}


def _lease_test(session: Session, uid: int, now: dt.datetime) -> AssignmentPublic | None:
    slot = repo.test_task_slot(session, uid)
    if slot is None:
        return None
    task, tr = slot
    run = session.get(Run, tr.run_id)
    assert run is not None
    a = Assignment(task_id=task.id, task_run_id=tr.id, run_id=tr.run_id, operator_id=uid, status=AssignmentStatus.accepted,
                   base_revision=run.revision, leased_at=now, lease_expires_at=now + dt.timedelta(seconds=task.lease_s),
                   created_at=now, updated_at=now)
    session.add(a)
    session.flush()
    repo.record(session, task_id=task.id, entity="assignment", assignment_id=a.id, task_run_id=tr.id, from_status=None,
                to_status=AssignmentStatus.accepted, actor_id=uid, at=now, reason="qualification test")
    return assignment_public(session, a, now)


def assignment_public(session: Session, a: Assignment, now: dt.datetime) -> AssignmentPublic:
    task = session.get(Task, a.task_id)
    assert task is not None
    remaining = None
    if a.status == AssignmentStatus.accepted and a.lease_expires_at is not None:
        remaining = max((a.lease_expires_at - now).total_seconds(), 0.0)
    brief = TaskBrief(id=task.id, title=task.title, instructions=task.instructions, reward_cents=task.reward_cents,
                      currency=task.currency, rules=task.rules)
    return AssignmentPublic(
        id=a.id, task_id=a.task_id, run_id=a.run_id, status=AssignmentStatus(a.status), operator_id=a.operator_id,
        base_revision=a.base_revision, leased_at=a.leased_at, lease_expires_at=a.lease_expires_at,
        lease_remaining_s=remaining, submitted_at=a.submitted_at, comment=a.comment, feedback=a.feedback,
        reviewed_at=a.reviewed_at, auto_approve_at=a.auto_approve_at, task=brief,
    )


def own_assignment(session: Session, principal: Principal, assignment_id: int) -> Assignment:
    a = repo.get_assignment(session, assignment_id, for_update=True)
    if a is None or a.operator_id != principal.user_id:
        raise NotFound(f"assignment {assignment_id} not found", code="assignment_not_found")
    return a


def visible_assignment(session: Session, principal: Principal, assignment_id: int) -> Assignment:
    a = repo.get_assignment(session, assignment_id)
    if a is None:
        raise NotFound(f"assignment {assignment_id} not found", code="assignment_not_found")
    if a.operator_id == principal.user_id or principal.role in (Role.admin, Role.reviewer):
        return a
    task = session.get(Task, a.task_id)
    if principal.role == Role.client and task is not None and task.requester_id == principal.user_id:
        return a
    raise NotFound(f"assignment {assignment_id} not found", code="assignment_not_found")


def _not_active(a: Assignment, now: dt.datetime) -> Exception:
    if a.status == AssignmentStatus.expired or (a.status == AssignmentStatus.accepted and a.lease_expires_at is not None
                                                and a.lease_expires_at <= now):
        return Gone(f"the lease on assignment {a.id} expired at {a.lease_expires_at.isoformat() if a.lease_expires_at else '?'}; "
                    "the work was not counted", code="lease_expired")
    return Conflict(f"assignment {a.id} is {a.status}, not held", code="assignment_not_active",
                    extra={"status": a.status})


def extend_lease(session: Session, principal: Principal, assignment_id: int, now: dt.datetime) -> Assignment:
    """Push the deadline to now + the task's lease (the operator is still working)."""
    a = own_assignment(session, principal, assignment_id)
    task = session.get(Task, a.task_id)
    assert task is not None
    new_deadline = now + dt.timedelta(seconds=task.lease_s)
    ok = repo.transition_assignment(
        session, a.id, from_status=(AssignmentStatus.accepted,), extra_where=[Assignment.lease_expires_at > now],
        values={"lease_expires_at": new_deadline, "updated_at": now},
    )
    if not ok:
        raise _not_active(a, now)
    repo.record(session, task_id=a.task_id, entity="assignment", assignment_id=a.id, task_run_id=a.task_run_id,
                from_status=AssignmentStatus.accepted, to_status=AssignmentStatus.accepted, actor_id=principal.user_id,
                at=now, reason="extended", detail={"lease_expires_at": new_deadline.isoformat()})
    session.refresh(a)
    return a


def _replace_slot(session: Session, a: Assignment, now: dt.datetime) -> None:
    task = session.get(Task, a.task_id)
    if task is None or task.is_test or task.status not in repo.ACTIVE_TASK:
        return
    tr = session.get(TaskRun, a.task_run_id)
    assert tr is not None
    repo.add_open_slots(session, [_slot(tr, now)])


def return_assignment(session: Session, principal: Principal, assignment_id: int, now: dt.datetime) -> Assignment:
    a = own_assignment(session, principal, assignment_id)
    if not move_assignment(session, a, AssignmentStatus.returned, now, actor_id=principal.user_id, reason="returned",
                           extra_where=[Assignment.lease_expires_at > now]):
        raise _not_active(a, now)
    _replace_slot(session, a, now)
    return a


def submit(session: Session, settings: Settings, principal: Principal, assignment_id: int, body: SubmitIn,
           now: dt.datetime, *, wake: Any = None) -> tuple[Assignment, list[dict[str, Any]]]:
    """Store the operator's edits on the assignment (not on the run): the run changes only when
    approved work is merged. Late (lease over) -> 410, never counted."""
    from posefix.edits import service as edits_service

    a = own_assignment(session, principal, assignment_id)
    if a.status != AssignmentStatus.accepted or a.lease_expires_at is None or a.lease_expires_at <= now:
        raise _not_active(a, now)
    if not body.moves and not body.deleted and not body.accept:
        raise Unprocessable("the submission is empty (no moves, deletions or accept)", code="empty_submission")
    run = session.get(Run, a.run_id)
    if run is None:
        raise NotFound(f"run {a.run_id} not found", code="run_not_found")
    base_revision = a.base_revision or 0
    base = edits_service.edit_set_at(session, run, base_revision)
    problem = edits_service.load_problem(session, settings, run)
    moves = [correction.BatchMove(m.index, m.lon, m.lat, m.alt) for m in body.moves]
    check = correction.check_batch(problem, run.rules, base, moves, body.deleted)
    if check.refusals:
        raise Unprocessable(f"{len(check.refusals)} edit(s) refused by the editing rules", code="edit_refused",
                            extra={"refusals": [r.to_json() for r in check.refusals]})
    edit_set = correction.merge(base, moves, body.deleted, check.flags)
    edit_set["accept"] = bool(body.accept)
    edit_set["own_moves"] = sorted(m.index for m in moves)
    task = session.get(Task, a.task_id)
    assert task is not None
    ok = move_assignment(
        session, a, AssignmentStatus.submitted, now, actor_id=principal.user_id, reason="submitted",
        extra_where=[Assignment.operator_id == principal.user_id, Assignment.lease_expires_at > now],
        values={"submitted_at": now, "edit_set": edit_set, "comment": body.comment,
                "auto_approve_at": now + dt.timedelta(seconds=task.auto_approval_delay_s)},
        detail={"moves": len(moves), "deleted": len(body.deleted), "accept": body.accept},
    )
    if not ok:
        raise _not_active(a, now)
    jobs.enqueue(session, EVALUATE_JOB, {"assignment_id": a.id}, run_id=a.run_id, created_by=principal.user_id)
    ensure_maintenance(session)  # auto-approval is due later
    if wake is not None:
        from posefix.db import on_commit

        on_commit(session, wake)
    return a, [f.to_json() for f in check.flags]


# -- evaluation, consensus, conflicts ------------------------------------------------------------

def _local_m(lon: np.ndarray, lat: np.ndarray, origin: geodesy.EnuOrigin) -> np.ndarray:
    """(..., 2) East-North metres of lon/lat arrays in the run's local frame."""
    shape = np.shape(lon)
    p = geodesy.geodetic_to_enu(np.ravel(lat), np.ravel(lon), np.zeros(np.size(lon)), origin)
    return p[:, :2].reshape(*shape, 2)


def _origin(session: Session, run_id: int) -> geodesy.EnuOrigin:
    cols = runs_repo.keyframe_columns(session, run_id)
    return geodesy.EnuOrigin(cols[0][4], cols[0][3], 0.0)


Reoptimise = Callable[[dict[str, Any]], np.ndarray]  # edit set -> (k, 2) lon, lat solved by the engine


def record_evaluation(session: Session, assignment_id: int, corrected: list[list[float]], gold_error_m: float | None,
                      now: dt.datetime, reoptimise: Reoptimise | None = None) -> Assignment | None:
    a = repo.get_assignment(session, assignment_id, for_update=True)
    if a is None or a.status not in repo.SUBMITTED_OR_BETTER:
        return None
    a.corrected = corrected
    a.gold_error_m = gold_error_m
    a.evaluated_at = now
    a.updated_at = now
    session.flush()
    task = session.get(Task, a.task_id)
    assert task is not None
    if task.is_test:
        _score_test(session, a, now)
    else:
        update_consensus(session, a.task_run_id, now, reoptimise)
    return a


def _score_test(session: Session, a: Assignment, now: dt.datetime) -> None:
    gold = session.get(GoldRun, a.run_id)
    threshold = gold.pass_error_m if gold is not None else 3.0
    err = a.gold_error_m
    passed = err is not None and err <= threshold
    message = (f"mean error {err:.2f} m, pass mark {threshold:.2f} m" if err is not None else "no truth to score against")
    move_assignment(session, a, AssignmentStatus.approved if passed else AssignmentStatus.rejected, now, actor_id=None,
                    reason="test scored", values={"reviewed_at": now, "feedback": message})
    set_qualification(session, a.operator_id or 0, TEST_QUALIFICATION, 1.0 if passed else 0.0, None, now,
                      detail={"message": message, "assignment_id": a.id, "error_m": err})


def update_consensus(session: Session, task_run_id: int, now: dt.datetime, reoptimise: Reoptimise | None = None) -> None:
    """When every wanted submission of a run is in and evaluated: consensus, conflicts, policy."""
    tr = session.get(TaskRun, task_run_id)
    task = session.get(Task, tr.task_id) if tr else None
    if tr is None or task is None or tr.status not in (TaskRunStatus.open,):
        return
    rows = repo.run_assignments(session, tr.id)
    pending = [a for a in rows if a.status in (AssignmentStatus.open, AssignmentStatus.accepted)]
    done = [a for a in rows if a.status in repo.SUBMITTED_OR_BETTER]
    if pending or not done or any(a.evaluated_at is None for a in done):
        return
    result = compute_consensus(session, tr, task, done, reoptimise)
    tr.consensus, tr.disagreement_m, tr.conflicts = result["consensus"], result["disagreement_m"], result["conflicts"]
    for a, err in zip(done, result["consensus_error_m"]):
        a.consensus_error_m = err
    before = tr.status
    if result["blocking"] and task.conflict_policy == "extend" and tr.extra_added < task.max_extra_assignments \
            and task.status in repo.ACTIVE_TASK + (TaskStatus.reviewable,):
        tr.extra_added += 1
        tr.wanted += 1
        repo.add_open_slots(session, [_slot(tr, now)])
        repo.record(session, task_id=task.id, entity="task_run", task_run_id=tr.id, from_status=before, to_status=before,
                    at=now, reason="extra assignment requested", detail={"conflicts": len(tr.conflicts or [])})
        if task.status == TaskStatus.reviewable:
            move_task(session, task, TaskStatus.in_progress, now, reason="extra assignment requested")
        tr.updated_at = now
        session.flush()
        return
    tr.status = TaskRunStatus.conflict if result["blocking"] else TaskRunStatus.agreed
    tr.updated_at = now
    repo.record(session, task_id=task.id, entity="task_run", task_run_id=tr.id, from_status=before, to_status=tr.status,
                at=now, reason="conflict flagged" if result["blocking"] else "submissions agree",
                detail={"conflicts": len(tr.conflicts or [])})
    session.flush()
    if repo.remaining_open_runs(session, task.id, (TaskRunStatus.open,)) == 0:
        move_task(session, task, TaskStatus.reviewable, now, reason="all submissions in")
    maybe_merge(session, tr, now, actor_id=None)


def compute_consensus(session: Session, tr: TaskRun, task: Task, done: list[Assignment],
                      reoptimise: Reoptimise | None = None) -> dict[str, Any]:
    """The consensus track and the conflicts between the submissions' corrected tracks.

    Consensus: the geometric median per keyframe of the corrected positions; with
    ``reoptimise`` (the engine, in the worker), the medians at the keyframes anyone moved
    (and the majority's deletions, as the merge would submit them) are re-optimised by the
    engine into one consistent track."""
    origin = _origin(session, tr.run_id)
    pos = np.array([a.corrected for a in done], dtype=float)            # (m, k, 2) lon, lat
    x_m = _local_m(pos[..., 0], pos[..., 1], origin)                      # (m, k, 2) metres
    valid = np.ones(x_m.shape[:2], dtype=bool)
    for i, a in enumerate(done):
        for d in (a.edit_set or {}).get("deleted", []):
            if 0 <= int(d) < valid.shape[1]:
                valid[i, int(d)] = False
    median_m = consensus.geometric_median(x_m, valid)
    # a keyframe every operator deleted has no median: keep the first track there (it is removed anyway)
    median_m = np.where(np.isnan(median_m), x_m[0], median_m)
    if reoptimise is not None:
        moves, deleted, _ = merged_edits(session, tr, done)
        solved = np.asarray(reoptimise({"moves": [[m.index, m.lon, m.lat, m.alt] for m in moves], "deleted": deleted, "flags": []}))
        lon, lat = solved[:, 0], solved[:, 1]
        median_m = _local_m(lon, lat, origin)
    else:
        lat, lon, _ = geodesy.enu_to_geodetic(np.column_stack([median_m, np.zeros(len(median_m))]), origin)
    tracks = consensus.track_conflicts(x_m, task.conflict_distance_m, task.conflict_keyframes, valid)
    moves_m = []
    for a in done:
        es = a.edit_set or {}
        own = set(es.get("own_moves", []))
        mv = [m for m in es.get("moves", []) if int(m[0]) in own]
        if mv:
            xy = _local_m(np.array([m[1] for m in mv]), np.array([m[2] for m in mv]), origin)
            moves_m.append({int(m[0]): xy[j] for j, m in enumerate(mv)})
        else:
            moves_m.append({})
    edits = consensus.edit_conflicts(moves_m, task.conflict_edit_m)
    ids = [a.id for a in done]
    conflicts = [
        {**c.to_json(), "a": ids[c.a], "b": ids[c.b]} for c in tracks
    ] + [{**c.to_json(), "a": ids[c.a], "b": ids[c.b]} for c in edits]
    err = np.linalg.norm(x_m - median_m[None], axis=2)                   # (m, k)
    consensus_error = [float(err[i][valid[i]].mean()) if valid[i].any() else 0.0 for i in range(len(done))]
    blocking = bool(conflicts)
    if blocking and len(done) >= 3:
        # plurality: the consensus stands when most tracks agree with it
        outliers = consensus.track_conflicts(np.concatenate([median_m[None], x_m]), task.conflict_distance_m,
                                             task.conflict_keyframes,
                                             np.concatenate([np.ones((1, valid.shape[1]), bool), valid]))
        away = {c.b - 1 for c in outliers if c.a == 0}
        blocking = len(away) * 2 >= len(done)
    return {
        "consensus": np.round(np.column_stack([lon, lat]), 8).tolist(),
        "disagreement_m": np.round(consensus.disagreement_m(x_m, valid), 3).tolist(),
        "conflicts": conflicts, "consensus_error_m": consensus_error, "blocking": blocking,
    }


# -- review and merge ----------------------------------------------------------------------------

def review(session: Session, principal: Principal, assignment_id: int, decision: str, feedback: str | None,
           now: dt.datetime) -> Assignment:
    a = repo.get_assignment(session, assignment_id, for_update=True)
    if a is None:
        raise NotFound(f"assignment {assignment_id} not found", code="assignment_not_found")
    if a.operator_id == principal.user_id:
        raise Forbidden("nobody reviews their own work", code="own_work")
    tr = session.get(TaskRun, a.task_run_id)
    assert tr is not None
    if any(x.operator_id == principal.user_id for x in repo.run_assignments(session, tr.id)):
        raise Forbidden("you worked on this run in this task, so you may not review it", code="own_work")
    to = AssignmentStatus.approved if decision == "approve" else AssignmentStatus.rejected
    if not move_assignment(session, a, to, now, actor_id=principal.user_id, reason="reviewed",
                           values={"reviewed_by": principal.user_id, "reviewed_at": now, "feedback": feedback}):
        raise Conflict(f"assignment {a.id} is {a.status}; only submitted work can be reviewed", code="not_reviewable",
                       extra={"status": a.status})
    if to == AssignmentStatus.rejected and tr.status == TaskRunStatus.open:
        _replace_slot(session, a, now)
    maybe_merge(session, tr, now, actor_id=principal.user_id)
    return a


def maybe_merge(session: Session, tr: TaskRun, now: dt.datetime, *, actor_id: int | None) -> None:
    """Once every submission of a run is decided, merge the approved ones (through the worker)."""
    if tr.status not in (TaskRunStatus.agreed, TaskRunStatus.conflict):
        return
    counts = repo.statuses_of_run(session, tr.id)
    if any(counts.get(s, 0) for s in (AssignmentStatus.open, AssignmentStatus.accepted, AssignmentStatus.submitted)):
        return
    before = tr.status
    task = session.get(Task, tr.task_id)
    assert task is not None
    if counts.get(AssignmentStatus.approved, 0) == 0:
        tr.status = TaskRunStatus.unmerged
        repo.record(session, task_id=tr.task_id, entity="task_run", task_run_id=tr.id, from_status=before,
                    to_status=tr.status, actor_id=actor_id, at=now, reason="every submission rejected")
        session.flush()
        _finish_task(session, task, now)
        return
    tr.status = TaskRunStatus.merging
    tr.updated_at = now
    repo.record(session, task_id=tr.task_id, entity="task_run", task_run_id=tr.id, from_status=before,
                to_status=tr.status, actor_id=actor_id, at=now, reason="merge enqueued")
    jobs.enqueue(session, MERGE_JOB, {"task_run_id": tr.id, "actor_id": actor_id}, run_id=tr.run_id, created_by=actor_id)
    session.flush()


def _finish_task(session: Session, task: Task, now: dt.datetime) -> None:
    left = repo.remaining_open_runs(session, task.id, (TaskRunStatus.open, TaskRunStatus.agreed, TaskRunStatus.conflict,
                                                       TaskRunStatus.merging))
    if left == 0 and task.status == TaskStatus.reviewable:
        move_task(session, task, TaskStatus.done, now, reason="every run merged or closed")


def merged_edits(session: Session, tr: TaskRun, approved: list[Assignment]) -> tuple[list[MoveIn], list[int], dict[str, Any]]:
    """Moves and deletions of the merged result: one submission's own edits, or the geometric
    median of the approved corrected tracks at every keyframe anyone moved; a keyframe is
    deleted when most approved operators deleted it."""
    if len(approved) == 1:
        es = approved[0].edit_set or {}
        moves = [MoveIn(index=int(m[0]), lon=m[1], lat=m[2], alt=m[3]) for m in es.get("moves", [])]
        return moves, [int(d) for d in es.get("deleted", [])], {"from": [approved[0].id], "method": "single"}
    origin = _origin(session, tr.run_id)
    pos = np.array([a.corrected for a in approved], dtype=float)
    x_m = _local_m(pos[..., 0], pos[..., 1], origin)
    moved = sorted({int(m[0]) for a in approved for m in (a.edit_set or {}).get("moves", [])})
    votes: dict[int, int] = {}
    for a in approved:
        for d in (a.edit_set or {}).get("deleted", []):
            votes[int(d)] = votes.get(int(d), 0) + 1
    deleted = sorted(d for d, n in votes.items() if 2 * n > len(approved))
    keep = [k for k in moved if k not in set(deleted)]
    moves: list[MoveIn] = []
    if keep:
        med = consensus.geometric_median(x_m[:, keep, :])
        lat, lon, _ = geodesy.enu_to_geodetic(np.column_stack([med, np.zeros(len(med))]), origin)
        moves = [MoveIn(index=k, lon=float(lo), lat=float(la)) for k, lo, la in zip(keep, lon, lat)]
    return moves, deleted, {"from": [a.id for a in approved], "method": "geometric_median"}


def merge_task_run(session: Session, settings: Settings, task_run_id: int, actor_id: int | None, now: dt.datetime) -> dict[str, Any]:
    """Worker side of a merge: submit the merged edits as a new revision of the run."""
    from posefix.edits import service as edits_service

    tr = session.get(TaskRun, task_run_id)
    if tr is None:
        return {"skipped": "task run gone"}
    if tr.status == TaskRunStatus.merged:
        return {"task_run_id": tr.id, "revision": tr.merged_revision, "already_merged": True}
    task = session.get(Task, tr.task_id)
    run = session.get(Run, tr.run_id)
    assert task is not None and run is not None
    approved = [a for a in repo.run_assignments(session, tr.id) if a.status == AssignmentStatus.approved]
    moves, deleted, detail = merged_edits(session, tr, approved)
    author_id = actor_id or task.requester_id
    author = session.get(User, author_id) if author_id else None
    principal = Principal(user_id=author.id if author else 0, username=author.username if author else "system",
                          role=Role(author.role) if author else Role.admin, via="job", scope="write", credential_hash="")  # type: ignore[arg-type]
    dropped: list[dict[str, Any]] = []
    for _ in range(5):
        try:
            with session.begin_nested():
                batch, job_id, _flags = edits_service.submit(
                    session, settings, principal, run, base=run.head_revision, moves=moves, deleted=deleted,
                    accept=True, comment=f"task {task.id}: merged from assignment(s) {', '.join(map(str, detail['from']))}",
                    task_id=task.id,
                )
            break
        except Unprocessable as exc:
            refused = {int(r["index"]) for r in exc.extra.get("refusals", [])}
            if not refused:
                raise
            dropped += exc.extra.get("refusals", [])
            moves = [m for m in moves if m.index not in refused]
            deleted = [d for d in deleted if d not in refused]
            session.refresh(run)
    else:
        raise Unprocessable("the merged edits kept being refused by the editing rules", code="merge_refused")
    before = tr.status
    tr.status = TaskRunStatus.merged
    tr.merge_batch_id = batch.id
    tr.merged_revision = batch.revision
    tr.merge_detail = {**detail, "dropped": dropped, "moves": len(moves), "deleted": len(deleted), "job_id": job_id}
    tr.updated_at = now
    repo.record(session, task_id=task.id, entity="task_run", task_run_id=tr.id, from_status=before, to_status=tr.status,
                actor_id=actor_id, at=now, reason="merged", detail={"revision": batch.revision, "batch_id": batch.id})
    session.flush()
    _finish_task(session, task, now)
    return {"task_run_id": tr.id, "revision": batch.revision, "batch_id": batch.id, "revision_job_id": job_id}


# -- maintenance (the worker) -----------------------------------------------------------------------

def maintain(session: Session, now: dt.datetime) -> dict[str, int]:
    """Return expired leases to the pool, auto-approve due work, expire old tasks, forget old tokens."""
    expired = 0
    for a in repo.expired_leases(session, now):
        if move_assignment(session, a, AssignmentStatus.expired, now, actor_id=None, reason="lease expired",
                           extra_where=[Assignment.lease_expires_at <= now]):
            _replace_slot(session, a, now)
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
            _withdraw(session, task, now, None)
            # work already submitted on runs that will get no more still goes to review
            for tr in repo.task_runs(session, task.id):
                update_consensus(session, tr.id, now)
            ended += 1
    forgotten = repo.forget_tokens(session, now - TOKEN_TTL)
    return {"leases_expired": expired, "auto_approved": approved, "tasks_expired": ended, "tokens_forgotten": forgotten}


# -- operators -------------------------------------------------------------------------------------

def set_home_area(session: Session, user_id: int, body: HomeAreaIn, now: dt.datetime) -> None:
    repo.lock_operator(session, user_id, now)
    prof = repo.profile(session, user_id)
    assert prof is not None
    prof.home_lon, prof.home_lat, prof.home_radius_m = body.lon, body.lat, body.radius_m
    prof.home_polygon = body.polygon
    prof.updated_at = now
    session.flush()


def set_qualification(session: Session, user_id: int, name: str, value: float, granted_by: int | None,
                      now: dt.datetime, detail: dict[str, Any] | None = None) -> OperatorQualification:
    q = session.get(OperatorQualification, (user_id, name))
    if q is None:
        q = OperatorQualification(user_id=user_id, name=name)
        session.add(q)
    q.value, q.granted_by, q.granted_at, q.detail = value, granted_by, now, detail
    session.flush()
    return q


def revoke_qualification(session: Session, user_id: int, name: str) -> None:
    q = session.get(OperatorQualification, (user_id, name))
    if q is None:
        raise NotFound(f"user {user_id} does not hold '{name}'", code="qualification_not_found")
    session.delete(q)
    session.flush()


def operator_stats(session: Session, users: list[User]) -> list[dict[str, Any]]:
    numbers = repo.operator_numbers(session, [u.id for u in users])
    out = []
    for u in users:
        n = numbers.get(u.id, {"submitted": 0, "approved": 0, "rejected": 0, "returned": 0, "expired": 0,
                               "accuracy_m": None, "gold_scored": 0, "agreement_m": None, "work_s": 0.0})
        facts = operator_facts(session, u.id)
        prof = repo.profile(session, u.id)
        home = None
        if prof is not None and facts.home.defined:
            home = {"lon": prof.home_lon, "lat": prof.home_lat, "radius_m": prof.home_radius_m, "polygon": prof.home_polygon}
        work_s = n["work_s"]
        out.append({
            "user_id": u.id, "username": u.username, "submitted": n["submitted"], "approved": n["approved"],
            "rejected": n["rejected"], "returned": n["returned"], "expired": n["expired"], "accuracy_m": n["accuracy_m"],
            "gold_scored": n["gold_scored"], "agreement_m": n["agreement_m"],
            "throughput_per_h": (n["submitted"] / (work_s / 3600.0)) if work_s > 0 else None,
            "mean_work_s": (work_s / n["submitted"]) if n["submitted"] else None,
            "test_status": facts.test_status, "home_area": home,
            "qualifications": [{"name": q.name, "value": q.value, "granted_by": q.granted_by, "granted_at": q.granted_at}
                               for q in repo.qualifications(session, u.id)],
        })
    return out


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
