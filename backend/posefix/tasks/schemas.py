"""Request and response bodies of the API for tasks, assignments, reviews, operators and gold runs (pydantic)."""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from posefix.core.rules import MAX_MOVE_LIMIT_M, MIN_MOVE_LIMIT_M, EditRules
from posefix.edits.schemas import MoveIn, RefusalOut
from posefix.tasks.models import AssignmentStatus, ConflictPolicy, TaskRunStatus, TaskStatus
from posefix.tasks.qualification import validate_requirement


class RulesIn(BaseModel):
    """The editing rules for the task's runs (the engine's ``EditRules``)."""

    every_n: int = Field(default=1, ge=1, le=1000)
    lock_n: int = Field(default=0, ge=0, le=1000)
    lock_direction: Literal["forward", "both"] = "forward"
    max_move_m: float = Field(default=EditRules().max_move_m, ge=MIN_MOVE_LIMIT_M, le=MAX_MOVE_LIMIT_M,
                              description="longest move of a keyframe, metres (always finite: a far move is a slip)")
    order_rule: Literal["refuse", "flag"] = "flag"
    deleted: Literal["remove", "flag"] = "remove"


class RequirementIn(BaseModel):
    qualification: str = Field(min_length=1, max_length=64, pattern=r"^[a-z0-9_.:-]+$")
    comparator: str
    value: float | list[float] | None = None

    @model_validator(mode="after")
    def _valid(self) -> RequirementIn:
        problem = validate_requirement(self.model_dump())
        if problem is not None:
            raise ValueError(f"requirement {self.qualification}: {problem}")
        return self


class TaskCreate(BaseModel):
    title: str = Field(min_length=1, max_length=200)
    instructions: str = Field(default="", max_length=20000)
    run_ids: list[int] = Field(min_length=1, max_length=1000)
    reward_cents: int = Field(default=0, ge=0, le=10**9, description="reward per assignment, in cents")
    currency: str = Field(default="EUR", pattern=r"^[A-Z]{3}$")
    assignments_per_run: int = Field(default=1, ge=1, le=50)
    lease_s: int = Field(default=1800, ge=30, le=7 * 86400, description="assignment duration (the lease)")
    lifetime_s: int = Field(default=7 * 86400, ge=60, le=365 * 86400)
    auto_approval_delay_s: int = Field(default=3 * 86400, ge=0, le=30 * 86400)
    priority: int = Field(default=0, ge=-1000, le=1000)
    max_active_leases: int = Field(default=1, ge=1, le=100, description="leases one operator may hold at once")
    rules: RulesIn | None = None
    requirements: list[RequirementIn] = Field(default_factory=list, max_length=10)
    conflict_distance_m: float = Field(default=5.0, gt=0, le=10000, description="tracks further apart than this...")
    conflict_keyframes: int = Field(default=3, ge=1, le=100000, description="...over this many consecutive keyframes")
    conflict_edit_m: float = Field(default=5.0, gt=0, le=10000, description="moves of one keyframe further apart")
    conflict_policy: ConflictPolicy = ConflictPolicy.extend
    max_extra_assignments: int = Field(default=1, ge=0, le=10)
    client_token: str | None = Field(default=None, min_length=1, max_length=64, description="idempotency token, kept 24 h")

    @field_validator("run_ids")
    @classmethod
    def _unique_runs(cls, v: list[int]) -> list[int]:
        if len(set(v)) != len(v):
            raise ValueError("run_ids repeat a run")
        return v


class TaskRunPublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    run_id: int
    wanted: int
    status: TaskRunStatus
    conflicts: list[dict[str, Any]] | None
    merged_revision: int | None
    counts: dict[str, int] = Field(default_factory=dict)


class TaskPublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    title: str
    instructions: str
    reward_cents: int
    currency: str
    assignments_per_run: int
    lease_s: int
    lifetime_s: int
    auto_approval_delay_s: int
    priority: int
    max_active_leases: int
    rules: dict[str, Any] | None
    requirements: list[dict[str, Any]]
    conflict_distance_m: float
    conflict_keyframes: int
    conflict_edit_m: float
    conflict_policy: str
    max_extra_assignments: int
    status: TaskStatus
    requester_id: int | None
    created_at: dt.datetime
    expires_at: dt.datetime
    counts: dict[str, int] = Field(default_factory=dict, description="assignments by status")
    runs: list[TaskRunPublic] = Field(default_factory=list)


class TaskList(BaseModel):
    items: list[TaskPublic]
    total: int


class TaskBrief(BaseModel):
    """What an operator sees of a task (no gold marks, no other operators)."""

    id: int
    title: str
    instructions: str
    reward_cents: int
    currency: str
    rules: dict[str, Any] | None


class AssignmentPublic(BaseModel):
    id: int
    task_id: int
    run_id: int
    status: AssignmentStatus
    operator_id: int | None
    base_revision: int | None
    leased_at: dt.datetime | None
    lease_expires_at: dt.datetime | None
    lease_remaining_s: float | None
    submitted_at: dt.datetime | None
    comment: str | None
    feedback: str | None
    reviewed_at: dt.datetime | None
    auto_approve_at: dt.datetime | None
    task: TaskBrief


class NextResponse(BaseModel):
    assignment: AssignmentPublic | None
    message: str
    ineligible: list[dict[str, Any]] = Field(default_factory=list, description="tasks you cannot take, with reasons")


class SubmitIn(BaseModel):
    moves: list[MoveIn] = Field(default_factory=list, max_length=10000)
    deleted: list[int] = Field(default_factory=list, max_length=100000)
    accept: bool = False
    comment: str | None = Field(default=None, max_length=4000)


class SubmitOut(BaseModel):
    assignment: AssignmentPublic
    flags: list[RefusalOut]


class ReviewIn(BaseModel):
    decision: Literal["approve", "reject"]
    feedback: str | None = Field(default=None, max_length=4000, description="required to reject (the operator is shown it), optional to approve")

    @model_validator(mode="after")
    def _reject_needs_reason(self) -> ReviewIn:
        if self.decision == "reject" and not (self.feedback or "").strip():
            raise ValueError("feedback: a rejection needs a reason the operator can act on")
        return self


class TransitionPublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    entity: str
    assignment_id: int | None
    task_run_id: int | None
    from_status: str | None
    to_status: str
    actor_id: int | None
    at: dt.datetime
    reason: str | None
    detail: dict[str, Any] | None


class SubmissionView(BaseModel):
    assignment_id: int
    operator_id: int | None
    operator: str | None
    status: AssignmentStatus
    submitted_at: dt.datetime | None
    comment: str | None
    moves: list[list[Any]]
    deleted: list[int]
    positions: list[list[float]] | None = Field(description="[lon, lat] per keyframe of the corrected track")
    consensus_error_m: float | None
    rank: int | None = Field(default=None, description="1 = closest to the weighted consensus")
    distance_m: float | None = Field(default=None, description="mean distance to the weighted consensus of the others, moved keyframes")
    expected_m: float | None = Field(default=None, description="the mean distance the operator's measured accuracy explains")
    accuracy_m: float | None = Field(default=None, description="the operator's mean error on gold runs (None: never measured)")
    gold_scored: int = 0
    sigma_m: float | None = Field(default=None, description="the operator's accuracy (per axis) from gold runs and shared runs")
    weight: float | None = Field(default=None, description="share of the weighted consensus")
    off_consensus: bool = Field(default=False, description="further off than the operator's accuracy explains: held for review")


class ReviewView(BaseModel):
    task_run_id: int
    task_id: int
    run_id: int
    status: TaskRunStatus
    reported: list[list[float]] = Field(description="[lon, lat] per keyframe as reported")
    consensus: list[list[float]] | None
    disagreement_m: list[float] | None = Field(description="per keyframe, the largest distance between two operators")
    conflicts: list[dict[str, Any]] | None
    submissions: list[SubmissionView] = Field(description="ranked: closest to the weighted consensus first")
    merged_revision: int | None
    method: str | None = Field(default=None, description="weighted, or geometric_median while nothing is known of the operators")
    consensus_sigma_m: list[float | None] | None = Field(default=None, description="per keyframe, the weighted consensus' standard deviation (per axis)")
    merge_detail: dict[str, Any] | None = None


class ReviewQueueItem(BaseModel):
    task_run_id: int
    task_id: int
    task_title: str
    run_id: int
    status: TaskRunStatus
    submitted: int
    conflicts: int


class HomeAreaIn(BaseModel):
    lon: float | None = Field(default=None, ge=-180, le=180)
    lat: float | None = Field(default=None, ge=-90, le=90)
    radius_m: float | None = Field(default=None, gt=0, le=2.0e7)
    polygon: list[list[float]] | None = Field(default=None, min_length=3, max_length=1000, description="[[lon, lat], ...]")

    @model_validator(mode="after")
    def _one_shape(self) -> HomeAreaIn:
        point = (self.lon, self.lat, self.radius_m)
        if self.polygon is not None:
            if any(v is not None for v in point):
                raise ValueError("give either lon/lat/radius_m or polygon, not both")
            for i, p in enumerate(self.polygon):
                if len(p) != 2 or not (-180 <= p[0] <= 180 and -90 <= p[1] <= 90):
                    raise ValueError(f"polygon[{i}] must be [lon, lat] within range")
        elif any(v is None for v in point) and any(v is not None for v in point):
            raise ValueError("a home point needs lon, lat and radius_m together")
        return self


class QualificationGrant(BaseModel):
    name: str = Field(min_length=1, max_length=64, pattern=r"^[a-z0-9_.:-]+$")
    value: float = 1.0


class QualificationPublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    name: str
    value: float
    granted_by: int | None
    granted_at: dt.datetime


class OperatorStats(BaseModel):
    user_id: int
    username: str
    submitted: int
    approved: int
    rejected: int
    returned: int
    expired: int
    accuracy_m: float | None = Field(description="mean horizontal error on gold runs, metres")
    gold_scored: int
    agreement_m: float | None = Field(description="mean distance of their tracks to the consensus, metres")
    throughput_per_h: float | None = Field(description="submissions per hour of lease time")
    mean_work_s: float | None
    test_status: str
    home_area: dict[str, Any] | None
    qualifications: list[QualificationPublic]


class GoldRunIn(BaseModel):
    run_id: int = Field(ge=1)
    truth_path: str | None = Field(default=None, max_length=1000, description="server-side truth file (admin only)")
    is_test: bool = False
    pass_error_m: float = Field(default=3.0, gt=0, le=1000)


class GoldRunPublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    run_id: int
    is_test: bool
    pass_error_m: float
    created_at: dt.datetime
