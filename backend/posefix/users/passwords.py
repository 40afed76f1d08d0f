"""Password policy after NIST SP 800-63B (section 3.1.1.2, "Password Verifiers").

- Length is what counts: at least 8 characters (Unicode code points), 12 for admins, whose
  accounts reach every run and user; at most 1024 (the hash input stays bounded). No rules
  about character classes and no expiry, which the guideline advises against.
- Refuse passwords known to be common or breached: the 30,000 most frequent passwords of
  public breach corpora, as shipped in the ``zxcvbn`` package's frequency lists (MIT
  licence, Dropbox), compared without regard to case.
- Refuse context-specific words: the username and its simple variants (case, reversed,
  digits or punctuation around it, look-alike digits such as ``adm1n``).
"""

from __future__ import annotations

import functools
import re

from posefix.users.models import Role

__all__ = ["MIN_LENGTH", "ADMIN_MIN_LENGTH", "MAX_LENGTH", "password_problem"]

MIN_LENGTH = 8
ADMIN_MIN_LENGTH = 12
MAX_LENGTH = 1024

_LOOK_ALIKES = str.maketrans({"0": "o", "1": "i", "3": "e", "4": "a", "5": "s", "7": "t", "@": "a", "$": "s", "!": "i"})


@functools.cache
def common_passwords() -> frozenset[str]:
    """Lower-cased common and breached passwords long enough to pass the length rule."""
    from zxcvbn.frequency_lists import FREQUENCY_LISTS

    return frozenset(p.lower() for p in FREQUENCY_LISTS["passwords"] if len(p) >= MIN_LENGTH)


def _letters(text: str) -> str:
    """Letters only, look-alike digits and symbols read as the letters they stand for."""
    return re.sub(r"[^a-z]", "", text.lower().translate(_LOOK_ALIKES))


def _is_username_variant(password: str, username: str) -> bool:
    raw = username.lower()
    lowered = password.lower()
    for form in (raw, raw[::-1]):  # the name with only digits or punctuation around it
        if form and form in lowered and re.fullmatch(r"[\W\d_]*", lowered.replace(form, "", 1)):
            return True
    name = _letters(username)
    if not name:
        return False
    stripped = re.sub(r"^[\W\d_]+|[\W\d_]+$", "", lowered)
    return any(_letters(c) in (name, name[::-1], name * 2) for c in (lowered, stripped))


def password_problem(password: str, username: str, role: Role) -> str | None:
    """Why ``password`` is refused for this account, or None when it is acceptable."""
    minimum = ADMIN_MIN_LENGTH if role == Role.admin else MIN_LENGTH
    if len(password) < minimum:
        who = "an admin's password" if role == Role.admin else "a password"
        return f"{who} needs at least {minimum} characters"
    if len(password) > MAX_LENGTH:
        return f"a password may have at most {MAX_LENGTH} characters"
    if password.lower() in common_passwords():
        return "this password is on a list of common or breached passwords; choose another"
    if _is_username_variant(password, username):
        return "a password must not be the username or a simple variant of it"
    return None
