"""Edits that carry their own sigma (``Edit.sigma_m``, a crowd's fused position): soft constraints
in the solve, and held-out edits scored with their noise in the model choice."""

from __future__ import annotations

import numpy as np

from posefix.core import geodesy
from posefix.core.simulate import simulate
from posefix.engine import CorrectionConfig, Edit, prepare
from posefix.engine.calibrate import ProcessFit, RW_TAU_S, choose, naive_ratio
from posefix.engine.edits import Edits


def _problem(model: str = "gnss", seed: int = 5):
    sim = simulate(duration_s=600.0, rate_hz=2.0, edit_every_s=0.0, seed=seed, regime="mixed")
    return sim, prepare(sim.run, CorrectionConfig.from_dict({"calibration": {"model": model}}))


def _edit(problem, k: int, p_enu, sigma=None) -> Edit:
    lat, lon, _ = geodesy.enu_to_geodetic(np.asarray(p_enu, dtype=float)[None], problem.origin)
    return Edit(k, float(lon[0]), float(lat[0]), None, sigma)


def _truth_edits(sim, problem, ks, sigma=None) -> list[Edit]:
    rows = problem.keyframe_index[list(ks)]
    return [Edit(int(k), float(sim.truth.lon_deg[r]), float(sim.truth.lat_deg[r]), None, sigma) for k, r in zip(ks, rows)]


def test_an_edit_with_a_sigma_is_a_soft_constraint_between_the_prior_and_its_target():
    sim, problem = _problem()
    base = _truth_edits(sim, problem, (50, 150, 250, 350, 450))
    prior = problem.solve_edits(Edits(tuple(base))).keyframes.p_enu_m[200]
    target = prior + np.array([6.0, -4.0, 0.0])
    d = target[:2] - prior[:2]
    share = []
    for sigma in (0.1, 0.5, 2.0, 5.0, 30.0):
        edits = Edits(tuple(sorted(base + [_edit(problem, 200, target, sigma)], key=lambda e: e.index)))
        p = problem.solve_edits(edits).keyframes.p_enu_m[200]
        share.append(float(np.dot(p[:2] - prior[:2], d) / np.dot(d, d)))
    # the keyframe lies between the prior and the edit, nearer the prior the looser the edit
    assert all(-0.02 < s < 1.02 for s in share), share
    assert all(a > b for a, b in zip(share, share[1:])), share
    assert share[0] > 0.9 and share[-1] < 0.1, share


def test_edits_carrying_the_configured_sigma_solve_as_ordinary_edits():
    sim, problem = _problem()
    ks = (30, 90, 150, 210, 270, 330, 390, 450)
    rng = np.random.default_rng(1)
    rows = problem.keyframe_index[list(ks)]
    c = problem.p_enu_m[rows] + np.column_stack([rng.normal(0, 3, (len(ks), 2)), np.zeros(len(ks))])
    plain = problem.solve_edits(Edits(tuple(_edit(problem, k, ck) for k, ck in zip(ks, c))))
    same = problem.solve_edits(Edits(tuple(_edit(problem, k, ck, problem.cfg.user.sigma_h_m) for k, ck in zip(ks, c))))
    assert np.allclose(plain.keyframes.p_enu_m, same.keyframes.p_enu_m, atol=1e-6)


def test_an_edits_sigma_is_stored_only_when_set_and_a_new_move_replaces_it():
    ordinary = Edit(3, 24.9, 60.1)
    fused = Edit(7, 24.9, 60.2, None, 0.4)
    es = Edits((ordinary, fused))
    data = es.to_json()
    assert data["moves"] == [[3, 24.9, 60.1, None], [7, 24.9, 60.2, None, 0.4]]  # ordinary edit sets unchanged
    assert Edits.from_json(data) == es
    assert Edits((ordinary,)).sigma_m is None
    assert np.array_equal(es.sigma_m, [np.nan, 0.4], equal_nan=True)
    # an operator moving a merged keyframe again: their click, with the configured sigma
    again = es.merged([Edit(7, 24.95, 60.2)])
    assert again.moves[1].sigma_m is None and again.sigma_m is None
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        try:
            Edit(1, 0.0, 0.0, None, bad)
        except ValueError:
            continue
        raise AssertionError(f"sigma {bad} accepted")


def test_naive_interpolation_is_scaled_with_the_noise_it_passes_through():
    t_e = np.arange(0.0, 1000.0, 10.0)
    kf_t = np.arange(0.0, 990.0, 0.5)
    picks = np.arange(10, 90, 7)
    walk = ProcessFit("random_walk", 0.0, 1.0 * RW_TAU_S / 2.0, RW_TAU_S, 1.0)
    # exact edits: a random walk bridged over one gap against a held-out edit mid-way in two (1/sqrt 3)
    assert abs(naive_ratio(kf_t, t_e, walk, 1e-12, picks) - 1.0 / np.sqrt(3.0)) < 0.01
    # noise alone: interpolated noise averages 2/3 R over the run, a held-out edit sees R/2 + R
    still = ProcessFit("random_walk", 0.0, 1e-12 * RW_TAU_S / 2.0, RW_TAU_S, 1e-12)
    assert abs(naive_ratio(kf_t, t_e, still, 0.25, picks) - 2.0 / 3.0) < 0.01
    # so noise raises naive's run-wide scale above the smoother's bridge (f = 1/sqrt 3 here)
    assert naive_ratio(kf_t, t_e, walk, 5.0, picks) > 0.62


def test_the_choice_scales_naive_by_its_own_ratio_when_edits_carry_noise():
    rng = np.random.default_rng(3)
    r_gnss = rng.normal(0, 1.0, (12, 2))
    residuals = {"gnss": r_gnss, "naive": 0.8 * r_gnss}  # naive predicts the held-out edits better
    assert choose(residuals, 0.6) == "naive"  # exact edits: on the same scale, it wins
    # noisy edits it passes straight through: run-wide it is the worse
    assert choose(residuals, 0.6, f_naive=0.8) == "gnss"


def test_noisy_edits_carrying_their_sigma_are_not_passed_through_by_naive_interpolation():
    # crowd-benchmark-like drive: every 5th keyframe placed with 1 m per axis of noise
    sim = simulate(duration_s=180.0, rate_hz=5.0, edit_every_s=0.0, seed=116)
    problem = prepare(sim.run)
    idx = problem.keyframe_index
    truth = problem.to_enu(np.interp(sim.run.t_s[idx], sim.truth.t_s, sim.truth.lon_deg),
                           np.interp(sim.run.t_s[idx], sim.truth.t_s, sim.truth.lat_deg), sim.run.alt_m[idx])
    ks = sorted(set(range(0, len(idx), 5)) | {len(idx) - 1})
    rng = np.random.default_rng(116)
    c = truth[ks] + np.column_stack([rng.normal(0, 1.0, (len(ks), 2)), np.zeros(len(ks))])
    chosen = {}
    for sigma in (None, 1.0):
        sol = problem.solve_edits(Edits(tuple(_edit(problem, k, ck, sigma) for k, ck in zip(ks, c))))
        chosen[sigma] = sol.drift.calibration.model
    assert chosen == {None: "naive", 1.0: "gnss"}
