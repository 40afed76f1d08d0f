"""Drift: the bias the edits reveal, its uncertainty, and the location weights it implies."""

import dataclasses

import numpy as np
import pytest

from posefix.core.drift import estimate_drift, estimate_walk, smooth_gauss_markov
from posefix.core import geodesy
from posefix.core.simulate import simulate
from posefix.engine import CorrectionConfig, prepare


def straight(k=601):
    t = np.arange(k, dtype=float)
    p = np.stack([10.0 * t, np.zeros(k), np.zeros(k)], 1)
    return t, p


def fit(t, p, g, edit_kf, c, **kw):
    args = dict(sigma_w_h_m=3.0, sigma_w_v_m=6.0, sigma_u_h_m=0.5, sigma_u_v_m=0.5,
                prior_sigma_m=5.0, prior_tau_s=300.0, min_edits_for_estimate=3)
    args.update(kw)
    return estimate_drift(t, p, g, np.asarray(edit_kf), np.asarray(c), np.zeros(len(edit_kf), bool), **args)


def test_a_constant_gnss_offset_is_found_and_removed():
    t, p = straight()
    rng = np.random.default_rng(0)
    offset = np.array([8.0, -6.0, 0.0])
    g = p + offset + rng.normal(0, 3.0, p.shape)  # biased GNSS; the pose is the truth here
    edits = np.arange(50, 601, 100)
    c = p[edits] + rng.normal(0, 0.5, (len(edits), 3))
    d = fit(t, p, g, edits, c)
    assert d.detected
    assert np.allclose(d.offset_enu_m[:2], offset[:2], atol=1.0)
    assert np.allclose(d.bias_enu_m[:, :2], offset[:2], atol=1.2)
    assert np.isnan(d.offset_enu_m[2])  # 2-D edits say nothing about the vertical
    assert d.walk_m2_per_s < 0.05


def test_no_bias_leaves_the_location_term_almost_untouched():
    t, p = straight()
    rng = np.random.default_rng(1)
    g = p + rng.normal(0, 3.0, p.shape)
    edits = np.arange(50, 601, 100)
    d = fit(t, p, g, edits, p[edits] + rng.normal(0, 0.5, (len(edits), 3)))
    assert not d.detected
    assert np.min(d.weight) > 0.75
    assert np.max(np.hypot(*d.bias_enu_m[:, :2].T)) < 1.5


def test_a_wandering_bias_lowers_the_weight_between_edits_not_at_them():
    t, p = straight()
    rng = np.random.default_rng(2)
    walk = np.cumsum(rng.normal(0, 1.0, (len(t), 3)), axis=0) * np.array([1, 1, 0])  # 1 m^2/s per axis
    g = p + walk + rng.normal(0, 1.0, p.shape)
    edits = np.arange(0, 601, 60)
    d = fit(t, p, g, edits, p[edits] + rng.normal(0, 0.5, (len(edits), 3)))
    assert d.detected
    assert 0.3 < d.walk_m2_per_s < 3.0
    mid = edits[:-1] + 30
    assert np.mean(d.weight[mid]) < np.mean(d.weight[edits[:-1]])
    assert np.mean(d.weight[mid]) < 0.6
    # the bias estimate follows the walk much better than ignoring it would
    err = np.hypot(*(d.bias_enu_m[:, :2] - walk[:, :2]).T)
    assert np.sqrt(np.mean(err**2)) < 0.5 * np.sqrt(np.mean(np.sum(walk[:, :2] ** 2, axis=1)))


def test_a_gnss_step_between_two_edits_is_located_and_taken_out():
    t, p = straight()
    rng = np.random.default_rng(3)
    jump = np.where(t[:, None] > 330, np.array([15.0, 0.0, 0.0]), 0.0)
    g = p + jump + rng.normal(0, 2.0, p.shape)
    edits = np.arange(0, 601, 60)
    d = fit(t, p, g, edits, p[edits] + rng.normal(0, 0.3, (len(edits), 3)))
    assert d.n_steps == 1 and d.detected
    # the bias follows the step (not a ramp from edit to edit) and only the ramp loses its weight
    assert np.all(np.abs(d.bias_enu_m[(t > 60) & (t < 300), 0]) < 1.5)
    assert np.all(np.abs(d.bias_enu_m[(t > 360) & (t < 540), 0] - 15.0) < 1.5)
    assert np.all(d.weight[(t > 326) & (t < 336)] < 0.2)
    assert np.mean(d.weight[(t > 60) & (t < 300)]) > 0.9


def test_a_pose_that_follows_its_gnss_shows_no_step():
    from posefix.core.drift import gnss_steps
    from scipy.signal import lfilter

    rng = np.random.default_rng(4)
    k = 600
    step = np.where(np.arange(k)[:, None] > 300, np.array([15.0, 0.0]), 0.0)
    a = np.exp(-1.0 / 10.0)
    follow = lfilter([1 - a], [1, -a], step, axis=0)  # an INS following the GNSS through a 10 s low-pass
    u = step - follow + rng.normal(0, 2.0, (k, 2))
    assert len(gnss_steps(u).index) == 0
    assert len(gnss_steps(step + rng.normal(0, 2.0, (k, 2))).index) == 1


def test_outlier_fixes_at_an_edit_do_not_corrupt_its_offset():
    t, p = straight()
    g = p.copy()
    g[298:303] += [50.0, 0.0, 0.0]  # a burst of 50 m outliers right at the edit
    d = fit(t, p, g, [300], p[[300]])
    assert np.hypot(*d.edit_offsets_enu_m[0, :2]) < 1e-9


def test_estimators_on_known_processes():
    rng = np.random.default_rng(4)
    tt = np.arange(0, 20000, 100.0)
    y = np.cumsum(rng.normal(0, np.sqrt(0.2 * 100.0), (len(tt), 2)), axis=0)
    q = estimate_walk(tt, y + rng.normal(0, 1.0, y.shape), np.full(len(tt), 1.0))
    assert 0.15 < q < 0.26
    mean, var = smooth_gauss_markov(np.array([0.0, 10.0]), np.array([1.0, 3.0]), np.array([1e-6, 1e-6]), 25.0, 300.0)
    assert np.allclose(mean, [1.0, 3.0], atol=1e-4) and np.all(var < 1e-5)


def test_an_offset_switched_on_and_off_between_two_edits_is_taken_out():
    # the GNSS carries a 12 m offset from 200 s to 350 s; the edits at 50 s and 550 s see no
    # change, yet the pair of steps (on, then off) is itself the evidence
    t, p = straight()
    rng = np.random.default_rng(5)
    on = ((t > 200) & (t <= 350))[:, None] * np.array([12.0, 0.0, 0.0])
    g = p + on + rng.normal(0, 2.0, p.shape)
    edits = np.array([50, 550])
    d = fit(t, p, g, edits, p[edits] + rng.normal(0, 0.3, (2, 3)))
    assert d.n_steps == 2
    inside = (t > 220) & (t < 330)
    assert np.all(np.abs(d.bias_enu_m[inside, 0] - 12.0) < 1.5)
    assert np.mean(d.weight[inside]) > 0.2  # not written off (an unconfirmed step leaves about 0.01)
    assert np.all(np.abs(d.bias_enu_m[(t > 380) & (t < 520), 0]) < 2.0)  # step sizes are estimated to about a metre


def test_edits_the_shape_cannot_join_bend_the_run_where_the_evidence_is():
    from posefix.core.drift import edit_bends

    k = 101
    p = np.stack([10.0 * np.arange(k), np.zeros(k), np.zeros(k)], 1)
    var = np.full(k - 1, 0.04)  # 0.2 m/sqrt(s), 1 s steps: 2 m over the interval
    evidence = np.ones(k - 1)
    evidence[60:65] = 1000.0  # where the pose slid
    edits = np.array([0, 100])
    c = p[edits].copy()
    c[1, 1] += 12.0  # the edits say the pose's error changed by 12 m
    extra_rel, dragged = edit_bends(p, var, evidence, edits, c, 0.5)
    assert 0.5 * 144.0 == pytest.approx(var.sum() + extra_rel.sum())  # the interval now allows what the edits show
    assert extra_rel[60:65].sum() > 0.9 * extra_rel.sum()  # most of it where the evidence is
    assert np.all(dragged[1:100]) and not dragged[0] and not dragged[100]  # the fixes between drop out
    # a change the relative sigmas already allow leaves everything as it was
    c[1, 1] = 3.0
    extra_rel, dragged = edit_bends(p, var, evidence, edits, c, 0.5)
    assert not extra_rel.any() and not dragged.any()
    # chi2 = 0 turns it off
    c[1, 1] = 12.0
    assert not edit_bends(p, var, evidence, edits, c, 0.5, chi2=0.0)[0].any()


def test_shape_change_evidence_peaks_at_a_gnss_transient_and_at_sideways_motion():
    from posefix.core.drift import gnss_transient, shape_change_evidence

    k = 300
    rng = np.random.default_rng(3)
    u = rng.normal(0, 2.5, (k, 2))
    u[150:170, 0] += 15.0 * np.exp(-np.arange(20) / 8.0)  # the fix jumped, the pose follows it
    u[60:63] += [50.0, -50.0]  # a 3 s burst of outliers is no transient
    side = np.full(k - 1, 0.05)
    side[40] = 2.0
    tr = gnss_transient(u, 5, 61)
    assert tr[150:160].max() > 13.8 and tr[55:70].max() < 13.8
    ev = shape_change_evidence(tr, side)
    assert 145 <= int(np.argmax(ev[100:200])) + 100 <= 160
    assert int(np.argmax(ev[:100])) == 40
    tr0 = gnss_transient(np.zeros((k, 2)), 5, 61)  # no separate GNSS: the sideways motion alone
    ev = shape_change_evidence(tr0, side)
    assert not tr0.any() and int(np.argmax(ev)) == 40 and np.all(np.isfinite(ev))


def test_a_pose_that_wandered_under_good_gnss_is_left_to_the_location_terms():
    from posefix.core.drift import edit_bends

    k = 101
    p = np.stack([10.0 * np.arange(k), np.zeros(k), np.zeros(k)], 1)
    rng = np.random.default_rng(4)
    truth = p.copy()
    truth[:, 1] += np.linspace(0.0, 12.0, k)  # the pose's error grew by 12 m over the interval
    g = truth + np.c_[rng.normal(0, 2.5, (k, 2)), np.zeros(k)]  # the fix stayed on the truth
    edits = np.array([0, 100])
    var = np.full(k - 1, 0.04)
    extra_rel, dragged = edit_bends(p, var, np.ones(k - 1), edits, truth[edits], 0.5, g_m=g, sigma_w_m=3.0)
    assert not extra_rel.any() and not dragged.any()
    # the same edits over a fix that followed the pose: dragged
    extra_rel, dragged = edit_bends(p, var, np.ones(k - 1), edits, truth[edits], 0.5, g_m=p.copy(), sigma_w_m=3.0)
    assert extra_rel.sum() > 0 and dragged[1:100].all()


def _canyon_drive(every_s, seed=5, regime="canyon"):
    from posefix.core import geodesy
    from posefix.core.simulate import simulate
    from posefix.engine import prepare
    from posefix.io.edits import EditSet, Move

    sim = simulate(duration_s=1800.0, rate_hz=10.0, edit_every_s=every_s, seed=seed, regime=regime)
    problem = prepare(sim.run)
    truth = geodesy.geodetic_to_enu(sim.truth.lat_deg, sim.truth.lon_deg, sim.truth.alt_m, problem.origin)
    moves = [Move(e.t_s, e.lat_deg, e.lon_deg, None) for e in sim.edits]
    return sim, problem, truth, moves, EditSet


def _h_rmse(a, b):
    return float(np.sqrt(np.mean(np.sum((a[:, :2] - b[:, :2]) ** 2, axis=1))))


def test_a_pose_dragged_by_canyon_jumps_is_corrected_better_than_interpolating_the_edits():
    """Urban-canyon offsets the pose inherited, edits every 30 s: the correction bends the run
    where the pose was dragged (beating the naive linear interpolation of the edit offsets,
    which it trailed by 25 % before), and the run between edits that agree keeps its shape."""
    from posefix.core import geodesy

    sim, problem, truth, moves, EditSet = _canyon_drive(30.0)
    out = problem.full_run(problem.solve(EditSet(moves=moves)))
    p = geodesy.geodetic_to_enu(out.run.lat_deg, out.run.lon_deg, out.run.alt_m, problem.origin)
    rows = np.array([e.index for e in sim.edits])
    off = problem.to_enu([m.lon_deg for m in moves], [m.lat_deg for m in moves], sim.run.alt_m[rows]) - problem.p_enu_m[rows]
    naive = problem.p_enu_m.copy()
    for j in range(2):
        naive[:, j] += np.interp(sim.run.t_s, sim.run.t_s[rows], off[:, j])
    assert _h_rmse(p, truth) < 0.8 * _h_rmse(naive, truth), (_h_rmse(p, truth), _h_rmse(naive, truth))
    assert out.solver.iterations <= 10


def test_one_more_edit_on_a_dragged_pose_solved_locally_lands_near_the_full_solve():
    sim, problem, truth, moves, EditSet = _canyon_drive(30.0)
    # the full solve in the warm solution's model (the held-out edits may choose another)
    problem = prepare(sim.run, CorrectionConfig.from_dict({"calibration": {"model": "gnss"}}))
    new = moves.pop(len(moves) // 2)
    prev = problem.solve(EditSet(moves=moves))
    edits = EditSet(moves=moves + [new])
    local = problem.solve(edits, warm_start=prev, local=True)
    full = problem.solve(edits)
    assert "window" in local.solver.method
    gap = np.hypot(*(local.keyframes.p_enu_m - full.keyframes.p_enu_m)[:, :2].T)
    assert np.max(gap) < 0.05, np.max(gap)


# ----------------------------------------------------------------------------- GNSS levels


def _levels_problem(seed: int = 3, k: int = 400):
    """A smooth pose error, a fix level that jumps for 80 s and again later, white noise: u = c - e + w."""
    from posefix.core.drift import GnssLevels

    rng = np.random.default_rng(seed)
    t = np.arange(k, dtype=float)
    e = np.column_stack([2.0 * np.sin(t / 70.0 + 1.0), 1.5 * np.cos(t / 90.0)])
    c = np.zeros((k, 2))
    c[150:230] += [8.0, -6.0]
    c[300:] += [-5.0, 4.0]
    u = c - e + rng.normal(0.0, 0.5, (k, 2))
    return t, e, c, u, GnssLevels


def test_level_jumps_are_found_where_the_fix_jumps_and_not_in_a_smooth_wander():
    from posefix.core.drift import find_level_jumps

    t, e, c, u, _ = _levels_problem()
    jumps, sizes = find_level_jumps(u, 0.5, window=20, gap=3)
    assert len(jumps) == 3 and np.all(np.abs(jumps - [150, 230, 300]) <= 3), jumps  # to the left-out gap (3)
    assert np.allclose(sizes, [[8, -6], [-8, 6], [-5, 4]], atol=1.0), sizes
    none, _ = find_level_jumps(-e + np.random.default_rng(4).normal(0.0, 0.5, e.shape), 0.5, window=20, gap=3)
    assert len(none) == 0, none


def test_level_smoother_matches_the_dense_solution_and_recovers_the_pose_error():
    from posefix.core.drift.levels import _level_blocks, find_level_jumps, solve_levels

    t, e, c, u, GnssLevels = _levels_problem(k=120)
    u = u.copy()
    c_small = c[:120]
    jumps, sizes = find_level_jumps(u, 0.5, window=20, gap=3)
    lv = GnssLevels(u, np.ones(120, dtype=bool), 0.5, jumps, sizes)
    edit_kf = np.array([10, 60, 110])
    y = e[edit_kf] + 0.1
    c_hat, e_hat, var_c = solve_levels(t, lv, edit_kf, y, 0.5, 3.0)
    Dg, L, w = _level_blocks(t, lv, edit_kf, 0.5, 3.0, 4)
    k = len(t)
    H = np.zeros((3 * k, 3 * k))
    for i in range(k):
        H[3 * i:3 * i + 3, 3 * i:3 * i + 3] = Dg[i]
    for i in range(k - 1):
        H[3 * i + 3:3 * i + 6, 3 * i:3 * i + 3] = L[i]
        H[3 * i:3 * i + 3, 3 * i + 3:3 * i + 6] = L[i].T
    g = np.zeros((k, 3, 2))
    g[:, 0] -= w[:, None] * u
    g[:, 2] += w[:, None] * u
    g[edit_kf, 0] += y / 0.25
    x = np.linalg.solve(H, g.reshape(3 * k, 2)).reshape(k, 3, 2)
    assert np.allclose(x[:, 2], c_hat, atol=1e-8) and np.allclose(x[:, 0], e_hat, atol=1e-8)
    exact = np.diag(np.linalg.inv(H))[2::3]
    bounds = np.concatenate([[0], jumps, [len(t)]])
    at = np.concatenate([(bounds[:-1] + bounds[1:]) // 2, jumps])
    assert np.allclose(exact[at], var_c[at], rtol=1e-8)  # solved exactly mid-level and at the jumps
    ramps = (jumps[:, None] + np.arange(-4, 5)[None, :]).ravel()
    assert np.all(var_c[ramps] >= exact[ramps] * (1 - 1e-8))  # the ramp takes the jump's peak
    inner = np.setdiff1d(np.arange(len(t)), ramps)
    assert np.allclose(exact[inner], var_c[inner], rtol=0.02)  # held over each level elsewhere
    assert np.sqrt(np.mean((e_hat - e[:120]) ** 2)) < 0.5
    assert np.sqrt(np.mean((c_hat - c_small) ** 2)) < 0.7


def _rmse_corrected_naive_input(problem, sim, sol) -> tuple[float, float, float]:
    """Horizontal RMSE (m) against the simulation's truth: the corrected run, the naive baseline, the input."""
    from benchmarks.engine import naive_positions

    truth = geodesy.geodetic_to_enu(sim.truth.lat_deg, sim.truth.lon_deg, sim.truth.alt_m, problem.origin)
    out = problem.full_run(sol).run
    p = geodesy.geodetic_to_enu(out.lat_deg, out.lon_deg, out.alt_m, problem.origin)

    def rmse(a):
        return float(np.sqrt(np.mean(np.sum((a - truth)[:, :2] ** 2, axis=1))))

    return rmse(p), rmse(naive_positions(problem, sim)), rmse(problem.p_enu_m)


def test_a_pose_that_bridged_canyon_offsets_is_corrected_by_the_level_model():
    from benchmarks.engine import edit_set

    sim = simulate(duration_s=900.0, rate_hz=10.0, edit_every_s=100.0, seed=11, regime="canyon_ins")
    problem = prepare(sim.run)
    sol = problem.solve(edit_set(sim))
    assert sol.drift.loc_sigma_h_m is not None  # the level model took over the location term
    pf, naive, given = _rmse_corrected_naive_input(problem, sim, sol)
    assert pf < 0.7 * naive, (pf, naive)
    assert pf < given / 4.0, (pf, given)


def test_the_level_model_takes_a_pose_that_bridged_the_jumps_but_not_one_that_followed_them():
    from posefix.core.drift import gnss_levels, levels_bridged

    k = 900
    t = np.arange(k, dtype=float)
    rng = np.random.default_rng(8)
    c = np.zeros((k, 2))
    for a, b, off in ((100, 250, [9.0, -7.0]), (400, 520, [-6.0, 8.0]), (650, 800, [12.0, 3.0])):
        c[a:b] += off
    e = np.column_stack([1.5 * np.sin(t / 80.0), 1.0 * np.cos(t / 110.0)])
    followed = np.zeros_like(c)  # an INS that trusted its fix: a 10 s low-pass of the level
    for i in range(1, k):
        followed[i] = followed[i - 1] + (c[i] - followed[i - 1]) / 10.0
    noise = rng.normal(0.0, 0.6, (k, 2))
    bridged = gnss_levels(t, c - e + noise, t)
    follows = gnss_levels(t, c - followed - e + noise, t)
    assert len(bridged.jumps) >= 6 and levels_bridged(bridged, t)
    assert not levels_bridged(follows, t)


@pytest.mark.parametrize("which", ["new", "moved"])
def test_a_live_drag_on_a_level_model_run_is_local_and_lands_where_the_full_solve_does(which):
    from posefix.io.edits import EditSet, Move

    sim = simulate(duration_s=1200.0, rate_hz=2.0, edit_every_s=100.0, seed=11, regime="canyon_ins")
    problem = prepare(sim.run)
    moves = [Move(e.t_s, e.lat_deg, e.lon_deg, None) for e in sim.edits]
    sol = problem.solve(EditSet(moves=moves))
    assert sol.drift.loc_sigma_h_m is not None
    rows = sol.keyframes.index
    if which == "new":
        k = 300
        t = float(sim.run.t_s[rows[k]])
    else:
        e = sim.edits[3]
        k, t = int(np.searchsorted(rows, e.index)), e.t_s
    lat, lon, _ = geodesy.enu_to_geodetic((sol.keyframes.p_enu_m[k] + [3.0, 0.0, 0.0])[None, :], problem.origin)
    dragged = Move(t, float(lat[0]), float(lon[0]), None)
    edits = EditSet(moves=moves + [dragged] if which == "new" else moves[:3] + [dragged] + moves[4:])
    local = problem.solve(edits, warm_start=sol, local=True)
    full = problem.solve(edits, warm_start=sol)
    assert local.solver.method.endswith("-window")
    moved = local.keyframes.p_enu_m[k] - sol.keyframes.p_enu_m[k]
    assert moved[0] > 1.5  # the keyframe follows the drag (the edits around hold part of it back)
    assert np.max(np.abs(local.keyframes.p_enu_m[k] - full.keyframes.p_enu_m[k])[:2]) < 0.15


def test_a_gnss_outage_across_a_level_change_frees_the_level():
    from benchmarks.engine import edit_set

    sim = simulate(duration_s=1800.0, rate_hz=10.0, edit_every_s=100.0, seed=11, regime="canyon_ins")
    run = sim.run
    gap = (run.t_s - run.t_s[0] >= 280.0) & (run.t_s - run.t_s[0] < 340.0)  # the fix leaves an 18 m canyon offset in here
    nan = np.where(gap, np.nan, 1.0)
    run = dataclasses.replace(run, gnss_lat_deg=run.gnss_lat_deg * nan, gnss_lon_deg=run.gnss_lon_deg * nan,
                              gnss_alt_m=run.gnss_alt_m * nan)
    problem = prepare(run)
    sol = problem.solve(edit_set(sim))
    assert sol.drift.loc_sigma_h_m is not None
    pf, naive, given = _rmse_corrected_naive_input(problem, sim, sol)
    assert pf < 0.7 * naive, (pf, naive)
    assert pf < given / 4.0, (pf, given)


def test_one_edit_on_a_bridged_run_lets_the_fixes_correct_all_of_it():
    # the fix's steps and the pose's bridging are read from the run itself; one edit anchors
    # the levels (with the open-sky prior), where the old model let canyon offsets pull the run
    from benchmarks.engine import edit_set
    from posefix.io.edits import EditSet

    sim = simulate(duration_s=1800.0, rate_hz=10.0, edit_every_s=100.0, seed=11, regime="canyon_ins")
    problem = prepare(sim.run)
    sol = problem.solve(EditSet(moves=edit_set(sim).moves[:1]))
    assert sol.drift.loc_sigma_h_m is not None
    pf, _, given = _rmse_corrected_naive_input(problem, sim, sol)
    assert pf < given / 3.0, (pf, given)
