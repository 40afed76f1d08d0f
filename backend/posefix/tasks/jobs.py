"""Worker jobs of the tasks domain (registered with web-core's job registry):

- ``tasks.evaluate``: solve a submission's edits with the engine, store the corrected keyframe
  track, score it against the truth on gold runs (``posefix.core.evaluate``), then update the
  run's consensus and conflicts;
- ``tasks.merge``: submit the approved/merged edits as a new revision of the run (the
  ``revision`` job then writes it);
- ``tasks.maintain``: expire leases, auto-approve, expire tasks; re-enqueues itself.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import replace
from typing import Any

import numpy as np

from posefix.core.evaluate import evaluate, position_errors_enu_m
from posefix.core.run import PoseRun
from posefix.db import utcnow
from posefix.jobs import repository as jobs
from posefix.jobs.registry import JobContext, PermanentJobError, register
from posefix.engine import Edits
from posefix.runs import solutions, storage
from posefix.runs.engine_config import engine_config
from posefix.runs import repository as runs_repo
from posefix.runs.models import Run
from posefix.tasks import clock
from posefix.tasks.maintenance import maintain as maintain_tasks
from posefix.tasks.maintenance import needs_maintenance
from posefix.edits.repository import on_task_batch
from posefix.tasks.merge import MergeRefused, fail_merge, follow_batch, merge_task_run
from posefix.tasks.states import EVALUATE_JOB, MAINTAIN_EVERY_S, MAINTAIN_JOB, MERGE_JOB
from posefix.tasks.submission import record_evaluation
from posefix.tasks.models import Assignment, GoldRun
from posefix.filestore import file_store


on_task_batch(follow_batch)  # the worker writes and fails revisions: a merge's run follows its batch


def _int(payload: dict[str, Any], key: str) -> int:
    try:
        return int(payload[key])
    except (KeyError, TypeError, ValueError):
        raise PermanentJobError(f"bad payload {payload!r}: needs integer {key}") from None


@register(EVALUATE_JOB)
def evaluate_submission(ctx: JobContext, payload: dict[str, Any]) -> dict[str, Any]:
    aid = _int(payload, "assignment_id")
    fs = file_store(ctx.settings)
    with ctx.db.transaction(write=False) as s:
        a = s.get(Assignment, aid)
        if a is None or a.edit_set is None:
            raise PermanentJobError(f"assignment {aid} has no submission")
        run = s.get(Run, a.run_id)
        rev0 = runs_repo.revision(s, a.run_id, 0)
        if run is None or rev0 is None:
            raise PermanentJobError(f"run {a.run_id} is gone")
        gold = s.get(GoldRun, a.run_id)
        truth_file = gold.truth_file if gold is not None else None
        edit_set, rules, name, derived, samples0 = dict(a.edit_set), dict(run.rules), run.name, run.orientation_derived, rev0.samples_file
        run_id = run.id

    def load() -> tuple[Any, Any]:
        pose = storage.read_samples(fs, samples0, orientation_derived=derived, source=name)
        return pose, engine_config(ctx.settings, rules)

    problem = solutions.PROBLEMS.problem(run_id, rules, load)
    ctx.progress(0.2, "optimising the submission")
    sol = problem.solve_edits(Edits.from_json(edit_set))
    lon, lat, _ = problem.lonlatalt(sol)
    corrected = np.round(np.column_stack([lon, lat]), 8).tolist()
    gold_error = None
    if truth_file is not None:
        ctx.progress(0.6, "scoring against the truth")
        truth = storage.read_samples(fs, truth_file, orientation_derived=False, source=f"truth of {name}")
        gold_error = gold_error_m(truth, problem.full_run(sol).run, problem.run.take(problem.keyframe_index), edit_set)
    def reoptimise(es: dict[str, Any]) -> np.ndarray:
        lo, la, _ = problem.lonlatalt(problem.solve_edits(Edits.from_json(es)))
        return np.column_stack([lo, la])

    with ctx.db.transaction() as s:
        record_evaluation(s, aid, corrected, gold_error, clock.now(), reoptimise)
    return {"assignment_id": aid, "gold_error_m": gold_error}


def gold_error_m(truth: PoseRun, solved: PoseRun, keyframes: PoseRun, edit_set: dict[str, Any]) -> float:
    """A submission's error on a gold run: the worse of its corrected track's mean horizontal
    error and the mean error of the keyframes the operator placed. The engine's solve draws a
    track through sparse placements with the IMU, so the track alone credits a clicker with
    the IMU's work (a 4 m clicker reads ~3 m); the placements alone would excuse what the
    operator left uncorrected."""
    track = float(evaluate(truth, solved).horizontal.mean_m)
    own = {int(k) for k in edit_set.get("own_moves", [])}
    placed = [m for m in edit_set.get("moves", []) if int(m[0]) in own and 0 <= int(m[0]) < keyframes.n]
    if not placed:
        return track
    rows = keyframes.take(np.array([int(m[0]) for m in placed]))
    clicks = replace(rows, lon_deg=np.array([float(m[1]) for m in placed]), lat_deg=np.array([float(m[2]) for m in placed]))
    e, _inside = position_errors_enu_m(truth, clicks)
    return max(track, float(np.mean(np.hypot(e[:, 0], e[:, 1])))) if len(e) else track


@register(MERGE_JOB)
def merge(ctx: JobContext, payload: dict[str, Any]) -> dict[str, Any]:
    trid = _int(payload, "task_run_id")
    actor = payload.get("actor_id")
    try:
        with ctx.db.transaction() as s:
            return merge_task_run(s, ctx.settings, trid, int(actor) if actor else None, clock.now())
    except MergeRefused as exc:
        with ctx.db.transaction() as s:
            fail_merge(s, trid, str(exc), clock.now())
        return {"task_run_id": trid, "failed": str(exc)}


@register(MAINTAIN_JOB)
def maintain(ctx: JobContext, payload: dict[str, Any]) -> dict[str, Any]:
    with ctx.db.transaction() as s:
        counts = maintain_tasks(s, clock.now())
    with ctx.db.transaction() as s:
        # keep ticking only while something can still expire or be auto-approved; creating a
        # task or submitting work starts it again (posefix.tasks.states.ensure_maintenance)
        if needs_maintenance(s):
            nxt = jobs.enqueue(s, MAINTAIN_JOB, {}, max_attempts=1000)
            nxt.run_after = utcnow() + dt.timedelta(seconds=MAINTAIN_EVERY_S)
            counts["next_in_s"] = MAINTAIN_EVERY_S
    return counts
