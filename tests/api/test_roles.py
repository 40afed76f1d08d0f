"""The role matrix: who may do what (403 role_forbidden when the role may not)."""

from __future__ import annotations

import pytest

from tests.conftest import drive_csv, upload

# (method, path template, json body or None, roles allowed). {run} is a run owned by "client".
MATRIX = [
    ("GET", "/api/v1/runs", None, {"admin", "reviewer", "operator", "client"}),
    ("GET", "/api/v1/users", None, {"admin"}),
    ("GET", "/api/v1/users/1/activity", None, {"admin"}),
    ("POST", "/api/v1/users", {"username": "u_{role}", "password": "longenough1", "role": "operator"}, {"admin"}),
    ("POST", "/api/v1/runs/{run}/preview", {"base_revision": 0, "moves": []}, {"admin", "reviewer", "operator"}),
    ("POST", "/api/v1/runs/{run}/edits", {"base_revision": "{head}", "deleted": [1]}, {"admin", "reviewer", "operator"}),
    ("POST", "/api/v1/runs/{run}/review", {"decision": "reject"}, {"admin", "reviewer"}),
    ("POST", "/api/v1/runs/{run}/revert", {"to_revision": 0}, {"admin", "reviewer", "operator"}),
    ("DELETE", "/api/v1/runs/{run}", None, {"admin", "client"}),
    ("GET", "/api/v1/auth/me", None, {"admin", "reviewer", "operator", "client"}),
]
ROLES = ("admin", "reviewer", "operator", "client")


@pytest.mark.parametrize("method, path, body, allowed", MATRIX, ids=[f"{m} {p}" for m, p, _, _ in MATRIX])
def test_role_matrix(client, users, app, method, path, body, allowed):
    app.state.settings.operators_see_all_runs = True
    for role in ROLES:
        rid = upload(client, users["client"], drive_csv(60), name=f"r-{role}").json()["id"]
        head = client.get(f"/api/v1/runs/{rid}", headers=users["admin"]).json()["head_revision"]
        url = path.format(run=rid)
        payload = None
        if body is not None:
            payload = {k: (v.format(role=role) if isinstance(v, str) and "{role}" in v else v) for k, v in body.items()}
            payload = {k: (head if v == "{head}" else v) for k, v in payload.items()}
        r = client.request(method, url, json=payload, headers=users[role])
        if role in allowed:
            assert r.status_code not in (401, 403), (role, r.status_code, r.text)
            assert r.status_code < 500
        else:
            assert r.status_code == 403, (role, r.status_code, r.text)
            assert r.json()["error"] == "role_forbidden"


def test_upload_roles(client, users):
    for role in ROLES:
        r = upload(client, users[role], drive_csv(30))
        assert r.status_code == (201 if role in ("admin", "client") else 403), (role, r.text)


def test_unauthenticated_everywhere(client, users):
    rid = upload(client, users["client"], drive_csv(30)).json()["id"]
    anon = {"Origin": "http://testserver"}
    for method, path, body, _ in MATRIX:
        r = client.request(method, path.format(run=rid), json=body, headers=anon, cookies={})
        assert r.status_code == 401, (method, path, r.status_code)
