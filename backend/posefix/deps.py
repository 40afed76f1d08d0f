"""Request dependencies as ``Annotated`` aliases, so routes read like prose.

``SessionDep`` is the request's unit of work (committed when the route returns, rolled back
on error). The principal aliases (``AnyUser``, ``AdminUser``...) authenticate (session
cookie or bearer token), enforce CSRF rules for cookie sessions and check the role.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from typing import Annotated, Any

import anyio
from urllib.parse import urlsplit

from fastapi import Depends, Request
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.db import Database
from posefix.errors import BadRequest, Forbidden, Unauthorized, UnsupportedMediaType
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


def expected_origins(request: Request, settings: Settings) -> set[str]:
    if settings.allowed_origins:
        return {o.rstrip("/") for o in settings.allowed_origins}
    host = request.headers.get("host", "")
    return {f"{request.url.scheme}://{host}", f"http://{host}", f"https://{host}"}


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
    if origin.rstrip("/") not in expected_origins(request, settings):
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
    return v
