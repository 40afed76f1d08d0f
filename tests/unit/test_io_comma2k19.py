"""The real comma2k19 drive: pose from global_pose, raw u-blox GNSS beside it."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from posefix.core.geodesy import geodetic_to_ecef, geodetic_to_enu, rotation_ecef_to_enu
from posefix.core.rotations import quat_to_matrix
from posefix.io import RunFormatError, read_run, write_run

from .io_helpers import comma2k19_segment


@pytest.fixture(scope="module")
def run():
    return read_run(comma2k19_segment())


def test_reads_the_fused_pose_and_gnss(run):
    assert run.n == 1200 and run.has_gnss and not run.orientation_derived
    assert 37.72 < run.lat_deg.min() and run.lat_deg.max() < 37.731
    assert np.abs(run.lon_deg + 122.472).max() < 0.002
    assert np.all(np.diff(run.t_s) > 0)
    # README: the u-blox fix is ~1.45 m from the fused pose on average (open sky)
    o = (run.lat_deg[0], run.lon_deg[0], run.alt_m[0])
    d = geodetic_to_enu(run.gnss_lat_deg, run.gnss_lon_deg, run.gnss_alt_m, o) - geodetic_to_enu(run.lat_deg, run.lon_deg, run.alt_m, o)
    horiz = np.hypot(d[:, 0], d[:, 1])
    assert 0.5 < np.nanmean(horiz) < 3.0
    # the speed column agrees with the distance travelled (about 1 km in 60 s)
    step = np.linalg.norm(np.diff(geodetic_to_ecef(run.lat_deg, run.lon_deg, run.alt_m), axis=0), axis=1)
    assert abs(step.sum() / (run.t_s[-1] - run.t_s[0]) / run.extra["speed_mps"].mean() - 1) < 0.03


def test_body_axes_forward_left_up(run):
    r = quat_to_matrix(run.q_body_to_enu_wxyz)
    p = geodetic_to_ecef(run.lat_deg, run.lon_deg, run.alt_m)
    v_enu = np.einsum("nij,nj->ni", rotation_ecef_to_enu(run.lat_deg, run.lon_deg)[:-1], np.diff(p, axis=0))
    v_dir = v_enu / np.linalg.norm(v_enu, axis=1, keepdims=True)
    fwd = r[:-1, :, 0]
    assert np.mean(np.einsum("ni,ni->n", fwd, v_dir)) > 0.99  # x follows the direction of travel
    assert np.all(r[:, 2, 2] > 0.95)  # z is up
    left = np.cross([0, 0, 1.0], fwd)  # y points left of forward
    assert np.mean(np.einsum("ni,ni->n", r[:-1, :, 1], left / np.linalg.norm(left, axis=1, keepdims=True))) > 0.99


def test_converts_to_csv_and_back(run, tmp_path):
    write_run(run, tmp_path / "c.csv")
    back = read_run(tmp_path / "c.csv")
    assert np.array_equal(back.t_s, run.t_s)
    assert np.abs(back.gnss_lat_deg - run.gnss_lat_deg).max() < 1e-10
    assert "speed_mps" in back.extra


def test_broken_segment_is_refused(tmp_path):
    seg = tmp_path / "segment"
    shutil.copytree(comma2k19_segment() / "segment" / "global_pose", seg / "global_pose")
    (seg / "global_pose" / "frame_positions").write_bytes(b"not numpy")
    with pytest.raises(RunFormatError, match="not a numpy array file") as info:
        read_run(tmp_path)
    assert info.value.file.endswith("frame_positions")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(RunFormatError, match="neither a comma2k19 segment nor a KITTI"):
        read_run(empty)
