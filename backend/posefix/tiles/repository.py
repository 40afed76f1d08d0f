"""Every query on tile sources."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from posefix.tiles.models import TileSource


def list_sources(session: Session) -> list[TileSource]:
    return list(session.scalars(select(TileSource).order_by(TileSource.id)).all())


def get_source(session: Session, source_id: int) -> TileSource | None:
    return session.get(TileSource, source_id)


def get_source_by_name(session: Session, name: str) -> TileSource | None:
    return session.scalars(select(TileSource).where(TileSource.name == name)).one_or_none()


def add(session: Session, source: TileSource) -> None:
    session.add(source)
    session.flush()


def delete(session: Session, source: TileSource) -> None:
    session.delete(source)
    session.flush()
