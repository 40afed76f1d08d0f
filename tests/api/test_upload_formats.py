"""The upload form's file types are the server's: one list, served by the API and enforced."""

from __future__ import annotations

from posefix.io import FILE_EXTENSIONS, read_run, write_run
from tests.conftest import drive_csv, upload


def test_formats_are_what_an_upload_accepts(client, users, tmp_path):
    r = client.get("/api/v1/upload-formats", headers=users["operator"])
    assert r.status_code == 200, r.text
    formats = r.json()
    assert formats["run"] == sorted([*FILE_EXTENSIONS, ".zip"]) and ".kitti" not in formats["run"]
    assert ".jpg" in formats["images"] and ".zip" not in formats["images"]
    # Each offered run extension is taken by the upload: an Arrow IPC file named .ipc among them.
    csv_path = tmp_path / "drive.csv"
    csv_path.write_bytes(drive_csv(300))
    write_run(read_run(csv_path), tmp_path / "drive.arrow")
    ok = upload(client, users["client"], (tmp_path / "drive.arrow").read_bytes(), name="ipc", filename="drive.ipc")
    assert ok.status_code == 201, ok.text
    refused = upload(client, users["client"], drive_csv(300), name="kitti", filename="drive.kitti")
    assert refused.status_code == 422 and refused.json()["error"] == "invalid_run", refused.text
    assert "'.kitti'" in refused.text and ".ipc" in refused.text  # names the file's extension and the known ones


def test_formats_need_a_signed_in_user(client):
    assert client.get("/api/v1/upload-formats").status_code == 401
