"""One edit, one edit set: operator moves by keyframe number, converted once at the edge.

An ``Edit`` moves keyframe ``index`` (into the problem's default keyframes, fixed when a run
is imported) to lon/lat (and altitude; None = a 2-D move that leaves the vertical free),
optionally with the horizontal 1-sigma per axis of that position (``sigma_m``: a crowd's
fused position carries its uncertainty; None = the configured ``[user] sigma_h_m``, an
operator's click).  An ``Edits`` set holds the moves (one per keyframe, in keyframe order),
the deleted keyframes and the rule flags.  The web layer turns request bodies into
``Edit``s, the store's JSON ``{"moves": [[k, lon, lat, alt_or_null(, sigma)], ...],
"deleted": [k, ...], "flags": [...]}`` (sigma only when set) goes through
``Edits.from_json`` / ``to_json``, and the engine works on nothing else.  Edits read
from a file name samples by time (``posefix.io.edits``); ``Problem.solve`` matches them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from posefix.core.rules import EditRules, KeyframeMove, Refusal, RuleCheck, check_edits, keyframes_left


@dataclass(frozen=True)
class Edit:
    """Move keyframe ``index`` to (lon_deg, lat_deg[, alt_m]); ``alt_m`` None = a 2-D move;
    ``sigma_m`` the position's horizontal 1-sigma per axis (None: the configured one)."""

    index: int
    lon_deg: float
    lat_deg: float
    alt_m: float | None = None
    sigma_m: float | None = None

    def __post_init__(self) -> None:
        if self.sigma_m is not None and not (np.isfinite(self.sigma_m) and self.sigma_m > 0):
            raise ValueError(f"keyframe {self.index}: an edit's sigma must be a positive number of metres, not {self.sigma_m!r}")

    def to_json(self) -> list:
        out = [self.index, self.lon_deg, self.lat_deg, self.alt_m]
        return out if self.sigma_m is None else out + [self.sigma_m]


@dataclass(frozen=True)
class Edits:
    """A cumulative edit set on a run's default keyframes."""

    moves: tuple[Edit, ...] = ()
    deleted: tuple[int, ...] = ()
    flags: tuple[Refusal, ...] = ()

    @classmethod
    def from_json(cls, data: dict[str, Any] | None) -> "Edits":
        data = data or {}
        moves = tuple(Edit(int(m[0]), float(m[1]), float(m[2]), None if m[3] is None else float(m[3]),
                           None if len(m) < 5 or m[4] is None else float(m[4]))
                      for m in data.get("moves", []))
        flags = tuple(Refusal(int(f["index"]), f["reason"], f["message"]) for f in data.get("flags", []))
        return cls(moves, tuple(int(d) for d in data.get("deleted", [])), flags)

    def to_json(self) -> dict[str, Any]:
        return {"moves": [m.to_json() for m in self.moves], "deleted": list(self.deleted),
                "flags": [f.to_json() for f in self.flags]}

    @property
    def index(self) -> np.ndarray:
        """(m,) keyframe of each move."""
        return np.array([m.index for m in self.moves], dtype=np.int64)

    @property
    def has_alt(self) -> np.ndarray:
        """(m,) bool: the move carries an altitude (3-D)."""
        return np.array([m.alt_m is not None for m in self.moves], dtype=bool)

    @property
    def sigma_m(self) -> np.ndarray | None:
        """(m,) horizontal 1-sigma per axis each move carries (NaN: none, the configured one);
        None when no move carries one, so ordinary edits take the engine's usual path."""
        if all(m.sigma_m is None for m in self.moves):
            return None
        return np.array([np.nan if m.sigma_m is None else m.sigma_m for m in self.moves], dtype=float)

    def merged(self, moves: list[Edit] | tuple[Edit, ...], deleted=(), flags=()) -> "Edits":
        """The cumulative set after a batch: a re-moved keyframe's newest move wins; a deleted
        keyframe loses its move; flags of keyframes moved or deleted now are replaced."""
        by_k = {m.index: m for m in self.moves}
        for m in moves:
            by_k[m.index] = m
        dels = sorted(set(self.deleted) | {int(d) for d in deleted})
        for d in dels:
            by_k.pop(d, None)
        moved_now = {m.index for m in moves}
        kept_flags = [f for f in self.flags if f.index not in moved_now and f.index not in dels]
        return Edits(tuple(by_k[k] for k in sorted(by_k)), tuple(dels), tuple(kept_flags) + tuple(flags))


def targets_enu(problem, moves) -> np.ndarray:
    """(m, 3) ENU targets of moves on ``problem``'s default keyframes (``Problem.targets``: a 2-D
    move at the keyframe's reported altitude, a 3-D move's height change on its reported up)."""
    moves = list(moves)
    if not moves:
        return np.zeros((0, 3))
    index = problem.keyframe_index
    rows = index[np.clip([m.index for m in moves], 0, len(index) - 1)]
    alt = np.array([np.nan if m.alt_m is None else m.alt_m for m in moves], dtype=float)
    return problem.targets(np.array([m.lon_deg for m in moves]), np.array([m.lat_deg for m in moves]), alt, rows)


def check_batch(problem, rules: EditRules, base: Edits, moves: list[Edit], deleted=()) -> RuleCheck:
    """The edit rules on a new batch, with the base edit set's moves as context."""
    index = problem.keyframe_index
    k = len(index)
    out_of_range = [Refusal(int(d), "out_of_range", f"keyframe {d} does not exist (0..{k - 1})")
                    for d in deleted if not 0 <= d < k]
    en_before = targets_enu(problem, base.moves)
    edited_before = {m.index: (float(c[0]), float(c[1])) for m, c in zip(base.moves, en_before)}
    en = targets_enu(problem, moves)
    km = [KeyframeMove(m.index, float(c[0]), float(c[1])) for m, c in zip(moves, en)]
    all_deleted = sorted(set(base.deleted) | {int(d) for d in deleted if 0 <= d < k})
    check = check_edits(rules, problem.p_enu_m[index, :2], km, all_deleted, edited_before)
    too_few = keyframes_left(k, all_deleted, [int(d) for d in deleted if 0 <= d < k])
    if out_of_range or too_few:
        return RuleCheck(accepted=check.accepted, refusals=out_of_range + too_few + check.refusals, flags=check.flags)
    return check


def accepted_batch(base: Edits, moves: list[Edit], deleted, check: RuleCheck) -> Edits:
    """The base set with the batch's accepted moves and in-range deletions merged in."""
    ok = {m.index for m in check.accepted}
    refused_deleted = {r.index for r in check.refusals if r.reason == "out_of_range"}
    kept = [m for m in moves if m.index in ok]
    return base.merged(kept, [d for d in deleted if d not in refused_deleted], check.flags)
