"""A run's consensus once every wanted submission is in and evaluated: the consensus track,
the conflicts between submissions, and the task's conflict policy (extra assignment, or
agreed / conflict); numerics in ``posefix.tasks.fusion`` and ``posefix.tasks.consensus``."""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from posefix.core import geodesy
from posefix.tasks import consensus
from posefix.tasks import repository as repo
from posefix.tasks.merge import maybe_merge, merged_edits
from posefix.tasks.models import Assignment, AssignmentStatus, Task, TaskRun, TaskRunStatus, TaskStatus
from posefix.tasks.states import local_m, move_task, slot, to_lonlat
from posefix.tasks.weighing import weigh

OFF_CONSENSUS = "off the weighted consensus by more than the operator's accuracy explains"
Reoptimise = Callable[[dict[str, Any]], np.ndarray]  # edit set -> (k, 2) lon, lat solved by the engine


def update_consensus(session: Session, task_run_id: int, now: dt.datetime, reoptimise: Reoptimise | None = None) -> None:
    """When every wanted submission of a run is in and evaluated: consensus, conflicts, policy."""
    tr = session.get(TaskRun, task_run_id)
    task = session.get(Task, tr.task_id) if tr else None
    if tr is None or task is None or tr.status not in (TaskRunStatus.open,):
        return
    rows = repo.run_assignments(session, tr.id)
    pending = [a for a in rows if a.status in (AssignmentStatus.open, AssignmentStatus.accepted)]
    done = [a for a in rows if a.status in repo.SUBMITTED_OR_BETTER]
    if pending or not done or any(a.evaluated_at is None for a in done):
        return
    result = compute_consensus(session, tr, task, done, reoptimise)
    tr.consensus, tr.disagreement_m, tr.conflicts = result["consensus"], result["disagreement_m"], result["conflicts"]
    for a, err in zip(done, result["consensus_error_m"]):
        a.consensus_error_m = err
    _hold(session, task, tr, [a for a in done if a.id in set(result["held"])], now, result["held_why"])
    before = tr.status
    if result["blocking"] and task.conflict_policy == "extend" and tr.extra_added < task.max_extra_assignments \
            and task.status in repo.ACTIVE_TASK + (TaskStatus.reviewable,):
        tr.extra_added += 1
        tr.wanted += 1
        repo.add_open_slots(session, [slot(tr, now)])
        repo.record(session, task_id=task.id, entity="task_run", task_run_id=tr.id, from_status=before, to_status=before,
                    at=now, reason="extra assignment requested", detail={"conflicts": len(tr.conflicts or [])})
        if task.status == TaskStatus.reviewable:
            move_task(session, task, TaskStatus.in_progress, now, reason="extra assignment requested")
        tr.updated_at = now
        session.flush()
        return
    tr.status = TaskRunStatus.conflict if result["blocking"] else TaskRunStatus.agreed
    tr.updated_at = now
    repo.record(session, task_id=task.id, entity="task_run", task_run_id=tr.id, from_status=before, to_status=tr.status,
                at=now, reason="conflict flagged" if result["blocking"] else "submissions agree",
                detail={"conflicts": len(tr.conflicts or [])})
    session.flush()
    if repo.remaining_open_runs(session, task.id, (TaskRunStatus.open,)) == 0:
        move_task(session, task, TaskStatus.reviewable, now, reason="all submissions in")
    maybe_merge(session, tr, now, actor_id=None)


def _hold(session: Session, task: Task, tr: TaskRun, off: list[Assignment], now: dt.datetime, why: str) -> None:
    """Work off the consensus waits for a reviewer: no auto-approval."""
    for a in off:
        if a.status == AssignmentStatus.submitted and a.auto_approve_at is not None:
            a.auto_approve_at = None
            repo.record(session, task_id=task.id, entity="assignment", assignment_id=a.id, task_run_id=tr.id,
                        from_status=a.status, to_status=a.status, at=now, reason="held for review",
                        detail={"why": why})


def compute_consensus(session: Session, tr: TaskRun, task: Task, done: list[Assignment],
                      reoptimise: Reoptimise | None = None) -> dict[str, Any]:
    """The consensus track, the submissions off it, and whether the run is in conflict.

    Consensus: the operator-weighted robust fusion per keyframe (``weighing``; the geometric
    median while nothing is known of the operators); with ``reoptimise`` (the engine, in the
    worker), the fused positions at the keyframes anyone moved (and the majority's deletions,
    as the merge would submit them) are re-optimised by the engine into one consistent track.

    Off the consensus: a submission its operator's measured accuracy does not explain
    (chi-square, ``weighing.ALPHA``); it is held for a reviewer, and so is the whole run
    while the evidence cannot tell which of the rest is right (``Weighing.settled``). The run is in conflict when
    half or more of its submissions are off (no majority to trust). With nothing known, the
    task's fixed distances decide, as the only evidence there is."""
    wg = weigh(session, tr, done)
    x_m, valid, origin = wg.x_m, wg.valid, wg.origin
    fused_m = np.where(np.isnan(wg.fused.t_m), x_m[0], wg.fused.t_m)  # a keyframe all deleted: removed anyway
    if reoptimise is not None:
        moves, deleted, _, _ = merged_edits(session, tr, done, wg=wg)
        solved = np.asarray(reoptimise({"moves": [[m.index, m.lon, m.lat, m.alt] for m in moves], "deleted": deleted, "flags": []}))
        lon, lat = solved[:, 0], solved[:, 1]
        fused_m = local_m(lon, lat, origin)
    else:
        lon, lat = to_lonlat(fused_m, origin)
    ids = [a.id for a in done]
    if wg.test is None:
        conflicts, blocking = _fixed_conflicts(task, done, x_m, valid, fused_m, origin)
        held: list[int] = []
        held_why = ""
    else:
        off = np.flatnonzero(wg.flagged)
        conflicts = [{"kind": "off_consensus", "a": ids[i], "keyframes": len(wg.moved),
                      "distance_m": round(float(wg.test.distance_m[i]), 3), "expected_m": round(float(wg.test.expected_m[i]), 3),
                      "statistic": round(float(wg.test.statistic[i]), 1), "dof": int(wg.test.dof[i]),
                      "p": float(wg.test.p[i])} for i in off]
        blocking = 2 * len(off) >= len(done)
        # work nobody can yet tell right from wrong waits for a reviewer (and for more evidence)
        held = [ids[i] for i in off] if wg.settled else ids
        held_why = (OFF_CONSENSUS if wg.settled else
                    "the run's agreeing work comes from operators never measured, beside work off the consensus: "
                    "nothing yet tells which is right")
    err = np.linalg.norm(x_m - fused_m[None], axis=2)                   # (m, k)
    consensus_error = [float(err[i][valid[i]].mean()) if valid[i].any() else 0.0 for i in range(len(done))]
    return {
        "consensus": np.round(np.column_stack([lon, lat]), 8).tolist(),
        "disagreement_m": np.round(consensus.disagreement_m(x_m, valid), 3).tolist(),
        "conflicts": conflicts, "consensus_error_m": consensus_error, "blocking": blocking, "held": held,
        "held_why": held_why,
        "method": wg.method,
    }


def _fixed_conflicts(task: Task, done: list[Assignment], x_m: np.ndarray, valid: np.ndarray, centre_m: np.ndarray,
                     origin: geodesy.EnuOrigin) -> tuple[list[dict[str, Any]], bool]:
    """Tracks and moves further apart than the task's fixed distances (nothing known of the operators)."""
    tracks = consensus.track_conflicts(x_m, task.conflict_distance_m, task.conflict_keyframes, valid)
    moves_m = []
    for a in done:
        es = a.edit_set or {}
        own = set(es.get("own_moves", []))
        mv = [m for m in es.get("moves", []) if int(m[0]) in own]
        if mv:
            xy = local_m(np.array([m[1] for m in mv]), np.array([m[2] for m in mv]), origin)
            moves_m.append({int(m[0]): xy[j] for j, m in enumerate(mv)})
        else:
            moves_m.append({})
    edits = consensus.edit_conflicts(moves_m, task.conflict_edit_m)
    ids = [a.id for a in done]
    conflicts = [{**c.to_json(), "a": ids[c.a], "b": ids[c.b]} for c in tracks] + [
        {**c.to_json(), "a": ids[c.a], "b": ids[c.b]} for c in edits]
    blocking = bool(conflicts)
    if blocking and len(done) >= 3:
        # plurality: the consensus stands when most tracks agree with it
        outliers = consensus.track_conflicts(np.concatenate([centre_m[None], x_m]), task.conflict_distance_m,
                                             task.conflict_keyframes,
                                             np.concatenate([np.ones((1, valid.shape[1]), bool), valid]))
        away = {c.b - 1 for c in outliers if c.a == 0}
        blocking = len(away) * 2 >= len(done)
    return conflicts, blocking
