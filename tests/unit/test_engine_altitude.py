"""A 2-D move holds altitude geodetically; a 3-D move still sets it.

The solver works in a tangent plane at the run's first sample.  Read back as a plane height,
a pose moved d across that plane would rise about d^2 / (2R) (1.96 m at 5 km, 7.8 m at 10 km),
so these runs are level on the ellipsoid (constant height) and every path out of the engine
is checked: the committed solve (``solve_edits`` + ``lonlatalt``, the revision job), the live
preview, the full-rate propagation, and edits named by time (``correct``).
"""

import numpy as np
import pytest

from posefix.core import geodesy
from posefix.core import rotations as rot
from posefix.core.run import PoseRun
from posefix.engine import CorrectionConfig, Edit, Edits, correct, prepare
from posefix.io.edits import EditSet, Move

ORIGIN = geodesy.EnuOrigin(48.8566, 2.3522, 35.0)
HEIGHT_M = 35.0
FAR_CFG = CorrectionConfig.from_dict({"rules": {"max_move_m": 10_000.0}})


def level_run(length_m: float, step_m: float = 10.0, speed_mps: float = 10.0, seed: int = 0) -> PoseRun:
    """A gently curving drive at a constant ellipsoidal height (a level road, not a plane)."""
    rng = np.random.default_rng(seed)
    k = int(length_m / step_m) + 1
    yaw = 0.2 + np.cumsum(rng.normal(0.0, 0.01, k))
    step = np.stack([np.cos(yaw), np.sin(yaw)], 1) * step_m
    en = np.cumsum(step, axis=0) - step[0]
    lat, lon, alt = geodesy.en_height_to_geodetic(en, np.full(k, HEIGHT_M), ORIGIN)
    q = rot.exp_quat(np.stack([np.zeros(k), np.zeros(k), yaw], 1))
    return PoseRun(t_s=1000.0 + np.arange(k) * step_m / speed_mps, lat_deg=lat, lon_deg=lon, alt_m=alt,
                   q_body_to_enu_wxyz=q, source="level")


def moved(problem, k: int, d_east_m: float, d_north_m: float = 0.0, alt_m: float | None = None) -> Edit:
    """Keyframe k moved by (d_east, d_north) metres on the ground (at its own height)."""
    row = problem.keyframe_index[k]
    p = problem.p_enu_m[row]
    lat, lon, _ = geodesy.en_height_to_geodetic([[p[0] + d_east_m, p[1] + d_north_m]], problem.run.alt_m[row],
                                                 problem.origin)
    return Edit(k, float(lon[0]), float(lat[0]), alt_m)


@pytest.mark.parametrize("d_m", [5_000.0, 9_990.0])  # up to the 10 km limit
def test_a_long_2d_move_keeps_the_altitudes(d_m):
    problem = prepare(level_run(2_000.0), FAR_CFG)
    k = len(problem.keyframe_index) // 2
    edit = moved(problem, k, d_m)
    edits = Edits((edit,))
    sol = problem.solve_edits(edits)
    lon, lat, alt = problem.lonlatalt(sol)
    # the move took: the keyframe sits where it was put, d metres from where it was
    d = geodesy.horizontal_distance_m(lon[k], lat[k], edit.lon_deg, edit.lat_deg)
    assert d < 0.05, d
    assert geodesy.horizontal_distance_m(lon[k], lat[k], problem.run.lon_deg[problem.keyframe_index[k]],
                                         problem.run.lat_deg[problem.keyframe_index[k]]) > 0.99 * d_m
    assert np.abs(alt - HEIGHT_M).max() < 0.01, np.abs(alt - HEIGHT_M).max()
    # every sample, as exported
    out = problem.full_run(sol).run
    assert np.abs(out.alt_m - HEIGHT_M).max() < 0.01, np.abs(out.alt_m - HEIGHT_M).max()
    # the live drag of the same move, on the unedited run: no lift from the plane, only the up the
    # solve itself gives (at 5 km none; at 10 km the drag's tapered drift leaves the far keyframes'
    # location terms ~10 km off, the robust loss all but drops them, and the solve stops at its
    # ftol with that nearly free vertical 0.4 m off; at ftol 1e-14 it settles at 3e-7 m)
    pv = problem.preview([edit])
    _, _, alt_pv = problem.lonlatalt(pv.solution)
    assert not pv.refusals
    assert geodesy.horizontal_distance_m(pv.lon_deg[k], pv.lat_deg[k], edit.lon_deg, edit.lat_deg) < 0.05
    kfs = pv.solution.keyframes
    up = kfs.p_enu_m[:, 2] - problem.p_enu_m[kfs.index, 2]
    assert np.abs(alt_pv - HEIGHT_M - up).max() < 0.01, np.abs(alt_pv - HEIGHT_M - up).max()
    if d_m <= 5_000.0:
        assert np.abs(alt_pv - HEIGHT_M).max() < 0.01, np.abs(alt_pv - HEIGHT_M).max()


def test_a_long_run_corrected_by_small_moves_keeps_its_altitudes():
    run = level_run(20_000.0)
    problem = prepare(run)
    kf = problem.keyframe_index
    span = np.ptp(problem.p_enu_m[:, :2], axis=0)
    assert np.hypot(*span) > 15_000.0  # the plane's up leaves the ellipsoid by ~18 m at the far end
    picks = np.linspace(0, len(kf) - 1, 9).round().astype(int)
    rng = np.random.default_rng(3)
    edits = Edits(tuple(moved(problem, int(k), *rng.normal(0.0, 8.0, 2)) for k in picks))
    sol = problem.solve_edits(edits)
    lon, lat, alt = problem.lonlatalt(sol)
    assert np.abs(alt - HEIGHT_M).max() < 0.01, np.abs(alt - HEIGHT_M).max()
    # the moves took (the relative terms share each ~11 m move with the reported shape)
    miss = [geodesy.horizontal_distance_m(lon[e.index], lat[e.index], e.lon_deg, e.lat_deg) for e in edits.moves]
    asked = [geodesy.horizontal_distance_m(run.lon_deg[kf[e.index]], run.lat_deg[kf[e.index]], e.lon_deg, e.lat_deg)
             for e in edits.moves]
    assert np.sqrt(np.mean(np.square(miss))) < 0.2 * np.sqrt(np.mean(np.square(asked))), (miss, asked)
    out = problem.full_run(sol).run
    assert np.abs(out.alt_m - HEIGHT_M).max() < 0.01, np.abs(out.alt_m - HEIGHT_M).max()
    # the same moves named by time through the file path (``posefix correct``)
    by_time = EditSet(moves=[Move(float(run.t_s[kf[e.index]]), e.lat_deg, e.lon_deg, None) for e in edits.moves])
    out = correct(run, by_time).run
    assert np.abs(out.alt_m - HEIGHT_M).max() < 0.01, np.abs(out.alt_m - HEIGHT_M).max()


@pytest.mark.parametrize("d_m", [0.0, 5_000.0, 9_990.0])
def test_a_3d_move_still_sets_the_altitude(d_m):
    problem = prepare(level_run(2_000.0), FAR_CFG)
    k = len(problem.keyframe_index) // 2
    edit = moved(problem, k, d_m, alt_m=HEIGHT_M + 4.0)
    lon, lat, alt = problem.lonlatalt(problem.solve_edits(Edits((edit,))))
    assert geodesy.horizontal_distance_m(lon[k], lat[k], edit.lon_deg, edit.lat_deg) < 0.05
    # in place the edit's 4 m is weighed against the reported pose (no GNSS: the location term
    # is the pose itself); moved far, the robust loss all but drops that pull and the edit wins
    assert alt[k] - HEIGHT_M > (3.0 if d_m == 0.0 else 3.99), alt[k]
    # no keyframe leaves the heights the run and the edit span (the plane would add ~2 m at 5 km)
    assert alt.min() > HEIGHT_M - 0.01 and alt.max() < HEIGHT_M + 4.01, (alt.min(), alt.max())


def test_en_height_to_geodetic_inverts_the_plane_at_a_stated_height():
    rng = np.random.default_rng(0)
    en = rng.uniform(-600e3, 600e3, (200, 2))
    h = rng.uniform(-50.0, 3000.0, 200)
    lat, lon, alt = geodesy.en_height_to_geodetic(en, h, ORIGIN)
    p = geodesy.geodetic_to_enu(lat, lon, h, ORIGIN)
    assert np.abs(p[:, :2] - en).max() < 1e-6
    assert np.array_equal(alt, h)
    # the plane's own up at those points is below the ellipsoid by ~d^2/(2R)
    d2 = (en ** 2).sum(1)
    assert np.allclose(h - ORIGIN.alt_m - p[:, 2], d2 / (2 * geodesy.WGS84_A_M), rtol=0.02)


def test_the_altitude_guard_still_refuses_a_height_the_input_does_not_allow():
    """With the plane's lift gone the guard only sees what the solve's up gives: a solution
    whose keyframes sit above the run's heights plus the margin is refused, naming the rule;
    the same heights are allowed when a 3-D edit asked for them."""
    import dataclasses

    from posefix.engine import EditRefusedError
    from posefix.engine.altitude import REASON, vertical_margin_m

    problem = prepare(level_run(2_000.0))
    sol = problem.solve_edits(Edits())
    lift = vertical_margin_m(problem.cfg) + 1.0
    kfs = sol.keyframes
    high = dataclasses.replace(sol, keyframes=dataclasses.replace(kfs, p_enu_m=kfs.p_enu_m + [0.0, 0.0, lift]))
    assert np.abs(problem.lonlatalt(high)[2] - (HEIGHT_M + lift)).max() < 1e-6
    with pytest.raises(EditRefusedError) as refused:
        problem.checked_altitudes(high, [None])
    assert [r.reason for r in refused.value.refusals] == [REASON]
    assert problem.checked_altitudes(high, [HEIGHT_M + lift]) is high
