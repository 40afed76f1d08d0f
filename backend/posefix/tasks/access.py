"""Operators see the runs of their current and past assignments (the app factory registers
this provider with ``runs.access``)."""

from __future__ import annotations

from sqlalchemy import Select, select

from posefix.tasks.models import Assignment


def runs_of_assignments(user_id: int) -> Select:
    return select(Assignment.run_id).where(Assignment.operator_id == user_id)
