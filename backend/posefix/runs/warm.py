"""A run's engine problem, loaded once per process, and a ready revision solved before the
first drag (the process cache itself is ``posefix.runs.solutions``)."""

from __future__ import annotations

from typing import Any

from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.db import Database
from posefix.engine import Edits, Problem
from posefix.errors import NotFound
from posefix.runs import repository as runs_repo
from posefix.runs import solutions, storage
from posefix.runs.engine_config import engine_config
from posefix.runs.models import Run, RunStatus
from posefix.filestore import file_store


def load_problem(session: Session, settings: Settings, run: Run) -> Problem:
    cached = solutions.PROBLEMS.peek(run.id, run.rules)
    if cached is not None:
        return cached
    rev0 = runs_repo.revision(session, run.id, 0)
    if rev0 is None:
        raise NotFound(f"run {run.id} has no imported data", code="revision_not_found")
    samples_file, derived, name, rules = rev0.samples_file, run.orientation_derived, run.name, dict(run.rules)

    def load() -> tuple[Any, Any]:
        pose = storage.read_samples(file_store(settings), samples_file, orientation_derived=derived, source=name)
        return pose, engine_config(settings, rules)

    return solutions.PROBLEMS.problem(run.id, rules, load)


def stored_solution(settings: Settings, run: Run, keyframes_file: str | None) -> solutions.StoredSolution | None:
    if keyframes_file is None:
        return None
    return solutions.StoredSolution.of(settings, keyframes_file, engine_config(settings, run.rules))


def prewarm(db: Database, settings: Settings, run_id: int, revision: int) -> None:
    """Load the run and solve a ready revision in the background, so the first drag is fast."""

    def work() -> None:
        with db.transaction(write=False) as session:
            run = session.get(Run, run_id)
            if run is None or run.status == RunStatus.deleted:
                return
            if solutions.PROBLEMS.solution(run.id, run.rules, revision) is not None:
                return
            rev = runs_repo.revision(session, run.id, revision)
            if rev is None:  # still being computed: its keyframes are not served yet either
                return
            base = Edits().to_json() if revision == 0 else rev.edit_set
            problem = load_problem(session, settings, run)
            rules = dict(run.rules)
            stored = stored_solution(settings, run, rev.keyframes_file)
        sol = solutions.base_solution(run_id, rules, revision, problem, base, stored)
        problem.drag_base(sol)  # an unedited run with implausible steps: the first drag's start (engine.drag_base)

    solutions.warm_once(run_id, revision, work)
