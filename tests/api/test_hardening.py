"""HTTP hardening on a real database (SQLite and PostgreSQL): security headers on every
response, a body-read time-out (over real sockets against uvicorn), strings with NUL, and
the CSRF origin taken from configuration rather than the request's Host header."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
import uvicorn
from fastapi.testclient import TestClient

from tests.api.test_concurrency import free_port
from tests.conftest import ORIGIN, add_user, direct_token


def _csp(response: Any) -> dict[str, str]:
    policy = response.headers["content-security-policy"]
    return {part.split()[0]: part.strip() for part in policy.split(";") if part.strip()}


class TestSecurityHeaders:
    @pytest.mark.parametrize("method,path", [
        ("GET", "/healthz"), ("GET", "/openapi.json"), ("GET", "/api/v1/auth/me"), ("GET", "/api/v1/runs/1"),
        ("POST", "/api/v1/auth/login"), ("GET", "/api/v1/no-such-route"), ("GET", "/metrics"),
    ])
    def test_every_response_carries_them(self, client: TestClient, method: str, path: str) -> None:
        response = client.request(method, path, json={} if method == "POST" else None)
        h = response.headers
        assert h["x-content-type-options"] == "nosniff"
        assert h["referrer-policy"] == "same-origin"
        assert h["x-frame-options"] == "DENY"
        csp = _csp(response)
        assert csp["frame-ancestors"] == "frame-ancestors 'none'"
        assert csp["script-src"] == "script-src 'self'"  # no inline script, no eval, no other origin
        assert "'unsafe-inline'" not in csp["style-src"] and "'unsafe-eval'" not in h["content-security-policy"]
        assert csp["worker-src"] == "worker-src 'self' blob:"  # MapLibre's worker
        assert csp["object-src"] == "object-src 'none'" and csp["connect-src"] == "connect-src 'self'"
        assert "strict-transport-security" not in h  # plain HTTP: HSTS would mean nothing

    def test_hsts_only_over_https(self, app: Any) -> None:
        with TestClient(app, base_url="https://testserver") as c:
            assert c.get("/healthz").headers["strict-transport-security"] == "max-age=31536000"

    def test_the_api_docs_get_their_own_policy(self, client: TestClient) -> None:
        response = client.get("/docs")
        assert response.status_code == 200
        csp = _csp(response)
        assert "https://cdn.jsdelivr.net" in csp["script-src"] and csp["frame-ancestors"] == "frame-ancestors 'none'"


# ------------------------------------------------------------------ slow bodies


@pytest.fixture
def served(settings: Any) -> Iterator[tuple[int, dict[str, str]]]:
    """uvicorn on loopback with a 1 s body time-out and a 2 KB/s floor: (port, token headers)."""
    from posefix.main import create_app

    settings.body_idle_timeout_s = 1.0
    settings.body_min_rate_bps = 2000.0
    app = create_app(settings)
    headers = direct_token(app, add_user(app, "uploader", "client"))
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.05)
    yield port, headers
    server.should_exit = True
    thread.join(timeout=10)
    app.state.db.dispose()


def _post_head(port: int, path: str, headers: dict[str, str], length: int, ctype: str) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    lines = [f"POST {path} HTTP/1.1", f"Host: 127.0.0.1:{port}", f"Content-Type: {ctype}", f"Content-Length: {length}",
             *(f"{k}: {v}" for k, v in headers.items())]
    sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
    return sock


def _read_until_closed(sock: socket.socket) -> bytes:
    out = b""
    while chunk := sock.recv(65536):  # a socket time-out (10 s) raises: the server held on
        out += chunk
    return out


class TestSlowBodies:
    def test_a_declared_gigabyte_that_stalls_is_dropped(self, served: tuple[int, dict[str, str]]) -> None:
        port, headers = served
        boundary = "x" * 16
        sock = _post_head(port, "/api/v1/runs", headers, 1024**3, f"multipart/form-data; boundary={boundary}")
        sock.sendall((f"--{boundary}\r\nContent-Disposition: form-data; name=\"name\"\r\n\r\ndrive\r\n").encode()[:81])
        started = time.monotonic()
        answer = _read_until_closed(sock)
        sock.close()
        assert answer.startswith(b"HTTP/1.1 408"), answer[:200]
        assert b"request_timeout" in answer
        assert time.monotonic() - started < 5

    def test_a_trickling_body_is_dropped_too(self, served: tuple[int, dict[str, str]]) -> None:
        port, _ = served
        body = b'{"username": "uploader", "password": "' + b"p" * 200 + b'"}'
        sock = _post_head(port, "/api/v1/auth/login", {"Origin": ORIGIN}, len(body), "application/json")
        started = time.monotonic()
        try:
            for i in range(len(body)):  # 10 bytes a second: each piece in time, the average far too low
                sock.sendall(body[i:i + 1])
                time.sleep(0.1)
        except (BrokenPipeError, ConnectionResetError):
            pass
        answer = _read_until_closed(sock)
        sock.close()
        assert answer.startswith(b"HTTP/1.1 408"), answer[:200]
        assert time.monotonic() - started < 8

    def test_a_body_that_keeps_coming_is_read(self, served: tuple[int, dict[str, str]]) -> None:
        port, _ = served
        body = b'{"username": "nobody", "password": "wrong-password"}'
        sock = _post_head(port, "/api/v1/auth/login", {"Origin": ORIGIN, "Connection": "close"}, len(body),
                          "application/json")
        for i in range(0, len(body), 10):
            sock.sendall(body[i:i + 10])
            time.sleep(0.1)  # slow, but done within the first second (the floor applies after it)
        answer = _read_until_closed(sock)
        sock.close()
        assert answer.startswith(b"HTTP/1.1 401"), answer[:200]


    def test_a_server_slow_to_read_does_not_blame_the_client(self) -> None:
        """The whole body is there at once; the app only starts reading after the idle window."""
        import anyio

        from posefix.hardening import BodyTimeoutMiddleware

        answers: list[dict[str, Any]] = []

        async def slow_app(scope: dict[str, Any], receive: Any, send: Any) -> None:
            await anyio.sleep(0.3)  # a busy thread pool, a queued database connection
            body = (await receive())["body"]
            await send({"type": "http.response.start", "status": 200, "headers": []})
            await send({"type": "http.response.body", "body": body})

        async def receive() -> dict[str, Any]:
            return {"type": "http.request", "body": b"all of it", "more_body": False}

        async def send(message: dict[str, Any]) -> None:
            answers.append(message)

        app = BodyTimeoutMiddleware(slow_app, idle_timeout_s=0.1, min_rate_bps=2000.0)
        anyio.run(app, {"type": "http", "path": "/"}, receive, send)
        assert answers[0]["status"] == 200 and answers[1]["body"] == b"all of it"


# ------------------------------------------------------------------ CSRF origin


class TestCsrfOrigin:
    def _login(self, app: Any, origin: str, host: str | None = None) -> int:
        with app.state.db.transaction(write=False) as s:
            from posefix.users.repository import get_user_by_username

            known = get_user_by_username(s, "ann") is not None
        if not known:
            add_user(app, "ann", "operator")
        headers = {"Origin": origin, **({"Host": host} if host else {})}
        with TestClient(app) as c:
            return c.post("/api/v1/auth/login", json={"username": "ann", "password": "correct horse battery"},
                          headers=headers).status_code

    def test_a_forged_host_header_does_not_make_an_origin_ours(self, app: Any) -> None:
        assert self._login(app, "http://evil.example", host="evil.example") == 403
        assert self._login(app, ORIGIN, host="evil.example") == 200  # the configured origin, whatever the Host

    def test_the_public_url_is_the_origin_when_no_list_is_given(self, settings: Any) -> None:
        from posefix.main import create_app

        settings.public_url = "https://posefix.example.org/app/"
        app = create_app(settings)
        try:
            assert self._login(app, "https://posefix.example.org", host="posefix.example.org") == 200
            assert self._login(app, ORIGIN) == 403
            assert self._login(app, "http://posefix.example.org", host="posefix.example.org") == 403  # scheme counts
        finally:
            app.state.db.dispose()

    def test_development_defaults_to_the_local_server(self, monkeypatch: pytest.MonkeyPatch) -> None:
        from posefix.config import Settings, with_listen_origins

        for key in ("POSEFIX_ALLOWED_ORIGINS", "POSEFIX_PUBLIC_URL"):
            monkeypatch.setenv(key, "")  # recorded, so with_listen_origins' own setting is undone too
            monkeypatch.delenv(key)
        dev = Settings(environment="development")
        configured = Settings(environment="development", public_url="https://me.example")
        assert dev.csrf_origins == {"http://localhost:8000", "http://127.0.0.1:8000", "http://[::1]:8000"}
        served = with_listen_origins(dev, "0.0.0.0", 9123)
        assert served.csrf_origins == {"http://localhost:9123", "http://127.0.0.1:9123", "http://[::1]:9123"}
        assert "9123" in __import__("os").environ["POSEFIX_ALLOWED_ORIGINS"]  # uvicorn's worker processes too
        assert with_listen_origins(dev, "10.0.0.5", 80).csrf_origins == {"http://10.0.0.5:80"}
        assert with_listen_origins(configured, "0.0.0.0", 9123).csrf_origins == {"https://me.example"}

    def test_production_without_an_origin_refuses_sessions_and_serve_will_not_start(
        self, settings: Any, monkeypatch: pytest.MonkeyPatch, tmp_path: Any,
    ) -> None:
        from click.testing import CliRunner

        from posefix.cli import build_app
        from posefix.main import create_app

        settings.environment = "production"
        app = create_app(settings)
        try:
            assert self._login(app, ORIGIN) == 403
        finally:
            app.state.db.dispose()
        for key in ("POSEFIX_ALLOWED_ORIGINS", "POSEFIX_PUBLIC_URL"):
            monkeypatch.setenv(key, "")
            monkeypatch.delenv(key)
        monkeypatch.setenv("POSEFIX_ENVIRONMENT", "production")
        monkeypatch.setenv("POSEFIX_SECRET_KEY", "s" * 48)
        monkeypatch.setenv("POSEFIX_DATA_DIR", str(tmp_path))
        out = CliRunner().invoke(build_app(["server"]), ["serve", "--port", "1"])
        assert out.exit_code == 2 and "POSEFIX_PUBLIC_URL" in out.output
        assert not (tmp_path / "posefix.sqlite").exists()  # refused before touching anything


# ------------------------------------------------------------------ NUL in strings


class TestNul:
    """PostgreSQL cannot store NUL (SQLite can): both answer 422 naming the field."""

    def _assert_names(self, response: Any, field: str) -> None:
        assert response.status_code == 422, response.text
        body = response.json()
        assert body["error"] == "validation_error" and body["fields"][0]["field"] == field
        assert field in body["detail"] and "NUL" in body["detail"]

    def test_json_body_query_path_and_form_fields(self, app: Any, client: TestClient) -> None:
        headers = direct_token(app, add_user(app, "root", "admin"))
        self._assert_names(client.post("/api/v1/auth/login", json={"username": "ro\x00ot", "password": "x"}),
                           "body.username")
        self._assert_names(client.post("/api/v1/tokens", json={"name": "a\x00b"}, headers=headers), "body.name")
        self._assert_names(client.post("/api/v1/users", json={"username": "u", "password": "long enough pass\x00",
                                                              "role": "operator"}, headers=headers), "body.password")
        self._assert_names(client.get("/api/v1/runs", params={"name": "a\x00"}, headers=headers), "query.name")
        self._assert_names(client.get("/api/v1/tile-sources/a%00b", headers=headers), "path.ref")
        response = client.post("/api/v1/runs", headers=headers, data={"name": "drive\x00"},
                               files={"file": ("d.csv", b"t,lat,lon\n", "text/csv")})
        self._assert_names(response, "form.name")
        # the same text without NUL is only as wrong as it is
        assert client.post("/api/v1/auth/login", json={"username": "root", "password": "x"}).status_code == 401
        assert client.get("/api/v1/runs", params={"name": "a"}, headers=headers).status_code == 200

    def test_an_escaped_backslash_is_no_nul(self, client: TestClient) -> None:
        # the text backslash-u-0-0-0-0, not a NUL: an ordinary wrong login
        response = client.post("/api/v1/auth/login", content=b'{"username": "a\\\\u0000b", "password": "x"}',
                               headers={"Content-Type": "application/json"})
        assert response.status_code == 401, response.text
