"""Hostile and broken uploads: size limits, malformed runs, path traversal, zip bombs, XML bombs.

Every refusal is a 4xx naming the file, stores nothing (no run row, no file) and leaves no
temporary file behind.
"""

from __future__ import annotations

import io
import os
import zipfile

import pytest
from sqlalchemy import func, select

from posefix.runs.models import Run
from tests.api.test_runs import jpeg, zip_of
from tests.conftest import drive_csv, upload


def stored_nothing(app, settings) -> None:
    with app.state.db.transaction(write=False) as s:
        assert s.scalar(select(func.count()).select_from(Run)) == 0
    files = settings.files_dir
    leftovers = [p for p in files.rglob("*") if p.is_file()] if files.exists() else []
    assert leftovers == [], leftovers


class TestSizeLimits:
    def test_run_file_over_limit_413(self, client, users, app, settings):
        settings.max_run_bytes = 10_000
        r = upload(client, users["admin"], drive_csv(600))
        assert r.status_code == 413
        body = r.json()
        assert body["error"] in ("payload_too_large", "file_too_large")
        stored_nothing(app, settings)

    def test_whole_body_over_limit_refused_before_reading(self, client, users, app, settings):
        settings.max_run_bytes = 1000
        settings.max_images_bytes = 1000
        r = upload(client, users["admin"], b"x" * (3 << 20))
        assert r.status_code == 413 and r.json()["error"] == "payload_too_large"
        stored_nothing(app, settings)

    def test_image_over_limit(self, client, users, app, settings):
        settings.max_image_bytes = 500
        r = upload(client, users["admin"], drive_csv(50), images=[("a.jpg", jpeg(size=(400, 400)))])
        assert r.status_code == 413 and r.json()["file"] == "a.jpg"
        stored_nothing(app, settings)

    def test_too_many_images(self, client, users, app, settings):
        settings.max_image_count = 2
        r = upload(client, users["admin"], drive_csv(50), images=[("photos.zip", zip_of({f"{i}.jpg": jpeg() for i in range(3)}))])
        assert r.status_code == 413
        stored_nothing(app, settings)


class TestMalformed:
    @pytest.mark.parametrize(
        "content, line, field",
        [
            (b"t,lat,lon,alt,qw,qx,qy,qz\n0,60,24,1,1,0,0,0\n1,abc,24,1,1,0,0,0\n", 3, "lat"),
            (b"t,lat,lon,alt,qw,qx,qy,qz\n0,60,24,1,1,0,0,0\n1,95,24,1,1,0,0,0\n", 3, "lat"),
            (b"t,lat,lon,alt,qw,qx,qy,qz\n0,60,24,1,1,0,0,0\n0,60,24,1,1,0,0,0\n", 3, "t"),
            (b"t,lat,alt,qw,qx,qy,qz\n0,60,1,1,0,0,0\n", None, "lon"),
        ],
    )
    def test_bad_csv_names_file_line_field(self, client, users, app, settings, content, line, field):
        r = upload(client, users["admin"], content, filename="bad.csv")
        assert r.status_code == 422, r.text
        body = r.json()
        assert body["error"] == "invalid_run" and body["file"] == "bad.csv"
        assert field in (body["field"] or "")
        if line is not None:
            assert body["line"] == line and f"bad.csv:{line}" in body["detail"]
        stored_nothing(app, settings)

    def test_empty_run(self, client, users, app, settings):
        r = upload(client, users["admin"], b"t,lat,lon,alt,qw,qx,qy,qz\n", filename="empty.csv")
        assert r.status_code == 422 and "empty.csv" in r.json()["detail"]
        stored_nothing(app, settings)

    def test_unknown_extension(self, client, users, app, settings):
        r = upload(client, users["admin"], b"hello", filename="run.exe")
        assert r.status_code == 422 and r.json()["file"] == "run.exe"
        stored_nothing(app, settings)

    def test_not_an_image(self, client, users, app, settings):
        r = upload(client, users["admin"], drive_csv(50), images=[("fake.jpg", b"not a jpeg")])
        assert r.status_code == 422 and r.json()["error"] == "bad_image" and r.json()["file"] == "fake.jpg"
        stored_nothing(app, settings)

    def test_broken_zip(self, client, users, app, settings):
        r = upload(client, users["admin"], drive_csv(50), images=[("photos.zip", b"PK\x03\x04garbage")])
        assert r.status_code == 422 and r.json()["error"] == "bad_archive"
        stored_nothing(app, settings)

    def test_good_run_then_bad_image_stores_nothing(self, client, users, app, settings):
        r = upload(client, users["admin"], drive_csv(50), images=[("ok.jpg", jpeg()), ("bad.png", b"\x89PNG nope")])
        assert r.status_code == 422
        stored_nothing(app, settings)


class TestPathTraversal:
    @pytest.mark.parametrize("name", ["../../etc/passwd.jpg", "..\\evil.jpg", "/abs/x.jpg", "a/../../b.jpg"])
    def test_image_names(self, client, users, app, settings, name):
        r = upload(client, users["admin"], drive_csv(50), images=[(name, jpeg())])
        # Some clients strip directories themselves; either way nothing escapes the store.
        assert r.status_code in (201, 400), r.text
        if r.status_code == 400:
            assert r.json()["error"] == "unsafe_path"
            stored_nothing(app, settings)
        else:
            img = client.get(f"/api/v1/runs/{r.json()['id']}/images", headers=users["admin"]).json()["items"][0]
            assert "/" not in img["filename"] and ".." not in img["filename"]

    @pytest.mark.parametrize("member", ["../escape.jpg", "/etc/x.jpg", "a/../../b.jpg", "C:\\x.jpg"])
    def test_zip_members(self, client, users, app, settings, member):
        r = upload(client, users["admin"], drive_csv(50), images=[("photos.zip", zip_of({member: jpeg()}))])
        assert r.status_code == 400 and r.json()["error"] == "unsafe_path"
        assert "path traversal" in r.json()["detail"]
        stored_nothing(app, settings)
        assert not (settings.data_dir.parent / "escape.jpg").exists()

    def test_run_file_name(self, client, users, app, settings):
        r = client.post("/api/v1/runs", files={"file": ("../../x.csv", drive_csv(20), "text/csv")}, data={"name": "x"},
                        headers=users["admin"])
        assert r.status_code in (201, 400)
        if r.status_code == 201:
            assert r.json()["original_filename"] == "x.csv"


class TestBombs:
    def test_zip_bomb(self, client, users, app, settings):
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("bomb.jpg", b"\0" * (50 << 20))  # 50 MB of zeros: ~50 kB compressed
        r = upload(client, users["admin"], drive_csv(50), images=[("photos.zip", buf.getvalue())])
        assert r.status_code == 413 and r.json()["error"] == "zip_bomb"
        stored_nothing(app, settings)

    def test_zip_with_lying_header(self, client, users, app, settings):
        """A member whose header claims a small size but inflates to more is cut at the claim."""
        good = jpeg()
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
            z.writestr("a.jpg", good + b"\0" * 1000)
        data = bytearray(buf.getvalue())
        # Patch the central directory's uncompressed size down to the JPEG alone.
        cd = data.rfind(b"PK\x01\x02")
        size_off = cd + 24
        data[size_off:size_off + 4] = len(good).to_bytes(4, "little")
        r = upload(client, users["admin"], drive_csv(50), images=[("photos.zip", bytes(data))])
        assert r.status_code in (201, 413, 422)
        if r.status_code != 201:
            stored_nothing(app, settings)

    def test_decompression_bomb_image(self, client, users, app, settings):
        from PIL import Image

        buf = io.BytesIO()
        Image.new("1", (12000, 12000)).save(buf, "PNG")  # 144 Mpx, a few kB
        r = upload(client, users["admin"], drive_csv(50), images=[("huge.png", buf.getvalue())])
        assert r.status_code == 413 and r.json()["error"] == "image_bomb"
        stored_nothing(app, settings)

    def test_xml_entity_bomb_gpx(self, client, users, app, settings):
        bomb = b"""<?xml version="1.0"?>
<!DOCTYPE lolz [<!ENTITY lol "lol"><!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
<!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
<!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">]>
<gpx version="1.1" creator="&lol4;" xmlns="http://www.topografix.com/GPX/1/1"><trk><trkseg>
<trkpt lat="60" lon="24"><time>2024-01-01T00:00:00Z</time></trkpt></trkseg></trk></gpx>"""
        r = upload(client, users["admin"], bomb, filename="bomb.gpx")
        assert r.status_code == 422 and r.json()["file"] == "bomb.gpx"
        assert "DTD" in r.json()["detail"] or "entit" in r.json()["detail"].lower()
        stored_nothing(app, settings)

    def test_no_temp_files_in_system_tmp(self, client, users, app, settings, tmp_path, monkeypatch):
        import tempfile

        monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
        (tmp_path / "tmp").mkdir()
        tempfile.tempdir = None
        try:
            r = upload(client, users["admin"], b"t,lat\n1,2\n", filename="bad.csv", images=[("a.jpg", jpeg())])
            assert r.status_code == 422
            assert os.listdir(tmp_path / "tmp") == []
        finally:
            tempfile.tempdir = None
        stored_nothing(app, settings)
