"""Requests to upstream tile servers that cannot be aimed inward.

An admin registers an upstream by URL, and every user's tile request makes the server fetch
from it, so a careless or hostile URL would let the server probe its own network. Hence:

- every new connection resolves the host itself and refuses it when any address is loopback,
  private, link-local, shared (CGNAT), multicast, reserved or unspecified, IPv4 or IPv6
  (IPv4-mapped and 6to4 addresses are judged by the IPv4 address inside), unless
  ``POSEFIX_TILE_UPSTREAM_ALLOW`` names the host or a network holding the address (a
  site's own tile server);
- it then connects to the address it checked, never resolving again, so a DNS answer that
  changes between the check and the connect (rebinding) cannot move it;
- redirects are not followed (a 3xx is a failure), so no hop escapes the check;
- connecting, each read and the whole body are bounded in time, and the body in size.

The reason for a failure goes to the server log; the client sees one uniform 502.
"""

from __future__ import annotations

import ipaddress
import socket
import threading
import time
from collections.abc import Iterable

import httpcore
import httpx

__all__ = ["UpstreamError", "address_refusal", "fetch", "guarded_client"]

IpAddress = ipaddress.IPv4Address | ipaddress.IPv6Address
IpNetwork = ipaddress.IPv4Network | ipaddress.IPv6Network

USER_AGENT = "posefix-tile-proxy/0.1 (+https://github.com/posefix)"
_SHARED_V4 = ipaddress.ip_network("100.64.0.0/10")  # carrier-grade NAT: not public, not "private" either


class UpstreamError(RuntimeError):
    """An upstream fetch failed; the message is for the server log, not for the client."""


class RefusedAddress(httpcore.ConnectError):
    """The upstream host resolves to an address this server must not connect to."""


def address_refusal(ip: IpAddress) -> str | None:
    """Why ``ip`` is no public internet address (None when it is one)."""
    if isinstance(ip, ipaddress.IPv6Address):
        inner = ip.ipv4_mapped or ip.sixtofour
        if inner is not None:
            return address_refusal(inner)
    for attribute, reason in (
        ("is_unspecified", "unspecified"), ("is_loopback", "loopback"), ("is_link_local", "link-local"),
        ("is_multicast", "multicast"), ("is_private", "private"), ("is_reserved", "reserved"),
    ):
        if getattr(ip, attribute):
            return reason
    if isinstance(ip, ipaddress.IPv4Address) and ip in _SHARED_V4:
        return "shared (carrier-grade NAT)"
    if not ip.is_global:
        return "non-global"
    return None


class Allowance:
    """``POSEFIX_TILE_UPSTREAM_ALLOW`` parsed: networks (``10.1.2.0/24``, ``127.0.0.1``) and host names."""

    def __init__(self, entries: Iterable[str]):
        self.networks: list[IpNetwork] = []
        self.hosts: set[str] = set()
        for entry in entries:
            entry = entry.strip()
            if not entry:
                continue
            try:
                self.networks.append(ipaddress.ip_network(entry, strict=False))
            except ValueError:
                self.hosts.add(entry.lower().rstrip("."))

    def key(self) -> tuple[str, ...]:
        return tuple(sorted(str(n) for n in self.networks)) + tuple(sorted(self.hosts))

    def refusal(self, host: str, ip: IpAddress) -> str | None:
        if host.lower().rstrip(".") in self.hosts or any(ip in net for net in self.networks):
            return None
        return address_refusal(ip)


class GuardedBackend(httpcore.SyncBackend):
    """httpcore's network backend, resolving and checking the host before it connects."""

    def __init__(self, allowance: Allowance):
        self.allowance = allowance

    def connect_tcp(self, host: str, port: int, timeout: float | None = None, local_address: str | None = None,
                    socket_options: Iterable[object] | None = None) -> httpcore.NetworkStream:
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        except (OSError, UnicodeError) as exc:
            raise httpcore.ConnectError(f"cannot resolve {host}: {exc}") from exc
        addresses = list(dict.fromkeys(ipaddress.ip_address(info[4][0].split("%")[0]) for info in infos))
        for ip in addresses:
            reason = self.allowance.refusal(host, ip)
            if reason is not None:
                raise RefusedAddress(
                    f"{host} resolves to {ip}, a {reason} address; a site's own tile server must be "
                    "listed in POSEFIX_TILE_UPSTREAM_ALLOW"
                )
        last: Exception | None = None
        for ip in addresses:  # connect to what was checked, not to a second DNS answer
            try:
                return super().connect_tcp(str(ip), port, timeout=timeout, local_address=local_address,
                                           socket_options=socket_options)  # type: ignore[arg-type]
            except (httpcore.ConnectError, httpcore.ConnectTimeout) as exc:
                last = exc
        raise last or httpcore.ConnectError(f"{host} has no address")


class GuardedTransport(httpx.HTTPTransport):
    def __init__(self, allowance: Allowance, limits: httpx.Limits):
        super().__init__(limits=limits, trust_env=False)
        self._pool = httpcore.ConnectionPool(
            ssl_context=httpx.create_ssl_context(trust_env=False),
            max_connections=limits.max_connections,
            max_keepalive_connections=limits.max_keepalive_connections,
            keepalive_expiry=limits.keepalive_expiry,
            network_backend=GuardedBackend(allowance),
        )


_CLIENTS: dict[tuple[str, ...], httpx.Client] = {}
_CLIENTS_LOCK = threading.Lock()


def guarded_client(allow: Iterable[str]) -> httpx.Client:
    """One pooled client per allow-list: no redirects, no proxy from the environment."""
    allowance = Allowance(allow)
    with _CLIENTS_LOCK:
        client = _CLIENTS.get(allowance.key())
        if client is None:
            limits = httpx.Limits(max_connections=32, max_keepalive_connections=16)
            client = _CLIENTS[allowance.key()] = httpx.Client(
                transport=GuardedTransport(allowance, limits), follow_redirects=False, trust_env=False,
                headers={"User-Agent": USER_AGENT, "Accept-Encoding": "identity"},
            )
        return client


def fetch(url: str, *, allow: Iterable[str], timeout_s: float, max_bytes: int) -> tuple[int, bytes, str]:
    """GET ``url``: (status, body, content type); body empty unless 200. Raises UpstreamError."""
    host = httpx.URL(url).host
    started = time.monotonic()
    timeout = httpx.Timeout(timeout_s, connect=min(3.0, timeout_s))
    try:
        with guarded_client(allow).stream("GET", url, timeout=timeout) as response:
            status = response.status_code
            if status in (301, 302, 303, 307, 308):
                raise UpstreamError(f"{host} redirected to {response.headers.get('location', '?')!r} (not followed)")
            if status != 200:
                return status, b"", response.headers.get("content-type", "")
            encoding = response.headers.get("content-encoding", "identity").lower()
            if encoding not in ("identity", ""):
                raise UpstreamError(f"{host} sent a {encoding}-encoded body though asked for identity")
            declared = response.headers.get("content-length")
            if declared is not None and declared.isdigit() and int(declared) > max_bytes:
                raise UpstreamError(f"{host} declared {declared} bytes, more than the {max_bytes} allowed")
            body = bytearray()
            for chunk in response.iter_raw():
                body += chunk
                if len(body) > max_bytes:
                    raise UpstreamError(f"{host} sent more than the {max_bytes} bytes allowed")
                if time.monotonic() - started > timeout_s:
                    raise UpstreamError(f"{host} took longer than {timeout_s:g} s to send the tile")
            return status, bytes(body), response.headers.get("content-type", "")
    except httpx.TimeoutException as exc:
        raise UpstreamError(f"{host} did not answer in time ({type(exc).__name__})") from exc
    except httpx.HTTPError as exc:
        raise UpstreamError(f"{host} unreachable ({exc})") from exc
