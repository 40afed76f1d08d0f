"""Edit rules of the service: preview, submit a batch against a base revision, revert, diff.

Submitting claims revision ``base + 1`` with one conditional UPDATE of the run's head
(``head_revision = base``): of two submitters on the same base exactly one changes a row,
the other gets 409 with the current head. The batch, its edits and its job are written in
the same transaction, so a job never points at a batch that was rolled back.
"""

from __future__ import annotations

import time
from typing import Any, Protocol

import numpy as np
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.db import on_commit
from posefix.edits import repository as edits_repo
from posefix.edits.models import EditBatch
from posefix.edits.schemas import MoveIn
from posefix.core.geodesy import horizontal_distance_m
from posefix.engine import Edit, EditRefusedError, Edits
from posefix.engine.edits import check_batch
from posefix.core.rules import keyframes_left
from posefix.errors import BadRequest, Conflict, NotFound, Unprocessable
from posefix.jobs import repository as jobs
from posefix.runs import solutions, storage
from posefix.runs import repository as runs_repo
from posefix.runs.models import Revision, Run, RunStatus
from posefix.runs.warm import load_problem, stored_solution
from posefix.users.models import Role
from posefix.users.service import Principal
from posefix.filestore import file_store

REVISION_JOB = "revision"


def edit_set_at(session: Session, run: Run, revision: int) -> dict[str, Any]:
    """The cumulative edit set of a revision, ready or still being computed."""
    if revision == 0:
        return Edits().to_json()
    rev = runs_repo.revision(session, run.id, revision)
    if rev is not None:
        return rev.edit_set
    batch = edits_repo.batch_for_revision(session, run.id, revision)
    if batch is None:
        raise NotFound(f"run {run.id} has no revision {revision}", code="revision_not_found",
                       extra={"current_revision": run.head_revision})
    return batch.edit_set


def revision_base(session: Session, settings: Settings, run: Run, revision: int) -> tuple[dict[str, Any], str | None]:
    """A revision's edit set and, once it is ready, its keyframes file (beside which its
    solution is stored). Ready revisions never change, so they are remembered in-process."""
    key = (settings.files_dir.as_posix(), run.id, revision)
    cached = solutions.PROBLEMS.revision(key)
    if cached is not None:
        return cached
    rev = runs_repo.revision(session, run.id, revision)
    if rev is None:
        return edit_set_at(session, run, revision), None
    value = (Edits().to_json() if revision == 0 else rev.edit_set, rev.keyframes_file)
    solutions.PROBLEMS.put_revision(key, value)
    return value


def _moves(moves: list[MoveIn]) -> list[Edit]:
    return [Edit(m.index, m.lon, m.lat, m.alt, m.sigma) for m in moves]


def preview(session: Session, settings: Settings, run: Run, base_revision: int, moves: list[MoveIn], deleted: list[int]) -> dict[str, Any]:
    """The preview of a batch on ``base_revision``; ``positions`` is a (k, 2) lon/lat array
    (the endpoint serialises it without making 7,000 Python floats).  A base that is not the
    run's head answers 409 ``stale_revision``, as submitting the same batch would: a preview
    of edits that cannot be saved would only hide the conflict until Submit."""
    started = time.perf_counter()
    if base_revision != run.head_revision:
        raise _stale(session, run, base_revision)
    base, keyframes_file = revision_base(session, settings, run, base_revision)
    problem = load_problem(session, settings, run)
    k = len(problem.keyframe_index)
    too_few = keyframes_left(k, list(base.get("deleted", [])) + [d for d in deleted if 0 <= d < k], [d for d in deleted if 0 <= d < k])
    if too_few:  # nothing to show: the run would have no track left
        raise Unprocessable(too_few[0].message, code="edit_refused", extra={"refusals": [r.to_json() for r in too_few]})
    try:
        pv, base_solved = solutions.preview(run.id, run.rules, base_revision, problem, base,
                                            stored_solution(settings, run, keyframes_file), _moves(moves), deleted)
    except EditRefusedError as exc:  # the solution itself is refused (altitude_out_of_range): nothing to show
        raise Unprocessable(exc.refusals[0].message, code="edit_refused",
                            extra={"refusals": [r.to_json() for r in exc.refusals]}) from None
    return {
        "base_revision": base_revision,
        "positions": np.round(np.stack([pv.lon_deg, pv.lat_deg], axis=1), 8),
        "solver": pv.solution.solver.to_json(),
        "preview": {**pv.info, "base_solved_in_request": base_solved},
        "drift": pv.solution.drift.to_json(),
        "refusals": [r.to_json() for r in pv.refusals],
        "flags": [f.to_json() for f in pv.flags],
        "time_ms": round((time.perf_counter() - started) * 1000, 2),
    }


def parse_base(if_match: str | None, body_base: int | None) -> int:
    header_base = None
    if if_match:
        raw = if_match.strip()
        if raw.startswith("W/"):
            raw = raw[2:]
        raw = raw.strip('"')
        if not raw.isdigit():
            raise BadRequest('If-Match must be a revision number, e.g. "3"', code="bad_if_match")
        header_base = int(raw)
    if header_base is not None and body_base is not None and header_base != body_base:
        raise BadRequest("If-Match and base_revision disagree", code="base_mismatch")
    base = header_base if header_base is not None else body_base
    if base is None:
        raise BadRequest("say which revision the edits were made on (If-Match or base_revision)", code="base_revision_required")
    return base


def _stale(session: Session, run: Run, base: int) -> Conflict:
    session.refresh(run)
    return Conflict(
        f"revision {base} is not the latest of run {run.id} (it is {run.head_revision}); reload and edit again",
        code="stale_revision", extra={"current_revision": run.head_revision, "ready_revision": run.revision},
    )


class Author(Protocol):
    """Whom a batch is written for: a signed-in ``Principal``, or a job acting for a user or for
    nobody (``user_id`` None); an admin's or reviewer's accepted batch accepts the run."""

    @property
    def user_id(self) -> int | None: ...

    @property
    def role(self) -> Role: ...


def _claim(session: Session, run: Run, base: int) -> None:
    if not runs_repo.claim_next_revision(session, run.id, base):
        raise _stale(session, run, base)


def _enqueue_revision(session: Session, settings: Settings, run: Run, batch: EditBatch, principal: Author, wake: Any) -> int:
    job = jobs.enqueue(
        session, REVISION_JOB, {"run_id": run.id, "batch_id": batch.id, "revision": batch.revision},
        run_id=run.id, created_by=principal.user_id, max_attempts=settings.job_max_attempts,
    )
    batch.job_id = job.id
    if wake is not None:
        on_commit(session, wake)
    return job.id


def submit(
    session: Session, settings: Settings, principal: Author, run: Run, *, base: int, moves: list[MoveIn],
    deleted: list[int], accept: bool, comment: str | None, task_id: int | None, wake: Any = None,
) -> tuple[EditBatch, int, list[dict[str, Any]]]:
    if not moves and not deleted and not accept:
        raise Unprocessable("the batch is empty (no moves, deletions or accept)", code="empty_batch")
    if base != run.head_revision:
        raise _stale(session, run, base)
    base_set = edit_set_at(session, run, base)
    problem = load_problem(session, settings, run)
    batch_moves = _moves(moves)
    check = check_batch(problem, problem.cfg.rules, Edits.from_json(base_set), batch_moves, deleted)
    if check.refusals:
        n = len(check.refusals)
        raise Unprocessable(
            f"{n} edit{'' if n == 1 else 's'} refused by the editing rules", code="edit_refused",
            extra={"refusals": [r.to_json() for r in check.refusals]},
        )
    _claim(session, run, base)
    merged = Edits.from_json(base_set).merged(batch_moves, deleted, check.flags).to_json()
    batch = EditBatch(
        run_id=run.id, kind="edit", base_revision=base, revision=base + 1, author_id=principal.user_id,
        task_id=task_id, accept=accept, comment=comment, edit_set=merged,
    )
    try:
        with session.begin_nested():
            edits_repo.add(session, batch)
    except IntegrityError:
        raise _stale(session, run, base) from None
    edits_repo.insert_edits(session, [
        {"batch_id": batch.id, "run_id": run.id, "k": m.index, "kind": src.kind, "lon": m.lon_deg, "lat": m.lat_deg, "alt": m.alt_m,
         "author_id": principal.user_id, "task_id": task_id}
        for m, src in zip(batch_moves, moves)
    ] + [
        {"batch_id": batch.id, "run_id": run.id, "k": int(d), "kind": "delete", "lon": None, "lat": None, "alt": None,
         "author_id": principal.user_id, "task_id": task_id}
        for d in deleted
    ])
    job_id = _enqueue_revision(session, settings, run, batch, principal, wake)
    session.refresh(run)
    if accept and principal.role in (Role.admin, Role.reviewer):
        new_status = RunStatus.accepted
    elif accept:
        new_status = RunStatus.corrected
    else:
        new_status = RunStatus.in_review
    runs_repo.record(
        session, run, principal.user_id, "edited", to_status=new_status if new_status != run.status else None,
        revision=batch.revision, task_id=task_id, comment=comment,
        detail={"batch_id": batch.id, "moves": len(moves), "deleted": len(deleted), "accept": accept, "job_id": job_id},
    )
    run.status = new_status
    run.verified = new_status == RunStatus.accepted
    if moves:
        run.adjusted = True
    session.flush()
    return batch, job_id, [f.to_json() for f in check.flags]


def revert(
    session: Session, settings: Settings, principal: Principal, run: Run, *, to_revision: int, base: int,
    comment: str | None, wake: Any = None,
) -> tuple[EditBatch, int]:
    if to_revision > run.revision:
        raise Conflict(f"revision {to_revision} is not ready (latest ready: {run.revision})", code="revision_pending")
    target = runs_repo.revision(session, run.id, to_revision)
    if target is None:
        raise NotFound(f"run {run.id} has no revision {to_revision}", code="revision_not_found")
    if base != run.head_revision:
        raise _stale(session, run, base)
    _claim(session, run, base)
    batch = EditBatch(
        run_id=run.id, kind="revert", base_revision=base, revision=base + 1, author_id=principal.user_id,
        accept=False, comment=comment, edit_set=target.edit_set,
    )
    try:
        with session.begin_nested():
            edits_repo.add(session, batch)
    except IntegrityError:
        raise _stale(session, run, base) from None
    job_id = _enqueue_revision(session, settings, run, batch, principal, wake)
    session.refresh(run)
    runs_repo.record(session, run, principal.user_id, "reverted", to_status=RunStatus.in_review if run.status != RunStatus.in_review else None,
                     revision=batch.revision, comment=comment, detail={"to_revision": to_revision, "batch_id": batch.id, "job_id": job_id})
    run.status = RunStatus.in_review
    run.verified = False
    session.flush()
    return batch, job_id


def ready(session: Session, run: Run, number: int) -> Revision:
    rev = runs_repo.revision(session, run.id, number)
    if rev is None:
        failed = edits_repo.failed_batch_for_revision(session, run.id, number) if number > run.head_revision else None
        if failed is not None:
            raise Conflict(f"revision {number} failed: {failed.error}", code="revision_failed",
                           extra={"batch_id": failed.id, "reason": failed.error, "head_revision": run.head_revision})
        if 0 <= number <= run.head_revision:
            raise Conflict(f"revision {number} is still being computed", code="revision_pending",
                           extra={"revision": run.revision, "head_revision": run.head_revision})
        raise NotFound(f"run {run.id} has no revision {number}", code="revision_not_found")
    return rev


def diff(session: Session, settings: Settings, run: Run, a: int, b: int) -> dict[str, Any]:
    ra, rb = ready(session, run, a), ready(session, run, b)
    fs = file_store(settings)
    ka, kb = storage.read_keyframes(fs, ra.keyframes_file), storage.read_keyframes(fs, rb.keyframes_file)
    d = horizontal_distance_m(ka.lon_deg, ka.lat_deg, kb.lon_deg, kb.lat_deg)
    changed = np.flatnonzero(d > 0.001)
    return {
        "from": a, "to": b,
        "max_m": float(d.max()) if len(d) else 0.0,
        "mean_m": float(d.mean()) if len(d) else 0.0,
        "changed": int(len(changed)),
        "displacement_m": np.round(d, 4).tolist(),
        "keyframes": [
            {"index": int(i), "displacement_m": round(float(d[i]), 4),
             "from": [round(float(ka.lon_deg[i]), 8), round(float(ka.lat_deg[i]), 8)],
             "to": [round(float(kb.lon_deg[i]), 8), round(float(kb.lat_deg[i]), 8)]}
            for i in changed
        ],
    }
