"""Operators see the runs of their current and past assignments; runs under a task are written
only through assignments (the app factory registers these providers with ``runs.access``)."""

from __future__ import annotations

from sqlalchemy import Select, select

from posefix.tasks import clock
from posefix.tasks.models import Assignment, AssignmentStatus, TaskRun


def runs_of_assignments(user_id: int) -> Select:
    return select(Assignment.run_id).where(Assignment.operator_id == user_id)


def task_runs() -> Select:
    return select(TaskRun.run_id)


def live_runs(user_id: int, task_id: int) -> Select:
    """Runs of ``task_id`` the user holds an unexpired lease on."""
    return select(Assignment.run_id).where(
        Assignment.operator_id == user_id, Assignment.task_id == task_id,
        Assignment.status == AssignmentStatus.accepted, Assignment.lease_expires_at > clock.now(),
    )
