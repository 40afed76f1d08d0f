"""The crowd's evidence at work through the API: an operator never measured is served a
gold run before an accuracy requirement is checked; a submission off the weighted consensus
waits for a reviewer; a merge the trusted operator says is worse than the input is stopped."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tests.api.tasks_support import Env, csv_bytes, env, task_body, truth_move  # noqa: F401

ACCURACY = [{"qualification": "accuracy_m", "comparator": "le", "value": 1.5}]


def _gold(env: Env, tmp_path: Path, run_id: int, **form: str) -> None:
    data = csv_bytes(env.sims[run_id].truth, tmp_path, f"truth-{run_id}.csv")
    r = env.client("admin").post("/api/v1/gold-runs", data={"run_id": str(run_id), **form},
                                 files={"truth": ("truth.csv", data, "text/csv")})
    assert r.status_code == 201, r.text


def _next(env: Env, who: str) -> dict[str, Any]:
    r = env.client(who).post("/api/v1/tasks/next")
    assert r.status_code == 200, r.text
    return r.json()


def _submit(env: Env, who: str, a: dict[str, Any], east_m: float, north_m: float = 0.0, every: int = 3) -> None:
    n = len(env.keyframes(a["run_id"]))
    moves = [truth_move(env, a["run_id"], k, error_east_m=east_m, error_north_m=north_m) for k in range(0, n, every)]
    r = env.client(who).post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": moves})
    assert r.status_code == 200, r.text


def test_an_unmeasured_operator_is_served_a_gold_run_first(env: Env, tmp_path: Path) -> None:
    own_gold = env.import_run("drive-own-gold", seed=31)
    test_gold = env.import_run("drive-test-gold", seed=32)
    work = env.import_run("drive-work", seed=33)
    _gold(env, tmp_path, own_gold)
    _gold(env, tmp_path, test_gold, is_test="true", pass_error_m="100")
    for who in ("first", "second", "sloppy"):
        env.add_user(who, "operator")
    task = env.client("admin").post("/api/v1/tasks", json=task_body([work, own_gold], assignments_per_run=2,
                                                                      requirements=ACCURACY)).json()
    # the task's own gold run while it has slots, then the test gold run
    served = {}
    for who, east in (("first", 0.0), ("second", 0.0), ("sloppy", 15.0)):
        out = _next(env, who)
        assert out["message"].startswith("first, a gold run that measures your accuracy"), out
        served[who] = out["assignment"]["run_id"]
        assert _next(env, who)["assignment"] is None  # one lease at a time, and no second gold run while one is held
        _submit(env, who, out["assignment"], east)
    assert served == {"first": own_gold, "second": own_gold, "sloppy": test_gold}
    env.drain()
    stats = {s["username"]: s for s in env.client("admin").get("/api/v1/operators").json()}
    assert stats["first"]["accuracy_m"] < 1.5 and stats["second"]["accuracy_m"] < 1.5 and stats["sloppy"]["accuracy_m"] > 10
    # measured: now the requirement decides
    assert _next(env, "second")["assignment"]["run_id"] == work
    out = _next(env, "sloppy")
    assert out["assignment"] is None
    assert out["ineligible"][0]["task_id"] == task["id"]
    assert out["ineligible"][0]["reasons"][0].startswith("needs an accuracy of at most 1.5 m on gold runs; yours is 1")


def _measured(env: Env, tmp_path: Path, who: str) -> None:
    """``who`` corrects a gold run onto the truth: their accuracy is measured."""
    gold = env.import_run(f"drive-gold-{who}", seed=41)
    _gold(env, tmp_path, gold)
    env.client("admin").post("/api/v1/tasks", json=task_body([gold], assignments_per_run=1, priority=10))
    a = _next(env, who)["assignment"]
    assert a["run_id"] == gold
    _submit(env, who, a, 0.0)
    env.drain()


def test_work_off_the_weighted_consensus_waits_and_a_bad_majority_is_not_merged(env: Env, tmp_path: Path) -> None:
    for who in ("good", "bad1", "bad2"):
        env.add_user(who, "operator")
    _measured(env, tmp_path, "good")
    work = env.import_run("drive-work", seed=42)
    task = env.client("admin").post("/api/v1/tasks", json=task_body([work], assignments_per_run=3)).json()
    ids = {}
    for who, east, north in (("good", 0.0, 0.0), ("bad1", 25.0, 0.0), ("bad2", 0.0, 25.0)):
        a = _next(env, who)["assignment"]
        assert a["run_id"] == work
        _submit(env, who, a, east, north)
        ids[who] = a["id"]
    env.drain()
    tr = env.client("admin").get(f"/api/v1/tasks/{task['id']}").json()["runs"][0]
    # the unknown two (who disagree with each other too) are off the measured operator's consensus by far more than their expected accuracy:
    # they wait for a reviewer; the measured operator's work keeps its auto-approval time
    assert tr["status"] in ("agreed", "conflict")
    assert {c["a"] for c in tr["conflicts"]} >= {ids["bad1"], ids["bad2"]} and all(c["kind"] == "off_consensus" for c in tr["conflicts"])
    held = {w: env.client("admin").get(f"/api/v1/assignments/{ids[w]}").json()["auto_approve_at"] for w in ids}
    assert held["bad1"] is None and held["bad2"] is None and held["good"] is not None
    view = env.client("reviewer").get(f"/api/v1/task-runs/{tr['id']}/review").json()
    good = next(s for s in view["submissions"] if s["operator"] == "good")
    assert good["accuracy_m"] is not None and good["accuracy_m"] < 1.0 and good["weight"] > 0.9
    # a reviewer backs the majority against the measured operator: the merge would leave the
    # run further from the trusted operator than its input, so it is stopped
    rv = env.client("reviewer")
    assert rv.post(f"/api/v1/assignments/{ids['good']}/review", json={"decision": "reject", "feedback": "disagrees with the others"}).status_code == 200
    for w in ("bad1", "bad2"):
        rv.post(f"/api/v1/assignments/{ids[w]}/review", json={"decision": "approve"})
    env.drain()
    tr = env.client("admin").get(f"/api/v1/tasks/{task['id']}").json()["runs"][0]
    assert tr["status"] == "unmerged" and tr["merged_revision"] is None
    view = rv.get(f"/api/v1/task-runs/{tr['id']}/review").json()
    assert "further than the input from every trusted operator" in view["merge_detail"]["stopped"]
    assert env.client("admin").get(f"/api/v1/runs/{work}").json()["head_revision"] == 0


def test_a_gold_run_scores_the_placements_not_only_the_smoothed_track(env: Env, tmp_path: Path) -> None:
    gold = env.import_run("drive-gold-clicks", seed=51)
    _gold(env, tmp_path, gold)
    env.add_user("zigzag", "operator")
    env.client("admin").post("/api/v1/tasks", json=task_body([gold], assignments_per_run=1, priority=10))
    a = _next(env, "zigzag")["assignment"]
    n = len(env.keyframes(gold))
    # every 3rd keyframe 3 m off the truth, alternately east and west: the engine's track
    # between them averages much of it away, the placements are 3 m off each
    moves = [truth_move(env, gold, k, error_east_m=3.0 if j % 2 else -3.0) for j, k in enumerate(range(0, n, 3))]
    assert env.client("zigzag").post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": moves}).status_code == 200
    env.drain()
    stats = {s["username"]: s for s in env.client("admin").get("/api/v1/operators").json()}
    assert 2.8 < stats["zigzag"]["accuracy_m"] < 3.3


def test_a_merge_not_measurably_better_than_the_input_is_stopped(env: Env) -> None:
    for who in ("east", "west"):
        env.add_user(who, "operator")
    work = env.import_run("drive-apart", seed=52)
    task = env.client("admin").post("/api/v1/tasks", json=task_body([work], assignments_per_run=2)).json()
    ids = {}
    for who, east in (("east", 20.0), ("west", -20.0)):
        a = _next(env, who)["assignment"]
        _submit(env, who, a, east)
        ids[who] = a["id"]
    env.drain()
    for aid in ids.values():  # a reviewer approves both: their midpoint is the truth, but nothing shows it
        assert env.client("reviewer").post(f"/api/v1/assignments/{aid}/review", json={"decision": "approve"}).status_code == 200
    env.drain()
    tr = env.client("admin").get(f"/api/v1/tasks/{task['id']}").json()["runs"][0]
    assert tr["status"] == "unmerged" and tr["merged_revision"] is None
    view = env.client("reviewer").get(f"/api/v1/task-runs/{tr['id']}/review").json()
    assert view["merge_detail"]["stopped"].startswith("the input is not measurably worse than the merge")
    assert env.client("admin").get(f"/api/v1/runs/{work}").json()["head_revision"] == 0


def test_a_merge_whose_revision_fails_says_so_and_can_be_merged_again(env: Env) -> None:
    from sqlalchemy import update

    from posefix.jobs.models import Job, JobStatus
    from posefix.runs import repository as runs_repo
    from posefix.runs import solutions
    from posefix.runs.storage import FileStore

    env.add_user("solo", "operator")
    work = env.import_run("drive-fails", seed=53)
    task = env.client("admin").post("/api/v1/tasks", json=task_body([work], assignments_per_run=1)).json()
    a = _next(env, "solo")["assignment"]
    _submit(env, "solo", a, 0.0)
    env.drain()
    assert env.client("reviewer").post(f"/api/v1/assignments/{a['id']}/review", json={"decision": "approve"}).status_code == 200
    trid = env.client("admin").get(f"/api/v1/tasks/{task['id']}").json()["runs"][0]["id"]
    rv = env.client("reviewer")
    for _ in range(10):  # the merge job submits its batch; its revision job has not run yet
        env.drain(max_jobs=1)
        if "revision" in (rv.get(f"/api/v1/task-runs/{trid}/review").json()["merge_detail"] or {}):
            break
    view = rv.get(f"/api/v1/task-runs/{trid}/review").json()
    assert view["status"] == "merging" and view["merged_revision"] is None  # not merged until the revision is written
    with env.db.transaction() as s:  # storage is gone, and the job gets no second attempt
        path = FileStore(env.settings.files_dir).path(runs_repo.revision(s, work, 0).samples_file)
        s.execute(update(Job).where(Job.status == JobStatus.queued).values(max_attempts=1))
    path.rename(path.with_name(path.name + ".away"))
    solutions.PROBLEMS.forget_all()
    env.drain()
    t = env.client("admin").get(f"/api/v1/tasks/{task['id']}").json()
    assert t["runs"][0]["status"] == "merge_failed" and t["runs"][0]["merged_revision"] is None and t["status"] != "done"
    view = rv.get(f"/api/v1/task-runs/{trid}/review").json()
    assert "FileNotFoundError" in view["merge_detail"]["failed"]
    # storage is back: a reviewer merges again (operators may not)
    path.with_name(path.name + ".away").rename(path)
    assert env.client("solo").post(f"/api/v1/task-runs/{trid}/merge").status_code == 403
    again = rv.post(f"/api/v1/task-runs/{trid}/merge")
    assert again.status_code == 200 and again.json()["status"] == "merging", again.text
    env.drain()
    t = env.client("admin").get(f"/api/v1/tasks/{task['id']}").json()
    assert t["runs"][0]["status"] == "merged" and t["runs"][0]["merged_revision"] == 1 and t["status"] == "done"
    assert env.client("admin").get(f"/api/v1/runs/{work}").json()["head_revision"] == 1
    twice = rv.post(f"/api/v1/task-runs/{trid}/merge")
    assert twice.status_code == 409 and twice.json()["error"] == "not_merge_failed"


def test_a_merged_revision_carries_the_fused_uncertainty_of_each_move(env: Env) -> None:
    import numpy as np

    from posefix.tasks import repository as repo
    from posefix.tasks.merge import edit_sigma_m
    from posefix.tasks.models import AssignmentStatus, TaskRun
    from posefix.tasks.weighing import weigh

    work = env.import_run("drive-fused", seed=54)
    task = env.client("admin").post("/api/v1/tasks", json=task_body([work], assignments_per_run=3)).json()
    n = len(env.keyframes(work))
    rng = np.random.default_rng(54)
    for who, sigma in (("fine", 0.3), ("fair", 0.6), ("rough", 1.2)):
        env.add_user(who, "operator")
        a = _next(env, who)["assignment"]
        moves = [truth_move(env, work, k, *rng.normal(0.0, sigma, 2)) for k in range(0, n, 3)]
        assert env.client(who).post(f"/api/v1/assignments/{a['id']}/submit", json={"moves": moves}).status_code == 200
    env.drain()
    tr = env.client("admin").get(f"/api/v1/tasks/{task['id']}").json()["runs"][0]
    view = env.client("reviewer").get(f"/api/v1/task-runs/{tr['id']}/review").json()
    assert view["method"] == "weighted"
    for s in view["submissions"]:
        r = env.client("reviewer").post(f"/api/v1/assignments/{s['assignment_id']}/review", json={"decision": "approve"})
        assert r.status_code == 200, r.text
    env.drain()
    tr = env.client("admin").get(f"/api/v1/tasks/{task['id']}").json()["runs"][0]
    assert tr["status"] == "merged", tr
    moves = env.client("admin").get(f"/api/v1/runs/{work}/revisions/{tr['merged_revision']}").json()["edit_set"]["moves"]
    assert moves and all(len(m) == 5 and m[4] > 0 for m in moves)
    # what it carries is the fusion's own: 1 / sqrt of the contributors' weights at each keyframe
    with env.db.transaction() as s:
        run = s.get(TaskRun, tr["id"])
        subs = [a for a in repo.run_assignments(s, run.id) if a.status == AssignmentStatus.approved]
        want = edit_sigma_m(weigh(s, run, subs, {a.id for a in subs}), [int(m[0]) for m in moves])
    assert np.allclose([m[4] for m in moves], want, atol=1e-3)
    # three operators fused: surer than the two weaker ones (0.6, 1.2 m) alone, and not merely the floor
    assert 0.2 < float(np.median([m[4] for m in moves])) < 0.45
    detail = env.client("reviewer").get(f"/api/v1/task-runs/{tr['id']}/review").json()["merge_detail"]
    assert detail["edit_sigma_m"] == round(float(np.median([m[4] for m in moves])), 3)
