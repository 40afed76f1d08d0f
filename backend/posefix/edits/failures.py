"""Batches whose revision job died: the run goes back to where it was, says why, and the
author may retry the batch or discard it.

A run is never left waiting for a revision nobody will write. When a batch's job dies
(retries exhausted, or a permanent error) the batch becomes ``failed`` with the job's error,
and if it was the run's head the head goes back to the highest revision still on its way
(ready, or claimed by a pending batch), so reviews and new edits work again. The status the
batch gave the run (``corrected`` by an accept...) is taken back too. ``retry`` claims the
number again when the run has not moved on since; ``discard`` closes the failure. Both are
recorded in the run's history, as is the failure.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import update
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.edits import repository as edits_repo
from posefix.edits.models import BatchStatus, EditBatch
from posefix.errors import Conflict, Forbidden, NotFound
from posefix.runs import repository as runs_repo
from posefix.runs.access import check_direct_write
from posefix.runs.models import Run, RunEvent, RunStatus
from posefix.users.models import Role
from posefix.users.service import Principal


def failed_json(batch: EditBatch) -> dict[str, Any]:
    return {"batch_id": batch.id, "revision": batch.revision, "base_revision": batch.base_revision,
            "status": batch.status, "error": batch.error, "failed_at": batch.failed_at, "author_id": batch.author_id}


def failed_edits(session: Session, run_ids: list[int]) -> dict[int, dict[str, Any]]:
    """Per run, its latest batch as ``failed_json`` when that batch failed."""
    return {rid: failed_json(b) for rid, b in edits_repo.last_failed(session, run_ids).items()}


def _status_before(session: Session, run: Run, batch: EditBatch) -> str | None:
    """The run's status before the batch changed it, while the batch's change still stands."""
    events = session.query(RunEvent).filter(RunEvent.run_id == run.id, RunEvent.revision == batch.revision,
                                            RunEvent.action.in_(("edited", "reverted"))).order_by(RunEvent.id.desc())
    for ev in events:
        if (ev.detail or {}).get("batch_id") == batch.id:
            return ev.from_status if ev.to_status is not None and ev.to_status == run.status else None
    return None


def fail_batch(session: Session, batch_id: int, error: str, *, job_id: int | None = None) -> bool:
    """Mark a pending batch failed and roll its run's head back; False when it was not pending."""
    batch = edits_repo.batch(session, batch_id)
    if batch is None or (job_id is not None and batch.job_id != job_id):
        return False  # gone, or retried since with another job
    if not edits_repo.mark_failed(session, batch_id, error):
        return False
    session.refresh(batch)
    run = session.get(Run, batch.run_id)
    assert run is not None
    back = max(run.revision, edits_repo.pending_below(session, run.id, batch.revision) or 0)
    rolled = session.execute(update(Run).where(Run.id == run.id, Run.head_revision == batch.revision)
                             .values(head_revision=back)).rowcount == 1
    session.refresh(run)
    before = _status_before(session, run, batch)
    runs_repo.record(session, run, None, "revision_failed", to_status=before, revision=batch.revision,
                     detail={"batch_id": batch.id, "job_id": job_id, "error": error[:1000],
                             "head_revision": run.head_revision, "rolled_back": rolled})
    if before is not None:
        run.status = before
        run.verified = before == RunStatus.accepted
    session.flush()
    return True


def _own_failed_batch(session: Session, principal: Principal, run: Run, batch_id: int) -> EditBatch:
    batch = edits_repo.batch(session, batch_id)
    if batch is None or batch.run_id != run.id:
        raise NotFound(f"run {run.id} has no edit batch {batch_id}", code="batch_not_found")
    if batch.author_id != principal.user_id and principal.role not in (Role.admin, Role.reviewer):
        raise Forbidden("only the batch's author, a reviewer or an admin may do this", code="not_author")
    if batch.status != BatchStatus.failed:
        raise Conflict(f"edit batch {batch_id} is {batch.status}, not failed", code="not_failed",
                       extra={"status": batch.status})
    return batch


def retry(session: Session, settings: Settings, principal: Principal, run: Run, batch_id: int, wake: Any = None) -> EditBatch:
    """Claim the failed batch's revision again and enqueue its job (409 when the run moved on)."""
    from posefix.edits.service import _enqueue_revision, _stale

    check_direct_write(session, principal, run)
    batch = _own_failed_batch(session, principal, run, batch_id)
    if not runs_repo.claim_next_revision(session, run.id, batch.base_revision):
        raise _stale(session, run, batch.base_revision)
    batch.status, batch.error, batch.failed_at = BatchStatus.pending, None, None
    session.flush()
    edits_repo.notify(session, batch.id)
    job_id = _enqueue_revision(session, settings, run, batch, principal, wake)
    session.refresh(run)
    runs_repo.record(session, run, principal.user_id, "retried", revision=batch.revision,
                     detail={"batch_id": batch.id, "job_id": job_id})
    session.flush()
    return batch


def discard(session: Session, principal: Principal, run: Run, batch_id: int) -> EditBatch:
    batch = _own_failed_batch(session, principal, run, batch_id)
    batch.status = BatchStatus.discarded
    session.flush()
    edits_repo.notify(session, batch.id)
    runs_repo.record(session, run, principal.user_id, "discarded", revision=batch.revision, detail={"batch_id": batch.id})
    session.flush()
    return batch
