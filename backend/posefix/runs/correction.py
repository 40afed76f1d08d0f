"""The bridge between the web service and the correction engine (``posefix.engine``).

Edit sets are stored as JSON by keyframe number (the keyframes of a run are fixed at import:
the engine's default keyframes, ``Problem.keyframe_index``)::

    {"moves": [[k, lon, lat, alt_or_null], ...], "deleted": [k, ...], "flags": [{index, reason, message}]}

A prepared ``Problem`` per run (and rules) is cached in-process, with the last solution per
revision for warm starts, so a live-drag preview only runs the keyframe solve.
"""

from __future__ import annotations

import dataclasses
import json
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from posefix.config import Settings
from posefix.core import geodesy
from posefix.core.rules import EditRules, KeyframeMove, Refusal, RuleCheck, check_edits
from posefix.core.run import PoseRun
from posefix.engine import CorrectionConfig, Problem, Solution, prepare

EMPTY_EDIT_SET: dict[str, Any] = {"moves": [], "deleted": [], "flags": []}


@lru_cache(maxsize=4)
def _load_config(path: str | None) -> CorrectionConfig:
    return CorrectionConfig.load(path) if path else CorrectionConfig()


def engine_config(settings: Settings, rules: dict[str, Any] | None = None) -> CorrectionConfig:
    cfg = _load_config(str(settings.engine_config) if settings.engine_config else None)
    if rules is not None:
        cfg = dataclasses.replace(cfg, rules=EditRules.from_json(rules))
    return cfg


def default_rules(settings: Settings) -> dict[str, Any]:
    return engine_config(settings).rules.to_json()


@dataclass(frozen=True)
class BatchMove:
    index: int
    lon: float
    lat: float
    alt: float | None = None


class ProblemCache:
    """LRU of prepared problems keyed by (run id, rules), plus warm-start solutions."""

    def __init__(self, size: int = 4):
        self.size = size
        self._problems: OrderedDict[tuple[int, str], Problem] = OrderedDict()
        self._solutions: OrderedDict[tuple[int, str, int], Solution] = OrderedDict()
        self._lock = threading.Lock()
        self._loading: dict[tuple[int, str], threading.Lock] = {}
        # The last preview per (run, rules, base revision, edited keyframes): the warm start of
        # the next frame of the same drag, so the engine can re-solve locally.
        self._previews: OrderedDict[tuple[Any, ...], Solution] = OrderedDict()

    def problem(self, run_id: int, rules: dict[str, Any], load: Callable[[], tuple[PoseRun, CorrectionConfig]]) -> Problem:
        key = (run_id, json.dumps(rules, sort_keys=True))
        with self._lock:
            if key in self._problems:
                self._problems.move_to_end(key)
                return self._problems[key]
            gate = self._loading.setdefault(key, threading.Lock())
        with gate:  # one thread prepares; the others wait for it
            with self._lock:
                if key in self._problems:
                    return self._problems[key]
            run, cfg = load()
            problem = prepare(run, cfg)
            self.put(run_id, rules, problem)
            return problem

    def put(self, run_id: int, rules: dict[str, Any], problem: Problem) -> None:
        key = (run_id, json.dumps(rules, sort_keys=True))
        with self._lock:
            self._problems[key] = problem
            self._problems.move_to_end(key)
            while len(self._problems) > self.size:
                self._problems.popitem(last=False)

    def solution(self, run_id: int, rules: dict[str, Any], revision: int) -> Solution | None:
        with self._lock:
            return self._solutions.get((run_id, json.dumps(rules, sort_keys=True), revision))

    def put_solution(self, run_id: int, rules: dict[str, Any], revision: int, sol: Solution) -> None:
        with self._lock:
            self._solutions[(run_id, json.dumps(rules, sort_keys=True), revision)] = sol
            while len(self._solutions) > 4 * self.size:
                self._solutions.popitem(last=False)

    def preview_solution(self, key: tuple[Any, ...]) -> Solution | None:
        with self._lock:
            return self._previews.get(key)

    def put_preview_solution(self, key: tuple[Any, ...], sol: Solution) -> None:
        with self._lock:
            self._previews[key] = sol
            self._previews.move_to_end(key)
            while len(self._previews) > 8 * self.size:
                self._previews.popitem(last=False)

    def forget_all(self) -> None:
        with self._lock:
            self._problems.clear()
            self._solutions.clear()
            self._previews.clear()

    def forget(self, run_id: int) -> None:
        with self._lock:
            for key in [k for k in self._problems if k[0] == run_id]:
                del self._problems[key]
            for skey in [k for k in self._solutions if k[0] == run_id]:
                del self._solutions[skey]
            for pkey in [k for k in self._previews if k[0] == run_id]:
                del self._previews[pkey]


PROBLEMS = ProblemCache()
_warming: set[tuple[int, int]] = set()
_warming_lock = threading.Lock()


def base_solution(run_id: int, rules: dict[str, Any], revision: int, problem: Problem, edit_set: dict[str, Any]) -> Solution:
    """The exact solution of a revision's edit set (cached): the warm start of its previews."""
    sol = PROBLEMS.solution(run_id, rules, revision)
    if sol is None:
        sol = solve(problem, edit_set, None)
        PROBLEMS.put_solution(run_id, rules, revision, sol)
    return sol


def warm_once(run_id: int, revision: int, fn: Callable[[], None]) -> None:
    """Run ``fn`` unless a warm-up of the same revision is already under way."""
    key = (run_id, revision)
    with _warming_lock:
        if key in _warming:
            return
        _warming.add(key)
    try:
        fn()
    finally:
        with _warming_lock:
            _warming.discard(key)


def moves_of(edit_set: dict[str, Any]) -> list[BatchMove]:
    return [BatchMove(int(m[0]), float(m[1]), float(m[2]), None if m[3] is None else float(m[3])) for m in edit_set.get("moves", [])]


def to_en(problem: Problem, moves: list[BatchMove]) -> np.ndarray:
    """(m, 3) ENU targets of moves; a 2-D move keeps the keyframe's reported altitude."""
    if not moves:
        return np.zeros((0, 3))
    index = problem.keyframe_index
    k = len(index)
    rows = index[np.clip([m.index for m in moves], 0, k - 1)]
    alt = np.array([problem.run.alt_m[r] if m.alt is None else m.alt for m, r in zip(moves, rows)])
    return problem.to_enu(np.array([m.lon for m in moves]), np.array([m.lat for m in moves]), alt)


def check_batch(
    problem: Problem, rules: dict[str, Any], base: dict[str, Any], moves: list[BatchMove], deleted: list[int]
) -> RuleCheck:
    """The engine's edit rules on a new batch, with the base revision's edits as context."""
    index = problem.keyframe_index
    k = len(index)
    out_of_range = [Refusal(int(d), "out_of_range", f"keyframe {d} does not exist (0..{k - 1})") for d in deleted if not 0 <= d < k]
    earlier = moves_of(base)
    en_before = to_en(problem, earlier)
    edited_before = {m.index: (float(c[0]), float(c[1])) for m, c in zip(earlier, en_before)}
    en = to_en(problem, moves)
    km = [KeyframeMove(m.index, float(c[0]), float(c[1])) for m, c in zip(moves, en)]
    all_deleted = sorted(set(base.get("deleted", [])) | {d for d in deleted if 0 <= d < k})
    check = check_edits(EditRules.from_json(rules), problem.p_enu_m[index, :2], km, all_deleted, edited_before)
    if out_of_range:
        return RuleCheck(accepted=check.accepted, refusals=out_of_range + check.refusals, flags=check.flags)
    return check


def merge(base: dict[str, Any], moves: list[BatchMove], deleted: list[int], flags: list[Refusal]) -> dict[str, Any]:
    """The cumulative edit set after a batch: a re-moved keyframe's newest move wins."""
    by_k = {int(m[0]): list(m) for m in base.get("moves", [])}
    for m in moves:
        by_k[m.index] = [m.index, m.lon, m.lat, m.alt]
    dels = sorted(set(int(d) for d in base.get("deleted", [])) | set(int(d) for d in deleted))
    for d in dels:
        by_k.pop(d, None)
    moved_now = {m.index for m in moves}
    kept_flags = [f for f in base.get("flags", []) if f["index"] not in moved_now and f["index"] not in dels]
    return {
        "moves": [by_k[k] for k in sorted(by_k)],
        "deleted": dels,
        "flags": kept_flags + [f.to_json() for f in flags],
    }


def solve(problem: Problem, edit_set: dict[str, Any], warm: Solution | None = None, *, local: bool = False) -> Solution:
    """Solve an edit set; ``local`` (with a warm start) re-optimises only around what changed."""
    moves = moves_of(edit_set)
    c_m = to_en(problem, moves)
    flags = [Refusal(int(f["index"]), f["reason"], f["message"]) for f in edit_set.get("flags", [])]
    return problem.solve_rows(
        problem.keyframe_index,
        np.array([m.index for m in moves], dtype=np.int64),
        c_m,
        np.array([m.alt is not None for m in moves], dtype=bool),
        np.array(edit_set.get("deleted", []), dtype=np.int64),
        warm,
        flags,
        local=local,
    )


def keyframe_lonlatalt(problem: Problem, sol: Solution) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lat, lon, alt = geodesy.enu_to_geodetic(sol.keyframes.p_enu_m, problem.origin)
    return np.asarray(lon), np.asarray(lat), np.asarray(alt)


def drift_json(sol: Solution) -> dict[str, Any]:
    return sol.drift.to_json()


def solver_json(sol: Solution) -> dict[str, Any]:
    return sol.solver.to_json()


def horizontal_distance_m(lon1: np.ndarray, lat1: np.ndarray, lon2: np.ndarray, lat2: np.ndarray) -> np.ndarray:
    """Great-circle distance on the mean sphere (for display: corrections of metres)."""
    r = 6371008.8
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dphi = p2 - p1
    dlmb = np.radians(lon2 - lon1)
    a = np.sin(dphi / 2) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dlmb / 2) ** 2
    return 2 * r * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0)))
