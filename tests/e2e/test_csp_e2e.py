"""The server's Content-Security-Policy in Chromium: the editor works under it (every other
browser test fails on a violation, see conftest.no_csp_violations), and a violation is seen."""

from __future__ import annotations

import time

import pytest

from tests.e2e.conftest import CSP_VIOLATIONS
from tests.e2e.helpers import login, open_run

pytestmark = pytest.mark.e2e


def _violations_within(seconds: float) -> list[str]:
    deadline = time.monotonic() + seconds
    while not CSP_VIOLATIONS and time.monotonic() < deadline:
        time.sleep(0.05)
    return list(CSP_VIOLATIONS)


def test_the_editor_runs_under_the_policy_and_a_violation_is_caught(server, context, run_id):
    page = context.new_page()
    response = page.goto(server.base_url + "/")
    assert "script-src 'self'" in response.headers["content-security-policy"]
    login(page, server, "op1")
    open_run(page, server, run_id)  # MapLibre's worker, tiles, style: all allowed
    assert page.evaluate("window.__posefixMap.loaded()")
    assert CSP_VIOLATIONS == []
    # An injected inline script and a foreign image are blocked and reported.
    page.evaluate("""() => {
        const s = document.createElement("script"); s.textContent = "window.__injected = 1"; document.head.append(s);
        const i = new Image(); i.src = "https://example.invalid/pixel.png"; document.body.append(i);
    }""")
    page.wait_for_timeout(300)
    found = _violations_within(5.0)
    assert page.evaluate("window.__injected === undefined")
    assert any("script-src" in v for v in found), found
    assert any("img-src" in v for v in found), found
    CSP_VIOLATIONS.clear()  # expected here: the autouse check must not fail this test
