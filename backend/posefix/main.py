"""The FastAPI application factory: ``create_app(settings)``.

Wires settings, the database, error handlers, request ids with JSON logs, Prometheus
metrics, the ops endpoints (/healthz, /readyz, /metrics) and the API v1 routers. The
front end (frontend/dist, copied to posefix/static/app) is served at ``/`` when built.
"""

from __future__ import annotations

import json
import logging
import sys
import time
import uuid
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import anyio
from fastapi import APIRouter, Depends, FastAPI, Request, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram, generate_latest
from sqlalchemy import text

from posefix.config import Settings
from posefix.db import Database
from posefix.deps import refuse_nul
from posefix.errors import install_error_handlers
from posefix.filestore import file_store
from posefix.edits.failures import failed_edits
from posefix.edits.repository import on_task_batch
from posefix.hardening import BodyTimeoutMiddleware, SecurityHeadersMiddleware
from posefix.runs.access import register_operator_runs, register_task_runs
from posefix.runs.endpoints import register_failed_edits
from posefix.tasks.access import live_runs, runs_of_assignments, task_runs
from posefix.tasks.merge import follow_batch

log = logging.getLogger("posefix.http")

API_PREFIX = "/api/v1"


class JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created)) + f".{int(record.msecs):03d}Z",
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
        }
        for key in ("request_id", "method", "path", "status", "duration_ms", "user_id", "job_id", "worker_id"):
            if hasattr(record, key):
                out[key] = getattr(record, key)
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(out)


def configure_logging(settings: Settings) -> None:
    root = logging.getLogger("posefix")
    if getattr(root, "_posefix_configured", False):
        return
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter() if settings.log_json else logging.Formatter("%(levelname)s %(name)s %(message)s"))
    root.addHandler(handler)
    root.setLevel(settings.log_level.upper())
    root.propagate = False
    root._posefix_configured = True  # type: ignore[attr-defined]


class Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter(
            "posefix_http_requests_total", "HTTP requests", ["method", "route", "status"], registry=self.registry
        )
        self.latency = Histogram(
            "posefix_http_request_duration_seconds", "HTTP request latency", ["method", "route"],
            registry=self.registry, buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10),
        )


class RequestContextMiddleware:
    """Request id (X-Request-ID in and out), access log line, metrics.

    A plain ASGI middleware (not BaseHTTPMiddleware): no extra task per request, and
    streamed responses (exports, SSE) pass through untouched.
    """

    def __init__(self, app: Any):
        self.app = app

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope.get("headers") or [])
        rid = (headers.get(b"x-request-id", b"").decode("latin-1") or uuid.uuid4().hex)[:64]
        scope.setdefault("state", {})["request_id"] = rid
        start = time.perf_counter()
        status = 500

        async def send_with_id(message: dict[str, Any]) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
                message.setdefault("headers", [])
                message["headers"] = [*message["headers"], (b"x-request-id", rid.encode("latin-1"))]
            await send(message)

        try:
            await self.app(scope, receive, send_with_id)
        finally:
            elapsed = time.perf_counter() - start
            route_path = getattr(scope.get("route"), "path", "unmatched")
            method = scope.get("method", "")
            metrics: Metrics = scope["app"].state.metrics
            metrics.requests.labels(method, route_path, str(status)).inc()
            metrics.latency.labels(method, route_path).observe(elapsed)
            state = scope.get("state", {})
            log.info(
                "%s %s %s", method, scope.get("path", ""), status,
                extra={
                    "request_id": rid, "method": method, "path": scope.get("path", ""), "status": status,
                    "duration_ms": round(elapsed * 1000, 2), "user_id": state.get("user_id"),
                },
            )


def ops_router() -> APIRouter:
    router = APIRouter(tags=["ops"])

    @router.get("/healthz")
    def healthz() -> dict[str, str]:
        """The process is up."""
        return {"status": "ok"}

    @router.get("/readyz", responses={503: {"description": "Not ready"}})
    def readyz(request: Request) -> Response:
        """The database answers and the file store is writable."""
        db: Database = request.app.state.db
        settings: Settings = request.app.state.settings
        try:
            with db.engine.connect() as conn:
                conn.execute(text("SELECT 1"))
            file_store(settings).check()
        except Exception as exc:
            return JSONResponse(status_code=503, content={"error": "not_ready", "detail": str(exc)[:300]})
        return JSONResponse({"status": "ready"})

    @router.get("/metrics", response_class=Response)
    def metrics(request: Request) -> Response:
        """Prometheus metrics."""
        registry = request.app.state.metrics.registry
        return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)

    return router


def api_router() -> APIRouter:
    from posefix.audit.endpoints import router as audit_router
    from posefix.edits.endpoints import router as edits_router
    from posefix.jobs.endpoints import router as jobs_router
    from posefix.maps.endpoints import router as maps_router
    from posefix.runs.endpoints import router as runs_router
    from posefix.tasks.endpoints import router as tasks_router
    from posefix.tiles.endpoints import router as tiles_router
    from posefix.users.endpoints import router as users_router

    router = APIRouter(prefix=API_PREFIX, dependencies=[Depends(refuse_nul)])
    router.include_router(users_router)
    router.include_router(audit_router)
    router.include_router(runs_router)
    router.include_router(edits_router)
    router.include_router(jobs_router)
    router.include_router(tiles_router)
    router.include_router(tasks_router)
    router.include_router(maps_router)
    return router


def create_app(settings: Settings | None = None, *, embedded_worker: bool = False) -> FastAPI:
    settings = settings or Settings()
    configure_logging(settings)
    register_operator_runs(runs_of_assignments)
    register_task_runs(task_runs, live_runs)
    register_failed_edits(failed_edits)
    on_task_batch(follow_batch)
    db = Database(
        settings.resolved_database_url,
        pool_size=settings.db_pool_size,
        max_overflow=settings.db_max_overflow,
    )

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # Each sync request holds one connection for its whole life: with more request
        # threads than connections, a burst would wait on the pool and fail. Keep one
        # connection spare for the embedded worker.
        limiter = anyio.to_thread.current_default_thread_limiter()
        limiter.total_tokens = max(4, min(limiter.total_tokens, db.max_connections - 1))
        worker = None
        if embedded_worker:
            from posefix.worker.runner import Worker

            worker = Worker(db, settings, name="embedded")
            worker.start_thread()
            app.state.worker = worker
        try:
            yield
        finally:
            if worker is not None:
                worker.stop()
                worker.join(timeout=30)
            db.dispose()

    app = FastAPI(
        title="posefix",
        version="1.0.0",
        description="Crowdsourced correction of vehicle trajectories: runs, edits, revisions, jobs.",
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.state.db = db
    app.state.metrics = Metrics()
    install_error_handlers(app)
    # Added last is outermost: the headers reach every response, the 408 of a stalled body too.
    app.add_middleware(BodyTimeoutMiddleware, idle_timeout_s=settings.body_idle_timeout_s,
                       min_rate_bps=settings.body_min_rate_bps)
    app.add_middleware(RequestContextMiddleware)
    app.add_middleware(SecurityHeadersMiddleware)
    app.include_router(ops_router())
    app.include_router(api_router())
    _mount_frontend(app)
    return app


def _mount_frontend(app: FastAPI) -> None:
    from fastapi.staticfiles import StaticFiles

    for candidate in (
        Path(__file__).parent / "static" / "app",
        Path(__file__).resolve().parents[2] / "frontend" / "dist",
    ):
        if (candidate / "index.html").is_file():
            app.mount("/", StaticFiles(directory=candidate, html=True), name="frontend")
            return
