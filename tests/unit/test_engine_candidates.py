"""benchmarks.engine_candidates: each candidate's figures, the leave-one-out stack and the oracle blend."""

from __future__ import annotations

import numpy as np

from benchmarks.engine_candidates import candidates_of, row, simplex
from benchmarks.engine_heldout import at_most
from posefix.core.families import simulate_family


def test_simplex_grid_holds_every_vertex_and_only_convex_weights():
    W = simplex(3, step=0.25)
    assert len(W) == 15  # C(4 + 2, 2)
    assert np.allclose(W.sum(axis=1), 1.0) and np.all(W >= -1e-12)
    for vertex in np.eye(3):
        assert np.any(np.all(np.isclose(W, vertex), axis=1))


def test_ties_count_only_at_float_level_for_both_peers():
    assert at_most(2.0, 2.0) and at_most(2.0 * (1 + 1e-12), 2.0)
    # a solver's tolerance away (the 0.5 % the GTSAM count once allowed) is a loss
    assert not at_most(2.0 * (1 + 1e-6), 2.0) and not at_most(2.0 * 1.004, 2.0)
    assert list(at_most([1.0, 3.0], [2.0, 2.0])) == [True, False]


def test_candidates_row_on_a_short_ekf_drive():
    sim = simulate_family("ekf", duration_s=360.0, rate_hz=2.0, edit_every_s=40.0, seed=3)
    r = candidates_of(sim)
    assert set(r["pos"]) == {"gnss", "plain", "relative", "naive"}
    assert r["chosen"] in r["pos"]
    out = row("ekf", 40.0, 3, r)
    # the oracle blend tries w = 0 and 1 of each model with naive: never worse than naive or the best model
    assert out["blend"] <= min(out["true"].values()) + 1e-9
    assert abs(sum(out["w"].values()) - 1.0) < 1e-9
    # the chosen model's solve is the one the engine returns: its error is that candidate's
    assert abs(out["posefix"] - out["true"][r["chosen"]]) < 1e-6
    assert out["predicted"] > 0
