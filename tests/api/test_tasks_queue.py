"""The queue under real concurrency (threads, one database session each) and the lease life
cycle with the controllable clock: expiry, late submit, extend, return, auto-approval."""

from __future__ import annotations

import threading
import time
from collections import Counter

from sqlalchemy import func, select

from posefix.tasks import leases, lifecycle, maintenance
from posefix.tasks.states import MAINTAIN_JOB
from posefix.tasks.models import Assignment, TaskEvent
from tests.api.tasks_support import Env, env, task_body, truth_move  # noqa: F401

N_OPERATORS = 50


def _ask_all_at_once(env: Env, names: list[str]) -> list[dict]:
    barrier = threading.Barrier(len(names))
    results: list[dict] = [{}] * len(names)
    errors: list[BaseException] = []

    def ask(i: int, name: str) -> None:
        try:
            barrier.wait()
            with env.db.transaction() as s:
                out = leases.next_assignment(s, env.principal(name, "operator"), env.clock.now())
                results[i] = {"assignment": out["assignment"].model_dump() if out["assignment"] else None,
                              "message": out["message"]}
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=ask, args=(i, n)) for i, n in enumerate(names)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not errors, errors
    return results


def test_fifty_operators_at_once_get_exactly_n_leases(env: Env) -> None:
    run_a = env.import_run("drive-a", seed=1)
    run_b = env.import_run("drive-b", seed=2)
    names = [f"op{i:02d}" for i in range(N_OPERATORS)]
    env.add_operators(names)
    n_wanted = 3
    r = env.client("admin").post("/api/v1/tasks", json=task_body([run_a, run_b], assignments_per_run=n_wanted))
    assert r.status_code == 201, r.text
    started = time.perf_counter()
    results = _ask_all_at_once(env, names)
    print(f"50 concurrent next: {time.perf_counter() - started:.2f} s")
    got = [x["assignment"] for x in results if x["assignment"]]
    assert len(got) == 2 * n_wanted
    assert len({a["id"] for a in got}) == len(got)
    assert Counter(a["run_id"] for a in got) == {run_a: n_wanted, run_b: n_wanted}
    assert len({a["operator_id"] for a in got}) == len(got)  # one lease per operator
    assert all(x["message"] == "no work is available right now" for x in results if not x["assignment"])
    with env.db.transaction(write=False) as s:
        held = s.scalar(select(func.count()).select_from(Assignment).where(Assignment.status == "accepted"))
        leased_events = s.scalar(select(func.count()).select_from(TaskEvent).where(TaskEvent.to_status == "accepted"))
    assert held == leased_events == 2 * n_wanted


def test_one_operator_asking_many_times_at_once_holds_one_lease(env: Env) -> None:
    runs = [env.import_run(f"drive-{i}", seed=10 + i) for i in range(3)]
    env.add_user("solo", "operator")
    r = env.client("admin").post("/api/v1/tasks", json=task_body(runs, assignments_per_run=1))
    assert r.status_code == 201
    results = _ask_all_at_once(env, ["solo"] * 8)
    got = [x for x in results if x["assignment"]]
    assert len(got) == 1
    assert {x["message"] for x in results if not x["assignment"]} == {"finish or return the assignment you hold first"}
    # a task allowing two leases at once gives a second one
    r = env.client("admin").post("/api/v1/tasks", json=task_body(runs, assignments_per_run=1, max_active_leases=2, priority=5))
    again = env.client("solo").post("/api/v1/tasks/next").json()
    assert again["assignment"] is not None and again["assignment"]["task_id"] == r.json()["id"]
    assert again["assignment"]["run_id"] != got[0]["assignment"]["run_id"]  # never the same run twice


def test_lease_expiry_late_submit_extend_and_return(env: Env) -> None:
    run_id = env.import_run("drive-a", seed=3)
    for n in ("op1", "op2", "op3"):
        env.add_user(n, "operator")
    env.client("admin").post("/api/v1/tasks", json=task_body([run_id], assignments_per_run=1, lease_s=300))
    a = env.client("op1").post("/api/v1/tasks/next").json()["assignment"]
    move = [truth_move(env, run_id, 5)]

    env.clock.advance(200)
    ext = env.client("op1").post(f"/api/v1/assignments/{a['id']}/extend")
    assert ext.status_code == 200 and ext.json()["lease_remaining_s"] == 300
    env.clock.advance(301)
    # past the deadline, before the worker noticed: still refused, and not counted
    late = env.client("op1").post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": move})
    assert late.status_code == 410 and late.json()["error"] == "lease_expired"
    assert env.client("op1").post(f"/api/v1/assignments/{a['id']}/extend").status_code == 410
    with env.db.transaction() as s:
        counts = maintenance.maintain(s, env.clock.now())
    assert counts["leases_expired"] == 1
    late = env.client("op1").post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": move})
    assert late.status_code == 410
    mine = env.client("op1").get(f"/api/v1/assignments/{a['id']}").json()
    assert mine["status"] == "expired" and mine["submitted_at"] is None
    hist = env.client("admin").get(f"/api/v1/tasks/{a['task_id']}/history").json()
    assert [h["reason"] for h in hist if h["assignment_id"] == a["id"]] == ["leased", "extended", "lease expired"]
    # the slot is back in the pool, but never for op1 again
    assert env.client("op1").post("/api/v1/tasks/next").json()["assignment"] is None
    b = env.client("op2").post("/api/v1/tasks/next").json()["assignment"]
    assert b is not None and b["run_id"] == run_id
    ret = env.client("op2").post(f"/api/v1/assignments/{b['id']}/return")
    assert ret.status_code == 200 and ret.json()["status"] == "returned"
    assert env.client("op2").post(f"/api/v1/assignments/{b['id']}/submit", json={"moves": move}).status_code == 409
    c = env.client("op3").post("/api/v1/tasks/next").json()["assignment"]
    assert c is not None
    # someone else's assignment is not found, whatever its state
    assert env.client("op1").post(f"/api/v1/assignments/{c['id']}/submit", json={"moves": move}).status_code == 404
    ok = env.client("op3").post(f"/api/v1/assignments/{c['id']}/submit", json={"moves": move})
    assert ok.status_code == 200, ok.text
    task = env.client("admin").get(f"/api/v1/tasks/{a['task_id']}").json()
    assert task["counts"] == {"expired": 1, "returned": 1, "submitted": 1}


def test_auto_approval_after_the_delay_merges_the_run(env: Env) -> None:
    run_id = env.import_run("drive-a", seed=4)
    env.add_user("op1", "operator")
    r = env.client("admin").post("/api/v1/tasks", json=task_body([run_id], assignments_per_run=1, auto_approval_delay_s=3600))
    task_id = r.json()["id"]
    a = env.client("op1").post("/api/v1/tasks/next").json()["assignment"]
    sub = env.client("op1").post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": [truth_move(env, run_id, 7)]})
    assert sub.status_code == 200
    env.drain()
    assert env.client("admin").get(f"/api/v1/tasks/{task_id}").json()["runs"][0]["status"] == "agreed"
    env.clock.advance(3599)
    with env.db.transaction() as s:
        assert maintenance.maintain(s, env.clock.now())["auto_approved"] == 0
    env.clock.advance(2)
    with env.db.transaction() as s:
        assert maintenance.maintain(s, env.clock.now())["auto_approved"] == 1
    env.drain()
    mine = env.client("op1").get(f"/api/v1/assignments/{a['id']}").json()
    assert mine["status"] == "approved" and "automatically" in mine["feedback"]
    task = env.client("admin").get(f"/api/v1/tasks/{task_id}").json()
    assert task["status"] == "done" and task["runs"][0]["merged_revision"] == 1
    revs = env.client("admin").get(f"/api/v1/runs/{run_id}/revisions").json()["items"]
    assert [r["number"] for r in revs] == [0, 1] and revs[1]["n_moves"] == 1


def test_task_lifetime_ends_and_open_slots_are_withdrawn(env: Env) -> None:
    run_id = env.import_run("drive-a", seed=5)
    other = env.import_run("drive-b", seed=6)
    env.add_user("op1", "operator")
    env.add_user("op2", "operator")
    task_id = env.client("admin").post("/api/v1/tasks", json=task_body([run_id, other], lifetime_s=3600, auto_approval_delay_s=86400)).json()["id"]
    a = env.client("op1").post("/api/v1/tasks/next").json()["assignment"]
    assert env.client("op1").post(f"/api/v1/assignments/{a['id']}/submit",
                                  json={"moves": [truth_move(env, a["run_id"], 6)]}).status_code == 200
    env.drain()
    env.clock.advance(3601)
    assert env.client("op2").post("/api/v1/tasks/next").json()["assignment"] is None
    with env.db.transaction() as s:
        assert maintenance.maintain(s, env.clock.now())["tasks_expired"] == 1
    task = env.client("admin").get(f"/api/v1/tasks/{task_id}").json()
    assert task["status"] == "expired" and task["counts"] == {"withdrawn": 3, "submitted": 1}
    # the one submission still reaches review and is merged; the untouched run stays open
    states = {r["run_id"]: r["status"] for r in task["runs"]}
    assert states == {a["run_id"]: "agreed", (other if a["run_id"] == run_id else run_id): "open"}
    assert env.client("reviewer").post(f"/api/v1/assignments/{a['id']}/review", json={"decision": "approve"}).status_code == 200
    env.drain()
    task = env.client("admin").get(f"/api/v1/tasks/{task_id}").json()
    assert {r["run_id"]: r["merged_revision"] for r in task["runs"]}[a["run_id"]] == 1
    # with nothing left that can time out, the worker's maintenance job stops re-scheduling itself
    from posefix.jobs.models import Job

    with env.db.transaction() as s:
        assert maintenance.needs_maintenance(s) is False
        for j in s.scalars(select(Job).where(Job.kind == MAINTAIN_JOB, Job.status == "queued")):
            j.run_after = j.created_at  # due now
    env.drain()
    with env.db.transaction(write=False) as s:
        left = [j.status for j in s.scalars(select(Job).where(Job.kind == MAINTAIN_JOB))]
    assert left and set(left) == {"succeeded"}


def test_same_client_token_at_once_makes_one_task(env: Env) -> None:
    from posefix.runs.access import visible_run_ids
    from posefix.tasks.schemas import TaskCreate

    run_id = env.import_run("drive-a", seed=7)
    admin = env.principal("admin", "admin")
    body = TaskCreate(**task_body([run_id], client_token="same-token"))
    barrier = threading.Barrier(10)
    ids: list[int] = []
    errors: list[BaseException] = []

    def create() -> None:
        try:
            barrier.wait()
            with env.db.transaction() as s:
                task, _created = lifecycle.create_task(s, env.settings, admin, body, env.clock.now(),
                                                     visible=visible_run_ids(admin, env.settings))
                ids.append(task.id)
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=create) for _ in range(10)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors, errors
    assert len(ids) == 10 and len(set(ids)) == 1
    assert env.client("admin").get("/api/v1/tasks").json()["total"] == 1
    assert env.client("admin").get(f"/api/v1/tasks/{ids[0]}").json()["counts"] == {"open": 2}
