"""Request dependencies as ``Annotated`` aliases, so routes read like prose.

``SessionDep`` is the request's unit of work (committed when the route returns, rolled back
on error). The principal aliases (``AnyUser``, ``AdminUser``...) authenticate (session
cookie or bearer token), enforce CSRF rules for cookie sessions and check the role.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterator
from typing import Annotated, Any

import anyio
from urllib.parse import urlsplit

from fastapi import Depends, Request
from sqlalchemy.orm import Session

from posefix.config import Settings, origin_of
from posefix.db import Database
from posefix.errors import BadRequest, Forbidden, Unauthorized, Unprocessable, UnsupportedMediaType
from posefix.users.models import Role, TokenScope
from posefix.users.service import Principal, resolve_session, resolve_token

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_database(request: Request) -> Database:
    return request.app.state.db


def get_session(request: Request) -> Iterator[Session]:
    db: Database = request.app.state.db
    with db.transaction(write=request.method not in SAFE_METHODS) as session:
        yield session


def get_read_session(request: Request) -> Iterator[Session]:
    """A reading unit of work whatever the method (a POST that writes nothing, e.g. a preview)."""
    with request.app.state.db.transaction(write=False) as session:
        yield session


SettingsDep = Annotated[Settings, Depends(get_settings)]
DatabaseDep = Annotated[Database, Depends(get_database)]
# scope="function": commit before the response is sent, so a failed commit is an error response.
SessionDep = Annotated[Session, Depends(get_session, scope="function")]
ReadSessionDep = Annotated[Session, Depends(get_read_session, scope="function")]


def solver_limiter(app: Any) -> anyio.CapacityLimiter:
    """The lane for CPU-bound solves: at most one per CPU, apart from the request threads,
    so a crowd of dragging operators cannot occupy every thread keyframes and tiles need."""
    limiter = getattr(app.state, "solver_limiter", None)
    if limiter is None:
        limiter = app.state.solver_limiter = anyio.CapacityLimiter(max(os.cpu_count() or 1, 1))
    return limiter


def client_ip(request: Request) -> str:
    return request.client.host if request.client else "unknown"


def check_origin(request: Request, settings: Settings, *, required: bool) -> None:
    """CSRF: the browser's Origin (or Referer) must be ours."""
    origin = request.headers.get("origin")
    if origin is None:
        referer = request.headers.get("referer")
        if referer:
            parts = urlsplit(referer)
            origin = f"{parts.scheme}://{parts.netloc}"
    if origin is None:
        if required:
            raise Forbidden("missing Origin header on a cookie-authenticated request", code="csrf_failed")
        return
    allowed = settings.csrf_origins
    if not allowed:
        raise Forbidden("no origin is configured for browser sessions: set POSEFIX_PUBLIC_URL or "
                        "POSEFIX_ALLOWED_ORIGINS", code="csrf_failed")
    if origin_of(origin) not in allowed:
        raise Forbidden(f"cross-site request from origin {origin!r} refused", code="csrf_failed")


def check_json_body(request: Request) -> None:
    has_body = request.headers.get("content-length", "0") not in ("", "0") or "transfer-encoding" in request.headers
    if not has_body:
        return
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != "application/json":
        raise UnsupportedMediaType(
            f"request bodies must be application/json (got {ctype or 'none'})", code="json_required"
        )


def authenticate(request: Request, session: Session, settings: Settings, *, allow_multipart: bool,
                 read_only: bool = False) -> Principal:
    db: Database = request.app.state.db
    write_session = session if request.method not in SAFE_METHODS and not read_only else None
    auth = request.headers.get("authorization")
    if auth:
        scheme, _, value = auth.partition(" ")
        if scheme.lower() != "bearer" or not value.strip():
            raise Unauthorized("Authorization must be 'Bearer <token>'", code="invalid_token")
        principal = resolve_token(db, session, settings, value.strip(), write_session)
        if request.method not in SAFE_METHODS and principal.scope != TokenScope.write:
            raise Forbidden("this API token is read-only", code="insufficient_scope")
        return principal
    sid = request.cookies.get(settings.session_cookie_name)
    if not sid:
        raise Unauthorized("not logged in", code="not_authenticated")
    principal = resolve_session(db, session, settings, sid, write_session)
    if request.method not in SAFE_METHODS:
        check_origin(request, settings, required=True)
        if not allow_multipart:
            check_json_body(request)
    return principal


def require(*roles: Role, allow_multipart: bool = False, read_only: bool = False) -> Callable[..., Principal]:
    """``read_only``: the route writes nothing (its session is a reading one even on POST, so on
    SQLite it does not take the database's one write lock; the session touch is its own)."""
    allowed = frozenset(roles)

    def check(request: Request, session: Session, settings: Settings) -> Principal:
        principal = authenticate(request, session, settings, allow_multipart=allow_multipart, read_only=read_only)
        if principal.role not in allowed:
            raise Forbidden(
                f"role {principal.role.value} may not do this (needs {', '.join(sorted(r.value for r in allowed))})",
                code="role_forbidden",
            )
        request.state.user_id = principal.user_id
        return principal

    def dependency(request: Request, session: SessionDep, settings: SettingsDep) -> Principal:
        return check(request, session, settings)

    def reading_dependency(request: Request, session: ReadSessionDep, settings: SettingsDep) -> Principal:
        principal = check(request, session, settings)
        session.commit()  # end the read: no connection held while the route waits (e.g. for a solver)
        return principal

    return reading_dependency if read_only else dependency


ALL_ROLES = tuple(Role)
AnyUser = Annotated[Principal, Depends(require(*ALL_ROLES))]
AdminUser = Annotated[Principal, Depends(require(Role.admin))]
ReviewerUser = Annotated[Principal, Depends(require(Role.admin, Role.reviewer))]
EditorUser = Annotated[Principal, Depends(require(Role.admin, Role.reviewer, Role.operator))]
EditorReader = Annotated[Principal, Depends(require(Role.admin, Role.reviewer, Role.operator, read_only=True))]
UploaderUser = Annotated[Principal, Depends(require(Role.admin, Role.client, allow_multipart=True))]
OwnerUser = Annotated[Principal, Depends(require(Role.admin, Role.client))]


def form_text(form: Any, key: str) -> str | None:
    """A multipart form's text field ``key`` (None when absent); a file there is a 400."""
    v = form.get(key)
    if v is None:
        return None
    if not isinstance(v, str):
        raise BadRequest(f"form field {key!r} must be text", code="bad_form", extra={"field": key})
    if "\x00" in v:
        raise nul_refused(f"form.{key}")
    return v


def nul_refused(field: str) -> Unprocessable:
    message = "must not contain the NUL character (\\u0000)"
    return Unprocessable(f"{field}: {message}", code="validation_error",
                         extra={"fields": [{"field": field, "message": message}]})


def _nul_path(value: Any, path: str) -> str | None:
    """Where in a decoded JSON value a string (or key) holds NUL, as ``a.b.0``; None if nowhere."""
    if isinstance(value, str):
        return path if "\x00" in value else None
    if isinstance(value, dict):
        for key, item in value.items():
            found = _nul_path(str(key), f"{path}.{key}") or _nul_path(item, f"{path}.{key}")
            if found:
                return found
    if isinstance(value, list):
        for i, item in enumerate(value):
            found = _nul_path(item, f"{path}.{i}")
            if found:
                return found
    return None


async def refuse_nul(request: Request) -> None:
    """No text in a path, query or JSON body may hold NUL: PostgreSQL cannot store it (SQLite
    would), so refuse it the same way on both, naming the field, before any route runs."""
    for name, value in request.path_params.items():
        if isinstance(value, str) and "\x00" in value:
            raise nul_refused(f"path.{name}")
    for name, value in request.query_params.multi_items():
        if "\x00" in name or "\x00" in value:
            raise nul_refused(f"query.{name.replace(chr(0), '?')}")
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype == "application/json":
        body = await request.body()
        if b"\\u0000" in body:  # JSON can carry NUL only as this escape
            try:
                found = _nul_path(json.loads(body), "body")
            except ValueError:
                return  # not JSON: the route's own validation says so
            if found:
                raise nul_refused(found)
