"""Keyframes: the samples the optimiser and the editor work on.

A run of n full-rate samples is reduced to k keyframes: one every S seconds, or one every
D metres travelled, plus every sample carrying an image (optional) and every sample named
by an edit (always).  The first and last samples are always keyframes so the correction
covers the whole run.  ``index`` (k,) holds sorted row numbers into the run; row r belongs
to keyframe segment ``searchsorted(index, r, 'right') - 1`` (the keyframe at or before it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class KeyframeSet:
    """Keyframes of a run, reported and (after a solve) corrected.

    index : (k,) int rows into the run.    t_s : (k,) seconds.
    p_enu_m, q_wxyz : (k, 3), (k, 4) corrected poses in the run's local frame (ENU anchored at
        the first sample; the quaternion rotates body vectors into that frame).
    reported_p_enu_m, reported_q_wxyz : the reported poses at the same rows.
    edited, deleted : (k,) bool.
    """

    index: np.ndarray
    t_s: np.ndarray
    p_enu_m: np.ndarray
    q_wxyz: np.ndarray
    reported_p_enu_m: np.ndarray
    reported_q_wxyz: np.ndarray
    edited: np.ndarray
    deleted: np.ndarray

    def __len__(self) -> int:
        return len(self.index)

    @property
    def correction_m(self) -> np.ndarray:
        """(k,) horizontal length of each keyframe's correction, metres."""
        return np.hypot(*(self.p_enu_m[:, :2] - self.reported_p_enu_m[:, :2]).T)


def path_length_m(p_enu_m: np.ndarray) -> np.ndarray:
    """(n,) cumulative 3-D distance travelled along the samples, metres, starting at 0."""
    step = np.linalg.norm(np.diff(p_enu_m, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(step)])


def select_keyframes(
    t_s: np.ndarray,
    p_enu_m: np.ndarray,
    every_s: float = 1.0,
    every_m: float = 0.0,
    image_mask: np.ndarray | None = None,
    required_rows: np.ndarray | list[int] = (),
) -> np.ndarray:
    """Rows chosen as keyframes, (k,) sorted unique ints.

    Parameters
    ----------
    t_s : ndarray, shape (n,)      strictly increasing sample times, seconds.
    p_enu_m : ndarray, shape (n, 3) positions, metres (for ``every_m``).
    every_s : float   spacing in seconds (used when every_m is 0).
    every_m : float   spacing in metres travelled (wins when > 0).
    image_mask : (n,) bool, optional   samples with images become keyframes.
    required_rows : rows that must be keyframes (edited samples).
    """
    t_s = np.asarray(t_s, dtype=float)
    n = len(t_s)
    if n == 0:
        raise ValueError("cannot choose keyframes of an empty run")
    if every_m > 0:
        along_m = path_length_m(np.asarray(p_enu_m, dtype=float))
        rows = _first_rows_reaching(along_m, every_m)
    elif every_s > 0:
        rows = _first_rows_reaching(t_s - t_s[0], every_s)
    else:
        raise ValueError("keyframe spacing: every_s or every_m must be > 0")
    parts = [rows, [0, n - 1], np.asarray(required_rows, dtype=np.int64)]
    if image_mask is not None:
        parts.append(np.flatnonzero(np.asarray(image_mask, dtype=bool)))
    index = np.unique(np.concatenate([np.asarray(p, dtype=np.int64) for p in parts]))
    if index[0] < 0 or index[-1] >= n:
        raise ValueError(f"keyframe rows must lie in 0..{n - 1}")
    return index


def _first_rows_reaching(coordinate: np.ndarray, spacing: float) -> np.ndarray:
    """First row at or past each multiple of ``spacing`` of a non-decreasing coordinate."""
    marks = np.arange(0.0, coordinate[-1] + spacing * 0.5, spacing)
    rows = np.searchsorted(coordinate, marks - 1e-9 * spacing, side="left")
    return np.unique(rows[rows < len(coordinate)])


def segment_of_rows(index: np.ndarray, n_rows: int) -> np.ndarray:
    """(n,) keyframe number owning each row: the last keyframe at or before it."""
    return np.searchsorted(index, np.arange(n_rows), side="right") - 1


def rows_of_keyframes(index: np.ndarray, n_rows: int, keyframes: np.ndarray) -> np.ndarray:
    """All rows owned by the given keyframe numbers (from each up to the next keyframe)."""
    ends = np.append(index[1:], n_rows)
    keyframes = np.asarray(keyframes, dtype=np.int64)
    if len(keyframes) == 0:
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([np.arange(index[k], ends[k]) for k in keyframes])
