"""End-to-end fixtures: a real `posefix serve` on a temporary SQLite database, seeded
through the server's own CLI and REST API, and Debian's Chromium driven by Playwright.

The server is started once per test session; each test that edits gets its own freshly
uploaded run so tests never depend on each other's revisions.
"""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import socket
import subprocess
import sys
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[2]
FRONTEND = ROOT / "frontend"
CHROMIUM = os.environ.get("POSEFIX_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
ARTIFACTS = ROOT / "test-artifacts"
PASSWORD = "e2e-password-123"
POSEFIX = [sys.executable, "-m", "posefix.cli"] if not (ROOT / ".venv/bin/posefix").exists() else [str(ROOT / ".venv/bin/posefix")]

# Rules that make every refusal reachable from the browser.
RULES_TOML = """
[rules]
every_n = 2
lock_n = 2
lock_direction = "forward"
max_move_m = 25.0
order_rule = "refuse"
"""


@dataclass
class Server:
    base_url: str
    data_dir: Path
    sim_dir: Path
    env: dict[str, str]

    def client(self, username: str) -> httpx.Client:
        """An HTTP client logged in as `username` (session cookie, matching Origin)."""
        c = httpx.Client(base_url=self.base_url, headers={"Origin": self.base_url}, timeout=60)
        r = c.post("/api/v1/auth/login", json={"username": username, "password": PASSWORD})
        r.raise_for_status()
        return c

    def get_json(self, username: str, path: str):
        c = self.client(username)
        try:
            r = c.get(path)
            r.raise_for_status()
            return r.json()
        finally:
            c.close()

    def upload_run(self, name: str) -> int:
        """Upload the simulated Helsinki drive with two cameras' images; wait until keyframes are ready."""
        c = self.client("admin")
        try:
            files = [
                ("file", ("run.csv", (self.sim_dir / "run_images.csv").read_bytes(), "text/csv")),
                ("images", ("images.zip", (self.sim_dir / "images.zip").read_bytes(), "application/zip")),
            ]
            r = c.post("/api/v1/runs", data={"name": name}, files=files)
            assert r.status_code in (200, 201, 202), r.text
            run_id = int(r.json()["id"])
            deadline = time.time() + 60
            while time.time() < deadline:
                k = c.get(f"/api/v1/runs/{run_id}/keyframes")
                if k.status_code == 200:
                    return run_id
                time.sleep(0.3)
            raise AssertionError(f"keyframes of run {run_id} never became ready: {k.status_code} {k.text[:300]}")
        finally:
            c.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ensure_frontend_built() -> None:
    dist = FRONTEND / "dist" / "index.html"
    src_mtime = max(p.stat().st_mtime for p in (FRONTEND / "src").rglob("*") if p.is_file())
    if dist.is_file() and dist.stat().st_mtime >= src_mtime:
        return
    npm = shutil.which("npm")
    if npm is None:
        raise RuntimeError("npm is needed to build the front end for the browser tests")
    if not (FRONTEND / "node_modules").is_dir():
        subprocess.run([npm, "ci", "--no-audit", "--no-fund"], cwd=FRONTEND, check=True)
    subprocess.run([npm, "run", "build", "--silent"], cwd=FRONTEND, check=True)


def _make_images(sim_dir: Path) -> None:
    """Add an `image` column (two cameras every 2 s) to the simulated run, and a zip of JPEGs."""
    from PIL import Image, ImageDraw

    with open(sim_dir / "run.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    if "image" not in header:
        header.append("image")
        body = [r + [""] for r in body]
    t_col, img_col = header.index("t"), header.index("image")
    t0 = float(body[0][t_col])
    zbuf = io.BytesIO()
    last_second = -1
    with zipfile.ZipFile(zbuf, "w") as zf:
        for r in body:
            s = int(float(r[t_col]) - t0)
            if s % 2 == 0 and s != last_second:
                last_second = s
                names = []
                for cam, color in (("front", (40, 90, 160)), ("left", (160, 90, 40))):
                    name = f"{cam}_{s:04d}.jpg"
                    im = Image.new("RGB", (320, 200), color)
                    d = ImageDraw.Draw(im)
                    d.text((12, 12), f"camera {cam}\nt = {s} s", fill=(255, 255, 255))
                    b = io.BytesIO()
                    im.save(b, "JPEG", quality=70)
                    zf.writestr(name, b.getvalue())
                    names.append(name)
                r[img_col] = ";".join(names)
    with open(sim_dir / "run_images.csv", "w", newline="") as fh:
        csv.writer(fh).writerows([header] + body)
    (sim_dir / "images.zip").write_bytes(zbuf.getvalue())


def _wait_ready(url: str, proc: subprocess.Popen, log: Path) -> None:
    deadline = time.time() + 60
    while time.time() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"posefix serve exited with {proc.returncode}:\n{log.read_text()[-3000:]}")
        try:
            if httpx.get(url + "/readyz", timeout=2).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise RuntimeError(f"posefix serve not ready after 60 s:\n{log.read_text()[-3000:]}")


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory):
    _ensure_frontend_built()
    tmp = tmp_path_factory.mktemp("e2e")
    data_dir = tmp / "var"
    data_dir.mkdir()
    (tmp / "engine.toml").write_text(RULES_TOML)
    port = _free_port()
    base_url = f"http://127.0.0.1:{port}"
    env = {
        **os.environ,
        "POSEFIX_ENVIRONMENT": "test",
        "POSEFIX_DATA_DIR": str(data_dir),
        "POSEFIX_ENGINE_CONFIG": str(tmp / "engine.toml"),
        "POSEFIX_OPERATORS_SEE_ALL_RUNS": "true",
        "POSEFIX_LOG_LEVEL": "WARNING",
        "POSEFIX_WORKER_POLL_S": "0.2",
        "POSEFIX_ALLOWED_ORIGINS": json.dumps([base_url]),
    }
    env.pop("POSEFIX_DATABASE_URL", None)
    run = lambda *args, **kw: subprocess.run([*POSEFIX, *args], env=env, cwd=tmp, check=True, capture_output=True, text=True, **kw)  # noqa: E731
    run("db", "upgrade")
    for user, role in (("admin", "admin"), ("op1", "operator"), ("op2", "operator")):
        run("users", "create", "--username", user, "--role", role, "--password-stdin", input=PASSWORD + "\n")

    # Basemaps: the Helsinki vector basemap built by the server's own builder, and the
    # small raster fixture, so the switcher has two kinds to choose from.
    from posefix.basemap import build_basemap

    (data_dir / "basemap").mkdir()
    build_basemap(ROOT / "data/osm/helsinki.osm.pbf", data_dir / "basemap/helsinki.pmtiles", 12, 15)
    shutil.copy(ROOT / "data/tiles/world-toner-z3.pmtiles", data_dir / "basemap/toner.pmtiles")

    sim_dir = tmp / "sim"
    run("simulate", "--osm", str(ROOT / "data/osm/helsinki.osm.pbf"), "--duration-s", "90", "--rate-hz", "10",
        "--edit-every-s", "0", "--regime", "canyon", "--seed", "3", "--out", str(sim_dir), "--quiet")
    _make_images(sim_dir)

    log = tmp / "server.log"
    with open(log, "w") as log_fh:
        proc = subprocess.Popen([*POSEFIX, "serve", "--port", str(port)], env=env, cwd=tmp, stdout=log_fh, stderr=subprocess.STDOUT)
    try:
        _wait_ready(base_url, proc, log)
        srv = Server(base_url=base_url, data_dir=data_dir, sim_dir=sim_dir, env=env)
        c = srv.client("admin")
        try:
            for body in (
                {"name": "helsinki", "title": "Helsinki streets", "kind": "street", "path": "basemap/helsinki.pmtiles",
                 "attribution": "© OpenStreetMap contributors"},
                {"name": "toner", "title": "Toner", "kind": "topo", "path": "basemap/toner.pmtiles",
                 "attribution": "Map tiles by Stamen Design, CC BY 3.0; data © OpenStreetMap contributors"},
            ):
                r = c.post("/api/v1/tile-sources", json=body)
                assert r.status_code in (200, 201), r.text
        finally:
            c.close()
        yield srv
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
        ARTIFACTS.mkdir(exist_ok=True)
        shutil.copy(log, ARTIFACTS / "e2e-server.log")


@pytest.fixture(scope="session")
def browser():
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        raise RuntimeError(f"{CHROMIUM} not found: install Debian's chromium (scripts/test.sh does)")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture
def context(browser, request):
    ctx = browser.new_context(viewport={"width": 1280, "height": 800}, locale="en-GB")
    yield ctx
    ARTIFACTS.mkdir(exist_ok=True)
    failed = getattr(request.node, "rep_call", None)
    if failed is not None and failed.failed:
        for i, pg in enumerate(ctx.pages):
            try:
                pg.screenshot(path=str(ARTIFACTS / f"FAILED-{request.node.name}-{i}.png"))
            except Exception:  # noqa: BLE001 - best effort on the way out
                pass
    ctx.close()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    rep = outcome.get_result()
    setattr(item, "rep_" + rep.when, rep)


@pytest.fixture
def run_id(server, request) -> int:
    return server.upload_run(f"e2e {request.node.name}")
