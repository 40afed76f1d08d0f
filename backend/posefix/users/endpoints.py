"""Routes: /auth (login, logout, me), /tokens, /users (admin)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request, Response, status

from posefix.deps import AdminUser, AnyUser, DatabaseDep, SessionDep, SettingsDep, check_origin, client_ip
from posefix.errors import NotFound, responses
from posefix.users import repository as repo
from posefix.users import service
from posefix.users.schemas import (
    LoginRequest, TokenCreate, TokenCreated, TokenList, TokenPublic, UserAdminView, UserCreate,
    UserList, UserPublic, UserUpdate,
)

router = APIRouter()


@router.post("/auth/login", response_model=UserPublic, tags=["auth"], responses=responses(401, 403, 429))
def login(body: LoginRequest, request: Request, response: Response, db: DatabaseDep, settings: SettingsDep) -> UserPublic:
    """Log in with a password; sets an HttpOnly session cookie."""
    check_origin(request, settings, required=False)
    user, sid = service.login(
        db, settings, body.username, body.password, client_ip(request), request.headers.get("user-agent")
    )
    response.set_cookie(
        settings.session_cookie_name, sid, max_age=settings.session_absolute_timeout_s, httponly=True,
        secure=request.url.scheme == "https", samesite="lax", path="/",
    )
    return UserPublic.model_validate(user)


@router.post("/auth/logout", status_code=status.HTTP_204_NO_CONTENT, tags=["auth"], responses=responses(401, 403))
def logout(principal: AnyUser, session: SessionDep, response: Response, settings: SettingsDep) -> Response:
    """End the current session (the cookie stops working at once)."""
    service.logout(session, principal)
    response.status_code = status.HTTP_204_NO_CONTENT
    response.delete_cookie(settings.session_cookie_name, path="/")
    return response


@router.get("/auth/me", response_model=UserPublic, tags=["auth"], responses=responses(401))
def me(principal: AnyUser) -> UserPublic:
    return UserPublic(id=principal.user_id, username=principal.username, role=principal.role)


@router.post("/tokens", response_model=TokenCreated, status_code=201, tags=["tokens"], responses=responses(401, 403))
def create_token(body: TokenCreate, principal: AnyUser, session: SessionDep, settings: SettingsDep) -> TokenCreated:
    """Create a personal API token (from a login session only: 403 ``session_required`` with a
    bearer token); the secret is returned once and stored only hashed."""
    row, secret = service.create_token(session, settings, principal, body.name, body.scope)
    return TokenCreated(id=row.id, name=row.name, scope=body.scope, token=secret)


@router.get("/tokens", response_model=TokenList, tags=["tokens"], responses=responses(401))
def list_tokens(principal: AnyUser, session: SessionDep) -> TokenList:
    return TokenList(items=[TokenPublic.model_validate(t) for t in repo.list_tokens(session, principal.user_id)])


@router.delete("/tokens/{token_id}", status_code=204, tags=["tokens"], responses=responses(401, 403, 404))
def revoke_token(token_id: int, principal: AnyUser, session: SessionDep) -> Response:
    service.revoke_token(session, principal, token_id)
    return Response(status_code=204)


@router.get("/users", response_model=UserList, tags=["users"], responses=responses(401, 403))
def list_users(
    _admin: AdminUser, session: SessionDep,
    limit: Annotated[int, Query(ge=1, le=500)] = 100, offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
) -> UserList:
    rows, total = repo.list_users(session, limit, offset)
    return UserList(items=[UserAdminView.model_validate(u) for u in rows], total=total)


@router.post("/users", response_model=UserAdminView, status_code=201, tags=["users"], responses=responses(401, 403, 409))
def create_user(body: UserCreate, _admin: AdminUser, session: SessionDep) -> UserAdminView:
    return UserAdminView.model_validate(service.create_user(session, body.username, body.password, body.role))


@router.get("/users/{user_id}", response_model=UserAdminView, tags=["users"], responses=responses(401, 403, 404))
def get_user(user_id: int, _admin: AdminUser, session: SessionDep) -> UserAdminView:
    user = repo.get_user(session, user_id)
    if user is None:
        raise NotFound(f"user {user_id} not found")
    return UserAdminView.model_validate(user)


@router.patch("/users/{user_id}", response_model=UserAdminView, tags=["users"], responses=responses(401, 403, 404, 409))
def update_user(user_id: int, body: UserUpdate, admin: AdminUser, session: SessionDep) -> UserAdminView:
    """Change a user's role, password or disabled flag; disabling ends their sessions."""
    user = service.update_user(
        session, admin, user_id, role=body.role, disabled=body.disabled, password=body.password
    )
    return UserAdminView.model_validate(user)
