"""The run's revision list tells who, why and what the review said; an admin's audit view
lists one person's edits and reviews (and nobody else may read it)."""

from __future__ import annotations

from tests.api.test_edits import new_run
from tests.conftest import wait_job


def _edit(client, users, app, rid, base, comment, role="operator"):
    r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": base, "deleted": [base + 3], "accept": True, "comment": comment},
                    headers=users[role])
    assert r.status_code == 202, r.text
    wait_job(app, r.json()["job_id"])


class TestRevisionNotes:
    def test_revisions_name_author_comment_and_review(self, client, users, app):
        app.state.settings.operators_see_all_runs = True
        rid = new_run(client, users)
        _edit(client, users, app, rid, 0, "moved onto the lane")
        rej = client.post(f"/api/v1/runs/{rid}/review", json={"decision": "reject", "comment": "wrong street"}, headers=users["reviewer"])
        assert rej.status_code == 200, rej.text
        items = client.get(f"/api/v1/runs/{rid}/revisions", headers=users["operator"]).json()["items"]
        assert [x["number"] for x in items] == [0, 1]
        first, edit = items
        assert first["comment"] is None and first["review"] is None
        assert edit["author"] == "operator" and edit["comment"] == "moved onto the lane" and edit["task_id"] is None
        assert edit["review"] == "rejected" and edit["review_comment"] == "wrong street" and edit["reviewer"] == "reviewer"


class TestUserActivity:
    def test_admin_sees_one_persons_edits_and_reviews(self, client, users, app):
        app.state.settings.operators_see_all_runs = True
        rid = new_run(client, users)
        _edit(client, users, app, rid, 0, "first pass")
        client.post(f"/api/v1/runs/{rid}/review", json={"decision": "accept", "comment": "fine"}, headers=users["reviewer"])
        people = {u["username"]: u["id"] for u in client.get("/api/v1/users", headers=users["admin"]).json()["items"]}
        op = client.get(f"/api/v1/users/{people['operator']}/activity", headers=users["admin"])
        assert op.status_code == 200, op.text
        body = op.json()
        assert body["username"] == "operator" and body["reviews"] == []
        assert [(e["run_id"], e["revision"], e["comment"], e["n_deleted"]) for e in body["edits"]] == [(rid, 1, "first pass", 1)]
        rv = client.get(f"/api/v1/users/{people['reviewer']}/activity", headers=users["admin"]).json()
        assert rv["edits"] == []
        assert [(r["target"], r["run_id"], r["decision"], r["comment"], r["revision"]) for r in rv["reviews"]] == [("run", rid, "accepted", "fine", 1)]

    def test_only_admins_read_it(self, client, users):
        people = {u["username"]: u["id"] for u in client.get("/api/v1/users", headers=users["admin"]).json()["items"]}
        for role in ("operator", "reviewer", "client"):
            assert client.get(f"/api/v1/users/{people['operator']}/activity", headers=users[role]).status_code == 403
        assert client.get("/api/v1/users/999999/activity", headers=users["admin"]).status_code == 404
