"""The tasks domain's clock: leases, expiry and auto-approval read time from here, so tests
(and a demo) can move time forward instead of sleeping."""

from __future__ import annotations

import datetime as dt
import threading

from posefix.db import utcnow

__all__ = ["Clock", "ManualClock", "now", "set_clock", "reset_clock"]


class Clock:
    def now(self) -> dt.datetime:
        return utcnow()


class ManualClock(Clock):
    """A clock that only moves when told to (thread-safe)."""

    def __init__(self, start: dt.datetime | None = None):
        self._now = start or utcnow()
        self._lock = threading.Lock()

    def now(self) -> dt.datetime:
        with self._lock:
            return self._now

    def advance(self, seconds: float) -> dt.datetime:
        with self._lock:
            self._now = self._now + dt.timedelta(seconds=seconds)
            return self._now


_clock: Clock = Clock()


def now() -> dt.datetime:
    return _clock.now()


def set_clock(clock: Clock) -> None:
    global _clock
    _clock = clock


def reset_clock() -> None:
    set_clock(Clock())
