"""Tile sources: one row per basemap the editor may show."""

from __future__ import annotations

import datetime as dt
import enum
from typing import Any

from sqlalchemy import JSON, ForeignKey, Integer, String
from sqlalchemy.orm import Mapped, mapped_column

from posefix.db import Base, UTCDateTime, utcnow


class TileKind(enum.StrEnum):
    """What the basemap shows; the editor's switcher groups sources by it."""

    satellite = "satellite"
    street = "street"
    topo = "topo"
    other = "other"


class TileFormat(enum.StrEnum):
    png = "png"
    jpg = "jpg"
    webp = "webp"
    avif = "avif"
    pbf = "pbf"


class TileSource(Base):
    """A tile source: a file under the data directory (``path``) or an upstream URL template.

    ``encoding``, ``vector_layers`` and ``style_schema`` are read from the file when it is
    registered, so building the style needs no file access.
    """

    __tablename__ = "tile_sources"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)
    title: Mapped[str] = mapped_column(String(200))
    kind: Mapped[str] = mapped_column(String(16))
    attribution: Mapped[str] = mapped_column(String(1000), default="")
    min_zoom: Mapped[int] = mapped_column(Integer)
    max_zoom: Mapped[int] = mapped_column(Integer)
    format: Mapped[str] = mapped_column(String(8))
    # Relative to the data directory; absolute paths are refused at registration.
    path: Mapped[str | None] = mapped_column(String(1000), nullable=True)
    url: Mapped[str | None] = mapped_column(String(2000), nullable=True)
    encoding: Mapped[str | None] = mapped_column(String(16), nullable=True)
    tile_size: Mapped[int] = mapped_column(Integer, default=256)
    bounds: Mapped[list[float] | None] = mapped_column(JSON, nullable=True)
    vector_layers: Mapped[list[dict[str, Any]]] = mapped_column(JSON, default=list)
    style_schema: Mapped[str] = mapped_column(String(64), default="")
    created_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), nullable=True)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
