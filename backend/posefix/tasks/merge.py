"""Merge: once every submission of a run is decided, the approved work becomes one new
revision of the run (through the worker), written for a real author: the operator-weighted
fusion of the approved tracks, unless the evidence says it would make the run worse."""

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
from posefix.runs import repository as runs_repo
from posefix.runs.models import Run
from posefix.tasks import repository as repo
from posefix.tasks.models import Assignment, AssignmentStatus, Task, TaskRun, TaskRunStatus
from posefix.tasks.states import MERGE_JOB, finish_task, local_m, to_lonlat
from posefix.tasks.weighing import Weighing, weigh
from posefix.users.models import Role, User

MIN_SHARE = 0.05  # a submission below this share of the fused weight is listed as outweighed, not as a source


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


def merged_edits(session: Session, tr: TaskRun, subs: list[Assignment], contributors: set[int] | None = None,
                 wg: Weighing | None = None) -> tuple[list[MoveIn], list[int], dict[str, Any]]:
    """Moves and deletions of the merged result: one submission's own edits, or the
    operator-weighted fusion (``weighing``) of the contributors' corrected tracks at every
    keyframe any of them moved; a keyframe is deleted when most contributors deleted it.
    ``contributors``: the assignment ids whose work is merged (default: all of ``subs``)."""
    ids = contributors if contributors is not None else {a.id for a in subs}
    approved = [a for a in subs if a.id in ids]
    if len(approved) == 1:
        es = approved[0].edit_set or {}
        moves = [MoveIn(index=int(m[0]), lon=m[1], lat=m[2], alt=m[3]) for m in es.get("moves", [])]
        return moves, [int(d) for d in es.get("deleted", [])], {"from": [approved[0].id], "method": "single"}
    wg = wg or weigh(session, tr, subs, ids)
    moved = sorted({int(m[0]) for a in approved for m in (a.edit_set or {}).get("moves", [])})
    votes: dict[int, int] = {}
    for a in approved:
        for d in (a.edit_set or {}).get("deleted", []):
            votes[int(d)] = votes.get(int(d), 0) + 1
    deleted = sorted(d for d, n in votes.items() if 2 * n > len(approved))
    keep = [k for k in moved if k not in set(deleted) and not np.isnan(wg.fused.t_m[k, 0])]
    moves: list[MoveIn] = []
    if keep:
        lon, lat = to_lonlat(wg.fused.t_m[keep], wg.origin)
        moves = [MoveIn(index=k, lon=float(lo), lat=float(la)) for k, lo, la in zip(keep, lon, lat)]
    share = wg.weight_share
    weights = {str(aid): round(float(w), 4) for aid, w in zip(wg.ids, share) if aid in ids}
    # work that carries (almost) no weight did not shape the result
    used = [aid for aid, w in zip(wg.ids, share) if aid in ids and w >= MIN_SHARE]
    sig = wg.fused.sigma_m[keep] if keep else np.array([])
    return moves, deleted, {"from": used, "outweighed": sorted(ids - set(used)), "method": wg.method, "weights": weights,
                            "sigma_m": None if not len(sig) or np.all(np.isnan(sig)) else round(float(np.nanmedian(sig)), 3)}


def merge_safe(session: Session, tr: TaskRun, moves: list[MoveIn], wg: Weighing) -> str | None:
    """None when the merge may go ahead, else why not: the merged positions are further than
    the run's input from every trusted operator's track at the keyframes it moves, so the
    evidence says the merge makes the run worse. Trusted: an operator whose accuracy was
    measured against the truth on gold runs, whatever this run's review made of their work
    (the case to catch is a reviewer backing a bad majority)."""
    trusted = [i for i in range(len(wg.ids)) if wg.accuracy_m[i] is not None]
    if not moves or not trusted:
        return None
    k = [m.index for m in moves]
    merged = local_m(np.array([m.lon for m in moves]), np.array([m.lat for m in moves]), wg.origin)
    cols = runs_repo.keyframe_columns(session, tr.run_id)
    inp = local_m(np.array([cols[j][3] for j in k]), np.array([cols[j][4] for j in k]), wg.origin)
    closer = []
    for i in trusted:
        x = wg.x_m[i, k]
        closer.append(float(np.mean(np.linalg.norm(merged - x, axis=1))) <= float(np.mean(np.linalg.norm(inp - x, axis=1))))
    if any(closer):
        return None
    return (f"the merged positions are further than the input from every trusted operator "
            f"(assignments {', '.join(str(wg.ids[i]) for i in trusted)})")


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


def _stop(session: Session, task: Task, tr: TaskRun, why: str, detail: dict[str, Any], actor_id: int | None,
          now: dt.datetime) -> dict[str, Any]:
    before = tr.status
    tr.status = TaskRunStatus.unmerged
    tr.merge_detail = {**detail, "stopped": why}
    tr.updated_at = now
    repo.record(session, task_id=task.id, entity="task_run", task_run_id=tr.id, from_status=before, to_status=tr.status,
                actor_id=actor_id, at=now, reason="merge stopped", detail={"why": why})
    session.flush()
    finish_task(session, task, now)
    return {"task_run_id": tr.id, "stopped": why}


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
    subs = [a for a in repo.run_assignments(session, tr.id) if a.status in (AssignmentStatus.approved, AssignmentStatus.rejected)
            and a.evaluated_at is not None]
    wg = weigh(session, tr, subs, {a.id for a in approved}) if len(approved) > 1 else None
    moves, deleted, detail = merged_edits(session, tr, subs, {a.id for a in approved}, wg=wg)
    why = merge_safe(session, tr, moves, wg) if wg is not None else None
    if why is not None:
        return _stop(session, task, tr, why, detail, actor_id, now)
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
