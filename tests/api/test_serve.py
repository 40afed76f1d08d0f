"""`posefix serve` on SQLite: migrates, serves, and its job worker writes revisions, with one HTTP
process (the worker a thread in it) and with two (the worker its own process)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from tests.api.test_concurrency import free_port
from tests.conftest import drive_csv

POSEFIX = str(Path(sys.executable).parent / "posefix")


def child_commands(pid: int) -> list[str]:
    kids = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    return [Path(f"/proc/{k}/cmdline").read_bytes().replace(b"\0", b" ").decode() for k in kids]


@pytest.mark.slow
@pytest.mark.parametrize("processes", [1, 2])
def test_serve_with_embedded_worker(tmp_path, processes):
    env = {**os.environ, "POSEFIX_DATA_DIR": str(tmp_path / "var"), "POSEFIX_ENVIRONMENT": "development",
           "POSEFIX_LOG_LEVEL": "WARNING", "POSEFIX_WORKER_POLL_S": "0.1"}
    env.pop("POSEFIX_DATABASE_URL", None)
    port = free_port()
    proc = subprocess.Popen([POSEFIX, "serve", "--port", str(port), "--workers", str(processes)], env=env, cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 180  # several processes start on a shared machine
        while True:
            try:
                if httpx.get(f"{base}/readyz", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.2)
        created = subprocess.run([POSEFIX, "users", "create", "--role", "admin", "--username", "root", "--password-stdin"],
                                 input="a-long-password\n", env=env, capture_output=True, text=True, cwd=tmp_path, timeout=120)
        assert created.returncode == 0, created.stderr
        c = httpx.Client(base_url=base, headers={"Origin": base}, timeout=60)
        assert c.post("/api/v1/auth/login", json={"username": "root", "password": "a-long-password"}).status_code == 200
        token = c.post("/api/v1/tokens", json={"name": "curl", "scope": "write"}).json()["token"]
        h = {"Authorization": f"Bearer {token}"}
        rid = httpx.post(f"{base}/api/v1/runs", files={"file": ("d.csv", drive_csv(300))}, data={"name": "d"}, headers=h,
                         timeout=60).json()["id"]
        r = httpx.post(f"{base}/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": [3]}, headers=h, timeout=60)
        assert r.status_code == 202
        deadline = time.monotonic() + 60
        while httpx.get(f"{base}/api/v1/jobs/{r.json()['job_id']}", headers=h, timeout=60).json()["status"] != "succeeded":
            assert time.monotonic() < deadline
            time.sleep(0.2)
        assert httpx.get(f"{base}/api/v1/runs/{rid}", headers=h, timeout=60).json()["revision"] == 1
        assert (tmp_path / "var" / "posefix.sqlite").exists()
        kids = child_commands(proc.pid)
        job_workers = [c for c in kids if "main(['worker'])" in c]
        if processes == 1:
            assert job_workers == [], kids
        else:  # the HTTP processes and the job worker beside them
            assert len(job_workers) == 1 and len(kids) >= 3, kids
    finally:
        proc.terminate()
        proc.wait(timeout=30)
