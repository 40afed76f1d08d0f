"""Errors that carry their HTTP status, and the one error body every response uses.

Body: ``{"error": <machine code>, "detail": <human text>, ...extra}``. Routes declare the
errors they may return through ``responses(...)`` so the OpenAPI spec lists them.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict
from sqlalchemy.exc import DataError
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.exceptions import HTTPException as StarletteHTTPException

__all__ = [
    "AppError", "BadRequest", "Unauthorized", "Forbidden", "NotFound", "Conflict", "Gone",
    "LengthRequired", "PayloadTooLarge", "UnsupportedMediaType", "Unprocessable", "TooManyRequests",
    "ErrorBody", "responses", "install_error_handlers",
]

log = logging.getLogger("posefix.errors")


class ErrorBody(BaseModel):
    """Every error response: a machine-readable code and a human sentence."""

    model_config = ConfigDict(extra="allow")
    error: str
    detail: str


class AppError(Exception):
    status_code = 400
    code = "bad_request"

    def __init__(
        self,
        detail: str,
        *,
        code: str | None = None,
        extra: dict[str, Any] | None = None,
        headers: dict[str, str] | None = None,
    ):
        super().__init__(detail)
        self.detail = detail
        if code is not None:
            self.code = code
        self.extra = extra or {}
        self.headers = headers

    def body(self) -> dict[str, Any]:
        return {"error": self.code, "detail": self.detail, **self.extra}


class BadRequest(AppError):
    status_code, code = 400, "bad_request"


class Unauthorized(AppError):
    status_code, code = 401, "unauthorized"


class Forbidden(AppError):
    status_code, code = 403, "forbidden"


class NotFound(AppError):
    status_code, code = 404, "not_found"


class Conflict(AppError):
    status_code, code = 409, "conflict"


class Gone(AppError):
    status_code, code = 410, "gone"


class LengthRequired(AppError):
    status_code, code = 411, "length_required"


class PayloadTooLarge(AppError):
    status_code, code = 413, "payload_too_large"


class UnsupportedMediaType(AppError):
    status_code, code = 415, "unsupported_media_type"


class Unprocessable(AppError):
    status_code, code = 422, "unprocessable"


class TooManyRequests(AppError):
    status_code, code = 429, "too_many_requests"


_DESCRIPTIONS = {
    400: "Bad request", 401: "Not authenticated", 403: "Not allowed", 404: "Not found",
    409: "Conflict", 410: "Gone", 411: "Length required", 413: "Payload too large", 415: "Unsupported media type",
    422: "Unprocessable", 429: "Too many requests",
}


def responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses=`` for the given error statuses, all with ``ErrorBody``."""
    return {s: {"model": ErrorBody, "description": _DESCRIPTIONS.get(s, "Error")} for s in statuses}


def _json(status: int, body: dict[str, Any], headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse(status_code=status, content=body, headers=headers)


_HTTP_CODES = {
    400: "bad_request", 401: "unauthorized", 403: "forbidden", 404: "not_found",
    405: "method_not_allowed", 406: "not_acceptable", 409: "conflict", 413: "payload_too_large",
    415: "unsupported_media_type", 422: "unprocessable", 429: "too_many_requests",
}


def _validation_detail(exc: RequestValidationError) -> tuple[str, list[dict[str, Any]]]:
    fields = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err.get("loc", ()))
        fields.append({"field": loc, "message": err.get("msg", "invalid")})
    text = "; ".join(f"{f['field']}: {f['message']}" for f in fields[:10]) or "invalid request"
    return text, fields


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(AppError)
    async def _app_error(_request: Request, exc: AppError) -> JSONResponse:
        return _json(exc.status_code, exc.body(), exc.headers)

    @app.exception_handler(RequestValidationError)
    async def _validation(_request: Request, exc: RequestValidationError) -> JSONResponse:
        text, fields = _validation_detail(exc)
        return _json(422, {"error": "validation_error", "detail": text, "fields": fields})

    @app.exception_handler(StarletteHTTPException)
    async def _http(_request: Request, exc: StarletteHTTPException) -> JSONResponse:
        code = _HTTP_CODES.get(exc.status_code, "http_error")
        detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
        if exc.status_code == 404 and detail == "Not Found":
            detail = "no such route"
        return _json(exc.status_code, {"error": code, "detail": detail}, getattr(exc, "headers", None))

    @app.exception_handler(PoolTimeout)
    async def _pool_exhausted(_request: Request, exc: Exception) -> JSONResponse:
        # Overload, not a bug: tell the client to come back rather than answer 500.
        log.warning("database connection pool exhausted: %s", str(exc).splitlines()[0][:200])
        return _json(503, {"error": "overloaded", "detail": "the server is busy; retry shortly"},
                     {"Retry-After": "2"})

    @app.exception_handler(OverflowError)
    @app.exception_handler(DataError)
    async def _out_of_range(_request: Request, exc: Exception) -> JSONResponse:
        # An id or number beyond what the database column stores names nothing that exists.
        log.info("database refused a value: %s", str(exc).splitlines()[0][:200])
        return _json(404, {"error": "not_found", "detail": "a number in the request is out of range"})

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return _json(500, {"error": "internal_error", "detail": "internal server error"})
