"""The queue and leases: the next assignment an operator qualifies for (taken in one
conditional UPDATE), the qualification test first when a task asks for it, extension and
return of a lease, and who may see an assignment."""

from __future__ import annotations

import datetime as dt
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from posefix.errors import Conflict, Gone, NotFound
from posefix.runs.models import Run
from posefix.tasks import qualification as qual
from posefix.tasks import repository as repo
from posefix.tasks.models import Assignment, AssignmentStatus, Task, TaskStatus
from posefix.tasks.operators import operator_facts
from posefix.tasks.schemas import AssignmentPublic, TaskBrief
from posefix.tasks.states import move_assignment, move_task, replace_slot
from posefix.users.models import Role
from posefix.users.service import Principal


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
    to_measure: list[Task] = []
    for task in candidates:
        reasons = qual.check_requirements(task.requirements, facts)
        if reasons:
            if qual.needs_test(task.requirements) and facts.test_status == "not_taken":
                wants_test = True
            if qual.waits_for_accuracy(task.requirements, facts):
                to_measure.append(task)
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
    if to_measure and active == 0 and not repo.gold_pending(session, uid):
        gold = _lease_qualifying_gold(session, uid, now, to_measure, deadlines)
        if gold is not None:
            return {"assignment": gold, "message": "first, a gold run that measures your accuracy: correct it as well as you can",
                    "ineligible": ineligible}
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


def _lease_qualifying_gold(session: Session, uid: int, now: dt.datetime, tasks: list[Task],
                           deadlines: dict[int, dt.datetime]) -> AssignmentPublic | None:
    """A gold run of one of ``tasks`` (which need a measured accuracy), else a test gold run:
    scoring it measures the operator, so an accuracy requirement can be met on a fresh team."""
    runs = repo.open_gold_task_runs(session, [t.id for t in tasks])
    got = repo.lease_one(session, uid, now, task_ids=[], task_run_ids=runs, deadlines=deadlines, active=0) if runs else None
    if got is None:
        return _lease_test(session, uid, now)
    aid, tid = got
    a = repo.get_assignment(session, aid)
    assert a is not None
    repo.record(session, task_id=tid, entity="assignment", assignment_id=aid, task_run_id=a.task_run_id,
                from_status=AssignmentStatus.open, to_status=AssignmentStatus.accepted, actor_id=uid, at=now,
                reason="leased to measure accuracy")
    task = session.get(Task, tid)
    assert task is not None
    if task.status == TaskStatus.assignable:
        move_task(session, task, TaskStatus.in_progress, now, actor_id=uid, reason="first lease", skip_locked=True)
    return assignment_public(session, a, now)


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


def not_active(a: Assignment, now: dt.datetime) -> Exception:
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
        raise not_active(a, now)
    repo.record(session, task_id=a.task_id, entity="assignment", assignment_id=a.id, task_run_id=a.task_run_id,
                from_status=AssignmentStatus.accepted, to_status=AssignmentStatus.accepted, actor_id=principal.user_id,
                at=now, reason="extended", detail={"lease_expires_at": new_deadline.isoformat()})
    session.refresh(a)
    return a


def return_assignment(session: Session, principal: Principal, assignment_id: int, now: dt.datetime) -> Assignment:
    a = own_assignment(session, principal, assignment_id)
    if not move_assignment(session, a, AssignmentStatus.returned, now, actor_id=principal.user_id, reason="returned",
                           extra_where=[Assignment.lease_expires_at > now]):
        raise not_active(a, now)
    replace_slot(session, a, now)
    return a
