"""Tasks end to end in Chromium against a real `posefix serve` (embedded worker): an admin
creates a task with 2 assignments in the browser, two operators each get it with "Get next
task" and correct the same keyframe differently (7 and 14 m off the input, the same way), the
conflict is flagged, a reviewer sees the submissions side by side and approves both, and the
merged revision appears."""

from __future__ import annotations

import math
import re
import time

import pytest

from tests.e2e.helpers import drag, keyframe_px, login, metres_px, shot, zoom_to
from tests.e2e.serverkit import PASSWORD

pytestmark = pytest.mark.e2e

KF = 10  # an adjustable keyframe under the e2e rules (every 2nd)


def wait_editor(page) -> None:
    page.wait_for_selector("#map[data-ready='true']", timeout=30_000)
    page.wait_for_function("() => document.querySelector('.editor') && document.querySelector('.editor').dataset.revision !== ''", timeout=30_000)
    page.wait_for_function(
        """() => { const m = window.__posefixMap; return m && m.getSource('pf-keyframes') && m.loaded()
              && m.queryRenderedFeatures({layers: ['pf-kf-hit']}).length > 0; }""",
        timeout=30_000,
    )


def across_track_m(server, run_id: int, k: int, metres: float) -> tuple[float, float]:
    """(east, north) metres perpendicular to the direction of travel at keyframe k (no order reversal)."""
    feats = server.get_json("admin", f"/api/v1/runs/{run_id}/keyframes")["features"]
    h = math.radians(feats[k]["properties"]["heading_deg"])
    return metres * math.cos(h), -metres * math.sin(h)


def operator_corrects(browser, server, username: str, run_id: int, east: float, north: float) -> None:
    context = browser.new_context(viewport={"width": 1280, "height": 800}, locale="en-GB")  # own cookies
    page = context.new_page()
    login(page, server, username)
    page.goto(server.base_url + "/#/tasks/work")
    page.get_by_test_id("next-task").click()
    page.wait_for_url(re.compile(r"#/tasks/work/\d+"))
    wait_editor(page)
    assert page.get_by_test_id("task-title").inner_text() == "Helsinki drive, two opinions"
    assert "centre of the lane" in page.get_by_test_id("instructions").inner_text()
    timer = page.get_by_test_id("lease-timer")
    assert re.fullmatch(r"\d\d:\d\d", timer.inner_text())
    first = timer.inner_text()
    page.wait_for_function("(t) => document.querySelector('[data-testid=lease-timer]').textContent !== t", arg=first, timeout=5_000)
    zoom_to(page, KF, 18)
    drag(page, keyframe_px(page, KF), metres_px(page, KF, east, north))
    page.wait_for_function("() => document.querySelector('.editor').dataset.unsaved === '1'", timeout=15_000)
    page.wait_for_function("() => document.querySelector('.editor').dataset.previewCurrent === 'true'", timeout=30_000)
    if username == "op1":
        shot(page, "task-operator", docs=True)
    page.get_by_test_id("task-submit").click()
    page.get_by_test_id("task-msg").filter(has_text="Submitted").wait_for(timeout=15_000)
    assert page.get_by_test_id("lease-timer").inner_text() == "submitted"
    context.close()


def test_admin_two_operators_conflict_review_merge(server, browser, context):
    run_id = server.upload_run("task e2e drive")
    try:
        server.srv.cli("users", "create", "--username", "rev1", "--role", "reviewer", "--password-stdin", stdin=PASSWORD + "\n")
    except Exception:  # noqa: BLE001 - the user exists when the session's server is reused
        pass

    admin = context.new_page()
    login(admin, server, "admin")
    admin.goto(server.base_url + "/#/tasks/admin")
    admin.get_by_label("Title").fill("Helsinki drive, two opinions")
    admin.get_by_label("Assignments per run").fill("2")
    admin.get_by_label("On conflict").select_option("flag")
    admin.locator(f"input[data-run='{run_id}']").check()
    admin.get_by_test_id("create-task").click()
    admin.get_by_test_id("create-msg").filter(has_text=re.compile(r"Task \d+ created with 2 assignments open")).wait_for()
    task_id = int(re.search(r"Task (\d+)", admin.get_by_test_id("create-msg").inner_text()).group(1))

    east, north = across_track_m(server, run_id, KF, 7.0)
    operator_corrects(browser, server, "op1", run_id, east, north)
    operator_corrects(browser, server, "op2", run_id, 2 * east, 2 * north)

    # the worker scores both submissions; the admin's monitor shows the conflict
    card = admin.get_by_test_id(f"task-{task_id}")
    card.get_by_test_id("run-state").filter(has_text="conflict").wait_for(timeout=60_000)
    assert re.match(r"\d+ — review", card.get_by_test_id("run-conflicts").inner_text())

    rev_context = browser.new_context(viewport={"width": 1280, "height": 800}, locale="en-GB")
    rev = rev_context.new_page()
    login(rev, server, "rev1")
    rev.goto(server.base_url + "/#/tasks/review")
    task = server.get_json("admin", f"/api/v1/tasks/{task_id}")
    tr_id = task["runs"][0]["id"]
    rev.get_by_test_id(f"review-{tr_id}").click()
    rev.wait_for_selector(".review-map[data-ready='true']", timeout=30_000)
    assert rev.get_by_test_id("review-state").inner_text() == "conflict"
    conflicts = rev.get_by_test_id("conflicts").inner_text()
    assert re.search(rf"Keyframe {KF} moved [67]\.\d m apart", conflicts), conflicts
    # the table leads with the keyframe where the two corrected runs lie furthest apart (one 7 m
    # edit each way can shift a short run as a whole: the drift model reads it as a GNSS bias)
    disagreement = server.get_json("admin", f"/api/v1/task-runs/{tr_id}/review")["disagreement_m"]
    first = rev.get_by_test_id("worst").locator("tbody tr").first.locator("td")
    assert int(first.nth(0).inner_text()) == max(range(len(disagreement)), key=disagreement.__getitem__)
    assert float(first.nth(1).inner_text()) == pytest.approx(max(disagreement), abs=0.006)
    assert disagreement[KF] > 6.0
    n_tracks = rev.evaluate("() => window.__posefixReviewMap.querySourceFeatures('review').filter(f => f.properties.kind === 'track').length")
    assert n_tracks >= 2
    shot(rev, "task-review", docs=True)
    subs = server.get_json("admin", f"/api/v1/task-runs/{tr_id}/review")["submissions"]
    assert len(subs) == 2
    for s in subs:
        rev.get_by_test_id(f"submission-{s['assignment_id']}").get_by_role("textbox").fill("thanks")
        rev.get_by_test_id(f"approve-{s['assignment_id']}").click()
        rev.get_by_test_id(f"submission-{s['assignment_id']}").filter(has_text="approved").wait_for(timeout=15_000)

    # both 7 and 14 m off the input the same way: their median is measurably better than the input, so it is merged
    rev.get_by_test_id("review-merged").filter(has_text="Merged as revision 1.").wait_for(timeout=60_000)
    card.get_by_test_id("merged-revision").filter(has_text="1").wait_for(timeout=60_000)
    deadline = time.time() + 60
    revs = []
    while time.time() < deadline:
        revs = [r["number"] for r in server.get_json("admin", f"/api/v1/runs/{run_id}/revisions")["items"]]
        if 1 in revs:
            break
        time.sleep(0.5)
    assert revs == [0, 1]
    card.get_by_test_id("task-status").filter(has_text="done").wait_for(timeout=15_000)
    shot(admin, "task-admin", docs=True)
    rev_context.close()


def test_review_screen_ranks_by_the_weighted_consensus_with_measured_accuracies(server, browser, context):
    """Three operators on a gold run (0.5, 1.5 and 20 m off the truth): the review screen lists
    them closest to the weighted consensus first, each with its measured accuracy and weight."""
    import numpy as np

    from posefix.io import read_run

    run_id = server.upload_run("weighted review drive")
    for user, role in (("op3", "operator"), ("rev1", "reviewer")):
        try:
            server.srv.cli("users", "create", "--username", user, "--role", role, "--password-stdin", stdin=PASSWORD + "\n")
        except Exception:  # noqa: BLE001 - the user exists when the session's server is reused
            pass
    truth_csv = server.run_csv.parent / "truth.csv"
    admin = server.srv.client("admin")
    with truth_csv.open("rb") as fh:
        admin.post("/api/v1/gold-runs", data={"run_id": str(run_id)}, files={"truth": ("truth.csv", fh, "text/csv")}).raise_for_status()
    # The operators put keyframes on the truth, which lies metres along the track from the reported
    # neighbours they leave unmoved (the drive's GNSS bias): the order rule flags those moves here
    # (the suite's engine config refuses them, to make the refusal reachable in the editor).
    task = admin.post("/api/v1/tasks", json={"title": "weighted review", "run_ids": [run_id], "assignments_per_run": 3,
                                             "lease_s": 600, "lifetime_s": 3600, "auto_approval_delay_s": 3600,
                                             "conflict_policy": "flag", "rules": {"every_n": 2, "lock_n": 2, "max_move_m": 60.0,
                                                                                  "order_rule": "flag"}})
    task.raise_for_status()
    task_id = task.json()["id"]
    truth = read_run(truth_csv)
    feats = admin.get(f"/api/v1/runs/{run_id}/keyframes").json()["features"]
    ks = list(range(0, len(feats), 4))  # the e2e rules: every 2nd adjustable, two either side locked
    t = np.array([feats[k]["properties"]["t"] for k in ks])
    lon, lat = np.interp(t, truth.t_s, truth.lon_deg), np.interp(t, truth.t_s, truth.lat_deg)
    aids = {}
    for user, off_m in (("op1", 0.5), ("op2", 20.0), ("op3", 1.5)):
        c = server.srv.client(user)
        a = c.post("/api/v1/tasks/next").json()["assignment"]
        # across the direction of travel, so a 20 m error never puts a keyframe behind the next one
        head = [math.radians(feats[k]["properties"]["heading_deg"]) for k in ks]
        moves = [{"index": k, "lon": float(lo) + off_m * math.cos(hd) / (111_320 * math.cos(math.radians(la))),
                  "lat": float(la) - off_m * math.sin(hd) / 111_320}
                 for k, lo, la, hd in zip(ks, lon, lat, head)]
        for _ in range(3):  # as an operator would: leave out the moves the rules refuse
            r = c.post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": moves})
            if r.status_code != 422:
                break
            refused = {x["index"] for x in r.json()["refusals"]}
            moves = [m for m in moves if m["index"] not in refused]
        assert r.status_code == 200, r.text
        aids[user] = a["id"]
        c.close()
    deadline = time.time() + 120
    while time.time() < deadline:
        tr = server.get_json("admin", f"/api/v1/tasks/{task_id}")["runs"][0]
        if tr["status"] != "open":
            break
        time.sleep(0.5)
    assert tr["status"] in ("agreed", "conflict")
    view = server.get_json("rev1", f"/api/v1/task-runs/{tr['id']}/review")
    assert [s["operator"] for s in view["submissions"]][-1] == "op2" and view["method"] == "weighted"
    measured = {s["operator"]: s["accuracy_m"] for s in view["submissions"]}
    assert measured["op1"] < measured["op3"] < measured["op2"]

    rev = context.new_page()
    login(rev, server, "rev1")
    rev.goto(server.base_url + f"/#/tasks/review/{tr['id']}")
    rev.wait_for_selector(".review-map[data-ready='true']", timeout=30_000)
    order = rev.locator("article.submission").evaluate_all("els => els.map(e => e.dataset.testid)")
    assert order[-1] == f"submission-{aids['op2']}"
    for s in view["submissions"]:
        line = rev.get_by_test_id(f"weighing-{s['assignment_id']}").inner_text()
        assert line.startswith(f"#{s['rank']} · {s['distance_m']:.2f} m from the weighted consensus")
        assert f"accuracy {s['accuracy_m']:.2f} m on 1 gold run(s)" in line and f"weight {round(s['weight'] * 100)} %" in line
    shot(rev, "task-review-weighted")
    admin.close()
