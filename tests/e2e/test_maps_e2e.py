"""Map matching in the browser: an admin uploads the shared floor plan, waits for its model,
tracks and replays a walk and sees the error at the waypoints; an operator fetches
map-matching suggestions in the editor, picks one with a click and accepts it with the button, submits, and the new
revision stores the move as a suggestion."""

from __future__ import annotations

import re
import zipfile
from pathlib import Path

from tests.e2e.helpers import login, open_run, shot

REPO = Path(__file__).resolve().parents[2]
FLOOR = REPO / "data" / "indoor-site1-F1"
WALK = FLOOR / "walks" / "5dd9e7aac5b77e0006b1732b.txt"


def test_floor_upload_replay_walk_and_see_waypoint_errors(server, context, tmp_path):
    zpath = tmp_path / "site1-F1.zip"
    with zipfile.ZipFile(zpath, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in ("floor_info.json", "geojson_map.json", "floor_image.png"):
            zf.write(FLOOR / name, f"site1/F1/{name}")
    page = context.new_page()
    login(page, server, "admin")
    page.get_by_role("link", name="Floor plans").click()
    page.get_by_label("Floor plan name").fill("Mall F1")
    page.get_by_test_id("floor-file").set_input_files(str(zpath))
    page.get_by_test_id("floor-upload").click()
    page.wait_for_function("() => document.querySelector('[data-testid=floor-upload-msg]').textContent.includes('built')", timeout=60_000)
    row = page.get_by_test_id("floor-row").filter(has_text="Mall F1")
    assert row.get_by_test_id("floor-status").inner_text() == "ready"
    row.get_by_role("link", name="Mall F1").click()
    page.wait_for_selector("canvas[data-image='loaded']", timeout=15_000)
    assert "download model" in page.get_by_test_id("floor-meta").inner_text()

    page.get_by_test_id("walk-file").set_input_files(str(WALK))
    page.get_by_test_id("walk-track").click()
    mean = page.get_by_test_id("error-mean")
    mean.wait_for(timeout=30_000)
    text = mean.inner_text()
    assert "Error at 6 waypoints" in text, text
    # Six scored waypoints plus the given start in the table.
    assert page.get_by_test_id("walk-errors").locator("tr").count() == 7
    canvas = page.get_by_test_id("floor-canvas")
    assert canvas.get_attribute("data-step") == "0" and canvas.get_attribute("data-waypoints-reached") == "0"

    # Scrub half way, then play to the end: the waypoints passed show their error.
    last = int(page.get_by_test_id("replay-scrub").get_attribute("max"))
    page.get_by_test_id("replay-scrub").fill(str(last // 2))
    assert canvas.get_attribute("data-step") == str(last // 2)
    page.get_by_test_id("replay-play").click()
    page.wait_for_function(f"() => document.querySelector('[data-testid=floor-canvas]').dataset.step === '{last}'", timeout=30_000)
    assert canvas.get_attribute("data-waypoints-reached") == "6"
    assert "last waypoint error" in page.get_by_test_id("replay-step").inner_text()
    assert page.get_by_test_id("replay-play").inner_text().startswith("▶")
    page.evaluate("window.scrollTo(0, 0)")
    shot(page, "floor-walk-replay", docs=True)

    # The same walk, unknown start, with a WiFi survey of the floor's OTHER walks: two survey walks
    # cannot calibrate f3, and the page says so instead of using it; the placement says whether
    # the walk converged.
    from posefix.mapmatch import read_walk
    from posefix.mapmatch.fingerprints import build_fingerprints, save_fingerprints

    survey = build_fingerprints([read_walk(w) for w in sorted((FLOOR / "walks").glob("*.txt")) if w != WALK])
    save_fingerprints(survey, tmp_path / "survey.npz")
    survey.f3_calibrated, survey.f3_note, survey.walk_corr = True, "", 0.25  # calibration set by hand: f3 used
    save_fingerprints(survey, tmp_path / "set.npz")
    page.get_by_test_id("walk-start").select_option("unknown")
    page.get_by_test_id("walk-fingerprints").set_input_files(str(tmp_path / "survey.npz"))
    page.get_by_test_id("walk-track").click()
    wifi = page.get_by_test_id("walk-wifi")
    # the known-start track above left its own line ("no fingerprint file given"): wait for this one
    page.wait_for_function("() => document.querySelector('[data-testid=walk-wifi]').textContent.startsWith('WiFi not used: f3')", timeout=30_000)
    assert wifi.inner_text().startswith("WiFi not used: f3 left out: 2 survey walks"), wifi.inner_text()
    # f3 left out, motion only: the walk's shape fits several corridors (as the API test finds).
    placed = page.get_by_test_id("walk-converged").inner_text()
    assert re.match(r"Not placed: not converged: \d+ places up to [\d.]+ m apart at the end", placed), placed
    page.get_by_test_id("walk-fingerprints").set_input_files(str(tmp_path / "set.npz"))
    page.get_by_test_id("walk-track").click()
    page.wait_for_function("() => document.querySelector('[data-testid=walk-wifi]').textContent.startsWith('WiFi: ')", timeout=30_000)
    text = wifi.inner_text()
    assert " placed by the survey set.npz; the whole walk's WiFi counts as at most 4.0 fixes" in text, text
    # The server's tracker reads the same survey and says the same.
    page.get_by_test_id("walk-server").click()
    page.wait_for_function("() => document.querySelector('[data-testid=server-error-mean]').textContent.includes('Server: WiFi')", timeout=30_000)
    assert "placed by the survey set.npz" in page.get_by_test_id("server-error-mean").inner_text()


def test_editor_accept_a_suggestion_and_submit(server, context, run_id):
    page = context.new_page()
    login(page, server, "op1")
    open_run(page, server, run_id)
    page.get_by_test_id("suggestions").click()
    info = page.get_by_test_id("suggestions-info")
    page.wait_for_function("() => /suggestion/.test(document.querySelector('[data-testid=suggestions-info]').textContent)", timeout=30_000)
    assert "off-road" in info.inner_text() and "road network" in info.inner_text()  # the editor asks for the road matcher
    accept_all = page.get_by_test_id("suggestions-accept-all")
    assert accept_all.is_visible()

    # Pick an offered suggestion (moving 3-20 m, within the run's 25 m rule) whose point is
    # clear of every keyframe at zoom 19, so the click cannot start a keyframe drag.
    pick = page.evaluate(
        """() => { const m = window.__posefixMap; const d = m.getSource('pf-suggestions')._data;
            const pts = (d.geojson || d).features.filter(f => f.properties.kind === 'point' && f.properties.moved >= 3 && f.properties.moved <= 20);
            const k = m.getSource('pf-keyframes')._data; const kfs = (k.geojson || k).features.map(f => f.geometry.coordinates);
            for (const f of pts) {
              m.jumpTo({center: f.geometry.coordinates, zoom: 19, bearing: 0});
              const p = m.project(f.geometry.coordinates);
              const clear = kfs.every(c => { const q = m.project(c); return Math.hypot(q.x - p.x, q.y - p.y) > 30; });
              if (clear) return [f.properties.i, f.properties.moved, f.geometry.coordinates];
            }
            return null; }"""
    )
    assert pick is not None, "no suggestion clear of the keyframes"
    page.wait_for_function("() => window.__posefixMap.loaded() && !window.__posefixMap.isMoving()")
    page.wait_for_function(
        """([c, i]) => { const m = window.__posefixMap; if (m.isMoving()) return false; const p = m.project(c);
            return m.queryRenderedFeatures([p.x, p.y], {layers: ['pf-sug-point']}).some(f => f.properties.i === i); }""",
        arg=[pick[2], pick[0]], timeout=15_000,
    )
    x, y = page.evaluate(
        """(c) => { const m = window.__posefixMap; const p = m.project(c); const r = m.getCanvas().getBoundingClientRect();
            return [r.left + p.x, r.top + p.y]; }""", pick[2])
    page.mouse.click(x, y)
    # The click picks the suggestion; accepting it is the explicit button (or Enter).
    page.get_by_test_id("suggestion-current").filter(has_text=f"Keyframe {pick[0]}:").wait_for(timeout=10_000)
    page.wait_for_timeout(300)
    assert page.evaluate("document.querySelector('.editor').dataset.unsaved") == "0"
    page.get_by_test_id("suggestion-accept").click()
    page.wait_for_function("() => document.querySelector('.editor').dataset.unsaved === '1'", timeout=10_000)
    assert f"keyframe {pick[0]}" in page.get_by_test_id("notices").inner_text()
    page.wait_for_function("() => document.querySelector('.editor').dataset.previewCurrent === 'true'", timeout=30_000)
    shot(page, "editor-suggestions", docs=True)

    page.get_by_test_id("submit").click()
    page.wait_for_function("() => document.querySelector('.editor').dataset.revision === '1'", timeout=60_000)
    edits = server.get_json("admin", f"/api/v1/runs/{run_id}/edits")
    rows = edits["items"] if isinstance(edits, dict) else edits
    assert [(e["k"], e["kind"]) for e in rows] == [(pick[0], "suggestion")]
