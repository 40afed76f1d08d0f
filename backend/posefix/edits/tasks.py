"""Worker job ``revision``: re-optimise a run with a batch's edit set, propagate to every
sample and write revision N exactly once.

Idempotent: if revision N already exists the job only reports it; files are written under a
unique tag first, and if the row insert loses to another run of the same job (unique
``(run_id, number)``) this run's files are removed.
"""

from __future__ import annotations

import uuid
from typing import Any

from sqlalchemy.exc import IntegrityError

from posefix.edits import repository as edits_repo
from posefix.edits.service import REVISION_JOB
from posefix.jobs.registry import JobContext, PermanentJobError, register
from posefix.runs import correction, storage
from posefix.runs import repository as runs_repo
from posefix.runs.models import Revision, Run



@register(REVISION_JOB)
def compute_revision(ctx: JobContext, payload: dict[str, Any]) -> dict[str, Any]:
    try:
        run_id, batch_id, number = int(payload["run_id"]), int(payload["batch_id"]), int(payload["revision"])
    except (KeyError, TypeError, ValueError):
        raise PermanentJobError(f"bad revision job payload {payload!r}") from None
    settings = ctx.settings
    fs = storage.FileStore(settings.files_dir)
    with ctx.db.transaction(write=False) as s:
        existing = runs_repo.revision(s, run_id, number)
        if existing is not None:
            return {"run_id": run_id, "revision": number, "already_written": True}
        run = s.get(Run, run_id)
        batch = edits_repo.batch(s, batch_id)
        rev0 = runs_repo.revision(s, run_id, 0)
        if run is None or batch is None or rev0 is None:
            raise PermanentJobError(f"run {run_id} or batch {batch_id} no longer exists")
        rules, name, derived = dict(run.rules), run.name, run.orientation_derived
        edit_set, author = dict(batch.edit_set), batch.author_id
        kind = batch.kind
        samples0 = rev0.samples_file
        prev_number = batch.base_revision

    ctx.progress(0.05, "loading run")

    def load() -> tuple[Any, Any]:
        pose = storage.read_samples(fs, samples0, orientation_derived=derived, source=name)
        return pose, correction.engine_config(settings, rules)

    problem = correction.PROBLEMS.problem(run_id, rules, load)
    ctx.progress(0.2, "optimising keyframes")
    warm = correction.PROBLEMS.solution(run_id, rules, prev_number)
    sol = correction.solve(problem, edit_set, warm)
    ctx.progress(0.6, "propagating to every sample")
    corr = problem.full_run(sol)
    lon, lat, alt = correction.keyframe_lonlatalt(problem, sol)
    line_lon, line_lat = storage.decimate_line(corr.run.lon_deg, corr.run.lat_deg, settings.line_max_points)
    arrays = storage.KeyframeArrays(
        lon_deg=lon, lat_deg=lat, alt_m=alt, heading_deg=storage.heading_deg(sol.keyframes.q_wxyz),
        line_lon_deg=line_lon, line_lat_deg=line_lat,
    )
    ctx.progress(0.8, "writing revision")
    tag = uuid.uuid4().hex[:8]
    samples_rel = storage.write_samples(fs, f"runs/{run_id}/r{number}-{tag}.parquet", corr.run)
    kf_rel = storage.write_keyframes(fs, f"runs/{run_id}/r{number}-{tag}.npz", arrays)
    rep_lon, rep_lat = problem.run.lon_deg[problem.keyframe_index], problem.run.lat_deg[problem.keyframe_index]
    max_corr = float(correction.horizontal_distance_m(rep_lon, rep_lat, lon, lat).max())
    solver, drift = correction.solver_json(sol), correction.drift_json(sol)
    try:
        with ctx.db.transaction() as s:
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
        fs.remove(samples_rel)
        fs.remove(kf_rel)
        return {"run_id": run_id, "revision": number, "already_written": True}
    correction.PROBLEMS.put_solution(run_id, rules, number, sol)
    return {"run_id": run_id, "revision": number, "already_written": False, "solver": solver,
            "max_correction_m": max_corr}


__all__ = ["compute_revision"]
