"""Edit rules: which keyframes an operator may move, and which moves stand.

Pure functions over plain data so the browser can port them line for line; the cases in
``tests/vectors/edit_rules.json`` are checked by pytest here and by vitest in the browser.

Positions are planar keyframe positions in metres, ``en_m`` shape (k, 2) (east, north in
the run's local frame); the caller projects lon/lat first.  Indices are keyframe indices
(0 .. k-1), not sample rows.

Rules, applied in this order to the moves sorted by keyframe index:

1. ``out_of_range``   the index names no keyframe;
2. ``duplicate``      the same keyframe is moved twice in one batch;
3. ``deleted``        the keyframe is deleted in this batch;
4. ``not_adjustable`` only every ``every_n``-th keyframe (index % every_n == 0) is adjustable;
5. ``locked``         the keyframe lies within ``lock_n`` keyframes after (``forward``) or
                      on either side of (``both``) an earlier-edited keyframe or an accepted
                      move of this batch with a lower index (moves are taken in index order);
6. ``too_far``        the move is longer than ``max_move_m`` (always finite, see below);
7. ``order_reversed`` between two consecutive surviving keyframes i < j, each where it
                      now lies (moved in this batch or an earlier edit, else where it was
                      reported), the chord c_j - c_i points backwards along the reported
                      chord p_j - p_i (dot product <= 0; chords shorter than 1 m are not
                      judged).  So a pose dragged past an unmoved neighbour reverses the
                      order as surely as one dragged past a moved one.  Only pairs with a
                      move of this batch are judged; its move is the culprit (the later one
                      when both are).  ``order_rule`` "refuse" refuses it, "flag" accepts it
                      with a flag.

Rules 1-6 always refuse.  A refused move is left out before rule 7 is judged.

Deletions answer to one rule of their own (``keyframes_left``): a batch may not leave the
run fewer than ``MIN_KEYFRAMES`` keyframes (or delete the only keyframe of a one-keyframe
run), since the relative-motion terms and the propagation to every sample need a pose on
each side of every sample; the reason is ``too_few_keyframes``.

``max_move_m`` defaults to 1,000 m: GNSS in urban canyons is off by 5-60 m and a multipath
jump by a few hundred at worst, so a longer drag is a slip of the mouse, not a correction.
The solver's tangent plane leaves the ellipsoid by about d^2 / (2 R) at d metres from its
origin (7.8 m at 10 km); heights are read back as the reported height plus the solve's up
correction (``engine.problem``), so a 2-D move keeps its altitude at any length.  There is
no "unlimited" all the same: settings (a task's rules, the engine's config file) take 1 m
to ``MAX_MOVE_LIMIT_M`` (10 km), and ``engine.altitude`` refuses any solution whose
altitudes leave what the input and the edits allow.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

REASONS = (
    "out_of_range",
    "duplicate",
    "deleted",
    "not_adjustable",
    "locked",
    "too_far",
    "order_reversed",
)
MIN_CHORD_M = 1.0
MIN_KEYFRAMES = 2
MIN_MOVE_LIMIT_M = 1.0  # the range a setting of max_move_m may take (see the module docstring)
MAX_MOVE_LIMIT_M = 10_000.0
TOO_FEW_KEYFRAMES = "too_few_keyframes"  # the reason of ``keyframes_left`` (deletions, not moves)


@dataclass(frozen=True)
class EditRules:
    """Parameters of the edit rules, published to the browser as JSON."""

    every_n: int = 1
    lock_n: int = 0
    lock_direction: str = "forward"  # "forward" | "both"
    max_move_m: float = 1000.0  # MIN_MOVE_LIMIT_M .. MAX_MOVE_LIMIT_M (see the module docstring)
    order_rule: str = "flag"  # "refuse" | "flag"
    deleted: str = "remove"  # "remove" | "flag"

    def to_json(self) -> dict:
        return {
            "every_n": self.every_n,
            "lock_n": self.lock_n,
            "lock_direction": self.lock_direction,
            "max_move_m": self.max_move_m,
            "order_rule": self.order_rule,
            "deleted": self.deleted,
        }

    @classmethod
    def from_json(cls, data: dict) -> "EditRules":
        return cls(**{k: data[k] for k in cls().to_json() if k in data})


@dataclass(frozen=True)
class Refusal:
    """One refused (or flagged) move: keyframe index, machine reason, human message."""

    index: int
    reason: str
    message: str

    def to_json(self) -> dict:
        return {"index": self.index, "reason": self.reason, "message": self.message}


@dataclass(frozen=True)
class KeyframeMove:
    """Move keyframe ``index`` to (east_m, north_m) in the local frame."""

    index: int
    east_m: float
    north_m: float


@dataclass(frozen=True)
class RuleCheck:
    """Outcome of ``check_edits``: accepted moves, refusals and flags."""

    accepted: list[KeyframeMove] = field(default_factory=list)
    refusals: list[Refusal] = field(default_factory=list)
    flags: list[Refusal] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.refusals


def adjustable_mask(n_keyframes: int, rules: EditRules) -> np.ndarray:
    """(k,) bool: keyframes an operator may move at all (index % every_n == 0)."""
    return np.arange(n_keyframes) % max(int(rules.every_n), 1) == 0


def lock_span(index: int, n_keyframes: int, rules: EditRules) -> range:
    """Keyframe indices locked by an edit at ``index`` (the edited one excluded)."""
    hi = min(index + rules.lock_n, n_keyframes - 1)
    lo = max(index - rules.lock_n, 0) if rules.lock_direction == "both" else index + 1
    return range(lo, hi + 1)


def locked_mask(n_keyframes: int, edited: list[int], rules: EditRules) -> np.ndarray:
    """(k,) bool: keyframes locked by the edited keyframes (which are never locked themselves)."""
    locked = np.zeros(n_keyframes, dtype=bool)
    for index in edited:
        for j in lock_span(int(index), n_keyframes, rules):
            locked[j] = True
    locked[[int(i) for i in edited if 0 <= int(i) < n_keyframes]] = False
    return locked


def check_edits(
    rules: EditRules,
    reported_en_m: np.ndarray,
    moves: list[KeyframeMove],
    deleted: list[int] = (),
    edited_before: dict[int, tuple[float, float]] | None = None,
) -> RuleCheck:
    """Apply the rules to one batch of moves.

    Parameters
    ----------
    reported_en_m : ndarray, shape (k, 2)
        Reported keyframe positions (east, north), metres.
    moves : list of KeyframeMove
        The batch, in any order.
    deleted : list of int
        Keyframes deleted in this batch.
    edited_before : dict index -> (east_m, north_m), optional
        Keyframes edited in earlier revisions and their corrected positions; they lock
        their neighbours and take part in the order check.  Moving one of them again is
        allowed (a re-drag replaces the earlier edit).
    """
    reported = np.asarray(reported_en_m, dtype=float).reshape(-1, 2)
    k = len(reported)
    edited_before = dict(edited_before or {})
    deleted_set = {int(i) for i in deleted}
    refusals: list[Refusal] = []
    flags: list[Refusal] = []
    seen: set[int] = set()
    accepted: list[KeyframeMove] = []
    lock_sources = sorted(i for i in edited_before if i not in {m.index for m in moves})
    locked = set()
    for i in lock_sources:
        locked.update(lock_span(i, k, rules))
    adjustable = adjustable_mask(k, rules)
    for move in sorted(moves, key=lambda m: m.index):
        i = int(move.index)
        refusal = _first_refusal(rules, reported, move, k, seen, deleted_set, adjustable, locked)
        seen.add(i)
        if refusal is not None:
            refusals.append(refusal)
            continue
        accepted.append(move)
        locked.update(j for j in lock_span(i, k, rules) if j != i)
    reversed_indices = _order_reversals(rules, reported, accepted, deleted_set, edited_before, refusals, flags)
    if rules.order_rule == "refuse":
        accepted = [m for m in accepted if m.index not in reversed_indices]
    return RuleCheck(accepted=accepted, refusals=refusals, flags=flags)


def _order_reversals(rules, reported, accepted, deleted_set, edited_before, refusals, flags) -> set[int]:
    """Rule 7 over every surviving keyframe in track order; appends to ``refusals`` or
    ``flags`` and returns the culprits."""
    k = len(reported)
    now = reported.copy()
    for i, xy in edited_before.items():
        if 0 <= i < k:
            now[i] = xy
    batch = {m.index for m in accepted}
    for m in accepted:
        now[m.index] = (m.east_m, m.north_m)
    alive = np.setdiff1d(np.arange(k), np.fromiter(deleted_set, dtype=np.int64, count=len(deleted_set)))
    a, b = alive[:-1], alive[1:]
    chord = reported[b] - reported[a]
    backwards = (np.hypot(chord[:, 0], chord[:, 1]) >= MIN_CHORD_M) & (np.sum((now[b] - now[a]) * chord, axis=1) <= 0.0)
    culprits: set[int] = set()
    for ia, ib in zip(a[backwards].tolist(), b[backwards].tolist()):
        culprit = ib if ib in batch else ia
        if culprit not in batch or culprit in culprits:
            continue
        culprits.add(culprit)
        other = ia if culprit == ib else ib
        item = Refusal(
            culprit,
            "order_reversed",
            f"Moving keyframe {culprit} puts it on the wrong side of keyframe {other}: "
            "the poses would run backwards along the track.",
        )
        (refusals if rules.order_rule == "refuse" else flags).append(item)
    return culprits


def _first_refusal(rules, reported, move, k, seen, deleted_set, adjustable, locked) -> Refusal | None:
    i = int(move.index)
    if i < 0 or i >= k:
        return Refusal(i, "out_of_range", f"There is no keyframe {i}; this run has {k} keyframes (0 to {k - 1}).")
    if i in seen:
        return Refusal(i, "duplicate", f"Keyframe {i} is moved twice in one batch; send one move per keyframe.")
    if i in deleted_set:
        return Refusal(i, "deleted", f"Keyframe {i} is deleted in this batch and cannot also be moved.")
    if not adjustable[i]:
        return Refusal(
            i, "not_adjustable", f"Only every {ordinal(rules.every_n)} keyframe can be moved; keyframe {i} is not one of them."
        )
    if i in locked:
        return Refusal(
            i, "locked",
            f"Keyframe {i} is locked: it lies within {rules.lock_n} keyframe{'' if rules.lock_n == 1 else 's'} of an edited keyframe."
        )
    distance_m = float(np.hypot(move.east_m - reported[i, 0], move.north_m - reported[i, 1]))
    if distance_m > rules.max_move_m:
        return Refusal(
            i,
            "too_far",
            f"Keyframe {i} would move {distance_m:.1f} m; the limit is {rules.max_move_m:g} m.",
        )
    return None


def ordinal(n: int) -> str:
    """1st, 2nd, 3rd, 4th, 11th, 12th, 21st..."""
    suffix = "th" if 11 <= abs(n) % 100 <= 13 else {1: "st", 2: "nd", 3: "rd"}.get(abs(n) % 10, "th")
    return f"{n}{suffix}"


def keyframes_left(n_keyframes: int, deleted: list[int], batch_deleted: list[int]) -> list[Refusal]:
    """Refuse this batch's deletions when, with the earlier ones (``deleted`` holds both),
    fewer than ``MIN_KEYFRAMES`` keyframes would remain (fewer than the run has, if it has less)."""
    left = n_keyframes - len({int(i) for i in deleted if 0 <= int(i) < n_keyframes})
    if left >= min(MIN_KEYFRAMES, n_keyframes):
        return []
    message = (f"Deleting these keyframes would leave {left} of the run's {n_keyframes}; "
               f"a run keeps at least {min(MIN_KEYFRAMES, n_keyframes)}.")
    return [Refusal(int(i), TOO_FEW_KEYFRAMES, message) for i in sorted({int(i) for i in batch_deleted})]
