"""Property-based fuzzing of every documented operation: no input may cause a 5xx.

Schemathesis generates requests from the OpenAPI spec (valid and invalid ones) and calls
the app in-process with an admin's write token, on SQLite and on PostgreSQL. Bounded:
a few examples per operation keep the whole run near a minute.
"""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, settings as hsettings
from schemathesis.checks import not_a_server_error

from posefix.config import Settings
from posefix.main import create_app
from tests.conftest import drive_csv, upload

EXCLUDED_PATHS = [
    "/api/v1/events",  # a stream open for up to max_s seconds: tested in test_concurrency
]

# The spec does not depend on the database; each test points this app at its own database.
FUZZ_APP = create_app(Settings(environment="test", database_url="sqlite://", log_level="ERROR"))
# Examples and fuzzing phases only: the coverage phase multiplies the cases tenfold.
CONFIG = schemathesis.Config.from_dict({"phases": {"coverage": {"enabled": False}, "stateful": {"enabled": False}}})
schema = (
    schemathesis.openapi.from_asgi("/openapi.json", FUZZ_APP, config=CONFIG)
    .exclude(path=EXCLUDED_PATHS)
    .exclude(method="DELETE", path_regex=r"^/api/v1/tokens/")
)


@pytest.fixture(scope="module")
def fuzz_headers(db_url, tmp_path_factory):
    """One database state for the whole module: the fuzzer only looks for 5xx, not for exact results."""
    from fastapi.testclient import TestClient

    from tests.conftest import _empty_tables, add_user, direct_token

    _empty_tables(db_url)
    settings = Settings(environment="test", database_url=db_url, data_dir=tmp_path_factory.mktemp("fuzz") / "var",
                        log_level="ERROR")
    app = create_app(settings)
    admin = direct_token(app, add_user(app, "admin", "admin"))
    owner = direct_token(app, add_user(app, "client", "client"))
    with TestClient(app) as client:
        upload(client, owner, drive_csv(120))  # a run exists, so small ids hit real rows
    FUZZ_APP.state.settings = settings
    FUZZ_APP.state.db = app.state.db
    yield admin
    _empty_tables(db_url)


@pytest.mark.parametrize("db_backend", ["fuzz"])
@schema.parametrize()
@hsettings(max_examples=10, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
def test_no_server_errors(case, fuzz_headers, db_backend):
    headers = {**(case.headers or {}), **fuzz_headers}
    case.call_and_validate(headers=headers, checks=[not_a_server_error])
