"""Review: the submissions of a run side by side, and a reviewer's decision on one (never on
their own work); a decided run goes on to the merge."""

from __future__ import annotations

import datetime as dt

import numpy as np
from sqlalchemy.orm import Session

from posefix.errors import Conflict, Forbidden, NotFound
from posefix.runs import repository as runs_repo
from posefix.tasks import repository as repo
from posefix.tasks.merge import maybe_merge, retry_merge
from posefix.tasks.models import Assignment, AssignmentStatus, TaskRun, TaskRunStatus
from posefix.tasks.schemas import ReviewView, SubmissionView
from posefix.tasks.states import move_assignment, replace_slot
from posefix.tasks.weighing import Weighing, weigh
from posefix.users.service import Principal

REVIEWABLE = (AssignmentStatus.submitted, AssignmentStatus.approved, AssignmentStatus.rejected)


def review_view(session: Session, task_run_id: int) -> ReviewView:
    tr = session.get(TaskRun, task_run_id)
    if tr is None:
        raise NotFound(f"task run {task_run_id} not found", code="task_run_not_found")
    reported = [[c[3], c[4]] for c in runs_repo.keyframe_columns(session, tr.run_id)]
    rows = [a for a in repo.run_assignments(session, tr.id) if a.status in REVIEWABLE]
    names = repo.usernames(session, [a.operator_id for a in rows if a.operator_id])
    subs = {a.id: _submission(a, names) for a in rows}
    evaluated = [a for a in rows if a.evaluated_at is not None and a.corrected]
    method, sigma = None, None
    if len(evaluated) >= 2:
        wg = weigh(session, tr, evaluated)
        method = wg.method
        sigma = [None if np.isnan(s) else round(float(s), 3) for s in wg.fused.sigma_m]
        share = wg.weight_share
        dist = wg.test.distance_m if wg.test is not None else _distance(wg)
        for i, aid in enumerate(wg.ids):
            v = subs[aid]
            v.accuracy_m, v.gold_scored = wg.accuracy_m[i], wg.gold_scored[i]
            v.distance_m = None if np.isnan(dist[i]) else round(float(dist[i]), 3)
            v.weight = round(float(share[i]), 4)
            if wg.test is not None:
                v.sigma_m = round(float(wg.sigma_m[i]), 3)
                v.expected_m = None if np.isnan(wg.test.expected_m[i]) else round(float(wg.test.expected_m[i]), 3)
                v.off_consensus = bool(wg.flagged[i])
    ranked = sorted(subs.values(), key=lambda v: (v.distance_m is None, v.distance_m or 0.0, v.assignment_id))
    for r, v in enumerate(ranked, 1):
        v.rank = r if v.distance_m is not None else None
    return ReviewView(task_run_id=tr.id, task_id=tr.task_id, run_id=tr.run_id, status=tr.status, reported=reported,
                      consensus=tr.consensus, disagreement_m=tr.disagreement_m, conflicts=tr.conflicts, submissions=ranked,
                      merged_revision=tr.merged_revision, method=method, consensus_sigma_m=sigma, merge_detail=tr.merge_detail)


def _submission(a: Assignment, names: dict[int, str]) -> SubmissionView:
    es = a.edit_set or {}
    own = set(es.get("own_moves", []))
    return SubmissionView(
        assignment_id=a.id, operator_id=a.operator_id, operator=names.get(a.operator_id or 0), status=AssignmentStatus(a.status),
        submitted_at=a.submitted_at, comment=a.comment, moves=[m for m in es.get("moves", []) if int(m[0]) in own],
        deleted=es.get("deleted", []), positions=a.corrected, consensus_error_m=a.consensus_error_m,
    )


def _distance(wg: Weighing) -> np.ndarray:
    """Mean distance of each track to the (unweighted) consensus at the moved keyframes."""
    k = wg.moved or list(range(wg.x_m.shape[1]))
    d = np.linalg.norm(wg.x_m[:, k] - wg.fused.t_m[None, k], axis=2)
    return np.array([float(np.mean(d[i][wg.valid[i, k]])) if wg.valid[i, k].any() else np.nan for i in range(len(wg.ids))])


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
        replace_slot(session, a, now)
    maybe_merge(session, tr, now, actor_id=principal.user_id)
    return a



def merge_again(session: Session, principal: Principal, task_run_id: int, now: dt.datetime) -> TaskRun:
    tr = session.get(TaskRun, task_run_id, with_for_update=True)
    if tr is None:
        raise NotFound(f"task run {task_run_id} not found", code="task_run_not_found")
    return retry_merge(session, tr, now, actor_id=principal.user_id)
