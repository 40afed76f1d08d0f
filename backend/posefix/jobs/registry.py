"""Job kinds and their handlers. A domain registers a handler for each kind it enqueues.

A handler ``fn(ctx: JobContext, payload: dict) -> dict`` runs in the worker; it does its
database writes in ``ctx.db`` transactions and must be idempotent (a job can run twice if
its worker dies after the work but before the job is marked done).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from posefix.config import Settings
from posefix.db import Database


class PermanentJobError(Exception):
    """The job can never succeed (bad payload, row gone): bury it without retrying."""


class LeaseLost(Exception):
    """Another worker took the job over (our lease expired): stop without writing."""


@dataclass
class JobContext:
    db: Database
    settings: Settings
    job_id: int
    worker_id: str
    attempt: int
    report: Callable[[float, str | None], None]

    def progress(self, fraction: float, message: str | None = None) -> None:
        """Record progress and extend the lease; raises ``LeaseLost`` when it was taken."""
        self.report(fraction, message)


Handler = Callable[[JobContext, dict[str, Any]], dict[str, Any]]
_HANDLERS: dict[str, Handler] = {}


def register(kind: str) -> Callable[[Handler], Handler]:
    def deco(fn: Handler) -> Handler:
        _HANDLERS[kind] = fn
        return fn

    return deco


Cleanup = Callable[[Database, Settings], int]
_CLEANUPS: list[Cleanup] = []


def register_cleanup(fn: Cleanup) -> Cleanup:
    """A housekeeping step the worker runs now and then (e.g. remove files of dead jobs):
    ``fn(db, settings) -> number of things cleaned``; it must be safe to run concurrently."""
    if fn not in _CLEANUPS:
        _CLEANUPS.append(fn)
    return fn


def cleanups() -> list[Cleanup]:
    return list(_CLEANUPS)


def handler_for(kind: str) -> Handler | None:
    return _HANDLERS.get(kind)
