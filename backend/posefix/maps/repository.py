"""Every query on floor plans."""

from __future__ import annotations

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from posefix.maps.models import FloorPlan


def add(session: Session, fp: FloorPlan) -> FloorPlan:
    session.add(fp)
    session.flush()
    return fp


def get(session: Session, floorplan_id: int) -> FloorPlan | None:
    return session.get(FloorPlan, floorplan_id)


def page(session: Session, limit: int, offset: int) -> tuple[list[FloorPlan], int]:
    total = int(session.scalar(select(func.count()).select_from(FloorPlan)) or 0)
    rows = list(session.scalars(select(FloorPlan).order_by(FloorPlan.id.desc()).limit(limit).offset(offset)))
    return rows, total


def delete(session: Session, fp: FloorPlan) -> None:
    session.delete(fp)
    session.flush()
