"""State machines of tasks and assignments, and the helpers every other tasks module shares
(the bottom of the package: it imports no other tasks service module).

    task:        assignable -> in_progress -> reviewable -> done
                 assignable | in_progress -> expired | cancelled;  reviewable -> in_progress (extra slot)
    assignment:  open -> accepted -> submitted -> approved | rejected
                 accepted -> returned | expired (a fresh open slot replaces it);  open -> withdrawn

Every transition is a conditional UPDATE and a ``TaskEvent`` row. Services never commit:
the request or the worker job does. ``now`` is passed in (the domain's clock,
``posefix.tasks.clock``), so tests can move time.
"""

from __future__ import annotations

import datetime as dt
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from posefix.core import geodesy
from posefix.jobs import repository as jobs
from posefix.runs import repository as runs_repo
from posefix.tasks import repository as repo
from posefix.tasks.models import Assignment, AssignmentStatus, Task, TaskRun, TaskRunStatus, TaskStatus

# the worker jobs the tasks domain enqueues (handlers in posefix.tasks.jobs)
EVALUATE_JOB = "tasks.evaluate"
MERGE_JOB = "tasks.merge"
MAINTAIN_JOB = "tasks.maintain"
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


def slot(tr: TaskRun, now: dt.datetime) -> dict[str, Any]:
    """The row of one open assignment slot on a task run."""
    return {"task_id": tr.task_id, "task_run_id": tr.id, "run_id": tr.run_id, "status": AssignmentStatus.open,
            "created_at": now, "updated_at": now}


def replace_slot(session: Session, a: Assignment, now: dt.datetime) -> None:
    """A fresh open slot for work that came back (returned, expired, rejected) on a live task."""
    task = session.get(Task, a.task_id)
    if task is None or task.is_test or task.status not in repo.ACTIVE_TASK:
        return
    tr = session.get(TaskRun, a.task_run_id)
    assert tr is not None
    repo.add_open_slots(session, [slot(tr, now)])


def withdraw(session: Session, task: Task, now: dt.datetime, actor_id: int | None) -> None:
    for aid in repo.withdraw_open(session, task.id, now):
        repo.record(session, task_id=task.id, entity="assignment", assignment_id=aid, from_status=AssignmentStatus.open,
                    to_status=AssignmentStatus.withdrawn, actor_id=actor_id, at=now, reason=f"task {task.status}")


def finish_task(session: Session, task: Task, now: dt.datetime) -> None:
    left = repo.remaining_open_runs(session, task.id, (TaskRunStatus.open, TaskRunStatus.agreed, TaskRunStatus.conflict,
                                                       TaskRunStatus.merging, TaskRunStatus.merge_failed))
    if left == 0 and task.status == TaskStatus.reviewable:
        move_task(session, task, TaskStatus.done, now, reason="every run merged or closed")


def ensure_maintenance(session: Session) -> None:
    """Keep one periodic maintenance job queued (lease expiry, auto-approval, task expiry)."""
    if not repo.pending_job(session, MAINTAIN_JOB):
        jobs.enqueue(session, MAINTAIN_JOB, {}, max_attempts=1000)


# -- positions of a run's keyframes in metres ------------------------------------------------------

def local_m(lon: np.ndarray, lat: np.ndarray, origin: geodesy.EnuOrigin) -> np.ndarray:
    """(..., 2) East-North metres of lon/lat arrays in the run's local frame."""
    shape = np.shape(lon)
    p = geodesy.geodetic_to_enu(np.ravel(lat), np.ravel(lon), np.zeros(np.size(lon)), origin)
    return p[:, :2].reshape(*shape, 2)


def run_origin(session: Session, run_id: int) -> geodesy.EnuOrigin:
    cols = runs_repo.keyframe_columns(session, run_id)
    return geodesy.EnuOrigin(cols[0][4], cols[0][3], 0.0)


def to_lonlat(x_m: np.ndarray, origin: geodesy.EnuOrigin) -> tuple[np.ndarray, np.ndarray]:
    """(k, 2) East-North metres -> lon (k,), lat (k,); the inverse of ``local_m``.

    ``local_m`` measures points on the ellipsoid (height 0), whose plane up falls about
    d²/2R below the tangent plane; going back at up = 0 would tilt them outwards by
    roughly d³/2R² (1.5 m at 50 km), so the way back asks for height 0 too."""
    lat, lon, _ = geodesy.en_height_to_geodetic(np.asarray(x_m, dtype=float).reshape(-1, 2), 0.0, origin)
    return lon, lat
