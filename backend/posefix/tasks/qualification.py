"""Qualification requirements of a task checked against an operator's facts, with reasons in words.

A requirement is ``{"qualification", "comparator", "value"}`` as on Mechanical Turk:

- ``approved_count`` — experience: approved assignments (numeric comparators);
- ``accuracy_m`` — mean horizontal error on gold runs, metres (numeric comparators; an
  operator never measured does not meet it, and is served a gold run to be measured on);
- ``home_area`` with ``contains`` — the run lies in the operator's home area (checked per run);
- ``qualification_test`` with ``passed`` — the operator passed the qualification test;
- any other name — an admin-granted qualification (numeric comparators, ``exists``,
  ``not_exists``, ``in``, ``not_in``).

No database here: the service gathers ``OperatorFacts`` and this module decides.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "Comparator", "Requirement", "OperatorFacts", "HomeArea", "check_requirements", "check_home_area",
    "BUILTIN", "validate_requirement",
]

EARTH_RADIUS_M = 6371008.8  # mean Earth radius (IUGG), enough for "within a few km of home"


class Comparator(enum.StrEnum):
    lt = "lt"
    le = "le"
    gt = "gt"
    ge = "ge"
    eq = "eq"
    ne = "ne"
    exists = "exists"
    not_exists = "not_exists"
    in_ = "in"
    not_in = "not_in"
    contains = "contains"
    passed = "passed"


NUMERIC = {Comparator.lt, Comparator.le, Comparator.gt, Comparator.ge, Comparator.eq, Comparator.ne}
WORDS = {
    Comparator.lt: "less than", Comparator.le: "at most", Comparator.gt: "more than", Comparator.ge: "at least",
    Comparator.eq: "exactly", Comparator.ne: "other than",
}
BUILTIN = {"approved_count", "accuracy_m", "home_area", "qualification_test"}


@dataclass(frozen=True)
class Requirement:
    qualification: str
    comparator: Comparator
    value: float | list[float] | None = None

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Requirement:
        return cls(str(data["qualification"]), Comparator(data["comparator"]), data.get("value"))


def validate_requirement(data: dict[str, Any]) -> str | None:
    """None when the requirement is well formed, else what is wrong with it."""
    name, comp, value = data.get("qualification"), data.get("comparator"), data.get("value")
    if comp not in set(Comparator):
        return f"comparator {comp!r} is not one of {', '.join(c.value for c in Comparator)}"
    c = Comparator(comp)
    if name == "home_area":
        return None if c == Comparator.contains else "home_area takes the comparator 'contains'"
    if name == "qualification_test":
        return None if c == Comparator.passed else "qualification_test takes the comparator 'passed'"
    if c in (Comparator.contains, Comparator.passed):
        return f"comparator {c.value!r} applies only to home_area / qualification_test"
    if name in ("approved_count", "accuracy_m") and c not in NUMERIC:
        return f"{name} takes a numeric comparator ({', '.join(sorted(x.value for x in NUMERIC))})"
    if c in NUMERIC and not isinstance(value, (int, float)):
        return f"comparator {c.value!r} needs a number as value"
    if c in (Comparator.in_, Comparator.not_in) and not (isinstance(value, list) and value and len(value) <= 15):
        return f"comparator {c.value!r} needs a list of 1 to 15 numbers as value"
    return None


@dataclass(frozen=True)
class HomeArea:
    """A point and radius, or a polygon ([[lon, lat], ...], closed or not)."""

    lon: float | None = None
    lat: float | None = None
    radius_m: float | None = None
    polygon: list[list[float]] | None = None

    @property
    def defined(self) -> bool:
        return bool(self.polygon) or (self.lon is not None and self.lat is not None and self.radius_m is not None)


@dataclass
class OperatorFacts:
    approved_count: int = 0
    accuracy_m: float | None = None
    gold_scored: int = 0
    granted: dict[str, float] = field(default_factory=dict)
    test_status: str = "not_taken"  # not_taken | pending | passed | failed
    test_detail: str = ""
    home: HomeArea = field(default_factory=HomeArea)


def haversine_m(lon1: np.ndarray, lat1: np.ndarray, lon2: float, lat2: float) -> np.ndarray:
    """Great-circle distance on the mean sphere, metres."""
    p1, p2 = np.radians(lat1), math.radians(lat2)
    a = np.sin((p2 - p1) / 2) ** 2 + np.cos(p1) * math.cos(p2) * np.sin(np.radians(lon2 - np.asarray(lon1)) / 2) ** 2
    return 2 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0)))


def points_in_polygon(lon: np.ndarray, lat: np.ndarray, polygon: list[list[float]]) -> np.ndarray:
    """Even-odd ray casting in lon/lat (fine for home areas of city size), vectorised over points."""
    px, py = np.asarray(lon, dtype=float)[:, None], np.asarray(lat, dtype=float)[:, None]
    poly = np.asarray(polygon, dtype=float)
    x1, y1 = poly[:, 0][None], poly[:, 1][None]
    x2, y2 = np.roll(poly[:, 0], -1)[None], np.roll(poly[:, 1], -1)[None]
    crosses = (y1 > py) != (y2 > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = x1 + (py - y1) * (x2 - x1) / (y2 - y1)
    return ((crosses & (px < x_at)).sum(axis=1) % 2) == 1


def check_home_area(home: HomeArea, lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
    """Which points (run centres) lie in the home area, (n,) bool."""
    lon, lat = np.atleast_1d(np.asarray(lon, dtype=float)), np.atleast_1d(np.asarray(lat, dtype=float))
    if not home.defined:
        return np.zeros(lon.shape, dtype=bool)
    if home.polygon:
        return points_in_polygon(lon, lat, home.polygon)
    assert home.lon is not None and home.lat is not None and home.radius_m is not None
    return haversine_m(lon, lat, home.lon, home.lat) <= home.radius_m


def _compare(c: Comparator, have: float, want: Any) -> bool:
    if c == Comparator.lt:
        return have < want
    if c == Comparator.le:
        return have <= want
    if c == Comparator.gt:
        return have > want
    if c == Comparator.ge:
        return have >= want
    if c == Comparator.eq:
        return have == want
    if c == Comparator.ne:
        return have != want
    if c == Comparator.in_:
        return have in want
    if c == Comparator.not_in:
        return have not in want
    raise ValueError(f"comparator {c} is not a value comparison")


def _fmt(x: Any) -> str:
    if isinstance(x, float):
        return f"{x:.6g}"
    return str(x)


def _check_one(req: Requirement, facts: OperatorFacts) -> str | None:
    """None when met, else the reason in words."""
    name, c, value = req.qualification, req.comparator, req.value
    if name == "home_area":
        # checked per run by the queue; here only that a home area exists at all
        return None if facts.home.defined else "you have no home area set in your profile, and this task needs runs near home"
    if name == "qualification_test":
        if facts.test_status == "passed":
            return None
        if facts.test_status == "failed":
            return f"you did not pass the qualification test ({facts.test_detail})"
        if facts.test_status == "pending":
            return "your qualification test is still being scored or corrected"
        return "you have not taken the qualification test yet (ask for a task to get it)"
    if name == "approved_count":
        if _compare(c, facts.approved_count, value):
            return None
        return f"needs {WORDS[c]} {_fmt(value)} approved assignments; you have {facts.approved_count}"
    if name == "accuracy_m":
        if facts.accuracy_m is None:
            return f"needs an accuracy of {WORDS[c]} {_fmt(value)} m on gold runs; yours has not been measured yet"
        if _compare(c, facts.accuracy_m, value):
            return None
        return (f"needs an accuracy of {WORDS[c]} {_fmt(value)} m on gold runs; yours is "
                f"{facts.accuracy_m:.2f} m over {facts.gold_scored} gold run(s)")
    held = facts.granted.get(name)
    if c == Comparator.exists:
        return None if held is not None else f"needs the qualification '{name}', which you do not hold"
    if c == Comparator.not_exists:
        return None if held is None else f"is closed to holders of the qualification '{name}'"
    if held is None:
        return f"needs the qualification '{name}', which you do not hold"
    if _compare(c, held, value):
        return None
    if c in (Comparator.in_, Comparator.not_in):
        joined = ", ".join(_fmt(v) for v in value)  # type: ignore[union-attr]
        return f"needs '{name}' {'one of' if c == Comparator.in_ else 'none of'} {joined}; yours is {_fmt(held)}"
    return f"needs '{name}' {WORDS[c]} {_fmt(value)}; yours is {_fmt(held)}"


def check_requirements(requirements: list[dict[str, Any]], facts: OperatorFacts) -> list[str]:
    """Reasons (in words) why the operator does not qualify; empty when they do."""
    out = []
    for data in requirements:
        reason = _check_one(Requirement.from_json(data), facts)
        if reason is not None:
            out.append(reason)
    return out


def needs_home_area(requirements: list[dict[str, Any]]) -> bool:
    return any(r.get("qualification") == "home_area" for r in requirements)


def waits_for_accuracy(requirements: list[dict[str, Any]], facts: OperatorFacts) -> bool:
    """The operator's accuracy was never measured and is all this task still waits for (a
    scored gold run would settle it)."""
    if facts.accuracy_m is not None or not any(r.get("qualification") == "accuracy_m" for r in requirements):
        return False
    return not check_requirements([r for r in requirements if r.get("qualification") != "accuracy_m"], facts)


def needs_test(requirements: list[dict[str, Any]]) -> bool:
    return any(r.get("qualification") == "qualification_test" for r in requirements)
