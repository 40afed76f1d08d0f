"""Operator edits: the EDITS.json file and matching its times to run samples.

Format::

    {"edits": [{"t": 12.5, "lat": 37.72, "lon": -122.47, "alt": 31.0}, ...],
     "deleted": [13.0, ...]}

``alt`` is optional (a 2-D edit: altitude left free). Each ``t`` must name a sample of the
run exactly, to the millisecond; ``match_edits`` refuses any that does not.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from posefix.core.run import PoseRun
from posefix.io._jsonpos import loads_with_lines
from posefix.io.atomic import atomic_write
from posefix.io.errors import EditMatchError, EditsFormatError

__all__ = ["Move", "EditSet", "MatchedEdits", "read_edits", "write_edits", "match_edits", "TIME_MATCH_TOLERANCE_S"]

# "to the millisecond": a time matches a sample when they round to the same millisecond,
# i.e. within half a millisecond (plus float slack for times like 1e9 s).
TIME_MATCH_TOLERANCE_S = 0.0005 + 1e-9


@dataclass(frozen=True)
class Move:
    """Move the sample at ``t_s`` to (lat_deg, lon_deg[, alt_m]); ``alt_m`` None = 2-D edit."""

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float | None = None


@dataclass(frozen=True)
class EditSet:
    """A batch of edits: moves and deletions, each naming a sample by its time."""

    moves: list[Move] = field(default_factory=list)
    deleted: list[float] = field(default_factory=list)
    source: str = ""
    # 1-based lines in ``source`` of each move's object and of the "deleted" list, when
    # read from a file (for messages); empty otherwise.
    move_lines: list[int | None] = field(default_factory=list)
    deleted_line: int | None = None

    def __len__(self) -> int:
        return len(self.moves) + len(self.deleted)


@dataclass(frozen=True)
class MatchedEdits:
    """Edits resolved to sample rows of a run.

    Attributes
    ----------
    move_index : ndarray, shape (m,), int
        Row of each move, in the order of ``EditSet.moves``.
    deleted_index : ndarray, shape (d,), int
        Row of each deleted sample, in the order of ``EditSet.deleted``.
    """

    move_index: np.ndarray
    deleted_index: np.ndarray


class _Bad(Exception):
    def __init__(self, obj: Any, field: str, message: str):
        self.obj, self.field, self.message = obj, field, message


def _number(obj: Any, key: str, path: str, optional: bool = False) -> float | None:
    if key not in obj or (optional and obj[key] is None):
        if optional:
            return None
        raise _Bad(obj, f"{path}.{key}", "missing")
    v = obj[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _Bad(obj, f"{path}.{key}", f"not a number: {v!r}")
    v = float(v)
    if not math.isfinite(v):
        raise _Bad(obj, f"{path}.{key}", f"not a finite number: {v!r}")
    return v


def _parse(doc: Any) -> tuple[list[Move], list[float], list[int | None]]:
    if not isinstance(doc, dict):
        raise _Bad(doc, "$", 'top level must be an object {"edits": [...], "deleted": [...]}')
    unknown = set(doc) - {"edits", "deleted"}
    if unknown:
        raise _Bad(doc, sorted(unknown)[0], "unknown key (expected 'edits' and 'deleted')")
    edits = doc.get("edits", [])
    deleted = doc.get("deleted", [])
    if not isinstance(edits, list):
        raise _Bad(doc, "edits", "must be a list")
    if not isinstance(deleted, list):
        raise _Bad(doc, "deleted", "must be a list of times")
    moves = []
    lines: list[int | None] = []
    for i, e in enumerate(edits):
        path = f"edits[{i}]"
        if not isinstance(e, dict):
            raise _Bad(doc, path, 'must be an object {"t", "lat", "lon"[, "alt"]}')
        extra = set(e) - {"t", "lat", "lon", "alt"}
        if extra:
            raise _Bad(e, f"{path}.{sorted(extra)[0]}", "unknown key")
        t = _number(e, "t", path)
        lat = _number(e, "lat", path)
        lon = _number(e, "lon", path)
        alt = _number(e, "alt", path, optional=True)
        if abs(lat) > 90:
            raise _Bad(e, f"{path}.lat", f"latitude {lat} is outside [-90, 90]")
        if abs(lon) > 180:
            raise _Bad(e, f"{path}.lon", f"longitude {lon} is outside [-180, 180]")
        moves.append(Move(t, lat, lon, alt))
        lines.append(getattr(e, "line", None))
    dels = []
    for i, t in enumerate(deleted):
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
            raise _Bad(doc, f"deleted[{i}]", f"not a finite time in seconds: {t!r}")
        dels.append(float(t))
    return moves, dels, lines


def read_edits(path: str | os.PathLike) -> EditSet:
    """Read EDITS.json; raise ``EditsFormatError`` naming file, line and JSON field."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise EditsFormatError(path, None, None, f"cannot read file: {exc}") from None
    try:
        doc = loads_with_lines(text)
    except json.JSONDecodeError as exc:
        raise EditsFormatError(path, exc.lineno, None, f"not valid JSON: {exc.msg}") from None
    try:
        moves, dels, lines = _parse(doc)
    except _Bad as exc:
        raise EditsFormatError(path, getattr(exc.obj, "line", None), exc.field, exc.message) from None
    deleted_line = _line_of_key(text, "deleted")
    return EditSet(moves=moves, deleted=dels, source=str(path), move_lines=lines, deleted_line=deleted_line)


def _line_of_key(text: str, key: str) -> int | None:
    pos = text.find(f'"{key}"')
    return None if pos < 0 else text.count("\n", 0, pos) + 1


def write_edits(edits: EditSet, path: str | os.PathLike) -> None:
    """Write an ``EditSet`` as EDITS.json, atomically (times to the microsecond)."""
    doc = {
        "edits": [
            {"t": m.t_s, "lat": m.lat_deg, "lon": m.lon_deg, **({} if m.alt_m is None else {"alt": m.alt_m})}
            for m in edits.moves
        ],
        "deleted": list(edits.deleted),
    }
    with atomic_write(path, "w") as fh:
        json.dump(doc, fh, indent=1)
        fh.write("\n")


def _match_times(t_run: np.ndarray, t_query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest sample row for each query time, and whether it is within the tolerance."""
    j = np.clip(np.searchsorted(t_run, t_query), 1, max(t_run.size - 1, 1))
    j0 = np.clip(j - 1, 0, t_run.size - 1)
    j1 = np.clip(j, 0, t_run.size - 1)
    pick = np.where(np.abs(t_run[j0] - t_query) <= np.abs(t_run[j1] - t_query), j0, j1)
    ok = np.abs(t_run[pick] - t_query) <= TIME_MATCH_TOLERANCE_S
    return pick, ok


def match_edits(run: PoseRun, edits: EditSet) -> MatchedEdits:
    """Resolve each edit's time to a sample row of ``run``.

    Raises
    ------
    EditMatchError
        when a time matches no sample (to the millisecond), or two edits name one sample,
        or a sample is both moved and deleted. The error names the edits file, the field
        (``edits[i].t`` / ``deleted[i]``) and the nearest sample time.
    """
    src = edits.source or "edits"
    t_moves = np.array([m.t_s for m in edits.moves], dtype=float)
    t_dels = np.array(edits.deleted, dtype=float)
    mi, mok = _match_times(run.t_s, t_moves) if t_moves.size else (np.zeros(0, int), np.zeros(0, bool))
    di, dok = _match_times(run.t_s, t_dels) if t_dels.size else (np.zeros(0, int), np.zeros(0, bool))
    def line_of(name: str, k: int) -> int | None:
        if name.startswith("edits"):
            return edits.move_lines[k] if k < len(edits.move_lines) else None
        return edits.deleted_line

    for name, times, rows, ok in (("edits[{}].t", t_moves, mi, mok), ("deleted[{}]", t_dels, di, dok)):
        bad = np.flatnonzero(~ok)
        if bad.size:
            k = int(bad[0])
            raise EditMatchError(
                src, line_of(name, k), name.format(k),
                f"t={float(times[k])!r} s matches no sample of {run.source or 'the run'} to the millisecond "
                f"(nearest sample t={float(run.t_s[rows[k]])!r} s)",
            )
    seen: dict[int, str] = {}
    for name, rows in (("edits[{}].t", mi), ("deleted[{}]", di)):
        for k, r in enumerate(rows.tolist()):
            label = name.format(k)
            if r in seen:
                raise EditMatchError(src, line_of(name, k), label, f"names the same sample (t={float(run.t_s[r])!r} s) as {seen[r]}")
            seen[r] = label
    return MatchedEdits(move_index=mi.astype(np.intp), deleted_index=di.astype(np.intp))
