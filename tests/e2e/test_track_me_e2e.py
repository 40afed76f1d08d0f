""""Track me" in Chromium on a phone-sized page: a recorded walk's accelerometer and rotation
samples are fed to the page as synthetic devicemotion / deviceorientationabsolute events.
The page downloads the model once, then tracks with no request to the server, and its error
at the walk's waypoints matches the server's online filter on the same model bytes. Then the
page is reloaded offline and tracks again from the service worker's copies."""

from __future__ import annotations

import io
import json
import math
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from posefix.mapmatch import load_model, read_walk, track_walk
from posefix.mapmatch.evaluate import evaluate_track
from posefix.mapmatch.sensors import quat_xyzw_from_rotation_vector
from tests.e2e.helpers import login, shot

REPO = Path(__file__).resolve().parents[2]
FLOOR = REPO / "data" / "indoor-site1-F1"
WALK = FLOOR / "walks" / "5dd9e7aac5b77e0006b1732b.txt"
PHONE = {"viewport": {"width": 390, "height": 844}, "device_scale_factor": 2, "is_mobile": True, "has_touch": True,
         "locale": "en-GB"}

FEED = """(ev) => {
  for (const e of ev) {
    if (e[0] === 0) window.dispatchEvent(new DeviceMotionEvent('devicemotion',
        {accelerationIncludingGravity: {x: e[1], y: e[2], z: e[3]}, interval: e[4]}));
    else window.dispatchEvent(new DeviceOrientationEvent('deviceorientationabsolute',
        {alpha: e[1], beta: e[2], gamma: e[3], absolute: true}));
  }
}"""


@pytest.fixture(scope="module")
def floor_id(server) -> int:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in ("floor_info.json", "geojson_map.json", "floor_image.png"):
            zf.write(FLOOR / name, f"site1/F1/{name}")
    c = server.srv.client("admin")
    try:
        r = c.post("/api/v1/floorplans", data={"name": "Track-me F1", "cell_m": "0.8"},
                   files=[("file", ("site1-F1.zip", buf.getvalue(), "application/zip"))])
        assert r.status_code == 202, r.text
        fid = r.json()["id"]
        deadline = time.time() + 120
        while c.get(f"/api/v1/floorplans/{fid}").json()["status"] != "ready":
            assert time.time() < deadline, "the floor's model was never built"
            time.sleep(0.3)
        return fid
    finally:
        c.close()


def euler_zxy_deg(rotvec: np.ndarray) -> np.ndarray:
    """DeviceOrientation angles (alpha, beta, gamma; R = Rz(α)·Rx(β)·Ry(γ), device -> ENU) of rotation vectors."""
    x, y, z, w = quat_xyzw_from_rotation_vector(rotvec).T
    r01 = 2 * (x * y - z * w)
    r11 = 1 - 2 * (x * x + z * z)
    r21 = 2 * (y * z + x * w)
    r20 = 2 * (x * z - y * w)
    r22 = 1 - 2 * (x * x + y * y)
    beta = np.degrees(np.arcsin(np.clip(r21, -1, 1)))
    alpha = np.degrees(np.arctan2(-r01, r11)) % 360.0
    gamma = np.degrees(np.arctan2(-r20, r22))
    return np.column_stack([alpha, beta, gamma])


def sensor_events(walk) -> list[list[float]]:
    """[kind, a, b, c, interval] in time order: kind 0 motion (m/s², interval ms), 1 orientation (degrees)."""
    acc, rot = walk.acc, walk.rotvec
    ang = euler_zxy_deg(rot[:, 1:4])
    ev = []
    for i in range(acc.shape[0]):
        ev.append((acc[i, 0], 1, [0, *acc[i, 1:4].tolist(), 0.0 if i == 0 else float(acc[i, 0] - acc[i - 1, 0])]))
    for j in range(rot.shape[0]):
        ev.append((rot[j, 0], 0, [1, *ang[j].tolist(), 0.0]))
    ev.sort(key=lambda e: (e[0], e[1]))  # an orientation sample at a motion sample's time comes first
    return [e[2] for e in ev]


def page_mean_error(track: list[dict], walk) -> float:
    """Mean error of the page's live track at the waypoints after the first (its times are ms since the first sample)."""
    t = np.array([s["t_ms"] for s in track], dtype=float) + walk.acc[0, 0]
    p = np.array([[s["x_m"], s["y_m"]] for s in track])
    return float(evaluate_track(walk.waypoints, t, p, skip_first=True).err_wp_m.mean())


def server_mean_error(server, floor_id: int, walk, start, tmp_path: Path) -> float:
    """The Python online filter's mean error on the same walk with the model bytes the server serves."""
    c = server.srv.client("op1")
    try:
        path = tmp_path / "model.npz"
        path.write_bytes(c.get(f"/api/v1/floorplans/{floor_id}/model").content)
    finally:
        c.close()
    res = track_walk(load_model(path), walk, start_xy_m=start)
    return float(evaluate_track(walk.waypoints, res.t_ms, res.online_xy_m, skip_first=True).err_wp_m.mean())


def track_on_page(page, events) -> list[dict]:
    page.get_by_test_id("track-me").click()
    page.wait_for_function("() => document.querySelector('[data-testid=live-msg]').textContent.includes('Waiting for the motion sensors')",
                           timeout=30_000)
    page.evaluate(FEED, events)
    page.get_by_test_id("track-stop").click()
    page.wait_for_function("() => document.querySelector('[data-testid=live-msg]').textContent.startsWith('Stopped')")
    return page.evaluate("window.__posefixLiveTrack")


def test_track_me_from_sensor_events_with_no_server_request_and_offline(server, browser, floor_id, tmp_path):
    walk = read_walk(WALK)
    x0, y0 = float(walk.waypoints[0, 1]), float(walk.waypoints[0, 2])
    ctx = browser.new_context(**PHONE)
    try:
        page = ctx.new_page()
        login(page, server, "op1")
        model_requests: list[str] = []
        ctx.on("request", lambda r: model_requests.append(r.url) if r.url.endswith(f"/floorplans/{floor_id}/model") else None)
        page.goto(f"{server.base_url}/#/floors/{floor_id}")
        page.wait_for_selector("canvas[data-image='loaded']", timeout=15_000)

        # The known start, tapped on the floor plan.
        canvas = page.get_by_test_id("floor-canvas")
        view = json.loads(canvas.get_attribute("data-view"))
        box = canvas.bounding_box()
        size = page.evaluate("() => { const c = document.querySelector('[data-testid=floor-canvas]'); return [c.width, c.height]; }")
        px, py = view["ox"] + x0 * view["scale"], view["heightPx"] - (view["oy"] + y0 * view["scale"])
        canvas.tap(position={"x": px * box["width"] / size[0], "y": py * box["height"] / size[1]})
        tapped = [float(v) for v in page.get_by_test_id("track-start").input_value().split(",")]
        assert math.hypot(tapped[0] - x0, tapped[1] - y0) < 1.0, tapped
        page.get_by_test_id("track-start").fill(f"{x0},{y0}")  # the exact point, as the server gets it

        # The page downloads the model, and its service worker keeps the page and the model.
        page.wait_for_function(f"() => caches.match('/api/v1/floorplans/{floor_id}/model').then((r) => !!r)", timeout=30_000)
        page.wait_for_function("() => caches.match('/').then((r) => !!r)", timeout=30_000)
        events = sensor_events(walk)
        requests: list[str] = []
        ctx.on("request", lambda r: requests.append(r.url))
        page.get_by_test_id("track-me").click()
        page.wait_for_function("() => document.querySelector('[data-testid=live-msg]').textContent.includes('Waiting for the motion sensors')",
                               timeout=30_000)
        after_model = len(requests)
        page.evaluate(FEED, events)
        page.get_by_test_id("track-stop").click()
        page.wait_for_function("() => document.querySelector('[data-testid=live-msg]').textContent.startsWith('Stopped')")
        assert model_requests, "the model was never downloaded"
        assert requests[after_model:] == [], "the page asked the server while tracking"
        track = page.evaluate("window.__posefixLiveTrack")
        steps = int(page.get_by_test_id("live-msg").get_attribute("data-steps"))
        assert steps == len(track) - 1 and steps >= 30, steps
        assert page.get_by_test_id("live-msg").get_attribute("data-converged") == "true"

        ours = page_mean_error(track, walk)
        theirs = server_mean_error(server, floor_id, walk, (x0, y0), tmp_path)
        assert abs(ours - theirs) <= 0.25, (ours, theirs)
        assert ours < 3.0, ours
        page.evaluate("document.querySelector('[data-testid=floor-canvas]').scrollIntoView()")
        shot(page, "track-me-phone", docs=True)

        # Offline: the service worker answers the page, its floor and the model; tracking works.
        ctx.set_offline(True)
        page.reload()
        page.wait_for_selector("canvas[data-image='loaded']", timeout=15_000)
        page.get_by_test_id("track-start").fill(f"{x0},{y0}")
        offline_track = track_on_page(page, events)
        assert abs(page_mean_error(offline_track, walk) - ours) < 1e-6
    finally:
        ctx.close()


def test_track_me_without_a_start_shows_the_modes(server, browser, floor_id):
    """No start tapped: the page does not pretend to know where the walker is."""
    walk = read_walk(WALK)
    ctx = browser.new_context(**PHONE)
    try:
        page = ctx.new_page()
        login(page, server, "op1")
        page.goto(f"{server.base_url}/#/floors/{floor_id}")
        page.wait_for_selector("canvas[data-image='loaded']", timeout=15_000)
        events = sensor_events(walk)
        page.get_by_test_id("track-me").click()
        page.wait_for_function("() => document.querySelector('[data-testid=live-msg]').textContent.includes('Waiting for the motion sensors')",
                               timeout=30_000)
        page.evaluate(FEED, events[: len(events) // 3])
        msg = page.get_by_test_id("live-msg")
        assert msg.get_attribute("data-converged") == "false"
        assert "not located yet" in msg.inner_text() and "places fit the steps" in msg.inner_text()
    finally:
        ctx.close()


def test_replay_tracks_the_walk_file_in_the_browser_beside_the_server(server, context, floor_id, tmp_path):
    """The floor page's replay runs the browser tracker on the file's sensor lines: its error at
    the waypoints is the Python online filter's on the same model bytes; the server's smoothed
    answer comes on request, beside it."""
    walk = read_walk(WALK)
    page = context.new_page()
    login(page, server, "op1")
    page.goto(f"{server.base_url}/#/floors/{floor_id}")
    page.wait_for_selector("canvas[data-image='loaded']", timeout=15_000)
    page.get_by_test_id("walk-file").set_input_files(str(WALK))
    page.get_by_test_id("walk-track").click()
    mean = page.get_by_test_id("error-mean")
    mean.wait_for(timeout=30_000)
    ours = float(mean.inner_text().split("mean ")[1].split(" m")[0])
    theirs = server_mean_error(server, floor_id, walk, (float(walk.waypoints[0, 1]), float(walk.waypoints[0, 2])), tmp_path)
    assert abs(ours - theirs) <= 0.006, (ours, theirs)  # the same filter, shown to the centimetre

    page.get_by_test_id("walk-server").click()
    line = page.get_by_test_id("server-error-mean")
    page.wait_for_function("() => document.querySelector('[data-testid=server-error-mean]').textContent.includes('Server (smoothed')",
                           timeout=30_000)
    c = server.srv.client("op1")
    try:
        r = c.post(f"/api/v1/floorplans/{floor_id}/walks", files=[("file", (WALK.name, WALK.read_bytes(), "text/plain"))])
        assert r.status_code == 200, r.text
        smoothed = r.json()["errors"]["mean_m"]
    finally:
        c.close()
    assert f"mean {smoothed:.2f} m at 6 waypoints" in line.inner_text()
