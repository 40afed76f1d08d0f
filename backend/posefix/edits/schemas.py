"""Request and response bodies of the API for previews, edit batches, revisions and diffs (pydantic)."""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from posefix.runs.schemas import FailedEdit


class MoveIn(BaseModel):
    index: int = Field(ge=0, le=10**7, description="keyframe index")
    lon: float = Field(ge=-180, le=180)
    lat: float = Field(ge=-90, le=90)
    alt: float | None = Field(default=None, ge=-1000, le=100000, description="metres; omit for a 2-D move")
    sigma: float | None = Field(default=None, ge=0.05, le=1000, description=(
        "horizontal 1-sigma per axis of the placed position, metres (a crowd's fused position carries its "
        "uncertainty); the correction holds the keyframe that loosely. Omit for the engine's configured one"))
    kind: Literal["move", "suggestion"] = Field(default="move", description="suggestion: accepted from map matching (stored as such)")


class PreviewRequest(BaseModel):
    base_revision: int = Field(ge=0, le=10**9)
    moves: list[MoveIn] = Field(default_factory=list, max_length=10000)
    deleted: list[int] = Field(default_factory=list, max_length=100000)


class RefusalOut(BaseModel):
    index: int
    reason: str
    message: str


class PreviewResponse(BaseModel):
    base_revision: int
    positions: list[list[float]] = Field(description="[lon, lat] per keyframe")
    solver: dict[str, Any]
    preview: dict[str, Any] = Field(description=(
        "what was solved: mode local|full, window [first, last] keyframe re-solved, full_solve, "
        "base_solved_in_request (the base revision had to be solved first); a preview keeps the "
        "base revision's drift estimate and is exact only after the commit"))
    drift: dict[str, Any]
    refusals: list[RefusalOut]
    flags: list[RefusalOut]
    time_ms: float


class EditBatchIn(BaseModel):
    base_revision: int | None = Field(default=None, ge=0, le=10**9, description="or header If-Match")
    moves: list[MoveIn] = Field(default_factory=list, max_length=10000)
    deleted: list[int] = Field(default_factory=list, max_length=100000)
    accept: bool = False
    comment: str | None = Field(default=None, max_length=4000)
    task_id: int | None = Field(default=None, ge=1, le=2**62)


class EditBatchAccepted(BaseModel):
    batch_id: int
    job_id: int
    revision: int = Field(description="the revision this batch will become")
    flags: list[RefusalOut]


class RevertRequest(BaseModel):
    to_revision: int = Field(ge=0, le=10**9)
    base_revision: int | None = Field(default=None, ge=0, le=10**9)
    comment: str | None = Field(default=None, max_length=4000)


class RevisionPublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    number: int
    kind: str
    batch_id: int | None
    created_by: int | None
    created_at: dt.datetime
    solver: dict[str, Any] | None
    drift: dict[str, Any] | None
    max_correction_m: float
    n_moves: int
    n_deleted: int
    author: str | None = Field(default=None, description="username of created_by")
    comment: str | None = Field(default=None, description="the submitter's comment (of the batch that made this revision)")
    task_id: int | None = Field(default=None, description="the task the batch was submitted for")
    review: str | None = Field(default=None, description="the last review decision on this revision: accepted | rejected")
    review_comment: str | None = None
    reviewer: str | None = None


class RevisionDetail(RevisionPublic):
    edit_set: dict[str, Any]


class RevisionList(BaseModel):
    items: list[RevisionPublic]
    head_revision: int
    failed: list[FailedEdit] = Field(default_factory=list, description="batches whose revision failed, oldest first")


class EditPublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    batch_id: int
    k: int
    kind: str
    lon: float | None
    lat: float | None
    alt: float | None
    author_id: int | None
    task_id: int | None
    created_at: dt.datetime


class DiffEntry(BaseModel):
    index: int
    displacement_m: float
    from_pos: list[float] = Field(alias="from")
    to_pos: list[float] = Field(alias="to")

    model_config = ConfigDict(populate_by_name=True)


class DiffResponse(BaseModel):
    from_revision: int = Field(alias="from")
    to_revision: int = Field(alias="to")
    max_m: float
    mean_m: float
    changed: int = Field(description="keyframes that moved more than 1 mm")
    displacement_m: list[float] = Field(description="horizontal displacement per keyframe, metres")
    keyframes: list[DiffEntry] = Field(description="the keyframes that moved")

    model_config = ConfigDict(populate_by_name=True)
