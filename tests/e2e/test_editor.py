"""The correction view in Chromium against a real server: log in, open a run, drag a keyframe
and see the re-optimised preview, hit each refusal, undo/redo, delete a range, submit and
see the new revision, a stale second tab's conflict screen, the images panel, keyboard use,
a failed submit that loses nothing, and a touch drag on a tablet-sized screen."""

from __future__ import annotations

import re

import pytest

from tests.e2e.helpers import drag, keyframe_px, login, metres_px, open_run, shot, zoom_to

pytestmark = pytest.mark.e2e


def editor_data(page, key: str) -> str:
    return page.evaluate(f"document.querySelector('.editor').dataset.{key}")


def wait_unsaved(page, n: int) -> None:
    page.wait_for_function(f"() => document.querySelector('.editor').dataset.unsaved === '{n}'", timeout=15_000)


def wait_preview(page) -> None:
    page.wait_for_function("() => document.querySelector('.editor').dataset.previewCurrent === 'true'", timeout=30_000)


def wait_revision(page, n: int) -> None:
    page.wait_for_function(f"() => document.querySelector('.editor').dataset.revision === '{n}'", timeout=60_000)


def displayed(page, index: int) -> list[float]:
    return page.evaluate(
        "(i) => { const f = window.__posefixMap.getSource('pf-keyframes')._data; return (f.geojson || f).features[i].geometry.coordinates; }",
        index,
    )


def status_of(page, index: int) -> str:
    return page.evaluate(
        "(i) => { const f = window.__posefixMap.getSource('pf-keyframes')._data; return (f.geojson || f).features[i].properties.s; }",
        index,
    )


def refusal(page) -> tuple[str, str]:
    box = page.get_by_test_id("refusal")
    box.wait_for(timeout=10_000)
    return box.get_attribute("data-reason"), box.inner_text()


def close_refusal(page) -> None:
    page.keyboard.press("Escape")
    page.get_by_test_id("refusal").wait_for(state="detached", timeout=5_000)


def move(page, index: int, east_m: float, north_m: float) -> None:
    drag(page, keyframe_px(page, index), metres_px(page, index, east_m, north_m))


class TestLoginAndOpen:
    def test_bad_password_then_login_lists_runs_and_opens_editor(self, server, context, run_id):
        page = context.new_page()
        page.goto(server.base_url + "/")
        page.wait_for_url(re.compile(r"#/login"))
        page.get_by_label("Username").fill("op1")
        page.get_by_label("Password").fill("wrong-password")
        page.get_by_role("button", name="Log in").click()
        page.get_by_role("alert").filter(has_text=re.compile(r"\w")).wait_for()
        login(page, server)
        page.get_by_test_id("runs-table").get_by_role("link", name=f"e2e {self.test_bad_password_then_login_lists_runs_and_opens_editor.__name__}").click()
        open_run(page, server, run_id)
        assert editor_data(page, "revision") == "0"
        legend = page.get_by_role("group", name="Legend")
        assert "Adjustable" in legend.inner_text() and "Locked" in legend.inner_text()
        # The basemap switcher shows one source at a time.
        page.get_by_label(re.compile("Toner")).check()
        vis = page.evaluate("""() => { const m = window.__posefixMap; const s = m.getStyle();
            const byKind = {}; for (const l of s.layers) { const src = l.source; if (!src || src.startsWith('pf-')) continue;
              byKind[src] = byKind[src] || (m.getLayoutProperty(l.id, 'visibility') !== 'none'); } return byKind; }""")
        assert vis == {"helsinki": False, "toner": True}
        page.get_by_label(re.compile("Helsinki streets")).check()
        assert page.locator(".maplibregl-ctrl-attrib").inner_text().count("OpenStreetMap") >= 1
        shot(page, "editor-overview", docs=True)


class TestDragPreviewUndoSubmit:
    def test_drag_shows_preview_locks_next_then_undo_redo_and_submit(self, server, context, run_id):
        page = context.new_page()
        login(page, server)
        open_run(page, server, run_id)
        zoom_to(page, 10)
        before5 = displayed(page, 5)
        # Follow the pointer while dragging (staging), before the drop.
        start = keyframe_px(page, 10)
        end = metres_px(page, 10, 6, 8)
        page.mouse.move(*start)
        page.mouse.down()
        page.mouse.move(end[0], end[1], steps=8)
        page.wait_for_function("() => { const f = window.__posefixMap.getSource('pf-staging')._data; return (f.geojson || f).features.length === 2; }")
        assert editor_data(page, "unsaved") == "0"  # staged, not yet an edit
        page.mouse.up()
        wait_unsaved(page, 1)
        wait_preview(page)
        # The re-optimised preview moved the neighbours too; the next two keyframes lock.
        after5 = displayed(page, 5)
        assert after5 != before5
        assert status_of(page, 10) == "moved"
        assert status_of(page, 11) == "locked" and status_of(page, 12) == "locked"
        assert re.search(r"last solver time \d+ ms", page.get_by_test_id("statusbar").inner_text())
        assert "Move keyframe 10" in page.get_by_test_id("undo").get_attribute("title")
        shot(page, "drag-preview", docs=True)
        page.get_by_test_id("ghost").click()
        assert page.evaluate("window.__posefixMap.getLayoutProperty('pf-ghost-line', 'visibility')") == "none"
        page.get_by_test_id("ghost").click()

        page.get_by_test_id("undo").click()
        wait_unsaved(page, 0)
        assert status_of(page, 10) == "adjustable"
        page.get_by_test_id("redo").click()
        wait_unsaved(page, 1)
        wait_preview(page)

        page.get_by_label("Comment for this submission").fill("e2e: moved keyframe 10")
        page.get_by_test_id("submit").click()
        wait_revision(page, 1)
        assert "Revision 1" in page.get_by_test_id("statusbar").inner_text()
        assert editor_data(page, "unsaved") == "0"
        assert page.get_by_test_id("submit-msg").inner_text() == "Saved as revision 1."
        revs = server.get_json("op1", f"/api/v1/runs/{run_id}/revisions")
        assert sorted(r["number"] for r in revs["items"]) == [0, 1]
        assert revs["items"][-1]["n_moves"] == 1 or any(r["n_moves"] == 1 for r in revs["items"])
        # The edited keyframe comes back as edited, and keeps its neighbours locked.
        open_run(page, server, run_id)
        assert status_of(page, 10) == "moved" and status_of(page, 11) == "locked"
        shot(page, "after-submit")


class TestPredictedAccuracy:
    def test_revision_shows_the_predicted_rmse_and_the_one_sigma_band(self, server, context, run_id):
        # four edits saved through the API (the editor's drag is tested above), then the editor shows
        # the model the held-out edits chose, the RMSE it predicts, and the 1-sigma band on the chart
        import math
        import time

        c = server.srv.client("admin")
        try:
            fc = c.get(f"/api/v1/runs/{run_id}/keyframes").json()
            xy = [f["geometry"]["coordinates"] for f in fc["features"]]
            m_lon = 1.0 / (111_320.0 * math.cos(math.radians(xy[0][1])))
            moves = [{"index": i, "lon": xy[i][0] + (3.0 + i % 5) * m_lon, "lat": xy[i][1]} for i in (6, 20, 36, 50)]
            r = c.post(f"/api/v1/runs/{run_id}/edits", json={"base_revision": 0, "moves": moves})
            assert r.status_code == 202, r.text
            deadline = time.time() + 60
            while c.get(f"/api/v1/runs/{run_id}/keyframes?revision=1").status_code != 200:
                assert time.time() < deadline, "revision 1 never became ready"
                time.sleep(0.3)
        finally:
            c.close()
        page = context.new_page()
        login(page, server)
        open_run(page, server, run_id)
        wait_revision(page, 1)
        page.wait_for_function("() => document.querySelector('canvas.chart').dataset.band === '1sigma'", timeout=15_000)
        text = page.get_by_test_id("drift").inner_text()
        assert re.search(r"Model: \w+, cross-validated RMSE \d+\.\d\d m at held-out edits; predicted RMSE along the run \d+\.\d\d m\.", text), text
        shot(page, "predicted-band")


class TestRefusals:
    def test_each_refusal_is_shown_where_dropped_and_the_marker_returns(self, server, context, run_id):
        page = context.new_page()
        login(page, server)
        open_run(page, server, run_id)
        zoom_to(page, 6)

        # Not adjustable: only every 2nd keyframe may move.
        orig3 = displayed(page, 3)
        move(page, 3, 0, 5)
        reason, text = refusal(page)
        assert reason == "not_adjustable" and "every 2th" in text or "every 2" in text
        assert displayed(page, 3) == orig3 and editor_data(page, "unsaved") == "0"
        shot(page, "refusal-not-adjustable")
        close_refusal(page)

        # Too far: the limit is 25 m from the reported position.
        move(page, 4, 0, 40)
        reason, text = refusal(page)
        assert reason == "too_far" and "the limit is 25 m" in text
        assert editor_data(page, "unsaved") == "0"
        shot(page, "refusal-too-far", docs=True)
        close_refusal(page)

        # Locked: a move locks the next two keyframes.
        move(page, 4, 2, 3)
        wait_unsaved(page, 1)
        wait_preview(page)
        move(page, 6, 0, 3)
        reason, text = refusal(page)
        assert reason == "locked" and "locked" in text
        assert editor_data(page, "unsaved") == "1"
        close_refusal(page)

        # Order: keyframe 8 dropped behind the moved keyframe 4 would reverse the poses.
        p4 = page.evaluate("() => window.__posefixMap.getSource('pf-keyframes')._data")  # noqa: F841 - ensure data present
        target = page.evaluate(
            """() => { const m = window.__posefixMap; const f = m.getSource('pf-keyframes')._data; const fs = (f.geojson || f).features;
                const a = fs[4].geometry.coordinates, b = fs[8].geometry.coordinates;
                // 3 m behind keyframe 4, along the direction 8 -> 4.
                const dx = a[0] - b[0], dy = a[1] - b[1]; const k = Math.cos(a[1] * Math.PI / 180);
                const len = Math.hypot(dx * k, dy) * 111320; const s = 1 + 3 / len;
                const p = m.project([b[0] + dx * s, b[1] + dy * s]); const r = m.getCanvas().getBoundingClientRect();
                return [r.left + p.x, r.top + p.y]; }"""
        )
        drag(page, keyframe_px(page, 8), (target[0], target[1]))
        reason, text = refusal(page)
        assert reason == "order_reversed" and "backwards" in text
        assert editor_data(page, "unsaved") == "1"
        shot(page, "refusal-order")
        close_refusal(page)

        # Deleted: a keyframe marked for deletion cannot also be moved.
        page.evaluate("() => 0")
        page.keyboard.press("Escape")
        for _ in range(13):
            page.keyboard.press(".")
        assert "#12" in page.get_by_test_id("selection-info").inner_text()
        page.get_by_test_id("delete").click()
        wait_unsaved(page, 2)
        move(page, 12, 0, 3)
        reason, _ = refusal(page)
        assert reason == "deleted"
        close_refusal(page)


class TestDeleteRangeAcceptReset:
    def test_range_deletion_accept_reset_are_undoable_steps(self, server, context, run_id):
        page = context.new_page()
        login(page, server)
        open_run(page, server, run_id)
        zoom_to(page, 22, zoom=17.5)
        page.get_by_test_id("delete-range").click()
        page.mouse.click(*keyframe_px(page, 20))
        page.mouse.click(*keyframe_px(page, 24))
        page.get_by_test_id("range-yes").click()
        wait_unsaved(page, 5)
        assert [status_of(page, i) for i in range(19, 26)] == ["fixed", "deleted", "deleted", "deleted", "deleted", "deleted", "fixed"]
        assert "Delete keyframes 20–24" in page.get_by_test_id("undo").get_attribute("title")
        wait_preview(page)
        shot(page, "delete-range")
        page.get_by_test_id("accept").click()
        wait_unsaved(page, 1)
        assert status_of(page, 20) == "adjustable"
        page.get_by_test_id("reset").click()
        wait_unsaved(page, 0)
        page.keyboard.press("Control+z")
        wait_unsaved(page, 1)
        page.keyboard.press("Control+z")
        wait_unsaved(page, 5)
        page.keyboard.press("Control+Shift+z")
        wait_unsaved(page, 1)
        page.get_by_test_id("submit").click()
        wait_revision(page, 1)


class TestConflict:
    def test_stale_second_tab_sees_conflict_and_reapplies(self, server, browser, run_id):
        ctx1 = browser.new_context(viewport={"width": 1280, "height": 800})
        ctx2 = browser.new_context(viewport={"width": 1280, "height": 800})
        try:
            a, b = ctx1.new_page(), ctx2.new_page()
            login(a, server, "op1")
            login(b, server, "op2")
            open_run(a, server, run_id)
            open_run(b, server, run_id)
            zoom_to(a, 30)
            zoom_to(b, 40)
            move(b, 40, 3, 3)
            wait_unsaved(b, 1)
            b.get_by_test_id("submit").click()
            wait_revision(b, 1)

            # The first tab had nothing unsaved: it shows revision 1 by itself (server-sent event).
            wait_revision(a, 1)
            assert "Revision 1 was saved by someone else" in a.get_by_test_id("notices").inner_text()
            # Now make it stale: op2 saves revision 2 while op1 has an unsaved move.
            move(a, 30, -3, 2)
            wait_unsaved(a, 1)
            zoom_to(b, 50)
            move(b, 50, 2, 2)
            wait_unsaved(b, 1)
            b.get_by_test_id("submit").click()
            wait_revision(b, 2)
            a.get_by_test_id("newer").filter(has_text="Revision 2 was saved by someone else").wait_for(timeout=15_000)
            a.get_by_test_id("submit").click()
            dialog = a.get_by_test_id("conflict")
            dialog.wait_for(timeout=15_000)
            text = dialog.inner_text()
            assert "changed since you opened it" in text and "revision 2" in text and "1 unsaved edit is kept" in text
            shot(a, "conflict", docs=True)
            a.get_by_test_id("conflict-reapply").click()
            wait_revision(a, 2)
            wait_unsaved(a, 1)
            assert status_of(a, 30) == "moved" and status_of(a, 40) == "moved" and status_of(a, 50) == "moved"
            a.get_by_test_id("submit").click()
            wait_revision(a, 3)
        finally:
            ctx1.close()
            ctx2.close()


class TestImagesAndKeyboard:
    def test_right_click_opens_images_with_cameras_time_and_position(self, server, context, run_id):
        page = context.new_page()
        login(page, server)
        open_run(page, server, run_id)
        idx = page.evaluate(
            "() => { const f = window.__posefixMap.getSource('pf-keyframes')._data; return 2; }"
        )
        zoom_to(page, idx)
        x, y = keyframe_px(page, idx)
        page.mouse.click(x, y, button="right")
        panel = page.get_by_test_id("images-panel")
        panel.wait_for()
        assert f"keyframe #{idx}" in panel.inner_text()
        assert page.get_by_test_id("image-count").inner_text() == "Camera image 1 of 2"
        page.wait_for_function("() => { const i = document.querySelector('[data-testid=image]'); return i && i.complete && i.naturalWidth === 320; }")
        meta = page.get_by_test_id("image-meta").inner_text()
        assert re.search(r"[\d.]+ s into the run .*UTC\) · 60\.\d{6}, 24\.\d{6}", meta)
        page.get_by_role("button", name="Next camera image").click()
        assert page.get_by_test_id("image-count").inner_text() == "Camera image 2 of 2"
        page.get_by_test_id("image").hover()
        page.mouse.wheel(0, 120)
        assert page.get_by_test_id("image-count").inner_text() == "Camera image 1 of 2"
        shot(page, "images-panel", docs=True)

    def test_keyboard_moves_selection_and_undoes(self, server, context, run_id):
        page = context.new_page()
        login(page, server)
        open_run(page, server, run_id)
        page.locator("#map").focus()
        page.keyboard.press(".")
        assert "#0" in page.get_by_test_id("selection-info").inner_text()
        page.keyboard.press(".")
        assert "#1" in page.get_by_test_id("selection-info").inner_text()
        page.keyboard.press("a")
        assert "#2" in page.get_by_test_id("selection-info").inner_text()
        page.keyboard.press(",")
        assert "#1" in page.get_by_test_id("selection-info").inner_text()
        page.keyboard.press("Delete")
        wait_unsaved(page, 1)
        page.keyboard.press("Control+z")
        wait_unsaved(page, 0)
        page.keyboard.press("Control+y")
        wait_unsaved(page, 1)
        page.keyboard.press("i")
        page.get_by_test_id("images-panel").wait_for()
        # Every control is reachable with Tab and has a name.
        names = page.evaluate("""() => [...document.querySelectorAll('.toolbar button, .toolbar input')]
            .map(e => e.getAttribute('aria-label') || e.textContent.trim()).filter(n => !n)""")
        assert names == []


class TestFailuresLoseNothing:
    def test_failed_submit_keeps_edits_and_reload_restores_them(self, server, context, run_id):
        page = context.new_page()
        login(page, server)
        open_run(page, server, run_id)
        zoom_to(page, 14)
        move(page, 14, 3, -2)
        wait_unsaved(page, 1)
        wait_preview(page)
        page.route(re.compile(r".*/api/v1/runs/\d+/edits$"), lambda route: route.abort("connectionrefused"))
        page.get_by_test_id("submit").click()
        msg = page.get_by_test_id("submit-msg")
        page.wait_for_function("() => document.querySelector('[data-testid=submit-msg]').textContent.includes('Cannot reach the server')")
        assert "Your edits are kept" in msg.inner_text()
        assert editor_data(page, "unsaved") == "1"
        page.unroute(re.compile(r".*/api/v1/runs/\d+/edits$"))
        # A server error on preview is shown plainly.
        page.route(re.compile(r".*/preview$"), lambda route: route.fulfill(status=500, json={"error": "internal", "detail": "boom"}))
        move(page, 20, 0, 3)
        page.get_by_test_id("error").wait_for()
        assert "Preview failed: The server failed (500): boom" in page.get_by_test_id("error").inner_text()
        page.unroute(re.compile(r".*/preview$"))
        shot(page, "error-shown")
        # Reloading the page restores the unsaved edits from this browser.
        page.reload()
        open_run(page, server, run_id)
        wait_unsaved(page, 2)
        assert "Restored 2 unsaved edits" in page.get_by_test_id("notices").inner_text()
        page.get_by_test_id("submit").click()
        wait_revision(page, 1)


class TestTablet:
    def test_touch_drag_on_tablet(self, server, browser, run_id):
        ctx = browser.new_context(viewport={"width": 1024, "height": 768}, has_touch=True, is_mobile=False)
        try:
            page = ctx.new_page()
            login(page, server)
            open_run(page, server, run_id)
            zoom_to(page, 16)
            sx, sy = keyframe_px(page, 16)
            ex, ey = metres_px(page, 16, 4, 4)
            cdp = ctx.new_cdp_session(page)
            cdp.send("Input.dispatchTouchEvent", {"type": "touchStart", "touchPoints": [{"x": sx, "y": sy}]})
            for i in range(1, 11):
                f = i / 10
                cdp.send("Input.dispatchTouchEvent", {"type": "touchMove", "touchPoints": [{"x": sx + (ex - sx) * f, "y": sy + (ey - sy) * f}]})
            cdp.send("Input.dispatchTouchEvent", {"type": "touchEnd", "touchPoints": []})
            wait_unsaved(page, 1)
            wait_preview(page)
            assert status_of(page, 16) == "moved"
            shot(page, "tablet-touch-drag", docs=True)
        finally:
            ctx.close()
