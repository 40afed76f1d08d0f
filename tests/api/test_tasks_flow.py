"""The whole life of a task over HTTP on SQLite and PostgreSQL: create (idempotent), lease,
submit two different corrections, conflict flagged, review, merged revision written."""

from __future__ import annotations

from tests.api.tasks_support import Env, env, task_body, truth_move  # noqa: F401


def _setup(env: Env) -> tuple[int, int]:
    run_id = env.import_run("drive-a", seed=11)
    env.add_user("op1", "operator")
    env.add_user("op2", "operator")
    env.add_user("op3", "operator")
    r = env.client("admin").post("/api/v1/tasks", json=task_body([run_id], client_token="tok-1"))
    assert r.status_code == 201, r.text
    return run_id, r.json()["id"]


def test_conflicting_corrections_are_flagged_reviewed_and_merged(env: Env) -> None:
    run_id, task_id = _setup(env)
    a1 = env.client("op1").post("/api/v1/tasks/next").json()["assignment"]
    a2 = env.client("op2").post("/api/v1/tasks/next").json()["assignment"]
    assert a1 and a2 and a1["run_id"] == a2["run_id"] == run_id and a1["id"] != a2["id"]
    assert a1["lease_remaining_s"] == 600 and a1["task"]["instructions"].startswith("Drag")
    third = env.client("op3").post("/api/v1/tasks/next").json()
    assert third["assignment"] is None and third["message"] == "no work is available right now"

    # the operator can now see the run (and only because of the assignment)
    assert env.client("op1").get(f"/api/v1/runs/{run_id}").status_code == 200
    assert env.client("op3").get(f"/api/v1/runs/{run_id}").status_code == 404

    # op1 drags keyframes 10..12 onto the truth, op2 puts them 20 m east of it
    m1 = [truth_move(env, run_id, k) for k in (10, 20, 30)]
    m2 = [truth_move(env, run_id, k, error_east_m=20.0) for k in (10, 20, 30)]
    r1 = env.client("op1").post(f"/api/v1/assignments/{a1['id']}/submit", json={"moves": m1, "comment": "on the road"})
    assert r1.status_code == 200, r1.text
    assert r1.json()["assignment"]["status"] == "submitted"
    r2 = env.client("op2").post(f"/api/v1/assignments/{a2['id']}/submit", json={"moves": m2})
    assert r2.status_code == 200, r2.text
    env.drain()

    task = env.client("admin").get(f"/api/v1/tasks/{task_id}").json()
    assert task["status"] == "reviewable"
    tr = task["runs"][0]
    assert tr["status"] == "conflict"
    kinds = {c["kind"] for c in tr["conflicts"]}
    assert kinds == {"tracks_apart", "edits_apart"}
    edit_conf = [c for c in tr["conflicts"] if c["kind"] == "edits_apart"]
    assert sorted(c["index"] for c in edit_conf) == [10, 20, 30]
    assert all(19.0 < c["distance_m"] < 21.0 for c in edit_conf)

    queue = env.client("reviewer").get("/api/v1/review/queue").json()
    assert [q["task_run_id"] for q in queue] == [tr["id"]] and queue[0]["status"] == "conflict"
    view = env.client("reviewer").get(f"/api/v1/task-runs/{tr['id']}/review").json()
    assert len(view["submissions"]) == 2 and len(view["disagreement_m"]) == len(view["reported"])
    assert 19.0 < max(view["disagreement_m"]) < 21.5
    assert [len(s["moves"]) for s in view["submissions"]] == [3, 3]
    # the consensus is the engine's re-optimisation of the medians: at keyframe 10 midway (~10 m east of truth)
    assert len(view["consensus"]) == len(view["reported"])
    mid = truth_move(env, run_id, 10, error_east_m=10.0)
    assert abs(view["consensus"][10][0] - mid["lon"]) < 2e-5 and abs(view["consensus"][10][1] - mid["lat"]) < 1e-5
    assert all(8.0 < s["consensus_error_m"] < 12.0 for s in view["submissions"])

    # operators cannot review, nobody reviews their own work
    assert env.client("op1").post(f"/api/v1/assignments/{a2['id']}/review", json={"decision": "approve"}).status_code == 403
    # the reviewer sides with op1 (approving both would be stopped: two tracks 20 m apart do not
    # show that their midpoint beats the input, test_tasks_crowd)
    for aid, decision in ((a1["id"], "approve"), (a2["id"], "reject")):
        r = env.client("reviewer").post(f"/api/v1/assignments/{aid}/review", json={"decision": decision, "feedback": "ok"})
        assert r.status_code == 200, r.text
    again = env.client("reviewer").post(f"/api/v1/assignments/{a1['id']}/review", json={"decision": "reject", "feedback": "late"})
    assert again.status_code == 409 and again.json()["error"] == "not_reviewable"
    env.drain()

    task = env.client("admin").get(f"/api/v1/tasks/{task_id}").json()
    assert task["runs"][0]["status"] == "merged" and task["status"] == "done"
    merged = task["runs"][0]["merged_revision"]
    revs = env.client("admin").get(f"/api/v1/runs/{run_id}/revisions").json()["items"]
    assert [r["number"] for r in revs] == [0, merged] == [0, 1]
    # the merged move of keyframe 10 is op1's (on the truth)
    detail = env.client("admin").get(f"/api/v1/runs/{run_id}/revisions/1").json()
    moves = {m[0]: m for m in detail["edit_set"]["moves"]}
    assert set(moves) == {10, 20, 30}
    t10 = truth_move(env, run_id, 10)
    assert abs(moves[10][1] - t10["lon"]) < 2e-6 and abs(moves[10][2] - t10["lat"]) < 2e-6
    hist = env.client("admin").get(f"/api/v1/tasks/{task_id}/history").json()
    seq = [(h["entity"], h["from_status"], h["to_status"]) for h in hist]
    assert ("task", "assignable", "in_progress") in seq and ("task", "reviewable", "done") in seq
    assert ("task_run", "open", "conflict") in seq and ("task_run", "merging", "merged") in seq


def test_idempotent_creation(env: Env) -> None:
    run_id, task_id = _setup(env)
    again = env.client("admin").post("/api/v1/tasks", json=task_body([run_id], client_token="tok-1"))
    assert again.status_code == 200 and again.json()["id"] == task_id
    other = env.client("admin").post("/api/v1/tasks", json=task_body([run_id], client_token="tok-1", priority=5))
    assert other.status_code == 409 and other.json()["error"] == "client_token_reused"
    listed = env.client("admin").get("/api/v1/tasks").json()
    assert listed["total"] == 1
    # after 24 h the token is forgotten and names a new task
    env.clock.advance(24 * 3600 + 1)
    later = env.client("admin").post("/api/v1/tasks", json=task_body([run_id], client_token="tok-1"))
    assert later.status_code == 201 and later.json()["id"] != task_id


def test_bad_task_input_is_refused_with_field(env: Env) -> None:
    run_id, _ = _setup(env)
    r = env.client("admin").post("/api/v1/tasks", json=task_body([run_id, 999]))
    assert r.status_code == 422 and r.json()["error"] == "unknown_runs" and r.json()["run_ids"] == [999]
    reqs = [{"qualification": f"q{i}", "comparator": "exists"} for i in range(11)]
    r = env.client("admin").post("/api/v1/tasks", json=task_body([run_id], requirements=reqs))
    assert r.status_code == 422 and "requirements" in r.json()["detail"]
    r = env.client("admin").post("/api/v1/tasks", json=task_body([run_id], requirements=[
        {"qualification": "approved_count", "comparator": "exists"}]))
    assert r.status_code == 422 and "numeric comparator" in r.json()["detail"]
    assert env.client("admin").get("/api/v1/tasks").json()["total"] == 1


def test_extend_policy_asks_one_more_operator_and_the_plurality_wins(env: Env) -> None:
    run_id = env.import_run("drive-b", seed=12)
    for n in ("op1", "op2", "op3", "op4"):
        env.add_user(n, "operator")
    task = env.client("admin").post("/api/v1/tasks", json=task_body(
        [run_id], conflict_policy="extend", max_extra_assignments=1)).json()
    ids = {}
    for who, east in (("op1", 0.0), ("op2", 20.0)):
        a = env.client(who).post("/api/v1/tasks/next").json()["assignment"]
        ids[who] = a["id"]
        r = env.client(who).post(f"/api/v1/assignments/{a['id']}/submit",
                                 json={"moves": [truth_move(env, run_id, k, error_east_m=east) for k in (10, 30)]})
        assert r.status_code == 200, r.text
    env.drain()
    t = env.client("admin").get(f"/api/v1/tasks/{task['id']}").json()
    assert t["status"] == "in_progress" and t["runs"][0]["status"] == "open" and t["runs"][0]["wanted"] == 3
    assert t["counts"]["open"] == 1
    # the third operator agrees (within a metre) with op1
    a3 = env.client("op3").post("/api/v1/tasks/next").json()["assignment"]
    r = env.client("op3").post(f"/api/v1/assignments/{a3['id']}/submit",
                               json={"moves": [truth_move(env, run_id, k, error_east_m=0.8) for k in (10, 30)]})
    assert r.status_code == 200
    env.drain()
    t = env.client("admin").get(f"/api/v1/tasks/{task['id']}").json()
    tr = t["runs"][0]
    assert tr["status"] == "agreed" and t["status"] == "reviewable"
    # three operators: their accuracies are estimated from how they agree, and op2 is off by more than they explain
    assert [(c["kind"], c["a"]) for c in tr["conflicts"]] == [("off_consensus", ids["op2"])]
    held = env.client("op2").get(f"/api/v1/assignments/{ids['op2']}").json()
    assert held["auto_approve_at"] is None  # held for a reviewer
    # and so is the agreeing pair: two operators never measured, against an outlier, could be an
    # accurate one and a careless one, and nothing yet says which
    assert env.client("op1").get(f"/api/v1/assignments/{ids['op1']}").json()["auto_approve_at"] is None
    view = env.client("reviewer").get(f"/api/v1/task-runs/{tr['id']}/review").json()
    assert view["method"] == "weighted" and view["submissions"][-1]["operator"] == "op2"
    assert view["submissions"][-1]["off_consensus"] and view["submissions"][-1]["weight"] < 0.05
    err = {s["operator"]: s["consensus_error_m"] for s in view["submissions"]}
    assert err["op2"] > 15.0 and err["op1"] < 2.0 and err["op3"] < 2.0  # the median sits with the majority
    # the outlier is rejected, the others approved; the merge uses the approved two
    env.client("reviewer").post(f"/api/v1/assignments/{ids['op2']}/review", json={"decision": "reject", "feedback": "20 m off"})
    assert env.client("admin").get(f"/api/v1/tasks/{task['id']}").json()["runs"][0]["status"] == "agreed"
    for aid in (ids["op1"], a3["id"]):
        env.client("reviewer").post(f"/api/v1/assignments/{aid}/review", json={"decision": "approve"})
    env.drain()
    t = env.client("admin").get(f"/api/v1/tasks/{task['id']}").json()
    assert t["runs"][0]["status"] == "merged" and t["status"] == "done"
    moves = {m[0]: m for m in env.client("admin").get(f"/api/v1/runs/{run_id}/revisions/1").json()["edit_set"]["moves"]}
    # between the two approved corrections (0 and 0.8 m east of truth), nowhere near op2's 20 m:
    # within half a metre (1e-5 degrees of longitude is 0.55 m here)
    ref = truth_move(env, run_id, 10, error_east_m=0.4)
    assert abs(moves[10][1] - ref["lon"]) < 1e-5 and abs(moves[10][2] - ref["lat"]) < 1e-5


def test_requester_receives_transitions_as_server_sent_events(env: Env) -> None:
    run_id = env.import_run("drive-c", seed=13)
    env.add_user("op1", "operator")
    task = env.client("admin").post("/api/v1/tasks", json=task_body([run_id], assignments_per_run=1)).json()
    env.client("op1").post("/api/v1/tasks/next")
    env.client("admin").post(f"/api/v1/tasks/{task['id']}/cancel")
    with env.client("admin").stream("GET", f"/api/v1/tasks/{task['id']}/events?max_s=10") as r:
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream")
        body = "".join(r.iter_text())
    events = [line for line in body.splitlines() if line.startswith("event:")]
    assert events and all(e == "event: task.transition" for e in events)
    assert '"to_status": "cancelled"' in body and '"to_status": "accepted"' in body
    assert env.client("op1").get(f"/api/v1/tasks/{task['id']}/events").status_code == 404
