"""Operators: the facts their qualification is judged on, eligibility for a task, home
areas, granted qualifications and statistics (the rules themselves: ``qualification``)."""

from __future__ import annotations

import datetime as dt
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from posefix.errors import NotFound
from posefix.tasks import qualification as qual
from posefix.tasks import repository as repo
from posefix.tasks.models import AssignmentStatus, OperatorQualification, Task
from posefix.tasks.schemas import HomeAreaIn
from posefix.users.models import User

TEST_QUALIFICATION = "qualification_test"


def operator_facts(session: Session, user_id: int) -> qual.OperatorFacts:
    prof = repo.profile(session, user_id)
    home = qual.HomeArea() if prof is None else qual.HomeArea(prof.home_lon, prof.home_lat, prof.home_radius_m, prof.home_polygon)
    granted = {q.name: q.value for q in repo.qualifications(session, user_id)}
    acc, n_gold = repo.gold_accuracy(session, user_id)
    tests = repo.test_assignments(session, user_id)
    status, detail = "not_taken", ""
    if TEST_QUALIFICATION in granted:
        status = "passed" if granted[TEST_QUALIFICATION] >= 1 else "failed"
        q = next(q for q in repo.qualifications(session, user_id) if q.name == TEST_QUALIFICATION)
        detail = (q.detail or {}).get("message", "")
    elif any(a.status in (AssignmentStatus.accepted, AssignmentStatus.submitted) for a in tests):
        status = "pending"
    return qual.OperatorFacts(approved_count=repo.approved_count(session, user_id), accuracy_m=acc, gold_scored=n_gold,
                              granted=granted, test_status=status, test_detail=detail, home=home)


def eligibility(session: Session, user_id: int, task: Task, facts: qual.OperatorFacts | None = None) -> list[str]:
    facts = facts or operator_facts(session, user_id)
    reasons = qual.check_requirements(task.requirements, facts)
    if not reasons and qual.needs_home_area(task.requirements):
        centres = repo.task_run_centres(session, [task.id])
        inside = qual.check_home_area(facts.home, np.array([c[2] for c in centres]), np.array([c[3] for c in centres]))
        if centres and not inside.any():
            reasons.append("none of this task's runs lies within your home area")
    return reasons


def set_home_area(session: Session, user_id: int, body: HomeAreaIn, now: dt.datetime) -> None:
    repo.lock_operator(session, user_id, now)
    prof = repo.profile(session, user_id)
    assert prof is not None
    prof.home_lon, prof.home_lat, prof.home_radius_m = body.lon, body.lat, body.radius_m
    prof.home_polygon = body.polygon
    prof.updated_at = now
    session.flush()


def set_qualification(session: Session, user_id: int, name: str, value: float, granted_by: int | None,
                      now: dt.datetime, detail: dict[str, Any] | None = None) -> OperatorQualification:
    q = session.get(OperatorQualification, (user_id, name))
    if q is None:
        q = OperatorQualification(user_id=user_id, name=name)
        session.add(q)
    q.value, q.granted_by, q.granted_at, q.detail = value, granted_by, now, detail
    session.flush()
    return q


def revoke_qualification(session: Session, user_id: int, name: str) -> None:
    q = session.get(OperatorQualification, (user_id, name))
    if q is None:
        raise NotFound(f"user {user_id} does not hold '{name}'", code="qualification_not_found")
    session.delete(q)
    session.flush()


def operator_stats(session: Session, users: list[User]) -> list[dict[str, Any]]:
    numbers = repo.operator_numbers(session, [u.id for u in users])
    out = []
    for u in users:
        n = numbers.get(u.id, {"submitted": 0, "approved": 0, "rejected": 0, "returned": 0, "expired": 0,
                               "accuracy_m": None, "gold_scored": 0, "agreement_m": None, "work_s": 0.0})
        facts = operator_facts(session, u.id)
        prof = repo.profile(session, u.id)
        home = None
        if prof is not None and facts.home.defined:
            home = {"lon": prof.home_lon, "lat": prof.home_lat, "radius_m": prof.home_radius_m, "polygon": prof.home_polygon}
        work_s = n["work_s"]
        out.append({
            "user_id": u.id, "username": u.username, "submitted": n["submitted"], "approved": n["approved"],
            "rejected": n["rejected"], "returned": n["returned"], "expired": n["expired"], "accuracy_m": n["accuracy_m"],
            "gold_scored": n["gold_scored"], "agreement_m": n["agreement_m"],
            "throughput_per_h": (n["submitted"] / (work_s / 3600.0)) if work_s > 0 else None,
            "mean_work_s": (work_s / n["submitted"]) if n["submitted"] else None,
            "test_status": facts.test_status, "home_area": home,
            "qualifications": [{"name": q.name, "value": q.value, "granted_by": q.granted_by, "granted_at": q.granted_at}
                               for q in repo.qualifications(session, u.id)],
        })
    return out
