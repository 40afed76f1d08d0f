"""The worker: claims jobs, keeps their lease alive with heartbeats, retries with backoff.

One ``Worker`` processes one job at a time. ``posefix worker`` runs it in the main thread
(SIGTERM/SIGINT finish the current job, then exit); ``posefix serve`` on SQLite runs one in
a daemon thread. Any number of workers may share one database: claiming is atomic.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
import traceback
import uuid

from posefix.config import Settings
from posefix.db import Database
from posefix.jobs import repository as jobs
from posefix.jobs.registry import JobContext, LeaseLost, PermanentJobError, cleanups, handler_for

# The job kinds a worker runs: importing each module registers its handlers.
from posefix.edits import jobs as _edit_jobs  # noqa: F401
from posefix.jobs import builtin as _builtin_jobs  # noqa: F401
from posefix.maps import jobs as _map_jobs  # noqa: F401
from posefix.tasks import jobs as _task_jobs  # noqa: F401

log = logging.getLogger("posefix.worker")


def backoff_s(settings: Settings, attempts: int) -> float:
    """Exponential backoff after the ``attempts``-th failure: base * 2^(attempts-1), capped."""
    return min(settings.job_backoff_base_s * (2 ** max(attempts - 1, 0)), settings.job_backoff_max_s)


class Worker:
    def __init__(self, db: Database, settings: Settings, *, name: str | None = None):
        self.db = db
        self.settings = settings
        self.worker_id = f"{name or socket.gethostname()}-{os.getpid()}-{uuid.uuid4().hex[:6]}"
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self.processed = 0
        self._last_bury = float("-inf")

    # -- lifecycle ---------------------------------------------------------------------
    def stop(self) -> None:
        self._stop.set()
        self._wake.set()

    def wake(self) -> None:
        self._wake.set()

    def start_thread(self) -> None:
        self._thread = threading.Thread(target=self.run, name=f"worker-{self.worker_id}", daemon=True)
        self._thread.start()

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def run(self) -> None:
        log.info("worker started", extra={"worker_id": self.worker_id})
        while not self._stop.is_set():
            try:
                worked = self.run_once()
            except Exception:
                log.exception("worker loop error", extra={"worker_id": self.worker_id})
                worked = False
            if not worked:
                self._wake.wait(self.settings.worker_poll_s)
                self._wake.clear()
        log.info("worker stopped", extra={"worker_id": self.worker_id})

    # -- one job -----------------------------------------------------------------------
    def run_once(self) -> bool:
        """Claim and run at most one job; True when a job was claimed."""
        now = time.monotonic()
        if now - self._last_bury >= self.settings.job_lease_s / 2:
            # Burying dead leases is housekeeping; once per half lease is plenty.
            self._last_bury = now
            with self.db.transaction() as s:
                jobs.bury_expired(s)
            self.clean_up()
        with self.db.transaction() as s:
            job_id = jobs.claim(s, self.worker_id, self.settings.job_lease_s)
        if job_id is None:
            return False
        with self.db.transaction(write=False) as s:
            job = jobs.get(s, job_id)
            assert job is not None
            s.expunge(job)
        self._execute(job)
        self.processed += 1
        return True

    def clean_up(self) -> None:
        """The registered housekeeping steps (files of dead jobs...); a failure is logged only."""
        for fn in cleanups():
            try:
                fn(self.db, self.settings)
            except Exception:
                log.exception("cleanup %s failed", getattr(fn, "__name__", fn), extra={"worker_id": self.worker_id})

    def _execute(self, job) -> None:  # type: ignore[no-untyped-def]
        extra = {"worker_id": self.worker_id, "job_id": job.id}
        log.info("job %s (%s) attempt %d", job.id, job.kind, job.attempts, extra=extra)
        handler = handler_for(job.kind)
        lost = threading.Event()
        done = threading.Event()

        def report(fraction: float | None, message: str | None) -> None:
            with self.db.transaction() as s:
                ok = jobs.heartbeat(s, job.id, self.worker_id, self.settings.job_lease_s, fraction, message)
            if not ok:
                lost.set()
                raise LeaseLost(f"job {job.id}: lease lost")

        def beat() -> None:
            while not done.wait(self.settings.job_heartbeat_s):
                try:
                    report(None, None)
                except LeaseLost:
                    return
                except Exception:
                    log.exception("heartbeat failed", extra=extra)

        beater = threading.Thread(target=beat, daemon=True)
        beater.start()
        try:
            if handler is None:
                raise PermanentJobError(f"no handler for job kind {job.kind!r}")
            ctx = JobContext(self.db, self.settings, job.id, self.worker_id, job.attempts, report)
            result = handler(ctx, dict(job.payload))
            with self.db.transaction() as s:
                if not jobs.succeed(s, job.id, self.worker_id, result or {}):
                    log.warning("job %s finished after its lease was taken over", job.id, extra=extra)
            log.info("job %s succeeded", job.id, extra=extra)
        except LeaseLost:
            log.warning("job %s: lease lost, abandoning", job.id, extra=extra)
        except Exception as exc:
            permanent = isinstance(exc, PermanentJobError)
            error = f"{type(exc).__name__}: {exc}"
            if not permanent:
                error += "\n" + traceback.format_exc(limit=5)
            with self.db.transaction() as s:
                status = jobs.fail(s, job, self.worker_id, error, backoff_s(self.settings, job.attempts), permanent=permanent)
            log.warning("job %s failed (%s): %s", job.id, status, exc, extra=extra)
            if status == "dead":
                self.clean_up()  # what waits on the job (a run's head) is released now, not at the next sweep
        finally:
            done.set()
            beater.join(timeout=5)
