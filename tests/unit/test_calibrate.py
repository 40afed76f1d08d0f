"""Per-run calibration (engine.calibrate) and the model the run's own edits choose."""

from __future__ import annotations

import dataclasses

import numpy as np

from posefix.core import geodesy
from posefix.core import terms as T
from posefix.core.drift import smooth_gauss_markov
from posefix.core.simulate import simulate
from posefix.core.solver import solve_banded
from posefix.engine import CorrectionConfig, Edit, prepare
from posefix.engine.calibrate import ProcessFit, best_process, fit_processes, loo_residuals, variogram
from posefix.engine.edits import Edits
from posefix.engine.naive import naive_held_out
from posefix.io.edits import EditSet, Move


def _walk(rng, t, q, nugget):
    e = np.cumsum(rng.standard_normal((len(t), 2)) * np.sqrt(q * np.diff(t, prepend=t[0] - 1.0))[:, None], axis=0)
    return e + rng.standard_normal((len(t), 2)) * np.sqrt(nugget)


def test_variogram_recovers_a_random_walk_and_its_nugget():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(5.0, 40.0, 800))
    y = _walk(rng, t, q=0.02, nugget=0.25)
    fits = {f.kind: f for f in fit_processes(*variogram(t, y), floor_m2=0.01)}
    rw = fits["random_walk"]
    assert abs(rw.q_m2_per_s - 0.02) < 0.2 * 0.02
    assert abs(rw.nugget_m2 - 0.25) < 0.35 * 0.25


def test_variogram_recovers_a_gauss_markov_process():
    rng = np.random.default_rng(2)
    t = np.cumsum(rng.uniform(10.0, 40.0, 1500))
    sigma, tau = 4.0, 200.0
    x = np.zeros((len(t), 2))
    x[0] = rng.standard_normal(2) * sigma
    a = np.exp(-np.diff(t) / tau)
    for i in range(1, len(t)):
        x[i] = a[i - 1] * x[i - 1] + np.sqrt(1 - a[i - 1] ** 2) * sigma * rng.standard_normal(2)
    y = x + rng.standard_normal(x.shape) * 0.5
    fit, *_ = best_process(t, y, floor_m2=0.01)
    assert fit.kind == "gauss_markov"
    assert abs(np.sqrt(fit.sigma2_m2) - sigma) < 0.2 * sigma
    assert 0.6 * tau < fit.tau_s < 1.6 * tau


def test_leave_one_out_from_the_smoother_equals_refitting_without_the_edit():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(30.0, 120.0, 25))
    y = _walk(rng, t, q=0.05, nugget=0.3)
    for fit in (ProcessFit("gauss_markov", 0.3, 9.0, 400.0, 2 * 9.0 / 400.0),
                ProcessFit("random_walk", 0.3, 0.05 * 1e7 / 2, 1e7, 0.05)):
        r, V, _, _ = loo_residuals(t, y, fit)
        for k in range(len(t)):
            # refit without edit k: its observation carries no information (variance 1e30)
            r_var = np.full(len(t), fit.nugget_m2)
            r_var[k] = 1e30
            xs, P = smooth_gauss_markov(t, y, r_var, fit.sigma2_m2, fit.tau_s)
            np.testing.assert_allclose(r[k], y[k] - xs[k], rtol=1e-6, atol=1e-8)
            np.testing.assert_allclose(V[k], P[k] + fit.nugget_m2, rtol=1e-6)


def _edits(sim):
    return EditSet(moves=[Move(e.t_s, e.lat_deg, e.lon_deg, None) for e in sim.edits])


def test_without_gnss_the_result_is_relative_terms_interpolation_of_the_edits():
    sim = simulate(duration_s=900.0, rate_hz=2.0, edit_every_s=100.0, seed=4, regime="drift", gnss_columns=False)
    problem = prepare(sim.run)
    sol = problem.solve(_edits(sim))
    assert sol.drift.calibration.model == "relative"
    assert np.isfinite(sol.drift.calibration.cv_rmse_m)
    # the same keyframes solved from the reported pose with the relative, gravity and edit terms only
    terms = dataclasses.replace(sol.terms, loc_w=np.zeros_like(sol.terms.loc_w))
    x, _ = solve_banded(terms, None, 100, 1e-12)
    assert np.max(np.abs(T.split_state(x)[0] - sol.keyframes.p_enu_m[sol.active])) < 2e-3
    assert sol.solver.cost_after["location"] == 0.0


def test_one_edit_moves_a_ten_minute_run_only_near_the_edit():
    # what the edit changes: the run corrected with it against the run corrected without it
    sim = simulate(duration_s=600.0, rate_hz=5.0, edit_every_s=0.0, seed=6, regime="white")
    problem = prepare(sim.run, CorrectionConfig())
    i = int(np.searchsorted(sim.run.t_s, sim.run.t_s[0] + 300.0))
    before = problem.full_run(problem.solve(EditSet()))
    p_before = problem.to_enu(before.run.lon_deg, before.run.lat_deg, before.run.alt_m)
    p = p_before[i] + np.array([6.0, -4.0, 0.0])
    lat, lon, _ = geodesy.enu_to_geodetic(p[None], problem.origin)
    out = problem.full_run(problem.solve(EditSet(moves=[Move(float(sim.run.t_s[i]), float(lat[0]), float(lon[0]))])))
    assert out.drift.calibration.model == "prior"
    moved = np.hypot(*(problem.to_enu(out.run.lon_deg, out.run.lat_deg, out.run.alt_m) - p_before)[:, :2].T)
    dt = np.abs(sim.run.t_s - sim.run.t_s[i])
    assert moved[i] > 6.0  # the edited sample follows the edit (7.2 m)
    assert moved[dt > 180.0].max() < 0.1 * moved[i]  # three minutes away the run stays where it was


def test_naive_candidate_is_naive_interpolation_and_its_held_out_residuals_equal_refitting():
    sim = simulate(duration_s=900.0, rate_hz=2.0, edit_every_s=100.0, seed=5, regime="canyon")
    naive_cfg = CorrectionConfig.from_dict({"calibration": {"model": "naive"}})
    problem = prepare(sim.run, naive_cfg)
    rows = np.array([e.index for e in sim.edits])
    c = problem.to_enu([e.lon_deg for e in sim.edits], [e.lat_deg for e in sim.edits], sim.run.alt_m[rows])
    sol = problem.solve(_edits(sim))
    assert sol.drift.calibration.model == "naive" and sol.solver.method == "naive"
    kf = sol.keyframes
    off = c - problem.p_enu_m[rows]
    for j in range(2):
        want = kf.reported_p_enu_m[:, j] + np.interp(kf.t_s, sim.run.t_s[rows], off[:, j])
        assert np.max(np.abs(kf.p_enu_m[:, j] - want)) < 1e-9
    assert np.array_equal(kf.q_wxyz, kf.reported_q_wxyz)
    # leave-one-out in closed form = solving naive again without the edit
    t_e, y = sim.run.t_s[rows], (problem.p_enu_m[rows] - c)[:, :2]
    picks = np.arange(len(rows))
    r = naive_held_out(t_e, y, picks)
    for k in picks:
        keep = np.arange(len(rows)) != k
        moves = [Move(e.t_s, e.lat_deg, e.lon_deg, None) for i, e in enumerate(sim.edits) if keep[i]]
        s = problem.solve(EditSet(moves=moves))
        at = int(np.searchsorted(s.keyframes.index, rows[k]))
        assert np.allclose(s.keyframes.p_enu_m[at, :2] - c[k, :2], r[k], atol=1e-6)


def test_a_drag_on_a_naive_revision_previews_naive_interpolation():
    sim = simulate(duration_s=600.0, rate_hz=2.0, edit_every_s=0.0, seed=5, regime="canyon")
    problem = prepare(sim.run, CorrectionConfig.from_dict({"calibration": {"model": "naive"}}))
    kf = problem.keyframe_index
    rows = kf[[50, 150, 250, 350, 450]]
    edits = Edits(tuple(Edit(int(k), float(sim.truth.lon_deg[r]), float(sim.truth.lat_deg[r]))
                        for k, r in zip((50, 150, 250, 350, 450), rows)))
    base = problem.solve_edits(edits)
    assert base.drift.calibration.model == "naive"
    p = base.keyframes.p_enu_m[200] + np.array([2.0, 1.0, 0.0])
    lat, lon, _ = geodesy.enu_to_geodetic(p[None], problem.origin)
    pv = problem.preview([Edit(200, float(lon[0]), float(lat[0]))], base_edits=edits, base=base)
    assert pv.refusals == [] and pv.solution.solver.method == "naive"
    assert np.allclose(pv.solution.keyframes.p_enu_m[200, :2], p[:2], atol=1e-6)  # the dragged keyframe lands on the drag
    # beyond the edits either side the run keeps the revision's positions
    assert np.allclose(pv.solution.keyframes.p_enu_m[260:, :2], base.keyframes.p_enu_m[260:, :2], atol=1e-9)


def test_plain_and_relative_start_from_the_gnss_answer_and_score_as_refits_do():
    """The other candidates are solved by Newton steps from the first model's answer and their
    held-out edits scored on one model of the run: both as a solve of their own and a refit per edit."""
    from posefix.engine.calibrate import Calibration, held_out_picks
    from posefix.engine.choose import held_out_fixed_terms, held_out_residuals, with_linearisation

    sim = simulate(duration_s=900.0, rate_hz=2.0, edit_every_s=60.0, seed=5, regime="mixed")
    problem = prepare(sim.run)
    index, edit_kf, c, has_alt, deleted = problem._resolve_edit_set(_edits(sim))
    args = (index, edit_kf, c, has_alt, deleted)
    picks = held_out_picks(len(edit_kf), 12)
    base = with_linearisation(problem.solve_rows(*args, calibration=Calibration("gnss", float("nan"))))
    for name in ("plain", "relative"):
        calib = Calibration(name, float("nan"))
        fast = problem.solve_rows(*args, base, calibration=calib, newton=True)
        assert fast.solver.method == "local-newton"
        full = problem.solve_rows(*args, calibration=calib)
        # horizontally (without a location term nothing holds the height but where it starts)
        assert np.max(np.abs(fast.keyframes.p_enu_m - full.keyframes.p_enu_m)[:, :2]) < 5e-3
        own = with_linearisation(dataclasses.replace(fast, linearisation=None))
        r_fast = held_out_fixed_terms(own, edit_kf, picks)
        r_refit = held_out_residuals(problem, own, *args, picks)
        assert r_fast is not None and np.max(np.abs(r_fast - r_refit)) < 1e-3
        assert np.max(np.abs(r_fast)) > 0.1  # the edits are not predicted trivially


def _gauss_markov(rng, t, sigma, tau, dims=2):
    x = np.zeros((len(t), dims))
    x[0] = rng.standard_normal(dims) * sigma
    a = np.exp(-np.diff(t) / tau)
    for i in range(1, len(t)):
        x[i] = a[i - 1] * x[i - 1] + np.sqrt(1 - a[i - 1] ** 2) * sigma * rng.standard_normal(dims)
    return x


def test_interpolation_variance_is_the_random_walk_bridge_and_matches_a_simulated_gauss_markov_one():
    from posefix.engine.calibrate import interpolation_variance

    q, G = 0.04, 100.0
    te = np.array([0.0, G])
    u = np.linspace(0.0, 1.0, 2001)
    v = interpolation_variance(lambda h: q * np.abs(h) / 2.0, u * G, te, 0.0, 0.0)
    assert np.allclose(v, q * G * u * (1 - u))
    assert abs(np.mean(v) - q * G / 6.0) < 1e-3 * q * G and abs(v[1000] - q * G / 4.0) < 1e-12
    # a Gauss-Markov process, white pose error and noisy edits: the formula against 4,000 draws
    rng = np.random.default_rng(3)
    sigma, tau, nw, ne = 2.0, 60.0, 0.3, 0.25
    t = np.arange(0.0, 100.5, 1.0)
    err = []
    for _ in range(4000):
        x = _gauss_markov(rng, t, sigma, tau, dims=1)[:, 0] + rng.standard_normal(len(t)) * np.sqrt(nw)
        y = x[[0, -1]] + rng.standard_normal(2) * np.sqrt(ne)
        err.append(x - np.interp(t, te, y))
    mc = np.mean(np.square(err), axis=0)
    model = interpolation_variance(lambda h: sigma**2 * -np.expm1(-np.abs(h) / tau), t, te, nw, ne)
    # (at the edits' own samples the pose's white error is the edit's: the formula is for every other)
    assert np.all(np.abs(mc - model)[1:-1] < 0.08 * model[1:-1])


def _naive_prediction(rng, t, err, every_s, n_max=None):
    """Naive interpolation of noisy edits every ``every_s`` of a pose error ``err`` (n,2): its
    true RMSE over the samples and the one predicted at the real spacing (module docstring 6)."""
    from posefix.engine.calibrate import CV_MAX_HELD_OUT, held_out_picks, spacing_ratio
    from posefix.engine.naive import interpolate_offsets

    idx = np.searchsorted(t, (np.arange(int(t[-1] // every_s)) + 0.5) * every_s)
    te = t[idx]
    y = err[idx] + rng.standard_normal((len(idx), 2)) * 0.5
    true = np.sqrt(np.mean(np.sum((err - interpolate_offsets(t, te, y)) ** 2, axis=1)))
    picks = held_out_picks(len(te), n_max or CV_MAX_HELD_OUT)
    cv = np.sqrt(np.mean(np.sum(naive_held_out(te, y, picks) ** 2, axis=1)))
    ratio, band = spacing_ratio(t, t, te, y, picks, 0.5)
    assert abs(np.mean(band) - 1.0) < 0.03  # V over its run mean (on at most 5,000 samples): RMS 1 along the run
    return true, cv * ratio, cv


def test_predicted_rmse_is_within_1_5_of_the_truth_on_known_random_walk_and_gauss_markov_processes():
    t = np.arange(0.0, 21600.0, 2.0)  # six hours: 72 to 720 edits, enough for the variogram's shape
    cases = []
    for seed in range(2):
        rng = np.random.default_rng(10 + seed)
        walk = np.cumsum(rng.standard_normal((len(t), 2)) * np.sqrt(0.02), axis=0)
        gm = _gauss_markov(rng, t, 4.0, 120.0)
        smooth = np.cumsum(_gauss_markov(rng, t, 0.15, 60.0), axis=0)  # an integrated velocity error
        for err in (walk, gm, smooth):
            for every in (30.0, 100.0, 300.0):
                cases.append(_naive_prediction(rng, t, err, every, n_max=10_000))
    ratios = np.array([pred / true for true, pred, _ in cases])
    assert np.all((ratios > 1 / 1.5) & (ratios < 1.5)), np.round(ratios, 2)
    # the held-out RMSE alone (a gap of two spacings) overstates: by about sqrt 3 for a random walk
    overstated = np.array([cv / true for true, _, cv in cases])
    assert np.median(overstated) > 1.5


def test_pose_jitter_is_the_white_part_of_the_pose_error():
    from posefix.engine.calibrate import pose_jitter_m2

    rng = np.random.default_rng(4)
    t = np.arange(0.0, 600.0, 0.1)
    track = np.stack([12.0 * t, 200.0 * np.sin(t / 40.0)], axis=1)  # a vehicle turning, 10 Hz
    assert pose_jitter_m2(track) < 1e-3
    assert abs(pose_jitter_m2(track + rng.standard_normal(track.shape) * 0.3) - 0.09) < 0.1 * 0.09


def test_the_band_is_pinned_at_the_edits_and_widest_between_them():
    from posefix.engine.calibrate import spacing_ratio

    rng = np.random.default_rng(5)
    t = np.arange(0.0, 3600.0, 1.0)
    idx = np.arange(50, 3600, 100)
    # a random walk well above the edits' noise (where that dominates, the error is largest at the
    # edits themselves: between two, their noise averages)
    y = np.cumsum(rng.standard_normal((len(t), 2)), axis=0)[idx] + rng.standard_normal((len(idx), 2)) * 0.5
    ratio, band = spacing_ratio(t, t, t[idx], y, np.arange(len(idx)), 0.5)
    sigma = np.sqrt(band)
    assert 0.3 < ratio < 0.8
    assert abs(np.sqrt(np.mean(band)) - 1.0) < 0.01  # RMS 1 along the run: scaled to the prediction
    assert np.all(sigma[idx[1:-1]] < 0.6 * sigma[idx[1:-1] - 50])  # at an edit vs mid-way to the last
    assert sigma[0] > sigma[idx[0]] and sigma[-1] > sigma[idx[-1]]  # beyond the end edits it grows again


def test_held_out_variance_is_the_interpolation_variance_without_the_edit_plus_its_noise():
    from posefix.engine.calibrate import held_out_variance, interpolation_variance

    rng = np.random.default_rng(6)
    te = np.cumsum(rng.uniform(20.0, 200.0, 9))
    for g in (lambda h: 0.02 * np.abs(h), lambda h: 9.0 * (1 - (1 + np.abs(h) / 80.0) * np.exp(-np.abs(h) / 80.0))):
        picks = np.arange(len(te))
        one_by_one = [interpolation_variance(g, te[k:k + 1], np.delete(te, k), 0.1, 0.25)[0] + 0.25 for k in picks]
        assert np.allclose(held_out_variance(g, te, picks, 0.1, 0.25), one_by_one)
