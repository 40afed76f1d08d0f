"""Login throttling per account and address with growing delays (shared by API processes
through the database), and the password policy after NIST SP 800-63B; SQLite and PostgreSQL."""

from __future__ import annotations

import time
from typing import Any

import pytest
from fastapi.testclient import TestClient

from posefix.users.models import Role
from posefix.users.passwords import common_passwords, password_problem
from posefix.users.throttle import delay_s
from tests.conftest import ORIGIN, PASSWORD, add_user, login


def _client(app: Any, address: str) -> TestClient:
    return TestClient(app, headers={"Origin": ORIGIN}, client=(address, 40000))


def _attempt(c: TestClient, password: str, username: str = "ann") -> Any:
    return c.post("/api/v1/auth/login", json={"username": username, "password": password})


@pytest.fixture
def throttled_app(settings: Any) -> Any:
    """Two free failures, then 2 s, 4 s, 8 s... (a short base keeps the test fast)."""
    from posefix.main import create_app

    settings.login_max_failures = 2
    settings.login_delay_base_s = 2.0
    app = create_app(settings)
    add_user(app, "ann", "operator")
    yield app
    app.state.db.dispose()


class TestThrottling:
    def test_delays_grow_per_account_and_address(self, throttled_app: Any) -> None:
        attacker = _client(throttled_app, "203.0.113.7")
        assert [_attempt(attacker, "guess").status_code for _ in range(2)] == [401, 401]
        r = _attempt(attacker, "guess")
        assert r.status_code == 429 and r.json()["error"] == "login_throttled"
        assert r.headers["Retry-After"] == "2"
        assert _attempt(attacker, PASSWORD).status_code == 429  # even the right password waits
        time.sleep(2.1)
        assert _attempt(attacker, "guess").status_code == 401  # the wait is over: one more try...
        r = _attempt(attacker, "guess")
        assert r.status_code == 429 and r.headers["Retry-After"] == "4"  # ...and the next wait doubles

    def test_the_account_stays_reachable_from_another_address(self, throttled_app: Any) -> None:
        attacker = _client(throttled_app, "203.0.113.7")
        for _ in range(6):
            _attempt(attacker, "guess")
        assert _attempt(attacker, PASSWORD).status_code == 429
        owner = _client(throttled_app, "198.51.100.20")
        assert _attempt(owner, PASSWORD).status_code == 200
        # and the owner's success does not reset the attacker's delay
        assert _attempt(attacker, "guess").status_code == 429

    def test_one_address_spraying_many_accounts_is_slowed(self, throttled_app: Any) -> None:
        sprayer = _client(throttled_app, "203.0.113.9")
        codes = [_attempt(sprayer, "Summer2024!", username=f"user{i}").status_code for i in range(9)]
        assert codes == [401] * 8 + [429]  # four times the per-account allowance
        assert _attempt(_client(throttled_app, "198.51.100.20"), PASSWORD).status_code == 200

    def test_the_429_holds_across_processes(self, throttled_app: Any, settings: Any) -> None:
        from posefix.main import create_app

        other = create_app(settings)  # another API process: its own engine and memory, the same database
        try:
            first, second = _client(throttled_app, "203.0.113.7"), _client(other, "203.0.113.7")
            assert _attempt(first, "guess").status_code == 401
            assert _attempt(second, "guess").status_code == 401
            assert _attempt(first, "guess").status_code == 429
            assert _attempt(second, PASSWORD).status_code == 429
        finally:
            other.state.db.dispose()

    def test_delay_schedule(self) -> None:
        assert [delay_s(n, 5, 1.0, 900.0) for n in (0, 4, 5, 6, 7, 14, 15, 100)] == [0, 0, 1, 2, 4, 512, 900, 900]


class TestPasswordPolicy:
    @pytest.mark.parametrize("password,role,fragment", [
        ("short7!", Role.operator, "at least 8"),
        ("elevenchars", Role.admin, "at least 12"),
        ("iloveyou2", Role.operator, "common or breached"),
        ("PASSWORD123", Role.operator, "common or breached"),
        ("Password1234", Role.admin, "common or breached"),
        ("marianne", Role.operator, "username"),
        ("MARIANNE2024!", Role.operator, "username"),
        ("ennairam!", Role.operator, "username"),
        ("m4r14nne#1", Role.operator, "username"),
        ("mariannemarianne", Role.admin, "username"),
        ("x" * 1025, Role.operator, "at most 1024"),
    ])
    def test_refused(self, password: str, role: Role, fragment: str) -> None:
        problem = password_problem(password, "marianne", role)
        assert problem is not None and fragment in problem

    @pytest.mark.parametrize("password,role", [
        ("correct horse battery", Role.operator), ("marianne likes maps", Role.operator),
        ("twelve chars", Role.admin), ("posefix-admin", Role.admin), ("posefix-operator1", Role.operator),
        ("ünïcödé-pässwörd", Role.operator),
    ])
    def test_accepted(self, password: str, role: Role) -> None:
        assert password_problem(password, "marianne", role) is None

    def test_the_list_is_the_breach_corpus_not_a_handful(self) -> None:
        assert len(common_passwords()) > 10_000 and "password1" in common_passwords()

    def test_the_api_refuses_with_422_naming_the_rule(self, app: Any) -> None:
        add_user(app, "root", "admin")
        admin = login(app, "root")
        r = admin.post("/api/v1/users", json={"username": "kartta", "password": "Kartta-2024", "role": "operator"})
        assert r.status_code == 422 and r.json()["error"] == "weak_password" and "username" in r.json()["detail"]
        r = admin.post("/api/v1/users", json={"username": "eve", "password": "a-fine-pass", "role": "admin"})
        assert r.status_code == 422 and "at least 12" in r.json()["detail"]
        assert admin.get("/api/v1/users").json()["total"] == 1  # nothing was created
        r = admin.post("/api/v1/users", json={"username": "bob", "password": "maps of helsinki", "role": "operator"})
        assert r.status_code == 201
        uid = r.json()["id"]
        r = admin.patch(f"/api/v1/users/{uid}", json={"password": "football1"})
        assert r.status_code == 422 and "common" in r.json()["detail"]
        r = admin.patch(f"/api/v1/users/{uid}", json={"role": "admin", "password": "shortish-pw"})
        assert r.status_code == 422 and "at least 12" in r.json()["detail"]
        assert admin.get(f"/api/v1/users/{uid}").json()["role"] == "operator"  # unchanged
