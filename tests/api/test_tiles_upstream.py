"""The upstream tile proxy: cache, failures, and the guards that keep it from being aimed
inward (refused addresses, the allow-list, redirects, size and time limits).

Every upstream is a real HTTP server on a loopback address that the test starts; the
proxy runs on a real database (SQLite, and PostgreSQL when POSEFIX_TEST_PG_URL is set).
"""

from __future__ import annotations

import http.server
import ipaddress
import json
import logging
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from posefix.tiles.outbound import address_refusal
from posefix.tiles.service import tile_settings
from tests.api.test_tiles import admin, app, database_url, register, template_database, tile_png  # noqa: F401


@pytest.fixture
def data_dir(tmp_path: Path) -> Path:
    root = tmp_path / "data"
    root.mkdir()
    return root


class _UpstreamHandler(http.server.BaseHTTPRequestHandler):
    """A real XYZ server: /{z}/{x}/{y}.png; its behaviour is set on the server."""

    def do_GET(self) -> None:  # noqa: N802 (http.server's naming)
        server = self.server
        server.hits.append(self.path)  # type: ignore[attr-defined]
        mode = server.mode  # type: ignore[attr-defined]
        if mode == "slow":
            time.sleep(2.0)
        if mode == "error":
            self.send_response(500)
            self.end_headers()
            return
        if mode == "redirect":
            self.send_response(302)
            self.send_header("Location", server.location)  # type: ignore[attr-defined]
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        parts = self.path.strip("/").removesuffix(".png").split("/")
        if mode == "html":
            body, ctype = b"<html>rate limited</html>", "text/html"
        elif parts[0] == "9":
            self.send_response(404)
            self.end_headers()
            return
        else:
            body, ctype = tile_png(*(int(p) for p in parts)), "image/png"
        if mode in ("huge", "huge_undeclared"):
            body = body + b"\0" * 200_000  # still starts as a PNG
        self.send_response(200)
        self.send_header("Content-Type", ctype)
        if mode == "huge_undeclared":
            self.send_header("Connection", "close")  # length known only at the end
        else:
            self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        try:
            self.wfile.write(body)
        except (BrokenPipeError, ConnectionResetError):
            pass

    def log_message(self, *_args: object) -> None:
        pass


def _serve(address: str) -> http.server.ThreadingHTTPServer:
    server = http.server.ThreadingHTTPServer((address, 0), _UpstreamHandler)
    server.hits = []  # type: ignore[attr-defined]
    server.mode = "ok"  # type: ignore[attr-defined]
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


@pytest.fixture
def upstream() -> Iterator[http.server.ThreadingHTTPServer]:
    server = _serve("127.0.0.1")
    yield server
    server.shutdown()
    server.server_close()


@pytest.fixture
def inner() -> Iterator[http.server.ThreadingHTTPServer]:
    """A second loopback server at another address (127.0.0.2): an internal service."""
    server = _serve("127.0.0.2")
    yield server
    server.shutdown()
    server.server_close()


@pytest.fixture
def allow(monkeypatch: pytest.MonkeyPatch):
    def set_allow(*entries: str) -> None:
        monkeypatch.setenv("POSEFIX_TILE_UPSTREAM_ALLOW", json.dumps(list(entries)))
        tile_settings.cache_clear()

    return set_allow


@pytest.fixture
def tile_log() -> Iterator[list[str]]:
    """What the tile service logs (the posefix loggers do not propagate to pytest's caplog)."""
    lines: list[str] = []

    class Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            lines.append(record.getMessage())

    handler = Collect(level=logging.DEBUG)
    logger = logging.getLogger("posefix.tiles")
    # Another test module's app may have set the posefix loggers' level first (the schemathesis
    # app logs errors only): this test reads warnings whatever ran before it in the process.
    old_level = logger.level
    logger.setLevel(logging.DEBUG)
    logger.addHandler(handler)
    yield lines
    logger.removeHandler(handler)
    logger.setLevel(old_level)


def _register(admin: TestClient, server: http.server.ThreadingHTTPServer, host: str | None = None) -> None:
    address, port = server.server_address[:2]
    register(admin, name="up", kind="satellite", url=f"http://{host or address}:{port}/{{z}}/{{x}}/{{y}}.png",
             max_zoom=12)


UNIFORM = "tile source 'up' could not deliver this tile"


def _assert_uniform_502(response) -> None:  # type: ignore[no-untyped-def]
    """The client learns that the upstream failed, never why (no address, status or type)."""
    assert response.status_code == 502, response.text
    assert response.json() == {"error": "upstream_failed", "detail": UNIFORM}


class TestGuards:
    @pytest.mark.parametrize("address", [
        "127.0.0.1", "10.1.2.3", "172.16.0.1", "192.168.1.1", "169.254.169.254", "100.64.0.1", "0.0.0.0",
        "224.0.0.1", "239.255.255.250", "255.255.255.255", "::1", "::", "fe80::1", "fc00::1", "fd12:3456::1",
        "ff02::1", "::ffff:127.0.0.1", "::ffff:169.254.169.254", "::ffff:10.0.0.1", "2002:7f00:1::1",
    ])
    def test_inward_addresses_are_refused(self, address: str) -> None:
        assert address_refusal(ipaddress.ip_address(address)) is not None

    @pytest.mark.parametrize("address", ["8.8.8.8", "1.1.1.1", "2001:4860:4860::8888", "::ffff:8.8.8.8"])
    def test_public_addresses_pass(self, address: str) -> None:
        assert address_refusal(ipaddress.ip_address(address)) is None

    def test_a_loopback_upstream_is_refused_by_default(
        self, admin: TestClient, upstream: http.server.ThreadingHTTPServer, tile_log: list[str],
    ) -> None:
        _register(admin, upstream)
        _assert_uniform_502(admin.get("/api/v1/tiles/up/3/2/5.png"))
        assert upstream.hits == []  # no connection was made
        assert any("127.0.0.1" in line and "loopback" in line for line in tile_log), tile_log

    def test_a_host_name_is_judged_by_its_addresses(
        self, admin: TestClient, upstream: http.server.ThreadingHTTPServer, tile_log: list[str],
    ) -> None:
        _register(admin, upstream, host="localhost")
        _assert_uniform_502(admin.get("/api/v1/tiles/up/3/2/5.png"))
        assert upstream.hits == []
        assert any("localhost resolves to" in line for line in tile_log), tile_log

    def test_the_allow_list_admits_a_sites_own_server_by_network_or_name(
        self, admin: TestClient, upstream: http.server.ThreadingHTTPServer, allow, data_dir: Path,
    ) -> None:
        allow("127.0.0.0/30")
        _register(admin, upstream)
        response = admin.get("/api/v1/tiles/up/3/2/5.png")
        assert response.status_code == 200 and response.content == tile_png(3, 2, 5)
        assert admin.delete("/api/v1/tile-sources/up").status_code == 204
        allow("LOCALHOST")
        _register(admin, upstream, host="localhost")
        assert admin.get("/api/v1/tiles/up/3/2/6.png").status_code == 200
        assert upstream.hits == ["/3/2/5.png", "/3/2/6.png"]

    def test_a_redirect_is_not_followed(
        self, admin: TestClient, upstream: http.server.ThreadingHTTPServer, inner: http.server.ThreadingHTTPServer,
        allow, tile_log: list[str],
    ) -> None:
        allow("127.0.0.1")  # the upstream is allowed, the internal service at 127.0.0.2 is not
        _register(admin, upstream)
        upstream.mode = "redirect"
        upstream.location = "http://127.0.0.2:%d/3/2/5.png" % inner.server_address[1]
        _assert_uniform_502(admin.get("/api/v1/tiles/up/3/2/5.png"))
        assert upstream.hits == ["/3/2/5.png"] and inner.hits == []
        assert any("redirected" in line and "127.0.0.2" in line for line in tile_log), tile_log

    @pytest.mark.parametrize("mode", ["huge", "huge_undeclared"])
    def test_an_oversized_body_is_dropped(
        self, admin: TestClient, upstream: http.server.ThreadingHTTPServer, allow, monkeypatch: pytest.MonkeyPatch,
        data_dir: Path, tile_log: list[str], mode: str,
    ) -> None:
        monkeypatch.setenv("POSEFIX_TILE_UPSTREAM_MAX_BYTES", "100000")
        allow("127.0.0.1")
        _register(admin, upstream)
        upstream.mode = mode
        _assert_uniform_502(admin.get("/api/v1/tiles/up/3/2/5.png"))
        assert not list((data_dir / "tile-cache").rglob("*.png"))  # nothing cached
        assert any("100000" in line and "allowed" in line for line in tile_log), tile_log
        upstream.mode = "ok"
        assert admin.get("/api/v1/tiles/up/3/2/5.png").status_code == 200


class TestUpstreamProxy:
    @pytest.fixture(autouse=True)
    def _allow_loopback(self, allow) -> None:
        allow("127.0.0.1")

    def test_first_fetch_goes_upstream_then_the_disk_cache_answers(
        self, admin: TestClient, upstream: http.server.ThreadingHTTPServer, data_dir: Path,
    ) -> None:
        _register(admin, upstream)
        first = admin.get("/api/v1/tiles/up/3/2/5.png")
        assert first.status_code == 200 and first.content == tile_png(3, 2, 5)
        assert upstream.hits == ["/3/2/5.png"]
        upstream.mode = "error"
        second = admin.get("/api/v1/tiles/up/3/2/5.png")
        assert second.status_code == 200 and second.content == first.content
        assert upstream.hits == ["/3/2/5.png"]
        cached = list((data_dir / "tile-cache").rglob("5.png"))
        assert len(cached) == 1 and cached[0].read_bytes() == first.content

    def test_upstream_failure_is_a_uniform_502_and_the_reason_is_logged(
        self, admin: TestClient, upstream: http.server.ThreadingHTTPServer, tile_log: list[str],
    ) -> None:
        _register(admin, upstream)
        upstream.mode = "error"
        _assert_uniform_502(admin.get("/api/v1/tiles/up/1/0/0.png"))
        upstream.mode = "html"
        _assert_uniform_502(admin.get("/api/v1/tiles/up/1/0/1.png"))
        assert any("HTTP 500" in line and "127.0.0.1" in line for line in tile_log), tile_log
        assert any("text/html" in line for line in tile_log), tile_log

    def test_a_closed_port_looks_like_any_other_failure(
        self, admin: TestClient, upstream: http.server.ThreadingHTTPServer,
    ) -> None:
        _register(admin, upstream)
        upstream.mode = "error"
        http_error = admin.get("/api/v1/tiles/up/1/0/0.png")
        admin.delete("/api/v1/tile-sources/up")
        register(admin, name="up", kind="satellite", url="http://127.0.0.1:9/{z}/{x}/{y}.png")
        closed = admin.get("/api/v1/tiles/up/1/0/0.png")
        assert (closed.status_code, closed.json()) == (http_error.status_code, http_error.json())

    def test_a_slow_upstream_times_out(
        self, admin: TestClient, upstream: http.server.ThreadingHTTPServer, monkeypatch: pytest.MonkeyPatch,
        tile_log: list[str],
    ) -> None:
        monkeypatch.setenv("POSEFIX_TILE_UPSTREAM_TIMEOUT_S", "0.3")
        tile_settings.cache_clear()
        _register(admin, upstream)
        upstream.mode = "slow"
        started = time.perf_counter()
        response = admin.get("/api/v1/tiles/up/2/1/1.png")
        assert time.perf_counter() - started < 1.5
        _assert_uniform_502(response)
        assert any("did not answer in time" in line for line in tile_log), tile_log

    def test_stale_cache_is_served_when_upstream_is_down(
        self, admin: TestClient, upstream: http.server.ThreadingHTTPServer, monkeypatch: pytest.MonkeyPatch,
    ) -> None:
        _register(admin, upstream)
        assert admin.get("/api/v1/tiles/up/2/2/2.png").status_code == 200
        monkeypatch.setenv("POSEFIX_TILE_UPSTREAM_MAX_AGE_S", "0")
        tile_settings.cache_clear()
        upstream.mode = "error"
        response = admin.get("/api/v1/tiles/up/2/2/2.png")
        assert response.status_code == 200 and response.content == tile_png(2, 2, 2)
        assert len(upstream.hits) == 2  # it did ask again, the copy was too old

    def test_upstream_404_is_a_missing_tile_and_deleting_clears_the_cache(
        self, admin: TestClient, upstream: http.server.ThreadingHTTPServer, data_dir: Path,
    ) -> None:
        _register(admin, upstream)
        response = admin.get("/api/v1/tiles/up/9/0/0.png")
        assert response.status_code == 404 and response.json()["error"] == "tile_not_found"
        assert admin.get("/api/v1/tiles/up/1/1/1.png").status_code == 200
        assert any((data_dir / "tile-cache").rglob("*.png"))
        assert admin.delete("/api/v1/tile-sources/up").status_code == 204
        assert not any((data_dir / "tile-cache").rglob("*.png"))
