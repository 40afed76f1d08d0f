"""Page helpers shared by the browser tests: log in, open a run, find keyframes on screen."""

from __future__ import annotations

import os
from pathlib import Path

from tests.e2e.serverkit import ARTIFACTS, PASSWORD

DOCS_IMG = Path(__file__).resolve().parents[2] / "docs" / "img"


def login(page, server, username: str = "op1") -> None:
    page.goto(server.base_url + "/#/login")
    page.get_by_label("Username").fill(username)
    page.get_by_label("Password").fill(PASSWORD)
    page.get_by_role("button", name="Log in").click()
    page.get_by_test_id("whoami").wait_for()


def open_run(page, server, run_id: int) -> None:
    page.goto(f"{server.base_url}/#/runs/{run_id}")
    page.wait_for_selector("#map[data-ready='true']", timeout=30_000)
    page.wait_for_function("() => document.querySelector('.editor').dataset.revision !== ''", timeout=30_000)
    # Wait for the map to have drawn the keyframes once (sources loaded, idle).
    page.wait_for_function(
        """() => { const m = window.__posefixMap; return m && m.getSource('pf-keyframes') && m.loaded()
              && m.queryRenderedFeatures({layers: ['pf-kf-hit']}).length > 0; }""",
        timeout=30_000,
    )


def keyframe_px(page, index: int) -> tuple[float, float]:
    """Page coordinates of keyframe `index` once it is drawn there (GeoJSON updates render
    asynchronously, so wait until the map's hit test at that pixel finds it)."""
    page.wait_for_function(
        """(i) => { const m = window.__posefixMap; if (m.isMoving()) return false;
            const f = m.getSource('pf-keyframes')._data; const c = (f.geojson || f).features[i].geometry.coordinates;
            const p = m.project(c);
            return m.queryRenderedFeatures([p.x, p.y], {layers: ['pf-kf-hit']}).some(g => g.properties.i === i); }""",
        arg=index,
        timeout=15_000,
    )
    xy = page.evaluate(
        """(i) => { const m = window.__posefixMap;
            const f = m.getSource('pf-keyframes')._data;
            const feats = (f.geojson || f).features;
            const c = feats[i].geometry.coordinates;
            const p = m.project(c); const r = m.getCanvas().getBoundingClientRect();
            return [r.left + p.x, r.top + p.y]; }""",
        index,
    )
    return xy[0], xy[1]


def metres_px(page, index: int, east_m: float, north_m: float) -> tuple[float, float]:
    """Page coordinates `east_m`/`north_m` metres from keyframe `index`'s reported position."""
    xy = page.evaluate(
        """([i, e, n]) => { const m = window.__posefixMap;
            const f = m.getSource('pf-keyframes')._data; const feats = (f.geojson || f).features;
            const c = feats[i].geometry.coordinates;
            const lat = c[1] + n / 111320; const lon = c[0] + e / (111320 * Math.cos(c[1] * Math.PI / 180));
            const p = m.project([lon, lat]); const r = m.getCanvas().getBoundingClientRect();
            return [r.left + p.x, r.top + p.y]; }""",
        [index, east_m, north_m],
    )
    return xy[0], xy[1]


def zoom_to(page, index: int, zoom: float = 18) -> None:
    page.evaluate(
        """([i, z]) => { const m = window.__posefixMap; const f = m.getSource('pf-keyframes')._data;
            const c = (f.geojson || f).features[i].geometry.coordinates; m.jumpTo({center: c, zoom: z, bearing: 0}); }""",
        [index, zoom],
    )
    page.wait_for_function("() => window.__posefixMap.loaded() && !window.__posefixMap.isMoving()")
    page.wait_for_timeout(150)


def drag(page, start: tuple[float, float], end: tuple[float, float], steps: int = 12) -> None:
    page.mouse.move(*start)
    page.mouse.down()
    page.mouse.move(*end, steps=steps)
    page.mouse.up()


def shot(page, name: str, docs: bool = False) -> Path:
    """Screenshot into test-artifacts/; the README's pictures (docs=True) are refreshed in
    docs/img/ only when POSEFIX_UPDATE_DOCS_IMG=1, so a test run leaves the tree clean."""
    ARTIFACTS.mkdir(exist_ok=True)
    path = ARTIFACTS / f"{name}.png"
    page.screenshot(path=str(path))
    if docs and os.environ.get("POSEFIX_UPDATE_DOCS_IMG") == "1":
        DOCS_IMG.mkdir(parents=True, exist_ok=True)
        (DOCS_IMG / f"{name}.png").write_bytes(path.read_bytes())
    return path
