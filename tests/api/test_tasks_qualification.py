"""Qualification edge cases, each with the reason in words: experience, admin-granted
qualifications, home area (point and polygon), accuracy on gold runs, the qualification test."""

from __future__ import annotations

from pathlib import Path

from posefix.tasks.qualification import HomeArea, OperatorFacts, check_home_area, check_requirements
from tests.api.tasks_support import Env, csv_bytes, env, shifted, task_body, truth_move  # noqa: F401


def _next(env: Env, who: str) -> dict:
    r = env.client(who).post("/api/v1/tasks/next")
    assert r.status_code == 200, r.text
    return r.json()


def test_reasons_in_words_for_each_comparator() -> None:
    facts = OperatorFacts(approved_count=3, accuracy_m=2.5, gold_scored=2, granted={"level": 2.0})
    req = lambda q, c, v=None: {"qualification": q, "comparator": c, "value": v}  # noqa: E731
    assert check_requirements([req("approved_count", "ge", 3)], facts) == []
    assert check_requirements([req("approved_count", "gt", 3)], facts) == ["needs more than 3 approved assignments; you have 3"]
    assert check_requirements([req("accuracy_m", "le", 2.0)], facts) == [
        "needs an accuracy of at most 2 m on gold runs; yours is 2.50 m over 2 gold run(s)"]
    assert check_requirements([req("accuracy_m", "le", 3.0)], facts) == []
    assert check_requirements([req("accuracy_m", "le", 3.0)], OperatorFacts()) == [
        "needs an accuracy of at most 3 m on gold runs; yours has not been measured yet"]
    assert check_requirements([req("level", "in", [1, 3])], facts) == ["needs 'level' one of 1, 3; yours is 2"]
    assert check_requirements([req("level", "not_in", [1, 3])], facts) == []
    assert check_requirements([req("level", "not_exists")], facts) == ["is closed to holders of the qualification 'level'"]
    assert check_requirements([req("other", "exists")], facts) == ["needs the qualification 'other', which you do not hold"]
    assert check_requirements([req("level", "eq", 2)], facts) == []
    assert check_requirements([req("home_area", "contains")], facts) == [
        "you have no home area set in your profile, and this task needs runs near home"]
    assert check_requirements([req("qualification_test", "passed")], facts) == [
        "you have not taken the qualification test yet (ask for a task to get it)"]
    # all reasons, not only the first
    assert len(check_requirements([req("approved_count", "ge", 10), req("other", "exists")], facts)) == 2


def test_home_area_point_radius_and_polygon_edges() -> None:
    home = HomeArea(lon=24.94, lat=60.17, radius_m=1000.0)
    lon_in, lat_in = shifted(24.94, 60.17, 999.0, 0.0)
    lon_out, lat_out = shifted(24.94, 60.17, 1001.0, 0.0)
    assert check_home_area(home, [lon_in, lon_out], [lat_in, lat_out]).tolist() == [True, False]
    square = HomeArea(polygon=[[24.0, 60.0], [25.0, 60.0], [25.0, 61.0], [24.0, 61.0]])
    assert check_home_area(square, [24.5, 25.5, 24.5], [60.5, 60.5, 61.5]).tolist() == [True, False, False]
    concave = HomeArea(polygon=[[0, 0], [4, 0], [4, 4], [2, 1], [0, 4]])  # a notch from the top
    assert check_home_area(concave, [2.0, 1.0], [3.0, 1.0]).tolist() == [False, True]
    assert check_home_area(HomeArea(), [24.5], [60.5]).tolist() == [False]


def test_experience_and_granted_qualifications(env: Env) -> None:
    run_id = env.import_run("drive-a", seed=21)
    env.add_user("op1", "operator")
    task = env.client("admin").post("/api/v1/tasks", json=task_body([run_id], requirements=[
        {"qualification": "approved_count", "comparator": "ge", "value": 1},
        {"qualification": "night_driving", "comparator": "ge", "value": 2},
    ])).json()
    out = _next(env, "op1")
    assert out["assignment"] is None
    assert out["message"] == "no task you qualify for has work left; see the reasons per task"
    assert out["ineligible"] == [{"task_id": task["id"], "title": task["title"], "reasons": [
        "needs at least 1 approved assignments; you have 0",
        "needs the qualification 'night_driving', which you do not hold"]}]
    uid = env.users["op1"]
    assert env.client("op1").post(f"/api/v1/operators/{uid}/qualifications", json={"name": "night_driving"}).status_code == 403
    g = env.client("admin").post(f"/api/v1/operators/{uid}/qualifications", json={"name": "night_driving", "value": 1})
    assert g.status_code == 201
    elig = env.client("op1").get(f"/api/v1/tasks/{task['id']}/eligibility").json()
    assert elig["reasons"][1] == "needs 'night_driving' at least 2; yours is 1"
    env.client("admin").post(f"/api/v1/operators/{uid}/qualifications", json={"name": "night_driving", "value": 2})
    assert env.client("op1").get(f"/api/v1/tasks/{task['id']}/eligibility").json()["reasons"] == [
        "needs at least 1 approved assignments; you have 0"]
    assert env.client("admin").delete(f"/api/v1/operators/{uid}/qualifications/night_driving").status_code == 204
    assert env.client("admin").delete(f"/api/v1/operators/{uid}/qualifications/night_driving").status_code == 404


def test_home_area_is_checked_per_run(env: Env) -> None:
    near = env.import_run("drive-near", seed=22)
    env.add_user("op1", "operator")
    task = env.client("admin").post("/api/v1/tasks", json=task_body([near], requirements=[
        {"qualification": "home_area", "comparator": "contains"}])).json()
    assert _next(env, "op1")["ineligible"][0]["reasons"] == [
        "you have no home area set in your profile, and this task needs runs near home"]
    bbox = env.client("admin").get(f"/api/v1/runs/{near}").json()["bbox"]
    centre = ((bbox[0] + bbox[2]) / 2, (bbox[1] + bbox[3]) / 2)
    far = shifted(*centre, 50_000.0, 0.0)
    r = env.client("op1").put("/api/v1/operators/me/home-area", json={"lon": far[0], "lat": far[1], "radius_m": 5000})
    assert r.status_code == 200 and r.json()["home_area"]["radius_m"] == 5000
    assert _next(env, "op1")["ineligible"] == [{"task_id": task["id"], "title": task["title"],
                                               "reasons": ["none of this task's open runs lies within your home area"]}]
    bad = env.client("op1").put("/api/v1/operators/me/home-area", json={"lon": far[0], "lat": far[1]})
    assert bad.status_code == 422 and "together" in bad.json()["detail"]
    poly = [list(shifted(*centre, dx, dy)) for dx, dy in ((-3000, -3000), (3000, -3000), (3000, 3000), (-3000, 3000))]
    assert env.client("op1").put("/api/v1/operators/me/home-area", json={"polygon": poly}).status_code == 200
    got = _next(env, "op1")["assignment"]
    assert got is not None and got["run_id"] == near


def _gold(env: Env, tmp_path: Path, run_id: int, **form: str) -> None:
    data = csv_bytes(env.sims[run_id].truth, tmp_path, f"truth-{run_id}.csv")
    r = env.client("admin").post("/api/v1/gold-runs", data={"run_id": str(run_id), **form},
                                 files={"truth": ("truth.csv", data, "text/csv")})
    assert r.status_code == 201, r.text


def _good_moves(env: Env, run_id: int) -> list[dict]:
    n = len(env.keyframes(run_id))
    return [truth_move(env, run_id, k) for k in range(0, n, 3)]


def test_accuracy_on_unmarked_gold_runs(env: Env, tmp_path: Path) -> None:
    gold_run = env.import_run("drive-gold", seed=23)
    work_run = env.import_run("drive-work", seed=24)
    _gold(env, tmp_path, gold_run)
    env.add_user("good", "operator")
    env.add_user("sloppy", "operator")
    env.client("admin").post("/api/v1/tasks", json=task_body([gold_run], assignments_per_run=2, priority=10))
    strict = env.client("admin").post("/api/v1/tasks", json=task_body([work_run], requirements=[
        {"qualification": "accuracy_m", "comparator": "le", "value": 1.5}])).json()
    reasons = {}
    for who, east in (("good", 0.0), ("sloppy", 15.0)):
        out = _next(env, who)
        a = out["assignment"]
        assert a["run_id"] == gold_run and "gold" not in str(a).lower()  # nothing marks it
        assert out["ineligible"][0]["reasons"] == [
            "needs an accuracy of at most 1.5 m on gold runs; yours has not been measured yet"]
        moves = [truth_move(env, gold_run, m["index"], error_east_m=east) for m in _good_moves(env, gold_run)]
        r = env.client(who).post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": moves})
        assert r.status_code == 200, r.text
    env.drain()
    stats = {s["username"]: s for s in env.client("admin").get("/api/v1/operators").json()}
    assert stats["good"]["gold_scored"] == 1 and stats["good"]["accuracy_m"] < 1.5
    assert stats["sloppy"]["accuracy_m"] > 10.0
    mine = env.client("sloppy").get("/api/v1/operators/me").json()
    assert mine["accuracy_m"] == stats["sloppy"]["accuracy_m"] and mine["username"] == "sloppy"
    assert env.client("sloppy").get("/api/v1/operators").status_code == 403
    for who in ("good", "sloppy"):
        reasons[who] = env.client(who).get(f"/api/v1/tasks/{strict['id']}/eligibility").json()["reasons"]
    assert reasons["good"] == []
    assert reasons["sloppy"][0].startswith("needs an accuracy of at most 1.5 m on gold runs; yours is 1")


def test_qualification_test_before_first_work(env: Env, tmp_path: Path) -> None:
    test_run = env.import_run("drive-test", seed=25)
    work_run = env.import_run("drive-work", seed=26)
    _gold(env, tmp_path, test_run, is_test="true", pass_error_m="2.0")
    env.add_user("pass", "operator")
    env.add_user("fail", "operator")
    task = env.client("admin").post("/api/v1/tasks", json=task_body([work_run], requirements=[
        {"qualification": "qualification_test", "comparator": "passed"}])).json()
    for who, east in (("pass", 0.0), ("fail", 25.0)):
        out = _next(env, who)
        a = out["assignment"]
        assert a["run_id"] == test_run and a["task"]["title"] == "Qualification test"
        assert out["message"].startswith("first, the qualification test")
        pending = env.client(who).get(f"/api/v1/tasks/{task['id']}/eligibility").json()["reasons"]
        assert pending == ["your qualification test is still being scored or corrected"]
        moves = [truth_move(env, test_run, m["index"], error_east_m=east) for m in _good_moves(env, test_run)]
        assert env.client(who).post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": moves}).status_code == 200
    env.drain()
    got = _next(env, "pass")["assignment"]
    assert got is not None and got["run_id"] == work_run
    out = _next(env, "fail")
    assert out["assignment"] is None
    reason = out["ineligible"][0]["reasons"][0]
    assert reason.startswith("you did not pass the qualification test (mean error ") and "pass mark 2.00 m" in reason
    stats = {s["username"]: s["test_status"] for s in env.client("admin").get("/api/v1/operators").json()}
    assert stats == {"pass": "passed", "fail": "failed"}
    # the test task is not a requester's task
    assert all(t["title"] != "Qualification test" for t in env.client("admin").get("/api/v1/tasks").json()["items"])


def test_bad_truth_file_is_refused_and_nothing_kept(env: Env, tmp_path: Path) -> None:
    run_id = env.import_run("drive-a", seed=27)
    r = env.client("admin").post("/api/v1/gold-runs", data={"run_id": str(run_id)},
                                 files={"truth": ("truth.csv", b"t,lat,lon\n0,60.1,notanumber\n", "text/csv")})
    assert r.status_code == 422 and r.json()["error"] == "invalid_truth" and "truth.csv" in r.json()["detail"]
    assert env.client("admin").get("/api/v1/gold-runs").json() == []
    assert not (env.settings.files_dir / "gold").exists()


def test_eligibility_hides_tasks_the_operator_may_not_see(env: Env) -> None:
    """An operator learns of live tasks from the queue; a finished one they never worked on
    answers exactly as a task that does not exist."""
    run_a, run_b = env.import_run("drive-a", seed=31), env.import_run("drive-b", seed=32)
    env.add_user("op1", "operator")
    env.add_user("op2", "operator")
    admin = env.client("admin")
    worked = admin.post("/api/v1/tasks", json=task_body([run_a], assignments_per_run=1)).json()["id"]
    assert _next(env, "op1")["assignment"]["task_id"] == worked
    unseen = admin.post("/api/v1/tasks", json=task_body([run_b], assignments_per_run=1)).json()["id"]
    assert env.client("op2").get(f"/api/v1/tasks/{unseen}/eligibility").status_code == 200  # live: the queue names it
    for task_id in (worked, unseen):
        assert admin.post(f"/api/v1/tasks/{task_id}/cancel").status_code == 200
    absent = env.client("op2").get("/api/v1/tasks/999999/eligibility")
    assert absent.status_code == 404
    for who, task_id in (("op2", unseen), ("op2", worked), ("op1", unseen)):
        r = env.client(who).get(f"/api/v1/tasks/{task_id}/eligibility")
        assert (r.status_code, r.json()["error"]) == (404, absent.json()["error"]), (who, task_id)
        assert r.json()["detail"] == absent.json()["detail"].replace("999999", str(task_id))
    assert env.client("op1").get(f"/api/v1/tasks/{worked}/eligibility").status_code == 200  # held an assignment
    assert admin.get(f"/api/v1/tasks/{unseen}/eligibility").status_code == 200
    assert env.client("reviewer").get(f"/api/v1/tasks/{unseen}/eligibility").status_code == 200
