"""Merge: once every submission of a run is decided, the approved work becomes one new
revision of the run (through the worker), written for a real author."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.edits import service as edits_service
from posefix.edits.schemas import MoveIn
from posefix.jobs import repository as jobs
from posefix.engine import Edit, Edits
from posefix.engine.edits import check_batch
from posefix.runs.models import Run
from posefix.tasks import consensus
from posefix.tasks import repository as repo
from posefix.tasks.models import Assignment, AssignmentStatus, Task, TaskRun, TaskRunStatus
from posefix.tasks.states import MERGE_JOB, finish_task, local_m, run_origin, to_lonlat
from posefix.users.models import Role, User


def maybe_merge(session: Session, tr: TaskRun, now: dt.datetime, *, actor_id: int | None) -> None:
    """Once every submission of a run is decided, merge the approved ones (through the worker)."""
    if tr.status not in (TaskRunStatus.agreed, TaskRunStatus.conflict):
        return
    counts = repo.statuses_of_run(session, tr.id)
    if any(counts.get(s, 0) for s in (AssignmentStatus.open, AssignmentStatus.accepted, AssignmentStatus.submitted)):
        return
    before = tr.status
    task = session.get(Task, tr.task_id)
    assert task is not None
    if counts.get(AssignmentStatus.approved, 0) == 0:
        tr.status = TaskRunStatus.unmerged
        repo.record(session, task_id=tr.task_id, entity="task_run", task_run_id=tr.id, from_status=before,
                    to_status=tr.status, actor_id=actor_id, at=now, reason="every submission rejected")
        session.flush()
        finish_task(session, task, now)
        return
    tr.status = TaskRunStatus.merging
    tr.updated_at = now
    repo.record(session, task_id=tr.task_id, entity="task_run", task_run_id=tr.id, from_status=before,
                to_status=tr.status, actor_id=actor_id, at=now, reason="merge enqueued")
    jobs.enqueue(session, MERGE_JOB, {"task_run_id": tr.id, "actor_id": actor_id}, run_id=tr.run_id, created_by=actor_id)
    session.flush()


def merged_edits(session: Session, tr: TaskRun, approved: list[Assignment]) -> tuple[list[MoveIn], list[int], dict[str, Any]]:
    """Moves and deletions of the merged result: one submission's own edits, or the geometric
    median of the approved corrected tracks at every keyframe anyone moved; a keyframe is
    deleted when most approved operators deleted it."""
    if len(approved) == 1:
        es = approved[0].edit_set or {}
        moves = [MoveIn(index=int(m[0]), lon=m[1], lat=m[2], alt=m[3]) for m in es.get("moves", [])]
        return moves, [int(d) for d in es.get("deleted", [])], {"from": [approved[0].id], "method": "single"}
    origin = run_origin(session, tr.run_id)
    pos = np.array([a.corrected for a in approved], dtype=float)
    x_m = local_m(pos[..., 0], pos[..., 1], origin)
    moved = sorted({int(m[0]) for a in approved for m in (a.edit_set or {}).get("moves", [])})
    votes: dict[int, int] = {}
    for a in approved:
        for d in (a.edit_set or {}).get("deleted", []):
            votes[int(d)] = votes.get(int(d), 0) + 1
    deleted = sorted(d for d, n in votes.items() if 2 * n > len(approved))
    keep = [k for k in moved if k not in set(deleted)]
    moves: list[MoveIn] = []
    if keep:
        med = consensus.geometric_median(x_m[:, keep, :])
        lon, lat = to_lonlat(med, origin)
        moves = [MoveIn(index=k, lon=float(lo), lat=float(la)) for k, lo, la in zip(keep, lon, lat)]
    return moves, deleted, {"from": [a.id for a in approved], "method": "geometric_median"}


@dataclass(frozen=True)
class MergeActor:
    """Whom a merge writes the run's new revision for: the reviewer whose decision completed
    the run, else the task's requester (auto-approved work); when neither account exists any
    more, the system (no user), whose merge of approved work stands as reviewed."""

    user_id: int | None
    role: Role

    @classmethod
    def for_merge(cls, session: Session, actor_id: int | None, task: Task) -> MergeActor:
        author_id = actor_id or task.requester_id
        author = session.get(User, author_id) if author_id else None
        if author is None:
            return cls(user_id=None, role=Role.reviewer)
        return cls(user_id=author.id, role=Role(author.role))


class MergeRefused(Exception):
    """The editing rules kept refusing the merged edits (each pass drops the refused ones)."""


def drop_refused(session: Session, settings: Settings, run: Run, moves: list[MoveIn], deleted: list[int],
                 passes: int = 5) -> tuple[list[MoveIn], list[int], list[dict[str, Any]]]:
    """The merged edits the run's rules accept, and the refusals dropped on the way. Dropping a
    refused edit can make another refusable (the rules look at neighbours), hence the passes."""
    base = edits_service.edit_set_at(session, run, run.head_revision)
    problem = edits_service.load_problem(session, settings, run)
    dropped: list[dict[str, Any]] = []
    for _ in range(passes):
        batch = [Edit(m.index, m.lon, m.lat, m.alt) for m in moves]
        refusals = check_batch(problem, problem.cfg.rules, Edits.from_json(base), batch, deleted).refusals
        if not refusals:
            return moves, deleted, dropped
        refused = {int(r.index) for r in refusals}
        dropped += [r.to_json() for r in refusals]
        moves = [m for m in moves if m.index not in refused]
        deleted = [d for d in deleted if d not in refused]
    raise MergeRefused(f"run {run.id}: the merged edits kept being refused by the editing rules after {passes} passes")


def merge_task_run(session: Session, settings: Settings, task_run_id: int, actor_id: int | None, now: dt.datetime) -> dict[str, Any]:
    """Worker side of a merge: submit the merged edits as a new revision of the run."""
    tr = session.get(TaskRun, task_run_id)
    if tr is None:
        return {"skipped": "task run gone"}
    if tr.status == TaskRunStatus.merged:
        return {"task_run_id": tr.id, "revision": tr.merged_revision, "already_merged": True}
    task = session.get(Task, tr.task_id)
    run = session.get(Run, tr.run_id)
    assert task is not None and run is not None
    approved = [a for a in repo.run_assignments(session, tr.id) if a.status == AssignmentStatus.approved]
    moves, deleted, detail = merged_edits(session, tr, approved)
    moves, deleted, dropped = drop_refused(session, settings, run, moves, deleted)
    batch, job_id, _flags = edits_service.submit(
        session, settings, MergeActor.for_merge(session, actor_id, task), run, base=run.head_revision, moves=moves,
        deleted=deleted, accept=True, task_id=task.id,
        comment=f"task {task.id}: merged from assignment(s) {', '.join(map(str, detail['from']))}",
    )
    before = tr.status
    tr.status = TaskRunStatus.merged
    tr.merge_batch_id = batch.id
    tr.merged_revision = batch.revision
    tr.merge_detail = {**detail, "dropped": dropped, "moves": len(moves), "deleted": len(deleted), "job_id": job_id}
    tr.updated_at = now
    repo.record(session, task_id=task.id, entity="task_run", task_run_id=tr.id, from_status=before, to_status=tr.status,
                actor_id=actor_id, at=now, reason="merged", detail={"revision": batch.revision, "batch_id": batch.id})
    session.flush()
    finish_task(session, task, now)
    return {"task_run_id": tr.id, "revision": batch.revision, "batch_id": batch.id, "revision_job_id": job_id}
