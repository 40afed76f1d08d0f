"""Login throttling per account and source address, with growing delays.

Every failed login is a row (username, client address, time) in the database, so all API
processes count the same failures. Within ``login_window_s``:

- for one account from one address, the first ``login_max_failures`` failures cost nothing;
  after the n-th, the next attempt must wait ``login_delay_base_s * 2**(n - max)`` seconds
  from the latest failure (1, 2, 4, ... s by default), at most ``login_max_delay_s``;
- one address over all accounts (password spraying) gets the same, with four times the
  free failures.

An attempt during a delay answers 429 with Retry-After, even with the right password (else
the delay would not slow guessing). The account itself is never locked: its owner logs in
from any other address at once, and a success clears that address's failures for it.
"""

from __future__ import annotations

import datetime as dt
import math

from posefix.config import Settings
from posefix.db import Database, utcnow
from posefix.errors import TooManyRequests
from posefix.users import repository as repo

__all__ = ["delay_s", "check_throttle"]

SPRAY_FACTOR = 4  # an address may fail this many times more often over all accounts (shared NAT)


def delay_s(failures: int, free: int, base_s: float, max_s: float) -> float:
    """Wait required after the latest of ``failures`` failures (0 while they are free)."""
    if failures < free:
        return 0.0
    return min(max_s, base_s * 2.0 ** min(failures - free, 60))


def _wait_s(failures: int, latest: dt.datetime | None, free: int, settings: Settings, now: dt.datetime) -> float:
    if latest is None:
        return 0.0
    wait = delay_s(failures, free, settings.login_delay_base_s, settings.login_max_delay_s)
    return (latest + dt.timedelta(seconds=wait) - now).total_seconds()


def check_throttle(db: Database, settings: Settings, username: str, client_ip: str) -> None:
    """Raise 429 while this account from this address (or this address at all) must wait."""
    now = utcnow()
    since = now - dt.timedelta(seconds=settings.login_window_s)
    with db.transaction(write=False) as s:
        n_pair, latest_pair = repo.failures_since(s, since, client_ip=client_ip, username=username)
        n_ip, latest_ip = repo.failures_since(s, since, client_ip=client_ip)
    wait = max(
        _wait_s(n_pair, latest_pair, settings.login_max_failures, settings, now),
        _wait_s(n_ip, latest_ip, SPRAY_FACTOR * settings.login_max_failures, settings, now),
    )
    if wait > 0:
        retry = max(1, math.ceil(wait))
        raise TooManyRequests(
            f"too many failed logins from this address; try again in {retry} s",
            code="login_throttled",
            headers={"Retry-After": str(retry)},
        )
