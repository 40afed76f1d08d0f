"""Accounts: login, sessions (timeouts, logout, disabling), CSRF, tokens, throttling, CLI."""

from __future__ import annotations

import datetime as dt
import os
import subprocess
import sys
from pathlib import Path

from fastapi.testclient import TestClient
from sqlalchemy import select, update

from posefix.users.models import ApiToken, AuthSession, User
from tests.conftest import ORIGIN, PASSWORD, add_user, login

POSEFIX = str(Path(sys.executable).parent / "posefix")


class TestLogin:
    def test_login_sets_httponly_lax_cookie(self, app, client):
        add_user(app, "ann", "operator")
        r = client.post("/api/v1/auth/login", json={"username": "ann", "password": PASSWORD})
        assert r.status_code == 200
        assert r.json()["role"] == "operator"
        cookie = r.headers["set-cookie"].lower()
        assert "httponly" in cookie and "samesite=lax" in cookie and "secure" not in cookie
        assert client.get("/api/v1/auth/me").json()["username"] == "ann"

    def test_secure_cookie_under_https(self, app):
        add_user(app, "ann", "operator")
        c = TestClient(app, base_url="https://testserver", headers={"Origin": "https://testserver"})
        r = c.post("/api/v1/auth/login", json={"username": "ann", "password": PASSWORD})
        assert "secure" in r.headers["set-cookie"].lower()

    def test_wrong_password(self, app, client):
        add_user(app, "ann", "operator")
        r = client.post("/api/v1/auth/login", json={"username": "ann", "password": "nope"})
        assert r.status_code == 401 and r.json()["error"] == "invalid_credentials"
        r = client.post("/api/v1/auth/login", json={"username": "nobody", "password": "nope"})
        assert r.status_code == 401 and r.json()["error"] == "invalid_credentials"

    def test_password_hashed_with_argon2id(self, app):
        add_user(app, "ann", "operator")
        with app.state.db.transaction() as s:
            h = s.scalars(select(User.password_hash)).one()
        assert h.startswith("$argon2id$") and PASSWORD not in h

    def test_throttling_429_with_retry_after(self, app, client):
        add_user(app, "ann", "operator")
        for _ in range(app.state.settings.login_max_failures):
            assert client.post("/api/v1/auth/login", json={"username": "ann", "password": "bad"}).status_code == 401
        r = client.post("/api/v1/auth/login", json={"username": "ann", "password": PASSWORD})
        assert r.status_code == 429
        assert r.json()["error"] == "login_throttled"
        assert 0 < int(r.headers["Retry-After"]) <= app.state.settings.login_window_s

    def test_login_from_foreign_origin_refused(self, app):
        add_user(app, "ann", "operator")
        c = TestClient(app, headers={"Origin": "https://evil.example"})
        r = c.post("/api/v1/auth/login", json={"username": "ann", "password": PASSWORD})
        assert r.status_code == 403 and r.json()["error"] == "csrf_failed"


class TestSessions:
    def test_logout_ends_session(self, app):
        add_user(app, "ann", "operator")
        c = login(app, "ann")
        cookie = c.cookies.get("posefix_session")
        assert c.post("/api/v1/auth/logout").status_code == 204
        c2 = TestClient(app, headers={"Origin": ORIGIN}, cookies={"posefix_session": cookie})
        assert c2.get("/api/v1/auth/me").status_code == 401

    def test_disabling_user_ends_sessions_and_tokens(self, app, users):
        add_user(app, "ann", "operator")
        c = login(app, "ann")
        tok = c.post("/api/v1/tokens", json={"name": "x", "scope": "read"}).json()["token"]
        admin = login(app, "admin")
        uid = c.get("/api/v1/auth/me").json()["id"]
        assert admin.patch(f"/api/v1/users/{uid}", json={"disabled": True}).status_code == 200
        assert c.get("/api/v1/auth/me").status_code == 401
        r = TestClient(app).get("/api/v1/auth/me", headers={"Authorization": f"Bearer {tok}"})
        assert r.status_code == 401 and r.json()["error"] == "account_disabled"
        bad = TestClient(app, headers={"Origin": ORIGIN}).post("/api/v1/auth/login", json={"username": "ann", "password": PASSWORD})
        assert bad.status_code == 401

    def test_idle_timeout(self, app):
        add_user(app, "ann", "operator")
        c = login(app, "ann")
        idle = app.state.settings.session_idle_timeout_s
        with app.state.db.transaction() as s:
            s.execute(update(AuthSession).values(last_seen_at=dt.datetime.now(dt.UTC) - dt.timedelta(seconds=idle + 5)))
        r = c.get("/api/v1/auth/me")
        assert r.status_code == 401 and r.json()["error"] == "session_expired"

    def test_absolute_timeout(self, app):
        add_user(app, "ann", "operator")
        c = login(app, "ann")
        with app.state.db.transaction() as s:
            s.execute(update(AuthSession).values(expires_at=dt.datetime.now(dt.UTC) - dt.timedelta(seconds=1)))
        assert c.get("/api/v1/auth/me").status_code == 401

    def test_session_id_stored_hashed(self, app):
        add_user(app, "ann", "operator")
        c = login(app, "ann")
        sid = c.cookies.get("posefix_session")
        with app.state.db.transaction() as s:
            stored = s.scalars(select(AuthSession.id_hash)).one()
        assert sid not in stored and len(stored) == 64


class TestCsrf:
    def test_cookie_post_without_origin_refused(self, app):
        add_user(app, "ann", "operator")
        c = login(app, "ann")
        del c.headers["Origin"]
        r = c.post("/api/v1/tokens", json={"name": "x"})
        assert r.status_code == 403 and r.json()["error"] == "csrf_failed"

    def test_cookie_post_from_other_origin_refused(self, app):
        add_user(app, "ann", "operator")
        c = login(app, "ann")
        r = c.post("/api/v1/tokens", json={"name": "x"}, headers={"Origin": "https://evil.example"})
        assert r.status_code == 403

    def test_cookie_post_form_body_refused(self, app):
        add_user(app, "ann", "operator")
        c = login(app, "ann")
        r = c.post("/api/v1/tokens", content=b"name=x&scope=write", headers={"Content-Type": "application/x-www-form-urlencoded"})
        assert r.status_code == 415 and r.json()["error"] == "json_required"

    def test_referer_accepted_when_origin_missing(self, app):
        add_user(app, "ann", "operator")
        c = login(app, "ann")
        del c.headers["Origin"]
        r = c.post("/api/v1/tokens", json={"name": "x"}, headers={"Referer": f"{ORIGIN}/runs/1"})
        assert r.status_code == 201

    def test_bearer_token_needs_no_origin(self, app, users):
        r = TestClient(app).put("/api/v1/operators/me/home-area", json={"lon": 24.94, "lat": 60.17, "radius_m": 500},
                                headers=users["operator"])
        assert r.status_code == 200, r.text


class TestTokens:
    def test_token_shown_once_and_hashed(self, app):
        add_user(app, "ann", "client")
        c = login(app, "ann")
        r = c.post("/api/v1/tokens", json={"name": "ci", "scope": "write"})
        secret = r.json()["token"]
        listed = c.get("/api/v1/tokens").json()["items"]
        assert len(listed) == 1 and "token" not in listed[0]
        with app.state.db.transaction() as s:
            stored = s.scalars(select(ApiToken.token_hash)).one()
        assert secret not in stored
        assert TestClient(app).get("/api/v1/auth/me", headers={"Authorization": f"Bearer {secret}"}).json()["username"] == "ann"

    def test_read_token_cannot_write(self, app):
        add_user(app, "ann", "client")
        c = login(app, "ann")
        secret = c.post("/api/v1/tokens", json={"name": "ro", "scope": "read"}).json()["token"]
        h = {"Authorization": f"Bearer {secret}"}
        t = TestClient(app)
        assert t.get("/api/v1/runs", headers=h).status_code == 200
        r = t.post("/api/v1/tokens", json={"name": "x"}, headers=h)
        assert r.status_code == 403 and r.json()["error"] == "insufficient_scope"

    def test_revoked_token_refused(self, app):
        add_user(app, "ann", "client")
        c = login(app, "ann")
        r = c.post("/api/v1/tokens", json={"name": "ci", "scope": "write"}).json()
        assert c.delete(f"/api/v1/tokens/{r['id']}").status_code == 204
        resp = TestClient(app).get("/api/v1/auth/me", headers={"Authorization": f"Bearer {r['token']}"})
        assert resp.status_code == 401 and resp.json()["error"] == "invalid_token"

    def test_cannot_revoke_someone_elses_token(self, app):
        add_user(app, "ann", "client")
        add_user(app, "bob", "client")
        a, b = login(app, "ann"), login(app, "bob")
        tid = a.post("/api/v1/tokens", json={"name": "ci"}).json()["id"]
        assert b.delete(f"/api/v1/tokens/{tid}").status_code == 404

    def test_malformed_authorization(self, app):
        r = TestClient(app).get("/api/v1/auth/me", headers={"Authorization": "Basic abc"})
        assert r.status_code == 401 and r.json()["error"] == "invalid_token"


class TestUsersAdmin:
    def test_create_list_update(self, app, users):
        admin = login(app, "admin")
        r = admin.post("/api/v1/users", json={"username": "newop", "password": "longenough1", "role": "operator"})
        assert r.status_code == 201
        assert admin.post("/api/v1/users", json={"username": "newop", "password": "longenough1", "role": "operator"}).status_code == 409
        assert any(u["username"] == "newop" for u in admin.get("/api/v1/users").json()["items"])
        uid = r.json()["id"]
        assert admin.patch(f"/api/v1/users/{uid}", json={"role": "reviewer"}).json()["role"] == "reviewer"

    def test_admin_cannot_disable_self(self, app, users):
        admin = login(app, "admin")
        me = admin.get("/api/v1/auth/me").json()["id"]
        assert admin.patch(f"/api/v1/users/{me}", json={"disabled": True}).status_code == 409


class TestCli:
    def test_users_create_password_stdin(self, settings):
        env = {**os.environ, "POSEFIX_DATABASE_URL": settings.database_url, "POSEFIX_DATA_DIR": str(settings.data_dir)}
        cmd = [POSEFIX, "users", "create", "--role", "admin", "--username", "root", "--password-stdin"]
        out = subprocess.run(cmd, input="a-long-password\n", env=env, capture_output=True, text=True, cwd="/", timeout=120)
        assert out.returncode == 0, out.stderr
        again = subprocess.run(cmd, input="a-long-password\n", env=env, capture_output=True, text=True, cwd="/", timeout=120)
        assert again.returncode == 1 and "already exists" in again.stderr
        short = subprocess.run(cmd[:-3] + ["--username", "x", "--password-stdin"], input="short\n", env=env, capture_output=True, text=True, cwd="/", timeout=120)
        assert short.returncode == 2

    def test_db_upgrade_from_any_directory(self, fresh_database, tmp_path):
        url = fresh_database("sqlite")
        env = {**os.environ, "POSEFIX_DATABASE_URL": url}
        out = subprocess.run([POSEFIX, "db", "upgrade"], env=env, capture_output=True, text=True, cwd=tmp_path, timeout=120)
        assert out.returncode == 0, out.stderr
        assert not (tmp_path / "var").exists()
