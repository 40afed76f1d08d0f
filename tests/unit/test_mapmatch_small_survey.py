"""A survey too small to calibrate f3 must not make the tracker confidently wrong.

data/ (a fresh clone) holds three walks a floor: a leave-one-out survey of one walk cannot
measure f3's error scale nor its walk-long correlation, so f3 is left out and the tracker
says what motion alone supports.
"""

from pathlib import Path

import numpy as np
import pytest

from posefix.mapmatch import build_model, read_walk, track_walk
from posefix.mapmatch.fingerprints import MIN_SURVEY_WALKS_F3, build_fingerprints, load_fingerprints, save_fingerprints

FLOOR = Path(__file__).resolve().parents[2] / "data" / "indoor-site1-F1"


@pytest.fixture(scope="module")
def floor():
    walks = [read_walk(p) for p in sorted((FLOOR / "walks").glob("*.txt"))]
    return build_model(FLOOR, cell_m=0.8), walks


def waypoint_errors(res, walk) -> tuple[np.ndarray, np.ndarray]:
    """(error m, converged) at each waypoint, from the row nearest it in time."""
    wp = walk.waypoints
    row = np.abs(res.t_ms[None, :] - wp[:, 0][:, None]).argmin(axis=1)
    return np.linalg.norm(res.p_xy_m[row] - wp[:, 1:3], axis=1), res.converged[row]


def test_one_walk_survey_leaves_f3_out_and_never_converges_far_off(floor, tmp_path):
    model, walks = floor
    for i, survey in enumerate(walks):
        fp = build_fingerprints([survey])
        assert not fp.f3_calibrated and "survey walk" in fp.f3_note
        save_fingerprints(fp, tmp_path / "fp.npz")
        back = load_fingerprints(tmp_path / "fp.npz")
        assert not back.f3_calibrated and back.predict_walk(walks[0]) == []
        for j, w in enumerate(walks):
            if j == i:
                continue
            res = track_walk(model, w, start_xy_m=None, fingerprints=back)
            err, conv = waypoint_errors(res, w)
            assert not np.any(conv & (err > 10.0)), (i, j, err[conv])


def test_f3_needs_enough_survey_walks(floor):
    _, walks = floor
    assert MIN_SURVEY_WALKS_F3 >= 3
    fp = build_fingerprints(walks[:2])
    assert not fp.f3_calibrated and "2 survey walks" in fp.f3_note
    fp = build_fingerprints(walks, calibrate=False)
    assert not fp.f3_calibrated
