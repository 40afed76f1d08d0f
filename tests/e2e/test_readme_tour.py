"""The README's curl tour, run as written against a server whose database already holds other
runs and jobs: every id it uses must come from an answer, never be assumed."""

from __future__ import annotations

import csv
import io
import math
import os
import re
import subprocess
from pathlib import Path

import pytest

from tests.e2e.serverkit import PASSWORD, ROOT
from tests.e2e.test_issue15 import api_move

pytestmark = pytest.mark.e2e

README = ROOT / "README.md"
SECTION = "### Import a run with curl and a token"


def tour_script() -> str:
    """The bash blocks of the README's curl tour, in order."""
    text = README.read_text()
    start = text.index(SECTION)
    end = text.index("\n### ", start + len(SECTION))
    return "\n".join(re.findall(r"```bash\n(.*?)```", text[start:end], flags=re.S))


def test_the_curl_tour_works_on_a_database_with_other_runs_and_jobs(server, tmp_path: Path):
    for i in range(2):  # runs and jobs the tour knows nothing of, so no id of its own is 1 or 3 by luck
        api_move(server, "admin", server.upload_run(f"before the tour {i}"), 10, 3.0, "earlier work")
    script = tour_script()
    assert "BASE=http://localhost:8000" in script and "posefix-admin" in script
    # The only changes: where the server is and the test accounts' password; the ids it used are noted after it.
    script = script.replace("BASE=http://localhost:8000", f"BASE={server.base_url}").replace("posefix-admin", PASSWORD)
    script += '\necho "$RUN $NEW" > tour-ids.txt\n'
    (tmp_path / ".venv").symlink_to(ROOT / ".venv")
    (tmp_path / "data").symlink_to(ROOT / "data")
    r = subprocess.run(["timeout", "300", "bash", "-euo", "pipefail", "-c", script], cwd=tmp_path, capture_output=True, text=True,
                       env={**os.environ, "NO_PROXY": "127.0.0.1,localhost"})
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    run_id, revision = map(int, (tmp_path / "tour-ids.txt").read_text().split())
    assert server.get_json("admin", f"/api/v1/runs/{run_id}")["name"] == "My drive" and revision == 1
    # The export is the tour's own run at its new revision: keyframe 100 (row 1,000) about 8 m from revision 0.
    corrected = list(csv.DictReader(open(tmp_path / "corrected.csv")))
    c = server.srv.client("admin")
    try:
        before = list(csv.DictReader(io.StringIO(c.get(f"/api/v1/runs/{run_id}/export?format=csv&revision=0").text)))
    finally:
        c.close()
    assert len(corrected) == len(before) == 3001
    a, b = before[1000], corrected[1000]
    north_m = (float(b["lat"]) - float(a["lat"])) * 111_320
    east_m = (float(b["lon"]) - float(a["lon"])) * 111_320 * math.cos(math.radians(float(a["lat"])))
    assert 5.0 < math.hypot(north_m, east_m) < 9.0, (north_m, east_m)
