"""No edit leaves a run stuck (issue 11, section 3), on SQLite and PostgreSQL: deletions that
would leave fewer than two keyframes are refused (edits, previews), the default rules bound
a move, and what they accept keeps the altitudes where the input had them."""

from __future__ import annotations

import csv
import io

import numpy as np

from tests.conftest import drive_csv, upload, wait_job

METRE_LON = 1 / (111320 * np.cos(np.radians(60.17)))  # degrees of longitude per metre at 60.17 N


def _run(client, users, n: int) -> tuple[int, list[dict]]:
    r = upload(client, users["client"], drive_csv(n))
    assert r.status_code == 201, r.text
    rid = r.json()["id"]
    return rid, client.get(f"/api/v1/runs/{rid}/keyframes", headers=users["admin"]).json()["features"]


def _head(client, users, rid: int) -> int:
    return client.get(f"/api/v1/runs/{rid}", headers=users["admin"]).json()["head_revision"]


def _refused(r, reason: str) -> list[dict]:
    assert r.status_code == 422 and r.json()["error"] == "edit_refused", r.text
    refusals = r.json()["refusals"]
    assert refusals and all(x["reason"] == reason for x in refusals), refusals
    return refusals


def test_deleting_down_to_one_keyframe_is_refused(client, users):
    rid, feats = _run(client, users, 60)
    k = len(feats)
    admin = users["admin"]
    for deleted in (list(range(k)), list(range(1, k))):
        for route in ("edits", "preview"):
            r = client.post(f"/api/v1/runs/{rid}/{route}", json={"base_revision": 0, "deleted": deleted}, headers=admin)
            refusals = _refused(r, "too_few_keyframes")
            assert {x["index"] for x in refusals} == set(deleted)
            assert "at least 2" in refusals[0]["message"]
    assert _head(client, users, rid) == 0
    # earlier deletions count: two batches that each leave enough, the second leaves one
    r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": list(range(2, k))}, headers=admin)
    assert r.status_code == 202, r.text
    r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 1, "deleted": [0]}, headers=admin)
    _refused(r, "too_few_keyframes")
    assert _head(client, users, rid) == 1


def test_preview_deleting_the_only_keyframe_is_a_422(client, users):
    rid, feats = _run(client, users, 1)
    assert len(feats) == 1
    r = client.post(f"/api/v1/runs/{rid}/preview", json={"base_revision": 0, "deleted": [0]}, headers=users["admin"])
    _refused(r, "too_few_keyframes")
    ok = client.post(f"/api/v1/runs/{rid}/preview", json={"base_revision": 0, "moves": []}, headers=users["admin"])
    assert ok.status_code == 200, ok.text


def test_default_rules_bound_a_move_and_altitudes_stay_put(client, users, app):
    rid, feats = _run(client, users, 120)
    lon, lat = feats[6]["geometry"]["coordinates"]
    accepted = []
    for east_m in (10.0 / METRE_LON, 5000.0, 900.0):  # 10 degrees of longitude (553 km), 5 km, 900 m
        move = {"index": 6, "lon": lon + east_m * METRE_LON, "lat": lat}
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": _head(client, users, rid), "moves": [move]},
                        headers=users["admin"])
        if east_m > 1000.0:
            assert "1000" in _refused(r, "too_far")[0]["message"]
            continue
        assert r.status_code == 202, r.text
        accepted.append(r.json())
    assert len(accepted) == 1
    assert wait_job(app, accepted[0]["job_id"])["status"] == "succeeded"
    text = client.get(f"/api/v1/runs/{rid}/export?format=csv&revision={accepted[0]['revision']}", headers=users["admin"]).text
    alt = np.array([float(row["alt"]) for row in csv.DictReader(io.StringIO(text))])
    # the input is flat at 12.5 m and the move horizontal: no height change (a height read off
    # the solver's tangent plane would be d^2/(2R) = 0.06 m higher at 900 m)
    assert np.abs(alt - 12.5).max() < 0.01, np.abs(alt - 12.5).max()


def _samples_path(app, rid: int):
    from posefix.runs import repository as runs_repo
    from posefix.runs.storage import FileStore

    with app.state.db.transaction(write=False) as s:
        rel = runs_repo.revision(s, rid, 0).samples_file
    return FileStore(app.state.settings.files_dir).path(rel)


def _edit_that_dies(client, users, app, rid: int, base: int, move: dict) -> dict:
    """Submit an edit whose revision job cannot read the run's samples (a storage outage)."""
    from posefix.runs import solutions

    r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": base, "moves": [move]}, headers=users["admin"])
    assert r.status_code == 202, r.text
    path = _samples_path(app, rid)
    path.rename(path.with_name(path.name + ".away"))
    solutions.PROBLEMS.forget_all()  # the worker must read the file
    job = wait_job(app, r.json()["job_id"])
    assert job["status"] == "dead" and job["attempts"] == app.state.settings.job_max_attempts
    path.with_name(path.name + ".away").rename(path)
    return r.json()


def test_a_dead_revision_job_rolls_the_run_back_then_retry_or_discard(client, users, app):
    rid, feats = _run(client, users, 120)
    lon, lat = feats[6]["geometry"]["coordinates"]
    move = {"index": 6, "lon": lon + 5 * METRE_LON, "lat": lat}
    admin, reviewer = users["admin"], users["reviewer"]
    died = _edit_that_dies(client, users, app, rid, 0, move)
    run = client.get(f"/api/v1/runs/{rid}", headers=admin).json()
    assert (run["revision"], run["head_revision"], run["status"]) == (0, 0, "imported")
    failed = run["failed_edit"]
    assert failed["batch_id"] == died["batch_id"] and failed["revision"] == 1 and failed["status"] == "failed"
    assert "FileNotFoundError" in failed["error"]
    revs = client.get(f"/api/v1/runs/{rid}/revisions", headers=admin).json()
    assert [x["number"] for x in revs["items"]] == [0] and [f["batch_id"] for f in revs["failed"]] == [died["batch_id"]]
    r1 = client.get(f"/api/v1/runs/{rid}/revisions/1", headers=admin)
    assert r1.status_code == 409 and r1.json()["error"] == "revision_failed" and "FileNotFoundError" in r1.json()["detail"]
    hist = client.get(f"/api/v1/runs/{rid}/history", headers=admin).json()["items"]
    assert [h["action"] for h in hist][-2:] == ["edited", "revision_failed"] and hist[-1]["to_status"] == "imported"
    # reviews work again (a stuck run answered 409 "still being computed" to every review)
    r = client.post(f"/api/v1/runs/{rid}/review", json={"decision": "reject"}, headers=reviewer)
    assert r.status_code == 409 and r.json()["error"] == "invalid_transition", r.text
    # the author retries once storage is back
    r = client.post(f"/api/v1/runs/{rid}/batches/{died['batch_id']}/retry", headers=admin)
    assert r.status_code == 202 and r.json()["revision"] == 1, r.text
    assert wait_job(app, r.json()["job_id"])["status"] == "succeeded"
    run = client.get(f"/api/v1/runs/{rid}", headers=admin).json()
    assert (run["revision"], run["head_revision"], run["failed_edit"]) == (1, 1, None)
    again = client.post(f"/api/v1/runs/{rid}/batches/{died['batch_id']}/retry", headers=admin)
    assert again.status_code == 409 and again.json()["error"] == "not_failed"

    # a second failure: the number is free for the next edit, and the failure can be discarded
    died2 = _edit_that_dies(client, users, app, rid, 1, {**move, "lon": lon + 8 * METRE_LON})
    assert client.get(f"/api/v1/runs/{rid}", headers=admin).json()["head_revision"] == 1
    d = client.post(f"/api/v1/runs/{rid}/batches/{died2['batch_id']}/discard", headers=reviewer)
    assert d.status_code == 200 and d.json()["status"] == "discarded", d.text
    assert client.get(f"/api/v1/runs/{rid}", headers=admin).json()["failed_edit"] is None
    r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 1, "moves": [move]}, headers=admin)
    assert r.status_code == 202 and r.json()["revision"] == 2, r.text
    assert wait_job(app, r.json()["job_id"])["status"] == "succeeded"
    assert client.get(f"/api/v1/runs/{rid}/revisions/2", headers=admin).json()["batch_id"] == r.json()["batch_id"]


def test_a_move_far_across_the_solver_plane_keeps_the_altitudes(client, users, app):
    """Rules stored before settings were bounded (max_move_m far beyond 10 km): a 553 km drag
    (where the solver's tangent plane is 24 km above the ellipsoid) previews and exports at
    the input's height; the altitude guard has nothing to refuse."""
    from tests.api.test_edits import set_rules

    rid, feats = _run(client, users, 120)
    set_rules(app, rid, max_move_m=1e9)
    lon, lat = feats[6]["geometry"]["coordinates"]
    move = {"index": 6, "lon": lon + 10.0, "lat": lat}  # 10 degrees of longitude: 553 km
    r = client.post(f"/api/v1/runs/{rid}/preview", json={"base_revision": 0, "moves": [move]}, headers=users["admin"])
    assert r.status_code == 200 and not r.json()["refusals"], r.text
    lon6, lat6 = r.json()["positions"][6]
    assert abs(lon6 - move["lon"]) < 1e-6 and abs(lat6 - lat) < 1e-6, (lon6, lat6)
    r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "moves": [move]}, headers=users["admin"])
    assert r.status_code == 202, r.text
    assert wait_job(app, r.json()["job_id"])["status"] == "succeeded"
    text = client.get(f"/api/v1/runs/{rid}/export?format=csv&revision={r.json()['revision']}", headers=users["admin"]).text
    rows = list(csv.DictReader(io.StringIO(text)))
    alt = np.array([float(row["alt"]) for row in rows])
    assert np.abs(alt - 12.5).max() < 0.01, np.abs(alt - 12.5).max()
    assert max(float(row["lon"]) for row in rows) > lon + 9.0  # the move took


def test_max_move_is_a_finite_setting(client, users, tmp_path):
    """A task's rules and the engine's config file take 1 m to 10 km; there is no 'unlimited'."""
    from posefix.core.config import ConfigError, CorrectionConfig

    rid, _ = _run(client, users, 30)
    body = {"title": "t", "run_ids": [rid]}
    for bad in (0.0, 0.5, 10_001.0):
        r = client.post("/api/v1/tasks", json={**body, "rules": {"max_move_m": bad}}, headers=users["admin"])
        assert r.status_code == 422 and "max_move_m" in r.text, (bad, r.text)
        path = tmp_path / "engine.toml"
        path.write_text(f"[rules]\nmax_move_m = {bad}\n")
        try:
            CorrectionConfig.load(path)
        except ConfigError as exc:
            assert "rules.max_move_m" in str(exc) and "between 1 and 10000" in str(exc)
        else:
            raise AssertionError(f"max_move_m = {bad} was accepted")
    r = client.post("/api/v1/tasks", json={**body, "rules": {"max_move_m": 10_000.0}}, headers=users["admin"])
    assert r.status_code == 201, r.text
