"""The failed-edit notice in Chromium against a real server: an edit whose revision job dies
(the run's samples file is away: a storage outage) leaves the run at its revision; the editor
says why, Retry computes it again (and it fails again, for the same reason), Discard closes
the failure."""

from __future__ import annotations

import json
import sqlite3
import time
from pathlib import Path

import pytest

from tests.e2e.helpers import login, open_run, shot

pytestmark = pytest.mark.e2e


def _samples_away(server, run_id: int, attempt: int) -> Path:
    """Move the run's samples file away and change its rules (a move bound no test move comes
    near), so the worker's prepared problem (kept per run and rules) is not reused: the job must
    read the file, and every attempt fails until it is back. Returns the moved file."""
    with sqlite3.connect(server.srv.data_dir / "posefix.sqlite") as db:
        (rules,) = db.execute("SELECT rules FROM runs WHERE id = ?", (run_id,)).fetchone()
        db.execute("UPDATE runs SET rules = ? WHERE id = ?", (json.dumps({**json.loads(rules), "max_move_m": 900.0 - attempt}), run_id))
        (rel,) = db.execute("SELECT samples_file FROM revisions WHERE run_id = ? AND number = 0", (run_id,)).fetchone()
    path = server.srv.data_dir / "files" / rel
    away = path.with_name(path.name + ".away")
    path.rename(away)
    return away


def _wait_dead(client, job_id: int, timeout_s: float = 120.0) -> dict:
    deadline = time.time() + timeout_s
    while time.time() < deadline:
        job = client.get(f"/api/v1/jobs/{job_id}").json()
        if job["status"] in ("dead", "succeeded"):
            return job
        time.sleep(0.3)
    raise AssertionError(f"job {job_id} still {job['status']}")


def _edit_that_dies(server, admin, run_id: int) -> tuple[int, Path]:
    """Submit an edit, then take the samples file away; the worker polls every 0.2 s, so it
    may (rarely) have read the file first: then that revision is simply made and we go again.
    Returns the failed revision's number and the moved file."""
    for attempt in range(3):
        head = admin.get(f"/api/v1/runs/{run_id}").json()["head_revision"]
        lon, lat = admin.get(f"/api/v1/runs/{run_id}/keyframes").json()["features"][4]["geometry"]["coordinates"]
        r = admin.post(f"/api/v1/runs/{run_id}/edits", json={"base_revision": head, "moves": [{"index": 4, "lon": lon + 5e-5, "lat": lat}]})
        assert r.status_code == 202, r.text
        away = _samples_away(server, run_id, attempt)
        if _wait_dead(admin, r.json()["job_id"])["status"] == "dead":
            return int(r.json()["revision"]), away
        away.rename(away.with_name(away.name.removesuffix(".away")))
    raise AssertionError("the worker read the samples file before it was moved, three times")


def test_failed_edit_notice_says_why_then_retry_and_discard(server, context, run_id):
    admin = server.srv.client("admin")
    away = None
    try:
        number, away = _edit_that_dies(server, admin, run_id)
        page = context.new_page()
        login(page, server, "admin")
        open_run(page, server, run_id)
        notice = page.get_by_test_id("failed-edit")
        notice.wait_for(state="visible", timeout=15_000)
        text = notice.inner_text()
        assert f"Revision {number} could not be computed, so the run stays at revision {number - 1}" in text, text
        assert "FileNotFoundError" in text, text
        shot(page, "failed-edit-notice")
        page.get_by_test_id("failed-retry").click()
        page.get_by_text(f"Revision {number} is being computed again.").wait_for(timeout=15_000)
        failed = admin.get(f"/api/v1/runs/{run_id}").json()["failed_edit"]
        if failed is None:  # the retried job has not died yet
            deadline = time.time() + 120  # five attempts, 2 + 4 + 8 + 16 s apart
            while failed is None and time.time() < deadline:
                time.sleep(0.3)
                failed = admin.get(f"/api/v1/runs/{run_id}").json()["failed_edit"]
        assert failed is not None and "FileNotFoundError" in failed["error"]
        page.reload()
        page.get_by_test_id("failed-edit").wait_for(state="visible", timeout=15_000)
        page.get_by_test_id("failed-discard").click()
        page.get_by_text("The failed edits were discarded.").wait_for(timeout=15_000)
        page.get_by_test_id("failed-edit").wait_for(state="hidden", timeout=15_000)
        run = admin.get(f"/api/v1/runs/{run_id}").json()
        assert run["failed_edit"] is None and run["head_revision"] == number - 1
        assert page.evaluate("document.querySelector('.editor').dataset.revision") == str(number - 1)
    finally:
        if away is not None:
            away.rename(away.with_name(away.name.removesuffix(".away")))
        admin.close()
