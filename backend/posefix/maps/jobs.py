"""Worker jobs: ``floorplan.build`` (build a floor plan's model file and record its size)
and ``run.suggestions`` (match a run's keyframes to OpenStreetMap; the answer is the job's
result). Both are idempotent: a second run computes the same thing again.
"""

from __future__ import annotations

from typing import Any

from posefix.jobs.registry import JobContext, PermanentJobError, register
from posefix.maps import repository as repo
from posefix.maps.models import FloorPlanStatus
from posefix.maps.service import BUILD_JOB, build_model
from posefix.maps.suggestions import SUGGEST_JOB, suggest


@register(BUILD_JOB)
def build_floorplan(ctx: JobContext, payload: dict[str, Any]) -> dict[str, Any]:
    fid = payload.get("floorplan_id")
    if not isinstance(fid, int):
        raise PermanentJobError(f"payload has no floorplan_id: {payload!r}")
    with ctx.db.transaction(write=False) as s:
        fp = repo.get(s, fid)
        if fp is None:
            raise PermanentJobError(f"floor plan {fid} is gone")
        s.expunge(fp)
    try:
        out = build_model(ctx.settings, fp, ctx.progress)
    except (ValueError, OSError) as exc:
        # A floor that cannot become a model never will: record why and stop retrying.
        with ctx.db.transaction() as s:
            fp = repo.get(s, fid)
            if fp is not None:
                fp.status, fp.error = FloorPlanStatus.failed, str(exc)[:2000]
        raise PermanentJobError(f"floor plan {fid}: {exc}") from exc
    with ctx.db.transaction() as s:
        fp = repo.get(s, fid)
        if fp is None:
            raise PermanentJobError(f"floor plan {fid} was deleted while its model was built")
        fp.status, fp.error = FloorPlanStatus.ready, None
        fp.n_vertices, fp.model_bytes, fp.build_s = out["n_vertices"], out["model_bytes"], out["build_s"]
    return {"floorplan_id": fid, **out}


@register(SUGGEST_JOB)
def run_suggestions(ctx: JobContext, payload: dict[str, Any]) -> dict[str, Any]:
    from posefix.errors import AppError
    from posefix.runs.models import Run

    ctx.progress(0.05, "reading the street map around the run")
    with ctx.db.transaction(write=False) as s:
        run = s.get(Run, payload.get("run_id"))
        if run is None:
            raise PermanentJobError(f"run {payload.get('run_id')} is gone")
        try:
            return suggest(s, ctx.settings, run, int(payload["revision"]), float(payload["cell_m"]),
                           str(payload.get("matcher", "grid")))  # a payload without a matcher was queued for the grid
        except AppError as exc:
            # No extract, no road near the run, revision gone: retrying will not help.
            raise PermanentJobError(exc.detail) from exc
