"""Who may see which runs — one place, so every route (runs, keyframes, exports, images,
jobs, events) applies the same rule.

- admin and reviewer: every run;
- client (REST requester): the runs they uploaded;
- operator: the runs granted by the registered providers — the app factory registers the
  tasks domain's, which yields the runs of tasks the operator holds or held
  (``register_operator_runs``); plus their own uploads. ``POSEFIX_OPERATORS_SEE_ALL_RUNS`` opens every run to operators
  (the demo before tasks exist).

Providers return a SELECT of run ids, so visibility stays one SQL query, never a Python loop.

Who may *write* a visible run directly (``POST /runs/{id}/edits``, accept, revert) is
``check_direct_write``: on a run that belongs to a task an operator's work goes through the
assignment (submit, review or consensus, merge), so only reviewers and admins write it;
operators may still write a run that belongs to no task (their uploads, or every run with
``POSEFIX_OPERATORS_SEE_ALL_RUNS``). A ``task_id`` on an edit must name a task the caller
holds a live assignment of on that run. The tasks domain answers both questions through
``register_task_runs`` (registered by the app factory). The rule of every route is in
docs/SECURITY.md.
"""

from __future__ import annotations

from collections.abc import Callable

from sqlalchemy import ColumnElement, Select, false, or_, select, true
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.errors import Forbidden, NotFound
from posefix.runs.models import Run, RunStatus
from posefix.users.models import Role
from posefix.users.service import Principal

RunIdsProvider = Callable[[int], Select]
_operator_providers: list[RunIdsProvider] = []
# (task_runs() -> SELECT run_id of runs under any task,
#  live_runs(user_id, task_id) -> SELECT run_id the user holds a live assignment on in that task)
TaskRunsProvider = tuple[Callable[[], Select], Callable[[int, int], Select]]
_task_providers: list[TaskRunsProvider] = []


def register_operator_runs(provider: RunIdsProvider) -> RunIdsProvider:
    """Register ``provider(user_id) -> SELECT run_id ...`` granting operators runs."""
    if provider not in _operator_providers:
        _operator_providers.append(provider)
    return provider


def register_task_runs(task_runs: Callable[[], Select], live_runs: Callable[[int, int], Select]) -> None:
    """Register which runs belong to tasks and which task runs a user holds a live assignment on."""
    if (task_runs, live_runs) not in _task_providers:
        _task_providers.append((task_runs, live_runs))


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


def is_task_run(session: Session, run_id: int) -> bool:
    """Whether the run belongs to any task (whatever the task's status)."""
    return any(session.scalar(select(Run.id).where(Run.id == run_id, Run.id.in_(t()))) is not None
               for t, _ in _task_providers)


def holds_live_assignment(session: Session, user_id: int, task_id: int, run_id: int) -> bool:
    return any(session.scalar(select(Run.id).where(Run.id == run_id, Run.id.in_(live(user_id, task_id)))) is not None
               for _, live in _task_providers)


def check_direct_write(session: Session, principal: Principal, run: Run, task_id: int | None = None) -> None:
    """403 unless the principal may edit, accept or revert this (visible) run directly."""
    if principal.role == Role.operator and is_task_run(session, run.id):
        raise Forbidden(
            f"run {run.id} belongs to a task: submit your work through your assignment, reviewers merge it",
            code="review_required",
        )
    if task_id is not None and not holds_live_assignment(session, principal.user_id, task_id, run.id):
        raise Forbidden(f"you hold no live assignment of task {task_id} on run {run.id}", code="not_on_task",
                        extra={"task_id": task_id})
