"""Worker job ``floorplan.build``: build a floor plan's model file and record its size.

Idempotent: a second run rebuilds the same file and writes the same row values.
"""

from __future__ import annotations

from typing import Any

from posefix.jobs.registry import JobContext, PermanentJobError, register
from posefix.maps import repository as repo
from posefix.maps.models import FloorPlanStatus
from posefix.maps.service import BUILD_JOB, build_model_files


@register(BUILD_JOB)
def build_floorplan(ctx: JobContext, payload: dict[str, Any]) -> dict[str, Any]:
    fid = payload.get("floorplan_id")
    if not isinstance(fid, int):
        raise PermanentJobError(f"payload has no floorplan_id: {payload!r}")
    with ctx.db.transaction(write=False) as s:
        fp = repo.get(s, fid)
        if fp is None:
            raise PermanentJobError(f"floor plan {fid} is gone")
        folder, source, cell_m = ctx.settings.files_dir / fp.folder, fp.source, fp.cell_m
    try:
        out = build_model_files(folder, source, cell_m, ctx.progress)
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
