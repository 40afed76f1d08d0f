"""Runs: upload, search, metadata, soft delete, keyframes GeoJSON, export, images, history, access."""

from __future__ import annotations

import csv
import io
import json
import xml.etree.ElementTree as ET
import zipfile

import numpy as np
from PIL import Image
from PIL.TiffImagePlugin import IFDRational

from tests.conftest import drive_csv, upload


def jpeg(lon: float | None = None, lat: float | None = None, size=(64, 48)) -> bytes:
    im = Image.new("RGB", size, (10, 200, 30))
    buf = io.BytesIO()
    if lon is None:
        im.save(buf, "JPEG")
        return buf.getvalue()

    def dms(v: float):
        v = abs(v)
        d = int(v)
        m = int((v - d) * 60)
        s = (v - d - m / 60) * 3600
        return (IFDRational(d), IFDRational(m), IFDRational(int(round(s * 1000)), 1000))

    exif = Image.Exif()
    exif[0x8825] = {1: "N" if lat >= 0 else "S", 2: dms(lat), 3: "E" if lon >= 0 else "W", 4: dms(lon)}
    im.save(buf, "JPEG", exif=exif.tobytes())
    return buf.getvalue()


def zip_of(files: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in files.items():
            z.writestr(name, data)
    return buf.getvalue()


class TestUpload:
    def test_upload_csv(self, client, users):
        r = upload(client, users["client"], name="Morning drive")
        assert r.status_code == 201, r.text
        run = r.json()
        assert run["n_samples"] == 600 and run["n_keyframes"] == 61
        assert run["status"] == "imported" and run["revision"] == 0 and run["head_revision"] == 0
        assert run["source_format"] == "csv" and run["original_filename"] == "drive.csv"
        assert run["bbox"][1] < run["bbox"][3]
        assert run["recorded_start"].startswith("2023-11-14")
        assert run["length_m"] > 600
        assert set(run["rules"]) >= {"every_n", "lock_n", "lock_direction", "max_move_m", "order_rule"}

    def test_upload_gpx(self, client, users):
        gpx = ['<?xml version="1.0"?><gpx version="1.1" creator="t" xmlns="http://www.topografix.com/GPX/1/1"><trk><trkseg>']
        for i in range(30):
            gpx.append(f'<trkpt lat="{60.17 + i * 1e-4:.6f}" lon="24.94"><ele>5</ele><time>2024-05-01T10:00:{i:02d}Z</time></trkpt>')
        gpx.append("</trkseg></trk></gpx>")
        r = upload(client, users["admin"], "".join(gpx).encode(), filename="walk.gpx")
        assert r.status_code == 201, r.text
        assert r.json()["orientation_derived"] is True and r.json()["n_samples"] == 30

    def test_upload_with_images_zip_and_exif(self, client, users, app):
        data = drive_csv(200, images_every=50)
        imgs = zip_of({"photos/img00000.jpg": jpeg(), "photos/img00050.jpg": jpeg(), "extra.jpg": jpeg(24.94, 60.1715)})
        r = upload(client, users["admin"], data, images=[("photos.zip", imgs)])
        assert r.status_code == 201, r.text
        rid = r.json()["id"]
        assert r.json()["n_images"] == 3
        items = {i["filename"]: i for i in client.get(f"/api/v1/runs/{rid}/images", headers=users["admin"]).json()["items"]}
        assert items["img00000.jpg"]["sample_index"] == 0 and items["img00050.jpg"]["keyframe"] is not None
        extra = items["extra.jpg"]
        assert abs(extra["exif_lat"] - 60.1715) < 1e-6 and abs(extra["exif_lon"] - 24.94) < 1e-6
        # nearest keyframe to the EXIF position: about 150 samples (15 s) along
        assert abs(extra["sample_index"] - 150) <= 10
        kf = client.get(f"/api/v1/runs/{rid}/keyframes", headers=users["admin"]).json()
        with_images = [f for f in kf["features"] if f["properties"]["has_images"]]
        assert {i for f in with_images for i in f["properties"]["images"]} == {i["id"] for i in items.values()}

    def test_upload_several_image_files_and_thumbnail(self, client, users):
        r = upload(client, users["admin"], drive_csv(100, images_every=50), images=[("img00000.jpg", jpeg(size=(1200, 800))), ("img00050.jpg", jpeg())])
        assert r.status_code == 201, r.text
        imgs = client.get(f"/api/v1/runs/{r.json()['id']}/images", headers=users["admin"]).json()["items"]
        big = next(i for i in imgs if i["width"] == 1200)
        orig = client.get(f"/api/v1/images/{big['id']}", headers=users["admin"])
        assert orig.status_code == 200 and orig.headers["content-type"] == "image/jpeg"
        thumb = client.get(f"/api/v1/images/{big['id']}/thumbnail", headers=users["admin"])
        assert thumb.status_code == 200
        assert max(Image.open(io.BytesIO(thumb.content)).size) == 320
        again = client.get(f"/api/v1/images/{big['id']}/thumbnail", headers=users["admin"])
        assert again.content == thumb.content

    def test_missing_fields(self, client, users):
        r = client.post("/api/v1/runs", files={"file": ("d.csv", drive_csv(10), "text/csv")}, headers=users["admin"])
        assert r.status_code == 400 and r.json()["error"] == "bad_form"
        r = client.post("/api/v1/runs", data={"name": "x"}, files={"other": ("a", b"b")}, headers=users["admin"])
        assert r.status_code == 400

    def test_json_body_refused(self, client, users):
        r = client.post("/api/v1/runs", json={"name": "x"}, headers=users["admin"])
        assert r.status_code == 415


class TestSearch:
    def _three(self, client, users):
        ids = []
        for i, (name, lat) in enumerate([("Helsinki north", 60.17), ("Espoo loop", 60.20), ("Tampere", 61.49)]):
            r = upload(client, users["client"], drive_csv(50, lat0=lat, t0=1.7e9 + i * 86400), name=name)
            ids.append(r.json()["id"])
        return ids

    def test_filters_and_pagination(self, client, users):
        ids = self._three(client, users)
        h = users["client"]
        assert client.get("/api/v1/runs", headers=h).json()["total"] == 3
        assert [r["name"] for r in client.get("/api/v1/runs?name=LOOP", headers=h).json()["items"]] == ["Espoo loop"]
        box = client.get("/api/v1/runs?bbox=24.0,60.0,25.0,60.19", headers=h).json()
        assert [r["id"] for r in box["items"]] == [ids[0]]
        page = client.get("/api/v1/runs?limit=2&offset=0", headers=h).json()
        assert page["total"] == 3 and len(page["items"]) == 2
        page2 = client.get("/api/v1/runs?limit=2&offset=2", headers=h).json()
        assert len(page2["items"]) == 1
        assert {r["id"] for r in page["items"] + page2["items"]} == set(ids)
        since = client.get("/api/v1/runs", params={"since": "2023-11-16T00:00:00Z"}, headers=h).json()
        assert {r["name"] for r in since["items"]} == {"Tampere"}
        until = client.get("/api/v1/runs", params={"until": "2023-11-14T23:00:00Z"}, headers=h).json()
        assert {r["name"] for r in until["items"]} == {"Helsinki north"}
        assert client.get("/api/v1/runs?status=accepted", headers=h).json()["total"] == 0

    def test_name_wildcards_are_literal(self, client, users):
        self._three(client, users)
        assert client.get("/api/v1/runs?name=%25", headers=users["client"]).json()["total"] == 0

    def test_bad_bbox(self, client, users):
        r = client.get("/api/v1/runs?bbox=1,2,3", headers=users["client"])
        assert r.status_code == 400 and r.json()["error"] == "bad_bbox"
        assert client.get("/api/v1/runs?bbox=5,5,1,1", headers=users["client"]).status_code == 400


class TestRunLifecycle:
    def test_get_and_soft_delete(self, client, users):
        rid = upload(client, users["client"]).json()["id"]
        assert client.get(f"/api/v1/runs/{rid}", headers=users["client"]).json()["id"] == rid
        assert client.delete(f"/api/v1/runs/{rid}", headers=users["client"]).status_code == 204
        assert client.get(f"/api/v1/runs/{rid}", headers=users["client"]).status_code == 404
        assert client.get("/api/v1/runs", headers=users["client"]).json()["total"] == 0
        deleted = client.get("/api/v1/runs?status=deleted", headers=users["admin"]).json()
        assert [r["id"] for r in deleted["items"]] == [rid]
        hist = client.get(f"/api/v1/runs/{rid}/history", headers=users["admin"]).json()["items"]
        assert [e["action"] for e in hist] == ["imported", "deleted"]
        assert hist[1]["from_status"] == "imported" and hist[1]["to_status"] == "deleted"

    def test_client_cannot_delete_someone_elses_run(self, client, users, app):
        from tests.conftest import add_user, direct_token

        other = direct_token(app, add_user(app, "other", "client"))
        rid = upload(client, users["client"]).json()["id"]
        assert client.delete(f"/api/v1/runs/{rid}", headers=other).status_code == 404


class TestKeyframes:
    def test_geojson_shape(self, client, users):
        rid = upload(client, users["client"]).json()["id"]
        r = client.get(f"/api/v1/runs/{rid}/keyframes", headers=users["client"])
        assert r.status_code == 200 and r.headers["content-type"] == "application/geo+json"
        fc = r.json()
        assert fc["type"] == "FeatureCollection" and fc["revision"] == 0 and len(fc["features"]) == 61
        f = fc["features"][10]
        assert f["geometry"]["type"] == "Point"
        p = f["properties"]
        assert set(p) >= {"index", "t", "heading_deg", "adjustable", "locked", "edited", "deleted", "flagged",
                          "has_images", "images", "reported", "correction_m", "sigma_m"}
        assert p["index"] == 10 and p["correction_m"] == 0.0 and p["reported"] == f["geometry"]["coordinates"]
        assert abs(p["heading_deg"] - 0.0) < 1e-6 or abs(p["heading_deg"] - 360.0) < 1e-6
        assert fc["line"]["type"] == "LineString" and len(fc["line"]["coordinates"]) == 600
        assert fc["rules"]["every_n"] >= 1

    def test_etag_revalidation_and_gzip(self, client, users):
        rid = upload(client, users["admin"]).json()["id"]
        url = f"/api/v1/runs/{rid}/keyframes"
        gz = client.get(url, headers={**users["admin"], "Accept-Encoding": "gzip"})
        assert gz.status_code == 200 and gz.headers["content-encoding"] == "gzip"
        assert gz.headers["cache-control"] == "private, no-cache" and gz.headers["vary"] == "Accept-Encoding"
        etag_gz = gz.headers["etag"]
        assert etag_gz.startswith('"') and etag_gz.endswith('-gz"')
        plain = client.get(url, headers={**users["admin"], "Accept-Encoding": "identity"})
        assert "content-encoding" not in plain.headers and plain.content == gz.content  # httpx decoded the gzip
        assert plain.headers["etag"] == etag_gz[:-4] + '"' and len(plain.content) > 3 * int(gz.headers["content-length"])
        for tag in (etag_gz, plain.headers["etag"], f'W/{etag_gz}, "other"'):
            again = client.get(url, headers={**users["admin"], "If-None-Match": tag, "Accept-Encoding": "gzip"})
            assert again.status_code == 304 and again.content == b"" and again.headers["etag"] == etag_gz
        assert client.get(url, headers={**users["admin"], "If-None-Match": '"stale"'}).status_code == 200
        # someone else's tag does not reveal the run: access is checked first
        other = upload(client, users["client"]).json()["id"]
        hidden = client.get(f"/api/v1/runs/{other}/keyframes", headers={**users["client"], "If-None-Match": etag_gz})
        assert hidden.status_code == 200  # another run, another tag
        assert client.get(f"/api/v1/runs/{rid}/keyframes", headers={**users["client"], "If-None-Match": etag_gz}).status_code == 404
        # a new head revision changes the content, so the old tag no longer matches
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "deleted": [3]}, headers=users["admin"])
        assert r.status_code == 202
        changed = client.get(url, headers={**users["admin"], "If-None-Match": etag_gz, "Accept-Encoding": "gzip"})
        assert changed.status_code == 200 and changed.headers["etag"] != etag_gz and changed.json()["head_revision"] == 1

    def test_rendered_once_for_concurrent_readers(self, client, users, app, monkeypatch):
        import threading
        import time

        from posefix.runs import service
        from posefix.runs.models import Run

        rid = upload(client, users["admin"]).json()["id"]
        renders = []
        real = service._render_geojson

        def slow_render(*args):
            renders.append(1)
            time.sleep(0.2)  # long enough for every reader to arrive meanwhile
            return real(*args)

        monkeypatch.setattr(service, "_render_geojson", slow_render)
        service.GEOJSON_CACHE.clear()
        results = []

        def read():
            with app.state.db.transaction(write=False) as s:
                results.append(service.keyframes_geojson(s, app.state.settings, s.get(Run, rid), None))

        threads = [threading.Thread(target=read) for _ in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(30)
        assert len(renders) == 1 and len(results) == 8 and all(r is results[0] for r in results)
        assert json.loads(results[0].body)["run_id"] == rid

    def test_unknown_revision(self, client, users):
        rid = upload(client, users["client"]).json()["id"]
        r = client.get(f"/api/v1/runs/{rid}/keyframes?revision=5", headers=users["client"])
        assert r.status_code == 404 and r.json()["error"] == "revision_not_found"

    def test_rules_shape_adjustable(self, client, users, app):
        from sqlalchemy import update

        from posefix.runs.models import Run

        rid = upload(client, users["client"]).json()["id"]
        with app.state.db.transaction() as s:
            s.execute(update(Run).where(Run.id == rid).values(rules={"every_n": 5, "lock_n": 2, "lock_direction": "forward", "max_move_m": 30.0, "order_rule": "refuse", "deleted": "remove"}))
        fc = client.get(f"/api/v1/runs/{rid}/keyframes", headers=users["client"]).json()
        adj = [f["properties"]["index"] for f in fc["features"] if f["properties"]["adjustable"]]
        assert adj[:3] == [0, 5, 10] and fc["rules"]["every_n"] == 5


class TestExport:
    def test_csv_roundtrip(self, client, users):
        data = drive_csv(300)
        rid = upload(client, users["client"], data).json()["id"]
        r = client.get(f"/api/v1/runs/{rid}/export?format=csv", headers=users["client"])
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
        assert "attachment" in r.headers["content-disposition"]
        rows = list(csv.DictReader(io.StringIO(r.text)))
        src = list(csv.DictReader(io.StringIO(data.decode())))
        assert len(rows) == 300
        assert np.allclose([float(x["lat"]) for x in rows], [float(x["lat"]) for x in src], atol=1e-12)

    def test_gpx_and_geojson(self, client, users, settings):
        rid = upload(client, users["client"], drive_csv(120)).json()["id"]
        gpx = client.get(f"/api/v1/runs/{rid}/export?format=gpx", headers=users["client"])
        root = ET.fromstring(gpx.content)
        assert len(root.findall(".//{http://www.topografix.com/GPX/1/1}trkpt")) == 120
        gj = client.get(f"/api/v1/runs/{rid}/export?format=geojson", headers=users["client"]).json()
        assert gj["type"] in ("FeatureCollection", "Feature")
        assert not any((settings.files_dir / "staging").iterdir())

    def test_parquet_upload_and_columnar_exports_carry_the_csv_samples(self, client, users, tmp_path, settings):
        from posefix.io import read_run, write_run

        (tmp_path / "d.csv").write_bytes(drive_csv(250))
        write_run(read_run(tmp_path / "d.csv"), tmp_path / "d.parquet")
        rid = upload(client, users["client"], (tmp_path / "d.parquet").read_bytes(), filename="d.parquet").json()["id"]
        runs = {}
        for fmt, media in (("csv", "text/csv"), ("parquet", "application/vnd.apache.parquet"),
                           ("arrow", "application/vnd.apache.arrow.file")):
            r = client.get(f"/api/v1/runs/{rid}/export?format={fmt}", headers=users["client"])
            assert r.status_code == 200 and r.headers["content-type"].startswith(media), r.text
            assert f'.{fmt}"' in r.headers["content-disposition"]
            (tmp_path / f"out.{fmt}").write_bytes(r.content)
            runs[fmt] = read_run(tmp_path / f"out.{fmt}")
        source = read_run(tmp_path / "d.csv")
        for fmt, run in runs.items():
            assert run.n == 250
            assert np.array_equal(run.t_s, source.t_s), fmt
            assert np.abs(run.lat_deg - source.lat_deg).max() < 1e-10, fmt
        assert np.array_equal(runs["parquet"].lat_deg, runs["arrow"].lat_deg)  # exact, unrounded
        assert not any((settings.files_dir / "staging").iterdir())

    def test_bad_format(self, client, users):
        rid = upload(client, users["client"], drive_csv(20)).json()["id"]
        assert client.get(f"/api/v1/runs/{rid}/export?format=kml", headers=users["client"]).status_code == 422


class TestAccess:
    def test_client_sees_only_own_runs(self, client, users, app):
        from tests.conftest import add_user, direct_token

        other = direct_token(app, add_user(app, "other", "client"))
        rid = upload(client, users["client"]).json()["id"]
        assert client.get("/api/v1/runs", headers=other).json()["total"] == 0
        for path in ("", "/keyframes", "/export", "/history", "/revisions", "/images"):
            assert client.get(f"/api/v1/runs/{rid}{path}", headers=other).status_code == 404, path

    def test_operator_sees_runs_granted_by_provider(self, client, users, app):
        from sqlalchemy import select

        from posefix.runs import access
        from posefix.runs.models import Run

        rid = upload(client, users["client"]).json()["id"]
        upload(client, users["client"])
        assert client.get("/api/v1/runs", headers=users["operator"]).json()["total"] == 0
        granted = {"ids": [rid]}

        def provider(user_id: int):
            return select(Run.id).where(Run.id.in_(granted["ids"]))

        access.register_operator_runs(provider)
        try:
            listed = client.get("/api/v1/runs", headers=users["operator"]).json()
            assert [r["id"] for r in listed["items"]] == [rid]
            assert client.get(f"/api/v1/runs/{rid}/keyframes", headers=users["operator"]).status_code == 200
        finally:
            access._operator_providers.remove(provider)

    def test_operators_see_all_setting(self, client, users, app):
        upload(client, users["client"])
        app.state.settings.operators_see_all_runs = True
        assert client.get("/api/v1/runs", headers=users["operator"]).json()["total"] == 1

    def test_image_access_follows_run(self, client, users, app):
        from tests.conftest import add_user, direct_token

        other = direct_token(app, add_user(app, "other", "client"))
        r = upload(client, users["client"], drive_csv(100, images_every=50), images=[("img00000.jpg", jpeg())])
        img = client.get(f"/api/v1/runs/{r.json()['id']}/images", headers=users["client"]).json()["items"][0]
        assert client.get(f"/api/v1/images/{img['id']}", headers=other).status_code == 404
        assert client.get(f"/api/v1/images/{img['id']}/thumbnail", headers=other).status_code == 404
        assert client.get(f"/api/v1/images/{img['id']}", headers=users["reviewer"]).status_code == 200
