"""End-to-end fixtures: a real `posefix serve` on a temporary SQLite database (see
serverkit.py) and Debian's Chromium driven by Playwright. The server starts once per test
session; each test that edits gets its own freshly uploaded run so tests never depend on
each other's revisions."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.e2e.serverkit import ARTIFACTS, PASSWORD, Server, add_camera_images, chromium, ensure_frontend_built, running_server

__all__ = ["ARTIFACTS", "PASSWORD"]

# Rules that make every refusal reachable from the browser.
RULES_TOML = """
[rules]
every_n = 2
lock_n = 2
lock_direction = "forward"
max_move_m = 25.0
order_rule = "refuse"
"""


@dataclass
class E2EServer:
    srv: Server
    run_csv: Path
    images_zip: Path

    @property
    def base_url(self) -> str:
        return self.srv.base_url

    def get_json(self, username: str, path: str):
        return self.srv.get_json(username, path)

    def upload_run(self, name: str) -> int:
        return self.srv.upload_run(name, self.run_csv, self.images_zip)


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory):
    ensure_frontend_built()
    with running_server(tmp_path_factory.mktemp("e2e"), RULES_TOML) as srv:
        # A 90 s drive through Helsinki (about 90 keyframes) with two cameras every 2 s.
        sim = srv.simulate("sim", duration_s=90, rate_hz=10, seed=3)
        run_csv, images_zip = add_camera_images(sim)
        yield E2EServer(srv, run_csv, images_zip)


# Every document reports a Content-Security-Policy violation to the console, where the
# context's listener (and Chromium's own "Refused to ..." messages) are collected.
_REPORT_CSP_VIOLATIONS = """
document.addEventListener("securitypolicyviolation", (e) => {
  console.error(`Content Security Policy violation: ${e.effectiveDirective} blocked ${e.blockedURI || "inline"}`
    + ` at ${e.sourceFile}:${e.lineNumber}`);
});
"""
CSP_VIOLATIONS: list[str] = []


def _watch_csp(ctx) -> None:
    ctx.add_init_script(_REPORT_CSP_VIOLATIONS)

    def on_console(message) -> None:
        if "Content Security Policy" in message.text or "Content-Security-Policy" in message.text:
            CSP_VIOLATIONS.append(f"{message.page.url if message.page else '?'}: {message.text}")

    ctx.on("console", on_console)


class CspWatchedBrowser:
    """The Playwright browser, but every context it makes reports CSP violations."""

    def __init__(self, browser):
        self._browser = browser

    def new_context(self, **kwargs):
        ctx = self._browser.new_context(**kwargs)
        _watch_csp(ctx)
        return ctx

    def new_page(self, **kwargs):
        return self.new_context(**kwargs).new_page()

    def __getattr__(self, name):
        return getattr(self._browser, name)


@pytest.fixture(scope="session")
def browser():
    with chromium() as b:
        yield CspWatchedBrowser(b)


@pytest.fixture(autouse=True)
def no_csp_violations():
    """A test whose pages broke the server's Content-Security-Policy fails."""
    CSP_VIOLATIONS.clear()
    yield
    found, CSP_VIOLATIONS[:] = list(CSP_VIOLATIONS), []
    if found:
        pytest.fail("Content-Security-Policy violations:\n" + "\n".join(found[:20]), pytrace=False)


@pytest.fixture
def context(browser, request):
    ctx = browser.new_context(viewport={"width": 1280, "height": 800}, locale="en-GB")
    yield ctx
    rep = getattr(request.node, "rep_call", None)
    if rep is not None and rep.failed:
        ARTIFACTS.mkdir(exist_ok=True)
        for i, pg in enumerate(ctx.pages):
            try:
                pg.screenshot(path=str(ARTIFACTS / f"FAILED-{request.node.name}-{i}.png"))
            except Exception:  # noqa: BLE001 - best effort on the way out
                pass
    ctx.close()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    rep = outcome.get_result()
    setattr(item, "rep_" + rep.when, rep)


@pytest.fixture
def run_id(server, request) -> int:
    return server.upload_run(f"e2e {request.node.name}")
