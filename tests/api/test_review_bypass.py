"""Review cannot be bypassed (issue 11, section 1), on SQLite and PostgreSQL.

An operator's work on a task's run goes through the assignment (submit, review or
consensus, merge): direct edits, accept and revert on a task run are for reviewers and
admins; a ``task_id`` on an edit names a task the caller holds a live assignment of;
nobody reviews a run they edited; tokens are made from a login session only.
"""

from __future__ import annotations

from fastapi.testclient import TestClient

from tests.api.tasks_support import Env, env, task_body, truth_move  # noqa: F401


def _task_run(env: Env) -> tuple[int, int, dict]:
    """A run under a task (assignments_per_run 1), op1 holding its assignment."""
    run_id = env.import_run("drive-a", seed=11)
    env.add_user("op1", "operator")
    r = env.client("admin").post("/api/v1/tasks", json=task_body([run_id], assignments_per_run=1))
    assert r.status_code == 201, r.text
    a = env.client("op1").post("/api/v1/tasks/next").json()["assignment"]
    assert a is not None and a["run_id"] == run_id
    return run_id, r.json()["id"], a


def _run(env: Env, run_id: int) -> dict:
    return env.client("admin").get(f"/api/v1/runs/{run_id}").json()


def test_operator_cannot_write_a_task_run_directly(env: Env) -> None:
    run_id, task_id, a = _task_run(env)
    op = env.client("op1")
    move = truth_move(env, run_id, 10)
    # holding the lease, and after submitting: never straight onto the run
    for when in ("leased", "submitted"):
        for body in ({"base_revision": 0, "moves": [move], "accept": True},
                     {"base_revision": 0, "accept": True},
                     {"base_revision": 0, "moves": [move], "task_id": task_id}):
            r = op.post(f"/api/v1/runs/{run_id}/edits", json=body)
            assert r.status_code == 403 and r.json()["error"] == "review_required", (when, body, r.text)
        r = op.post(f"/api/v1/runs/{run_id}/revert", json={"to_revision": 0})
        assert r.status_code == 403 and r.json()["error"] == "review_required", (when, r.text)
        if when == "leased":
            sub = op.post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": [move], "accept": True})
            assert sub.status_code == 200, sub.text
    run = _run(env, run_id)
    assert run["status"] == "imported" and run["head_revision"] == 0
    # a preview stores nothing, so the operator may still preview the run they work on
    p = op.post(f"/api/v1/runs/{run_id}/preview", json={"base_revision": 0, "moves": [move]})
    assert p.status_code == 200, p.text
    assert _run(env, run_id)["head_revision"] == 0
    # reviewers and admins still write task runs directly
    r = env.client("reviewer").post(f"/api/v1/runs/{run_id}/edits", json={"base_revision": 0, "moves": [move]})
    assert r.status_code == 202, r.text
    r = env.client("admin").post(f"/api/v1/runs/{run_id}/revert", json={"to_revision": 0})
    assert r.status_code == 202, r.text


def test_task_id_must_name_a_live_assignment_of_the_caller(env: Env) -> None:
    run_id, task_id, _ = _task_run(env)
    other = env.import_run("drive-b", seed=12)
    env.settings.operators_see_all_runs = True  # the operator may write runs that belong to no task
    move = truth_move(env, other, 10)
    for who in ("op1", "admin", "reviewer"):
        for tid in (task_id, 99999):
            r = env.client(who).post(f"/api/v1/runs/{other}/edits", json={"base_revision": 0, "moves": [move], "task_id": tid})
            assert r.status_code == 403 and r.json()["error"] == "not_on_task", (who, tid, r.text)
    assert _run(env, other)["head_revision"] == 0
    # without a task_id the operator's edit of a run in no task stands (and needs review to be accepted)
    r = env.client("op1").post(f"/api/v1/runs/{other}/edits", json={"base_revision": 0, "moves": [move], "accept": True})
    assert r.status_code == 202, r.text
    assert _run(env, other)["status"] == "corrected"


def test_reviewer_cannot_review_their_own_edits(env: Env) -> None:
    run_id = env.import_run("drive-a", seed=11)
    env.add_user("reviewer2", "reviewer")
    r = env.client("reviewer").post(f"/api/v1/runs/{run_id}/edits",
                                    json={"base_revision": 0, "moves": [truth_move(env, run_id, 10)]})
    assert r.status_code == 202, r.text
    env.drain()
    for decision in ("accept", "reject"):
        own = env.client("reviewer").post(f"/api/v1/runs/{run_id}/review", json={"decision": decision})
        assert own.status_code == 403 and own.json()["error"] == "own_work", own.text
    assert _run(env, run_id)["status"] == "in_review"
    ok = env.client("reviewer2").post(f"/api/v1/runs/{run_id}/review", json={"decision": "accept"})
    assert ok.status_code == 200 and ok.json()["status"] == "accepted", ok.text


def test_tokens_are_made_from_a_login_session_only(env: Env) -> None:
    env.add_user("op1", "operator")
    session = env.client("op1")
    made = {}
    for scope in ("read", "write"):
        r = session.post("/api/v1/tokens", json={"name": scope, "scope": scope})
        assert r.status_code == 201, r.text
        made[scope] = {"Authorization": f"Bearer {r.json()['token']}"}
    bare = TestClient(env.app)
    for scope in ("read", "write"):
        for wanted in ("read", "write"):
            r = bare.post("/api/v1/tokens", json={"name": "more", "scope": wanted}, headers=made[scope])
            assert r.status_code == 403, (scope, wanted, r.text)
            assert r.json()["error"] == ("session_required" if scope == "write" else "insufficient_scope")
    assert len(session.get("/api/v1/tokens").json()["items"]) == 2
