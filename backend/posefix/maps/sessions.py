"""Live tracking sessions, kept in this process's memory.

Why memory and not the database: a session's state is the Viterbi filter (a (V,) column
plus one int8 back-pointer row of V per step: 12 KB per step on the shared floor) and the
raw-sensor buffer; serialising that on every step would cost more than the step itself
(≤ 2 ms). So sessions live in the server process that created them, expire after
``TTL_S`` idle seconds, and at most ``MAX_SESSIONS`` exist at once (429 beyond that); a
session holds at most ``MAX_STEPS`` steps (409 beyond; start a new one from the last
position). **Several server processes:** a session exists in one process only, so a
client must reach the same process for its whole session (sticky routing by session id);
another process answers 404 ``session_not_found`` and the client starts a new session.
A server restart ends every session.
"""

from __future__ import annotations

import secrets
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from posefix.errors import Conflict, NotFound, TooManyRequests, Unprocessable
from posefix.mapmatch import api as mapmatch

TTL_S = 600.0
MAX_SESSIONS = 16
MAX_STEPS = 1000
# Raw sensors: a step is reported once this much signal follows it (the forward-backward
# low-pass and the peak prominence need the samples after a peak), and the buffer keeps
# this many seconds before the last reported step.
SETTLE_MS = 600
BUFFER_MS = 10_000


@dataclass
class TrackingSession:
    id: str
    owner_id: int
    floorplan_id: int
    model: mapmatch.Model
    tracker: mapmatch.Tracker
    last_used: float
    lock: threading.Lock = field(default_factory=threading.Lock)
    acc: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    rotvec: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    last_step_ms: float = -np.inf

    @property
    def n_steps(self) -> int:
        return len(self.tracker.t_ms) - 1


def position_json(model: mapmatch.Model, t_ms: int, summary: mapmatch.GaussianSummary) -> dict[str, Any]:
    x, y = (float(v) for v in summary.mean_xy_m)
    out = {"t_ms": int(t_ms), "x_m": round(x, 3), "y_m": round(y, 3),
           "sigma_major_m": round(float(summary.sigma_major_m), 3), "sigma_minor_m": round(float(summary.sigma_minor_m), 3),
           "angle_deg": round(float(summary.angle_deg), 1), "lon": None, "lat": None}
    geo = model.graph.georef
    if geo is not None:
        ll = geo.to_lonlat(np.array([[x, y]]))[0]
        out["lon"], out["lat"] = round(float(ll[0]), 8), round(float(ll[1]), 8)
    return out


class SessionStore:
    def __init__(self) -> None:
        self._items: dict[str, TrackingSession] = {}
        self._lock = threading.Lock()

    def _purge(self, now: float) -> None:
        for sid in [k for k, s in self._items.items() if now - s.last_used > TTL_S]:
            del self._items[sid]

    def create(self, owner_id: int, floorplan_id: int, model: mapmatch.Model,
               start_xy_m: tuple[float, float] | None) -> tuple[TrackingSession, dict[str, Any]]:
        now = time.monotonic()
        with self._lock:
            self._purge(now)
            if len(self._items) >= MAX_SESSIONS:
                raise TooManyRequests(
                    f"{MAX_SESSIONS} tracking sessions are open on this server; close one (DELETE) or wait {TTL_S:.0f} s",
                    code="too_many_sessions", headers={"Retry-After": "60"},
                )
        t0 = 0
        try:
            tracker = mapmatch.Tracker(model, start_xy_m=start_xy_m, t0_ms=t0)
        except ValueError as exc:
            raise Conflict(f"start_xy_m: {exc}", code="bad_start", extra={"field": "start_xy_m"}) from None
        summ = mapmatch.current_summary(tracker)
        sess = TrackingSession(secrets.token_urlsafe(16), owner_id, floorplan_id, model, tracker, now)
        with self._lock:
            self._items[sess.id] = sess
        return sess, position_json(model, t0, summ)

    def get(self, session_id: str, owner_id: int) -> TrackingSession:
        now = time.monotonic()
        with self._lock:
            self._purge(now)
            sess = self._items.get(session_id)
            # Another user's session does not exist for this caller (no existence leak).
            if sess is None or sess.owner_id != owner_id:
                raise NotFound(f"tracking session {session_id[:40]!r} not found (expired after {TTL_S:.0f} s idle, "
                               "closed, or held by another server process)", code="session_not_found")
            sess.last_used = now
            return sess

    def delete(self, session_id: str, owner_id: int) -> None:
        sess = self.get(session_id, owner_id)
        with self._lock:
            self._items.pop(sess.id, None)

    def drop_floorplan(self, floorplan_id: int) -> None:
        with self._lock:
            for sid in [k for k, s in self._items.items() if s.floorplan_id == floorplan_id]:
                del self._items[sid]

    def clear(self) -> None:
        with self._lock:
            self._items.clear()


SESSIONS = SessionStore()


def step_vectors(model: mapmatch.Model, steps: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    """(n,) t_ms and (n, 2) floor-frame step vectors from ``StepIn`` items: a vector as
    given, or ``length · (cos(θ + b), sin(θ + b))`` with the model's heading bias b."""
    t = np.array([s.t_ms for s in steps], dtype=np.int64)
    vec = np.zeros((len(steps), 2))
    b = model.step_model.heading_bias_rad
    for i, s in enumerate(steps):
        if s.dx_m is not None:
            vec[i] = (s.dx_m, s.dy_m)
        else:
            vec[i] = (s.length_m * np.cos(s.heading_rad + b), s.length_m * np.sin(s.heading_rad + b))
    return t, vec


def _rows(name: str, rows: list[list[float]]) -> np.ndarray:
    a = np.asarray(rows, dtype=float) if rows else np.zeros((0, 4))
    if a.ndim != 2 or a.shape[1] != 4 or not np.all(np.isfinite(a)):
        raise Unprocessable(f"sensors.{name}: rows must be [t_ms, x, y, z] finite numbers", code="bad_sensors",
                            extra={"field": f"sensors.{name}"})
    return a


def steps_from_sensors(sess: TrackingSession, acc_rows: list[list[float]], rot_rows: list[list[float]]) -> tuple[np.ndarray, np.ndarray]:
    """Append raw samples to the session buffer; return the newly settled steps (t_ms, vectors)."""
    acc, rot = _rows("acc", acc_rows), _rows("rotvec", rot_rows)
    sess.acc = np.vstack([sess.acc, acc[np.argsort(acc[:, 0], kind="stable")]])
    sess.rotvec = np.vstack([sess.rotvec, rot[np.argsort(rot[:, 0], kind="stable")]])
    empty = (np.zeros(0, dtype=np.int64), np.zeros((0, 2)))
    if sess.acc.shape[0] < 16 or sess.rotvec.shape[0] < 2:
        return empty
    settled_until = min(sess.acc[-1, 0], sess.rotvec[-1, 0]) - SETTLE_MS
    t_new, vec = mapmatch.settled_steps(sess.acc, sess.rotvec, sess.last_step_ms, settled_until, sess.model)
    if t_new.size == 0:
        return empty
    sess.last_step_ms = float(t_new[-1])
    keep_from = sess.last_step_ms - BUFFER_MS
    sess.acc = sess.acc[sess.acc[:, 0] >= keep_from]
    sess.rotvec = sess.rotvec[sess.rotvec[:, 0] >= keep_from]
    return t_new, vec


def advance(sess: TrackingSession, t_ms: np.ndarray, vec: np.ndarray) -> list[dict[str, Any]]:
    if sess.n_steps + len(t_ms) > MAX_STEPS:
        raise Conflict(f"a session tracks at most {MAX_STEPS} steps ({sess.n_steps} so far); start a new session "
                       "from the last position", code="session_full", extra={"n_steps": sess.n_steps})
    out = []
    for t, v in zip(t_ms, vec):
        tp = sess.tracker.step(v, int(t))
        out.append(position_json(sess.model, int(t), tp.summary))
    return out
