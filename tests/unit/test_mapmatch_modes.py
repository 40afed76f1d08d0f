"""Modes of a position posterior and the converged flag (posefix.mapmatch.modes)."""

import numpy as np
import pytest

from posefix.mapmatch.modes import posterior_modes


def grid(n=100, cell=0.8):
    xx, yy = np.meshgrid((np.arange(n) + 0.5) * cell, (np.arange(n) + 0.5) * cell)
    return np.column_stack([xx.ravel(), yy.ravel()])


def blob(p, c, sigma, along=None):
    d = p - np.asarray(c)
    if along is None:
        return np.exp(-0.5 * np.sum(d**2, axis=1) / sigma**2)
    return np.exp(-0.5 * (d[:, 0] ** 2 / along**2 + d[:, 1] ** 2 / sigma**2))


def test_one_blob_is_one_converged_mode_even_when_long():
    p = grid()
    m = posterior_modes(p, blob(p, (40, 40), 1.5))
    assert m.n == 1 and m.converged and m.spread_m == 0.0
    assert np.allclose(m.mean_xy_m[0], (40, 40), atol=0.1) and m.mass[0] > 0.99
    # A walk placed across a corridor but not yet along it: one connected mode, but 12 m (1σ)
    # along the corridor is not a place.
    m = posterior_modes(p, blob(p, (40, 40), 1.0, along=12.0))
    assert m.n == 1 and not m.converged
    assert posterior_modes(p, blob(p, (40, 40), 1.0, along=4.0)).converged


def test_two_places_are_two_modes_and_not_converged():
    p = grid()
    prob = 0.7 * blob(p, (20, 20), 1.5) + 0.3 * blob(p, (60, 50), 1.5)
    m = posterior_modes(p, prob)
    assert m.n == 2 and not m.converged
    assert m.mass[0] == pytest.approx(0.7, abs=0.01) and m.mass[1] == pytest.approx(0.3, abs=0.01)
    assert m.spread_m == pytest.approx(50.0, abs=0.2)
    # A second place with 3 % of the mass 20 m away is counted but does not stop convergence
    # at 95 % (it moves the reported mean 0.6 m and widens its ellipse to 1σ 3.7 m)...
    m = posterior_modes(p, 0.97 * blob(p, (20, 20), 1.5) + 0.03 * blob(p, (40, 20), 1.5))
    assert m.n == 2 and m.converged and m.sigma_major_m == pytest.approx(3.7, abs=0.1)
    # ... but 50 m away the same 3 % stretches the reported ellipse to 1σ 8.7 m: no fix.
    m = posterior_modes(p, 0.97 * blob(p, (20, 20), 1.5) + 0.03 * blob(p, (60, 50), 1.5))
    assert m.n == 2 and not m.converged and m.mass[0] >= 0.95 and m.sigma_major_m > 8.0
    # ... while one with 0.5 % is below the 1 % that counts as a place.
    m = posterior_modes(p, 0.995 * blob(p, (20, 20), 1.5) + 0.005 * blob(p, (60, 50), 1.5))
    assert m.n == 1


def test_uniform_posterior_over_a_floor_is_not_converged():
    p = grid(60)
    keep = (p[:, 0] < 10) | (p[:, 0] > 38)  # two wings with nothing between them
    m = posterior_modes(p[keep], np.ones(keep.sum()))
    assert m.n == 2 and not m.converged and m.spread_m > 30.0
    # Uniform over one connected floor: one component, nowhere in particular.
    m = posterior_modes(p, np.ones(len(p)))
    assert m.n == 1 and not m.converged


def test_ties_are_broken_by_position_so_other_implementations_agree():
    # Equal masses everywhere: the support keeps the lower-numbered bins (row by row, from
    # the lowest y), so half the support is the lower half of both wings.
    p = grid(60)
    keep = (p[:, 0] < 10) | (p[:, 0] > 38)
    m = posterior_modes(p[keep], np.ones(keep.sum()), support=0.5)
    assert m.n == 2 and np.all(m.mean_xy_m[:, 1] < 20) and np.all(m.mass < 0.26)
    # Two identical places: the one whose first bin comes first (the left one) is the main one.
    prob = np.zeros((60, 60))  # rows (y) x columns (x) of grid(60)
    prob[10:13, 10:13] = prob[10:13, 40:43] = 1.0
    prob = prob.ravel()
    m = posterior_modes(p, prob)
    assert m.n == 2 and m.mass[0] == m.mass[1] and m.mean_xy_m[0, 0] < m.mean_xy_m[1, 0]


def test_a_converged_estimate_is_near_its_place_and_small_whatever_the_rest_does():
    # The guarantee of the rule (module docstring): converged means the reported mean (of the
    # whole posterior) is within σ·√(ε/(1 − ε)) of the main mode's mean, ε = 1 − its mass,
    # and the reported 1σ is at most 5 m. Random mixtures of up to four blobs, anywhere.
    rng = np.random.default_rng(7)
    p = grid(80)
    seen = 0
    for _ in range(150):
        n = int(rng.integers(1, 5))
        mix = rng.dirichlet(np.full(n, 0.3))
        mix[0] += rng.uniform(0, 3)  # often one dominant place
        prob = sum(w * blob(p, rng.uniform(5, 59, 2), rng.uniform(0.5, 4)) / blob(p, (32, 32), 1).sum()
                   for w in mix)
        m = posterior_modes(p, prob)
        if not m.converged:
            continue
        seen += 1
        w = prob / prob.sum()
        eps = 1.0 - m.mass[0]
        shift = np.linalg.norm(w @ p - m.mean_xy_m[0])
        assert m.sigma_major_m <= 5.0 and m.mass[0] >= 0.95
        assert shift <= m.sigma_major_m * np.sqrt(eps / (1 - eps)) + 1e-9, (shift, m)
    assert seen >= 30  # the property was exercised


def test_step_correction_recovers_a_walks_heading_and_scale_from_its_converged_stretches():
    from posefix.mapmatch.calibrate import apply_step_correction, estimate_step_correction

    rng = np.random.default_rng(3)
    # An L-shaped walk of 0.7 m steps: 40 east, then 40 north.
    steps = np.vstack([np.tile([0.7, 0.0], (40, 1)), np.tile([0.0, 0.7], (40, 1))])
    a_true = 1.08 * np.exp(1j * np.radians(6.0))
    truth = np.vstack([[0.0, 0.0], np.cumsum(apply_step_correction(steps, a_true), axis=0)])
    p = truth + rng.normal(0.0, 0.2, truth.shape)
    a = estimate_step_correction(steps, p, np.ones(len(p), bool), cell_m=0.8, sigma_len_m=0.35, sigma_a=10.0)
    assert abs(a) == pytest.approx(1.08, abs=0.02) and np.degrees(np.angle(a)) == pytest.approx(6.0, abs=1.0)
    # The prior (σ 0.1 around 1) pulls a short walk's estimate part of the way back to 1.
    a_map = estimate_step_correction(steps, p, np.ones(len(p), bool), cell_m=0.8, sigma_len_m=0.35)
    assert 0.3 < abs(a_map - 1) / abs(a - 1) < 0.9 and np.angle(a_map) > 0
    # Nothing converged (the posterior between places says nothing): the prior, a = 1.
    assert estimate_step_correction(steps, p, np.zeros(len(p), bool), 0.8, 0.35) == 1.0
    # Windows with a turn inside are left out: only the corner window here, the rest still agree.
    ok = np.ones(len(p), bool)
    assert abs(estimate_step_correction(steps, p, ok, 0.8, 0.35, window_steps=10, sigma_a=10.0) - a) < 0.02


def test_cli_track_says_whether_it_converged(tmp_path):
    from pathlib import Path

    from click.testing import CliRunner

    from posefix.cli import build_app

    floor = Path(__file__).resolve().parents[2] / "data" / "indoor-site2-F2"
    walk = sorted((floor / "walks").glob("*.txt"))[0]
    app, r = build_app(), CliRunner()
    assert r.invoke(app, ["mapmatch", "build", "--floor", str(floor), "--output", str(tmp_path / "m.npz")]).exit_code == 0
    from posefix.mapmatch import read_walk

    x, y = read_walk(walk).waypoints[0, 1:3]
    out = r.invoke(app, ["mapmatch", "track", str(walk), "--model", str(tmp_path / "m.npz"), "--start", f"{x},{y}",
                         "--output", str(tmp_path / "t.csv")])
    assert out.exit_code == 0, out.output
    assert "converged: yes" in out.output
    rows = (tmp_path / "t.csv").read_text().splitlines()
    assert rows[0].endswith(",converged,n_modes,mode_spread_m") and rows[-1].split(",")[-3:] == ["1", "1", "0.0"]
    # Unknown start, motion only: the walk's shape fits several places, and the CLI names them.
    out = r.invoke(app, ["mapmatch", "track", str(walk), "--model", str(tmp_path / "m.npz"),
                         "--output", str(tmp_path / "u.csv")])
    assert out.exit_code == 0, out.output
    assert "converged: no - the walk fits " in out.output and " places up to " in out.output
    last = (tmp_path / "u.csv").read_text().splitlines()[-1].split(",")
    assert last[-3] == "0" and int(last[-2]) >= 2 and float(last[-1]) > 0.0
