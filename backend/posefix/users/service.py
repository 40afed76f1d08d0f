"""Account rules: login with throttling, sessions with idle and absolute timeouts, tokens."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.db import Database, utcnow
from posefix.errors import Conflict, Forbidden, NotFound, Unauthorized, Unprocessable
from posefix.security import hash_password, hash_secret, new_api_token, new_session_id, verify_password
from posefix.users import repository as repo
from posefix.users.passwords import password_problem
from posefix.users.throttle import check_throttle
from posefix.users.models import ApiToken, AuthSession, Role, TokenScope, User

# Update a session's last-seen time at most this often (seconds), to spare writes.
TOUCH_EVERY_S = 60


@dataclass(frozen=True)
class Principal:
    """Who is calling and how: ``via`` is "session" or "token"; ``scope`` read or write."""

    user_id: int
    username: str
    role: Role
    via: str
    scope: TokenScope
    credential_hash: str

    def has_role(self, *roles: Role) -> bool:
        return self.role in roles


def check_password(password: str, username: str, role: Role) -> None:
    """Refuse a password the policy (``posefix.users.passwords``) does not accept, with 422."""
    problem = password_problem(password, username, role)
    if problem is not None:
        raise Unprocessable(problem, code="weak_password", extra={"field": "password"})


def create_user(session: Session, username: str, password: str, role: Role) -> User:
    check_password(password, username, role)
    if repo.get_user_by_username(session, username) is not None:
        raise Conflict(f"user {username!r} already exists", code="user_exists")
    user = User(username=username, password_hash=hash_password(password), role=role.value, disabled=False)
    try:
        with session.begin_nested():
            repo.add(session, user)
    except IntegrityError:
        raise Conflict(f"user {username!r} already exists", code="user_exists") from None
    return user


def update_user(
    session: Session, actor: Principal, user_id: int, *, role: Role | None, disabled: bool | None,
    password: str | None,
) -> User:
    user = repo.get_user(session, user_id)
    if user is None:
        raise NotFound(f"user {user_id} not found")
    if user.id == actor.user_id and (disabled or (role is not None and role != Role.admin)):
        raise Conflict("admins cannot disable or demote themselves", code="self_demotion")
    if password is not None:
        check_password(password, user.username, role or Role(user.role))
    if role is not None:
        user.role = role.value
    if password is not None:
        user.password_hash = hash_password(password)
        repo.revoke_user_sessions(session, user.id)
    if disabled is not None:
        user.disabled = disabled
        if disabled:
            repo.revoke_user_sessions(session, user.id)
    session.flush()
    return user


def login(
    db: Database, settings: Settings, username: str, password: str, client_ip: str, user_agent: str | None,
) -> tuple[User, str]:
    """Check the password; return the user and a new session id (the cookie value).

    Runs its own transaction so a failure is recorded even though the request answers 401.
    """
    check_throttle(db, settings, username, client_ip)
    with db.transaction() as session:
        user = repo.get_user_by_username(session, username)
        ok = verify_password(password, user.password_hash if user else None)
        if not ok or user is None or user.disabled:
            repo.add_failure(session, username, client_ip)
            user = None
        else:
            sid = new_session_id()
            now = utcnow()
            repo.add(
                session,
                AuthSession(
                    id_hash=hash_secret(sid, settings.secret_key), user_id=user.id, created_at=now,
                    last_seen_at=now, expires_at=now + dt.timedelta(seconds=settings.session_absolute_timeout_s),
                    client_ip=client_ip[:64], user_agent=(user_agent or "")[:255],
                ),
            )
            repo.clear_failures(session, username, client_ip[:64])
    if user is None:
        raise Unauthorized("wrong username or password", code="invalid_credentials")
    return user, sid


def _touch(db: Database, write_session: Session | None, fn: Any) -> None:
    # In a writing request the request's own transaction holds SQLite's write lock, so the
    # touch must go through it; a reading request touches in a short transaction of its own.
    if write_session is not None:
        fn(write_session)
    else:
        with db.transaction() as s:
            fn(s)


def resolve_session(db: Database, session: Session, settings: Settings, sid: str, write_session: Session | None = None) -> Principal:
    id_hash = hash_secret(sid, settings.secret_key)
    auth = repo.get_session_by_hash(session, id_hash)
    now = utcnow()
    if auth is None or auth.revoked_at is not None:
        raise Unauthorized("not logged in", code="not_authenticated")
    if now >= auth.expires_at:
        raise Unauthorized("session expired", code="session_expired")
    if now - auth.last_seen_at > dt.timedelta(seconds=settings.session_idle_timeout_s):
        raise Unauthorized("session expired after inactivity", code="session_expired")
    user = repo.get_user(session, auth.user_id)
    if user is None or user.disabled:
        raise Unauthorized("account disabled", code="account_disabled")
    if (now - auth.last_seen_at).total_seconds() > TOUCH_EVERY_S:
        _touch(db, write_session, lambda s: repo.touch_session(s, id_hash, now))
    return Principal(user.id, user.username, Role(user.role), "session", TokenScope.write, id_hash)


def resolve_token(db: Database, session: Session, settings: Settings, token: str, write_session: Session | None = None) -> Principal:
    token_hash = hash_secret(token, settings.secret_key)
    row = repo.get_token_by_hash(session, token_hash)
    if row is None or row.revoked_at is not None:
        raise Unauthorized("invalid or revoked API token", code="invalid_token")
    user = repo.get_user(session, row.user_id)
    if user is None or user.disabled:
        raise Unauthorized("account disabled", code="account_disabled")
    now = utcnow()
    if row.last_used_at is None or (now - row.last_used_at).total_seconds() > TOUCH_EVERY_S:
        _touch(db, write_session, lambda s: repo.touch_token(s, row.id, now))
    return Principal(user.id, user.username, Role(user.role), "token", TokenScope(row.scope), token_hash)


def logout(session: Session, principal: Principal) -> None:
    if principal.via == "session":
        repo.revoke_session(session, principal.credential_hash)


def create_token(session: Session, settings: Settings, principal: Principal, name: str, scope: TokenScope) -> tuple[ApiToken, str]:
    # Only a login session makes tokens: a leaked token cannot mint longer-lived copies of itself
    # that survive its revocation.
    if principal.via != "session":
        raise Forbidden("API tokens are made from a login session, not with another token", code="session_required")
    secret = new_api_token()
    row = ApiToken(user_id=principal.user_id, name=name, token_hash=hash_secret(secret, settings.secret_key), scope=scope.value)
    repo.add(session, row)
    return row, secret


def revoke_token(session: Session, principal: Principal, token_id: int) -> None:
    row = repo.get_token(session, token_id)
    if row is None or (row.user_id != principal.user_id and principal.role != Role.admin):
        raise NotFound(f"token {token_id} not found")
    if row.revoked_at is None:
        row.revoked_at = utcnow()
