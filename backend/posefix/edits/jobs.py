"""Worker job ``revision``: re-optimise a run with a batch's edit set, propagate to every
sample and write revision N exactly once.

Idempotent: if revision N already exists the job only reports it. Files are written under a
unique tag, each to a temporary name renamed into place, and count only once the revision's
row is committed (unique ``(run_id, number)``). Whoever finds the row committed (the run that
committed it, a run that lost the race, a re-run after a worker died mid-job) removes every
other file of revision N: those of runs that died before committing, half-written
temporaries included. Revisions whose job died for good are swept by the worker's cleanup
(``sweep_dead_revision_jobs``), which also fails their batch and rolls the run's head back
(``edits.failures``). A revision is committed only while its batch is still pending.
"""

from __future__ import annotations

import logging
import uuid
from typing import Any

from sqlalchemy import select, update
from sqlalchemy.exc import IntegrityError

from posefix.config import Settings
from posefix.db import Database
from posefix.edits import failures
from posefix.edits import repository as edits_repo
from posefix.edits.service import REVISION_JOB
from posefix.engine import EditRefusedError
from posefix.jobs.models import Job, JobStatus
from posefix.jobs.registry import JobContext, PermanentJobError, register, register_cleanup
from posefix.core.geodesy import horizontal_distance_m
from posefix.runs import solutions, storage
from posefix.runs.engine_config import engine_config
from posefix.runs import repository as runs_repo
from posefix.runs.models import Revision, Run
from posefix.filestore import file_store

log = logging.getLogger("posefix.worker")


def committed_files(db: Database, run_id: int, number: int) -> set[str] | None:
    """The files of revision ``number``'s committed row, or None when it has no row."""
    with db.transaction(write=False) as s:
        rev = runs_repo.revision(s, run_id, number)
        return None if rev is None else {rev.samples_file, rev.keyframes_file}


def sweep_after_commit(db: Database, fs: storage.FileStore, run_id: int, number: int) -> list[str]:
    """Once revision ``number`` is committed: remove every file of it its row does not name."""
    keep = committed_files(db, run_id, number)
    if keep is None:
        return []
    removed = storage.sweep_revision_files(fs, run_id, number, keep)
    if removed:
        log.info("run %s revision %s: removed %d files of uncommitted attempts", run_id, number, len(removed))
    return removed


class _NotPending(Exception):
    pass


@register(REVISION_JOB)
def compute_revision(ctx: JobContext, payload: dict[str, Any]) -> dict[str, Any]:
    try:
        run_id, batch_id, number = int(payload["run_id"]), int(payload["batch_id"]), int(payload["revision"])
    except (KeyError, TypeError, ValueError):
        raise PermanentJobError(f"bad revision job payload {payload!r}") from None
    settings = ctx.settings
    fs = file_store(settings)
    with ctx.db.transaction(write=False) as s:
        existing = runs_repo.revision(s, run_id, number)
        run = s.get(Run, run_id)
        batch = edits_repo.batch(s, batch_id)
        rev0 = runs_repo.revision(s, run_id, 0)
        if existing is None and (run is None or batch is None or rev0 is None):
            raise PermanentJobError(f"run {run_id} or batch {batch_id} no longer exists")
        if existing is None:
            assert run is not None and batch is not None and rev0 is not None
            rules, name, derived = dict(run.rules), run.name, run.orientation_derived
            edit_set, author = dict(batch.edit_set), batch.author_id
            kind, batch_status = batch.kind, batch.status
            samples0 = rev0.samples_file
            prev_number = batch.base_revision
    if existing is not None:
        removed = sweep_after_commit(ctx.db, fs, run_id, number)
        return {"run_id": run_id, "revision": number, "already_written": True, "removed_files": len(removed)}
    if batch_status != "pending":
        raise PermanentJobError(f"edit batch {batch_id} is {batch_status}; its revision is not computed")

    ctx.progress(0.05, "loading run")
    cfg = engine_config(settings, rules)

    def load() -> tuple[Any, Any]:
        pose = storage.read_samples(fs, samples0, orientation_derived=derived, source=name)
        return pose, cfg

    ctx.progress(0.2, "optimising keyframes")
    try:
        problem, sol = solutions.solve_revision(settings, run_id, rules, prev_number, edit_set, load)
    except EditRefusedError as exc:  # the correction itself is refused: solving again gives the same answer
        raise PermanentJobError(exc.refusals[0].message) from None
    ctx.progress(0.6, "propagating to every sample")
    corr = problem.full_run(sol)
    lon, lat, alt = problem.lonlatalt(sol)
    line_lon, line_lat = storage.decimate_line(corr.run.lon_deg, corr.run.lat_deg, settings.line_max_points)
    sigma = getattr(sol.drift.calibration, "sigma_m", None)
    arrays = storage.KeyframeArrays(
        lon_deg=lon, lat_deg=lat, alt_m=alt, heading_deg=storage.heading_deg(sol.keyframes.q_wxyz),
        line_lon_deg=line_lon, line_lat_deg=line_lat,
        sigma_m=None if sigma is None or len(sigma) != len(lon) else sigma,
    )
    ctx.progress(0.8, "writing revision")
    stem = f"runs/{run_id}/r{number}-{uuid.uuid4().hex[:8]}"
    samples_rel, kf_rel = f"{stem}.parquet", f"{stem}.npz"
    stored = solutions.StoredSolution.of(settings, kf_rel, cfg)
    mine = (samples_rel, kf_rel, stored.rel)
    try:
        storage.write_samples(fs, samples_rel, corr.run)
        storage.write_keyframes(fs, kf_rel, arrays)
        stored.save(sol)  # previews in every API process start from it instead of solving again
    except OSError:
        # Another run of this job may have committed meanwhile and swept our temporaries.
        for rel in mine:
            fs.remove(rel)
        if committed_files(ctx.db, run_id, number) is not None:
            return {"run_id": run_id, "revision": number, "already_written": True}
        raise
    rep_lon, rep_lat = problem.run.lon_deg[problem.keyframe_index], problem.run.lat_deg[problem.keyframe_index]
    max_corr = float(horizontal_distance_m(rep_lon, rep_lat, lon, lat).max())
    solver, drift = sol.solver.to_json(), sol.drift.to_json()
    try:
        with ctx.db.transaction() as s:
            if not edits_repo.mark_ready(s, batch_id):
                raise _NotPending
            s.add(Revision(
                run_id=run_id, number=number, kind=kind, batch_id=batch_id, created_by=author, edit_set=edit_set,
                solver=solver, drift=drift, samples_file=samples_rel, keyframes_file=kf_rel, max_correction_m=max_corr,
            ))
            s.flush()
            runs_repo.advance_revision(s, run_id, number)
            run = s.get(Run, run_id)
            assert run is not None
            runs_repo.record(s, run, author, "revision_ready", revision=number,
                             detail={"batch_id": batch_id, "job_id": ctx.job_id, "solver_status": solver["status"],
                                     "max_correction_m": round(max_corr, 3)})
    except IntegrityError:
        for rel in mine:
            fs.remove(rel)
        sweep_after_commit(ctx.db, fs, run_id, number)
        return {"run_id": run_id, "revision": number, "already_written": True}
    except _NotPending:
        for rel in mine:
            fs.remove(rel)
        if committed_files(ctx.db, run_id, number) is not None:  # another run of this job came first
            sweep_after_commit(ctx.db, fs, run_id, number)
            return {"run_id": run_id, "revision": number, "already_written": True}
        # the batch failed meanwhile (this run of the job outlived its lease): nothing is written
        return {"run_id": run_id, "revision": number, "already_written": False, "batch_failed": True}
    removed = sweep_after_commit(ctx.db, fs, run_id, number)
    solutions.PROBLEMS.put_solution(run_id, rules, number, sol)
    return {"run_id": run_id, "revision": number, "already_written": False, "solver": solver,
            "max_correction_m": max_corr, "removed_files": len(removed)}


@register_cleanup
def sweep_dead_revision_jobs(db: Database, settings: Settings) -> int:
    """Once per dead revision job: remove its revision's files (they will never be committed),
    then fail its batch and roll the run's head back, which frees the revision's number (so
    the files go first); returns how many files were removed."""
    fs = file_store(settings)
    with db.transaction(write=False) as s:
        dead = s.execute(
            select(Job.id, Job.payload, Job.last_error).where(Job.kind == REVISION_JOB, Job.status == JobStatus.dead,
                                                              Job.result.is_(None))
            .order_by(Job.id).limit(100)
        ).all()
    total = 0
    for job_id, payload, last_error in dead:
        removed: list[str] = []
        try:
            run_id, number, batch_id = int(payload["run_id"]), int(payload["revision"]), int(payload["batch_id"])
        except (KeyError, TypeError, ValueError):
            run_id = number = batch_id = -1
        if run_id >= 0 and committed_files(db, run_id, number) is None and _still_pending(db, batch_id):
            removed = storage.sweep_revision_files(fs, run_id, number, set())
        with db.transaction() as s:
            claimed = s.execute(update(Job).where(Job.id == job_id, Job.status == JobStatus.dead, Job.result.is_(None))
                                .values(result={"removed_files": removed})).rowcount == 1
            if claimed and batch_id >= 0:
                reason = (last_error or "the revision job died").split("\n", 1)[0]
                failures.fail_batch(s, batch_id, reason, job_id=job_id)
        total += len(removed)
    return total


def _still_pending(db: Database, batch_id: int) -> bool:
    """Whether the batch still holds its number (no other batch can be writing its files)."""
    with db.transaction(write=False) as s:
        batch = edits_repo.batch(s, batch_id)
        return batch is not None and batch.status == "pending"


__all__ = ["compute_revision", "sweep_dead_revision_jobs"]
