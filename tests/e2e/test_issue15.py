"""The browser app's finishing items (issue 15), one Chromium test each: history, compare and
revert with an admin's audit view; review that needs a reason; one way through a task; and
the editor's smaller fixes."""

from __future__ import annotations

import math
import time

import pytest

from tests.e2e.helpers import keyframe_px, login, open_run, shot, zoom_to

pytestmark = pytest.mark.e2e


def wait_revision(page, n: int) -> None:
    page.wait_for_function(f"() => document.querySelector('.editor').dataset.revision === '{n}'", timeout=60_000)


def api_move(server, username: str, run_id: int, index: int, east_m: float, comment: str, base: int = 0) -> None:
    """Submit one move through the API (as `username`) and wait for its revision."""
    c = server.srv.client(username)
    try:
        fc = c.get(f"/api/v1/runs/{run_id}/keyframes").json()
        lon, lat = fc["features"][index]["geometry"]["coordinates"][:2]
        lon += east_m / (111320 * math.cos(math.radians(lat)))
        r = c.post(f"/api/v1/runs/{run_id}/edits", json={"base_revision": base, "moves": [{"index": index, "lon": lon, "lat": lat}], "comment": comment})
        assert r.status_code == 202, r.text
        job = r.json()["job_id"]
        deadline = time.time() + 60
        while c.get(f"/api/v1/jobs/{job}").json()["status"] != "succeeded":
            assert time.time() < deadline, "the correction job did not finish"
            time.sleep(0.3)
    finally:
        c.close()


def test_history_compare_revert_and_audit(server, browser, run_id):
    api_move(server, "op1", run_id, 10, 2.0, "onto the lane")  # small: 6 m east would pass keyframe 9 (order rule)
    page = browser.new_page(viewport={"width": 1400, "height": 900})
    login(page, server, "admin")
    open_run(page, server, run_id)
    page.get_by_test_id("history").click()
    row = page.get_by_test_id("revision-1")
    row.wait_for()
    assert "op1" in row.inner_text() and "onto the lane" in row.inner_text()
    # Compare revisions 0 and 1: both tracks and the moved keyframes are drawn, and the summary counts them.
    page.get_by_test_id("pick-0").check()
    page.get_by_test_id("pick-1").check()
    summary = page.get_by_test_id("compare-summary")
    summary.wait_for()
    assert "moved, up to" in summary.inner_text()
    page.wait_for_function("() => { const f = window.__posefixMap.getSource('pf-compare')._data; const g = f.geojson || f;"
                           " return g.features.filter(x => x.properties.kind === 'track').length === 2"
                           " && g.features.some(x => x.properties.kind === 'moved' && x.properties.i === 10); }")
    shot(page, "history-compare", docs=True)
    # Revert to revision 0: the confirmation says what will change, then revision 2 is made.
    page.get_by_test_id("revert-0").click()
    question = page.get_by_test_id("revert-question")
    question.wait_for()
    text = question.inner_text()
    assert "Revert to revision 0?" in text and "new revision 2" in text and "will move" in text
    page.get_by_test_id("revert-yes").click()
    wait_revision(page, 2)
    page.get_by_test_id("revision-2").wait_for()
    assert "revert" in page.get_by_test_id("revision-2").inner_text()
    # The admin's audit view of op1 lists the edit with its comment.
    page.goto(server.base_url + "/#/admin/people")
    page.get_by_test_id("person-op1").click()
    edits = page.get_by_test_id("activity-edits")
    edits.get_by_text("onto the lane").wait_for()
    assert f"e2e {'test_history_compare_revert_and_audit'}" in edits.inner_text()
    page.close()


def status_of(page, index: int) -> str:
    return page.evaluate("(i) => { const f = window.__posefixMap.getSource('pf-keyframes')._data; return (f.geojson || f).features[i].properties.s; }", index)


def test_delete_range_is_between_the_two_clicks_and_asks_first(server, browser, run_id):
    api_move(server, "op1", run_id, 22, 5.0, "kept lane")
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    login(page, server)
    open_run(page, server, run_id)
    zoom_to(page, 25, zoom=17.5)
    page.mouse.click(*keyframe_px(page, 30))  # selected before the range tool: not part of the range
    page.get_by_test_id("delete-range").click()
    page.mouse.click(*keyframe_px(page, 20))
    page.mouse.click(*keyframe_px(page, 24))
    q = page.get_by_test_id("range-question")
    q.wait_for()
    assert q.inner_text() == "Delete keyframes 20–24 (5 keyframes)? This drops the move of keyframe 22."
    page.get_by_test_id("range-no").click()
    assert page.evaluate("document.querySelector('.editor').dataset.unsaved") == "0"
    page.get_by_test_id("delete-range").click()
    page.mouse.click(*keyframe_px(page, 20))
    page.mouse.click(*keyframe_px(page, 24))
    page.get_by_test_id("range-yes").click()
    page.wait_for_function("() => document.querySelector('.editor').dataset.unsaved === '5'")
    assert [status_of(page, i) for i in (19, 20, 24, 25, 30)] == ["fixed", "deleted", "deleted", "fixed", "adjustable"]
    page.close()


def test_tile_source_name_is_checked_in_the_browser(server, browser):
    page = browser.new_page()
    login(page, server, "admin")
    page.goto(server.base_url + "/#/admin/tiles")
    name = page.locator("#ts-name")
    name.fill("Bad Name")
    assert name.evaluate("el => el.validity.patternMismatch") is True
    name.fill("good-name_2")
    assert name.evaluate("el => el.validity.valid") is True
    page.close()


def _ensure_user(server, name: str, role: str) -> None:
    from tests.e2e.serverkit import PASSWORD

    try:
        server.srv.cli("users", "create", "--username", name, "--role", role, "--password-stdin", stdin=PASSWORD + "\n")
    except RuntimeError as err:  # made by an earlier test of this session
        assert "exist" in str(err).lower() or "taken" in str(err).lower(), err


def _task_with_submissions(server, run_id: int, operators: list[str]) -> int:
    """A task on one run, one submission (a 4 m move of keyframe 8) per operator; its task-run id."""
    admin = server.srv.client("admin")
    try:
        body = {"title": f"review keys {run_id}", "instructions": "Drag keyframes onto the lane.", "run_ids": [run_id],
                "reward_cents": 10, "currency": "EUR", "assignments_per_run": len(operators), "lease_s": 600,
                "lifetime_s": 86400, "auto_approval_delay_s": 3600, "priority": 100, "conflict_policy": "flag"}
        task = admin.post("/api/v1/tasks", json=body)
        assert task.status_code == 201, task.text
        fc = admin.get(f"/api/v1/runs/{run_id}/keyframes").json()
    finally:
        admin.close()
    lon, lat = fc["features"][8]["geometry"]["coordinates"][:2]
    for i, who in enumerate(operators):
        c = server.srv.client(who)
        try:
            a = c.post("/api/v1/tasks/next").json()["assignment"]
            assert a is not None and a["run_id"] == run_id, a
            east = (4.0 + i) / (111320 * math.cos(math.radians(lat)))
            r = c.post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": [{"index": 8, "lon": lon + east, "lat": lat}], "comment": f"by {who}"})
            assert r.status_code == 200, r.text
        finally:
            c.close()
    return task.json()["runs"][0]["id"]


def test_review_by_keyboard_needs_a_reason_to_reject(server, browser, run_id):
    _ensure_user(server, "rev15", "reviewer")
    tr_id = _task_with_submissions(server, run_id, ["op1", "op2"])
    page = browser.new_page(viewport={"width": 1400, "height": 900})
    login(page, server, "rev15")
    page.goto(f"{server.base_url}/#/tasks/review/{tr_id}")
    page.wait_for_selector(".review-map[data-ready='true']", timeout=30_000)
    legend = page.get_by_test_id("review-legend").inner_text()
    assert "consensus" in legend and "reported track" in legend and "disagreement" in legend
    subs = server.get_json("admin", f"/api/v1/task-runs/{tr_id}/review")["submissions"]
    first, second = subs[0]["assignment_id"], subs[1]["assignment_id"]
    page.locator("body").press("r")  # reject the focused (first) submission: no reason yet, so nothing is sent
    msg = page.get_by_test_id(f"decide-msg-{first}")
    msg.filter(has_text="needs a reason").wait_for()
    assert page.evaluate("document.activeElement.dataset.testid") == f"feedback-{first}"
    page.keyboard.type("keyframe 8 is on the pavement")
    page.keyboard.press("Enter")
    page.get_by_test_id(f"submission-{first}").filter(has_text="rejected").wait_for(timeout=15_000)
    page.locator("body").press("s")  # show the focused (now the second) submission alone on the map
    n = page.evaluate("() => window.__posefixReviewMap.queryRenderedFeatures({layers: ['rv-tracks']}).map(f => f.properties.aid)")
    page.wait_for_function(f"() => {{ const a = window.__posefixReviewMap.queryRenderedFeatures({{layers: ['rv-tracks']}}).map(f => f.properties.aid);"
                           f" return a.length > 0 && a.every(x => x === {second}); }}")
    assert n is not None
    page.locator("body").press("a")
    page.get_by_test_id(f"submission-{second}").filter(has_text="approved").wait_for(timeout=15_000)
    shot(page, "review-keyboard", docs=True)
    # The operator sees the reason beside the rejected assignment.
    op = browser.new_page()
    rejected_by = next(s["operator"] for s in subs if s["assignment_id"] == first)
    login(op, server, rejected_by)
    op.goto(server.base_url + "/#/tasks/work")
    op.get_by_test_id(f"feedback-{first}").filter(has_text="keyframe 8 is on the pavement").wait_for()
    op.close()
    page.close()


def test_one_way_through_a_task(server, browser, run_id):
    admin = server.srv.client("admin")
    try:
        body = {"title": f"one way {run_id}", "instructions": "Delete what is wrong.", "run_ids": [run_id], "reward_cents": 10,
                "currency": "EUR", "assignments_per_run": 1, "lease_s": 600, "lifetime_s": 86400, "auto_approval_delay_s": 3600,
                "priority": 200, "conflict_policy": "flag"}
        assert admin.post("/api/v1/tasks", json=body).status_code == 201
    finally:
        admin.close()
    page = browser.new_page(viewport={"width": 1400, "height": 900})
    login(page, server, "op2")
    page.goto(server.base_url + "/#/tasks/work")
    page.get_by_test_id("next-task").click()
    page.wait_for_selector("#map[data-ready='true']", timeout=30_000)
    page.wait_for_function("() => document.querySelector('.editor').dataset.revision !== ''", timeout=30_000)
    assert page.locator("button:has-text('Submit')").count() == 1
    assert page.locator("input[aria-label*='omment']").count() == 1
    page.locator("#map").focus()
    page.keyboard.press(".")
    page.keyboard.press("Delete")
    page.wait_for_function("() => document.querySelector('.editor').dataset.unsaved === '1'")
    page.get_by_label("Comment for the reviewer").fill("removed the first keyframe")
    page.get_by_test_id("task-submit").click()
    page.get_by_test_id("offer-next").wait_for(timeout=15_000)
    page.wait_for_function("() => document.querySelector('.editor').dataset.unsaved === '0'")
    mine = server.get_json("op2", "/api/v1/assignments/mine")
    sub = next(a for a in mine if a["run_id"] == run_id)
    assert sub["status"] == "submitted" and sub["comment"] == "removed the first keyframe"
    page.close()


def test_basemap_says_when_it_has_no_tiles_at_this_zoom(server, browser, run_id):
    page = browser.new_page()
    login(page, server)
    open_run(page, server, run_id)
    page.get_by_label("Toner (topo)").check()
    note = page.get_by_test_id("zoom-note")
    note.filter(has_text="Toner has no tiles beyond zoom 3").wait_for(timeout=10_000)
    page.get_by_label("Helsinki streets (street)").check()
    # The streets source's own range is then what the note speaks of (its tiles stop at zoom 15).
    page.wait_for_function("() => !document.querySelector('[data-testid=zoom-note]').textContent.includes('Toner')")
    page.close()
