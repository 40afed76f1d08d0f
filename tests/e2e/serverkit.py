"""Start a real `posefix serve` on a temporary SQLite database, seeded through the server's
own CLI (migrations, users, simulated drives) and REST API (tile sources, run uploads).
Used by the browser tests' fixtures and by benchmarks/editor_drag.py."""

from __future__ import annotations

import contextlib
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
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import httpx

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
OSM = ROOT / "data/osm/helsinki.osm.pbf"


def posefix_cmd() -> list[str]:
    exe = ROOT / ".venv/bin/posefix"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "posefix.cli"]


@dataclass
class Server:
    base_url: str
    data_dir: Path
    workdir: Path
    env: dict[str, str] = field(repr=False)

    def cli(self, *args: str, stdin: str | None = None) -> str:
        r = subprocess.run([*posefix_cmd(), *args], env=self.env, cwd=self.workdir, capture_output=True, text=True, input=stdin)
        if r.returncode != 0:
            raise RuntimeError(f"posefix {' '.join(args)} failed ({r.returncode}):\n{r.stdout}\n{r.stderr}")
        return r.stdout

    def client(self, username: str) -> httpx.Client:
        """An HTTP client logged in as `username` (session cookie, matching Origin). Close it."""
        c = httpx.Client(base_url=self.base_url, headers={"Origin": self.base_url}, timeout=120)
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

    def simulate(self, name: str, duration_s: float, rate_hz: float, seed: int, regime: str = "canyon") -> Path:
        out = self.workdir / name
        self.cli("simulate", "--osm", str(OSM), "--duration-s", str(duration_s), "--rate-hz", str(rate_hz),
                 "--edit-every-s", "0", "--regime", regime, "--seed", str(seed), "--out", str(out), "--quiet")
        return out

    def upload_run(self, name: str, run_csv: Path, images_zip: Path | None = None, timeout_s: float = 120) -> int:
        """Upload a run as admin; wait until its keyframes are served."""
        c = self.client("admin")
        try:
            files = [("file", (run_csv.name, run_csv.read_bytes(), "text/csv"))]
            if images_zip is not None:
                files.append(("images", (images_zip.name, images_zip.read_bytes(), "application/zip")))
            r = c.post("/api/v1/runs", data={"name": name}, files=files)
            if r.status_code not in (200, 201, 202):
                raise RuntimeError(f"upload of {run_csv} failed: {r.status_code} {r.text[:500]}")
            run_id = int(r.json()["id"])
            deadline = time.time() + timeout_s
            while time.time() < deadline:
                k = c.get(f"/api/v1/runs/{run_id}/keyframes")
                if k.status_code == 200:
                    return run_id
                time.sleep(0.3)
            raise RuntimeError(f"keyframes of run {run_id} never became ready: {k.status_code} {k.text[:300]}")
        finally:
            c.close()

    def add_tile_source(self, body: dict) -> None:
        c = self.client("admin")
        try:
            r = c.post("/api/v1/tile-sources", json=body)
            if r.status_code not in (200, 201):
                raise RuntimeError(f"tile source {body.get('name')}: {r.status_code} {r.text[:300]}")
        finally:
            c.close()


def ensure_frontend_built() -> None:
    """Build frontend/dist when it is missing or older than the sources (one build at a
    time: pytest-xdist workers share the tree)."""
    import fcntl

    ARTIFACTS.mkdir(exist_ok=True)
    with open(ARTIFACTS / ".frontend-build.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
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


def add_camera_images(sim_dir: Path, every_s: int = 2) -> tuple[Path, Path]:
    """Add an `image` column (two cameras every `every_s` s) to a simulated run, and a zip of JPEGs.
    Returns (run csv, images zip)."""
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
            if s % every_s == 0 and s != last_second:
                last_second = s
                names = []
                for cam, color in (("front", (40, 90, 160)), ("left", (160, 90, 40))):
                    name = f"{cam}_{s:04d}.jpg"
                    im = Image.new("RGB", (320, 200), color)
                    ImageDraw.Draw(im).text((12, 12), f"camera {cam}\nt = {s} s", fill=(255, 255, 255))
                    b = io.BytesIO()
                    im.save(b, "JPEG", quality=70)
                    zf.writestr(name, b.getvalue())
                    names.append(name)
                r[img_col] = ";".join(names)
    run_csv, images_zip = sim_dir / "run_images.csv", sim_dir / "images.zip"
    with open(run_csv, "w", newline="") as fh:
        csv.writer(fh).writerows([header] + body)
    images_zip.write_bytes(zbuf.getvalue())
    return run_csv, images_zip


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_ready(url: str, proc: subprocess.Popen, log: Path) -> None:
    deadline = time.time() + 180  # two HTTP processes and a worker importing everything on a loaded 2-core machine
    while time.time() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"posefix serve exited with {proc.returncode}:\n{log.read_text()[-3000:]}")
        try:
            if httpx.get(url + "/readyz", timeout=2).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise RuntimeError(f"posefix serve not ready after 180 s:\n{log.read_text()[-3000:]}")


@contextlib.contextmanager
def running_server(workdir: Path, rules_toml: str, basemaps: bool = True) -> Iterator[Server]:
    """Migrate a fresh SQLite database in `workdir`, create admin/op1/op2, register the
    Helsinki vector basemap and the raster fixture, and serve until the block ends."""
    data_dir = workdir / "var"
    data_dir.mkdir(parents=True)
    (workdir / "engine.toml").write_text(rules_toml)
    port = _free_port()
    base_url = f"http://127.0.0.1:{port}"
    env = {
        **os.environ,
        "POSEFIX_ENVIRONMENT": "test",
        "POSEFIX_DATA_DIR": str(data_dir),
        "POSEFIX_ENGINE_CONFIG": str(workdir / "engine.toml"),
        "POSEFIX_OPERATORS_SEE_ALL_RUNS": "true",
        "POSEFIX_LOG_LEVEL": "WARNING",
        "POSEFIX_WORKER_POLL_S": "0.2",
        "POSEFIX_ALLOWED_ORIGINS": json.dumps([base_url]),
    }
    env.pop("POSEFIX_DATABASE_URL", None)
    srv = Server(base_url=base_url, data_dir=data_dir, workdir=workdir, env=env)
    srv.cli("db", "upgrade")
    for user, role in (("admin", "admin"), ("op1", "operator"), ("op2", "operator")):
        srv.cli("users", "create", "--username", user, "--role", role, "--password-stdin", stdin=PASSWORD + "\n")
    if basemaps:
        from posefix.basemap import build_basemap

        (data_dir / "basemap").mkdir()
        build_basemap(OSM, data_dir / "basemap/helsinki.pmtiles", 12, 15)
        shutil.copy(ROOT / "data/tiles/world-toner-z3.pmtiles", data_dir / "basemap/toner.pmtiles")
    log = workdir / "server.log"
    with open(log, "w") as log_fh:
        proc = subprocess.Popen([*posefix_cmd(), "serve", "--port", str(port)], env=env, cwd=workdir, stdout=log_fh, stderr=subprocess.STDOUT)
    try:
        _wait_ready(base_url, proc, log)
        if basemaps:
            srv.add_tile_source({"name": "helsinki", "title": "Helsinki streets", "kind": "street", "path": "basemap/helsinki.pmtiles",
                                 "attribution": "© OpenStreetMap contributors"})
            srv.add_tile_source({"name": "toner", "title": "Toner", "kind": "topo", "path": "basemap/toner.pmtiles",
                                 "attribution": "Map tiles by Stamen Design, CC BY 3.0; data © OpenStreetMap contributors"})
        yield srv
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
        if log.exists():
            ARTIFACTS.mkdir(exist_ok=True)
            shutil.copy(log, ARTIFACTS / f"server-{workdir.name}.log")


@contextlib.contextmanager
def chromium() -> Iterator[object]:
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        raise RuntimeError(f"{CHROMIUM} not found: install Debian's chromium (scripts/test.sh does)")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()
