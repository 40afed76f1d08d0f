"""Secrets: password hashing (argon2id via pwdlib), session ids and API tokens.

Session ids and API tokens are 256-bit random strings; only their keyed hash
(HMAC-SHA256 with the server secret) is stored, so a database leak reveals no usable
credential. Passwords use argon2id with pwdlib's recommended parameters.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets

from pwdlib import PasswordHash
from pwdlib.hashers.argon2 import Argon2Hasher

__all__ = [
    "hash_password", "verify_password", "new_session_id", "new_api_token", "hash_secret",
    "TOKEN_PREFIX",
]

_hasher = PasswordHash((Argon2Hasher(),))
# A valid hash to verify against when the user does not exist (constant-ish timing).
_DUMMY_HASH = _hasher.hash("posefix-dummy-password")
TOKEN_PREFIX = "pfx_"


def hash_password(password: str) -> str:
    return _hasher.hash(password)


def verify_password(password: str, password_hash: str | None) -> bool:
    if password_hash is None:
        _hasher.verify(password, _DUMMY_HASH)
        return False
    try:
        return _hasher.verify(password, password_hash)
    except Exception:
        return False


def new_session_id() -> str:
    return secrets.token_urlsafe(32)


def new_api_token() -> str:
    return TOKEN_PREFIX + secrets.token_urlsafe(32)


def hash_secret(value: str, key: str) -> str:
    """Keyed hash of a session id or token, hex (64 chars)."""
    return hmac.new(key.encode(), value.encode(), hashlib.sha256).hexdigest()
