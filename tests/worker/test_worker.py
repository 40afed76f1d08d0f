"""The job queue and worker: atomic claims, leases, heartbeats, retries, dead jobs, idempotent
revisions, SIGKILL and SIGTERM. Separate worker processes where it matters."""

from __future__ import annotations

import datetime as dt
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from sqlalchemy import func, select, update

from posefix.jobs import repository as jobs
from posefix.jobs.models import Job
from posefix.jobs.registry import PermanentJobError, register
from posefix.runs import storage
from posefix.runs.models import Revision
from posefix.worker.runner import Worker, backoff_s
from tests.conftest import drive_csv, upload

POSEFIX = str(Path(sys.executable).parent / "posefix")


@register("test.fail")
def _always_fails(ctx, payload):
    raise RuntimeError("boom")


@register("test.permanent")
def _permanent(ctx, payload):
    raise PermanentJobError("cannot ever work")


def enqueue(app, kind, payload, n=1, max_attempts=5):
    ids = []
    with app.state.db.transaction() as s:
        for _ in range(n):
            ids.append(jobs.enqueue(s, kind, payload, max_attempts=max_attempts).id)
    return ids


def job(app, job_id) -> Job:
    with app.state.db.transaction(write=False) as s:
        j = s.get(Job, job_id)
        s.expunge(j)
        return j


def run_a_worker_until_finished(app, jid, env):
    """Start a fresh worker process, wait until job ``jid`` succeeds or dies, stop the worker
    with SIGTERM and return the job."""
    worker = subprocess.Popen([POSEFIX, "worker"], env=env, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 180
        while job(app, jid).status not in ("succeeded", "dead"):
            assert time.monotonic() < deadline
            time.sleep(0.05)
    finally:
        worker.send_signal(signal.SIGTERM)
        worker.wait(timeout=60)
    return job(app, jid)


def worker_env(settings, **extra) -> dict[str, str]:
    env = {**os.environ, "POSEFIX_DATABASE_URL": settings.database_url, "POSEFIX_DATA_DIR": str(settings.data_dir),
           "POSEFIX_ENVIRONMENT": "test", "POSEFIX_WORKER_POLL_S": "0.05", "POSEFIX_LOG_LEVEL": "WARNING"}
    env.update({k: str(v) for k, v in extra.items()})
    return env


class TestClaim:
    def test_enqueue_rolls_back_with_transaction(self, app):
        with pytest.raises(RuntimeError):
            with app.state.db.transaction() as s:
                jobs.enqueue(s, "sleep", {})
                raise RuntimeError("request failed")
        with app.state.db.transaction(write=False) as s:
            assert s.scalar(select(func.count()).select_from(Job)) == 0

    def test_claim_is_exclusive(self, app):
        (jid,) = enqueue(app, "sleep", {})
        with app.state.db.transaction() as s:
            assert jobs.claim(s, "a", 60) == jid
        with app.state.db.transaction() as s:
            assert jobs.claim(s, "b", 60) is None

    def test_expired_lease_is_claimed_again(self, app):
        (jid,) = enqueue(app, "sleep", {})
        with app.state.db.transaction() as s:
            jobs.claim(s, "a", 60)
            s.execute(update(Job).values(lease_expires_at=dt.datetime.now(dt.UTC) - dt.timedelta(seconds=1)))
        with app.state.db.transaction() as s:
            assert jobs.claim(s, "b", 60) == jid
        j = job(app, jid)
        assert j.worker_id == "b" and j.attempts == 2
        with app.state.db.transaction() as s:
            assert jobs.heartbeat(s, jid, "a", 60, 0.5, None) is False
            assert jobs.succeed(s, jid, "a", {}) is False
            assert jobs.heartbeat(s, jid, "b", 60, 0.5, "half") is True
        assert job(app, jid).progress == 0.5

    def test_expired_lease_on_last_attempt_is_dead(self, app):
        (jid,) = enqueue(app, "sleep", {}, max_attempts=1)
        with app.state.db.transaction() as s:
            jobs.claim(s, "a", 60)
            s.execute(update(Job).values(lease_expires_at=dt.datetime.now(dt.UTC) - dt.timedelta(seconds=1)))
        w = Worker(app.state.db, app.state.settings)
        assert w.run_once() is False
        assert job(app, jid).status == "dead"

    def test_threads_each_job_once(self, app):
        ids = enqueue(app, "sleep", {"seconds": 0}, n=60)
        workers = [Worker(app.state.db, app.state.settings, name=f"t{i}") for i in range(4)]

        def drain(w):
            while w.run_once():
                pass

        threads = [threading.Thread(target=drain, args=(w,)) for w in workers]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120)
        done = [job(app, i) for i in ids]
        assert all(j.status == "succeeded" and j.attempts == 1 for j in done)
        assert sum(w.processed for w in workers) == 60


class TestRetries:
    def test_backoff_then_dead(self, app):
        (jid,) = enqueue(app, "test.fail", {}, max_attempts=3)
        w = Worker(app.state.db, app.state.settings)
        for attempt in (1, 2):
            before = dt.datetime.now(dt.UTC)
            assert w.run_once()
            j = job(app, jid)
            assert j.status == "queued" and j.attempts == attempt and "boom" in j.last_error
            assert j.run_after >= before + dt.timedelta(seconds=backoff_s(app.state.settings, attempt) * 0.9)
            with app.state.db.transaction() as s:  # skip the wait
                s.execute(update(Job).values(run_after=dt.datetime.now(dt.UTC)))
        assert w.run_once()
        j = job(app, jid)
        assert j.status == "dead" and j.attempts == 3 and j.finished_at is not None

    def test_backoff_grows_and_caps(self, settings):
        assert [backoff_s(settings, a) for a in (1, 2, 3)] == [0.05, 0.1, 0.2]
        assert backoff_s(settings, 60) == settings.job_backoff_max_s

    def test_permanent_error_buries_at_once(self, app):
        (jid,) = enqueue(app, "test.permanent", {})
        assert Worker(app.state.db, app.state.settings).run_once()
        j = job(app, jid)
        assert j.status == "dead" and j.attempts == 1 and "cannot ever work" in j.last_error

    def test_unknown_kind_is_dead(self, app):
        (jid,) = enqueue(app, "no.such.kind", {})
        Worker(app.state.db, app.state.settings).run_once()
        assert job(app, jid).status == "dead"


@pytest.mark.slow
class TestProcesses:
    def test_200_jobs_8_worker_processes_each_once(self, app, settings):
        ids = enqueue(app, "sleep", {"seconds": 0.005}, n=200)
        env = worker_env(settings)
        procs = [subprocess.Popen([POSEFIX, "worker", "--once"], env=env, stderr=subprocess.PIPE, text=True) for _ in range(8)]
        for p in procs:
            _, err = p.communicate(timeout=240)
            assert p.returncode == 0, err[-2000:]
        with app.state.db.transaction(write=False) as s:
            rows = s.execute(select(Job.id, Job.status, Job.attempts, Job.worker_id).where(Job.id.in_(ids))).all()
        assert len(rows) == 200
        assert all(r.status == "succeeded" and r.attempts == 1 for r in rows), [r for r in rows if r.attempts != 1][:5]
        assert len({r.worker_id for r in rows}) >= 2

    def test_sigterm_finishes_current_job(self, app, settings):
        (jid,) = enqueue(app, "sleep", {"seconds": 2.0, "steps": 8})
        p = subprocess.Popen([POSEFIX, "worker"], env=worker_env(settings), stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 60
            while job(app, jid).status != "running":
                assert time.monotonic() < deadline and p.poll() is None
                time.sleep(0.02)
            p.send_signal(signal.SIGTERM)
            p.wait(timeout=60)
        finally:
            if p.poll() is None:
                p.kill()
        assert p.returncode == 0
        j = job(app, jid)
        assert j.status == "succeeded" and j.attempts == 1 and j.progress == 1.0

    def test_sigkill_mid_job_reruns_after_lease_and_writes_revision_once(self, app, settings, client, users):
        # A long run so the job is still running when the worker is killed.
        rid = upload(client, users["admin"], drive_csv(50_000, hz=100.0)).json()["id"]
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": [7]}, headers=users["admin"])
        jid = r.json()["job_id"]
        env = worker_env(settings, POSEFIX_JOB_LEASE_S=2, POSEFIX_JOB_HEARTBEAT_S=0.5)
        first = subprocess.Popen([POSEFIX, "worker"], env=env, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 120
            while job(app, jid).status != "running":
                assert time.monotonic() < deadline
                time.sleep(0.005)
            first.send_signal(signal.SIGKILL)
            first.wait(timeout=30)
        finally:
            if first.poll() is None:
                first.kill()
        killed = job(app, jid)
        assert killed.status == "running" and killed.attempts == 1
        done = run_a_worker_until_finished(app, jid, env)
        assert done.status == "succeeded" and done.attempts == 2
        assert done.worker_id != killed.worker_id
        with app.state.db.transaction(write=False) as s:
            assert s.scalar(select(func.count()).select_from(Revision).where(Revision.run_id == rid, Revision.number == 1)) == 1


def revision_rows(app, rid) -> list[Revision]:
    with app.state.db.transaction(write=False) as s:
        rows = list(s.scalars(select(Revision).where(Revision.run_id == rid).order_by(Revision.number)))
        for r in rows:
            s.expunge(r)
        return rows


def stray_files(app, settings, rid) -> list[str]:
    """Files in the run's folder that no committed revision names (besides the upload)."""
    named = {"original.csv"}
    for rev in revision_rows(app, rid):
        named |= {Path(rev.samples_file).name, Path(rev.keyframes_file).name,
                  Path(storage.solution_rel(rev.keyframes_file)).name}
    return sorted(p.name for p in (settings.files_dir / "runs" / str(rid)).iterdir() if p.name not in named)


def kill_while_writing_revision(app, settings, rid: int, number: int, env: dict[str, str]) -> list[str]:
    """Start a worker and SIGKILL it once it has begun writing the files of revision
    ``number`` (before their row is committed); returns the files it left behind.

    The worker is stepped with SIGSTOP/SIGCONT and the folder looked at while it is stopped,
    so the kill lands inside the few milliseconds of writing even on a busy machine.
    """
    fs = storage.FileStore(settings.files_dir)
    worker = subprocess.Popen([POSEFIX, "worker"], env=env, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 180
        while True:
            os.kill(worker.pid, signal.SIGSTOP)
            left = storage.revision_files(fs, rid, number)
            if left:
                break
            os.kill(worker.pid, signal.SIGCONT)
            assert worker.poll() is None and time.monotonic() < deadline, "the worker never wrote the revision"
        worker.send_signal(signal.SIGKILL)
        worker.wait(timeout=30)
    finally:
        if worker.poll() is None:
            worker.kill()
            worker.wait(timeout=30)
    assert [r.number for r in revision_rows(app, rid)] == list(range(number)), "killed after the commit"
    return storage.revision_files(fs, rid, number)


@pytest.mark.slow
class TestKilledWhileWriting:
    """A worker killed between writing a revision's files and committing its row."""

    def submit(self, client, users, n=50_000):
        rid = upload(client, users["admin"], drive_csv(n, hz=100.0)).json()["id"]
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": [7]}, headers=users["admin"])
        assert r.status_code == 202, r.text
        return rid, r.json()["job_id"]

    def test_rerun_writes_revision_once_and_removes_the_orphans(self, app, settings, client, users):
        rid, jid = self.submit(client, users)
        env = worker_env(settings, POSEFIX_JOB_LEASE_S=2, POSEFIX_JOB_HEARTBEAT_S=0.5)
        orphans = kill_while_writing_revision(app, settings, rid, 1, env)
        assert orphans and stray_files(app, settings, rid) == sorted(orphans)  # the kill did leave files
        killed = job(app, jid)
        assert killed.status == "running" and killed.attempts == 1
        done = run_a_worker_until_finished(app, jid, env)
        assert done.status == "succeeded" and done.attempts == 2 and done.result["already_written"] is False
        revs = revision_rows(app, rid)
        assert [r.number for r in revs] == [0, 1]
        assert stray_files(app, settings, rid) == []  # no orphan, no half-written temporary
        assert done.result["removed_files"] == len(orphans)
        assert (settings.files_dir / storage.solution_rel(revs[1].keyframes_file)).is_file()
        with app.state.db.transaction(write=False) as s:
            from posefix.runs.models import RunEvent

            ready = s.scalar(select(func.count()).select_from(RunEvent).where(
                RunEvent.run_id == rid, RunEvent.action == "revision_ready"))
        assert ready == 1

    def test_dead_job_files_are_removed_by_the_cleanup(self, app, settings, client, users):
        rid, jid = self.submit(client, users)
        with app.state.db.transaction() as s:  # this attempt is its last
            s.execute(update(Job).where(Job.id == jid).values(max_attempts=1))
        env = worker_env(settings, POSEFIX_JOB_LEASE_S=1, POSEFIX_JOB_HEARTBEAT_S=0.25)
        orphans = kill_while_writing_revision(app, settings, rid, 1, env)
        assert orphans
        deadline = time.monotonic() + 30
        while job(app, jid).lease_expires_at > dt.datetime.now(dt.UTC):
            assert time.monotonic() < deadline
            time.sleep(0.1)
        Worker(app.state.db, app.state.settings, name="janitor").run_once()  # buries the job, then cleans up
        dead = job(app, jid)
        assert dead.status == "dead" and dead.result == {"removed_files": sorted(orphans)}
        assert stray_files(app, settings, rid) == [] and [r.number for r in revision_rows(app, rid)] == [0]
        Worker(app.state.db, app.state.settings, name="janitor-2").clean_up()  # once per job
        assert job(app, jid).result == {"removed_files": sorted(orphans)}


class TestIdempotentRevision:
    def test_job_run_twice_writes_revision_once(self, app, client, users, settings):
        from posefix.edits.jobs import compute_revision
        from posefix.jobs.registry import JobContext

        rid = upload(client, users["admin"], drive_csv(3000)).json()["id"]
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": [3]}, headers=users["admin"])
        with app.state.db.transaction(write=False) as s:
            payload = s.get(Job, r.json()["job_id"]).payload
        ctx = JobContext(app.state.db, settings, r.json()["job_id"], "w", 1, lambda f, m: None)
        results = []

        def run():
            results.append(compute_revision(ctx, payload))

        threads = [threading.Thread(target=run) for _ in range(3)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120)
        results.append(compute_revision(ctx, payload))
        assert sum(not x["already_written"] for x in results) == 1
        with app.state.db.transaction(write=False) as s:
            revs = s.scalars(select(Revision).where(Revision.run_id == rid, Revision.number == 1)).all()
        assert len(revs) == 1
        files = sorted(p.name for p in (settings.files_dir / "runs" / str(rid)).iterdir() if "r1-" in p.name)
        assert files == sorted([Path(revs[0].samples_file).name, Path(revs[0].keyframes_file).name,
                                Path(storage.solution_rel(revs[0].keyframes_file)).name])
