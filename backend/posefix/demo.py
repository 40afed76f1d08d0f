"""Demo data set-up: accounts, the offline Helsinki basemap, and two runs with camera images.

``set_up_demo(settings)`` is idempotent: it migrates the database, then adds only what is
missing — a re-run finds the accounts, tile sources and runs by name and leaves them be.
It goes through the same services as the API (``users.service.create_user``,
``tiles.service.create_source``, ``runs.service.import_run``), so demo data is exactly
what an upload would have made.

The demo's accounts have published passwords, so it refuses to run outside development.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import hashlib
import io
import math
import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw
from sqlalchemy import select
from tqdm import tqdm

from posefix.basemap import build_basemap
from posefix.config import Settings
from posefix.core.run import PoseRun
from posefix.db import Database, upgrade_database

__all__ = [
    "DEMO_ACCOUNTS", "DemoAccount", "DemoError", "DemoSummary", "demo_data_dir", "render_camera_frame",
    "set_up_demo", "simulated_drive",
]

SIMULATED_RUN_NAME = "Helsinki simulated drive"
COMMA_RUN_NAME = "comma2k19 I-280 highway drive"
BASEMAP_FILE = "tiles/helsinki-basemap.pmtiles"
TONER_FILE = "tiles/world-toner-z3.pmtiles"
TONER_ATTRIBUTION = "Map tiles by Stamen Design, CC BY 3.0; data © OpenStreetMap contributors, ODbL"
CAMERAS = ("front", "rear")
FRAME_SIZE_PX = (640, 360)


class DemoError(RuntimeError):
    """The demo cannot be set up; the message says why and what to do."""


@dataclass(frozen=True)
class DemoAccount:
    username: str
    role: str
    password: str


# Fixed, published passwords: convenient for a demo and for the browser tests, and the
# reason set_up_demo refuses to run outside development.
DEMO_ACCOUNTS = (
    DemoAccount("admin", "admin", "posefix-admin"),
    DemoAccount("operator1", "operator", "posefix-operator1"),
    DemoAccount("operator2", "operator", "posefix-operator2"),
    DemoAccount("reviewer", "reviewer", "posefix-reviewer"),
)


@dataclass
class DemoSummary:
    """What the demo holds, and what this call added (``created``)."""

    accounts: tuple[DemoAccount, ...]
    tile_sources: list[str]
    runs: dict[str, int]
    created: list[str]


def demo_data_dir() -> Path:
    """The project's ``data/`` folder (shipped OSM extract, tile fixture, comma2k19 segment).

    ``POSEFIX_DEMO_DATA`` overrides it, e.g. where the package is installed without the repository.
    """
    override = os.environ.get("POSEFIX_DEMO_DATA")
    path = Path(override) if override else Path(__file__).resolve().parents[2] / "data"
    if not (path / "osm" / "helsinki.osm.pbf").is_file():
        raise DemoError(f"{path}: no osm/helsinki.osm.pbf here; set POSEFIX_DEMO_DATA to the project's data/ folder")
    return path


# ----------------------------------------------------------------------------- camera frames


def _palette(seed: str) -> np.random.Generator:
    return np.random.default_rng(int.from_bytes(hashlib.blake2b(seed.encode(), digest_size=8).digest(), "little"))


def render_camera_frame(
    camera: str, t_s: float, lon_deg: float, lat_deg: float, heading_deg: float, turn_rate_deg_s: float,
    travelled_m: float,
) -> bytes:
    """A synthetic street-view JPEG: road in perspective, facades, and the frame's time and position.

    The road bends with the turn rate, lane dashes move with the distance travelled and the
    facades change with the block (position rounded to ~50 m), so consecutive frames differ
    the way a real camera's would. ``rear`` frames look backwards (heading + 180°).
    """
    width, height = FRAME_SIZE_PX
    horizon = int(height * 0.45)
    image = Image.new("RGB", (width, height))
    draw = ImageDraw.Draw(image)
    for row in range(horizon):  # sky: light at the horizon, deeper blue above
        shade = row / horizon
        draw.line([(0, row), (width, row)], fill=(int(110 + 90 * shade), int(150 + 70 * shade), int(200 + 40 * shade)))
    draw.rectangle([0, horizon, width, height], fill=(92, 96, 90))

    sign = -1.0 if camera == "rear" else 1.0
    vanish_x = width / 2 + sign * float(np.clip(turn_rate_deg_s * 12.0, -width / 3, width / 3))
    block = f"{round(lon_deg * 2000)}:{round(lat_deg * 2000)}:{camera}"
    rng = _palette(block)
    for side in (-1, 1):  # facades on both sides, shrinking toward the vanishing point
        x = width / 2 + side * width * 0.12
        for _ in range(5):
            depth = rng.uniform(0.2, 0.55)
            top = horizon - rng.uniform(40, 150) * depth
            edge = x + side * width * 0.5 * depth
            color = tuple(int(c) for c in rng.integers(120, 230, 3))
            draw.polygon([(x, horizon), (edge, horizon + 40 * depth), (edge, top - 30 * depth), (x, top)], fill=color)
            for w in range(3):  # windows
                wx = x + (edge - x) * (w + 0.3) / 3
                draw.rectangle([min(wx, wx + side * 6), top + 8, max(wx, wx + side * 6), top + 16], fill=(60, 70, 90))
            x = edge
    road_half = width * 0.42
    draw.polygon([(width / 2 - road_half, height), (width / 2 + road_half, height), (vanish_x + 6, horizon),
                  (vanish_x - 6, horizon)], fill=(58, 58, 62))
    phase = (travelled_m % 6.0) / 6.0
    for i in range(8):  # centre-line dashes, spaced evenly in depth
        near = (i + phase) / 8.0
        far = (i + phase + 0.45) / 8.0
        y0, y1 = horizon + (height - horizon) * near ** 2, horizon + (height - horizon) * far ** 2
        x0 = vanish_x + (width / 2 - vanish_x) * near ** 2
        x1 = vanish_x + (width / 2 - vanish_x) * far ** 2
        draw.line([(x0, y0), (x1, y1)], fill=(235, 225, 160), width=max(1, int(6 * far)))

    when = dt.datetime.fromtimestamp(t_s, dt.UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-5]
    view = (heading_deg + (180.0 if camera == "rear" else 0.0)) % 360.0
    lines = [f"posefix demo - {camera} camera", f"{when} UTC", f"lon {lon_deg:.6f}  lat {lat_deg:.6f}",
             f"looking {view:05.1f} deg"]
    draw.rectangle([8, 8, 300, 14 + 16 * len(lines)], fill=(0, 0, 0))
    for i, text in enumerate(lines):
        draw.text((14, 12 + 16 * i), text, fill=(255, 255, 255))
    out = io.BytesIO()
    image.save(out, format="JPEG", quality=80)
    return out.getvalue()


def _heading_deg(q_body_to_enu_wxyz: np.ndarray) -> np.ndarray:
    """Heading clockwise from north of the body x axis (forward), degrees in [0, 360)."""
    w, x, y, z = q_body_to_enu_wxyz.T
    east = 1 - 2 * (y * y + z * z)  # first column of the rotation matrix: body x in ENU
    north = 2 * (x * y + w * z)
    return np.degrees(np.arctan2(east, north)) % 360.0


def simulated_drive(
    osm_path: Path, duration_s: float, rate_hz: float, frame_every_s: float, show_progress: bool,
) -> tuple[PoseRun, list[tuple[str, bytes]]]:
    """A drive along the extract's streets with two cameras' frames named in its images column."""
    from posefix.core.simulate import simulate

    run = simulate(duration_s=duration_s, rate_hz=rate_hz, osm_path=str(osm_path), seed=2019, edit_every_s=0).run
    heading = _heading_deg(run.q_body_to_enu_wxyz)
    turn = np.gradient(np.unwrap(np.radians(heading)), run.t_s)
    step_m = np.hypot(np.diff(run.lon_deg) * 111320 * math.cos(math.radians(float(run.lat_deg[0]))),
                      np.diff(run.lat_deg) * 110540)
    travelled = np.concatenate([[0.0], np.cumsum(step_m)])
    rows = np.unique(np.searchsorted(run.t_s, np.arange(run.t_s[0], run.t_s[-1], frame_every_s)))
    names = [""] * run.n
    frames: list[tuple[str, bytes]] = []
    for row in tqdm(rows, desc="camera frames", unit="frame", disable=not show_progress):
        row_names = []
        for camera in CAMERAS:
            name = f"{camera}-{int(row):06d}.jpg"
            frames.append((name, render_camera_frame(
                camera, float(run.t_s[row]), float(run.lon_deg[row]), float(run.lat_deg[row]), float(heading[row]),
                float(np.degrees(turn[row])), float(travelled[row]),
            )))
            row_names.append(name)
        names[row] = ";".join(row_names)
    return dataclasses.replace(run, images=names), frames


def comma_drive(data_dir: Path) -> tuple[PoseRun, list[tuple[str, bytes]]]:
    """The real comma2k19 segment, its first camera frame attached to the first sample."""
    from posefix.io import read_run

    segment = data_dir / "comma2k19" / "segment"
    run = read_run(segment, fmt="comma2k19")
    frame = (segment / "preview.png").read_bytes()
    names = [""] * run.n
    names[0] = "comma2k19-frame-0000.png"
    return dataclasses.replace(run, images=names), [(names[0], frame)]


# ----------------------------------------------------------------------------- set-up steps


def _ensure_accounts(db: Database, created: list[str]) -> int:
    """Create missing demo accounts; the admin's id (it owns the demo runs and sources)."""
    from posefix.users import repository as users_repo
    from posefix.users.models import Role
    from posefix.users.service import create_user

    with db.transaction() as session:
        for account in DEMO_ACCOUNTS:
            if users_repo.get_user_by_username(session, account.username) is None:
                create_user(session, account.username, account.password, Role(account.role))
                created.append(f"account {account.username}")
        admin = users_repo.get_user_by_username(session, DEMO_ACCOUNTS[0].username)
        if admin is None or admin.role != "admin" or admin.disabled:
            raise DemoError("user 'admin' exists but is not an enabled admin; use another data directory")
        return admin.id


def _ensure_tile_sources(db: Database, settings: Settings, source_data: Path, admin_id: int,
                         created: list[str], show_progress: bool) -> list[str]:
    from posefix.tiles import service as tiles
    from posefix.tiles.models import TileKind
    from posefix.tiles.schemas import TileSourceCreate

    data_dir = Path(settings.data_dir)
    basemap = data_dir / BASEMAP_FILE
    if not basemap.is_file():
        summary = build_basemap(source_data / "osm" / "helsinki.osm.pbf", basemap, min_zoom=12, max_zoom=16,
                                show_progress=show_progress)
        created.append(f"basemap {BASEMAP_FILE} ({summary.tiles} tiles, {summary.bytes // 1024} KiB)")
    toner = data_dir / TONER_FILE
    if not toner.is_file():
        toner.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source_data / "tiles" / "world-toner-z3.pmtiles", toner)
    wanted = [
        TileSourceCreate(name="helsinki", title="Helsinki streets (offline)", kind=TileKind.street,
                         path=BASEMAP_FILE, attribution="© OpenStreetMap contributors"),
        TileSourceCreate(name="toner", title="World toner (zoom 0-3)", kind=TileKind.topo,
                         path=TONER_FILE, attribution=TONER_ATTRIBUTION),
    ]
    with db.transaction() as session:
        existing = {source.name for source in tiles.list_sources(session)}
        for body in wanted:
            if body.name not in existing:
                tiles.create_source(session, settings, body, admin_id)
                created.append(f"tile source {body.name}")
        return [source.name for source in tiles.list_sources(session)]


def _existing_run_id(db: Database, name: str) -> int | None:
    from posefix.runs.models import Run, RunStatus

    with db.transaction(write=False) as session:
        return session.scalar(
            select(Run.id).where(Run.name == name, Run.status != RunStatus.deleted).order_by(Run.id).limit(1)
        )


def _import(db: Database, settings: Settings, admin_id: int, name: str, run: PoseRun,
            frames: list[tuple[str, bytes]]) -> int:
    """Upload a run as a CSV with its images through the runs service, as the API would."""
    from posefix.io import write_run
    from posefix.runs.service import import_run
    from posefix.users.models import Role, TokenScope
    from posefix.users.service import Principal

    principal = Principal(admin_id, DEMO_ACCOUNTS[0].username, Role.admin, "demo", TokenScope.write, "")
    with tempfile.TemporaryDirectory(prefix="posefix-demo-") as tmp:
        csv_path = Path(tmp) / f"{name.lower().replace(' ', '-')}.csv"
        write_run(run, csv_path, fmt="csv")
        with open(csv_path, "rb") as handle, db.transaction() as session:
            row = import_run(
                session, settings, principal, name=name, file_name=csv_path.name, file=handle,
                images=[(frame_name, io.BytesIO(data)) for frame_name, data in frames],
            )
            return row.id


def set_up_demo(
    settings: Settings,
    *,
    drive_duration_s: float = 600.0,
    drive_rate_hz: float = 10.0,
    frame_every_s: float = 5.0,
    show_progress: bool = False,
    say: Callable[[str], None] = lambda _message: None,
) -> DemoSummary:
    """Migrate, then add whatever of the demo is missing (see the module docstring)."""
    if settings.environment != "development":
        raise DemoError(
            f"the demo creates accounts with published passwords, so it runs only in development "
            f"(POSEFIX_ENVIRONMENT is {settings.environment!r})"
        )
    source_data = demo_data_dir()
    Path(settings.data_dir).mkdir(parents=True, exist_ok=True)
    say(f"database: {settings.resolved_database_url}")
    upgrade_database(settings.resolved_database_url)
    db = Database(settings.resolved_database_url)
    created: list[str] = []
    try:
        admin_id = _ensure_accounts(db, created)
        say("accounts ready; tile sources next")
        sources = _ensure_tile_sources(db, settings, source_data, admin_id, created, show_progress)
        runs: dict[str, int] = {}
        if (run_id := _existing_run_id(db, SIMULATED_RUN_NAME)) is None:
            say(f"simulating a {drive_duration_s / 60:.0f} min drive at {drive_rate_hz:g} Hz through Helsinki")
            run, frames = simulated_drive(source_data / "osm" / "helsinki.osm.pbf", drive_duration_s, drive_rate_hz,
                                          frame_every_s, show_progress)
            say(f"importing {run.n} samples and {len(frames)} camera frames")
            run_id = _import(db, settings, admin_id, SIMULATED_RUN_NAME, run, frames)
            created.append(f"run {SIMULATED_RUN_NAME!r}")
        runs[SIMULATED_RUN_NAME] = run_id
        if (run_id := _existing_run_id(db, COMMA_RUN_NAME)) is None:
            say("importing the comma2k19 drive")
            run, frames = comma_drive(source_data)
            run_id = _import(db, settings, admin_id, COMMA_RUN_NAME, run, frames)
            created.append(f"run {COMMA_RUN_NAME!r}")
        runs[COMMA_RUN_NAME] = run_id
        from posefix.maps.demo import ensure_demo_floorplan

        ensure_demo_floorplan(db, settings, source_data, admin_id, created, say)
    finally:
        db.dispose()
    return DemoSummary(DEMO_ACCOUNTS, sources, runs, created)
