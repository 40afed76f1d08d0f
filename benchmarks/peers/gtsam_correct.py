"""GTSAM correction script: keyframes every second (and at each edit), a Pose3 per keyframe,
GPSFactor on the GNSS fix (raw columns when present, else the reported position) with a
Cauchy loss, BetweenFactorPose3 from the reported relative motion, edits as tight GPS
factors; Levenberg-Marquardt; every sample moved by its keyframes' correction interpolated
in time (translation linearly, rotation on its rotation vector)."""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import gtsam  # noqa: E402
import numpy as np  # noqa: E402

from _common import Frame, col, edit_indices, read_edits, read_table, write_table  # noqa: E402

GNSS_SIGMA_M = (3.0, 3.0, 5.0)
EDIT_SIGMA_M = (0.5, 0.5, 1e6)
BETWEEN_SIGMAS = (0.01, 0.01, 0.01, 0.1, 0.1, 0.1)  # rad, rad, rad, m, m, m per keyframe step


def quat_to_matrices(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


def rotvec_to_quat(v: np.ndarray) -> np.ndarray:
    angle = np.linalg.norm(v, axis=1)
    s = np.where(angle > 1e-12, np.sin(angle / 2) / np.maximum(angle, 1e-12), 0.5)
    return np.column_stack([np.cos(angle / 2), v * s[:, None]])


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.column_stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])


def main(src: str, edits_path: str, out: str) -> None:
    table = read_table(src)
    t, lat, lon, alt = (col(table, c) for c in ("t", "lat", "lon", "alt"))
    q = np.column_stack([col(table, c) for c in ("qw", "qx", "qy", "qz")])
    frame = Frame(lat[0], lon[0], alt[0])
    p = frame.enu(lat, lon, alt)
    names = set(table.column_names)
    if {"gnss_lat", "gnss_lon", "gnss_alt"} <= names:
        g = frame.enu(col(table, "gnss_lat"), col(table, "gnss_lon"), col(table, "gnss_alt"))
        g = np.where(np.isnan(g), p, g)
    else:
        g = p
    edits = read_edits(edits_path)
    e_idx = edit_indices(t, edits) if edits else np.zeros(0, int)
    kf = np.unique(np.concatenate([np.searchsorted(t, np.arange(t[0], t[-1], 1.0)), [len(t) - 1], e_idx]))
    R = quat_to_matrices(q[kf])

    X = gtsam.symbol_shorthand.X
    graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
    poses = [gtsam.Pose3(gtsam.Rot3(R[i]), p[k]) for i, k in enumerate(kf)]
    gnss_model = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(1.0),
                                                gtsam.noiseModel.Diagonal.Sigmas(np.array(GNSS_SIGMA_M)))
    between = gtsam.noiseModel.Diagonal.Sigmas(np.array(BETWEEN_SIGMAS))
    for i, k in enumerate(kf):
        initial.insert(X(i), poses[i])
        graph.add(gtsam.GPSFactor(X(i), g[k], gnss_model))
        if i:
            graph.add(gtsam.BetweenFactorPose3(X(i - 1), X(i), poses[i - 1].between(poses[i]), between))
    edit_model = gtsam.noiseModel.Diagonal.Sigmas(np.array(EDIT_SIGMA_M))
    where = {int(k): i for i, k in enumerate(kf)}
    for (_t, e_lat, e_lon), k in zip(edits, e_idx):
        target = frame.enu([e_lat], [e_lon], [alt[k]])[0]
        graph.add(gtsam.GPSFactor(X(where[int(k)]), target, edit_model))
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams()).optimize()

    dp = np.empty((len(kf), 3))
    dr = np.empty((len(kf), 3))
    for i, k in enumerate(kf):
        pose = result.atPose3(X(i))
        dp[i] = pose.translation() - p[k]
        dr[i] = gtsam.Rot3.Logmap(pose.rotation().compose(poses[i].rotation().inverse()))
    tk = t[kf]
    p_new = p + np.column_stack([np.interp(t, tk, dp[:, j]) for j in range(3)])
    dq = rotvec_to_quat(np.column_stack([np.interp(t, tk, dr[:, j]) for j in range(3)]))
    write_table(table, *frame.geodetic(p_new), out, q=quat_mul(dq, q))


if __name__ == "__main__":
    main(*sys.argv[1:4])
