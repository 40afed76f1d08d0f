"""Review: the submissions of a run side by side, and a reviewer's decision on one (never on
their own work); a decided run goes on to the merge."""

from __future__ import annotations

import datetime as dt

from sqlalchemy.orm import Session

from posefix.errors import Conflict, Forbidden, NotFound
from posefix.runs import repository as runs_repo
from posefix.tasks import repository as repo
from posefix.tasks.merge import maybe_merge
from posefix.tasks.models import Assignment, AssignmentStatus, TaskRun, TaskRunStatus
from posefix.tasks.schemas import ReviewView, SubmissionView
from posefix.tasks.states import move_assignment, replace_slot
from posefix.users.service import Principal

REVIEWABLE = (AssignmentStatus.submitted, AssignmentStatus.approved, AssignmentStatus.rejected)


def review_view(session: Session, task_run_id: int) -> ReviewView:
    tr = session.get(TaskRun, task_run_id)
    if tr is None:
        raise NotFound(f"task run {task_run_id} not found", code="task_run_not_found")
    reported = [[c[3], c[4]] for c in runs_repo.keyframe_columns(session, tr.run_id)]
    rows = [a for a in repo.run_assignments(session, tr.id) if a.status in REVIEWABLE]
    names = repo.usernames(session, [a.operator_id for a in rows if a.operator_id])
    subs = [
        SubmissionView(
            assignment_id=a.id, operator_id=a.operator_id, operator=names.get(a.operator_id or 0), status=AssignmentStatus(a.status),
            submitted_at=a.submitted_at, comment=a.comment,
            moves=[m for m in (a.edit_set or {}).get("moves", []) if int(m[0]) in set((a.edit_set or {}).get("own_moves", []))],
            deleted=(a.edit_set or {}).get("deleted", []), positions=a.corrected, consensus_error_m=a.consensus_error_m,
        )
        for a in rows
    ]
    return ReviewView(task_run_id=tr.id, task_id=tr.task_id, run_id=tr.run_id, status=tr.status, reported=reported,
                      consensus=tr.consensus, disagreement_m=tr.disagreement_m, conflicts=tr.conflicts, submissions=subs,
                      merged_revision=tr.merged_revision)


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

