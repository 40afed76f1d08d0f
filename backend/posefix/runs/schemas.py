"""Request and response bodies of the API for runs, revisions and images (pydantic)."""

from __future__ import annotations

import datetime as dt
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from posefix.runs.models import RunStatus


class FailedEdit(BaseModel):
    """An edit batch whose revision could not be computed (its job died), and why."""

    batch_id: int
    revision: int = Field(description="the revision number the batch had claimed (free again)")
    base_revision: int
    status: str = Field(description="failed (retry or discard it) or discarded")
    error: str | None
    failed_at: dt.datetime | None
    author_id: int | None


class RunPublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    name: str
    status: RunStatus
    verified: bool
    adjusted: bool
    owner_id: int | None
    source_format: str
    original_filename: str
    n_samples: int
    n_keyframes: int
    t_start_s: float
    t_end_s: float
    recorded_start: dt.datetime | None
    recorded_end: dt.datetime | None
    bbox: list[float] = Field(description="[min_lon, min_lat, max_lon, max_lat]")
    length_m: float
    orientation_derived: bool
    revision: int = Field(description="latest revision whose data is ready")
    head_revision: int = Field(description="latest revision claimed by a submitted batch")
    rules: dict[str, Any]
    n_images: int = 0
    created_at: dt.datetime
    updated_at: dt.datetime
    failed_edit: FailedEdit | None = Field(
        default=None, description="the run's latest batch when its revision failed: retry or discard it")


class RunList(BaseModel):
    items: list[RunPublic]
    total: int
    limit: int
    offset: int


class UploadFormats(BaseModel):
    """The file name extensions an upload accepts, lower case with the dot."""

    run: list[str] = Field(description="run files, and .zip for a zipped KITTI oxts or comma2k19 folder")
    images: list[str] = Field(description="image files (also accepted inside a .zip)")


class RunEventPublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    at: dt.datetime
    actor_id: int | None
    action: str
    from_status: str | None
    to_status: str | None
    revision: int | None
    task_id: int | None
    comment: str | None
    detail: dict[str, Any] | None


class RunHistory(BaseModel):
    items: list[RunEventPublic]


class ReviewRequest(BaseModel):
    decision: str = Field(pattern="^(accept|reject)$")
    comment: str | None = Field(default=None, max_length=4000)


class ImagePublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    run_id: int
    filename: str
    content_type: str
    size_bytes: int
    width: int
    height: int
    sample_index: int | None
    keyframe: int | None
    exif_lon: float | None
    exif_lat: float | None
    exif_time: str | None


class ImageList(BaseModel):
    items: list[ImagePublic]
