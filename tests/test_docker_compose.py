"""docker-compose.yml and the Dockerfile, checked without a Docker engine.

``docker compose config`` (or Debian's ``docker-compose config``) validates the file and
resolves it; the checks below read the resolved form. Every command the services run is
parsed by posefix's own CLI, so a renamed option fails here, not in production.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml
from click.testing import CliRunner

REPO = Path(__file__).resolve().parents[1]
ENV = {"POSTGRES_PASSWORD": "pg-secret-for-test", "POSEFIX_SECRET_KEY": "s" * 48, "MINIO_ROOT_PASSWORD": "m" * 40}
# An empty env file, so a developer's own .env does not leak into the checks.
EMPTY_ENV_FILE = REPO / "docker" / "test.env"


def compose_command() -> list[str]:
    docker = shutil.which("docker")
    if docker and subprocess.run([docker, "compose", "version"], capture_output=True).returncode == 0:
        return [docker, "compose"]
    legacy = shutil.which("docker-compose")
    assert legacy, "neither `docker compose` nor `docker-compose` is installed (scripts/test.sh installs docker-compose)"
    return [legacy]


def compose_config(env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    clean = {k: v for k, v in os.environ.items() if k not in ENV and not k.startswith("POSEFIX_")}
    return subprocess.run(
        [*compose_command(), "-f", str(REPO / "docker-compose.yml"), "--project-directory", str(REPO),
         "--env-file", str(EMPTY_ENV_FILE), "config"],
        capture_output=True, text=True, env={**clean, **env}, cwd=REPO, timeout=60,
    )


@pytest.fixture(scope="module")
def config() -> dict:
    result = compose_config(ENV)
    assert result.returncode == 0, result.stderr
    return yaml.safe_load(result.stdout)


def test_services_and_replicas(config: dict) -> None:
    services = config["services"]
    assert set(services) == {"postgres", "minio", "bucket", "migrate", "api", "worker", "proxy"}
    assert services["minio"]["image"].startswith("minio/minio")
    assert services["api"]["deploy"]["replicas"] == 2
    assert services["worker"]["deploy"]["replicas"] == 2
    assert services["postgres"]["image"].startswith("postgres:")


def test_api_and_workers_share_postgres_and_the_object_store(config: dict) -> None:
    services = config["services"]
    for name in ("api", "worker", "migrate"):
        env = services[name]["environment"]
        assert env["POSEFIX_DATABASE_URL"] == "postgresql+psycopg://posefix:pg-secret-for-test@postgres:5432/posefix"
        assert env["POSEFIX_ENVIRONMENT"] == "production" and env["POSEFIX_SECRET_KEY"] == "s" * 48
    for name in ("api", "worker"):
        mounts = [str(v["target"] if isinstance(v, dict) else v.split(":")[1]) for v in services[name]["volumes"]]
        assert mounts == ["/var/lib/posefix"], name
        assert services[name]["environment"]["POSEFIX_DATA_DIR"] == "/var/lib/posefix"
        assert services[name]["depends_on"]["migrate"]["condition"] == "service_completed_successfully"
        assert services[name]["depends_on"]["bucket"]["condition"] == "service_completed_successfully"
        env = services[name]["environment"]
        assert env["POSEFIX_FILES_URL"] == "s3://posefix/files" and env["POSEFIX_S3_ENDPOINT_URL"] == "http://minio:9000"
        assert env["POSEFIX_S3_SECRET_ACCESS_KEY"] == services["minio"]["environment"]["MINIO_ROOT_PASSWORD"] == "m" * 40
    assert "mb --ignore-existing local/posefix" in " ".join(services["bucket"]["entrypoint"])
    assert {"pgdata", "objects", "var"} <= set(config["volumes"])
    assert services["worker"]["stop_grace_period"] in ("90s", "1m30s")


def test_secrets_are_required(tmp_path: Path) -> None:
    for missing in ENV:
        result = compose_config({k: v for k, v in ENV.items() if k != missing})
        assert result.returncode != 0
        assert missing in result.stderr


def test_every_service_command_parses_with_the_cli(config: dict) -> None:
    from posefix.cli import build_app

    app = build_app()
    runner = CliRunner()
    for name in ("migrate", "api", "worker"):
        command = config["services"][name]["command"]
        assert command[0] == "posefix"
        result = runner.invoke(app, [*command[1:], "--help"])
        assert result.exit_code == 0, (name, result.output)
    assert "--no-embedded-worker" in config["services"]["api"]["command"]


def test_proxy_spreads_requests_over_the_api_replicas(config: dict) -> None:
    proxy = config["services"]["proxy"]
    assert proxy["image"].startswith("nginx:")
    nginx = (REPO / "docker" / "nginx.conf").read_text()
    assert "server api:8000;" in nginx and "proxy_buffering off;" in nginx
    published = proxy["ports"][0]
    target = published["target"] if isinstance(published, dict) else int(str(published).split(":")[-1])
    assert int(target) == 8080 and re.search(r"listen 8080;", nginx)


def test_dockerfile_builds_the_front_end_and_the_app() -> None:
    dockerfile = (REPO / "Dockerfile").read_text()
    stages = re.findall(r"^FROM (\S+) AS (\w+)", dockerfile, flags=re.M)
    assert [stage for _, stage in stages] == ["frontend", "python", "runtime"]
    assert stages[0][0].startswith("node:")
    assert "RUN npm ci" in dockerfile and "RUN npm run build" in dockerfile
    assert "COPY --from=frontend /app/frontend/dist frontend/dist" in dockerfile
    assert "pip install -e ./backend" in dockerfile
    assert re.search(r"^USER posefix$", dockerfile, flags=re.M)
    # What the image copies must exist in a checkout.
    for path in ("frontend/package.json", "frontend/package-lock.json", "backend/pyproject.toml", "migrations",
                 "data", "README.md"):
        assert (REPO / path).exists(), path
    # The package's migrations lookup is relative to the source tree: /app/backend -> /app/migrations.
    from posefix.db import MIGRATIONS_DIR

    assert MIGRATIONS_DIR == REPO / "migrations"


def test_dockerignore_keeps_local_state_out() -> None:
    ignored = set((REPO / ".dockerignore").read_text().split())
    assert {".git", ".venv", ".env", "frontend/node_modules", "*.sqlite"} <= ignored
