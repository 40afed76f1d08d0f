"""The bridge between the web service and the correction engine (``posefix.engine``).

Edit sets are stored as JSON by keyframe number (the keyframes of a run are fixed at import:
the engine's default keyframes, ``Problem.keyframe_index``)::

    {"moves": [[k, lon, lat, alt_or_null], ...], "deleted": [k, ...], "flags": [{index, reason, message}]}

A prepared ``Problem`` per run (and rules) is cached in-process, with the last solution per
revision for warm starts, so a live-drag preview only runs the keyframe solve. The solution of
each revision is also stored beside its files (``storage.write_solution``): the worker writes
it with the revision, and any API process loads it instead of solving the revision again.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import threading
import weakref
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from posefix.config import Settings
from posefix.core import geodesy
from posefix.core.rules import EditRules, KeyframeMove, Refusal, RuleCheck, check_edits
from posefix.core.drift import DriftEstimate, GnssSteps, estimate_drift, gnss_steps, step_window
from posefix.core.run import PoseRun
from posefix.engine import CorrectionConfig, Problem, Solution, prepare
from posefix.runs import storage

log = logging.getLogger("posefix.correction")

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
        return cls(storage.FileStore(settings.files_dir), storage.solution_rel(keyframes_rel), config_fingerprint(cfg))

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
            sol = solve(problem, edit_set, None)
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


_STEPS: weakref.WeakKeyDictionary[Problem, GnssSteps] = weakref.WeakKeyDictionary()  # GNSS steps on a problem's default keyframes
PREVIEW_DRIFT_KEYFRAMES = (30, 90)  # the new drift estimate in full within this many keyframes of a new edit, none beyond the second


def local_drift(problem: Problem, merged: dict[str, Any], base: Solution) -> DriftEstimate | None:
    """The drift estimate of the new edit set near the keyframes whose edits differ from the
    base solution's, tapering linearly to the base solution's estimate further away.

    (k,) per-keyframe arrays; only on the default keyframes with none removed (otherwise the
    base estimate as it is; None when keyframes are deleted, whose rows the base estimate
    does not match).  Near the drag the location terms are those the commit will see
    (so the dragged keyframe follows the cursor); far away they stay as in the base solution,
    so the change is local and a window solve answers it.
    """
    cfg = problem.cfg
    index = problem.keyframe_index
    k = len(index)
    moves = moves_of(merged)
    if merged.get("deleted") or not bool(np.all(base.active)) or len(base.drift.bias_sigma_m) != k:
        # Deleted keyframes change the solve's rows: the base estimate no longer lines up,
        # so let the solve estimate drift over the keyframes that remain.
        return None
    if not cfg.drift.enabled or not moves:
        return base.drift
    edit_kf = np.array([m.index for m in moves], dtype=np.int64)
    c_m = to_en(problem, moves)
    has_alt = np.array([m.alt is not None for m in moves], dtype=bool)
    base_kf = base.keyframes.edited
    new_kf = edit_kf[~base_kf[edit_kf]] if len(base_kf) == k else edit_kf
    # keyframes edited now and not in the base revision (being dragged); else all edited ones
    changed = new_kf if len(new_kf) else edit_kf
    p_rep = problem.p_enu_m[index]
    g = p_rep if problem.g_enu_m is None else problem.g_enu_m[index]
    g_nan = np.where(np.all(np.isfinite(g), axis=1)[:, None], g, np.nan)
    lc, uc = cfg.location, cfg.user
    t_s = problem.run.t_s[index]
    steps = _STEPS.get(problem)
    if steps is None:  # they depend on the run only: most of the estimate's cost, found once
        steps = _STEPS[problem] = gnss_steps((g_nan - p_rep)[:, :2], window=step_window(t_s))
    new = estimate_drift(
        t_s, p_rep, g_nan, edit_kf, c_m, has_alt, lc.sigma_h_m, lc.sigma_v_m, uc.sigma_h_m,
        uc.sigma_v_m, cfg.drift.bias_sigma_m, cfg.drift.bias_tau_s, cfg.drift.min_edits_for_estimate, steps=steps,
        levels=lambda: problem.gnss_levels(index),
        # GNSS levels: re-solved near the drag, the base revision's beyond (drift._levels_near_new_edits)
        frozen=(None if base.drift.loc_sigma_h_m is None or base.drift.tau_s <= 0 else
                (base.drift.sigma_b_m**2, base.drift.tau_s, base.drift.detected, base.drift)),
    )
    near, far = PREVIEW_DRIFT_KEYFRAMES
    dist = np.min(np.abs(np.arange(k)[:, None] - changed[None, :]), axis=1)
    w = np.clip((far - dist) / (far - near), 0.0, 1.0)
    return dataclasses.replace(
        new,
        bias_enu_m=w[:, None] * new.bias_enu_m + (1 - w[:, None]) * base.drift.bias_enu_m,
        bias_sigma_m=w * new.bias_sigma_m + (1 - w) * base.drift.bias_sigma_m,
        weight=w * new.weight + (1 - w) * base.drift.weight,
        loc_sigma_h_m=(None if new.loc_sigma_h_m is None or base.drift.loc_sigma_h_m is None
                       else w * new.loc_sigma_h_m + (1 - w) * base.drift.loc_sigma_h_m),
    )


def preview_solve(problem: Problem, merged: dict[str, Any], base: Solution, warm: Solution | None) -> tuple[Solution, dict[str, Any]]:
    """A live-drag answer: a local solve around the dragged keyframes, warm-started from the
    previous frame of the drag (or the base revision's exact solution).

    The drift estimate of a new edit set reaches the whole run (one edit showing a GNSS
    bias down-weights every fix), which would make every first drag a full solve; the
    preview applies it only near the drag (``local_drift``) and leaves the rest to the
    commit, whose worker solves the exact problem.  Returns the solution and a description
    of what was solved (``local``: only a window was re-solved).
    """
    drift = local_drift(problem, merged, base)
    sol = solve(problem, merged, warm or base, local=True, drift=drift)
    window = sol.solver.extra.get("window")
    held = sol.solver.extra.get("window_held")
    info = {
        "mode": "local" if held is not None else "full",
        "local": held is not None,
        "full_solve": held is None,
        "window": None if window is None else [int(window[0]), int(window[1])],
        "keyframes": int(len(sol.keyframes.index)),
        "drift": f"the new estimate within {PREVIEW_DRIFT_KEYFRAMES[0]}-{PREVIEW_DRIFT_KEYFRAMES[1]} keyframes of the drag, the base revision's beyond (the commit re-estimates it over the whole run)",
        "exact": False,
    }
    return sol, info


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


def solve(problem: Problem, edit_set: dict[str, Any], warm: Solution | None = None, *, local: bool = False,
          drift: DriftEstimate | None = None) -> Solution:
    """Solve an edit set; ``local`` (with a warm start) re-optimises only around what changed;
    ``drift`` replaces the drift estimate (a preview keeps the base solution's)."""
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
        drift=drift,
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
