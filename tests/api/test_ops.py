"""Ops endpoints, the one error body, settings safety, OpenAPI declarations."""

from __future__ import annotations

import pytest

from posefix.config import DEFAULT_SECRET, Settings


class TestHealth:
    def test_healthz_readyz(self, client):
        assert client.get("/healthz").json() == {"status": "ok"}
        assert client.get("/readyz").json() == {"status": "ready"}

    def test_metrics_count_requests(self, client):
        client.get("/healthz")
        body = client.get("/metrics").text
        assert 'posefix_http_requests_total{method="GET",route="/healthz",status="200"}' in body
        assert "posefix_http_request_duration_seconds_bucket" in body

    def test_request_id_echoed_and_generated(self, client):
        assert client.get("/healthz", headers={"X-Request-ID": "abc123"}).headers["X-Request-ID"] == "abc123"
        assert len(client.get("/healthz").headers["X-Request-ID"]) == 32


class TestErrorBody:
    def test_unknown_route(self, client):
        r = client.get("/api/v1/nothing-here")
        assert r.status_code == 404
        assert r.json() == {"error": "not_found", "detail": "no such route"}

    def test_validation_error(self, client, users):
        r = client.get("/api/v1/runs?limit=0", headers=users["admin"])
        assert r.status_code == 422
        body = r.json()
        assert body["error"] == "validation_error" and "limit" in body["detail"]

    def test_unauthenticated(self, client):
        r = client.get("/api/v1/runs")
        assert r.status_code == 401
        assert r.json()["error"] == "not_authenticated"

    def test_method_not_allowed(self, client):
        r = client.put("/healthz")
        assert r.status_code == 405
        assert set(r.json()) == {"error", "detail"}

    def test_openapi_declares_error_body(self, client):
        spec = client.get("/openapi.json").json()
        assert "ErrorBody" in spec["components"]["schemas"]
        edits = spec["paths"]["/api/v1/runs/{run_id}/edits"]["post"]["responses"]
        assert {"409", "422"} <= set(edits)
        assert edits["409"]["content"]["application/json"]["schema"]["$ref"].endswith("/ErrorBody")


class TestSettings:
    def test_default_secret_refused_in_production(self):
        with pytest.raises(ValueError, match="SECRET_KEY"):
            Settings(environment="production", secret_key=DEFAULT_SECRET)

    def test_short_secret_refused_in_production(self):
        with pytest.raises(ValueError, match="32 characters"):
            Settings(environment="production", secret_key="short")

    def test_development_accepts_default(self):
        assert Settings(environment="development").secret_key == DEFAULT_SECRET

    def test_env_prefix(self, monkeypatch):
        monkeypatch.setenv("POSEFIX_MAX_RUN_BYTES", "1234")
        assert Settings().max_run_bytes == 1234

    def test_dotenv(self, tmp_path, monkeypatch):
        (tmp_path / ".env").write_text("POSEFIX_LOGIN_MAX_FAILURES=9\n")
        monkeypatch.chdir(tmp_path)
        assert Settings().login_max_failures == 9


class TestLogs:
    def test_access_log_is_json_with_request_id(self, app, client):
        import io
        import json
        import logging

        from posefix.main import JsonFormatter

        buf = io.StringIO()
        handler = logging.StreamHandler(buf)
        handler.setFormatter(JsonFormatter())
        logger = logging.getLogger("posefix.http")
        logger.addHandler(handler)
        old = logger.level
        logger.setLevel(logging.INFO)
        try:
            client.get("/healthz", headers={"X-Request-ID": "req-42"})
        finally:
            logger.removeHandler(handler)
            logger.setLevel(old)
        line = json.loads(buf.getvalue().strip().splitlines()[-1])
        assert line["request_id"] == "req-42" and line["path"] == "/healthz" and line["status"] == 200
        assert line["level"] == "info" and "duration_ms" in line and line["time"].endswith("Z")
