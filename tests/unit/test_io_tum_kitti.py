"""TUM trajectories (local frame + origin) and KITTI raw OXTS folders."""

from __future__ import annotations

import numpy as np
import pytest

from posefix.core.geodesy import geodetic_to_enu
from posefix.core.rotations import quat_to_matrix
from posefix.io import RunFormatError, read_run, write_run
from posefix.io.kitti import write_kitti_oxts

from .io_helpers import small_run, yaw_quat

ORIGIN = (60.17, 24.94, 20.0)


def test_tum_round_trip_and_frame(tmp_path):
    run = small_run(gnss=False, images=False, extra=False)
    write_run(run, tmp_path / "r.tum", origin=ORIGIN)
    vals = np.loadtxt(tmp_path / "r.tum")
    # positions in the file are ENU at the origin
    assert np.allclose(vals[:, 1:4], geodetic_to_enu(run.lat_deg, run.lon_deg, run.alt_m, ORIGIN), atol=1e-9)
    back = read_run(tmp_path / "r.tum", origin=ORIGIN)
    assert np.abs(back.lat_deg - run.lat_deg).max() < 1e-12
    assert np.abs(back.alt_m - run.alt_m).max() < 1e-6
    assert np.abs(back.q_body_to_enu_wxyz - run.q_body_to_enu_wxyz).max() < 1e-12


def test_tum_100_km_away_re_expresses_orientation_locally(tmp_path):
    # A pose 100 km east of the origin heading "east" in the origin frame is rotated by
    # the meridian convergence (about Δλ·sin φ = 1.56 deg at 60 N) in its own local frame.
    p = tmp_path / "far.tum"
    p.write_text("# t x y z qx qy qz qw\n0 100000 0 0 0 0 0 1\n1 100010 0 0 0 0 0 1\n")
    run = read_run(p, origin=ORIGIN)
    yaw = np.degrees(2 * np.arctan2(run.q_body_to_enu_wxyz[:, 3], run.q_body_to_enu_wxyz[:, 0]))
    convergence = (run.lon_deg[0] - ORIGIN[1]) * np.sin(np.radians(ORIGIN[0]))
    assert abs(abs(yaw[0]) - convergence) < 0.05
    # and the forward axis still follows the track in the local frame
    d = geodetic_to_enu(run.lat_deg[1:], run.lon_deg[1:], run.alt_m[1:], (run.lat_deg[0], run.lon_deg[0], run.alt_m[0]))[0]
    fwd = quat_to_matrix(run.q_body_to_enu_wxyz[0])[:, 0]
    assert np.dot(fwd, d) / np.linalg.norm(d) > 0.9999999


@pytest.mark.parametrize("text,origin,line,field,fragment", [
    ("0 0 0 0 0 0 0 1\n", None, None, "origin", "origin"),
    ("# c\n0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0\n", ORIGIN, 3, None, "expected 8 values"),
    ("0 0 0 0 0 0 0 1\n1 1 zz 0 0 0 0 1\n", ORIGIN, 2, "ty", "not a number"),
    ("0 0 0 0 0 0 0 1\n\n1 1 0 0 0 0 0 0\n", ORIGIN, 3, "qx,qy,qz,qw", "zero quaternion"),
    ("0 0 0 0 0 0 0 1\n0 1 0 0 0 0 0 1\n", ORIGIN, 2, "timestamp", "not strictly increasing"),
    ("# only a comment\n", ORIGIN, None, None, "empty"),
])
def test_tum_bad_input(tmp_path, text, origin, line, field, fragment):
    p = tmp_path / "bad.tum"
    p.write_text(text)
    with pytest.raises(RunFormatError) as info:
        read_run(p, origin=origin)
    assert (info.value.line, info.value.field) == (line, field)
    assert fragment in info.value.message


def test_kitti_oxts_folder_reads_pose_and_time(tmp_path):
    run = small_run(n=12, gnss=False, images=False, extra=False)
    drive = tmp_path / "2011_09_26_drive_0001_sync"
    write_kitti_oxts(run, drive / "oxts")
    first = (drive / "oxts" / "timestamps.txt").read_text().splitlines()[0]
    assert first.startswith("2023-11-14 22:13:20.000000000")
    back = read_run(drive)  # the drive folder is recognised by its layout
    assert back.n == 12
    assert np.abs(back.t_s - run.t_s).max() < 1e-6
    assert np.abs(back.lat_deg - run.lat_deg).max() < 1e-12
    assert np.abs(back.q_body_to_enu_wxyz - run.q_body_to_enu_wxyz).max() < 1e-12
    assert set(back.extra) >= {"vf", "vl", "wu"}


def test_kitti_yaw_convention_is_from_east_counter_clockwise(tmp_path):
    run = small_run(n=3, gnss=False, images=False, extra=False)
    from dataclasses import replace

    run = replace(run, q_body_to_enu_wxyz=yaw_quat(np.full(3, np.radians(90.0))))
    write_kitti_oxts(run, tmp_path / "oxts")
    vals = np.loadtxt(tmp_path / "oxts" / "data" / "0000000000.txt")
    assert vals[5] == pytest.approx(np.pi / 2)  # yaw column: heading north


def test_kitti_bad_value_names_the_packet_file(tmp_path):
    run = small_run(n=3, gnss=False, images=False, extra=False)
    write_kitti_oxts(run, tmp_path / "oxts")
    bad = tmp_path / "oxts" / "data" / "0000000001.txt"
    parts = bad.read_text().split()
    parts[0] = "north"
    bad.write_text(" ".join(parts))
    with pytest.raises(RunFormatError) as info:
        read_run(tmp_path / "oxts")
    assert (info.value.file, info.value.line, info.value.field) == (str(bad), 1, "lat")
    parts[0] = "123.0"  # latitude out of range
    bad.write_text(" ".join(parts))
    with pytest.raises(RunFormatError, match="outside") as info:
        read_run(tmp_path / "oxts")
    assert info.value.file == str(bad)


def test_kitti_count_mismatch(tmp_path):
    run = small_run(n=3, gnss=False, images=False, extra=False)
    write_kitti_oxts(run, tmp_path / "oxts")
    (tmp_path / "oxts" / "data" / "0000000002.txt").unlink()
    with pytest.raises(RunFormatError, match="3 timestamps but 2 data files"):
        read_run(tmp_path / "oxts")
