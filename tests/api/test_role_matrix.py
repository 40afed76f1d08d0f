"""The role matrix on SQLite and PostgreSQL: every route of the OpenAPI schema, asked by
every principal, answers the outcome class that ``tests/api/access_rules.py`` states.

One seeded app per database serves the whole module. Two tasks over two runs: operator
``op_own`` holds the assignment of task A (the target run, which carries an image), ``op_other``
that of task B, ``op_none`` holds nothing; reviewer ``rev_own`` edited the target run,
``rev_other`` did not. A floor plan with its model, a live tracking session of ``op_own``'s on
it, and a tile source whose upstream is a real loopback XYZ server (allowed through
``POSEFIX_TILE_UPSTREAM_ALLOW``, as a site's own tile server is) are real too, so every cell
exercises the real object and its owner. Tokens are the admin's, so their cells show the scope
alone. Routes that destroy what others use (DELETE, logout, return, cancel) run last, DELETE
ones on a fresh resource per principal.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.api import access_rules
from tests.api.tasks_support import (
    ORIGIN, PASSWORD, Env, _pg_admin_exec, build_env, fresh_pg_url, fresh_sqlite_url, shifted, task_body,
)
from tests.api.test_maps import floor_zip
from tests.api.test_runs import jpeg
from tests.api.test_tiles_upstream import _serve
from tests.conftest import direct_token, drive_csv

PRINCIPALS = access_rules.PRINCIPALS
LAST = {("POST", "/api/v1/auth/logout"), ("POST", "/api/v1/assignments/{assignment_id}/return"),
        ("POST", "/api/v1/tasks/{task_id}/cancel")}


def _routes() -> list[tuple[str, str]]:
    from posefix.main import create_app

    paths = create_app().openapi()["paths"]
    routes = [(m.upper(), p) for p, ops in paths.items() for m in ops]
    return sorted(routes, key=lambda r: (r[0] == "DELETE" or r in LAST, r in LAST))


ROUTES = _routes()


@pytest.fixture(scope="module", params=["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def world(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    tmp = tmp_path_factory.mktemp("rolematrix")
    name = None
    if request.param == "sqlite":
        url = fresh_sqlite_url(tmp / "m.sqlite")
    else:
        url, name = fresh_pg_url()
    upstream = _serve("127.0.0.1")
    with pytest.MonkeyPatch.context() as mp:
        from posefix.maps.sessions import SESSIONS
        from posefix.tiles.service import tile_settings

        mp.setenv("POSEFIX_TILE_UPSTREAM_ALLOW", '["127.0.0.1"]')  # the site's own tile server
        tile_settings.cache_clear()
        env = build_env(tmp, url)
        try:
            yield _seed(env, f"http://127.0.0.1:{upstream.server_address[1]}/{{z}}/{{x}}/{{y}}.png")
        finally:
            env.db.dispose()
            upstream.shutdown()
            upstream.server_close()
            SESSIONS.clear()
            tile_settings.cache_clear()
        from posefix.tasks import clock as task_clock

        task_clock.reset_clock()
        if name:
            _pg_admin_exec(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def _upload_with_image(env: Env) -> int:
    files = [("file", ("a.csv", drive_csv(300, images_every=100), "text/csv")), ("images", ("img00100.jpg", jpeg(), "image/jpeg"))]
    r = env.client("admin").post("/api/v1/runs", files=files, data={"name": "drive-a"})
    assert r.status_code == 201, r.text
    return r.json()["id"]


def _nudge(env: Env, run_id: int, k: int) -> dict[str, Any]:
    """Keyframe k moved 3 m east, as an operator would drag it."""
    lon, lat = env.keyframes(run_id)[k]["geometry"]["coordinates"]
    lon, lat = shifted(lon, lat, 3.0, 0.0)
    return {"index": k, "lon": lon, "lat": lat}


def _floorplan(env: Env, name: str) -> int:
    r = env.client("admin").post("/api/v1/floorplans", data={"name": name},
                                 files={"file": ("floor.zip", floor_zip(), "application/octet-stream")})
    assert r.status_code == 202, r.text
    return r.json()["id"]


def _session(env: Env, floorplan_id: int) -> str:
    r = env.client("op_own").post(f"/api/v1/floorplans/{floorplan_id}/sessions", json={})
    assert r.status_code == 201, r.text
    return r.json()["session_id"]


def _seed(env: Env, upstream_url: str) -> dict[str, Any]:
    for user, role in (("op_own", "operator"), ("op_other", "operator"), ("op_none", "operator"),
                       ("rev_own", "reviewer"), ("rev_other", "reviewer"), ("spare", "operator")):
        env.add_user(user, role)
    run_a, run_b = _upload_with_image(env), env.import_run("drive-b", seed=12)
    admin = env.client("admin")
    task_a = admin.post("/api/v1/tasks", json=task_body([run_a], assignments_per_run=1)).json()["id"]
    asg_a = env.client("op_own").post("/api/v1/tasks/next").json()["assignment"]
    admin.post("/api/v1/tasks", json=task_body([run_b], assignments_per_run=1))
    asg_b = env.client("op_other").post("/api/v1/tasks/next").json()["assignment"]
    assert asg_a["run_id"] == run_a and asg_b["run_id"] == run_b
    move = _nudge(env, run_a, 5)
    edit = env.client("rev_own").post(f"/api/v1/runs/{run_a}/edits", json={"base_revision": 0, "moves": [move]})
    assert edit.status_code == 202, edit.text
    env.drain()
    batch = env.client("admin").get(f"/api/v1/runs/{run_a}/edits").json()
    batch_id = (batch["items"] if isinstance(batch, dict) else batch)[0]["batch_id"] if batch else 1
    r = admin.post("/api/v1/tile-sources", json={"name": "up", "kind": "satellite", "url": upstream_url, "max_zoom": 12})
    assert r.status_code == 201, r.text
    images = admin.get(f"/api/v1/runs/{run_a}/images").json()["items"]
    floorplan_id = _floorplan(env, "site1 F1")
    env.drain()  # the floor plan's model
    assert admin.get(f"/api/v1/floorplans/{floorplan_id}").json()["status"] == "ready"
    ids = {"run_id": run_a, "task_id": task_a, "assignment_id": asg_a["id"], "task_run_id": asg_a.get("task_run_id", 1),
           "batch_id": batch_id, "number": 0, "job_id": edit.json().get("job_id", 1), "user_id": env.users["spare"],
           "image_id": images[0]["id"], "token_id": 1, "ref": "up", "source": "up", "z": 2, "x": 1, "y": 1, "ext": "png",
           "name": "q", "floorplan_id": floorplan_id, "session_id": _session(env, floorplan_id)}
    bodies = {
        "/api/v1/auth/login": {"username": "spare", "password": PASSWORD},
        "/api/v1/tokens": {"name": "t", "scope": "read"},
        "/api/v1/users": {"username": "newbie", "password": "a long enough phrase 42", "role": "operator"},
        "/api/v1/users/{user_id}": {"display_name": "x"},
        "/api/v1/runs/{run_id}/review": {"decision": "reject"},
        "/api/v1/runs/{run_id}/preview": {"base_revision": 1, "moves": [move]},
        "/api/v1/runs/{run_id}/edits": {"base_revision": 1, "moves": [move]},
        "/api/v1/runs/{run_id}/revert": {"to_revision": 1},
        "/api/v1/tile-sources": {"name": "up2", "kind": "satellite", "url": upstream_url, "max_zoom": 12},
        "/api/v1/floorplans/{floorplan_id}/sessions": {},
        "/api/v1/sessions/{session_id}/steps": {"steps": [{"t_ms": 500, "dx_m": 0.7, "dy_m": 0.0}]},
        "/api/v1/tasks": task_body([run_b]),
        "/api/v1/assignments/{assignment_id}/submit": {"moves": [move]},
        "/api/v1/assignments/{assignment_id}/review": {"decision": "approve"},
        "/api/v1/operators/me/home-area": {"lon": 24.9, "lat": 60.2, "radius_m": 1000},
        "/api/v1/operators/{user_id}/home-area": {"lon": 24.9, "lat": 60.2, "radius_m": 1000},
        "/api/v1/operators/{user_id}/qualifications": {"name": "q", "value": 1.0},
    }
    admin_id = env.users["admin"]
    heads = {"read_token": direct_token(env.app, admin_id, "read"), "write_token": direct_token(env.app, admin_id, "write")}
    return {"env": env, "ids": ids, "bodies": bodies, "heads": heads, "run_b": run_b, "upstream_url": upstream_url}


def _fresh(world: dict[str, Any], method: str, path: str) -> dict[str, Any]:
    """A resource of its own for a DELETE, so one principal's success does not turn the next into 404."""
    env, ids = world["env"], dict(world["ids"])
    admin = env.client("admin")
    if path == "/api/v1/runs/{run_id}":
        ids["run_id"] = env.import_run(f"gone-{len(env.sims)}", seed=len(env.sims) + 20)
    elif path == "/api/v1/tokens/{token_id}":
        ids["token_id"] = admin.post("/api/v1/tokens", json={"name": "gone"}).json()["id"]
    elif path == "/api/v1/tile-sources/{ref}":
        ids["ref"] = f"gone{len(env.clients)}{os.urandom(3).hex()}"
        assert admin.post("/api/v1/tile-sources", json={"name": ids["ref"], "kind": "satellite", "url": world["upstream_url"], "max_zoom": 12}).status_code == 201
    elif path == "/api/v1/floorplans/{floorplan_id}":
        ids["floorplan_id"] = _floorplan(env, "gone")
    elif path == "/api/v1/sessions/{session_id}":
        ids["session_id"] = _session(env, ids["floorplan_id"])
    elif path == "/api/v1/operators/{user_id}/qualifications/{name}":
        admin.post(f"/api/v1/operators/{ids['user_id']}/qualifications", json={"name": "q", "value": 1.0})
    return ids


def _client(world: dict[str, Any], who: str, fresh_session: bool) -> tuple[TestClient, dict[str, str]]:
    env = world["env"]
    if who in world["heads"]:
        return TestClient(env.app, headers={"Origin": ORIGIN}), world["heads"][who]
    if who == "anonymous":
        return TestClient(env.app, headers={"Origin": ORIGIN}), {}
    user = {"op_own_task": "op_own", "op_other_task": "op_other", "op_no_task": "op_none",
            "rev_own_work": "rev_own", "rev_other_work": "rev_other", "admin": "admin"}[who]
    if fresh_session:
        c = TestClient(env.app, headers={"Origin": ORIGIN})
        assert c.post("/api/v1/auth/login", json={"username": user, "password": PASSWORD}).status_code == 200
        return c, {}
    return env.client(user), {}


def outcome(status: int) -> str:
    return str(status) if status in (401, 403, 404) else "ok"


def test_every_route_has_a_rule() -> None:
    assert sorted(set(ROUTES) - set(access_rules.RULES)) == [], "routes missing from tests/api/access_rules.py"
    assert sorted(set(access_rules.RULES) - set(ROUTES)) == [], "rules of routes the app no longer has"


def test_security_md_matches_the_rules() -> None:
    doc = (Path(access_rules.__file__).resolve().parents[2] / "docs" / "SECURITY.md").read_text()
    assert access_rules.with_table(doc) == doc, "run: python -m tests.api.access_rules --write"


@pytest.mark.parametrize("method, path", ROUTES, ids=[f"{m} {p}" for m, p in ROUTES])
def test_route_answers_as_the_rules_say(world: dict[str, Any], method: str, path: str) -> None:
    got = []
    for who in PRINCIPALS:
        ids = _fresh(world, method, path) if method == "DELETE" else world["ids"]
        client, headers = _client(world, who, fresh_session=(method, path) in LAST or path == "/api/v1/auth/login")
        body = world["bodies"].get(path) if method in ("POST", "PUT", "PATCH") else None
        if method in ("POST", "PUT", "PATCH") and body is None:
            body = {}
        # event streams close after max_s
        query = {"max_s": 0.1} if path.endswith("/events") else None
        if path.endswith("/diff"):  # a valid query, so hiding is judged before validation could answer 422
            query = {"from": 0, "to": 0}
        r = client.request(method, path.format(**ids), json=body, headers=headers, params=query)
        assert r.status_code < 500, (who, r.text[:300])
        got.append(outcome(r.status_code))
    want = access_rules.RULES.get((method, path))
    assert want is not None, f"{method} {path} is missing from access_rules.RULES; it answers {' '.join(got)}"
    assert dict(zip(PRINCIPALS, got)) == dict(zip(PRINCIPALS, want.split())), f"{method} {path}"
