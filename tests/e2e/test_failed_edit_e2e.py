"""The failed-edit notice in Chromium against a real server: an edit whose revision job dies
leaves the run at its revision; the editor says why, Retry computes it again (and it fails
again, for the same reason), Discard closes the failure."""

from __future__ import annotations

import json
import sqlite3
import time

import pytest

from tests.e2e.helpers import login, open_run, shot

pytestmark = pytest.mark.e2e


def _rules_beyond_the_settings(server, run_id: int) -> None:
    """Rules stored before settings were bounded (max_move_m far beyond 10 km), with reversals
    flagged rather than refused: only the altitude check stands between a 553 km drag and an
    exported run."""
    with sqlite3.connect(server.srv.data_dir / "posefix.sqlite") as db:
        (rules,) = db.execute("SELECT rules FROM runs WHERE id = ?", (run_id,)).fetchone()
        db.execute("UPDATE runs SET rules = ? WHERE id = ?", (json.dumps({**json.loads(rules), "max_move_m": 1e9, "order_rule": "flag"}), run_id))


def _wait_dead(client, job_id: int, timeout_s: float = 60.0) -> dict:
    deadline = time.time() + timeout_s
    while time.time() < deadline:
        job = client.get(f"/api/v1/jobs/{job_id}").json()
        if job["status"] in ("dead", "succeeded"):
            return job
        time.sleep(0.3)
    raise AssertionError(f"job {job_id} still {job['status']}")


def test_failed_edit_notice_says_why_then_retry_and_discard(server, context, run_id):
    _rules_beyond_the_settings(server, run_id)
    admin = server.srv.client("admin")
    try:
        lon, lat = admin.get(f"/api/v1/runs/{run_id}/keyframes").json()["features"][4]["geometry"]["coordinates"]
        r = admin.post(f"/api/v1/runs/{run_id}/edits", json={"base_revision": 0, "moves": [{"index": 4, "lon": lon + 10.0, "lat": lat}]})
        assert r.status_code == 202, r.text
        assert _wait_dead(admin, r.json()["job_id"])["status"] == "dead"
        page = context.new_page()
        login(page, server, "admin")
        open_run(page, server, run_id)
        notice = page.get_by_test_id("failed-edit")
        notice.wait_for(state="visible", timeout=15_000)
        text = notice.inner_text()
        assert "Revision 1 could not be computed, so the run stays at revision 0" in text, text
        assert "altitude" in text, text
        shot(page, "failed-edit-notice")
        page.get_by_test_id("failed-retry").click()
        page.get_by_text("Revision 1 is being computed again.").wait_for(timeout=15_000)
        failed = admin.get(f"/api/v1/runs/{run_id}").json()["failed_edit"]
        if failed is None:  # the retried job has not died yet
            deadline = time.time() + 60
            while failed is None and time.time() < deadline:
                time.sleep(0.3)
                failed = admin.get(f"/api/v1/runs/{run_id}").json()["failed_edit"]
        assert failed is not None and "altitude" in failed["error"]
        page.reload()
        page.get_by_test_id("failed-edit").wait_for(state="visible", timeout=15_000)
        page.get_by_test_id("failed-discard").click()
        page.get_by_text("The failed edits were discarded.").wait_for(timeout=15_000)
        page.get_by_test_id("failed-edit").wait_for(state="hidden", timeout=15_000)
        run = admin.get(f"/api/v1/runs/{run_id}").json()
        assert run["failed_edit"] is None and run["head_revision"] == 0
        assert page.evaluate("document.querySelector('.editor').dataset.revision") == "0"
    finally:
        admin.close()
