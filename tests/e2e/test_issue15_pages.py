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
