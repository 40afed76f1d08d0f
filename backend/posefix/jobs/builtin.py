"""Built-in job kinds used by operations and tests."""

from __future__ import annotations

import time
from typing import Any

from posefix.jobs.registry import JobContext, PermanentJobError, register


@register("sleep")
def sleep_job(ctx: JobContext, payload: dict[str, Any]) -> dict[str, Any]:
    """Sleep ``seconds`` in ``steps`` steps reporting progress (for health checks and tests)."""
    seconds = float(payload.get("seconds", 0.0))
    steps = max(int(payload.get("steps", 1)), 1)
    if seconds < 0 or seconds > 3600:
        raise PermanentJobError("seconds must be within [0, 3600]")
    for i in range(steps):
        time.sleep(seconds / steps)
        ctx.progress((i + 1) / steps, f"step {i + 1}/{steps}")
    return {"slept_s": seconds, "attempt": ctx.attempt}
