"""Submission and evaluation: an operator's edits are checked by the run's rules and kept on
the assignment (the run changes only when approved work is merged); the worker's evaluation
stores the corrected track and the gold error, scores qualification tests, and updates the
run's consensus."""

from __future__ import annotations

import datetime as dt
from typing import Any

from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.errors import NotFound, Unprocessable
from posefix.jobs import repository as jobs
from posefix.engine import Edit, Edits
from posefix.engine.edits import check_batch
from posefix.runs.models import Run
from posefix.tasks import repository as repo
from posefix.tasks.agreement import Reoptimise, update_consensus
from posefix.tasks.leases import not_active, own_assignment
from posefix.tasks.models import Assignment, AssignmentStatus, GoldRun, Task
from posefix.tasks.operators import TEST_QUALIFICATION, set_qualification
from posefix.tasks.schemas import SubmitIn
from posefix.tasks.states import EVALUATE_JOB, ensure_maintenance, move_assignment
from posefix.users.service import Principal


def submit(session: Session, settings: Settings, principal: Principal, assignment_id: int, body: SubmitIn,
           now: dt.datetime, *, wake: Any = None) -> tuple[Assignment, list[dict[str, Any]]]:
    """Store the operator's edits on the assignment (not on the run): the run changes only when
    approved work is merged. Late (lease over) -> 410, never counted."""
    from posefix.edits import service as edits_service

    a = own_assignment(session, principal, assignment_id)
    if a.status != AssignmentStatus.accepted or a.lease_expires_at is None or a.lease_expires_at <= now:
        raise not_active(a, now)
    if not body.moves and not body.deleted and not body.accept:
        raise Unprocessable("the submission is empty (no moves, deletions or accept)", code="empty_submission")
    run = session.get(Run, a.run_id)
    if run is None:
        raise NotFound(f"run {a.run_id} not found", code="run_not_found")
    base_revision = a.base_revision or 0
    base = edits_service.edit_set_at(session, run, base_revision)
    problem = edits_service.load_problem(session, settings, run)
    moves = [Edit(m.index, m.lon, m.lat, m.alt) for m in body.moves]
    check = check_batch(problem, problem.cfg.rules, Edits.from_json(base), moves, body.deleted)
    if check.refusals:
        n = len(check.refusals)
        raise Unprocessable(f"{n} edit{'' if n == 1 else 's'} refused by the editing rules", code="edit_refused",
                            extra={"refusals": [r.to_json() for r in check.refusals]})
    edit_set = Edits.from_json(base).merged(moves, body.deleted, check.flags).to_json()
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
        raise not_active(a, now)
    jobs.enqueue(session, EVALUATE_JOB, {"assignment_id": a.id}, run_id=a.run_id, created_by=principal.user_id)
    ensure_maintenance(session)  # auto-approval is due later
    if wake is not None:
        from posefix.db import on_commit

        on_commit(session, wake)
    return a, [f.to_json() for f in check.flags]


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
