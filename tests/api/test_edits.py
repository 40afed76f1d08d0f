"""Edits and revisions: preview, batches against a base revision, rules, revisions, diff, revert, status."""

from __future__ import annotations

import csv
import io

import numpy as np
from sqlalchemy import update

from posefix.core import geodesy
from posefix.runs.models import Run
from tests.conftest import drive_csv, upload, wait_job

METRE_LON = 1 / (111320 * np.cos(np.radians(60.17)))  # degrees of longitude per metre at 60.17 N


def new_run(client, users, n=600):
    r = upload(client, users["client"], drive_csv(n))
    assert r.status_code == 201, r.text
    return r.json()["id"]


def kf_coords(client, h, rid, revision=None):
    q = "" if revision is None else f"?revision={revision}"
    fc = client.get(f"/api/v1/runs/{rid}/keyframes{q}", headers=h).json()
    return fc, np.array([f["geometry"]["coordinates"] for f in fc["features"]])


def set_rules(app, rid, **rules):
    base = {"every_n": 1, "lock_n": 0, "lock_direction": "forward", "max_move_m": 10000.0, "order_rule": "flag", "deleted": "remove"}
    with app.state.db.transaction() as s:
        s.execute(update(Run).where(Run.id == rid).values(rules={**base, **rules}))


class TestPreview:
    def test_preview_moves_keyframe(self, client, users):
        rid = new_run(client, users)
        _, xy = kf_coords(client, users["operator"], rid) if False else kf_coords(client, users["admin"], rid)
        target = [xy[30, 0] + 5 * METRE_LON, xy[30, 1]]
        r = client.post(f"/api/v1/runs/{rid}/preview", json={"base_revision": 0, "moves": [{"index": 30, "lon": target[0], "lat": target[1]}]},
                        headers=users["operator"] if False else users["admin"])
        assert r.status_code == 200, r.text
        body = r.json()
        pos = np.array(body["positions"])
        assert pos.shape == (61, 2)
        moved_m = (pos[30, 0] - xy[30, 0]) / METRE_LON
        assert 4.0 < moved_m <= 5.01
        assert body["refusals"] == [] and body["solver"]["status"] == "converged"
        assert body["time_ms"] > 0  # reported; its speed is measured by benchmarks.server, not here

    def test_preview_of_a_revision_is_local_not_a_full_solve(self, client, users, app):
        import time

        from posefix.runs import solutions

        rid = new_run(client, users, n=10000)  # 1,001 keyframes: the window around a drag is under half
        _, xy0 = kf_coords(client, users["admin"], rid)
        # An edited revision: the engine measures an edited run's relative terms on its plausible
        # steps (an unedited run keeps them as reported), so the very first edit of a run changes
        # terms along the whole run and is solved in full; every later drag is local.
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "moves": [
            {"index": 990, "lon": xy0[990, 0] + 2 * METRE_LON, "lat": xy0[990, 1]}]}, headers=users["admin"])
        assert wait_job(app, r.json()["job_id"])["status"] == "succeeded"
        fc, xy = kf_coords(client, users["admin"], rid)  # opening the revision loads its solution in the background
        assert fc["revision"] == 1
        deadline = time.monotonic() + 60
        while solutions.PROBLEMS.solution(rid, fc["rules"], 1) is None:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        for k in (500, 150, 850):  # each the first new edit of the revision: drift would reach the whole run
            target = [xy[k, 0] + 5 * METRE_LON, xy[k, 1]]
            body = client.post(f"/api/v1/runs/{rid}/preview", json={"base_revision": 1, "moves": [{"index": k, "lon": target[0], "lat": target[1]}]},
                               headers=users["admin"]).json()
            info = body["preview"]
            assert info["mode"] == "local" and info["full_solve"] is False and info["base_solved_in_request"] is False, info
            a, b = info["window"]
            assert a <= k <= b and b - a + 1 < 1001 / 2
            assert body["solver"]["method"].endswith("-window")
            pos = np.array(body["positions"])
            assert 3.0 < (pos[k, 0] - xy[k, 0]) / METRE_LON <= 5.01
            far = [i for i in range(1001) if i < a or i > b]
            assert np.abs(pos[far] - xy[far]).max() < 1e-7  # outside the window: the base solution as served

    def test_the_first_drag_of_an_unedited_revision_is_local(self, client, users):
        import time

        from posefix.runs import solutions

        rid = new_run(client, users, n=10000)
        fc, xy = kf_coords(client, users["admin"], rid)  # opening revision 0 warms its solution and drag base
        deadline = time.monotonic() + 60
        while solutions.PROBLEMS.solution(rid, fc["rules"], 0) is None:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        for k in (500, 150):
            target = [xy[k, 0] + 5 * METRE_LON, xy[k, 1]]
            body = client.post(f"/api/v1/runs/{rid}/preview", json={"base_revision": 0, "moves": [{"index": k, "lon": target[0], "lat": target[1]}]},
                               headers=users["admin"]).json()
            info = body["preview"]
            assert info["mode"] == "local" and info["full_solve"] is False, info
            a, b = info["window"]
            assert a <= k <= b and b - a + 1 < 1001 / 2
            pos = np.array(body["positions"])
            assert 3.0 < (pos[k, 0] - xy[k, 0]) / METRE_LON <= 5.01

    def test_a_run_whose_pose_bridged_canyon_offsets_gets_the_level_model_and_local_drags(self, client, users, app, tmp_path):
        import time

        from posefix.core.simulate import simulate
        from posefix.io.csv import write_csv
        from posefix.runs import solutions

        sim = simulate(duration_s=1200.0, rate_hz=2.0, edit_every_s=100.0, seed=11, regime="canyon_ins")
        write_csv(sim.run, tmp_path / "run.csv")
        r = upload(client, users["client"], (tmp_path / "run.csv").read_bytes())
        assert r.status_code == 201, r.text
        rid = r.json()["id"]
        fc, xy = kf_coords(client, users["admin"], rid)
        t_kf = np.array([f["properties"]["t"] for f in fc["features"]])
        moves = [{"index": int(np.argmin(np.abs(t_kf - e.t_s))), "lon": e.lon_deg, "lat": e.lat_deg} for e in sim.edits]
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "moves": moves}, headers=users["admin"])
        assert r.status_code == 202, r.text
        assert wait_job(app, r.json()["job_id"], timeout=120)["status"] == "succeeded"
        fc, xy = kf_coords(client, users["admin"], rid)
        assert fc["revision"] == 1 and fc["drift"]["gnss_levels"] is True, fc["drift"]
        deadline = time.monotonic() + 60
        while solutions.PROBLEMS.solution(rid, fc["rules"], 1) is None:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        k = 300
        body = client.post(f"/api/v1/runs/{rid}/preview", json={"base_revision": 1, "moves": [
            {"index": k, "lon": xy[k, 0] + 4 * METRE_LON, "lat": xy[k, 1]}]}, headers=users["admin"]).json()
        info = body["preview"]
        assert info["mode"] == "local" and info["full_solve"] is False, info
        a, b = info["window"]
        assert a <= k <= b and b - a + 1 < len(xy) / 2
        pos = np.array(body["positions"])
        # the commit re-solves the levels with the new edit: the preview lands where the commit does
        # (short of the 4 m: the edits either side, with the fixes' level between, hold it back)
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 1, "moves": [
            {"index": k, "lon": xy[k, 0] + 4 * METRE_LON, "lat": xy[k, 1]}]}, headers=users["admin"])
        assert wait_job(app, r.json()["job_id"], timeout=120)["status"] == "succeeded"
        _, xy2 = kf_coords(client, users["admin"], rid, revision=2)
        assert 2.0 < (xy2[k, 0] - xy[k, 0]) / METRE_LON <= 4.01
        assert abs(pos[k, 0] - xy2[k, 0]) / METRE_LON < 0.3 and abs(pos[k, 1] - xy2[k, 1]) / METRE_LON < 0.3

    def test_preview_with_deletions_after_the_revision_is_solved(self, client, users):
        import time

        from posefix.runs import solutions

        rid = new_run(client, users)
        fc, xy = kf_coords(client, users["admin"], rid)
        deadline = time.monotonic() + 60
        while solutions.PROBLEMS.solution(rid, fc["rules"], 0) is None:  # the base solution is cached
            assert time.monotonic() < deadline
            time.sleep(0.05)
        # Deleting keyframes drops rows from the solve: the base drift estimate no longer lines up.
        for moves in ([], [{"index": 40, "lon": xy[40, 0] + 4 * METRE_LON, "lat": xy[40, 1]}]):
            r = client.post(f"/api/v1/runs/{rid}/preview",
                            json={"base_revision": 0, "moves": moves, "deleted": [20, 21, 22]}, headers=users["admin"])
            assert r.status_code == 200, r.text
            pos = np.array(r.json()["positions"])
            assert pos.shape == (61, 2) and np.isfinite(pos[[0, 19, 23, 60]]).all()
            if moves:
                assert 3.0 < (pos[40, 0] - xy[40, 0]) / METRE_LON <= 4.01

    def test_preview_lists_refusals_and_leaves_them_out(self, client, users, app):
        rid = new_run(client, users)
        set_rules(app, rid, every_n=2)
        _, xy = kf_coords(client, users["admin"], rid)
        moves = [{"index": 31, "lon": xy[31, 0] + 10 * METRE_LON, "lat": xy[31, 1]}]
        body = client.post(f"/api/v1/runs/{rid}/preview", json={"base_revision": 0, "moves": moves}, headers=users["admin"]).json()
        assert [(x["index"], x["reason"]) for x in body["refusals"]] == [(31, "not_adjustable")]
        assert abs(body["positions"][31][0] - xy[31, 0]) < 1e-6

    def test_stale_base_answers_409_as_submitting_would(self, client, users, app):
        rid = new_run(client, users)
        assert client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": [3]}, headers=users["admin"]).status_code == 202
        _, xy = kf_coords(client, users["admin"], rid, revision=0)
        body = {"base_revision": 0, "moves": [{"index": 30, "lon": xy[30, 0] + 2 * METRE_LON, "lat": xy[30, 1]}]}
        pv = client.post(f"/api/v1/runs/{rid}/preview", json=body, headers=users["reviewer"])
        ed = client.post(f"/api/v1/runs/{rid}/edits", json=body, headers=users["reviewer"])
        assert pv.status_code == ed.status_code == 409
        assert pv.json()["error"] == ed.json()["error"] == "stale_revision"
        assert pv.json()["current_revision"] == ed.json()["current_revision"] == 1

    def test_preview_needs_editor_role(self, client, users):
        rid = new_run(client, users)
        r = client.post(f"/api/v1/runs/{rid}/preview", json={"base_revision": 0, "moves": []}, headers=users["client"])
        assert r.status_code == 403 and r.json()["error"] == "role_forbidden"


class TestSubmit:
    def test_submit_writes_next_revision(self, client, users, app):
        rid = new_run(client, users)
        _, xy = kf_coords(client, users["admin"], rid)
        move = {"index": 20, "lon": xy[20, 0] + 8 * METRE_LON, "lat": xy[20, 1]}
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "moves": [move], "comment": "kerb"}, headers=users["admin"])
        assert r.status_code == 202, r.text
        acc = r.json()
        assert acc["revision"] == 1
        run = client.get(f"/api/v1/runs/{rid}", headers=users["admin"]).json()
        assert run["head_revision"] == 1 and run["revision"] == 0 and run["status"] == "in_review"
        pending = client.get(f"/api/v1/runs/{rid}/keyframes?revision=1", headers=users["admin"])
        assert pending.status_code == 409 and pending.json()["error"] == "revision_pending"
        job = wait_job(app, acc["job_id"])
        assert job["status"] == "succeeded" and job["result"]["revision"] == 1
        fc, xy1 = kf_coords(client, users["admin"], rid)
        assert fc["revision"] == 1
        p = fc["features"][20]["properties"]
        assert p["edited"] and 6 < p["correction_m"] < 8.5
        assert fc["solver"]["status"] == "converged"
        assert client.get(f"/api/v1/runs/{rid}", headers=users["admin"]).json()["adjusted"] is True
        # the full-rate export follows the edit
        rows = list(csv.DictReader(io.StringIO(client.get(f"/api/v1/runs/{rid}/export?format=csv", headers=users["admin"]).text)))
        assert len(rows) == 600
        assert abs(float(rows[200]["lon"]) - xy1[20, 0]) < 1e-7

    def test_revision_carries_the_predicted_one_sigma_per_keyframe(self, client, users, app):
        rid = new_run(client, users)
        _, xy = kf_coords(client, users["admin"], rid)
        moves = [{"index": i, "lon": xy[i, 0] + (3 + i % 7) * METRE_LON, "lat": xy[i, 1]} for i in (5, 20, 35, 50)]
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "moves": moves}, headers=users["admin"])
        assert r.status_code == 202, r.text
        assert wait_job(app, r.json()["job_id"])["status"] == "succeeded"
        fc, _ = kf_coords(client, users["admin"], rid)
        sigma = [f["properties"]["sigma_m"] for f in fc["features"]]
        assert all(isinstance(v, float) and v > 0 for v in sigma)
        cal = fc["drift"]["calibration"]
        assert cal["predicted_rmse_m"] > 0 and cal["model"] in ("gnss", "plain", "relative", "naive")
        # revision 0 (no edits) predicts nothing
        r0, _ = kf_coords(client, users["admin"], rid, revision=0)
        assert all(f["properties"]["sigma_m"] is None for f in r0["features"])

    def test_if_match_header(self, client, users, app):
        rid = new_run(client, users)
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"deleted": [5]}, headers={**users["admin"], "If-Match": '"0"'})
        assert r.status_code == 202
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"deleted": [6], "base_revision": 0}, headers={**users["admin"], "If-Match": '"1"'})
        assert r.status_code == 400 and r.json()["error"] == "base_mismatch"
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"deleted": [6]}, headers=users["admin"])
        assert r.status_code == 400 and r.json()["error"] == "base_revision_required"
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"deleted": [6]}, headers={**users["admin"], "If-Match": "abc"})
        assert r.status_code == 400

    def test_stale_base_409_with_current_revision(self, client, users, app):
        rid = new_run(client, users)
        assert client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": [3]}, headers=users["admin"]).status_code == 202
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": [4]}, headers=users["operator"] if False else users["reviewer"])
        assert r.status_code == 409
        assert r.json()["error"] == "stale_revision" and r.json()["current_revision"] == 1
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 7, "deleted": [4]}, headers=users["admin"])
        assert r.status_code == 409

    def test_rules_refuse_with_reason_per_edit(self, client, users, app):
        rid = new_run(client, users)
        set_rules(app, rid, every_n=2, max_move_m=20.0)
        _, xy = kf_coords(client, users["admin"], rid)
        moves = [
            {"index": 3, "lon": xy[3, 0] + 2 * METRE_LON, "lat": xy[3, 1]},
            {"index": 10, "lon": xy[10, 0] + 50 * METRE_LON, "lat": xy[10, 1]},
            {"index": 99, "lon": 24.9, "lat": 60.1},
            {"index": 12, "lon": xy[12, 0] + 2 * METRE_LON, "lat": xy[12, 1]},
        ]
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "moves": moves}, headers=users["admin"])
        assert r.status_code == 422
        body = r.json()
        assert body["error"] == "edit_refused"
        reasons = {x["index"]: x["reason"] for x in body["refusals"]}
        assert reasons == {3: "not_adjustable", 10: "too_far", 99: "out_of_range"}
        assert all(x["message"] for x in body["refusals"])
        run = client.get(f"/api/v1/runs/{rid}", headers=users["admin"]).json()
        assert run["head_revision"] == 0 and client.get(f"/api/v1/runs/{rid}/edits", headers=users["admin"]).json() == []

    def test_lock_after_earlier_edit(self, client, users, app):
        rid = new_run(client, users)
        set_rules(app, rid, lock_n=3, lock_direction="forward")
        _, xy = kf_coords(client, users["admin"], rid)
        m = {"index": 10, "lon": xy[10, 0] + 2 * METRE_LON, "lat": xy[10, 1]}
        assert client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "moves": [m]}, headers=users["admin"]).status_code == 202
        fc = client.get(f"/api/v1/runs/{rid}/keyframes", headers=users["admin"]).json()
        m2 = {"index": 12, "lon": xy[12, 0] + 2 * METRE_LON, "lat": xy[12, 1]}
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 1, "moves": [m2]}, headers=users["admin"])
        assert r.status_code == 422 and r.json()["refusals"][0]["reason"] == "locked"
        assert fc["head_revision"] == 1

    def test_dragging_past_an_unmoved_neighbour_reverses_the_order(self, client, users, app):
        rid = new_run(client, users)
        set_rules(app, rid, order_rule="refuse")
        _, xy = kf_coords(client, users["admin"], rid)
        past = xy[21] + 0.5 * (xy[21] - xy[20])  # half a step beyond keyframe 21, which stays put
        body = {"base_revision": 0, "moves": [{"index": 20, "lon": past[0], "lat": past[1]}]}
        r = client.post(f"/api/v1/runs/{rid}/edits", json=body, headers=users["admin"])
        assert r.status_code == 422, r.text
        assert [(x["index"], x["reason"]) for x in r.json()["refusals"]] == [(20, "order_reversed")]
        pv = client.post(f"/api/v1/runs/{rid}/preview", json=body, headers=users["admin"]).json()
        assert [(x["index"], x["reason"]) for x in pv["refusals"]] == [(20, "order_reversed")]
        set_rules(app, rid, order_rule="flag")
        r = client.post(f"/api/v1/runs/{rid}/edits", json=body, headers=users["admin"])
        assert r.status_code == 202 and [f["reason"] for f in r.json()["flags"]] == ["order_reversed"], r.text

    def test_empty_batch(self, client, users):
        rid = new_run(client, users)
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0}, headers=users["admin"])
        assert r.status_code == 422 and r.json()["error"] == "empty_batch"

    def test_edits_appended_with_author(self, client, users, app):
        rid = new_run(client, users)
        _, xy = kf_coords(client, users["admin"], rid)
        for base, dx, who in ((0, 3, "admin"), (1, 6, "reviewer")):
            m = {"index": 15, "lon": xy[15, 0] + dx * METRE_LON, "lat": xy[15, 1]}
            r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": base, "moves": [m]}, headers=users[who])
            assert r.status_code == 202, r.text
        edits = client.get(f"/api/v1/runs/{rid}/edits", headers=users["admin"]).json()
        assert [e["k"] for e in edits] == [15, 15]
        assert edits[0]["author_id"] != edits[1]["author_id"] and {e["task_id"] for e in edits} == {None}
        assert edits[0]["lon"] != edits[1]["lon"]
        last = wait_job(app, 2)
        assert last["status"] == "succeeded"
        wait_job(app, 1)
        rev2 = client.get(f"/api/v1/runs/{rid}/revisions/2", headers=users["admin"]).json()
        assert rev2["edit_set"]["moves"] == [[15, edits[1]["lon"], edits[1]["lat"], None]]

    def test_delete_keyframes_drops_samples(self, client, users, app):
        rid = new_run(client, users)
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": [5, 6]}, headers=users["admin"])
        wait_job(app, r.json()["job_id"])
        fc = client.get(f"/api/v1/runs/{rid}/keyframes", headers=users["admin"]).json()
        assert [f["properties"]["index"] for f in fc["features"] if f["properties"]["deleted"]] == [5, 6]
        rows = list(csv.DictReader(io.StringIO(client.get(f"/api/v1/runs/{rid}/export", headers=users["admin"]).text)))
        assert len(rows) == 580


class TestRevisions:
    def _two_revisions(self, client, users, app):
        rid = new_run(client, users)
        _, xy = kf_coords(client, users["admin"], rid)
        m = {"index": 25, "lon": xy[25, 0] + 6 * METRE_LON, "lat": xy[25, 1]}
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "moves": [m]}, headers=users["admin"])
        wait_job(app, r.json()["job_id"])
        return rid, xy

    def test_list_detail_diff(self, client, users, app):
        rid, _ = self._two_revisions(client, users, app)
        revs = client.get(f"/api/v1/runs/{rid}/revisions", headers=users["client"]).json()
        assert [x["number"] for x in revs["items"]] == [0, 1] and revs["head_revision"] == 1
        assert revs["items"][0]["kind"] == "import" and revs["items"][1]["n_moves"] == 1
        detail = client.get(f"/api/v1/runs/{rid}/revisions/1", headers=users["client"]).json()
        assert detail["edit_set"]["moves"][0][0] == 25 and detail["solver"]["status"] == "converged"
        d = client.get(f"/api/v1/runs/{rid}/diff?from=0&to=1", headers=users["client"]).json()
        assert len(d["displacement_m"]) == 61
        assert 5.0 < d["displacement_m"][25] <= 6.1 and abs(d["max_m"] - max(d["displacement_m"])) < 1e-3
        assert any(k["index"] == 25 for k in d["keyframes"])
        assert client.get(f"/api/v1/runs/{rid}/diff?from=0&to=9", headers=users["client"]).status_code == 404
        assert client.get(f"/api/v1/runs/{rid}/revisions/9", headers=users["client"]).status_code == 404

    def test_revert_makes_new_revision(self, client, users, app):
        rid, xy = self._two_revisions(client, users, app)
        r = client.post(f"/api/v1/runs/{rid}/revert", json={"to_revision": 0, "comment": "undo"}, headers=users["reviewer"])
        assert r.status_code == 202 and r.json()["revision"] == 2
        wait_job(app, r.json()["job_id"])
        fc, xy2 = kf_coords(client, users["admin"], rid)
        assert fc["revision"] == 2
        assert np.abs(xy2 - xy).max() < 1e-7
        revs = client.get(f"/api/v1/runs/{rid}/revisions", headers=users["admin"]).json()["items"]
        assert [x["kind"] for x in revs] == ["import", "edit", "revert"]
        r = client.post(f"/api/v1/runs/{rid}/revert", json={"to_revision": 1, "base_revision": 1}, headers=users["reviewer"])
        assert r.status_code == 409 and r.json()["current_revision"] == 2


class TestStatus:
    def test_operator_accept_then_review(self, client, users, app):
        app.state.settings.operators_see_all_runs = True
        rid = new_run(client, users)
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": [2], "accept": True}, headers=users["operator"])
        assert r.status_code == 202, r.text
        assert client.get(f"/api/v1/runs/{rid}", headers=users["admin"]).json()["status"] == "corrected"
        early = client.post(f"/api/v1/runs/{rid}/review", json={"decision": "accept"}, headers=users["reviewer"])
        assert early.status_code == 409 and early.json()["error"] == "revision_pending"
        wait_job(app, r.json()["job_id"])
        assert client.post(f"/api/v1/runs/{rid}/review", json={"decision": "accept"}, headers=users["operator"]).status_code == 403
        rej = client.post(f"/api/v1/runs/{rid}/review", json={"decision": "reject", "comment": "wrong street"}, headers=users["reviewer"])
        assert rej.status_code == 200 and rej.json()["status"] == "in_review"
        acc = client.post(f"/api/v1/runs/{rid}/review", json={"decision": "accept"}, headers=users["reviewer"]).json()
        assert acc["status"] == "accepted" and acc["verified"] is True
        hist = client.get(f"/api/v1/runs/{rid}/history", headers=users["admin"]).json()["items"]
        assert [h["action"] for h in hist] == ["imported", "edited", "revision_ready", "rejected", "accepted"]
        assert [h["to_status"] for h in hist] == ["imported", "corrected", None, "in_review", "accepted"]
        assert hist[3]["comment"] == "wrong street"

    def test_reviewer_accept_in_batch(self, client, users, app):
        rid = new_run(client, users)
        client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "accept": True}, headers=users["reviewer"])
        run = client.get(f"/api/v1/runs/{rid}", headers=users["admin"]).json()
        assert run["status"] == "accepted" and run["verified"] is True and run["adjusted"] is False


class TestPreviewCache:
    def test_keyframes_request_presolves_head_revision_for_editors(self, client, users):
        import time

        from posefix.runs import solutions

        rid = new_run(client, users)
        run = client.get(f"/api/v1/runs/{rid}", headers=users["client"]).json()
        client.get(f"/api/v1/runs/{rid}/keyframes", headers=users["client"])
        time.sleep(0.3)
        assert solutions.PROBLEMS.solution(rid, run["rules"], 0) is None  # a client does not edit
        client.get(f"/api/v1/runs/{rid}/keyframes", headers=users["admin"])
        deadline = time.monotonic() + 30
        while solutions.PROBLEMS.solution(rid, run["rules"], 0) is None:
            assert time.monotonic() < deadline
            time.sleep(0.05)

    def test_drag_frames_agree_with_a_cold_solve(self, client, users, app):
        from posefix.runs import solutions

        rid = new_run(client, users)
        _, xy = kf_coords(client, users["admin"], rid)
        frames = []
        for i in range(4):
            m = {"index": 30, "lon": xy[30, 0] + (2 + i) * METRE_LON, "lat": xy[30, 1]}
            frames.append(client.post(f"/api/v1/runs/{rid}/preview", json={"base_revision": 0, "moves": [m]}, headers=users["admin"]).json())
        solutions.PROBLEMS.forget_all()
        cold = client.post(f"/api/v1/runs/{rid}/preview", json={"base_revision": 0, "moves": [m]}, headers=users["admin"]).json()
        a, b = np.array(frames[-1]["positions"]), np.array(cold["positions"])
        diff_m = geodesy.horizontal_distance_m(a[:, 0], a[:, 1], b[:, 0], b[:, 1]).max()
        assert diff_m < 0.05


class TestStoredSolution:
    """Each revision's solution is stored beside its files, so another API process (here: the
    in-memory caches emptied) loads it instead of solving the revision again."""

    def preview(self, client, users, rid, base, xy, k=30):
        body = {"base_revision": base, "moves": [{"index": k, "lon": xy[k, 0] + 3 * METRE_LON, "lat": xy[k, 1]}]}
        r = client.post(f"/api/v1/runs/{rid}/preview", json=body, headers=users["admin"])
        assert r.status_code == 200, r.text
        return r.json()

    def test_revision_solution_written_by_worker_and_loaded_by_a_fresh_process(self, client, users, app, settings):
        from posefix.runs import solutions, storage
        from posefix.runs.models import Revision

        rid = new_run(client, users)
        _, xy = kf_coords(client, users["admin"], rid)
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "moves": [
            {"index": 20, "lon": xy[20, 0] + 4 * METRE_LON, "lat": xy[20, 1]}]}, headers=users["admin"])
        assert wait_job(app, r.json()["job_id"])["status"] == "succeeded"
        with app.state.db.transaction(write=False) as s:
            rev = s.query(Revision).filter_by(run_id=rid, number=1).one()
            kf_file = rev.keyframes_file
        assert (settings.files_dir / storage.solution_rel(kf_file)).is_file()
        _, xy1 = kf_coords(client, users["admin"], rid, revision=1)
        warm = self.preview(client, users, rid, 1, xy1)
        solutions.PROBLEMS.forget_all()  # as in another API process
        fresh = self.preview(client, users, rid, 1, xy1)
        assert fresh["preview"]["base_solved_in_request"] is False
        assert np.abs(np.array(fresh["positions"]) - np.array(warm["positions"])).max() < 1e-7

    def test_first_solve_of_a_revision_is_stored_for_the_others(self, client, users, settings):
        from posefix.runs import solutions

        rid = new_run(client, users)
        _, xy = kf_coords(client, users["client"], rid)  # a client's view does not pre-solve
        first = self.preview(client, users, rid, 0, xy)
        assert first["preview"]["base_solved_in_request"] is True
        assert len(list((settings.files_dir / "runs" / str(rid)).glob("r0-*.solution.npz"))) == 1
        solutions.PROBLEMS.forget_all()
        again = self.preview(client, users, rid, 0, xy)
        assert again["preview"]["base_solved_in_request"] is False
        assert np.abs(np.array(again["positions"]) - np.array(first["positions"])).max() < 1e-7

    def test_solution_of_another_configuration_is_not_used(self, tmp_path):
        from posefix.engine import CorrectionConfig, Edits, prepare
        from posefix.io import read_run
        from posefix.runs import solutions, storage

        path = tmp_path / "drive.csv"
        path.write_bytes(drive_csv(300))
        problem = prepare(read_run(path), CorrectionConfig())
        sol = problem.solve_edits(Edits())
        fs = storage.FileStore(tmp_path / "files")
        storage.write_solution(fs, "runs/1/r0-x.solution.npz", sol, "config-a")
        back = storage.read_solution(fs, "runs/1/r0-x.solution.npz", "config-a")
        assert np.array_equal(back.x, sol.x) and np.array_equal(back.keyframes.p_enu_m, sol.keyframes.p_enu_m)
        assert back.terms is not None and np.array_equal(back.terms.rel_delta_m, sol.terms.rel_delta_m)
        assert storage.read_solution(fs, "runs/1/r0-x.solution.npz", "config-b") is None
        assert storage.read_solution(fs, "runs/1/none.solution.npz", "config-a") is None
        fs.put_bytes(b"not an npz", "runs/1/r0-y.solution.npz")
        assert storage.read_solution(fs, "runs/1/r0-y.solution.npz", "config-a") is None


class TestPreviewWritesNothing:
    def test_preview_answers_while_another_transaction_holds_the_write_lock(self, client, users, app):
        """A preview reads only: on SQLite it used to take the database's write lock (a POST's
        session), so it waited behind every writer, up to the 30 s busy timeout."""
        import threading
        import time

        from sqlalchemy import text

        rid = new_run(client, users)
        _, xy = kf_coords(client, users["admin"], rid)
        body = {"base_revision": 0, "moves": [{"index": 30, "lon": xy[30, 0] + 3 * METRE_LON, "lat": xy[30, 1]}]}
        assert client.post(f"/api/v1/runs/{rid}/preview", json=body, headers=users["admin"]).status_code == 200
        held, release = threading.Event(), threading.Event()

        def hold_write_lock():
            # SQLite: BEGIN IMMEDIATE (the database's one write lock); PostgreSQL: every table a
            # preview reads, locked against any writer
            with app.state.db.engine.connect().execution_options(sqlite_begin="IMMEDIATE") as conn:
                with conn.begin():
                    if not app.state.db.is_sqlite:
                        conn.execute(text("LOCK TABLE runs, revisions, keyframes, users, auth_sessions, api_tokens "
                                          "IN SHARE ROW EXCLUSIVE MODE"))
                    held.set()
                    release.wait(20)

        holder = threading.Thread(target=hold_write_lock)
        holder.start()
        try:
            assert held.wait(10)
            started = time.monotonic()
            r = client.post(f"/api/v1/runs/{rid}/preview", json=body, headers=users["admin"])
            elapsed = time.monotonic() - started
        finally:
            release.set()
            holder.join(30)
        assert r.status_code == 200, r.text
        assert elapsed < 5.0, f"the preview waited {elapsed:.1f} s for the write lock"
