"""The demo's floor plan: the shared competition floor site1/F1 from ``data/indoor-site1-F1``."""

from __future__ import annotations

import io
import zipfile
from collections.abc import Callable
from pathlib import Path

from sqlalchemy import select

from posefix.config import Settings
from posefix.db import Database
from posefix.maps.models import FloorPlan
from posefix.maps.service import FLOOR_FILES, create_floorplan
from posefix.users.models import Role, TokenScope
from posefix.users.service import Principal

DEMO_FLOOR_NAME = "Mall site1 F1 (Indoor Location Competition)"


def ensure_demo_floorplan(db: Database, settings: Settings, source_data: Path, admin_id: int, created: list[str],
                          say: Callable[[str], None] = lambda _m: None) -> int | None:
    """Add the floor plan (model built now) unless it exists; None when the data is not there."""
    folder = source_data / "indoor-site1-F1"
    if not all((folder / f).is_file() for f in FLOOR_FILES):
        say(f"no floor plan: {folder} lacks {', '.join(FLOOR_FILES)}")
        return None
    with db.transaction(write=False) as s:
        existing = s.scalar(select(FloorPlan.id).where(FloorPlan.name == DEMO_FLOOR_NAME))
    if existing is not None:
        return int(existing)
    say("building the indoor floor plan's map-matching model")
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in FLOOR_FILES:
            zf.write(folder / name, name)
    buf.seek(0)
    principal = Principal(admin_id, "admin", Role.admin, "session", TokenScope.write, "")
    with db.transaction() as s:
        fp = create_floorplan(s, settings, principal, name=DEMO_FLOOR_NAME, filename="indoor-site1-F1.zip", fh=buf,
                              cell_m=0.8, build_now=True)
        fid = fp.id
    created.append(f"floor plan {DEMO_FLOOR_NAME!r} (walks to track: {folder / 'walks'})")
    return fid
