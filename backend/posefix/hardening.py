"""HTTP hardening that applies to every response and every request body.

``SecurityHeadersMiddleware`` adds the browser-side defences: a Content-Security-Policy
fitted to the built front end (scripts, styles and MapLibre's worker from this origin only,
no inline script, images from this origin plus ``data:``/``blob:`` which MapLibre makes,
every fetch to this origin since tiles are proxied here), ``nosniff``, a same-origin
Referrer-Policy, no framing (``frame-ancestors 'none'`` and ``X-Frame-Options: DENY``), and
HSTS when the request came over HTTPS (directly or through a proxy uvicorn trusts).

``BodyTimeoutMiddleware`` drops a request whose body stops arriving: each read of the body
must deliver within ``body_idle_timeout_s``, and after that long the body must keep up an
average of ``body_min_rate_bps``, so a client that declares 1 GB and stalls (or trickles)
cannot hold a connection and a request thread. It answers 408 when no response has started.
"""

from __future__ import annotations

import time
from typing import Any

import anyio

__all__ = ["APP_CSP", "DOCS_CSP", "SecurityHeadersMiddleware", "BodyTimeoutMiddleware"]

APP_CSP = "; ".join([
    "default-src 'self'",
    "script-src 'self'",
    "style-src 'self'",
    "img-src 'self' data: blob:",
    "font-src 'self' data:",
    "connect-src 'self'",
    "worker-src 'self' blob:",
    "child-src 'self' blob:",
    "object-src 'none'",
    "base-uri 'none'",
    "form-action 'self'",
    "frame-ancestors 'none'",
])
# FastAPI's /docs and /redoc pages load Swagger UI / ReDoc from a CDN and start them with an
# inline script; they show no user content, so they alone get these.
DOCS_CSP = "; ".join([
    "default-src 'self'",
    "script-src 'self' 'unsafe-inline' https://cdn.jsdelivr.net",
    "style-src 'self' 'unsafe-inline' https://cdn.jsdelivr.net https://fonts.googleapis.com",
    "font-src 'self' https://fonts.gstatic.com",
    "img-src 'self' data: https://fastapi.tiangolo.com https://cdn.redoc.ly",
    "worker-src 'self' blob:",
    "connect-src 'self'",
    "object-src 'none'",
    "base-uri 'none'",
    "frame-ancestors 'none'",
])
DOCS_PATHS = frozenset({"/docs", "/docs/oauth2-redirect", "/redoc"})
HSTS = "max-age=31536000"


class SecurityHeadersMiddleware:
    def __init__(self, app: Any):
        self.app = app

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        extra = [
            (b"content-security-policy", (DOCS_CSP if scope.get("path") in DOCS_PATHS else APP_CSP).encode()),
            (b"x-content-type-options", b"nosniff"),
            (b"referrer-policy", b"same-origin"),
            (b"x-frame-options", b"DENY"),
            (b"cross-origin-opener-policy", b"same-origin"),
        ]
        if scope.get("scheme") == "https":
            extra.append((b"strict-transport-security", HSTS.encode()))

        async def send_with_headers(message: dict[str, Any]) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers") or [])
                present = {name.lower() for name, _ in headers}
                message["headers"] = headers + [(k, v) for k, v in extra if k not in present]
            await send(message)

        await self.app(scope, receive, send_with_headers)


class BodyTimeoutMiddleware:
    def __init__(self, app: Any, idle_timeout_s: float, min_rate_bps: float):
        self.app = app
        self.idle_timeout_s = idle_timeout_s
        self.min_rate_bps = min_rate_bps

    def _wait_s(self, waited_s: float, received: int) -> float:
        """How long the next piece of the body may take, given the time already spent waiting for it.

        Only time spent waiting on the client counts: a server slow to start reading (a busy
        thread pool, a queued database connection) must not turn into the client's 408."""
        if waited_s < self.idle_timeout_s or self.min_rate_bps <= 0:
            return self.idle_timeout_s
        # past the idle window the body must also keep its average rate up
        return max(0.0, min(self.idle_timeout_s, received / self.min_rate_bps - waited_s))

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        waited = 0.0
        received = 0
        body_done = False
        timed_out = False
        answered = False

        async def guarded_receive() -> dict[str, Any]:
            nonlocal received, body_done, timed_out, waited
            if body_done:  # e.g. a streamed response listening for the disconnect: no limit
                return await receive()
            wait_s = self._wait_s(waited, received)
            asked = time.monotonic()
            try:
                if wait_s <= 0:
                    raise TimeoutError
                with anyio.fail_after(wait_s):
                    message = await receive()
            except TimeoutError:
                timed_out = True
                raise BodyTimeout() from None
            finally:
                waited += time.monotonic() - asked
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                body_done = not message.get("more_body", False)
            else:
                body_done = True
            return message

        async def guarded_send(message: dict[str, Any]) -> None:
            nonlocal answered
            # Whatever the route made of the interrupted body (FastAPI turns it into a 400),
            # the client is told the truth, once, and the connection closes.
            if timed_out:
                if not answered:
                    answered = True
                    await _send_timeout(send)
                return
            answered = answered or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, guarded_receive, guarded_send)
        except Exception:
            if not timed_out:
                raise
        if timed_out and not answered:
            await _send_timeout(send)


class BodyTimeout(Exception):
    """The request body stopped arriving (see BodyTimeoutMiddleware)."""


async def _send_timeout(send: Any) -> None:
    body = b'{"error":"request_timeout","detail":"the request body stopped arriving; the connection is closed"}'
    await send({
        "type": "http.response.start", "status": 408,
        "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                    (b"connection", b"close")],
    })
    await send({"type": "http.response.body", "body": body})
