"""Issue 15's editor tools in Chromium: export of the shown revision, help (the `?` overlay,
the help page and the first-run tour), the task form's run map, suggestions you cannot
accept by accident, and the larger image view with its filmstrip."""

from __future__ import annotations

import csv
import json
import math

import pytest

from tests.e2e.helpers import drag, keyframe_px, login, metres_px, open_run, shot, zoom_to
from tests.e2e.test_issue15 import api_move

pytestmark = pytest.mark.e2e


def editor_data(page, key: str) -> str:
    return page.evaluate(f"document.querySelector('.editor').dataset.{key}")


def wait_editor(page, key: str, value: str, timeout: int = 30_000) -> None:
    page.wait_for_function(f"() => document.querySelector('.editor').dataset.{key} === '{value}'", timeout=timeout)


def test_export_the_shown_revision_from_the_editor(server, context, run_id):
    api_move(server, "op1", run_id, 10, 2.0, "for export")
    page = context.new_page()
    login(page, server, "op1")  # an operator: export is not an admin's privilege
    open_run(page, server, run_id)
    wait_editor(page, "revision", "1")
    page.get_by_text("Export", exact=True).click()
    assert "Revision 1, as shown." in page.get_by_test_id("export-note").inner_text()
    got = {}
    for fmt in ("csv", "gpx", "geojson"):
        if page.get_by_test_id("export").get_attribute("open") is None:
            page.get_by_text("Export", exact=True).click()
        with page.expect_download() as dl:
            page.get_by_test_id(f"export-{fmt}").click()
        d = dl.value
        assert d.suggested_filename.endswith(f"-r1.{fmt}"), d.suggested_filename
        got[fmt] = open(d.path(), "rb").read()
    c = server.srv.client("op1")
    try:
        rev1 = c.get(f"/api/v1/runs/{run_id}/export", params={"format": "csv", "revision": 1}).content
        rev0 = c.get(f"/api/v1/runs/{run_id}/export", params={"format": "csv", "revision": 0}).content
    finally:
        c.close()
    assert got["csv"] == rev1 and got["csv"] != rev0  # the shown revision, not the first one
    assert b"<gpx" in got["gpx"] and b"<trkpt" in got["gpx"]
    assert json.loads(got["geojson"])["type"] == "FeatureCollection"
    # With unsaved edits the menu says they are not in the download.
    page.keyboard.press("Escape")
    page.locator("#map").focus()
    page.keyboard.press(".")
    page.keyboard.press("Delete")
    wait_editor(page, "unsaved", "1")
    assert page.get_by_test_id("export").get_attribute("open") is None  # closed once a format was chosen
    page.get_by_text("Export", exact=True).click()
    assert "unsaved edits are not in it" in page.get_by_test_id("export-note").inner_text()


def test_help_overlay_help_page_and_first_run_tour(server, context, run_id):
    page = context.new_page()
    login(page, server, "op1")
    open_run(page, server, run_id)
    tour = page.get_by_test_id("tour")
    assert page.get_by_test_id("tour-title").inner_text() == "Drag a keyframe"

    # `?` lists every shortcut; keys pressed while it is open do not reach the editor.
    page.locator("#map").focus()
    page.keyboard.press("?")
    overlay = page.get_by_test_id("help-overlay")
    overlay.wait_for()
    editor_rows = page.get_by_test_id("shortcuts-editor").locator("tbody tr")
    keys = [editor_rows.nth(i).get_attribute("data-keys") for i in range(editor_rows.count())]
    for k in (". n", "ArrowRight", "Shift+ArrowUp", "Ctrl+Z", "Ctrl+Shift+Z Ctrl+Y", "Delete Backspace", "R", "U", "I", "G", "F", "H", "Escape", "Enter", "S"):
        assert k in keys, (k, keys)
    assert page.get_by_test_id("shortcuts-review").locator("tbody tr").count() == 6
    page.keyboard.press(".")
    assert page.get_by_test_id("selection-info").count() == 0  # the editor did not select
    shot(page, "help-overlay", docs=True)
    page.keyboard.press("Escape")
    overlay.wait_for(state="hidden")

    # The tour: a drag, then a refusal (a locked keyframe), then a submit.
    zoom_to(page, 10)
    drag(page, keyframe_px(page, 10), metres_px(page, 10, 3, 4))
    wait_editor(page, "unsaved", "1")
    page.get_by_test_id("tour-title").filter(has_text="Meet a refusal").wait_for()
    assert "locked" in page.get_by_test_id("tour-text").inner_text()
    drag(page, keyframe_px(page, 11), metres_px(page, 11, 0, 4))
    page.get_by_test_id("refusal").wait_for(timeout=10_000)
    page.get_by_test_id("tour-title").filter(has_text="Submit").wait_for()
    assert editor_data(page, "tourStep") == "submit"  # the Submit button is highlighted
    page.keyboard.press("Escape")
    page.get_by_test_id("submit").click()
    wait_editor(page, "revision", "1", 60_000)
    page.get_by_test_id("tour-title").filter(has_text="That is all").wait_for()
    page.get_by_test_id("tour-close").click()
    tour.wait_for(state="hidden")
    page.reload()
    open_run(page, server, run_id)
    assert not tour.is_visible()  # shown once per browser

    # The help page, linked from the header, explains and restarts the tour.
    page.get_by_test_id("help-link").click()
    help_page = page.get_by_test_id("help-page")
    help_page.wait_for()
    assert "Keyboard shortcuts" in help_page.inner_text() and "refused" in help_page.inner_text()
    page.get_by_test_id("restart-tour").click()
    open_run(page, server, run_id)
    assert page.get_by_test_id("tour-title").inner_text() == "Drag a keyframe"


def _far_run_csv(server, tmp_path):
    """The test drive moved 20 degrees east: a run in another region."""
    with open(server.run_csv, newline="") as fh:
        rows = list(csv.reader(fh))
    col = next(i for i, name in enumerate(rows[0]) if name.lower() in ("lon", "longitude", "lon_deg"))
    for r in rows[1:]:
        r[col] = repr(float(r[col]) + 20.0)
    out = tmp_path / "far.csv"
    with open(out, "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    return out


def _map_bounds(page):
    return page.evaluate("() => { const b = window.__posefixTaskMap.getBounds(); return [b.getWest(), b.getSouth(), b.getEast(), b.getNorth()]; }")


def _contains(outer, inner) -> bool:
    return outer[0] <= inner[0] and outer[1] <= inner[1] and outer[2] >= inner[2] and outer[3] >= inner[3]


def test_task_form_map_fits_the_work_picks_outlines_and_resets(server, context, run_id, tmp_path):
    far_id = server.srv.upload_run("e2e far away", _far_run_csv(server, tmp_path))
    runs = {r["id"]: r for r in server.get_json("admin", "/api/v1/runs?limit=500")["items"]}
    near_box, far_box = runs[run_id]["bbox"], runs[far_id]["bbox"]
    page = context.new_page()
    login(page, server, "admin")
    page.goto(server.base_url + "/#/tasks/admin")
    page.wait_for_selector(".choice-map[data-ready='true']", timeout=30_000)
    page.wait_for_function("() => window.__posefixTaskMap.loaded() && !window.__posefixTaskMap.isMoving()")
    # Not the box of every run in the world: the newest run's region (the far one).
    b = _map_bounds(page)
    assert _contains(b, far_box) and not _contains(b, near_box), b
    # Choosing a run in the list fits it.
    page.locator(f"input[data-run='{run_id}']").check()
    page.wait_for_function(f"() => {{ const m = window.__posefixTaskMap; const b = m.getBounds(); const r = {json.dumps(near_box)};"
                           " return !m.isMoving() && b.getWest() <= r[0] && b.getSouth() <= r[1] && b.getEast() >= r[2] && b.getNorth() >= r[3]; }", timeout=10_000)
    assert not _contains(_map_bounds(page), far_box)
    page.locator(f"input[data-run='{run_id}']").uncheck()
    # A click on the run's outline selects it (the middle of its west edge).
    page.locator(".choice-map").scroll_into_view_if_needed()
    x, y = page.evaluate(f"""() => {{ const m = window.__posefixTaskMap; const r = {json.dumps(near_box)};
        const p = m.project([r[0], (r[1] + r[3]) / 2]); const c = m.getCanvas().getBoundingClientRect(); return [c.left + p.x, c.top + p.y]; }}""")
    page.mouse.click(x, y)
    page.wait_for_function(f"() => document.querySelector(\"input[data-run='{run_id}']\").checked")
    # Qualifications are picked from the known ones; comparators read as words.
    page.get_by_role("button", name="+ requirement").click()
    qual = page.get_by_test_id("req-qualification")
    options = qual.locator("option").all_inner_texts()
    assert "approved assignments (count)" in options and "qualification test" in options
    qual.select_option("approved_count")
    comp = page.get_by_test_id("req-comparator")
    assert "at least" in comp.locator("option").all_inner_texts()
    comp.select_option(label="at least")
    page.get_by_test_id("req-value").fill("1000")  # nobody qualifies: the task serves no other test
    page.get_by_label("Title").fill("Map form task")
    page.get_by_test_id("create-task").click()
    msg = page.get_by_test_id("create-msg")
    msg.filter(has_text="created").wait_for(timeout=15_000)
    task_id = int(msg.inner_text().split()[1])
    # The form is new again.
    assert page.locator("input[data-run]:checked").count() == 0
    assert page.get_by_test_id("req-qualification").count() == 0
    assert page.get_by_label("Title").input_value() == "Correct the drives"
    task = server.get_json("admin", f"/api/v1/tasks/{task_id}")
    assert task["requirements"] == [{"qualification": "approved_count", "comparator": "ge", "value": 1000}]
    c = server.srv.client("admin")
    try:
        c.post(f"/api/v1/tasks/{task_id}/cancel")
    finally:
        c.close()


def test_suggestions_are_picked_by_click_and_decided_by_key(server, context, run_id):
    page = context.new_page()
    login(page, server, "op1")
    open_run(page, server, run_id)
    page.get_by_test_id("suggestions").click()
    page.get_by_test_id("suggestion-panel").wait_for(timeout=60_000)
    # Their own colour, not the locked keyframes' amber; a legend entry.
    colours = page.evaluate("() => [window.__posefixMap.getPaintProperty('pf-sug-point', 'circle-stroke-color'),"
                            " window.__posefixMap.getPaintProperty('pf-sug-offroad', 'circle-stroke-color')]")
    assert "#d97706" not in colours, colours
    assert "Suggested position" in page.get_by_test_id("legend-suggestions").inner_text()
    buttons = page.get_by_test_id("suggestion-list").locator("button")
    listed = []
    for i in range(buttons.count()):
        text = buttons.nth(i).inner_text()  # "#12 · 4.2 m · to decide"
        listed.append((int(text.split(" · ")[0][1:]), float(text.split(" · ")[1].split()[0])))
    # Two the run's rules allow (the limit is 25 m), apart so the first's lock does not matter.
    ok = [k for k, m in listed if 1.0 <= m <= 20.0]
    assert len(ok) >= 2, listed
    first, second = ok[0], ok[-1]
    # A click picks (the list marks it and the map rings it); it does not accept.
    row = page.get_by_test_id(f"suggestion-row-{second}")
    row.click()
    assert row.get_attribute("aria-current") == "true"
    assert editor_data(page, "unsaved") == "0"
    assert f"Keyframe {second}:" in page.get_by_test_id("suggestion-current").inner_text()
    page.wait_for_function(f"() => {{ const d = window.__posefixMap.getSource('pf-suggestions')._data; return (d.geojson || d).features.some(f => f.properties.kind === 'point' && f.properties.focus && f.properties.i === {second}); }}")
    # S skips it (marked, left out of Accept all, the next one picked); [ steps back one.
    todo_before = page.get_by_test_id("suggestions-accept-all").inner_text()
    page.locator("#map").focus()
    page.keyboard.press("s")
    assert row.inner_text().endswith("skipped")
    assert row.get_attribute("aria-current") is None
    assert page.get_by_test_id("suggestions-accept-all").inner_text() != todo_before
    order = [k for k, _ in listed]
    now = int(page.get_by_test_id("suggestion-list").locator("[aria-current=true]").get_attribute("data-testid").split("-")[-1])
    assert now != second
    page.keyboard.press("[")
    before = order[max(0, order.index(now) - 1)]
    assert page.get_by_test_id(f"suggestion-row-{before}").get_attribute("aria-current") == "true"
    # Pick the first and accept it with Enter.
    page.get_by_test_id(f"suggestion-row-{first}").click()
    assert editor_data(page, "unsaved") == "0"
    page.locator("#map").focus()
    page.keyboard.press("Enter")
    wait_editor(page, "unsaved", "1", 10_000)
    assert page.get_by_test_id(f"suggestion-row-{first}").inner_text().endswith("accepted")
    shot(page, "editor-suggestions-list", docs=True)
    # The toggle hides them: no layer, no legend entry, and the keys rest.
    toggle = page.get_by_test_id("suggestions")  # once they are here, the same button shows or hides them
    assert toggle.get_attribute("aria-pressed") == "true"
    toggle.click()
    assert toggle.get_attribute("aria-pressed") == "false"
    page.wait_for_function("() => { const d = window.__posefixMap.getSource('pf-suggestions')._data; return (d.geojson || d).features.length === 0; }")
    assert page.get_by_test_id("legend-suggestions").count() == 0
    page.locator("#map").focus()
    page.keyboard.press("Enter")
    page.wait_for_timeout(300)
    assert editor_data(page, "unsaved") == "1"


def test_images_larger_view_full_screen_and_filmstrip(server, context, run_id):
    fc = server.get_json("op1", f"/api/v1/runs/{run_id}/keyframes")
    with_images = [f["properties"]["index"] if "index" in f["properties"] else i for i, f in enumerate(fc["features"]) if f["properties"].get("images")]
    assert len(with_images) >= 4
    k0 = with_images[1]
    page = context.new_page()
    login(page, server, "op1")
    open_run(page, server, run_id)
    zoom_to(page, k0)
    page.mouse.click(*keyframe_px(page, k0), button="right")
    page.get_by_test_id("images-panel").wait_for()
    panel_w = page.get_by_test_id("image").bounding_box()["width"]
    page.get_by_test_id("images-enlarge").click()
    viewer = page.get_by_test_id("image-viewer")
    viewer.wait_for()
    page.wait_for_function("() => { const i = document.querySelector('[data-testid=viewer-image]'); return i && i.complete && i.naturalWidth === 320; }")
    assert page.get_by_test_id("viewer-image").bounding_box()["width"] > 1.5 * panel_w
    assert viewer.get_attribute("data-keyframe") == str(k0)
    assert f"Keyframe #{k0} · camera 1 of 2" in page.get_by_test_id("viewer-caption").inner_text()
    # Step: the second camera, then the next keyframe's first; the editor follows on the map.
    page.get_by_test_id("viewer-image").focus()
    page.keyboard.press("ArrowRight")
    assert "camera 2 of 2" in page.get_by_test_id("viewer-caption").inner_text()
    page.keyboard.press("ArrowRight")
    k1 = with_images[2]
    assert viewer.get_attribute("data-keyframe") == str(k1)
    page.get_by_test_id("selection-info").filter(has_text=f"#{k1}").wait_for()
    page.wait_for_function(f"""() => {{ const s = window.__posefixMap.getSource('pf-selection')._data; const f = (s.geojson || s).features[0];
        const k = window.__posefixMap.getSource('pf-keyframes')._data; const c = (k.geojson || k).features[{k1}].geometry.coordinates;
        return f && f.geometry.coordinates[0] === c[0] && f.geometry.coordinates[1] === c[1]; }}""")
    # The keyframe is in the part of the map the viewer leaves visible.
    page.wait_for_function("() => !window.__posefixMap.isMoving()")
    px = keyframe_px(page, k1)
    vb = viewer.bounding_box()
    assert px[0] < vb["x"], (px, vb)
    # The filmstrip jumps; PageDown steps a whole keyframe.
    page.get_by_test_id("filmstrip").get_by_role("button", name=f"Keyframe {with_images[3]}, camera 1").click()
    assert viewer.get_attribute("data-keyframe") == str(with_images[3])
    page.get_by_test_id("viewer-image").focus()
    page.keyboard.press("PageDown")
    assert viewer.get_attribute("data-keyframe") == str(with_images[4])
    shot(page, "image-viewer", docs=True)
    # Full screen, then out, then closed with Esc.
    page.get_by_test_id("viewer-fullscreen").click()
    page.wait_for_function("() => !!document.fullscreenElement && document.querySelector('[data-testid=image-viewer]').contains(document.fullscreenElement)")
    page.keyboard.press("Escape")
    page.wait_for_function("() => document.fullscreenElement === null")
    page.get_by_test_id("viewer-image").focus()
    page.keyboard.press("Escape")
    viewer.wait_for(state="hidden")
    assert not math.isnan(px[0])
