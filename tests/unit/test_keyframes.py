"""Keyframe choice and the mapping between keyframes and full-rate rows."""

import numpy as np
import pytest

from posefix.core.keyframes import path_length_m, rows_of_keyframes, segment_of_rows, select_keyframes


def drive(n=1001, rate_hz=100.0, speed=lambda t: 10.0 + 0 * t):
    t = np.arange(n) / rate_hz
    v = speed(t)
    x = np.concatenate([[0.0], np.cumsum(v[:-1] / rate_hz)])
    return t, np.stack([x, np.zeros(n), np.zeros(n)], 1)


def test_every_second_keeps_first_and_last():
    t, p = drive(1051)
    idx = select_keyframes(t, p, every_s=1.0)
    assert idx.tolist() == list(range(0, 1051, 100)) + [1050]


def test_every_metre_follows_distance_not_time():
    # 5 m/s for 5 s then 20 m/s: keyframes every 10 m come every 2 s at first, then every 0.5 s
    t, p = drive(1001, speed=lambda t: np.where(t < 5.0, 5.0, 20.0))
    idx = select_keyframes(t, p, every_s=1.0, every_m=10.0)
    gaps = np.diff(t[idx])
    assert np.allclose(gaps[:2], 2.0, atol=0.011)
    assert np.allclose(gaps[-4:-1], 0.5, atol=0.011)
    assert np.allclose(np.diff(path_length_m(p)[idx])[:-1], 10.0, atol=0.21)


def test_images_and_edited_rows_become_keyframes():
    t, p = drive(501)
    images = np.zeros(501, dtype=bool)
    images[[37, 333]] = True
    idx = select_keyframes(t, p, every_s=1.0, image_mask=images, required_rows=[250, 499])
    for r in (0, 37, 100, 250, 333, 499, 500):
        assert r in idx


def test_bad_spacing_and_empty_runs_are_refused():
    t, p = drive(10)
    with pytest.raises(ValueError, match="every_s or every_m"):
        select_keyframes(t, p, every_s=0.0, every_m=0.0)
    with pytest.raises(ValueError, match="empty"):
        select_keyframes(np.zeros(0), np.zeros((0, 3)))


def test_rows_map_to_their_keyframe_segment():
    idx = np.array([0, 4, 9])
    assert segment_of_rows(idx, 12).tolist() == [0, 0, 0, 0, 1, 1, 1, 1, 1, 2, 2, 2]
    assert rows_of_keyframes(idx, 12, [1]).tolist() == [4, 5, 6, 7, 8]
    assert rows_of_keyframes(idx, 12, [2]).tolist() == [9, 10, 11]
