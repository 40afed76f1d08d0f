"""The demo set-up: idempotent, through the real services, and served by `posefix demo`."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from posefix.config import Settings
from posefix.demo import COMMA_RUN_NAME, DEMO_ACCOUNTS, SIMULATED_RUN_NAME, DemoError, set_up_demo
from posefix.main import create_app

REPO = Path(__file__).resolve().parents[1]


def _settings(data_dir: Path, **extra: object) -> Settings:
    # the TestClient's origin; the served demo allows its own host and port
    return Settings(data_dir=data_dir, database_url="", environment="development", log_json=False,
                    operators_see_all_runs=True, public_url="http://testserver", **extra)


def _login(client: TestClient, username: str) -> None:
    password = next(a.password for a in DEMO_ACCOUNTS if a.username == username)
    response = client.post("/api/v1/auth/login", json={"username": username, "password": password},
                           headers={"Origin": "http://testserver"})
    assert response.status_code == 200, response.text


def test_set_up_twice_adds_everything_once(tmp_path: Path) -> None:
    settings = _settings(tmp_path / "var")
    first = set_up_demo(settings, drive_duration_s=60.0, frame_every_s=10.0)
    assert {"account admin", "account operator1", "account operator2", "account reviewer",
            "tile source helsinki", "tile source toner"} <= set(first.created)
    assert any(item.startswith("basemap ") for item in first.created)
    assert set(first.runs) == {SIMULATED_RUN_NAME, COMMA_RUN_NAME}
    files_before = sorted(p.relative_to(tmp_path) for p in (tmp_path / "var").rglob("*") if p.is_file()
                          and "sqlite" not in p.name)

    second = set_up_demo(settings, drive_duration_s=60.0, frame_every_s=10.0)
    assert second.created == [] and second.runs == first.runs and second.tile_sources == ["helsinki", "toner"]
    files_after = sorted(p.relative_to(tmp_path) for p in (tmp_path / "var").rglob("*") if p.is_file()
                         and "sqlite" not in p.name)
    assert files_after == files_before

    with TestClient(create_app(settings)) as client:
        _login(client, "operator1")
        runs = client.get("/api/v1/runs").json()
        assert runs["total"] == 2 and {r["name"] for r in runs["items"]} == set(first.runs)
        simulated = next(r for r in runs["items"] if r["name"] == SIMULATED_RUN_NAME)
        assert simulated["n_samples"] == 601 and simulated["n_images"] == 12  # a frame every 10 s from 0 to 50 s, 2 cameras
        # The drive stays on the extract's streets, in central Helsinki.
        min_lon, min_lat, max_lon, max_lat = simulated["bbox"]
        assert 24.93 < min_lon < max_lon < 24.96 and 60.16 < min_lat < max_lat < 60.18
        keyframes = client.get(f"/api/v1/runs/{simulated['id']}/keyframes").json()
        with_images = [f for f in keyframes["features"] if f["properties"]["has_images"]]
        assert with_images
        image = client.get(f"/api/v1/images/{with_images[0]['properties']['images'][0]}")
        assert image.status_code == 200 and image.headers["content-type"] == "image/jpeg"
        comma = next(r for r in runs["items"] if r["name"] == COMMA_RUN_NAME)
        assert comma["n_samples"] == 1200 and comma["n_images"] == 1 and comma["bbox"][0] == pytest.approx(-122.472, abs=0.001)

        style = client.get("/api/v1/map/style.json").json()
        assert style["metadata"]["posefix:default"] == "helsinki"
        assert style["sources"]["helsinki"]["attribution"] == "© OpenStreetMap contributors"
        assert client.get("/api/v1/tiles/helsinki/16/37308/18969.pbf").status_code == 200
        assert client.get("/api/v1/tiles/toner/0/0/0.png").status_code == 200


def test_camera_frames_show_time_and_position(tmp_path: Path) -> None:
    from posefix.demo import render_camera_frame

    front = render_camera_frame("front", 1_600_000_000.0, 24.94, 60.17, 90.0, 0.0, 0.0)
    rear = render_camera_frame("rear", 1_600_000_000.0, 24.94, 60.17, 90.0, 0.0, 0.0)
    later = render_camera_frame("front", 1_600_000_005.0, 24.9412, 60.1705, 92.0, 3.0, 40.0)
    assert len({front, rear, later}) == 3
    (tmp_path / "f.jpg").write_bytes(front)
    with Image.open(tmp_path / "f.jpg") as image:
        assert image.format == "JPEG" and image.size == (640, 360)


def test_demo_refuses_to_run_in_production(tmp_path: Path) -> None:
    settings = _settings(tmp_path / "var").model_copy(update={"environment": "production", "secret_key": "x" * 40})
    with pytest.raises(DemoError, match="published passwords"):
        set_up_demo(settings)
    assert not (tmp_path / "var").exists()


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_posefix_demo_command_sets_up_and_serves(tmp_path: Path) -> None:
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("POSEFIX_")}
    command = [str(Path(sys.executable).parent / "posefix"), "demo", "--data-dir", str(tmp_path / "var"), "--port", str(port)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=tmp_path)
    output: list[str] = []
    try:
        deadline = time.monotonic() + 180
        assert process.stdout is not None
        while time.monotonic() < deadline:
            line = process.stdout.readline()
            if not line:
                break
            output.append(line)
            if "posefix demo: open" in line:
                break
        text = "".join(output)
        assert f"open http://localhost:{port}/" in text, text[-3000:]
        accounts = dict(re.findall(r"^\s+\w+\s+(\w+)\s+password: (\S+)$", text, flags=re.M))
        assert set(accounts) == {"admin", "operator1", "operator2", "reviewer"}
        base = f"http://127.0.0.1:{port}"
        for _ in range(100):
            try:
                if httpx.get(f"{base}/healthz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                time.sleep(0.2)
        with httpx.Client(base_url=base, headers={"Origin": base}) as client:
            login = client.post("/api/v1/auth/login", json={"username": "operator1", "password": accounts["operator1"]})
            assert login.status_code == 200
            runs = client.get("/api/v1/runs").json()
            simulated = next(r for r in runs["items"] if r["name"] == SIMULATED_RUN_NAME)
            # ~10 minutes at 10 Hz, one frame per 5 s from each of two cameras.
            assert simulated["n_samples"] == 6001 and simulated["n_images"] == 240
    finally:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()

    rerun = subprocess.run([*command, "--no-serve"], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert rerun.returncode == 0, rerun.stderr
    assert "added: nothing (all there already)" in rerun.stdout
