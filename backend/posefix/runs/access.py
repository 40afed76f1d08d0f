"""Who may see which runs — one place, so every route (runs, keyframes, exports, images,
jobs, events) applies the same rule.

- admin and reviewer: every run;
- client (REST requester): the runs they uploaded;
- operator: the runs granted by the registered providers — the app factory registers the
  tasks domain's, which yields the runs of tasks the operator holds or held
  (``register_operator_runs``); plus their own uploads. ``POSEFIX_OPERATORS_SEE_ALL_RUNS`` opens every run to operators
  (the demo before tasks exist).

Providers return a SELECT of run ids, so visibility stays one SQL query, never a Python loop.
"""

from __future__ import annotations

from collections.abc import Callable

from sqlalchemy import ColumnElement, Select, false, or_, select, true
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.errors import NotFound
from posefix.runs.models import Run, RunStatus
from posefix.users.models import Role
from posefix.users.service import Principal

RunIdsProvider = Callable[[int], Select]
_operator_providers: list[RunIdsProvider] = []


def register_operator_runs(provider: RunIdsProvider) -> RunIdsProvider:
    """Register ``provider(user_id) -> SELECT run_id ...`` granting operators runs."""
    if provider not in _operator_providers:
        _operator_providers.append(provider)
    return provider


def visible_clause(principal: Principal, settings: Settings) -> ColumnElement[bool]:
    """A WHERE clause on ``Run`` selecting the runs this principal may see."""
    if principal.role in (Role.admin, Role.reviewer):
        return true()
    if principal.role == Role.client:
        return Run.owner_id == principal.user_id
    if principal.role == Role.operator:
        if settings.operators_see_all_runs:
            return true()
        clauses = [Run.owner_id == principal.user_id]
        clauses += [Run.id.in_(p(principal.user_id)) for p in _operator_providers]
        return or_(*clauses)
    return false()


def visible_run_ids(principal: Principal, settings: Settings) -> Select:
    return select(Run.id).where(visible_clause(principal, settings))


def is_visible(session: Session, principal: Principal, settings: Settings, run_id: int) -> bool:
    return session.scalar(visible_run_ids(principal, settings).where(Run.id == run_id)) is not None


def get_visible_run(
    session: Session, principal: Principal, settings: Settings, run_id: int, *, include_deleted: bool = False
) -> Run:
    """The run, or 404 when it does not exist, is deleted or is not visible (no existence leak)."""
    stmt = select(Run).where(Run.id == run_id, visible_clause(principal, settings))
    if not include_deleted:
        stmt = stmt.where(Run.status != RunStatus.deleted)
    run = session.scalars(stmt).one_or_none()
    if run is None:
        raise NotFound(f"run {run_id} not found", code="run_not_found")
    return run
