"""Every query on accounts."""

from __future__ import annotations

import datetime as dt

from sqlalchemy import func, select, update
from sqlalchemy.orm import Session

from posefix.db import utcnow
from posefix.users.models import ApiToken, AuthSession, LoginFailure, User


def get_user(session: Session, user_id: int) -> User | None:
    return session.get(User, user_id)


def get_user_by_username(session: Session, username: str) -> User | None:
    return session.scalars(select(User).where(User.username == username)).one_or_none()


def list_users(session: Session, limit: int, offset: int) -> tuple[list[User], int]:
    total = session.scalar(select(func.count()).select_from(User)) or 0
    rows = session.scalars(select(User).order_by(User.id).limit(limit).offset(offset)).all()
    return list(rows), total


def add(session: Session, obj: object) -> None:
    session.add(obj)
    session.flush()


def get_session_by_hash(session: Session, id_hash: str) -> AuthSession | None:
    return session.get(AuthSession, id_hash)


def touch_session(session: Session, id_hash: str, now: dt.datetime) -> None:
    session.execute(update(AuthSession).where(AuthSession.id_hash == id_hash).values(last_seen_at=now))


def revoke_session(session: Session, id_hash: str) -> None:
    session.execute(
        update(AuthSession)
        .where(AuthSession.id_hash == id_hash, AuthSession.revoked_at.is_(None))
        .values(revoked_at=utcnow())
    )


def revoke_user_sessions(session: Session, user_id: int) -> None:
    session.execute(
        update(AuthSession)
        .where(AuthSession.user_id == user_id, AuthSession.revoked_at.is_(None))
        .values(revoked_at=utcnow())
    )


def get_token_by_hash(session: Session, token_hash: str) -> ApiToken | None:
    return session.scalars(select(ApiToken).where(ApiToken.token_hash == token_hash)).one_or_none()


def list_tokens(session: Session, user_id: int) -> list[ApiToken]:
    return list(session.scalars(select(ApiToken).where(ApiToken.user_id == user_id).order_by(ApiToken.id)))


def get_token(session: Session, token_id: int) -> ApiToken | None:
    return session.get(ApiToken, token_id)


def touch_token(session: Session, token_id: int, now: dt.datetime) -> None:
    session.execute(update(ApiToken).where(ApiToken.id == token_id).values(last_used_at=now))


def failures_since(session: Session, since: dt.datetime, *, client_ip: str,
                   username: str | None = None) -> tuple[int, dt.datetime | None]:
    """Failed logins from this address (for this username, when given) since ``since``:
    how many, and when the latest was."""
    where = [LoginFailure.client_ip == client_ip, LoginFailure.at >= since]
    if username is not None:
        where.append(LoginFailure.username == username)
    n, latest = session.execute(select(func.count(), func.max(LoginFailure.at)).where(*where)).one()
    if latest is not None and latest.tzinfo is None:
        latest = latest.replace(tzinfo=dt.UTC)
    return int(n), latest


def add_failure(session: Session, username: str, client_ip: str) -> None:
    session.add(LoginFailure(username=username[:64], client_ip=client_ip[:64], at=utcnow()))


def clear_failures(session: Session, username: str, client_ip: str) -> None:
    session.query(LoginFailure).filter(LoginFailure.username == username, LoginFailure.client_ip == client_ip).delete()
