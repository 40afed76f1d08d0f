"""Merge: once every submission of a run is decided, the approved work becomes one new
revision of the run (through the worker), written for a real author: the operator-weighted
fusion of the approved tracks, unless the evidence says it would make the run worse."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.db import utcnow
from posefix.edits import repository as edits_repo
from posefix.edits import service as edits_service
from posefix.edits.models import BatchStatus, EditBatch
from posefix.errors import Conflict
from posefix.edits.schemas import MoveIn
from posefix.jobs import repository as jobs
from posefix.engine import Edit, Edits
from posefix.engine.edits import check_batch
from posefix.runs import repository as runs_repo
from posefix.runs.models import Run
from posefix.tasks import repository as repo
from posefix.tasks.models import Assignment, AssignmentStatus, Task, TaskRun, TaskRunStatus
from posefix.tasks.states import MERGE_JOB, finish_task, local_m, to_lonlat
from posefix.tasks.fusion import SIGMA_FLOOR_M
from posefix.tasks.weighing import Weighing, weigh
from posefix.users.models import Role, User

INPUT_ALPHA = 0.05  # how sure the evidence must be that the merge beats the input (see merge_safe)
MIN_SHARE = 0.05  # a submission below this share of the fused weight is left out of the merge (outweighed)


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
                 wg: Weighing | None = None) -> tuple[list[MoveIn], list[int], dict[str, Any], Weighing | None]:
    """Moves and deletions of the merged result: one submission's own edits, or the
    operator-weighted fusion (``weighing``) of the contributors' corrected tracks at every
    keyframe any of them moved; a keyframe is deleted when most contributors deleted it.
    ``contributors``: the assignment ids whose work is merged (default: all of ``subs``).
    Also returns the JSON detail and the weighing the fusion used (``wg`` for one submission)."""
    ids = contributors if contributors is not None else {a.id for a in subs}
    approved = [a for a in subs if a.id in ids]
    if len(approved) == 1:
        es = approved[0].edit_set or {}
        moves = [MoveIn(index=int(m[0]), lon=m[1], lat=m[2], alt=m[3]) for m in es.get("moves", [])]
        return moves, [int(d) for d in es.get("deleted", [])], {"from": [approved[0].id], "method": "single"}, wg
    wg = wg or weigh(session, tr, subs, ids)
    # work that carries (almost) no weight is left out altogether, so it cannot pull at all
    outweighed = {aid for aid, w in zip(wg.ids, wg.weight_share) if aid in ids and w < MIN_SHARE}
    if outweighed and ids - outweighed:
        ids = ids - outweighed
        approved = [a for a in approved if a.id in ids]
        wg = weigh(session, tr, subs, ids)
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
        sig = edit_sigma_m(wg, keep)
        moves = [MoveIn(index=k, lon=float(lo), lat=float(la), sigma=None if s is None else round(s, 3))
                 for k, lo, la, s in zip(keep, lon, lat, sig)]
    share = wg.weight_share
    weights = {str(aid): round(float(w), 4) for aid, w in zip(wg.ids, share) if aid in ids}
    sig = wg.fused.sigma_m[keep] if keep else np.array([])
    carried = [m.sigma for m in moves if m.sigma is not None]
    return moves, deleted, {"from": sorted(ids), "outweighed": sorted(outweighed), "method": wg.method, "weights": weights,
                            "sigma_m": None if not len(sig) or np.all(np.isnan(sig)) else round(float(np.nanmedian(sig)), 3),
                            "edit_sigma_m": round(float(np.median(carried)), 3) if carried else None}, wg


def edit_sigma_m(wg: Weighing, k: list[int]) -> list[float | None]:
    """The horizontal 1-sigma each merged move carries into the correction (``Edit.sigma_m``):
    the fused position's own scatter, 1 / sqrt(W_k) of the contributors' weights, not the
    level's uncertainty (an offset shared by every fused keyframe, which holding the edits
    more loosely cannot average away) nor the t-distribution's allowance. None (the engine's
    configured sigma) where the fusion weighed nobody (the geometric median: nothing known)."""
    if wg.method != "weighted":
        return [None] * len(k)
    wsum = wg.fused.w[:, k].sum(axis=0)
    return [float(max(1.0 / np.sqrt(w), SIGMA_FLOOR_M)) if w > 0 else None for w in wsum]


def merge_safe(session: Session, tr: TaskRun, moves: list[MoveIn], wg: Weighing) -> str | None:
    """None when the merge may go ahead, else why not. Two tests at the keyframes it moves:

    - trusted operators: the merged positions are further than the run's input from every
      operator whose accuracy was measured against the truth on gold runs, whatever this
      run's review made of their work (a reviewer backing a bad majority);
    - measured accuracy: the merge must be the better of the two. With ``P_k`` the fused
      position's per-axis variance and ``d_k`` the input's distance from it,
      ``E|d_k|^2 = e_in^2 + 2 P_k``; were the input as good as the merge (``e_in^2 = 2 P_k``,
      so ``d_k`` has per-axis variance ``2 P_k``) ``T = sum_k |d_k|^2 / (2 P_k)`` would be
      chi-square with ``2 n`` dof; the merge goes ahead only when ``T`` is beyond its
      ``1 - INPUT_ALPHA`` quantile (the input is measurably worse).
    """
    if not moves:
        return None
    k = [m.index for m in moves]
    merged = local_m(np.array([m.lon for m in moves]), np.array([m.lat for m in moves]), wg.origin)
    cols = runs_repo.keyframe_columns(session, tr.run_id)
    inp = local_m(np.array([cols[j][3] for j in k]), np.array([cols[j][4] for j in k]), wg.origin)
    trusted = [i for i in range(len(wg.ids)) if wg.accuracy_m[i] is not None]
    if trusted and not any(float(np.mean(np.linalg.norm(merged - wg.x_m[i, k], axis=1)))
                           <= float(np.mean(np.linalg.norm(inp - wg.x_m[i, k], axis=1))) for i in trusted):
        return (f"the merged positions are further than the input from every trusted operator "
                f"(assignments {', '.join(str(wg.ids[i]) for i in trusted)})")
    p_m2 = merged_variance_m2(wg, k)
    if p_m2 is None:
        return None
    d2 = np.sum((inp - merged) ** 2, axis=1)
    stat = float(np.sum(d2 / (2.0 * p_m2)))
    if stat > float(stats.chi2.ppf(1.0 - INPUT_ALPHA, 2 * len(k))):
        return None
    rms_in = float(np.sqrt(max(np.mean(d2 - 2.0 * p_m2), 0.0)))
    rms_merge = float(np.sqrt(np.mean(2.0 * p_m2)))
    return (f"the input is not measurably worse than the merge (estimated error {rms_in:.2f} m against the "
            f"merge's {rms_merge:.2f} m at the {len(k)} moved keyframes)")


def merged_variance_m2(wg: Weighing, k: list[int]) -> np.ndarray | None:
    """(len(k),) per-axis variance of the merged positions: the fusion's, else (nothing known
    of the operators) the spread of the merged tracks about their median, shared equally."""
    sig = wg.fused.sigma_m[k]
    if np.all(np.isfinite(sig)):
        return np.maximum(sig, SIGMA_FLOOR_M) ** 2
    w = wg.fused.w[:, k] > 0
    n = w.sum(axis=0)
    if np.any(n < 2):
        return None
    r2 = np.sum((wg.x_m[:, k] - wg.fused.t_m[None, k]) ** 2, axis=2)
    s2 = float(np.sum(np.where(w, r2, 0.0)) / (2.0 * np.sum(n - 1)))   # per-axis variance of one track
    return np.maximum(s2 / n, SIGMA_FLOOR_M ** 2)


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
        batch = [Edit(m.index, m.lon, m.lat, m.alt, m.sigma) for m in moves]
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
    if tr.status != TaskRunStatus.merging or tr.merge_batch_id is not None:
        return {"task_run_id": tr.id, "skipped": f"task run is {tr.status}", "batch_id": tr.merge_batch_id}
    task = session.get(Task, tr.task_id)
    run = session.get(Run, tr.run_id)
    assert task is not None and run is not None
    approved = [a for a in repo.run_assignments(session, tr.id) if a.status == AssignmentStatus.approved]
    subs = [a for a in repo.run_assignments(session, tr.id) if a.status in (AssignmentStatus.approved, AssignmentStatus.rejected)
            and a.evaluated_at is not None]
    wg = weigh(session, tr, subs, {a.id for a in approved}) if len(subs) > 1 else None
    moves, deleted, detail, wg = merged_edits(session, tr, subs, {a.id for a in approved}, wg=wg)
    why = merge_safe(session, tr, moves, wg) if wg is not None else None
    if why is not None:
        return _stop(session, task, tr, why, detail, actor_id, now)
    moves, deleted, dropped = drop_refused(session, settings, run, moves, deleted)
    batch, job_id, _flags = edits_service.submit(
        session, settings, MergeActor.for_merge(session, actor_id, task), run, base=run.head_revision, moves=moves,
        deleted=deleted, accept=True, task_id=task.id,
        comment=f"task {task.id}: merged from assignment(s) {', '.join(map(str, detail['from']))}",
    )
    # merged once the revision is written (follow_batch); until then it is still merging
    tr.merge_batch_id = batch.id
    tr.merge_detail = {**detail, "dropped": dropped, "moves": len(moves), "deleted": len(deleted), "job_id": job_id,
                       "revision": batch.revision}
    tr.updated_at = now
    repo.record(session, task_id=task.id, entity="task_run", task_run_id=tr.id, from_status=tr.status, to_status=tr.status,
                actor_id=actor_id, at=now, reason="merge submitted", detail={"revision": batch.revision, "batch_id": batch.id})
    session.flush()
    return {"task_run_id": tr.id, "revision": batch.revision, "batch_id": batch.id, "revision_job_id": job_id}


def _move_run(session: Session, tr: TaskRun, to: TaskRunStatus, now: dt.datetime, reason: str, *,
              actor_id: int | None = None, detail: dict[str, Any] | None = None) -> None:
    before = tr.status
    tr.status = to
    tr.updated_at = now
    repo.record(session, task_id=tr.task_id, entity="task_run", task_run_id=tr.id, from_status=before, to_status=to,
                actor_id=actor_id, at=now, reason=reason, detail=detail)
    session.flush()


def follow_batch(session: Session, batch: EditBatch) -> None:
    """The merge's batch moved (``edits.repository.on_task_batch``): the task run follows it:
    written -> merged, failed or discarded -> merge_failed (with the batch's error), retried ->
    merging again."""
    tr = repo.task_run_of_batch(session, batch.id)
    if tr is None:
        return
    now = utcnow()
    if batch.status == BatchStatus.ready and tr.status in (TaskRunStatus.merging, TaskRunStatus.merge_failed):
        tr.merged_revision = batch.revision
        _move_run(session, tr, TaskRunStatus.merged, now, "merged", detail={"revision": batch.revision, "batch_id": batch.id})
        task = session.get(Task, tr.task_id)
        assert task is not None
        finish_task(session, task, now)
    elif batch.status in (BatchStatus.failed, BatchStatus.discarded) and tr.status in (TaskRunStatus.merging, TaskRunStatus.merged):
        tr.merged_revision = None
        tr.merge_detail = {**(tr.merge_detail or {}), "failed": batch.error or f"revision batch {batch.status}"}
        _move_run(session, tr, TaskRunStatus.merge_failed, now, "merge failed",
                  detail={"batch_id": batch.id, "error": (batch.error or batch.status)[:500]})
    elif batch.status == BatchStatus.pending and tr.status == TaskRunStatus.merge_failed:
        _move_run(session, tr, TaskRunStatus.merging, now, "merge retried", detail={"batch_id": batch.id})


def fail_merge(session: Session, task_run_id: int, why: str, now: dt.datetime) -> None:
    """The merge job itself failed (refused edits, or it died): say so; a reviewer may merge again."""
    tr = session.get(TaskRun, task_run_id)
    if tr is None or tr.status != TaskRunStatus.merging or tr.merge_batch_id is not None:
        return
    tr.merge_detail = {**(tr.merge_detail or {}), "failed": why[:1000]}
    _move_run(session, tr, TaskRunStatus.merge_failed, now, "merge failed", detail={"error": why[:500]})


def retry_merge(session: Session, tr: TaskRun, now: dt.datetime, *, actor_id: int | None) -> TaskRun:
    """Merge a run whose merge failed again, from the approved work, on the run's latest
    revision (the failed batch is closed: the new merge replaces it)."""
    if tr.status != TaskRunStatus.merge_failed:
        raise Conflict(f"task run {tr.id} is {tr.status}; only a failed merge can be retried", code="not_merge_failed",
                       extra={"status": tr.status})
    old = edits_repo.batch(session, tr.merge_batch_id) if tr.merge_batch_id is not None else None
    tr.merge_batch_id = None
    if old is not None and old.status == BatchStatus.failed:
        old.status = BatchStatus.discarded
    detail = dict(tr.merge_detail or {})
    detail.pop("failed", None)
    tr.merge_detail = detail
    _move_run(session, tr, TaskRunStatus.merging, now, "merge retried", actor_id=actor_id)
    jobs.enqueue(session, MERGE_JOB, {"task_run_id": tr.id, "actor_id": actor_id}, run_id=tr.run_id, created_by=actor_id)
    session.flush()
    return tr


def sweep_dead_merges(session: Session, now: dt.datetime) -> int:
    """Runs still merging whose merge job is over without a batch (it died): merge_failed."""
    n = 0
    for tr in repo.merging_runs(session):
        if tr.merge_batch_id is None and not repo.pending_job(session, MERGE_JOB, tr.run_id):
            fail_merge(session, tr.id, "the merge job ended without writing a revision", now)
            n += 1
    return n
