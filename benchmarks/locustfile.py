"""The operators of ``python -m benchmarks.server``'s load, for locust.

Run by the benchmark (not by hand): ``locust -f benchmarks/locustfile.py --headless -u N -r N
-t T --processes P --host URL --csv PREFIX --only-summary`` with ``POSEFIX_BENCH_LOAD`` naming
a JSON file the benchmark writes: ``run_id``, ``tiles`` ([z, x, y] keys of source
``bench-pm``), ``sessions`` (one logged-in session's cookies per operator, made before the
load: argon2id logins are slow on purpose and not part of it), ``seconds`` (the load) and
``spawn_s`` (time after the test starts by which every operator has been spawned; the load
starts then for all of them, ``-t`` is ``spawn_s + seconds`` plus a margin so no request is
cut off). Each locust process writes its CPU seconds from test start to stop into the
directory ``<config>.cpu``.

Requests are named by kind (``keyframes``, ``preview``, ``tile``) so locust's statistics
group them; the first connection of each operator (``/healthz``) goes through the raw
client, which records nothing: it is made before the load, untimed.
"""

from __future__ import annotations

import json
import os
import random
import time
from pathlib import Path

import gevent
import orjson
from locust import events
from locust.contrib.fasthttp import FastHttpUser
from locust.exception import StopUser
from requests.cookies import create_cookie

from benchmarks.server import adjustable_features, preview_body

CONFIG_PATH = Path(os.environ.get("POSEFIX_BENCH_LOAD", "posefix-bench-load.json"))
_test_started_at = 0.0  # time.time() of this process's test start (one per locust process)
_test_started_cpu_s = 0.0  # and its CPU time then


@events.test_start.add_listener
def note_test_start(environment, **_kwargs) -> None:  # type: ignore[no-untyped-def]
    global _test_started_at, _test_started_cpu_s
    _test_started_at, _test_started_cpu_s = time.time(), time.process_time()


@events.test_stop.add_listener
def write_test_cpu(environment, **_kwargs) -> None:  # type: ignore[no-untyped-def]
    """This process's CPU seconds from test start to stop, for the benchmark's generator CPU
    without locust's start-up (imports, forking, workers connecting)."""
    cpu_dir = CONFIG_PATH.with_suffix(".cpu")
    cpu_dir.mkdir(exist_ok=True)
    (cpu_dir / str(os.getpid())).write_text(f"{time.process_time() - _test_started_cpu_s:.3f}")


def claim_operator(claims_dir: Path, n_operators: int) -> int:
    """A session index no other operator, in any locust process, holds (an exclusive file)."""
    for index in range(n_operators):
        try:
            os.close(os.open(claims_dir / f"{index:04d}", os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            return index
        except FileExistsError:
            continue
    raise RuntimeError(f"more locust users than the {n_operators} sessions in {CONFIG_PATH}")


class Operator(FastHttpUser):
    """One operator's browser tab: keep-alive connections, gzip accepted, and a reload of
    the keyframes revalidated with ``If-None-Match`` (a browser does that by itself for a
    ``Cache-Control: no-cache`` response with an ETag) keeping its copy on 304. The GeoJSON
    is parsed only when a new one arrives; preview and tile bodies are read, not parsed."""

    network_timeout = 30.0
    connection_timeout = 30.0

    def on_start(self) -> None:
        config = json.loads(CONFIG_PATH.read_text())
        index = claim_operator(CONFIG_PATH.with_suffix(".claims"), len(config["sessions"]))
        for cookie in config["sessions"][index]:
            self.client.cookiejar.set_cookie(create_cookie(**cookie))
        self.rng = random.Random(index)
        self.run_id = config["run_id"]
        self.tiles = [tuple(key) for key in config["tiles"]]
        self.headers = {"Origin": self.host}  # the CSRF rule: an unsafe request names its origin
        # Untimed, before the load starts: the tab has loaded the app, so its connection is open.
        response = self.client.client.urlopen(f"{self.host}/healthz", method="GET", headers=self.headers)
        if response.status_code != 200:
            raise RuntimeError(f"/healthz answered {response.status_code}")
        response.content  # noqa: B018 - read to the end so the connection is reused
        start_at = _test_started_at + config["spawn_s"]
        gevent.sleep(max(start_at - time.time(), 0.0))  # every operator starts the load together
        self.stop_at = start_at + config["seconds"]
        gevent.sleep(self.rng.uniform(0, 1.0))  # operators do not all start at once
        self.candidates: list[dict] = []
        self.revision = 0
        self.etag: str | None = None

    def wait_time(self) -> float:
        return 0.0  # the think time is slept in operate, with this operator's own generator

    def operate(self) -> None:
        """One action, then 0.5-1.5 s of thinking; stops at the end of the load."""
        if time.time() >= self.stop_at:
            raise StopUser()
        rng, url = self.rng, f"/api/v1/runs/{self.run_id}"
        if not self.candidates or rng.random() < 0.1:
            headers = {**self.headers, "If-None-Match": self.etag} if self.etag and self.candidates else self.headers
            response = self.client.get(f"{url}/keyframes", name="keyframes", headers=headers)
            if response.status_code == 200:
                collection = orjson.loads(response.content)
                self.candidates, self.revision = adjustable_features(collection["features"]), collection["revision"]
                self.etag = response.headers.get("etag")
        elif rng.random() < 0.6:
            body = orjson.dumps(preview_body(self.candidates, self.revision, rng), option=orjson.OPT_SERIALIZE_NUMPY)
            self.client.post(f"{url}/preview", name="preview", data=body,
                             headers={**self.headers, "Content-Type": "application/json"})
        else:
            start = rng.randrange(len(self.tiles))
            for z, x, y in (self.tiles * 2)[start:start + 6]:
                self.client.get(f"/api/v1/tiles/bench-pm/{z}/{x}/{y}.pbf", name="tile", headers=self.headers)
        gevent.sleep(rng.uniform(0.5, 1.5))

    tasks = [operate]
