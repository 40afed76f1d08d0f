"""Files past one machine: run files, images, solutions and floor plans in S3-compatible
object storage, against a real S3 HTTP endpoint the test starts (moto in server mode).

Two "machines" share the database and the bucket but not a disk: each has its own data
folder. A run uploaded through one is corrected by the other's worker, and both serve its
keyframes, export, images and floor plan; nothing reaches either machine's local file
folder. The credentials never appear in a log line, a repr or an error answer."""

from __future__ import annotations

import io
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.api.test_maps import floor_zip
from tests.api.test_runs import jpeg
from tests.conftest import ORIGIN, add_user, direct_token, drive_csv, upload, wait_job

BUCKET = "posefix-files"
KEY_ID = "POSEFIXTESTKEYID4242"
SECRET = "s3cr3t-that-must-never-be-logged-9f8e7d"
METRE_LON = 1 / (111320 * np.cos(np.radians(60.17)))


@pytest.fixture(scope="module")
def s3_endpoint() -> Iterator[str]:
    from moto.server import ThreadedMotoServer

    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    endpoint = f"http://{host}:{port}"
    import boto3

    boto3.client("s3", endpoint_url=endpoint, region_name="us-east-1", aws_access_key_id=KEY_ID,
                 aws_secret_access_key=SECRET).create_bucket(Bucket=BUCKET)
    yield endpoint
    server.stop()


def _on_s3(settings: Any, endpoint: str, data_dir: Path, prefix: str) -> Any:
    from pydantic import SecretStr

    return settings.model_copy(update={
        "data_dir": data_dir, "files_url": f"s3://{BUCKET}/{prefix}", "s3_endpoint_url": endpoint,
        "s3_region": "us-east-1", "s3_access_key_id": SecretStr(KEY_ID), "s3_secret_access_key": SecretStr(SECRET),
        "log_level": "DEBUG",
    })


@pytest.fixture
def machines(settings: Any, s3_endpoint: str, tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[list[Any]]:
    """Two apps on one database and one bucket prefix, each with its own data folder."""
    from posefix.main import create_app

    prefix = f"t{abs(hash(request.node.nodeid)) % 10**8}"
    apps = [create_app(_on_s3(settings, s3_endpoint, tmp_path / f"machine{i}", prefix)) for i in (1, 2)]
    yield apps
    for a in apps:
        a.state.db.dispose()


def _local_files(app: Any) -> list[Path]:
    root = app.state.settings.files_dir
    return sorted(p for p in root.rglob("*") if p.is_file()) if root.exists() else []


def _bucket_keys(app: Any) -> list[str]:
    from posefix.filestore import file_store

    fs = file_store(app.state.settings)
    return sorted(k[len(fs.root) + 1:] for k in fs.fs.find(fs.root))


def test_a_run_travels_between_machines_through_the_bucket(machines: list[Any], caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG)
    one, two = machines
    admin_id = add_user(one, "boss", "admin")
    head = direct_token(one, admin_id)
    c1, c2 = TestClient(one, headers={"Origin": ORIGIN}), TestClient(two, headers={"Origin": ORIGIN})
    r = upload(c1, head, drive_csv(200, images_every=100), images=[("img00000.jpg", jpeg(size=(900, 600))), ("img00100.jpg", jpeg())])
    assert r.status_code == 201, r.text
    rid = r.json()["id"]
    keys = _bucket_keys(one)
    assert f"runs/{rid}/original.csv" in keys and any(k.startswith(f"runs/{rid}/r0-") and k.endswith(".parquet") for k in keys)
    assert sum(k.startswith(f"images/{rid}/") for k in keys) == 2
    # machine two serves what machine one stored
    feats = c2.get(f"/api/v1/runs/{rid}/keyframes", headers=head).json()["features"]
    lon, lat = feats[5]["geometry"]["coordinates"]
    move = {"index": 5, "lon": lon + 4 * METRE_LON, "lat": lat}
    edit = c1.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "moves": [move]}, headers=head)
    assert edit.status_code == 202, edit.text
    assert wait_job(two, edit.json()["job_id"])["status"] == "succeeded"  # the worker runs on machine two
    keys = _bucket_keys(one)
    assert any(k.startswith(f"runs/{rid}/r1-") and k.endswith(".solution.npz") for k in keys), keys
    moved = c1.get(f"/api/v1/runs/{rid}/keyframes?revision=1", headers=head).json()["features"][5]["geometry"]["coordinates"]
    assert abs((moved[0] - lon) / METRE_LON - 4.0) < 0.3  # the edit holds to its 0.5 m sigma
    export = c1.get(f"/api/v1/runs/{rid}/export?format=csv&revision=1", headers=head)
    assert export.status_code == 200 and export.text.count("\n") == 201
    images = c2.get(f"/api/v1/runs/{rid}/images", headers=head).json()["items"]
    original = c2.get(f"/api/v1/images/{images[0]['id']}", headers=head)
    assert original.status_code == 200 and original.headers["content-type"] == "image/jpeg"
    from PIL import Image

    thumb = c1.get(f"/api/v1/images/{images[0]['id']}/thumbnail", headers=head)
    assert thumb.status_code == 200 and max(Image.open(io.BytesIO(thumb.content)).size) == 320
    assert f"images/{rid}/{images[0]['id']}.thumb.jpg" in _bucket_keys(two)
    # deleting the run on machine two keeps its files (soft delete) and both machines' disks stay clean
    assert _local_files(one) == [] and _local_files(two) == []
    _assert_no_credentials(caplog.text, one, two)


def test_a_floor_plan_is_built_on_one_machine_and_served_by_the_other(machines: list[Any]) -> None:
    one, two = machines
    admin_id = add_user(one, "boss", "admin")
    head = direct_token(one, admin_id)
    c1, c2 = TestClient(one, headers={"Origin": ORIGIN}), TestClient(two, headers={"Origin": ORIGIN})
    r = c1.post("/api/v1/floorplans", files={"file": ("floor.zip", floor_zip(), "application/octet-stream")},
                data={"name": "site1 F1"}, headers=head)
    assert r.status_code == 202, r.text
    fid = r.json()["id"]
    assert wait_job(two, r.json()["job_id"], timeout=120)["status"] == "succeeded"
    model = c1.get(f"/api/v1/floorplans/{fid}/model", headers=head)
    assert model.status_code == 200 and int(model.headers["X-Model-Bytes"]) == len(model.content) > 1000
    assert c1.get(f"/api/v1/floorplans/{fid}/image", headers=head).content[:8] == b"\x89PNG\r\n\x1a\n"
    s = c1.post(f"/api/v1/floorplans/{fid}/sessions", json={}, headers=head)
    assert s.status_code == 201, s.text
    assert any(k.endswith("/model.npz") for k in _bucket_keys(one))
    assert c2.delete(f"/api/v1/floorplans/{fid}", headers=head).status_code == 204
    assert not any(k.startswith("floorplans/") for k in _bucket_keys(one))


def test_a_tile_file_in_the_bucket_serves_every_machine(machines: list[Any]) -> None:
    """A basemap put in the bucket once (key tiles/<path>) is registered on one machine and
    served by the other, each fetching its own copy."""
    from posefix.filestore import file_store
    from tests.conftest import REPO

    one, two = machines
    head = direct_token(one, add_user(one, "boss", "admin"))
    file_store(one.state.settings).put_bytes((REPO / "data/tiles/world-toner-z3.pmtiles").read_bytes(),
                                             "tiles/basemap/toner.pmtiles")
    c1, c2 = TestClient(one, headers={"Origin": ORIGIN}), TestClient(two, headers={"Origin": ORIGIN})
    r = c1.post("/api/v1/tile-sources", json={"name": "toner", "kind": "topo", "path": "basemap/toner.pmtiles"}, headers=head)
    assert r.status_code == 201, r.text
    tile = c2.get("/api/v1/tiles/toner/2/1/1.png", headers=head)
    assert tile.status_code == 200 and tile.content[:8] == b"\x89PNG\r\n\x1a\n"
    assert (two.state.settings.data_dir / "basemap/toner.pmtiles").is_file()


def test_credentials_stay_secret(settings: Any, s3_endpoint: str, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    from posefix.filestore import file_store
    from posefix.main import create_app

    caplog.set_level(logging.DEBUG)
    good = _on_s3(settings, s3_endpoint, tmp_path / "m", "secret-check")
    assert SECRET not in repr(good) and SECRET not in str(good.model_dump())
    assert SECRET not in repr(file_store(good)) and KEY_ID not in repr(file_store(good))
    ready = TestClient(create_app(good)).get("/readyz")
    assert ready.status_code == 200, ready.text
    wrong = good.model_copy(update={"files_url": "s3://no-such-bucket/x"})
    app = create_app(wrong)
    not_ready = TestClient(app).get("/readyz")
    assert not_ready.status_code == 503 and "no-such-bucket" in not_ready.text
    _assert_no_credentials(caplog.text + not_ready.text, app)
    app.state.db.dispose()


def _assert_no_credentials(text: str, *apps: Any) -> None:
    assert SECRET not in text and KEY_ID not in text
    for a in apps:
        assert SECRET not in repr(a.state.settings)
