"""Shared set-up of the tile API tests: a migrated database, users, a logged-in client,
and tile files made on the spot (MBTiles with PNG tiles that name their own z/x/y)."""

from __future__ import annotations

import gzip
import io
import os
import sqlite3
from pathlib import Path

from alembic import command
from alembic.config import Config
from fastapi import APIRouter, FastAPI
from fastapi.testclient import TestClient
from PIL import Image, ImageDraw

from posefix.basemap.tiling import flip_y
from posefix.config import Settings
from posefix.db import Database
from posefix.errors import install_error_handlers

REPO = Path(__file__).resolve().parents[2]
ORIGIN = "http://testserver"


def migrate(url: str) -> None:
    cfg = Config(str(REPO / "migrations" / "alembic.ini"))
    cfg.set_main_option("script_location", str(REPO / "migrations"))
    cfg.set_main_option("sqlalchemy.url", url)
    command.upgrade(cfg, "head")


def make_app(settings: Settings) -> FastAPI:
    """The account and tile routers on a real database, as ``posefix.main`` mounts them."""
    from posefix.tiles.endpoints import router as tiles_router
    from posefix.users.endpoints import router as users_router

    app = FastAPI()
    app.state.settings = settings
    app.state.db = Database(settings.resolved_database_url)
    install_error_handlers(app)
    api = APIRouter(prefix="/api/v1")
    api.include_router(users_router)
    api.include_router(tiles_router)
    app.include_router(api)
    return app


def login(app: FastAPI, username: str, password: str) -> TestClient:
    client = TestClient(app, headers={"Origin": ORIGIN})
    response = client.post("/api/v1/auth/login", json={"username": username, "password": password})
    assert response.status_code == 200, response.text
    return client


def tile_png(z: int, x: int, y: int) -> bytes:
    """A 256 px PNG whose colour and text encode (z, x, y), so a wrong row is visible."""
    image = Image.new("RGB", (256, 256), ((z * 40) % 256, (x * 70) % 256, (y * 110) % 256))
    ImageDraw.Draw(image).text((20, 120), f"{z}/{x}/{y}", fill=(255, 255, 255))
    out = io.BytesIO()
    image.save(out, format="PNG")
    return out.getvalue()


def write_mbtiles(path: Path, tiles: dict[tuple[int, int, int], bytes], metadata: dict[str, str]) -> None:
    """An MBTiles 1.3 file: XYZ (z, x, y) keys are stored with TMS rows, as the spec says."""
    path.parent.mkdir(parents=True, exist_ok=True)
    conn = sqlite3.connect(path)
    conn.execute("CREATE TABLE metadata (name TEXT, value TEXT)")
    conn.execute("CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER, tile_data BLOB)")
    conn.execute("CREATE UNIQUE INDEX tile_index ON tiles (zoom_level, tile_column, tile_row)")
    conn.executemany("INSERT INTO metadata VALUES (?, ?)", list(metadata.items()))
    conn.executemany(
        "INSERT INTO tiles VALUES (?, ?, ?, ?)",
        [(z, x, flip_y(z, y), data) for (z, x, y), data in tiles.items()],
    )
    conn.commit()
    conn.close()


def raster_mbtiles(path: Path, max_zoom: int = 2) -> dict[tuple[int, int, int], bytes]:
    tiles = {(z, x, y): tile_png(z, x, y) for z in range(max_zoom + 1) for x in range(1 << z) for y in range(1 << z)}
    del tiles[(2, 3, 0)]  # a hole, to see how a missing raster tile is answered
    write_mbtiles(path, tiles, {
        "name": "test raster", "format": "png", "minzoom": "0", "maxzoom": str(max_zoom),
        "attribution": "Test tiles © posefix tests",
    })
    return tiles


def gzip_bytes(data: bytes) -> bytes:
    return gzip.compress(data, mtime=0)


def pg_url() -> str | None:
    return os.environ.get("POSEFIX_TEST_PG_URL")


# ------------------------------------------------------------------ fixtures

import shutil
import uuid
from collections.abc import Iterator

import mapbox_vector_tile
import psycopg
import pytest
from sqlalchemy.engine import make_url

from posefix.basemap import build_basemap
from posefix.basemap.tiling import tiles_covering
from posefix.tiles.service import forget_cached_sources, tile_settings

SHARED_FIXTURE = REPO / "data" / "tiles" / "world-toner-z3.pmtiles"
HELSINKI_OSM = REPO / "data" / "osm" / "helsinki.osm.pbf"
TONER_ATTRIBUTION = "Map tiles by Stamen Design, CC BY 3.0; data © OpenStreetMap contributors, ODbL"


def _database_urls() -> list[str]:
    return ["sqlite"] + (["postgresql"] if pg_url() else [])


def _admin_dsn(url: str) -> str:
    return make_url(url).set(drivername="postgresql", database="postgres").render_as_string(hide_password=False)


def _seed(url: str) -> None:
    """Migrate an empty database and add the two test accounts (argon2 hashing is slow, so once)."""
    migrate(url)
    db = Database(url)
    try:
        from posefix.users.models import Role
        from posefix.users.service import create_user

        with db.transaction() as session:
            create_user(session, "root", "root-password-1", Role.admin)
            create_user(session, "olga", "olga-password-1", Role.operator)
    finally:
        db.dispose()


@pytest.fixture(scope="module", params=_database_urls())
def template_database(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, str]]:
    """A migrated, seeded database that each test copies: (backend, sqlite path or PG name)."""
    if request.param == "sqlite":
        path = tmp_path_factory.mktemp("template") / "posefix.sqlite"
        _seed(f"sqlite:///{path}")
        yield "sqlite", str(path)
        return
    name = f"posefix_tiles_tmpl_{uuid.uuid4().hex[:8]}"
    with psycopg.connect(_admin_dsn(pg_url()), autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        _seed(make_url(pg_url()).set(database=name).render_as_string(hide_password=False))
        yield "postgresql", name
    finally:
        with psycopg.connect(_admin_dsn(pg_url()), autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture
def database_url(template_database: tuple[str, str], tmp_path: Path) -> Iterator[str]:
    """A fresh copy of the template for one test: a file copy, or CREATE DATABASE ... TEMPLATE."""
    backend, template = template_database
    if backend == "sqlite":
        copy = tmp_path / "posefix.sqlite"
        with sqlite3.connect(template) as source, sqlite3.connect(copy) as target:
            source.backup(target)
        yield f"sqlite:///{copy}"
        return
    name = f"posefix_tiles_{uuid.uuid4().hex[:10]}"
    with psycopg.connect(_admin_dsn(pg_url()), autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}" TEMPLATE "{template}"')
    try:
        yield make_url(pg_url()).set(database=name).render_as_string(hide_password=False)
    finally:
        with psycopg.connect(_admin_dsn(pg_url()), autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture(scope="module")
def basemap_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("basemap") / "helsinki.pmtiles"
    build_basemap(HELSINKI_OSM, out, min_zoom=12, max_zoom=16)
    return out


@pytest.fixture
def data_dir(tmp_path: Path, basemap_file: Path) -> Path:
    root = tmp_path / "data"
    (root / "tiles").mkdir(parents=True)
    shutil.copy(SHARED_FIXTURE, root / "tiles" / "toner.pmtiles")
    shutil.copy(basemap_file, root / "tiles" / "helsinki.pmtiles")
    return root


@pytest.fixture
def app(database_url: str, data_dir: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[FastAPI]:
    monkeypatch.setenv("POSEFIX_TILE_CACHE_DIR", str(data_dir / "tile-cache"))
    tile_settings.cache_clear()
    forget_cached_sources()
    settings = Settings(environment="test", database_url=database_url, data_dir=data_dir, log_json=False)
    application = make_app(settings)
    yield application
    application.state.db.dispose()
    tile_settings.cache_clear()
    forget_cached_sources()


@pytest.fixture
def admin(app: FastAPI) -> TestClient:
    return login(app, "root", "root-password-1")


@pytest.fixture
def operator(app: FastAPI) -> TestClient:
    return login(app, "olga", "olga-password-1")


def register(client: TestClient, **body: object) -> dict:
    response = client.post("/api/v1/tile-sources", json=body)
    assert response.status_code == 201, response.text
    return response.json()


# ------------------------------------------------------------------ registration


class TestRegisterTileSource:
    def test_pmtiles_file_takes_format_and_zooms_from_the_file(self, admin: TestClient) -> None:
        body = register(admin, name="toner", kind="topo", path="tiles/toner.pmtiles", attribution=TONER_ATTRIBUTION)
        assert body["format"] == "png" and body["min_zoom"] == 0 and body["max_zoom"] == 3
        assert body["origin"] == "file" and body["path"] == "tiles/toner.pmtiles"
        assert body["tile_url"] == "http://testserver/api/v1/tiles/toner/{z}/{x}/{y}.png"

    def test_absolute_path_inside_the_data_dir_is_stored_relative(self, admin: TestClient, data_dir: Path) -> None:
        body = register(admin, name="street", kind="street", path=str(data_dir / "tiles" / "helsinki.pmtiles"))
        assert body["path"] == "tiles/helsinki.pmtiles"
        assert body["format"] == "pbf" and body["attribution"] == "© OpenStreetMap contributors"

    def test_path_outside_the_data_dir_is_refused(self, admin: TestClient) -> None:
        for path in ("../outside.pmtiles", str(SHARED_FIXTURE), "tiles/../../x.pmtiles"):
            response = admin.post("/api/v1/tile-sources", json={"name": "evil", "kind": "other", "path": path})
            assert response.status_code == 422, path
            assert response.json()["error"] == "tile_path_outside_data_dir"

    def test_a_file_that_is_no_tile_file_is_refused_and_nothing_stored(self, admin: TestClient, data_dir: Path) -> None:
        (data_dir / "tiles" / "junk.mbtiles").write_bytes(b"not sqlite at all" * 100)
        (data_dir / "tiles" / "junk.pmtiles").write_bytes(b"PMTiles\x02" + b"\0" * 200)
        (data_dir / "tiles" / "junk.png").write_bytes(tile_png(0, 0, 0))
        for name in ("junk.mbtiles", "junk.pmtiles", "junk.png", "missing.pmtiles"):
            response = admin.post("/api/v1/tile-sources", json={"name": "junk", "kind": "other", "path": f"tiles/{name}"})
            assert response.status_code == 422, (name, response.text)
            assert response.json()["error"] == "invalid_tile_file"
            assert name in response.json()["detail"]
        assert admin.get("/api/v1/tile-sources").json()["total"] == 0

    def test_duplicate_name_is_a_conflict(self, admin: TestClient) -> None:
        register(admin, name="toner", kind="topo", path="tiles/toner.pmtiles")
        response = admin.post("/api/v1/tile-sources", json={"name": "toner", "kind": "topo", "path": "tiles/toner.pmtiles"})
        assert response.status_code == 409 and response.json()["error"] == "tile_source_exists"

    def test_request_must_agree_with_the_file(self, admin: TestClient) -> None:
        wrong_format = {"name": "t", "kind": "topo", "path": "tiles/toner.pmtiles", "format": "jpg"}
        assert admin.post("/api/v1/tile-sources", json=wrong_format).json()["error"] == "tile_format_mismatch"
        too_deep = {"name": "t", "kind": "topo", "path": "tiles/toner.pmtiles", "max_zoom": 5}
        response = admin.post("/api/v1/tile-sources", json=too_deep)
        assert response.status_code == 422 and response.json()["error"] == "tile_zoom_range"

    def test_body_must_name_exactly_one_origin_and_a_good_name(self, admin: TestClient) -> None:
        both = {"name": "t", "kind": "topo", "path": "tiles/toner.pmtiles", "url": "https://a/{z}/{x}/{y}.png"}
        neither = {"name": "t", "kind": "topo"}
        bad_name = {"name": "9lives", "kind": "topo", "path": "tiles/toner.pmtiles"}
        bad_kind = {"name": "t", "kind": "aerial", "path": "tiles/toner.pmtiles"}
        nul = {"name": "t", "kind": "topo", "path": "tiles/toner.pmtiles", "attribution": "a\x00b"}
        for body in (both, neither, bad_name, bad_kind, nul):
            response = admin.post("/api/v1/tile-sources", json=body)
            assert response.status_code == 422 and response.json()["error"] == "validation_error", body

    def test_upstream_url_must_be_an_xyz_template_of_raster_tiles(self, admin: TestClient) -> None:
        cases = {
            "ftp://tiles.example/{z}/{x}/{y}.png": "invalid_tile_url",
            "https://tiles.example/{z}/{x}.png": "invalid_tile_url",
            "https://tiles.example/{z}/{x}/{y}": "tile_format_unknown",
            "https://tiles.example/{z}/{x}/{y}.pbf": "tile_format_unsupported",
        }
        cases["http://[::1/{z}/{x}/{y}.png"] = "invalid_tile_url"
        for url, code in cases.items():
            response = admin.post("/api/v1/tile-sources", json={"name": "up", "kind": "satellite", "url": url})
            assert response.status_code == 422 and response.json()["error"] == code, url
        body = register(admin, name="up", kind="satellite", url="https://tiles.example/{z}/{x}/{-y}", format="jpeg")
        assert body["format"] == "jpg" and body["origin"] == "upstream" and body["max_zoom"] == 19

    def test_only_admins_register_and_delete(self, admin: TestClient, operator: TestClient, app: FastAPI) -> None:
        body = {"name": "toner", "kind": "topo", "path": "tiles/toner.pmtiles"}
        response = operator.post("/api/v1/tile-sources", json=body)
        assert response.status_code == 403 and response.json()["error"] == "role_forbidden"
        register(admin, **body)
        assert operator.get("/api/v1/tile-sources").json()["total"] == 1
        assert operator.delete("/api/v1/tile-sources/toner").status_code == 403
        assert TestClient(app).get("/api/v1/tile-sources").status_code == 401

    def test_delete_by_name_or_id(self, admin: TestClient) -> None:
        first = register(admin, name="toner", kind="topo", path="tiles/toner.pmtiles")
        register(admin, name="street", kind="street", path="tiles/helsinki.pmtiles")
        assert admin.delete(f"/api/v1/tile-sources/{first['id']}").status_code == 204
        assert admin.delete("/api/v1/tile-sources/street").status_code == 204
        assert admin.get("/api/v1/tile-sources").json() == {"items": [], "total": 0}
        assert admin.get("/api/v1/tiles/toner/0/0/0.png").status_code == 404
        for ref in ("street", "99", "9" * 40, "²"):
            response = admin.delete(f"/api/v1/tile-sources/{ref}")
            assert response.status_code == 404 and response.json()["error"] == "tile_source_not_found", ref


# ------------------------------------------------------------------ serving


class TestServeMBTiles:
    def test_rows_are_flipped_from_tms_and_headers_are_set(self, admin: TestClient, data_dir: Path) -> None:
        tiles = raster_mbtiles(data_dir / "tiles" / "raster.mbtiles")
        register(admin, name="raster", kind="other", path="tiles/raster.mbtiles")
        for (z, x, y), png in tiles.items():
            response = admin.get(f"/api/v1/tiles/raster/{z}/{x}/{y}.png")
            assert response.status_code == 200
            assert response.content == png, (z, x, y)
        response = admin.get("/api/v1/tiles/raster/2/1/3.png")
        assert response.headers["content-type"] == "image/png"
        assert response.headers["cache-control"] == "private, max-age=3600"
        assert response.headers["etag"].startswith('"') and "content-encoding" not in response.headers

    def test_if_none_match_gives_304_and_other_tiles_differ(self, admin: TestClient, data_dir: Path) -> None:
        raster_mbtiles(data_dir / "tiles" / "raster.mbtiles")
        register(admin, name="raster", kind="other", path="tiles/raster.mbtiles")
        etag = admin.get("/api/v1/tiles/raster/1/0/1.png").headers["etag"]
        again = admin.get("/api/v1/tiles/raster/1/0/1.png", headers={"If-None-Match": etag})
        assert again.status_code == 304 and again.content == b"" and again.headers["etag"] == etag
        weak = admin.get("/api/v1/tiles/raster/1/0/1.png", headers={"If-None-Match": f'"x", W/{etag}'})
        assert weak.status_code == 304
        other = admin.get("/api/v1/tiles/raster/1/1/1.png", headers={"If-None-Match": etag})
        assert other.status_code == 200 and other.headers["etag"] != etag

    def test_bad_coordinates_and_extensions(self, admin: TestClient, data_dir: Path) -> None:
        raster_mbtiles(data_dir / "tiles" / "raster.mbtiles")
        register(admin, name="raster", kind="other", path="tiles/raster.mbtiles")
        cases = {
            "/api/v1/tiles/raster/2/3/0.png": (404, "tile_not_found"),  # the hole in the file
            "/api/v1/tiles/raster/1/0/0.jpg": (404, "tile_format_mismatch"),
            "/api/v1/tiles/raster/1/2/0.png": (400, "tile_out_of_range"),
            "/api/v1/tiles/raster/3/0/0.png": (404, "tile_zoom_out_of_range"),
            "/api/v1/tiles/nothing/0/0/0.png": (404, "tile_source_not_found"),
        }
        for url, (status, code) in cases.items():
            response = admin.get(url)
            assert (response.status_code, response.json()["error"]) == (status, code), url

    def test_gzipped_vector_tiles_keep_their_encoding(self, admin: TestClient, data_dir: Path) -> None:
        mvt = mapbox_vector_tile.encode([{"name": "roads", "features": [
            {"geometry": "LINESTRING (0 0, 4096 4096)", "properties": {"class": "primary"}}]}])
        write_mbtiles(data_dir / "tiles" / "vector.mbtiles", {(0, 0, 0): gzip_bytes(mvt)}, {
            "name": "v", "format": "pbf", "minzoom": "0", "maxzoom": "0",
            "json": '{"vector_layers": [{"id": "roads", "fields": {"class": "String"}}]}',
        })
        register(admin, name="vector", kind="street", path="tiles/vector.mbtiles")
        response = admin.get("/api/v1/tiles/vector/0/0/0.pbf", headers={"Accept-Encoding": "gzip"})
        assert response.status_code == 200
        assert response.headers["content-type"] == "application/x-protobuf"
        assert response.headers["content-encoding"] == "gzip"
        # httpx undid the gzip, as a browser does: the body is the original MVT.
        assert response.content == mvt
        style = admin.get("/api/v1/map/style.json").json()
        assert {layer["source-layer"] for layer in style["layers"] if layer.get("source") == "vector"} == {"roads"}


class TestServePMTiles:
    def test_raster_fixture_tiles_match_the_file(self, admin: TestClient, data_dir: Path) -> None:
        from pmtiles.reader import MmapSource, Reader, all_tiles

        register(admin, name="toner", kind="topo", path="tiles/toner.pmtiles", attribution=TONER_ATTRIBUTION)
        with open(data_dir / "tiles" / "toner.pmtiles", "rb") as handle:
            expected = dict(all_tiles(MmapSource(handle)))
        assert len(expected) == 85
        for (z, x, y), data in expected.items():
            response = admin.get(f"/api/v1/tiles/toner/{z}/{x}/{y}.png")
            assert response.status_code == 200 and response.content == data
            assert response.headers["content-type"] == "image/png"

    def test_vector_basemap_tiles_are_gzip_mvt_and_missing_ones_empty(self, admin: TestClient) -> None:
        register(admin, name="street", kind="street", path="tiles/helsinki.pmtiles")
        # The zoom 16 tile at Helsinki railway station (24.9414 E, 60.1710 N): Kaivokatu
        # (primary), side streets, footways, the station building and the tracks.
        [(x, y)] = tiles_covering(16, (24.9414, 60.1710, 24.9414, 60.1710))
        response = admin.get(f"/api/v1/tiles/street/16/{x}/{y}.pbf")
        assert response.status_code == 200 and response.headers["content-encoding"] == "gzip"
        layers = mapbox_vector_tile.decode(response.content)
        assert {"roads", "buildings", "rail"} <= set(layers)
        classes = {feature["properties"]["class"] for feature in layers["roads"]["features"]}
        assert {"primary", "minor", "path"} <= classes
        # A tile of the same zoom far from Helsinki holds nothing: 204 draws nothing.
        assert admin.get("/api/v1/tiles/street/16/0/0.pbf").status_code == 204

    def test_a_registered_file_that_goes_missing_is_a_clear_503(self, admin: TestClient, data_dir: Path) -> None:
        register(admin, name="toner", kind="topo", path="tiles/toner.pmtiles")
        (data_dir / "tiles" / "toner.pmtiles").unlink()
        response = admin.get("/api/v1/tiles/toner/0/0/0.png")
        assert response.status_code == 503 and response.json()["error"] == "tile_file_unavailable"
        assert "toner.pmtiles" in response.json()["detail"]

    def test_tiles_need_a_login(self, app: FastAPI, admin: TestClient) -> None:
        register(admin, name="toner", kind="topo", path="tiles/toner.pmtiles")
        assert TestClient(app).get("/api/v1/tiles/toner/0/0/0.png").status_code == 401


# ------------------------------------------------------------------ style


class TestStyle:
    def test_style_of_the_demo_sources(self, admin: TestClient, operator: TestClient) -> None:
        register(admin, name="toner", kind="topo", path="tiles/toner.pmtiles", attribution=TONER_ATTRIBUTION)
        register(admin, name="helsinki", kind="street", path="tiles/helsinki.pmtiles", title="Helsinki (offline)")
        response = operator.get("/api/v1/map/style.json")
        assert response.status_code == 200 and response.headers["content-type"] == "application/json"
        style = response.json()
        assert style["version"] == 8
        # Offline: no glyphs, no sprites, nothing outside this server.
        assert "glyphs" not in style and "sprite" not in style
        assert not [layer for layer in style["layers"] if layer["type"] == "symbol"]
        for spec in style["sources"].values():
            assert all(url.startswith("http://testserver/api/v1/tiles/") for url in spec["tiles"])
        assert style["sources"]["helsinki"]["type"] == "vector"
        assert style["sources"]["helsinki"]["attribution"] == "© OpenStreetMap contributors"
        assert style["sources"]["toner"] == {
            "type": "raster", "tiles": ["http://testserver/api/v1/tiles/toner/{z}/{x}/{y}.png"],
            "minzoom": 0, "maxzoom": 3, "attribution": TONER_ATTRIBUTION, "tileSize": 256,
            "bounds": [-180.0, -85.0, 180.0, 85.0],
        }
        meta = style["metadata"]
        assert meta["posefix:default"] == "helsinki"
        assert [s["name"] for s in meta["posefix:sources"]] == ["toner", "helsinki"]
        by_source: dict[str, set[str]] = {}
        for layer in style["layers"][1:]:
            by_source.setdefault(layer["metadata"]["posefix:source"], set()).add(layer["layout"]["visibility"])
        assert by_source == {"toner": {"none"}, "helsinki": {"visible"}}
        used = {layer.get("source-layer") for layer in style["layers"] if layer.get("source") == "helsinki"}
        assert used == {"roads", "rail", "buildings", "water", "parks"}
        assert style["center"][0] == pytest.approx(24.944, abs=0.01)
        assert style["center"][1] == pytest.approx(60.172, abs=0.01)

    def test_style_validators(self, admin: TestClient) -> None:
        register(admin, name="toner", kind="topo", path="tiles/toner.pmtiles")
        first = admin.get("/api/v1/map/style.json")
        assert admin.get("/api/v1/map/style.json", headers={"If-None-Match": first.headers["etag"]}).status_code == 304
        register(admin, name="helsinki", kind="street", path="tiles/helsinki.pmtiles")
        changed = admin.get("/api/v1/map/style.json", headers={"If-None-Match": first.headers["etag"]})
        assert changed.status_code == 200 and changed.json()["metadata"]["posefix:default"] == "helsinki"

    def test_empty_style_is_still_a_valid_map(self, admin: TestClient) -> None:
        style = admin.get("/api/v1/map/style.json").json()
        assert style["sources"] == {} and [layer["id"] for layer in style["layers"]] == ["background"]
        assert style["metadata"]["posefix:default"] is None
