"""`posefix tasks maintain | list | operators` against a real database."""

from __future__ import annotations

import json

from click.testing import CliRunner

from tests.api.tasks_support import Env, env, task_body  # noqa: F401


def test_cli_lists_maintains_and_reports(env: Env, monkeypatch) -> None:
    from posefix.cli import build_app

    app = build_app()
    run_id = env.import_run("drive-a", seed=41)
    env.add_user("op1", "operator")
    task = env.client("admin").post("/api/v1/tasks", json=task_body([run_id], lease_s=60)).json()
    assert env.client("op1").post("/api/v1/tasks/next").json()["assignment"] is not None
    monkeypatch.setenv("POSEFIX_DATABASE_URL", env.settings.resolved_database_url)
    monkeypatch.setenv("POSEFIX_DATA_DIR", str(env.settings.data_dir))
    runner = CliRunner()
    out = runner.invoke(app, ["tasks", "list"])
    assert out.exit_code == 0, out.output
    assert f"{task['id']:>5}  in_progress" in out.output and "accepted 1, open 1" in out.output
    env.clock.advance(61)  # the CLI reads the same (test) clock
    out = runner.invoke(app, ["tasks", "maintain"])
    assert out.exit_code == 0 and json.loads(out.output)["leases_expired"] == 1
    out = runner.invoke(app, ["tasks", "operators"])
    row = json.loads(out.output.splitlines()[0])
    assert row["username"] == "op1" and row["expired"] == 1
