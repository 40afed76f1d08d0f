"""Operators see the runs of their current and past assignments (registered with runs.access)."""

from __future__ import annotations

from sqlalchemy import Select, select

from posefix.runs.access import register_operator_runs
from posefix.tasks.models import Assignment


@register_operator_runs
def runs_of_assignments(user_id: int) -> Select:
    return select(Assignment.run_id).where(Assignment.operator_id == user_id)
