"""Property-based fuzzing of every documented operation: no input may cause a 5xx.

Schemathesis generates requests from the OpenAPI spec (valid and invalid ones) and calls
the app in-process with an admin's write token, on SQLite and on PostgreSQL. Bounded:
a few examples per operation keep the whole run near a minute.

The database holds one of everything an id can name (a run with images and a revision, its
jobs and edit batch, a tile source, a task with an assignment, users, a token), and every
other case has its ids replaced by those, so the fuzzer reaches past the 404 into the
routes' own work; the other half keeps the generated ids (invalid and out-of-range ones).
Deleting operations keep their generated ids, so the seeded rows survive the run.
"""

from __future__ import annotations

import itertools
import shutil
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings as hsettings
from schemathesis.checks import not_a_server_error

from posefix.config import Settings
from posefix.main import create_app
from tests.conftest import drive_csv, upload

EXCLUDED_PATHS = [
    "/api/v1/events",  # a stream open for up to max_s seconds: tested in test_concurrency
    "/api/v1/tasks/{task_id}/events",  # the same for a task (the seeded one stays open)
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


TONER = Path(__file__).resolve().parents[2] / "data" / "tiles" / "world-toner-z3.pmtiles"


def _seed(app, admin: dict[str, str], owner: dict[str, str], operator: dict[str, str]) -> dict[str, object]:
    """One row of each kind an id can name; returns the values to put in path and query parameters."""
    from fastapi.testclient import TestClient

    from tests.api.tasks_support import task_body
    from tests.conftest import wait_job

    settings = app.state.settings
    (settings.data_dir / "tiles").mkdir(parents=True, exist_ok=True)
    shutil.copy(TONER, settings.data_dir / "tiles" / "toner.pmtiles")
    with TestClient(app) as c:
        run = upload(c, owner, drive_csv(120, images_every=20), images=[(f"img{i:05d}.jpg", _jpeg()) for i in range(0, 120, 20)])
        assert run.status_code == 201, run.text
        run_id = run.json()["id"]
        image_id = c.get(f"/api/v1/runs/{run_id}/images", headers=admin).json()["items"][0]["id"]
        edit = c.post(f"/api/v1/runs/{run_id}/edits", json={"base_revision": 0, "deleted": [3]}, headers=admin)
        assert edit.status_code == 202, edit.text
        assert wait_job(app, edit.json()["job_id"])["status"] == "succeeded"
        tiles = c.post("/api/v1/tile-sources", json={"name": "toner", "kind": "topo", "path": "tiles/toner.pmtiles"},
                       headers=admin)
        assert tiles.status_code == 201, tiles.text
        task = c.post("/api/v1/tasks", json=task_body([run_id]), headers=admin)
        assert task.status_code == 201, task.text
        assignment = c.post("/api/v1/tasks/next", headers=operator).json()["assignment"]
        assert assignment is not None
        token_id = c.get("/api/v1/tokens", headers=admin).json()["items"][0]["id"]
        operator_id = c.get("/api/v1/auth/me", headers=operator).json()["id"]
    return {
        "run_id": run_id, "image_id": image_id, "job_id": edit.json()["job_id"], "batch_id": edit.json()["batch_id"],
        "number": 1, "revision": 1, "from": 0, "to": 1, "ref": "toner", "source": "toner", "z": 1, "x": 1, "y": 0,
        "ext": "png", "task_id": task.json()["id"], "task_run_id": task.json()["runs"][0]["id"],
        "assignment_id": assignment["id"], "user_id": operator_id, "token_id": token_id,
    }


def _jpeg() -> bytes:
    import io

    from PIL import Image

    out = io.BytesIO()
    Image.new("RGB", (32, 24), (90, 120, 150)).save(out, "JPEG")
    return out.getvalue()


@pytest.fixture(scope="module")
def fuzz_state(db_url, tmp_path_factory):
    """One database state for the whole module: the fuzzer only looks for 5xx, not for exact results."""
    from tests.conftest import _empty_tables, add_user, direct_token

    _empty_tables(db_url)
    settings = Settings(environment="test", database_url=db_url, data_dir=tmp_path_factory.mktemp("fuzz") / "var",
                        log_level="ERROR", job_backoff_base_s=0.05)
    app = create_app(settings)
    admin = direct_token(app, add_user(app, "admin", "admin"))
    owner = direct_token(app, add_user(app, "client", "client"))
    operator = direct_token(app, add_user(app, "operator", "operator"))
    seeded = _seed(app, admin, owner, operator)
    FUZZ_APP.state.settings = settings
    FUZZ_APP.state.db = app.state.db
    yield admin, seeded
    _empty_tables(db_url)


_CASES = itertools.count()


def with_seeded_ids(case, seeded: dict[str, object]) -> None:
    """Every other case: the generated ids become the seeded rows' (DELETE keeps its own)."""
    if next(_CASES) % 2 or case.method.upper() == "DELETE":
        return
    for params in (case.path_parameters, case.query):
        if params:
            for key in list(params):
                if key in seeded:
                    params[key] = seeded[key]


@pytest.mark.parametrize("db_backend", ["fuzz"])
@schema.parametrize()
@hsettings(max_examples=10, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
def test_no_server_errors(case, fuzz_state, db_backend):
    admin, seeded = fuzz_state
    with_seeded_ids(case, seeded)
    headers = {**(case.headers or {}), **admin}
    case.call_and_validate(headers=headers, checks=[not_a_server_error])
