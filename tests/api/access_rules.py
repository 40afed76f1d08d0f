"""The access rule of every route: the one table the role-matrix test and docs/SECURITY.md share.

Each route maps to the outcome class it gives each principal, in PRINCIPALS order:
``ok`` (served: 2xx, or a 4xx that is not about access, e.g. 409 or 422), ``401`` (no
credentials), ``403`` (role, scope or review rule refuses), ``404`` (hidden or absent: a run or
task the caller may not see answers as if it did not exist). ``tests/api/test_role_matrix.py``
asks every route as every principal against a seeded app (see its docstring for who owns what)
on SQLite and PostgreSQL. ``python -m tests.api.access_rules --write`` writes the table into
docs/SECURITY.md between the markers; ``--check`` fails when the page differs.

Every id the test asks with names a real seeded object (a run with an image, a floor plan with
its model, a tracking session, a tile source with a live upstream), so each cell shows how the
object's owner and the caller's role are judged, not how an absent id answers.
"""

from __future__ import annotations

import sys
from pathlib import Path

PRINCIPALS = ("anonymous", "op_own_task", "op_other_task", "op_no_task", "rev_own_work", "rev_other_work",
              "admin", "read_token", "write_token")
BEGIN = "<!-- role-matrix:begin (python -m tests.api.access_rules --write) -->"
END = "<!-- role-matrix:end -->"
DOC = Path(__file__).resolve().parents[2] / "docs" / "SECURITY.md"

RULES: dict[tuple[str, str], str] = {
    ("GET", "/healthz"):                                             "ok ok ok ok ok ok ok ok ok",
    ("GET", "/readyz"):                                              "ok ok ok ok ok ok ok ok ok",
    ("GET", "/metrics"):                                             "ok ok ok ok ok ok ok ok ok",
    ("POST", "/api/v1/auth/login"):                                  "ok ok ok ok ok ok ok ok ok",
    ("GET", "/api/v1/auth/me"):                                      "401 ok ok ok ok ok ok ok ok",
    ("GET", "/api/v1/tokens"):                                       "401 ok ok ok ok ok ok ok ok",
    ("POST", "/api/v1/tokens"):                                      "401 ok ok ok ok ok ok 403 403",
    ("GET", "/api/v1/users"):                                        "401 403 403 403 403 403 ok ok ok",
    ("POST", "/api/v1/users"):                                       "401 403 403 403 403 403 ok 403 ok",
    ("GET", "/api/v1/users/{user_id}"):                              "401 403 403 403 403 403 ok ok ok",
    ("PATCH", "/api/v1/users/{user_id}"):                            "401 403 403 403 403 403 ok 403 ok",
    ("GET", "/api/v1/users/{user_id}/activity"):                     "401 403 403 403 403 403 ok ok ok",
    ("POST", "/api/v1/runs"):                                        "401 403 403 403 403 403 ok 403 ok",
    ("GET", "/api/v1/runs"):                                         "401 ok ok ok ok ok ok ok ok",
    ("GET", "/api/v1/upload-formats"):                               "401 ok ok ok ok ok ok ok ok",
    ("GET", "/api/v1/runs/{run_id}"):                                "401 ok 404 404 ok ok ok ok ok",
    ("GET", "/api/v1/runs/{run_id}/keyframes"):                      "401 ok 404 404 ok ok ok ok ok",
    ("GET", "/api/v1/runs/{run_id}/export"):                         "401 ok 404 404 ok ok ok ok ok",
    ("GET", "/api/v1/runs/{run_id}/history"):                        "401 ok 404 404 ok ok ok ok ok",
    ("POST", "/api/v1/runs/{run_id}/review"):                        "401 403 403 403 403 ok ok 403 ok",
    ("GET", "/api/v1/runs/{run_id}/images"):                         "401 ok 404 404 ok ok ok ok ok",
    ("GET", "/api/v1/images/{image_id}"):                            "401 ok 404 404 ok ok ok ok ok",
    ("GET", "/api/v1/images/{image_id}/thumbnail"):                  "401 ok 404 404 ok ok ok ok ok",
    ("POST", "/api/v1/runs/{run_id}/preview"):                       "401 ok 404 404 ok ok ok 403 ok",
    ("POST", "/api/v1/runs/{run_id}/edits"):                         "401 403 404 404 ok ok ok 403 ok",
    ("GET", "/api/v1/runs/{run_id}/edits"):                          "401 ok 404 404 ok ok ok ok ok",
    ("GET", "/api/v1/runs/{run_id}/revisions"):                      "401 ok 404 404 ok ok ok ok ok",
    ("GET", "/api/v1/runs/{run_id}/revisions/{number}"):             "401 ok 404 404 ok ok ok ok ok",
    ("GET", "/api/v1/runs/{run_id}/diff"):                           "401 ok 404 404 ok ok ok ok ok",
    ("POST", "/api/v1/runs/{run_id}/revert"):                        "401 403 404 404 ok ok ok 403 ok",
    ("POST", "/api/v1/runs/{run_id}/batches/{batch_id}/retry"):      "401 403 404 404 ok ok ok 403 ok",
    ("POST", "/api/v1/runs/{run_id}/batches/{batch_id}/discard"):    "401 403 404 404 ok ok ok 403 ok",
    ("GET", "/api/v1/jobs/{job_id}"):                                "401 ok 404 404 ok ok ok ok ok",
    ("GET", "/api/v1/events"):                                       "401 ok ok ok ok ok ok ok ok",
    ("GET", "/api/v1/tile-sources"):                                 "401 ok ok ok ok ok ok ok ok",
    ("POST", "/api/v1/tile-sources"):                                "401 403 403 403 403 403 ok 403 ok",
    ("GET", "/api/v1/tile-sources/{ref}"):                           "401 ok ok ok ok ok ok ok ok",
    ("GET", "/api/v1/tiles/{source}/{z}/{x}/{y}.{ext}"):             "401 ok ok ok ok ok ok ok ok",
    ("GET", "/api/v1/map/style.json"):                               "401 ok ok ok ok ok ok ok ok",
    ("POST", "/api/v1/tasks"):                                       "401 403 403 403 403 403 ok 403 ok",
    ("GET", "/api/v1/tasks"):                                        "401 403 403 403 ok ok ok ok ok",
    ("GET", "/api/v1/tasks/{task_id}"):                              "401 404 404 404 ok ok ok ok ok",
    ("GET", "/api/v1/tasks/{task_id}/history"):                      "401 404 404 404 ok ok ok ok ok",
    ("GET", "/api/v1/tasks/{task_id}/events"):                       "401 404 404 404 ok ok ok ok ok",
    ("GET", "/api/v1/tasks/{task_id}/eligibility"):                  "401 ok ok ok ok ok ok ok ok",
    ("POST", "/api/v1/tasks/next"):                                  "401 ok ok ok ok ok ok 403 ok",
    ("GET", "/api/v1/assignments/mine"):                             "401 ok ok ok ok ok ok ok ok",
    ("GET", "/api/v1/assignments/{assignment_id}"):                  "401 ok 404 404 ok ok ok ok ok",
    ("POST", "/api/v1/assignments/{assignment_id}/extend"):          "401 ok 404 404 404 404 404 403 404",
    ("POST", "/api/v1/assignments/{assignment_id}/submit"):          "401 ok 404 404 404 404 404 403 404",
    ("GET", "/api/v1/review/queue"):                                 "401 403 403 403 ok ok ok ok ok",
    ("GET", "/api/v1/task-runs/{task_run_id}/review"):               "401 403 403 403 ok ok ok ok ok",
    ("POST", "/api/v1/task-runs/{task_run_id}/merge"):               "401 403 403 403 ok ok ok 403 ok",
    ("POST", "/api/v1/assignments/{assignment_id}/review"):          "401 403 403 403 ok ok ok 403 ok",
    ("GET", "/api/v1/operators"):                                    "401 403 403 403 403 403 ok ok ok",
    ("GET", "/api/v1/operators/me"):                                 "401 ok ok ok ok ok ok ok ok",
    ("PUT", "/api/v1/operators/me/home-area"):                       "401 ok ok ok ok ok ok 403 ok",
    ("PUT", "/api/v1/operators/{user_id}/home-area"):                "401 403 403 403 403 403 ok 403 ok",
    ("POST", "/api/v1/operators/{user_id}/qualifications"):          "401 403 403 403 403 403 ok 403 ok",
    ("GET", "/api/v1/gold-runs"):                                    "401 403 403 403 403 403 ok ok ok",
    ("POST", "/api/v1/gold-runs"):                                   "401 403 403 403 403 403 ok 403 ok",
    ("POST", "/api/v1/floorplans"):                                  "401 403 403 403 403 403 ok 403 ok",
    ("GET", "/api/v1/floorplans"):                                   "401 ok ok ok ok ok ok ok ok",
    ("GET", "/api/v1/floorplans/{floorplan_id}"):                    "401 ok ok ok ok ok ok ok ok",
    ("GET", "/api/v1/floorplans/{floorplan_id}/model"):              "401 ok ok ok ok ok ok ok ok",
    ("GET", "/api/v1/floorplans/{floorplan_id}/image"):              "401 ok ok ok ok ok ok ok ok",
    ("POST", "/api/v1/floorplans/{floorplan_id}/walks"):             "401 ok ok ok ok ok ok 403 ok",
    ("POST", "/api/v1/floorplans/{floorplan_id}/sessions"):          "401 ok ok ok ok ok ok 403 ok",
    ("POST", "/api/v1/sessions/{session_id}/steps"):                 "401 ok 404 404 404 404 404 403 404",
    ("POST", "/api/v1/runs/{run_id}/suggestions"):                   "401 ok 404 404 ok ok ok 403 ok",
    ("DELETE", "/api/v1/tokens/{token_id}"):                         "401 404 404 404 404 404 ok 403 ok",
    ("DELETE", "/api/v1/runs/{run_id}"):                             "401 403 403 403 403 403 ok 403 ok",
    ("DELETE", "/api/v1/tile-sources/{ref}"):                        "401 403 403 403 403 403 ok 403 ok",
    ("DELETE", "/api/v1/operators/{user_id}/qualifications/{name}"): "401 403 403 403 403 403 ok 403 ok",
    ("DELETE", "/api/v1/floorplans/{floorplan_id}"):                 "401 403 403 403 403 403 ok 403 ok",
    ("DELETE", "/api/v1/sessions/{session_id}"):                     "401 ok 404 404 404 404 404 403 404",
    ("POST", "/api/v1/auth/logout"):                                 "401 ok ok ok ok ok ok 403 ok",
    ("POST", "/api/v1/tasks/{task_id}/cancel"):                      "401 403 403 403 403 403 ok 403 ok",
    ("POST", "/api/v1/assignments/{assignment_id}/return"):          "401 ok 404 404 404 404 404 403 404",
}


def render() -> str:
    head = "| method | path | " + " | ".join(PRINCIPALS) + " |"
    rule = "| --- | --- | " + " | ".join("---" for _ in PRINCIPALS) + " |"
    body = [f"| {m} | `{p}` | " + " | ".join(cells.split()) + " |" for (m, p), cells in RULES.items()]
    return "\n".join([BEGIN, head, rule, *body, END])


def with_table(doc: str) -> str:
    """The page with the table between the markers (appended under a heading when absent)."""
    if BEGIN in doc and END in doc:
        before, rest = doc.split(BEGIN, 1)
        return before + render() + rest.split(END, 1)[1]
    return doc.rstrip("\n") + "\n\n## Role matrix\n\n" + PRINCIPAL_NOTE + "\n\n" + render() + "\n"


PRINCIPAL_NOTE = (
    "Outcome of every route for each principal: `ok` served (2xx, or a 4xx not about access such as 409/422), "
    "`401` no credentials, `403` refused by role, scope or the review rule, `404` hidden or absent. "
    "`op_own_task` holds the assignment of the task whose run is asked about, `op_other_task` one of another "
    "task, `op_no_task` none; `rev_own_work` edited that run, `rev_other_work` did not; the tokens are an admin's, "
    "so their cells show the scope alone. The tracking session is `op_own`'s; every id names a real object."
)


def main(argv: list[str]) -> int:
    doc = DOC.read_text()
    new = with_table(doc)
    if "--write" in argv:
        DOC.write_text(new)
        return 0
    if new != doc:
        print("docs/SECURITY.md differs from tests/api/access_rules.py: run python -m tests.api.access_rules --write")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
