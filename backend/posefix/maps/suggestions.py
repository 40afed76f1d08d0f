"""Map-matching suggestions for a pose run's keyframes (OpenStreetMap roads).

The keyframes of a ready revision (their corrected positions, the heading stored with them
and their times) are matched in a worker job (``run.suggestions``) by
:func:`posefix.roads.suggest_vehicle_run`: on the road network by default (``matcher``
"roads"), on the drivable-area grid when asked ("grid") or when most keyframes have no road
within reach. Reading the extract is most of a first call's cost, so the worker keeps the
road network and the grid's raster in memory (keyed by the extract's hash and the snapped
box), and a finished job for the same run, revision, matcher and cell size is reused.
An accepted suggestion is submitted through the normal edits path as a move of kind
``suggestion``; see docs/maps-api.md for how it is weighted.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.core.rules import EditRules, adjustable_mask
from posefix.db import on_commit
from posefix.errors import NotFound, Unprocessable
from posefix.jobs import repository as jobs
from posefix.runs import storage
from posefix.runs.models import Run
from posefix.users.service import Principal
from posefix.filestore import file_store

SUGGEST_JOB = "run.suggestions"

DEFAULT_OSM = Path(__file__).resolve().parents[3] / "data" / "osm" / "helsinki.osm.pbf"


def osm_path(settings: Settings) -> Path:
    """The extract to match against: ``POSEFIX_OSM_EXTRACT``, else the repository's Helsinki extract."""
    candidates = [settings.osm_extract] if settings.osm_extract else [DEFAULT_OSM, Path("data/osm/helsinki.osm.pbf").resolve()]
    for p in candidates:
        if p is not None and Path(p).is_file():
            return Path(p)
    raise NotFound(f"no OpenStreetMap extract at {candidates[0]}; set POSEFIX_OSM_EXTRACT to an .osm.pbf file",
                   code="osm_not_found")


def quaternion_from_heading(heading_deg_cw_from_north: np.ndarray) -> np.ndarray:
    """(n, 4) w,x,y,z yaw-only body->ENU quaternions for headings (deg clockwise from north)."""
    yaw = np.radians(90.0 - np.asarray(heading_deg_cw_from_north, dtype=float))  # CCW from east
    q = np.zeros((yaw.size, 4))
    q[:, 0], q[:, 3] = np.cos(yaw / 2.0), np.sin(yaw / 2.0)
    return q


def suggest(session: Session, settings: Settings, run: Run, revision: int | None, cell_m: float,
            matcher: str = "roads") -> dict[str, Any]:
    from posefix.edits.service import ready
    from posefix.roads import suggest_vehicle_run
    from posefix.runs import repository

    t0 = time.perf_counter()
    number = run.revision if revision is None else revision
    rev = ready(session, run, number)
    kf = storage.read_keyframes(file_store(settings), rev.keyframes_file)
    k = int(kf.lon_deg.size)
    if k < 2:
        raise Unprocessable(f"run {run.id} has {k} keyframe(s); matching needs two or more", code="too_few_keyframes")
    osm = osm_path(settings)
    t_s = np.array([row[2] for row in repository.keyframe_columns(session, run.id)], dtype=float)
    try:
        sug = suggest_vehicle_run(kf.lon_deg, kf.lat_deg, quaternion_from_heading(kf.heading_deg), osm,
                                  t_s=t_s if t_s.size == k else None, matcher=matcher, cell_m=cell_m)
    except ValueError as exc:
        # e.g. no drivable way near the run: the extract does not cover it.
        raise Unprocessable(f"run {run.id}: {exc}", code="no_match", extra={"file": osm.name}) from None
    deleted = {int(d) for d in (rev.edit_set or {}).get("deleted", [])}
    adjustable = adjustable_mask(k, EditRules.from_json(run.rules))
    items = [
        {"index": i, "lon": round(float(sug.lonlat_deg[i, 0]), 8), "lat": round(float(sug.lonlat_deg[i, 1]), 8),
         "moved_m": round(float(sug.moved_m[i]), 3), "off_road": bool(sug.off_road[i]),
         "sigma_m": round(float(sug.sigma_m[i]), 3), "adjustable": bool(adjustable[i]) and i not in deleted}
        for i in range(k)
    ]
    return {
        "run_id": run.id, "revision": number, "osm": osm.name, "matcher": sug.matcher, "n_vertices": int(sug.n_vertices),
        "time_ms": round((time.perf_counter() - t0) * 1000, 1), "off_road": int(np.sum(sug.off_road)), "items": items,
    }


def request_suggestions(session: Session, settings: Settings, principal: Principal, run: Run, revision: int | None,
                        cell_m: float, wake: Any = None, matcher: str = "roads") -> dict[str, Any]:
    """Queue the matching of a ready revision (or reuse a finished or running job for it)."""
    from posefix.edits.service import ready

    number = run.revision if revision is None else revision
    ready(session, run, number)
    osm_path(settings)  # 404 now rather than a dead job
    payload = {"run_id": run.id, "revision": number, "cell_m": cell_m, "matcher": matcher}
    for job in jobs.live_for_run(session, SUGGEST_JOB, run.id):
        if job.payload == payload:
            return {"job_id": job.id, "status": job.status, "run_id": run.id, "revision": number}
    job = jobs.enqueue(session, SUGGEST_JOB, payload, run_id=run.id, created_by=principal.user_id, max_attempts=2)
    if wake is not None:
        on_commit(session, wake)
    return {"job_id": job.id, "status": job.status, "run_id": run.id, "revision": number}
