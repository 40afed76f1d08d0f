"""Every query on runs, keyframes, revisions, images and the run history."""

from __future__ import annotations

import datetime as dt
from typing import Any

from sqlalchemy import ColumnElement, Select, func, insert, select, update
from sqlalchemy.orm import Session

from posefix.runs.models import Keyframe, Revision, Run, RunEvent, RunImage, RunStatus


def add(session: Session, obj: object) -> None:
    session.add(obj)
    session.flush()


def insert_keyframes(session: Session, rows: list[dict[str, Any]]) -> None:
    if rows:
        session.execute(insert(Keyframe), rows)


def keyframes(session: Session, run_id: int) -> list[Keyframe]:
    return list(session.scalars(select(Keyframe).where(Keyframe.run_id == run_id).order_by(Keyframe.k)))


def keyframe_columns(session: Session, run_id: int) -> list[tuple[int, int, float, float, float, float]]:
    """(k, sample_index, t_s, lon, lat, alt) rows in keyframe order, without ORM objects."""
    stmt = (
        select(Keyframe.k, Keyframe.sample_index, Keyframe.t_s, Keyframe.lon, Keyframe.lat, Keyframe.alt)
        .where(Keyframe.run_id == run_id).order_by(Keyframe.k)
    )
    return [tuple(r) for r in session.execute(stmt)]  # type: ignore[misc]


def search(
    session: Session, visible: ColumnElement[bool], *, name: str | None, status: RunStatus | None,
    bbox: tuple[float, float, float, float] | None, since: dt.datetime | None, until: dt.datetime | None,
    limit: int, offset: int,
) -> tuple[list[Run], int]:
    stmt = select(Run).where(visible)
    if status is None:
        stmt = stmt.where(Run.status != RunStatus.deleted)
    else:
        stmt = stmt.where(Run.status == status)
    if name:
        escaped = name.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")
        stmt = stmt.where(func.lower(Run.name).like(f"%{escaped.lower()}%", escape="\\"))
    if bbox is not None:
        min_lon, min_lat, max_lon, max_lat = bbox
        # Runs whose bounding box intersects the query box.
        stmt = stmt.where(Run.max_lon >= min_lon, Run.min_lon <= max_lon, Run.max_lat >= min_lat, Run.min_lat <= max_lat)
    start = func.coalesce(Run.recorded_start, Run.created_at)
    end = func.coalesce(Run.recorded_end, Run.created_at)
    if since is not None:
        stmt = stmt.where(end >= since)
    if until is not None:
        stmt = stmt.where(start <= until)
    total = session.scalar(select(func.count()).select_from(stmt.subquery())) or 0
    rows = session.scalars(stmt.order_by(Run.id.desc()).limit(limit).offset(offset)).all()
    return list(rows), int(total)


def image_counts(session: Session, run_ids: list[int]) -> dict[int, int]:
    if not run_ids:
        return {}
    stmt = select(RunImage.run_id, func.count()).where(RunImage.run_id.in_(run_ids)).group_by(RunImage.run_id)
    return {int(r): int(c) for r, c in session.execute(stmt)}


def revision(session: Session, run_id: int, number: int) -> Revision | None:
    return session.scalars(select(Revision).where(Revision.run_id == run_id, Revision.number == number)).one_or_none()


def revisions(session: Session, run_id: int) -> list[Revision]:
    return list(session.scalars(select(Revision).where(Revision.run_id == run_id).order_by(Revision.number)))


def revisions_after(session: Session, after_id: int, run_ids: Select, limit: int = 200) -> list[Revision]:
    """Revisions with an id above ``after_id`` of the runs ``run_ids`` selects, oldest first."""
    stmt = select(Revision).where(Revision.id > after_id, Revision.run_id.in_(run_ids)).order_by(Revision.id).limit(limit)
    return list(session.scalars(stmt))


def last_revision_id_at(session: Session, when: dt.datetime) -> int:
    """The id of the newest revision created at or before ``when`` (0 when none)."""
    stmt = select(Revision.id).where(Revision.created_at <= when).order_by(Revision.id.desc()).limit(1)
    return int(session.scalar(stmt) or 0)


def images(session: Session, run_id: int) -> list[RunImage]:
    return list(session.scalars(select(RunImage).where(RunImage.run_id == run_id).order_by(RunImage.id)))


def image(session: Session, image_id: int) -> RunImage | None:
    return session.get(RunImage, image_id)


def history(session: Session, run_id: int) -> list[RunEvent]:
    return list(session.scalars(select(RunEvent).where(RunEvent.run_id == run_id).order_by(RunEvent.id)))


def record(session: Session, run: Run, actor_id: int | None, action: str, *, to_status: str | None = None,
           revision: int | None = None, task_id: int | None = None, comment: str | None = None,
           detail: dict[str, Any] | None = None) -> RunEvent:
    ev = RunEvent(
        run_id=run.id, actor_id=actor_id, action=action, from_status=run.status if to_status else None,
        to_status=to_status, revision=revision, task_id=task_id, comment=comment, detail=detail,
    )
    session.add(ev)
    return ev


def authored_up_to(session: Session, run_id: int, user_id: int, revision: int) -> bool:
    """Whether the user edited or reverted the run in a batch up to ``revision``."""
    stmt = select(RunEvent.id).where(
        RunEvent.run_id == run_id, RunEvent.actor_id == user_id, RunEvent.action.in_(("edited", "reverted")),
        RunEvent.revision <= revision,
    ).limit(1)
    return session.scalar(stmt) is not None


def claim_next_revision(session: Session, run_id: int, base_revision: int) -> bool:
    """Move the run's head from ``base_revision`` to ``base_revision + 1`` in one conditional
    UPDATE; False when another batch got there first (the base is stale)."""
    res = session.execute(
        update(Run)
        .where(Run.id == run_id, Run.head_revision == base_revision, Run.status != RunStatus.deleted)
        .values(head_revision=base_revision + 1)
    )
    return (res.rowcount or 0) == 1


def advance_revision(session: Session, run_id: int, number: int) -> None:
    """Mark revision ``number`` ready, never moving backwards (revisions may finish out of order)."""
    session.execute(update(Run).where(Run.id == run_id, Run.revision < number).values(revision=number))
