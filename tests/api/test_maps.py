"""Map matching over HTTP: floor plan upload -> model job -> download, walk tracking with the
error at the waypoints, live tracking sessions, bad uploads, access, run suggestions.
Real database (SQLite and PostgreSQL), real worker, the shared floor in data/indoor-site1-F1."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from posefix.maps.sessions import SESSIONS
from tests.conftest import REPO, drive_csv, upload, wait_job

FLOOR = REPO / "data" / "indoor-site1-F1"
WALK = FLOOR / "walks" / "5dd9e7aac5b77e0006b1732b.txt"
FLOOR_FILES = ("floor_info.json", "geojson_map.json", "floor_image.png")


def floor_zip(folder: str = "site1-F1/", extra: dict[str, bytes] | None = None, skip: str | None = None) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in FLOOR_FILES:
            if name != skip:
                zf.write(FLOOR / name, folder + name)
        for name, data in (extra or {}).items():
            zf.writestr(name, data)
    return buf.getvalue()


def post_floor(client, headers, data: bytes, filename: str = "floor.zip", name: str = "site1 F1", cell_m: str | None = None):
    form = {"name": name}
    if cell_m is not None:
        form["cell_m"] = cell_m
    return client.post("/api/v1/floorplans", files={"file": (filename, data, "application/octet-stream")}, data=form, headers=headers)


def ready_floor(app, client, users) -> dict:
    r = post_floor(client, users["admin"], floor_zip())
    assert r.status_code == 202, r.text
    job = wait_job(app, r.json()["job_id"])
    assert job["status"] == "succeeded", job
    return client.get(f"/api/v1/floorplans/{r.json()['id']}", headers=users["admin"]).json()


def stored_files(settings) -> list[Path]:
    root = settings.files_dir
    return sorted(p for p in root.rglob("*") if p.is_file()) if root.exists() else []


@pytest.fixture(autouse=True)
def _no_sessions():
    SESSIONS.clear()
    yield
    SESSIONS.clear()


class TestFloorPlanUpload:
    def test_upload_builds_model_by_job_and_download_has_its_size(self, app, client, users):
        from posefix.mapmatch.model import load_model

        r = post_floor(client, users["admin"], floor_zip())
        assert r.status_code == 202, r.text
        fp = r.json()
        assert fp["status"] == "queued" and fp["source"] == "competition" and fp["has_image"]
        assert fp["width_m"] == pytest.approx(239.8, abs=0.5) and fp["height_m"] == pytest.approx(176.4, abs=0.5)
        assert len(fp["georef"]) == 4
        r = client.get(f"/api/v1/floorplans/{fp['id']}/model", headers=users["operator"])
        assert r.status_code == 409 and r.json()["error"] == "model_not_ready"
        job = wait_job(app, fp["job_id"])
        assert job["status"] == "succeeded" and job["result"]["floorplan_id"] == fp["id"]
        job_view = client.get(f"/api/v1/jobs/{fp['job_id']}", headers=users["admin"]).json()
        assert job_view["progress"] == 1.0
        got = client.get(f"/api/v1/floorplans/{fp['id']}", headers=users["client"]).json()
        assert got["status"] == "ready" and got["n_vertices"] > 10000 and got["build_s"] > 0
        r = client.get(f"/api/v1/floorplans/{fp['id']}/model", headers=users["client"])
        assert r.status_code == 200
        assert int(r.headers["content-length"]) == len(r.content) == got["model_bytes"] == int(r.headers["x-model-bytes"])
        assert got["model_bytes"] < 400 * 1024  # compact: the floor's graph as a few arrays
        path = Path(app.state.settings.data_dir) / "m.npz"
        path.write_bytes(r.content)
        assert load_model(path).graph.n_vertices == got["n_vertices"]
        img = client.get(f"/api/v1/floorplans/{fp['id']}/image", headers=users["client"])
        assert img.status_code == 200 and img.content[:8] == b"\x89PNG\r\n\x1a\n"
        listing = client.get("/api/v1/floorplans", headers=users["operator"]).json()
        assert listing["total"] == 1 and listing["items"][0]["id"] == fp["id"]

    def test_geojson_polygons_with_cell_size(self, app, client, users):
        # A 20 x 10 m room with a 2 m thick wall from y=0 to y=8 at x=9..11 (a door at the top).
        gj = {"type": "FeatureCollection", "features": [
            {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [20, 0], [20, 10], [0, 10], [0, 0]]]}},
            {"type": "Feature", "properties": {"walkable": False}, "geometry": {"type": "Polygon", "coordinates": [[[9, 0], [11, 0], [11, 8], [9, 8], [9, 0]]]}},
        ]}
        r = post_floor(client, users["admin"], json.dumps(gj).encode(), filename="room.geojson", cell_m="1.0")
        assert r.status_code == 202, r.text
        assert r.json()["cell_m"] == 1.0 and r.json()["has_image"] is False
        assert wait_job(app, r.json()["job_id"])["status"] == "succeeded"
        fp = client.get(f"/api/v1/floorplans/{r.json()['id']}", headers=users["admin"]).json()
        # 200 m² minus the 16 m² wall at 1 m cells.
        assert 170 <= fp["n_vertices"] <= 184

    def test_delete_removes_row_files_and_sessions(self, app, client, users, settings):
        fp = ready_floor(app, client, users)
        s = client.post(f"/api/v1/floorplans/{fp['id']}/sessions", json={}, headers=users["operator"]).json()
        assert client.delete(f"/api/v1/floorplans/{fp['id']}", headers=users["reviewer"]).status_code == 403
        assert client.delete(f"/api/v1/floorplans/{fp['id']}", headers=users["admin"]).status_code == 204
        assert client.get(f"/api/v1/floorplans/{fp['id']}", headers=users["admin"]).status_code == 404
        assert not any("floorplans" in str(p) for p in stored_files(settings))
        r = client.post(f"/api/v1/sessions/{s['session_id']}/steps", json={"steps": [{"t_ms": 1, "dx_m": 0.7, "dy_m": 0}]},
                        headers=users["operator"])
        assert r.status_code == 404


class TestBadUploads:
    @pytest.mark.parametrize("case", ["traversal", "bomb", "missing", "not_zip", "bad_json", "bad_png", "lonlat_geojson", "wrong_ext"])
    def test_refused_with_named_file_and_nothing_left(self, client, users, settings, app, case):
        if case == "traversal":
            data, fname = floor_zip(extra={"../../evil.txt": b"x"}), "floor.zip"
            expect, names = 400, "../../evil.txt"
        elif case == "bomb":
            data, fname = floor_zip(extra={"floor/big.bin": b"\0" * (300 * 1024 * 1024)}), "floor.zip"
            expect, names = 413, "big.bin"
        elif case == "missing":
            data, fname = floor_zip(skip="geojson_map.json"), "floor.zip"
            expect, names = 422, "geojson_map.json"
        elif case == "not_zip":
            data, fname = b"PK\x03\x04 this is not really a zip", "floor.zip"
            expect, names = 422, "floor.zip"
        elif case == "bad_json":
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w") as zf:
                zf.writestr("floor_info.json", '{"map_info": {"height": 10}}')
                zf.write(FLOOR / "geojson_map.json", "geojson_map.json")
                zf.write(FLOOR / "floor_image.png", "floor_image.png")
            data, fname = buf.getvalue(), "floor.zip"
            expect, names = 422, "floor_info.json"
        elif case == "bad_png":
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w") as zf:
                zf.write(FLOOR / "floor_info.json", "floor_info.json")
                zf.write(FLOOR / "geojson_map.json", "geojson_map.json")
                zf.writestr("floor_image.png", b"not a png")
            data, fname = buf.getvalue(), "floor.zip"
            expect, names = 422, "floor_image.png"
        elif case == "lonlat_geojson":
            gj = {"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {},
                  "geometry": {"type": "Polygon", "coordinates": [[[-120.1, 30.0], [-120.0, 30.0], [-120.0, 30.1], [-120.1, 30.0]]]}}]}
            data, fname = json.dumps(gj).encode(), "plan.geojson"
            expect, names = 422, "features[0].geometry"
        else:
            data, fname = b"hello", "floor.exe"
            expect, names = 422, "floor.exe"
        r = post_floor(client, users["admin"], data, filename=fname)
        assert r.status_code == expect, r.text
        body = r.json()
        assert set(body) >= {"error", "detail"} and names in body["detail"], body
        assert stored_files(settings) == []
        assert client.get("/api/v1/floorplans", headers=users["admin"]).json()["total"] == 0

    def test_bad_cell_size_and_missing_file(self, client, users):
        r = post_floor(client, users["admin"], floor_zip(), cell_m="0")
        assert r.status_code == 400 and r.json()["field"] == "cell_m"
        r = client.post("/api/v1/floorplans", data={"name": "x"}, files={"other": ("a", b"b")}, headers=users["admin"])
        assert r.status_code == 400 and "'file'" in r.json()["detail"]

    def test_bad_walk_names_line_and_field(self, app, client, users):
        fp = ready_floor(app, client, users)
        lines = WALK.read_text().splitlines()[:400]
        lines[250] = "1574140000000\tTYPE_ACCELEROMETER\tabc\t1\t2"
        r = client.post(f"/api/v1/floorplans/{fp['id']}/walks", files={"file": ("w.txt", "\n".join(lines).encode())}, headers=users["operator"])
        assert r.status_code == 422, r.text
        assert r.json()["line"] == 251 and r.json()["field"] == "TYPE_ACCELEROMETER" and "w.txt:251" in r.json()["detail"]
        # The walk's staging copy is gone: only the floor's own files remain.
        assert all("floorplans" in str(p) for p in stored_files(app.state.settings))


class TestAccess:
    def test_roles(self, app, client, users):
        for role in ("operator", "reviewer", "client"):
            r = post_floor(client, users[role], floor_zip())
            assert r.status_code == 403 and r.json()["error"] == "role_forbidden"
        assert client.get("/api/v1/floorplans").status_code == 401
        assert client.get("/api/v1/floorplans/999", headers=users["client"]).status_code == 404

    def test_sessions_are_private(self, app, client, users):
        fp = ready_floor(app, client, users)
        s = client.post(f"/api/v1/floorplans/{fp['id']}/sessions", json={}, headers=users["operator"]).json()
        step = {"steps": [{"t_ms": 1, "dx_m": 0.7, "dy_m": 0.0}]}
        assert client.post(f"/api/v1/sessions/{s['session_id']}/steps", json=step, headers=users["client"]).status_code == 404
        assert client.delete(f"/api/v1/sessions/{s['session_id']}", headers=users["client"]).status_code == 404
        assert client.post(f"/api/v1/sessions/{s['session_id']}/steps", json=step, headers=users["operator"]).status_code == 200

    def test_access_is_judged_before_the_body(self, app, client, users):
        """Another user's session is absent whatever the body: a 422 would tell it exists."""
        fp = ready_floor(app, client, users)
        sid = client.post(f"/api/v1/floorplans/{fp['id']}/sessions", json={}, headers=users["operator"]).json()["session_id"]
        for bad in ({}, {"steps": "x"}, {"steps": [{"t_ms": "soon"}]}):
            r = client.post(f"/api/v1/sessions/{sid}/steps", json=bad, headers=users["client"])
            assert r.status_code == 404 and r.json()["error"] == "session_not_found", r.text
            assert client.post(f"/api/v1/sessions/{sid}/steps", json=bad).status_code == 401
            assert client.post(f"/api/v1/sessions/{sid}/steps", json=bad, headers=users["operator"]).status_code == 422
        r = client.post("/api/v1/sessions/no-such-session/steps", json={}, headers=users["operator"])
        assert r.status_code == 404 and r.json()["error"] == "session_not_found"


class TestWalkTracking:
    def test_track_returns_tracks_ellipses_and_waypoint_errors(self, app, client, users):
        from posefix.mapmatch import read_walk

        fp = ready_floor(app, client, users)
        walk = read_walk(WALK)
        r = client.post(f"/api/v1/floorplans/{fp['id']}/walks", files={"file": (WALK.name, WALK.read_bytes())}, headers=users["client"])
        assert r.status_code == 200, r.text
        body = r.json()
        kinds = [f["properties"]["kind"] for f in body["features"]]
        assert kinds[:2] == ["matched", "dead_reckoning"] and kinds.count("waypoint") == walk.waypoints.shape[0]
        n = body["walk"]["n_steps"]
        assert n > 20 and len(body["steps"]) == n + 1 == len(body["features"][0]["geometry"]["coordinates"])
        first = body["steps"][0]
        assert (first["x_m"], first["y_m"]) == pytest.approx(tuple(walk.waypoints[0, 1:3]), abs=1.0)
        assert all(s["sigma_major_m"] >= s["sigma_minor_m"] > 0 for s in body["steps"])
        err = body["errors"]
        assert err["skip_first"] and err["n"] == walk.waypoints.shape[0] - 1
        wp_err = [w["error_m"] for w in err["waypoints"][1:]]
        assert err["mean_m"] == pytest.approx(np.mean(wp_err), abs=2e-3)
        # Matched to the corridors, the track ends within a few metres of the surveyed end.
        assert err["max_m"] < 5.0 and err["mean_m"] < err["dr_mean_m"]
        assert body["steps"][-1]["lon"] == pytest.approx(fp["georef"][0] + body["steps"][-1]["x_m"] * fp["georef"][2], abs=1e-6)
        # From the given start the posterior stays on one place: converged, one mode, at every step.
        assert all(s["converged"] and s["n_modes"] == 1 and s["mode_spread_m"] == 0.0 for s in body["steps"])
        assert body["walk"]["converged_at_end"] and body["walk"]["converged_share"] == 1.0

    def test_unknown_and_explicit_start(self, app, client, users):
        fp = ready_floor(app, client, users)
        for start, ok in (("unknown", 200), ("81.3,93.3", 200), ("north", 400)):
            r = client.post(f"/api/v1/floorplans/{fp['id']}/walks", files={"file": (WALK.name, WALK.read_bytes())},
                            data={"start": start}, headers=users["client"])
            assert r.status_code == ok, r.text
            if start == "unknown":
                # Motion only, unknown start: the walk's shape fits several corridors, and the answer says so.
                last = r.json()["steps"][-1]
                assert not r.json()["walk"]["converged_at_end"] and not last["converged"]
                assert last["n_modes"] >= 2 and last["mode_spread_m"] > 10.0
        assert r.json()["error"] == "bad_start"

    def test_fingerprints_say_whether_the_walks_wifi_was_used(self, app, client, users, tmp_path):
        from posefix.mapmatch import read_walk
        from posefix.mapmatch.fingerprints import build_fingerprints, save_fingerprints

        fp = ready_floor(app, client, users)
        url = f"/api/v1/floorplans/{fp['id']}/walks"
        survey = [read_walk(w) for w in sorted((FLOOR / "walks").glob("*.txt")) if w != WALK]  # never the walk tracked
        small = build_fingerprints(survey)
        assert not small.f3_calibrated  # two survey walks cannot calibrate f3
        save_fingerprints(small, tmp_path / "small.npz")
        # The same map, its calibration set by hand (as the browser parity fixture does), so f3 is used.
        small.f3_calibrated, small.f3_note, small.walk_corr = True, "", 0.25
        save_fingerprints(small, tmp_path / "set.npz")

        r = client.post(url, files={"file": (WALK.name, WALK.read_bytes())}, data={"start": "unknown"}, headers=users["client"])
        assert r.status_code == 200 and r.json()["walk"]["wifi"] == {
            "fingerprints": None, "fixes": 0, "used": False, "note": "no fingerprint file given", "walk_corr": None,
            "robust": None}
        r = client.post(url, files={"file": (WALK.name, WALK.read_bytes()),
                                    "fingerprints": ("survey.npz", (tmp_path / "small.npz").read_bytes())},
                        data={"start": "unknown"}, headers=users["client"])
        assert r.status_code == 200, r.text
        wifi = r.json()["walk"]["wifi"]
        assert wifi["fingerprints"] == "survey.npz" and not wifi["used"] and wifi["fixes"] == 0
        assert "f3 left out" in wifi["note"] and "needs 3" in wifi["note"]
        r = client.post(url, files={"file": (WALK.name, WALK.read_bytes()),
                                    "fingerprints": ("set.npz", (tmp_path / "set.npz").read_bytes())},
                        data={"start": "unknown"}, headers=users["client"])
        assert r.status_code == 200, r.text
        body = r.json()
        wifi = body["walk"]["wifi"]
        n_scans = len({int(row[0]) for row in read_walk(WALK).wifi})
        assert wifi["used"] and 0 < wifi["fixes"] <= n_scans and wifi["note"] == "" and wifi["robust"] is True
        assert wifi["walk_corr"] == 0.25
        # Each step still says whether it is placed, and how many places it may be.
        assert all({"converged", "n_modes", "mode_spread_m"} <= set(s) for s in body["steps"])

        r = client.post(url, files={"file": (WALK.name, WALK.read_bytes()), "fingerprints": ("junk.npz", b"not a zip")},
                        headers=users["client"])
        assert r.status_code == 422 and r.json()["error"] == "invalid_fingerprints", r.text
        assert r.json()["detail"].startswith("junk.npz:0: field file: ") and r.json()["field"] == "file"


class TestTrackingSession:
    def test_steps_one_by_one_match_the_offline_tracker(self, app, client, users):
        from posefix.mapmatch import Tracker, read_walk
        from posefix.mapmatch.sensors import steps_from_walk
        from posefix.maps.service import MODELS, get_floorplan

        fp = ready_floor(app, client, users)
        walk = read_walk(WALK)
        start = [float(walk.waypoints[0, 1]), float(walk.waypoints[0, 2])]
        r = client.post(f"/api/v1/floorplans/{fp['id']}/sessions", json={"start_xy_m": start}, headers=users["operator"])
        assert r.status_code == 201, r.text
        sid = r.json()["session_id"]
        assert r.json()["position"]["x_m"] == pytest.approx(start[0], abs=1.0)
        with app.state.db.transaction(write=False) as s:
            model = MODELS.get(app.state.settings, get_floorplan(s, fp["id"]))
        steps = steps_from_walk(walk)
        vec = steps.vectors_m(model.step_model)
        ref = Tracker(model, start_xy_m=tuple(start))
        for i in range(len(steps)):
            # Alternate the two step forms: a vector, and the sensor heading + length.
            if i % 2 == 0:
                item = {"t_ms": int(steps.t_ms[i]), "dx_m": float(vec[i, 0]), "dy_m": float(vec[i, 1])}
            else:
                item = {"t_ms": int(steps.t_ms[i]), "heading_rad": float(steps.heading_rad[i]), "length_m": float(np.hypot(*vec[i]))}
            r = client.post(f"/api/v1/sessions/{sid}/steps", json={"steps": [item]}, headers=users["operator"])
            assert r.status_code == 200, r.text
            pos = r.json()["positions"]
            assert len(pos) == 1 and r.json()["n_steps"] == i + 1
            want = ref.step(vec[i], int(steps.t_ms[i])).summary
            assert (pos[0]["x_m"], pos[0]["y_m"]) == pytest.approx(tuple(want.mean_xy_m), abs=2e-3)
            assert pos[0]["sigma_major_m"] == pytest.approx(want.sigma_major_m, abs=2e-3)
        # The last online position is near the surveyed end of the walk.
        assert np.hypot(pos[0]["x_m"] - walk.waypoints[-1, 1], pos[0]["y_m"] - walk.waypoints[-1, 2]) < 8.0
        assert client.delete(f"/api/v1/sessions/{sid}", headers=users["operator"]).status_code == 204
        r = client.post(f"/api/v1/sessions/{sid}/steps", json={"steps": [item]}, headers=users["operator"])
        assert r.status_code == 404 and r.json()["error"] == "session_not_found"

    def test_raw_sensor_batches_detect_the_walks_steps(self, app, client, users):
        from posefix.mapmatch import read_walk
        from posefix.mapmatch.sensors import steps_from_walk

        fp = ready_floor(app, client, users)
        walk = read_walk(WALK)
        start = [float(walk.waypoints[0, 1]), float(walk.waypoints[0, 2])]
        sid = client.post(f"/api/v1/floorplans/{fp['id']}/sessions", json={"start_xy_m": start}, headers=users["operator"]).json()["session_id"]
        t0, t1 = walk.acc[0, 0], walk.acc[-1, 0]
        got = []
        for a in np.arange(t0, t1 + 2000, 2000.0):  # 2 s batches, as a phone would post them
            acc = walk.acc[(walk.acc[:, 0] >= a) & (walk.acc[:, 0] < a + 2000)]
            rot = walk.rotvec[(walk.rotvec[:, 0] >= a) & (walk.rotvec[:, 0] < a + 2000)]
            r = client.post(f"/api/v1/sessions/{sid}/steps", json={"sensors": {"acc": acc.tolist(), "rotvec": rot.tolist()}},
                            headers=users["operator"])
            assert r.status_code == 200, r.text
            got += r.json()["positions"]
        offline = len(steps_from_walk(walk))
        # The last 0.6 s never settle, and batch edges can shift a peak: within a few steps.
        assert offline - 3 <= len(got) <= offline + 1
        assert [p["t_ms"] for p in got] == sorted(p["t_ms"] for p in got)

    def test_bad_steps_and_session_cap(self, app, client, users):
        from posefix.maps import sessions

        fp = ready_floor(app, client, users)
        url = f"/api/v1/floorplans/{fp['id']}/sessions"
        assert client.post(url, json={"start_xy_m": [-5, 3]}, headers=users["operator"]).status_code == 400
        sid = client.post(url, json={}, headers=users["operator"]).json()["session_id"]
        r = client.post(f"/api/v1/sessions/{sid}/steps", json={"steps": [{"t_ms": 1, "dx_m": 0.5}]}, headers=users["operator"])
        assert r.status_code == 422 and "dx_m and dy_m" in r.json()["detail"]
        r = client.post(f"/api/v1/sessions/{sid}/steps", json={"sensors": {"acc": [[1, 2, 3]]}}, headers=users["operator"])
        assert r.status_code == 422 and r.json()["field"] == "sensors.acc"
        for _ in range(sessions.MAX_SESSIONS - 1):
            assert client.post(url, json={}, headers=users["operator"]).status_code == 201
        r = client.post(url, json={}, headers=users["operator"])
        assert r.status_code == 429 and r.json()["error"] == "too_many_sessions"


class TestSuggestions:
    def test_suggestions_then_accept_one_as_suggestion_edit(self, app, client, users):
        rid = upload(client, users["client"], drive_csv(300)).json()["id"]
        r = client.post(f"/api/v1/runs/{rid}/suggestions", headers=users["admin"])
        assert r.status_code == 202, r.text
        job_id = r.json()["job_id"]
        assert r.json()["revision"] == 0
        job = wait_job(app, job_id)
        assert job["status"] == "succeeded", job
        body = client.get(f"/api/v1/jobs/{job_id}", headers=users["admin"]).json()["result"]
        # Asking again for the same revision reuses the finished job.
        again = client.post(f"/api/v1/runs/{rid}/suggestions", json={"revision": 0}, headers=users["admin"]).json()
        assert again["job_id"] == job_id and again["status"] == "succeeded"
        assert body["run_id"] == rid and body["revision"] == 0
        fc = client.get(f"/api/v1/runs/{rid}/keyframes", headers=users["admin"]).json()
        assert len(body["items"]) == len(fc["features"]) and body["osm"] == "helsinki.osm.pbf"
        assert body["matcher"] == "roads"  # a drive on the extract's streets: the road network answers
        assert all(it["sigma_m"] > 0 and it["moved_m"] >= 0 for it in body["items"])
        assert [it["adjustable"] for it in body["items"]] == [f["properties"]["adjustable"] for f in fc["features"]]
        it = max((x for x in body["items"] if x["adjustable"] and 0 < x["moved_m"] < 20), key=lambda x: x["moved_m"])
        r = client.post(f"/api/v1/runs/{rid}/edits", json={"base_revision": 0, "moves": [
            {"index": it["index"], "lon": it["lon"], "lat": it["lat"], "kind": "suggestion"}]}, headers=users["admin"])
        assert r.status_code == 202, r.text
        assert wait_job(app, r.json()["job_id"])["status"] == "succeeded"
        edits = client.get(f"/api/v1/runs/{rid}/edits", headers=users["admin"]).json()
        rows = edits["items"] if isinstance(edits, dict) else edits
        assert [(e["k"], e["kind"]) for e in rows] == [(it["index"], "suggestion")]

    def test_the_grid_when_asked_is_another_job_with_its_own_answer(self, app, client, users):
        rid = upload(client, users["client"], drive_csv(100)).json()["id"]
        roads_id = client.post(f"/api/v1/runs/{rid}/suggestions", headers=users["admin"]).json()["job_id"]
        roads = wait_job(app, roads_id)["result"]
        r = client.post(f"/api/v1/runs/{rid}/suggestions", json={"matcher": "grid"}, headers=users["admin"])
        assert r.status_code == 202 and r.json()["job_id"] != roads_id
        grid = wait_job(app, r.json()["job_id"])["result"]
        assert roads["matcher"] == "roads" and grid["matcher"] == "grid" and len(grid["items"]) == len(roads["items"])
        r = client.post(f"/api/v1/runs/{rid}/suggestions", json={"matcher": "nearest"}, headers=users["admin"])
        assert r.status_code == 422 and "matcher" in r.text

    def test_suggestion_access(self, client, users):
        rid = upload(client, users["client"], drive_csv(100)).json()["id"]
        assert client.post(f"/api/v1/runs/{rid}/suggestions", headers=users["client"]).status_code == 403
        assert client.post(f"/api/v1/runs/{rid}/suggestions", headers=users["operator"]).status_code == 404
        assert client.post("/api/v1/runs/99999/suggestions", headers=users["admin"]).status_code == 404
        r = client.post(f"/api/v1/runs/{rid}/suggestions", json={"revision": 5}, headers=users["admin"])
        assert r.status_code == 404 and r.json()["error"] == "revision_not_found"

    def test_suggestions_without_osm_extract(self, app, client, users, settings, tmp_path):
        rid = upload(client, users["client"], drive_csv(100)).json()["id"]
        settings.osm_extract = tmp_path / "missing.osm.pbf"
        r = client.post(f"/api/v1/runs/{rid}/suggestions", headers=users["admin"])
        assert r.status_code == 404 and r.json()["error"] == "osm_not_found" and "missing.osm.pbf" in r.json()["detail"]

    def test_run_far_from_the_extract_fails_the_job_with_a_reason(self, app, client, users):
        rid = upload(client, users["client"], drive_csv(100, lat0=48.85, lon0=2.35)).json()["id"]
        job_id = client.post(f"/api/v1/runs/{rid}/suggestions", headers=users["admin"]).json()["job_id"]
        job = wait_job(app, job_id)
        assert job["status"] == "dead" and "no drive ways" in job["error"]


class TestDemoFloor:
    def test_demo_seeds_the_shared_floor_once_with_its_model(self, app, client, users, settings):
        from posefix.maps.demo import DEMO_FLOOR_NAME, ensure_demo_floorplan
        from tests.conftest import add_user

        admin_id = add_user(app, "demo-admin", "admin")
        created: list[str] = []
        fid = ensure_demo_floorplan(app.state.db, settings, REPO / "data", admin_id, created)
        again: list[str] = []
        assert ensure_demo_floorplan(app.state.db, settings, REPO / "data", admin_id, again) == fid
        assert len(created) == 1 and again == []
        fp = client.get(f"/api/v1/floorplans/{fid}", headers=users["operator"]).json()
        assert fp["name"] == DEMO_FLOOR_NAME and fp["status"] == "ready" and fp["n_vertices"] > 10000
        r = client.get(f"/api/v1/floorplans/{fid}/model", headers=users["operator"])
        assert len(r.content) == fp["model_bytes"]


def test_maps_models_match_migrations(db_url):
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    import posefix.edits.models  # noqa: F401
    import posefix.maps.models  # noqa: F401
    from posefix.db import Base, Database

    db = Database(db_url)
    try:
        with db.engine.connect() as conn:
            diffs = compare_metadata(MigrationContext.configure(conn, opts={"compare_type": True}), Base.metadata)
    finally:
        db.dispose()
    text = repr(diffs)
    assert "floor_plans" not in text and "'edits'" not in text, text
