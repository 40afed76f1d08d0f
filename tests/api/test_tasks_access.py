"""Who may do what with tasks: operators see only runs of their current and past assignments
(runs, keyframes, exports, revisions); requesters see their own tasks; reviewers review but
never their own work; every role is refused what it may not do."""

from __future__ import annotations

from tests.api.tasks_support import Env, env, task_body, truth_move  # noqa: F401


def _runs_listed(env: Env, who: str) -> set[int]:
    return {r["id"] for r in env.client(who).get("/api/v1/runs").json()["items"]}


def test_operator_sees_runs_of_current_and_past_assignments_only(env: Env) -> None:
    a_run = env.import_run("drive-a", seed=31)
    b_run = env.import_run("drive-b", seed=32)
    env.add_user("op1", "operator")
    env.client("admin").post("/api/v1/tasks", json=task_body([a_run], assignments_per_run=1))
    assert _runs_listed(env, "op1") == set()
    for path in (f"/api/v1/runs/{a_run}", f"/api/v1/runs/{a_run}/keyframes", f"/api/v1/runs/{a_run}/export?format=csv"):
        assert env.client("op1").get(path).status_code == 404, path
    a = env.client("op1").post("/api/v1/tasks/next").json()["assignment"]
    assert _runs_listed(env, "op1") == {a_run}
    for path in (f"/api/v1/runs/{a_run}", f"/api/v1/runs/{a_run}/keyframes", f"/api/v1/runs/{a_run}/export?format=csv",
                 f"/api/v1/runs/{a_run}/revisions"):
        assert env.client("op1").get(path).status_code == 200, path
    assert env.client("op1").get(f"/api/v1/runs/{b_run}").status_code == 404
    # the live preview works on the leased run
    move = truth_move(env, a_run, 4)
    pv = env.client("op1").post(f"/api/v1/runs/{a_run}/preview", json={"base_revision": 0, "moves": [move]})
    assert pv.status_code == 200, pv.text
    # a past assignment keeps the run visible
    assert env.client("op1").post(f"/api/v1/assignments/{a['id']}/return").status_code == 200
    assert _runs_listed(env, "op1") == {a_run}


def test_requesters_see_their_own_tasks_only(env: Env) -> None:
    admin_run = env.import_run("drive-admin", seed=33)
    client_run = env.import_run("drive-client", seed=34, owner="client")
    admin_task = env.client("admin").post("/api/v1/tasks", json=task_body([admin_run])).json()
    theirs = env.client("client").post("/api/v1/tasks", json=task_body([client_run]))
    assert theirs.status_code == 201, theirs.text
    # a client cannot build a task over someone else's run
    other = env.client("client").post("/api/v1/tasks", json=task_body([admin_run]))
    assert other.status_code == 422 and other.json()["run_ids"] == [admin_run]
    assert [t["id"] for t in env.client("client").get("/api/v1/tasks").json()["items"]] == [theirs.json()["id"]]
    assert env.client("client").get(f"/api/v1/tasks/{admin_task['id']}").status_code == 404
    assert env.client("client").get(f"/api/v1/tasks/{admin_task['id']}/history").status_code == 404
    assert env.client("client").post(f"/api/v1/tasks/{admin_task['id']}/cancel").status_code == 404
    assert {t["id"] for t in env.client("reviewer").get("/api/v1/tasks").json()["items"]} == {admin_task["id"], theirs.json()["id"]}
    c = env.client("client").post(f"/api/v1/tasks/{theirs.json()['id']}/cancel")
    assert c.status_code == 200 and c.json()["status"] == "cancelled" and c.json()["counts"] == {"withdrawn": 2}
    again = env.client("client").post(f"/api/v1/tasks/{theirs.json()['id']}/cancel")
    assert again.status_code == 409 and again.json()["error"] == "task_not_cancellable"


ROLE_CASES = [
    ("op1", "post", "/api/v1/tasks", 403),
    ("op1", "get", "/api/v1/tasks", 403),
    ("op1", "get", "/api/v1/review/queue", 403),
    ("op1", "get", "/api/v1/operators", 403),
    ("op1", "get", "/api/v1/gold-runs", 403),
    ("client", "post", "/api/v1/tasks/next", 403),
    ("client", "get", "/api/v1/operators/me", 403),
    ("client", "get", "/api/v1/review/queue", 403),
    ("reviewer", "post", "/api/v1/tasks", 403),
    ("reviewer", "get", "/api/v1/operators", 403),
    (None, "get", "/api/v1/tasks", 401),
    (None, "post", "/api/v1/tasks/next", 401),
]


def test_role_matrix(env: Env) -> None:
    from fastapi.testclient import TestClient

    env.add_user("op1", "operator")
    anonymous = TestClient(env.app, headers={"Origin": "http://testserver"})
    for who, method, path, status in ROLE_CASES:
        client = env.client(who) if who else anonymous
        body = {"json": task_body([1])} if method == "post" and path.endswith("/tasks") else {}
        r = getattr(client, method)(path, **body)
        assert r.status_code == status, (who, method, path, r.text)


def test_nobody_reviews_their_own_work(env: Env) -> None:
    run_id = env.import_run("drive-a", seed=35)
    env.add_user("op1", "operator")
    env.add_user("reviewer2", "reviewer")
    env.client("admin").post("/api/v1/tasks", json=task_body([run_id], assignments_per_run=2))
    mine = env.client("reviewer").post("/api/v1/tasks/next").json()["assignment"]
    theirs = env.client("op1").post("/api/v1/tasks/next").json()["assignment"]
    for who, a in (("reviewer", mine), ("op1", theirs)):
        r = env.client(who).post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": [truth_move(env, run_id, 3)]})
        assert r.status_code == 200, r.text
    env.drain()
    own = env.client("reviewer").post(f"/api/v1/assignments/{mine['id']}/review", json={"decision": "approve"})
    assert own.status_code == 403 and own.json()["error"] == "own_work"
    # nor the other submissions on a run they worked on, and it is not in their queue
    other = env.client("reviewer").post(f"/api/v1/assignments/{theirs['id']}/review", json={"decision": "approve"})
    assert other.status_code == 403
    assert env.client("reviewer").get("/api/v1/review/queue").json() == []
    assert len(env.client("reviewer2").get("/api/v1/review/queue").json()) == 1
    for feedback in (None, "  "):  # a rejection needs a reason; nothing changes without one
        bare = env.client("reviewer2").post(f"/api/v1/assignments/{mine['id']}/review", json={"decision": "reject", "feedback": feedback})
        assert bare.status_code == 422 and "feedback" in bare.text, bare.text
    assert env.client("reviewer2").get(f"/api/v1/assignments/{mine['id']}").json()["status"] == "submitted"
    ok = env.client("reviewer2").post(f"/api/v1/assignments/{mine['id']}/review", json={"decision": "reject", "feedback": "off road"})
    assert ok.status_code == 200 and ok.json()["status"] == "rejected" and ok.json()["feedback"] == "off road"
    # the reviewer (as worker) sees the feedback on their own assignment
    assert env.client("reviewer").get(f"/api/v1/assignments/{mine['id']}").json()["feedback"] == "off road"
    # another operator's assignment is invisible
    assert env.client("op1").get(f"/api/v1/assignments/{mine['id']}").status_code == 404
