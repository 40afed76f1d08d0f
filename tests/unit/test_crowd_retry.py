"""benchmarks.crowd tries a request again when the server drops the connection, and looks
first whether a state-changing request took effect before repeating it."""

from __future__ import annotations

import socket
import threading

import httpx

from benchmarks.crowd import call


class DroppingServer:
    """Loopback HTTP that closes the first ``drops`` connections without answering, then
    answers every request with 200 and counts the requests it answered."""

    def __init__(self, drops: int) -> None:
        self.drops, self.answered = drops, 0
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}"
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            with conn:
                conn.recv(65536)
                if self.drops > 0:
                    self.drops -= 1
                    continue  # closed without a response
                self.answered += 1
                conn.sendall(b"HTTP/1.1 200 OK\r\ncontent-type: application/json\r\ncontent-length: 2\r\nconnection: close\r\n\r\n{}")

    def close(self) -> None:
        self.sock.close()


def test_a_dropped_request_is_sent_again() -> None:
    server = DroppingServer(drops=1)
    try:
        with httpx.Client(base_url=server.url, timeout=5) as client:
            assert call(client, "GET", "/x").status_code == 200
        assert server.answered == 1
    finally:
        server.close()


def test_a_dropped_request_that_took_effect_is_not_repeated() -> None:
    server = DroppingServer(drops=1)
    try:
        stand_in = httpx.Response(200, json={"found": True})
        with httpx.Client(base_url=server.url, timeout=5) as client:
            got = call(client, "POST", "/submit", json={}, settled=lambda: stand_in)
        assert got is stand_in and server.answered == 0
    finally:
        server.close()
