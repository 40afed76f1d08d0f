"""Real HTTP (uvicorn on loopback): concurrent submitters on one base revision, and SSE."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Iterator

import httpx
import pytest
import uvicorn
from sqlalchemy import func, select

from posefix.edits.models import Edit, EditBatch
from tests.conftest import drive_csv


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def live(settings, users_live) -> Iterator[str]:
    yield users_live


@pytest.fixture
def users_live(settings):
    """A uvicorn server in a thread with an embedded worker; yields (base_url, app, headers)."""
    from posefix.main import create_app
    from tests.conftest import add_user, direct_token

    app = create_app(settings, embedded_worker=True)
    headers = {role: direct_token(app, add_user(app, role, role)) for role in ("admin", "reviewer", "operator", "client")}
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert time.monotonic() < deadline, "server did not start"
        time.sleep(0.02)
    try:
        yield f"http://127.0.0.1:{port}", app, headers
    finally:
        server.should_exit = True
        thread.join(30)


def upload_run(base: str, h: dict[str, str], n: int = 600) -> int:
    r = httpx.post(f"{base}/api/v1/runs", files={"file": ("d.csv", drive_csv(n))}, data={"name": "c"}, headers=h, timeout=60)
    assert r.status_code == 201, r.text
    return r.json()["id"]


class TestConcurrentSubmitters:
    def test_exactly_one_wins_each_round(self, live):
        base, app, hs = live
        rid = upload_run(base, hs["admin"])
        rounds = 6
        wins = 0
        for rnd in range(rounds):
            barrier = threading.Barrier(2)
            out: dict[str, httpx.Response] = {}

            def submit(who: str, k: int) -> None:
                with httpx.Client(timeout=60) as c:
                    barrier.wait()
                    out[who] = c.post(f"{base}/api/v1/runs/{rid}/edits",
                                      json={"base_revision": rnd, "deleted": [k]}, headers=hs[who])

            threads = [threading.Thread(target=submit, args=(who, 2 * rnd + i + 1)) for i, who in enumerate(("admin", "reviewer"))]
            for t in threads:
                t.start()
            for t in threads:
                t.join(60)
            codes = sorted(r.status_code for r in out.values())
            assert codes == [202, 409], [r.text for r in out.values()]
            loser = next(r for r in out.values() if r.status_code == 409)
            assert loser.json()["error"] == "stale_revision" and loser.json()["current_revision"] == rnd + 1
            wins += 1
        with app.state.db.transaction(write=False) as s:
            batches = s.scalars(select(EditBatch.revision).where(EditBatch.run_id == rid).order_by(EditBatch.revision)).all()
            n_edits = s.scalar(select(func.count()).select_from(Edit).where(Edit.run_id == rid))
        assert batches == list(range(1, rounds + 1)) and n_edits == wins
        # nothing lost: the last revision carries every winner's deletion
        deadline = time.monotonic() + 120
        while True:
            run = httpx.get(f"{base}/api/v1/runs/{rid}", headers=hs["admin"], timeout=60).json()
            if run["revision"] == rounds:
                break
            assert time.monotonic() < deadline
            time.sleep(0.2)
        rev = httpx.get(f"{base}/api/v1/runs/{rid}/revisions/{rounds}", headers=hs["admin"], timeout=60).json()
        assert len(rev["edit_set"]["deleted"]) == rounds


class TestEvents:
    def test_sse_job_progress_and_revision_ready(self, live):
        base, app, hs = live
        rid = upload_run(base, hs["admin"], 5000)
        r = httpx.post(f"{base}/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": [4]}, headers=hs["admin"], timeout=60)
        jid = r.json()["job_id"]
        events = []
        with httpx.stream("GET", f"{base}/api/v1/events", params={"job_id": jid, "until_done": "true", "max_s": 60},
                          headers=hs["admin"], timeout=90) as resp:
            assert resp.status_code == 200 and resp.headers["content-type"].startswith("text/event-stream")
            event = None
            for line in resp.iter_lines():
                if line.startswith("event:"):
                    event = line.split(":", 1)[1].strip()
                elif line.startswith("data:") and event:
                    events.append((event, json.loads(line.split(":", 1)[1])))
        kinds = [e for e, _ in events]
        assert "job.progress" in kinds
        jobs = [d for e, d in events if e == "job.progress"]
        assert jobs[-1]["status"] == "succeeded" and jobs[-1]["id"] == jid
        progress = [d["progress"] for d in jobs]
        assert progress == sorted(progress)
        revs = [d for e, d in events if e == "revision.ready"]
        assert revs and revs[-1]["run_id"] == rid and revs[-1]["revision"] == 1

    def test_sse_only_visible_runs(self, live):
        base, app, hs = live
        rid = upload_run(base, hs["client"], 600)
        r = httpx.post(f"{base}/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": [4]}, headers=hs["admin"], timeout=60)
        with httpx.stream("GET", f"{base}/api/v1/events", params={"max_s": 3}, headers=hs["operator"], timeout=30) as resp:
            body = "".join(resp.iter_text())
        assert "revision.ready" not in body and "job.progress" not in body
        assert r.status_code == 202

    def test_sse_requires_login(self, live):
        base, _, _ = live
        assert httpx.get(f"{base}/api/v1/events", timeout=60).status_code == 401
