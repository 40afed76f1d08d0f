"""The editor's remaining issue-15 items in Chromium: the order rule against unmoved
neighbours, keyboard nudges, a preview against a stale revision, labels and visible focus."""

from __future__ import annotations

import json
import math

import pytest

from tests.e2e.helpers import drag, keyframe_px, login, open_run, zoom_to
from tests.e2e.test_editor import displayed, editor_data, refusal, status_of, wait_preview, wait_unsaved
from tests.e2e.test_issue15 import api_move

pytestmark = pytest.mark.e2e


def along_track_px(page, index: int, beyond: int, fraction: float) -> tuple[float, float]:
    """Page coordinates `fraction` of a step past keyframe `beyond`, going from `index` to it."""
    xy = page.evaluate(
        """([i, j, f]) => { const m = window.__posefixMap; const g = m.getSource('pf-keyframes')._data;
            const fs = (g.geojson || g).features; const a = fs[i].geometry.coordinates, b = fs[j].geometry.coordinates;
            const p = m.project([b[0] + (b[0] - a[0]) * f, b[1] + (b[1] - a[1]) * f]);
            const r = m.getCanvas().getBoundingClientRect(); return [r.left + p.x, r.top + p.y]; }""",
        [index, beyond, fraction],
    )
    return xy[0], xy[1]


def east_north_m(a: list[float], b: list[float]) -> tuple[float, float]:
    k = 111320 * math.cos(math.radians(a[1]))
    return (b[0] - a[0]) * k, (b[1] - a[1]) * 111320


def test_dragging_past_an_unmoved_neighbour_is_refused(server, browser, run_id):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    login(page, server)
    open_run(page, server, run_id)
    zoom_to(page, 10, zoom=18.5)
    # Keyframe 11 stays where it was reported; 10 dropped past it would run the poses backwards.
    drag(page, keyframe_px(page, 10), along_track_px(page, 10, 11, 0.6))
    reason, text = refusal(page)
    assert reason == "order_reversed" and "keyframe 11" in text and "backwards" in text
    assert editor_data(page, "unsaved") == "0"
    page.close()


def test_arrow_keys_nudge_the_selected_keyframe_as_one_undo_step(server, browser, run_id):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    login(page, server)
    open_run(page, server, run_id)
    zoom_to(page, 10, zoom=18)
    before = displayed(page, 10)
    page.mouse.click(*keyframe_px(page, 10))
    assert "#10" in page.get_by_test_id("selection-info").inner_text()
    page.keyboard.press("ArrowRight")
    page.keyboard.press("ArrowRight")
    page.keyboard.press("Shift+ArrowUp")
    wait_unsaved(page, 1)
    wait_preview(page)
    assert status_of(page, 10) == "moved" and status_of(page, 11) == "locked"
    saved = json.loads(page.evaluate(f"localStorage.getItem('posefix.unsaved.{run_id}')"))
    move = next(m for m in saved["body"]["moves"] if m["index"] == 10)
    east, north = east_north_m(before, [move["lon"], move["lat"]])
    assert abs(east - 1.0) < 0.05 and abs(north - 5.0) < 0.05, (east, north)
    assert "Nudge keyframe 10" in page.get_by_test_id("undo").get_attribute("title")
    page.keyboard.press("Control+z")  # the three nudges are one step
    wait_unsaved(page, 0)
    # A nudge the rules refuse is shown where the keyframe would have gone (11 is not adjustable).
    page.keyboard.press(".")
    assert "#11" in page.get_by_test_id("selection-info").inner_text()
    page.keyboard.press("ArrowDown")
    reason, _ = refusal(page)
    assert reason == "not_adjustable" and editor_data(page, "unsaved") == "0"
    page.close()


def test_every_control_has_a_name_and_focus_is_visible(server, browser, run_id):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    login(page, server)
    open_run(page, server, run_id)
    unnamed = page.evaluate(
        """() => [...document.querySelectorAll('.editor button, .editor input, .editor select, .editor [tabindex], header a, header button')]
            .filter(e => e.offsetParent !== null)
            .filter(e => !(e.getAttribute('aria-label') || (e.labels && e.labels.length) || e.getAttribute('aria-labelledby')
                          || e.textContent.trim() || e.getAttribute('title')))
            .map(e => e.outerHTML.slice(0, 80))"""
    )
    assert unnamed == []
    page.get_by_test_id("undo").focus()
    for _ in range(4):  # from the toolbar on, every stop shows where the focus is
        page.keyboard.press("Tab")
        outline = page.evaluate("() => { const s = getComputedStyle(document.activeElement); return [s.outlineStyle, s.outlineWidth]; }")
        assert outline[0] != "none" and outline[1] != "0px", outline
    page.close()


def test_a_preview_on_a_stale_revision_shows_the_conflict(server, browser, run_id):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    login(page, server)
    open_run(page, server, run_id)
    zoom_to(page, 14, zoom=18)
    page.mouse.click(*keyframe_px(page, 14))
    page.keyboard.press("ArrowRight")
    wait_unsaved(page, 1)
    wait_preview(page)
    api_move(server, "op2", run_id, 30, 3.0, "someone else first")  # revision 1, made on revision 0
    page.keyboard.press("ArrowRight")  # the next preview is on revision 0, no longer the latest
    conflict = page.get_by_test_id("conflict")
    conflict.wait_for(timeout=15_000)
    assert "Someone saved revision 1 while you were editing revision 0" in conflict.inner_text()
    page.close()


def test_a_notice_leaves_when_the_state_it_describes_changes(server, browser, run_id):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    login(page, server)
    open_run(page, server, run_id)
    zoom_to(page, 10, zoom=18)
    page.mouse.click(*keyframe_px(page, 10))
    page.keyboard.press("ArrowRight")
    wait_unsaved(page, 1)
    page.get_by_test_id("submit").click()
    notices = page.get_by_test_id("notices")
    notices.filter(has_text="Submitted. Revision 1 is ready.").wait_for(timeout=60_000)
    assert page.get_by_test_id("submit-msg").inner_text() == "Saved as revision 1."
    page.mouse.click(*keyframe_px(page, 20))
    page.keyboard.press("ArrowUp")  # a new unsaved edit: "saved" and "ready" no longer describe the screen
    wait_unsaved(page, 1)
    assert notices.inner_text().strip() == "" and page.get_by_test_id("submit-msg").inner_text() == ""
    page.close()
