"""Admin pages in Chromium: upload a run with progress and see it listed with its status;
list, add and remove tile sources; operators see no admin pages."""

from __future__ import annotations

import re

import pytest

from tests.e2e.helpers import login, shot

pytestmark = pytest.mark.e2e


def test_admin_uploads_run_with_progress_and_sees_it_listed(server, context):
    page = context.new_page()
    login(page, server, "admin")
    page.get_by_role("link", name="Runs (admin)").click()
    page.get_by_label("Name").fill("uploaded from the browser")
    page.get_by_label(re.compile("Run file")).set_input_files(str(server.run_csv))
    page.get_by_label(re.compile("Images")).set_input_files(str(server.images_zip))
    page.get_by_role("button", name="Upload").click()
    status = page.get_by_role("status").filter(has_text="Uploaded")
    status.wait_for(timeout=60_000)
    assert "“uploaded from the browser”" in status.inner_text()
    assert page.evaluate("document.querySelector('progress').value") in (0, 1)
    row = page.get_by_test_id("admin-runs-table").get_by_role("row").filter(has_text="uploaded from the browser")
    row.wait_for()
    assert re.search(r"imported|in_review|corrected|accepted", row.inner_text())
    shot(page, "admin-runs")


def test_admin_lists_adds_and_removes_tile_sources(server, context):
    page = context.new_page()
    login(page, server, "admin")
    page.goto(server.base_url + "/#/admin/tiles")
    table = page.get_by_test_id("tiles-table")
    table.wait_for()
    text = table.inner_text()
    assert "Helsinki streets" in text and "Toner" in text and "© OpenStreetMap contributors" in text
    page.get_by_label("Name (in tile URLs)").fill("e2e-upstream")
    page.get_by_label("Kind").select_option("satellite")
    page.get_by_label("Origin").select_option("url")
    page.get_by_label("File path or URL template").fill("http://127.0.0.1:9/{z}/{x}/{y}.png")
    page.get_by_label("Attribution").fill("e2e imagery")
    page.get_by_role("button", name="Add").click()
    page.get_by_role("status").filter(has_text="Added e2e-upstream").wait_for()
    table.get_by_role("row").filter(has_text="e2e-upstream").wait_for()
    shot(page, "admin-tiles")
    page.once("dialog", lambda d: d.accept())
    page.get_by_role("button", name="Remove tile source e2e-upstream").click()
    table.get_by_role("row").filter(has_text="e2e-upstream").wait_for(state="detached")


def test_operator_sees_no_admin_pages(server, context):
    page = context.new_page()
    login(page, server, "op1")
    nav = page.get_by_role("navigation", name="Main").inner_text()
    assert "My runs" in nav and "admin" not in nav.lower() and "Tile sources" not in nav
