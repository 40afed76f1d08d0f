"""Operator-weighted fusion: the EM recovers known operator accuracies from shared runs
alone, the fused position beats the best operator, an adversary cannot move it, and the
chi-square test flags what the accuracies do not explain (and little else)."""

from __future__ import annotations

import numpy as np

from posefix.tasks import fusion

SIGMAS = np.array([0.5, 1.0, 2.0, 2.0, 4.0, 8.0])


def _crowd(rng: np.random.Generator, n_runs: int, per_run: int, k: int, sigmas: np.ndarray,
           offsets: dict[int, float] | None = None) -> tuple[list[fusion.RunObs], list[np.ndarray]]:
    runs, truths = [], []
    for _ in range(n_runs):
        ops = rng.choice(len(sigmas), per_run, replace=False)
        t = rng.uniform(-500, 500, (k, 2))
        x = t[None] + rng.normal(size=(per_run, k, 2)) * sigmas[ops][:, None, None]
        for j, o in enumerate(ops):
            if offsets and o in offsets:
                ang = rng.uniform(0, 2 * np.pi)
                x[j] = t + offsets[o] * np.array([np.cos(ang), np.sin(ang)])
        runs.append(fusion.RunObs(x, np.ones((per_run, k), bool), ops, np.ones(per_run, bool)))
        truths.append(t)
    return runs, truths


def test_em_recovers_operator_accuracies_from_shared_runs_alone() -> None:
    rng = np.random.default_rng(3)
    runs, _ = _crowd(rng, 40, 3, 40, SIGMAS)
    none = np.full(len(SIGMAS), np.nan)
    est = fusion.estimate(runs, none, np.zeros(len(SIGMAS)))
    ratio = est.sigma_m / SIGMAS
    assert np.all(np.abs(ratio - 1) < 0.2), ratio
    assert list(np.argsort(est.sigma_m)[[0, 1]]) == [0, 1]


def test_weighted_fusion_beats_the_best_operator_and_the_geometric_median() -> None:
    rng = np.random.default_rng(5)
    k = 2000
    t = np.zeros((k, 2))
    s = np.array([0.5, 1.0, 2.0])
    x = t[None] + rng.normal(size=(3, k, 2)) * s[:, None, None]
    f = fusion.fuse(x, np.ones((3, k), bool), s)
    rmse = float(np.sqrt(np.mean(np.sum(f.t_m ** 2, axis=1))))
    best = float(np.sqrt(np.mean(np.sum(x[0] ** 2, axis=1))))
    gm = fusion.geometric_median(x)
    gm_rmse = float(np.sqrt(np.mean(np.sum(gm ** 2, axis=1))))
    assert rmse < 0.95 * best < gm_rmse
    # inverse-variance theory: 1/sqrt(4 + 1 + 0.25) = 0.436 m per axis; reported per keyframe
    assert abs(float(np.median(f.sigma_m)) - 0.436) < 0.05
    assert abs(rmse / np.sqrt(2) - 0.436) < 0.05


def test_an_adversary_cannot_move_the_consensus_nor_hide_from_the_test() -> None:
    rng = np.random.default_rng(7)
    sig = np.array([0.5, 1.0, 2.0, 2.0, 4.0, 8.0, 1.0])   # the last one is adversarial, 30 m off
    runs, truths = _crowd(rng, 30, 3, 40, sig, offsets={6: 30.0})
    est = fusion.estimate(runs, np.full(len(sig), np.nan), np.zeros(len(sig)))
    # its shape is as precise as its clicks; its steady offset is what gives it away
    assert est.tau_m is not None and est.tau_m[6] > 10 * est.sigma_m[1] and np.all(est.tau_m[:6] < 1.0)
    for run, t, f in zip(runs, truths, est.fused):
        if 6 in run.op:
            assert np.max(np.linalg.norm(f.t_m - t, axis=1)) < 12.0
            # measured elsewhere the adversary looks like a 1 m operator: the test catches it
            test = fusion.chi2_test(run.x_m, run.valid, est.sigma_m[run.op], np.where(run.op == 6, 1.0, sig[run.op]))
            assert test.p[list(run.op).index(6)] < 1e-6


def test_flags_are_rare_when_operators_are_as_accurate_as_measured() -> None:
    rng = np.random.default_rng(11)
    runs, _ = _crowd(rng, 200, 3, 30, SIGMAS[:4])
    flagged = 0
    for run in runs:
        test = fusion.chi2_test(run.x_m, run.valid, SIGMAS[run.op], SIGMAS[run.op])
        flagged += int(np.any(test.p < 1e-3))
    assert flagged / len(runs) < 0.02


def test_gold_prior_fixes_scales_that_two_operators_alone_cannot() -> None:
    rng = np.random.default_rng(13)
    t = np.zeros((50, 2))
    x = t[None] + rng.normal(size=(2, 50, 2)) * np.array([0.5, 4.0])[:, None, None]
    run = fusion.RunObs(x, np.ones((2, 50), bool), np.array([0, 1]), np.ones(2, bool))
    est = fusion.estimate([run], np.array([0.5, np.nan]), np.array([fusion.GOLD_POSITIONS, 0.0]))
    assert est.sigma_m[0] < 0.8 and est.sigma_m[1] > 2.5
    assert np.sqrt(np.mean(np.sum(est.fused[0].t_m ** 2, axis=1))) < 0.9


def test_a_steady_offset_is_off_even_for_an_operator_measured_as_inaccurate() -> None:
    """An adversary the EM has measured by agreement alone (a ~21 m scale) is still off: its
    30 m are the same direction all along; an honest operator whose two partners are both
    steadily off (each its own way) is not blamed for their offsets."""
    rng = np.random.default_rng(13)
    k = 37
    t = rng.uniform(-500, 500, (k, 2))
    honest = t[None] + rng.normal(size=(2, k, 2)) * np.array([0.5, 2.0])[:, None, None]
    adversary = t + np.array([30.0, 0.0]) + rng.normal(size=(k, 2)) * 0.5
    x = np.concatenate([honest, adversary[None]])
    measured = np.array([0.5, 2.0, 21.0])
    test = fusion.chi2_test(x, np.ones((3, k), bool), measured, measured, dof_ref=np.full(3, 200.0))
    assert test.p[2] < 1e-6 and test.p[0] > 1e-3 and test.p[1] > 1e-3
    bad = np.stack([t + np.array([25.0, 0.0]), t + np.array([0.0, 25.0])]) + rng.normal(size=(2, k, 2))
    y = np.concatenate([honest[:1], bad])
    sig = np.array([0.5, 18.0, 18.0])
    test = fusion.chi2_test(y, np.ones((3, k), bool), sig, sig, dof_ref=np.full(3, 200.0))
    assert test.p[0] > 1e-3


def test_a_shifted_submission_still_tells_which_partner_is_accurate() -> None:
    """Two weak operators (4 and 8 m) and an adversary 30 m off but precise: without steady
    offsets in the model only the sum of the two weak ones' variances shows; with them the
    adversary's shape separates the two, and the fusion of the weak pair leans on the 4 m one."""
    rng = np.random.default_rng(17)
    k = 40
    t = rng.uniform(-500, 500, (k, 2))
    x = np.stack([t + rng.normal(size=(k, 2)) * 4.0, t + rng.normal(size=(k, 2)) * 8.0,
                  t + np.array([21.0, 21.0]) + rng.normal(size=(k, 2)) * 0.5])
    run = fusion.RunObs(x, np.ones((3, k), bool), np.array([0, 1, 2]), np.array([True, True, False]))
    est = fusion.estimate([run], np.full(3, np.nan), np.zeros(3))
    assert est.tau_m is not None and est.tau_m[2] > 10.0
    assert 2.5 < est.sigma_m[0] < 6.0 and est.sigma_m[1] > 1.5 * est.sigma_m[0]
    f = fusion.fuse(x[:2], np.ones((2, k), bool), est.sigma_m[:2], tau_m=est.tau_m[:2])
    assert f.w[0].sum() > 2.0 * f.w[1].sum()


def test_the_level_comes_from_operators_steady_elsewhere() -> None:
    """A run whose three submissions are each shifted from the others (a good operator, one
    left on a biased input, an adversary): the run alone cannot say whose level is right; the
    operators' other runs do, and the fused run sits on the good operator's level."""
    rng = np.random.default_rng(19)
    k = 40
    ops = {"good": 0, "careless": 1, "adversary": 2, "a": 3, "b": 4}
    sig = {0: 0.5, 3: 1.0, 4: 2.0}
    runs, truths = [], []
    for members in ([0, 1, 2], [0, 3, 4], [1, 3, 4], [2, 3, 4], [0, 3, 1]):
        t = rng.uniform(-500, 500, (k, 2))
        bias = rng.normal(0, 8.0, 2)
        rows = []
        for o in members:
            if o == ops["careless"]:
                rows.append(t + bias + rng.normal(size=(k, 2)) * 0.3)
            elif o == ops["adversary"]:
                ang = rng.uniform(0, 2 * np.pi)
                rows.append(t + 30.0 * np.array([np.cos(ang), np.sin(ang)]) + rng.normal(size=(k, 2)) * 0.5)
            else:
                rows.append(t + rng.normal(size=(k, 2)) * sig[o])
        runs.append(fusion.RunObs(np.stack(rows), np.ones((3, k), bool), np.array(members), np.ones(3, bool)))
        truths.append(t)
    est = fusion.estimate(runs, np.full(5, np.nan), np.zeros(5))
    level = np.linalg.norm(np.mean(est.fused[0].t_m - truths[0], axis=0))
    assert level < 1.0, (level, est.tau_m)


def test_rejected_work_beside_shifted_work_does_not_swap_the_scales() -> None:
    """A 2 m operator, an 8 m operator a reviewer rejected and an adversary 30 m off: the
    model without offsets splits the two honest ones' variance arbitrarily; the offset model,
    started alike, reads the adversary's shape and keeps the 2 m operator the accurate one."""
    rng = np.random.default_rng(1)
    k = 37
    t = np.cumsum(rng.normal(0, 3, (k, 2)), axis=0)
    x = np.stack([t + rng.normal(0, 2, (k, 2)), t + rng.normal(0, 8, (k, 2)), t + [21.0, 21.0] + rng.normal(0, 0.5, (k, 2))])
    run = fusion.RunObs(x, np.ones((3, k), bool), np.array([0, 1, 2]), np.array([True, False, False]))
    est = fusion.estimate([run], np.full(3, np.nan), np.zeros(3))
    assert est.sigma_m[0] < 3.0 < 6.0 < est.sigma_m[1], est.sigma_m
