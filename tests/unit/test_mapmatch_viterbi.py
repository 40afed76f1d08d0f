"""Viterbi and forward-backward against brute-force enumeration on tiny graphs."""

import itertools

import numpy as np
from scipy.special import logsumexp

from posefix.mapmatch.floorplan import raster_from_polygons
from posefix.mapmatch.graph import build_graph
from posefix.mapmatch.viterbi import ViterbiFilter, forward_backward, gaussian_summary, viterbi


def tiny_graph():
    # 3 x 2 room with a wall stub so that not every move is allowed.
    wall = np.array([[[1.0, 0.0], [1.0, 1.0]]])
    r = raster_from_polygons(3.0, 2.0, [[np.array([[0, 0], [3, 0], [3, 2], [0, 2]], float)]],
                             walls=wall, res_m=0.05)
    return build_graph(r, cell_m=1.0, reach_m=1.0, min_component_m2=1.0)


def problem(seed, t_n=3):
    g = tiny_graph()
    rng = np.random.default_rng(seed)
    trans = rng.normal(size=(t_n, g.offsets.shape[0]))
    state = [rng.normal(size=g.n_vertices) if t % 2 == 0 else None for t in range(t_n)]
    prior = rng.normal(size=g.n_vertices)
    return g, prior, trans, state


def enumerate_paths(g, prior, trans, state):
    """All vertex sequences with their scores (-inf when a move is not allowed)."""
    t_n = trans.shape[0]
    out = []
    for seq in itertools.product(range(g.n_vertices), repeat=t_n + 1):
        s = prior[seq[0]]
        ks = []
        for t in range(t_n):
            hit = np.nonzero(g.succ[seq[t]] == seq[t + 1])[0]
            if hit.size == 0:
                s = -np.inf
                break
            k = int(hit[0])
            ks.append(k)
            s += trans[t, k] + (state[t][seq[t + 1]] if state[t] is not None else 0.0)
        out.append((seq, s, ks))
    return out


def test_viterbi_matches_brute_force():
    for seed in range(3):
        g, prior, trans, state = problem(seed)
        paths = enumerate_paths(g, prior, trans, state)
        best_seq, best_s, _ = max(paths, key=lambda p: p[1])
        path, score = viterbi(g, prior, trans, state, beam=None)
        assert tuple(path.tolist()) == best_seq
        assert np.isclose(score, best_s)


def test_online_filter_best_path_is_prefix_consistent():
    g, prior, trans, state = problem(7, t_n=4)
    f = ViterbiFilter(g, prior, beam=None)
    for t in range(4):
        f.step(trans[t], state[t])
        sub = enumerate_paths(g, prior, trans[: t + 1], state[: t + 1])
        assert tuple(f.best_path().tolist()) == max(sub, key=lambda p: p[1])[0]
        col = f.column()
        assert np.isclose(logsumexp(col[np.isfinite(col)]), 0.0)


def test_forward_backward_matches_brute_force_and_sums_to_one():
    g, prior, trans, state = problem(3)
    paths = enumerate_paths(g, prior, trans, state)
    scores = np.array([p[1] for p in paths])
    log_z = logsumexp(scores)
    fb = forward_backward(g, prior, trans, state, beam=None)
    assert np.isclose(fb.log_z, log_z)
    assert np.allclose(fb.gamma.sum(axis=1), 1.0)
    assert np.allclose(fb.xi_k.sum(axis=1), 1.0)
    p = np.exp(scores - log_z)
    gamma = np.zeros_like(fb.gamma)
    xi = np.zeros_like(fb.xi_k)
    for (seq, _, ks), w in zip(paths, p):
        if w == 0:
            continue
        gamma[np.arange(len(seq)), list(seq)] += w
        xi[np.arange(len(ks)), ks] += w
    assert np.allclose(fb.gamma, gamma, atol=1e-12)
    assert np.allclose(fb.xi_k, xi, atol=1e-12)


def test_gaussian_summary_ellipse():
    p = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 0.0]])
    s = gaussian_summary(p, np.log(np.array([0.25, 0.25, 0.5])))
    assert np.allclose(s.mean_xy_m, [1.0, 0.0])
    assert np.isclose(s.sigma_major_m, np.sqrt(0.5)) and np.isclose(s.sigma_minor_m, 0.0)
    assert np.isclose(s.angle_deg % 180.0, 0.0)


def test_unknown_start_survives_the_beam_and_smoothing_corrects_the_start():
    # A 10 m x 4 m room, 1 m cells, uniform start prior; five steps east, each other move
    # 10 nats worse. Only starts at least 5 cells from the east wall are consistent:
    # smoothing must move the step-0 marginal there (the walk's end disambiguates its
    # start), and the 25-nat beam must not prune the true start at step 0.
    r = raster_from_polygons(10.0, 4.0, [[np.array([[0, 0], [10, 0], [10, 4], [0, 4]], float)]], res_m=0.05)
    g = build_graph(r, cell_m=1.0, reach_m=1.0, min_component_m2=1.0)
    east = int(np.nonzero((g.offsets[:, 0] == 1) & (g.offsets[:, 1] == 0))[0][0])
    trans = np.full((5, g.offsets.shape[0]), -10.0)
    trans[:, east] = 0.0
    prior = np.zeros(g.n_vertices)
    fb = forward_backward(g, prior, trans, beam=25.0)
    exact = forward_backward(g, prior, trans, beam=None)
    assert np.allclose(fb.gamma, exact.gamma, atol=1e-6)
    x0 = g.p_xy_m[:, 0]
    ok = x0 < 10.0 - 5.0  # centres 0.5 .. 4.5 m: room for five 1 m steps east
    assert fb.gamma[0, ok].sum() > 0.999
    assert np.allclose(fb.gamma[0, ok], 1.0 / ok.sum(), atol=1e-3)  # no consistent start preferred
    # The filtered (online) column at step 0 is still uniform: only smoothing corrects it.
    f = ViterbiFilter(g, prior, beam=25.0)
    assert np.allclose(np.exp(f.column()), 1.0 / g.n_vertices)


def test_forward_filter_evidence_is_the_log_partition_over_paths():
    from posefix.mapmatch.viterbi import ForwardFilter

    for seed in range(3):
        g, prior, trans, state = problem(seed)
        f = ForwardFilter(g, prior, beam=None)
        for t in range(trans.shape[0]):
            f.step(trans[t], state[t])
        scores = np.array([s for _, s, _ in enumerate_paths(g, prior, trans, state)])
        assert np.isclose(f.log_evidence(), logsumexp(scores), rtol=1e-10)
