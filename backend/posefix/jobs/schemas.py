"""Request and response bodies of the API for jobs (pydantic)."""

from __future__ import annotations

import datetime as dt
from typing import Any

from pydantic import BaseModel, ConfigDict

from posefix.jobs.models import JobStatus


class JobPublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    kind: str
    status: JobStatus
    progress: float
    message: str | None
    attempts: int
    max_attempts: int
    run_id: int | None
    result: dict[str, Any] | None
    last_error: str | None
    created_at: dt.datetime
    updated_at: dt.datetime
    finished_at: dt.datetime | None
