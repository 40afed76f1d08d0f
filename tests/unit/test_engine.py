"""The engine's Python API on small simulated and hand-made runs."""

import dataclasses

import numpy as np
import pytest

from posefix.core import geodesy
from posefix.core.config import ConfigError
from posefix.core.run import PoseRun
from posefix.core.simulate import simulate
from posefix.engine import CorrectionConfig, EditRefusedError, Edit, correct, prepare
from posefix.io.edits import EditSet, Move
from tests.unit.engine_helpers import curvy_drive

ORIGIN = (48.8566, 2.3522, 35.0)


def hand_run(k=241, rate_hz=10.0, seed=0, gnss_offset=None, gnss_outliers=None):
    """A 10 Hz drive whose reported pose is the truth (so the local shape is exact)."""
    t = np.arange(k) / rate_hz
    p, q = curvy_drive(k, seed, step_m=10.0 / rate_hz)
    lat, lon, alt = geodesy.enu_to_geodetic(p, ORIGIN)
    gnss = {}
    if gnss_offset is not None or gnss_outliers is not None:
        g = p.copy()
        if gnss_offset is not None:
            g += gnss_offset
        if gnss_outliers is not None:
            g[gnss_outliers] += [50.0, -50.0, 0.0]
        glat, glon, galt = geodesy.enu_to_geodetic(g, ORIGIN)
        gnss = dict(gnss_lat_deg=glat, gnss_lon_deg=glon, gnss_alt_m=galt)
    extra = {"speed_mps": np.full(k, 10.0), "label": np.array([f"s{i}" for i in range(k)])}
    run = PoseRun(t_s=1000.0 + t, lat_deg=lat, lon_deg=lon, alt_m=alt, q_body_to_enu_wxyz=q, extra=extra,
                  source="hand", **gnss)
    return run, p


def enu(run, origin=ORIGIN):
    return geodesy.geodetic_to_enu(run.lat_deg, run.lon_deg, run.alt_m, origin)


def move(run, row, d_east_m=0.0, d_north_m=0.0):
    p = enu(run)[row] + [d_east_m, d_north_m, 0.0]
    lat, lon, _ = geodesy.enu_to_geodetic(p[None], ORIGIN)
    return Move(float(run.t_s[row]), float(lat[0]), float(lon[0]), None)


def test_no_edits_leave_the_run_near_its_reported_poses():
    run, p = hand_run()
    out = correct(run, EditSet())
    assert out.solver.status == "converged"
    assert np.max(np.abs(enu(out.run) - p)) < 1e-3
    assert np.allclose(out.run.t_s, run.t_s) and out.run.n == run.n


def test_an_edit_pulls_its_neighbours_and_the_pull_decays_with_distance():
    run, p = hand_run(k=8001)  # 800 s, 801 keyframes
    row = 4000
    out = correct(run, EditSet(moves=[move(run, row, d_east_m=6.0)]))
    shift = enu(out.run)[:, 0] - p[:, 0]
    assert 5.0 < shift[row] < 6.2
    pulls = [shift[row + d] for d in (0, 50, 500, 1500, 3900)]
    assert all(a > b for a, b in zip(pulls, pulls[1:])), pulls
    assert pulls[1] > 0.8 * pulls[0]  # the neighbours come along
    assert pulls[-1] < 0.5 * pulls[0]  # far away the pull has faded
    left = [shift[row - d] for d in (50, 500, 1500, 3900)]
    assert all(a > b for a, b in zip(left, left[1:]))


def test_fifty_metre_outliers_do_not_bend_the_run():
    bad = np.r_[300:330, 900:920]  # 3 s and 2 s bursts of 50 m outliers
    run, p = hand_run(k=1201, gnss_offset=np.zeros(3), gnss_outliers=bad)
    out = correct(run, EditSet())
    err = np.hypot(*(enu(out.run)[:, :2] - p[:, :2]).T)
    assert np.max(err) < 1.0
    plain = correct(run, EditSet(), CorrectionConfig.from_dict({"location": {"loss": "none"}}))
    assert np.max(np.hypot(*(enu(plain.run)[:, :2] - p[:, :2]).T)) > 3.0 * np.max(err)


def test_edits_beat_a_biased_gnss_track():
    run, p = hand_run(k=3001, gnss_offset=np.array([12.0, -9.0, 0.0]))
    # the reported pose follows the biased GNSS too: that is what edits are for
    g = enu(run)
    lat, lon, alt = geodesy.enu_to_geodetic(p + [12.0, -9.0, 0.0], ORIGIN)
    biased = run.with_poses(lat, lon, alt)
    truth_moves = []
    for row in range(150, 3001, 1000):
        la, lo, _ = geodesy.enu_to_geodetic(p[row][None], ORIGIN)
        truth_moves.append(Move(float(run.t_s[row]), float(la[0]), float(lo[0]), None))
    out = correct(biased, EditSet(moves=truth_moves))  # the model the held-out edits choose
    assert np.sqrt(np.mean(np.hypot(*(enu(out.run)[:, :2] - p[:, :2]).T) ** 2)) < 0.5
    gnss = CorrectionConfig.from_dict({"calibration": {"model": "gnss"}})
    out = correct(biased, EditSet(moves=truth_moves), gnss)  # the location term with the drift model
    err = np.hypot(*(enu(out.run)[:, :2] - p[:, :2]).T)
    assert np.sqrt(np.mean(err**2)) < 0.5, np.sqrt(np.mean(err**2))
    assert out.drift.detected and np.hypot(*out.drift.offset_enu_m[:2]) > 13.0
    no_drift = correct(biased, EditSet(moves=truth_moves),
                       CorrectionConfig.from_dict({"drift": {"enabled": False}, "calibration": {"model": "gnss"}}))
    err_nd = np.hypot(*(enu(no_drift.run)[:, :2] - p[:, :2]).T)
    assert np.sqrt(np.mean(err_nd**2)) > 2.0 * np.sqrt(np.mean(err**2))
    assert g.shape == p.shape


def test_output_keeps_order_columns_and_deletes_rows_of_deleted_keyframes():
    run, _ = hand_run(k=301)
    edits = EditSet(moves=[move(run, 150, 2.0)], deleted=[float(run.t_s[100])])
    out = correct(run, edits)
    assert 100 not in out.kept_rows and 99 in out.kept_rows and 110 in out.kept_rows
    assert out.run.n == len(out.kept_rows) == run.n - 10  # keyframe 10 owned rows 100..109
    assert np.all(out.run.extra["label"] == run.extra["label"][out.kept_rows])
    assert np.allclose(out.run.t_s, run.t_s[out.kept_rows])
    flagged_cfg = CorrectionConfig.from_dict({"rules": {"deleted": "flag"}})
    flagged = correct(run, edits, flagged_cfg)
    assert flagged.run.n == run.n and flagged.run.extra["flagged"][100:110].tolist() == [1] * 10
    assert flagged.run.extra["flagged"].sum() == 10


def test_gnss_columns_feed_the_location_term_and_pose_columns_the_shape():
    run, p = hand_run(k=601, gnss_offset=np.array([0.0, 0.0, 0.0]))
    rng = np.random.default_rng(0)
    lat, lon, alt = geodesy.enu_to_geodetic(p + [4.0, 0.0, 0.0] + 0 * rng.normal(size=p.shape), ORIGIN)
    shifted_pose = run.with_poses(lat, lon, alt)  # pose 4 m east of the (unbiased) GNSS
    out = correct(shifted_pose, EditSet())
    # with no edits the weak GNSS terms pull the rigid shape back onto the GNSS
    assert np.max(np.abs(enu(out.run)[:, 0] - p[:, 0])) < 0.5


def test_rules_refuse_moves_with_reasons():
    run, _ = hand_run(k=301)
    cfg = CorrectionConfig.from_dict({"rules": {"max_move_m": 3.0}})
    with pytest.raises(EditRefusedError) as info:
        correct(run, EditSet(moves=[move(run, 150, 5.0)]), cfg)
    assert info.value.refusals[0].reason == "too_far"


def test_preview_answers_at_keyframe_level_with_warm_start():
    run, p = hand_run(k=1201)
    problem = prepare(run)
    kf = problem.keyframe_index
    lat, lon, _ = geodesy.enu_to_geodetic(p[kf[60]][None] + [3.0, 0.0, 0.0], ORIGIN)
    first = problem.preview([Edit(60, float(lon[0]), float(lat[0]))])
    assert first.refusals == [] and len(first.lon_deg) == len(kf)
    lat2, lon2, _ = geodesy.enu_to_geodetic(p[kf[60]][None] + [3.2, 0.1, 0.0], ORIGIN)
    second = problem.preview([Edit(60, float(lon2[0]), float(lat2[0])), Edit(999, 0.0, 0.0)],
                             warm_start=first.solution)
    assert [r.reason for r in second.refusals] == ["out_of_range"]
    cold = problem.preview([Edit(60, float(lon2[0]), float(lat2[0]))])
    assert second.solution.solver.iterations <= cold.solution.solver.iterations
    assert abs(second.solution.solver.cost - cold.solution.solver.cost) <= 1e-6 * cold.solution.solver.cost


def test_scipy_reference_path_gives_the_same_correction():
    sim = simulate(duration_s=120.0, rate_hz=5.0, edit_every_s=40.0, seed=3, regime="mixed")
    edits = EditSet(moves=[Move(e.t_s, e.lat_deg, e.lon_deg, None) for e in sim.edits])
    # one model: with three edits the held-out choice may tip either way on the solvers' round-off
    fast = correct(sim.run, edits, CorrectionConfig.from_dict({"calibration": {"model": "gnss"}}))
    ref = correct(sim.run, edits, CorrectionConfig.from_dict({"solver": {"method": "scipy"},
                                                              "calibration": {"model": "gnss"}}))
    assert abs(fast.solver.cost - ref.solver.cost) <= 1e-6 * ref.solver.cost
    assert np.max(np.abs(fast.keyframes.p_enu_m - ref.keyframes.p_enu_m)) < 1e-3


def test_config_file_overrides_defaults_and_refuses_bad_values(tmp_path):
    good = tmp_path / "c.toml"
    good.write_text("[location]\nsigma_h_m = 5.0\nloss = 'huber'\n[keyframes]\nevery_m = 20\n")
    cfg = CorrectionConfig.load(good)
    assert cfg.location.sigma_h_m == 5.0 and cfg.location.loss == "huber" and cfg.keyframes.every_m == 20.0
    assert cfg.user == CorrectionConfig().user
    for text, field in (
        ("[location]\nloss = 'tukey'\n", "location.loss"),
        ("[location]\nsigma_h_m = -1\n", "location.sigma_h_m"),
        ("[solver]\nmax_iterations = 'many'\n", "solver.max_iterations"),
        ("[nonsense]\nx = 1\n", "nonsense"),
        ("[user]\nsigma_q = 1\n", "user.sigma_q"),
    ):
        bad = tmp_path / "bad.toml"
        bad.write_text(text)
        with pytest.raises(ConfigError) as info:
            CorrectionConfig.load(bad)
        assert field in str(info.value) and "bad.toml" in str(info.value) and ":" in str(info.value)


def test_default_config_file_equals_the_built_in_defaults():
    from posefix.core.config import DEFAULT_CONFIG_PATH

    assert CorrectionConfig.load(DEFAULT_CONFIG_PATH) == CorrectionConfig()


def test_time_propagation_and_metre_keyframes_are_honoured():
    run, p = hand_run(k=601)
    cfg = CorrectionConfig.from_dict({"propagation": {"mode": "time"}, "keyframes": {"every_m": 25.0}})
    out = correct(run, EditSet(moves=[move(run, 300, 2.0)]), cfg)
    gaps = np.diff(prepare(run, cfg).along_m[out.keyframes.index])
    assert np.median(gaps) == pytest.approx(25.0, abs=1.0)
    assert out.keyframes.edited.sum() == 1 and 300 in out.keyframes.index
    assert dataclasses.asdict(out.solver)["status"] == "converged"


def test_a_correction_warm_starts_the_next_solve():
    run, _ = hand_run(k=1201)
    problem = prepare(run)
    first = problem.full_run(problem.solve(EditSet(moves=[move(run, 300, 3.0)])))
    # (edits the reported shape can join: two that it cannot change the problem itself - the
    # relative terms between them loosen and the fixes there drop out - so the first answer is no
    # better a start than the reported poses)
    both = EditSet(moves=[move(run, 300, 3.0), move(run, 900, 2.0)])
    warm = problem.solve(both, warm_start=first)
    cold = problem.solve(both)
    assert warm.solver.iterations <= cold.solver.iterations
    assert abs(warm.solver.cost - cold.solver.cost) <= 1e-6 * cold.solver.cost


def test_sideways_motion_a_vehicle_cannot_make_is_measured():
    from posefix.core import rotations as rot
    from posefix.engine import implausible_motion_m

    k = 6
    p = np.stack([10.0 * np.arange(k), np.zeros(k), np.zeros(k)], 1)
    p[3:, 1] += 4.0  # the track jumps 4 m sideways between keyframes 2 and 3 (1 s apart)
    q = np.tile(rot.exp_quat(np.zeros((1, 3))), (k, 1))  # heading east
    excess = implausible_motion_m(p, q, np.ones(k - 1), 0.5)
    assert excess[2] == pytest.approx(3.5)
    assert np.all(excess[[0, 1, 3, 4]] == 0.0)
    assert np.all(implausible_motion_m(p, q, np.ones(k - 1), 0.0) == 0.0)  # check off


def test_a_local_solve_of_one_more_edit_lands_near_the_full_solve():
    sim = simulate(duration_s=1999.0, rate_hz=1.0, edit_every_s=100.0, seed=4, regime="white")
    moves = [Move(e.t_s, e.lat_deg, e.lon_deg, None) for e in sim.edits]
    new = moves.pop(9)  # the next edit lands mid-run
    problem = prepare(sim.run)
    prev = problem.solve(EditSet(moves=moves))
    edits = EditSet(moves=moves + [new])
    local = problem.solve(edits, warm_start=prev, local=True)
    full = problem.solve(edits, warm_start=prev)
    assert "window" in local.solver.method and local.solver.extra["window"][1] - local.solver.extra["window"][0] < 1000
    gap = np.hypot(*(local.keyframes.p_enu_m - full.keyframes.p_enu_m)[:, :2].T)
    assert np.max(gap) < 0.05, np.max(gap)
    # the cost it reports (previous cost outside the window + the window's) is the full problem's
    from posefix.core import terms as T

    assert abs(T.cost(full.terms, local.x) - local.solver.cost) <= 1e-6 * local.solver.cost
    assert full.solver.cost * (1 - 1e-9) <= local.solver.cost <= full.solver.cost * (1 + 1e-3)


def test_one_more_edit_reuses_the_full_solves_linearisation_and_lands_where_a_fresh_one_does():
    sim = simulate(duration_s=999.0, rate_hz=1.0, edit_every_s=100.0, seed=5, regime="mixed")
    moves = [Move(e.t_s, e.lat_deg, e.lon_deg, None) for e in sim.edits]
    new = moves.pop(4)
    problem = prepare(sim.run)
    prev = problem.solve(EditSet(moves=moves))
    assert prev.linearisation is not None and prev.linearisation.matches(prev.terms)
    edits = EditSet(moves=moves + [new])
    local = problem.solve(edits, warm_start=prev, local=True)
    fresh = problem.solve(edits, warm_start=dataclasses.replace(prev, linearisation=None), local=True)
    assert "window" in local.solver.method and local.solver.extra["window"] == fresh.solver.extra["window"]
    assert np.max(np.abs(local.keyframes.p_enu_m - fresh.keyframes.p_enu_m)) < 1e-6
    for name, cost in fresh.solver.cost_after.items():
        assert local.solver.cost_after[name] == pytest.approx(cost, rel=1e-9)
        assert local.solver.cost_before[name] == pytest.approx(fresh.solver.cost_before[name], rel=1e-9)
    assert local.linearisation is prev.linearisation  # kept for the next frame of a drag
    # the drag goes on from the local answer (start away from the linearisation point)
    lat, lon, _ = geodesy.enu_to_geodetic(problem.to_enu(new.lon_deg, new.lat_deg, 0.0) + [3.0, -2.0, 0.0],
                                          problem.origin)
    dragged = EditSet(moves=moves + [Move(new.t_s, float(lat[0]), float(lon[0]), None)])
    nxt = problem.solve(dragged, warm_start=local, local=True)
    nxt_fresh = problem.solve(dragged, warm_start=dataclasses.replace(local, linearisation=None), local=True)
    assert "window" in nxt.solver.method
    assert np.max(np.abs(nxt.keyframes.p_enu_m - nxt_fresh.keyframes.p_enu_m)) < 1e-3
    assert nxt.solver.cost == pytest.approx(nxt_fresh.solver.cost, rel=1e-6)


def test_the_first_edit_of_an_unedited_run_with_sideways_jumps_is_a_local_solve():
    # canyon: the reported pose inherits GNSS jumps, so some steps slide sideways faster than a
    # car can; any edit measures those steps without the slide along the whole run
    sim = simulate(duration_s=1999.0, rate_hz=1.0, edit_every_s=100.0, seed=4, regime="canyon")
    problem = prepare(sim.run)
    base = problem.solve(None)
    plausible = problem.drag_base(base)
    assert plausible is not base and not np.array_equal(plausible.terms.rel_delta_m, base.terms.rel_delta_m)
    assert problem.drag_base(base) is plausible  # solved once
    # the location terms kept as in the base (a server's preview tapers the new drift estimate
    # away from the drag): what changes along the run is only how the steps are measured
    edits = EditSet(moves=[Move(e.t_s, e.lat_deg, e.lon_deg, None) for e in sim.edits[9:10]])
    index, edit_kf, c_m, has_alt, deleted_kf = problem._resolve_edit_set(edits)
    local = problem.solve_rows(index, edit_kf, c_m, has_alt, deleted_kf, warm_start=base, local=True,
                               drift=base.drift)
    full = problem.solve_rows(index, edit_kf, c_m, has_alt, deleted_kf, drift=base.drift)
    window = local.solver.extra.get("window")
    assert window is not None and window[1] - window[0] < 1000, local.solver.method
    gap = np.hypot(*(local.keyframes.p_enu_m - full.keyframes.p_enu_m)[:, :2].T)
    near = np.abs(np.arange(len(gap)) - edit_kf[0]) <= 100
    # a live drag's answer: centimetres from the exact one (the commit solves it exactly)
    assert np.max(gap[near]) < 0.05 and np.max(gap) < 0.1, (np.max(gap[near]), np.max(gap))
    # a run whose steps are all plausible starts from its own solution
    run, _ = hand_run(k=301)
    easy = prepare(run)
    sol = easy.solve(None)
    assert easy.drag_base(sol) is sol
