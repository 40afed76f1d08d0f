"""Floor plans: one row per uploaded floor layout and the model built from it.

The uploaded files and the built model live in the file store under
``floorplans/<id>/``; the row keeps what the list and the download need without opening
them (status, size, extent, geo-reference).
"""

from __future__ import annotations

import datetime as dt
import enum
from typing import Any

from sqlalchemy import JSON, Boolean, Float, ForeignKey, Integer, String, Text
from sqlalchemy.orm import Mapped, mapped_column

from posefix.db import Base, UTCDateTime, utcnow


class FloorPlanStatus(enum.StrEnum):
    queued = "queued"  # uploaded, the model job has not finished
    ready = "ready"  # model built
    failed = "failed"  # the model job could not build a model (see ``error``)


class FloorPlanSource(enum.StrEnum):
    competition = "competition"  # floor_info.json + geojson_map.json + floor_image.png
    geojson = "geojson"  # walkable polygons in floor metres


class FloorPlan(Base):
    __tablename__ = "floor_plans"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(200))
    source: Mapped[str] = mapped_column(String(16))
    status: Mapped[str] = mapped_column(String(16), default=FloorPlanStatus.queued, index=True)
    cell_m: Mapped[float] = mapped_column(Float)
    # Floor frame extent (m) and the optional geo-reference [lon0, lat0, dlon_per_m, dlat_per_m].
    width_m: Mapped[float] = mapped_column(Float)
    height_m: Mapped[float] = mapped_column(Float)
    georef: Mapped[list[float] | None] = mapped_column(JSON, nullable=True)
    has_image: Mapped[bool] = mapped_column(Boolean, default=False)
    # Relative to the file store root.
    folder: Mapped[str] = mapped_column(String(200))
    n_vertices: Mapped[int | None] = mapped_column(Integer, nullable=True)
    model_bytes: Mapped[int | None] = mapped_column(Integer, nullable=True)
    build_s: Mapped[float | None] = mapped_column(Float, nullable=True)
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    job_id: Mapped[int | None] = mapped_column(Integer, nullable=True)
    created_by_id: Mapped[int | None] = mapped_column(ForeignKey("users.id", ondelete="SET NULL"), nullable=True)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    extra: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
