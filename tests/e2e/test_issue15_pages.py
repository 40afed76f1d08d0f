"""Issue 15's page-level items in Chromium: the upload picker offers the server's own list of
file types, and the header fits a phone."""

from __future__ import annotations

import pytest

from tests.e2e.helpers import login, shot

pytestmark = pytest.mark.e2e


def test_upload_picker_offers_what_the_server_accepts(server, browser):
    formats = server.get_json("admin", "/api/v1/upload-formats")
    page = browser.new_page()
    login(page, server, "admin")
    page.goto(server.base_url + "/#/admin/runs")
    page.get_by_test_id("run-extensions").filter(has_text=".csv").wait_for()
    offered = page.locator("#up-file").get_attribute("accept").split(",")
    assert offered == formats["run"] and ".kitti" not in offered and ".parquet" in offered
    assert page.locator("#up-images").get_attribute("accept").split(",") == [".zip", *formats["images"]]
    page.close()


@pytest.mark.parametrize("who", ["admin", "op1"])
def test_header_fits_a_phone(server, browser, who):
    page = browser.new_page(viewport={"width": 360, "height": 740}, is_mobile=True, has_touch=True)
    login(page, server, who)
    outside = page.evaluate(
        """() => [...document.querySelectorAll('header.topbar a, header.topbar button, header.topbar [data-testid=whoami]')]
            .map(e => [e.textContent.trim(), e.getBoundingClientRect()])
            .filter(([, r]) => r.left < 0 || r.right > window.innerWidth + 0.5)
            .map(([t]) => t)"""
    )
    assert outside == []
    assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth")
    if who == "admin":
        shot(page, "header-phone")
    page.close()


def test_floor_page_draws_the_floor_and_the_replayed_walk_on_a_maplibre_map(server, browser, tmp_path):
    import zipfile

    from tests.e2e.test_maps_e2e import FLOOR, WALK

    zpath = tmp_path / "floor.zip"
    with zipfile.ZipFile(zpath, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in ("floor_info.json", "geojson_map.json", "floor_image.png"):
            zf.write(FLOOR / name, f"site1/F1/{name}")
    page = browser.new_page(viewport={"width": 1400, "height": 1000})
    login(page, server, "admin")
    page.goto(server.base_url + "/#/floors")
    page.get_by_label("Floor plan name").fill("Map F1")
    page.get_by_test_id("floor-file").set_input_files(str(zpath))
    page.get_by_test_id("floor-upload").click()
    page.wait_for_function("() => document.querySelector('[data-testid=floor-upload-msg]').textContent.includes('built')", timeout=60_000)
    page.get_by_test_id("floor-row").filter(has_text="Map F1").get_by_role("link", name="Map F1").click()
    page.wait_for_selector("[data-testid=floor-map][data-ready='true']", timeout=30_000)
    # The floor image is placed on the map (its own metric frame: this floor has no georeference).
    page.wait_for_function("() => { const m = window.__posefixFloorMap; const s = m.getSource('floor-image');"
                           " return s && s.loaded() && m.getLayer('floor-image') && m.loaded(); }", timeout=30_000)
    page.get_by_test_id("walk-file").set_input_files(str(WALK))
    page.get_by_test_id("walk-track").click()
    page.get_by_test_id("error-mean").wait_for(timeout=30_000)
    last = int(page.get_by_test_id("replay-scrub").get_attribute("max"))
    page.get_by_test_id("replay-scrub").fill(str(last // 2))
    drawn = page.evaluate("""() => { const d = window.__posefixFloorMap.getSource('floor-walk')._data; const g = d.geojson || d;
        const by = (k) => g.features.find(f => f.properties.kind === k);
        return [by('matched').geometry.coordinates.length, by('dr').geometry.coordinates.length, !!by('position')]; }""")
    assert drawn[0] == last // 2 + 1 and drawn[1] > 1 and drawn[2], drawn
    assert page.get_by_test_id("floor-map").get_attribute("data-step") == str(last // 2)
    page.wait_for_function("() => window.__posefixFloorMap.queryRenderedFeatures({layers: ['floor-matched']}).length > 0")
    page.get_by_test_id("floor-map").scroll_into_view_if_needed()
    shot(page, "floor-map", docs=True)
    page.close()
