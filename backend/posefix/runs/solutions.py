"""Solutions of a run's revisions: the process cache and the stored solution files.

Edit sets are stored as JSON by keyframe number (``engine.Edits.to_json``; the keyframes of a
run are fixed at import: the engine's default keyframes, ``Problem.keyframe_index``).  A
prepared ``Problem`` per run (and rules) is cached in-process, with the last solution per
revision for warm starts, so a live-drag preview only runs the keyframe solve.  The solution of
each revision is also stored beside its files (``storage.write_solution``): the worker writes
it with the revision, and any API process loads it instead of solving the revision again.

The web layer makes one call each: ``preview`` (a live drag) and ``solve_revision`` (the
revision job); the algorithm is the engine's (``Problem.preview``, ``Problem.solve_edits``).
"""

from __future__ import annotations

import hashlib
import json
import logging
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from posefix.config import Settings
from posefix.core.run import PoseRun
from posefix.engine import CorrectionConfig, Edit, Edits, Preview, Problem, Solution, prepare
from posefix.runs import storage
from posefix.filestore import file_store

log = logging.getLogger("posefix.solutions")


def config_fingerprint(cfg: CorrectionConfig) -> str:
    """Identifies the engine configuration a stored solution was solved with."""
    text = json.dumps(cfg.to_dict(), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class StoredSolution:
    """Where a ready revision's solution is stored (``None`` for a revision still computing)."""

    store: storage.FileStore
    rel: str
    fingerprint: str

    @classmethod
    def of(cls, settings: Settings, keyframes_rel: str, cfg: CorrectionConfig) -> "StoredSolution":
        return cls(file_store(settings), storage.solution_rel(keyframes_rel), config_fingerprint(cfg))

    def load(self, problem: Problem) -> Solution | None:
        sol = storage.read_solution(self.store, self.rel, self.fingerprint)
        if not isinstance(sol, Solution) or not np.array_equal(sol.keyframes.index, problem.keyframe_index):
            return None
        return sol

    def save(self, sol: Solution) -> None:
        """Best effort: the file is a cache, a failure only costs another process a solve."""
        try:
            storage.write_solution(self.store, self.rel, sol, self.fingerprint)
        except (OSError, TypeError, ValueError):
            log.warning("could not store the solution %s", self.rel, exc_info=True)


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
        # Ready revisions never change: their edit set and keyframes file, so a preview does
        # not read the revision row again (key: file store, run, revision number).
        self._revisions: OrderedDict[tuple[Any, ...], tuple[dict[str, Any], str]] = OrderedDict()

    def peek(self, run_id: int, rules: dict[str, Any]) -> Problem | None:
        """The prepared problem if it is cached (no loading)."""
        with self._lock:
            return self._problems.get((run_id, json.dumps(rules, sort_keys=True)))

    def revision(self, key: tuple[Any, ...]) -> tuple[dict[str, Any], str] | None:
        with self._lock:
            return self._revisions.get(key)

    def put_revision(self, key: tuple[Any, ...], value: tuple[dict[str, Any], str]) -> None:
        with self._lock:
            self._revisions[key] = value
            self._revisions.move_to_end(key)
            while len(self._revisions) > 64 * self.size:
                self._revisions.popitem(last=False)

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
            self._revisions.clear()

    def forget(self, run_id: int) -> None:
        with self._lock:
            for key in [k for k in self._problems if k[0] == run_id]:
                del self._problems[key]
            for skey in [k for k in self._solutions if k[0] == run_id]:
                del self._solutions[skey]
            for pkey in [k for k in self._previews if k[0] == run_id]:
                del self._previews[pkey]
            for rkey in [k for k in self._revisions if k[1] == run_id]:
                del self._revisions[rkey]


PROBLEMS = ProblemCache()
_warming: set[tuple[int, int]] = set()
_warming_lock = threading.Lock()


_base_gates: dict[tuple[int, str, int], threading.Lock] = {}
_base_gates_lock = threading.Lock()


def base_solution_state(run_id: int, rules: dict[str, Any], revision: int, problem: Problem,
                        edit_set: dict[str, Any], stored: StoredSolution | None = None) -> tuple[Solution, bool]:
    """The exact solution of a revision's edit set (cached) and whether this call solved it.

    One full solve per (run, rules, revision) and process: concurrent callers (the warm-up
    after the keyframes were served, the worker writing the revision, previews) wait for
    the one that is solving instead of solving again. A ready revision's solution is read
    from its file (``stored``) when the worker (or another process) stored it; a solve here
    stores it for the others.
    """
    sol = PROBLEMS.solution(run_id, rules, revision)
    if sol is not None:
        return sol, False
    key = (run_id, json.dumps(rules, sort_keys=True), revision)
    with _base_gates_lock:
        gate = _base_gates.setdefault(key, threading.Lock())
    with gate:
        sol = PROBLEMS.solution(run_id, rules, revision)
        if sol is not None:
            return sol, False
        sol = stored.load(problem) if stored is not None else None
        solved = sol is None
        if sol is None:
            sol = problem.solve_edits(Edits.from_json(edit_set))
            if stored is not None:
                stored.save(sol)
        PROBLEMS.put_solution(run_id, rules, revision, sol)
    with _base_gates_lock:
        _base_gates.pop(key, None)
    return sol, solved


def base_solution(run_id: int, rules: dict[str, Any], revision: int, problem: Problem, edit_set: dict[str, Any],
                  stored: StoredSolution | None = None) -> Solution:
    """The exact solution of a revision's edit set (cached): the warm start of its previews."""
    return base_solution_state(run_id, rules, revision, problem, edit_set, stored)[0]


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




def preview(run_id: int, rules: dict[str, Any], base_revision: int, problem: Problem, base_set: dict[str, Any],
            stored: StoredSolution | None, moves: list[Edit], deleted: list[int]) -> tuple[Preview, bool]:
    """A live drag on ``base_revision``: the engine's preview, warm from the previous frame of the
    same drag, else the base revision's exact solution (stored with the revision, or solved once
    per process). Returns the preview and whether the base had to be solved in this call."""
    base_edits = Edits.from_json(base_set)
    base_sol, base_solved = base_solution_state(run_id, rules, base_revision, problem, base_set, stored)
    rules_key = json.dumps(rules, sort_keys=True)

    def drag_key(merged: Edits) -> tuple[Any, ...]:  # a drag: the same keyframes edited and deleted
        return (run_id, rules_key, base_revision, tuple(m.index for m in merged.moves), tuple(merged.deleted))

    pv = problem.preview(moves, deleted, base_edits, base_sol, lambda merged: PROBLEMS.preview_solution(drag_key(merged)))
    PROBLEMS.put_preview_solution(drag_key(pv.edits), pv.solution)
    return pv, base_solved


def solve_revision(settings: Settings, run_id: int, rules: dict[str, Any], base_revision: int,
                   edit_set: dict[str, Any], load: Callable[[], tuple[PoseRun, CorrectionConfig]]) -> tuple[Problem, Solution]:
    """The revision job's solve: the run's problem (cached, else ``load``ed), the edit set solved
    exactly, warm from the base revision's solution when this process has it."""
    problem = PROBLEMS.problem(run_id, rules, load)
    warm = PROBLEMS.solution(run_id, rules, base_revision)
    return problem, problem.solve_edits(Edits.from_json(edit_set), warm)
